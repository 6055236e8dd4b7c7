"""The measurement transport: when (and whether) a frame's measurement reaches the controller.

This is the one place the loop models latency: a fixed read-out/compute latency, the
correlator device's pipeline (which blocks of which frame it processes and when each frame's
last result arrives, from :mod:`correlator.timing` via the wiring), random losses, and a
channel (the serial link) that may corrupt or lose records on the way.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from compensation.blocks import BlockMeasurements

#: a channel passes a measurement on (possibly with blocks marked invalid) or loses it
Channel = Callable[[BlockMeasurements, float], BlockMeasurements | None]


@dataclass(frozen=True)
class TransportState:
    sent: int
    lost: int


@dataclass(frozen=True)
class Transport:
    """Latency, the device schedule, drops and a channel.

    latency_s : from the end of an exposure (or the device's delivery) to the controller, s.
    deliver_s : (T,) when the correlator device delivers each frame's results (inf: the
        device processed none of its blocks); None: as soon as the exposure ends.
    processed : (T, B) which blocks of each frame the device correlates; None: all.
    drop_probability : chance a frame's measurement is lost; drops of frame k are drawn from
        ``numpy.random.default_rng([*seed, k])``.
    channel : the serial link (or None).
    """

    latency_s: float = 0.0
    deliver_s: np.ndarray | None = None
    processed: np.ndarray | None = None
    drop_probability: float = 0.0
    seed: tuple[int, ...] = (0,)
    channel: Channel | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.latency_s) and self.latency_s >= 0):
            raise ValueError(f"latency_s must be >= 0, got {self.latency_s}")
        if not 0 <= self.drop_probability < 1:
            raise ValueError(f"drop_probability must be within [0, 1), got "
                             f"{self.drop_probability}")

    def init(self) -> TransportState:
        return TransportState(0, 0)

    def blocks(self, frame: int, n_blocks: int) -> np.ndarray:
        if self.processed is None:
            return np.ones(n_blocks, bool)
        return np.asarray(self.processed[frame], dtype=bool)

    def send(self, state: TransportState, meas: BlockMeasurements, ready_s: float):
        k = meas.frame
        t = ready_s if self.deliver_s is None else float(self.deliver_s[k])
        if not np.isfinite(t):
            return state, None, meas
        t = t + self.latency_s
        if self.drop_probability and (np.random.default_rng([*self.seed, k]).random()
                                      < self.drop_probability):
            return dataclasses.replace(state, lost=state.lost + 1), None, meas
        if self.channel is not None:
            out = self.channel(meas, t)
            if out is None:
                return dataclasses.replace(state, lost=state.lost + 1), None, meas
            meas = out
        return dataclasses.replace(state, sent=state.sent + 1), t, meas

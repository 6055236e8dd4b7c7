"""When a correlator delivers: the optical correlator's pipeline as a schedule.

The seed's hardware model: video inputs at 30 frames/s; each optical processor does 30 Fourier
transforms/s; a correlation takes 2 transforms (input plane -> JPS, JPS -> correlation plane),
done by 2 cascaded processors, each transforming two image pairs at once. So every cycle of
1/30 s the pipeline accepts 2 new pairs and delivers 2: 60 correlations/s, each result
``latency_s`` = input transfer + 2 cycles + output after its frame was read out.

:meth:`PipelineTiming.schedule` turns frame read-out times and a block count into, per
(frame, block), whether the device processed it and when its result arrives. Policy
``latest`` (default) drops pairs of a frame still waiting when a newer frame is ready (a
tracker wants the freshest motion); ``fifo`` keeps every pair in order (latency then grows
without bound when the tracker asks for more than the device does).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POLICIES = ("latest", "fifo")


@dataclass(frozen=True)
class Schedule:
    """Per (frame, block): ``done`` (T, B) processed, ``deliver_s`` (T, B) arrival time of the
    result (inf when dropped), ``start_s`` (T, B) start of its first transform."""

    done: np.ndarray
    deliver_s: np.ndarray
    start_s: np.ndarray

    @property
    def dropped(self) -> int:
        return int((~self.done).sum())

    def frame_deliver_s(self) -> np.ndarray:
        """(T,) when the last processed block of each frame arrives (inf: nothing processed)."""
        d = np.where(self.done, self.deliver_s, -np.inf).max(axis=1)
        return np.where(np.isfinite(d), d, np.inf)


@dataclass(frozen=True)
class PipelineTiming:
    """A correlator's throughput and latency (defaults: the seed's hardware model, 60/s).

    transforms_per_s : optical Fourier transforms per second of one processor.
    processors : processors in cascade (each does one transform of every correlation).
    transforms_per_correlation : transforms one correlation needs.
    pairs_per_transform : image pairs one transform handles at once.
    input_latency_s : from frame read-out to the input SLM (a video frame).
    output_latency_s : from the correlation plane to the host (read-out, peak, record).
    policy : 'latest' or 'fifo' (module docstring).
    """

    transforms_per_s: float = 30.0
    processors: int = 2
    transforms_per_correlation: int = 2
    pairs_per_transform: int = 2
    input_latency_s: float = 1.0 / 30.0
    output_latency_s: float = 0.005
    policy: str = "latest"

    def __post_init__(self) -> None:
        if self.transforms_per_s <= 0 or min(self.processors, self.transforms_per_correlation,
                                             self.pairs_per_transform) < 1:
            raise ValueError("transforms_per_s must be > 0; processors, "
                             "transforms_per_correlation and pairs_per_transform >= 1")
        if self.input_latency_s < 0 or self.output_latency_s < 0:
            raise ValueError("input_latency_s and output_latency_s must be >= 0")
        if self.policy not in POLICIES:
            raise ValueError(f"policy must be one of {POLICIES}, got {self.policy!r}")

    @classmethod
    def fast(cls, correlations_per_s: float = 10_000.0) -> PipelineTiming:
        """A device with the claimed 10,000 correlations/s (128^2 blocks): same architecture,
        faster transforms, no video frame in the input path."""
        return cls(transforms_per_s=correlations_per_s / 2.0, input_latency_s=0.0,
                   output_latency_s=1e-4)

    @property
    def cycle_s(self) -> float:
        """Time between batches entering the pipeline."""
        return self.transforms_per_correlation / (self.transforms_per_s * self.processors)

    @property
    def pairs_per_cycle(self) -> int:
        return self.pairs_per_transform

    @property
    def correlations_per_s(self) -> float:
        return self.pairs_per_cycle / self.cycle_s

    @property
    def latency_s(self) -> float:
        """From frame read-out to result, for a pair that does not wait."""
        return (self.input_latency_s + self.transforms_per_correlation / self.transforms_per_s
                + self.output_latency_s)

    def schedule(self, ready_s: np.ndarray, n_blocks: int) -> Schedule:
        """Which pairs of frames read out at ``ready_s`` (T,) are correlated, and when they
        arrive. Cycles start at multiples of ``cycle_s``; pairs queue in frame, block order."""
        ready = np.asarray(ready_s, dtype=np.float64) + self.input_latency_s
        t_n = len(ready)
        done = np.zeros((t_n, n_blocks), bool)
        start = np.full((t_n, n_blocks), np.inf)
        if t_n == 0:
            return Schedule(done, start.copy(), start)
        if np.any(np.diff(ready) < 0):
            raise ValueError("frame read-out times must be non-decreasing")
        cyc, per = self.cycle_s, self.pairs_per_cycle
        queue: list[tuple[int, int]] = []
        k_next = 0
        c = int(np.ceil(ready[0] / cyc - 1e-9))
        # an event loop over cycles (cheap: one step per cycle, not per pixel)
        while k_next < t_n or queue:
            t = c * cyc
            while k_next < t_n and ready[k_next] <= t + 1e-12:
                if self.policy == "latest":
                    queue = []
                queue.extend((k_next, b) for b in range(n_blocks))
                k_next += 1
            if not queue:  # idle until the next frame is ready
                c = max(c + 1, int(np.ceil(ready[k_next] / cyc - 1e-9)))
                continue
            take, queue = queue[:per], queue[per:]
            for k, b in take:
                done[k, b] = True
                start[k, b] = t
            c += 1
        total = self.transforms_per_correlation / self.transforms_per_s + self.output_latency_s
        deliver = np.where(done, start + total, np.inf)
        return Schedule(done, deliver, start)

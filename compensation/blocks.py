"""The loop's signals, the protocols of its blocks, and the registry that picks them by kind.

A block is a small frozen object with an ``init()`` that returns its state and an update
method ``(state, input) -> (state, output)`` (python-control's update / output functions).
States are frozen dataclasses of numbers and arrays, so a checkpoint can store them
(:mod:`compensation.state`). The code that steps time (:mod:`compensation.loop`) knows these
protocols only: it never sees a renderer, a correlator or a camera.

Units: pixels of the tracker sensor (px) and seconds (s); (row, col) order everywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class BlockMeasurements:
    """What the tracker measured in one frame: every block against its reference frame.

    frame : the measured frame index; t_s : its exposure mid-time, s.
    ref_frame : (B,) reference frame of each block.
    centers_px : (B, 2) block centres in the reference frame, sensor px.
    shift_px : (B, 2) content shift against the reference (docs/conventions.md), NaN where
        not measured.
    sigma_px : (B, 2) predicted 1-sigma error (CRLB), inf where invalid.
    valid : (B,) the correlator's validity flags.
    peak : (B,) peak-to-sidelobe ratio (0 where not measured).
    deform_px : (B,) predicted change of the motion across each block since its reference
        (perspective, rotation, scale), px; what makes a reference stale.
    leaving : (B,) the block's content leaves the sensor within the next frames: it needs a
        new reference now (scanning views).
    predicted_px : (B, 2) the orbit/attitude/DEM prediction (no jitter) of each block's
        content motion from its reference to this frame, px (zeros when nothing is known).
    field_predicted_px : (2,) the same at the main imager's field point.
    """

    frame: int
    t_s: float
    ref_frame: np.ndarray
    centers_px: np.ndarray
    shift_px: np.ndarray
    sigma_px: np.ndarray
    valid: np.ndarray
    peak: np.ndarray
    deform_px: np.ndarray
    leaving: np.ndarray
    predicted_px: np.ndarray
    field_predicted_px: np.ndarray

    @property
    def n_blocks(self) -> int:
        return len(self.valid)


@dataclass(frozen=True)
class MotionEstimate:
    """The estimator's output for one frame, at the main imager's field point.

    motion_px : (2,) content motion at the field point since frame 0 (pseudo-open-loop: the
        stage the frame and its reference were exposed with is added back), px.
    sigma_px : (2,) its predicted 1-sigma error, px.
    valid : usable by a controller.
    used : (B,) blocks that entered the fit; outliers : (B,) blocks rejected as outliers.
    model : the motion-field model fitted ('none', 'mean', 'translation', 'similarity',
        'affine').
    """

    frame: int
    t_s: float
    motion_px: np.ndarray
    sigma_px: np.ndarray
    valid: bool
    used: np.ndarray
    outliers: np.ndarray
    model: str


@dataclass(frozen=True)
class ControlInput:
    """What a controller sees when a measurement arrives.

    t_s : now (the command acts from this time), s.
    t_meas_s : exposure mid-time of the measured frame, s.
    target_px : (2,) where the stage should have been during that exposure: the estimated
        content motion minus the motion the main imager follows by itself (TDI charge), px.
    stage_px : (2,) the commanded stage position averaged over that exposure, px; so
        ``target_px - stage_px`` is the residual the tracker saw.
    last_command_px : (2,) the command now applied, px.
    sigma_px : (2,) predicted 1-sigma error of target_px; valid : usable.
    period_s : the nominal time between measurements (for predictors), s.
    """

    t_s: float
    t_meas_s: float
    target_px: np.ndarray
    stage_px: np.ndarray
    last_command_px: np.ndarray
    sigma_px: np.ndarray
    valid: bool
    period_s: float


@runtime_checkable
class Estimator(Protocol):
    """Blocks' shifts -> one motion estimate at the main imager's field point."""

    kind: str

    def init(self, n_blocks: int) -> Any:
        """The state before the first measurement of ``n_blocks`` blocks."""
        ...

    def update(self, state: Any, meas: BlockMeasurements, stage_px: np.ndarray,
               ref_stage_px: np.ndarray) -> tuple[Any, MotionEstimate]:
        """stage_px (2,): commanded stage mean over the measured exposure; ref_stage_px
        (B, 2): the same over each block's reference exposure."""
        ...

    def rereference(self, state: Any, meas: BlockMeasurements) -> tuple[Any, bool]:
        """Should every block take the measured frame as its new reference? (Decided at
        measurement time, on the tracker's side.)"""
        ...


@runtime_checkable
class Controller(Protocol):
    """Measurement -> stage command (px)."""

    kind: str

    def init(self) -> Any:
        """The state before the first measurement (no command yet)."""
        ...

    def update(self, state: Any, inp: ControlInput) -> tuple[Any, np.ndarray]: ...


@runtime_checkable
class Supervisor(Protocol):
    """Optional: watches each delivered measurement and the command the controller proposes,
    and may replace the command (hold the stage, de-rate the law). Its decisions live in its
    state (:meth:`decisions` lists them)."""

    kind: str

    def init(self) -> Any: ...

    def update(self, state: Any, inp: ControlInput, u_px: np.ndarray
               ) -> tuple[Any, np.ndarray]: ...

    def decisions(self, state: Any) -> list[dict]: ...


@runtime_checkable
class Actuator(Protocol):
    """The focal-plane stage: commands in, a continuous trajectory out.

    ``advance`` integrates the stage up to a time and returns the trajectory samples it
    produced; ``interpolation`` says how to read the stage between samples ('previous': a
    step at each sample, 'linear').
    """

    kind: str
    interpolation: str

    def init(self, t0_s: float) -> Any:
        """The stage at rest at zero offset at time ``t0_s``."""
        ...

    def clip(self, u_px: np.ndarray) -> np.ndarray:
        """The command as the stage can follow it (stroke limits), px."""
        ...

    def command_model(self) -> Actuator:
        """The ideal actuator the loop assumes when it adds the stage back to a measurement
        (pseudo-open-loop): what it knows of the stage without a position sensor."""
        ...

    def linearized(self) -> Actuator:
        """The same actuator without its nonlinear effects (for the analytic model)."""
        ...

    def command(self, state: Any, t_s: float, u_px: np.ndarray) -> Any: ...

    def saturated_s(self, state: Any) -> float:
        """Time spent with a command clipped at the stroke so far, s."""
        ...

    def advance(self, state: Any, t_s: float) -> tuple[Any, np.ndarray, np.ndarray]:
        """-> (state, sample times (N,), positions (N, 2)) produced since the last call."""
        ...


@runtime_checkable
class Transport(Protocol):
    """How a frame's measurement reaches the controller: latency, drops, the device
    pipeline, a serial link. The loop models latency here and nowhere else."""

    def init(self) -> Any:
        """The state before the first frame (nothing in flight)."""
        ...

    def blocks(self, frame: int, n_blocks: int) -> np.ndarray:
        """(B,) blocks of this frame the correlator processes."""
        ...

    def send(self, state: Any, meas: BlockMeasurements, ready_s: float
             ) -> tuple[Any, float | None, BlockMeasurements]:
        """-> (state, arrival time or None if lost, the measurement as it arrives)."""
        ...


@runtime_checkable
class Plant(Protocol):
    """Everything outside the loop's blocks: truth, images, correlator.

    ``measure`` exposes frame k with the stage trajectory ``stage`` (a function of time,
    px) and returns the tracker's measurements; ``rereference`` makes frame k every block's
    reference. A plant may keep its frames; the loop does not look at them.
    """

    n_blocks: int

    def measure(self, k: int, stage: Callable[[np.ndarray], np.ndarray],
                blocks: np.ndarray) -> BlockMeasurements: ...

    def rereference(self, k: int) -> None: ...

    def chunk_arrays(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """What frames [start, stop) added to the plant, and its small state now, for a
        checkpoint."""
        ...

    def restore(self, chunks: list[dict[str, np.ndarray]]) -> None:
        """Continue from the arrays of every checkpoint chunk (in order)."""
        ...


#: kind -> class, per role; filled by :func:`register` as the block modules are imported
#: (compensation.registry imports the built-in ones)
REGISTRY: dict[str, dict[str, type]] = {"estimator": {}, "controller": {}, "actuator": {},
                                        "supervisor": {}}


def register(role: str, kind: str):
    """Class decorator: make ``kind`` buildable by :func:`build` for ``role``."""

    def deco(cls):
        if kind in REGISTRY[role]:
            raise ValueError(f"{role} kind {kind!r} is registered twice")
        REGISTRY[role][kind] = cls
        cls.kind = kind
        return cls

    return deco

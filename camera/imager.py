"""The main imager on the focal plane: a frame camera or a TDI pushbroom, and its smear.

A TDI (time delay and integration) imager clocks its charge packets one row per line period
along +row, the direction the ground flows (docs/conventions.md). A ground point's image moves
by m(t); its charge moves by q(t) = line_rate * t along rows (``clock_phases`` = 0: ideal,
continuous; p: in steps of 1/p px, as a p-phase CCD does). The residual m(t) - q(t) over the
N-stage integration is what blurs the line: with image velocity v (px/s) and line rate L the
linear smear is (v / L - 1) N px, zero when the line rate is synchronous.

The imager kind is a class (:data:`IMAGERS`, by the scenario's ``camera.main_imager.kind``):
each answers whether it scans, its integration time, its sampling (:mod:`camera.sampling`),
the charge motion it follows by itself and the sign that maps a residual image motion to a
line-of-sight offset on its nominal grid, so the stages above ask the imager instead of
testing its kind.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar, Literal

import numpy as np

from camera.geometry import FocalPlane
from camera.sampling import FrameSampling, LineSampling, frame_sampling, tdi_sampling


@dataclass(frozen=True)
class FrameImager:
    """A staring frame camera: ``rows`` x ``cols`` exposed for ``exposure_s``.

    ``center_offset_px`` is its centre relative to the principal point, (row, col) px.
    """

    rows: int = 4096
    cols: int = 4096
    exposure_s: float = 0.1
    center_offset_px: tuple[float, float] = (0.0, 0.0)
    kind: Literal["frame"] = "frame"
    #: a frame camera stares: its whole window integrates over one exposure
    scanning: ClassVar[bool] = False
    #: (row, col) factors from the residual image motion r = jitter - stage to the
    #: line-of-sight offset on the nominal grid (``image[p] ~ static[p + off]``): a frame
    #: pixel sees the ground the image moved away from (docs/conventions.md)
    product_sign: ClassVar[tuple[float, float]] = (-1.0, -1.0)

    @classmethod
    def from_config(cls, cfg: Any) -> FrameImager:
        """The imager of a scenario's ``camera.main_imager`` section (any object with its
        fields)."""
        return cls(exposure_s=cfg.exposure_s, center_offset_px=tuple(cfg.center_offset_px))

    @property
    def line_rate_hz(self) -> None:
        """A frame camera clocks no lines."""
        return None

    @property
    def charge_velocity_px_s(self) -> tuple[float, float]:
        """The mean velocity (row, col) of the charge on the focal plane: at rest, px/s."""
        return (0.0, 0.0)

    def with_line_rate(self, velocity_px_s: np.ndarray) -> FrameImager:
        """The imager as it runs at the predicted image velocity: unchanged."""
        return self

    def focal_plane(self, focal_length_m: float, pixel_pitch_m: float) -> FocalPlane:
        return FocalPlane(focal_length_m, pixel_pitch_m, self.rows, self.cols,
                          self.center_offset_px)

    def integration_s(self, line_rate_hz: float | None = None) -> float:
        """The exposure, s."""
        return self.exposure_s

    def sampling(self, samples: int = 8, footprint: bool = True) -> FrameSampling:
        """The exposure's S instants and footprint offsets
        (:func:`camera.sampling.frame_sampling`)."""
        return frame_sampling(self, samples, footprint)

    def charge_motion_px(self, t_s: np.ndarray, line_rate_hz: float | None = None) -> np.ndarray:
        """A frame camera's charge does not move: zeros (..., 2)."""
        return np.zeros(np.shape(t_s) + (2,))


@dataclass(frozen=True)
class TdiImager:
    """A TDI pushbroom: ``cols`` detectors across track, ``stages`` rows integrated along it.

    ``line_rate_hz`` None means synchronous: set from the predicted image velocity at the
    imager's centre (:func:`synchronous_line_rate_hz`).
    """

    cols: int = 13500
    stages: int = 32
    line_rate_hz: float | None = None
    clock_phases: int = 0
    center_offset_px: tuple[float, float] = (0.0, 0.0)
    kind: Literal["tdi"] = "tdi"
    #: a TDI pushbroom scans: its lines integrate one after the other
    scanning: ClassVar[bool] = True
    #: (row, col) factors from the residual image motion to the line-of-sight offset on the
    #: nominal grid: a TDI line counts against the image flow along rows
    product_sign: ClassVar[tuple[float, float]] = (1.0, -1.0)

    @classmethod
    def from_config(cls, cfg: Any) -> TdiImager:
        """The imager of a scenario's ``camera.main_imager`` section (line rate None:
        synchronous, set by :meth:`with_line_rate`)."""
        return cls(stages=cfg.stages, line_rate_hz=cfg.line_rate_hz,
                   clock_phases=cfg.clock_phases, center_offset_px=tuple(cfg.center_offset_px))

    def with_line_rate(self, velocity_px_s: np.ndarray) -> TdiImager:
        """The imager with its line rate set: its own, else synchronous with the predicted
        image velocity (row, col) px/s at its centre (:func:`synchronous_line_rate_hz`)."""
        if self.line_rate_hz is not None:
            return self
        return replace(self, line_rate_hz=synchronous_line_rate_hz(velocity_px_s))

    @property
    def charge_velocity_px_s(self) -> tuple[float, float]:
        """The mean velocity (row, col) of the charge on the focal plane, px/s: the line rate
        along rows (a stepped clock's mean too)."""
        return (self._rate(None), 0.0)

    def sampling(self, samples: int = 8, footprint: bool = True) -> LineSampling:
        """A line's S instants and footprint offsets at the imager's line rate
        (:func:`camera.sampling.tdi_sampling`)."""
        return tdi_sampling(self, self._rate(None), samples, footprint)

    def _rate(self, line_rate_hz: float | None) -> float:
        rate = self.line_rate_hz if line_rate_hz is None else line_rate_hz
        if rate is None:
            raise ValueError("the TDI imager's line rate is not set: call with_line_rate")
        return float(rate)

    def __post_init__(self) -> None:
        if self.stages < 1 or self.cols < 1:
            raise ValueError("a TDI imager needs stages >= 1 and cols >= 1")
        if self.line_rate_hz is not None and self.line_rate_hz <= 0:
            raise ValueError("TDI line_rate_hz must be > 0 (or None for synchronous)")
        if self.clock_phases < 0:
            raise ValueError("TDI clock_phases must be >= 0 (0: continuous charge transfer)")

    def focal_plane(self, focal_length_m: float, pixel_pitch_m: float) -> FocalPlane:
        return FocalPlane(focal_length_m, pixel_pitch_m, self.stages, self.cols,
                          self.center_offset_px)

    def integration_s(self, line_rate_hz: float | None = None) -> float:
        """Time a charge packet spends crossing all stages at ``line_rate_hz`` (default the
        imager's own), s."""
        return self.stages / self._rate(line_rate_hz)

    def charge_motion_px(self, t_s: np.ndarray, line_rate_hz: float | None = None) -> np.ndarray:
        """Charge displacement (..., 2) = (rows, 0) after t_s seconds of clocking at
        ``line_rate_hz`` (default the imager's own), px."""
        rows = np.asarray(t_s, dtype=np.float64) * self._rate(line_rate_hz)
        if self.clock_phases:
            rows = np.floor(rows * self.clock_phases) / self.clock_phases
        return np.stack([rows, np.zeros_like(rows)], axis=-1)


MainImager = FrameImager | TdiImager

#: the imager kinds by the scenario's ``camera.main_imager.kind``
IMAGERS: dict[str, type[FrameImager] | type[TdiImager]] = {"frame": FrameImager,
                                                           "tdi": TdiImager}


def synchronous_line_rate_hz(velocity_px_s: np.ndarray) -> float:
    """Line rate matching an image velocity (row, col) px/s: its along-row component."""
    v = float(np.asarray(velocity_px_s)[..., 0])
    if v <= 0.0:
        raise ValueError(
            f"the image does not flow toward +row (row velocity {v:.3g} px/s): a TDI imager "
            "needs a scanning attitude (mode nadir or off_nadir)")
    return v


def tdi_linear_smear_px(velocity_row_px_s: float, line_rate_hz: float, stages: int) -> float:
    """Along-track smear (v / L - 1) N of a TDI line with a constant image velocity, px."""
    return (velocity_row_px_s / line_rate_hz - 1.0) * stages

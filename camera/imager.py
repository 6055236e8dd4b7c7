"""The main imager on the focal plane: a frame camera or a TDI pushbroom, and its smear.

A TDI (time delay and integration) imager clocks its charge packets one row per line period
along +row, the direction the ground flows (docs/conventions.md). A ground point's image moves
by m(t); its charge moves by q(t) = line_rate * t along rows (``clock_phases`` = 0: ideal,
continuous; p: in steps of 1/p px, as a p-phase CCD does). The residual m(t) - q(t) over the
N-stage integration is what blurs the line: with image velocity v (px/s) and line rate L the
linear smear is (v / L - 1) N px, zero when the line rate is synchronous.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from camera.geometry import FocalPlane


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

    def focal_plane(self, focal_length_m: float, pixel_pitch_m: float) -> FocalPlane:
        return FocalPlane(focal_length_m, pixel_pitch_m, self.rows, self.cols,
                          self.center_offset_px)

    def integration_s(self, line_rate_hz: float | None = None) -> float:
        return self.exposure_s

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

    def integration_s(self, line_rate_hz: float) -> float:
        """Time a charge packet spends crossing all stages, s."""
        return self.stages / line_rate_hz

    def charge_motion_px(self, t_s: np.ndarray, line_rate_hz: float) -> np.ndarray:
        """Charge displacement (..., 2) = (rows, 0) after t_s seconds of clocking, px."""
        rows = np.asarray(t_s, dtype=np.float64) * line_rate_hz
        if self.clock_phases:
            rows = np.floor(rows * self.clock_phases) / self.clock_phases
        return np.stack([rows, np.zeros_like(rows)], axis=-1)


MainImager = FrameImager | TdiImager


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

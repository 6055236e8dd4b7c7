"""Residual image-motion metrics: RMS, peak-to-peak, motion MTF at Nyquist.

For a trajectory r(t) (px) over an exposure, the motion MTF at spatial frequency f
(cycles/px) along unit axis u is |mean_t exp(-2 pi i f u . r(t))| (Wulich & Kopeika 1987;
Hadar et al. 1992). Nyquist is f = 0.5 cycles/px.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

NYQUIST = 0.5


def motion_mtf(r_px: np.ndarray, freq: float = NYQUIST, axis: int = 0) -> np.ndarray:
    """Motion MTF of trajectories r (..., T, 2) along pixel axis 0 (row) or 1 (col)."""
    phase = np.exp(-2j * np.pi * freq * np.asarray(r_px)[..., axis])
    return np.abs(phase.mean(axis=-1))


@dataclass(frozen=True)
class ResidualMetrics:
    """Statistics of one residual image-motion time series (px)."""

    rms_px: tuple[float, float]
    rms_total_px: float
    peak_to_peak_px: tuple[float, float]
    mtf_nyquist: tuple[float, float]
    mtf_nyquist_worst: tuple[float, float]
    window_s: float

    def to_dict(self) -> dict:
        return asdict(self)


def residual_metrics(t_s: np.ndarray, r_px: np.ndarray, window_s: float) -> ResidualMetrics:
    """Metrics of residual motion r (T, 2) sampled at t_s (T,) uniformly.

    RMS and peak-to-peak are over the whole series (relative to zero: the reference
    position). The MTF is evaluated over consecutive windows of ``window_s`` (the main
    imager's exposure): mean and worst (minimum) over windows, per axis.
    """
    t = np.asarray(t_s, dtype=np.float64)
    r = np.asarray(r_px, dtype=np.float64)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else window_s
    per = max(1, int(round(window_s / dt)))
    n_win = max(1, len(t) // per)
    win = r[: n_win * per].reshape(n_win, per, 2)
    mtf = np.stack([motion_mtf(win, axis=0), motion_mtf(win, axis=1)], axis=-1)
    rms = np.sqrt(np.mean(r**2, axis=0))
    return ResidualMetrics(
        rms_px=(float(rms[0]), float(rms[1])),
        rms_total_px=float(np.sqrt(np.mean(np.sum(r**2, axis=1)))),
        peak_to_peak_px=tuple(float(v) for v in np.ptp(r, axis=0)),
        mtf_nyquist=tuple(float(v) for v in mtf.mean(axis=0)),
        mtf_nyquist_worst=tuple(float(v) for v in mtf.min(axis=0)),
        window_s=float(per * dt),
    )


def json_dict(figures) -> dict:
    """A dataclass of figures as a dict for strict JSON: non-finite floats become None."""
    return {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
            for k, v in asdict(figures).items()}

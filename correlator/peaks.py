"""Peak detection on correlation surfaces: 3-point sub-pixel fits and peak-to-sidelobe ratio."""

from __future__ import annotations

import numpy as np


def peak_fit(nb: np.ndarray, kind: str) -> np.ndarray:
    """Sub-pixel offset (N, 2) of the peak from its 3x3 neighbourhood (N, 3, 3)."""
    if kind == "com":
        v = np.maximum(nb - nb.min(axis=(1, 2), keepdims=True), 0.0)
        tot = v.sum(axis=(1, 2)) + 1e-30
        off = np.arange(-1, 2, dtype=np.float64)
        return np.column_stack([(v.sum(axis=2) * off).sum(1) / tot,
                                (v.sum(axis=1) * off).sum(1) / tot])
    row = nb[:, :, 1]
    col = nb[:, 1, :]
    if kind == "gaussian":
        floor = np.minimum(row.min(1), col.min(1))[:, None]
        eps = 1e-6 * (nb[:, 1, 1] - floor[:, 0])[:, None] + 1e-30
        row = np.log(row - floor + eps)
        col = np.log(col - floor + eps)

    def fit(v):
        den = v[:, 0] - 2.0 * v[:, 1] + v[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            d = 0.5 * (v[:, 0] - v[:, 2]) / den
        return np.clip(np.where(np.isfinite(d) & (den < 0), d, 0.0), -0.5, 0.5)

    return np.column_stack([fit(row), fit(col)])



def neighbourhood(surf: np.ndarray, iy: np.ndarray, ix: np.ndarray, r: int = 1) -> np.ndarray:
    """(N, 2r+1, 2r+1) values of surfaces (N, h, w) around (iy, ix), wrapped at the edges."""
    n, h, w = surf.shape
    off = np.arange(-r, r + 1)
    rows = (iy[:, None] + off[None, :]) % h
    cols = (ix[:, None] + off[None, :]) % w
    return surf[np.arange(n)[:, None, None], rows[:, :, None], cols[:, None, :]]


def psr(surf: np.ndarray, iy: np.ndarray, ix: np.ndarray, exclude: int = 2) -> np.ndarray:
    """Peak-to-sidelobe ratio (N,) of surfaces (N, h, w) at (iy, ix).

    Peak: the surface at (iy, ix); sidelobes: every other sample outside a box of +-exclude
    px around it (wrapped); PSR = (peak - mean) / std of the sidelobes.
    """
    n, h, w = surf.shape
    box = neighbourhood(surf, iy, ix, exclude).astype(np.float64)
    s = surf.astype(np.float64)
    cnt = h * w - box.shape[1] * box.shape[2]
    mean = (s.sum(axis=(1, 2)) - box.sum(axis=(1, 2))) / cnt
    sq = ((s * s).sum(axis=(1, 2)) - (box * box).sum(axis=(1, 2))) / cnt
    std = np.sqrt(np.maximum(sq - mean * mean, 1e-300))
    return (box[:, exclude, exclude] - mean) / std

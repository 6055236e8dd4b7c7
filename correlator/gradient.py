"""Spatial refinement: symmetric Lucas-Kanade on cubic B-spline resampled blocks.

Both blocks are resampled by +-d/2 so the estimate is symmetric in ref and cur; iterating
removes the pixel-locking bias of peak fits. Slower than the Fourier refinement
(:mod:`correlator.spectral`) but uses every pixel of the overlap with no window.

Reference: Lucas & Kanade, "An iterative image registration technique", IJCAI (1981).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def _bspline_weights(t: np.ndarray) -> list[np.ndarray]:
    """Cubic B-spline weights for taps -1, 0, 1, 2 at fraction t (coefficients prefiltered)."""
    t2, t3 = t * t, t * t * t
    return [
        (1.0 - t) ** 3 / 6.0,
        (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
        (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
        t3 / 6.0,
    ]


def _sample(coef: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Cubic-spline samples (N, H, W) at (y + off_y, x + off_x) for every pixel (y, x).

    ``coef`` (N, H, W) are B-spline coefficients (:func:`_spline_coefficients`), extended by
    edge values outside the block; ``off`` (N, 2) a constant offset per block. One window
    gather per block for the integer part, then the 4-tap filters by slicing.
    """
    n, h, w = coef.shape
    base = np.floor(off).astype(np.int64)
    fr = off - base
    pad = int(np.abs(base).max()) + 2
    padded = np.pad(coef, ((0, 0), (pad, pad), (pad, pad)), mode="edge")
    views = np.lib.stride_tricks.sliding_window_view(padded, (h + 3, w + 3), axis=(1, 2))
    win = views[np.arange(n), pad - 1 + base[:, 0], pad - 1 + base[:, 1]]  # (N, H+3, W+3)
    tmp = sum(wy[:, None, None] * win[:, i : i + h, :]
              for i, wy in enumerate(_bspline_weights(fr[:, 0])))
    return sum(wx[:, None, None] * tmp[:, :, j : j + w]
               for j, wx in enumerate(_bspline_weights(fr[:, 1])))


def _spline_coefficients(blocks: np.ndarray) -> np.ndarray:
    """Cubic B-spline coefficients of each block (filtered along rows and columns only)."""
    c = ndimage.spline_filter1d(blocks, order=3, axis=1, mode="mirror", output=np.float64)
    return ndimage.spline_filter1d(c, order=3, axis=2, mode="mirror", output=np.float64)


def refine(ref: np.ndarray, cur: np.ndarray, shift: np.ndarray, iterations: int):
    """Symmetric Lucas-Kanade refinement; returns (shift, crlb, last step)."""
    n, h, w = ref.shape
    ref, cur = _spline_coefficients(ref), _spline_coefficients(cur)
    shift = shift.copy()
    step = np.zeros_like(shift)
    crlb = np.full_like(shift, np.inf)
    for it in range(iterations + 1):
        half = np.where(np.isfinite(shift), shift, 0.0) / 2.0
        cs = _sample(cur, half)
        rs = _sample(ref, -half)
        # per-block mask: both samples (and their gradient neighbours) inside the block
        ok = np.ones((n, h - 2, w - 2), bool)
        for sign in (1.0, -1.0):
            py = np.arange(1, h - 1)[None, :] + sign * half[:, 0:1]
            px = np.arange(1, w - 1)[None, :] + sign * half[:, 1:2]
            ok &= ((py >= 2) & (py <= h - 3))[:, :, None] & ((px >= 2) & (px <= w - 3))[:, None, :]
        wgt = ok.astype(np.float64)
        e = (cs - rs)[:, 1:-1, 1:-1] * wgt
        gy = 0.25 * ((cs[:, 2:, 1:-1] - cs[:, :-2, 1:-1]) + (rs[:, 2:, 1:-1] - rs[:, :-2, 1:-1]))
        gx = 0.25 * ((cs[:, 1:-1, 2:] - cs[:, 1:-1, :-2]) + (rs[:, 1:-1, 2:] - rs[:, 1:-1, :-2]))
        gy, gx = gy * wgt, gx * wgt
        a11 = (gy * gy).sum(axis=(1, 2))
        a12 = (gy * gx).sum(axis=(1, 2))
        a22 = (gx * gx).sum(axis=(1, 2))
        b1 = (gy * e).sum(axis=(1, 2))
        b2 = (gx * e).sum(axis=(1, 2))
        det = a11 * a22 - a12 * a12
        with np.errstate(divide="ignore", invalid="ignore"):
            s1 = (a22 * b1 - a12 * b2) / det
            s2 = (a11 * b2 - a12 * b1) / det
            if it == iterations:
                npix = np.maximum(wgt.sum(axis=(1, 2)), 1.0)
                var_e = (e**2).sum(axis=(1, 2)) / npix
                # remove the noise contribution to the gradient energy (central differences
                # of two averaged images: sigma^2/4 per pixel = var_e/8)
                corr = npix * var_e / 8.0
                t11 = np.maximum(a11 - corr, 0.1 * a11)
                t22 = np.maximum(a22 - corr, 0.1 * a22)
                tdet = t11 * t22 - a12 * a12
                tdet = np.where(tdet > 0, tdet, np.nan)
                crlb = np.sqrt(np.column_stack([var_e * t22 / tdet, var_e * t11 / tdet]))
                crlb = np.where(np.isfinite(crlb), crlb, np.inf)
                break
        step = np.column_stack([s1, s2])
        step = np.where(np.isfinite(step), np.clip(step, -1.0, 1.0), 0.0)
        shift = shift - step
    return shift, crlb, step

"""The main imager's blur from the truth alone: the residual-motion PSF and MTF of every
exposure (integration window), open and closed loop, written to blur.npz.

The PSF of a residual trajectory r(t) over one exposure is the time it spends at each
position (:func:`ground.restore.residual_psf`'s time-weighted histogram); its MTF is
|mean_t exp(-2 pi i f . r(t))| (Wulich & Kopeika 1987). The rendered picture of the worst
exposure (main_imager.png) is the product's: :func:`imc.wiring.product.picture_study`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from compensation.loop import Trajectory
from compensation.metrics import NYQUIST
from ground.restore import residual_psf
from imc.io import write_npz
from imc.wiring.truth import Truth

#: PSF grid: bin size (px; coarser when the residual is large), half-width (px) at least,
#: and the most bins a side (a diverging loop's residual of tens of px stays a small image)
PSF_BIN_PX = 0.02
PSF_MIN_HALF_PX = 0.5
PSF_MAX_BINS = 201
#: frequencies of the 2-D MTF, cycles/px (0 .. 1, Nyquist at the middle)
MTF_FREQS = np.linspace(-1.0, 1.0, 41)


def psf_image(r_px: np.ndarray, half_px: float, bin_px: float = PSF_BIN_PX) -> np.ndarray:
    """Time-weighted histogram (G, G), G = 2 ceil(half_px / bin_px) + 1, of a residual
    trajectory r (N, 2) (row, col) px on a grid of ``bin_px`` centred on its mean, ``half_px``
    each side (:func:`ground.restore.residual_psf`, padded to the common grid); sums to 1."""
    n = int(np.ceil(half_px / bin_px))
    fine = residual_psf(np.asarray(r_px, dtype=np.float64), bin_px=bin_px).fine
    k = fine.shape[0] // 2
    if k > n:  # samples beyond the grid: clipped (half_px covers them as window_blur calls)
        fine = fine[k - n:k + n + 1, k - n:k + n + 1]
    else:
        fine = np.pad(fine, n - k)
    return fine / max(fine.sum(), 1e-300)


def mtf_image(r_px: np.ndarray, freqs: np.ndarray = MTF_FREQS) -> np.ndarray:
    """Motion MTF (F, F) of a trajectory r (N, 2) on a grid of (f_row, f_col), cycles/px."""
    r = np.asarray(r_px)
    ph_r = np.exp(-2j * np.pi * freqs[:, None] * r[None, :, 0])  # (F, N)
    ph_c = np.exp(-2j * np.pi * freqs[:, None] * r[None, :, 1])
    return np.abs(ph_r @ ph_c.T) / len(r)


def window_blur(truth: Truth, trajectory: Trajectory | None) -> dict[str, np.ndarray]:
    """PSF and MTF images of every main-imager exposure (integration window)."""
    r = truth.residual_px(trajectory)
    wins = np.unique(truth.window)
    groups = [r[truth.window == w] for w in wins]
    span = max(PSF_MIN_HALF_PX, 1.05 * max(float(np.max(np.abs(g - g.mean(axis=0))))
                                           for g in groups))
    bin_px = max(PSF_BIN_PX, 2.0 * span / (PSF_MAX_BINS - 2))
    psf = np.stack([psf_image(g, span, bin_px) for g in groups])
    mtf = np.stack([mtf_image(g) for g in groups])
    return {"psf": psf, "mtf": mtf, "psf_bin_px": np.array(bin_px),
            "mtf_freqs": MTF_FREQS, "window_start_s": np.array(
                [truth.t_s[truth.window == w][0] for w in wins]) - 0.5 * (
                truth.t_s[1] - truth.t_s[0])}


def write_blur_npz(path: Path, truth: Truth, trajectory: Trajectory,
                   blurs: tuple[dict, dict] | None = None) -> dict:
    """blur.npz: open- and closed-loop PSF and MTF images per exposure (``blurs``: the two
    :func:`window_blur` results when the caller has them); returns the worst exposure's
    figures."""
    open_, closed = blurs or (window_blur(truth, None), window_blur(truth, trajectory))
    nyq = np.argmin(np.abs(MTF_FREQS - NYQUIST))
    zero = np.argmin(np.abs(MTF_FREQS))
    worst = int(np.argmin(open_["mtf"][:, nyq, zero]))
    write_npz(path, **{f"open_{k}": v for k, v in open_.items()},
              **{f"closed_{k}": v for k, v in closed.items() if k not in ("mtf_freqs",)})
    return {"worst_window": worst,
            "worst_window_start_s": float(open_["window_start_s"][worst]),
            "mtf_nyquist_row_open": float(open_["mtf"][worst, nyq, zero]),
            "mtf_nyquist_row_closed": float(closed["mtf"][worst, nyq, zero]),
            "mtf_nyquist_col_open": float(open_["mtf"][worst, zero, nyq]),
            "mtf_nyquist_col_closed": float(closed["mtf"][worst, zero, nyq])}

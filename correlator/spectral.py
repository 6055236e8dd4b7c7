"""Frequency-domain layout of the correlator: windows, frequency grids, the central band.

The correlator works on one-sided spectra (``rfft2``) of stacks of N blocks. The continuous
correlation at a lag d (px) is evaluated straight from the cross spectrum X = conj(R) C (or a
weighted Y = W X) as a trigonometric sum::

    c(d) = sum_k alpha_k Re(Y_k exp(i a_k . d)),     a_k = 2 pi (k_y / H, k_x / W) rad/px,

where alpha_k = 2 counts the conjugate half of the spectrum (1 on the k_x = 0 column; the
Nyquist row and column carry no usable shift information and get 0). c, its gradient and its
Hessian are sums over the spectrum, so Newton's method finds the peak to machine precision
with exact band-limited (sinc) interpolation: no pixel-locking. The weights are Knapp-Carter's
W_k = P_k / (2 P_k + s2) (P_k: the smoothed texture power, of the reference, then in the
common-content passes of both blocks; s2: the noise power per bin), and the predicted error
the sandwich H^-1 J H^-1; the compiled implementations are in
:mod:`correlator.kernels` (``newton``, ``ref_spectra``, ``crlb``).

References
----------
Knapp & Carter, "The generalized correlation method for estimation of time delay",
IEEE Trans. ASSP 24 (1976): SNR weighting of the cross spectrum.
Robinson & Milanfar, "Fundamental performance limits in image registration",
IEEE Trans. Image Process. 13 (2004): the bound 2 sigma^2 (sum g g^T)^-1 for two noisy images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def tukey_1d(n: int, taper_px: float, margin_px: float | np.ndarray = 0.0,
             shift_px: float | np.ndarray = 0.0) -> np.ndarray:
    """Tukey (flat-top, cosine-tapered) window over n pixels, (..., n) float32.

    The window is 0 within ``margin_px`` of both ends, rises over ``taper_px`` and is 1 inside;
    ``shift_px`` moves it by a (sub-pixel) amount. ``margin_px`` and ``shift_px`` broadcast
    (one value per block).
    """
    x = np.arange(n, dtype=np.float64) - np.asarray(shift_px, dtype=np.float64)[..., None]
    m = np.asarray(margin_px, dtype=np.float64)[..., None]
    dist = np.minimum(x + 0.5, n - 0.5 - x) - m
    t = np.clip(dist / max(float(taper_px), 1e-9), 0.0, 1.0)
    return (0.5 - 0.5 * np.cos(np.pi * t)).astype(np.float32)


@dataclass(frozen=True)
class Grid:
    """Frequency grid of an (h, w) block's one-sided spectrum.

    ay (h,), ax (k,): angular frequencies, rad/px; alpha (k,): half-spectrum weights with the
    Nyquist column zeroed; rows (h,): 0 on the Nyquist row, else 1.
    """

    h: int
    w: int
    ay: np.ndarray
    ax: np.ndarray
    alpha: np.ndarray
    rows: np.ndarray

    @classmethod
    def of(cls, h: int, w: int, rows_idx: np.ndarray | None = None,
           cols_n: int | None = None) -> Grid:
        """Grid of the full (h, w) spectrum, or of the sub-block ``[rows_idx, :cols_n]``."""
        import scipy.fft as sfft  # lazily: imc.scenario imports this module (via optical)

        ay = 2.0 * np.pi * sfft.fftfreq(h)
        ax = 2.0 * np.pi * sfft.rfftfreq(w)
        alpha = np.full(ax.shape, 2.0)
        alpha[0] = 1.0
        if w % 2 == 0:
            alpha[-1] = 0.0
        rows = np.ones(h)
        if h % 2 == 0:
            rows[h // 2] = 0.0
        if rows_idx is not None:
            ay, rows = ay[rows_idx], rows[rows_idx]
            ax, alpha = ax[:cols_n], alpha[:cols_n]
            if cols_n is not None and cols_n < w // 2 + 1:
                alpha = alpha.copy()
                alpha[-1] = 0.0  # the crop's own Nyquist column
            keep = np.abs(ay) < np.pi * (len(rows_idx) - 1) / h
            rows = rows * keep
        return cls(h, w, ay, ax, alpha, rows)


def low_band(h: int, w: int, q: int) -> tuple[np.ndarray, int]:
    """Row indices and column count of the central 1/q of an rfft2 spectrum (decimation by q)."""
    hq = h // (2 * q)
    rows = np.r_[0:hq, h - hq : h]
    return rows, w // (2 * q) + 1

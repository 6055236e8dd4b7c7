"""Frequency-domain pieces of the correlator: windows, cross spectra, Newton peak search, CRLB.

All functions work on stacks of N blocks and on one-sided spectra (``scipy.fft.rfft2``).

The continuous correlation at a lag d (px) is evaluated straight from the cross spectrum
X = conj(R) C (or a weighted Y = W X) as a trigonometric sum::

    c(d) = sum_k alpha_k Re(Y_k exp(i a_k . d)),     a_k = 2 pi (k_y / H, k_x / W) rad/px,

where alpha_k = 2 counts the conjugate half of the spectrum (1 on the k_x = 0 column; the
Nyquist row and column carry no usable shift information and get 0). c, its gradient and its
Hessian are three small matrix products per block (``newton_terms``), so Newton's method finds
the peak to machine precision with exact band-limited (sinc) interpolation: no pixel-locking.

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
import scipy.fft as sfft
from scipy.ndimage import uniform_filter1d


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


def newton_terms(y: np.ndarray, d: np.ndarray, g: Grid):
    """Correlation value (N,), gradient (N, 2) and Hessian (N, 2, 2) at lags d (N, 2) px.

    ``y`` (N, h, k) complex64 one-sided (weighted) cross spectra. The k-sum is one real matrix
    product per block on the interleaved (re, im) view of y, the h-sum a (3 x h) product.
    """
    n, h, k = y.shape
    ux = np.exp(1j * g.ax[None, :] * d[:, 1:2]) * g.alpha  # (N, k)
    v = np.stack([ux, ux * g.ax, ux * g.ax**2], axis=-1)  # (N, k, 3) complex
    m = np.empty((n, 2 * k, 6), np.float32)
    m[:, 0::2, :3] = v.real
    m[:, 0::2, 3:] = v.imag
    m[:, 1::2, :3] = -v.imag
    m[:, 1::2, 3:] = v.real
    pr = np.ascontiguousarray(y).view(np.float32) @ m  # (N, h, 6): Re, Im of Y @ v
    p = pr[..., :3].astype(np.float64) + 1j * pr[..., 3:]
    uy = np.exp(1j * g.ay[None, :] * d[:, 0:1]) * g.rows  # (N, h)
    u = np.stack([uy, uy * g.ay, uy * g.ay**2], axis=1)  # (N, 3, h)
    s = u @ p  # s[i, j] = sum a_y^i a_x^j Y u
    val = s[:, 0, 0].real
    grad = np.column_stack([-s[:, 1, 0].imag, -s[:, 0, 1].imag])
    hess = np.empty((n, 2, 2))
    hess[:, 0, 0] = -s[:, 2, 0].real
    hess[:, 1, 1] = -s[:, 0, 2].real
    hess[:, 0, 1] = hess[:, 1, 0] = -s[:, 1, 1].real
    return val, grad, hess


def newton_peak(y: np.ndarray, d0: np.ndarray, g: Grid, iterations: int, max_step_px: float):
    """Newton ascent of c(d) from d0 (>= 1 iteration).

    Returns (d, Hessian at the last evaluation, last step); the Hessian is taken one step
    before d, which changes it by O(step^2) once converged.
    """
    d = np.array(d0, dtype=np.float64)
    step = np.zeros_like(d)
    hess = np.zeros((len(d), 2, 2))
    for _ in range(max(1, iterations)):
        _, grad, hess = newton_terms(y, d, g)
        det = hess[:, 0, 0] * hess[:, 1, 1] - hess[:, 0, 1] ** 2
        concave = (det > 0) & (hess[:, 0, 0] < 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            sy = (hess[:, 1, 1] * grad[:, 0] - hess[:, 0, 1] * grad[:, 1]) / det
            sx = (hess[:, 0, 0] * grad[:, 1] - hess[:, 0, 1] * grad[:, 0]) / det
        newton = -np.column_stack([sy, sx])
        # off the concave cap (rare: a poor start) take a bounded gradient step instead
        scale = np.abs(np.trace(hess, axis1=1, axis2=2))[:, None] + 1e-30
        step = np.where(concave[:, None] & np.isfinite(newton), newton, grad / scale)
        step = np.clip(np.nan_to_num(step), -max_step_px, max_step_px)
        d = d + step
    return d, hess, step



def snr_weights(ref_power: np.ndarray, noise_k: np.ndarray, smooth: int = 11) -> np.ndarray:
    """Generalised-correlation (Knapp-Carter ML) weights W_k = P_k / (2 P_k + s2), (N, h, k).

    P_k, the texture power at k, is the reference's power spectrum |R_k|^2 smoothed over
    ``smooth`` x ``smooth`` bins less the noise power per bin s2 = ``noise_k`` (N,). W -> 1/2
    where texture dominates (flat weights: the high-SNR ML) and -> P/s2 where noise does, so
    noise-only frequencies cannot steer the peak. The weights depend on the reference alone
    (never on the cross spectrum's phases), so they cannot reinforce a noise peak, and a
    tracker computes them once.
    """
    p = uniform_filter1d(ref_power, smooth, axis=1, mode="wrap")
    p = uniform_filter1d(p, smooth, axis=2, mode="mirror")
    p = np.maximum(p - noise_k[:, None, None], 0.0)
    return (p / (2.0 * p + noise_k[:, None, None] + 1e-30)).astype(np.float32)


def gradient_power(w: np.ndarray, ref_power: np.ndarray, g: Grid) -> np.ndarray:
    """(N, 3, 3) sums alpha a_y^i a_x^j W^2 |R|^2 over the spectrum (for :func:`sandwich_crlb`)."""
    q = ref_power * (w * w) * g.rows[:, None].astype(np.float32)
    cols = q @ np.stack([g.alpha, g.alpha * g.ax, g.alpha * g.ax**2], axis=-1).astype(np.float32)
    rows = np.stack([np.ones_like(g.ay), g.ay, g.ay**2])  # (3, h)
    return rows[None] @ cols.astype(np.float64)


def sandwich_crlb(m: np.ndarray, noise_var: np.ndarray, hess: np.ndarray,
                  npix: int) -> np.ndarray:
    """Predicted 1-sigma error (N, 2) px of the (weighted) correlation peak.

    var(d) = H^-1 J H^-1, with H the Hessian of c at the peak and J the covariance of its
    gradient under white pixel noise of variance ``noise_var`` (N,) in both images:
    J = 2 sigma^2 npix sum_k alpha W^2 a a^T |R_k|^2 (one-sided ``ref_power`` = |R|^2 of the
    windowed reference, summed by :func:`gradient_power` into ``m``). For flat weights at
    high SNR this is the Cramer-Rao bound 2 sigma^2 (sum_x g g^T)^-1 of the windowed reference
    (Parseval).
    """
    jm = np.empty_like(hess)
    jm[:, 0, 0] = m[:, 2, 0]
    jm[:, 1, 1] = m[:, 0, 2]
    jm[:, 0, 1] = jm[:, 1, 0] = m[:, 1, 1]
    jm *= (2.0 * npix * noise_var)[:, None, None]
    hs = np.where(np.isfinite(hess), hess, 0.0)
    det = hs[:, 0, 0] * hs[:, 1, 1] - hs[:, 0, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        hinv = np.stack([np.stack([hs[:, 1, 1], -hs[:, 0, 1]], -1),
                         np.stack([-hs[:, 1, 0], hs[:, 0, 0]], -1)], 1) / det[:, None, None]
        cov = hinv @ jm @ hinv
    var = np.diagonal(cov, axis1=1, axis2=2)
    with np.errstate(invalid="ignore"):
        out = np.sqrt(np.where(var > 0, var, np.inf))
    return np.where(np.isfinite(out) & (det > 0)[:, None], out, np.inf)

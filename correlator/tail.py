"""The sub-pixel error's tail: the probability that a settled estimate is 0.5 px or more off.

The detection (:mod:`correlator.detection`) models one way a result is wrong: the chosen peak
is a noise peak. The other is the refinement's own error on the true peak. Linearised, the
estimate's error is e = g / H (g the noise's gradient of the correlation at the true lag, H the
peak's curvature), Gaussian with the predicted 1-sigma ``crlb``. But the correlation's pull
back towards its peak is not linear: at an offset delta along an axis it is

    F(delta) = sum_k alpha W Re(z_k) a sin(a delta)   (z the cross spectrum aligned on the
                                                       peak, a the bin's frequency, rad/px)

against the linear H delta = sum_k alpha W Re(z_k) a^2 delta. The estimate lands delta or
further off when the noise's gradient exceeds F(delta), so with the restoring ratio
rho = F(delta) / (H delta) (< 1, the more so the more of the peak's curvature high
frequencies carry)

    P(|e| >= delta) = 2 Q(rho delta / crlb),  Q(z) = erfc(z / sqrt 2) / 2,

per axis, where the linear model's tail is 2 Q(delta / crlb). A result's probability of
being wrong is then p_wrong = 1 - (1 - p_false)(1 - p_tail), p_tail = 1 - prod_axes
(1 - P(|e_axis| >= 0.5 px)); both terms come from the pair's own spectra and noise, nothing
is fitted.

References
----------
Kay, "Fundamentals of Statistical Signal Processing, Vol. I: Estimation Theory", Prentice
Hall (1993), ch. 7 (the MLE's threshold behaviour away from its linearised regime).
Knapp & Carter, "The generalized correlation method for estimation of time delay",
IEEE Trans. ASSP 24 (1976).
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: the error that makes a result wrong, px (an axis off by half a pixel or more)
WRONG_PX = 0.5


@nb.njit(nogil=True, cache=True, error_model="numpy",
         fastmath={"reassoc", "contract", "arcp", "nsz"})  # as correlator.kernels
def restoring_ratio(y, blk, rows_idx, ay, rows_w, ax, alpha, d, delta, out):  # pragma: no cover
    """out (n, 2): F(delta) / (H delta) per axis (row, col) of the correlation
    c(x) = sum alpha rows Re(y exp(i a.x)) of the (interleaved float32) spectra
    y[blk, rows_idx, :len(ax)] about its peak at d (n, 2) px: F(delta) = sum alpha rows
    a sin(a delta) Re(z), H = sum alpha rows a^2 Re(z), z = y exp(i a.d). NaN where H <= 0.
    ``ay``, ``ax`` (rad/px) lie on the FFT grid, as in :func:`correlator.kernels.newton`."""
    n = blk.shape[0]
    hb = rows_idx.shape[0]
    kb = ax.shape[0]
    w1 = np.empty(kb, np.float32)  # the column weights of F_x and H_x
    w2 = np.empty(kb, np.float32)
    for j in range(kb):
        w1[j] = ax[j] * np.sin(ax[j] * delta)
        w2[j] = ax[j] * ax[j]
    exr = np.empty(kb, np.float32)
    exi = np.empty(kb, np.float32)
    for b in range(n):
        for j in range(kb):
            exr[j] = alpha[j] * np.cos(ax[j] * d[b, 1])
            exi[j] = alpha[j] * np.sin(ax[j] * d[b, 1])
        fy = 0.0
        hy = 0.0
        fx = 0.0
        hx = 0.0
        for r in range(hb):
            if rows_w[r] == 0.0:
                continue
            yr = y[blk[b], rows_idx[r]]
            # Re(y ex ey) = Re(ey) Re(y ex) - Im(ey) Im(y ex): column sums first (float32)
            a0 = np.float32(0.0)
            b0 = np.float32(0.0)
            a1 = np.float32(0.0)
            b1 = np.float32(0.0)
            a2 = np.float32(0.0)
            b2 = np.float32(0.0)
            for j in range(kb):
                vr = yr[2 * j]
                vi = yr[2 * j + 1]
                pr = vr * exr[j] - vi * exi[j]
                pi = vr * exi[j] + vi * exr[j]
                a0 += pr
                b0 += pi
                a1 += pr * w1[j]
                b1 += pi * w1[j]
                a2 += pr * w2[j]
                b2 += pi * w2[j]
            c = np.cos(ay[r] * d[b, 0])
            s = np.sin(ay[r] * d[b, 0])
            t0 = c * a0 - s * b0
            a = ay[r]
            fy += rows_w[r] * a * np.sin(a * delta) * t0
            hy += rows_w[r] * a * a * t0
            fx += rows_w[r] * (c * a1 - s * b1)
            hx += rows_w[r] * (c * a2 - s * b2)
        out[b, 0] = fy / (hy * delta) if hy > 0.0 else np.nan
        out[b, 1] = fx / (hx * delta) if hx > 0.0 else np.nan


def tail_probability(crlb: np.ndarray, rho: np.ndarray, limit_px: float = WRONG_PX
                     ) -> np.ndarray:
    """P(an axis's error >= ``limit_px``) (n,) of estimates with predicted 1-sigma errors
    crlb (n, 2) px and restoring ratios rho (n, 2): 1 - prod (1 - 2 Q(rho limit / crlb));
    a ratio above 1 (noise in the high frequencies' Re(z)) counts as 1, the linear tail;
    1 where either is not finite or positive."""
    from scipy import special

    crlb = np.asarray(crlb, dtype=np.float64)
    rho = np.asarray(rho, dtype=np.float64)
    ok = np.isfinite(crlb) & (crlb > 0) & np.isfinite(rho) & (rho > 0)
    z = np.where(ok, np.minimum(rho, 1.0) * limit_px / np.where(ok, crlb, 1.0), 0.0)
    with np.errstate(divide="ignore"):  # log1p(-1) = -inf: certainly wrong
        return -np.expm1(np.sum(np.log1p(-2.0 * special.ndtr(-z)), axis=1))

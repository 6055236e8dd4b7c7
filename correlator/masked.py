"""Large-shift detection: overlap-normalised cross-correlation of binned, zero-padded blocks.

A circular correlation of two B x B blocks cannot tell a lag d from d - B, and at 40 % overlap
its peak competes with clutter from the content the two blocks do not share. The masked
normalised cross-correlation (Padfield 2012) instead gives, for every lag u, the Pearson
correlation coefficient of the two blocks over their overlap only:

    ncc(u) = [S12 - S1 S2 / n] / sqrt([S11 - S1^2 / n] [S22 - S2^2 / n])

with n(u) the overlap pixel count and S the sums of ref, cur, their squares and their product
over that overlap, all from zero-padded (linear, not circular) FFT correlations. The lag
search maximises Fisher's z = atanh(ncc), weighted by sqrt(overlap fraction) (the z of a
chance correlation shrinks as 1/sqrt(overlap)), over lags within the search range whose overlap
is at least ``min_overlap`` of the block. Blocks are averaged over q x q bins first: detection
needs only the integer lag to within a bin, and the bins lift the per-pixel SNR by q.

Reference: D. Padfield, "Masked object registration in the Fourier domain",
IEEE Trans. Image Process. 21 (2012) 2706-2718.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
from scipy import ndimage

#: correlation coefficients are clipped to +-this before Fisher's z
NCC_CLIP = 0.999
#: a rival peak is a local maximum more than this many bins from the best one
RIVAL_MIN_BINS = 3


def bin_blocks(blocks: np.ndarray, q: int) -> np.ndarray:
    """Mean over q x q bins of (N, h, w) blocks, float64 (N, h // q, w // q); edges cropped."""
    n, h, w = blocks.shape
    hq, wq = h // q, w // q
    b = np.asarray(blocks[:, : hq * q, : wq * q], dtype=np.float64)
    return b.reshape(n, hq, q, wq, q).mean(axis=(2, 4))


class MaskedDetector:
    """Integer lags of cur blocks against fixed reference blocks by masked NCC.

    Parameters
    ----------
    ref : (N, h, w) reference blocks (zero-mean float).
    max_shift_px : largest |lag| component searched, px.
    min_overlap : smallest overlap fraction of the block area searched, in (0, 1].
    q : bin size, px.
    """

    def __init__(self, ref: np.ndarray, max_shift_px: float, min_overlap: float, q: int):
        if not 0.0 < min_overlap <= 1.0:
            raise ValueError(f"min_overlap must be within (0, 1], got {min_overlap}")
        self.q = int(q)
        f1 = bin_blocks(ref, self.q)
        _, hb, wb = f1.shape
        self.lim = int(np.floor(max_shift_px / self.q + 0.5))
        ly = min(self.lim, hb - 1)
        lx = min(self.lim, wb - 1)
        # padded size: lags up to +-l need no wrap when P >= size + l + 1
        self.pad = (sfft.next_fast_len(hb + ly + 1, real=True),
                    sfft.next_fast_len(wb + lx + 1, real=True))
        p0, p1 = self.pad
        self.lag_y = np.where(np.arange(p0) <= ly, np.arange(p0), np.arange(p0) - p0)
        self.lag_x = np.where(np.arange(p1) <= lx, np.arange(p1), np.arange(p1) - p1)
        oy = np.clip(hb - np.abs(self.lag_y), 0, None).astype(np.float64)
        ox = np.clip(wb - np.abs(self.lag_x), 0, None).astype(np.float64)
        self.count = oy[:, None] * ox[None, :]  # overlap pixels n(u)
        frac = self.count / (hb * wb)
        self.search = ((np.abs(self.lag_y) <= ly)[:, None] & (np.abs(self.lag_x) <= lx)[None, :]
                       & (frac >= min_overlap - 1e-12))
        self.weight = np.sqrt(frac)
        self._shape = (hb, wb)
        self._mask_spec = sfft.rfft2(np.ones((hb, wb)), s=self.pad)
        f1c = np.conj(sfft.rfft2(f1, s=self.pad, workers=-1))
        self._f1c = f1c
        # ref-only sums over each overlap: S1(u), S11(u)
        m = self._mask_spec
        self._s1 = sfft.irfft2(f1c * m, s=self.pad, workers=-1)
        self._s11 = sfft.irfft2(np.conj(sfft.rfft2(f1 * f1, s=self.pad, workers=-1)) * m,
                                s=self.pad, workers=-1)

    def ncc(self, cur: np.ndarray, sel: slice | np.ndarray) -> np.ndarray:
        """Masked NCC surfaces (N, P0, P1) of cur blocks (N, h, w) vs references ``sel``."""
        f2 = bin_blocks(cur, self.q)
        s = self.pad
        mc = np.conj(self._mask_spec)
        f2s = sfft.rfft2(f2, s=s, workers=1)
        s12 = sfft.irfft2(self._f1c[sel] * f2s, s=s, workers=1)
        s2 = sfft.irfft2(mc * f2s, s=s, workers=1)
        s22 = sfft.irfft2(mc * sfft.rfft2(f2 * f2, s=s, workers=1), s=s, workers=1)
        n = np.maximum(self.count, 1.0)
        s1 = self._s1[sel]
        num = s12 - s1 * s2 / n
        var1 = np.maximum(self._s11[sel] - s1 * s1 / n, 0.0)
        var2 = np.maximum(s22 - s2 * s2 / n, 0.0)
        den = np.sqrt(var1 * var2)
        # overlaps without texture (variance at rounding level) get 0
        tiny = 1e-12 * den.reshape(len(den), -1).max(axis=1)[:, None, None] + 1e-300
        return np.divide(num, den, out=np.zeros_like(num), where=den > tiny)

    def detect(self, cur: np.ndarray, sel: slice | np.ndarray):
        """Lags (N, 2) px (a multiple of q, plus a parabolic sub-bin step), peak NCC (N,) and
        rival ratio (N,): the best other local maximum of the score (more than
        ``RIVAL_MIN_BINS`` bins away) over the best. A ratio near 1 means an ambiguous match: a
        single straight edge (the lag along it is unconstrained) or a repeated pattern."""
        r = self.ncc(cur, sel)
        n, p0, p1 = r.shape
        z = np.arctanh(np.clip(r, -NCC_CLIP, NCC_CLIP)) * self.weight
        zs = np.where(self.search[None], z, -np.inf)
        k = zs.reshape(n, -1).argmax(axis=1)
        iy, ix = np.unravel_index(k, (p0, p1))
        rows = np.arange(n)
        peak_max = zs == ndimage.maximum_filter(zs, size=(1, 3, 3), mode="wrap")
        dy = np.abs((np.arange(p0)[None, :] - iy[:, None] + p0 // 2) % p0 - p0 // 2)
        dx = np.abs((np.arange(p1)[None, :] - ix[:, None] + p1 // 2) % p1 - p1 // 2)
        away = (dy[:, :, None] > RIVAL_MIN_BINS) | (dx[:, None, :] > RIVAL_MIN_BINS)
        best = zs[rows, iy, ix]
        rival = np.where(peak_max & away & np.isfinite(zs), zs, -np.inf).reshape(n, -1).max(1)
        ratio = np.where(best > 0, np.maximum(rival, 0.0) / np.where(best > 0, best, 1.0), 1.0)
        # sub-bin step: a 3-point parabola on z along each axis (0 at the search's edge)
        zc = z[rows, iy, ix]
        step = []
        for lo, hi in ((z[rows, (iy - 1) % p0, ix], z[rows, (iy + 1) % p0, ix]),
                       (z[rows, iy, (ix - 1) % p1], z[rows, iy, (ix + 1) % p1])):
            den = lo - 2.0 * zc + hi
            step.append(np.where(den < 0.0, np.clip(0.5 * (lo - hi) / np.where(den < 0, den, -1.0),
                                                    -0.5, 0.5), 0.0))
        lag = np.column_stack([self.lag_y[iy] + step[0], self.lag_x[ix] + step[1]])
        return self.q * lag, r[rows, iy, ix], ratio

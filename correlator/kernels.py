"""Compiled (numba) kernels of the correlator's hot path, one pass over each block's data.

Each kernel loops over a stack of blocks and releases the GIL, so the correlator's threads run
them in parallel. They fuse what numpy would do in several passes with temporaries: the
window, mean and sanity statistics of a block (:func:`prep_blocks`); a reference's power,
noise, Knapp-Carter weights and gradient sums (:func:`ref_spectra`; under a second window
from the first's power, :func:`scaled_weights`); the cross spectrum with
the noise and floor sums (:func:`cross_spectra`); the SNR-whitened band (:func:`whiten_band`);
the peak, PSR and rival peak of a detection surface (:func:`detect`); Newton's method on
the spectrum (:func:`newton`); and the common-content passes' weights from both blocks'
power (:func:`box_power`, :func:`both_weights`). Formulas and references:
:mod:`correlator.spectral`, :mod:`correlator.core`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: no NaN/inf assumptions (non-finite input is detected), but sums may be reassociated
_JIT = {"nogil": True, "cache": True, "error_model": "numpy",
        "fastmath": {"reassoc", "contract", "arcp", "nsz"}}


@nb.njit(**_JIT)
def prep_blocks(blocks, blk, wy, wx, weighted, out, stats):
    """Windowed, demeaned float32 blocks and their sanity statistics.

    blocks (N, h, w) real, of which blocks ``blk`` (n,) are read; wy (1 or n, h),
    wx (1 or n, w) float32 separable window; ``weighted``: remove the window-weighted mean
    (else the plain mean). Writes out (n, h, w) float32 = (block - mean) * wy * wx (non-finite
    pixels count as 0) and stats (n, 4) float64: plain mean, plain std, non-finite pixel count,
    saturated (1.0 when more than half the pixels sit at the block's maximum); a stats of
    no rows (0, 4): none (the maximum and the spread are not computed, ``out`` is the same).
    """
    h, w = blocks.shape[1], blocks.shape[2]
    npix = h * w
    want = stats.shape[0] > 0
    for q in range(blk.shape[0]):
        b = blk[q]
        jy = q if wy.shape[0] > 1 else 0
        jx = q if wx.shape[0] > 1 else 0
        sw = 0.0
        for j in range(w):
            sw += wx[jx, j]
        sw_tot = 0.0
        for i in range(h):
            sw_tot += wy[jy, i]
        sw_tot *= sw
        s = 0.0
        swx = 0.0
        top = -np.inf
        for i in range(h):  # float32 row sums (vectorised), accumulated in float64
            rs = np.float32(0.0)
            rw = np.float32(0.0)
            for j in range(w):
                v = np.float32(blocks[b, i, j])
                rs += v
                rw += v * wx[jx, j]
            s += rs
            swx += wy[jy, i] * rw
            if want:
                rt = np.float32(-np.inf)
                for j in range(w):
                    rt = max(rt, np.float32(blocks[b, i, j]))
                top = max(top, np.float64(rt))
        bad = 0
        # rare: count and zero the non-finite pixels
        if not np.isfinite(s + swx + (top if want else 0.0)):
            s = 0.0
            swx = 0.0
            top = -np.inf
            for i in range(h):
                for j in range(w):
                    v = np.float64(blocks[b, i, j])
                    if not np.isfinite(v):
                        bad += 1
                        v = 0.0
                    s += v
                    swx += wy[jy, i] * v * wx[jx, j]
                    top = max(top, v)
        mean = s / npix
        mw = swx / sw_tot if weighted and sw_tot > 0 else mean
        m32 = np.float32(mw)
        if not want:  # the windowed block alone
            for i in range(h):
                for j in range(w):
                    v = np.float32(blocks[b, i, j])
                    if bad and not np.isfinite(v):
                        v = np.float32(0.0)
                    out[q, i, j] = (v - m32) * wy[jy, i] * wx[jx, j]
            continue
        t32 = np.float32(top)
        at_top = 0
        ss = 0.0
        for i in range(h):
            rss = np.float32(0.0)
            for j in range(w):
                v = np.float32(blocks[b, i, j])
                if bad and not np.isfinite(v):
                    v = np.float32(0.0)
                at_top += v >= t32
                c = v - m32
                rss += c * c
                out[q, i, j] = c * wy[jy, i] * wx[jx, j]
            ss += rss
        stats[q, 0] = mean
        # sum (v - mw)^2 / n less (mean - mw)^2: no cancellation of the level
        stats[q, 1] = np.sqrt(max(ss / npix - (mean - mw) ** 2, 0.0))
        stats[q, 2] = bad
        stats[q, 3] = 1.0 if at_top > npix // 2 else 0.0


@nb.njit(**_JIT)
def _add_row_moments(m, b, row_w, ay_i, c0, c1, c2):
    """Add one spectrum row's column moments (c0, c1, c2: sums of q, q ax, q ax^2) to block
    b's moment matrix m[b] (the CRLB's sums), weighted by the row's weight and its ay."""
    y1 = row_w * ay_i
    y2 = y1 * ay_i
    m[b, 0, 0] += row_w * c0
    m[b, 0, 1] += row_w * c1
    m[b, 0, 2] += row_w * c2
    m[b, 1, 0] += y1 * c0
    m[b, 1, 1] += y1 * c1
    m[b, 2, 0] += y2 * c0


@nb.njit(**_JIT)
def _column_prefix_sums(p, mirror, i0, nr, cs):
    """cs[q + 1, o] = p[i0 + o, mirror[0]] + ... + p[i0 + o, mirror[q]] for the nr (<= 4)
    rows from i0 (cs[0] = 0): prefix sums over the mirrored columns, the rows as four
    independent addition chains; box sums are differences of them."""
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    a3 = 0.0
    cs[0, 0] = 0.0
    cs[0, 1] = 0.0
    cs[0, 2] = 0.0
    cs[0, 3] = 0.0
    for q in range(mirror.shape[0]):
        jj = mirror[q]
        a0 += p[i0, jj]
        if nr > 1:
            a1 += p[i0 + 1, jj]
        if nr > 2:
            a2 += p[i0 + 2, jj]
        if nr > 3:
            a3 += p[i0 + 3, jj]
        cs[q + 1, 0] = a0
        cs[q + 1, 1] = a1
        cs[q + 1, 2] = a2
        cs[q + 1, 3] = a3


@nb.njit(**_JIT)
def ref_spectra(spec, imm, imm_norm, energy, box, box_det, flat, alpha, ay, ax, rows,
                outer_from, band_rows, wconj, fw, bw, m, noise, pbox):
    """Per reference block: noise variance, Knapp-Carter weights W, W conj(R), gradient sums.

    spec (n, h, k) complex64 one-sided spectra of windowed blocks; imm (h, k) Immerkaer
    weights (sum ``imm_norm``); energy (n,) each window's sum of squares. W = P / (2 P + s2),
    P: the mean of |R|^2 over ``box`` x ``box`` bins (odd; wrapped over rows, mirrored over
    columns) less the noise power s2 per bin; ``flat``: W = 1/2. The detection's weights are
    the same over the smaller ``box_det`` (selective, where the estimate wants low noise),
    kept as their ratio to W (0 where W = 0): fw (n, h, k) float32 that ratio at the outer
    frequencies (from column outer_from[i] of row i; 0 elsewhere), bw (n, len(band_rows),
    band columns) float32 that ratio on the central band. Writes wconj = W conj(R),
    m (n, 3, 3) float64 (the sums alpha rows a_y^i a_x^j W^2 (|R|^2 - s2 / 2), i + j <= 2: see
    :func:`crlb`), noise (n,) pixel variance and, where pbox (float32) has n blocks (not 1),
    the box mean of |R|^2 pbox (n, h, k) (for :func:`both_weights`). fw and bw of no blocks
    (0, ...): the detection's weights are not made (a pass's reference that no detection
    reads; the other outputs are the same). The complex arrays (n, h, k) are passed as their
    interleaved float32 views (n, h, 2k).
    """
    n, h, k2 = spec.shape
    k = k2 // 2
    r = box // 2
    det = fw.shape[0] == n and n > 0
    p = np.empty((h, k), np.float32)
    cs = np.empty((k + 2 * r + 1, 4), np.float64)  # prefix sums of mirror-padded rows
    mirror = np.empty(k + 2 * r, np.int64)
    for q in range(k + 2 * r):
        jj = q - r
        mirror[q] = -jj if jj < 0 else (2 * (k - 1) - jj if jj >= k else jj)
    rd = box_det // 2
    kb = bw.shape[2]
    band_of = np.full(h, -1, np.int64)  # row of the band array holding spectrum row i
    for q in range(band_rows.shape[0]):
        band_of[band_rows[q]] = q
    ratio = np.empty(k, np.float32)
    tmp = np.empty((h, k), np.float64)  # box sums over columns
    tmd = np.empty((h, k), np.float64)  # the same, detection box
    t = np.empty(k, np.float64)  # running box sums over rows (float64: |R|^2 spans decades)
    td = np.empty(k, np.float64)
    wts = np.empty(k, np.float32)
    norm = 1.0 / (box * box)
    norm_d = 1.0 / (box_det * box_det)
    for b in range(n):
        acc = 0.0
        for i in range(h):
            ra = np.float32(0.0)
            sr = spec[b, i]
            for j in range(k):
                pv = sr[2 * j] * sr[2 * j] + sr[2 * j + 1] * sr[2 * j + 1]
                p[i, j] = pv
                ra += imm[i, j] * pv
            acc += ra
        nv = acc / (imm_norm * energy[b])
        noise[b] = nv
        s2 = np.float32(nv * energy[b])
        half_s2 = np.float32(0.5) * s2
        if not flat:
            # box sums over columns (mirrored: d c b | a b c d | c b a) from prefix sums,
            # four rows at a time (four independent addition chains) ...
            for i0 in range(0, h, 4):
                nr = min(4, h - i0)
                _column_prefix_sums(p, mirror, i0, nr, cs)
                for o in range(nr):
                    for j in range(k):
                        tmp[i0 + o, j] = cs[j + box, o] - cs[j, o]
                    if det:
                        for j in range(k):
                            tmd[i0 + o, j] = cs[j + r + rd + 1, o] - cs[j + r - rd, o]
            # ... then a running box over rows (wrapped)
            for j in range(k):
                t[j] = 0.0
                td[j] = 0.0
            for o in range(-r, r + 1):
                for j in range(k):
                    t[j] += tmp[o % h, j]
            if det:
                for o in range(-rd, rd + 1):
                    for j in range(k):
                        td[j] += tmd[o % h, j]
        for a in range(3):
            for c in range(3):
                m[b, a, c] = 0.0
        for i in range(h):
            if flat:
                for j in range(k):
                    wts[j] = 0.5
                    ratio[j] = 1.0
            else:
                if pbox.shape[0] == n:
                    for j in range(k):
                        pbox[b, i, j] = np.float32(t[j] * norm)
                for j in range(k):
                    ps = max(np.float32(t[j] * norm) - s2, np.float32(0.0))
                    wts[j] = ps / (np.float32(2.0) * ps + s2 + np.float32(1e-30))
                if det:
                    for j in range(k):
                        pd = max(np.float32(td[j] * norm_d) - s2, np.float32(0.0))
                        wd = pd / (np.float32(2.0) * pd + s2 + np.float32(1e-30))
                        ratio[j] = wd / wts[j] if wts[j] > 0 else np.float32(0.0)
                ia = (i + r + 1) % h
                ib = (i - r) % h
                for j in range(k):
                    t[j] += tmp[ia, j] - tmp[ib, j]
                if det:
                    ia = (i + rd + 1) % h
                    ib = (i - rd) % h
                    for j in range(k):
                        td[j] += tmd[ia, j] - tmd[ib, j]
            if det:
                for j in range(k):
                    fw[b, i, j] = ratio[j] if j >= outer_from[i] else np.float32(0.0)
                if band_of[i] >= 0:
                    for j in range(kb):
                        bw[b, band_of[i], j] = ratio[j]
            c0 = np.float32(0.0)
            c1 = np.float32(0.0)
            c2 = np.float32(0.0)
            sr = spec[b, i]
            wr = wconj[b, i]
            for j in range(k):
                wv = wts[j]
                wr[2 * j] = wv * sr[2 * j]
                wr[2 * j + 1] = -wv * sr[2 * j + 1]
                q = alpha[j] * wv * wv * (p[i, j] - half_s2)
                c0 += q
                c1 += q * ax[j]
                c2 += q * ax[j] * ax[j]
            if rows[i] != 0.0:
                _add_row_moments(m, b, rows[i], ay[i], c0, c1, c2)


@nb.njit(**_JIT)
def scaled_weights(spec, pbox, prow, scale, s2, alpha, ay, ax, rows, wconj, m):
    """A reference's Knapp-Carter weights under a second window from the box means of its
    power under the first: W = P / (2 P + s2) with P = max(scale pbox - s2, 0), pbox rows
    ``prow`` (n,) of (N, h, k) float32 (:func:`ref_spectra`'s box means), ``scale`` (n,) the
    ratio of the two windows' energies and s2 (n,) the noise power per bin under the second.
    Writes wconj = W conj(R) and the CRLB sums m (n, 3, 3) of :func:`ref_spectra` for the
    spectra ``spec`` (n, h, k) under the second window (complex arrays as their interleaved
    float32 views): the weights without a second box average over the spectrum."""
    n, h, k2 = spec.shape
    k = k2 // 2
    for b in range(n):
        sn2 = np.float32(s2[b])
        half_s2 = np.float32(0.5) * sn2
        sc = np.float32(scale[b])
        pb = pbox[prow[b]]
        for a in range(3):
            for c in range(3):
                m[b, a, c] = 0.0
        for i in range(h):
            sr = spec[b, i]
            wr = wconj[b, i]
            c0 = np.float32(0.0)
            c1 = np.float32(0.0)
            c2 = np.float32(0.0)
            for j in range(k):
                ps = max(sc * pb[i, j] - sn2, np.float32(0.0))
                wv = ps / (np.float32(2.0) * ps + sn2 + np.float32(1e-30))
                re = sr[2 * j]
                im = sr[2 * j + 1]
                wr[2 * j] = wv * re
                wr[2 * j + 1] = -wv * im
                q = alpha[j] * wv * wv * (re * re + im * im - half_s2)
                c0 += q
                c1 += q * ax[j]
                c2 += q * ax[j] * ax[j]
            if rows[i] != 0.0:
                _add_row_moments(m, b, rows[i], ay[i], c0, c1, c2)


@nb.njit(**_JIT)
def cross_spectra(spec, wconj, fw, ref_idx, imm, outer_n, y, noise_raw, floor):
    """Weighted cross spectra y = W conj(R) C of blocks ``spec`` against reference rows
    ``ref_idx`` (n,) of ``wconj``; noise_raw (n,) the Immerkaer sum of |C|^2 (divide by the
    norm and window energy); floor (n,) the mean of |fw y| (the detection's cross spectrum at
    the ``outer_n`` outer frequencies, fw: rows as ``wconj``, 0 elsewhere), at least 1e-6 of
    the RMS |y|; with noise_raw and floor of no blocks (0,), y alone (fw is not read). Complex
    arrays (n, h, k) are passed as their interleaved float32 views (n, h, 2k).
    """
    n, h, k2 = spec.shape
    k = k2 // 2
    if floor.shape[0] == 0:
        for b in range(n):
            rb = ref_idx[b]
            for i in range(h):
                c = spec[b, i]
                wc = wconj[rb, i]
                yr = y[b, i]
                for j in range(k):
                    cr = c[2 * j]
                    ci = c[2 * j + 1]
                    wr = wc[2 * j]
                    wi = wc[2 * j + 1]
                    yr[2 * j] = wr * cr - wi * ci
                    yr[2 * j + 1] = wr * ci + wi * cr
        return
    for b in range(n):
        rb = ref_idx[b]
        acc = 0.0
        fl = 0.0
        tot = 0.0
        for i in range(h):
            c = spec[b, i]
            wc = wconj[rb, i]
            f = fw[rb, i]
            yr = y[b, i]
            mi = imm[i]
            ra = np.float32(0.0)
            rt = np.float32(0.0)
            rf = np.float32(0.0)
            for j in range(k):
                cr = c[2 * j]
                ci = c[2 * j + 1]
                wr = wc[2 * j]
                wi = wc[2 * j + 1]
                ra += mi[j] * (cr * cr + ci * ci)
                vr = wr * cr - wi * ci
                vi = wr * ci + wi * cr
                yr[2 * j] = vr
                yr[2 * j + 1] = vi
                a2 = vr * vr + vi * vi
                rt += a2
                rf += f[j] * np.sqrt(a2)
            acc += ra
            tot += rt
            fl += rf
        noise_raw[b] = acc
        floor[b] = max(fl / outer_n, 1e-6 * np.sqrt(tot / (h * k)) + 1e-30)


@nb.njit(**_JIT)
def whiten_band(y, bw, ref_idx, band_rows, band_cols, floor, out):
    """out (n, len(band_rows), band_cols) = central band of x / (|x| + floor), x = bw y (bw:
    the band's detection weights, rows ``ref_idx``), on the interleaved (re, im) float32 views
    of y and out (so that the loop vectorises)."""
    n = y.shape[0]
    for b in range(n):
        f = np.float32(floor[b])
        for i in range(band_rows.shape[0]):
            src = y[b, band_rows[i]]
            ro = bw[ref_idx[b], i]
            dst = out[b, i]
            for j in range(band_cols):
                re = ro[j] * src[2 * j]
                im = ro[j] * src[2 * j + 1]
                g = np.float32(1.0) / (np.sqrt(re * re + im * im) + f)
                dst[2 * j] = re * g
                dst[2 * j + 1] = im * g


@nb.njit(**_JIT)
def detect(surf, rows_in, cols_in, exclude, rival_px, given, lag, psr, ratio):
    """Peak, PSR and rival ratio of detection surfaces (n, hs, ws) (lag 0 at [0, 0], wrapped).

    The search range is the samples of rows ``rows_in`` and columns ``cols_in``. The peak is
    the largest sample there, or the sample ``given`` (n, 2)
    where its first entry is >= 0; writes lag (n, 2), its signed lag in samples plus a
    3-point parabolic step (within +-0.5) on each axis; psr (n,) = (peak - mean) / std of the
    samples outside a box of +-``exclude`` around it (0 where not finite); ratio (n,) the PSR
    of the best other local maximum (3 x 3, wrapped) inside the range and more than
    ``rival_px`` samples from the peak over the peak's PSR (-inf if none; 1 where the PSR is
    not positive). A given peak is not searched for rivals (ratio -inf): it was not chosen
    from the surface.
    """
    n, hs, ws = surf.shape
    for b in range(n):
        if given[b, 0] >= 0:
            by = given[b, 0] % hs
            bx = given[b, 1] % ws
        else:
            best = -np.inf
            by = 0
            bx = 0
            for i in rows_in:
                for j in cols_in:
                    if surf[b, i, j] > best:
                        best = surf[b, i, j]
                        by = i
                        bx = j
        peak = np.float64(surf[b, by, bx])
        for ax_ in range(2):
            if ax_ == 0:
                lo = np.float64(surf[b, (by - 1) % hs, bx])
                hi = np.float64(surf[b, (by + 1) % hs, bx])
                base = by if by < (hs + 1) // 2 else by - hs
            else:
                lo = np.float64(surf[b, by, (bx - 1) % ws])
                hi = np.float64(surf[b, by, (bx + 1) % ws])
                base = bx if bx < (ws + 1) // 2 else bx - ws
            den = lo - 2.0 * peak + hi
            frac = 0.5 * (lo - hi) / den if den < 0.0 else 0.0
            lag[b, ax_] = base + (min(max(frac, -0.5), 0.5) if np.isfinite(frac) else 0.0)
        s = 0.0
        ss = 0.0
        for i in range(hs):
            rs = np.float32(0.0)
            rss = np.float32(0.0)
            for j in range(ws):
                v = surf[b, i, j]
                rs += v
                rss += v * v
            s += rs
            ss += rss
        cnt = 0
        for o in range(-exclude, exclude + 1):
            for p in range(-exclude, exclude + 1):
                v = np.float64(surf[b, (by + o) % hs, (bx + p) % ws])
                s -= v
                ss -= v * v
                cnt += 1
        cnt = hs * ws - cnt
        mean = s / cnt
        std = np.sqrt(max(ss / cnt - mean * mean, 1e-300))
        v_psr = (peak - mean) / std
        psr[b] = v_psr if np.isfinite(v_psr) else 0.0
        ratio[b] = -np.inf
        if given[b, 0] >= 0:
            continue
        top = -np.inf
        for i in rows_in:
            dy = abs((i - by + hs // 2) % hs - hs // 2)
            for j in cols_in:
                dx = abs((j - bx + ws // 2) % ws - ws // 2)
                if dy <= rival_px and dx <= rival_px:
                    continue
                v = surf[b, i, j]
                if v <= top:
                    continue
                is_max = True
                for o in range(-1, 2):
                    for p in range(-1, 2):
                        if (o or p) and surf[b, (i + o) % hs, (j + p) % ws] > v:
                            is_max = False
                if is_max:
                    top = v
        if not psr[b] > 0.0:
            ratio[b] = 1.0
        elif top > -np.inf:
            v_ratio = ((top - mean) / std) / psr[b]
            ratio[b] = v_ratio if np.isfinite(v_ratio) else 1.0


@nb.njit(**_JIT)
def crlb(m, noise, hess, npix, out):
    """Predicted 1-sigma error (n, 2) px of the (weighted) correlation peak.

    var(d) = H^-1 J H^-1, with H (n, 2, 2) the Hessian of c at the peak and J the covariance
    of its gradient under white pixel noise of variance ``noise`` (n,) in both images:
    per bin, the texture S meets the noise of the other image twice (2 N |S|^2) and the two
    noises meet once (N^2), so J = 2 sigma^2 npix sum_k alpha W^2 a a^T (|R_k|^2 - N_k / 2)
    (E|R|^2 = |S|^2 + N), from the sums m (n, 3, 3) of :func:`ref_spectra`. For flat weights
    at high SNR this is the Cramer-Rao bound 2 sigma^2 (sum_x g g^T)^-1 of the windowed
    reference (Parseval). inf where H is not negative definite or the variance is not
    positive.
    """
    for b in range(hess.shape[0]):
        s = 2.0 * npix * noise[b]
        j00 = s * m[b, 2, 0]
        j11 = s * m[b, 0, 2]
        j01 = s * m[b, 1, 1]
        h00 = hess[b, 0, 0] if np.isfinite(hess[b, 0, 0]) else 0.0
        h11 = hess[b, 1, 1] if np.isfinite(hess[b, 1, 1]) else 0.0
        h01 = hess[b, 0, 1] if np.isfinite(hess[b, 0, 1]) else 0.0
        det = h00 * h11 - h01 * h01
        out[b, 0] = np.inf
        out[b, 1] = np.inf
        if not det > 0.0:
            continue
        i00 = h11 / det
        i01 = -h01 / det
        i11 = h00 / det
        c00 = (i00 * j00 + i01 * j01) * i00 + (i00 * j01 + i01 * j11) * i01
        c11 = (i01 * j00 + i11 * j01) * i01 + (i01 * j01 + i11 * j11) * i11
        if c00 > 0.0 and np.isfinite(c00):
            out[b, 0] = np.sqrt(c00)
        if c11 > 0.0 and np.isfinite(c11):
            out[b, 1] = np.sqrt(c11)


@nb.njit(**_JIT)
def _phasors(base, kmax, out):
    """out[k] = base**k, k = 0..kmax (complex128, by recurrence)."""
    out[0] = 1.0
    for k in range(1, kmax + 1):
        out[k] = out[k - 1] * base


@nb.njit(**_JIT)
def newton(y, blk, rows_idx, ay, rows_w, ax, alpha, d, iterations, max_step, stop, val, hess,
           step):
    """Newton ascent of c(d) = sum alpha rows Re(y exp(i a.d)) on the sub-spectra
    y[blk, rows_idx, :len(ax)], from d (n, 2) px (updated in place), 1 to ``iterations``
    iterations: a block stops after a step below ``stop`` px on both axes (Newton converges
    quadratically: what is left after a step s is ~s^2 / the peak's width).

    y is passed as its interleaved float32 view (N, h, 2k). ``ay``, ``ax`` (rad/px) are
    whole multiples of 2 pi / h and 2 pi / w (the FFT grid), so the phasors exp(i a d) are
    powers of one. Writes val (n,), hess (n, 2, 2) (at the last
    evaluation, one step before d) and step (n, 2) (the last step). Off the concave cap a
    gradient step scaled by the trace is taken; steps are clipped to +-max_step px.
    """
    n = blk.shape[0]
    hb = rows_idx.shape[0]
    kb = ax.shape[0]
    h = y.shape[1]
    w = 2 * (y.shape[2] // 2 - 1)
    ky = np.empty(hb, np.int64)
    for r in range(hb):
        ky[r] = np.int64(np.rint(ay[r] * h / (2.0 * np.pi)))
    kymax = np.max(np.abs(ky))
    kx = np.empty(kb, np.int64)
    for j in range(kb):
        kx[j] = np.int64(np.rint(ax[j] * w / (2.0 * np.pi)))
    py = np.empty(kymax + 1, np.complex128)
    px = np.empty(np.max(kx) + 1, np.complex128)
    uxr = np.empty(kb, np.float32)
    uxi = np.empty(kb, np.float32)
    ax1 = ax.astype(np.float32)
    ax2 = (ax * ax).astype(np.float32)
    for b in range(n):
        for _ in range(max(1, iterations)):
            _phasors(np.exp(2j * np.pi * d[b, 1] / w), px.shape[0] - 1, px)
            _phasors(np.exp(2j * np.pi * d[b, 0] / h), kymax, py)
            for j in range(kb):
                uxr[j] = alpha[j] * px[kx[j]].real
                uxi[j] = alpha[j] * px[kx[j]].imag
            s00 = 0j
            s10 = 0j
            s20 = 0j
            s01 = 0j
            s11 = 0j
            s02 = 0j
            for r in range(hb):
                if rows_w[r] == 0.0:
                    continue
                yr = y[blk[b], rows_idx[r]]
                t0r = np.float32(0.0)
                t0i = np.float32(0.0)
                t1r = np.float32(0.0)
                t1i = np.float32(0.0)
                t2r = np.float32(0.0)
                t2i = np.float32(0.0)
                for j in range(kb):
                    vr = yr[2 * j]
                    vi = yr[2 * j + 1]
                    pr = vr * uxr[j] - vi * uxi[j]
                    pi = vr * uxi[j] + vi * uxr[j]
                    t0r += pr
                    t0i += pi
                    t1r += pr * ax1[j]
                    t1i += pi * ax1[j]
                    t2r += pr * ax2[j]
                    t2i += pi * ax2[j]
                a = ay[r]
                u = py[ky[r]] if ky[r] >= 0 else np.conj(py[-ky[r]])
                u = rows_w[r] * u
                t0 = u * complex(t0r, t0i)
                t1 = u * complex(t1r, t1i)
                s00 += t0
                s10 += a * t0
                s20 += a * a * t0
                s01 += t1
                s11 += a * t1
                s02 += u * complex(t2r, t2i)
            gy = -s10.imag
            gx = -s01.imag
            h00 = -s20.real
            h11 = -s02.real
            h01 = -s11.real
            val[b] = s00.real
            hess[b, 0, 0] = h00
            hess[b, 1, 1] = h11
            hess[b, 0, 1] = h01
            hess[b, 1, 0] = h01
            det = h00 * h11 - h01 * h01
            sy = 0.0
            sx = 0.0
            if det > 0.0 and h00 < 0.0:
                sy = -(h11 * gy - h01 * gx) / det
                sx = -(h00 * gx - h01 * gy) / det
            if not (det > 0.0 and h00 < 0.0) or not (np.isfinite(sy) and np.isfinite(sx)):
                sc = abs(h00 + h11) + 1e-30
                sy = gy / sc
                sx = gx / sc
            sy = 0.0 if not np.isfinite(sy) else min(max(sy, -max_step), max_step)
            sx = 0.0 if not np.isfinite(sx) else min(max(sx, -max_step), max_step)
            d[b, 0] += sy
            d[b, 1] += sx
            step[b, 0] = sy
            step[b, 1] = sx
            if abs(sy) < stop and abs(sx) < stop:
                break


@nb.njit(**_JIT)
def box_power(spec, blk, box, out):
    """out[q] (h, k) float32: the mean of |spec[blk[q]]|^2 over ``box`` x ``box`` bins (odd;
    wrapped over rows, mirrored over columns, as :func:`ref_spectra`'s weights), spec passed
    as its interleaved float32 view (n, h, 2k)."""
    h, k2 = spec.shape[1], spec.shape[2]
    k = k2 // 2
    r = box // 2
    pc = np.empty((h, k), np.float32)
    cs = np.empty((k + 2 * r + 1, 4), np.float64)
    mirror = np.empty(k + 2 * r, np.int64)
    for q in range(k + 2 * r):
        jj = q - r
        mirror[q] = -jj if jj < 0 else (2 * (k - 1) - jj if jj >= k else jj)
    tmp = np.empty((h, k), np.float64)
    t = np.empty(k, np.float64)
    norm = 1.0 / (box * box)
    for q0 in range(blk.shape[0]):
        sc = spec[blk[q0]]
        for i in range(h):
            for j in range(k):
                pc[i, j] = sc[i, 2 * j] * sc[i, 2 * j] + sc[i, 2 * j + 1] * sc[i, 2 * j + 1]
        for i0 in range(0, h, 4):  # box sums over columns from prefix sums, four rows at once
            nr = min(4, h - i0)
            _column_prefix_sums(pc, mirror, i0, nr, cs)
            for o in range(nr):
                for j in range(k):
                    tmp[i0 + o, j] = cs[j + box, o] - cs[j, o]
        for j in range(k):  # a running box over rows (wrapped)
            t[j] = 0.0
        for o in range(-r, r + 1):
            for j in range(k):
                t[j] += tmp[o % h, j]
        for i in range(h):
            for j in range(k):
                out[q0, i, j] = np.float32(t[j] * norm)
            ia = (i + r + 1) % h
            ib = (i - r) % h
            for j in range(k):
                t[j] += tmp[ia, j] - tmp[ib, j]


@nb.njit(**_JIT)
def both_weights(y, spec, pbox, prow, cbox, crow, cscale, s2r, s2, shrink, alpha, ay, ax,
                 rows, m):
    """Knapp-Carter weights from both images' power: y = W_R conj(R) C (n, h, k) becomes
    W conj(R) C in place, W = P / (2 P + s2) with P = max(shrink b - s2, 0), b the box mean
    of (|R|^2 + |C|^2) / 2 and s2 (n,) the noise power per bin (``shrink`` = 1 - k se / b:
    the power counted where it stands k standard errors se of the box mean above the noise).

    spec (n, h, k): the C spectra; pbox (N, h, k) float32: the box means of |R|^2
    (:func:`ref_spectra`, rows ``prow`` (n,)), whose weights W_R were made with the noise
    power s2r (n,); cbox (M, h, k) float32: box means of |C|^2 (:func:`box_power`, rows
    ``crow`` (n,), times ``cscale`` (n,): the ratio of the window energies where they were
    made from an earlier window of the block). Only bins with W_R > 0 are kept (y = 0
    elsewhere). Writes m (n, 3, 3), the CRLB sums of :func:`ref_spectra` for W with
    (|R|^2 + |C|^2) / 2 in place of |R|^2 (|R|^2 = |y|^2 / (W_R^2 |C|^2)). Complex arrays
    are passed as their interleaved float32 views.
    """
    n, h, k2 = spec.shape
    k = k2 // 2
    for b in range(n):
        sc = spec[b]
        sr2 = np.float32(s2r[b])
        sn2 = np.float32(s2[b])
        half = np.float32(0.5) * sn2
        cf = np.float32(0.5 * cscale[b])
        sk = np.float32(shrink)
        pr = pbox[prow[b]]
        pcb = cbox[crow[b]]
        for a in range(3):
            for c in range(3):
                m[b, a, c] = 0.0
        for i in range(h):
            yr = y[b, i]
            c0 = np.float32(0.0)
            c1 = np.float32(0.0)
            c2 = np.float32(0.0)
            for j in range(k):
                ps = max(pr[i, j] - sr2, np.float32(0.0))
                wr = ps / (np.float32(2.0) * ps + sr2 + np.float32(1e-30))
                pb = max(sk * (np.float32(0.5) * pr[i, j] + cf * pcb[i, j]) - sn2,
                         np.float32(0.0))
                wn = pb / (np.float32(2.0) * pb + sn2 + np.float32(1e-30))
                g = wn / wr if wr > 0 else np.float32(0.0)
                vr = yr[2 * j]
                vi = yr[2 * j + 1]
                pc = sc[i, 2 * j] * sc[i, 2 * j] + sc[i, 2 * j + 1] * sc[i, 2 * j + 1]
                den = wr * wr * pc
                rr = (vr * vr + vi * vi) / den if den > 0 else np.float32(0.0)
                yr[2 * j] = g * vr
                yr[2 * j + 1] = g * vi
                we = g * wr
                q = alpha[j] * we * we * (np.float32(0.5) * (rr + pc) - half)
                c0 += q
                c1 += q * ax[j]
                c2 += q * ax[j] * ax[j]
            if rows[i] != 0.0:
                _add_row_moments(m, b, rows[i], ay[i], c0, c1, c2)


@nb.njit(**_JIT)
def self_cross(wconj, spec, wrow, other, orow, s, y):
    """The weighted cross spectrum of a reference against itself under another window, less
    its noise x noise term: y = W conj(R) R' - s W, with W conj(R) ``wconj`` and R ``spec``
    (rows ``wrow`` (n,)) the reference's spectrum under one window (W = |W conj(R)| / |R|),
    R' rows ``orow`` (n,)
    of ``other`` its spectrum under the other window, and s (n,) the noise's expected product
    per bin (pixel variance times the sum of the two windows' product). Complex arrays
    (n, h, k) as their interleaved float32 views (n, h, 2k); y likewise."""
    n = wrow.shape[0]
    h, k2 = spec.shape[1], spec.shape[2]
    k = k2 // 2
    for b in range(n):
        sb = np.float32(s[b])
        for i in range(h):
            wc = wconj[wrow[b], i]
            r = spec[wrow[b], i]
            o = other[orow[b], i]
            yr = y[b, i]
            for j in range(k):
                wr = wc[2 * j]
                wi = wc[2 * j + 1]
                rr = r[2 * j]
                ri = r[2 * j + 1]
                a = rr * rr + ri * ri
                wv = np.sqrt((wr * wr + wi * wi) / a) if a > 0 else np.float32(0.0)
                orr = o[2 * j]
                oi = o[2 * j + 1]
                yr[2 * j] = wr * orr - wi * oi - sb * wv
                yr[2 * j + 1] = wr * oi + wi * orr

"""Batched 2-D shift measurement: JTC / cross-correlation / phase correlation + sub-pixel.

Sign convention (docs/conventions.md): ``shift = (d_row, d_col)`` is the displacement of
``cur``'s content relative to ``ref``: cur(x) ~ ref(x - d).

Pipeline for a stack of N block pairs (no Python loop over blocks; the per-block work runs in
compiled kernels, :mod:`correlator.kernels`, on threads over the stack; FFTs through
:mod:`correlator.fftbackend`, FFTW where installed):

1. windows: ref gets a flat-top (Tukey) window that is zero within a margin m of its edges,
   cur one tapered only at its edges. For |d| <= m every ref sample meets a cur sample under
   a flat window, so the correlation of the windowed pair is exactly the correlation of the
   scene: no window bias. Each block first loses its window-weighted mean. The reference's
   spectrum, noise level, weights and gradient sums are computed once (:class:`Correlator`).
2. one FFT of each cur block; cross spectrum X = conj(R) C (``jtc``: the joint transform
   correlator's cross term, through the joint input plane with ``joint_plane=True``).
3. detection: a decimated surface from the central band of the SNR-whitened spectrum
   X / (|X| + noise floor); its integer peak within the search range, its peak-to-sidelobe
   ratio (PSR), the normalised statistic on which the seed paper's threshold is applied, and
   the PSR of its best rival peak (an ambiguous match, a repeated or one-directional pattern,
   has a rival almost as high). Searches beyond a quarter block use the overlap-normalised
   correlation of the zero-padded blocks instead (:mod:`correlator.masked`: no alias at
   d - B, no clutter from unshared content), the PSR of the common content's surface, and the
   masked score's rival-peak test. With a trusted prediction (``trust_prediction_px``,
   ``Correlator.measure(predicted=...)``) Newton starts from the prediction instead; the
   search runs only for blocks whose result is not settled within that distance of it.
4. sub-pixel: ``fourier`` (default): Newton's method on the continuous correlation evaluated
   from the spectrum (exact band-limited interpolation), first on the central band, then on the
   full band with Knapp-Carter SNR weights: the first pass, ref's window moved to the shift on
   the same cur spectrum, less the bias its unlike windows give (measured on the reference
   against itself, :meth:`Correlator._window_reference`); its weights from the box means of the
   reference's power under the fixed window, scaled by the windows' energies. Blocks moved by
   more than m, those whose first pass needs them (:meth:`Correlator._needs_precise`; all with
   ``rewindow=True``) get passes with both windows on the common content: ref's zero within
   whole-pixel margins that hold the shift, cur's the same moved by the estimate (each block
   less its window mean). A block's pass reference is kept while its margins hold, so a tracker
   pays one cur FFT per pass. The passes' Knapp-Carter weights take the texture power from both
   blocks: the box mean of (|R|^2 + |C|^2) / 2 less the noise and one standard error of that
   mean (:data:`BOTH_POWER_SE`), whose estimation noise is half that of the reference's power
   alone (cur's box mean is made on the block's first pass). The weights are functions of the
   magnitudes only, so they do not pull the estimate towards the lag at which they were made.
   The passes repeat to their fixed point (Aitken-accelerated). ``gradient``: symmetric
   Lucas-Kanade on cubic B-splines. ``parabolic``, ``gaussian``, ``com`` (the paper's centre of
   mass): 3-point fits on the method's full surface.
5. ``crlb``: the predicted 1-sigma error H^-1 J H^-1 of this estimate from the pair's own
   spectra (after the passes, J from the same weights and (|R|^2 + |C|^2) / 2) and the noise
   level (estimated from the highest frequencies), equal to the Cramer-Rao bound
   2 sigma^2 (sum g g^T)^-1 for flat weights at high SNR.
6. validity: a detection decision: the probability that the result is 0.5 px or more off
   (``p_wrong``) at most ``false_valid_rate``. It is wrong when noise alone puts a peak as
   high as the chosen one in the searched area (``p_false``, :mod:`correlator.detection`,
   from the PSR and the number of searched cells of the whitened surface) or when the
   estimate on the true peak lands in its tail (:mod:`correlator.tail`, from the predicted
   error and the peak's restoring ratio). Besides: the PSR above a safeguard floor; no rival
   peak near the best, texture and finite input, a concave peak that is settled (last Newton
   step and last pass move small against the block's own predicted error) and, if asked, a
   predicted error below ``max_crlb_px``.

References
----------
Weaver & Goodman, "A technique for optically convolving two functions", Appl. Opt. 5 (1966).
Kuglin & Hines, "The phase correlation image alignment method", IEEE Cybernetics (1975).
Knapp & Carter, "The generalized correlation method for estimation of time delay",
IEEE Trans. ASSP 24 (1976).
Immerkaer, "Fast noise variance estimation", Comput. Vis. Image Underst. 64 (1996).
Janschek, Tchernykh, Dyblenko, "Performances of image motion tracking with optical correlation".
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from threadpoolctl import ThreadpoolController

from correlator import detection, fftbackend, gradient, jtc, kernels, peaks, spectral, tail
from correlator.masked import MaskedDetector
from correlator.optical import OpticalJtc
from correlator.options import (  # noqa: F401  (re-exported: the options belong with the core)
    DETECTIONS,
    METHODS,
    OPTICAL_MAX_CRLB_PX,
    OPTICAL_PSR_THRESHOLD,
    OPTICAL_SUBPIXEL,
    PSR_SAFEGUARD,
    SUBPIXEL,
    WEIGHTINGS,
    CorrelatorOptions,
)

#: common-content passes at most, and the change (px) below which a block stops repeating
COMMON_PASSES = 6
COMMON_PASS_TOL_PX = 0.002
#: a block whose last pass still moved it by more than this is not converged
COMMON_PASS_MAX_MOVE_PX = 0.02
#: the same two limits relative to the block's own predicted error (crlb): a block stops
#: repeating once a pass moves it by less than PASS_TOL_REL crlb, and it is settled when its
#: last Newton step and last pass moved it by at most SETTLED_REL crlb (an unsettled remainder
#: of 0.25 sigma adds at most 6 % to the error variance); the larger limit applies
PASS_TOL_REL = 0.05
SETTLED_REL = 0.25
#: last Newton step (px) of a settled block, at the least
NEWTON_TOL_PX = 0.01
#: Newton stops after a step below this (px): what is left is ~1e-6 px (quadratic convergence)
NEWTON_STOP_PX = 1e-3
#: the reference power is averaged over a box of 2 round(f B) + 1 bins (B: the block size)
#: for the Knapp-Carter weights: 31 bins at 128^2. The weights' efficiency at low SNR is set by
#: this average's noise: 11 bins gave 1.21x the CRLB on the medium texture at SNR 10 and
#: 1.6-1.9x the Knapp-Carter bound on low-contrast photographs, 31 bins 1.17x and 1.2-1.4x
#: (CRLB of central differences, 1.3x high; against the spectral CRLB: 1.55x and 1.48x).
#: The passes average both blocks' power over the same box (half the noise of the average;
#: issue 25: 1-3 % less RMS at SNR 1.6, 6 % on the medium texture at SNR 3, none at SNR 10;
#: over the reference-only weights, the weights from the smoothed noise-free power, the best
#: a smoothed estimate can do, gain 6-13 %, the per-bin oracle weights of
#: :func:`correlator.testimages.correlation_bound_px` 19-26 %)
SMOOTH_FRACTION = 0.12
#: the passes count the box mean b of both blocks' power as texture where it stands this many
#: standard errors above the noise: P = max(b (1 - k / (sqrt 2 box)) - s2, 0) (b averages
#: 2 box^2 bins of roughly exponential power: se = b / (sqrt 2 box)). Where the texture is
#: below the noise (beyond an optics cut-off, most of a weak block's spectrum) b - s2 is the
#: box mean's noise, and its positive part (0.4 se on average) gave those bins weights at the
#: highest frequencies. Measured on the same draws, k = 0 / 0.5 / 1 / 2: valid and within
#: 0.5 px 31 / 36 / 40 / 44 % on the weak texture at SNR 10 and 42 / 47 / 54 / 61 % on the
#: medium one at SNR 3 (RMS 1.36 / 1.32 / 1.28 / 1.24x the correlation bound), but on
#: low-contrast photographs (power at every frequency) 82.5 / 82.6 / 82.2 / 81.3 % and on
#: grass and gravel at SNR 1.6 1.266 / 1.260 / 1.260 / 1.271x: one standard error keeps the
#: photographs and takes most of the gain; none at SNR 10
BOTH_POWER_SE = 1.0
#: ... and for the detection's whitening over 11 bins: selective weights (a wide average lets
#: noise-dominated frequencies into the whitened surface and lowers the PSR of good matches)
DETECT_SMOOTH_BINS = 11
#: blocks per chunk of work (a 128^2 block's arrays take ~0.4 MB): one thread on 256 independent
#: pairs in calls of 64, one process, alternated 5 times (load 8.9): chunks of 8 / 16 / 32 / 64
#: took 844 / 742 / 691 / 623 us a pair (median): the per-call work outweighs the cache
CHUNK_BLOCKS = 64
#: the default path (``rewindow=None``) gives a block the common-content passes after its
#: first pass (:meth:`Correlator._needs_precise`) when that pass predicts an error above
#: ADAPT_MAX_CRLB_PX (px, either axis: weak or smooth texture; both images' weights raise
#: the valid fraction there) or below ADAPT_MIN_CRLB_PX (px, for 128^2 blocks, scaled as
#: 128 / block size: high SNR, where what is left of the first pass's window error, the
#: Fourier interpolation of cur near ref's support, would dominate: strong texture at SNR 100
#: 1.54x the CRLB against the passes' 1.15x; at 256^2 with 0.0025 px the strong texture at
#: SNR 10 keeps the first pass, 1.21x the bound against the passes' 1.18x, and SNR 30-100
#: takes the passes, 1.02-1.05x against the first pass's 1.17-2.05x), finds a PSR below
#: ADAPT_MIN_PSR, has not settled, removed a window bias (:meth:`Correlator._window_reference`)
#: of more than ADAPT_MAX_BIAS_SIGMA predicted sigma (its removal is good to ~5 % of it: on
#: the flight test's rendered blocks the first pass differed from the passes by 0.84 sigma
#: rms where the bias was 3-10 sigma, 1.2 at 10-30, 2.4 beyond 30), or has a broad peak: a
#: restoring ratio (:mod:`correlator.tail`) above ADAPT_MAX_RHO on an axis, i.e. the
#: texture's power at low frequencies (0.93 on the strong texture, 0.96 on the medium one
#: and on the quickstart's rendered 64^2 blocks, 0.96-0.98 on 1/f^3-1/f^3.5 texture). With
#: 0.97 the quickstart's blocks kept their first pass (0.74 sigma from the passes), but its
#: predicted error is the first pass's, 20 % above the passes' (0.0152 against 0.0126 px for
#: a measured 0.015), the loop weighed the measurements less and its residual went from
#: 0.0175 to 0.019 px (52x to 48x); the medium texture at SNR 10 would take the first pass
#: at 1.08x the passes' error
ADAPT_MAX_CRLB_PX = 0.05
ADAPT_MIN_PSR = 8.0
ADAPT_MIN_CRLB_PX = 0.005
ADAPT_MAX_BIAS_SIGMA = 10.0
ADAPT_MAX_RHO = 0.95
#: the default path sends a block to the passes before its first pass where its PSR is below
#: ADAPT_MIN_PSR or the restoring ratio of its full-band correlation on the fixed windows
#: (the detection's), at the band's estimate, is above ADAPT_MAX_RHO + EARLY_RHO_MARGIN
#: (:meth:`Correlator._surely_precise`): on 1,900 blocks of 9 texture sets (synthetic,
#: photographs at their own and at 12 % contrast, 1/f^2-1/f^3.5) 2 blocks above 0.955 would
#: have kept their first pass, and 36-100 % of the blocks that take the passes skip it
EARLY_RHO_MARGIN = 0.01
#: the first pass's reference window leaves this much (px) of cur's flat region beyond the
#: shift on either side, for the shift's own error
FIRST_SAFETY_PX = 0.25
#: Aitken extrapolation: smallest previous move (px) and the range of move ratios it trusts
AITKEN_MIN_PX = 0.005
AITKEN_RATIO = (0.2, 0.9)
#: band detection: a rival is a local maximum more than this many decimated samples from the
#: peak (the whitened peak is one to two samples wide)
BAND_RIVAL_SAMPLES = 2
#: band detection: a result is ambiguous when its best rival's PSR reaches this fraction of
#: its own (rivals of textured pairs stay below 0.5 of the peak; the repeats of a periodic
#: pattern and the ridge of a one-directional one reach 0.8-1.0)
BAND_MAX_RIVAL_RATIO = 0.7
@dataclass(frozen=True)
class ShiftResult:
    """Measured shifts of a stack of block pairs.

    Attributes
    ----------
    shift : (..., 2) float64, (d_row, d_col) px, cur(x) ~ ref(x - d).
    valid : (...) bool, the detection passed the threshold and sanity checks.
    peak : (...) float64, peak-to-sidelobe ratio of the SNR-whitened correlation surface.
    crlb : (..., 2) float64, predicted 1-sigma error of each component, px.
    p_false : (...) float64 or None, the probability that noise alone puts a peak of the
        detection surface as high as the chosen one (:mod:`correlator.detection`); NaN
        where the method has no such model (the optical correlator).
    p_wrong : (...) float64 or None, the probability that the result is 0.5 px or more off
        on an axis: a noise peak (``p_false``) or the true peak's estimate in its tail
        (:mod:`correlator.tail`); valid results have p_wrong <= ``false_valid_rate``. NaN
        for the optical correlator.
    precise : (...) bool or None, which blocks took the common-content passes (the precise
        path: all with ``rewindow=True`` or a masked detection, none with ``rewindow=False``
        but blocks moved beyond the exact margin; the default decides per block,
        :meth:`Correlator._needs_precise`).
    """

    shift: np.ndarray
    valid: np.ndarray
    peak: np.ndarray
    crlb: np.ndarray
    p_false: np.ndarray | None = None
    p_wrong: np.ndarray | None = None
    precise: np.ndarray | None = None


def _as_stack(a: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"{name} must be (H, W) or (N, H, W), got shape {np.shape(a)}")
    if arr.shape[1] < 16 or arr.shape[2] < 16:
        raise ValueError(f"{name} blocks must be at least 16x16, got {arr.shape[1:]}")
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float32)  # the kernels are compiled for these two
    return arr


def _sanitise(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zero-mean float32 blocks (non-finite pixels zeroed) and a per-block 'usable' flag
    (see :func:`_usable`); for the surfaces and fits that work on unwindowed blocks."""
    b = blocks.astype(np.float32, copy=False)
    mean = b.mean(axis=(1, 2), dtype=np.float64)
    finite = np.isfinite(mean)
    if not finite.all():
        b = np.where(np.isfinite(b), b, 0.0).astype(np.float32)
        mean = np.where(finite, mean, b.mean(axis=(1, 2), dtype=np.float64))
    clean = b - mean.astype(np.float32)[:, None, None]
    flat = clean.reshape(len(b), b.shape[1] * b.shape[2])  # explicit: (0, H, W) too
    std = np.sqrt(np.einsum("ij,ij->i", flat, flat, dtype=np.float64) / flat.shape[1])
    top = flat.max(axis=1)
    saturated = np.count_nonzero(flat >= top[:, None], axis=1) > flat.shape[1] // 2
    return clean, _usable(mean, std, ~finite, saturated)


def _usable(mean, std, nonfinite, saturated) -> np.ndarray:
    """Unusable: any non-finite pixel, no texture (std below 1e-6 of the level), or saturated
    (more than half the pixels at the block maximum)."""
    return ((np.asarray(nonfinite) == 0) & (std > 1e-6 * np.maximum(np.abs(mean), 1.0))
            & (np.asarray(saturated) == 0))


@dataclass(frozen=True)
class _Layout:
    """Windows, frequency grids and masks of one block shape (h, w)."""

    h: int
    w: int
    margin: tuple[int, int]
    taper: tuple[float, float]
    wy_ref: np.ndarray
    wx_ref: np.ndarray
    wy_cur: np.ndarray
    wx_cur: np.ndarray
    e_ref: float
    e_cur: float
    q: int
    band_rows: np.ndarray
    band_cols: int
    full: spectral.Grid
    band: spectral.Grid
    outer_from: np.ndarray
    outer_n: int
    immerkaer: np.ndarray
    immerkaer_norm: float
    smooth: int

    @classmethod
    def of(cls, h: int, w: int) -> _Layout:
        m = (max(2, h // 32), max(2, w // 32))
        tc = m
        tr = (max(2, h // 16), max(2, w // 16))
        wy_ref = spectral.tukey_1d(h, tr[0], m[0] + tc[0])
        wx_ref = spectral.tukey_1d(w, tr[1], m[1] + tc[1])
        wy_cur = spectral.tukey_1d(h, tc[0])
        wx_cur = spectral.tukey_1d(w, tc[1])
        q = max(1, min(h, w) // 64)
        rows, cols = spectral.low_band(h, w, q)
        fy = np.abs(sfft.fftfreq(h))[:, None]
        fx = sfft.rfftfreq(w)[None, :]
        outer = np.hypot(fy, fx) > 0.35
        full = spectral.Grid.of(h, w)
        ay = full.ay[:, None]
        ax = full.ax[None, :]
        imm = ((2 - 2 * np.cos(ay)) * (2 - 2 * np.cos(ax))) ** 2 * full.alpha * full.rows[:, None]
        return cls(h, w, m, tr, wy_ref, wx_ref, wy_cur, wx_cur,
                   float(_energy(wy_ref, wx_ref)), float(_energy(wy_cur, wx_cur)),
                   q, rows.astype(np.int64), cols, full, spectral.Grid.of(h, w, rows, cols),
                   np.argmax(np.c_[outer, np.ones(len(outer), bool)], axis=1).astype(np.int64),
                   int(outer.sum()), imm.astype(np.float32), float(imm.sum()),
                   2 * max(DETECT_SMOOTH_BINS // 2, round(SMOOTH_FRACTION * min(h, w))) + 1)

    @property
    def win_ref(self) -> np.ndarray:
        return np.outer(self.wy_ref, self.wx_ref)

    @property
    def win_cur(self) -> np.ndarray:
        return np.outer(self.wy_cur, self.wx_cur)


@lru_cache(maxsize=16)
def _layout(h: int, w: int) -> _Layout:
    """The layout of (h, w) blocks, made once per shape (its arrays are read, never written:
    every Correlator of that shape shares them)."""
    return _Layout.of(h, w)


def _energy(wy: np.ndarray, wx: np.ndarray) -> np.ndarray:
    """Sum of squares of separable windows wy (..., h) x wx (..., w)."""
    return ((wy.astype(np.float64) ** 2).sum(axis=-1)
            * (wx.astype(np.float64) ** 2).sum(axis=-1))


def _pass_margins(d: np.ndarray) -> np.ndarray:
    """Whole-pixel zero margins (n, 2, 2) [axis, (low, high)] of the reference window of a
    common-content pass at shifts d (n, 2): the content ref shares with cur(x) = ref(x - d)."""
    return np.stack([np.ceil(np.maximum(-d, 0.0)), np.ceil(np.maximum(d, 0.0))],
                    axis=-1).astype(np.int64)


def _first_margins(d: np.ndarray, cur_taper: tuple[int, int]) -> np.ndarray:
    """Whole-pixel zero margins (n, 2, 2) [axis, (low, high)] of the first pass's reference
    window at shifts d (n, 2) px: its support, moved by d (and :data:`FIRST_SAFETY_PX` more
    either way), lies where cur's window (tapered over ``cur_taper`` px at its edges) is flat,
    so the correlation near d is the scene's."""
    t = np.asarray(cur_taper, dtype=np.float64)[None, :]
    lo = np.ceil(np.maximum(t - d + FIRST_SAFETY_PX, 0.0))
    hi = np.ceil(np.maximum(t + d + FIRST_SAFETY_PX, 0.0))
    return np.stack([lo, hi], axis=-1).astype(np.int64)


def _pass_windows(n: int, taper: float, lo: np.ndarray, hi: np.ndarray,
                  shift: np.ndarray | float = 0.0) -> np.ndarray:
    """Tukey windows (m, n) zero within lo (m,) px of the start and hi (m,) of the end,
    moved by ``shift`` px."""
    return spectral.tukey_1d(n, taper, 0.5 * (lo + hi), 0.5 * (lo - hi) + shift)


def _margin_windows(n: int, taper: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """:func:`_pass_windows` (m, n) of whole-pixel margins lo, hi (m,) (no shift), each
    distinct pair of margins made once (a stack holds a few)."""
    u, inv = np.unique(lo * (n + 1) + hi, return_inverse=True)
    return _pass_windows(n, taper, u // (n + 1), u % (n + 1))[inv.reshape(-1)]


def _run_of(rows: np.ndarray) -> slice | None:
    """The slice of ``rows`` (m,) where they are a run of consecutive blocks (an array's
    rows then made in place, no copy), else None."""
    if len(rows) and rows[-1] - rows[0] + 1 == len(rows) and np.all(np.diff(rows) == 1):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return None


class _CurPower:
    """Box means of the cur blocks' power (n, h, k) float32 from their first common-content
    pass, the energies (n,) of the windows they were made with, and which are made (n,)."""

    def __init__(self, n: int, shape: tuple[int, int]):
        self.power = np.empty((n, shape[0], shape[1] // 2 + 1), np.float32)
        self.energy = np.ones(n)
        self.have = np.zeros(n, bool)


class Correlator:
    """Shift measurement against fixed reference blocks (their spectra computed once).

    Parameters
    ----------
    ref : (H, W) or (N, H, W) reference blocks, any real dtype.
    options : :class:`CorrelatorOptions`, or keyword arguments for it.
    rng : noise of the emulated optical correlator's sensors (method 'optical' only); default
        ``np.random.default_rng(0)``. Each ``measure`` draws one child seed per block from it, so
        results do not depend on how the stack is split over threads.

    Notes
    -----
    A Correlator keeps each block's latest common-content reference (its spectrum for the
    window margins of the last pass), so a tracker re-uses it from frame to frame; calls to
    ``measure`` on one instance are serialised by a lock.

    Examples
    --------
    >>> import numpy as np
    >>> from correlator.testimages import texture_pairs
    >>> ref, cur, d = texture_pairs(4, 64, np.random.default_rng(0), max_shift_px=2.0)
    >>> res = Correlator(ref).measure(cur)
    >>> bool(np.all(np.abs(res.shift - d) < 0.01)), bool(res.valid.all())
    (True, True)
    """

    def __init__(self, ref: np.ndarray, options: CorrelatorOptions | None = None,
                 rng: np.random.Generator | None = None, **kwargs):
        self.options = options or CorrelatorOptions(**kwargs)
        o = self.options
        self._single = np.ndim(ref) == 2
        self._ref_in = _as_stack(ref, "ref")
        n, h, w = self._ref_in.shape
        self.shape = (h, w)
        self._lay = lay = _layout(h, w)
        m = o.max_shift_px
        self.max_shift_px = float(min(h, w) // 4 if m is None else m)
        nw = o.workers
        self._threads = (os.cpu_count() or 1) if nw == -1 else max(1, int(nw))
        self._lock = threading.Lock()
        masked = o.detection == "masked" or (o.detection == "auto"
                                             and self.max_shift_px > min(h, w) / 4)
        # the first pass's paths (default and one-FFT) make its weights from the box means of
        # the reference's power under the fixed window (:meth:`_window_reference`)
        self._fp_from_power = (o.subpixel == "fourier" and o.rewindow is not True
                               and not masked and o.method != "optical"
                               and o.weighting == "snr")
        # ---- the reference, once: windowed spectrum, noise, weights W conj(R), CRLB sums
        k = w // 2 + 1
        self._ref_w = fftbackend.empty((n, h, w), np.float32)
        self._ref_ok = np.zeros(n, bool)
        self._ref_spec = fftbackend.empty((n, h, k), np.complex64)
        self._ref_wconj = np.empty((n, h, k), np.complex64)
        self._ref_fw = np.empty((n, h, k), np.float32)
        self._ref_bw = np.empty((n, len(lay.band_rows), lay.band_cols), np.float32)
        self._ref_m = np.zeros((n, 3, 3))
        self._ref_noise = np.zeros(n)
        # the box means of its power, where the first pass's weights are made from them
        self._ref_pbox = np.empty((n, h, k) if self._fp_from_power else (0, 1, 1), np.float32)

        # computed per chunk just before its first measurement (while it is in cache)
        self._ref_ready = np.zeros(n, bool)
        # a detection sample (decimated) is searched when its lag is within the range
        hs, ws = len(lay.band_rows), 2 * (lay.band_cols - 1)
        lim = self.max_shift_px / lay.q + 0.5
        self._rows_in = np.flatnonzero(np.abs(_lag(np.arange(hs), hs)) <= lim)
        self._cols_in = np.flatnonzero(np.abs(_lag(np.arange(ws), ws)) <= lim)
        # pass references, filled on demand: margins (-1: none), W conj(R), CRLB sums
        self._pass_key = np.full((n, 4), -1, np.int64)
        self._pass_wconj: np.ndarray | None = None
        self._pass_fw: np.ndarray | None = None
        self._pass_bw: np.ndarray | None = None
        self._pass_m = np.zeros((n, 3, 3))
        self._pass_pbox: np.ndarray | None = None
        self._pass_s2 = np.zeros(n)
        # first-pass references (ref's window moved to the shift), filled on demand alike
        self._fp_key = np.full((n, 4), -1, np.int64)
        self._fp_wconj: np.ndarray | None = None
        self._fp_m = np.zeros((n, 3, 3))
        self._fp_bias = np.zeros((n, 2))
        # reference spectra under cur's window (the first pass's bias), filled on demand
        self._refc: np.ndarray | None = None
        self._refc_ready = np.zeros(n, bool)
        # the detection weights' stand-in where a reference has none (_ref_terms' detect)
        self._no_detect = (np.empty((0, h, k), np.float32),
                           np.empty((0, len(lay.band_rows), lay.band_cols), np.float32))
        # unwindowed reference blocks less their means: for the masked search, Lucas-Kanade
        # and the optical emulation (made here, never by the worker threads)
        self._ref0 = None
        if masked or o.subpixel == "gradient" or o.method == "optical":
            self._ref0 = _sanitise(self._ref_in)[0]
        self._masked = None
        if masked and o.method != "optical":
            # bins of half the band's decimation (2 px for 256^2 blocks): finer bins find
            # the right lag on low-texture, edge-dominated blocks more often
            self._masked = MaskedDetector(self._ref0, self.max_shift_px, o.min_overlap,
                                          max(1, lay.q // 2))
        if o.trust_prediction_px is not None and self._masked is not None:
            raise ValueError("trust_prediction_px needs the band detection (max_shift_px up "
                             "to a quarter block, or detection='band')")
        self._optical = None
        if o.method == "optical":
            self._optical = OpticalJtc(o.optical, h, w, self.max_shift_px)
            self._rng = rng if rng is not None else np.random.default_rng(0)

    @property
    def n_blocks(self) -> int:
        return self._ref_in.shape[0]

    def _ensure_ref(self, rows: np.ndarray) -> None:
        """Compute the reference terms of blocks ``rows`` not computed yet: window, spectrum,
        W conj(R), detection weights, CRLB sums, noise. A worker thread only ever computes
        rows of its own chunk (the rows of a call with repeated blocks are made before the
        threads start), so no thread reads a row another is writing."""
        ready = self._ref_ready[rows]
        if ready.all():
            return
        todo = np.unique(rows[~ready])
        lay = self._lay
        arrays = (self._ref_w, self._ref_spec, self._ref_wconj, self._ref_fw, self._ref_bw,
                  self._ref_m, self._ref_noise, self._ref_pbox)
        if todo[-1] - todo[0] + 1 == len(todo):  # a run of blocks: write in place
            sel = slice(todo[0], todo[-1] + 1)
            out = [a[sel] for a in arrays]
        else:
            out = [np.empty((len(todo) if len(a) else 0, *a.shape[1:]), a.dtype)
                   for a in arrays]
        ref_w, spec, *terms, pbox = out
        _, ok = self._prep(self._ref_in, todo, lay.wy_ref[None], lay.wx_ref[None], ref_w)
        fftbackend.rfft2(ref_w, spec)
        self._ref_terms(spec, np.full(len(todo), lay.e_ref), tuple(terms),
                        pbox=pbox if len(pbox) else None)
        if todo[-1] - todo[0] + 1 != len(todo):
            for a, o in zip(arrays, out, strict=True):
                if len(a):
                    a[todo] = o
        self._ref_ok[todo] = ok
        self._ref_ready[todo] = True

    # ------------------------------------------------------------------------- public
    def measure(self, cur: np.ndarray, rng: np.random.Generator | None = None,
                index: np.ndarray | None = None,
                predicted: np.ndarray | None = None) -> ShiftResult:
        """Shifts of ``cur`` blocks (same shape as ref) relative to the reference blocks.

        ``rng``: the optical emulation's noise for this call (default: the instance's).
        ``index``: measure only these reference blocks (``cur`` then holds just them).
        ``predicted``: (n, 2) or (2,) expected shifts, px; used with
        ``options.trust_prediction_px`` (see :class:`CorrelatorOptions`).
        """
        cur_arr = _as_stack(cur, "cur")
        idx = np.arange(self.n_blocks) if index is None else np.asarray(index, dtype=int)
        n = len(idx)
        if cur_arr.shape[1:] != self._ref_in.shape[1:] or cur_arr.shape[0] not in (1, n):
            raise ValueError(f"cur shape {np.shape(cur)} does not match the reference blocks "
                             f"{(n, *self._ref_in.shape[1:])}")
        if cur_arr.shape[0] != n:
            cur_arr = np.broadcast_to(cur_arr, (n, *self._ref_in.shape[1:]))
        pred = None
        if predicted is not None:
            if self.options.trust_prediction_px is None:
                raise ValueError("predicted needs options.trust_prediction_px (how far the "
                                 "prediction is trusted)")
            pred = np.broadcast_to(np.asarray(predicted, dtype=np.float64), (n, 2))
        if n == 0:
            z = np.zeros((0, 2))
            return ShiftResult(z, np.zeros(0, bool), np.zeros(0), z.copy(), np.zeros(0),
                               np.zeros(0), np.zeros(0, bool))
        with self._lock:
            if self._optical is not None:  # one pass: the emulation threads its FFTs itself
                seeds = (rng if rng is not None else self._rng).integers(0, 2**63 - 1, size=n)
                parts = [self._measure_optical(cur_arr, seeds, idx)]
            else:
                # pass references are cached per reference block: only when no block repeats
                cache = index is None or len(np.unique(idx)) == n
                if not cache:  # repeated rows: make their reference terms before the threads
                    rows = np.unique(idx)
                    self._parallel(lambda s: self._ensure_ref(rows[s]), len(rows))
                if cache and self._pass_wconj is None:
                    self._pass_wconj = np.empty_like(self._ref_wconj)
                    self._pass_fw = np.empty_like(self._ref_fw)
                    self._pass_bw = np.empty_like(self._ref_bw)
                    self._pass_pbox = np.empty(self._ref_fw.shape, np.float32)
                if cache and self._fp_wconj is None:
                    self._fp_wconj = np.empty_like(self._ref_wconj)
                    self._refc = fftbackend.empty(self._ref_wconj.shape, np.complex64)
                parts = self._parallel(
                    lambda s: self._measure(cur_arr[s], idx[s],
                                            None if pred is None else pred[s], cache), n)
        out = [np.concatenate([p[i] for p in parts]) for i in range(7)]
        if self._single and np.ndim(cur) == 2:
            return ShiftResult(*(a[0] for a in out))
        return ShiftResult(*out)

    # ---------------------------------------------------------------------- internals
    def _parallel(self, fn, n: int) -> list:
        """``fn`` of each chunk (a slice) of a stack of n blocks, on the worker threads."""
        chunks = self._chunks(n)
        if len(chunks) == 1 or self._threads == 1:
            return [fn(c) for c in chunks]
        # one BLAS thread per worker: the per-block matrix products are small, and nested
        # BLAS threads on top of ours would oversubscribe the cores
        with _blas().limit(limits=1, user_api="blas"):
            return list(_pool().map(fn, chunks))

    def _prep(self, blocks: np.ndarray, blk: np.ndarray, wy: np.ndarray, wx: np.ndarray,
              out: np.ndarray | None = None, usable: bool = True):
        """Blocks ``blk`` of ``blocks`` less their window-weighted means, times the window
        wy (1 or m, h) x wx (1 or m, w) (FFT-aligned float32, or into ``out``), and their
        usable flags (None with ``usable=False``: a block already judged, not read again for
        its statistics)."""
        if out is None:
            out = fftbackend.empty((len(blk), *blocks.shape[1:]), np.float32)
        stats = np.empty((len(blk) if usable else 0, 4))
        kernels.prep_blocks(blocks, blk, np.ascontiguousarray(wy, dtype=np.float32),
                            np.ascontiguousarray(wx, dtype=np.float32), True, out, stats)
        if not usable:
            return out, None
        return out, _usable(stats[:, 0], stats[:, 1], stats[:, 2], stats[:, 3])

    def _ref_terms(self, spec: np.ndarray, energy: np.ndarray, out: tuple | None = None,
                   pbox: np.ndarray | None = None, detect: bool = True):
        """W conj(R) (n, h, k), the detection's weights over W at the outer frequencies
        (n, h, k) and on the band (n, hb, kb), CRLB sums (n, 3, 3) and noise variance (n,) of
        reference spectra (n, h, k) of windows with energies (n,) (or into the five arrays
        ``out``); with ``pbox`` (n, h, k) float32, also the box means of |R|^2 into it.
        ``detect=False``: no detection weights (the two arrays have no blocks; a reference
        that no detection reads)."""
        lay = self._lay
        g = lay.full
        n = len(spec)
        if out is None:
            nd = n if detect else 0
            out = (np.empty(spec.shape, np.complex64),
                   np.empty((nd, *spec.shape[1:]), np.float32),
                   np.empty((nd, len(lay.band_rows), lay.band_cols), np.float32),
                   np.zeros((n, 3, 3)), np.empty(n))
        wconj, fw, bw, m, noise = out
        kernels.ref_spectra(spec.view(np.float32), lay.immerkaer, lay.immerkaer_norm, energy,
                            lay.smooth, DETECT_SMOOTH_BINS, self.options.weighting == "flat",
                            g.alpha, g.ay, g.ax, g.rows, lay.outer_from, lay.band_rows,
                            wconj.view(np.float32), fw, bw, m, noise,
                            np.empty((0, 1, 1), np.float32) if pbox is None else pbox)
        return out

    def _cross(self, spec: np.ndarray, wconj: np.ndarray, fw: np.ndarray | None,
               rows: np.ndarray):
        """Weighted cross spectra y (n, h, k) of cur spectra against rows of ``wconj``, the
        cur blocks' Immerkaer sums (n,) and the whitening floors (n,) (of ``fw`` y; both None
        where ``fw`` is None: y alone)."""
        lay = self._lay
        n = len(spec)
        y = np.empty(spec.shape, np.complex64)
        if fw is None:
            none = np.empty(0)
            kernels.cross_spectra(spec.view(np.float32), wconj.view(np.float32),
                                  np.empty((0, 1, 1), np.float32),
                                  np.asarray(rows, dtype=np.int64), lay.immerkaer, lay.outer_n,
                                  y.view(np.float32), none, none)
            return y, None, None
        noise_raw, floor = np.empty(n), np.empty(n)
        kernels.cross_spectra(spec.view(np.float32), wconj.view(np.float32), fw,
                              np.asarray(rows, dtype=np.int64), lay.immerkaer, lay.outer_n,
                              y.view(np.float32), noise_raw, floor)
        return y, noise_raw, floor

    def _newton(self, y, blk, d0, iterations: int, band: bool = False):
        """Newton on the full spectrum (or its central band) of blocks ``blk`` of y from
        d0 (m, 2): (d, Hessian one step before d, last step)."""
        lay = self._lay
        g = lay.band if band else lay.full
        rows = lay.band_rows if band else np.arange(lay.h, dtype=np.int64)
        d = np.array(d0, dtype=np.float64)
        m = len(d)
        val, hess, step = np.empty(m), np.zeros((m, 2, 2)), np.zeros((m, 2))
        kernels.newton(y.view(np.float32), np.asarray(blk, dtype=np.int64), rows, g.ay, g.rows,
                       g.ax, g.alpha, d, iterations, float(lay.q) if band else 0.5,
                       0.0 if band else NEWTON_STOP_PX, val, hess, step)
        return d, hess, step, val

    def _restoring(self, y: np.ndarray, blk: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Restoring ratios (m, 2) of the full-spectrum correlation of blocks ``blk`` of y
        about its peak at d (m, 2): :func:`correlator.tail.restoring_ratio` at 0.5 px."""
        g = self._lay.full
        out = np.empty((len(d), 2))
        tail.restoring_ratio(y.view(np.float32), np.asarray(blk, dtype=np.int64),
                             np.arange(self._lay.h, dtype=np.int64), g.ay, g.rows, g.ax,
                             g.alpha, np.asarray(d, dtype=np.float64), tail.WRONG_PX, out)
        return out

    def _hessian(self, y: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Hessian (n, 2, 2) of the correlation of spectra y (n, h, k) at lags d (n, 2)."""
        return self._newton(y, np.arange(len(y)), d, 1)[1]

    def _chunks(self, n: int) -> list[slice]:
        """Split the stack into chunks of at most CHUNK_BLOCKS blocks (a chunk's arrays stay in
        the core's cache from one step to the next), and over the threads when each part keeps
        >= 4 blocks."""
        k = max(1, -(-n // CHUNK_BLOCKS), min(self._threads, n // 4))
        edges = np.linspace(0, n, k + 1).astype(int)
        return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]

    def _measure(self, cur_arr: np.ndarray, ridx: np.ndarray, pred: np.ndarray | None,
                 cache: bool):
        """Results of ``cur_arr`` against the reference blocks ``ridx``."""
        o, lay = self.options, self._lay
        h, w = self.shape
        n = len(ridx)
        self._ensure_ref(ridx)
        cur_w, cur_ok = self._prep(cur_arr, np.arange(n), lay.wy_cur[None], lay.wx_cur[None])
        cspec = fftbackend.rfft2(cur_w)
        y, noise_raw, floor = self._cross(cspec, self._ref_wconj, self._ref_fw, ridx)
        noise = 0.5 * (self._ref_noise[ridx] + noise_raw / (lay.immerkaer_norm * lay.e_cur))
        ref_m = self._ref_m[ridx]

        # ---- detection: the integer peak (and, for the band search, its PSR and rival)
        ambiguous = np.zeros(n, bool)
        if self._masked is not None:
            d0, _, rival = self._masked.detect(self._cur0(cur_arr), ridx)
            ambiguous = rival >= o.max_rival_ratio
            psr = np.zeros(n)
        fits = ("parabolic", "gaussian", "com", "gradient")
        if o.subpixel in fits or o.joint_plane:
            surf = self._method_surface(np.conj(self._ref_spec[ridx]) * cspec, cur_w, ridx)
            if self._masked is not None:  # fit around the detected lag (may exceed h / 2)
                base = np.rint(d0).astype(int)
                jy, jx = base[:, 0] % h, base[:, 1] % w
            else:
                jy, jx = self._argmax(surf, 1)
                base = np.column_stack([_lag(jy, h), _lag(jx, w)])
            nb = peaks.neighbourhood(surf, jy, jx).astype(np.float64)
            kind = o.subpixel if o.subpixel in ("parabolic", "gaussian", "com") else "parabolic"
            d_fit = base + peaks.peak_fit(nb, kind)

        # ---- sub-pixel
        precise = np.zeros(n, bool)
        if o.subpixel == "fourier":
            if self._masked is not None:
                shift, crlb, rho, converged = self._fourier_masked(y, ridx, cur_arr, noise, d0,
                                                                   cache)
                precise[:] = True
            else:
                shift, crlb, rho, converged, psr, ambiguous, cells, precise = self._fourier(
                    y, floor, ridx, cur_arr, noise, ref_m, pred,
                    d_fit if o.joint_plane else None, cache, cspec)
        else:
            if self._masked is None:
                psr, (_, _, cells) = self._band_detect(y, self._ref_bw, ridx, floor,
                                                       np.full((n, 2), -1, np.int64))
            if o.subpixel == "gradient":
                shift, crlb, step = gradient.refine(self._ref0[ridx], self._cur0(cur_arr), d_fit,
                                                    o.iterations)
                converged = ((np.abs(step).max(axis=1) < 0.05)
                             & (np.abs(shift - d_fit).max(axis=1) < 1.5))
                # Lucas-Kanade's own error is too small at low SNR (27 of 102 valid results
                # 0.5 px off on the medium texture at SNR 4): the larger of it and the
                # spectrum's predicted error (0 of 3)
                crlb = np.maximum(crlb, _crlb(ref_m, noise, self._hessian(y, shift), h * w))
            else:
                shift, converged = d_fit, np.ones(n, bool)
                crlb = _crlb(ref_m, noise, self._hessian(y, shift), h * w)
            rho = self._restoring(y, np.arange(n), shift)
        if self._masked is not None:
            psr, agree, cells = self._common_psr(ridx, cur_arr, shift, cache)
            converged &= agree
        p_false = detection.false_alarm_probability(psr, cells)
        # wrong: a noise peak, or the true peak's estimate 0.5 px or more off (its tail)
        with np.errstate(divide="ignore"):
            p_wrong = -np.expm1(np.log1p(-p_false) + np.log1p(-tail.tail_probability(crlb, rho)))
        valid = (
            self._ref_ok[ridx]
            & cur_ok
            & (p_wrong <= o.false_valid_rate)
            & (psr >= o.psr_threshold)
            & converged
            & ~ambiguous
            & np.all(np.isfinite(shift), axis=1)
            & np.all(np.abs(shift) <= self.max_shift_px + 0.5, axis=1)
            & (np.all(crlb <= o.max_crlb_px, axis=1) if o.max_crlb_px is not None else True)
        )
        shift = np.where(np.isfinite(shift), shift, 0.0)
        # the detection's PSR is finite (0 where it is not)
        return shift, valid, psr, crlb, p_false, p_wrong, precise

    def _cur0(self, cur_arr: np.ndarray) -> np.ndarray:
        return _sanitise(cur_arr)[0]

    def _measure_optical(self, cur_arr: np.ndarray, seeds: np.ndarray, idx: np.ndarray):
        """The emulated JTOC: shift and PSR from its output plane; crlb is the pair's bound
        (what an ideal estimator would reach), for comparison and the texture check."""
        o, lay = self.options, self._lay
        h, w = self.shape
        self._ensure_ref(idx)
        cur_w, cur_ok = self._prep(cur_arr, np.arange(len(idx)), lay.wy_cur[None],
                                   lay.wx_cur[None])
        amplitude = o.optical.on("slm_amplitude")
        cur0 = self._cur0(cur_arr) if amplitude else None
        rngs = [np.random.default_rng(int(s)) for s in seeds]
        shift, psr = self._optical.measure(self._ref0[idx] if amplitude else self._ref_w[idx],
                                           cur0 if amplitude else cur_w, rngs, o.subpixel)
        y, noise_raw, _ = self._cross(fftbackend.rfft2(cur_w), self._ref_wconj, self._ref_fw,
                                      idx)
        noise = 0.5 * (self._ref_noise[idx] + noise_raw / (lay.immerkaer_norm * lay.e_cur))
        crlb = _crlb(self._ref_m[idx], noise, self._hessian(y, shift), h * w)
        valid = (self._ref_ok[idx] & cur_ok & (psr >= o.psr_threshold)
                 & np.all(np.abs(shift) <= self.max_shift_px + 0.5, axis=1)
                 & np.all(crlb <= (OPTICAL_MAX_CRLB_PX if o.max_crlb_px is None
                                   else o.max_crlb_px), axis=1))
        return (shift, valid, np.nan_to_num(psr), crlb, *np.full((2, len(idx)), np.nan),
                np.zeros(len(idx), bool))

    def _band_detect(self, y: np.ndarray, bw: np.ndarray, rows: np.ndarray,
                     floor: np.ndarray, given: np.ndarray):
        """Band detection on the SNR-whitened surfaces of the detection's cross spectra
        ``bw`` y (n, h, k) on the band (``bw`` rows ``rows``): the integer peak
        within the search range (or at the decimated sample ``given`` (n, 2) where >= 0),
        returned as (PSR (n,), lag (n, 2) px with a parabolic sub-sample step), the rival
        ratio (n,): the PSR of the best local maximum more than BAND_RIVAL_SAMPLES samples
        away over the peak's, and the cells searched (n,) (the whitened surface's samples,
        independent: :mod:`correlator.detection`)."""
        lay = self._lay
        n = len(y)
        hb, kb = len(lay.band_rows), lay.band_cols
        white = fftbackend.empty((n, hb, kb), np.complex64)
        kernels.whiten_band(y.view(np.float32), bw, np.asarray(rows, dtype=np.int64),
                            lay.band_rows, kb, floor, white.view(np.float32))
        surf = fftbackend.irfft2(white, (hb, 2 * (kb - 1)), normalise=False)
        lag, psr, ratio = np.empty((n, 2)), np.empty(n), np.empty(n)
        kernels.detect(surf, self._rows_in, self._cols_in, 2, BAND_RIVAL_SAMPLES, given, lag, psr,
                       ratio)
        lag *= lay.q
        cells = np.full(n, float(len(self._rows_in) * len(self._cols_in)))
        return psr, (lag, ratio, cells)

    def _fourier(self, y, floor, ridx, cur_arr, noise, ref_m, pred, d_fit, cache, cspec):
        """Fourier refinement after the band detection: band Newton from the detected peak
        (or the joint plane's fit ``d_fit``), weighted full-band Newton, the first pass (ref's
        window moved to the shift, on the same cur spectrum ``cspec``) and, for the blocks
        that need them (``rewindow``: None decides per block, :meth:`_needs_precise`; True:
        all), the common-content passes; blocks with a trusted prediction ``pred`` start
        Newton from it. Returns (shift, crlb, restoring ratio, converged, psr, ambiguous,
        cells, which blocks took the common-content passes)."""
        o, lay = self.options, self._lay
        h, w = self.shape
        n = len(y)
        d = np.zeros((n, 2))
        hess = np.zeros((n, 2, 2))
        step = np.zeros((n, 2))
        given = np.full((n, 2), -1, np.int64)
        trusted = np.zeros(n, bool)
        if pred is not None:  # the untrusted rows of d, hess, step are replaced by the search's
            d, hess, step, _ = self._newton(y, np.arange(n), pred, max(1, o.iterations))
            trusted = (_settled(step, _crlb(ref_m, noise, hess, h * w), NEWTON_TOL_PX)
                       & np.all(np.abs(d - pred) <= o.trust_prediction_px, axis=1))
            hs, ws = len(lay.band_rows), 2 * (lay.band_cols - 1)
            given[trusted] = np.rint(d[trusted] / lay.q).astype(np.int64) % [hs, ws]
        psr, (d0, ratio, cells) = self._band_detect(y, self._ref_bw, ridx, floor, given)
        if d_fit is not None:
            d0 = d_fit
        search = np.flatnonzero(~trusted)
        if len(search):
            ds = self._newton(y, search, d0[search], 2, band=True)[0]
            if o.rewindow is True:
                d[search], hess[search], step[search], _ = self._newton(y, search, ds,
                                                                        o.iterations)
            else:  # the first pass refines them (the band's estimate is good to ~0.1 px)
                d[search] = ds
        crlb = _crlb(ref_m, noise, hess, h * w)
        ambiguous = ~trusted & (ratio >= BAND_MAX_RIVAL_RATIO)
        settled = _settled(step, crlb, NEWTON_TOL_PX)
        # ---- the first pass: ref's window moved to the shift, on the same cur spectrum
        fin = np.isfinite(d).all(axis=1)
        far = np.any(np.abs(d) > lay.margin, axis=1) & fin
        rho = np.full((n, 2), np.nan)  # the first pass and the passes set theirs
        precise = np.ones(n, bool) if o.rewindow else far.copy()
        if o.rewindow is None:  # blocks certain to take the passes skip the first pass
            near = np.flatnonzero(fin & ~far)
            early = near[self._surely_precise(psr[near], self._restoring(y, near, d[near]))]
            precise[early] = True  # their passes start from the band's estimate
        if o.rewindow is not True:
            first = np.flatnonzero(fin & ~precise)
            d[first], crlb[first], settled[first], rho[first], bias = self._first_pass(
                first, ridx, cspec, noise, d, cache)
            if o.rewindow is None and len(first):  # adaptive: the passes where needed
                precise[first] = self._needs_precise(
                    crlb[first], psr[first], settled[first], np.abs(bias).max(axis=1),
                    rho[first],
                    ADAPT_MIN_CRLB_PX * 128.0 / min(h, w))
        sane = trusted | (np.abs(d - d0).max(axis=1) < lay.q + 1)
        # ---- common-content passes
        idx = np.flatnonzero(precise)
        rest = np.flatnonzero(~precise & np.isnan(rho[:, 0]))
        rho[rest] = self._restoring(y, rest, d[rest])
        settled = self._passes(idx, ridx, cur_arr, noise, d, crlb, rho, settled, cache)
        if o.rewindow is None and len(early):  # sane: their result agrees with the detection
            sane[early] = np.abs(d[early] - d0[early]).max(axis=1) < lay.q + 1
        return d, crlb, rho, sane & settled, psr, ambiguous, cells, precise

    @staticmethod
    def _surely_precise(psr: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """Which blocks (n,) :meth:`_needs_precise` sends to the common-content passes
        whatever their first pass gives, judged before it from the full-band pass on the
        fixed windows: a PSR ``psr`` (n,) below :data:`ADAPT_MIN_PSR` (the same PSR), or a
        restoring ratio ``rho`` (n, 2) above the decision's limit by
        :data:`EARLY_RHO_MARGIN` (a broad peak; NaN: not decided early). These blocks skip
        the first pass (its two reference spectra, the window bias, its cross spectrum and
        Newton): the passes start from the full-band estimate, as on the precise path."""
        with np.errstate(invalid="ignore"):
            return (psr < ADAPT_MIN_PSR) | (np.max(rho, axis=1) > ADAPT_MAX_RHO
                                            + EARLY_RHO_MARGIN)

    @staticmethod
    def _needs_precise(crlb: np.ndarray, psr: np.ndarray, settled: np.ndarray,
                       bias: np.ndarray, rho: np.ndarray,
                       min_crlb_px: float = ADAPT_MIN_CRLB_PX) -> np.ndarray:
        """Which blocks (n,) need the common-content passes after their first pass, from
        the block's own statistics (never the truth).

        A predicted error ``crlb`` (n, 2) px above :data:`ADAPT_MAX_CRLB_PX` (weak or smooth
        texture, where both images' weights lower the error and raise the valid fraction) or
        below ``min_crlb_px`` (high SNR, where the first pass's interpolation error would
        dominate; :data:`ADAPT_MIN_CRLB_PX` at 128^2); a PSR ``psr`` (n,) below
        :data:`ADAPT_MIN_PSR` (near the detection floor); a first pass that has not
        ``settled`` (n,); a window bias ``bias`` (n,) px removed from it (the larger axis)
        above :data:`ADAPT_MAX_BIAS_SIGMA` predicted errors, or not finite; or a broad peak,
        a restoring ratio ``rho`` (n, 2) above :data:`ADAPT_MAX_RHO` on an axis (power at the
        lowest frequencies; NaN counts as broad).
        """
        c = crlb.max(axis=1)
        return (~settled | (c > ADAPT_MAX_CRLB_PX) | (c < min_crlb_px)
                | (psr < ADAPT_MIN_PSR) | ~(bias <= ADAPT_MAX_BIAS_SIGMA * c)
                | ~(np.max(rho, axis=1) <= ADAPT_MAX_RHO))

    def _first_pass(self, blk, ridx, cspec, noise, d, cache):
        """The first pass of blocks ``blk`` at their shifts d (n, 2) px: ref windowed zero
        within whole-pixel margins that put its support, moved by d, inside cur's flat
        region (:func:`_first_margins`), against the cur spectra ``cspec`` already made, so
        no further FFT of cur (a tracker keeps the reference for its margins), less the
        windows' bias (:meth:`_window_reference`). Returns (d, crlb, settled, restoring
        ratio, the bias removed (n, 2) px) of the blocks."""
        lay = self._lay
        h, w = self.shape
        if not len(blk):
            z = np.zeros((0, 2))
            return z, z.copy(), np.zeros(0, bool), z.copy(), z.copy()
        mg = _first_margins(d[blk], lay.margin)
        rows = ridx[blk]
        if cache:
            key = mg.reshape(len(blk), 4)
            miss = np.flatnonzero(np.any(self._fp_key[rows] != key, axis=1))
            if len(miss):
                tgt = rows[miss]
                run = _run_of(tgt)
                if run is not None:  # a run of blocks (independent pairs): made in place
                    self._window_reference(tgt, mg[miss], cache=True, out=(
                        self._fp_wconj[run], self._fp_m[run], self._fp_bias[run]))
                else:
                    wc, mm, bias = self._window_reference(tgt, mg[miss], cache=True)
                    self._fp_wconj[tgt] = wc
                    self._fp_m[tgt] = mm
                    self._fp_bias[tgt] = bias
                self._fp_key[tgt] = key[miss]
            src, srow, m = self._fp_wconj, rows, self._fp_m[rows]
            bias = self._fp_bias[rows]
        else:
            src, m, bias = self._window_reference(rows, mg)
            srow = np.arange(len(blk))
        y = self._cross(cspec if len(blk) == len(cspec) else cspec[blk], src, None, srow)[0]
        b = np.arange(len(blk))
        d2, hess, step, _ = self._newton(y, b, d[blk], self.options.iterations)
        crlb = _crlb(m, noise[blk], hess, h * w)
        rho = self._restoring(y, b, d2)
        return (d2 - np.where(np.isfinite(bias), bias, 0.0), crlb,
                _settled(step, crlb, NEWTON_TOL_PX), rho, bias)

    def _window_reference(self, rows: np.ndarray, mg: np.ndarray, cache: bool = False,
                          out: tuple | None = None):
        """The first pass's reference terms of blocks ``rows`` windowed with zero margins
        mg (m, 2, 2): W conj(R) (m, h, k), the CRLB sums (m, 3, 3), and the bias (m, 2)
        px that the windows give the first pass's estimate (or into the three arrays ``out``).

        ref's window is narrower than cur's, so the pass correlates a windowed block against
        an unwindowed one: sum w(x) s(x) s(x + e) peaks where its gradient
        -1/2 sum grad(w) s^2 vanishes, off e = 0 wherever the texture's power differs
        between the window's opposite tapers (a field edge, a building, a bright roof: on the
        flight test's rendered 64^2 blocks 0.16 px rms, 23 predicted sigma; on stationary
        synthetic texture a few tenths of a sigma). The bias is the same pass run on the
        reference against itself under cur's window, whose noise x noise term (the noise's
        own correlation, a peak at lag 0 that would shrink the estimate) is removed
        (:func:`kernels.self_cross`); it is cached with the reference, and with ``cache``
        (rows unique) the reference's spectrum under cur's window too (it does not depend on
        the margins). The detection's weights are not made (the pass has its detection)."""
        n = len(rows)
        spec, wy, wx = self._windowed_reference(rows, mg)
        if out is None:
            out = (np.empty(spec.shape, np.complex64), np.zeros((n, 3, 3)), np.empty((n, 2)))
        wc, mm, bias_out = out
        energy = _energy(wy, wx)
        if self._fp_from_power:
            # the weights from the power under the fixed window (its box means, made with the
            # detection's reference), scaled by the windows' energies: no second box average
            noise = self._ref_noise[rows]
            g = self._lay.full
            kernels.scaled_weights(spec.view(np.float32), self._ref_pbox,
                                   np.asarray(rows, dtype=np.int64), energy / self._lay.e_ref,
                                   noise * energy, g.alpha, g.ay, g.ax, g.rows,
                                   wc.view(np.float32), mm)
        else:
            noise = np.empty(n)
            self._ref_terms(spec, energy, (wc, *self._no_detect, mm, noise))
        bias_out[...] = self._self_bias(wc, spec, np.arange(n), rows, noise, wy, wx, cache)
        return wc, mm, bias_out

    def _cur_window_reference(self, rows: np.ndarray, cache: bool):
        """The spectra of reference blocks ``rows`` under cur's window: (array, its rows of
        these blocks); with ``cache`` (rows unique) kept for the reference (they do not
        depend on any margin)."""
        lay = self._lay
        if not cache:
            ref_c, _ = self._prep(self._ref_in, rows, lay.wy_cur[None], lay.wx_cur[None],
                                  usable=False)
            return fftbackend.rfft2(ref_c), np.arange(len(rows))
        todo = rows[~self._refc_ready[rows]]
        if len(todo):
            ref_c, _ = self._prep(self._ref_in, todo, lay.wy_cur[None], lay.wx_cur[None],
                                  usable=False)
            run = _run_of(todo)
            if run is not None:
                fftbackend.rfft2(ref_c, self._refc[run])
            else:
                self._refc[todo] = fftbackend.rfft2(ref_c)
            self._refc_ready[todo] = True
        return self._refc, rows

    def _self_bias(self, wconj, spec, wrow, rows, noise, wy, wx, cache):
        """The bias (m, 2) px that ref's window wy (1 or m, h) x wx (1 or m, w) gives a pass
        against cur's window: Newton from 0 on the reference blocks ``rows`` against
        themselves under cur's window, W conj(R) ``wconj`` and R ``spec`` (rows ``wrow``)
        under ref's, less the noise x noise term of noise variances ``noise`` (m,)
        (:meth:`_window_reference`); NaN where not finite."""
        n = len(rows)
        other, orow = self._cur_window_reference(rows, cache)
        # cur's window is flat (1) on ref's support: the windows' product sums to ref's sum
        s = noise * (wy.sum(axis=1, dtype=np.float64) * wx.sum(axis=1, dtype=np.float64))
        y = np.empty((n, *spec.shape[1:]), np.complex64)
        kernels.self_cross(wconj.view(np.float32), spec.view(np.float32),
                           np.asarray(wrow, dtype=np.int64), other.view(np.float32),
                           np.asarray(orow, dtype=np.int64), s, y.view(np.float32))
        bias = self._newton(y, np.arange(n), np.zeros((n, 2)), self.options.iterations)[0]
        return np.where(np.isfinite(bias), bias, np.nan)

    def _fourier_masked(self, y, ridx, cur_arr, noise, d0, cache):
        """Fourier refinement after a masked detection: the lag is good to a bin, so straight
        to the common content (the circular surface of a far-shifted pair is dominated by
        content the blocks do not share); this coarse pass need not settle, the passes after
        it must."""
        lay = self._lay
        n = len(d0)
        idx = np.arange(n)
        cbox = _CurPower(n, self.shape)
        d, crlb, _, _ = self._common_pass(idx, ridx, cur_arr, noise, d0, cache, coarse=True,
                                          cbox=cbox)
        rho = np.full((n, 2), np.nan)  # set by the passes (d not finite: no result)
        sane = np.abs(d - d0).max(axis=1) < lay.q + 1
        idx = np.flatnonzero(np.isfinite(d).all(axis=1))
        settled = self._passes(idx, ridx, cur_arr, noise, d, crlb, rho, np.ones(n, bool),
                               cache, cbox)
        return d, crlb, rho, sane & settled

    def _passes(self, idx, ridx, cur_arr, noise, d, crlb, rho, settled, cache,
                cbox: _CurPower | None = None):
        """Common-content passes of blocks ``idx``, in place on d, crlb and rho, repeated to their
        fixed point; returns ``settled`` updated by each block's last pass.

        The windows follow the estimate, so the pass is repeated until it is self-consistent.
        A window displaced by e moves the estimate by s e: s ~ 0.1-0.2 on even texture, up to
        ~0.7 where a bright, smooth structure (a cloud, a snow field) lies in the taper. The
        passes contract linearly, d' - d* = s (d - d*), so after two plain moves each
        component jumps to its fixed point (Aitken's delta-squared), then starts over.
        """
        settled = settled.copy()
        if not len(idx):
            return settled
        if cbox is None:
            cbox = _CurPower(len(d), self.shape)
        prev = np.zeros_like(d)
        moved = np.zeros(len(d))
        for it in range(COMMON_PASSES):
            if not len(idx):
                break
            d2, c2, step2, y = self._common_pass(idx, ridx, cur_arr, noise, d[idx], cache,
                                                 cbox=cbox)
            step = d2 - d[idx]
            p = prev[idx]
            ratio = np.divide(step, p, out=np.zeros_like(step), where=np.abs(p) > AITKEN_MIN_PX)
            jump = (ratio > AITKEN_RATIO[0]) & (ratio < AITKEN_RATIO[1])
            prev[idx] = np.where(jump, 0.0, step)
            step = np.where(jump, step / (1.0 - np.where(jump, ratio, 0.0)), step)
            d[idx], crlb[idx] = d[idx] + step, c2
            settled[idx] = _settled(step2, c2, NEWTON_TOL_PX)
            moved[idx] = np.abs(step).max(axis=1)
            tol = np.maximum(COMMON_PASS_TOL_PX, PASS_TOL_REL * c2.max(axis=1))
            more = np.isfinite(moved[idx]) & (moved[idx] > tol)
            done = np.flatnonzero(~more | (it == COMMON_PASSES - 1))
            if len(done):  # a block's last pass: its restoring ratio (correlator.tail)
                rho[idx[done]] = self._restoring(y, done, d2[done])
            idx = idx[more]
        # still moving after the last pass: not self-consistent, not a result to trust
        return settled & (moved <= np.maximum(COMMON_PASS_MAX_MOVE_PX,
                                              SETTLED_REL * crlb.max(axis=1)))

    def _common_pass(self, idx, ridx, cur_arr, noise, d, cache, coarse: bool = False,
                     cbox: _CurPower | None = None):
        """One pass of blocks ``idx`` with both windows on the content common to ref and cur
        at lags d; ``coarse``: start with two band Newton steps (d good only to a decimation
        step). The weights are Knapp-Carter's from the power of both blocks (the box means
        of cur's power are made on a block's first pass and kept in ``cbox``, scaled by the
        windows' energies after). Returns (d, crlb, last Newton step, the pass's weighted cross
        spectra y (m, h, k))."""
        o = self.options
        h, w = self.shape
        y, _, m, (_, srow), (cspec, pbox, s2r, energy) = self._pass_spectra(
            idx, ridx, cur_arr, d, cache)
        if o.weighting == "snr":  # the weights from both images' power
            g = self._lay.full
            if cbox is None:
                cbox = _CurPower(len(cur_arr), self.shape)
            first = np.flatnonzero(~cbox.have[idx])
            if len(first):  # the first pass of these blocks: the box means of their power
                tmp = np.empty((len(first), *cspec.shape[1:]), np.float32)
                kernels.box_power(cspec.view(np.float32), first.astype(np.int64),
                                  self._lay.smooth, tmp)
                cbox.power[idx[first]] = tmp
                cbox.energy[idx[first]] = energy[first]
                cbox.have[idx[first]] = True
            m = np.empty((len(idx), 3, 3))
            kernels.both_weights(y.view(np.float32), cspec.view(np.float32), pbox,
                                 np.asarray(srow, dtype=np.int64), cbox.power,
                                 np.asarray(idx, dtype=np.int64), energy / cbox.energy[idx],
                                 s2r, noise[idx] * energy,
                                 1.0 - BOTH_POWER_SE / (np.sqrt(2.0) * self._lay.smooth),
                                 g.alpha, g.ay, g.ax, g.rows, m)
        blk = np.arange(len(idx))
        if coarse:
            d = self._newton(y, blk, d, 2, band=True)[0]
        d2, hess, step, _ = self._newton(y, blk, d, o.iterations)
        crlb = _crlb(m, noise[idx], hess, h * w)
        return d2, crlb, step, y

    def _pass_spectra(self, idx, ridx, cur_arr, d, cache):
        """Weighted cross spectra (m, h, k) of blocks ``idx`` with ref windowed to the content
        it shares with cur at lags d (m, 2) (whole-pixel margins, :func:`_pass_margins`) and
        cur windowed alike, moved by d; their whitening floors, CRLB sums (m, 3, 3) and the
        detection's band weights (array, its rows)."""
        lay = self._lay
        h, w = self.shape
        mg = _pass_margins(d)
        rows = ridx[idx]
        key = mg.reshape(len(idx), 4)
        detect = self._masked is not None  # only the masked detection's PSR reads them
        if cache:
            miss = np.flatnonzero(np.any(self._pass_key[rows] != key, axis=1))
            if len(miss):
                tgt = rows[miss]
                run = _run_of(tgt)
                if run is not None:  # a run of blocks: made in place
                    self._pass_reference(tgt, mg[miss], detect, out=(
                        self._pass_wconj[run],
                        self._pass_fw[run] if detect else self._no_detect[0],
                        self._pass_bw[run] if detect else self._no_detect[1],
                        self._pass_m[run], self._pass_pbox[run], self._pass_s2[run]))
                else:
                    wc, fw, bw, mm, _, pb, s2 = self._pass_reference(tgt, mg[miss], detect)
                    self._pass_pbox[tgt] = pb
                    self._pass_s2[tgt] = s2
                    self._pass_wconj[tgt] = wc
                    if detect:
                        self._pass_fw[tgt] = fw
                        self._pass_bw[tgt] = bw
                    self._pass_m[tgt] = mm
                self._pass_key[tgt] = key[miss]
            src, fw, bw = self._pass_wconj, self._pass_fw, self._pass_bw
            srow, m = rows, self._pass_m[rows]
            pbox, s2r = self._pass_pbox, self._pass_s2[rows]
        else:
            src, fw, bw, m, _, pbox, s2r = self._pass_reference(rows, mg, detect)
            srow = np.arange(len(idx))
        wy = _pass_windows(h, lay.taper[0], mg[:, 0, 0], mg[:, 0, 1], d[:, 0])
        wx = _pass_windows(w, lay.taper[1], mg[:, 1, 0], mg[:, 1, 1], d[:, 1])
        cur_w, _ = self._prep(cur_arr, idx, wy, wx, usable=False)
        cspec = fftbackend.rfft2(cur_w)
        y, _, floor = self._cross(cspec, src, fw if detect else None, srow)
        return y, floor, m, (bw, srow), (cspec, pbox, s2r, _energy(wy, wx))

    def _windowed_reference(self, rows: np.ndarray, mg: np.ndarray):
        """The spectra (m, h, w//2+1) of reference blocks ``rows`` windowed with zero margins
        mg (m, 2, 2), and those windows (m, h), (m, w)."""
        lay = self._lay
        h, w = self.shape
        wy = _margin_windows(h, lay.taper[0], mg[:, 0, 0], mg[:, 0, 1])
        wx = _margin_windows(w, lay.taper[1], mg[:, 1, 0], mg[:, 1, 1])
        ref_w, _ = self._prep(self._ref_in, rows, wy, wx, usable=False)
        return fftbackend.rfft2(ref_w), wy, wx

    def _pass_reference(self, rows: np.ndarray, mg: np.ndarray, detect: bool = True,
                        out: tuple | None = None):
        """:meth:`_ref_terms` of reference blocks ``rows`` windowed with zero margins
        mg (m, 2, 2) (their own Knapp-Carter weights; the detection's with ``detect``), the
        box means of their power (m, h, k) and the noise power per bin (m,) of their weights;
        or into ``out``: (W conj(R), detection weights (outer, band; no blocks without
        ``detect``), CRLB sums, box means, noise power per bin)."""
        spec, wy, wx = self._windowed_reference(rows, mg)
        energy = _energy(wy, wx)
        n = len(rows)
        if out is None:
            nd = n if detect else 0
            out = (np.empty(spec.shape, np.complex64),
                   np.empty((nd, *spec.shape[1:]), np.float32),
                   np.empty((nd, *self._ref_bw.shape[1:]), np.float32), np.zeros((n, 3, 3)),
                   np.empty(spec.shape, np.float32), np.empty(n))
        wc, fw, bw, mm, pbox, s2 = out
        noise = np.empty(n)
        self._ref_terms(spec, energy, (wc, fw, bw, mm, noise), pbox=pbox)
        s2[...] = noise * energy
        return wc, fw, bw, mm, noise, pbox, s2

    def _common_psr(self, ridx, cur_arr, d, cache):
        """PSR (N,) of the whitened surface of the content common at lag ``d`` (N, 2) px, and
        whether that surface's own peak agrees with ``d`` to a decimation step (mod the block):
        after a masked detection, the statistic on which the threshold is applied."""
        lay = self._lay
        h, w = self.shape
        n = len(d)
        y, floor, _, (bw, rows), _ = self._pass_spectra(np.arange(n), ridx, cur_arr, d,
                                                        cache)
        psr, (lag, _, cells) = self._band_detect(y, bw, rows, floor,
                                                 np.full((n, 2), -1, np.int64))
        lag = lay.q * np.rint(lag / lay.q)
        size = np.array([h, w])
        diff = np.mod(lag - d + size / 2, size) - size / 2
        # the masked search chose among its own lags: count those where they are more
        cells = np.maximum(cells, float(np.count_nonzero(self._masked.search)))
        return psr, np.all(np.abs(diff) <= lay.q + 0.5, axis=1), cells

    def _argmax(self, surf: np.ndarray, q: int) -> tuple[np.ndarray, np.ndarray]:
        """Integer peak (iy, ix) of wrapped surfaces within the search range (scaled by q)."""
        n, hs, ws = surf.shape
        lim = self.max_shift_px / q + 0.5
        inside = ((np.abs(_lag(np.arange(hs), hs)) <= lim)[:, None]
                  & (np.abs(_lag(np.arange(ws), ws)) <= lim)[None, :])
        flat = np.where(inside[None], surf, -np.inf).reshape(n, -1).argmax(axis=1)
        return np.unravel_index(flat, (hs, ws))

    def _method_surface(self, x, cur_w, ridx) -> np.ndarray:
        """Full-resolution correlation surface of the chosen method (lag 0 at [0, 0])."""
        o = self.options
        h, w = self.shape
        if o.method == "jtc" and o.joint_plane:
            return jtc.joint_plane_surface(self._ref_w[ridx], cur_w, o.jtc_filter)
        if o.method == "phase":
            spec = x / (np.abs(x) + 1e-30)
        elif o.method == "jtc" and o.jtc_filter == "fringe":
            rs = self._ref_spec[ridx]
            pr = rs.real**2 + rs.imag**2
            spec = x / (pr + jtc.fringe_eps(pr))
        else:
            spec = x
        return fftbackend.irfft2(spec, (h, w))


def _crlb(m: np.ndarray, noise: np.ndarray, hess: np.ndarray, npix: int) -> np.ndarray:
    """Predicted 1-sigma error (n, 2) px: :func:`correlator.kernels.crlb`."""
    out = np.empty((len(hess), 2))
    kernels.crlb(m, np.asarray(noise, dtype=np.float64), hess, npix, out)
    return out


def _settled(step: np.ndarray, crlb: np.ndarray, abs_tol: float) -> np.ndarray:
    """Whether a last Newton step (n, 2) px is small: within abs_tol or SETTLED_REL of the
    block's own predicted error (n, 2) on both axes."""
    return np.all(np.abs(step) <= np.maximum(abs_tol, SETTLED_REL * crlb), axis=1)


@lru_cache(maxsize=1)
def _blas() -> ThreadpoolController:
    """The process's BLAS thread pools (inspected once: the inspection costs milliseconds)."""
    return ThreadpoolController()


@lru_cache(maxsize=1)
def _pool() -> ThreadPoolExecutor:
    """The correlators' worker threads, kept for the process (each keeps its FFT plans)."""
    return ThreadPoolExecutor(os.cpu_count() or 1, thread_name_prefix="correlator")


def _lag(i: np.ndarray, size: int) -> np.ndarray:
    """Signed lag of index i on a wrapped axis of length size."""
    i = np.asarray(i)
    return np.where(i < (size + 1) // 2, i, i - size)


def measure_shift(ref: np.ndarray, cur: np.ndarray, method: str = "jtc",
                  rng: np.random.Generator | None = None, **options) -> ShiftResult:
    """Measure the displacement of ``cur`` relative to ``ref``.

    Parameters
    ----------
    ref, cur : (H, W) or stacked (N, H, W) real arrays of equal shape (blocks >= 16x16).
    method : 'jtc', 'xcorr', 'phase' or 'optical' (the emulated optical correlator).
    rng : sensor noise of method 'optical' (default ``np.random.default_rng(0)``).
    **options : see :class:`CorrelatorOptions` (subpixel, psr_threshold, max_shift_px, ...).

    Returns
    -------
    ShiftResult
        ``shift`` (..., 2) = (d_row, d_col) px with cur(x) ~ ref(x - d); ``valid``; ``peak``
        (peak-to-sidelobe ratio); ``crlb`` (..., 2) predicted 1-sigma error, px.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> img = rng.normal(size=(80, 80))
    >>> r = measure_shift(img[8:72, 8:72], img[5:69, 10:74])  # content moved by (+3, -2)
    >>> np.round(r.shift, 3).tolist(), bool(r.valid)
    ([3.0, -2.0], True)
    """
    if np.shape(ref) != np.shape(cur):
        raise ValueError(f"ref and cur must have the same shape, got {np.shape(ref)} and "
                         f"{np.shape(cur)}")
    return Correlator(ref, CorrelatorOptions(method=method, **options), rng).measure(cur)

"""The motion record solved as a network of pair measurements, smoothed, and aided.

A tracker that compares the scene with itself after a lag measures differences, never the
motion: link i between reference frame ``a_i`` and current frame ``b_i`` (``a_i < b_i``)
measures, per axis (row, col) and in px,

    d_i = s_{b_i} - s_{a_i} + (nu_{b_i} - nu_{a_i}) + e_i,     e_i ~ N(0, sigma_i^2),

``s_k = s(t_k)`` the image motion at frame k, ``e_i`` the link's own error (independent
between links) and ``nu_k ~ N(0, sigma_f,k^2)`` an optional per-frame noise (frame k's
texture and sensor noise, which enters every link that uses frame k: links sharing a frame
are correlated). :func:`solve_network` estimates all ``s_k`` at once by sparse weighted
least squares (scipy.sparse normal equations, SuperLU), each row weighted by 1/sigma^2,
invalid links dropped. The per-frame noise is handled by augmented unknowns: each ``nu_k``
is solved with the prior ``nu_k = 0 +- sigma_f,k``, which is the generalised least squares
with the links' covariance ``diag(sigma^2) + D diag(sigma_f^2) D^T`` (D the incidence
matrix) and keeps the model exact when aiding measures ``s`` without ``nu``.

Links that share their frames' pixels (:class:`SharedNoise`): a chained tracker measures
each pair on blocks of its two frames, and each frame's noise over a block's pixels enters
every link measured on those pixels (half a pair's variance from each frame, the analytic
plant's split; the rendered no_stage.yaml's pairs from one reference region correlate by
0.40-0.53). The links' covariance ``R = diag(sigma^2) + R_shared``, ``R_shared`` from the
regions' overlaps (block-sparse: links correlate only through a frame they share), is used
whole: generalised least squares through the sparse saddle-point (KKT) system
``[[R, A], [A^T, 0]]``, whose inverse's lower-right block is the estimate's covariance
``-(A^T R^-1 A)^-1``, exact for that noise model; a link all of whose error is shared has
``sigma`` 0. Without it the rows are independent and the normal equations are solved as
before (a chain solves to the same cumulative sum either way; only its covariance differs).

The gauge: links see only differences, so one constant per axis is free. ``"first"``
fixes ``s_0 = 0`` (the loop's zero, docs/conventions.md); ``"mean"`` gives the solution and
covariance with zero mean (the same solution projected: ``P s``, ``P C P``, ``P = I - 11^T/N``);
``"none"`` needs absolute measurements (ground control, a star tracker) and leaves s absolute.
A chain (links ``(k, k+1)`` only) under ``"first"`` is exactly today's cumulative sum, with
covariance ``C_jk = sum_{i < min(j, k)} sigma_i^2``.

Aiding in the same solve (ground/aiding.py): a gyro's increments between frames
(``g_{k+1} - g_k = s_{k+1} - s_k + beta dt_k + (w_{k+1} - w_k) + ARW``, ``beta`` one rate-bias
unknown per axis with the bias instability as its prior, ``w`` the gyro's per-frame noise as
augmented unknowns) and absolute fixes (``s`` at fractional frame positions, linearly
interpolated).

The two-sided smoother (:func:`smooth_network`) is least squares with a prior added to the
same system: p-th differences of s are zero with variance ``c_k q`` (p = 1: a random walk,
``c_k = dt_k``; p = 2: an integrated random walk, the Whittaker / cubic-smoothing-spline
prior, ``c_k = (2/3) dt^3``, the p-th differences taken as independent). The intensity
``q`` per axis is estimated from the record itself, never from the scenario's jitter: by
maximum marginal likelihood of the unsmoothed solution's p-th differences ``y = D_p s_hat``,
``y ~ N(0, q diag(c) + D_p C D_p^T)`` with C the solve's own predicted covariance
(:func:`estimate_prior`). Being linear in the same system,
the smoothed series keeps an exact posterior covariance (exact when the prior holds).

Covariance: the full (N, N) covariance per axis is returned, dense: 8 N^2 bytes per axis
(8 MB at N = 1,000 frames, 72 MB at 3,000), computed by solving the factorised normal
matrix (or saddle-point system) against the s columns in blocks of 256. Differences and projections
(:meth:`NetworkSolution.difference_sigma_px`, :func:`geometry_rms`) read it.

References
----------
Sheikh, Zhai & Shah, ACCV 2004 (aligning each frame to all overlapping frames);
MintPy ``ifgram_inversion`` (a network of pairs solved into a time series with covariance);
Sciacchitano, Scarano & Wieneke, Exp. Fluids 53, 2012 (multi-frame correlation);
Rauch, Tung & Striebel, AIAA J. 3(8), 1965 and Whittaker, Proc. Edinburgh Math. Soc. 41,
1923 (smoothing priors); ../shared/notes/product-facts.md, "Restitution".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import sparse
from scipy.sparse import csgraph
from scipy.sparse import linalg as spla

from ground.aiding import Absolute, GyroAiding
from ground.record import MotionRecord

GAUGES = ("first", "mean", "none")
#: sigmas below this are raised to it (a noiseless measurement is weighted as 1e-6 px)
SIGMA_FLOOR_PX = 1e-6
_BLOCK = 256


def _frame_array(v: ArrayLike, n_frames: int, name: str) -> np.ndarray:
    try:
        a = np.broadcast_to(np.asarray(v, dtype=np.float64), (n_frames, 2))
    except ValueError:
        raise ValueError(f"{name} must broadcast to ({n_frames}, 2) (per frame, per axis) px, "
                         f"got shape {np.shape(v)}") from None
    if not np.all(np.isfinite(a) & (a >= 0)):
        raise ValueError(f"{name} must be finite and >= 0 px")
    return a


@dataclass(frozen=True, eq=False)  # holds arrays
class SharedNoise:
    """Noise the links share through the pixels of their frames.

    A link is measured on regions (blocks) of its two frames; each frame's noise over a region
    enters every link measured on those pixels. Entry p puts ``coef_px[p]`` (per axis, px,
    signed: + in the current frame, - in the reference) times the unit-variance noise of
    frame ``frame[p]`` over the square region of ``block_px`` at ``corner_px[p]`` into link
    ``link[p]``. Two regions of one frame share their noise in proportion to their overlap:
    the noise is a field of independent cells of ``cell_px`` (1: the sensor's pixels; the
    analytic plant's field: its ``cell_px``), a region's noise the sum over its cells scaled
    to unit variance, so the covariance of two regions is the fraction of their cells in
    common (corners rounded to the cell grid). The links' shared covariance is then

        R_LM = sum over entries p of L, q of M in one frame of coef_p coef_q overlap(p, q),

    block-sparse: links correlate only through frames they share.

    Parameters
    ----------
    link : array_like of int, (e,)
        Index of the entry's link in :class:`Links`.
    frame : array_like of int, (e,)
        The frame whose pixels the entry reads.
    corner_px : array_like of int, (e, 2)
        Top-left corner (row, col) of the region in that frame, px.
    coef_px : array_like, (e, 2)
        The entry's standard deviation in its link, signed, per axis, px.
    block_px : int
        The regions' side, px.
    cell_px : int, optional
        The noise field's cell, px (default 1: independent pixels).

    References
    ----------
    The analytic plant's pair noise (compensation/analytic_plant.py, ``_region_noise``), and
    the rendered no_stage.yaml's links (docs/product.md, "Links share their frames' pixels").
    """

    link: np.ndarray
    frame: np.ndarray
    corner_px: np.ndarray
    coef_px: np.ndarray
    block_px: int
    cell_px: int = 1

    def __post_init__(self) -> None:
        link = np.asarray(self.link)
        frame = np.asarray(self.frame)
        corner = np.asarray(self.corner_px)
        coef = np.asarray(self.coef_px, dtype=np.float64)
        e = link.shape[0] if link.ndim == 1 else -1
        if (e < 0 or frame.shape != (e,) or corner.shape != (e, 2) or coef.shape != (e, 2)):
            raise ValueError(f"SharedNoise needs link (e,), frame (e,), corner_px (e, 2) and "
                             f"coef_px (e, 2), got {link.shape}, {frame.shape}, "
                             f"{corner.shape}, {coef.shape}")
        for name, v in (("link", link), ("frame", frame), ("corner_px", corner)):
            if not np.issubdtype(v.dtype, np.integer):
                raise ValueError(f"SharedNoise.{name} must be integers")
        if e and (link.min() < 0 or frame.min() < 0):
            raise ValueError("SharedNoise.link and frame must be >= 0")
        if not np.all(np.isfinite(coef)):
            raise ValueError("SharedNoise.coef_px must be finite")
        if not (int(self.block_px) >= 1 and 1 <= int(self.cell_px) <= int(self.block_px)):
            raise ValueError(f"block_px must be >= 1 and cell_px in [1, block_px], got "
                             f"{self.block_px}, {self.cell_px}")
        for name, val in (("link", link.astype(np.int64)), ("frame", frame.astype(np.int64)),
                          ("corner_px", corner.astype(np.int64)), ("coef_px", coef),
                          ("block_px", int(self.block_px)), ("cell_px", int(self.cell_px))):
            object.__setattr__(self, name, val)

    @classmethod
    def from_blocks(cls, a: ArrayLike, b: ArrayLike, ref_corner_px: ArrayLike,
                    cur_corner_px: ArrayLike, share_px: ArrayLike, block_px: int,
                    cell_px: int = 1) -> SharedNoise:
        """Links made of blocks, each block's noise half its reference frame's noise over
        its reference region and half its current frame's over its current region (the
        analytic plant's split; the rendered tracker's pairs from one reference region
        correlate by 0.40-0.53).

        Parameters
        ----------
        a, b : array_like of int, (n,)
            Each link's reference and current frame.
        ref_corner_px, cur_corner_px : array_like of int, (n, B, 2)
            Each block's top-left corner in the reference and the current frame, px.
        share_px : array_like, (n, B, 2)
            Each block's noise in its link per axis, px (its weight in the link times its
            error; 0 for a block not used): the link's variance is their sum of squares
            when its blocks do not overlap.
        block_px, cell_px : int
            As the class.

        Returns
        -------
        SharedNoise
            Two entries per used block: -share / sqrt(2) in frame a, +share / sqrt(2) in b.
        """
        ref_c = np.asarray(ref_corner_px)
        share = np.broadcast_to(np.asarray(share_px, dtype=np.float64), ref_c.shape)
        li, bi = np.nonzero(np.any(share != 0, axis=2))
        a = np.asarray(a)[li]
        b = np.asarray(b)[li]
        ref = ref_c[li, bi]
        cur = np.asarray(cur_corner_px)[li, bi]
        c = share[li, bi] / np.sqrt(2.0)
        return cls(np.concatenate([li, li]), np.concatenate([a, b]),
                   np.concatenate([ref, cur]).astype(np.int64), np.concatenate([-c, c]),
                   block_px, cell_px)

    def covariance(self, keep: np.ndarray) -> list[sparse.csr_matrix]:
        """The shared covariance per axis (row, col) of the links ``keep`` (m,) (indices, in
        that order): two (m, m) sparse matrices, px^2.

        Every pair of entries in one frame is formed batched, one offset of the entries
        sorted by frame at a time (as many offsets as the most entries one frame holds)."""
        keep = np.asarray(keep, dtype=np.int64)
        pos = np.full(max(int(self.link.max(initial=-1)), int(keep.max(initial=-1))) + 1, -1)
        pos[keep] = np.arange(keep.size)
        sel = np.flatnonzero(pos[self.link] >= 0) if self.link.size else np.zeros(0, int)
        order = sel[np.argsort(self.frame[sel], kind="stable")]
        f = self.frame[order]
        li = pos[self.link[order]]
        w = self.block_px // self.cell_px
        cell = np.rint(self.corner_px[order] / self.cell_px).astype(np.int64)
        coef = self.coef_px[order]
        rows, cols, vals = [], [], []
        for o in range(order.size):
            p = np.arange(order.size - o)
            q = p + o
            same = f[p] == f[q]
            if not same.any():
                break
            p, q = p[same], q[same]
            ov = np.prod(np.clip(w - np.abs(cell[p] - cell[q]), 0, None), axis=1) / w**2
            v = coef[p] * coef[q] * ov[:, None]
            rows += [li[p]] + ([li[q]] if o else [])
            cols += [li[q]] + ([li[p]] if o else [])
            vals += [v] + ([v] if o else [])
        r = np.concatenate(rows) if rows else np.zeros(0, int)
        c = np.concatenate(cols) if cols else np.zeros(0, int)
        v = np.concatenate(vals) if vals else np.zeros((0, 2))
        return [sparse.csr_matrix((v[:, ax], (r, c)), shape=(keep.size, keep.size))
                for ax in range(2)]


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields, not objects
class Links:
    """A network of pair measurements of the image motion.

    Parameters
    ----------
    a, b : array_like of int, (n,)
        Reference and current frame of each link, ``0 <= a < b``.
    d_px : array_like, (n, 2) or (n, 2, m)
        Measured displacement ``s(t_b) - s(t_a)`` (row, col) px; a trailing axis holds m
        realisations solved with one factorisation (Monte Carlo). Anything where invalid.
    sigma_px : array_like, (n, 2)
        Each link's predicted independent error, px (> 0 where valid).
    valid : array_like of bool, (n,), optional
        Links to use (default all).
    t_s : array_like, (N,), optional
        Frame times, s, strictly increasing (needed by the smoother, the gyro and time
        metrics; frame index otherwise).
    frame_sigma_px : array_like, broadcast to (N, 2), optional
        Per-frame noise entering every link of that frame, px.
    shared : SharedNoise, optional
        Noise the links share through the pixels of their frames (each frame's noise over
        each region it is measured on); ``sigma_px`` is then each link's part of its own
        (0 where the shared part is all of it).
    """

    a: np.ndarray
    b: np.ndarray
    d_px: np.ndarray
    sigma_px: np.ndarray
    valid: np.ndarray | None = None
    t_s: np.ndarray | None = None
    frame_sigma_px: np.ndarray | None = None
    shared: SharedNoise | None = None

    def __post_init__(self) -> None:
        a = np.asarray(self.a)
        b = np.asarray(self.b)
        if a.ndim != 1 or a.size == 0 or b.shape != a.shape:
            raise ValueError(f"a and b must be non-empty 1-D arrays of the same length, got "
                             f"{a.shape} and {b.shape}")
        if not (np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype, np.integer)):
            raise ValueError("a and b must be integer frame indices")
        if np.any(a < 0) or np.any(b <= a):
            raise ValueError("every link needs 0 <= a < b (a the reference, b the current "
                             "frame): swap a pair and negate its d_px")
        n = a.size
        d = np.asarray(self.d_px, dtype=np.float64)
        if d.shape[:2] != (n, 2) or d.ndim not in (2, 3):
            raise ValueError(f"d_px must have shape ({n}, 2) or ({n}, 2, m), got {d.shape}")
        s = np.asarray(self.sigma_px, dtype=np.float64)
        if s.shape != (n, 2):
            raise ValueError(f"sigma_px must have shape ({n}, 2), got {s.shape}")
        v = np.ones(n, bool) if self.valid is None else np.asarray(self.valid, dtype=bool)
        if v.shape != (n,):
            raise ValueError(f"valid must have shape ({n},), got {v.shape}")
        if not np.all(np.isfinite(d[v])):
            raise ValueError("d_px must be finite where valid: mark the bad links invalid")
        if self.shared is None and not np.all(np.isfinite(s[v]) & (s[v] > 0)):
            raise ValueError("sigma_px must be finite and > 0 where valid")
        if self.shared is not None:
            if not np.all(np.isfinite(s[v]) & (s[v] >= 0)):
                raise ValueError("sigma_px must be finite and >= 0 where valid")
            if self.shared.link.size and (self.shared.link.max() >= n
                                          or self.shared.frame.max() > b.max()):
                raise ValueError(f"shared noise names links beyond the {n} links or frames "
                                 f"beyond the last ({b.max()})")
        t = None
        if self.t_s is not None:
            t = np.asarray(self.t_s, dtype=np.float64)
            if (t.ndim != 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0)
                    or t.size <= b.max()):
                raise ValueError(f"t_s must be finite, strictly increasing and hold every "
                                 f"frame (> {b.max()} times), got shape {t.shape}")
        f = None
        if self.frame_sigma_px is not None:
            f = np.asarray(self.frame_sigma_px, dtype=np.float64)
            if not np.all(np.isfinite(f) & (f >= 0)):
                raise ValueError("frame_sigma_px must be finite and >= 0 px")
        for name, val in (("a", a.astype(np.int64)), ("b", b.astype(np.int64)), ("d_px", d),
                          ("sigma_px", s), ("valid", v), ("t_s", t), ("frame_sigma_px", f)):
            object.__setattr__(self, name, val)

    @classmethod
    def chain(cls, d_px: ArrayLike, sigma_px: ArrayLike, *, valid: ArrayLike | None = None,
              t_s: ArrayLike | None = None,
              frame_sigma_px: ArrayLike | None = None) -> Links:
        """Today's chain: link k between frames k and k + 1 (``d_px`` (N - 1, 2) px)."""
        n = np.shape(d_px)[0]
        return cls(np.arange(n), np.arange(1, n + 1), d_px, sigma_px, valid, t_s,
                   frame_sigma_px)

    @classmethod
    def baselines(cls, s_px: ArrayLike, k_max: int,
                  sigma_px: ArrayLike | Callable[[int], ArrayLike],
                  rng: np.random.Generator | None = None, *, t_s: ArrayLike | None = None,
                  frame_sigma_px: ArrayLike | None = None) -> Links:
        """Every link of baseline 1..``k_max`` frames over a motion ``s_px`` (N, 2) px.

        ``sigma_px``: a callable of the baseline k returning the link's sigma (px, scalar or
        (2,) per axis), or a scalar, (k_max,) or (k_max, 2) array. With ``rng`` (a named
        stream), the links' independent errors N(0, sigma^2) and, with ``frame_sigma_px``,
        each frame's noise (entering all its links) are drawn; without it the links are
        exact (for predictions). For synthetic networks (tests, trade studies).
        """
        s = np.asarray(s_px, dtype=np.float64)
        if s.ndim != 2 or s.shape[1] != 2 or s.shape[0] < 2:
            raise ValueError(f"s_px must have shape (N >= 2, 2), got {s.shape}")
        if not (isinstance(k_max, int | np.integer) and 1 <= k_max < s.shape[0]):
            raise ValueError(f"k_max must be an int in [1, {s.shape[0] - 1}], got {k_max}")
        n = s.shape[0]
        ks = np.arange(1, k_max + 1)
        if callable(sigma_px):
            sig = np.array([np.broadcast_to(sigma_px(int(k)), (2,)) for k in ks], float)
        else:
            sig = np.asarray(sigma_px, dtype=np.float64)
            sig = sig.reshape(-1, 1) if sig.ndim < 2 else sig
            if sig.ndim > 2 or sig.shape[0] not in (1, k_max) or sig.shape[-1] not in (1, 2):
                raise ValueError(f"sigma_px must be a scalar, ({k_max},) or ({k_max}, 2) px, "
                                 f"or a callable of the baseline, got shape {np.shape(sigma_px)}")
            sig = np.broadcast_to(sig, (k_max, 2))
        kk = np.concatenate([np.full(n - k, k) for k in ks])
        a = np.concatenate([np.arange(n - k) for k in ks])
        b = a + kk
        sg = sig[kk - 1]
        d = s[b] - s[a]
        if rng is not None:
            d = d + sg * rng.normal(0.0, 1.0, sg.shape)
            if frame_sigma_px is not None:
                nu = _frame_array(frame_sigma_px, n, "frame_sigma_px") \
                    * rng.normal(0.0, 1.0, (n, 2))
                d = d + nu[b] - nu[a]
        return cls(a, b, d, sg, None, t_s, frame_sigma_px)


def with_independent_fraction(links: Links, fraction: ArrayLike) -> Links:
    """The same links with a fraction f (scalar or (2,) per axis) of each link's variance
    taken as its own and the rest shared through its frames' pixels: the links' covariance
    ``(1 - f) R + f diag(R)`` (R their covariance with their :class:`SharedNoise`); each
    link's variance is unchanged. See :func:`estimate_independent_fraction`."""
    f = np.broadcast_to(np.asarray(fraction, dtype=np.float64), (2,))
    if not np.all((f >= 0) & (f <= 1)):
        raise ValueError(f"fraction must be in [0, 1] per axis, got {f}")
    if links.shared is None:
        raise ValueError("links carry no shared noise: nothing to split")
    sh = links.shared
    diag = np.zeros((links.a.size, 2))
    for ax, c in enumerate(sh.covariance(np.arange(links.a.size))):
        diag[:, ax] = c.diagonal()
    sigma = np.sqrt(links.sigma_px**2 + f * diag)
    shared = SharedNoise(sh.link, sh.frame, sh.corner_px, sh.coef_px * np.sqrt(1.0 - f),
                         sh.block_px, sh.cell_px)
    return Links(links.a, links.b, links.d_px, sigma, links.valid, links.t_s,
                 links.frame_sigma_px, shared)


@dataclass(frozen=True)
class Prior:
    """The smoother's prior: p-th differences of s are N(0, c_k q) (see the module
    docstring). ``order``: 1 (random walk) or 2 (integrated random walk); ``q_px2`` (2,)
    per axis, px^2/s (order 1) or px^2/s^3 (order 2)."""

    order: int
    q_px2: tuple[float, float]

    def __post_init__(self) -> None:
        if self.order not in (1, 2):
            raise ValueError(f"order must be 1 (random walk) or 2 (integrated random walk), "
                             f"got {self.order}")
        q = tuple(float(x) for x in self.q_px2)
        if len(q) != 2 or not all(np.isfinite(x) and x > 0 for x in q):
            raise ValueError(f"q_px2 must be two finite values > 0 (row, col), got {q}")
        object.__setattr__(self, "q_px2", q)


@dataclass(frozen=True, eq=False)  # holds arrays
class NetworkSolution:
    """The solved motion series.

    ``s_px`` (N, 2) or (N, 2, m) px; ``cov_px2`` (2, N, N) its error covariance per axis
    (row, col), px^2; ``t_s`` (N,) the frame times (s, or frame index when the links had
    none); ``gauge``; ``prior`` (the smoother's, None unsmoothed); ``bias_px_s`` (2,) the
    gyro's estimated rate bias and ``bias_sigma_px_s`` (2,) its sigma (None without a gyro).
    """

    s_px: np.ndarray
    cov_px2: np.ndarray
    t_s: np.ndarray
    gauge: str
    prior: Prior | None = None
    bias_px_s: np.ndarray | None = None
    bias_sigma_px_s: np.ndarray | None = None

    @property
    def sigma_px(self) -> np.ndarray:
        """Predicted error of each sample (N, 2) px: the covariance's diagonal, rooted."""
        return np.sqrt(np.clip(np.diagonal(self.cov_px2, axis1=1, axis2=2).T, 0.0, None))

    def difference_sigma_px(self, i: ArrayLike, j: ArrayLike) -> np.ndarray:
        """Predicted error of ``s_j - s_i`` per axis, (..., 2) px (i, j frame indices,
        broadcast)."""
        i = np.asarray(i)
        j = np.asarray(j)
        c = self.cov_px2
        v = c[:, i, i] + c[:, j, j] - 2.0 * c[:, i, j]
        return np.sqrt(np.clip(np.moveaxis(v, 0, -1), 0.0, None))


    def at(self, t_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """The series and its predicted error at any times, e.g. each line's integration
        mid-time.

        Parameters
        ----------
        t_s : array_like, (q,)
            Times, s (frame index when the links had no times); held at the end values
            outside the frames' span.

        Returns
        -------
        s_px : numpy.ndarray, (q, 2[, m])
            Linearly interpolated between frames, px.
        sigma_px : numpy.ndarray, (q, 2)
            Its predicted error, the covariance carried through the same weights, px.

        References
        ----------
        ground/record.py (the line model these feed).
        """
        lo, w = self._bracket(t_s)
        s = (1 - w)[(...,) + (None,) * (self.s_px.ndim - 1)] * self.s_px[lo] \
            + w[(...,) + (None,) * (self.s_px.ndim - 1)] * self.s_px[lo + 1]
        c = self.cov_px2
        var = ((1 - w) ** 2 * c[:, lo, lo] + w**2 * c[:, lo + 1, lo + 1]
               + 2 * w * (1 - w) * c[:, lo, lo + 1])
        return s, np.sqrt(np.clip(var.T, 0.0, None))

    def _bracket(self, t_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(the frame before each time, the weight of the frame after) of the linear
        interpolation between frames, times held at the end values outside their span."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise ValueError(f"t_s must be a finite 1-D array of times (s), got {t.shape}")
        tf = self.t_s
        tc = np.clip(t, tf[0], tf[-1])
        lo = np.clip(np.searchsorted(tf, tc, side="right") - 1, 0, tf.size - 2)
        return lo, (tc - tf[lo]) / (tf[lo + 1] - tf[lo])

    def covariance_at(self, t_s: ArrayLike) -> np.ndarray:
        """The error covariance (2, q, q) px^2 of the series at times t_s (q,), s, carried
        through the same linear interpolation as :meth:`at` (dense: 16 q^2 bytes)."""
        lo, w = self._bracket(t_s)
        q = np.arange(lo.size)
        weights = np.zeros((lo.size, self.t_s.size))
        weights[q, lo] = 1.0 - w
        weights[q, lo + 1] += w
        return weights @ self.cov_px2 @ weights.T

    def to_record(self) -> MotionRecord:
        """The solution as a :class:`ground.record.MotionRecord` (all frames valid, its
        predicted sigma), for :func:`ground.record.line_motion` (first realisation when
        batched)."""
        s = self.s_px if self.s_px.ndim == 2 else self.s_px[..., 0]
        return MotionRecord(self.t_s, s, np.ones(self.t_s.size, bool),
                            np.maximum(self.sigma_px, SIGMA_FLOOR_PX))


def _difference_operator(n: int, order: int) -> sparse.csr_matrix:
    d = sparse.eye(n, format="csr")
    for _ in range(order):
        d = (d[1:] - d[:-1]).tocsr()
    return d


def _prior_scale(t: np.ndarray, order: int) -> np.ndarray:
    """c_k: the variance of each p-th difference per unit q."""
    h = np.diff(t)
    if order == 1:
        return h
    return (2.0 / 3.0) * (0.5 * (h[1:] + h[:-1])) ** 3


def _assemble(links: Links, n: int, gyro: GyroAiding | None, absolute: Absolute | None,
              prior: Prior | None, t: np.ndarray):
    """Rows of the design: (A csr (rows, unknowns), y (rows, 2[, m]), sigma (rows, 2),
    the s-columns' ground flags per row for the connectivity check, offsets)."""
    rows, cols, vals = [], [], []
    ys, sigs = [], []
    batch = links.d_px.shape[2:]
    r0 = 0
    n_unk = n
    fs = None
    if links.frame_sigma_px is not None:
        fs = _frame_array(links.frame_sigma_px, n, "frame_sigma_px")
        off_cam = n_unk
        n_unk += n
    v = links.valid
    a, b = links.a[v], links.b[v]
    m = a.size
    ri = r0 + np.arange(m)
    rows += [ri, ri]
    cols += [b, a]
    vals += [np.ones(m), -np.ones(m)]
    if fs is not None:
        rows += [ri, ri]
        cols += [off_cam + b, off_cam + a]
        vals += [np.ones(m), -np.ones(m)]
    ys.append(links.d_px[v])
    sigs.append(links.sigma_px[v])
    r0 += m
    absolute_rows = np.zeros(0, bool)
    if fs is not None:  # nu_k = 0 +- sigma_f
        ri = r0 + np.arange(n)
        rows.append(ri)
        cols.append(off_cam + np.arange(n))
        vals.append(np.ones(n))
        ys.append(np.zeros((n, 2) + batch))
        sigs.append(fs)
        r0 += n
    bias_col = None
    if gyro is not None:
        if gyro.t_s.size != n:
            raise ValueError(f"gyro has {gyro.t_s.size} frame times, the network {n} frames: "
                             "build it with gyro_aiding(..., t_frame_s=the frames' times)")
        off_g = n_unk
        bias_col = off_g + n
        n_unk += n + 1
        k = np.arange(n - 1)
        ri = r0 + k
        dt = np.diff(gyro.t_s)
        rows += [ri, ri, ri, ri, ri]
        cols += [k + 1, k, off_g + k + 1, off_g + k, np.full(n - 1, bias_col)]
        vals += [np.ones(n - 1), -np.ones(n - 1), np.ones(n - 1), -np.ones(n - 1), dt]
        inc = np.diff(gyro.angle_px, axis=0)
        ys.append(np.broadcast_to(inc.reshape(inc.shape + (1,) * len(batch)),
                                  inc.shape + batch))
        sigs.append(np.repeat(gyro.step_sigma_px[:, None], 2, axis=1))
        r0 += n - 1
        ri = r0 + np.arange(n + 1)
        rows.append(ri)
        cols.append(off_g + np.arange(n + 1))
        vals.append(np.ones(n + 1))
        ys.append(np.zeros((n + 1, 2) + batch))
        sigs.append(np.concatenate([np.repeat(gyro.frame_sigma_px[:, None], 2, axis=1),
                                    np.full((1, 2), gyro.bias_sigma_px_s)]))
        r0 += n + 1
    if absolute is not None:
        f = absolute.frame
        if f.max() > n - 1:
            raise ValueError(f"absolute fixes reach frame {f.max():.3f}, beyond the network's "
                             f"last frame {n - 1}")
        lo = np.minimum(np.floor(f).astype(np.int64), n - 2)
        w = f - lo
        mm = f.size
        ri = r0 + np.arange(mm)
        rows += [ri, ri]
        cols += [lo, lo + 1]
        vals += [1.0 - w, w]
        sa = absolute.s_px
        ys.append(np.broadcast_to(sa.reshape(sa.shape + (1,) * len(batch)), sa.shape + batch))
        sigs.append(absolute.sigma_px)
        absolute_rows = np.zeros(r0 + mm, bool)
        absolute_rows[r0:] = True
        r0 += mm
    if prior is not None:
        dop = _difference_operator(n, prior.order).tocoo()
        c = _prior_scale(t, prior.order)
        rows.append(r0 + dop.row)
        cols.append(dop.col)
        vals.append(dop.data)
        ys.append(np.zeros((dop.shape[0], 2) + batch))
        sigs.append(np.sqrt(c[:, None] * np.asarray(prior.q_px2)[None, :]))
        r0 += dop.shape[0]
    a_mat = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                      np.concatenate(cols))),
                              shape=(r0, n_unk))
    a_mat.eliminate_zeros()
    absolute_rows = np.concatenate([absolute_rows, np.zeros(r0 - absolute_rows.size, bool)])
    return a_mat, np.concatenate(ys), np.concatenate(sigs), absolute_rows, bias_col


def _check_connected(a_mat: sparse.csr_matrix, n: int, absolute_rows: np.ndarray,
                     gauge: str) -> None:
    """Every frame must be tied to the datum (frame 0 or an absolute fix) through rows."""
    s_part = a_mat[:, :n].tocoo()
    order = np.lexsort((s_part.col, s_part.row))
    r, c = s_part.row[order], s_part.col[order]
    same = r[1:] == r[:-1]
    rows, first = np.unique(r, return_index=True)  # each row's first s column
    tied = absolute_rows[rows]
    ground = n
    src = [c[:-1][same], c[first][tied], np.zeros(int(gauge != "none"), np.int64)]
    dst = [c[1:][same], np.full(int(tied.sum()), ground), np.full(int(gauge != "none"), ground)]
    src, dst = np.concatenate(src), np.concatenate(dst)
    g = sparse.coo_matrix((np.ones(src.size), (src, dst)), shape=(n + 1, n + 1))
    _, lab = csgraph.connected_components(g, directed=False)
    loose = np.flatnonzero(lab[:n] != lab[ground])
    if loose.size:
        raise ValueError(f"frames {loose[:8].tolist()}{' ...' if loose.size > 8 else ''} "
                         f"({loose.size} in all) are tied to no datum by any valid link or "
                         "aiding: add a baseline across the gap, aiding, a smoothing prior, or "
                         "solve the pieces separately")


def _normal_solver(a_mat: sparse.csc_matrix, sigma: np.ndarray):
    """Weighted least squares with independent rows of errors ``sigma`` (rows,): the normal
    equations factorised once. Returns (estimate: y (rows, m) -> x (unknowns, m),
    covariance: columns (c,) -> those columns (unknowns, c) of the estimate's covariance)."""
    w = 1.0 / np.maximum(sigma, SIGMA_FLOOR_PX) ** 2
    lu = spla.splu((a_mat.T @ sparse.diags(w) @ a_mat).tocsc())

    def estimate(y: np.ndarray) -> np.ndarray:
        return lu.solve(np.asarray(a_mat.T @ (w[:, None] * y)))

    def covariance(cols: np.ndarray) -> np.ndarray:
        e = np.zeros((a_mat.shape[1], cols.size))
        e[cols, np.arange(cols.size)] = 1.0
        return lu.solve(e)

    return estimate, covariance


def _kkt_system(a_mat: sparse.csc_matrix, sigma: np.ndarray, shared: sparse.csr_matrix,
                independent: float = 0.0):
    """The scaled saddle-point matrix (csc) of :func:`_kkt_solver`, the rows' scale d (rows,)
    and the unknowns' col (unknowns,); ``independent``: the fraction f of each shared link's
    variance taken as its own, ``R_f = (1 - f) R + f diag(R)`` on the links' rows (the
    diagonal, hence both scales, does not change with f)."""
    n_rows = a_mat.shape[0]
    m = shared.shape[0]
    var = np.maximum(sigma, SIGMA_FLOOR_PX) ** 2
    r = sparse.diags(var) + sparse.block_diag([shared, sparse.csr_matrix(
        (n_rows - m, n_rows - m))])
    if independent:
        diag = r.diagonal()
        r = (1.0 - independent) * r + independent * sparse.diags(diag)
    d = 1.0 / np.sqrt(r.diagonal())
    a_s = sparse.diags(d) @ a_mat
    col = 1.0 / np.sqrt(np.asarray(a_s.multiply(a_s).sum(axis=0))).ravel()
    a_s = a_s @ sparse.diags(col)
    kkt = sparse.bmat([[sparse.diags(d) @ r @ sparse.diags(d), a_s], [a_s.T, None]],
                      format="csc")
    return kkt, d, col


def _kkt_solver(a_mat: sparse.csc_matrix, sigma: np.ndarray, shared: sparse.csr_matrix):
    """Generalised least squares with the rows' covariance ``R = diag(sigma^2) + shared``
    (``shared`` (m, m) on the first m rows: the links'), sparse, through the saddle-point
    system ``[[R, A], [A^T, 0]] [lambda; x] = [y; 0]``: x = (A^T R^-1 A)^-1 A^T R^-1 y, and
    the lower-right block of its inverse is -(A^T R^-1 A)^-1, the estimate's covariance.
    R need not be invertible row by row (a link all of whose noise is shared has sigma 0);
    rows and unknowns are scaled to unit size first (R to a correlation matrix, A's columns
    to unit norm). Same returns as :func:`_normal_solver`."""
    n_rows, n_unk = a_mat.shape
    kkt, d, col = _kkt_system(a_mat, sigma, shared)
    lu = spla.splu(kkt)

    def estimate(y: np.ndarray) -> np.ndarray:
        rhs = np.zeros((n_rows + n_unk, y.shape[1]))
        rhs[:n_rows] = d[:, None] * y
        return col[:, None] * lu.solve(rhs)[n_rows:]

    def covariance(cols: np.ndarray) -> np.ndarray:
        e = np.zeros((n_rows + n_unk, cols.size))
        e[n_rows + cols, np.arange(cols.size)] = col[cols]
        return -col[:, None] * lu.solve(e)[n_rows:]

    return estimate, covariance


def _solve(links: Links, n_frames: int, *, gauge: str | None, gyro: GyroAiding | None,
           absolute: Absolute | None, prior: Prior | None) -> NetworkSolution:
    if not (isinstance(n_frames, int | np.integer) and n_frames >= 2):
        raise ValueError(f"n_frames must be an int >= 2, got {n_frames!r}")
    n = int(n_frames)
    if links.b.max() >= n:
        raise ValueError(f"links reach frame {links.b.max()}, beyond n_frames - 1 = {n - 1}: "
                         "raise n_frames or drop those links")
    if gauge is None:
        gauge = "none" if absolute is not None else "first"
    if gauge not in GAUGES:
        raise ValueError(f"gauge must be one of {GAUGES}, got {gauge!r}")
    if absolute is not None and gauge != "none":
        raise ValueError(f"gauge={gauge!r} conflicts with absolute fixes (they set the datum): "
                         "use gauge='none'")
    if absolute is None and gauge == "none":
        raise ValueError("gauge='none' needs absolute fixes (ground control, a star "
                         "tracker): without them use 'first' or 'mean'")
    if links.t_s is not None:
        t = links.t_s[:n]
        if links.t_s.size != n:
            raise ValueError(f"links.t_s holds {links.t_s.size} times for {n} frames")
    elif gyro is not None:
        t = gyro.t_s
    else:
        t = np.arange(n, dtype=np.float64)
    if gyro is not None and links.t_s is not None and not np.allclose(gyro.t_s, t,
                                                                        rtol=0, atol=1e-9):
        raise ValueError("gyro.t_s must be the links' frame times t_s")
    a_mat, y, sig, absolute_rows, bias_col = _assemble(links, n, gyro, absolute, prior, t)
    _check_connected(a_mat, n, absolute_rows, gauge)
    keep = np.arange(a_mat.shape[1])
    if gauge in ("first", "mean"):
        keep = keep[1:]
    a_k = a_mat[:, keep].tocsc()
    s_cols = np.flatnonzero(keep < n)  # positions of the s unknowns in the kept system
    s_frames = keep[s_cols]
    batch = y.shape[2:]
    s_out = np.zeros((n, 2) + batch)
    cov = np.zeros((2, n, n))
    bias = np.zeros(2) if bias_col is not None else None
    bias_sig = np.zeros(2) if bias_col is not None else None
    shared = None
    if links.shared is not None:
        shared = links.shared.covariance(np.flatnonzero(links.valid))
    for ax in range(2):
        if shared is None:
            estimate, covariance = _normal_solver(a_k, sig[:, ax])
        else:
            estimate, covariance = _kkt_solver(a_k, sig[:, ax], shared[ax])
        x = estimate(y[:, ax].reshape(y.shape[0], -1))
        s_out[s_frames, ax] = x[s_cols].reshape((s_cols.size,) + batch)
        for j0 in range(0, s_cols.size, _BLOCK):
            blk = s_cols[j0:j0 + _BLOCK]
            cov[ax][np.ix_(s_frames, s_frames[j0:j0 + _BLOCK])] = covariance(blk)[s_cols]
        if bias_col is not None:
            jb = int(np.flatnonzero(keep == bias_col)[0])
            bias[ax] = x[jb, 0]
            bias_sig[ax] = np.sqrt(covariance(np.array([jb]))[jb, 0])
    if gauge == "mean":
        s_out -= s_out.mean(axis=0, keepdims=True)
        cov = (cov - cov.mean(axis=1, keepdims=True) - cov.mean(axis=2, keepdims=True)
               + cov.mean(axis=(1, 2), keepdims=True))
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    return NetworkSolution(s_out, cov, t, gauge, prior, bias, bias_sig)


def solve_network(links: Links, n_frames: int, *, gauge: str | None = None,
                  gyro: GyroAiding | None = None,
                  absolute: Absolute | None = None) -> NetworkSolution:
    """The image-motion series at every frame from a network of links, by sparse weighted
    least squares, with its covariance; aiding fused in the same solve.

    Parameters
    ----------
    links : Links
        The pair measurements (px), with per-link sigmas and optional per-frame noise.
    n_frames : int
        N, the number of frames (unknowns per axis).
    gauge : {"first", "mean", "none"}, optional
        The datum (module docstring). Default: "none" with absolute fixes, else "first".
    gyro : GyroAiding, optional
        A gyro's increments between the frames (ground/aiding.py).
    absolute : Absolute, optional
        Ground control points or star-tracker fixes (px, with accuracies).

    Returns
    -------
    NetworkSolution
        s (N, 2[, m]) px and its covariance (2, N, N) px^2.

    References
    ----------
    Sheikh, Zhai & Shah, ACCV 2004; MintPy ``ifgram_inversion``.
    """
    return _solve(links, n_frames, gauge=gauge, gyro=gyro, absolute=absolute, prior=None)


def estimate_independent_fraction(links: Links, n_frames: int) -> np.ndarray:
    """How much of each link's error is its own rather than its frames' pixels', per axis,
    estimated from the record itself: the fraction f (2,) of the links' variance in
    ``R_f = c ((1 - f) R + f diag(R))`` (R the links' covariance with their
    :class:`SharedNoise`, c a free scale) that maximises the restricted (REML) likelihood of
    the network's redundant links, ``-1/2 (log|R_f| + log|A^T R_f^-1 A| + r^T R_f^-1 r)``
    with c profiled out. One sparse LU of the saddle-point system per evaluation gives both
    determinants at once (``|KKT| = |R_f| |A^T R_f^-1 A|``) and ``r^T R_f^-1 r = y^T lambda``;
    on a grid of f in [0, 0.95], then bounded Brent.

    Parameters
    ----------
    links : Links
        Links with their shared noise (``links.shared``), in px.
    n_frames : int
        N, the frames (unknowns per axis).

    Returns
    -------
    numpy.ndarray, (2,)
        f per axis (row, col): 0 when the shared model explains the links' consistency, up
        to 0.95.

    References
    ----------
    Patterson & Thompson, Biometrika 58(3), 1971 (restricted maximum likelihood); Harville,
    JASA 72, 1977.
    """
    from scipy.optimize import minimize_scalar

    if links.shared is None:
        raise ValueError("links carry no shared noise: nothing to split")
    if links.d_px.ndim != 2:
        raise ValueError("estimate the fraction on one realisation (d_px (n, 2))")
    n = int(n_frames)
    t = np.arange(n, dtype=np.float64)
    a_mat, y, sig, _, _ = _assemble(links, n, None, None, None, t)
    a_k = a_mat[:, 1:].tocsc()  # the gauge "first"
    dof = a_k.shape[0] - a_k.shape[1]
    if dof < 3:
        raise ValueError(f"the network has {dof} redundant links: too few to tell the links' "
                         "own error from their frames'")
    shared = links.shared.covariance(np.flatnonzero(links.valid))
    out = np.zeros(2)
    for ax in range(2):
        def crit(f: float, ax=ax) -> float:
            kkt, d, _ = _kkt_system(a_k, sig[:, ax], shared[ax], f)
            lu = spla.splu(kkt)
            rhs = np.zeros(kkt.shape[0])
            rhs[:a_k.shape[0]] = d * y[:, ax]
            q = float(rhs[:a_k.shape[0]] @ lu.solve(rhs)[:a_k.shape[0]])
            logdet = float(np.sum(np.log(np.abs(lu.U.diagonal()))))
            return logdet + dof * np.log(max(q, 1e-300))

        grid = np.linspace(0.0, 0.95, 11)
        vals = [crit(f) for f in grid]
        k = int(np.argmin(vals))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
        res = minimize_scalar(crit, bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-3})
        out[ax] = float(res.x) if res.fun < vals[k] else float(grid[k])
    return out


def estimate_prior(solution: NetworkSolution, order: int = 2) -> Prior:
    """The smoother's prior intensity per axis, estimated from an unsmoothed solution.

    Maximum marginal likelihood (type-II ML) on the solution's p-th differences
    ``y = D_p s_hat`` (module docstring): under the prior and the solve's predicted errors
    ``y ~ N(0, q diag(c) + D_p C D_p^T)``; with ``W = diag(c)^-1/2 D_p C D_p^T diag(c)^-1/2
    = U diag(lambda) U^T`` (one eigendecomposition, O(N^3)) the log-likelihood is
    ``-1/2 sum(log(q + lambda_i) + z_i^2 / (q + lambda_i))``, ``z = U^T diag(c)^-1/2 y``,
    maximised over log q on a grid and then by bounded Brent. Nothing of the scenario's
    jitter enters: only the record's solution and its own covariance.

    Parameters
    ----------
    solution : NetworkSolution
        An unsmoothed solution (its s (N, 2) px and covariance px^2; the first realisation
        when batched).
    order : int
        1 (random walk, q in px^2/s) or 2 (integrated random walk, q in px^2/s^3).

    Returns
    -------
    Prior
        ``order`` and the estimated ``q_px2`` (row, col).

    References
    ----------
    Whittaker, Proc. Edinburgh Math. Soc. 41, 1923 (difference priors); Wahba, Ann. Stat.
    13(4), 1985 (choosing a smoothing spline's penalty by marginal likelihood).
    """
    from scipy.optimize import minimize_scalar

    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order}")
    n = solution.t_s.size
    if n < order + 3:
        raise ValueError(f"the smoother needs at least {order + 3} frames, got {n}")
    dop = _difference_operator(n, order)
    c = _prior_scale(solution.t_s, order)
    rc = 1.0 / np.sqrt(c)
    s = solution.s_px if solution.s_px.ndim == 2 else solution.s_px[..., 0]
    q = []
    for ax in range(2):
        y = (dop @ s[:, ax]) * rc
        dc = dop @ solution.cov_px2[ax]
        w = (dop @ dc.T) * rc[:, None] * rc[None, :]
        lam, u = np.linalg.eigh(0.5 * (w + w.T))
        lam = np.clip(lam, 0.0, None)
        z2 = (u.T @ y) ** 2

        def nll(logq: float, lam=lam, z2=z2) -> float:
            v = np.exp(logq) + lam
            return float(np.sum(np.log(v) + z2 / v))

        hi = np.log(max(float(np.mean(y**2)), SIGMA_FLOOR_PX**2) * 10.0)
        grid = np.linspace(hi - 40.0, hi, 81)
        k = int(np.argmin([nll(g) for g in grid]))
        lo_b, hi_b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
        res = minimize_scalar(nll, bounds=(lo_b, hi_b), method="bounded",
                              options={"xatol": 1e-4})
        q.append(float(np.exp(res.x)))
    return Prior(order, (q[0], q[1]))


def smooth_network(links: Links, n_frames: int, *, order: int = 2, prior: Prior | None = None,
                   gauge: str | None = None, gyro: GyroAiding | None = None,
                   absolute: Absolute | None = None) -> NetworkSolution:
    """The two-sided smoother: the network solved with a difference prior whose intensity
    is estimated from the record itself (:func:`estimate_prior` on the unsmoothed solve).

    Parameters
    ----------
    links, n_frames, gauge, gyro, absolute
        As :func:`solve_network`.
    order : int
        1 (random walk prior) or 2 (integrated random walk: a cubic smoothing spline).
    prior : Prior, optional
        A prior to use instead of estimating one (for studies; never the scenario's truth).

    Returns
    -------
    NetworkSolution
        The smoothed s (N, 2[, m]) px, its posterior covariance (2, N, N) px^2 (per-sample
        predicted error: ``sigma_px``) and the prior used.

    References
    ----------
    Rauch, Tung & Striebel, AIAA J. 3(8), 1965 (the fixed-interval smoother this least
    squares equals for a Gauss-Markov prior); Whittaker 1923.
    """
    if prior is None:
        raw = solve_network(links, n_frames, gauge=gauge, gyro=gyro, absolute=absolute)
        prior = estimate_prior(raw, order)
    return _solve(links, n_frames, gauge=gauge, gyro=gyro, absolute=absolute, prior=prior)


def trend_basis(t: np.ndarray, terms: str) -> np.ndarray:
    """Orthonormal columns (n, 1 or 2) spanning a constant (``terms`` "constant") or a
    constant and a linear trend in t (n,) ("affine"): the terms a geometry figure removes."""
    x = (t - t.mean()) / max(float(np.ptp(t)), 1e-300)
    cols = [np.ones_like(x)] if terms == "constant" else [np.ones_like(x), x]
    q, _ = np.linalg.qr(np.stack(cols, axis=1))
    return q


def geometry_rms(error_px: ArrayLike, t_s: ArrayLike | None = None,
                 cov_px2: ArrayLike | None = None) -> dict[str, np.ndarray]:
    """Geometry per axis as mission engineers state it: the RMS of an error series after
    removing a constant, and after removing an affine (bias + linear trend in time: the best
    any ground control could do), measured and predicted.

    Parameters
    ----------
    error_px : array_like, (n, 2)
        The error (estimate - truth) per sample, (row, col) px.
    t_s : array_like, (n,), optional
        Sample times, s (default: the index); the trend is linear in these.
    cov_px2 : array_like, (2, n, n) or (n, n), optional
        The error's predicted covariance per axis (or one for both), px^2.

    Returns
    -------
    dict
        ``"constant"``, ``"affine"`` (2,) px measured; with ``cov_px2`` also
        ``"predicted_constant"``, ``"predicted_affine"`` (2,) px: sqrt(trace(P C P) / n),
        P the projection removing those terms.

    References
    ----------
    ../shared/notes/product-facts.md, "Restitution" (which terms a figure has removed).
    """
    e = np.asarray(error_px, dtype=np.float64)
    if e.ndim != 2 or e.shape[1] != 2 or e.shape[0] < 3 or not np.all(np.isfinite(e)):
        raise ValueError(f"error_px must be finite with shape (n >= 3, 2), got {e.shape}")
    n = e.shape[0]
    t = np.arange(n, dtype=np.float64) if t_s is None else np.asarray(t_s, dtype=np.float64)
    if t.shape != (n,) or not np.all(np.isfinite(t)) or np.ptp(t) <= 0:
        raise ValueError(f"t_s must be finite with shape ({n},) and not constant")
    out: dict[str, np.ndarray] = {}
    c = None
    if cov_px2 is not None:
        c = np.asarray(cov_px2, dtype=np.float64)
        c = np.broadcast_to(c, (2, n, n)) if c.shape == (n, n) else c
        if c.shape != (2, n, n):
            raise ValueError(f"cov_px2 must have shape (2, {n}, {n}) or ({n}, {n}), got "
                             f"{np.shape(cov_px2)}")
    for key in ("constant", "affine"):
        q = trend_basis(t, key)
        r = e - q @ (q.T @ e)
        out[key] = np.sqrt(np.mean(r**2, axis=0))
        if c is not None:
            tr = np.trace(c, axis1=1, axis2=2) - np.einsum("ip,aij,jp->a", q, c, q)
            out[f"predicted_{key}"] = np.sqrt(np.clip(tr, 0.0, None) / n)
    return out

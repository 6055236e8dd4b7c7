"""Geometric rectification: the strip resampled onto the nominal (motion-free) grid.

The strip and its per-line offsets follow the convention shared with the strip renderer:
``strip[l, c] ~= static[l + off[l, 0], c + off[l, 1]]``, ``off`` of shape (n_lines, 2) (row,
col) px, or field-dependent (n_lines, n_cols, 2) (rotation/scale across the line). The
rectified product is ``corrected[y, x] = strip[l*, c*]`` with ``l* + off_row(l*, c*) = y`` and
``c* + off_col(l*, c*) = x``: the mapping is inverted by Newton's method on the line
coordinate (per-line offsets), or by the fixed-point iteration ``(l, c) <- (y, x) - off(l, c)``
(field-dependent offsets, a contraction while they change by less than 1 px per line or
column: the strip does not fold over), then the strip is sampled there by
``scipy.ndimage.map_coordinates`` (cubic B-spline by default). Offsets between lines are
cubic-spline interpolated. Pixels whose source falls outside the strip are flagged invalid
and filled with ``fill``.

Compare with ASP's ``jitter_solve``/``sat_sim`` and the SmartScan ground correction (Janschek,
Tchernykh, Dyblenko): the correction's error is the offset model's error.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage
from scipy.interpolate import CubicSpline

#: inversion of the mapping: stop when no source coordinate moves more than this (px)
TOL_PX = 1e-7
MAX_ITER = 200


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields, not objects
class Rectified:
    """A rectified product: ``image`` (n_lines, n_cols), ``valid`` mask (source inside the
    strip), and the source coordinates ``source_px`` (2, n_lines, n_cols) (l*, c*)."""

    image: np.ndarray
    valid: np.ndarray
    source_px: np.ndarray


def _check(strip, line_offset_px) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(strip, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] < 2 or s.shape[1] < 1:
        raise ValueError(f"strip must be 2-D (n_lines >= 2, n_cols >= 1), got shape {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ValueError("strip has non-finite pixels: fill them before rectifying")
    off = np.asarray(line_offset_px, dtype=np.float64)
    if off.shape not in ((s.shape[0], 2), (*s.shape, 2)):
        raise ValueError(f"line_offset_px must have shape ({s.shape[0]}, 2) or "
                         f"({s.shape[0]}, {s.shape[1]}, 2) for this strip, got {off.shape}")
    if not np.all(np.isfinite(off)):
        raise ValueError("line_offset_px has non-finite values: interpolate the gaps first")
    if np.any(np.diff(off[..., 0], axis=0) <= -1.0):
        raise ValueError("line_offset_px[..., 0] falls by 1 px or more between lines: the "
                         "strip folds over and has no single-valued rectification")
    if off.ndim == 3 and np.any(np.abs(np.diff(off, axis=1)) >= 1.0):
        raise ValueError("line_offset_px changes by 1 px or more between columns")
    return s, off


def source_coordinates(line_offset_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Where each nominal pixel (y, x) of a strip of ``shape`` comes from: (2, n, m) (l*, c*).

    Solves ``(l, c) + off(l, c) = (y, x)`` (Newton on l for per-line offsets, fixed-point
    iteration for field-dependent ones) with the offsets cubic-spline interpolated and held
    constant beyond the strip's ends.

    Parameters
    ----------
    line_offset_px : numpy.ndarray, (n, 2) or (n, m, 2)
        Offsets (row, col) of each line, or of each pixel, px (the module docstring's
        convention).
    shape : tuple of int
        The strip's (n_lines, n_cols), px.

    Returns
    -------
    numpy.ndarray, (2, n, m)
        Source coordinates (l*, c*) in the strip of each nominal pixel (y, x), px.

    References
    ----------
    ``scipy.interpolate.CubicSpline`` (per-line offsets); ``scipy.ndimage.spline_filter`` and
    ``scipy.ndimage.map_coordinates`` (order 3, field-dependent offsets).
    """
    n, m = shape
    off = np.asarray(line_offset_px, dtype=np.float64)
    lines = np.arange(n, dtype=np.float64)
    if off.ndim == 2:  # one offset per line: solve l + off_row(l) = y per nominal line only
        spl = CubicSpline(lines, off, axis=0)
        slope = spl.derivative()
        lsol = np.interp(lines, lines + off[:, 0], lines)  # monotone first guess
        for _ in range(MAX_ITER):  # Newton, the offsets held constant beyond the ends
            at = np.clip(lsol, 0, n - 1)
            inside = (lsol >= 0) & (lsol <= n - 1)
            step = (lsol + spl(at)[:, 0] - lines) / (1.0 + np.where(inside, slope(at)[:, 0], 0.0))
            lsol = lsol - step
            if np.max(np.abs(step)) < TOL_PX:
                break
        else:
            raise ValueError("line_offset_px: the line mapping l + off_row(l) did not invert "
                             f"to {TOL_PX} px in {MAX_ITER} steps (it is nearly folding over)")
        col_off = spl(np.clip(lsol, 0, n - 1))[:, 1]
        rows = np.broadcast_to(lsol[:, None], (n, m))
        cols = np.arange(m, dtype=np.float64)[None, :] - col_off[:, None]
        return np.stack([rows, cols])
    coef = [ndimage.spline_filter(off[..., k], order=3) for k in range(2)]
    yx = np.mgrid[0:n, 0:m].astype(np.float64)
    src = yx - np.moveaxis(off, -1, 0)
    hi = np.array([n - 1, m - 1], dtype=np.float64)[:, None, None]
    for _ in range(MAX_ITER):
        at = np.clip(src, 0, hi)
        o = np.stack([ndimage.map_coordinates(c, at, order=3, prefilter=False) for c in coef])
        new = yx - o
        done = np.max(np.abs(new - src)) < TOL_PX
        src = new
        if done:
            return src
    raise ValueError("line_offset_px: the field mapping did not invert to "
                     f"{TOL_PX} px in {MAX_ITER} steps (offsets change too fast across the field)")


def rectify(strip, line_offset_px, *, order: int = 3, fill: float = np.nan,
            edge_tol_px: float = 1e-6) -> Rectified:
    """Resample ``strip`` (n_lines, n_cols) onto the nominal grid given ``line_offset_px``
    ((n_lines, 2) or (n_lines, n_cols, 2), (row, col) px, the convention in the module
    docstring). ``order``: the B-spline order of ``map_coordinates`` (3: cubic); pixels whose
    source lies more than ``edge_tol_px`` outside the strip are invalid and set to ``fill``.

    Parameters
    ----------
    strip : array_like, (n_lines, n_cols)
        The strip as imaged, image (intensity) units, finite, n_lines >= 2.
    line_offset_px : array_like, (n_lines, 2) or (n_lines, n_cols, 2)
        Offsets (row, col), px; falling by less than 1 px between lines (and changing by less
        than 1 px between columns).
    order : int, optional
        B-spline order of the resampling, 0..5 (3: cubic).
    fill : float, optional
        Value of invalid pixels, image units.
    edge_tol_px : float, optional
        How far outside the strip a source may lie and still count as inside, px.

    Returns
    -------
    Rectified
        The image on the nominal grid (image units), its valid mask and the source
        coordinates (2, n_lines, n_cols), px.

    References
    ----------
    ``scipy.ndimage.map_coordinates`` (``mode="nearest"``), which it wraps.
    """
    s, off = _check(strip, line_offset_px)
    if order not in range(6):
        raise ValueError(f"order must be a spline order 0..5, got {order}")
    src = source_coordinates(off, s.shape)
    img = ndimage.map_coordinates(s, src, order=order, mode="nearest")
    n, m = s.shape
    valid = ((src[0] >= -edge_tol_px) & (src[0] <= n - 1 + edge_tol_px)
             & (src[1] >= -edge_tol_px) & (src[1] <= m - 1 + edge_tol_px))
    return Rectified(image=np.where(valid, img, fill), valid=valid, source_px=src)


@dataclass(frozen=True)
class GeometricError:
    """Error of an estimated offset against the true one, per axis (row, col), px: RMS (about
    zero), peak-to-peak, bias (mean) and largest absolute error, over ``n`` lines/pixels."""

    rms_px: tuple[float, float]
    peak_to_peak_px: tuple[float, float]
    bias_px: tuple[float, float]
    max_abs_px: tuple[float, float]
    n: int

    def to_dict(self) -> dict:
        return asdict(self)


def geometric_error(estimated_px, true_px, valid=None) -> GeometricError:
    """Per-line error of ``estimated_px`` against ``true_px`` (both (n_lines, 2) or
    (n_lines, n_cols, 2) px); ``valid`` (n_lines,) or (n_lines, n_cols) selects what counts.

    Parameters
    ----------
    estimated_px : array_like, (n_lines, 2) or (n_lines, n_cols, 2)
        Estimated offsets (row, col), px.
    true_px : array_like
        True offsets, px, same shape.
    valid : array_like of bool, (n_lines,) or (n_lines, n_cols), optional
        Lines (or pixels) that count (default: all).

    Returns
    -------
    GeometricError
        RMS, peak-to-peak, bias and largest absolute error per axis (row, col), px, and the
        count ``n``.

    References
    ----------
    None: plain statistics (``numpy.mean``, ``numpy.ptp``).
    """
    e = np.asarray(estimated_px, dtype=np.float64)
    t = np.asarray(true_px, dtype=np.float64)
    if e.shape != t.shape or e.ndim not in (2, 3) or e.shape[-1] != 2 or e.shape[0] == 0:
        raise ValueError(f"estimated_px and true_px must have the same shape (n_lines, 2) or "
                         f"(n_lines, n_cols, 2), got {e.shape} and {t.shape}")
    err = (e - t).reshape(-1, 2)
    keep = np.ones(len(err), bool) if valid is None else np.asarray(valid, bool).ravel()
    if keep.shape != (len(err),):
        raise ValueError(f"valid must have shape {e.shape[:-1]}, got {np.shape(valid)}")
    err = err[keep]
    if len(err) == 0 or not np.all(np.isfinite(err)):
        raise ValueError("estimated_px/true_px must be finite on a non-empty valid set")

    def pair(v):
        return (float(v[0]), float(v[1]))

    return GeometricError(rms_px=pair(np.sqrt(np.mean(err**2, axis=0))),
                          peak_to_peak_px=pair(np.ptp(err, axis=0)),
                          bias_px=pair(err.mean(axis=0)),
                          max_abs_px=pair(np.max(np.abs(err), axis=0)), n=len(err))

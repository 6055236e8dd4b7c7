"""The main imager's image as the camera forms it: a TDI strip line by line, or a frame,
by batched ray casting (:class:`scene.kernel.RayCaster`, passed in: this module does not
import Mitsuba).

For every sampling instant (:mod:`camera.linescan`) the host computes, in float64, the pose
keyframe of the true (or nominal) camera with the focal-plane position the sample looks
through folded into its offset (charge packet row, footprint offset, stage); the kernel forms
the rays of all detector columns from it. A strip is rendered in chunks of lines, so the
working memory does not grow with its length; :func:`iter_strip` yields each chunk (write
it, and resume with ``first_line``), :func:`render_strip` collects them.

"Static", "open loop" and "closed loop" strips are three calls: ``nominal=True`` without a
stage; the true pose without a stage; the true pose with the stage trajectory.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from camera.imager import FrameImager, TdiImager, synchronous_line_rate_hz
from camera.linescan import (
    HeightFn,
    StageFn,
    check_imager_camera,
    frame_offset_px,
    frame_sampling,
    line_offset_px,
    stage_at,
    tdi_sampling,
)
from camera.motion import CameraModel
from scene.pinhole import HitCounts, ray_keyframes

#: detector columns the line-of-sight truth is evaluated at (spread over the window)
OFFSET_PROBES = 5


class Caster(Protocol):
    """What the strip renderer needs of the kernel (:class:`scene.kernel.RayCaster`)."""

    batch_rays: int
    z_start_m: float

    def cast_radiance(self, keyframes: np.ndarray, qx: np.ndarray,
                      qy: np.ndarray | None = None): ...


@dataclass(frozen=True)
class StripChunk(HitCounts):
    """Lines ``first_line .. first_line + n - 1`` of a strip.

    Attributes
    ----------
    first_line : index of the chunk's first line in the strip.
    radiance : (n, C) float32, the mean over the line's samples (stages x instants) of the
        radiance (unit-irradiance sun); times the integration time it is the line's signal.
    line_offset_px : (n, 2) the true line-of-sight offset (row, col) on the nominal grid,
        averaged over the probe columns (:func:`camera.linescan.line_offset_px`).
    offset_field_px : (n, P, 2) the same at each probe column.
    rays, first_hits, hits : rays cast, hits on the first cast, hits after the re-cast.
    """

    first_line: int
    radiance: np.ndarray
    line_offset_px: np.ndarray
    offset_field_px: np.ndarray
    rays: int
    first_hits: int
    hits: int


@dataclass(frozen=True)
class StripResult(HitCounts):
    """A whole strip: radiance (L, C), line_offset_px (L, 2), offset_field_px (L, P, 2) at
    ``probe_cols`` (P,), the line rate used, and the ray counts (hit_fraction: first cast)."""

    radiance: np.ndarray
    line_offset_px: np.ndarray
    offset_field_px: np.ndarray
    probe_cols: np.ndarray
    line_rate_hz: float
    rays: int
    first_hits: int
    hits: int



def line_rate_for(camera: CameraModel, imager: TdiImager, t_s: float, height_fn: HeightFn,
                  line_rate_hz: float | None = None) -> float:
    """The line rate to clock: ``line_rate_hz``, else the imager's, else synchronous with the
    predicted (nominal) row velocity at the imager's centre at t_s, Hz; ``camera`` with the
    imager's focal plane."""
    if line_rate_hz is not None:
        if not line_rate_hz > 0:
            raise ValueError(f"line_rate_hz must be > 0, got {line_rate_hz}")
        return float(line_rate_hz)
    if imager.line_rate_hz is not None:
        return float(imager.line_rate_hz)
    cam = check_imager_camera(camera, imager)
    v = cam.velocity_field_px_s(cam.focal_plane.center_px, t_s, height_fn, nominal=True)[0]
    return synchronous_line_rate_hz(v)


def _indices(values, n_max: int, name: str = "cols") -> np.ndarray:
    """Detector rows or columns (N,) as float64, checked against the imager's n_max."""
    c = np.atleast_1d(np.asarray(values))
    if c.ndim != 1 or len(c) == 0:
        raise ValueError(f"{name} must be a non-empty 1-D array of detector {name}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name} must be finite")
    if c.min() < -0.5 or c.max() > n_max - 0.5:
        raise ValueError(f"{name} must lie on the imager's {n_max} {name}")
    return c.astype(np.float64)


def probe_columns(cols) -> np.ndarray:
    """The detector columns (P,) a strip's line-of-sight truth is evaluated at:
    :data:`OFFSET_PROBES` spread over ``cols``, float64."""
    c = np.asarray(cols, dtype=np.float64)
    return np.unique(np.round(np.linspace(c.min(), c.max(), OFFSET_PROBES), 6))


@dataclass(frozen=True)
class _StripSetup:
    """What a strip's chunks share, computed once per strip: the columns (C,), the line rate,
    the sampling, the probe columns (P,) of the truth, lines per chunk."""

    cols: np.ndarray
    line_rate_hz: float
    sampling: object
    probes: np.ndarray
    lines_per_chunk: int


def _strip_setup(caster: Caster, camera: CameraModel, imager: TdiImager, t0_s: float, cols,
                 samples_per_line: int, line_rate_hz: float | None,
                 lines_per_chunk: int | None, footprint: bool,
                 height: HeightFn) -> _StripSetup:
    fp = check_imager_camera(camera, imager).focal_plane
    cols = _indices(cols, fp.cols)
    rate = line_rate_for(camera, imager, t0_s, height, line_rate_hz)
    sampling = tdi_sampling(imager, rate, samples_per_line, footprint)
    if lines_per_chunk is None:
        lines_per_chunk = max(1, caster.batch_rays // (sampling.samples * len(cols)))
    if lines_per_chunk < 1:
        raise ValueError(f"lines_per_chunk must be >= 1, got {lines_per_chunk}")
    return _StripSetup(cols, rate, sampling, probe_columns(cols), int(lines_per_chunk))


def iter_strip(caster: Caster, camera: CameraModel, imager: TdiImager, t0_s: float,
               n_lines: int, cols, samples_per_line: int = 8,
               stage_offset_px: StageFn | None = None, nominal: bool = False,
               line_rate_hz: float | None = None, first_line: int = 0,
               lines_per_chunk: int | None = None, footprint: bool = True,
               height_fn: HeightFn | None = None) -> Iterator[StripChunk]:
    """Render a TDI strip chunk by chunk (see :func:`render_strip` for the parameters).

    ``first_line`` resumes a strip: the chunks are those of the whole strip from there on,
    identical to an uninterrupted run's (the line times are t0 + l T).
    """
    if n_lines < 1:
        raise ValueError(f"n_lines must be >= 1, got {n_lines}")
    if not 0 <= first_line < n_lines:
        raise ValueError(f"first_line must be in [0, {n_lines}), got {first_line}")
    height = height_fn or caster.terrain.height_at  # type: ignore[attr-defined]
    setup = _strip_setup(caster, camera, imager, t0_s, cols, samples_per_line, line_rate_hz,
                         lines_per_chunk, footprint, height)
    return _chunks(caster, camera, imager, setup, t0_s, n_lines, stage_offset_px, nominal,
                   first_line, height)


def _chunks(caster: Caster, cam: CameraModel, imager: TdiImager, setup: _StripSetup,
            t0_s: float, n_lines: int, stage_offset_px: StageFn | None, nominal: bool,
            first_line: int, height: HeightFn) -> Iterator[StripChunk]:
    fp = cam.focal_plane
    sampling, cols, probes = setup.sampling, setup.cols, setup.probes
    s = sampling.samples
    qx = (cols + 0.5) / fp.cols - 0.5
    # the keyframes' film row qy = 0 is the stage plane's centre row (rows - 1) / 2
    row0 = (fp.rows - 1) / 2.0
    step = setup.lines_per_chunk
    # chunk boundaries belong to the whole strip, so a resumed run casts the same batches
    start = (first_line // step) * step
    for a in range(start, n_lines, step):
        lines = np.arange(max(a, first_line), min(a + step, n_lines))
        t = sampling.times_s(t0_s, lines)  # (n, S)
        stage = stage_at(stage_offset_px, t)
        off = np.empty(t.shape + (2,))
        off[..., 0] = sampling.packet_row_px + sampling.subpixel_px[:, 0] + stage[..., 0] - row0
        off[..., 1] = sampling.subpixel_px[:, 1] + stage[..., 1]
        poses = cam.pose(t.ravel(), nominal=nominal)
        kf = ray_keyframes(poses, fp, off.reshape(-1, 2), caster.z_start_m)
        res = caster.cast_radiance(kf, qx)
        rad = res.radiance.reshape(len(lines), s, len(cols)).mean(axis=1, dtype=np.float64)
        field = line_offset_px(cam, imager, sampling, t0_s, lines, probes, height,
                               stage_offset_px, nominal)
        yield StripChunk(int(lines[0]), rad.astype(np.float32), field.mean(axis=1), field,
                         res.rays, res.first_hits, res.hits)


def render_strip(caster: Caster, camera: CameraModel, imager: TdiImager, t0_s: float,
                 n_lines: int, cols, samples_per_line: int = 8,
                 stage_offset_px: StageFn | None = None, nominal: bool = False,
                 line_rate_hz: float | None = None, lines_per_chunk: int | None = None,
                 footprint: bool = True, height_fn: HeightFn | None = None,
                 on_chunk: Callable[[StripChunk], None] | None = None) -> StripResult:
    """A TDI strip (n_lines, C) rendered line by line, and each line's true offset.

    Parameters
    ----------
    caster : the kernel (:class:`scene.kernel.RayCaster`) with the scene.
    camera : the camera model (orbit, attitude with jitter, frame) with the imager's focal
        plane (:func:`camera.linescan.imager_camera`, built once by the caller).
    imager : the TDI imager (stages, clock phases, centre offset).
    t0_s : start of line 0's integration, s since the epoch.
    n_lines : lines to render; cols : detector columns (C,) (e.g. ``np.arange(c0, c1)``).
    samples_per_line : S instants per line (stratified over the N-stage integration).
    stage_offset_px : stage trajectory s(t) -> (..., 2) px (the detectors move by +s), or None.
    nominal : render from the nominal (jitter-free) pose.
    line_rate_hz : the clocked line rate; default the imager's, else synchronous at t0.
    lines_per_chunk : lines per chunk (default: one kernel batch of rays).
    footprint : integrate the detector footprint with the samples (False: point samples).
    height_fn : the terrain height for the truth (default the caster's terrain).
    on_chunk : called with every :class:`StripChunk` as it is done.

    Returns
    -------
    StripResult with ``radiance`` (L, C) and ``line_offset_px`` (L, 2), defined by
    ``strip[l, c] ~ static[l + off[l, 0], c + off[l, 1]]``.
    """
    if n_lines < 1:
        raise ValueError(f"n_lines must be >= 1, got {n_lines}")
    height = height_fn or caster.terrain.height_at  # type: ignore[attr-defined]
    setup = _strip_setup(caster, camera, imager, t0_s, cols, samples_per_line, line_rate_hz,
                         lines_per_chunk, footprint, height)
    out = np.empty((n_lines, len(setup.cols)), np.float32)
    offs, fields = [], []
    rays = first = hits = 0
    for ch in _chunks(caster, camera, imager, setup, t0_s, n_lines, stage_offset_px, nominal,
                      0, height):
        n = len(ch.radiance)
        out[ch.first_line:ch.first_line + n] = ch.radiance
        offs.append(ch.line_offset_px)
        fields.append(ch.offset_field_px)
        rays, first, hits = rays + ch.rays, first + ch.first_hits, hits + ch.hits
        if on_chunk is not None:
            on_chunk(ch)
    return StripResult(out, np.concatenate(offs), np.concatenate(fields), setup.probes,
                       setup.line_rate_hz, rays, first, hits)


@dataclass(frozen=True)
class FrameResult(HitCounts):
    """A frame exposure: radiance (R, C) (mean over the samples), the true offset (P, 2) at
    ``probe_rc`` (P, 2), and the ray counts."""

    radiance: np.ndarray
    offset_px: np.ndarray
    probe_rc: np.ndarray
    rays: int
    first_hits: int
    hits: int



def render_frame(caster: Caster, camera: CameraModel, imager: FrameImager, t0_s: float,
                 rows, cols, samples: int = 8, stage_offset_px: StageFn | None = None,
                 nominal: bool = False, rows_per_chunk: int | None = None,
                 footprint: bool = True, height_fn: HeightFn | None = None) -> FrameResult:
    """A frame imager's exposure [t0, t0 + exposure] over a window: detector rows (R,) x
    cols (C,), sampled at ``samples`` instants (:func:`camera.linescan.frame_sampling`), each
    with its pose, stage offset and footprint offset; rendered in chunks of rows.

    ``offset_px`` is the truth :func:`camera.linescan.frame_offset_px` at the window's
    corners and centre: ``frame[p] ~ static[p + off]``.
    """
    height = height_fn or caster.terrain.height_at  # type: ignore[attr-defined]
    cam = check_imager_camera(camera, imager)
    fp = cam.focal_plane
    rows = _indices(rows, fp.rows, "rows")
    cols = _indices(cols, fp.cols)
    sampling = frame_sampling(imager, samples, footprint)
    t = t0_s + sampling.tau_s
    off = sampling.subpixel_px + stage_at(stage_offset_px, t)
    kf = ray_keyframes(cam.pose(t, nominal=nominal), fp, off, caster.z_start_m)
    if rows_per_chunk is None:
        rows_per_chunk = max(1, caster.batch_rays // (samples * len(cols)))
    out = np.empty((len(rows), len(cols)), np.float32)
    qx = (cols + 0.5) / fp.cols - 0.5
    n_rays = first = hits = 0
    for a in range(0, len(rows), rows_per_chunk):
        r = rows[a:a + rows_per_chunk]
        res = caster.cast_radiance(kf, qx, (r + 0.5) / fp.rows - 0.5)
        out[a:a + len(r)] = res.radiance.mean(axis=0, dtype=np.float64)
        n_rays, first, hits = n_rays + res.rays, first + res.first_hits, hits + res.hits
    rr = [rows.min(), rows.max(), 0.5 * (rows.min() + rows.max())]
    cc = [cols.min(), cols.max(), 0.5 * (cols.min() + cols.max())]
    probes = np.array([[rr[0], cc[0]], [rr[0], cc[1]], [rr[1], cc[0]], [rr[1], cc[1]],
                       [rr[2], cc[2]]])
    offset = frame_offset_px(camera, imager, sampling, t0_s, probes, height,
                             stage_offset_px, nominal)
    return FrameResult(out, offset, probes, n_rays, first, hits)

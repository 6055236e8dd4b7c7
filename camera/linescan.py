"""The main imager's camera and the truth of what each rendered line or frame saw. Pure
numpy, float64.

The imager's camera (:func:`imager_camera`: the camera model with the imager's focal plane) is
built once by the caller and passed in. The sampling of a line or an exposure
(:mod:`camera.sampling`, re-exported here) integrates the detector footprint with the samples
themselves rather than point samples plus a pixel MTF afterwards: the terrain texture has
detail above the imager's Nyquist frequency, which point samples alias irrecoverably; the
tracker's renders integrate the pixel the same way (the optics module leaves the footprint to
the renderer). ``footprint=False`` gives point samples (for a caller that applies the pixel
MTF itself).

Truth: :func:`line_offset_px` says, from the camera model alone, where each rendered line's
content sits on the nominal (jitter-free, stage-free) grid of the same imager;
:func:`frame_offset_px` the same for a frame exposure; :func:`pixel_ground_m` where a strip
pixel's content lies on the ground (a Level-1 product's check points and its RPC grid).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from camera.geometry import Pose, project
from camera.imager import FrameImager, TdiImager
from camera.motion import CameraModel
from camera.sampling import (  # noqa: F401  (re-exported: the line scan's sampling)
    FrameSampling,
    LineSampling,
    frame_sampling,
    subpixel_lattice,
    tdi_sampling,
)

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
StageFn = Callable[[np.ndarray], np.ndarray]


def imager_camera(camera: CameraModel, imager: TdiImager | FrameImager) -> CameraModel:
    """The camera model with the imager's own focal plane (TDI: stages x cols): built once
    (a run's ``Models.main_camera``) and passed to the functions here and in
    :mod:`scene.strip`, which check it with :func:`check_imager_camera`."""
    fp0 = camera.focal_plane
    return replace(camera, focal_plane=imager.focal_plane(fp0.focal_length_m,
                                                          fp0.pixel_pitch_m))


def check_imager_camera(camera: CameraModel, imager: TdiImager | FrameImager) -> CameraModel:
    """``camera`` if its focal plane is the imager's, else a ValueError that says how to make
    it (:func:`imager_camera`)."""
    fp = camera.focal_plane
    want = imager.focal_plane(fp.focal_length_m, fp.pixel_pitch_m)
    if (fp.rows, fp.cols) != (want.rows, want.cols) or tuple(fp.center_offset_px) != tuple(
            want.center_offset_px):
        raise ValueError(f"camera: its focal plane is {fp.rows} x {fp.cols}, the imager's "
                         f"{want.rows} x {want.cols}: pass imager_camera(camera, imager)")
    return camera


def stage_at(stage_offset_px: StageFn | None, t_s: np.ndarray) -> np.ndarray:
    """Stage offsets (..., 2) px at times t_s (...), zeros without a stage."""
    t = np.asarray(t_s, dtype=np.float64)
    if stage_offset_px is None:
        return np.zeros(t.shape + (2,))
    s = np.asarray(stage_offset_px(t), dtype=np.float64)
    if s.shape != t.shape + (2,):
        raise ValueError(f"stage_offset_px(t) must return {t.shape + (2,)}, got {s.shape}")
    return s


def line_offset_px(camera: CameraModel, imager: TdiImager, sampling: LineSampling,
                   t0_s: float, lines: np.ndarray, cols: np.ndarray, height_fn: HeightFn,
                   stage_offset_px: StageFn | None = None, nominal: bool = False,
                   iterations: int = 4) -> np.ndarray:
    """Each line's true line-of-sight offset (L, P, 2) on the nominal grid, px.

    Defined so that ``strip[l, c] ~ static[l + off[l, c, 0], c + off[l, c, 1]]``, ``static``
    the same strip with the nominal pose and no stage: for every sample of line l at
    column c the ground point X the true (or nominal) pose and the stage make it see is found
    on the static strip's grid, i.e. the fractional line lambda and column gamma whose static
    sample s sees X (the nominal projection of X at ``t0 + lambda T + tau_s`` lands on that
    sample's detector position: a Newton iteration in lambda), and ``(lambda - l,
    gamma - c)`` is averaged over the samples. From the camera model alone, never from pixels.
    Signs: a stage at +s makes the detectors look at focal-plane row rho + s, ground the
    static strip sees in line l - s (the image flows toward +row, later lines see the ground
    upstream): offset (-s_row, +s_col). A +pitch jitter moves the image toward +row, as a
    stage at -pitch would: offset +pitch_px in rows; +roll: -roll_px in columns.

    Parameters
    ----------
    camera : the true camera with the imager's focal plane (:func:`imager_camera`).
    imager, sampling : the TDI imager and its sampling (:func:`tdi_sampling`).
    t0_s : the start of line 0's integration, s.
    lines : (L,) line indices; cols : (P,) detector columns to evaluate at.
    height_fn : terrain height h(E, N), m (the renderer's DEM).
    stage_offset_px : the stage trajectory s(t) -> (..., 2) px, or None (at rest).
    nominal : the strip's own pose is the nominal one (then only the stage offsets it).
    """
    cam = check_imager_camera(camera, imager)
    fp = cam.focal_plane
    lines = np.asarray(lines, dtype=np.float64)
    cols = np.asarray(cols, dtype=np.float64)
    if lines.ndim != 1 or cols.ndim != 1:
        raise ValueError("lines and cols must be 1-D")
    t = sampling.times_s(t0_s, lines)  # (L, S)
    det = sampling.detector_rc(cols)  # (S, P, 2)
    pos = det[None] + stage_at(stage_offset_px, t)[:, :, None, :]  # (L, S, P, 2)
    poses = cam.pose(t, nominal=nominal)
    pose4 = Pose(poses.position_m[:, :, None, :], poses.enu_from_cam[:, :, None, :, :])
    x = cam.ground_points_posed(pose4, pos, height_fn)  # (L, S, P, 3)
    period, tau = sampling.line_period_s, sampling.tau_s
    lam = np.broadcast_to(lines[:, None, None], x.shape[:-1]).copy()

    def nominal_rc(lam_):
        tt = t0_s + lam_ * period + tau[None, :, None]
        return project(x, cam.pose(tt, nominal=True), fp)

    rc = nominal_rc(lam)
    slope = nominal_rc(lam + 1.0)[..., 0] - rc[..., 0]  # rows per line (~1 synchronous)
    if np.any(np.abs(slope) < 1e-3):
        raise ValueError("the nominal image does not move along rows: not a scanning view")
    target_row = det[None, :, :, 0]
    for _ in range(iterations):
        lam = lam - (rc[..., 0] - target_row) / slope
        rc = nominal_rc(lam)
    gamma = rc[..., 1] - sampling.subpixel_px[None, :, None, 1]
    off = np.stack([lam - lines[:, None, None], gamma - cols[None, None, :]], axis=-1)
    return off.mean(axis=1)


def pixel_ground_m(camera: CameraModel, imager: TdiImager, sampling: LineSampling,
                   t0_s: float, lines: np.ndarray, cols: np.ndarray, height_fn: HeightFn,
                   stage_offset_px: StageFn | None = None, nominal: bool = False
                   ) -> np.ndarray:
    """Where the content of strip pixels (line, col) lies on a surface: the mean ENU ground
    point (N, 3) m over the pixel's samples (every instant, stage and footprint offset the
    renderer casts for it), from the camera model alone.

    Parameters
    ----------
    camera : the true camera with the imager's focal plane (:func:`imager_camera`).
    imager, sampling : the TDI imager and its sampling (:func:`tdi_sampling`).
    t0_s : the start of line 0's integration, s.
    lines, cols : (N,) paired line indices and detector columns (fractional allowed: a
        point between pixels; a line between lines integrates between their times).
    height_fn : the surface h(E, N), m: the terrain (the truth), or a layer of constant
        height above the ellipsoid (a replacement sensor model's fitting grid).
    stage_offset_px : the stage trajectory, or None (at rest).
    nominal : the nominal pose (the geometry the ground knows) instead of the true one.
    """
    cam = check_imager_camera(camera, imager)
    lines = np.atleast_1d(np.asarray(lines, dtype=np.float64))
    cols = np.atleast_1d(np.asarray(cols, dtype=np.float64))
    if lines.shape != cols.shape or lines.ndim != 1:
        raise ValueError(f"lines and cols must be paired 1-D arrays, got {lines.shape} and "
                         f"{cols.shape}")
    t = sampling.times_s(t0_s, lines)  # (N, S)
    det = np.moveaxis(sampling.detector_rc(cols), 0, 1)  # (N, S, 2)
    pos = det + stage_at(stage_offset_px, t)
    x = cam.ground_points_posed(cam.pose(t, nominal=nominal), pos, height_fn)
    return x.mean(axis=1)


def frame_offset_px(camera: CameraModel, imager: FrameImager, sampling: FrameSampling,
                    t0_s: float, pixel_rc: np.ndarray, height_fn: HeightFn,
                    stage_offset_px: StageFn | None = None, nominal: bool = False
                    ) -> np.ndarray:
    """A frame exposure's true offset (P, 2) px at pixels (P, 2), on the nominal grid:
    ``frame[p] ~ static[p + off[p]]`` with ``static`` the nominal, stage-free exposure over
    the same instants (the nominal projection of each sample's true ground point minus the
    sample's detector position, averaged over the samples); ``camera`` with the imager's
    focal plane (:func:`imager_camera`)."""
    cam = check_imager_camera(camera, imager)
    fp = cam.focal_plane
    pix = np.atleast_2d(np.asarray(pixel_rc, dtype=np.float64))
    t = t0_s + sampling.tau_s  # (S,)
    det = pix[None, :, :] + sampling.subpixel_px[:, None, :]  # (S, P, 2)
    pos = det + stage_at(stage_offset_px, t)[:, None, :]
    poses = cam.pose(t, nominal=nominal)
    pose3 = Pose(poses.position_m[:, None, :], poses.enu_from_cam[:, None, :, :])
    x = cam.ground_points_posed(pose3, pos, height_fn)
    nom = cam.pose(t, nominal=True)
    rc = project(x, Pose(nom.position_m[:, None, :], nom.enu_from_cam[:, None, :, :]), fp)
    return (rc - det).mean(axis=0)

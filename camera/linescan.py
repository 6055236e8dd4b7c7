"""How the main imager samples the scene in time and on the focal plane, and the truth of
what each line saw. Pure numpy, float64.

A TDI line l (line period T = 1 / line_rate, N stages) integrates over
``[t0 + l T, t0 + (l + N) T)``; its charge packet moves toward +row with the clock
(docs/conventions.md). S instants per line, stratified over the N T: sample s at
``tau_s = (s + 1/2) N T / S`` (a stepped p-phase clock also spreads the instants over one
clock step, so the step's smear is integrated too). At tau the packet's centre is at
focal-plane row ``rho(tau) = q(tau) - 1/2 + 1/(2p)`` (``q`` the imager's charge motion; p = 0,
continuous: ``q - 1/2``): its mean over the integration is the stage plane's centre row
(N - 1) / 2 for any clock.

The detector footprint (the pixel's area) is integrated by the samples themselves: sample s
also carries a sub-pixel offset from an S-point rank-1 (Fibonacci) lattice on the pixel, the
same for every line and column. Area sampling rather than point samples plus a pixel MTF
afterwards: the terrain texture has detail above the imager's Nyquist frequency, which point
samples alias irrecoverably; the tracker's renders integrate the pixel the same way (the
optics module leaves the footprint to the renderer). ``footprint=False`` gives point samples
(for a caller that applies the pixel MTF itself).

Truth: :func:`line_offset_px` says, from the camera model alone, where each rendered line's
content sits on the nominal (jitter-free, stage-free) grid of the same imager.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from camera.geometry import FocalPlane, Pose, project
from camera.imager import FrameImager, TdiImager
from camera.motion import CameraModel

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
StageFn = Callable[[np.ndarray], np.ndarray]


def subpixel_lattice(n: int) -> np.ndarray:
    """Sub-pixel offsets (n, 2) (row, col) in px within [-1/2, 1/2) of the n samples taken at
    the time strata s = 0 .. n-1: a rank-1 (Korobov) lattice in (time, row, col) with
    generator (1, g_row, g_col), the integers nearest n / golden ratio and n / golden ratio^2
    coprime with n (distinct where n allows): each row and each column stratum holds one
    sample, and the row offset is not ordered with time, so a motion during the exposure does
    not add coherently to the footprint (with rows in time order a 0.85 px smear and the
    1 px footprint become one 1.7 px box instead of their convolution).
    """
    if n < 1:
        raise ValueError(f"subpixel_lattice needs n >= 1, got {n}")
    s = np.arange(n)
    g_row = _coprime_near(n, n / 1.6180339887498949)
    g_col = _coprime_near(n, n / 2.618033988749895, avoid=g_row)
    rows = ((s * g_row) % n + 0.5) / n - 0.5
    cols = ((s * g_col) % n + 0.5) / n - 0.5
    return np.stack([rows, cols], axis=-1)


def _coprime_near(n: int, x: float, avoid: int = 0) -> int:
    """The integer >= 1 nearest x that is coprime with n and not ``avoid`` (if any is)."""
    for g in sorted(range(1, max(n, 2)), key=lambda k: (abs(k - x), k)):
        if np.gcd(g, n) == 1 and g != avoid:
            return g
    return 1


@dataclass(frozen=True)
class LineSampling:
    """The S sampling instants of a TDI line and where the sampled charge sits.

    Attributes
    ----------
    line_period_s : T = 1 / line_rate, s.
    stages : N, the integrated rows.
    tau_s : (S,) sample instants after the line's start, s, within [0, N T).
    packet_row_px : (S,) the charge packet's centre row on the stage plane at tau_s, px.
    subpixel_px : (S, 2) detector-footprint offsets (row, col) of each sample, px.
    """

    line_period_s: float
    stages: int
    tau_s: np.ndarray
    packet_row_px: np.ndarray
    subpixel_px: np.ndarray

    @property
    def samples(self) -> int:
        return len(self.tau_s)

    @property
    def integration_s(self) -> float:
        return self.stages * self.line_period_s

    def times_s(self, t0_s: float, lines: np.ndarray) -> np.ndarray:
        """Sample instants (L, S), s, of lines (L,) of a strip whose line 0 starts at t0_s."""
        lines = np.asarray(lines, dtype=np.float64)
        return t0_s + lines[..., None] * self.line_period_s + self.tau_s

    def detector_rc(self, cols: np.ndarray) -> np.ndarray:
        """Focal-plane (row, col) (S, C, 2) each sample looks through for detector columns
        (C,), before any stage offset (charge position plus footprint offset)."""
        cols = np.asarray(cols, dtype=np.float64)
        row = np.broadcast_to((self.packet_row_px + self.subpixel_px[:, 0])[:, None],
                              (self.samples, len(cols)))
        col = cols[None, :] + self.subpixel_px[:, 1:2]
        return np.stack([row, col], axis=-1)


def tdi_sampling(imager: TdiImager, line_rate_hz: float, samples_per_line: int = 8,
                 footprint: bool = True) -> LineSampling:
    """The sampling of a TDI line (see the module docstring).

    Parameters
    ----------
    imager : the TDI imager (stages, clock_phases).
    line_rate_hz : the line rate actually clocked, Hz.
    samples_per_line : S, instants per line (>= 1).
    footprint : integrate the pixel area with the lattice offsets (False: point samples).
    """
    if not line_rate_hz > 0:
        raise ValueError(f"line_rate_hz must be > 0, got {line_rate_hz}")
    if samples_per_line < 1:
        raise ValueError(f"samples_per_line must be >= 1, got {samples_per_line}")
    period = 1.0 / line_rate_hz
    s = np.arange(samples_per_line)
    frac = (s + 0.5) / samples_per_line
    tau = frac * imager.stages * period
    p = imager.clock_phases
    if p:
        # spread the instants over one clock step too: its phase is then stratified even
        # when N p / S is an integer (every stratum midpoint on a step boundary otherwise)
        tau = tau + (frac - 0.5) * period / p
        tau = np.clip(tau, 0.0, np.nextafter(imager.stages * period, 0.0))
    rows = imager.charge_motion_px(tau, line_rate_hz)[:, 0]
    rows = rows - 0.5 + (0.5 / p if p else 0.0)
    sub = subpixel_lattice(samples_per_line) if footprint else np.zeros((samples_per_line, 2))
    return LineSampling(period, imager.stages, tau, rows, sub)


@dataclass(frozen=True)
class FrameSampling:
    """The S sampling instants of a frame exposure and their footprint offsets.

    Attributes
    ----------
    exposure_s : exposure time, s.
    tau_s : (S,) instants after the exposure's start, s (strata midpoints).
    subpixel_px : (S, 2) detector-footprint offsets (row, col), px.
    """

    exposure_s: float
    tau_s: np.ndarray
    subpixel_px: np.ndarray

    @property
    def samples(self) -> int:
        return len(self.tau_s)


def frame_sampling(imager: FrameImager, samples: int = 8,
                   footprint: bool = True) -> FrameSampling:
    """A frame exposure sampled at S stratified instants, each with a lattice footprint
    offset (point samples if not ``footprint``)."""
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    tau = (np.arange(samples) + 0.5) / samples * imager.exposure_s
    sub = subpixel_lattice(samples) if footprint else np.zeros((samples, 2))
    return FrameSampling(float(imager.exposure_s), tau, sub)


def imager_camera(camera: CameraModel, imager: TdiImager | FrameImager) -> CameraModel:
    """The camera model with the imager's own focal plane (TDI: stages x cols)."""
    fp0 = camera.focal_plane
    return replace(camera, focal_plane=imager.focal_plane(fp0.focal_length_m,
                                                          fp0.pixel_pitch_m))


def ground_points(poses: Pose, focal_plane: FocalPlane, pixel_rc: np.ndarray,
                  height_fn: HeightFn, iterations: int = 8) -> np.ndarray:
    """ENU points (..., 3) seen at focal-plane positions (..., 2) (row, col; a stage offset
    already added) by poses broadcasting against them, on the surface h(E, N), float64.

    Fixed-point iteration on the height, as :meth:`CameraModel.ground_points` (< 1 mm for
    rays within a degree of vertical) but one pose per point.
    """
    d_cam = focal_plane.cam_direction(pixel_rc)
    d = np.einsum("...ij,...j->...i", poses.enu_from_cam, d_cam)
    c = poses.position_m
    h = np.zeros(d.shape[:-1])
    for _ in range(iterations):
        s = (h - c[..., 2]) / d[..., 2]
        p = c[..., :2] + s[..., None] * d[..., :2]
        h = height_fn(p[..., 0], p[..., 1])
    s = (h - c[..., 2]) / d[..., 2]
    return c + s[..., None] * d


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
    camera : the true camera (any focal plane; the imager's is used).
    imager, sampling : the TDI imager and its sampling (:func:`tdi_sampling`).
    t0_s : the start of line 0's integration, s.
    lines : (L,) line indices; cols : (P,) detector columns to evaluate at.
    height_fn : terrain height h(E, N), m (the renderer's DEM).
    stage_offset_px : the stage trajectory s(t) -> (..., 2) px, or None (at rest).
    nominal : the strip's own pose is the nominal one (then only the stage offsets it).
    """
    cam = imager_camera(camera, imager)
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
    x = ground_points(pose4, fp, pos, height_fn)  # (L, S, P, 3)
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


def frame_offset_px(camera: CameraModel, imager: FrameImager, sampling: FrameSampling,
                    t0_s: float, pixel_rc: np.ndarray, height_fn: HeightFn,
                    stage_offset_px: StageFn | None = None, nominal: bool = False
                    ) -> np.ndarray:
    """A frame exposure's true offset (P, 2) px at pixels (P, 2), on the nominal grid:
    ``frame[p] ~ static[p + off[p]]`` with ``static`` the nominal, stage-free exposure over
    the same instants (the nominal projection of each sample's true ground point minus the
    sample's detector position, averaged over the samples)."""
    cam = imager_camera(camera, imager)
    fp = cam.focal_plane
    pix = np.atleast_2d(np.asarray(pixel_rc, dtype=np.float64))
    t = t0_s + sampling.tau_s  # (S,)
    det = pix[None, :, :] + sampling.subpixel_px[:, None, :]  # (S, P, 2)
    pos = det + stage_at(stage_offset_px, t)[:, None, :]
    poses = cam.pose(t, nominal=nominal)
    pose3 = Pose(poses.position_m[:, None, :], poses.enu_from_cam[:, None, :, :])
    x = ground_points(pose3, fp, pos, height_fn)
    nom = cam.pose(t, nominal=True)
    rc = project(x, Pose(nom.position_m[:, None, :], nom.enu_from_cam[:, None, :, :]), fp)
    return (rc - det).mean(axis=0)

"""Truth: the camera model's exact image motion, never the estimates.

``motion_px`` samples the main imager's integration windows (from camera.main_imager.start_s
on); the stage comes from the actuator's recorded trajectory at the same instants (it moves
inside exposures); ``meas_px`` is the true shift of every tracker measurement;
:func:`jitter_px` is the true motion against the nominal (jitter-free) pose, what a perfect
record of the jitter holds (the main imager's product compares its record with it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camera.geometry import Pose, project
from compensation.loop import LoopRecord, Trajectory
from imc.wiring.build import Models


@dataclass(frozen=True)
class Truth:
    """True image motion at the main imager's centre (px).

    ``t_s`` samples its integration windows (``window`` index of each sample); ``motion_px``
    is the image motion of the ground there (a frame imager: the ground seen at t = 0,
    relative to its mean over tracker frame 0's exposure, the reference the tracker and the
    loop hold the image to; TDI: the ground entering each line, relative to the line's
    start),
    ``charge_px`` what the imager follows itself (TDI charge transfer within the line),
    ``meas_px`` the truth of every tracker measurement (T, B, 2), ``stage_mean_px`` the
    stage's exposure mean in every tracker frame (T, 2).
    """

    t_s: np.ndarray
    window: np.ndarray
    window_s: float
    motion_px: np.ndarray
    charge_px: np.ndarray
    meas_px: np.ndarray
    stage_mean_px: np.ndarray
    per_window_reset: bool

    def stage_px(self, trajectory: Trajectory | None) -> np.ndarray:
        """The stage (N, 2) at each sample, with the window-start value removed for TDI lines
        (None: the stage at rest)."""
        if trajectory is None:
            return np.zeros_like(self.motion_px)
        s = trajectory(self.t_s)
        if self.per_window_reset:
            first = np.r_[0, np.flatnonzero(np.diff(self.window)) + 1]
            s = s - np.repeat(s[first], np.diff(np.r_[first, len(s)]), axis=0)
        return s

    def residual_px(self, trajectory: Trajectory | None) -> np.ndarray:
        return self.motion_px - self.stage_px(trajectory) - self.charge_px


def exposure_times(m: Models, k: int, n: int) -> np.ndarray:
    """n times (s) spread evenly (cell centres) over frame k's exposure."""
    return m.frame_t_s[k] + (np.arange(n) + 0.5) / n * m.exposure_s


def measurement_truth(m: Models, rec: LoopRecord, stage_mean: np.ndarray) -> np.ndarray:
    """True shift (T, B, 2) of every tracker measurement: exposure-mean motion of the ground
    at each reference block centre, minus the stage's exposure-mean change between the two
    frames."""
    s = m.scenario.metrics.samples_per_frame
    out = np.zeros(rec.shift_px.shape)
    grounds: dict[tuple[int, bytes], np.ndarray] = {}  # a fixed reference is intersected once
    for k in range(1, len(m.frame_t_s)):
        kr = int(rec.ref_frame[k, 0])
        centers = rec.centers_px[k]
        key = (kr, centers.tobytes())
        if key not in grounds:
            grounds[key] = m.camera.ground_points(centers + stage_mean[kr],
                                                  float(m.frame_mid_s[kr]), m.terrain.height_at)
        times = np.concatenate([exposure_times(m, kr, s), exposure_times(m, k, s)])
        mo = m.camera.image_motion_px(grounds[key], times, float(m.frame_mid_s[kr]))
        out[k] = mo[s:].mean(axis=0) - mo[:s].mean(axis=0) - (stage_mean[k] - stage_mean[kr])
    return out


def compute_truth(m: Models, rec: LoopRecord, trajectory: Trajectory) -> Truth:
    """True motion at the main imager over its integration windows, and of every
    measurement."""
    sc = m.scenario
    duration = len(m.frame_t_s) / sc.camera.tracker.frame_rate_hz
    start = sc.camera.main_imager.start_s
    cam = m.main_camera
    centre = cam.focal_plane.center_px[None]
    tdi = m.imager.scanning
    window = m.imager.integration_s()
    span = duration - start
    n_win = max(1, int(np.floor(span / window + 1e-9)))
    if not tdi and window > span:
        window, n_win = span, 1
    dt = min(1.0 / sc.camera.tracker.frame_rate_hz / sc.metrics.samples_per_frame,
             window / 16.0)
    per = max(2, int(np.ceil(window / dt)))
    frac = (np.arange(per) + 0.5) / per
    t_s = start + ((np.arange(n_win)[:, None] + frac[None, :]) * window).ravel()
    win = np.repeat(np.arange(n_win), per)
    if tdi:
        starts = start + np.arange(n_win) * window
        ground = np.stack([cam.ground_points(centre, float(t0), m.terrain.height_at)[0]
                           for t0 in starts])  # (W, 3)
        pose = cam.pose(np.concatenate([starts, t_s]))
        p0 = project(ground, pose[:n_win], cam.focal_plane)  # (W, 2)
        moving = Pose(pose.position_m[n_win:].reshape(n_win, per, 3),
                      pose.enu_from_cam[n_win:].reshape(n_win, per, 3, 3))
        pw = project(ground[:, None, :], moving, cam.focal_plane)  # (W, per, 2)
        motion = (pw - p0[:, None, :]).reshape(-1, 2)
        charge = m.imager.charge_motion_px(t_s - starts[win])
    else:
        ground = cam.ground_points(centre, 0.0, m.terrain.height_at)
        ref = cam.image_motion_px(ground, exposure_times(m, 0, sc.metrics.samples_per_frame),
                                  0.0)[:, 0].mean(axis=0)
        motion = cam.image_motion_px(ground, t_s, 0.0)[:, 0] - ref
        charge = np.zeros_like(motion)
    stage_mean = np.stack([trajectory.mean(float(t0), float(t0) + m.exposure_s)
                           for t0 in m.frame_t_s])
    return Truth(t_s, win, window, motion, charge, measurement_truth(m, rec, stage_mean),
                 stage_mean, tdi)


def jitter_px(m: Models, t_s: np.ndarray) -> np.ndarray:
    """The true image motion (T, 2) px at the main imager's centre against the nominal pose
    at times t_s (T,): where the true camera sees the ground the nominal one sees at the
    centre, projected, less the centre (the jitter alone: orbit and attitude cancel)."""
    cam = m.main_camera
    fp = cam.focal_plane
    t = np.asarray(t_s, dtype=np.float64)
    centre = np.broadcast_to(fp.center_px, (len(t), 2))
    g = cam.ground_points_posed(cam.pose(t, nominal=True), centre, m.terrain.height_at)
    return project(g, cam.pose(t), fp) - centre

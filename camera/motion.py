"""Camera kinematics: orbit + attitude + Earth rotation -> camera poses and image motion."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camera.geometry import BODY_FROM_CAM, FocalPlane, Pose, project
from orbit.attitude import Attitude
from orbit.frames import LocalFrame, eci_to_ecef_matrix, eci_to_ecef_rate, gmst_rad
from orbit.kepler import EarthOrbit

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class CameraModel:
    """The true camera: poses at any time, exact projection, predicted image motion.

    Image motion and velocity are of ground points fixed in the scene's ENU frame (Earth
    rotation, orbit, attitude, jitter and terrain height all enter through the exact
    projection); ``nominal=True`` drops the jitter: the *predicted* motion a tracker can know
    in advance.
    """

    orbit: EarthOrbit
    attitude: Attitude
    frame: LocalFrame
    focal_plane: FocalPlane

    def pose(self, t_s: np.ndarray, nominal: bool = False) -> Pose:
        """Camera poses in ENU at times t_s (s since the orbit epoch); jitter-free if nominal."""
        t = np.asarray(t_s, dtype=np.float64)
        r_ecef, _ = self.orbit.state_ecef(t)
        ecef_from_eci = eci_to_ecef_matrix(gmst_rad(self.orbit.epoch_utc, t))
        eci_from_body = self.attitude.eci_from_body(self.orbit, t, nominal)
        enu_from_cam = self.frame.enu_from_ecef @ ecef_from_eci @ eci_from_body @ BODY_FROM_CAM
        return Pose(self.frame.ecef_to_enu(r_ecef), enu_from_cam)

    def pose_and_rate(self, t_s: np.ndarray, nominal: bool = False):
        """:meth:`pose` and its time derivatives: camera velocity (..., 3) in m/s (ENU) and
        d(enu_from_cam)/dt (..., 3, 3) in 1/s."""
        t = np.asarray(t_s, dtype=np.float64)
        r_ecef, v_ecef = self.orbit.state_ecef(t)
        g = gmst_rad(self.orbit.epoch_utc, t)
        m, mdot = eci_to_ecef_matrix(g), eci_to_ecef_rate(g)
        b, bdot = self.attitude.eci_from_body_and_rate(self.orbit, t, nominal)
        e = self.frame.enu_from_ecef
        pose = Pose(self.frame.ecef_to_enu(r_ecef), e @ m @ b @ BODY_FROM_CAM)
        rdot = e @ (mdot @ b + m @ bdot) @ BODY_FROM_CAM
        return pose, np.einsum("ij,...j->...i", e, v_ecef), rdot

    def project(self, points_enu_m: np.ndarray, t_s: np.ndarray, nominal: bool = False):
        """Pixel (row, col) of ENU points at times t_s (no stage offset), float64."""
        return project(points_enu_m, self.pose(t_s, nominal), self.focal_plane)

    def image_motion_px(
        self, points_enu_m: np.ndarray, t_s: np.ndarray, t_ref_s: float, nominal: bool = False
    ) -> np.ndarray:
        """Image motion (T, P, 2) in px of ground points (P, 3) from t_ref_s to times t_s (T,).

        No stage offset is applied: this is the motion the compensation has to cancel.
        """
        pts = np.atleast_2d(np.asarray(points_enu_m, dtype=np.float64))
        pose = self.pose(np.atleast_1d(np.asarray(t_s, dtype=np.float64)), nominal)
        moving = Pose(pose.position_m[:, None, :], pose.enu_from_cam[:, None, :, :])
        ref = project(pts, self.pose(np.asarray(t_ref_s, dtype=np.float64), nominal),
                      self.focal_plane)
        return project(pts[None], moving, self.focal_plane) - ref[None]

    def image_velocity_px_s(
        self, points_enu_m: np.ndarray, t_s: np.ndarray, nominal: bool = False
    ) -> np.ndarray:
        """Image velocity (T, P, 2), px/s (row, col), of ground points (P, 3) at times t_s (T,).

        Differentiates the projection analytically: with camera coordinates
        q = R^T (p - c), dq/dt = dR^T/dt (p - c) - R^T dc/dt and col = c_pp + f q_x / q_z,
        d col/dt = f (dq_x q_z - q_x dq_z) / q_z^2 (rows likewise).
        """
        pts = np.atleast_2d(np.asarray(points_enu_m, dtype=np.float64))
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        pose, cdot, rdot = self.pose_and_rate(t, nominal)
        d = pts[None] - pose.position_m[:, None, :]  # (T, P, 3)
        q = np.einsum("tji,tpj->tpi", pose.enu_from_cam, d)
        qd = (np.einsum("tji,tpj->tpi", rdot, d)
              - np.einsum("tji,tj->ti", pose.enu_from_cam, cdot)[:, None, :])
        f = self.focal_plane.f_px
        z2 = q[..., 2] ** 2
        col = f * (qd[..., 0] * q[..., 2] - q[..., 0] * qd[..., 2]) / z2
        row = f * (qd[..., 1] * q[..., 2] - q[..., 1] * qd[..., 2]) / z2
        return np.stack([row, col], axis=-1)

    def motion_field_px(self, pixel_rc: np.ndarray, t_s: np.ndarray, t_ref_s: float,
                        height_fn: HeightFn, nominal: bool = False) -> np.ndarray:
        """Image motion (T, P, 2) in px, from t_ref_s to t_s, of the ground seen at focal-plane
        pixels (P, 2) at t_ref_s on the surface h(E, N) (relief parallax included)."""
        ground = self.ground_points(np.atleast_2d(pixel_rc), t_ref_s, height_fn)
        return self.image_motion_px(ground, t_s, t_ref_s, nominal)

    def velocity_field_px_s(self, pixel_rc: np.ndarray, t_s: float, height_fn: HeightFn,
                            nominal: bool = False) -> np.ndarray:
        """Image velocity (P, 2) in px/s at time t_s of the ground seen at pixels (P, 2)."""
        ground = self.ground_points(np.atleast_2d(pixel_rc), t_s, height_fn)
        return self.image_velocity_px_s(ground, np.array([t_s]), nominal)[0]

    def ground_points(
        self, pixel_rc: np.ndarray, t_s: float | np.ndarray, height_fn: HeightFn,
        iterations: int = 8
    ) -> np.ndarray:
        """ENU points (..., 3) seen at pixels (..., 2) at time t_s on the surface h(E, N);
        for times t_s (T,), the points (T, ..., 3) at each of them
        (:func:`intersect_terrain`)."""
        t = np.asarray(t_s, dtype=np.float64)
        if t.ndim > 1:
            raise ValueError(f"t_s must be a time or a 1-D array of times, got shape {t.shape}")
        pose = self.pose(t)
        pix = np.asarray(pixel_rc, dtype=np.float64)
        if t.ndim == 1:
            lead = (1,) * (pix.ndim - 1)
            pose = Pose(pose.position_m.reshape(len(t), *lead, 3),
                        pose.enu_from_cam.reshape(len(t), *lead, 3, 3))
        return intersect_terrain(pose, self.focal_plane, pix, height_fn, iterations)

    def ground_points_posed(self, poses: Pose, pixel_rc: np.ndarray, height_fn: HeightFn,
                            iterations: int = 8) -> np.ndarray:
        """ENU points (..., 3) seen at focal-plane positions (..., 2) (a stage offset already
        added) by ``poses`` broadcasting against them, one pose per point
        (:func:`intersect_terrain` on this camera's focal plane)."""
        return intersect_terrain(poses, self.focal_plane, pixel_rc, height_fn, iterations)


def intersect_terrain(poses: Pose, focal_plane: FocalPlane, pixel_rc: np.ndarray,
                      height_fn: HeightFn, iterations: int = 8) -> np.ndarray:
    """The ray-terrain intersection: ENU points (..., 3) seen at focal-plane positions
    (..., 2) (row, col) px by poses broadcasting against them, on the surface h(E, N), float64.

    Parameters
    ----------
    poses : camera poses (position (..., 3) m, enu_from_cam (..., 3, 3)) broadcasting against
        the positions' leading shape.
    focal_plane : the focal plane the positions are on.
    pixel_rc : (..., 2) focal-plane positions, px.
    height_fn : terrain height h(E, N), m.
    iterations : fixed-point steps on the height (rays within a degree of vertical converge to
        < 1 mm in a few).

    Returns
    -------
    (..., 3) ENU points, m.
    """
    d_cam = focal_plane.cam_direction(np.asarray(pixel_rc, dtype=np.float64))
    d = np.einsum("...ij,...j->...i", poses.enu_from_cam, d_cam)
    c = poses.position_m
    h = np.zeros(np.broadcast_shapes(d.shape[:-1], c.shape[:-1]))
    for _ in range(iterations):
        s = (h - c[..., 2]) / d[..., 2]
        p = c[..., :2] + s[..., None] * d[..., :2]
        h = height_fn(p[..., 0], p[..., 1])
    s = (h - c[..., 2]) / d[..., 2]
    return c + s[..., None] * d

"""Camera kinematics: orbit + attitude + Earth rotation -> camera poses and image motion."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camera.geometry import BODY_FROM_CAM, FocalPlane, Pose, project
from orbit.attitude import Attitude
from orbit.frames import LocalFrame, eci_to_ecef_matrix, gmst_rad
from orbit.kepler import CircularOrbit

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class CameraModel:
    """The true camera: poses at any time, exact projection, predicted image motion."""

    orbit: CircularOrbit
    attitude: Attitude
    frame: LocalFrame
    focal_plane: FocalPlane

    def pose(self, t_s: np.ndarray, nominal: bool = False) -> Pose:
        """Camera poses in ENU at times t_s (s since the orbit epoch); jitter-free if nominal."""
        t = np.asarray(t_s, dtype=np.float64)
        r_eci, _ = self.orbit.state_eci(t)
        ecef_from_eci = eci_to_ecef_matrix(gmst_rad(self.orbit.epoch_utc, t))
        r_ecef = np.einsum("...ij,...j->...i", ecef_from_eci, r_eci)
        eci_from_body = (
            self.attitude.nominal_eci_from_body(self.orbit, t)
            if nominal
            else self.attitude.eci_from_body(self.orbit, t)
        )
        enu_from_cam = self.frame.enu_from_ecef @ ecef_from_eci @ eci_from_body @ BODY_FROM_CAM
        return Pose(self.frame.ecef_to_enu(r_ecef), enu_from_cam)

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

    def ground_points(
        self, pixel_rc: np.ndarray, t_s: float, height_fn: HeightFn, iterations: int = 8
    ) -> np.ndarray:
        """ENU points (..., 3) seen at pixels (..., 2) at time t_s on the surface h(E, N).

        Intersects each pixel's ray with the terrain by fixed-point iteration on the height
        (rays are within a degree of vertical, so it converges to < 1 mm in a few steps).
        """
        pose = self.pose(np.asarray(t_s, dtype=np.float64))
        d = np.einsum("ij,...j->...i", pose.enu_from_cam, self.focal_plane.cam_direction(pixel_rc))
        c = pose.position_m
        h = np.zeros(d.shape[:-1])
        for _ in range(iterations):
            s = (h - c[2]) / d[..., 2]
            p = c + s[..., None] * d
            h = height_fn(p[..., 0], p[..., 1])
        s = (h - c[2]) / d[..., 2]
        return c + s[..., None] * d

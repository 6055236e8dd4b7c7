"""Pinhole focal-plane geometry, exact in float64.

Camera frame: x_c toward increasing column, y_c toward increasing row, z_c along the line of
sight. The focal plane is described as the erect (virtual) image in front of the lens, so a
point at camera coordinates (X, Y, Z) lands at
``col = c_pp + (f / pitch) X / Z - s_col`` and ``row = r_pp + (f / pitch) Y / Z - s_row``,
where (r_pp, c_pp) is the principal point in sensor pixels and s the focal-plane stage offset
(the detector moved by +s px, so the content it sees moves by -s px).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Camera axes in body coordinates (columns): x_c = y_b, y_c = -x_b, z_c = z_b.
#: Rows therefore run against the flight direction: the ground flows toward +row.
BODY_FROM_CAM = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class FocalPlane:
    """A rectangular matrix sensor on the focal plane of a pinhole camera.

    Attributes
    ----------
    focal_length_m : effective focal length, m.
    pixel_pitch_m : detector pixel pitch, m.
    rows, cols : sensor size in pixels.
    center_offset_px : (row, col) of the sensor centre relative to the principal point, px.
    """

    focal_length_m: float
    pixel_pitch_m: float
    rows: int
    cols: int
    center_offset_px: tuple[float, float] = (0.0, 0.0)

    @property
    def ifov_rad(self) -> float:
        """Instantaneous field of view of one pixel, rad."""
        return self.pixel_pitch_m / self.focal_length_m

    @property
    def f_px(self) -> float:
        """Focal length in pixels."""
        return self.focal_length_m / self.pixel_pitch_m

    @property
    def principal_point_px(self) -> np.ndarray:
        """Principal point (row, col) in this sensor's pixel coordinates."""
        return np.array(
            [
                (self.rows - 1) / 2.0 - self.center_offset_px[0],
                (self.cols - 1) / 2.0 - self.center_offset_px[1],
            ]
        )

    @property
    def center_px(self) -> np.ndarray:
        """Sensor centre (row, col) in its own pixel coordinates."""
        return np.array([(self.rows - 1) / 2.0, (self.cols - 1) / 2.0])

    def cam_direction(self, pixel_rc: np.ndarray, offset_px=(0.0, 0.0)) -> np.ndarray:
        """Un-normalised camera-frame ray directions (..., 3) for pixels (..., 2) = (row, col)."""
        p = np.asarray(pixel_rc, dtype=np.float64)
        pp = self.principal_point_px
        x = p[..., 1] + offset_px[1] - pp[1]
        y = p[..., 0] + offset_px[0] - pp[0]
        return np.stack([x, y, np.full_like(x, self.f_px)], axis=-1)


@dataclass(frozen=True)
class Pose:
    """Camera poses in the scene's ENU frame: positions (..., 3) m, rotations (..., 3, 3).

    ``enu_from_cam`` has the camera axes (x_c, y_c, z_c) in ENU as columns.
    """

    position_m: np.ndarray
    enu_from_cam: np.ndarray

    def __getitem__(self, item) -> Pose:
        return Pose(self.position_m[item], self.enu_from_cam[item])


def project(
    points_enu_m: np.ndarray, pose: Pose, focal_plane: FocalPlane, offset_px=(0.0, 0.0)
) -> np.ndarray:
    """Exact pinhole projection of ENU points to sensor pixels (row, col), float64.

    ``points_enu_m`` (..., 3) broadcasts against the pose's leading shape.
    """
    d = np.asarray(points_enu_m, dtype=np.float64) - pose.position_m
    cam = np.einsum("...ji,...j->...i", pose.enu_from_cam, d)
    pp = focal_plane.principal_point_px
    f = focal_plane.f_px
    col = pp[1] + f * cam[..., 0] / cam[..., 2] - offset_px[1]
    row = pp[0] + f * cam[..., 1] / cam[..., 2] - offset_px[0]
    return np.stack([row, col], axis=-1)

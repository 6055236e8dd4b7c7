"""Host-side (float64) ray geometry for the exact pinhole sensor. Pure numpy.

Float32 cannot hold a camera 681 km away to 8 mm (0.01 px), so the renderer never sees the
camera position. For each pose keyframe the host computes, in float64, the map from film
coordinates q = (u - 0.5, v - 0.5, 1) to the point where that pixel's pinhole ray crosses a
horizontal start plane z = z_start (above all terrain): a homography, written relative to the
sensor centre's crossing point P_c so every float32 quantity stays small:

    P_xy(q) = P_c + (N' . q) / (D . q),   direction(q) = normalize(A q)

The rays are the exact pinhole lines; they only start on the plane instead of at the lens.
Keyframes across the exposure let one render integrate the motion (ray.time).
"""

from __future__ import annotations

import numpy as np

from camera.geometry import FocalPlane, Pose

#: floats per keyframe: P_c (3), N'_x (3), N'_y (3), D (3), A (9, row-major)
KEYFRAME_FLOATS = 21


def ray_keyframes(
    poses: Pose, focal_plane: FocalPlane, offset_px, z_start_m: float
) -> np.ndarray:
    """Packed float64 keyframes (K, 21) for poses (K,) with a stage offset (row, col) px:
    one (2,) for all keyframes, or (K, 2), one per keyframe (the stage moving)."""
    rows, cols = focal_plane.rows, focal_plane.cols
    pp = focal_plane.principal_point_px
    off = np.broadcast_to(np.asarray(offset_px, dtype=np.float64),
                          (len(poses.position_m), 2))
    m = np.zeros((len(off), 3, 3))
    m[:, 0, 0], m[:, 1, 1], m[:, 2, 2] = cols, rows, focal_plane.f_px
    m[:, 0, 2] = cols / 2.0 - 0.5 + off[:, 1] - pp[1]
    m[:, 1, 2] = rows / 2.0 - 0.5 + off[:, 0] - pp[0]
    a = poses.enu_from_cam @ m  # (K, 3, 3): world direction = A q
    c = poses.position_m  # (K, 3)
    if np.any(c[:, 2] <= z_start_m):
        raise ValueError("camera is below the ray start plane")
    dz = (z_start_m - c[:, 2])[:, None]
    nx = c[:, 0:1] * a[:, 2, :] + dz * a[:, 0, :]
    ny = c[:, 1:2] * a[:, 2, :] + dz * a[:, 1, :]
    d = a[:, 2, :].copy()
    pcx = nx[:, 2] / d[:, 2]
    pcy = ny[:, 2] / d[:, 2]
    nxp = nx - pcx[:, None] * d
    nyp = ny - pcy[:, None] * d
    scale = d[:, 2:3]
    nxp, nyp, d = nxp / scale, nyp / scale, d / scale
    pc = np.column_stack([pcx, pcy, np.full_like(pcx, z_start_m)])
    return np.concatenate([pc, nxp, nyp, d, a.reshape(-1, 9)], axis=1)


def rays_from_keyframe(kf: np.ndarray, qx: np.ndarray, qy: np.ndarray):
    """Origins and unit directions (float64) encoded by one keyframe, for checking."""
    pc, nxp, nyp, d, a = kf[0:3], kf[3:6], kf[6:9], kf[9:12], kf[12:21].reshape(3, 3)
    q = np.stack([qx, qy, np.ones_like(qx)], axis=-1)
    den = q @ d
    o = np.stack([pc[0] + (q @ nxp) / den, pc[1] + (q @ nyp) / den,
                  np.full_like(den, pc[2])], axis=-1)
    w = q @ a.T
    return o, w / np.linalg.norm(w, axis=-1, keepdims=True)


class HitCounts:
    """What a ray cast counts, and the figure to watch: ``rays``, ``first_hits`` (hits of the
    first cast), ``hits`` (after misses were re-cast); a mixin of the cast results."""

    rays: int
    first_hits: int
    hits: int

    @property
    def hit_fraction(self) -> float:
        """Fraction of rays that hit on the first cast."""
        return self.first_hits / max(self.rays, 1)

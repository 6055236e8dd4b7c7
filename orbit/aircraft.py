"""An aircraft platform: straight, level flight over the scene, and its camera's attitude.

The aircraft flies a straight line at constant speed and height in the scene's ENU frame,
the frame its terrain lives in, so its height above the terrain is exact. (The tangent plane
leaves the ellipsoid by d^2 / 2R: 8 cm at 1 km from the centre; over a scene that is the
"level" of the terrain model too.) Position and velocity in ECEF and ECI follow from the
frame, so the aircraft plugs into :class:`~camera.motion.CameraModel` where an orbit does:
``state_ecef``, ``state_eci``, ``ground_point``, ``ground_speed_mps``, ``heading_deg`` and
``epoch_utc``.

The body frame of :class:`AircraftAttitude` follows docs/conventions.md with the velocity
relative to the ground (the scene is Earth-fixed): z_b along the line of sight, x_b the
flight direction's component perpendicular to it. ``nadir`` looks along the scene's
down axis; ``off_nadir`` turns that frame by roll about the flight axis (+: left of the
track), then pitch about the new y axis (+: ahead), the satellite's signs. The ground then
flows exactly along +row in every mode (nothing crabs it: yaw steering changes nothing).
Jitter (already through the camera suspension, :mod:`orbit.suspension`) is applied in the
body frame as for a satellite.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orbit.attitude import Attitude, perp, unit_vector
from orbit.frames import LocalFrame, eci_to_ecef_matrix, eci_to_ecef_rate, gmst_rad
from orbit.kepler import DEFAULT_EPOCH, EarthOrbit


@dataclass(frozen=True)
class Aircraft(EarthOrbit):
    """Straight, level flight in the scene's ENU frame.

    Attributes
    ----------
    frame : the scene's ENU frame.
    height_enu_m : the flight level's ENU height (up), m.
    speed_mps : ground speed, m/s.
    track_deg : direction of flight, from north toward east, deg.
    start_en_m : (east, north) at t = 0, m.
    epoch_utc : UTC time of t = 0.
    """

    frame: LocalFrame
    height_enu_m: float
    speed_mps: float
    track_deg: float = 0.0
    start_en_m: tuple[float, float] = (0.0, 0.0)
    epoch_utc: np.datetime64 = DEFAULT_EPOCH

    def __post_init__(self) -> None:
        if self.speed_mps <= 0.0:
            raise ValueError(f"aircraft ground speed must be > 0 m/s, got {self.speed_mps}")
        object.__setattr__(self, "epoch_utc", np.datetime64(self.epoch_utc, "ns"))

    @property
    def velocity_enu_mps(self) -> np.ndarray:
        """Constant velocity (3,) in ENU, m/s."""
        a = np.deg2rad(self.track_deg)
        return self.speed_mps * np.array([np.sin(a), np.cos(a), 0.0])

    def position_enu_m(self, t_s) -> np.ndarray:
        """ENU positions (..., 3) at times t_s, m."""
        t = np.asarray(t_s, dtype=np.float64)
        p0 = np.array([self.start_en_m[0], self.start_en_m[1], self.height_enu_m])
        return p0 + t[..., None] * self.velocity_enu_mps

    def state_ecef(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and Earth-relative velocity (m/s) in ECEF, (..., 3) each."""
        p = self.position_enu_m(t_s)
        v = np.broadcast_to(self.velocity_enu_mps @ self.frame.enu_from_ecef, p.shape)
        return self.frame.enu_to_ecef(p), v.copy()

    def state_eci(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and inertial velocity (m/s) in ECI, (..., 3) each."""
        t = np.asarray(t_s, dtype=np.float64)
        r, v = self.state_ecef(t)
        g = gmst_rad(self.epoch_utc, t)
        m, mdot = eci_to_ecef_matrix(g), eci_to_ecef_rate(g)
        mt, mdt = np.swapaxes(m, -1, -2), np.swapaxes(mdot, -1, -2)
        return (np.einsum("...ij,...j->...i", mt, r),
                np.einsum("...ij,...j->...i", mt, v) + np.einsum("...ij,...j->...i", mdt, r))

    def ground_speed_mps(self, t_s) -> np.ndarray:
        """Ground speed (exact), m/s."""
        return np.full(np.shape(t_s), self.speed_mps)

    def heading_deg(self, t_s) -> np.ndarray:
        """Direction of flight from north toward east, deg in [0, 360)."""
        return np.full(np.shape(t_s), np.mod(self.track_deg, 360.0))

    @classmethod
    def over_point(cls, frame: LocalFrame, height_enu_m: float, speed_mps: float,
                   track_deg: float, epoch_utc: np.datetime64, t_cross_s: float,
                   ground_enu_m: float = 0.0, roll_deg: float = 0.0,
                   pitch_deg: float = 0.0) -> Aircraft:
        """The flight whose line of sight (roll, pitch) meets the point (0, 0, ground_enu_m)
        of the scene at t_cross_s."""
        probe = cls(frame, height_enu_m, speed_mps, track_deg, (0.0, 0.0), epoch_utc)
        los = AircraftAttitude("off_nadir", roll_deg=roll_deg,
                               pitch_deg=pitch_deg).line_of_sight_enu(probe)
        reach = (ground_enu_m - height_enu_m) / los[2] * los[:2]
        start = -reach - t_cross_s * probe.velocity_enu_mps[:2]
        return cls(frame, height_enu_m, speed_mps, track_deg, (float(start[0]),
                                                               float(start[1])), epoch_utc)


@dataclass(frozen=True)
class AircraftAttitude(Attitude):
    """Level flight: the camera's nominal pointing fixed in the scene's ENU frame (modes
    ``nadir`` and ``off_nadir``), plus jitter in the body frame. Use with an
    :class:`Aircraft`."""

    def __post_init__(self) -> None:
        if self.mode == "target":
            raise ValueError("an aircraft's camera looks nadir or off_nadir, not 'target'")
        super().__post_init__()

    def line_of_sight_enu(self, orbit: Aircraft) -> np.ndarray:
        """Unit line of sight z_b (3,) in ENU."""
        x0 = orbit.velocity_enu_mps / orbit.speed_mps
        z0 = np.array([0.0, 0.0, -1.0])
        y0 = np.cross(z0, x0)
        ph, th = np.deg2rad(self.roll_deg), np.deg2rad(self.pitch_deg)
        return np.sin(th) * x0 - np.sin(ph) * np.cos(th) * y0 + np.cos(ph) * np.cos(th) * z0

    def enu_from_body(self, orbit: Aircraft) -> np.ndarray:
        """Nominal rotation (3, 3) whose columns are x_b, y_b, z_b in ENU (constant)."""
        z = self.line_of_sight_enu(orbit)
        x = unit_vector(perp(orbit.velocity_enu_mps, z))
        return np.stack([x, np.cross(z, x), z], axis=-1)

    def line_of_sight_eci(self, orbit: Aircraft, t_s) -> np.ndarray:
        return self.nominal_eci_from_body(orbit, t_s)[..., :, 2]

    def boresight_image_flow_eci(self, orbit: Aircraft, t_s) -> np.ndarray:
        """The boresight image flows along -x_b at the ground's speed across the line of
        sight (m/s, ECI; the ground is fixed in the scene)."""
        b = self.nominal_eci_from_body(orbit, t_s)
        z = b[..., :, 2]
        v = np.einsum("...ij,j->...i", b, self.enu_from_body(orbit).T @ orbit.velocity_enu_mps)
        return -perp(v, z)

    def nominal_eci_from_body(self, orbit: Aircraft, t_s) -> np.ndarray:
        """Nominal rotations (..., 3, 3) whose columns are x_b, y_b, z_b in ECI."""
        t = np.asarray(t_s, dtype=np.float64)
        eci_from_ecef = np.swapaxes(eci_to_ecef_matrix(gmst_rad(orbit.epoch_utc, t)), -1, -2)
        return eci_from_ecef @ (orbit.frame.enu_from_ecef.T @ self.enu_from_body(orbit))

    def off_nadir_deg(self, orbit: Aircraft, t_s) -> np.ndarray:
        """Angle between the line of sight and the scene's down axis, deg."""
        z = self.line_of_sight_enu(orbit)
        return np.full(np.shape(t_s), np.rad2deg(np.arccos(np.clip(-z[2], -1.0, 1.0))))

"""Spacecraft attitude: nominal pointing (nadir, off-nadir, target), yaw steering, jitter.

Body frame (docs/conventions.md): z_b along the line of sight (toward the ground), x_b the
component of the inertial velocity perpendicular to z_b (flight direction), y_b = z_b x x_b.
With ``yaw_steering`` x_b is instead turned about z_b to point against the image motion of the
boresight's ground point, so the ground flows exactly along +row (what a TDI imager needs:
Earth rotation otherwise crabs the image by ~3-4 deg).

Pointing modes (the line of sight z_b):

* ``nadir``: the geocentric nadir -r/|r|;
* ``off_nadir``: the nadir frame (LVLH: z0 = -r/|r|, x0 = velocity perpendicular to it,
  y0 = z0 x x0) turned by ``roll_deg`` about x0, then ``pitch_deg`` about the new y axis:
  +pitch looks ahead along the flight direction, +roll looks toward -y0 (left of the track);
* ``target``: held on the ECEF point ``target_ecef_m`` (a staring frame camera).

Jitter is a small rotation vector (roll about x_b, pitch about y_b, yaw about z_b) applied in
the body frame: R_eci_body = R_nominal @ R(jitter).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from geographiclib.geodesic import Geodesic

from orbit.frames import (
    OMEGA_EARTH_RAD_S,
    ecef_to_geodetic,
    eci_to_ecef_matrix,
    gmst_rad,
    ray_ellipsoid_m,
)
from orbit.jitter import JitterSeries, JitterTerm, realize_jitter
from orbit.kepler import EarthOrbit, Orbit

_DT_S = 1e-3  # central-difference step for nominal rates (the pointing rotates < 2 mrad/s)


def rotation_matrices(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (axis times angle, rad), by
    Rodrigues' formula R = I + a K + b K^2 with a = sin t / t and b = (1 - cos t) / t^2 (their
    Taylor series below t = 1e-4 rad, exact to double precision there)."""
    v = np.asarray(rotvec, dtype=np.float64)
    t2 = np.sum(v * v, axis=-1)[..., None, None]
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(ts)) / (ts * ts))
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return np.eye(3) + a * k + b * (k @ k)


def unit_vector(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def perp(v: np.ndarray, z: np.ndarray) -> np.ndarray:
    return v - np.sum(v * z, axis=-1, keepdims=True) * z


def _skew(w: np.ndarray) -> np.ndarray:
    s = np.zeros(w.shape[:-1] + (3, 3))
    s[..., 0, 1], s[..., 0, 2] = -w[..., 2], w[..., 1]
    s[..., 1, 0], s[..., 1, 2] = w[..., 2], -w[..., 0]
    s[..., 2, 0], s[..., 2, 1] = -w[..., 1], w[..., 0]
    return s


def _right_jacobian(phi: np.ndarray, v: np.ndarray) -> np.ndarray:
    """J_r(phi) v (..., 3): the body angular velocity of R(phi) when phi changes at v, i.e.
    d/dt R(phi) = R(phi) [J_r(phi) dphi/dt]x; J_r = I - a [phi]x + b [phi]x^2 with
    a = (1 - cos th) / th^2, b = (th - sin th) / th^3 (series below 1e-4 rad)."""
    th2 = np.sum(phi * phi, axis=-1, keepdims=True)
    th = np.sqrt(th2)
    small = th < 1e-4
    safe = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0 - th2 / 120.0, (safe - np.sin(safe)) / safe**3)
    c = np.cross(phi, v)
    return v - a * c + b * np.cross(phi, c)


@dataclass(frozen=True)
class Attitude:
    """Nominal pointing plus jitter; see the module docstring for the modes.

    ``jitter`` is a realised :class:`~orbit.jitter.JitterSeries`, or a tuple of sinusoidal
    :class:`~orbit.jitter.JitterTerm` (deterministic, realised here).
    """

    mode: Literal["nadir", "off_nadir", "target"] = "nadir"
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    target_ecef_m: tuple[float, float, float] | None = None
    yaw_steering: bool = False
    jitter: JitterSeries | tuple[JitterTerm, ...] = field(default_factory=JitterSeries)

    def __post_init__(self) -> None:
        if self.mode not in ("nadir", "off_nadir", "target"):
            raise ValueError(f"attitude mode must be nadir, off_nadir or target, got {self.mode!r}")
        if self.mode == "target" and self.target_ecef_m is None:
            raise ValueError("attitude mode 'target' needs target_ecef_m")
        if self.mode == "target" and self.yaw_steering:
            raise ValueError("yaw steering needs a scanning mode (nadir or off_nadir): in "
                             "'target' mode the boresight image does not move")
        if self.mode != "off_nadir" and (self.roll_deg or self.pitch_deg):
            raise ValueError("roll_deg / pitch_deg apply to mode 'off_nadir' only")
        if not isinstance(self.jitter, JitterSeries):
            terms = tuple(self.jitter)
            if not all(isinstance(t, JitterTerm) for t in terms):
                raise TypeError("pass random or wheel jitter as a realised JitterSeries "
                                "(orbit.jitter.realize_jitter)")
            object.__setattr__(self, "jitter",
                               realize_jitter(terms, 1.0, np.random.default_rng(0)))

    # ----- pointing ------------------------------------------------------------------------
    def line_of_sight_eci(self, orbit: EarthOrbit, t_s) -> np.ndarray:
        """Unit line-of-sight vectors z_b (..., 3) in ECI."""
        t = np.asarray(t_s, dtype=np.float64)
        r, v = orbit.state_eci(t)
        if self.mode == "target":
            ecef_to_eci = np.swapaxes(eci_to_ecef_matrix(gmst_rad(orbit.epoch_utc, t)), -1, -2)
            target = np.einsum("...ij,j->...i", ecef_to_eci, np.asarray(self.target_ecef_m))
            return unit_vector(target - r)
        z0 = unit_vector(-r)
        if self.mode == "nadir":
            return z0
        x0 = unit_vector(perp(v, z0))
        y0 = np.cross(z0, x0)
        ph, th = np.deg2rad(self.roll_deg), np.deg2rad(self.pitch_deg)
        los_lvlh = np.array([np.sin(th), -np.sin(ph) * np.cos(th), np.cos(ph) * np.cos(th)])
        return los_lvlh[0] * x0 + los_lvlh[1] * y0 + los_lvlh[2] * z0

    def boresight_image_flow_eci(self, orbit: EarthOrbit, t_s) -> np.ndarray:
        """Velocity (..., 3), m/s in ECI, of the boresight's ground point relative to the line of
        sight, perpendicular to it: the focal-plane image moves along this direction.

        With the line of sight z rotating at dz/dt and the ground point p = r + Z z on the
        ellipsoid, the camera sees p move at (omega_E x p - v - Z dz/dt), perpendicular to z.
        """
        t = np.asarray(t_s, dtype=np.float64)
        r, v = orbit.state_eci(t)
        z = self.line_of_sight_eci(orbit, t)
        zdot = (self.line_of_sight_eci(orbit, t + _DT_S)
                - self.line_of_sight_eci(orbit, t - _DT_S)) / (2.0 * _DT_S)
        m = eci_to_ecef_matrix(gmst_rad(orbit.epoch_utc, t))
        rng_m = ray_ellipsoid_m(np.einsum("...ij,...j->...i", m, r),
                                np.einsum("...ij,...j->...i", m, z))
        if np.any(~np.isfinite(rng_m)):
            raise ValueError("the line of sight misses the Earth")
        p = r + rng_m[..., None] * z
        earth = OMEGA_EARTH_RAD_S * np.stack([-p[..., 1], p[..., 0], 0.0 * p[..., 2]], axis=-1)
        return perp(earth - v - rng_m[..., None] * zdot, z)

    def nominal_eci_from_body(self, orbit: EarthOrbit, t_s) -> np.ndarray:
        """Nominal (jitter-free) rotations (..., 3, 3) whose columns are x_b, y_b, z_b in ECI."""
        t = np.asarray(t_s, dtype=np.float64)
        z = self.line_of_sight_eci(orbit, t)
        if self.yaw_steering:
            x = -self.boresight_image_flow_eci(orbit, t)
        else:
            _, v = orbit.state_eci(t)
            x = perp(v, z)
        x = unit_vector(x)
        return np.stack([x, np.cross(z, x), z], axis=-1)

    def _jitter_matrix(self, t: np.ndarray) -> np.ndarray:
        return rotation_matrices(self.jitter.rotvec_rad(t))

    def eci_from_body(self, orbit: EarthOrbit, t_s, nominal: bool = False) -> np.ndarray:
        """Rotations (..., 3, 3): nominal pointing with jitter applied in the body frame
        (``nominal=True``: without the jitter)."""
        t = np.asarray(t_s, dtype=np.float64)
        n = self.nominal_eci_from_body(orbit, t)
        if nominal or len(self.jitter) == 0:
            return n
        return n @ self._jitter_matrix(t)

    def eci_from_body_and_rate(self, orbit: EarthOrbit, t_s,
                               nominal: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`eci_from_body` (..., 3, 3) and its time derivative (..., 3, 3) in 1/s.

        The nominal part by a central difference (smooth: < 2 mrad/s), the jitter part
        analytically: d/dt (N J) = dN/dt J + N J [w]x with the body rate w = J_r(phi) dphi/dt
        (J_r: SO(3)'s right Jacobian; dphi/dt alone is off by ~|phi| / 2 of the rate, 1e-5 for
        a satellite, 1e-3 for an aircraft).
        """
        t = np.asarray(t_s, dtype=np.float64)
        n = self.nominal_eci_from_body(orbit, t)
        nd = (self.nominal_eci_from_body(orbit, t + _DT_S)
              - self.nominal_eci_from_body(orbit, t - _DT_S)) / (2.0 * _DT_S)
        if nominal or len(self.jitter) == 0:
            return n, nd
        jit = self._jitter_matrix(t)
        w = _right_jacobian(self.jitter.rotvec_rad(t), self.jitter.rate_rad_s(t))
        return n @ jit, nd @ jit + n @ jit @ _skew(w)

    def off_nadir_deg(self, orbit: EarthOrbit, t_s) -> np.ndarray:
        """Angle (...) between the line of sight and the geocentric nadir, deg."""
        t = np.asarray(t_s, dtype=np.float64)
        r, _ = orbit.state_eci(t)
        z = self.line_of_sight_eci(orbit, t)
        return np.rad2deg(np.arccos(np.clip(np.sum(-unit_vector(r) * z, axis=-1), -1.0, 1.0)))


def orbit_looking_at(lat_deg: float, lon_deg: float, altitude_m: float, inclination_deg: float,
                     epoch_utc: np.datetime64, descending: bool = True, roll_deg: float = 0.0,
                     pitch_deg: float = 0.0, j2: bool = True, tol_m: float = 1e-3):
    """The circular orbit whose off-nadir line of sight (roll, pitch; LVLH) at t = 0 meets the
    ellipsoid at (lat, lon).

    Starts over the point and moves the sub-satellite point by the geodesic miss until the
    line of sight lands within ``tol_m`` (a handful of iterations).

    Raises
    ------
    ValueError
        If the latitude is unreachable or the look angles miss the Earth.
    """
    sub_lat, sub_lon = lat_deg, lon_deg
    orbit = Orbit.over_point(sub_lat, sub_lon, altitude_m, inclination_deg, epoch_utc,
                             descending, j2)
    if roll_deg == 0.0 and pitch_deg == 0.0:
        return orbit
    att = Attitude("off_nadir", roll_deg=roll_deg, pitch_deg=pitch_deg)
    geod = Geodesic.WGS84
    for _ in range(30):
        r_e, _ = orbit.state_ecef(0.0)
        m = eci_to_ecef_matrix(gmst_rad(orbit.epoch_utc, 0.0))
        z = m @ att.line_of_sight_eci(orbit, 0.0)
        s = ray_ellipsoid_m(r_e, z)
        if not np.isfinite(s):
            raise ValueError(f"a line of sight at roll {roll_deg} deg, pitch {pitch_deg} deg "
                             "misses the Earth")
        hit_lat, hit_lon, _ = ecef_to_geodetic(r_e + s * z)
        inv = geod.Inverse(float(hit_lat), float(hit_lon), lat_deg, lon_deg)
        if inv["s12"] < tol_m:
            return orbit
        d = geod.Direct(sub_lat, sub_lon, inv["azi1"], inv["s12"])
        sub_lat, sub_lon = d["lat2"], d["lon2"]
        orbit = Orbit.over_point(sub_lat, sub_lon, altitude_m, inclination_deg, epoch_utc,
                                 descending, j2)
    raise ValueError("could not place the orbit so the line of sight meets the scene")

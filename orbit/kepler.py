"""Circular two-body orbits (J2 secular rates come with the orbit issue)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from geographiclib.geodesic import Geodesic

from orbit.frames import (
    GM_EARTH_M3_S2,
    OMEGA_EARTH_RAD_S,
    WGS84_A_M,
    ecef_to_geodetic,
    eci_to_ecef_matrix,
    geodetic_to_ecef,
    gmst_rad,
)


@dataclass(frozen=True)
class CircularOrbit:
    """A circular orbit about a spherical-gravity Earth (radius WGS84 a + altitude).

    Attributes
    ----------
    altitude_m : height above the WGS84 equatorial radius, m.
    inclination_deg : orbit inclination, deg.
    raan_deg : right ascension of the ascending node at the epoch, deg.
    arg_latitude_deg : argument of latitude (angle from the ascending node) at t = 0, deg.
    epoch_utc : UTC time of t = 0 (``numpy.datetime64``).
    """

    altitude_m: float
    inclination_deg: float
    raan_deg: float
    arg_latitude_deg: float
    epoch_utc: np.datetime64

    @property
    def radius_m(self) -> float:
        return WGS84_A_M + self.altitude_m

    @property
    def mean_motion_rad_s(self) -> float:
        return float(np.sqrt(GM_EARTH_M3_S2 / self.radius_m**3))

    @property
    def period_s(self) -> float:
        return 2.0 * np.pi / self.mean_motion_rad_s

    @classmethod
    def over_point(
        cls,
        lat_deg: float,
        lon_deg: float,
        altitude_m: float,
        inclination_deg: float,
        epoch_utc: np.datetime64,
        descending: bool = True,
    ) -> CircularOrbit:
        """The orbit whose geocentric sub-satellite point at t = 0 is (lat, lon).

        Raises
        ------
        ValueError
            If |lat| exceeds what the inclination can reach.
        """
        inc = np.deg2rad(inclination_deg)
        p = geodetic_to_ecef(lat_deg, lon_deg, 0.0)
        lat_gc = np.arcsin(p[2] / np.linalg.norm(p))
        s = np.sin(lat_gc) / np.sin(inc)
        if abs(s) > 1.0:
            raise ValueError(
                f"latitude {lat_deg} deg is not reachable with inclination {inclination_deg} deg"
            )
        u = np.arcsin(s)
        if descending:
            u = np.pi - u
        alpha = np.deg2rad(lon_deg) + gmst_rad(epoch_utc, 0.0)
        raan = alpha - np.arctan2(np.cos(inc) * np.sin(u), np.cos(u))
        return cls(
            altitude_m=altitude_m,
            inclination_deg=inclination_deg,
            raan_deg=float(np.rad2deg(raan) % 360.0),
            arg_latitude_deg=float(np.rad2deg(u) % 360.0),
            epoch_utc=np.datetime64(epoch_utc, "ns"),
        )

    def state_eci(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Position (..., 3) in m and velocity (..., 3) in m/s, ECI, at times t_s."""
        t = np.asarray(t_s, dtype=np.float64)
        n = self.mean_motion_rad_s
        u = np.deg2rad(self.arg_latitude_deg) + n * t
        om, inc = np.deg2rad(self.raan_deg), np.deg2rad(self.inclination_deg)
        # perifocal in-plane unit vectors: node direction and its 90 deg advance
        p_hat = np.array([np.cos(om), np.sin(om), 0.0])
        q_hat = np.array([-np.sin(om) * np.cos(inc), np.cos(om) * np.cos(inc), np.sin(inc)])
        cu, su = np.cos(u)[..., None], np.sin(u)[..., None]
        r = self.radius_m * (cu * p_hat + su * q_hat)
        v = self.radius_m * n * (-su * p_hat + cu * q_hat)
        return r, v

    def state_ecef(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and Earth-relative velocity (m/s) in ECEF, (..., 3) each."""
        t = np.asarray(t_s, dtype=np.float64)
        r, v = self.state_eci(t)
        m = eci_to_ecef_matrix(gmst_rad(self.epoch_utc, t))
        omega = np.array([0.0, 0.0, OMEGA_EARTH_RAD_S])
        r_e = np.einsum("...ij,...j->...i", m, r)
        v_e = np.einsum("...ij,...j->...i", m, v) - np.cross(omega, r_e)
        return r_e, v_e

    def ground_point(self, t_s: np.ndarray | float):
        """Geodetic (lat_deg, lon_deg, h_m) of the geocentric sub-satellite point."""
        r_e, _ = self.state_ecef(t_s)
        lat, lon, _ = ecef_to_geodetic(r_e)
        return lat, lon, np.zeros_like(lat)

    def ground_speed_mps(self, t_s: np.ndarray | float, dt_s: float = 0.5) -> np.ndarray:
        """Speed (m/s) of the sub-satellite point on the WGS84 ellipsoid (geodesic distance)."""
        t = np.asarray(t_s, dtype=np.float64)
        lat0, lon0, _ = self.ground_point(t - dt_s)
        lat1, lon1, _ = self.ground_point(t + dt_s)
        dist = np.vectorize(lambda a, b, c, d: Geodesic.WGS84.Inverse(a, b, c, d)["s12"])(
            lat0, lon0, lat1, lon1
        )
        return dist / (2.0 * dt_s)

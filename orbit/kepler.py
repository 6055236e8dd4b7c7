"""Keplerian orbits with J2 secular rates, and what every orbit shares (ECEF, ground track).

Mean elements drift at the first-order J2 secular rates (Vallado, *Fundamentals of
Astrodynamics and Applications*, 4th ed., eqs. 9-41): node, argument of perigee and mean
anomaly. Short-period J2 terms (~10 km in radius, smooth over an orbit) are not modelled:
over one exposure they add no measurable image motion. Velocities are the exact time
derivative of the modelled positions, so image motion computed from either agrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from geographiclib.geodesic import Geodesic

from orbit.frames import (
    GM_EARTH_M3_S2,
    J2_EARTH,
    WGS84_A_M,
    ecef_to_geodetic,
    eci_to_ecef_matrix,
    eci_to_ecef_rate,
    enu_matrix,
    geodetic_to_ecef,
    gmst_rad,
)
from orbit.sun import SUN_MEAN_MOTION_DEG_DAY, sun_mean_longitude_deg

#: a sun-synchronous node rate: one turn per tropical year, rad/s (0.9856 deg/day)
SUN_SYNC_RAAN_RATE_RAD_S = np.deg2rad(SUN_MEAN_MOTION_DEG_DAY) / 86400.0
#: the default epoch of the constructors (the quickstart's)
DEFAULT_EPOCH = np.datetime64("2026-06-21T10:30:00", "ns")


class EarthOrbit:
    """What every orbit model offers once it has ``epoch_utc`` and ``state_eci(t)``."""

    epoch_utc: np.datetime64

    def state_eci(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    @property
    def span_s(self) -> tuple[float, float]:
        """The times (s since epoch_utc) the model can be evaluated at: everywhere for a
        propagator, an ephemeris' states' span for one (orbit.oem_orbit)."""
        return (-np.inf, np.inf)

    def state_ecef(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and Earth-relative velocity (m/s) in ECEF, (..., 3) each."""
        t = np.asarray(t_s, dtype=np.float64)
        r, v = self.state_eci(t)
        g = gmst_rad(self.epoch_utc, t)
        m, mdot = eci_to_ecef_matrix(g), eci_to_ecef_rate(g)
        r_e = np.einsum("...ij,...j->...i", m, r)
        v_e = np.einsum("...ij,...j->...i", m, v) + np.einsum("...ij,...j->...i", mdot, r)
        return r_e, v_e

    def ground_point(self, t_s: np.ndarray | float):
        """Sub-satellite point (lat_deg, lon_deg) on WGS84 and the satellite's height h_m above it.

        The point is the foot of the ellipsoid normal through the satellite (geodetic nadir).
        """
        r_e, _ = self.state_ecef(t_s)
        return ecef_to_geodetic(r_e)

    def _foot_ecef(self, t_s) -> np.ndarray:
        lat, lon, _ = self.ground_point(t_s)
        return geodetic_to_ecef(lat, lon, 0.0)

    def ground_velocity_enu_mps(self, t_s: np.ndarray | float, dt_s: float = 0.01) -> np.ndarray:
        """Velocity (..., 3) of the sub-satellite point in its local ENU frame, m/s."""
        t = np.asarray(t_s, dtype=np.float64)
        v = (self._foot_ecef(t + dt_s) - self._foot_ecef(t - dt_s)) / (2.0 * dt_s)
        lat, lon, _ = self.ground_point(t)
        return np.einsum("...ij,...j->...i", enu_matrix(lat, lon), v)

    def ground_speed_mps(self, t_s: np.ndarray | float) -> np.ndarray:
        """Speed of the sub-satellite point over the WGS84 ellipsoid, m/s."""
        return np.linalg.norm(self.ground_velocity_enu_mps(t_s), axis=-1)

    def heading_deg(self, t_s: np.ndarray | float) -> np.ndarray:
        """Azimuth of the ground track (from north toward east), deg in [0, 360)."""
        v = self.ground_velocity_enu_mps(t_s)
        return np.mod(np.rad2deg(np.arctan2(v[..., 0], v[..., 1])), 360.0)

    def ground_track_length_m(self, t0_s: float, t1_s: float, step_s: float = 1.0) -> float:
        """Along-track distance of the sub-satellite point from t0 to t1: sum of geodesics, m."""
        n = max(1, int(np.ceil(abs(t1_s - t0_s) / step_s)))
        lat, lon, _ = self.ground_point(np.linspace(t0_s, t1_s, n + 1))
        return float(sum(Geodesic.WGS84.Inverse(lat[i], lon[i], lat[i + 1], lon[i + 1])["s12"]
                         for i in range(n)))


def _hours(local_time) -> float:
    """Local time as hours: a number, or 'HH:MM' / 'HH:MM:SS'."""
    if isinstance(local_time, str):
        try:
            parts = [float(p) for p in local_time.split(":")]
        except ValueError:
            parts = []
        if not 1 <= len(parts) <= 3:
            raise ValueError(f"local time must be hours or 'HH:MM', got {local_time!r}")
        h = sum(p / 60.0**i for i, p in enumerate(parts))
    else:
        h = float(local_time)
    if not 0.0 <= h < 24.0:
        raise ValueError(f"local time must be in [0, 24) h, got {local_time!r}")
    return h


def sun_synchronous_inclination_deg(altitude_m: float, eccentricity: float = 0.0) -> float:
    """Inclination (deg) whose J2 node rate follows the mean sun (0.9856 deg/day).

    Raises
    ------
    ValueError
        Above ~5,970 km no inclination is fast enough.
    """
    a = WGS84_A_M + altitude_m
    n = np.sqrt(GM_EARTH_M3_S2 / a**3)
    p = a * (1.0 - eccentricity**2)
    cos_i = -SUN_SYNC_RAAN_RATE_RAD_S / (1.5 * n * J2_EARTH * (WGS84_A_M / p) ** 2)
    if cos_i < -1.0:
        raise ValueError(f"no sun-synchronous orbit exists at altitude {altitude_m:g} m")
    return float(np.rad2deg(np.arccos(cos_i)))


@dataclass(frozen=True)
class Orbit(EarthOrbit):
    """Keplerian mean elements at ``epoch_utc`` with J2 secular drift (``j2=False``: two-body).

    Attributes
    ----------
    semi_major_axis_m : semi-major axis, m.
    eccentricity : 0 <= e < 1.
    inclination_deg, raan_deg, arg_perigee_deg, mean_anomaly_deg : the angles at the epoch, deg.
    epoch_utc : UTC time of t = 0 (``numpy.datetime64``).
    j2 : apply the J2 secular rates.
    """

    semi_major_axis_m: float
    eccentricity: float
    inclination_deg: float
    raan_deg: float
    arg_perigee_deg: float
    mean_anomaly_deg: float
    epoch_utc: np.datetime64
    j2: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.eccentricity < 1.0:
            raise ValueError(f"eccentricity must be in [0, 1), got {self.eccentricity}")
        perigee = self.semi_major_axis_m * (1.0 - self.eccentricity)
        if perigee <= WGS84_A_M + 100e3:
            raise ValueError(f"perigee altitude {(perigee - WGS84_A_M) / 1e3:.0f} km is below "
                             "100 km: raise semi_major_axis_m or lower eccentricity")
        if not 0.0 <= self.inclination_deg <= 180.0:
            raise ValueError(f"inclination must be in [0, 180] deg, got {self.inclination_deg}")
        object.__setattr__(self, "epoch_utc", np.datetime64(self.epoch_utc, "ns"))

    # ----- constructors ------------------------------------------------------------------
    @classmethod
    def circular(cls, altitude_m: float, inclination_deg: float, raan_deg: float = 0.0,
                 arg_latitude_deg: float = 0.0,
                 epoch_utc: np.datetime64 = DEFAULT_EPOCH,
                 j2: bool = True) -> Orbit:
        """A circular orbit ``altitude_m`` above the WGS84 equatorial radius."""
        return cls(WGS84_A_M + altitude_m, 0.0, inclination_deg, raan_deg, 0.0,
                   arg_latitude_deg, epoch_utc, j2)

    @classmethod
    def sun_synchronous(cls, altitude_m: float, local_time_of_node: float | str = "10:30",
                        node: str = "descending",
                        epoch_utc: np.datetime64 = DEFAULT_EPOCH,
                        arg_latitude_deg: float = 0.0) -> Orbit:
        """A circular sun-synchronous orbit crossing ``node`` at the given local mean time.

        ``local_time_of_node`` is hours or 'HH:MM' (IKONOS: '10:30', descending).
        """
        if node not in ("ascending", "descending"):
            raise ValueError(f"node must be 'ascending' or 'descending', got {node!r}")
        ltan = _hours(local_time_of_node) + (12.0 if node == "descending" else 0.0)
        raan = sun_mean_longitude_deg(epoch_utc) + (ltan - 12.0) * 15.0
        return cls.circular(altitude_m, sun_synchronous_inclination_deg(altitude_m),
                            float(np.mod(raan, 360.0)), arg_latitude_deg, epoch_utc, True)

    @classmethod
    def over_point(cls, lat_deg: float, lon_deg: float, altitude_m: float,
                   inclination_deg: float, epoch_utc: np.datetime64, descending: bool = True,
                   j2: bool = True) -> Orbit:
        """The circular orbit whose geocentric sub-satellite point at t = 0 is (lat, lon).

        Raises
        ------
        ValueError
            If |lat| exceeds what the inclination can reach.
        """
        inc = np.deg2rad(inclination_deg)
        p = geodetic_to_ecef(lat_deg, lon_deg, 0.0)
        lat_gc = np.arcsin(p[2] / np.linalg.norm(p))
        s = np.sin(lat_gc) / np.sin(inc) if np.sin(inc) > 0 else np.inf
        if abs(s) > 1.0:
            raise ValueError(
                f"latitude {lat_deg} deg is not reachable with inclination {inclination_deg} deg"
            )
        u = np.arcsin(s)
        if descending:
            u = np.pi - u
        alpha = np.deg2rad(lon_deg) + gmst_rad(epoch_utc, 0.0)
        raan = alpha - np.arctan2(np.cos(inc) * np.sin(u), np.cos(u))
        return cls.circular(altitude_m, inclination_deg, float(np.rad2deg(raan) % 360.0),
                            float(np.rad2deg(u) % 360.0), epoch_utc, j2)

    # ----- rates and periods -------------------------------------------------------------
    @property
    def altitude_m(self) -> float:
        """Semi-major axis minus the WGS84 equatorial radius, m."""
        return self.semi_major_axis_m - WGS84_A_M

    @property
    def mean_motion_rad_s(self) -> float:
        """Two-body mean motion sqrt(mu / a^3), rad/s."""
        return float(np.sqrt(GM_EARTH_M3_S2 / self.semi_major_axis_m**3))

    @property
    def period_s(self) -> float:
        """Keplerian period 2 pi / n, s (681 km: 5,903 s = 98.4 min)."""
        return 2.0 * np.pi / self.mean_motion_rad_s

    def _j2k(self) -> float:
        if not self.j2:
            return 0.0
        p = self.semi_major_axis_m * (1.0 - self.eccentricity**2)
        return self.mean_motion_rad_s * J2_EARTH * (WGS84_A_M / p) ** 2

    @property
    def raan_rate_rad_s(self) -> float:
        return -1.5 * self._j2k() * np.cos(np.deg2rad(self.inclination_deg))

    @property
    def arg_perigee_rate_rad_s(self) -> float:
        c = np.cos(np.deg2rad(self.inclination_deg))
        return 0.75 * self._j2k() * (5.0 * c * c - 1.0)

    @property
    def mean_anomaly_rate_rad_s(self) -> float:
        c = np.cos(np.deg2rad(self.inclination_deg))
        e2 = self.eccentricity**2
        return self.mean_motion_rad_s + 0.75 * self._j2k() * np.sqrt(1.0 - e2) * (3 * c * c - 1)

    @property
    def nodal_period_s(self) -> float:
        """Time between ascending-node crossings (J2 included), s."""
        return 2.0 * np.pi / (self.mean_anomaly_rate_rad_s + self.arg_perigee_rate_rad_s)

    @property
    def local_time_of_ascending_node_h(self) -> float:
        """Local mean solar time of the ascending node at the epoch, hours."""
        d = self.raan_deg - float(sun_mean_longitude_deg(self.epoch_utc))
        return float(np.mod(12.0 + d / 15.0, 24.0))

    # ----- state ---------------------------------------------------------------------------
    def state_eci(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Position (..., 3) in m and velocity (..., 3) in m/s, ECI, at times t_s."""
        t = np.asarray(t_s, dtype=np.float64)
        e, a = self.eccentricity, self.semi_major_axis_m
        mdot = self.mean_anomaly_rate_rad_s
        m = np.deg2rad(self.mean_anomaly_deg) + mdot * t
        big_e = m.copy()
        if e > 0.0:
            for _ in range(30):  # Newton on Kepler's equation; converges in < 6 for e < 0.9
                step = (big_e - e * np.sin(big_e) - m) / (1.0 - e * np.cos(big_e))
                big_e = big_e - step
                if np.all(np.abs(step) < 1e-15):
                    break
        ce, se = np.cos(big_e), np.sin(big_e)
        s1 = np.sqrt(1.0 - e * e)
        nu = np.arctan2(s1 * se, ce - e)
        r = a * (1.0 - e * ce)
        rdot = a * e * se * mdot / (1.0 - e * ce)
        nudot = mdot * s1 / (1.0 - e * ce) ** 2
        om = np.deg2rad(self.raan_deg) + self.raan_rate_rad_s * t
        w = np.deg2rad(self.arg_perigee_deg) + self.arg_perigee_rate_rad_s * t
        u, udot = w + nu, nudot + self.arg_perigee_rate_rad_s
        inc = np.deg2rad(self.inclination_deg)
        com, som = np.cos(om)[..., None], np.sin(om)[..., None]
        zero = np.zeros_like(com)
        p_hat = np.concatenate([com, som, zero], axis=-1)
        q_hat = np.concatenate([-som * np.cos(inc), com * np.cos(inc),
                                np.full_like(com, np.sin(inc))], axis=-1)
        cu, su = np.cos(u)[..., None], np.sin(u)[..., None]
        radial = cu * p_hat + su * q_hat
        along = -su * p_hat + cu * q_hat
        pos = r[..., None] * radial
        vel = rdot[..., None] * radial + (r * udot)[..., None] * along
        # the node's drift rotates the whole orbit about the polar axis
        vel = vel + self.raan_rate_rad_s * np.stack(
            [-pos[..., 1], pos[..., 0], np.zeros_like(pos[..., 0])], axis=-1)
        return pos, vel

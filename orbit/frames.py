"""Earth frames: ECI, ECEF (WGS84) and a local east-north-up (ENU) frame.

ECI here is a true-of-date equatorial frame whose z axis is the Earth's rotation axis; ECEF
follows from it by one rotation about z through the Greenwich mean sidereal angle (UT1 taken
equal to UTC, no precession/nutation/polar motion: the errors are far below what moves an
image over a few seconds, since all of them rotate the scene and the orbit together).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
GM_EARTH_M3_S2 = 3.986004418e14
J2_EARTH = 1.08262668e-3
_GMST_DEG_PER_DAY = 360.98564736629
#: rotation rate of ECEF against ECI, rad/s: the rate of the GMST formula below (the WGS84
#: defining constant 7.292115e-5 rounds it); ECEF velocities use this one so that positions
#: and velocities stay consistent to 1e-12.
OMEGA_EARTH_RAD_S = np.deg2rad(_GMST_DEG_PER_DAY) / 86400.0
_J2000_JD = 2451545.0


def julian_date(epoch_utc: np.datetime64) -> float:
    """Julian date (UTC) of a ``numpy.datetime64``."""
    seconds = (np.datetime64(epoch_utc, "ns") - np.datetime64("2000-01-01T12:00:00", "ns")) / (
        np.timedelta64(1, "s")
    )
    return _J2000_JD + float(seconds) / 86400.0


def gmst_rad(epoch_utc: np.datetime64, t_s: np.ndarray | float = 0.0) -> np.ndarray:
    """Greenwich mean sidereal angle (rad) at ``epoch_utc + t_s`` (IAU 1982, UT1 = UTC).

    The angle at the epoch is reduced modulo 360 deg first, so t_s keeps its full float64
    resolution (a smooth angle to 1e-15 rad over a run, not 1e-11).
    """
    d0 = julian_date(epoch_utc) - _J2000_JD
    deg0 = np.mod(280.46061837 + _GMST_DEG_PER_DAY * d0, 360.0)
    deg = deg0 + (_GMST_DEG_PER_DAY / 86400.0) * np.asarray(t_s, dtype=np.float64)
    return np.deg2rad(np.mod(deg, 360.0))


def eci_to_ecef_matrix(gmst: np.ndarray | float) -> np.ndarray:
    """Rotation matrices (..., 3, 3) taking ECI vectors to ECEF: r_ecef = M @ r_eci."""
    g = np.asarray(gmst, dtype=np.float64)
    c, s = np.cos(g), np.sin(g)
    m = np.zeros(g.shape + (3, 3))
    m[..., 0, 0] = c
    m[..., 0, 1] = s
    m[..., 1, 0] = -s
    m[..., 1, 1] = c
    m[..., 2, 2] = 1.0
    return m


def eci_to_ecef_rate(gmst: np.ndarray | float) -> np.ndarray:
    """Time derivative (..., 3, 3) of :func:`eci_to_ecef_matrix`, 1/s."""
    g = np.asarray(gmst, dtype=np.float64)
    c, s = np.cos(g), np.sin(g)
    m = np.zeros(g.shape + (3, 3))
    m[..., 0, 0] = -s
    m[..., 0, 1] = c
    m[..., 1, 0] = -c
    m[..., 1, 1] = -s
    return m * OMEGA_EARTH_RAD_S


def ray_ellipsoid_m(origin_m: np.ndarray, direction: np.ndarray, h_m: float = 0.0) -> np.ndarray:
    """Distance (...) along unit rays (ECEF) to the WGS84 ellipsoid raised by h_m; NaN if missed.

    The raised surface is approximated by the ellipsoid with semi-axes a + h, b + h (exact for
    h = 0; < 1 mm of height error for |h| < 10 km).
    """
    o = np.asarray(origin_m, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    a = WGS84_A_M + h_m
    b = WGS84_A_M * (1.0 - WGS84_F) + h_m
    w = np.array([1.0 / a, 1.0 / a, 1.0 / b])
    os_, ds = o * w, d * w
    qa = np.sum(ds * ds, axis=-1)
    qb = 2.0 * np.sum(os_ * ds, axis=-1)
    qc = np.sum(os_ * os_, axis=-1) - 1.0
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(invalid="ignore"):
        # the nearer root, written to avoid cancellation (qb < 0 when looking at the Earth)
        s = (2.0 * qc) / (-qb + np.sqrt(disc))
    return np.where((disc >= 0.0) & (s > 0.0), s, np.nan)


def geodetic_to_ecef(lat_deg, lon_deg, h_m) -> np.ndarray:
    """WGS84 geodetic latitude/longitude (deg) and ellipsoidal height (m) to ECEF (..., 3), m."""
    lat = np.deg2rad(np.asarray(lat_deg, dtype=np.float64))
    lon = np.deg2rad(np.asarray(lon_deg, dtype=np.float64))
    h = np.asarray(h_m, dtype=np.float64)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    x = (n + h) * np.cos(lat) * np.cos(lon)
    y = (n + h) * np.cos(lat) * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + h) * np.sin(lat)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(xyz_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF (..., 3) in m to WGS84 (lat_deg, lon_deg, h_m); iterative, converged to < 1 mm."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    h = np.zeros_like(p)
    for _ in range(6):
        n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    return np.rad2deg(lat), np.rad2deg(lon), h


def enu_matrix(lat_deg, lon_deg) -> np.ndarray:
    """Rotations (..., 3, 3) taking ECEF vectors to local east-north-up: v_enu = M @ v_ecef."""
    lat = np.deg2rad(np.asarray(lat_deg, dtype=np.float64))
    lon = np.deg2rad(np.asarray(lon_deg, dtype=np.float64))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl * so)
    rows = [[-so + zero, co + zero, zero], [-sl * co, -sl * so, cl + zero],
            [cl * co, cl * so, sl + zero]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


@dataclass(frozen=True)
class LocalFrame:
    """The scene's local ENU frame: origin on the WGS84 ellipsoid at (lat, lon, h)."""

    lat_deg: float
    lon_deg: float
    h_m: float = 0.0

    @property
    def origin_ecef_m(self) -> np.ndarray:
        return geodetic_to_ecef(self.lat_deg, self.lon_deg, self.h_m)

    @property
    def enu_from_ecef(self) -> np.ndarray:
        return enu_matrix(self.lat_deg, self.lon_deg)

    def ecef_to_enu(self, xyz_m: np.ndarray) -> np.ndarray:
        """ECEF points (..., 3) to ENU points (..., 3), m."""
        return (np.asarray(xyz_m) - self.origin_ecef_m) @ self.enu_from_ecef.T

    def enu_to_ecef(self, enu_m: np.ndarray) -> np.ndarray:
        """ENU points (..., 3) to ECEF points (..., 3), m."""
        return np.asarray(enu_m) @ self.enu_from_ecef + self.origin_ecef_m

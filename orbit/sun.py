"""Solar position from UTC: the Astronomical Almanac's low-precision formulae (~0.01 deg).

References
----------
.. [1] The Astronomical Almanac, section C "Sun: low precision formulas" (1950-2050:
   0.01 deg in right ascension and declination).
"""

from __future__ import annotations

import numpy as np

from orbit.frames import eci_to_ecef_matrix, enu_matrix, gmst_rad, julian_date

_J2000_JD = 2451545.0
#: rate of the mean sun's longitude = a sun-synchronous orbit's node rate, deg/day
SUN_MEAN_MOTION_DEG_DAY = 0.9856474


def _days(epoch_utc: np.datetime64, t_s) -> np.ndarray:
    return julian_date(epoch_utc) - _J2000_JD + np.asarray(t_s, dtype=np.float64) / 86400.0


def sun_mean_longitude_deg(epoch_utc: np.datetime64, t_s=0.0) -> np.ndarray:
    """Mean longitude of the Sun (= right ascension of the fictitious mean sun), deg."""
    return np.mod(280.460 + SUN_MEAN_MOTION_DEG_DAY * _days(epoch_utc, t_s), 360.0)


def sun_direction_eci(epoch_utc: np.datetime64, t_s=0.0) -> np.ndarray:
    """Unit vectors (..., 3) from the Earth's centre toward the Sun, in the ECI frame."""
    n = _days(epoch_utc, t_s)
    lam_mean = np.deg2rad(280.460 + SUN_MEAN_MOTION_DEG_DAY * n)
    g = np.deg2rad(357.528 + 0.9856003 * n)
    lam = lam_mean + np.deg2rad(1.915 * np.sin(g) + 0.020 * np.sin(2.0 * g))
    eps = np.deg2rad(23.439 - 4.0e-7 * n)
    return np.stack([np.cos(lam), np.cos(eps) * np.sin(lam), np.sin(eps) * np.sin(lam)], axis=-1)


def sun_elevation_azimuth_deg(
    lat_deg: float, lon_deg: float, epoch_utc: np.datetime64, t_s=0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Sun elevation above the local horizon and azimuth (from north toward east), deg.

    Geodetic horizon at (lat, lon); the Sun's parallax (8.8 arcsec) and refraction are ignored.
    """
    s_eci = sun_direction_eci(epoch_utc, t_s)
    s_ecef = np.einsum("...ij,...j->...i", eci_to_ecef_matrix(gmst_rad(epoch_utc, t_s)), s_eci)
    e, n, u = np.moveaxis(s_ecef @ enu_matrix(lat_deg, lon_deg).T, -1, 0)
    el = np.rad2deg(np.arcsin(np.clip(u, -1.0, 1.0)))
    az = np.mod(np.rad2deg(np.arctan2(e, n)), 360.0)
    return el, az


def local_mean_solar_time_h(lon_deg, epoch_utc: np.datetime64, t_s=0.0) -> np.ndarray:
    """Local mean solar time (hours in [0, 24)) at longitude lon_deg."""
    ut_h = (_days(epoch_utc, t_s) + 0.5) % 1.0 * 24.0
    return np.mod(ut_h + np.asarray(lon_deg) / 15.0, 24.0)

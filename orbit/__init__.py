"""Orbit propagation, Earth frames (WGS84), solar position and spacecraft attitude.

- `kepler`: Keplerian orbits with J2 secular rates; `tle`: SGP4 from a two-line element set;
  `oem_orbit`: an ephemeris from a CCSDS OEM; `aircraft`: straight, level flight;
- `frames`: ECI, ECEF and the local ENU frame; `sun`: the solar position;
- `attitude`: nominal pointing, yaw steering and jitter; `jitter`: sinusoids, PSD draws,
  wheel harmonics; `attitude_series`: measured attitude (CSV, CCSDS AEM) as the jitter, with
  `ccsds` the CCSDS frames and times; `suspension`: the camera's mount between platform and
  camera.

Units: SI (m, s, rad) inside; angles in degrees only where a name says ``_deg``.
Frames are described in ``docs/conventions.md``.
"""

from orbit.attitude import Attitude
from orbit.frames import (
    LocalFrame,
    ecef_to_geodetic,
    eci_to_ecef_matrix,
    geodetic_to_ecef,
    gmst_rad,
)
from orbit.jitter import JitterSeries, JitterTerm, RandomJitter, WheelJitter, realize_jitter
from orbit.kepler import EarthOrbit, Orbit, sun_synchronous_inclination_deg
from orbit.sun import sun_direction_eci, sun_elevation_azimuth_deg
from orbit.tle import TleOrbit

__all__ = [
    "Attitude",
    "EarthOrbit",
    "JitterSeries",
    "JitterTerm",
    "LocalFrame",
    "Orbit",
    "RandomJitter",
    "TleOrbit",
    "WheelJitter",
    "ecef_to_geodetic",
    "eci_to_ecef_matrix",
    "geodetic_to_ecef",
    "gmst_rad",
    "realize_jitter",
    "sun_direction_eci",
    "sun_elevation_azimuth_deg",
    "sun_synchronous_inclination_deg",
]

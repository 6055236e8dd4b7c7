"""Orbit propagation, Earth frames (WGS84) and spacecraft attitude (pointing + jitter).

Units: SI (m, s, rad) inside; angles in degrees only where a name says ``_deg``.
Frames are described in ``docs/conventions.md``.
"""

from orbit.attitude import Attitude, JitterTerm
from orbit.frames import (
    LocalFrame,
    ecef_to_geodetic,
    eci_to_ecef_matrix,
    geodetic_to_ecef,
    gmst_rad,
)
from orbit.kepler import CircularOrbit

__all__ = [
    "Attitude",
    "CircularOrbit",
    "JitterTerm",
    "LocalFrame",
    "ecef_to_geodetic",
    "eci_to_ecef_matrix",
    "geodetic_to_ecef",
    "gmst_rad",
]

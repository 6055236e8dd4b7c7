import numpy as np
import pytest
from geographiclib.geodesic import Geodesic

from orbit.frames import ecef_to_geodetic, geodetic_to_ecef, gmst_rad, julian_date
from orbit.kepler import CircularOrbit

EPOCH = np.datetime64("2026-06-21T10:30:00")


def test_period_681km_is_98_3_min():
    orb = CircularOrbit(681e3, 98.1, 0.0, 0.0, EPOCH)
    # IKONOS: 681 km, ~98.3 min (two-body, spherical Earth of WGS84 radius: 98.4 min)
    assert orb.period_s / 60.0 == pytest.approx(98.3, abs=0.15)


def test_ground_speed_about_6_8_km_s():
    orb = CircularOrbit.over_point(35.0, 10.0, 681e3, 98.1, EPOCH)
    v = orb.ground_speed_mps(np.array([0.0, 100.0, 1000.0]))
    assert np.all(np.abs(v - 6800.0) < 150.0)


def test_over_point_puts_the_satellite_over_the_scene():
    for descending in (True, False):
        orb = CircularOrbit.over_point(35.0, 10.0, 681e3, 98.1, EPOCH, descending=descending)
        r, _ = orb.state_ecef(0.0)
        p = geodetic_to_ecef(35.0, 10.0, 0.0)
        ang = np.linalg.norm(np.cross(r, p)) / np.linalg.norm(r) / np.linalg.norm(p)
        assert ang < 1e-10  # rad: 0.7 mm on the ground
        # the pass direction: descending moves south
        lat1 = orb.ground_point(10.0)[0]
        assert (lat1 < 35.0) == descending


def test_unreachable_latitude_is_a_value_error():
    with pytest.raises(ValueError, match="not reachable"):
        CircularOrbit.over_point(60.0, 0.0, 681e3, 45.0, EPOCH)


def test_geodetic_round_trip_below_a_millimetre():
    lat = np.array([-89.0, -35.5, 0.0, 12.25, 60.0, 88.9])
    lon = np.array([-179.0, -20.0, 0.0, 10.5, 100.0, 179.9])
    h = np.array([0.0, -50.0, 681e3, 8848.0, 100.0, 2000.0])
    la, lo, hh = ecef_to_geodetic(geodetic_to_ecef(lat, lon, h))
    assert np.all(np.abs(la - lat) * 111e3 < 1e-3)
    assert np.all(np.abs(((lo - lon + 180) % 360) - 180) * 111e3 < 1e-3)
    assert np.all(np.abs(hh - h) < 1e-3)


def test_gmst_at_j2000_and_sidereal_rate():
    j2000 = np.datetime64("2000-01-01T12:00:00")
    assert julian_date(j2000) == 2451545.0
    assert np.rad2deg(gmst_rad(j2000)) == pytest.approx(280.46061837, abs=1e-9)
    # one sidereal day later the angle is back
    assert float(gmst_rad(j2000, 86164.0905)) == pytest.approx(float(gmst_rad(j2000)), abs=1e-6)


def test_ground_track_length_matches_geographiclib():
    orb = CircularOrbit.over_point(35.0, 10.0, 681e3, 98.1, EPOCH)
    t = np.linspace(0.0, 60.0, 61)
    lat, lon, _ = orb.ground_point(t)
    steps = [Geodesic.WGS84.Inverse(lat[i], lon[i], lat[i + 1], lon[i + 1])["s12"]
             for i in range(len(t) - 1)]
    total = Geodesic.WGS84.Inverse(lat[0], lon[0], lat[-1], lon[-1])["s12"]
    # a minute of ground track is ~408 km and nearly a geodesic
    assert sum(steps) == pytest.approx(total, rel=1e-4)
    assert sum(steps) / 60.0 == pytest.approx(6800.0, abs=150.0)

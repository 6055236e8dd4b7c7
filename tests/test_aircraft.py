"""The aircraft platform: image velocity v f / h, the camera suspension, the rendered geometry
at flight height, and the refusals of impossible flights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.signal import lsim

from camera.geometry import FocalPlane, project
from camera.motion import CameraModel
from imc.scenario import ScenarioError, parse_scenario
from orbit.aircraft import Aircraft, AircraftAttitude
from orbit.frames import LocalFrame
from orbit.jitter import JitterTerm, realize_jitter
from orbit.suspension import Suspension

ROOT = Path(__file__).resolve().parents[1]

EPOCH = np.datetime64("2026-06-21T10:30:00")
FRAME = LocalFrame(48.1, 11.3, 0.0)
FLIGHT = ROOT / "scenarios" / "flight_test.yaml"


def _camera(height_m: float, fp: FocalPlane, track_deg: float = 90.0, speed: float = 67.0,
            jitter=(), **look) -> CameraModel:
    plane = Aircraft.over_point(FRAME, height_m, speed, track_deg, EPOCH, 0.0,
                                roll_deg=look.get("roll_deg", 0.0),
                                pitch_deg=look.get("pitch_deg", 0.0))
    mode = "off_nadir" if look else "nadir"
    return CameraModel(plane, AircraftAttitude(mode, jitter=tuple(jitter), **look), FRAME, fp)


def _flat(e, n):
    return np.zeros_like(np.asarray(e, dtype=np.float64))


@pytest.mark.parametrize("track_deg", [90.0, 37.0])
def test_image_velocity_at_nadir_is_v_f_over_h_along_rows(track_deg):
    """Over flat ground at nadir the image moves at v f / (h pitch) px/s toward +row, whatever
    the heading; the ECEF/ECI round trip of the pose leaves < 1e-9 of it."""
    fp = FocalPlane(0.110, 20.625e-6, 256, 288)
    cam = _camera(2400.0, fp, track_deg)
    expected = 67.0 * 0.110 / (2400.0 * 20.625e-6)  # 148.9 px/s: 0.45 m pixels at 67 m/s
    v = cam.velocity_field_px_s(fp.center_px[None], 0.0, _flat)[0]
    assert v[0] == pytest.approx(expected, rel=1e-9)
    assert abs(v[1]) < 1e-9 * expected
    # ... and the exact projection moves the ground by that much in 0.5 s
    ground = cam.ground_points(fp.center_px[None], 0.0, _flat)
    mo = cam.image_motion_px(ground, np.array([0.5]), 0.0)[0, 0]
    assert mo[0] == pytest.approx(0.5 * expected, rel=1e-9)
    assert cam.orbit.ground_speed_mps(0.0) == 67.0
    assert cam.orbit.heading_deg(0.0) == track_deg
    lat, lon, h = cam.orbit.ground_point(0.0)
    assert float(h) == pytest.approx(2400.0, abs=1e-3)  # over the frame's origin at t = 0


def test_off_nadir_aircraft_looks_where_it_was_placed_and_flows_along_rows():
    """+pitch looks ahead, +roll left (the satellite's signs): the line of sight meets the
    scene origin at t = 0 and the boresight's image still flows exactly along +row."""
    fp = FocalPlane(0.110, 20.625e-6, 256, 256)
    cam = _camera(2400.0, fp, 0.0, pitch_deg=10.0, roll_deg=5.0)
    p = cam.pose(np.array(0.0))
    assert np.abs(project(np.zeros(3), p, fp) - fp.principal_point_px).max() < 1e-6
    assert p.position_m[1] < 0.0 and p.position_m[0] > 0.0  # behind (south), right (east)
    v = cam.velocity_field_px_s(fp.center_px[None], 0.0, _flat)[0]
    assert v[0] > 100.0 and abs(v[1]) < 1e-9 * v[0]
    assert float(cam.attitude.off_nadir_deg(cam.orbit, 0.0)) == pytest.approx(
        np.rad2deg(np.arccos(np.cos(np.deg2rad(10.0)) * np.cos(np.deg2rad(5.0)))), abs=1e-9)


def test_jitter_moves_the_aircraft_image_as_the_conventions_say():
    """+pitch moves the image toward +row and +roll toward +col by angle / IFOV; the analytic
    image velocity matches a finite difference of the projection (< 1e-5 relative)."""
    fp = FocalPlane(0.110, 20.625e-6, 256, 256)
    jit = [JitterTerm("pitch", 0.0, 3.0 * fp.ifov_rad, np.pi / 2),
           JitterTerm("roll", 0.0, 2.0 * fp.ifov_rad, -np.pi / 2)]
    still = _camera(2400.0, fp)
    shaken = _camera(2400.0, fp, jitter=jit)
    ground = still.ground_points(fp.center_px[None], 0.0, _flat)
    d = shaken.project(ground, np.array(0.0)) - still.project(ground, np.array(0.0))
    assert d[0, 0] == pytest.approx(3.0, abs=2e-3) and d[0, 1] == pytest.approx(-2.0, abs=2e-3)
    wavy = _camera(2400.0, fp, jitter=[JitterTerm("pitch", 7.0, 2.0 * fp.ifov_rad),
                                       JitterTerm("yaw", 3.0, 1e-3)])
    pts = wavy.ground_points(np.array([[10.0, 20.0], [200.0, 240.0]]), 0.3, _flat)
    dt = 1e-4
    fd = (wavy.image_motion_px(pts, np.array([0.3 + dt]), 0.3)
          - wavy.image_motion_px(pts, np.array([0.3 - dt]), 0.3))[0] / (2 * dt)
    v = wavy.image_velocity_px_s(pts, np.array([0.3]))[0]
    assert np.abs(v - fd).max() < 1e-5 * np.abs(v).max()


def test_suspension_at_its_cutoff_and_in_the_time_domain():
    """H(f_c) = 1 / (2 zeta) at -90 deg; the filtered jitter series equals the steady state of
    the mass-spring-damper ODE driven by the platform's jitter (lsim), within 0.5 % of the
    input amplitude (the ODE starts at rest, its transient decays as exp(-zeta w_c t): after
    4 s at zeta 0.3, w_c 2 pi 5 it is e^-38)."""
    s = Suspension(cutoff_hz=5.0, damping=0.3)
    h = s.response(5.0)
    assert abs(h) == pytest.approx(1.0 / 0.6, rel=1e-12)
    assert np.angle(h, deg=True) == pytest.approx(-90.0, abs=1e-9)
    assert abs(s.response(50.0)) == pytest.approx(1.0 / 99.0, rel=0.01)  # (f_c / f)^2
    assert abs(s.response(0.05)) == pytest.approx(1.0, abs=1e-3)
    amp = 1e-4
    terms = [JitterTerm("pitch", 5.0, amp, 0.3), JitterTerm("pitch", 1.0, amp, 1.0),
             JitterTerm("pitch", 26.5, amp, 2.0)]
    platform = realize_jitter(terms, 1.0, np.random.default_rng(0))
    camera = s.apply(platform)
    t = np.arange(0.0, 6.0, 1e-4)
    w = 2 * np.pi * s.cutoff_hz
    _, y, _ = lsim(([w * w], [1.0, 2 * s.damping * w, w * w]), platform.rotvec_rad(t)[:, 1], t)
    late = t > 4.0
    assert np.abs(y[late] - camera.rotvec_rad(t[late])[:, 1]).max() < 5e-3 * amp
    # at the cut-off the camera moves 1 / (2 zeta) = 1.67 x the platform
    only_fc = s.apply(realize_jitter(terms[:1], 1.0, np.random.default_rng(0)))
    assert only_fc.amplitude_rad[0] == pytest.approx(amp / 0.6, rel=1e-12)


def _flight(**changes) -> dict:
    data = yaml.safe_load(FLIGHT.read_text())
    for key, value in changes.items():
        node = data
        *path, last = key.split(".")
        for p in path:
            node = node.setdefault(p, {})
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    return data


def test_flight_test_scenario_geometry():
    """The paper's camera: 0.45 m pixels from 2,400 m, 149 px/s of flow along the rows (v f /
    h within the ground's relief: 0.3 % per 7 m), heading east, nadir."""
    from imc.outputs.report import geometry_summary
    from imc.wiring.build import build_models

    sc = parse_scenario(_flight(**{"scene.size_m": 512, "scene.texel_m": 0.5,
                                   "duration_s": 1.0}), "flight")
    g = geometry_summary(build_models(sc))
    assert g["gsd_m"] == pytest.approx(0.45, rel=0.005)
    assert g["image_velocity_px_s"][0] == pytest.approx(148.9, rel=0.005)
    assert abs(g["image_velocity_px_s"][1]) < 1e-6
    assert g["ground_speed_mps"] == 67.0 and g["heading_deg"] == 90.0
    assert g["off_nadir_deg"] == 0.0 and g["orbit_period_s"] is None


@pytest.mark.parametrize("changes, field", [
    ({"orbit.height_m": 20.0, "scene.relief_rms_m": 15.0}, "orbit.height_m"),
    ({"orbit.ground_speed_mps": 900.0, "orbit.height_m": 300.0}, "orbit.ground_speed_mps"),
    ({"attitude.mode": "target"}, "attitude.mode"),
    ({"orbit.height_m": None}, "height_m"),
    ({"orbit.kind": "sun_synchronous"}, "aircraft"),
    ({"scene.kind": "mountain", "orbit.height_m": 1000.0}, "orbit.height_m"),
])
def test_impossible_flights_are_refused_in_one_line(changes, field):
    """Below the highest terrain (or a mountain's cloud tops), an image that crosses the
    tracker within one frame, a staring aircraft, a missing height: one line naming it."""
    from imc.wiring.build import build_models

    data = _flight(**{"scene.size_m": 512, "scene.texel_m": 0.5, "duration_s": 1.0,
                      **changes})
    with pytest.raises(ScenarioError) as e:
        build_models(parse_scenario(data, "flight.yaml"))
    msg = str(e.value)
    assert field in msg and "\n" not in msg


@pytest.fixture(scope="module")
def urban():
    from scene.classes import scene_class

    return scene_class("urban", 256.0, 0.16, 2.0, np.random.default_rng(4))


@pytest.mark.parametrize("height_m", [2400.0, 300.0])
def test_rendered_attitude_step_at_flight_height_within_0p01_px(urban, height_m):
    """A 0.3 / -0.2 px attitude step rendered from an aircraft (0.45 m pixels, f = 110 mm at
    2,400 m; the same pixels from 300 m, where rays start half-way down) is measured as the
    camera model predicts: mean of four 112^2 blocks within 0.01 px, each within 0.025 px
    (Monte Carlo noise ~0.006 px per block at spp 16, tests/test_scene_fidelity.py)."""
    from conftest import attitude_step_error

    from scene.kernel import Renderer, Sun

    n = 256
    cam = _camera(height_m, FocalPlane(0.110, 0.45 * 0.110 / height_m, n, n), 30.0)
    r = Renderer(urban, Sun(50.0, 140.0), n, n, spp=16, ceiling_m=height_m)
    assert r.z_start_m < height_m
    err, predicted, valid = attitude_step_error(r, cam, urban.height_at)
    assert valid.all()
    assert np.abs(predicted).min() > 0.15
    assert np.abs(err.mean(axis=0)).max() < 0.01
    assert np.abs(err).max() < 0.025

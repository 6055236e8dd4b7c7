"""Pins the one sign convention of docs/conventions.md across stages."""

import numpy as np
import pytest

from camera.geometry import FocalPlane, project
from camera.motion import CameraModel
from correlator import measure_shift
from orbit.attitude import Attitude
from orbit.frames import LocalFrame
from orbit.jitter import JitterTerm
from orbit.kepler import Orbit

EPOCH = np.datetime64("2026-06-21T10:30:00")
FP = FocalPlane(10.0, 12e-6, 256, 256)


def _model(mode="target", jitter=()):
    frame = LocalFrame(35.0, 10.0, 0.0)
    orb = Orbit.over_point(35.0, 10.0, 681e3, 98.1, EPOCH)
    att = Attitude(mode=mode, target_ecef_m=tuple(frame.origin_ecef_m) if mode == "target"
                   else None, jitter=jitter)
    return CameraModel(orb, att, frame, FP)


def _centre_motion(model, t):
    ground = model.ground_points(FP.center_px[None], 0.0, lambda e, n: 0.0 * e)
    return model.image_motion_px(ground, np.atleast_1d(t), 0.0)[:, 0]


@pytest.mark.parametrize("axis, index", [("pitch", 0), ("roll", 1)])
def test_positive_pitch_moves_rows_positive_roll_moves_cols(axis, index):
    amp = 2.0 * FP.ifov_rad  # 2 px
    cam = _model(jitter=(JitterTerm(axis, 1.0, amp),))
    still = _model()
    m = _centre_motion(cam, 0.25) - _centre_motion(still, 0.25)  # sin peaks at t = 0.25 s
    assert m[0, index] == pytest.approx(2.0, abs=0.01)
    assert abs(m[0, 1 - index]) < 0.01


def test_target_mode_holds_the_image_still():
    m = _centre_motion(_model("target"), np.linspace(0.0, 1.0, 11))
    assert np.abs(m).max() < 0.01


def test_nadir_mode_ground_flows_toward_plus_row():
    m = _centre_motion(_model("nadir"), np.array([0.01]))
    # ~6.8 km/s over a ~0.82 m GSD: ~83 px in 10 ms, along +row; without yaw steering the
    # Earth's rotation (0.38 km/s across the track at 35 deg) crabs it by ~5.6 % in columns
    assert m[0, 0] == pytest.approx(83.0, rel=0.05)
    assert 0.03 * m[0, 0] < abs(m[0, 1]) < 0.08 * m[0, 0]


def test_stage_offset_moves_content_by_minus_s():
    cam = _model()
    pose = cam.pose(np.array(0.0))
    pt = cam.ground_points(np.array([[100.0, 50.0]]), 0.0, lambda e, n: 0.0 * e)
    base = project(pt, pose, FP)
    moved = project(pt, pose, FP, offset_px=(0.3, -0.7))
    assert np.allclose(moved - base, [[-0.3, 0.7]], atol=1e-9)


def test_correlator_shift_is_displacement_of_cur_content():
    rng = np.random.default_rng(3)
    img = rng.normal(size=(100, 100))
    ref = img[20:84, 20:84]
    cur = img[17:81, 22:86]  # cur(x) = img(x + (-3, +2)) = ref(x - (3, -2))
    r = measure_shift(ref, cur)
    assert np.allclose(r.shift, [3.0, -2.0], atol=1e-3)
    assert r.valid

import numpy as np
import pytest

from camera.geometry import FocalPlane
from camera.sensor import SensorModel


def test_nadir_gsd_is_0_817_m():
    """681 km over the equator (where the orbit radius is a + 681 km): GSD = H * IFOV."""
    from camera.motion import CameraModel
    from orbit.attitude import Attitude
    from orbit.frames import LocalFrame
    from orbit.kepler import CircularOrbit

    epoch = np.datetime64("2026-06-21T10:30:00")
    frame = LocalFrame(0.0, 10.0, 0.0)
    cam = CameraModel(CircularOrbit.over_point(0.0, 10.0, 681e3, 98.1, epoch),
                      Attitude("target", tuple(frame.origin_ecef_m)), frame,
                      FocalPlane(10.0, 12e-6, 256, 256))
    pix = np.array([[127.5, 127.5], [127.5, 128.5], [128.5, 127.5]])
    g = cam.ground_points(pix, 0.0, lambda e, n: 0.0 * e)
    assert np.linalg.norm(g[1] - g[0]) == pytest.approx(0.817, abs=0.001)
    assert np.linalg.norm(g[2] - g[0]) == pytest.approx(0.817, abs=0.001)


def test_ifov_is_1_2_urad():
    fp = FocalPlane(10.0, 12e-6, 256, 256)
    assert fp.ifov_rad == pytest.approx(1.2e-6)


def test_ground_points_project_back_to_their_pixels(camera_model):
    rng = np.random.default_rng(0)
    pix = rng.uniform(0, 255, size=(50, 2))

    def hill(e, n):
        return 60.0 * np.exp(-(e**2 + n**2) / 80.0**2)

    for t in (0.0, 0.37):
        g = camera_model.ground_points(pix, t, hill)
        assert np.allclose(g[:, 2], hill(g[:, 0], g[:, 1]), atol=1e-3)
        back = camera_model.project(g, np.array(t))
        assert np.abs(back - pix).max() < 1e-6


def test_relief_parallax_matches_h_over_H(camera_model):
    """A point h above the ground moves against a ground point by ~ h * dtheta * f / pitch."""
    fp = camera_model.focal_plane
    top = camera_model.ground_points(fp.center_px[None], 0.0, lambda e, n: 0.0 * e + 100.0)
    low = top.copy()
    low[:, 2] = 0.0
    t = np.array([0.5])
    m_top = camera_model.image_motion_px(top, t, 0.0)[0, 0]
    m_low = camera_model.image_motion_px(low, t, 0.0)[0, 0]
    # staring: the line of sight turns by v t / H; a 100 m tall point shifts by h * angle / GSD
    r0 = camera_model.pose(np.array(0.0)).position_m
    r1 = camera_model.pose(t).position_m[0]
    angle = np.linalg.norm((r1 - r0)[:2]) / r0[2]
    expected = 100.0 * angle / (r0[2] * fp.ifov_rad)
    assert np.linalg.norm(m_top - m_low) == pytest.approx(expected, rel=0.02)


def test_sensor_noise_and_quantisation():
    s = SensorModel(mean_signal_dn=100.0, noise_sigma_dn=10.0, adc_bits=12)
    rad = np.full((256, 256), 0.2)
    gain = s.gain_for(rad)
    frame = s.expose(rad, gain, np.random.default_rng(1))
    assert frame.dtype == np.uint16
    assert frame.mean() == pytest.approx(100.0, abs=0.2)
    # rounding adds 1/12 DN^2 of variance
    assert frame.std() == pytest.approx(np.sqrt(100.0 + 1 / 12), rel=0.02)
    assert s.snr == 10.0
    sat = s.expose(rad * 100, gain, np.random.default_rng(1))
    assert sat.max() == 4095
    with pytest.raises(ValueError, match="black"):
        s.gain_for(np.zeros((4, 4)))

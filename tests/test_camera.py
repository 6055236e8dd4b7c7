import numpy as np
import pytest

from camera.geometry import FocalPlane
from camera.motion import CameraModel
from camera.sensor import SensorModel


def test_nadir_gsd_is_0_817_m():
    """681 km over the equator (where the orbit radius is a + 681 km): GSD = H * IFOV."""
    from camera.motion import CameraModel
    from orbit.attitude import Attitude
    from orbit.frames import LocalFrame
    from orbit.kepler import Orbit

    epoch = np.datetime64("2026-06-21T10:30:00")
    frame = LocalFrame(0.0, 10.0, 0.0)
    cam = CameraModel(Orbit.over_point(0.0, 10.0, 681e3, 98.1, epoch),
                      Attitude("target", target_ecef_m=tuple(frame.origin_ecef_m)), frame,
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
    s = SensorModel(mean_signal_dn=100.0, noise_sigma_dn=10.0, adc_bits=12,
                    noise_model="additive")
    rad = np.full((256, 256), 0.2)
    gain = s.gain_for(rad)
    frame = s.expose(rad * gain, np.random.default_rng(1))
    assert frame.dtype == np.uint16
    assert frame.mean() == pytest.approx(100.0, abs=0.2)
    # rounding adds 1/12 DN^2 of variance
    assert frame.std() == pytest.approx(np.sqrt(100.0 + 1 / 12), rel=0.02)
    assert s.snr() == pytest.approx(10.0 / np.sqrt(1 + 1 / 1200), rel=1e-9)
    sat = s.expose(rad * gain * 100, np.random.default_rng(1))
    assert sat.max() == 4095
    with pytest.raises(ValueError, match="black"):
        s.gain_for(np.zeros((4, 4)))


def test_physical_noise_has_the_predicted_variance_and_full_well():
    s = SensorModel(noise_model="physical", noise_sigma_dn=0.0, gain_e_per_dn=4.0,
                    full_well_e=20000.0, read_noise_e=10.0, dark_current_e_per_s=500.0,
                    adc_bits=12)
    e, t = 400.0, 0.01
    frame = s.expose(np.full((512, 512), e), np.random.default_rng(2), t)
    # shot (400 + 5 dark) + read 100 -> 505 e^2 = 31.6 DN^2, plus 1/12 of quantisation
    assert frame.mean() == pytest.approx((e + 5.0) / 4.0, abs=0.05)
    assert frame.std() == pytest.approx(float(s.noise_sigma_dn_at(e, t)), rel=0.02)
    assert s.snr(e, t) == pytest.approx(100.0 / np.sqrt(505 / 16 + 1 / 12), rel=1e-9)
    full = s.expose(np.full((8, 8), 1e6), np.random.default_rng(2), t)
    assert np.all(full == 5000) or np.all(full == 4095)  # full well 20 ke = 5000 DN > 12 bit


def test_diffraction_mtf_ikonos_figures():
    from camera.optics import Optics

    o = Optics(focal_length_m=10.0, aperture_m=0.70, wavelength_m=0.675e-6,
               pixel_pitch_m=12e-6)
    # F/14.3: cut-off 1 / (lambda N) = 103.7 cycles/mm = 1.244 cycles/px; Nyquist x = 0.402
    assert o.cutoff_cycles_per_px == pytest.approx(1.2444, abs=0.0005)
    x = 0.5 / o.cutoff_cycles_per_px
    expected = 2 / np.pi * (np.arccos(x) - x * np.sqrt(1 - x * x))
    assert float(o.mtf(0.5)) == pytest.approx(expected, rel=1e-12)
    assert float(o.mtf(0.5)) == pytest.approx(0.502, abs=0.003)
    assert float(o.mtf(0.0)) == 1.0 and float(o.mtf(3.0)) == 0.0
    # the filter applies exactly that MTF to a Nyquist-frequency pattern along columns
    img = np.tile(np.cos(np.pi * np.arange(64))[None, :], (64, 1)) + 1.0
    out = o.apply(img)
    assert np.ptp(out[:, 10:54]) / 2 == pytest.approx(float(o.mtf(0.5)), rel=1e-9)
    psf = o.psf(17, 4)
    assert psf.sum() == pytest.approx(1.0) and psf.argmax() == np.ravel_multi_index(
        (34, 34), psf.shape)


def _scanning_camera(yaw_steering: bool, roll_deg: float = 0.0, jitter=()):
    from orbit.attitude import Attitude, orbit_looking_at
    from orbit.frames import LocalFrame

    epoch = np.datetime64("2026-06-21T10:30:00")
    orbit = orbit_looking_at(35.0, 10.0, 681e3, 98.1, epoch, roll_deg=roll_deg)
    att = Attitude("off_nadir" if roll_deg else "nadir", roll_deg=roll_deg,
                   yaw_steering=yaw_steering, jitter=jitter)
    fp = FocalPlane(10.0, 12e-6, 32, 1024)
    return CameraModel(orbit, att, LocalFrame(35.0, 10.0, 0.0), fp)


def _tdi_smear(cam, imager, line_rate):
    flat = lambda e, n: 0.0 * e  # noqa: E731
    g = cam.ground_points(cam.focal_plane.center_px[None], 0.0, flat)
    t = np.linspace(0.0, imager.integration_s(line_rate), 201)
    r = cam.image_motion_px(g, t, 0.0)[:, 0] - imager.charge_motion_px(t, line_rate)
    return r[-1] - r[0], r


@pytest.mark.parametrize("roll_deg", [0.0, 20.0])
def test_tdi_synchronous_line_rate_has_no_smear_and_2pc_mismatch_gives_0_02_n(roll_deg):
    from camera.imager import TdiImager, synchronous_line_rate_hz, tdi_linear_smear_px

    cam = _scanning_camera(True, roll_deg)
    flat = lambda e, n: 0.0 * e  # noqa: E731
    v = cam.velocity_field_px_s(cam.focal_plane.center_px, 0.0, flat)[0]
    sync = synchronous_line_rate_hz(v)
    assert abs(v[1]) < 1e-3  # yaw steering: the ground flows along the rows only
    tdi = TdiImager(stages=32)
    smear, _ = _tdi_smear(cam, tdi, sync)
    assert np.abs(smear).max() < 0.01
    # image 2 % faster than the charge: 0.02 N px along track
    smear, _ = _tdi_smear(cam, tdi, sync / 1.02)
    assert smear[0] == pytest.approx(0.02 * 32, rel=0.01)
    assert tdi_linear_smear_px(v[0], sync / 1.02, 32) == pytest.approx(0.64, rel=1e-9)


def test_without_yaw_steering_earth_rotation_smears_tdi_across_track():
    from camera.imager import TdiImager, synchronous_line_rate_hz

    cam = _scanning_camera(False)
    v = cam.velocity_field_px_s(cam.focal_plane.center_px, 0.0, lambda e, n: 0.0 * e)[0]
    # the Earth turns 0.38 km/s under a 6.8 km/s track at 35 deg: a ~3.5 deg crab
    assert np.degrees(np.arctan2(abs(v[1]), v[0])) == pytest.approx(3.5, abs=0.7)
    smear, _ = _tdi_smear(cam, TdiImager(stages=32), synchronous_line_rate_hz(v))
    assert abs(smear[1]) == pytest.approx(32 * abs(v[1]) / v[0], rel=0.01)


def test_predicted_velocity_equals_finite_differences_of_the_projection():
    from orbit.jitter import JitterTerm, RandomJitter, WheelJitter, realize_jitter

    ifov = 1.2e-6
    jit = realize_jitter([JitterTerm("roll", 0.65, ifov), JitterTerm("pitch", 4.3, 0.1 * ifov),
                          RandomJitter("yaw", 0.05 * ifov, 1.0, 50.0),
                          WheelJitter("pitch", 35.0, ((1, 0.02 * ifov), (2, 0.02 * ifov)),
                                      speed_rate_hz_s=2.0)],
                         2.0, np.random.default_rng(5))
    hill = lambda e, n: 100.0 * np.exp(-(e**2 + n**2) / 200.0**2)  # noqa: E731
    for cam in (_scanning_camera(True, 20.0, jit), _scanning_camera(False, 0.0, jit)):
        pix = np.array([[0.0, 0.0], [16.0, 512.0], [31.0, 1000.0]])
        g = cam.ground_points(pix, 0.4, hill)
        v = cam.image_velocity_px_s(g, np.array([0.4]))[0]
        dt = 1e-5
        fd = (cam.image_motion_px(g, np.array([0.4 + dt]), 0.4)
              - cam.image_motion_px(g, np.array([0.4 - dt]), 0.4))[0] / (2 * dt)
        # ~8,000 px/s; central differences are good to ~1e-3 px/s at this step
        assert np.abs(v - fd).max() < 5e-3


def test_poisson_draw_is_exact_and_local():
    """Counts are the exact Poisson quantiles of one uniform per pixel (scipy's ppf), and a
    one-ulp change of one pixel's mean cannot shift the draws of the other pixels."""
    from scipy import stats

    from camera.sensor import poisson_draw

    lam = np.random.default_rng(0).uniform(0.0, 3e4, 4000)
    lam[:500] = np.random.default_rng(1).uniform(0.0, 30.0, 500)
    got = poisson_draw(lam, np.random.default_rng(5))
    u = np.random.default_rng(5).random(lam.shape)
    assert np.array_equal(got, stats.poisson.ppf(u, lam))
    bumped = lam.copy()
    bumped[7] = np.nextafter(bumped[7], np.inf)
    again = poisson_draw(bumped, np.random.default_rng(5))
    assert np.array_equal(np.delete(again, 7), np.delete(got, 7))

"""The loop's blocks alone: known responses of actuators, controllers, estimators, the
transport, and line identification."""

import dataclasses

import numpy as np
import pytest
from scipy.signal import lfilter

from compensation.actuators import IdealStage, PiezoStage, _cycle_width
from compensation.blocks import BlockMeasurements, ControlInput
from compensation.controllers import (
    PI,
    PII,
    Integrator,
    KalmanPredictor,
    Notch,
    find_lines,
    polyval_x,
)
from compensation.estimators import MeanEstimator, MotionFieldEstimator
from compensation.loop import Trajectory
from compensation.registry import build, kinds
from compensation.transport import Transport


def _run_actuator(act, commands, t_end):
    """Trajectory of an actuator given [(t, (row, col)), ...] commands."""
    st = act.init(0.0)
    traj = Trajectory(act.interpolation, 0.0)
    for t, u in commands:
        st, ts, ss = act.advance(st, t)
        traj.append(ts, ss)
        st = act.command(st, t, np.asarray(u, float))
    st, ts, ss = act.advance(st, t_end)
    traj.append(ts, ss)
    return traj, st


def test_registry_lists_every_kind():
    assert kinds("controller") == ("integrator", "kalman", "pi", "pii")
    assert kinds("actuator") == ("ideal", "piezo")
    assert kinds("estimator") == ("mean", "motion_field")
    with pytest.raises(ValueError, match="unknown controller kind 'pid'"):
        build("controller", "pid")


def test_ideal_stage_holds_clips_and_counts_saturation():
    act = IdealStage(stroke_px=2.0)
    traj, st = _run_actuator(act, [(0.1, (0.5, 0.0)), (0.2, (3.0, 0.0)), (0.5, (0.0, 0.0))], 1.0)
    assert traj(np.array([0.05, 0.15, 0.3, 0.7]))[:, 0].tolist() == [0.0, 0.5, 1.0, 0.0]
    # clipped at +1 px (half the stroke) from 0.2 s to 0.5 s
    assert act.saturated_s(st) == pytest.approx(0.3)
    # exposure means are exact, also across a step
    assert traj.mean(0.15, 0.25)[0] == pytest.approx(0.5 * 0.5 + 0.5 * 1.0)


def test_ideal_stage_ramp_is_a_first_order_hold():
    act = IdealStage(ramp=True, ramp_s=0.1)
    traj, _ = _run_actuator(act, [(0.0, (1.0, 0.0)), (0.1, (1.0, 2.0)), (0.15, (0.0, 0.0))],
                            0.5)
    s = traj(np.array([0.05, 0.1, 0.125, 0.15, 0.2, 0.25, 0.4]))
    # the third command cuts the second ramp at (1, 1) and ramps from there to (0, 0)
    assert s[:, 0] == pytest.approx([0.5, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0])
    assert s[:, 1] == pytest.approx([0.0, 0.0, 0.5, 1.0, 0.5, 0.0, 0.0])
    assert act.lag_s == pytest.approx(0.05)


def test_piezo_step_settles_rings_at_its_resonance_and_is_quantised():
    act = PiezoStage(update_hz=20_000.0, resonance_hz=400.0, damping=0.05, stroke_px=4.0,
                     dac_bits=8)
    traj, _ = _run_actuator(act, [(0.0, (1.0, 0.0))], 0.2)
    t, s = traj.samples
    q = 4.0 / 256
    assert s[-1, 0] == pytest.approx(np.round(1.0 / q) * q, abs=1e-6)  # DC gain 1, quantised
    # overshoot of a second-order step: exp(-pi zeta / sqrt(1 - zeta^2)) = 0.855
    assert s[:, 0].max() - s[-1, 0] == pytest.approx(0.855 * s[-1, 0], rel=0.02)
    # ringing period = 1 / (f_n sqrt(1 - zeta^2))
    peaks = t[1:-1][(s[1:-1, 0] > s[:-2, 0]) & (s[1:-1, 0] >= s[2:, 0])]
    assert np.median(np.diff(peaks[:6])) == pytest.approx(1 / (400 * np.sqrt(1 - 0.05**2)),
                                                         rel=0.01)


def test_piezo_drive_notch_replaces_the_mode_by_a_damped_one():
    """The drive notch's zeros cancel the 300 Hz mode (damping 0.05: 85 % overshoot) and its
    poles put a 900 Hz mode of damping 0.7 in its place: the step then overshoots as that
    mode does, exp(-pi 0.7 / sqrt(1 - 0.49)) = 4.6 %, with DC gain 1; an identification
    5 % off leaves a small ring of the true mode; a large step clips the boosted drive at
    the DAC's range and counts as saturated."""
    plain = dict(update_hz=18_000.0, resonance_hz=300.0, damping=0.05, stroke_px=None,
                 dac_bits=None)
    act = PiezoStage(**plain, drive_notch_hz=300.0)
    traj, _ = _run_actuator(act, [(0.0, (1.0, 0.0))], 0.1)
    s = traj.samples[1][:, 0]
    assert s[-1] == pytest.approx(1.0, abs=1e-6)
    assert s.max() - 1.0 == pytest.approx(np.exp(-np.pi * 0.7 / np.sqrt(1 - 0.49)), abs=0.01)
    # the same as a stage whose own mode is that target, within the discretisation
    target = PiezoStage(**{**plain, "resonance_hz": 900.0, "damping": 0.7})
    t_traj, _ = _run_actuator(target, [(0.0, (1.0, 0.0))], 0.1)
    assert np.abs(s - t_traj.samples[1][:, 0]).max() < 0.02
    off = PiezoStage(**plain, drive_notch_hz=315.0)
    s_off = _run_actuator(off, [(0.0, (1.0, 0.0))], 0.1)[0].samples[1][:, 0]
    assert 0.05 < s_off.max() - 1.0 < 0.3 and s_off[-1] == pytest.approx(1.0, abs=0.01)
    assert act.lag_s == pytest.approx(2 * 0.7 / (2 * np.pi * 900))  # the target's group delay
    clipped = PiezoStage(**{**plain, "stroke_px": 4.5}, drive_notch_hz=300.0)
    _, st = _run_actuator(clipped, [(0.0, (2.0, 0.0))], 0.1)
    assert 0 < clipped.saturated_s(st) < 0.01
    with pytest.raises(ValueError, match="drive_notch_hz"):
        PiezoStage(**plain, drive_target_hz=900.0)
    with pytest.raises(ValueError, match="4 x the drive notch"):
        PiezoStage(**{**plain, "update_hz": 3000.0}, drive_notch_hz=300.0)


def test_piezo_update_rate_makes_room_for_the_drive_notch_and_old_states_restore():
    """The wiring's DAC rate: a multiple of the frame rate at or above 20 x the resonance and
    4 x the drive notch's frequencies; a state written before a field was added restores
    with that field's default."""
    from compensation.state import from_arrays, to_arrays
    from imc.wiring.build import piezo_update_hz

    assert piezo_update_hz(1000.0, 300.0) == 6000.0
    assert piezo_update_hz(1000.0, 300.0, 1600.0) == 7000.0
    PiezoStage(update_hz=7000.0, resonance_hz=300.0, drive_notch_hz=300.0,
               drive_target_hz=1600.0)
    act = PiezoStage(update_hz=6000.0, resonance_hz=300.0, drive_notch_hz=300.0)
    st = act.advance(act.command(act.init(0.0), 0.0, np.array([0.5, 0.0])), 0.01)[0]
    arrays = {k: v for k, v in to_arrays("a", st).items() if not k.startswith("a/shaper")}
    old = from_arrays("a", type(st), arrays)
    assert np.array_equal(old.x, st.x) and np.array_equal(old.shaper, np.zeros((2, 2)))


def test_piezo_drive_notch_recovers_the_rigid_stages_rejection():
    """1 kHz, 2 frames, every loop at its largest integrator gain with peak |S| <= 2: a
    300 Hz stage keeps 79 % of the rigid stage's rejection at 10 Hz; the drive notch (to a
    900 Hz, 0.7-damped mode) brings it above 80 % even with the mode identified 5 % off
    (measured 86.5 / 87.6 / 85.6 % exact / 5 % low / 5 % high)."""
    from compensation.analytic import LoopModel, max_integrator_gain

    r = 1000.0

    def rejection(act):
        m = LoopModel(r, 1 / r, 1 / r, Integrator(rate_hz=r), act)
        g = max_integrator_gain(m)
        m = dataclasses.replace(m, controller=Integrator(rate_hz=r, gain=g))
        return 1.0 / abs(m.rejection([10.0])[0])

    rigid = rejection(IdealStage())
    plain = dict(update_hz=6000.0, resonance_hz=300.0, stroke_px=None, dac_bits=None)
    assert rejection(PiezoStage(**plain)) / rigid < 0.8
    for f in (285.0, 315.0):
        assert rejection(PiezoStage(**plain, drive_notch_hz=f)) / rigid > 0.8


def test_piezo_hysteresis_width_slew_and_creep():
    # the calibrated Bouc-Wen loop is hysteresis_pct of the stroke wide
    act = PiezoStage(update_hz=20_000.0, stroke_px=4.5, hysteresis_pct=12.0, dac_bits=None)
    alpha, beta = act._hysteresis
    assert _cycle_width(alpha, beta, 4.5) == pytest.approx(0.12 * 4.5, rel=1e-3)
    # slew: a 1 px step at 100 px/s takes 10 ms
    slew = PiezoStage(update_hz=20_000.0, resonance_hz=2000.0, slew_px_s=100.0, dac_bits=None)
    traj, _ = _run_actuator(slew, [(0.0, (1.0, 0.0))], 0.05)
    assert traj(np.array([0.005]))[0, 0] == pytest.approx(0.5, abs=0.02)
    # creep: the step response still grows by ~creep per decade after the mode has settled
    creep = PiezoStage(update_hz=8_000.0, creep_pct_per_decade=2.0, dac_bits=None)
    traj, _ = _run_actuator(creep, [(0.0, (1.0, 0.0))], 12.0)
    x = traj(np.array([0.12, 1.2, 12.0]))[:, 0]
    assert np.diff(x) == pytest.approx([0.02, 0.02], abs=0.006)


def _impulse(ctl, n=64):
    st, out = ctl.init(), []
    for j in range(n):
        e = np.array([1.0 if j == 0 else 0.0, 0.0])
        inp = ControlInput(j * 1e-3, j * 1e-3, e, np.zeros(2), np.zeros(2), np.full(2, 0.01),
                           True, 1e-3)
        st, u = ctl.update(st, inp)
        out.append(u[0])
    return np.array(out)


@pytest.mark.parametrize("ctl", [
    Integrator(rate_hz=1000.0, gain=0.4, leak=0.01),
    PI(rate_hz=1000.0, kp=0.3, ki=0.2),
    PII(rate_hz=1000.0, kp=0.2, ki=0.3, kii=0.05),
    Integrator(rate_hz=1000.0, gain=0.4, notch=Notch(300.0, 60.0, 30.0)),
])
def test_feedback_controllers_follow_their_transfer_function(ctl):
    b, a = ctl.transfer()
    imp = np.zeros(64)
    imp[0] = 1.0
    assert _impulse(ctl) == pytest.approx(lfilter(b, a, imp), abs=1e-12)


def test_notch_depth_and_unity_dc_gain():
    b, a = Notch(300.0, 60.0, 30.0).coefficients(1000.0)
    z = np.exp(2j * np.pi * np.array([0.0, 300.0]) / 1000.0)
    g = np.abs(polyval_x(b, z) / polyval_x(a, z))
    assert g[0] == pytest.approx(1.0)
    assert 20 * np.log10(g[1]) == pytest.approx(-30.0, abs=1e-6)


def test_invalid_measurement_holds_the_command():
    ctl = Integrator(rate_hz=100.0, gain=0.5)
    st = ctl.init()
    inp = ControlInput(0.0, 0.0, np.array([9.0, 9.0]), np.zeros(2), np.array([0.3, -0.1]),
                       np.full(2, np.inf), False, 0.01)
    st2, u = ctl.update(st, inp)
    assert u.tolist() == [0.3, -0.1] and st2 is st


def test_kalman_predicts_a_ramp_to_the_middle_of_the_next_hold():
    ctl = KalmanPredictor(rate_hz=100.0, order=2, bandwidth_hz=5.0, identify=False,
                          lead_s=0.0)
    st = ctl.init()
    v = 3.0  # px/s
    for k in range(200):
        t_meas = k * 0.01 + 0.005
        inp = ControlInput(t_meas + 0.005, t_meas, np.array([v * t_meas, -v * t_meas]),
                           np.zeros(2), np.zeros(2), np.full(2, 0.01), True, 0.01)
        st, u = ctl.update(st, inp)
    # the command holds from t_meas + 0.005 for 0.01 s: aim at its middle, 0.01 s ahead
    assert u == pytest.approx([v * (t_meas + 0.01), -v * (t_meas + 0.01)], abs=1e-6)


def test_find_lines_recovers_sinusoids_in_noise_and_nothing_in_noise_alone():
    rng = np.random.default_rng(4)
    t = np.arange(2000) * 1e-3
    z = np.zeros((2000, 2))
    z[:, 0] = (0.5 * np.sin(2 * np.pi * 1.3 * t + 0.2) + 0.3 * np.sin(2 * np.pi * 7.0 * t)
               + 0.05 * np.sin(2 * np.pi * 65.0 * t + 1.0) + 0.2 * t)
    noisy = z + 0.02 * rng.standard_normal(z.shape)
    found = np.sort(find_lines(t, noisy, 0.75, 40.0, 4, np.empty(0)))
    assert found == pytest.approx([1.3, 7.0, 65.0], abs=0.03)
    assert len(find_lines(t, 0.02 * rng.standard_normal(z.shape), 0.75, 40.0, 4,
                          np.empty(0))) == 0


def _meas(shift, sigma, centers, valid=None, predicted=None, field=(0.0, 0.0), frame=5):
    n = len(shift)
    return BlockMeasurements(
        frame, 0.05, np.zeros(n, int), np.asarray(centers, float), np.asarray(shift, float),
        np.asarray(sigma, float), np.ones(n, bool) if valid is None else np.asarray(valid),
        np.full(n, 20.0), np.zeros(n), np.zeros(n, bool),
        np.zeros((n, 2)) if predicted is None else np.asarray(predicted, float),
        np.asarray(field, float))


def test_motion_field_fit_finds_the_field_point_motion_and_rejects_an_outlier():
    centers = np.array([[40, 40], [40, 216], [216, 40], [216, 216], [128, 60], [128, 196],
                        [60, 128]], float)
    fp = np.array([140.0, 120.0])
    t, scale, rot = np.array([0.3, -0.2]), 2e-3, 1e-3
    d = centers - fp
    shift = t + scale * d + rot * np.column_stack([d[:, 1], -d[:, 0]])
    sigma = np.full_like(shift, 0.01)
    est = MotionFieldEstimator(field_point_px=tuple(fp), model="similarity")
    st, out = est.update(est.init(7), _meas(shift, sigma, centers), np.zeros(2),
                         np.zeros((7, 2)))
    assert out.motion_px == pytest.approx(t, abs=1e-9) and out.model == "similarity"
    bad = shift.copy()
    bad[3] += [0.8, 0.0]  # one block locked on a wrong peak
    st, out = est.update(est.init(7), _meas(bad, sigma, centers), np.zeros(2),
                         np.zeros((7, 2)))
    assert out.outliers.tolist() == [False, False, False, True, False, False, False]
    assert out.motion_px == pytest.approx(t, abs=1e-9)
    # the mean estimator is the plain mean (today's)
    st, out = MeanEstimator().update(MeanEstimator().init(7), _meas(shift, sigma, centers),
                                     np.zeros(2), np.zeros((7, 2)))
    assert out.motion_px == pytest.approx(shift.mean(axis=0))


def test_motion_field_adds_back_the_prediction_and_the_stage():
    centers = np.array([[64, 64], [64, 192], [192, 64], [192, 192]], float)
    pred = np.array([[0.1, 0.0], [0.2, 0.0], [-0.1, 0.0], [0.0, 0.05]])  # relief parallax
    jitter = np.array([0.4, -0.3])
    stage = np.array([0.25, 0.1])
    shift = pred + jitter - stage  # the detectors moved with the stage
    est = MotionFieldEstimator(field_point_px=(128.0, 128.0))
    _, out = est.update(est.init(4), _meas(shift, np.full((4, 2), 0.01), centers,
                                           predicted=pred, field=(0.07, 0.01)),
                        stage, np.zeros((4, 2)))
    assert out.motion_px == pytest.approx(jitter + [0.07, 0.01], abs=1e-9)


def test_transport_latency_schedule_drops_and_channel():
    m = _meas(np.zeros((2, 2)), np.full((2, 2), 0.01), [[0, 0], [1, 1]])
    tr = Transport(latency_s=0.002)
    _, t, out = tr.send(tr.init(), m, 0.01)
    assert t == pytest.approx(0.012) and out is m
    sched = Transport(deliver_s=np.full(10, np.inf))
    assert sched.send(sched.init(), m, 0.01)[1] is None  # the device processed nothing
    lossy = Transport(drop_probability=0.5, seed=(1, 9))
    arrived = [lossy.send(lossy.init(), dataclasses.replace(m, frame=k), 0.0)[1] is not None
               for k in range(200)]
    assert 0.35 < np.mean(arrived) < 0.65
    assert arrived == [lossy.send(lossy.init(), dataclasses.replace(m, frame=k), 0.0)[1]
                       is not None for k in range(200)]  # the same draws again
    chan = Transport(channel=lambda meas, t: dataclasses.replace(
        meas, valid=np.array([True, False])))
    assert chan.send(chan.init(), m, 0.0)[2].valid.tolist() == [True, False]

"""The ground's record in a run (imc.wiring.links, imc.wiring.restitution): the analytic
plant's chain and its links, the network's record in the product, stage + ground against the
stage alone, and the geometry-only product against the rendered one."""

import numpy as np
import pytest
import yaml

from compensation.loop import simulate
from imc.pipeline import run_scenario
from imc.scenario import parse_scenario
from imc.wiring.build import build_loop, build_models
from imc.wiring.links import measure_links, overlap_baselines
from imc.wiring.rendered_plant import build_plant
from tests.test_product import TDI


def _scenario(**changes) -> dict:
    d = yaml.safe_load(yaml.safe_dump(TDI))
    for path, value in changes.items():
        cur = d
        keys = path.split(".")
        for k in keys[:-1]:
            cur = cur.setdefault(k, {})
        cur[keys[-1]] = value
    return d


def _loop(d: dict):
    m = build_models(parse_scenario(d))
    plant = build_plant(m)
    parts = build_loop(m, None, float(np.mean(plant.sigma_px)))
    res = simulate(plant, parts.estimator, parts.controller, parts.actuator, parts.transport,
                   parts.timeline, enabled=m.scenario.compensation.enabled,
                   supervisor=parts.supervisor)
    return m, plant, res


def test_the_analytic_plant_chains_and_its_first_baseline_is_the_loops_own():
    # a scanning view: the analytic plant re-references every frame as the image plants do,
    # and the ground's baseline-1 links carry the loop's own measurement noise
    m, plant, res = _loop(_scenario())
    assert m.chain and plant.chain
    assert np.all(res.record.ref_frame[2:, 0] == np.arange(1, len(m.frame_t_s) - 1))
    links = measure_links(m, res.record, plant, np.zeros((len(m.frame_t_s), 2)), k_max=1)
    assert np.all(links.baseline == 1) and links.valid.all()
    # the loop's shift less the plant's own prediction and the stage is the link's jitter
    # increment, block by block: their means agree to rounding
    rec = res.record
    k = np.arange(1, len(m.frame_t_s))
    pred = np.stack([plant.predict_between(int(i) - 1, int(i))[0] for i in k])
    stage = plant.stage_mean[k] - plant.stage_mean[k - 1]
    w = 1.0 / plant.sigma_px**2  # (B, 2): the link is the blocks' inverse-variance mean
    loop_d = ((rec.shift_px[k] - pred + stage[:, None, :]) * w).sum(axis=1) / w.sum(axis=0)
    np.testing.assert_allclose(links.d_px, loop_d, atol=1e-9)
    # more baselines: each frame against up to K earlier ones
    assert overlap_baselines(m) >= 3
    more = measure_links(m, rec, plant, np.zeros((len(m.frame_t_s), 2)), k_max=3)
    assert set(np.unique(more.baseline)) == {1, 2, 3}


def test_consecutive_chain_links_share_their_frames_noise():
    # rho = 0.1 of each link's variance per frame: consecutive links correlate by -0.1
    from compensation.analytic_plant import AnalyticPlant

    t = np.arange(4001) / 200.0
    plant = AnalyticPlant(lambda tt: np.zeros((len(tt), 1, 2)), np.zeros((1, 2)), 0.01, t,
                          1e-4, seed=(5,), chain=True)
    a, b, d, _, _ = plant.pair_links(1)
    e = d[:, 0, :]
    corr = [np.corrcoef(e[:-1, i], e[1:, i])[0, 1] for i in range(2)]
    assert np.std(e) == pytest.approx(0.01, rel=0.05)
    np.testing.assert_allclose(corr, -0.1, atol=3 / np.sqrt(len(e)))


def _geometry(tmp_path, name, **changes) -> dict:
    sc = parse_scenario(_scenario(**{"product.render": False, **changes}))
    metrics, _ = run_scenario(sc, tmp_path / name, rerun=False)
    return metrics["product"]


def test_stage_and_ground_is_never_worse_than_the_stage_and_better_above_its_band(tmp_path):
    # a deliberately noisy record (0.3 px a block, a bare chain, no smoother): the ground
    # must not add its noise to what the stage left
    noisy = _geometry(tmp_path, "noisy", **{
        "plant.sigma_px": 0.3, "product.restitution": {"baselines": 1, "smoother": False},
        "attitude.jitter": {"sinusoids": [{"axis": "roll", "frequency_hz": 3.0,
                                           "amplitude_px": 0.5}]}})
    g = noisy["geometry"]["closed"]
    stage_only, both = np.array(g["before"]["rms_px"]), np.array(g["after"]["rms_px"])
    open_after = np.array(noisy["geometry"]["open"]["after"]["rms_px"])
    # the record errs across track as much as the stage leaves (the noise drives both: the
    # region noise model of the chain gives 0.18 against 0.18 px), so applied whole it
    # would not help
    assert open_after[1] > 0.9 * stage_only[1]
    assert np.all(both <= 1.1 * stage_only)
    # a 45 Hz roll line above a slow stage's band (an integrator at 5 Hz): the record
    # resolves it (200 Hz) and the ground removes what the stage leaves
    fast = _geometry(tmp_path, "fast", **{
        "attitude.jitter": {"sinusoids": [{"axis": "roll", "frequency_hz": 45.0,
                                           "amplitude_px": 0.3}]},
        "compensation.controller": {"kind": "integrator", "gain": 0.3}})
    g = fast["geometry"]["closed"]
    assert np.array(g["before"]["rms_px"])[1] > 0.05
    assert np.array(g["after"]["rms_px"])[1] < 0.5 * np.array(g["before"]["rms_px"])[1]


def test_the_record_is_the_networks_and_predicts_its_error(tmp_path):
    p = _geometry(tmp_path, "net")
    rec = p["record"]
    assert rec["restitution"]["baselines"] >= 3 and rec["restitution"]["links"] > 24
    # the predicted error after an affine is the size of the measured one (both ways)
    measured = np.array(p["geometry"]["open"]["affine"]["rms_px"])
    predicted = np.array(rec["predicted"]["affine_px"])
    assert np.all(measured < 3.0 * predicted) and np.all(measured > predicted / 3.0)
    # control points fused in the solve: the absolute error is bounded without a constant
    cp = _geometry(tmp_path, "gcp", **{"product.ground_control": {"points": 3,
                                                                  "sigma_px": 0.002}})
    absolute = np.array(cp["geometry"]["open"]["control_points"]["rms_px"])
    assert np.all(absolute < 0.02)


def test_the_grounds_pairs_stay_inside_the_sensors_margin():
    # a 256-row tracker, 64-px blocks at rows 32 and 160, content moving 83 px (2 frames),
    # 166 px (4 frames): each pair's reference and current block stay 8 px inside the
    # sensor (its edges carry the optics' periodic wrap), the loop's cut where it fits, and
    # a block whose reference would repeat another's content is not used
    from imc.wiring.links import OVERLAP_MARGIN_PX, pair_corners

    corners = np.array([[32, 16], [32, 144], [160, 16], [160, 144]])
    lim = np.array([256 - 64, 256 - 64])
    for rows, kept in ((20, 4), (83, 4), (166, 2)):
        step = np.tile([rows, 0.4], (4, 1))
        out, used = pair_corners(corners, step, 64, lim)
        assert used.sum() == kept
        for c in (out[used], out[used] + np.rint(step[used]).astype(int)):
            assert c.min() >= OVERLAP_MARGIN_PX and np.all(c <= lim - OVERLAP_MARGIN_PX)
        if rows == 20:  # it fits: the loop's chain cut, half the motion before the block
            assert np.array_equal(out, corners - [10, 0])
    _, used = pair_corners(corners, np.tile([250.0, 0.0], (4, 1)), 64, lim)
    assert not used.any()  # the content leaves the sensor: no block


def test_chain_links_share_the_frames_noise_over_the_pixels_they_share():
    # a frame's noise field over the blocks each pair is measured on: pairs from one
    # reference region share half their variance (the rendered no_stage.yaml's ground pairs:
    # 0.40-0.53), consecutive loop links the overlap of a block moved by 41.5 px (rendered
    # -0.08 / -0.12), every link keeps its variance
    from compensation.analytic_plant import AnalyticPlant
    from imc.wiring.links import pair_corners

    corners = np.array([[32, 32], [32, 160], [160, 32], [160, 160]])
    step = np.array([41.5, 0.0])

    def regions(a, b):
        st = np.tile(step * (b - a), (4, 1))
        ref, used = pair_corners(corners, st, 64, np.array([192, 192]))
        return ref, ref + np.rint(st).astype(int), used

    plant = AnalyticPlant(lambda tt: np.zeros((len(tt), 4, 2)), corners + 31.5, 0.01,
                          np.arange(2001) / 200.0, 1e-4, seed=(5,), chain=True,
                          pair_regions=regions, frame_shape=(256, 256), block_px=64)
    a, b, d, _, valid = plant.pair_links(4)
    j = b - a
    for k in range(1, 5):
        assert np.std(d[j == k][valid[j == k]]) == pytest.approx(0.01, rel=0.05)
    by = {(int(x), int(y)): d[i, 0] for i, (x, y) in enumerate(zip(a, j, strict=True))}
    x = np.array([(by[(r, 2)], by[(r, 3)]) for r in range(1900)])
    same_ref = [np.corrcoef(x[:, 0, ax], x[:, 1, ax])[0, 1] for ax in range(2)]
    np.testing.assert_allclose(same_ref, 0.5, atol=0.08)
    loop = d[j == 1].mean(axis=1)
    lag1 = [np.corrcoef(loop[:-1, ax], loop[1:, ax])[0, 1] for ax in range(2)]
    assert all(-0.2 < c < -0.05 for c in lag1)


def test_the_analytic_floor_is_drawn_unreported_and_the_record_consistency_finds_it():
    # a link error the bound leaves out (the rendered tracker's Monte Carlo floor): drawn with
    # the sensor's noise at hypot(sigma, floor), reported at sigma; the blocks' scatter about
    # their link (the record's consistency, imc.wiring.links) reads hypot / sigma, as on the
    # rendered record; floor 0 keeps today's draws
    from compensation.analytic_plant import AnalyticPlant
    from imc.wiring.links import combine_blocks, pair_corners

    corners = np.array([[32, 32], [32, 160], [160, 32], [160, 160]])
    step = np.array([41.5, 0.3])

    def regions(a, b):
        st = np.tile(step * (b - a), (4, 1))
        ref, used = pair_corners(corners, st, 64, np.array([192, 192]))
        return ref, ref + np.rint(st).astype(int), used

    def plant(floor, eff=1.0):
        return AnalyticPlant(lambda tt: np.zeros((len(tt), 4, 2)), corners + 31.5, 0.011,
                             np.arange(1001) / 200.0, 2e-4, seed=(5,), chain=True,
                             pair_regions=regions, frame_shape=(256, 256), block_px=64,
                             floor_px=floor, efficiency=eff)

    floor = np.array([0.0064, 0.0056])
    a, b, d, sig, valid = plant(floor).pair_links(4)
    np.testing.assert_array_equal(sig[valid], 0.011)  # reported: the bound alone
    drawn = np.hypot(0.011, floor)
    np.testing.assert_allclose(np.std(d[valid], axis=0), drawn, rtol=0.05)
    _, _, nblk, chi2 = combine_blocks(d, sig, valid)
    ok = nblk >= 2
    eff = np.sqrt(chi2[ok].sum(axis=0) / (nblk[ok] - 1).sum())
    np.testing.assert_allclose(eff, drawn / 0.011, rtol=0.05)
    assert np.all(eff > 1.1)  # the effect it checks: 1.16 / 1.12, against 1.0 without
    d0 = plant(0.0).pair_links(4)[2]
    _, _, _, chi0 = combine_blocks(d0, sig, valid)
    np.testing.assert_allclose(np.sqrt(chi0[ok].sum(axis=0) / (nblk[ok] - 1).sum()), 1.0,
                               rtol=0.05)
    # the correlator's efficiency on the texture scales the bound's part, not the report
    _, _, d2, sig2, _ = plant(floor, 1.3).pair_links(4)
    np.testing.assert_array_equal(sig2[valid], 0.011)
    np.testing.assert_allclose(np.std(d2[valid], axis=0), np.hypot(1.3 * 0.011, floor),
                               rtol=0.05)
    with pytest.raises(ValueError, match="floor_px"):
        plant(-0.01)
    with pytest.raises(ValueError, match="efficiency"):
        plant(0.0, 0.0)


def test_the_grounds_pairs_carry_no_sub_pixel_phase_bias():
    # two band-limited textures (urban, 1/f^2.5), the current frame moved by an exact Fourier
    # phase ramp 41 px + phi along the rows, noise-free: the ground's pair measurement
    # (integer cut, the correlator's sub-pixel) errs by <= 0.23e-3 px on average at every
    # phase; a cubic-spline resampling of the current block at the predicted motion (the
    # ground's way before) moves the content by +2.1..+4.1e-3 px more at a quarter pixel and
    # -0.9..-1.8e-3 at 0.93, an error a chain's links share per baseline (a drift)
    import scipy.fft as sfft

    from correlator.tracker import BlockTracker
    from imc.wiring.links import measure_pair

    rng = np.random.default_rng(3)
    size = 256
    fy, fx = sfft.fftfreq(size)[:, None], sfft.rfftfreq(size)[None, :]
    f = np.hypot(fy, fx)
    corners = np.array([[96, 32], [96, 160]])
    spectra = {"urban": 1.0 / (1.0 + (f / 0.2) ** 2),
               "power law 2.5": 1.0 / np.maximum(f, 1.0 / size) ** 1.25}
    for name, amp in spectra.items():
        amp = amp * (f < 0.45) * np.exp(-(f / 0.3) ** 2)
        amp[0, 0] = 0.0
        for phase in (0.25, 0.93):
            cut, spline = [], []
            for _ in range(8):
                spec = (rng.normal(size=amp.shape) + 1j * rng.normal(size=amp.shape)) * amp
                d = np.array([41.0 + phase, rng.uniform(-0.3, 0.3)])
                a = sfft.irfft2(spec, s=(size, size))
                b = sfft.irfft2(spec * np.exp(-2j * np.pi * (fy * d[0] + fx * d[1])),
                                s=(size, size))
                gain = 25.0 / a.std()
                a, b = a * gain + 100.0, b * gain + 100.0
                ref = corners - np.rint(d / 2).astype(int)
                pred = np.tile(d, (2, 1))
                cut.append(measure_pair(a, b, ref, pred, 64).shift[:, 0] - d[0])
                flow = np.broadcast_to(pred[:, None, None, :], (2, 64, 64, 2))
                spline.append(BlockTracker(a, ref, 64).update(b, pred, flow=flow).shift[:, 0]
                              - d[0])
            cut_bias, spline_bias = np.mean(cut), np.mean(spline)
            assert abs(cut_bias) < 3e-4, (name, phase, cut_bias)
            assert abs(spline_bias) > 2.5 * abs(cut_bias) + 5e-4, (name, phase, spline_bias)

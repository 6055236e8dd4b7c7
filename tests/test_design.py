"""`imc design`: the fast predictors against the time-domain loop, the search against an
exhaustive evaluation, the one-line refusals and exit codes, and the chosen design's YAML
validating and running."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from imc.cli import app
from imc.scenario import ScenarioError, load_scenario, parse_scenario
from imc.workflow.design import (
    choose,
    evaluate,
    load_design,
    pareto_front,
    parse_design,
    run_design,
)
from imc.workflow.predict import Disturbance, LoopChoice, loop_model, predict_loop

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def _base() -> dict:
    """The quickstart on a smaller tile, analytic plant, 0.6 s, one pitch sinusoid."""
    d = yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text())
    d["duration_s"] = 0.6
    d["scene"]["size_m"] = 200
    d["scene"]["texel_m"] = 0.5
    d["camera"]["tracker"].update(rows=128, cols=128)
    d["correlator"].update(block_px=32, n_blocks=4)
    d["plant"] = {"fidelity": "analytic"}
    d["metrics"]["blur_images"] = False
    d.pop("expect")
    return d


def _design(**over) -> dict:
    d = {"name": "toy", "base": _base(), "tracker_crlb_px": 0.02,
         "requirements": {"with_compensation.rms_total_px": {"max": 0.2}},
         "free": {"frame_rate_hz": [50, 100], "block_px": [16, 32], "n_blocks": [1, 4],
                  "controller": ["integrator"], "bandwidth_hz": [3, 10],
                  "stage": ["none", "ideal"]},
         "verify": {"designs": 1, "seeds": 1, "fidelity": "analytic"}}
    d.update(over)
    return d


def _simulate(model, amp_px: float, f_hz: float, sigma_px: float, seconds: float,
              seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(t, residual row) of the time-domain loop (compensation's simulate) on the analytic
    plant: one block, a pitch sinusoid, white measurement noise sigma_px."""
    from compensation.analytic_plant import AnalyticPlant, sinusoids
    from compensation.estimators import MeanEstimator
    from compensation.loop import Timeline, simulate
    from compensation.transport import Transport

    t_per = model.period_s
    n = int(round(seconds / t_per))
    frame_t = np.arange(n) * t_per
    motion = sinusoids([(amp_px, f_hz, 0.0, 0)])
    plant = AnalyticPlant(motion, np.zeros((1, 2)), sigma_px, frame_t, model.exposure_s,
                          seed=(seed,), noise_scale=1.0 if sigma_px > 0 else 0.0)
    tl = Timeline(frame_t, model.exposure_s, n * t_per, np.zeros((n, 2)), t_per)
    res = simulate(plant, MeanEstimator(), model.controller, model.actuator,
                   Transport(latency_s=model.latency_s), tl)
    ts = np.arange(int(2.0 / t_per) * 8, n * 8) * t_per / 8 + t_per / 16  # after 2 s
    r = amp_px * np.sin(2 * np.pi * f_hz * ts) - res.trajectory(ts)[:, 0]
    return ts, r


def _one_sine(f_hz: float, amp_px: float) -> dict:
    b = _base()
    b["attitude"]["jitter"]["sinusoids"] = [
        {"axis": "pitch", "frequency_hz": f_hz, "amplitude_px": amp_px, "phase_deg": 0}]
    b["duration_s"] = 6.0
    b["camera"]["main_imager"]["start_s"] = 2.0  # the metrics' window: after the transient
    return b


@pytest.mark.parametrize("f_hz", [0.7, 3.0])
def test_first_order_loop_on_a_sinusoid_matches_the_time_domain_loop(f_hz):
    base = parse_scenario(_one_sine(f_hz, 1.0))
    ch = LoopChoice(100.0, "integrator", 4.0, "ideal")
    pred = predict_loop(ch, base, Disturbance.from_scenario(base))
    model = loop_model(ch, base)
    _, r = _simulate(model, 1.0, f_hz, 0.0, 6.0)
    measured = float(np.sqrt(np.mean(r**2)))
    # the loop rejects the sinusoid (open: 0.707 px); the prediction within 3 % of the run
    assert measured < 0.5
    assert pred.rms_det_px[0] == pytest.approx(measured, rel=0.03)


def test_noise_gain_matches_the_time_domain_loop():
    base = parse_scenario(_one_sine(0.5, 0.0))
    ch = LoopChoice(100.0, "integrator", 8.0, "ideal")
    pred = predict_loop(ch, base, Disturbance.from_scenario(base))
    model = loop_model(ch, base)
    sigma = 0.05
    _, r = _simulate(model, 0.0, 0.5, sigma, 22.0)
    measured = float(np.sqrt(np.mean(r**2)))
    # the noise RMS differs from sigma by > 30 %; the prediction within 8 % (2000 frames)
    assert abs(measured / sigma - 1.0) > 0.3
    assert pred.noise_gain * sigma == pytest.approx(measured, rel=0.08)


def test_pareto_front_and_choice_on_a_toy_problem_with_a_known_optimum():
    rng = np.random.default_rng(5)
    cost = rng.uniform(0, 10, 300)
    margin = np.sqrt(cost) - 1.5 + rng.normal(0, 0.3, 300)  # dearer is better, noisily
    front = pareto_front(cost, margin)
    for i in range(300):  # brute force: dominated iff someone is cheaper-or-equal and better
        dominated = np.any((cost <= cost[i]) & (margin > margin[i])
                           | (cost < cost[i]) & (margin >= margin[i]))
        assert (i in front) == (not dominated)

    class C:  # the fields choose() reads
        feasible = margin >= 0
        worst = margin

    C.cost = cost
    i, _ = choose(C, 0.25)
    ok = np.flatnonzero(margin >= 0.25)
    assert i == ok[np.argmin(cost[ok])]


def test_search_choice_equals_an_exhaustive_evaluation_on_a_reduced_space():
    d = parse_design(_design())
    c = evaluate(d)
    assert len(c) == 2 * (2 * 1 + 1) * 2 * 2  # rates x (bw x ctl + none) x sizes x counts
    # every candidate predicted again on its own, the cheapest meeting the bound picked
    dist = Disturbance.from_scenario(d.base)
    best, best_cost = None, np.inf
    for i in range(len(c)):
        r = c.row(i)
        ch = LoopChoice(r["frame_rate_hz"], "integrator", r["bandwidth_hz"], r["stage"])
        p = predict_loop(ch, d.base, dist, lock=False)
        sigma = 0.02 * (32 / r["block_px"]) / np.sqrt(r["n_blocks"])
        total = np.sqrt(sum(x**2 for x in p.rms_det_px) + 2 * (p.noise_gain * sigma) ** 2)
        assert total == pytest.approx(r["predicted"]["with_compensation.rms_total_px"],
                                      rel=1e-9)
        if p.ok and (0.2 - total) / 0.2 >= 0.25 and r["cost"] < best_cost - 1e-12:
            best, best_cost = i, r["cost"]
    chosen, why = choose(c, 0.25)
    assert best is not None and chosen == best, why


def test_the_fast_search_equals_the_reference_evaluation_on_a_reduced_space():
    # the search's loops share their stage's work (StageShare: the stage's response in
    # closed form, the plant per grid, the held response, the actuator) and a Kalman steady
    # state across stages; the reference predicts each loop alone with compensation's
    # LoopModel: the same figures, feasible set, limits, Pareto front and choice
    d = parse_design(_design(
        requirements={"with_compensation.rms_total_px": {"max": 0.05},
                      "with_compensation.mtf_nyquist_worst": {"min": 0.995},
                      "loop.lock.analytic_s": {"max": 0.3}},
        free={"frame_rate_hz": [50, 200], "block_px": [16, 32], "n_blocks": [1, 4],
              "controller": ["integrator", "kalman"], "bandwidth_hz": [3, 20],
              "stage": ["none", "ideal", "piezo"], "piezo_resonance_hz": [357],
              "piezo_stroke_px": [2.5, 9]}))
    fast, ref = evaluate(d, workers=2), evaluate(d, fast=False)  # the workers: 6 groups
    assert fast.n_loops == 2 * (1 + 2 * 2 + 2 * 2) and len(fast) == len(ref)
    for path, v in ref.predicted.items():
        np.testing.assert_allclose(fast.predicted[path], v, rtol=1e-9, atol=0.0,
                                   err_msg=path)
    assert 0 < fast.feasible.sum() < len(fast)  # the bounds split the space
    assert np.array_equal(fast.feasible, ref.feasible)
    assert np.array_equal(fast.limiting, ref.limiting)
    assert np.array_equal(pareto_front(fast.cost, fast.worst), pareto_front(ref.cost, ref.worst))
    assert choose(fast, 0.25) == choose(ref, 0.25)


def test_the_closed_form_stage_response_matches_the_segment_sum():
    from compensation.analytic import _piecewise_fourier, linear_fourier

    rng = np.random.default_rng(11)
    t = 0.003 + np.arange(2001) * 2.5e-4  # a uniform grid not starting at 0
    s = np.cumsum(rng.normal(0.0, 0.05, t.size)) * np.exp(-t / 0.1)
    w = 2 * np.pi * np.concatenate([np.geomspace(1e-3, 10.0, 50), np.linspace(10.0, 3000, 300)])
    ld = np.longdouble  # the segment sum in extended precision: the truth
    truth = _piecewise_fourier(t.astype(ld), s.astype(ld), w.astype(ld), "linear",
                               t[-1]).astype(complex)
    ref = _piecewise_fourier(t, s, w, "linear", t[-1])
    got = linear_fourier(t, s, w)
    top = np.abs(truth).max()
    assert top / np.abs(truth).min() > 1e3  # the transform spans decades
    # the closed form within 1e-10 of the largest value everywhere (3e-11 here); the
    # segment sum in doubles (the model's own) loses 1.4e-7 at the lowest frequencies (each
    # segment's exponentials' difference), and agrees with it within that
    assert np.max(np.abs(got - truth)) < 1e-10 * top
    assert np.max(np.abs(got - ref)) < 1e-6 * top
    t_bent = t.copy()
    t_bent[7] += 1e-5  # not uniform: no closed form, the caller integrates by segments
    assert linear_fourier(t_bent, s, w) is None


@pytest.mark.parametrize("change, words", [
    ({"requirements": {"tracker.rms_error_px": {"max": 0.1}}},
     ["requirements", "supported", "with_compensation.rms_total_px"]),
    ({"free": {"bandwidth_hz": {"min": 5, "max": 2}}}, ["free.bandwidth_hz", "max"]),
    ({"free": {"stage": ["magnetic"]}}, ["free.stage"]),
    ({"extra_field": 1}, ["extra_field", "unknown field"]),
])
def test_bad_design_is_one_line_naming_the_field(change, words):
    d = _design()
    d.update(change)
    with pytest.raises(ScenarioError) as e:
        parse_design(d)
    text = str(e.value)
    assert "\n" not in text
    for w in words:
        assert w in text


def _write(tmp_path: Path, design: dict) -> Path:
    p = tmp_path / "design.yaml"
    p.write_text(yaml.safe_dump(design))
    return p


def test_an_infeasible_requirement_is_one_line_and_exit_1(tmp_path):
    d = _design(requirements={"with_compensation.rms_total_px": {"max": 1e-5}})
    res = runner.invoke(app, ["design", str(_write(tmp_path, d)), "--out",
                              str(tmp_path / "out"), "--no-verify", "--workers", "1"])
    assert res.exit_code == 1
    line = [x for x in res.output.splitlines() if "no candidate" in x]
    assert len(line) == 1 and "limited by with_compensation.rms_total_px" in line[0]
    assert (tmp_path / "out" / "design.json").exists()


def test_the_chosen_design_yaml_validates_and_runs(tmp_path):
    from imc.pipeline import run_scenario
    from imc.workflow.expect import judge

    d = load_design(_write(tmp_path, _design()))
    res = run_design(d, tmp_path / "out", verify_runs=False, log=lambda s: None)
    assert res.exit_code == 0
    yml = tmp_path / "out" / "toy_design.yaml"
    res_v = runner.invoke(app, ["validate", str(yml)])
    assert res_v.exit_code == 0, res_v.output
    sc = load_scenario(yml)
    assert "with_compensation.rms_total_px" in sc.expect
    short = copy.deepcopy(yaml.safe_load(yml.read_text()))
    short["duration_s"] = 0.4
    metrics, _ = run_scenario(parse_scenario(short), tmp_path / "run", rerun=False)
    outcomes = judge(sc.expect, metrics)
    assert outcomes and outcomes[0].value != "missing"
    page = (tmp_path / "out" / "design.html").read_text()
    assert page.count("base64") >= 1 and "Sensitivity to frame_rate_hz" in page


def test_verification_reports_predicted_against_measured(tmp_path):
    d = load_design(_write(tmp_path, _design()))
    res = run_design(d, tmp_path / "out", verify_runs=True, log=lambda s: None)
    (v,) = res.verified  # verify: 1 design, 1 seed
    measured = v["measured"]["with_compensation.rms_total_px"]
    assert len(measured) == 1 and np.isfinite(measured[0])
    assert np.isfinite(v["margin_error"]["with_compensation.rms_total_px"])
    import json

    rec = json.loads((tmp_path / "out" / "design.json").read_text())
    assert rec["validated_margin_error"] is not None
    assert "Predicted against measured" in (tmp_path / "out" / "design.html").read_text()


def test_the_refusal_names_every_supported_path():
    from imc.workflow.predict import SUPPORTED

    d = _design(requirements={"loop.commands": {"max": 1}})
    with pytest.raises(ScenarioError) as e:
        parse_design(d)
    for path in SUPPORTED:
        assert path.removesuffix(".0").removesuffix(".1") in str(e.value)


def test_the_tracker_predictor_scales_the_bound_by_the_plants_calibrated_efficiency():
    from imc.workflow.design import base_tracker_snr
    from imc.workflow.predict import correlator_efficiency

    d = parse_design(_design())
    model = correlator_efficiency("texture", d.base.scene.kind)
    assert model.spread > 0 and "calibrate" in model.source
    snr = base_tracker_snr(d)
    assert snr == pytest.approx(20.0, rel=0.05)  # the quickstart's tracker: 100 DN / 5 DN
    c_a = evaluate(parse_design(_design()))
    c_t = evaluate(parse_design(_design(verify={"designs": 1, "seeds": 1,
                                                "fidelity": "texture"})))
    # the same loops: the tracker's share of the residual (total^2 - the sinusoids') grows
    # by the efficiency (at its block size) squared; the efficiency moves it by > 15 %
    dist = Disturbance.from_scenario(parse_design(_design()).base)
    p_key = "with_compensation.rms_total_px"
    base = parse_design(_design()).base
    for i in range(len(c_a)):
        r = c_a.row(i)
        if r["stage"] == "none":
            continue
        p = predict_loop(LoopChoice(r["frame_rate_hz"], "integrator", r["bandwidth_hz"],
                                    "ideal"), base, dist, lock=False)
        det2 = sum(x**2 for x in p.rms_det_px)
        noise_a = c_a.predicted[p_key][i] ** 2 - det2
        noise_t = c_t.predicted[p_key][i] ** 2 - det2
        eff_b = model.at(snr, r["block_px"])  # at the candidate's block size
        assert noise_t / noise_a == pytest.approx(eff_b**2, rel=1e-6)
    assert abs(model.at(snr, 32) ** 2 - 1.0) > 0.15  # the candidates' blocks: 16, 32 px


def _esf_from_mtf(x_px: np.ndarray, mtf_fn) -> np.ndarray:
    """The edge spread function at distances x_px of a symmetric system with MTF mtf_fn:
    0.5 + (1 / pi) integral MTF(f) sin(2 pi f x) / f df (to 8 cycles/px)."""
    f = np.linspace(1e-6, 8.0, 4001)
    return 0.5 + np.trapezoid(mtf_fn(f)[None, :] * np.sin(2 * np.pi * f[None, :]
                                                          * x_px[:, None]) / f[None, :],
                              f, axis=1) / np.pi


def _edge_image(esf, angle_deg: float = 5.0, n: int = 96) -> np.ndarray:
    """A nearly horizontal edge (across the rows) through the image centre, turned
    angle_deg, each pixel the ESF at its centre's distance to the edge (a spread along the
    rows is in the ESF already)."""
    rr, cc = np.mgrid[0:n, 0:n].astype(float)
    a = np.deg2rad(angle_deg)
    d = ((rr - n / 2) - np.tan(a) * (cc - n / 2)) * np.cos(a)
    return 0.12 + 0.38 * esf(d)


def test_niirs_predictor_matches_giqe5_of_measured_edges():
    """The NIIRS predictor (RER from the system MTF times the motion MTF) against ground/
    quality.py's GIQE 5 of slanted edges measured on images (ISO 12233) whose ESF is the
    static system's, smeared in space by a 0.7 px linear drift along the rows and a
    Gaussian of 0.25 px along the columns."""
    from camera.optics import Optics
    from ground.quality import edge_figures, niirs_giqe5
    from imc.workflow.predict import NIIRS_FREQS, NiirsInputs

    optics = Optics()
    static = lambda f: optics.mtf(f) * np.abs(np.sinc(f))  # noqa: E731
    x = np.linspace(-10, 10, 2001)
    esf_s = _esf_from_mtf(x, static)
    drift, sigma = 0.9, 0.3
    s = np.linspace(-drift / 2, drift / 2, 91)  # the drift: the ESF averaged over it
    esf_drift = np.mean([np.interp(x - si, x, esf_s) for si in s], axis=0)
    g = np.linspace(-5 * sigma, 5 * sigma, 101)
    w = np.exp(-0.5 * (g / sigma) ** 2)
    esf_gauss = np.sum([wi * np.interp(x - gi, x, esf_s) for gi, wi in zip(g, w, strict=True)],
                       axis=0) / w.sum()

    def rer(esf_x):
        return edge_figures(_edge_image(lambda d: np.interp(d, x, esf_x))).rer

    gsd, snr, elev = 0.8, 12.0, np.pi / 2
    r_s, r_row, r_col = rer(esf_s), rer(esf_drift), rer(esf_gauss)
    measured = niirs_giqe5(r_s, r_s, gsd, snr, elev) - niirs_giqe5(r_row, r_col, gsd, snr, elev)
    ni = NiirsInputs(static(NIIRS_FREQS), gsd, snr, elev)
    curve = np.stack([np.abs(np.sinc(NIIRS_FREQS * drift)), np.ones_like(NIIRS_FREQS)], -1)
    predicted, rer_m = ni.loss(curve, np.array([0.0, sigma**2]))
    # the blur costs 0.028 NIIRS; predicted within 10 % of GIQE 5 of the measured edges,
    # and the static and smeared RER within 3 %
    assert measured > 0.02
    assert predicted == pytest.approx(measured, rel=0.10)
    assert ni.rer_static() == pytest.approx(r_s, rel=0.03)
    assert rer_m[0] == pytest.approx(r_row, rel=0.03)
    assert rer_m[1] == pytest.approx(r_col, rel=0.03)


def test_a_tdi_lines_residual_counts_from_the_lines_start():
    """The open loop's residual of a sinusoid on a TDI imager, from the time-domain path
    (each line's residual less its value at the line's start) against the window weight
    the noise and random terms use (2 (1 - sinc(2 f w)), over random phases), and far below
    the sinusoid's own RMS (what a frame imager's metric counts)."""
    from imc.workflow.predict import exposure_windows, predict_model, window_weights

    d = yaml.safe_load((ROOT / "scenarios" / "ikonos_tdi_scan.yaml").read_text())
    f_hz, amp = 20.0, 0.2
    d["attitude"]["jitter"] = {"sinusoids": [{"axis": "pitch", "frequency_hz": f_hz,
                                              "amplitude_px": amp}]}
    base = parse_scenario(d)
    _, _, window = exposure_windows(base)
    p = predict_model(None, base, Disturbance.from_scenario(base), 2e-4, lock=False)
    w_rms, _ = window_weights(window, tdi=True)
    expected = amp * np.sqrt(w_rms(np.array([f_hz]))[0] / 2.0)
    assert p.rms_det_px[0] < 0.5 * amp / np.sqrt(2.0)
    assert p.rms_det_px[0] == pytest.approx(expected, rel=0.05)


def test_a_niirs_requirement_is_predicted_and_measured_on_the_right_product():
    from imc.workflow.design import candidate_mapping

    d = parse_design(_design(requirements={"product.quality.closed.niirs_loss": {"max": 0.05}}))
    c = evaluate(d)
    loss = c.predicted["product.quality.closed.niirs_loss"]
    none = np.array([c.row(i)["stage"] == "none" for i in range(len(c))])
    ok = np.isfinite(loss)
    # the open loop blurs 1 px of 2 Hz jitter in 0.1 s exposures: a loss the loop removes
    assert np.all(loss[none] > 0.005)
    assert np.all(loss[~none & ok] < 0.5 * loss[none].min())
    assert loss[~none & ok].min() < 0.05 * loss[none].min()
    i_none, i_stage = int(np.flatnonzero(none)[0]), int(np.flatnonzero(~none & ok)[0])
    m_none, m_stage = (candidate_mapping(d, c.row(i)) for i in (i_none, i_stage))
    assert m_none["product"]["enabled"] and m_none["product"]["render"]
    assert list(m_none["expect"]) == ["product.quality.open.niirs_loss"]
    assert list(m_stage["expect"]) == ["product.quality.closed.niirs_loss"]


def _scan_base() -> dict:
    """no_stage.yaml's pushbroom (681 km, ~8,300 px/s of image flow along the rows) on a
    128 px tracker, 0.3 s, analytic plant."""
    d = yaml.safe_load((ROOT / "scenarios" / "no_stage.yaml").read_text())
    d["duration_s"] = 0.3
    d["scene"]["size_m"] = 2592
    d["camera"]["tracker"].update(rows=128, cols=128)
    d["correlator"].update(block_px=32, n_blocks=1)
    d["product"]["lines"] = 1024
    d["plant"] = {"fidelity": "analytic"}
    d.pop("expect")
    return d


def test_the_chain_overlap_is_the_trackers_own_block_placement():
    """The issue's failed run (50 Hz, 4 x 32 px on 256 px, 166 px of flow per frame): its
    lower two blocks never overlapped the next frame; at 200 Hz (41 px) all four do."""
    from imc.workflow.predict import chain_break_probability, chain_overlap

    assert chain_overlap(256, 256, 32, 4, np.array([166.0, 0.0])) == 2
    assert chain_overlap(256, 256, 32, 4, np.array([41.5, 0.0])) == 4
    assert chain_overlap(256, 256, 32, 1, np.array([300.0, 0.0])) == 0
    # two of four overlap, half must be valid: both, at 92 % each
    p = chain_break_probability(np.array([2, 4]), np.array([4, 4]), np.array([0.92, 0.92]),
                                0.5)
    assert p[0] == pytest.approx(1 - 0.92**2) and p[1] < 0.01


def test_a_scanning_candidate_without_block_overlap_is_infeasible():
    """25 Hz leaves 330 px of flow per frame on a 128 px tracker: no block's content reaches
    the next frame, named as the limit; 400 Hz (21 px per frame) overlaps and is feasible."""
    d = parse_design({"name": "scan", "base": _scan_base(), "tracker_crlb_px": 0.02,
                      "requirements": {"product.geometry.open.after.rms_px": {"max": 0.1}},
                      "free": {"frame_rate_hz": [25, 400], "block_px": [32],
                               "n_blocks": [1], "stage": ["none"],
                               "ground": ["correction"]},
                      "verify": {"designs": 0, "fidelity": "analytic"}})
    c = evaluate(d)
    rate = c.columns["frame_rate_hz"]
    slow, fast = int(np.flatnonzero(rate == 25)[0]), int(np.flatnonzero(rate == 400)[0])
    assert not c.feasible[slow]
    assert c.limiting[slow].startswith("frame overlap")
    assert c.extras["blocks_overlapping"][slow] == 0
    assert c.feasible[fast] and c.extras["blocks_overlapping"][fast] == 1


def test_the_records_interpolation_floor_grows_with_the_jitters_frequency():
    """A perfect 50 Hz record of a 1 px sinusoid, interpolated as the product does: below
    1e-4 px at 0.65 Hz (no_stage's wobble), above 0.05 px at 20 Hz (2.5 samples a period),
    rising in between (what bounds ground correction without a stage)."""
    from imc.workflow.predict import Disturbance, record_floor_px

    lines = np.arange(6000) / 8000.0 + 0.05
    floors = []
    for f in (0.65, 5.0, 10.0, 20.0):
        d = Disturbance(np.array([1]), np.array([f]), np.array([1.0]), np.array([0.3]),
                        np.geomspace(1e-3, 1e3, 1), np.zeros((1, 2)))
        after, _ = record_floor_px(d, 50.0, 2e-4, 0.9, lines, 32 / 8000.0)
        assert after[0] == 0.0  # the row axis has no jitter
        floors.append(after[1])
    assert floors[0] < 1e-4 and floors[-1] > 0.05
    assert np.all(np.diff(floors) > 0)


def test_the_shared_pixel_record_predictor_reproduces_the_pixels_noise():
    """The record predictor's network (`record_links`: a chain of 12 frames, baselines
    1-3, 4 blocks of 16 px on a 64 px sensor, 9 px of flow a frame, 10 % of each link's
    variance its own) against 2,000 draws of the pixel model itself: each frame's noise
    over a region of its pixels (unit variance; two regions' covariance the share of their
    pixels in common, counted on pixel masks), each block's error half its reference
    region's noise and half its current region's (as the run's links are cut:
    `chain_corners`, `pair_corners`), the links solved as a network. The mean squared
    geometry after a constant and after an affine equals the prediction's within
    3 sqrt(2 / N); the shared pixels make the record > 1.15x worse than independent links of
    the same variances; at f = 1 the predictor is that independent network."""
    from ground.network import Links, geometry_rms, solve_network
    from imc.workflow.predict import ChainGeometry, record_links

    n, k, f, draws, bp = 12, 3, 0.1, 2000, 16
    geo = ChainGeometry(64, 64, bp, 4, (9.0, 0.0))
    links = record_links(n, k, geo, f)
    t = np.arange(n) / 100.0
    pred = geometry_rms(np.zeros((n, 2)), t, solve_network(links, n).cov_px2)
    cuts = [geo.cut(j) for j in range(1, k + 1)]
    n1 = cuts[0][2].sum()
    # every region each frame is read on, and their noises drawn jointly from pixel masks
    rng = np.random.default_rng(33)
    entries = []  # (link, frame, region corner, coefficient)
    for i, (a, b) in enumerate(zip(links.a, links.b, strict=True)):
        ref, cur, used = cuts[b - a - 1]
        c = np.sqrt(n1) / used.sum() / np.sqrt(2)
        entries += [(i, a, tuple(r), -c) for r in ref[used]]
        entries += [(i, b, tuple(r), c) for r in cur[used]]
    err = np.zeros((len(links.a), draws))
    for fr in range(n):
        regions = sorted({e[2] for e in entries if e[1] == fr})
        masks = np.zeros((len(regions), 64, 64), bool)
        for j, (r, c) in enumerate(regions):
            masks[j, r:r + bp, c:c + bp] = True
        cov = np.einsum("ixy,jxy->ij", masks.astype(float), masks.astype(float)) / bp**2
        w, v = np.linalg.eigh(cov)
        nu = (v * np.sqrt(np.clip(w, 0, None))) @ rng.standard_normal((len(regions), draws))
        for li, fe, reg, c in entries:
            if fe == fr:
                err[li] += c * nu[regions.index(reg)]
    var = np.var(err, axis=1)  # each link's own part keeps its variance's share f
    d = np.sqrt(1 - f) * err + np.sqrt(f * var)[:, None] * rng.standard_normal(err.shape)
    sol = solve_network(Links(links.a, links.b, np.repeat(d[:, None], 2, 1),
                              links.sigma_px, shared=links.shared), n)
    tol = 3 * np.sqrt(2 / draws)
    for key in ("constant", "affine"):
        ms = np.mean([geometry_rms(sol.s_px[:, :, j], t)[key] ** 2 for j in range(draws)], 0)
        assert np.allclose(ms / pred[f"predicted_{key}"] ** 2, 1.0, atol=tol), key
    # independent links of the same variances (the shared covariance's diagonal)
    whole = record_links(n, k, geo, 0.0)
    diag = np.stack([c.diagonal() for c in whole.shared.covariance(np.arange(len(whole.a)))],
                    1)
    indep = geometry_rms(np.zeros((n, 2)), t, solve_network(Links(
        whole.a, whole.b, np.zeros_like(diag), np.sqrt(diag)), n).cov_px2)
    assert np.all(pred["predicted_constant"] > 1.15 * indep["predicted_constant"])
    one = geometry_rms(np.zeros((n, 2)), t, solve_network(record_links(n, k, geo, 1.0),
                                                          n).cov_px2)
    for key in ("predicted_constant", "predicted_affine"):
        assert np.allclose(one[key], indep[key], rtol=1e-9)


@pytest.mark.parametrize("size_m, texel_m, dem_m", [(704.0, 1.6, 16.0), (641.6, 1.6, 16.04)])
def test_a_procedural_tiles_albedo_window_is_the_whole_tiles(size_m, texel_m, dem_m):
    """The tile's draws (DEM, field seeds, roads) and any window of its albedo built alone
    equal the whole tile's (an even and an odd side; windows at the corners and inside),
    and the stream is left where the whole tile leaves it."""
    from scene.terrain import procedural_draws, procedural_terrain

    g_full, g_draws = np.random.default_rng(11), np.random.default_rng(11)
    full = procedural_terrain(size_m, texel_m, dem_m, 15.0, g_full)
    draws = procedural_draws(size_m, texel_m, dem_m, 15.0, g_draws)
    assert g_full.random() == g_draws.random()
    geo = draws.geometry()
    assert geo.size_m == full.size_m and np.array_equal(geo.dem_m, full.dem_m)
    n = draws.n
    assert full.albedo.shape == (n, n) and n % 2 == (0 if size_m == 704.0 else 1)
    for rows, cols in (((0, 37), (n - 60, n)), ((101, 230), (5, 140)), ((n - 9, n), (0, n))):
        w = draws.albedo_window(rows, cols)
        ref = full.albedo[rows[0]:rows[1], cols[0]:cols[1]]
        assert w.dtype == np.float32 and w.shape == ref.shape
        # the transforms' rounding (~1e-13) may move a float32 value by one unit in the
        # last place, and only rarely
        ulp = np.spacing(ref)
        assert np.all(np.abs(w - ref) <= ulp)
        assert np.mean(w != ref) <= 1e-3
        assert np.std(ref) > 0.02  # a textured window, not a constant


def _scan_base() -> dict:
    """no_stage's pushbroom on a short strip: frame 0's footprint lies off the tile's
    centre."""
    d = yaml.safe_load((ROOT / "scenarios" / "no_stage.yaml").read_text())
    d.pop("expect")
    d.update(duration_s=0.1)
    d["scene"].update(size_m=1408.0)
    d["camera"]["tracker"].update(rows=128, cols=128)
    d["correlator"].update(block_px=32)
    d["product"]["enabled"] = False
    return d


@pytest.mark.parametrize("base, texel_m", [("quickstart", None), ("quickstart", 0.25),
                                           ("scan", None)])
def test_the_bounds_on_the_footprints_albedo_equal_the_whole_tiles(base, texel_m):
    """The tracker's bounds per block size (and the record's base bound) on frame 0 made
    from the albedo under the footprint alone (:func:`bound_frame0`) equal those on the
    whole tile, bit for bit: a staring view, the same with the albedo smoothed to the GSD
    (texels finer than the ground sample), and a scan whose footprint is off-centre."""
    from imc.wiring.build import build_models
    from imc.wiring.rendered_plant import base_image
    from imc.workflow.predict import bound_frame0, tracker_bound, tracker_bounds

    d = _base() if base == "quickstart" else _scan_base()
    if texel_m is not None:
        d["scene"]["texel_m"] = texel_m
    sc = parse_scenario(d)
    m_new, rad_new = bound_frame0(sc, "texture")
    assert m_new.terrain.albedo.shape == (16, 16)  # the whole albedo was not built
    m_old = build_models(sc)
    rad_old = base_image(m_old, 0)
    assert np.array_equal(rad_new, rad_old) and np.std(rad_old) > 0.01
    sizes = [32, 64]
    new = tracker_bounds(m_new, sizes, "texture", radiance=rad_new)
    old = tracker_bounds(m_old, sizes, "texture")
    assert new == old and all(np.isfinite(v[0]) for v in old.values())
    b_new, b_old = tracker_bound(m_new, radiance=rad_new), tracker_bound(m_old)
    assert np.array_equal(b_new[0], b_old[0]) and b_new[1] == b_old[1]
    assert m_new.chain == m_old.chain


def test_the_bases_bound_alone_equals_the_searchs():
    """`base_crlb_px` (the bound a design's record is asked at when the search did not give
    one) equals the bound the search computed on the same base: both from frame 0's
    footprint (`bound_frame0`)."""
    from imc.workflow.design import base_crlb_px

    d = parse_design(_design(tracker_crlb_px=None))
    alone = base_crlb_px(d)
    assert np.isfinite(alone) and alone > 0
    assert alone == pytest.approx(evaluate(d).base_crlb_px, rel=1e-12)


def test_a_kalman_that_identifies_its_line_is_predicted_to_follow_it_after_identifying():
    """The quickstart's loop held for 3 s: its Kalman predictor (identify on by default)
    finds the 2 Hz pitch line at 0.9 of its 1.28 s window, so the exposures after 1.15 s are
    predicted with the line modelled: the sinusoid's residual along the rows well below the
    prediction without it; with ``identify: false`` the prediction is the plain loop's."""
    import yaml

    from imc.scenario import parse_scenario
    from imc.wiring.build import build_loop, build_models
    from imc.workflow.predict import identified_prediction, predict_model

    d = yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text())
    d["duration_s"] = 3.0
    sc = parse_scenario(d)
    m = build_models(sc, light=True)
    parts = build_loop(m)
    dist = Disturbance.from_scenario(sc)
    plain = predict_model(parts.model, sc, dist, m.exposure_s)
    found = identified_prediction(parts.model, parts.controller, sc, dist, m)
    assert found.rms_det_px[0] < 0.8 * plain.rms_det_px[0]  # 0.68: 36 % of it before
    assert found.mtf_det_worst[0] <= plain.mtf_det_worst[0] + 1e-12  # the early exposures
    d["compensation"]["controller"]["identify"] = False
    sc = parse_scenario(d)
    m = build_models(sc, light=True)
    parts = build_loop(m)
    same = identified_prediction(parts.model, parts.controller, sc, dist, m)
    assert same.rms_det_px == predict_model(parts.model, sc, dist, m.exposure_s).rms_det_px

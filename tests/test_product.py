"""The main imager's product (imc.wiring.product): the ground's per-line offsets from a
record against the camera model's truth, refusals that name the field, and a product that a
killed run finishes identically."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from camera.linescan import frame_offset_px, frame_sampling, line_offset_px, tdi_sampling
from ground.record import MotionRecord
from imc.scenario import ScenarioError, load_scenario, parse_scenario
from imc.wiring.build import build_models
from imc.wiring.product import ProductPlan, line_offsets, perfect_jitter, plan_product

QUICKSTART = Path(__file__).resolve().parents[1] / "scenarios" / "quickstart.yaml"

#: a small TDI scan (0.12 s, 16 stages) shaken by 0.3 px on both axes at 30 and 23 Hz
TDI = {
    "name": "tdi_small", "seed": 3, "duration_s": 0.12,
    "orbit": {"kind": "sun_synchronous", "altitude_m": 681000,
              "epoch_utc": "2026-06-21T10:30:00", "pass_direction": "descending"},
    "attitude": {"mode": "nadir", "yaw_steering": True, "jitter": {"sinusoids": [
        {"axis": "pitch", "frequency_hz": 30.0, "amplitude_px": 0.3},
        {"axis": "roll", "frequency_hz": 23.0, "amplitude_px": 0.3, "phase_deg": 40.0}]}},
    "scene": {"size_m": 1400, "texel_m": 1.0, "dem_spacing_m": 8.0, "relief_rms_m": 5.0,
              "sun_elevation_deg": 60, "sun_azimuth_deg": 140, "spp": 1},
    "camera": {"tracker": {"rows": 256, "cols": 256, "frame_rate_hz": 200,
                           "exposure_s": 0.0002},
               "main_imager": {"kind": "tdi", "stages": 16}},
    "correlator": {"block_px": 64, "n_blocks": 4},
    "plant": {"fidelity": "analytic"},
    "product": {"enabled": True, "lines": 300, "cols": 128, "samples": 16},
}


def _tdi(**product) -> dict:
    data = yaml.safe_load(yaml.safe_dump(TDI))
    data["product"].update(product)
    return data


def _stage(t):
    t = np.asarray(t, dtype=np.float64)
    return np.stack([0.2 * np.sin(2 * np.pi * 11.0 * t), -0.15 * np.cos(2 * np.pi * 9.0 * t)],
                    axis=-1)


def _record(m):
    return MotionRecord(m.frame_mid_s, np.zeros((len(m.frame_mid_s), 2)),
                        np.ones(len(m.frame_mid_s), bool))


@pytest.fixture(scope="module")
def tdi_models():
    return build_models(parse_scenario(TDI))


@pytest.mark.parametrize("stage", [None, _stage])
def test_a_perfect_record_gives_every_lines_offset_on_the_nominal_grid(tdi_models, stage):
    # the ground's model (record of the jitter at the tracker's 200 Hz, cubic, averaged over
    # each line, signs of docs/conventions.md) against the camera model's truth per line:
    # the target for a perfect record is < 0.005 px (interpolation only)
    m = tdi_models
    plan = plan_product(m)
    smp = tdi_sampling(m.imager, plan.line_rate_hz, m.scenario.product.samples)
    lines = np.arange(plan.n_lines)
    probes = np.array([plan.cols[0], plan.cols[-1]], dtype=np.float64)
    truth = line_offset_px(m.main_camera, m.imager, smp, plan.t0_s, lines, probes,
                           m.terrain.height_at, stage).mean(axis=1)
    est = line_offsets(plan, perfect_jitter(m, _record(m)), stage)
    err = (est - truth) - (est - truth).mean(axis=0)  # the constant: ground control's
    assert np.ptp(truth, axis=0).min() > 0.3  # the jitter (and stage) really moves the lines
    assert np.sqrt(np.mean(err**2, axis=0)).max() < 0.005


def test_a_frame_offset_has_the_frame_signs():
    sc = parse_scenario(yaml.safe_load(QUICKSTART.read_text())
                        | {"product": {"enabled": True, "lines": 128, "cols": 128}})
    m = build_models(sc)
    plan = plan_product(m)
    assert plan.kind == "frame" and isinstance(plan, ProductPlan)
    smp = frame_sampling(m.imager, 16)
    centre = np.array([[plan.rows.mean(), plan.cols.mean()]])
    truth = frame_offset_px(m.main_camera, m.imager, smp, plan.t0_s, centre, m.terrain.height_at)[0]
    est = line_offsets(plan, perfect_jitter(m, _record(m)), None)[0]
    # the quickstart's record counts from frame 0's exposure; the truth from the nominal pose
    # (the 2 Hz pitch moves the frame by ~0.6 px): the same up to that one constant, which the
    # record cannot see; here the perfect record's jitter is absolute, so they agree
    assert abs(truth[0]) > 0.3
    np.testing.assert_allclose(est, truth, atol=0.01)


@pytest.mark.parametrize("product, field", [
    ({"lines": 4000}, "product.lines"),  # ends after the run
    ({"cols": 16000}, "product.cols"),  # wider than the 13,500-column imager
])
def test_a_product_that_does_not_fit_is_refused_naming_the_field(tdi_models, product, field):
    with pytest.raises(ScenarioError, match=field.replace(".", r"\.")):
        plan_product(build_models(parse_scenario(_tdi(**product)), light=True))


@pytest.mark.parametrize("lines", [0, -5])
def test_a_product_of_no_size_is_refused_naming_the_field(tmp_path, lines):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(_tdi(lines=lines)))
    with pytest.raises(ScenarioError, match=r"product\.lines"):
        load_scenario(p)


def test_a_product_above_the_memory_budget_is_refused():
    from imc.wiring.budget import check_run_size, estimate_run

    sc = parse_scenario(_tdi(lines=65536, cols=16384))
    est = estimate_run(sc)
    with pytest.raises(ScenarioError, match=r"product\.lines x product\.cols"):
        check_run_size(sc, est.__class__(est.frames, est.peak_bytes, est.parts, est.texels,
                                         budget_bytes=est.peak_bytes / 2))


def test_a_killed_run_finishes_the_same_product(tmp_path):
    from imc.pipeline import run_scenario

    sc = parse_scenario(TDI)
    metrics, _ = run_scenario(sc, tmp_path / "a", rerun=False)
    p = metrics["product"]
    assert p["hit_fraction"] > 0.999999
    assert set(p["quality"]) == {"static", "open", "closed", "open_gc", "open_gc_restored",
                                 "closed_gc", "closed_gc_restored"}
    for name in ("open", "closed"):
        assert p["geometry"][name]["after_perfect_record"]["rms_px"][0] < 0.005
    # a run killed after some chunks: the later versions' chunks are gone
    run_scenario(sc, tmp_path / "b", rerun=False)
    chunks = sorted((tmp_path / "b" / "product" / "chunks").rglob("*.npz"))
    for f in chunks[len(chunks) // 2:]:
        f.unlink()
    (tmp_path / "b" / "product" / "product.npz").unlink()
    run_scenario(sc, tmp_path / "b", rerun=False)
    with np.load(tmp_path / "a" / "product" / "product.npz") as a, \
            np.load(tmp_path / "b" / "product" / "product.npz") as b:
        assert set(a.files) == set(b.files)
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)

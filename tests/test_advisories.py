"""What a run is told before it starts (imc.wiring.advisories) and the exposures it made worse
(imc.outputs.report.exposure_comparison)."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from imc.cli import app
from imc.scenario import parse_scenario
from imc.wiring.advisories import advisories
from imc.wiring.build import build_loop, build_models
from imc.yamlload import with_changes

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def _models(name: str, **changes):
    data = with_changes(yaml.safe_load((ROOT / "scenarios" / f"{name}.yaml").read_text()),
                        changes)
    m = build_models(parse_scenario(data), light=True)
    return m, build_loop(m)


def test_a_device_asked_for_twice_its_rate_is_warned_with_the_frames_it_skips():
    # the seed's device: 2 transforms/correlation on 2 processors at 30/s -> 60 correlations/s;
    # its 2 blocks at 60 frames/s ask for 120/s, twice that: every other frame goes unmeasured
    m, parts = _models("seed_device", **{"camera.tracker.frame_rate_hz": 60.0})
    figures, lines = advisories(m, parts)
    b = figures["correlator_budget"]
    assert b["asked_per_s"] == pytest.approx(2 * b["device_per_s"])
    n = b["frames_measured"] + b["frames_skipped"]
    assert b["frames_skipped"] == pytest.approx(n / 2, abs=2)
    assert b["measurement_rate_hz"] == pytest.approx(30.0, rel=0.02)
    warning = next(w for w in lines if w.startswith("correlator.timing"))
    assert "120 correlations/s" in warning and f"{b['frames_skipped']} of {n}" in warning
    # 4 blocks at 30 frames/s: every frame measured, half of the pairs dropped
    m, parts = _models("seed_device", **{"correlator.n_blocks": 4})
    b = advisories(m, parts)[0]["correlator_budget"]
    assert b["frames_skipped"] == 0 and b["pairs_dropped"] >= 0.49 * 4 * b["frames_measured"]
    # at the device's own rate: no warning
    m, parts = _models("seed_device")
    assert not any(w.startswith("correlator.timing") for w in advisories(m, parts)[1])


def test_an_imager_that_starts_before_lock_is_warned_naming_its_field():
    m, parts = _models("quickstart", **{"camera.main_imager.start_s": 0.0})
    figures, lines = advisories(m, parts)
    assert figures["lock"]["analytic_s"] > 0.05
    assert any(w.startswith("camera.main_imager.start_s:") for w in lines)
    m, parts = _models("quickstart")  # starts at the lock time: nothing to say
    assert not advisories(m, parts)[1]


def test_validate_prints_the_lock_and_the_warning_in_one_line_each(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(with_changes(
        yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text()),
        {"camera.main_imager.start_s": 0.0})))
    r = runner.invoke(app, ["validate", str(p)])
    assert r.exit_code == 0, r.output
    assert "loop locks in" in r.output
    warn = [ln for ln in r.output.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "camera.main_imager.start_s" in warn[0]


def test_exposures_the_loop_made_worse_are_counted_and_listed():
    from imc.outputs.report import exposure_comparison
    from imc.wiring.truth import Truth

    # two exposures of 100 samples: the loop halves the first one's motion and doubles the
    # second one's (a 1 px ramp: motion MTF sinc(0.5) open)
    t = np.arange(200) * 1e-3
    ramp = np.linspace(-0.5, 0.5, 100)
    motion = np.zeros((200, 2))
    motion[:, 0] = np.concatenate([ramp, ramp])
    stage = np.zeros((200, 2))
    stage[:100, 0] = 0.5 * ramp
    stage[100:, 0] = -ramp
    truth = Truth(t, np.repeat([0, 1], 100), 0.1, motion, np.zeros((200, 2)),
                  np.zeros((1, 1, 2)), np.zeros((1, 2)), False)

    def trajectory(ts):  # the stage at the truth's own sample times
        return stage[np.searchsorted(t, ts)]

    ex = exposure_comparison(truth, trajectory)
    assert ex["n"] == 2 and ex["worse_than_open"] == 1
    (worse,) = ex["worse"]
    assert worse["start_s"] == pytest.approx(0.1)
    assert worse["mtf_nyquist_closed"][0] < worse["mtf_nyquist_open"][0]


def test_a_design_refused_with_an_overloaded_device_says_both():
    # the quickstart's law on the seed's 60/s device: refused for its peak |S| (rightly), and
    # the refusal says too that 4 blocks at 100 frames/s are more than the device can take
    from imc.scenario import ScenarioError

    data = with_changes(yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text()),
                        {"correlator.timing": {"enabled": True}})
    with pytest.raises(ScenarioError, match=r"compensation\.controller.*and correlator\.timing: "
                                            r"the run asks for 400 correlations/s"):
        build_loop(build_models(parse_scenario(data), light=True))

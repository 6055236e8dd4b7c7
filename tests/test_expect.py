"""Expectations: bounds on metrics, `imc run`'s table and exit code, `imc check`, JUnit XML."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
import yaml
from conftest import ROOT, tiny_base
from typer.testing import CliRunner

from imc.cli import app
from imc.scenario import METRIC_SECTIONS, BoundConfig, ScenarioError, parse_scenario
from imc.workflow.expect import CaseResult, Outcome, judge, lookup, write_junit

cli = CliRunner()
METRICS = {"with_compensation": {"rms_total_px": 0.02, "rms_px": [0.015, 0.013]},
           "rms_reduction": 40.0, "tracker": {"rms_error_px": [0.01, None]}}


def _bounds(**kw) -> dict[str, BoundConfig]:
    return {k.replace("__", "."): BoundConfig(**v) for k, v in kw.items()}


def test_bounds_pass_and_fail_on_the_edges():
    out = judge(_bounds(with_compensation__rms_total_px={"max": 0.02},
                        rms_reduction={"min": 40.0001},
                        with_compensation__rms_px={"within": [0.013, 0.015]}), METRICS)
    assert [o.passed for o in out] == [True, False, True]
    assert out[1].line() == "FAIL  rms_reduction = 40 (expected >= 40.0001)"
    assert out[2].value == "[0.015, 0.013]"


def test_a_list_must_hold_everywhere_unless_indexed():
    assert not judge(_bounds(with_compensation__rms_px={"max": 0.014}), METRICS)[0].passed
    assert judge({"with_compensation.rms_px.1": BoundConfig(max=0.014)}, METRICS)[0].passed
    nan = judge({"tracker.rms_error_px": BoundConfig(max=1.0)}, METRICS)[0]
    assert not nan.passed and nan.note == "no value (NaN)"


def test_missing_metrics_fail_with_the_reason():
    out = judge({"tracker.valid_fraction": BoundConfig(min=0.9),
                 "with_compensation.rms_px.2": BoundConfig(max=1)}, METRICS)
    assert not any(o.passed for o in out)
    assert "tracker has no 'valid_fraction'" in out[0].note
    assert "a list of 2; index it with 0..1" in out[1].note
    assert lookup(METRICS, "with_compensation.rms_px.-1") == 0.013


@pytest.mark.parametrize("expect, words", [
    ({"with_compensaton.rms_total_px": {"max": 1}}, "metrics.json has no 'with_compensaton'"),
    ({"rms_reduction": {}}, "expect.rms_reduction: give max, min or within"),
    ({"rms_reduction": {"within": [3, 1]}}, "needs lo <= hi"),
    ({"rms_reduction": {"min": 1, "within": [0, 2]}}, "not both"),
    ({"rms_reduction": {"maximum": 1}}, "expect.rms_reduction.maximum: unknown field"),
])
def test_bad_expectations_name_the_path(expect, words):
    with pytest.raises(ScenarioError) as e:
        parse_scenario({"expect": expect})
    assert words in str(e.value) and "\n" not in str(e.value)


def test_expectations_do_not_change_the_digest():
    a = parse_scenario({})
    b = parse_scenario({"expect": {"rms_reduction": {"min": 2}}})
    assert a.digest() == b.digest()


def test_junit_xml_has_one_testcase_per_scenario(tmp_path):
    ok = Outcome("rms_reduction", ">= 2", "40", True)
    bad = Outcome("with_compensation.rms_total_px", "<= 0.01", "0.02", False)
    cases = [CaseResult("a", "scenarios/a.yaml", 1.5, (ok,)),
             CaseResult("b", "scenarios/b.yaml", 2.0, (ok, bad)),
             CaseResult("c", "scenarios/c.yaml", 0.1, error="c.yaml: orbit.kind: bad")]
    write_junit(tmp_path / "j.xml", cases)
    root = ET.parse(tmp_path / "j.xml").getroot()
    suite = root.find("testsuite")
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("3", "1", "1")
    tcs = suite.findall("testcase")
    assert [t.get("name") for t in tcs] == ["a", "b", "c"]
    assert tcs[0].find("failure") is None and tcs[0].find("error") is None
    assert "with_compensation.rms_total_px = 0.02" in tcs[1].find("failure").get("message")
    assert tcs[2].find("error").get("message") == "c.yaml: orbit.kind: bad"


@pytest.fixture(scope="module")
def tiny_scenario(tmp_path_factory):
    d = tmp_path_factory.mktemp("expect")
    data = tiny_base()
    data["expect"] = {"with_compensation.rms_total_px": {"max": 5.0},
                      "rms_reduction": {"min": 1.0}}
    good = d / "good.yaml"
    good.write_text(yaml.safe_dump(data))
    data["expect"]["rms_reduction"] = {"min": 1000.0}  # no loop gains 1000x here
    bad = d / "bad.yaml"
    bad.write_text(yaml.safe_dump({**data, "name": "bad"}))
    return d, good, bad


def test_imc_run_prints_the_table_and_exits_1_on_a_failure(tiny_scenario):
    d, good, bad = tiny_scenario
    r = cli.invoke(app, ["run", str(good), "--out", str(d / "g"), "--no-rerun", "--no-report"])
    assert r.exit_code == 0, r.output
    assert "expectations" in r.output and "FAIL" not in r.output
    r = cli.invoke(app, ["run", str(bad), "--out", str(d / "b"), "--no-rerun", "--no-report"])
    assert r.exit_code == 1
    assert "FAIL" in r.output and "1 of 2 expectations failed" in r.output


def test_imc_check_writes_junit_for_each_scenario(tiny_scenario, tmp_path):
    d, good, bad = tiny_scenario
    junit = tmp_path / "junit.xml"
    r = cli.invoke(app, ["check", str(good), str(bad), "--junit", str(junit), "--out",
                         str(tmp_path / "runs")])
    assert r.exit_code == 1, r.output
    tcs = ET.parse(junit).getroot().find("testsuite").findall("testcase")
    assert [t.get("name") for t in tcs] == ["quickstart", "bad"]  # the base keeps its name
    assert tcs[0].find("failure") is None and tcs[1].find("failure") is not None
    assert (tmp_path / "runs" / "bad" / "expectations.json").exists()


def test_imc_check_refuses_a_bad_scenario_before_running(tmp_path):
    p = tmp_path / "x.yaml"
    p.write_text("duration_s: -1\n")
    r = cli.invoke(app, ["check", str(p), "--junit", str(tmp_path / "j.xml")])
    assert r.exit_code == 2 and "duration_s" in r.output and "Traceback" not in r.output
    err = ET.parse(tmp_path / "j.xml").getroot().find("testsuite/testcase/error")
    assert "duration_s" in err.get("message")


def test_metric_sections_are_what_a_run_reports(tiny_scenario):
    """Every top-level key of a real metrics.json is a known section (and expect: can name
    it); the optional ones (device, link, the product) are the only ones missing."""
    import json

    d, _, _ = tiny_scenario
    keys = set(json.loads((d / "g" / "metrics.json").read_text()))
    assert keys <= set(METRIC_SECTIONS)
    assert set(METRIC_SECTIONS) - keys <= {"correlator_device", "link", "product"}


def test_bundled_fast_scenarios_meet_their_expectations(tmp_path):
    """The project's own regression check: `imc check` on every bundled scenario that runs
    on the analytic plant (seconds each); the rendered ones run in `make check-scenarios`."""
    from imc.scenario import load_scenario

    files = sorted((ROOT / "scenarios").glob("*.yaml"))
    fast = [f for f in files if load_scenario(f).plant.fidelity == "analytic"]
    assert fast and all(load_scenario(f).expect for f in fast)
    r = cli.invoke(app, ["check", *map(str, fast), "--junit", str(tmp_path / "j.xml"),
                         "--out", str(tmp_path / "runs")])
    assert r.exit_code == 0, r.output
    assert f"{len(fast)} of {len(fast)} scenarios passed" in r.output


def test_imc_check_skips_a_scenario_whose_data_is_not_fetched(tmp_path):
    """scenarios/olinda.yaml reads data `make data` fetches: without it, a one-line skip
    that names the missing file, not a failure of the whole check."""
    import shutil

    p = tmp_path / "olinda.yaml"
    shutil.copy(ROOT / "scenarios" / "olinda.yaml", p)  # its data/ is not beside the copy
    r = cli.invoke(app, ["check", str(p), "--out", str(tmp_path / "runs")])
    assert r.exit_code == 0, r.output
    line = next(x for x in r.output.splitlines() if x.startswith("skipped"))
    assert "olinda" in line and "L7_ETMs.tif" in line and "make data" in line
    assert "0 of 0 scenarios passed" in r.output


def test_imc_check_on_a_folder_leaves_out_sweeps_and_designs(tmp_path):
    """A folder holds scenarios beside sweeps and designs (scenarios/ does): `imc check` on
    it runs the scenarios only; a design file named on its own is still a scenario and is
    refused in one line."""
    import shutil

    from imc.cli import _scenario_files

    for sub in ("sweeps", "designs"):
        shutil.copytree(ROOT / "scenarios" / sub, tmp_path / sub)
    shutil.copy(ROOT / "scenarios" / "quickstart.yaml", tmp_path / "quickstart.yaml")
    assert _scenario_files([tmp_path]) == [tmp_path / "quickstart.yaml"]
    design = tmp_path / "designs" / "quickstart_frame.yaml"
    r = cli.invoke(app, ["check", str(design), "--out", str(tmp_path / "runs")])
    assert r.exit_code == 2 and "base" in r.output and "Traceback" not in r.output

"""Sweeps: axes and their errors, points on Dask or in process, restart, results."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
import yaml
from conftest import QUICKSTART, ROOT, tiny_base, tiny_sweep
from typer.testing import CliRunner

from imc.cli import app
from imc.workflow.distribute import runner
from imc.workflow.sweep import AxisRange, SweepError, expand, load_sweep, run_sweep

cli = CliRunner()


def test_axis_ranges_include_both_ends():
    assert AxisRange(linear=(0.0, 0.1, 3)).values() == [0.0, 0.05, 0.1]
    assert AxisRange(log=(0.1, 10.0, 3)).values() == pytest.approx([0.1, 1.0, 10.0])
    with pytest.raises(ValueError, match="start and stop > 0"):
        AxisRange(log=(0.0, 1.0, 3)).values()


def test_grid_and_zip_points_set_the_fields():
    sw = expand(tiny_sweep())
    assert len(sw.points) == 2 * 2 * 2 and sw.dims == ("compensation.controller.gain",
                                                      "attitude.jitter.sinusoids.0.frequency_hz",
                                                      "seed")
    p = sw.points[3]  # gain 0.3, 3 Hz, seed 1
    assert p.coords == {"compensation.controller.gain": 0.3,
                        "attitude.jitter.sinusoids.0.frequency_hz": 3.0, "seed": 1}
    assert p.scenario["compensation"]["controller"]["gain"] == 0.3
    assert p.scenario["attitude"]["jitter"]["sinusoids"][0]["frequency_hz"] == 3.0
    assert p.scenario["seed"] == tiny_base()["seed"] + 1
    assert len({q.digest for q in sw.points}) == len(sw.points)
    z = expand(tiny_sweep(mode="zip", seeds=1))
    assert [tuple(q.coords.values())[:2] for q in z.points] == [(0.3, 1.0), (0.8, 3.0)]


def test_a_field_left_at_its_default_can_be_swept():
    """transport.latency_s is not in the base file: the axis takes the default section."""
    sw = expand(tiny_sweep(axes={"compensation.transport.latency_s": [0.0, 0.02]}))
    assert [p.scenario["compensation"]["transport"]["latency_s"] for p in sw.points[::2]] == [
        0.0, 0.02]


@pytest.mark.parametrize("axes, words", [
    ({"compensation.controler.gain": [1]},
     "axis compensation.controler.gain = 1: compensation.controler: unknown field"),
    ({"compensation.controller.gian": [1]},
     "compensation.controller.gian: unknown parameter of controller kind 'integrator'"),
    ({"camera.tracker.frame_rate_hz": [100, -5]},
     "axis camera.tracker.frame_rate_hz = -5: camera.tracker.frame_rate_hz: Input should be "
     "greater than 0"),
    ({"attitude.jitter.sinusoids.2.frequency_hz": [1]},
     "axis attitude.jitter.sinusoids.2.frequency_hz: attitude.jitter.sinusoids is a list of 1"),
    ({"seed.x": [1]}, "axis seed.x: seed is a value, not a section"),
    ({"duration_s": [0.001]}, "axis duration_s = 0.001: (top level): duration_s covers fewer"),
])
def test_bad_axes_are_named_with_their_field_before_anything_runs(axes, words):
    with pytest.raises(SweepError) as e:
        expand(tiny_sweep(axes=axes))
    assert words in str(e.value) and "\n" not in str(e.value)


def test_sweep_file_errors_are_one_line(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("base: nothing.yaml\naxes: {seed: [1, 2]}\n")
    with pytest.raises(SweepError, match="use seeds: N"):
        load_sweep(p)
    p.write_text("base: nothing.yaml\naxes: {duration_s: [1]}\n")
    with pytest.raises(SweepError, match="nothing.yaml: file not found"):
        load_sweep(p)
    p.write_text("base: {}\naxes: {duration_s: [1]}\nmode: zipp\n")
    with pytest.raises(SweepError, match="mode"):
        load_sweep(p)


def test_points_and_results_are_written(tiny_run):
    sw, out, summary = tiny_run
    assert summary.ran == 8 and summary.failed == 0 and summary.skipped == 0
    assert sorted(p.name for p in (out / "points").iterdir()) == sorted(
        f"{p.digest}.json" for p in sw.points)
    assert not (out / "runs").exists()  # run folders removed unless keep_runs
    ds = xr.open_dataset(out / "results.nc", engine="h5netcdf")
    rms = ds["with_compensation.rms_total_px"]
    assert rms.dims == sw.dims and rms.shape == (2, 2, 2)
    assert list(ds["compensation.controller.gain"].values) == [0.3, 0.8]
    # a higher gain follows a 1 Hz, 1 px oscillation better (100 Hz, 1 frame of delay)
    assert float(rms.sel({"compensation.controller.gain": 0.8}).isel(
        {"attitude.jitter.sinusoids.0.frequency_hz": 0}).max()) < float(
        rms.sel({"compensation.controller.gain": 0.3}).isel(
            {"attitude.jitter.sinusoids.0.frequency_hz": 0}).min())
    df = pd.read_parquet(out / "results.parquet")
    assert len(df) == 8 and (df["status"] == "ok").all()
    rec = json.loads((out / "points" / f"{sw.points[5].digest}.json").read_text())
    row = df[df["digest"] == sw.points[5].digest].iloc[0]
    assert row["with_compensation.rms_total_px"] == rec["metrics"]["with_compensation"][
        "rms_total_px"]
    assert len(pd.read_csv(out / "results.csv")) == 8


def test_restart_runs_only_the_missing_points(tiny_run, tmp_path):
    sw, out, _ = tiny_run
    import shutil

    again = tmp_path / "again"
    shutil.copytree(out, again)
    lost = [sw.points[1].digest, sw.points[6].digest]
    for d in lost:
        (again / "points" / f"{d}.json").unlink()
    ran = []
    with runner(0) as r:
        summary = run_sweep(sw, again, r, progress=lambda done, n: ran.append(done))
    assert summary.skipped == 6 and summary.ran == 2 and ran[0] == 6
    a = xr.open_dataset(out / "results.nc", engine="h5netcdf")
    b = xr.open_dataset(again / "results.nc", engine="h5netcdf")
    # the same points run again give the same metrics (seeded, analytic plant)
    np.testing.assert_array_equal(a["with_compensation.rms_total_px"].values,
                                  b["with_compensation.rms_total_px"].values)


def test_a_failing_point_records_its_error_and_the_sweep_goes_on(tmp_path):
    # an integrator gain of 2 passes the schema but its loop is refused as unstable
    sw = expand(tiny_sweep(seeds=1, axes={"compensation.controller.gain": [0.5, 2.0]}))
    with runner(0) as r:
        summary = run_sweep(sw, tmp_path, r)
    assert summary.ran == 2 and summary.failed == 1
    df = pd.read_parquet(tmp_path / "results.parquet")
    bad = df[df["status"] == "error"].iloc[0]
    assert bad["compensation.controller.gain"] == 2.0 and "unstable" in bad["error"]
    assert "\n" not in bad["error"] and np.isnan(bad["with_compensation.rms_total_px"])
    assert (df["status"] == "ok").sum() == 1
    with runner(0) as r:  # failed points are not retried unless asked
        assert run_sweep(sw, tmp_path, r).ran == 0
        assert run_sweep(sw, tmp_path, r, retry_failed=True).ran == 1


def test_two_dask_workers_give_the_serial_results(tiny_run, tmp_path):
    """Points on a LocalCluster of 2 processes equal the in-process ones bit for bit."""
    sw, out, _ = tiny_run
    with runner(2, memory_limit="2GiB") as r:
        assert r.n_workers == 2
        summary = run_sweep(sw, tmp_path, r)
    assert summary.ran == 8 and summary.failed == 0 and not summary.lost
    a = pd.read_parquet(out / "results.parquet").set_index("digest").sort_index()
    b = pd.read_parquet(tmp_path / "results.parquet").set_index("digest").sort_index()
    cols = [c for c in a.columns if c.startswith(("with_", "without_", "tracker."))]
    pd.testing.assert_frame_equal(a[cols], b[cols])
    workers = {json.loads(p.read_text())["worker"] for p in (tmp_path / "points").iterdir()}
    assert len(workers) == 2


def test_cli_sweep_bad_axis_and_unreachable_scheduler_are_one_line(tmp_path):
    p = tmp_path / "s.yaml"
    spec = {"base": str(QUICKSTART), "axes": {"correlator.blok_px": [32, 64]}}
    p.write_text(yaml.safe_dump(spec))
    r = cli.invoke(app, ["sweep", str(p), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "axis correlator.blok_px = 32: correlator.blok_px: unknown " \
        "field" in " ".join(r.output.split())
    assert not (tmp_path / "o").exists()  # nothing ran
    spec["axes"] = {"correlator.block_px": [32, 64]}
    p.write_text(yaml.safe_dump(spec))
    r = cli.invoke(app, ["sweep", str(p), "--out", str(tmp_path / "o"), "--scheduler",
                         "tcp://127.0.0.1:9"])
    text = " ".join(r.output.split())
    assert r.exit_code == 2 and "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in text
    assert "Traceback" not in r.output


def test_bundled_sweeps_validate():
    for f in sorted((ROOT / "scenarios" / "sweeps").glob("*.yaml")):
        sw = load_sweep(f)
        assert sw.points, f


def test_cli_zip_sweep_writes_results_and_report_and_resumes(tmp_path):
    spec = tiny_sweep(mode="zip", seeds=1).model_dump(mode="json")
    p = tmp_path / "zip.yaml"
    p.write_text(yaml.safe_dump(spec))
    out = tmp_path / "out"
    r = cli.invoke(app, ["sweep", str(p), "--out", str(out), "--workers", "0"])
    assert r.exit_code == 0, r.output
    assert "2 points run, 0 already done, 0 failed" in " ".join(r.output.split())
    ds = xr.open_dataset(out / "results.nc", engine="h5netcdf")
    assert ds["rms_reduction"].dims == ("point", "seed") and ds.sizes["point"] == 2
    assert list(ds["compensation.controller.gain"].values) == [0.3, 0.8]
    assert list(ds["attitude.jitter.sinusoids.0.frequency_hz"].values) == [1.0, 3.0]
    assert (out / "report.html").exists() and (out / "figures").is_dir()
    r = cli.invoke(app, ["sweep", str(p), "--out", str(out), "--workers", "0", "--no-report"])
    assert r.exit_code == 0 and "0 points run, 2 already done" in " ".join(r.output.split())


def test_fresh_runs_every_point_again_and_replaces_each_result(tiny_run, tmp_path):
    """`--fresh` runs every point again by the same code (a point whose file was edited or
    written otherwise is kept without it), each earlier result replaced as it finishes."""
    sw, out, _ = tiny_run
    import shutil

    again = tmp_path / "again"
    shutil.copytree(out, again)
    stale = again / "points" / f"{sw.points[3].digest}.json"
    rec = json.loads(stale.read_text())
    rec["metrics"]["with_compensation"]["rms_total_px"] = -1.0  # as if edited
    stale.write_text(json.dumps(rec))
    with runner(0) as r:
        assert run_sweep(sw, again, r).ran == 0  # kept as it is
        summary = run_sweep(sw, again, r, fresh=True)
    assert summary.skipped == 0 and summary.ran == len({p.digest for p in sw.points})
    assert json.loads(stale.read_text())["metrics"]["with_compensation"]["rms_total_px"] > 0


def test_a_code_change_changes_every_points_digest(monkeypatch):
    """A point (and a run's checkpoint) is known by its scenario and the code's source: the
    same scenario under other code gets another digest, so it is run again."""
    import imc.scenario as scenario_mod

    sc = scenario_mod.load_scenario(QUICKSTART)
    before = sc.digest()
    monkeypatch.setattr(scenario_mod, "code_digest", lambda: "0" * 16)
    assert sc.digest() != before

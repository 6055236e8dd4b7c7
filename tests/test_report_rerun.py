"""The run and sweep reports, the Rerun recording and its blueprint, imc report / view."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import tiny_base
from typer.testing import CliRunner

from imc.cli import app
from imc.outputs.rerun_log import ENTITY_PATHS

cli = CliRunner()
RERUN = str(Path(sys.executable).parent / "rerun")
ENV = {"RERUN_TELEMETRY_ENABLED": "0", "PATH": "/usr/bin:/bin"}


@pytest.fixture(scope="module")
def texture_run(tmp_path_factory):
    """A 0.3 s texture-plant run (real frames and correlator) through `imc run`."""
    d = tmp_path_factory.mktemp("texture")
    data = tiny_base()
    data["plant"] = {"fidelity": "texture"}
    data["name"] = "tiny_texture"
    p = d / "s.yaml"
    p.write_text(yaml.safe_dump(data))
    r = cli.invoke(app, ["run", str(p), "--out", str(d / "out")])
    assert r.exit_code == 0, r.output
    return d / "out"


def _rrd(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([RERUN, "rrd", *args], capture_output=True, text=True, timeout=120,
                          env=ENV)


def test_run_report_is_self_contained_with_every_figure(texture_run):
    html = (texture_run / "report.html").read_text()
    for name in ("fig_motion", "fig_spectrum", "fig_psf", "fig_tracker", "fig_frame"):
        assert (texture_run / f"{name}.png").stat().st_size > 10_000, name
    imgs = re.findall(r'<img src="([^"]{0,30})', html)
    assert len(imgs) == 5 and all(s.startswith("data:image/png;base64,") for s in imgs)
    assert "tiny_texture" in html and "Residual image motion" in html


def test_imc_report_writes_it_again(texture_run):
    (texture_run / "report.html").unlink()
    (texture_run / "fig_psf.png").unlink()
    r = cli.invoke(app, ["report", str(texture_run)])
    assert r.exit_code == 0, r.output
    assert (texture_run / "report.html").exists() and (texture_run / "fig_psf.png").exists()
    r = cli.invoke(app, ["report", str(texture_run / "nothing")])
    assert r.exit_code == 2 and "neither a run folder" in r.output


def test_recording_verifies_and_holds_the_entity_paths(texture_run):
    rrd = texture_run / "recording.rrd"
    v = _rrd("verify", str(rrd))
    assert v.returncode == 0, v.stderr
    p = _rrd("print", str(rrd))
    assert p.returncode == 0, p.stderr
    paths = set(re.findall(r" - (/\S+) - data columns", p.stdout))
    expected = {f"/{e}" for e in (*ENTITY_PATHS, "tracker/frame")}
    assert expected <= paths, expected - paths
    assert {f"/tracker/error/block_{b}/crlb_col" for b in range(4)} <= paths


def test_blueprint_is_in_the_recording_and_loads(texture_run):
    """The recording carries a blueprint store made the default, whose containers and views
    decode (rerun rrd print reads every chunk); the views are the blueprint's."""
    p = _rrd("print", "-v", str(texture_run / "recording.rrd"))
    assert p.returncode == 0, p.stderr
    assert "Blueprint" in p.stdout and "make_default: true" in p.stdout
    views = set(re.findall(r" - (/view/[0-9a-f-]+) - ", p.stdout))
    # 2-D: frame, PSF open/closed; time series: row, col, 4 blocks; 3-D: 2
    assert len(views) == 11


def test_imc_view_needs_a_recording(tmp_path):
    r = cli.invoke(app, ["view", str(tmp_path)])
    assert r.exit_code == 2 and "no recording" in r.output


def test_sweep_report_has_lines_and_heat_maps(tiny_run, tmp_path):
    import shutil

    from imc.outputs.htmlreport import write_sweep_report

    _, out, _ = tiny_run
    shutil.copytree(out, tmp_path / "s")
    html = write_sweep_report(tmp_path / "s").read_text()
    tmp_path = tmp_path / "s"
    figs = sorted(f.name for f in (tmp_path / "figures").iterdir())
    # 3 metrics x (2 line plots + 1 heat map)
    assert len([f for f in figs if f.startswith("line_")]) == 6
    assert len([f for f in figs if f.startswith("heat_")]) == 3
    assert html.count("data:image/png;base64,") == 9 and "Extremes" in html


# ------------------------------------------------------------------ the run's output jobs


def _fails() -> None:
    raise ValueError("this job fails")


def _dies_in_a_helper() -> str:
    import multiprocessing
    import os

    if multiprocessing.parent_process() is not None:
        os._exit(3)
    return "ran inline"


@pytest.mark.parametrize("parallel", [False, True])
def test_jobs_hand_back_results_and_failures_in_order(parallel):
    from imc.outputs.jobs import make_jobs

    jobs = make_jobs(parallel)
    try:
        ok, bad, later = jobs.submit(sum, [1, 2]), jobs.submit(_fails), jobs.submit(max, [4, 5])
        assert jobs.result(ok) == 3
        with pytest.raises(ValueError, match="this job fails"):
            jobs.result(bad)
        assert jobs.result(later) == 5
    finally:
        jobs.close()


def _note(path: str, word: str, die_in_a_helper: bool = False) -> str:
    import multiprocessing
    import os

    if die_in_a_helper and multiprocessing.parent_process() is not None:
        os._exit(3)
    with open(path, "a") as f:
        f.write(word)
    return word


def test_jobs_the_helper_did_not_finish_run_inline_in_their_order(tmp_path):
    """The helper dies in job a with b queued behind it; c comes after the helper is gone:
    a, b, c still run in their order (c may need what b writes), each once."""
    import time

    from imc.outputs.jobs import ProcessJobs

    path = str(tmp_path / "notes")
    jobs = ProcessJobs()
    try:
        a, b = jobs.submit(_note, path, "a", True), jobs.submit(_note, path, "b")
        for _ in range(300):
            if jobs._pool._broken:
                break
            time.sleep(0.1)
        c = jobs.submit(_note, path, "c")
        assert [jobs.result(t) for t in (a, b, c)] == ["a", "b", "c"]
    finally:
        jobs.close()
    assert Path(path).read_text() == "abc"


def test_a_failed_run_stops_its_helper_at_once():
    """close(cancel=True), what a run that raised (or was interrupted) calls: the helper's
    job in progress and those queued are dropped, without waiting for them."""
    import time

    from imc.outputs.jobs import ProcessJobs

    jobs = ProcessJobs()
    jobs.submit(time.sleep, 60.0)
    jobs.submit(time.sleep, 60.0)
    t0 = time.perf_counter()
    jobs.close(cancel=True)
    assert time.perf_counter() - t0 < 15.0


def test_a_job_whose_helper_died_runs_again_inline():
    from imc.outputs.jobs import ProcessJobs

    jobs = ProcessJobs()
    try:
        assert jobs.result(jobs.submit(_dies_in_a_helper)) == "ran inline"
        assert jobs.result(jobs.submit(sum, [2, 2])) == 4  # the helper is gone: inline too
    finally:
        jobs.close()


def _jobs_in_a_daemon(queue) -> None:
    from imc.outputs.jobs import make_jobs

    jobs = make_jobs(True)
    queue.put((type(jobs).__name__, jobs.result(jobs.submit(sum, [1, 2]))))
    jobs.close()


def test_jobs_in_a_process_that_may_not_start_one_run_inline():
    """A pool's worker (a daemonic process) may not start a helper: the jobs run inline."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_jobs_in_a_daemon, args=(queue,), daemon=True)
    proc.start()
    try:
        assert queue.get(timeout=120) == ("InlineJobs", 3)
    finally:
        proc.join(timeout=60)


def test_a_killed_run_leaves_no_helper_behind():
    """SIGKILL the process that started the helper: the helper ends too (within seconds)."""
    import os
    import signal
    import time

    code = ("import time; from imc.outputs.jobs import ProcessJobs\n"
            "jobs = ProcessJobs(); jobs.result(jobs.submit(sum, [1]))\n"
            "print(*jobs._pool._processes, flush=True); time.sleep(120)")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        helper = int(proc.stdout.readline())
        os.kill(helper, 0)  # it runs
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    for _ in range(100):
        try:
            os.kill(helper, 0)
        except ProcessLookupError:
            return
        # a zombie awaits its reaper (init): it has ended all the same
        with open(f"/proc/{helper}/stat") as f:
            if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                return
        time.sleep(0.1)
    os.kill(helper, signal.SIGKILL)
    raise AssertionError("the helper outlived its parent by 10 s")


def test_a_helper_process_writes_what_inline_writes(tmp_path):
    """The same metrics, report figures (byte for byte), main-imager figure and recording,
    drawn on a helper process or in the run's own."""
    import json

    from imc.pipeline import run_scenario
    from imc.scenario import parse_scenario

    data = tiny_base()
    data["metrics"].update(blur_images=True, blur_spp=4)
    sc = parse_scenario(data)
    runs = {p: run_scenario(sc, tmp_path / f"parallel_{p}", report_figures=True,
                            parallel_outputs=p) for p in (False, True)}
    (m_in, i_in), (m_out, i_out) = runs[False], runs[True]
    # the closed-loop renders repeat to float32 rounding only (4e-8 relative), inline too
    blur_in, blur_out = m_in.pop("main_imager_blur"), m_out.pop("main_imager_blur")
    assert json.dumps(m_in, sort_keys=True) == json.dumps(m_out, sort_keys=True)
    assert blur_in.keys() == blur_out.keys()
    for key, v in blur_in.items():
        assert v == pytest.approx(blur_out[key], rel=1e-6), key
    names = [f.path.name for f in i_in["figures"]]
    assert names == [f.path.name for f in i_out["figures"]] and "fig_psf.png" in names
    assert sorted(Path(f).name for f in i_in["files"]) == sorted(
        Path(f).name for f in i_out["files"])
    for name in names:
        a, b = (tmp_path / f"parallel_{p}" / name for p in (False, True))
        assert a.read_bytes() == b.read_bytes(), name
    for p in (False, True):
        assert (tmp_path / f"parallel_{p}" / "main_imager.png").stat().st_size > 50_000
        assert (tmp_path / f"parallel_{p}" / "recording.rrd").stat().st_size > 10_000


def test_a_run_without_pictures_leaves_no_earlier_picture_in_its_folder(tmp_path):
    """main_imager.png of an earlier run in the same folder would show in this run's report
    and recording: a run that does not draw it removes it."""
    from imc.pipeline import run_scenario
    from imc.scenario import parse_scenario

    data = tiny_base()
    data["metrics"].update(blur_images=True, blur_spp=4)
    run_scenario(parse_scenario(data), tmp_path, rerun=False)
    assert (tmp_path / "main_imager.png").exists()
    data["metrics"]["blur_images"] = False
    _, info = run_scenario(parse_scenario(data), tmp_path, fresh=True, rerun=False,
                           report_figures=True)
    assert not (tmp_path / "main_imager.png").exists()
    assert all(Path(f).name != "main_imager.png" for f in info["files"])

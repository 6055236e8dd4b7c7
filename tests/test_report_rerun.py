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

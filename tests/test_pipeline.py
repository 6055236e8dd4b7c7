"""End to end: the quickstart scenario, its outputs, and resuming a run."""

import csv
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import QUICKSTART

from imc.pipeline import run_scenario
from imc.scenario import parse_scenario


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, quickstart):
    out = tmp_path_factory.mktemp("quickstart")
    metrics, info = run_scenario(quickstart, out, save_frames=True)
    return out, metrics, info


def test_loop_reduces_residual_rms_at_least_5x(quick_run):
    _, m, _ = quick_run
    # 1 px, 2 Hz jitter, 100 Hz tracker, one frame of latency, gain 0.8
    assert m["without_compensation"]["rms_total_px"] > 0.6
    assert m["rms_reduction"] >= 5.0
    assert m["with_compensation"]["mtf_nyquist"][0] > m["without_compensation"]["mtf_nyquist"][0]


def test_tracker_measures_rendered_motion(quick_run):
    _, m, _ = quick_run
    t = m["tracker"]
    assert t["valid_fraction"] >= 0.95
    # rendered 64x64 blocks at SNR 20: error near the CRLB (~0.015 px), bounded at 0.05 px
    assert max(t["rms_error_px"]) < 0.05
    assert max(t["rms_error_px"]) < 2.0 * max(t["median_crlb_px"])


def test_frames_npz_lets_anyone_check_the_chain(quick_run):
    out, _, _ = quick_run
    with np.load(out / "frames.npz") as z:
        frames, t = z["frames"], z["t_s"]
        true_shift, stage = z["true_shift_px"], z["stage_offset_px"]
        ref_index = z["ref_index"]
    assert frames.shape == (100, 256, 256) and t.shape == (100,)
    assert true_shift.shape == (100, 4, 2) and np.all(ref_index == 0)  # staring: fixed ref
    # the pitch jitter moves the content along rows by up to ~2 px peak-to-peak (less what
    # the stage took out); columns barely move
    motion = true_shift.mean(axis=1) + stage
    assert 1.5 < np.ptp(motion[:, 0]) < 2.5 and np.ptp(motion[:, 1]) < 0.05
    # independent check: correlate the central block of frame 50 against frame 0
    from correlator import measure_shift

    res = measure_shift(frames[0, 64:192, 64:192], frames[50, 64:192, 64:192])
    assert np.abs(res.shift - true_shift[50].mean(axis=0)).max() < 0.05


def test_tracks_csv_and_metrics_json(quick_run):
    out, m, _ = quick_run
    rows = list(csv.DictReader(open(out / "tracks.csv")))
    assert len(rows) == 100 * 4
    assert {"t_s", "block", "true_row_px", "meas_row_px", "valid"} <= set(rows[0])
    assert json.loads((out / "metrics.json").read_text())["rms_reduction"] == m["rms_reduction"]


def test_recording_rrd_verifies(quick_run):
    out, _, _ = quick_run
    rerun = shutil.which("rerun") or str(Path(__import__("sys").executable).parent / "rerun")
    proc = subprocess.run([rerun, "rrd", "verify", str(out / "recording.rrd")],
                          capture_output=True, text=True, timeout=120,
                          env={"RERUN_TELEMETRY_ENABLED": "0", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr


def test_resumed_run_equals_uninterrupted_run(tmp_path):
    data = yaml.safe_load(QUICKSTART.read_text())
    data["duration_s"] = 0.2
    data["camera"]["tracker"].update(rows=128, cols=128)
    data["scene"]["size_m"] = 256
    sc = parse_scenario(data)
    full, _ = run_scenario(sc, tmp_path / "full", rerun=False)
    # interrupted after 10 frames: keep only the first checkpoint chunk (as a kill leaves it)
    part = tmp_path / "part" / "checkpoint"
    part.mkdir(parents=True)
    src = tmp_path / "full" / "checkpoint"
    shutil.copy(src / "meta.json", part / "meta.json")
    shutil.copy(src / "chunk_0000000.npz", part / "chunk_0000000.npz")
    resumed, info = run_scenario(sc, part.parent, rerun=False)
    assert info["resumed_from_frame"] == 10
    # Dr.Jit's multi-threaded film accumulation is reproducible to one ulp only (~270 pixels
    # of a 128^2 frame differ by 6e-8 between identical renders); now and then a frame ends
    # up with one pixel a few DN apart (seen: 7 DN at 1 pixel of 16384), which moves a block's
    # shift by ~0.0015 px and the stage after it by ~2e-4 px. A resumed run must match to a
    # tenth of the tracker's noise (0.002 px, or 0.2 % for ratios).
    _assert_same(resumed, full, tol=2e-3)


def _assert_same(a, b, tol: float, path: str = "metrics") -> None:
    """Equal structure, equal non-numbers, numbers within ``tol`` (absolute, and relative for
    large ones)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), path
        for k in a:
            _assert_same(a[k], b[k], tol, f"{path}.{k}")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, tol, f"{path}[{i}]")
    elif isinstance(a, float) and not isinstance(a, bool):
        assert b == pytest.approx(a, rel=tol, abs=tol, nan_ok=True), path
    else:
        assert a == b, path


def test_todays_loop_through_the_rendered_pipeline_is_the_first_order_law(tmp_path):
    """The quickstart with the loop imcsim had before (ideal stage holding each command,
    first-order law with gain 0.8, mean of the blocks): the stage of every frame, as
    tracks.csv reports it, is the law s_{k+1} = s_k + 0.8 (m_k - s_k) replayed on the
    rendered frames' measured shifts (m_k: their mean plus the stage frame k was taken with)."""
    data = yaml.safe_load(QUICKSTART.read_text())
    data["duration_s"] = 0.3
    data["camera"]["main_imager"]["start_s"] = 0.0
    data["compensation"] = {"controller": {"kind": "integrator", "gain": 0.8},
                            "actuator": {"kind": "ideal"}, "estimator": {"kind": "mean"}}
    run_scenario(parse_scenario(data), tmp_path, rerun=False)
    rows = list(csv.DictReader(open(tmp_path / "tracks.csv")))
    n = len(rows) // 4
    meas = np.array([[float(r["meas_row_px"]), float(r["meas_col_px"])]
                     for r in rows]).reshape(n, 4, 2)
    stage = np.array([[float(r["stage_row_px"]), float(r["stage_col_px"])]
                      for r in rows]).reshape(n, 4, 2)[:, 0]
    replay = np.zeros((n, 2))
    for k in range(n - 1):
        estimate = meas[k].mean(axis=0) + replay[k]
        replay[k + 1:] = replay[k] + 0.8 * (estimate - replay[k])
    assert stage == pytest.approx(replay, abs=2e-5)  # tracks.csv keeps 5 decimals

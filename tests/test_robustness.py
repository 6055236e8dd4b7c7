"""Malformed input ends in one line (exit 2), a bug in one line and a log (exit 1); numbers
finite; epochs in any ISO form; strict YAML; run sizes checked before anything is allocated;
outputs strict and atomic; damaged checkpoints moved aside (issue 17)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import QUICKSTART, ROOT
from test_scenario_cli import _quickstart_with as _quickstart
from test_scenario_cli import _write
from typer.testing import CliRunner

from imc.cli import app, main
from imc.scenario import OrbitConfig, ScenarioError, _Model, load_scenario, parse_scenario

runner = CliRunner()



def _one_line_error(res, *words) -> str:
    """The CLI result is exit 2 with one line naming words, no traceback."""
    text = res.output.strip()
    assert res.exit_code == 2, text
    assert "Traceback" not in text and len(text.splitlines()) == 1, text
    for w in words:
        assert w in text, (w, text)
    return text


# ------------------------------------------------------------------------------ numbers
def _models():
    seen, todo = [], [_Model]
    while todo:
        cls = todo.pop()
        for sub in cls.__subclasses__():
            if sub not in seen:
                seen.append(sub)
                todo.append(sub)
    return seen


def _float_fields():
    out = []
    for cls in _models():
        for name, f in cls.model_fields.items():
            if "float" in str(f.annotation):
                out.append((cls, name, f.annotation))
    return out


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e308])
def test_every_float_field_of_the_schema_refuses_non_finite_and_huge(bad):
    fields = _float_fields()
    assert len(fields) > 60  # the whole schema, not a sample
    for cls, name, ann in fields:
        value = [bad, bad] if str(ann).startswith("tuple") else bad
        try:
            cls.model_validate({name: value})
        except Exception as e:  # noqa: BLE001 (pydantic's ValidationError)
            errs = [err for err in e.errors() if err["loc"][:1] == (name,)]
            assert errs, (cls.__name__, name, bad)
            continue
        raise AssertionError(f"{cls.__name__}.{name} accepted {bad}")


@pytest.mark.parametrize("dotted, value, field", [
    ("camera.optics.aperture_m", math.inf, "camera.optics.aperture_m"),
    ("attitude.jitter.sinusoids", [{"axis": "roll", "frequency_hz": 1.0,
                                    "amplitude_px": math.inf}],
     "attitude.jitter.sinusoids.0.amplitude_px"),
    ("attitude.jitter", [{"axis": "roll", "frequency_hz": math.nan, "amplitude_px": 1.0}],
     "attitude.jitter.0.frequency_hz"),  # the list form: the path as written
    ("camera.tracker.noise_sigma_dn", math.inf, "camera.tracker.noise_sigma_dn"),
    ("correlator.psr_threshold", math.inf, "correlator.psr_threshold"),
    ("compensation.gain", math.nan, "compensation.gain"),  # the older spelling, as written
    ("compensation.latency_frames", -1, "compensation.latency_frames"),
    ("correlator.optical.input_slm.rows", 0, "correlator.optical.input_slm.rows"),
    ("seed", True, "seed"),
    ("camera.tracker.center_offset_px", [0.0, 1e300], "camera.tracker.center_offset_px"),
])
def test_bad_numbers_name_the_field_as_written(dotted, value, field):
    data = _quickstart(**{dotted: value})
    if dotted == "compensation.gain":  # the older spelling alone (the quickstart has both)
        data["compensation"].pop("controller", None)
    if dotted.startswith("compensation.latency"):
        data["compensation"].pop("gain", None)
        data["compensation"].pop("transport", None)
    with pytest.raises(ScenarioError) as e:
        parse_scenario(data, "q.yaml")
    msg = str(e.value)
    assert f"q.yaml: {field}" in msg and "\n" not in msg, msg


def test_block_parameters_are_finite_numbers_too():
    for ctl, key in (({"kind": "pi", "kp": math.inf, "ki": 1.0}, "kp"),
                     ({"kind": "pii", "lines": [1.0, math.nan]}, "lines.1"),
                     ({"kind": "kalman", "bandwidth_hz": True}, "bandwidth_hz")):
        with pytest.raises(ScenarioError, match=rf"compensation\.controller\.{key}:"):
            parse_scenario({"compensation": {"controller": ctl}})


def test_optical_model_errors_name_the_scenario_path():
    from imc.wiring.build import build_models

    sc = parse_scenario(_quickstart(**{"correlator.method": "optical",
                                       "correlator.subpixel": "com",
                                       "correlator.optical": {"lens1_focal_m": 0.01}}))
    with pytest.raises(ScenarioError, match=r"^correlator\.optical\.lens1_focal_m = 0\.01"):
        build_models(sc, light=True)


# -------------------------------------------------------------------------------- time
@pytest.mark.parametrize("text", [
    "2026-06-21T10:30:00Z", "2026-06-21T10:30:00+00:00", "2026-06-21T12:30:00+02:00",
    "2026-06-21T05:30:00-05:00", "2026-06-21 10:30:00", "2026-06-21T10:30:00",
    "'2026-06-21T10:30:00Z'", "'2026-06-21T12:30:00+02:00'"])
def test_epochs_with_z_offsets_or_none_are_the_same_utc_instant(tmp_path, text):
    sc = load_scenario(_write(tmp_path, f"orbit:\n  epoch_utc: {text}\n"))
    assert sc.orbit.epoch_utc == datetime(2026, 6, 21, 10, 30)
    assert sc.epoch == np.datetime64("2026-06-21T10:30:00", "ns")
    assert runner.invoke(app, ["validate", str(_write(tmp_path, yaml.safe_dump(
        _quickstart(**{"orbit.epoch_utc": sc.orbit.epoch_utc}))))]).exit_code == 0


@pytest.mark.parametrize("text, words", [
    ("0", "not a number"), ("1700000000", "not a number"), ("2300-01-01", "1678-09-22"),
    ("1600-01-01T00:00:00Z", "2262-04-10"), ("'yesterday'", "ISO 8601"),
    ("2026-13-01", "month must be in 1..12"), ("2026-02-30", "day is out of range"),
    ("9999-12-31T23:59:59-12:00", "2262-04-10")])
def test_epochs_imcsim_cannot_propagate_are_refused(tmp_path, text, words):
    with pytest.raises(ScenarioError, match=words) as e:
        load_scenario(_write(tmp_path, f"orbit:\n  epoch_utc: {text}\n"))
    assert "epoch_utc" in str(e.value) or "line 2" in str(e.value)


def test_the_propagatable_range_has_no_silent_wrap():
    from imc.scenario import EPOCH_MAX, EPOCH_MIN

    for when in (EPOCH_MIN, EPOCH_MAX):
        sc = parse_scenario({"orbit": {"epoch_utc": when.isoformat()}})
        assert sc.epoch.astype("datetime64[s]").astype(datetime) == when
    assert "1678-09-22" in OrbitConfig.model_fields["epoch_utc"].description


# -------------------------------------------------------------------------------- YAML
@pytest.mark.parametrize("text, words", [
    ("camera: {}\ncamera: {}\n", "line 2, column 1: duplicate key camera (first at line 1)"),
    ("orbit:\n  kind: tle\n  kind: circular\n", "line 3, column 3: duplicate key kind"),
    ("seed: !!float abc\n", "line 1, column 7: cannot read abc as float"),
    ("orbit: {epoch_utc: !!timestamp noon}\n", "cannot read noon as timestamp"),
    ("seed: !!python/object:os.system ls\n", "tag !!python/object:os.system is not allowed"),
    ("seed: !custom 5\n", "tag !custom is not allowed"),
    ("name: !!binary aGVsbG8=\n", "tag !!binary is not allowed"),
    ("seed: " + "7" * 5000 + "\n", "line 1, column 7: cannot read"),
    ("x: " + "[" * 3000 + "]" * 3000 + "\n", "nesting deeper than 32 levels"),
    ("x: &r [*r]\n", "recursive alias"),
    ("orbit: [1, 2\n", "YAML syntax error at line 2"),
])
def test_yaml_problems_are_one_line_with_line_and_column(tmp_path, text, words):
    with pytest.raises(ScenarioError) as e:
        load_scenario(_write(tmp_path, text))
    msg = str(e.value)
    assert words in msg and "\n" not in msg and len(msg) < 600, msg


def test_an_alias_bomb_is_refused_quickly(tmp_path):
    import time

    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 10)]
    p = _write(tmp_path, "\n".join(lines) + "\n")
    t = time.perf_counter()
    with pytest.raises(ScenarioError, match="expands to more than 100,000 values"):
        load_scenario(p)
    assert time.perf_counter() - t < 2.0


def test_files_that_are_not_scenarios(tmp_path):
    with pytest.raises(ScenarioError, match="is a folder"):
        load_scenario(tmp_path)
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ScenarioError, match="not a regular file"):  # and no hang
        load_scenario(fifo)
    with pytest.raises(ScenarioError, match="a scenario is a few KB"):
        load_scenario(_write(tmp_path, "#" * 2_000_000))
    (tmp_path / "bin.yaml").write_bytes(b"name: \xff\xfe\n")
    with pytest.raises(ScenarioError, match="not UTF-8"):
        load_scenario(tmp_path / "bin.yaml")
    with pytest.raises(ScenarioError, match="cannot read the file"):
        load_scenario(tmp_path / ("x" * 5000))


def test_long_values_are_cut_in_messages(tmp_path):
    p = _write(tmp_path, yaml.safe_dump(_quickstart(**{"correlator.method": "m" * 100_000})))
    res = runner.invoke(app, ["validate", str(p)])
    text = _one_line_error(res, "correlator.method", "(100000 characters)")
    assert len(text) < 600


# ----------------------------------------------------------------------------- run size
def test_600_s_at_100_khz_is_refused_before_anything_is_built(tmp_path):
    p = _write(tmp_path, "duration_s: 600\ncamera: {tracker: {frame_rate_hz: 100000}}\n")
    proc = subprocess.run([sys.executable, "-m", "imc.cli", "validate", str(p)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "duration_s x camera.tracker.frame_rate_hz" in proc.stderr
    assert "60,000,000 frames" in proc.stderr and "--force" in proc.stderr


@pytest.mark.parametrize("argv, code, words", [
    (["validate", "QUICKSTART"], 0, "terrain not built"),  # its last line, through a pipe
    (["run"], 2, "Missing argument"),
    (["metrics", "/nonexistent"], 2, "not found"),
])
def test_the_console_entry_keeps_exit_status_and_output(argv, code, words):
    """`imc` ends validate, run, metrics ... without the interpreter's teardown: the exit
    status and everything printed are kept."""
    argv = [str(QUICKSTART) if a == "QUICKSTART" else a for a in argv]
    proc = subprocess.run([sys.executable, "-c", "import sys; from imc.cli import entry; "
                           f"sys.argv = ['imc', *{argv!r}]; entry()"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == code, proc.stderr
    assert words in (proc.stdout + proc.stderr) and "Traceback" not in proc.stderr


def test_the_largest_tile_is_refused_with_the_estimate(tmp_path, monkeypatch):
    import imc.wiring.budget

    monkeypatch.setattr(imc.wiring.budget, "memory_budget_bytes", lambda: 8e9)
    p = _write(tmp_path, "scene: {size_m: 6553.6, texel_m: 0.4, dem_spacing_m: 6.4}\n")
    res = runner.invoke(app, ["validate", str(p)])
    _one_line_error(res, "scene.size_m / scene.texel_m", "16,384 texels", "GB", "--force")
    for cmd in (["run", str(p), "--out", str(tmp_path / "o")],
                ["loop", str(p), "--out", str(tmp_path / "o")]):
        _one_line_error(runner.invoke(app, cmd), "scene.size_m / scene.texel_m")
    assert not (tmp_path / "o" / "checkpoint").exists()


def test_validate_prints_the_estimate_and_stays_light():
    from imc.wiring.budget import estimate_run

    res = runner.invoke(app, ["validate", str(ROOT / "scenarios" / "ikonos_tdi_scan.yaml")])
    assert res.exit_code == 0, res.output
    assert "run size: 60 frames, peak memory" in res.output
    assert "terrain not built (23.0 M texels)" in res.output
    est = estimate_run(load_scenario(ROOT / "scenarios" / "ikonos_tdi_scan.yaml"))
    assert est.parts["terrain"] > 1.5e9  # the 4800^2 procedural tile of the run


@pytest.mark.parametrize("fidelity, blur_images", [("rendered", True), ("texture", True),
                                                   ("analytic", True), ("analytic", False)])
def test_estimate_bounds_a_measured_run(tmp_path, fidelity, blur_images):
    """The estimate is an upper-end figure: at least the measured peak of a small run (and
    not wildly above it), with and without the main imager's rendered blur images."""
    data = _quickstart(duration_s=0.1, **{"camera.tracker.rows": 128, "plant.fidelity": fidelity,
                                          "camera.main_imager.start_s": 0.0,
                                          "metrics.blur_images": blur_images,
                                          "camera.tracker.cols": 128, "scene.size_m": 256})
    data.pop("expect", None)  # the quickstart's bounds are for its own run
    p = _write(tmp_path, yaml.safe_dump(data))
    # VmHWM: this process's peak (ru_maxrss would carry the parent's from before exec)
    code = ("import re, sys; from imc.cli import main; sys.argv[1:] = ['run', "
            f"{str(p)!r}, '--out', {str(tmp_path / 'o')!r}, '--no-rerun']\n"
            "try: main()\nexcept SystemExit as e: rc = e.code\n"
            "hwm = re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)\n"
            "print('PEAK', int(hwm) * 1024, rc)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, env={**os.environ, "RERUN_TELEMETRY_ENABLED": "0"})
    peak, rc = proc.stdout.split("PEAK")[1].split()
    assert rc == "0", proc.stderr
    from imc.wiring.budget import estimate_run

    est = estimate_run(parse_scenario(data))
    assert float(peak) <= est.peak_bytes <= 3.0 * float(peak)


# --------------------------------------------------------------------------- CLI lines
@pytest.mark.parametrize("argv, words", [
    (["frobnicate"], "No such command"),
    (["validate"], "Missing argument"),
    (["bench", "correlator", "--seed", "-1"], "'--seed'"),
    (["bench", "correlator", "--pairs", "1e20"], "'--pairs'"),
    (["loop", str(QUICKSTART), "--amplitude-px", "nan"], "'--amplitude-px'"),
    (["device-read", "x", "--seconds", "inf"], "'--seconds'"),
    (["run", str(QUICKSTART), "--bogus"], "No such option"),
])
def test_bad_arguments_are_one_line(capsys, argv, words):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "Traceback" not in err, err


def test_out_is_checked_before_any_work(tmp_path, monkeypatch):
    import imc.pipeline

    called = []
    monkeypatch.setattr(imc.pipeline, "run_scenario", lambda *a, **k: called.append(1))
    (tmp_path / "f").write_text("x")
    q = str(QUICKSTART)
    for out, words in (("", "the path is empty"), (str(tmp_path / "f"), "is a file"),
                       (str(tmp_path / "f" / "sub"), "a part of the path is a file"),
                       (str(tmp_path / ("y" * 300)), "cannot use it as a folder")):
        _one_line_error(runner.invoke(app, ["run", q, "--out", out]), "--out", words)
    import tempfile

    def denied(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "NamedTemporaryFile", denied)
    _one_line_error(runner.invoke(app, ["run", q, "--out", str(tmp_path / "ro")]),
                    "not writable")
    assert not called


def test_an_internal_error_is_one_line_and_a_log(tmp_path, monkeypatch):
    import imc.pipeline

    def bug(*a, **k):
        return 1 / 0

    monkeypatch.setattr(imc.pipeline, "run_scenario", bug)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(QUICKSTART), "--out", str(out)])
    text = res.output.strip()
    assert res.exit_code == 1 and len(text.splitlines()) == 1, text
    assert "internal error (a bug in imcsim" in text and str(out / "imc-error.log") in text
    log = (out / "imc-error.log").read_text()
    assert "Traceback" in log and "ZeroDivisionError" in log


def test_metrics_of_the_wrong_shape_and_with_nulls(tmp_path):
    (tmp_path / "metrics.json").write_text('{"scenario": "x", "without_compensation": [1]}')
    _one_line_error(runner.invoke(app, ["metrics", str(tmp_path)]), "not a metrics file")
    (tmp_path / "metrics.json").write_text("{\"a\": NaN")
    _one_line_error(runner.invoke(app, ["metrics", str(tmp_path)]), "cannot read it")
    _one_line_error(runner.invoke(app, ["metrics", str(tmp_path / "none")]), "not found")
    _one_line_error(runner.invoke(app, ["metrics", "x" * 5000]), "File name too long")
    block = {"rms_px": [None, 0.1], "rms_total_px": None, "peak_to_peak_px": [0.1, 0.2],
             "mtf_nyquist": [1.0, None], "mtf_nyquist_worst": [None, None], "window_s": 0.1}
    (tmp_path / "metrics.json").write_text(json.dumps(
        {"scenario": "x", "without_compensation": block, "with_compensation": block}))
    res = runner.invoke(app, ["metrics", str(tmp_path)])
    assert res.exit_code == 0 and "n/a" in res.output


def test_device_emulator_link_folder_is_checked(tmp_path):
    p = str(ROOT / "scenarios" / "optical.yaml")
    _one_line_error(runner.invoke(app, ["device-emulator", p, "--link",
                                        str(tmp_path / "missing" / "jtoc")]), "does not exist")
    _one_line_error(runner.invoke(app, ["device-emulator", p, "--link", str(tmp_path)]),
                    "is a folder")


# ------------------------------------------------------------------------------ outputs
def test_json_is_strict():
    from imc.io import strict_json, write_json

    obj = {"a": math.nan, "b": [math.inf, 1.0, np.float32("nan")], "c": np.array([1.0, np.nan]),
           "d": np.int64(3), "e": {"f": -math.inf}}
    assert strict_json(obj) == {"a": None, "b": [None, 1.0, None], "c": [1.0, None], "d": 3,
                                "e": {"f": None}}
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        write_json(Path(d) / "m.json", obj)
        text = (Path(d) / "m.json").read_text()

    def refuse(name):
        raise ValueError(name)

    assert json.loads(text, parse_constant=refuse)["a"] is None


def test_a_killed_write_leaves_a_marked_temp_file_the_next_run_removes(tmp_path):
    code = ("import os, signal; from pathlib import Path; from imc.io import atomic_write\n"
            "def w(p):\n    p.write_text('half'); os.kill(os.getpid(), signal.SIGKILL)\n"
            f"atomic_write(Path({str(tmp_path / 'recording.rrd')!r}), w)")
    subprocess.run([sys.executable, "-c", code], timeout=60)
    left = [p.name for p in tmp_path.iterdir()]
    assert len(left) == 1 and left[0].startswith(".recording.rrd.imctmp-"), left
    from imc.io import remove_stale_temps

    (tmp_path / "keep.txt").write_text("mine")
    assert len(remove_stale_temps(tmp_path)) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]


# -------------------------------------------------------------------------- checkpoints
def _store(tmp_path, digest="d1", warn=None):
    from imc.wiring.checkpoint import ChunkStore

    return ChunkStore(tmp_path / "checkpoint", digest, warn)


def _chunks(store, n=4):
    from compensation.loop import Chunk

    for k in range(n):
        store.write(Chunk(10 * k, 10 * k + 10, {"rec/x": np.arange(10.0) + 10 * k}))


@pytest.mark.parametrize("damage", ["truncate", "flip", "empty", "gap", "folder"])
def test_a_damaged_chunk_is_moved_aside_and_the_run_resumes_before_it(tmp_path, damage):
    warnings = []
    store = _store(tmp_path, warn=warnings.append)
    _chunks(store)
    p = store.folder / "chunk_0000020.npz"
    raw = p.read_bytes()
    if damage == "truncate":
        p.write_bytes(raw[: len(raw) // 2])
    elif damage == "flip":  # inside the array data: the zip's CRC catches it
        b = bytearray(raw)
        i = raw.index(np.arange(20.0, 30.0).tobytes()) + 17
        b[i] ^= 0x04
        p.write_bytes(bytes(b))
    elif damage == "empty":
        p.write_bytes(b"")
    elif damage == "gap":
        p.unlink()
    else:
        p.unlink()
        p.mkdir()
    got = _store(tmp_path, warn=warnings.append).load()
    assert [c.start for c in got] == [0, 10]
    assert np.array_equal(got[1].arrays["rec/x"], np.arange(10.0, 20.0))
    if damage != "gap":
        assert len(warnings) == 1 and "chunk_0000020.npz is damaged" in warnings[0]
        assert (store.folder / "chunk_0000020.npz.bad").exists()
    assert (store.folder / "chunk_0000030.npz.bad").exists()


def test_a_damaged_meta_moves_the_checkpoint_aside_another_scenarios_is_removed(tmp_path):
    warnings = []
    store = _store(tmp_path, warn=warnings.append)
    _chunks(store, 2)
    (store.folder / "meta.json").write_text("{not json")
    assert _store(tmp_path, warn=warnings.append).load() == []
    assert "damaged" in warnings[-1]
    assert (tmp_path / "checkpoint.bad" / "chunk_0000000.npz").exists()
    assert not store.folder.exists()
    _chunks(store, 2)
    assert len(_store(tmp_path, "d1").load()) == 2
    assert _store(tmp_path, "d2", warnings.append).load() == []
    assert "another scenario" in warnings[-1] and not store.folder.exists()
    # the next run of d2 writes its own meta: a later resume finds its chunks
    s2 = _store(tmp_path, "d2")
    _chunks(s2, 1)
    assert len(_store(tmp_path, "d2").load()) == 1


def test_resume_with_the_serial_link_reports_what_the_uninterrupted_run_does(tmp_path):
    """The link's counters, sequence numbers and fault generator travel with the chunks: a
    run resumed after its first chunk reports the same link counters and metrics."""
    import shutil

    from imc.pipeline import run_scenario

    data = yaml.safe_load((ROOT / "scenarios" / "optical.yaml").read_text())
    data.update(duration_s=0.2, plant={"fidelity": "analytic", "sigma_px": 0.05})
    data["correlator"]["timing"] = {"enabled": False}
    data["correlator"]["link"] = {"kind": "emulator", "corrupt_probability": 0.05,
                                  "drop_probability": 0.03}
    sc = parse_scenario(data)
    full, _ = run_scenario(sc, tmp_path / "full", rerun=False)
    assert full["link"]["lost"] + full["link"]["crc_errors"] > 0
    part = tmp_path / "part" / "checkpoint"
    part.mkdir(parents=True)
    for name in ("meta.json", "chunk_0000000.npz"):
        shutil.copy(tmp_path / "full" / "checkpoint" / name, part / name)
    resumed, info = run_scenario(sc, part.parent, rerun=False)
    assert info["resumed_from_frame"] == 10
    assert resumed["link"] == full["link"]
    assert json.dumps(resumed, sort_keys=True) == json.dumps(full, sort_keys=True)


# ---------------------------------------------------------------------------- correlator
@pytest.mark.parametrize("options", [{}, {"method": "optical"}, {"method": "xcorr"},
                                     {"detection": "masked", "max_shift_px": 20.0}])
def test_empty_block_stacks_give_empty_results(options):
    from correlator import measure_shift

    r = measure_shift(np.zeros((0, 32, 32)), np.zeros((0, 32, 32)), **options)
    assert r.shift.shape == (0, 2) and r.valid.shape == (0,)


@pytest.mark.parametrize("name", ["max_shift_px", "psr_threshold", "max_crlb_px",
                                  "min_overlap", "max_rival_ratio"])
def test_nan_correlator_options_are_refused(name):
    from correlator import CorrelatorOptions

    with pytest.raises(ValueError, match=f"{name} must be a finite number"):
        CorrelatorOptions(**{name: math.nan})


def test_an_instantaneous_exposure_is_an_instant_not_nan(tmp_path):
    """camera.tracker.exposure_s = 1e-300 is inside the schema: the loop model takes the
    stage's value at that instant (a fresh fuzz found NaN margins and an internal error)."""
    data = _quickstart(**{"camera.tracker.exposure_s": 1e-300})
    res = runner.invoke(app, ["validate", str(_write(tmp_path, yaml.safe_dump(data)))])
    assert res.exit_code == 0, res.output
    assert "peak |S|" in res.output and "nan" not in res.output.lower()


def test_a_block_parameter_written_as_text_that_reads_as_inf_is_refused(tmp_path):
    """PyYAML reads 1e400 (no dot) as text, which pydantic's lax mode turns into inf inside a
    block's parameters (a second fresh fuzz found it): refused, naming the element."""
    text = (ROOT / "scenarios" / "ikonos_tdi_scan.yaml").read_text()
    text = text.replace("lines_hz: [4.3, 35.0, 70.0]", "lines_hz: [4.3, 35.0, 1e400]")
    assert "1e400" in text
    res = runner.invoke(app, ["validate", str(_write(tmp_path, text))])
    assert res.exit_code == 2
    assert "compensation.controller.lines_hz.2: must be a finite number" in res.output

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import QUICKSTART
from typer.testing import CliRunner

from imc.cli import app
from imc.scenario import ScenarioError, load_scenario, parse_scenario
from imc.yamlload import with_changes

runner = CliRunner()


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return p


def _quickstart_with(**changes) -> dict:
    return with_changes(yaml.safe_load(QUICKSTART.read_text()), changes)


def test_quickstart_loads_with_ikonos_values(quickstart):
    assert quickstart.n_frames == 100
    assert quickstart.exposure_s == pytest.approx(0.01)
    assert quickstart.camera.focal_length_m == 10.0
    assert quickstart.attitude.jitter.sinusoids[0].frequency_hz == 2.0
    assert quickstart.attitude.jitter.wheels == ()  # a given jitter section replaces the default


def test_defaults_are_ikonos_like():
    from imc.scenario import DEFAULT_JITTER, parse_scenario

    sc = parse_scenario({})
    assert sc.orbit.kind == "sun_synchronous" and sc.orbit.altitude_m == 681e3
    assert sc.attitude.jitter == DEFAULT_JITTER
    f = sorted(s.frequency_hz for s in DEFAULT_JITTER.sinusoids)
    assert f == [0.65, 4.3]
    assert DEFAULT_JITTER.wheels[0].harmonics[0].amplitude_px == 0.02
    assert sc.camera.optics.aperture_m == 0.70 and sc.camera.main_imager.kind == "frame"


@pytest.mark.parametrize(
    "data, words",
    [
        ({"orbit": {"kind": "tle"}}, "orbit: kind 'tle' needs tle_line1"),
        ({"orbit": {"kind": "elements"}}, "semi_major_axis_m"),
        ({"orbit": {"kind": "tle", "tle_line1": "1 x", "tle_line2": "2 y"},
          "attitude": {"mode": "nadir"}}, "use attitude.mode 'target'"),
        ({"camera": {"main_imager": {"kind": "tdi"}}}, "needs a scanning attitude"),
        ({"attitude": {"mode": "nadir", "roll_deg": 10}}, "use mode 'off_nadir'"),
        ({"attitude": {"mode": "target", "yaw_steering": True}}, "scanning mode"),
        ({"attitude": {"jitter": {"random": [{"axis": "roll", "rms_px": 1, "f_min_hz": 5,
                                              "f_max_hz": 1}]}}}, "f_max_hz must exceed"),
    ],
)
def test_new_sections_name_the_field_and_the_fix(data, words):
    from imc.scenario import ScenarioError, parse_scenario

    with pytest.raises(ScenarioError) as e:
        parse_scenario(data)
    assert words in str(e.value)
    assert "\n" not in str(e.value)


def test_bad_tle_is_a_scenario_error():
    from imc.scenario import ScenarioError, parse_scenario
    from imc.wiring.build import build_models

    sc = parse_scenario({"orbit": {"kind": "tle", "tle_line1": "1 25544U garbage",
                                   "tle_line2": "2 25544 garbage"}})
    with pytest.raises(ScenarioError, match="orbit: .*TLE"):
        build_models(sc)


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"camera.tracker.frame_rate_hz": -5}, "camera.tracker.frame_rate_hz"),
        ({"camera.tracker.rows": "many"}, "camera.tracker.rows"),
        ({"correlator.method": "fft"}, "correlator.method"),
        ({"correlator.block_px": 512}, "block_px"),
        ({"scene.sizee_m": 5}, "scene.sizee_m"),
        ({"attitude.jitter": [{"axis": "pitch", "frequency_hz": 2.0}]},
         "attitude.jitter.0"),  # the list form: the path as written
        ({"camera.tracker.exposure_s": 0.5}, "camera.tracker"),
    ],
)
def test_invalid_fields_are_named(changes, field):
    with pytest.raises(ScenarioError) as e:
        parse_scenario(_quickstart_with(**changes), "q.yaml")
    msg = str(e.value)
    assert field in msg and "\n" not in msg


def test_yaml_syntax_and_file_errors(tmp_path):
    with pytest.raises(ScenarioError, match="YAML syntax error at line 3"):
        load_scenario(_write(tmp_path, "name: x\norbit: [1, 2\n"))
    with pytest.raises(ScenarioError, match="not found"):
        load_scenario(tmp_path / "missing.yaml")
    with pytest.raises(ScenarioError, match="mapping"):
        load_scenario(_write(tmp_path, "- 1\n- 2\n"))
    with pytest.raises(ScenarioError, match="empty"):
        load_scenario(_write(tmp_path, ""))


def test_cli_bad_scenario_is_one_line_and_nonzero(tmp_path):
    bad = _write(tmp_path, yaml.safe_dump(_quickstart_with(**{"scene.spp": 0})))
    res = runner.invoke(app, ["run", str(bad), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    text = res.output.strip()
    assert "scene.spp" in text and "Traceback" not in text


def test_cli_subprocess_never_prints_a_traceback(tmp_path):
    bad = _write(tmp_path, "orbit:\n  altitude_m: low\n")
    proc = subprocess.run([sys.executable, "-m", "imc.cli", "run", str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "orbit.altitude_m" in proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert len(proc.stderr.strip().splitlines()) <= 2


def test_validate_catches_a_tile_too_small_for_nadir_mode(tmp_path):
    data = _quickstart_with(**{"attitude.mode": "nadir"})
    p = _write(tmp_path, yaml.safe_dump(data))
    res = runner.invoke(app, ["validate", str(p)])
    assert res.exit_code == 2
    assert "scene.size_m" in res.output and "nadir" in res.output
    ok = runner.invoke(app, ["validate", str(QUICKSTART)])
    assert ok.exit_code == 0, ok.output


def test_info_names_the_variant():
    res = runner.invoke(app, ["info"])
    assert res.exit_code == 0
    assert "mitsuba variant:" in res.output
    assert any(v in res.output for v in ("llvm_ad_rgb", "cuda_ad_rgb", "scalar_rgb"))


def test_scenario_reference_is_current():
    import importlib.util

    from conftest import ROOT

    spec = importlib.util.spec_from_file_location("gen", ROOT / "scripts" / "gen_scenario_doc.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    assert (ROOT / "docs" / "scenario.md").read_text() == gen.render(), (
        "docs/scenario.md is stale: run .venv/bin/python scripts/gen_scenario_doc.py")


def test_scene_kinds_sun_and_clouds_from_the_scenario():
    from imc.wiring.build import build_scene

    auto = parse_scenario(_quickstart_with(**{"scene.sun_elevation_deg": None,
                                             "scene.sun_azimuth_deg": None}))
    _, _, centre, sun = build_scene(auto)
    from orbit.sun import sun_elevation_azimuth_deg

    el, az = sun_elevation_azimuth_deg(35.0, 10.0, auto.epoch)
    assert sun == pytest.approx((float(el), float(az))) and centre == (35.0, 10.0)
    night = parse_scenario(_quickstart_with(**{"scene.sun_elevation_deg": None,
                                              "scene.sun_azimuth_deg": None,
                                              "orbit.epoch_utc": "2026-06-21T23:00:00"}))
    with pytest.raises(ScenarioError, match="daytime epoch"):
        build_scene(night)
    with pytest.raises(ScenarioError, match="give both sun_elevation_deg and sun_azimuth_deg"):
        parse_scenario(_quickstart_with(**{"scene.sun_azimuth_deg": None}))
    mountain = parse_scenario(_quickstart_with(**{"scene.kind": "mountain",
                                                 "scene.relief_rms_m": None}))
    terrain, clouds, _, _ = build_scene(mountain)
    assert clouds is not None and clouds.cover == pytest.approx(0.2, abs=0.03)
    assert clouds.base_m == pytest.approx(float(terrain.dem_m.max()) + 1000.0)
    clear = parse_scenario(_quickstart_with(**{"scene.kind": "mountain",
                                              "scene.clouds": {"cover": 0.0}}))
    assert build_scene(clear)[1] is None


def test_geotiff_scene_paths_are_relative_to_the_scenario(tmp_path):
    import numpy as np

    from scene.geotiff import write_geotiff

    (tmp_path / "data").mkdir()
    img = (np.random.default_rng(0).random((1400, 1400)) * 200).astype(np.uint8)
    write_geotiff(tmp_path / "data" / "ortho.tif", img, 500000.0, 4000000.0, 0.4, 0.4)
    data = _quickstart_with(**{"scene.kind": "geotiff"})
    data["scene"]["geotiff"] = {"ortho": "data/ortho.tif"}
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(data))
    res = runner.invoke(app, ["validate", str(p)])
    assert res.exit_code == 0, res.output
    data["scene"]["geotiff"] = {"ortho": "data/missing.tif"}
    p.write_text(yaml.safe_dump(data))
    res = runner.invoke(app, ["validate", str(p)])
    assert res.exit_code == 2
    assert "scene.geotiff.ortho" in res.output and "file not found" in res.output
    assert "Traceback" not in res.output
    data["scene"].pop("geotiff")
    p.write_text(yaml.safe_dump(data))
    res = runner.invoke(app, ["validate", str(p)])
    assert res.exit_code == 2 and "needs the geotiff section" in res.output

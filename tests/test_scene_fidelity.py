"""Rendering fidelity: rendered motion equals the camera model's predicted image motion.

Tolerances (measured with Monte Carlo pixel integration; the default fixed quadrature is
quieter, see the floor tests): Monte Carlo noise at spp 16 gives ~0.006 px 1-sigma per
112^2 block (measured over 24 blocks: RMS 0.005-0.006 px, bias < 0.004 px), so the mean of
4 blocks is held to 0.01 px and each block to 0.025 px (4 sigma).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camera.geometry import FocalPlane, Pose, project
from camera.motion import CameraModel
from correlator import measure_shift
from orbit.attitude import Attitude, orbit_looking_at
from orbit.frames import LocalFrame
from scene.classes import scene_class
from scene.pinhole import ray_keyframes
from scene.terrain import Terrain

EPOCH = np.datetime64("2026-06-21T10:30:00")
N = 256
BASE = "urban"  # texture of the mesa scene (aliasing-free enough at 64^2 blocks)


def _camera(roll_deg: float, fp: FocalPlane, mode: str | None = None) -> CameraModel:
    frame = LocalFrame(35.0, 10.0, 0.0)
    orbit = orbit_looking_at(35.0, 10.0, 681e3, 98.1, EPOCH, roll_deg=roll_deg)
    if mode == "target":
        att = Attitude("target", target_ecef_m=tuple(frame.origin_ecef_m.tolist()))
    else:
        att = Attitude("off_nadir" if roll_deg else "nadir", roll_deg=roll_deg,
                       yaw_steering=True)
    return CameraModel(orbit, att, frame, fp)


def _blocks(img: np.ndarray, corners, b: int) -> np.ndarray:
    return np.stack([img[r:r + b, c:c + b] for r, c in corners])


@pytest.fixture(scope="module")
def urban_renderer():
    from scene.kernel import Renderer, Sun

    terrain = scene_class("urban", 512.0, 0.4, 2.0, np.random.default_rng(3))
    return terrain, Renderer(terrain, Sun(50.0, 140.0), N, N, spp=16)


@pytest.mark.parametrize("roll_deg", [0.0, 20.0])
def test_commanded_subpixel_pose_change_is_measured_within_0p01_px(urban_renderer, roll_deg):
    """0.3 px / -0.2 px attitude step, nadir and 20 deg off-nadir with yaw steering."""
    from conftest import attitude_step_error

    terrain, r = urban_renderer
    cam = _camera(roll_deg, FocalPlane(10.0, 12e-6, N, N))
    err, predicted, valid = attitude_step_error(r, cam, terrain.height_at)
    assert valid.all()
    assert np.abs(predicted).min() > 0.15  # the command is really sub-pixel and 2-D
    assert np.abs(err.mean(axis=0)).max() < 0.01
    assert np.abs(err).max() < 0.025


def _mesa(height_m: float, centre_en_m, radius_m: float, rng) -> Terrain:
    """Flat textured ground with one flat-topped hill (steep 15 m sides)."""
    base = scene_class(BASE, 512.0, 0.4, 2.0, rng, relief_rms_m=0.0)
    m = base.dem_m.shape[0]
    east = -256.0 + np.arange(m) * 2.0
    north = 256.0 - np.arange(m) * 2.0
    ee, nn = np.meshgrid(east, north)
    d = np.hypot(ee - centre_en_m[0], nn - centre_en_m[1])
    dem = height_m * np.clip((radius_m + 15.0 - d) / 15.0, 0.0, 1.0)
    return Terrain(base.albedo, base.texel_m, dem.astype(np.float32), 2.0)


def test_relief_parallax_of_a_100m_hill_follows_h_v_over_H():
    """Staring at the scene for 1.5 s, a block on a 100 m mesa moves against a flat block by
    h v dt / (H GSD) (v: the satellite's velocity relative to the ground, H its height): the
    exact model within 0.03 px, the first-order formula within 2 %."""
    from scene.kernel import Renderer, Sun

    fp = FocalPlane(10.0, 12e-6, N, N)
    cam = _camera(0.0, fp, mode="target")
    terrain = _mesa(100.0, (60.0, 0.0), 45.0, np.random.default_rng(8))
    r = Renderer(terrain, Sun(75.0, 140.0), N, N, spp=16)
    dt = 1.5
    poses = [cam.pose(np.array([t, t]), nominal=True) for t in (0.0, dt)]
    imgs = [r.render(ray_keyframes(p, fp, (0.0, 0.0), r.z_start_m), seed=s)
            for p, s in zip(poses, (5, 6), strict=True)]
    b = 64
    # blocks on the mesa top (east of the centre) and on the flat ground (west)
    gsd = float(np.linalg.norm(poses[0].position_m[0])) * fp.ifov_rad
    seen = project(np.array([[60.0, 0.0, 100.0], [-60.0, 0.0, 0.0]]), poses[0][0], fp)
    corners = [tuple(int(round(v)) - b // 2 for v in px) for px in seen]
    res = measure_shift(_blocks(imgs[0], corners, b), _blocks(imgs[1], corners, b))
    assert res.valid.all()
    centres = np.array(corners, float) + (b - 1) / 2.0
    ground = cam.ground_points(centres, 0.0, terrain.height_at)
    assert ground[0, 2] == pytest.approx(100.0) and ground[1, 2] == pytest.approx(0.0)
    model = cam.image_motion_px(ground, np.array([dt]), 0.0, nominal=True)[0]
    measured_parallax = res.shift[0] - res.shift[1]
    model_parallax = model[0] - model[1]
    assert np.abs(measured_parallax - model_parallax).max() < 0.03
    # v: the satellite's speed relative to the scene (at its altitude, not the ground speed)
    _, vel, _ = cam.pose_and_rate(np.array(0.0), nominal=True)
    v = float(np.hypot(vel[0], vel[1]))
    h_sat = float(poses[0].position_m[0, 2])
    formula_px = 100.0 * v * dt / (h_sat * gsd)
    assert np.linalg.norm(model_parallax) == pytest.approx(formula_px, rel=0.02)
    assert formula_px > 1.5  # a real, multi-pixel effect


def test_in_render_motion_blur_equals_mean_of_subframes(urban_renderer):
    """One render with the pose moving 3 px across the exposure (9 keyframes) equals the mean
    of 16 static sub-frame renders (same total samples) within Monte Carlo noise (Monte Carlo
    pixel integration, whose noise two seeds measure)."""
    from scene.kernel import Renderer, Sun

    terrain, _ = urban_renderer
    r = Renderer(terrain, Sun(50.0, 140.0), N, N, spp=16, quadrature=False)
    fp = FocalPlane(10.0, 12e-6, N, N)
    cam = _camera(0.0, fp)
    pose0 = cam.pose(np.array(0.0), nominal=True)

    def poses(t):  # the line of sight turns 3 IFOV (row) and 1.5 IFOV (col) over t = 0..1
        t = np.atleast_1d(t)
        rot = Rotation.from_rotvec(np.outer(t, [3.0, -1.5, 0.0]) * fp.ifov_rad).as_matrix()
        return Pose(np.repeat(pose0.position_m[None], len(t), 0), pose0.enu_from_cam @ rot)

    spp = r.spp
    try:
        r.spp = 64
        kf = ray_keyframes(poses(np.linspace(0.0, 1.0, 9)), fp, (0.0, 0.0), r.z_start_m)
        blur_a = r.render(kf, seed=11)
        blur_b = r.render(kf, seed=12)
        r.spp = 4
        subs = []
        for k, t in enumerate((np.arange(16) + 0.5) / 16):
            p = poses(np.array([t, t]))
            subs.append(r.render(ray_keyframes(p, fp, (0.0, 0.0), r.z_start_m), seed=100 + k))
    finally:
        r.spp = spp
    mean_sub = np.mean(subs, axis=0)
    inner = (slice(8, -8), slice(8, -8))
    sigma_blur = np.std((blur_a - blur_b)[inner]) / np.sqrt(2.0)
    diff = (blur_a - mean_sub)[inner]
    # mean of 16 spp-4 frames has about the noise of one spp-64 frame
    expected = np.sqrt(2.0) * sigma_blur
    assert np.std(diff) < 1.3 * expected
    assert abs(diff.mean()) < 0.002 * blur_a.mean() + 3 * expected / np.sqrt(diff.size)
    # and the blurred content sits where the sub-frames put it
    res = measure_shift(blur_a[64:192, 64:192], mean_sub[64:192, 64:192])
    assert res.valid and np.abs(res.shift).max() < 0.01
    # the blur is real: a static frame differs far beyond the noise
    static = subs[8]
    assert np.std((static - mean_sub)[inner]) > 5 * expected


def _floor_renders(quadrature: bool):
    """(render, rms): one urban pose rendered at a seed, samples a pixel and row step (px),
    and the RMS error of 16 64-px blocks' shift between two renders about the known step."""
    from scene.kernel import Renderer, Sun

    terrain = scene_class("urban", 512.0, 0.4, 2.0, np.random.default_rng(3))
    cam = _camera(0.0, FocalPlane(10.0, 12e-6, N, N))
    r = Renderer(terrain, Sun(50.0, 140.0), N, N, spp=4, quadrature=quadrature)
    times = np.linspace(0.0, 2e-4, 5)

    def render(seed, spp, step=0.0):
        r.spp = spp
        kf = ray_keyframes(cam.pose(times), cam.focal_plane,
                           np.tile([step, 0.0], (len(times), 1)), r.z_start_m)
        return r.render(kf, seed).astype(np.float64)

    b = 64
    corners = [(i, j) for i in range(0, N, b) for j in range(0, N, b)]

    def rms(a, c, step=0.0):
        s = measure_shift(_blocks(a, corners, b), _blocks(c, corners, b))
        assert s.valid.all()
        # a stage step of +d px moves the content by -d px
        e = s.shift - np.array([-step, 0.0])
        return float(np.sqrt(np.mean(e ** 2)))

    return render, rms


def test_the_monte_carlo_floor_falls_as_one_over_sqrt_spp():
    """Monte Carlo pixel integration (``quadrature=False``): one pose rendered with two sampler
    seeds, no sensor noise, 16 blocks of 64 px: the blocks' apparent shift is the Monte Carlo
    noise's own; at 16 samples a pixel it is half the 4-sample one (1 / sqrt(spp), within the
    16 blocks' sampling spread), and a half-pixel step of the same pose adds no more than that
    spread (aliasing is not the floor)."""
    render, rms = _floor_renders(quadrature=False)
    f4 = rms(render(1, 4), render(2, 4))
    f16 = rms(render(1, 16), render(2, 16))
    half = rms(render(1, 4), render(2, 4, 0.5), 0.5)
    assert f4 > 0.01  # a floor worth modelling at the tracker's 0.01 px bound
    assert 1.3 < f4 / f16 < 3.0  # 2 expected
    assert half < 1.4 * f4  # a sub-pixel phase change adds no aliasing floor of its size


def test_the_fixed_quadrature_has_no_seed_noise_and_a_smaller_phase_error():
    """The default fixed quadrature: two seeds of one pose agree to a twentieth of the Monte
    Carlo floor (only the sky's BSDF samples still vary), and what is left of a link's floor,
    the quadrature's dependence on the content's sub-pixel phase (a half-pixel step), is below
    the Monte Carlo floor at the same samples a pixel and falls as the grid refines (2x2 to
    4x4 cells: measured 0.012 -> 0.006 px, Monte Carlo 0.025 -> 0.010)."""
    render, rms = _floor_renders(quadrature=True)
    render_mc, rms_mc = _floor_renders(quadrature=False)
    mc4 = rms_mc(render_mc(1, 4), render_mc(2, 4))
    same = rms(render(1, 4), render(2, 4))
    half4 = rms(render(1, 4), render(2, 4, 0.5), 0.5)
    half16 = rms(render(1, 16), render(2, 16, 0.5), 0.5)
    assert same < 0.05 * mc4
    assert half4 < 0.75 * mc4
    assert half16 < 0.7 * half4


def test_a_rendered_run_names_scene_spp_when_its_floor_rivals_the_bound(monkeypatch):
    """The run's check (`render_floor_check`) with the floor given: at 0.8x the bound on one
    axis it warns, naming ``scene.spp`` and a sample count whose 1 / sqrt(spp) floor is at
    most 0.5x the bound; at 0.4x it stays silent; the figures go to metrics.json."""
    import re
    from types import SimpleNamespace

    from imc.wiring import rendered_plant as rp

    m = SimpleNamespace(scenario=SimpleNamespace(scene=SimpleNamespace(spp=4, quadrature=True)))
    crlb = np.array([0.010, 0.012])
    monkeypatch.setattr(rp, "render_floor_px", lambda m, plant=None: np.array([0.004, 0.0096]))
    info, line = rp.render_floor_check(m, None, crlb)
    assert line is not None and line.startswith("scene.spp = 4:")
    need = int(re.search(r"scene\.spp >= (\d+)", line).group(1))
    assert 0.0096 * np.sqrt(4 / need) / 0.012 <= rp.RENDER_FLOOR_WARN + 1e-12
    assert 0.0096 * np.sqrt(4 / (need - 1)) / 0.012 > rp.RENDER_FLOOR_WARN  # the least that does
    assert np.allclose(info["over_crlb"], [0.4, 0.8]) and info["spp"] == 4
    monkeypatch.setattr(rp, "render_floor_px", lambda m, plant=None: np.array([0.004, 0.0048]))
    assert rp.render_floor_check(m, None, crlb)[1] is None


def test_the_analytic_plants_rendered_noise_is_the_rendered_trackers_bound():
    """``plant.noise: rendered``: the analytic plant's noise predicted on frame 0 as the
    renderer draws it, with the correlator's efficiency on it and the renderer's floor
    (:func:`imc.wiring.rendered_plant.rendered_noise`). On the quickstart's scene (15 m of
    relief under a 50 deg sun) the shading is texture of its own: the bound on the rendered
    frame is 0.60-0.77x the flat-shaded albedo's (measured). It is the bound that the rendered
    tracker itself reports over its first 20 frames, to within 10 %; the albedo's is 1.3x
    off. The floor is the renderer's own (measured 0.26-0.32x the bound), and the efficiency
    is the correlator's (measured 1.00 / 1.05)."""
    import yaml
    from conftest import ROOT

    from compensation.loop import simulate
    from imc.scenario import parse_scenario
    from imc.wiring.build import build_loop, build_models
    from imc.wiring.rendered_plant import build_plant, predicted_sigma_px

    d = yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text())
    d.pop("expect", None)
    d.update(duration_s=0.2, plant={"fidelity": "analytic", "noise": "rendered"})
    m = build_models(parse_scenario(d))
    plant = build_plant(m)
    albedo = np.sqrt(np.mean(predicted_sigma_px(m) ** 2, axis=0))
    ours = np.sqrt(np.mean(plant.sigma_px ** 2, axis=0))
    d["plant"] = {"fidelity": "rendered"}
    mr = build_models(parse_scenario(d))
    rendered = build_plant(mr)
    try:
        parts = build_loop(mr, None, None)
        res = simulate(rendered, parts.estimator, parts.controller, parts.actuator,
                       parts.transport, parts.timeline, enabled=True)
    finally:
        rendered.close()
    rec = res.record
    reported = np.sqrt(np.nanmean(np.where(rec.valid[1:, :, None], rec.sigma_px[1:], np.nan)
                                  ** 2, axis=(0, 1)))
    assert np.all(np.abs(ours / reported - 1.0) < 0.10)
    assert np.all(albedo / reported > 1.2)  # the flat shading misses the relief's texture
    assert np.all(plant.floor_px > 0.1 * ours) and np.all(plant.floor_px < 0.5 * ours)
    assert np.all((plant.efficiency > 0.9) & (plant.efficiency < 1.5))


def test_rendered_noise_on_a_scene_without_trackable_texture_is_a_scenario_error():
    """``plant.noise: rendered`` on a tile whose rendered frame holds no block the correlator
    accepts (texels 20x the ground sample over a flat, shadowless tile) ends in a one-line
    ScenarioError that names the field and the ways out, not a made-up noise level."""
    import yaml
    from conftest import ROOT

    from imc.scenario import ScenarioError, parse_scenario
    from imc.wiring.build import build_models
    from imc.wiring.rendered_plant import build_plant

    d = yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text())
    d.pop("expect", None)
    d.update(duration_s=0.2, plant={"fidelity": "analytic", "noise": "rendered"})
    d["scene"].update(texel_m=16.0, relief_rms_m=0.0)
    m = build_models(parse_scenario(d))
    with pytest.raises(ScenarioError, match=r"^plant\.noise: .*plant\.sigma_px") as e:
        build_plant(m)
    assert "\n" not in str(e.value)


def test_the_noise_tile_predicts_a_coarse_scenes_noise_at_the_trackers_texels():
    """``plant.noise_texel_m``: a scene too coarse to track when rendered (the previous test's
    16 m texels) gets its analytic noise from a small tile of 0.4 m texels of the same kind
    around the centre (:func:`imc.wiring.rendered_plant.noise_tile_models`): every block
    trackable, its bound that of a textured scene (the quickstart's reads 0.010-0.014 px,
    the coarse scene's albedo none) and the tile far smaller than the scene."""
    import yaml
    from conftest import ROOT

    from imc.scenario import parse_scenario
    from imc.wiring.build import build_models
    from imc.wiring.rendered_plant import build_plant, noise_tile_models

    d = yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text())
    d.pop("expect", None)
    d.update(duration_s=0.2, plant={"fidelity": "analytic", "noise": "rendered",
                                    "noise_texel_m": 0.4})
    d["scene"].update(texel_m=16.0, relief_rms_m=0.0, size_m=2048.0)
    m = build_models(parse_scenario(d))
    tile = noise_tile_models(m, 0.4)
    assert tile.scenario.scene.texel_m == 0.4 and tile.scenario.scene.size_m < 0.5 * 2048.0
    plant = build_plant(m)
    assert np.all((plant.sigma_px > 0.003) & (plant.sigma_px < 0.03))
    assert np.all(np.isfinite(plant.floor_px)) and np.all(np.isfinite(plant.efficiency))

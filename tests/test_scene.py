import numpy as np
import pytest

from camera.geometry import FocalPlane
from correlator import measure_shift
from scene import variant
from scene.pinhole import ray_keyframes, rays_from_keyframe
from scene.terrain import Terrain, procedural_terrain


def test_variant_env_override_and_errors(monkeypatch):
    monkeypatch.setattr(variant, "cuda_usable", lambda: False)
    monkeypatch.setattr(variant, "find_libllvm", lambda min_major=16: None)
    assert variant.choose_variant({}).variant == "scalar_rgb"
    assert variant.choose_variant({"IMC_MITSUBA_VARIANT": "scalar_rgb"}).variant == "scalar_rgb"
    with pytest.raises(variant.VariantError, match="not supported"):
        variant.choose_variant({"IMC_MITSUBA_VARIANT": "vulkan_rgb"})
    with pytest.raises(variant.VariantError, match="libLLVM"):
        variant.choose_variant({"IMC_MITSUBA_VARIANT": "llvm_ad_rgb"})
    monkeypatch.setattr(variant, "find_libllvm", lambda min_major=16: "/x/libLLVM-19.so")
    assert variant.choose_variant({}).variant == "llvm_ad_rgb"
    monkeypatch.setattr(variant, "cuda_usable", lambda: True)
    assert variant.choose_variant({}).variant == "cuda_ad_rgb"


def test_libllvm15_is_never_handed_to_drjit(monkeypatch):
    monkeypatch.setattr(variant, "cuda_usable", lambda: False)
    env = {"DRJIT_LIBLLVM_PATH": "/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1"}
    choice = variant.choose_variant(env)
    assert choice.libllvm_path is None or "15" not in choice.libllvm_path
    variant.prepare_environment(variant.VariantChoice("scalar_rgb", "test", None), env)
    assert "15" not in env["DRJIT_LIBLLVM_PATH"]
    assert variant.llvm_major("libLLVM-15.so.1") == 15
    assert variant.llvm_major("libLLVM.so.19.1") == 19
    assert variant.llvm_major("libLLVM-19.so") == 19


def test_keyframe_rays_are_the_exact_pinhole_lines(camera_model):
    """Start points on the plane project back to their pixels within 1e-6 px (float64)."""
    fp = camera_model.focal_plane
    poses = camera_model.pose(np.array([0.0, 0.2]))
    offset = (0.3, -1.1)
    kf = ray_keyframes(poses, fp, offset, z_start_m=500.0)
    u = np.array([0.0, 0.25, 0.5, 0.9, 1.0])
    qx, qy = np.meshgrid(u - 0.5, u - 0.5)
    for k in range(2):
        o, d = rays_from_keyframe(kf[k], qx.ravel(), qy.ravel())
        from camera.geometry import project

        pix = project(o, poses[k], fp, offset_px=offset)
        col = (qx.ravel() + 0.5) * fp.cols - 0.5
        row = (qy.ravel() + 0.5) * fp.rows - 0.5
        assert np.abs(pix[:, 0] - row).max() < 1e-6
        assert np.abs(pix[:, 1] - col).max() < 1e-6
        # directions point from the camera through the start point
        to_o = o - poses[k].position_m
        to_o /= np.linalg.norm(to_o, axis=1, keepdims=True)
        assert np.abs(to_o - d).max() < 1e-9
    # float32-sized quantities only: everything but the constant plane height is < 10 km
    assert np.abs(kf[:, :2]).max() < 1e4


def test_terrain_rejects_nan_and_mismatched_dem():
    alb = np.full((10, 10), 0.3, np.float32)
    with pytest.raises(ValueError, match="NaN"):
        Terrain(np.where(np.eye(10) > 0, np.nan, alb), 1.0, np.zeros((3, 3)), 5.0)
    with pytest.raises(ValueError, match="does not span"):
        Terrain(alb, 1.0, np.zeros((4, 4)), 5.0)


def test_procedural_terrain_is_seeded_and_textured():
    a = procedural_terrain(128.0, 0.5, 4.0, 10.0, np.random.default_rng(5))
    b = procedural_terrain(128.0, 0.5, 4.0, 10.0, np.random.default_rng(5))
    assert np.array_equal(a.albedo, b.albedo) and np.array_equal(a.dem_m, b.dem_m)
    assert 0.02 <= a.albedo.min() and a.albedo.max() <= 0.95
    assert a.albedo.std() > 0.05
    assert a.dem_m.std() == pytest.approx(10.0, rel=0.05)
    assert a.height_at(np.array([-64.0]), np.array([64.0]))[0] == pytest.approx(a.dem_m[0, 0])


@pytest.fixture(scope="module")
def small_renderer():
    from scene.kernel import Renderer, Sun

    terrain = procedural_terrain(256.0, 0.4, 4.0, 10.0, np.random.default_rng(11))
    return Renderer(terrain, Sun(50.0, 140.0), 128, 128, spp=16)


def test_rendered_pair_with_commanded_subpixel_pose_change(small_renderer, camera_model):
    """A 0.3 px pose change (attitude rotation) is measured as the model predicts."""
    from scipy.spatial.transform import Rotation

    from camera.geometry import Pose

    fp = FocalPlane(10.0, 12e-6, 128, 128)
    pose0 = camera_model.pose(np.array([0.0, 0.0]), nominal=True)
    # rotate the camera about its x and y axes by ~0.3 and ~-0.2 IFOV
    rot = Rotation.from_rotvec([-0.2 * fp.ifov_rad, 0.3 * fp.ifov_rad, 0.0]).as_matrix()
    pose1 = Pose(pose0.position_m, pose0.enu_from_cam @ rot)
    r = small_renderer
    img0 = r.render(ray_keyframes(pose0, fp, (0.0, 0.0), r.z_start_m), seed=1)
    img1 = r.render(ray_keyframes(pose1, fp, (0.0, 0.0), r.z_start_m), seed=2)
    centre = np.array([[63.5, 63.5]])
    from camera.geometry import project

    g = camera_model.ground_points(centre, 0.0, lambda e, n: 0.0 * e)  # flat enough at centre
    predicted = project(g, pose1[0], fp) - project(g, pose0[0], fp)
    res = measure_shift(img0[16:112, 16:112], img1[16:112, 16:112])
    assert res.valid
    assert np.abs(predicted[0]).min() > 0.15  # the command is really sub-pixel and 2-D
    assert np.abs(res.shift - predicted[0]).max() < 0.05


def test_rendered_frame_is_textured_and_lit(small_renderer, camera_model):
    fp = FocalPlane(10.0, 12e-6, 128, 128)
    pose = camera_model.pose(np.array([0.0, 0.0]), nominal=True)
    img = small_renderer.render(ray_keyframes(pose, fp, (0.0, 0.0), small_renderer.z_start_m), 3)
    assert img.shape == (128, 128) and np.isfinite(img).all()
    assert img.min() > 0.0
    assert img.std() / img.mean() > 0.1


_TINY_RENDER = """
import numpy as np
from camera.geometry import FocalPlane
from imc.wiring.build import build_models
from imc.scenario import load_scenario
from scene.kernel import Renderer, Sun
from scene.pinhole import ray_keyframes
from scene.terrain import procedural_terrain
m = build_models(load_scenario('scenarios/quickstart.yaml'))
terrain = procedural_terrain(128.0, 0.4, 4.0, 5.0, np.random.default_rng(1))
r = Renderer(terrain, Sun(), 24, 24, spp=4)
fp = FocalPlane(10.0, 12e-6, 24, 24)
img = r.render(ray_keyframes(m.camera.pose(np.array([0.0, 0.01])), fp, (0, 0), r.z_start_m), 5)
print(r.variant, float(img.mean()), float(img.std()))
"""


def test_scalar_fallback_renders_and_never_loads_libllvm15():
    """With Debian's libLLVM 15 forced on Dr.Jit, imcsim falls back to scalar, no abort."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, IMC_MITSUBA_VARIANT="scalar_rgb",
               DRJIT_LIBLLVM_PATH="/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1")
    proc = subprocess.run([sys.executable, "-c", _TINY_RENDER], cwd=root, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    variant_name, mean, std = proc.stdout.split()
    assert variant_name == "scalar_rgb"
    # the same scene in this process's (vectorised) variant agrees within Monte Carlo noise
    env2 = dict(os.environ)
    env2.pop("IMC_MITSUBA_VARIANT", None)
    ref = subprocess.run([sys.executable, "-c", _TINY_RENDER], cwd=root, env=env2,
                         capture_output=True, text=True, timeout=300)
    assert ref.returncode == 0, ref.stderr[-2000:]
    _, mean2, std2 = ref.stdout.split()
    assert float(mean) == pytest.approx(float(mean2), rel=0.03)
    assert float(std) == pytest.approx(float(std2), rel=0.15)


@pytest.mark.parametrize("n_seeds", [2, 40, 3000])
def test_nearest_seed_equals_the_texel_by_texel_query(n_seeds):
    """The Voronoi labelling decided per block from its centre equals a k-d tree's query at
    every texel, for cells much larger than a block and for cells about a block wide."""
    from scipy.spatial import cKDTree

    from scene.terrain import nearest_seed

    n = 301
    seeds = np.random.default_rng(n_seeds).uniform(0, n, size=(n_seeds, 2))
    yy, xx = np.mgrid[0:n, 0:n]
    _, want = cKDTree(seeds).query(np.column_stack([yy.ravel(), xx.ravel()]).astype(float))
    assert np.array_equal(nearest_seed(seeds, n), want.reshape(n, n))

"""Shared fixtures: small, deterministic models built from the quickstart scenario."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "0")

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "scenarios" / "quickstart.yaml"


@pytest.fixture(scope="session")
def quickstart():
    from imc.scenario import load_scenario

    return load_scenario(QUICKSTART)


@pytest.fixture(scope="session")
def camera_model(quickstart):
    """The quickstart camera model (target staring, 2 Hz pitch jitter)."""
    from imc.wiring.build import build_models

    return build_models(quickstart).camera


def textured(shape, rng: np.random.Generator, blur_px: float = 0.8) -> np.ndarray:
    """Band-limited periodic texture (power ~ f^-2, Gaussian-blurred), mean 100, std 20."""
    from scipy.ndimage import gaussian_filter

    from scene.terrain import fractal_noise

    img = gaussian_filter(fractal_noise(shape, 2.0, rng, 2.0), blur_px, mode="wrap")
    return img / img.std() * 20.0 + 100.0


def fourier_shifted(img: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Stack of copies of a periodic image with content moved by shifts (N, 2) px."""
    from scipy.ndimage import fourier_shift

    spec = np.fft.fft2(img)
    return np.stack([np.fft.ifft2(fourier_shift(spec, d)).real for d in shifts])


def tiny_base() -> dict:
    """The quickstart on the analytic plant, 0.3 s on a 128 x 128 tracker (~1 s a run)."""
    import yaml

    data = yaml.safe_load(QUICKSTART.read_text())
    data.pop("expect", None)  # the quickstart's bounds are for the full run
    data.update(duration_s=0.3, plant={"fidelity": "analytic"})
    data["camera"]["tracker"].update(rows=128, cols=128)
    data["scene"]["size_m"] = 256
    data["metrics"]["blur_images"] = False
    data["compensation"] = {"controller": {"kind": "integrator", "gain": 0.5},
                            "actuator": {"kind": "ideal"}}
    return data


def tiny_sweep(**changes):
    """A sweep of tiny_base: 2 gains x 2 jitter frequencies x 2 seeds."""
    from imc.workflow.sweep import SweepConfig

    spec = {"name": "tiny", "base": tiny_base(), "seeds": 2,
            "axes": {"compensation.controller.gain": [0.3, 0.8],
                     "attitude.jitter.sinusoids.0.frequency_hz": [1.0, 3.0]}}
    spec.update(changes)
    return SweepConfig.model_validate(spec)


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """The tiny sweep run in process, once."""
    from imc.workflow.distribute import runner
    from imc.workflow.sweep import expand, run_sweep

    out = tmp_path_factory.mktemp("sweep")
    sw = expand(tiny_sweep())
    with runner(0) as r:
        summary = run_sweep(sw, out, r)
    return sw, out, summary


def attitude_step_error(renderer, cam, height_fn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a 0.3 / -0.2 px attitude step (rotation about body x and y) of ``cam`` at
    t = 0, measure it on four 112^2 blocks of a 256^2 sensor; returns (error (4, 2) px
    against the camera model's exact projection, the predicted shift (4, 2), valid (4,))."""
    from scipy.spatial.transform import Rotation

    from camera.geometry import Pose, project
    from correlator import measure_shift
    from scene.pinhole import ray_keyframes

    fp = cam.focal_plane
    pose0 = cam.pose(np.array([0.0, 0.0]), nominal=True)
    rot = Rotation.from_rotvec(np.array([-0.2, 0.3, 0.0]) * fp.ifov_rad).as_matrix()
    pose1 = Pose(pose0.position_m, pose0.enu_from_cam @ rot)
    r = renderer
    imgs = [r.render(ray_keyframes(p, fp, (0.0, 0.0), r.z_start_m), seed=s)
            for p, s in ((pose0, 1), (pose1, 2))]
    b = 112
    corners = [(8, 8), (8, 136), (136, 8), (136, 136)]
    blocks = [np.stack([im[y:y + b, x:x + b] for y, x in corners]) for im in imgs]
    res = measure_shift(*blocks)
    centres = np.array(corners, float) + (b - 1) / 2.0
    ground = cam.ground_points(centres, 0.0, height_fn)
    predicted = project(ground, pose1[0], fp) - project(ground, pose0[0], fp)
    return res.shift - predicted, predicted, res.valid

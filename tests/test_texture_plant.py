"""The texture plant's geometry (imc.wiring.rendered_plant.TexturePlant): every pixel shows
the ground point the camera model puts there, however far the content has moved since the
t = 0 view its albedo image was taken from."""

import numpy as np
import pytest
import yaml
from scipy.ndimage import map_coordinates

from camera.geometry import project
from imc.scenario import parse_scenario
from imc.wiring.build import build_models
from imc.wiring.rendered_plant import TexturePlant
from tests.test_product import TDI


def _stage(t):
    t = np.asarray(t, dtype=np.float64)
    return np.stack([0.4 * np.sin(2 * np.pi * 3.0 * t), -0.3 * np.cos(2 * np.pi * 2.0 * t)],
                    axis=-1)


@pytest.fixture(scope="module")
def scan():
    """A 0.8 s nadir pushbroom scan (~6,600 px of flow along the rows) seen by a 64 x 64
    tracker at 10 Hz, over 15 m of relief, with a moving stage: the texture plant of a
    scanning run, one sample per exposure."""
    d = yaml.safe_load(yaml.safe_dump(TDI))
    d.update(duration_s=0.8, plant={"fidelity": "texture"})
    d["scene"].update(size_m=7008, texel_m=4.0, dem_spacing_m=16.0, relief_rms_m=15.0)
    d["camera"]["tracker"].update(rows=64, cols=64, frame_rate_hz=10)
    d["correlator"] = {"block_px": 32, "n_blocks": 1}
    d["product"] = {"enabled": False}
    m = build_models(parse_scenario(d))
    return m, TexturePlant(m, subsamples=1)


def test_each_pixel_shows_the_ground_point_the_camera_model_puts_there(scan):
    # the albedo image replaced by its own row (col) coordinate: a cubic B-spline's
    # coefficients reproduce a linear ramp exactly, so the radiance of each pixel is the
    # t = 0 view's position of what it shows. Ground points on the DEM, projected by the
    # true camera (orbit, attitude, jitter) less the stage at the frame's instant, must show
    # their own t = 0 position. The plant that warped the t = 0 view by the motion of the
    # point each pixel saw at t = 0 missed it by 0.24 / 0.34 px (row / col, RMS) at the last
    # frame here (+0.009 / +0.022 px a link on smallsat_pushbroom's 50 Hz chain); now
    # 9e-5 / 3e-9 px RMS, 5e-4 px at most (the rays traced on a 4 px grid)
    m, plant = scan
    cam, fp = m.camera, m.camera.focal_plane
    k = len(m.frame_t_s) - 1
    t = float(plant.times[k, 0])
    rng = np.random.default_rng(5)
    q = rng.uniform(8.0, fp.rows - 9.0, (200, 2))
    ground = cam.ground_points(q + rng.uniform(-0.5, 0.5, q.shape), t, m.terrain.height_at)
    ground[:, 2] = m.terrain.height_at(ground[:, 0], ground[:, 1])  # on the DEM
    p = project(ground, cam.pose(np.asarray(t)), fp) - _stage(np.array([t]))[0]
    want = project(ground, cam.pose(np.asarray(float(m.frame_mid_s[0]))), fp)
    shape = plant.base.shape
    got = []
    for axis in range(2):
        plant.base = np.broadcast_to(np.arange(shape[axis], dtype=np.float64)[:, None]
                                     if axis == 0 else np.arange(shape[1], dtype=np.float64),
                                     shape).copy()
        img = plant.radiance(k, _stage)
        got.append(map_coordinates(img, p.T, order=1) - plant.margin[axis])
    err = np.stack(got, axis=-1) - want
    assert np.abs(want - p).max() > 5000.0  # the content moved by thousands of pixels
    np.testing.assert_array_less(np.abs(err).max(axis=0), 0.005)

"""The texture-robustness map: its bound, its resampling and blur, and one rendered block of a
user GeoTIFF measured as the correlator predicts."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.fft as sfft

from correlator.bounds import correlation_bound_px
from correlator.bounds import crlb_px as shift_crlb_px
from imc.studies.texture_map import (
    TextureMapConfig,
    bin_fine,
    motion_blur,
    resample_bandlimited,
    run_map,
)
from scene.terrain import fractal_noise


def test_bound_of_a_sinusoid_is_the_analytic_one():
    """A sinusoid of amplitude A at f cycles/px along columns over N x N pixels carries
    sum g^2 = N^2 (2 pi f A)^2 / 2, so the bound is sqrt(2 sigma^2 / that) (within 1 %: the
    mirror extension's edge); the rows, with no texture, are unbounded."""
    n, a, f, sigma = 128, 30.0, 0.13, 20.0
    x = np.arange(n)
    img = np.broadcast_to(a * np.sin(2 * np.pi * f * x + 0.4), (n, n)).copy()
    img += 0.5 * np.sin(2 * np.pi * 0.05 * x)[:, None]  # a faint row texture: invertible
    got = shift_crlb_px(img[None], sigma)[0]
    expected = np.sqrt(2.0 * sigma**2 / (n * n * (2 * np.pi * f * a) ** 2 / 2.0))
    assert got[1] == pytest.approx(expected, rel=0.01)
    assert got[0] > 20 * got[1]


def test_correlation_bound_counts_the_noise_x_noise_term():
    """A sinusoid of a whole number of cycles puts |S|^2 = (A N / 2)^2 in each of its two
    bins: where that is far above sigma^2 the correlation bound is the Cramer-Rao bound;
    where 2 |S|^2 = sigma^2 it is sqrt(1 + sigma^2 / (2 |S|^2)) = sqrt 2 times it."""
    n, f, sigma = 128, 17 / 128, 20.0
    x = np.arange(n)
    for amp, ratio in ((30.0, 1.0), (2 * np.sqrt(sigma**2 / 2) / n, np.sqrt(2.0))):
        img = np.broadcast_to(amp * np.sin(2 * np.pi * f * x + 0.4), (n, n)).copy()
        img += 5.0 * np.sin(2 * np.pi * 0.05 * x)[:, None]
        crlb = shift_crlb_px(img[None], sigma)[0]
        got = correlation_bound_px(img[None], sigma)[0]
        assert got[1] / crlb[1] == pytest.approx(ratio, rel=0.02)


def _field(rng, n: int = 480) -> np.ndarray:
    return fractal_noise((n, n), 2.0, rng, cutoff_cycles=4.0)


def _shift(img: np.ndarray, d) -> np.ndarray:
    """Exact (periodic) Fourier shift of the content by d = (row, col) px."""
    fy = sfft.fftfreq(img.shape[0])[:, None]
    fx = sfft.fftfreq(img.shape[1])[None, :]
    ramp = np.exp(-2j * np.pi * (fy * d[0] + fx * d[1]))
    return sfft.ifft2(sfft.fft2(img) * ramp).real


def test_a_shift_before_bandlimited_resampling_is_the_same_shift_after_it():
    """Moving a fine texture by 1.3 fine px then resampling 3:1 equals moving the resampled
    image by 1.3 / 3 coarse px (alias-free: < 1 % of the texture's std away from the edges);
    3 x 3 binning passes 64 % at the coarse Nyquist frequency and misses by > 5 x more."""
    img = _field(np.random.default_rng(3))
    d = np.array([1.3, -0.7])
    inner = (slice(16, -16), slice(16, -16))
    errs = {}
    for name, resample in (("band", resample_bandlimited), ("box", bin_fine)):
        a, b = resample(img, 3), resample(_shift(img, d), 3)
        errs[name] = np.std((_shift(a, d / 3.0) - b)[inner]) / np.std(a)
    assert errs["band"] < 0.01
    assert errs["box"] > 5 * errs["band"]


def test_motion_blur_is_a_sinc_along_its_direction():
    """A smear of length L attenuates a sinusoid of f cycles/px along it by sinc(L f) and
    leaves one across it untouched; zero length is the identity."""
    n, f = 128, 8 / 128
    x = np.arange(n)
    along = np.broadcast_to(np.cos(2 * np.pi * f * x), (n, n))  # varies along columns
    out = motion_blur(np.stack([along, along, along.T]), np.array([3.0, 0.0, 3.0]),
                      np.array([np.pi / 2, np.pi / 2, np.pi / 2]))
    assert np.abs(out[0] - np.sinc(3.0 * f) * along).max() < 1e-9
    assert np.abs(out[1] - along).max() < 1e-9
    assert np.abs(out[2] - along.T).max() < 1e-9


def test_rendered_geotiff_block_is_measured_as_predicted(tmp_path):
    """One 128^2 block of a user GeoTIFF (an urban orthophoto with its DEM), rendered at
    0.25 m and resampled alias-free to 0.75 m, 96 trials: the measured |bias| + 1 sigma is
    within 30 % of the correlator's predicted error (the issue's target; with 96 trials the
    sigma is known to ~7 % and |bias| adds ~0.08 sigma) and no better than the clean
    texture's bound allows (>= 0.95 x: the bound's own sampling); the aliased box
    resampling is worse."""
    from scene.classes import scene_class
    from scene.geotiff import terrain_from_geotiff, write_geotiff

    urban = scene_class("urban", 160.0, 0.125, 2.0, np.random.default_rng(5))
    ortho, dem = tmp_path / "ortho.tif", tmp_path / "dem.tif"
    n = urban.albedo.shape[0]
    write_geotiff(ortho, (urban.albedo * 255).astype(np.uint8), 500_000.0, 5_300_000.0,
                  0.125, 0.125)
    write_geotiff(dem, urban.dem_m, 500_000.0 - 1.0, 5_300_000.0 + 1.0, 2.0, 2.0)
    terrain, centre = terrain_from_geotiff(ortho, dem, 2.0)
    # placed by pyproj: UTM's scale factor (0.9996 on the central meridian) makes imcsim
    # resample onto true ground metres, cropping a margin of a few texels
    assert centre is not None and abs(terrain.albedo.shape[0] - n) <= 0.02 * n
    cfg = TextureMapConfig(grid=1, trials=96, variants=TextureMapConfig().variants[:2])
    maps = run_map(terrain, cfg, seed=2)
    band, box = maps["bandlimited"], maps["box"]
    assert band.success[0, 0] == 1.0 and band.wrong[0, 0] == 0.0
    assert abs(band.ratio[0, 0] - 1.0) <= 0.3, band.ratio
    assert band.error_px[0, 0] >= 0.95 * band.bound_px[0, 0]
    assert box.error_px[0, 0] > band.error_px[0, 0]


def test_block_error_is_taken_over_successful_trials():
    """A trial called valid but off by > 0.5 px is wrong, not part of the block's error; an
    invalid one is neither; a block with fewer than half its trials successful is flagged
    (NaN error and prediction) while its bound stays."""
    from imc.studies.texture_map import BlockResult

    errors = np.array([[0.01, -0.01], [-0.01, 0.01], [0.8, 0.0], [0.0, 0.0]])
    valid = np.array([True, True, True, False])
    pred = np.full((4, 2), 0.01)
    r = BlockResult(errors, valid, pred, pred, 20.0)
    assert r.success.tolist() == [True, True, False, False]
    assert r.wrong == 0.25 and r.measured
    assert r.error_px() == pytest.approx(0.01) and r.predicted_px() == pytest.approx(0.01)
    flagged = BlockResult(errors, np.array([True, False, True, False]), pred, pred, 20.0)
    assert not flagged.measured
    assert np.isnan(flagged.error_px()) and np.isnan(flagged.predicted_px())
    assert flagged.bound_px() == pytest.approx(0.01)

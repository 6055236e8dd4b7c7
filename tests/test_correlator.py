import numpy as np
import pytest
from conftest import fourier_shifted, textured

from correlator import Correlator, measure_shift
from correlator.tracker import BlockTracker, block_grid, extract_blocks


@pytest.fixture(scope="module")
def pairs():
    """60 pairs of 96x96 blocks of one texture with known sub-pixel shifts within +-3 px."""
    rng = np.random.default_rng(7)
    img = textured((256, 256), rng)
    d = rng.uniform(-3.0, 3.0, size=(60, 2))
    big = fourier_shifted(img, d)
    ref = np.broadcast_to(img[80:176, 80:176], (60, 96, 96)).copy()
    return ref, big[:, 80:176, 80:176], d


@pytest.mark.parametrize("method", ["jtc", "xcorr", "phase"])
def test_known_subpixel_shifts_noise_free(pairs, method):
    ref, cur, d = pairs
    res = measure_shift(ref, cur, method=method)
    assert res.valid.all()
    # band-limited texture, no noise: what is left is interpolation error of the refinement
    assert np.sqrt(np.mean((res.shift - d) ** 2)) < 0.01


@pytest.mark.parametrize("subpixel, tol", [("parabolic", 0.08), ("gaussian", 0.15),
                                           ("com", 0.15)])
def test_peak_fit_estimators_are_coarser(pairs, subpixel, tol):
    ref, cur, d = pairs
    res = measure_shift(ref, cur, method="xcorr", subpixel=subpixel)
    rms = np.sqrt(np.mean((res.shift - d) ** 2))
    assert rms < tol
    # the gradient refinement beats every peak fit on the same pairs
    assert np.sqrt(np.mean((measure_shift(ref, cur).shift - d) ** 2)) < rms


def test_noise_within_the_crlb(pairs):
    """With SNR 10 on both images, the RMS error stays within 1.5x of the predicted CRLB."""
    ref, cur, d = pairs
    rng = np.random.default_rng(8)
    res = measure_shift(ref + rng.normal(0, 10, ref.shape), cur + rng.normal(0, 10, cur.shape))
    assert res.valid.all()
    rms = np.sqrt(np.mean((res.shift - d) ** 2, axis=0))
    crlb = np.sqrt(np.mean(res.crlb**2, axis=0))
    assert np.all(rms < 1.5 * crlb)
    assert np.all(rms > 0.5 * crlb)  # and the CRLB is not a loose over-estimate


def test_batched_equals_single(pairs):
    ref, cur, _ = pairs
    batch = measure_shift(ref[:5], cur[:5])
    for i in range(5):
        one = measure_shift(ref[i], cur[i])
        assert one.shift.shape == (2,)
        assert np.allclose(one.shift, batch.shift[i], atol=1e-9)
        assert one.valid == batch.valid[i]


def test_jtc_joint_plane_agrees_with_fast_path(pairs):
    ref, cur, d = pairs
    fast = measure_shift(ref[:10], cur[:10], method="jtc")
    plane = measure_shift(ref[:10], cur[:10], method="jtc", joint_plane=True)
    assert np.abs(fast.shift - plane.shift).max() < 0.01
    assert np.abs(plane.shift - d[:10]).max() < 0.05


def test_invalid_on_noise_constant_and_nan():
    rng = np.random.default_rng(9)
    a = rng.normal(size=(500, 64, 64))
    b = rng.normal(size=(500, 64, 64))
    assert measure_shift(a, b).valid.mean() < 0.01
    const = np.full((64, 64), 100.0)
    assert not measure_shift(const, const).valid
    tex = textured((64, 64), rng)
    assert not measure_shift(tex, const).valid
    bad = tex.copy()
    bad[3, 4] = np.nan
    res = measure_shift(tex, bad)
    assert not res.valid and np.all(np.isfinite(res.shift))


def test_bad_arguments_raise_clear_value_errors():
    with pytest.raises(ValueError, match="same shape"):
        measure_shift(np.zeros((32, 32)), np.zeros((32, 33)))
    with pytest.raises(ValueError, match="method"):
        measure_shift(np.zeros((32, 32)), np.zeros((32, 32)), method="fft")
    with pytest.raises(ValueError, match="real numeric"):
        measure_shift(np.zeros((32, 32), complex), np.zeros((32, 32), complex))
    with pytest.raises(ValueError, match="at least 8x8"):
        measure_shift(np.zeros((4, 4)), np.zeros((4, 4)))


def test_correlator_reuses_reference_and_tracker_follows_a_frame():
    rng = np.random.default_rng(10)
    img = textured((256, 256), rng)
    d = np.array([[1.3, -0.6]])
    moved = fourier_shifted(img, d)[0]
    corners = block_grid(256, 256, 64, 4)
    tracker = BlockTracker(img, corners, 64)
    res = tracker.update(moved)
    assert res.valid.all()
    # 64x64 blocks, noise-free: the cubic-spline refinement is interpolation-limited at ~0.02 px
    assert np.abs(res.shift - d).max() < 0.03
    assert np.sqrt(np.mean((res.shift - d) ** 2)) < 0.015
    cor = Correlator(extract_blocks(img, corners, 64))
    assert np.allclose(cor.measure(extract_blocks(moved, corners, 64)).shift, res.shift)
    assert np.allclose(tracker.centers_px[0], corners[0] + 31.5)

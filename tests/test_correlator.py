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
    # the Fourier refinement beats every peak fit on the same pairs
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
    with pytest.raises(ValueError, match="at least 16x16"):
        measure_shift(np.zeros((4, 4)), np.zeros((4, 4)))
    with pytest.raises(ValueError, match="jtc_filter"):
        measure_shift(np.zeros((32, 32)), np.zeros((32, 32)), jtc_filter="plain")
    with pytest.raises(ValueError, match="subpixel"):
        measure_shift(np.zeros((32, 32)), np.zeros((32, 32)), subpixel="spline")


def test_correlator_reuses_reference_and_tracker_follows_a_frame():
    rng = np.random.default_rng(10)
    img = textured((256, 256), rng)
    d = np.array([[1.3, -0.6]])
    moved = fourier_shifted(img, d)[0]
    corners = block_grid(256, 256, 64, 4)
    tracker = BlockTracker(img, corners, 64)
    res = tracker.update(moved)
    assert res.valid.all()
    # 64x64 blocks of a rough (f^-2) texture, noise-free: the 4 px window tapers leave ~0.01 px
    assert np.abs(res.shift - d).max() < 0.02
    assert np.sqrt(np.mean((res.shift - d) ** 2)) < 0.01
    cor = Correlator(extract_blocks(img, corners, 64))
    assert np.allclose(cor.measure(extract_blocks(moved, corners, 64)).shift, res.shift)
    assert np.allclose(tracker.centers_px[0], corners[0] + 31.5)


# ----------------------------------------------------------------- issue 3: the new correlator
from correlator.bounds import crlb_px  # noqa: E402
from correlator.testimages import texture_pairs  # noqa: E402


@pytest.mark.parametrize("subpixel", ["fourier", "gradient"])
def test_texture_pairs_recovered_noise_free(subpixel):
    ref, cur, d = texture_pairs(40, 64, np.random.default_rng(21), texture="medium")
    res = measure_shift(ref, cur, subpixel=subpixel)
    assert res.valid.all()
    tol = 0.005 if subpixel == "fourier" else 0.03  # exact interpolation vs cubic splines
    assert np.abs(res.shift - d).max() < tol


def test_single_pass_mode_is_close_and_shares_the_reference_spectrum():
    ref, cur, d = texture_pairs(40, 128, np.random.default_rng(22), texture="strong", snr=20)
    fast = measure_shift(ref, cur, rewindow=False)
    precise = measure_shift(ref, cur, rewindow=True)
    assert fast.valid.all() and precise.valid.all()
    e_fast = np.sqrt(np.mean((fast.shift - d) ** 2))
    e_precise = np.sqrt(np.mean((precise.shift - d) ** 2))
    assert e_precise < 0.01 and e_fast < 0.015


def test_threads_give_the_same_answer_as_one_thread():
    ref, cur, _ = texture_pairs(16, 64, np.random.default_rng(23), snr=10)
    one = measure_shift(ref, cur, workers=1)
    two = measure_shift(ref, cur, workers=2)
    assert np.array_equal(one.valid, two.valid)
    assert np.allclose(one.shift, two.shift, atol=1e-9)


def test_crlb_agrees_with_the_monte_carlo_spread():
    """One texture, 300 noise draws at SNR 10: the spread of the precise path's estimates
    matches both the predicted ``crlb`` and the textbook bound 2 sigma^2 (sum g g^T)^-1
    within 30 %. (The default path keeps the first pass on this texture: its spread is
    1.29-1.34x the bound, see ``tests/test_correlator_adaptive.py``.)"""
    rng = np.random.default_rng(24)
    ref, cur, d, clean = texture_pairs(1, 128, rng, texture="strong", return_clean=True)
    cur_clean = cur[0]
    n, sigma = 300, 10.0
    refs = clean[0][None] + rng.normal(0, sigma, (n, 128, 128))
    curs = cur_clean[None] + rng.normal(0, sigma, (n, 128, 128))
    res = measure_shift(refs, curs, rewindow=True)
    assert res.valid.all()
    spread = (res.shift - d[0]).std(axis=0)
    bias = np.abs((res.shift - d[0]).mean(axis=0))
    predicted = np.sqrt(np.mean(res.crlb**2, axis=0))
    bound = crlb_px(clean, sigma)[0]
    assert np.all(np.abs(spread / predicted - 1) < 0.3), (spread, predicted)
    assert np.all(np.abs(spread / bound - 1) < 0.3), (spread, bound)
    assert np.all(bias < 3 * spread / np.sqrt(n) + 1e-3)


def test_noise_only_false_alarms_below_half_a_percent():
    rng = np.random.default_rng(25)
    a = rng.normal(100, 10, size=(400, 128, 128))
    b = rng.normal(100, 10, size=(400, 128, 128))
    assert measure_shift(a, b).valid.mean() <= 0.005


def test_saturated_and_textureless_blocks_are_invalid():
    rng = np.random.default_rng(26)
    ref, cur, _ = texture_pairs(3, 64, rng, snr=10)
    sat = cur.copy()
    sat[0] = np.minimum(sat[0], np.percentile(sat[0], 30))  # 70 % of the block clipped
    calm = np.full_like(ref[1], 100.0) + rng.normal(0, 10, ref[1].shape)  # calm water: noise
    res = measure_shift(np.stack([ref[0], ref[1], ref[2]]), np.stack([sat[0], calm, cur[2]]))
    assert res.valid.tolist() == [False, False, True]


@pytest.mark.parametrize("jtc_filter", ["subtract", "fringe", "plain"])
def test_joint_plane_filters_find_the_shift(jtc_filter):
    ref, cur, d = texture_pairs(6, 64, np.random.default_rng(27), snr=20)
    res = measure_shift(ref, cur, joint_plane=True, jtc_filter=jtc_filter, subpixel="parabolic")
    assert np.abs(res.shift - d).max() < 0.3  # a 3-point fit on the joint-plane surface
    fine = measure_shift(ref, cur, joint_plane=True, jtc_filter=jtc_filter)
    assert np.abs(fine.shift - d).max() < 0.05


def test_joint_plane_cross_term_equals_the_digital_cross_correlation():
    import scipy.fft as sfft

    from correlator.jtc import joint_plane_surface

    ref, cur, _ = texture_pairs(2, 32, np.random.default_rng(28))
    r = ref - ref.mean(axis=(1, 2), keepdims=True)
    c = cur - cur.mean(axis=(1, 2), keepdims=True)
    plane = joint_plane_surface(r, c, "subtract")
    # linear (zero-padded) cross-correlation: the +(G + d) half of 2 Re(conj(R) C exp(..))
    big = (64, 64)
    lin = sfft.irfft2(np.conj(sfft.rfft2(r, s=big)) * sfft.rfft2(c, s=big), s=big)
    lags = np.r_[0:16, -16:0]
    expected = lin[:, lags[:, None], lags[None, :]]
    assert np.allclose(plane, expected, atol=1e-3 * np.abs(expected).max())


def test_benchmark_scoring_counts_success_and_false_valid():
    from imc.studies.correlator_peers import score

    d = np.zeros((4, 2))
    shift = np.array([[0.1, 0.0], [0.0, 0.7], [0.0, -0.1], [2.0, 0.0]])
    valid = np.array([True, True, True, False])
    sc, ok = score(shift, valid, d, np.full((4, 2), 0.1))
    assert ok.tolist() == [True, False, True, False]
    assert sc["success_pct"] == 50.0 and sc["false_valid_pct"] == 25.0
    assert np.isclose(sc["rms_px"], np.sqrt((0.01 + 0.01) / 4))
    assert np.isclose(sc["rms_over_crlb"], sc["rms_px"] / 0.1)


def test_docstring_examples_run():
    import doctest

    import correlator.core

    assert doctest.testmod(correlator.core).failed == 0

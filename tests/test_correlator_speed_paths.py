"""Issue 15: FFT backends, the prediction-trusting tracking path, ambiguous textures and the
validity of low-contrast blocks (speed itself is measured by `imc bench correlator`)."""

import numpy as np
import pytest
from conftest import fourier_shifted
from scipy.ndimage import gaussian_filter

from correlator import Correlator, CorrelatorOptions, fftbackend, measure_shift
from correlator.testimages import texture_pairs
from correlator.tracker import BlockTracker, block_grid


def _scene(n: int, rng: np.random.Generator, shapes: int = 120) -> np.ndarray:
    """Periodic piecewise-smooth scene (overlapping ellipses, edges blurred by 0.5 px), std 12 %
    of its mean 100: large flat areas and a few edges, like a low-contrast photograph."""
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    img = np.zeros((n, n))
    for _ in range(shapes):
        cy, cx = rng.uniform(0, n, 2)
        ay, ax = rng.uniform(8, 60, 2)
        th = rng.uniform(0, np.pi)
        dy = (yy - cy + n / 2) % n - n / 2
        dx = (xx - cx + n / 2) % n - n / 2
        u = dy * np.cos(th) + dx * np.sin(th)
        v = -dy * np.sin(th) + dx * np.cos(th)
        img += rng.normal() * ((u / ay) ** 2 + (v / ax) ** 2 < 1)
    img = gaussian_filter(img, 0.5, mode="wrap")
    return (img - img.mean()) / img.std() * 12.0 + 100.0


@pytest.fixture(scope="module")
def low_contrast():
    """60 pairs of 128^2 blocks of the scene, shifts within +-3 px, SNR 10 on both images."""
    rng = np.random.default_rng(43)
    img = _scene(384, rng)
    n = 60
    d = rng.uniform(-3.0, 3.0, (n, 2))
    big = fourier_shifted(img, d)
    tl = rng.integers(0, 384 - 128, (n, 2))
    ref = np.stack([img[y:y + 128, x:x + 128] for y, x in tl])
    cur = np.stack([big[i, y:y + 128, x:x + 128] for i, (y, x) in enumerate(tl)])
    return ref + rng.normal(0, 10, ref.shape), cur + rng.normal(0, 10, cur.shape), d


@pytest.mark.skipif("fftw" not in fftbackend.available(), reason="pyfftw not installed")
@pytest.mark.parametrize("rewindow, size", [(True, 64), (False, 64), (True, 45)])
def test_fftw_backend_gives_the_pocketfft_shifts(rewindow, size):
    """Both backends compute the same float32 transforms: shifts agree to 1e-5 px (rounding
    of ~1e-7 relative moves a 0.01 px-wide Newton optimum by far less). 45 px: blocks that
    do not start on FFTW's SIMD alignment (copied through pyfftw's checked call)."""
    ref, cur, _ = texture_pairs(24, size, np.random.default_rng(51), snr=10.0)
    with fftbackend.use("fftw"):
        a = measure_shift(ref, cur, rewindow=rewindow)
    with fftbackend.use("pocketfft"):
        b = measure_shift(ref, cur, rewindow=rewindow)
    assert np.array_equal(a.valid, b.valid)
    assert np.abs(a.shift - b.shift).max() < 1e-5


def test_backend_transforms_match_scipy():
    import scipy.fft as sfft

    x = np.random.default_rng(52).normal(size=(11, 32, 48)).astype(np.float32)
    for name in fftbackend.available():
        with fftbackend.use(name):
            spec = fftbackend.rfft2(x)
            assert spec.dtype == np.complex64
            assert np.allclose(spec, sfft.rfft2(x.astype(np.float64)), atol=1e-3)
            assert np.allclose(fftbackend.irfft2(spec.copy(), (32, 48)), x, atol=1e-5)
    with pytest.raises(ValueError, match="backend"):
        fftbackend.set_backend("fftpack")


@pytest.mark.parametrize("rewindow, tol", [(False, 1e-4), (True, 0.2)])
def test_prediction_path_equals_search_when_right_and_recovers_when_wrong(rewindow, tol):
    """A right prediction (within 0.1 px) gives the search path's result: the same peak of
    the same correlation (fast mode: to Newton's convergence; precise mode: the same window
    fixed point, to a fifth of the predicted error). A prediction 3 px off is not trusted
    (beyond trust_prediction_px) and the block is searched: same result again."""
    ref, cur, d = texture_pairs(30, 96, np.random.default_rng(53), snr=10.0)
    search = Correlator(ref, rewindow=rewindow).measure(cur)
    c = Correlator(ref, rewindow=rewindow, trust_prediction_px=1.0)
    rng = np.random.default_rng(54)
    for pred in (d + rng.uniform(-0.1, 0.1, d.shape), d + 3.0 * np.sign(rng.normal(size=d.shape))):
        res = c.measure(cur, predicted=pred)
        assert np.array_equal(res.valid, search.valid) and res.valid.all()
        assert np.all(np.abs(res.shift - search.shift) <= tol * np.maximum(search.crlb, 5e-4))
        assert np.abs(res.shift - d).max() < 0.1


def test_tracker_uses_the_prediction_only_when_asked():
    rng = np.random.default_rng(55)
    ref, cur, d = texture_pairs(1, 384, rng, max_shift_px=0.0, snr=20.0)
    frame0 = ref[0]
    shift = np.array([5.3, -7.6])
    frame1 = fourier_shifted(frame0.astype(np.float64), shift[None])[0]
    corners = block_grid(384, 384, 96, 9)
    plain = BlockTracker(frame0, corners, 96)
    trusting = BlockTracker(frame0, corners, 96, CorrelatorOptions(trust_prediction_px=1.0,
                                                                   rewindow=False))
    pred = np.broadcast_to(shift + 0.2, (9, 2))
    a = plain.update(frame1, pred)
    b = trusting.update(frame1, pred)
    assert a.valid.all() and b.valid.all()
    assert np.abs(a.shift - shift).max() < 0.05 and np.abs(b.shift - shift).max() < 0.05
    with pytest.raises(ValueError, match="trust_prediction_px"):
        plain.correlator.measure(frame1[:96, :96], predicted=np.zeros(2))
    with pytest.raises(ValueError, match="trust_prediction_px"):
        CorrelatorOptions(trust_prediction_px=0.0)


def test_periodic_and_one_directional_patterns_are_invalid():
    """A checkerboard of period 8 px moved by (2, 3) correlates as well at (2, 3) - (4, 4) and
    its other repeats, and stripes at any lag along them: ambiguous, so invalid (the band
    detection's rival-peak test), never a wrong valid shift."""
    rng = np.random.default_rng(56)
    yy, xx = np.mgrid[0:160, 0:160] + 0.5
    checker = 100 + 20 * np.sign(np.sin(np.pi * yy / 4) * np.sin(np.pi * xx / 4))
    stripes = 100 + 20 * np.sin(2 * np.pi * xx / 9.3)
    line = gaussian_filter(rng.normal(size=160), 1.0, mode="wrap")
    stripes_1d = 100 + 20 * line[None, :] / line.std() * np.ones((160, 1))
    for img in (checker, stripes, stripes_1d):
        for b in (64, 128):
            ref = img[16:16 + b, 16:16 + b] + rng.normal(0, 0.5, (6, b, b))
            cur = img[14:14 + b, 13:13 + b] + rng.normal(0, 0.5, (6, b, b))  # moved by (2, 3)
            assert not measure_shift(ref, cur).valid.any()
            # noise-free, where the repeats are exact (the seed correlator's PSR passed 7)
            assert not measure_shift(img[16:16 + b, 16:16 + b], img[14:14 + b, 13:13 + b]).valid


def test_low_contrast_blocks_with_a_small_predicted_error_are_valid(low_contrast):
    """Std 12 % of the mean at SNR 10 (per-pixel SNR 1.2): blocks the correlator predicts to
    0.1 px (a 5-sigma margin to 0.5 px) and detects (PSR >= 7) are valid and right: no
    convergence or window test with a fixed px tolerance rejects them."""
    ref, cur, d = low_contrast
    res = measure_shift(ref, cur)
    sure = (res.crlb.max(axis=1) <= 0.1) & (res.peak >= 7.0)
    assert sure.sum() >= 10
    assert res.valid[sure].all()
    err = np.abs(res.shift - d).max(axis=1)
    assert err[res.valid].max() < 0.5


@pytest.mark.parametrize("texture, snr", [("weak", 10.0), ("strong", 1.6)])
def test_low_snr_predicted_error_matches_the_monte_carlo_spread(texture, snr):
    """Per-pixel SNR 0.5 (weak texture, SNR 10) and 0.16 (strong, SNR 1.6): over 150 noise
    draws the spread of the estimates is the predicted error within 20 %. Per frequency the
    texture meets the other image's noise twice and the two noises meet once; counting the
    noise x noise term twice (|R|^2 for |S|^2) over-predicted these by 1.25-1.4x."""
    ref, cur, d = texture_pairs(1, 128, np.random.default_rng(3), texture=texture)
    rng = np.random.default_rng(57)
    n, sigma = 150, 100.0 / snr
    res = measure_shift(ref[0] + rng.normal(0, sigma, (n, 128, 128)),
                        cur[0] + rng.normal(0, sigma, (n, 128, 128)))
    err = res.shift - d[0]
    ok = np.abs(err).max(axis=1) < 0.5
    assert ok.mean() > 0.95
    ratio = err[ok].std(axis=0) / np.sqrt(np.mean(res.crlb[ok] ** 2, axis=0))
    assert np.all(np.abs(ratio - 1) < 0.2), ratio


def test_image_pairs_move_any_image_by_the_stated_shift():
    """Blocks cut from a (non-periodic) image, moved through its mirrored periodic field:
    the correlator finds the stated shifts noise-free, and each block has the asked contrast."""
    from conftest import textured

    from correlator.testimages import image_pairs

    img = textured((200, 300), np.random.default_rng(58))[:, :250]  # not periodic any more
    ref, cur, d = image_pairs([img, img.T], 20, 64, np.random.default_rng(59), contrast=0.1)
    assert np.allclose(ref.std(axis=(1, 2)) / ref.mean(axis=(1, 2)), 0.1, rtol=1e-3)
    res = measure_shift(ref, cur)
    assert res.valid.all() and np.abs(res.shift - d).max() < 0.02
    with pytest.raises(ValueError, match="images"):
        image_pairs([img[:50, :50]], 2, 64, np.random.default_rng(0))


def test_fftw_wisdom_file_makes_every_process_use_the_same_plans(tmp_path):
    """pyfftw is a dependency of imcsim (pyproject.toml), so this always runs. The first
    process measures its plans and writes the wisdom file; a second process plans from it
    (measures nothing new, so the file is not rewritten) and gets the same shifts bit for
    bit: a run and its resumed run agree exactly."""
    import os
    import subprocess
    import sys

    code = ("import numpy as np; from correlator import measure_shift\n"
            "rng = np.random.default_rng(1); a = rng.random((16, 96, 96), np.float32)\n"
            "b = np.roll(a, (1, 2), axis=(1, 2)) + 0.05 * rng.random(a.shape, np.float32)\n"
            "print(measure_shift(a, b).shift.astype(np.float64).tobytes().hex())")
    env = {**os.environ, "IMC_FFTW_WISDOM": str(tmp_path / "w.npz"), "IMC_FFT": "fftw"}
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, check=True).stdout
    written = (tmp_path / "w.npz").read_bytes()
    second = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                            text=True, check=True).stdout
    assert second == first
    assert (tmp_path / "w.npz").read_bytes() == written


def test_scenario_passes_the_trusted_prediction_to_the_tracker():
    import yaml
    from conftest import QUICKSTART

    from imc.scenario import ScenarioError, parse_scenario
    from imc.wiring.build import correlator_options

    data = yaml.safe_load(QUICKSTART.read_text())
    assert correlator_options(parse_scenario(data)).trust_prediction_px is None
    data["correlator"]["trust_prediction_px"] = 1.5
    assert correlator_options(parse_scenario(data)).trust_prediction_px == 1.5
    data["correlator"]["trust_prediction_px"] = 0.0
    with pytest.raises(ScenarioError, match="correlator.trust_prediction_px"):
        parse_scenario(data)


def test_lean_kernel_variants_equal_the_full_ones():
    """The variants that skip what a pass does not read (issue 35's independent-pair speed):
    a block windowed without its sanity statistics, a reference's terms without the
    detection's weights, a cross spectrum without its noise and floor sums, each gives the
    full kernel's other outputs bit for bit."""
    from correlator import kernels
    from correlator.core import _Layout

    lay = _Layout.of(64, 64)
    g = lay.full
    rng = np.random.default_rng(3501)
    blocks = (100.0 + 10.0 * rng.normal(size=(3, 64, 64))).astype(np.float32)
    blk = np.arange(3)
    wy, wx = lay.wy_ref[None], lay.wx_ref[None]
    full, lean = fftbackend.empty(blocks.shape), fftbackend.empty(blocks.shape)
    kernels.prep_blocks(blocks, blk, wy, wx, True, full, np.empty((3, 4)))
    kernels.prep_blocks(blocks, blk, wy, wx, True, lean, np.empty((0, 4)))
    assert np.array_equal(full, lean)
    spec = fftbackend.rfft2(full)
    n, h, k = spec.shape
    outs = []
    for det in (True, False):
        nd = n if det else 0
        o = (np.empty(spec.shape, np.complex64), np.empty((nd, h, k), np.float32),
             np.empty((nd, len(lay.band_rows), lay.band_cols), np.float32),
             np.zeros((n, 3, 3)), np.empty(n), np.empty(spec.shape, np.float32))
        kernels.ref_spectra(spec.view(np.float32), lay.immerkaer, lay.immerkaer_norm,
                            np.full(n, lay.e_ref), lay.smooth, 11, False, g.alpha, g.ay, g.ax,
                            g.rows, lay.outer_from, lay.band_rows, o[0].view(np.float32),
                            o[1], o[2], o[3], o[4], o[5])
        outs.append(o)
    for i in (0, 3, 4, 5):  # W conj(R), CRLB sums, noise, box means
        assert np.array_equal(outs[0][i], outs[1][i]), i
    ys = []
    for fl in (np.empty(n), np.empty(0)):
        y = np.empty(spec.shape, np.complex64)
        kernels.cross_spectra(spec.view(np.float32), outs[0][0].view(np.float32),
                              outs[0][1] if len(fl) else np.empty((0, 1, 1), np.float32),
                              blk, lay.immerkaer, lay.outer_n, y.view(np.float32),
                              np.empty(len(fl)), fl)
        ys.append(y)
    assert np.array_equal(ys[0], ys[1])


@pytest.mark.parametrize("rewindow", [None, True])
def test_references_made_in_place_equal_those_made_apart(rewindow):
    """A correlator makes its first-pass and pass references in place where its blocks are a
    run (independent pairs) and apart, then copied, where they are not (``index`` out of
    order): the same results either way, to floating noise (the order of the blocks alone
    moves the shifts by ~2e-8 px, before this change too; a reference made wrong would be
    0.001-1 px off) and the same decisions."""
    ref, cur, _ = texture_pairs(12, 64, np.random.default_rng(3502), snr=10.0,
                                texture="medium")
    a = Correlator(ref, rewindow=rewindow, workers=1).measure(cur)
    perm = np.random.default_rng(3503).permutation(12)
    b = Correlator(ref, rewindow=rewindow, workers=1).measure(cur[perm], index=perm)
    assert a.precise.any()
    for f in ("valid", "precise"):
        assert np.array_equal(getattr(a, f)[perm], getattr(b, f)), f
    for f in ("shift", "crlb", "peak", "p_wrong"):
        assert np.allclose(getattr(a, f)[perm], getattr(b, f), rtol=1e-5, atol=1e-6), f

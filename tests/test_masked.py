"""Large shifts at partial overlap: the masked (overlap-normalised) detection."""

import numpy as np
import pytest
from conftest import fourier_shifted, textured

from correlator import Correlator, measure_shift
from correlator.core import CorrelatorOptions
from correlator.masked import MaskedDetector
from correlator.testimages import texture_pairs


@pytest.fixture(scope="module")
def far_pairs():
    """256^2 pairs at SNR 10 with shifts up to +-144 px and >= 40 % overlap (Table 2's range),
    a quarter of them beyond half the block (where a circular correlation aliases)."""
    rng = np.random.default_rng(31)
    ref, cur, d = texture_pairs(120, 256, rng, snr=10.0, max_shift_px=144.0)
    keep = np.prod(1 - np.abs(d) / 256, axis=1) >= 0.4
    return ref[keep], cur[keep], d[keep]


def test_masked_ncc_equals_the_pearson_correlation_over_each_overlap():
    """The FFT formula gives, at every lag, the correlation coefficient of the overlap alone."""
    rng = np.random.default_rng(32)
    ref = rng.normal(size=(1, 24, 20))
    cur = rng.normal(size=(1, 24, 20))
    md = MaskedDetector(ref - ref.mean(), 15.0, 0.1, 1)
    r = md.ncc(cur - cur.mean(), slice(None))[0]
    for uy, ux in [(0, 0), (5, -3), (-11, 7), (15, 15), (-15, -2)]:
        # sum_x ref(x) cur(x + u) over the overlap
        a = ref[0][max(0, -uy):24 - max(0, uy), max(0, -ux):20 - max(0, ux)]
        b = cur[0][max(0, uy):24 - max(0, -uy), max(0, ux):20 - max(0, -ux)]
        assert a.shape == b.shape and a.size > 0
        assert r[uy % r.shape[0], ux % r.shape[1]] == pytest.approx(
            np.corrcoef(a.ravel(), b.ravel())[0, 1], abs=1e-9)


def test_far_shifts_at_40_percent_overlap_are_measured(far_pairs):
    ref, cur, d = far_pairs
    res = Correlator(ref, CorrelatorOptions(max_shift_px=148.0)).measure(cur)
    err = np.abs(res.shift - d).max(axis=1)
    assert (np.abs(d) > 128).any(axis=1).sum() >= 5  # the aliasing range is exercised
    assert res.valid.all()
    # SNR 10, 40-100 % of 256^2 shared: the CRLB is ~0.005-0.01 px
    assert err.max() < 0.05, err.max()


def test_band_detection_aliases_beyond_half_a_block(far_pairs):
    """The circular search cannot tell d from d - 256: what the masked search is for."""
    ref, cur, d = far_pairs
    far = (np.abs(d) > 128).any(axis=1)
    res = Correlator(ref[far], CorrelatorOptions(max_shift_px=148.0, detection="band")
                     ).measure(cur[far])
    ok = res.valid & (np.abs(res.shift - d[far]).max(axis=1) < 0.5)
    assert ok.mean() < 0.2


def test_unshared_brightness_does_not_bias_the_estimate():
    """~45 % overlap on a scene with a large brightness swing (snow or cloud beside dark
    rock): the two blocks' means differ by ~100 levels, which must not pull the peak."""
    rng = np.random.default_rng(33)
    n = 512
    yy, xx = np.mgrid[0:n, 0:n] * (2 * np.pi / n)
    img = textured((n, n), rng) + 75.0 * (1.0 + np.tanh(4.0 * np.sin(yy + 0.1 * np.cos(xx))))
    d = np.array([110.0, 70.0]) + rng.uniform(-1.0, 1.0, size=(8, 2))
    cur = fourier_shifted(img, d)[:, 128:384, 128:384]  # cur(x) = img(x - d)
    ref = np.broadcast_to(img[128:384, 128:384], cur.shape)
    ref = ref + rng.normal(0.0, 5.0, ref.shape)
    cur = cur + rng.normal(0.0, 5.0, cur.shape)
    assert np.abs(cur.mean(axis=(1, 2)) - ref.mean(axis=(1, 2))).min() > 50.0
    res = Correlator(ref, CorrelatorOptions(max_shift_px=148.0)).measure(cur)
    assert res.valid.all()
    assert np.abs(res.shift - d).max() < 0.05, np.abs(res.shift - d).max()


def test_textureless_far_search_is_invalid_not_wrong():
    rng = np.random.default_rng(34)
    a = rng.normal(100, 10, size=(40, 256, 256))
    b = rng.normal(100, 10, size=(40, 256, 256))
    assert measure_shift(a, b, max_shift_px=148.0).valid.sum() == 0


def test_auto_detection_choice_and_option_errors():
    rng = np.random.default_rng(35)
    ref = rng.normal(size=(2, 64, 64))
    assert Correlator(ref)._masked is None  # default range: a quarter block, band search
    assert Correlator(ref, max_shift_px=20.0)._masked is not None
    assert Correlator(ref, max_shift_px=20.0, detection="band")._masked is None
    with pytest.raises(ValueError, match="detection"):
        CorrelatorOptions(detection="peak")
    with pytest.raises(ValueError, match="min_overlap"):
        CorrelatorOptions(min_overlap=0.0)

"""The Fourier estimator against its bounds (issue 25, part 3): Knapp-Carter weights from both
images' power in the common-content passes, and the predicted error that gates validity."""

import numpy as np

from correlator import fftbackend, kernels
from correlator.bounds import correlation_bound_px, crlb_px
from correlator.core import _Layout, measure_shift
from correlator.testimages import MEAN_LEVEL, texture_pairs


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def test_low_snr_rms_near_the_correlation_bound():
    """Strong texture, 128^2, SNR 1.6, 240 pairs: the RMS error over all pairs is within 1.4x
    the correlation bound (the oracle per-bin Knapp-Carter weights), and the predicted error
    matches the actual one within 15 %.

    Tolerances: with weights from a smoothed power (what an estimator that does not know the
    scene can use) the best reachable is ~1.2x this bound on these textures (the oracle's
    weights from the smoothed clean power, measured 1.19-1.28x); the estimator measures
    1.25x on these pairs (the reference-only weights before it 1.29x; 1.29x and 1.34x on
    300 other pairs), and an RMS over 240 pairs x 2 axes has a sampling error of ~5 %, so
    1.4 is two of those above the worst measured. The ratio of actual to predicted error
    measures 0.99 (the same sampling error: 15 % is three)."""
    snr = 1.6
    ref, cur, d, clean = texture_pairs(240, 128, np.random.default_rng(2501), snr=snr,
                                       texture="strong", return_clean=True)
    res = measure_shift(ref, cur)
    err = res.shift - d
    bound = _rms(correlation_bound_px(clean, MEAN_LEVEL / snr))
    assert res.valid.mean() > 0.97
    assert np.abs(err).max() < 0.5
    assert _rms(err) < 1.4 * bound, (_rms(err), bound)
    assert abs(_rms(err[res.valid]) / _rms(res.crlb[res.valid]) - 1.0) < 0.15


def test_high_snr_accuracy_kept():
    """Strong texture, 128^2, SNR 10, 200 pairs: every pair valid, RMS within 1.25x the
    Cramer-Rao bound and 1.2x the correlation bound (measured 1.21x and 1.13x here, 1.20x and
    1.11x over 400 other pairs, unchanged by the weights: at high SNR per bin they are
    flat), and the prediction within 25 % (measured 0.92-0.97: the Immerkaer noise estimate
    is ~9 % high on this texture, whose power reaches the frequencies it reads). The precise
    path (``rewindow=True``): the default keeps the first pass on these blocks
    (``tests/test_correlator_adaptive.py``)."""
    snr = 10.0
    ref, cur, d, clean = texture_pairs(200, 128, np.random.default_rng(2502), snr=snr,
                                       texture="strong", return_clean=True)
    res = measure_shift(ref, cur, rewindow=True)
    err = res.shift - d
    assert res.valid.all()
    assert _rms(err) < 1.25 * _rms(crlb_px(clean, MEAN_LEVEL / snr))
    assert _rms(err) < 1.2 * _rms(correlation_bound_px(clean, MEAN_LEVEL / snr))
    assert abs(_rms(err) / _rms(res.crlb) - 1.0) < 0.25


def test_both_weights_reduce_to_the_reference_weights_for_identical_blocks():
    """With cur = ref the weights from both images' power are the reference's own: the
    cross spectrum is unchanged and the CRLB sums equal :func:`kernels.ref_spectra`'s."""
    lay = _Layout.of(64, 64)
    g = lay.full
    rng = np.random.default_rng(2503)
    blocks = (rng.normal(size=(3, 64, 64)) * lay.win_ref).astype(np.float32)
    x = fftbackend.empty(blocks.shape, np.float32)
    x[...] = blocks
    spec = fftbackend.rfft2(x)
    n, h, k = spec.shape
    energy = np.full(n, lay.e_ref)
    wconj = np.empty(spec.shape, np.complex64)
    fw = np.empty(spec.shape, np.float32)
    bw = np.empty((n, len(lay.band_rows), lay.band_cols), np.float32)
    m_ref, noise = np.zeros((n, 3, 3)), np.empty(n)
    pbox = np.empty(spec.shape, np.float32)
    kernels.ref_spectra(spec.view(np.float32), lay.immerkaer, lay.immerkaer_norm, energy,
                        lay.smooth, 11, False, g.alpha, g.ay, g.ax, g.rows, lay.outer_from,
                        lay.band_rows, wconj.view(np.float32), fw, bw, m_ref, noise, pbox)
    y = (wconj * spec).astype(np.complex64)
    y0 = y.copy()
    cbox = np.empty(spec.shape, np.float32)
    kernels.box_power(spec.view(np.float32), np.arange(n), lay.smooth, cbox)
    assert np.allclose(cbox, pbox, rtol=1e-5)
    s2 = noise * energy
    m = np.empty((n, 3, 3))
    kernels.both_weights(y.view(np.float32), spec.view(np.float32), pbox, np.arange(n), cbox,
                         np.arange(n), np.ones(n), s2, s2, 1.0, g.alpha, g.ay, g.ax, g.rows, m)
    assert np.allclose(y, y0, rtol=1e-4, atol=1e-6 * np.abs(y0).max())
    iu = [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (2, 0)]
    for a, c in iu:
        assert np.allclose(m[:, a, c], m_ref[:, a, c], rtol=1e-3), (a, c)

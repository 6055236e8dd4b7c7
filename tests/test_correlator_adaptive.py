"""The default correlator path (issue 35, ``rewindow=None``): one FFT per block where the
block's first pass says that is enough, the common-content passes (the precise path)
elsewhere; and the first pass's window bias, removed from the block's own reference."""

import numpy as np
import pytest

from correlator.core import Correlator, measure_shift
from correlator.options import CorrelatorOptions
from correlator.testimages import image_pairs, powerlaw_images, texture_pairs

#: P(|z| > 3) on either of two independent unit-normal axes
OUTSIDE_3_SIGMA = 1.0 - (1.0 - 0.0027) ** 2


def _smooth_pairs(n: int, seed: int, beta: float = 3.0, contrast: float = 0.15):
    """n smooth, low-contrast pairs (power-law texture, std ``contrast`` of the mean, SNR 10)."""
    rng = np.random.default_rng(seed)
    return image_pairs(powerlaw_images(4, 256, beta, rng), n, 128, rng, snr=10.0,
                       contrast=contrast)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _uneven_pairs(n: int, seed: int):
    """n pairs of strong texture whose contrast varies across each block (an envelope of
    0.1-1 over ~128-150 px, as fields, roofs and shadows do on rendered scenes), SNR 30,
    shifts within +-3.5 px (inside the first pass's exact margin)."""
    rng = np.random.default_rng(seed)
    fields, _, _ = texture_pairs(6, 384, rng, max_shift_px=0.0)
    yy, xx = np.mgrid[0:384, 0:384]
    env = 0.1 + 0.9 * ((0.5 + 0.5 * np.sin(2 * np.pi * xx / 256.0))
                       * (0.5 + 0.5 * np.cos(2 * np.pi * yy / 300.0)))
    return image_pairs([(f - 100.0) * env for f in fields], n, 128, rng, snr=30.0,
                       contrast=0.25, max_shift_px=3.5)


def test_default_equals_the_precise_path_within_the_predicted_error():
    """Strong texture, SNR 10, 200 pairs of 128^2: most blocks keep their first pass, and the
    default's shifts differ from the precise path's by more than 3 predicted sigma on an
    axis no more often than the expected fraction of a normal variable (0.54 %: 1 of 200;
    measured 0: the two differ by ~0.5 sigma rms)."""
    ref, cur, _ = texture_pairs(200, 128, np.random.default_rng(3501), snr=10.0)
    default = measure_shift(ref, cur)
    precise = measure_shift(ref, cur, rewindow=True)
    assert default.valid.all() and precise.valid.all()
    assert default.precise.mean() < 0.1 and precise.precise.all()
    outside = np.any(np.abs(default.shift - precise.shift) > 3.0 * precise.crlb, axis=1)
    assert outside.sum() <= np.floor(OUTSIDE_3_SIGMA * len(ref))


def test_first_pass_is_unbiased_where_the_texture_is_uneven():
    """The first pass correlates ref under a narrow window against cur under a wide one; where
    the texture's power differs between the window's opposite tapers its peak moves by
    -1/2 sum grad(w) s^2 over the curvature (the flight test's rendered blocks: 23 predicted
    sigma). On texture whose contrast varies across the block (200 pairs, SNR 30) the first
    pass with that bias removed (measured on the reference against itself) is off by more
    than 3 predicted sigma no more often than a normal variable (0.54 %: 1 of 200; measured
    0, RMS 0.9 sigma), where the bias it removed is several sigma (without it: 192 of 200
    outside, RMS 6.4 sigma)."""
    ref, cur, d = _uneven_pairs(200, 3507)
    c = Correlator(ref, rewindow=False)
    r = c.measure(cur)
    assert r.valid.all() and not r.precise.any()
    outside = np.any(np.abs(r.shift - d) > 3.0 * r.crlb, axis=1)
    assert outside.sum() <= np.floor(OUTSIDE_3_SIGMA * len(ref))
    removed = c._fp_bias / r.crlb  # the bias each block's first pass removed, in its sigma
    assert _rms(removed) > 4.0


def test_adaptive_decision_sends_smooth_blocks_to_the_precise_passes():
    """From the block's own first pass: smooth low-contrast blocks (1/f^3 texture, std 15 %
    of the mean, SNR 10; predicted errors 0.05-0.2 px) take the common-content passes, strong
    texture at SNR 10 (0.007 px) keeps the first pass; each of the rule's reasons on its
    own."""
    ref, cur, _ = _smooth_pairs(24, 3502)
    assert measure_shift(ref, cur).precise.mean() >= 0.9
    ref, cur, _ = texture_pairs(24, 128, np.random.default_rng(3503), snr=10.0)
    assert measure_shift(ref, cur).precise.mean() <= 0.1
    ok, sharp, hi = np.ones(1, bool), np.full((1, 2), 0.93), np.array([20.0])
    crlb, zero = np.full((1, 2), 0.01), np.array([0.0])

    def rule(crlb=crlb, psr=hi, settled=ok, bias=zero, rho=sharp):
        return bool(Correlator._needs_precise(crlb, psr, settled, bias, rho)[0])

    assert not rule()  # a strong block keeps its first pass
    assert rule(crlb=crlb * 10)  # a large predicted error
    assert rule(crlb=crlb / 10)  # so small that the first pass's window bias dominates
    assert rule(psr=np.array([6.0]))  # near the PSR floor
    assert rule(settled=~ok)  # not settled
    assert not rule(bias=np.array([0.05]))  # a bias of 5 sigma removed: kept
    assert rule(bias=np.array([0.2]))  # 20 sigma: its removal's own error matters
    assert rule(bias=np.array([np.nan]))
    assert rule(rho=np.full((1, 2), 0.96))  # a broad peak: smooth texture
    assert rule(rho=np.full((1, 2), np.nan))


def test_mixed_batch_accuracy_within_ten_percent_of_the_precise_path():
    """64 strong (SNR 10) and 64 smooth pairs in one batch: the default's RMS error (over the
    pairs both paths call valid) within 10 % of the precise path's on each part and its
    valid-and-within-0.5-px count no lower, with only the smooth part's blocks (about half)
    re-windowed."""
    ref_s, cur_s, d_s = texture_pairs(64, 128, np.random.default_rng(3504), snr=10.0)
    ref_m, cur_m, d_m = _smooth_pairs(64, 3505, beta=2.5, contrast=0.08)
    ref, cur, d = (np.concatenate(a) for a in ((ref_s, ref_m), (cur_s, cur_m), (d_s, d_m)))
    default = measure_shift(ref, cur)
    precise = measure_shift(ref, cur, rewindow=True)
    assert 0.3 < default.precise.mean() < 0.7
    both = default.valid & precise.valid
    for part in (slice(0, 64), slice(64, 128)):
        k = both[part]
        assert k.sum() >= 32
        e_def = _rms((default.shift - d)[part][k])
        e_pre = _rms((precise.shift - d)[part][k])
        assert e_def < 1.1 * e_pre, (part, e_def, e_pre)

    def good(r):
        return int((r.valid & (np.abs(r.shift - d).max(axis=1) < 0.5)).sum())

    assert good(default) >= good(precise) - 1


def test_rewindow_options_force_one_path():
    """``rewindow``: None (default) decides per block, True gives every block the passes,
    False none (but a block moved beyond the exact margin); anything else is refused."""
    ref, cur, _ = _smooth_pairs(8, 3506)
    assert measure_shift(ref, cur, rewindow=True).precise.all()
    assert not measure_shift(ref, cur, rewindow=False).precise.any()
    assert CorrelatorOptions().rewindow is None
    with pytest.raises(ValueError, match="rewindow"):
        CorrelatorOptions(rewindow="auto")


def test_blocks_certain_to_take_the_passes_skip_the_first_pass(monkeypatch):
    """Blocks whose fixed-window correlation already shows a broad peak (the medium texture:
    restoring ratio ~0.96) go to the common-content passes without a first pass (counted by
    a hook on it: 73-83 % of them on 200-400 pairs); their results equal the precise path's
    within the passes' own stopping tolerance (0.05 predicted sigma; measured 0.001) with the
    same validity. Strong blocks (ratio ~0.93) all take their first pass."""
    seen = []
    first = Correlator._first_pass

    def counted(self, blk, *args, **kwargs):
        seen.append(len(blk))
        return first(self, blk, *args, **kwargs)

    monkeypatch.setattr(Correlator, "_first_pass", counted)
    ref, cur, _ = texture_pairs(32, 128, np.random.default_rng(3504), snr=10.0,
                                texture="medium")
    a = measure_shift(ref, cur)
    assert sum(seen) <= 16, seen  # at least half decided early (28 of 32 here)
    b = measure_shift(ref, cur, rewindow=True)
    assert a.precise.all()
    assert np.array_equal(a.valid, b.valid)
    assert np.all(np.abs(a.shift - b.shift) <= 0.05 * b.crlb)
    seen.clear()
    ref, cur, _ = texture_pairs(32, 128, np.random.default_rng(3505), snr=10.0,
                                texture="strong")
    r = measure_shift(ref, cur)
    assert sum(seen) == 32 and not r.precise.any()


def test_scaled_weights_equal_the_reference_weights_under_the_same_window():
    """The first pass's weights from box means of the power (``kernels.scaled_weights``) are
    the reference's own Knapp-Carter weights when the box means are its own and the scale 1:
    W conj(R) and the CRLB sums equal :func:`kernels.ref_spectra`'s to float32 rounding."""
    from correlator import kernels

    ref, _, _ = texture_pairs(4, 64, np.random.default_rng(3513), snr=10.0)
    c = Correlator(ref)
    c._ensure_ref(np.arange(4))
    lay, g = c._lay, c._lay.full
    spec = c._ref_spec
    wc, m = np.empty_like(spec), np.zeros((4, 3, 3))
    kernels.scaled_weights(spec.view(np.float32), c._ref_pbox, np.arange(4), np.ones(4),
                           c._ref_noise * lay.e_ref, g.alpha, g.ay, g.ax, g.rows,
                           wc.view(np.float32), m)
    assert np.allclose(wc, c._ref_wconj, rtol=1e-5, atol=1e-6 * np.abs(c._ref_wconj).max())
    assert np.allclose(m, c._ref_m, rtol=1e-4)


@pytest.mark.parametrize("snr", [10.0, 6.0])
def test_first_pass_weights_from_the_fixed_windows_power(snr):
    """The first pass weighs its reference by the fixed window's box means of the power
    scaled by the windows' energies (one box average a reference, not two): on strong
    texture the blocks that keep their first pass (all but those moved beyond its margin and
    at most 2 of 64 whose decision moves) give the results of its own box means within 0.1
    predicted sigma (measured 0.03), with the same validity, predicted errors within 1 % and
    the RMS error within 2 %."""
    ref, cur, d = texture_pairs(64, 128, np.random.default_rng(3510), snr=snr)
    new = Correlator(ref).measure(cur)
    own = Correlator(ref)
    own._fp_from_power = False  # the first pass's reference makes its own weights
    old = own.measure(cur)
    assert np.count_nonzero(new.precise != old.precise) <= 2
    keep = ~new.precise & ~old.precise
    assert keep.sum() >= 48
    assert np.all(np.abs(new.shift - old.shift)[keep] <= 0.1 * old.crlb[keep])
    assert np.array_equal(new.valid, old.valid)
    assert np.allclose(new.crlb[keep], old.crlb[keep], rtol=0.01)
    assert _rms((new.shift - d)[keep]) <= 1.02 * _rms((old.shift - d)[keep])

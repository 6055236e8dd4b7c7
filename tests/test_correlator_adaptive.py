"""The adaptive correlator path (issue 35, ``rewindow=None``; the default stays the precise
path until the adaptive one holds on rendered scenes): one FFT per block where the block's
first pass says that is enough, the common-content passes (the precise path) elsewhere."""

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


def test_default_equals_the_precise_path_within_the_predicted_error():
    """Strong texture, SNR 10, 200 pairs of 128^2: most blocks keep their first pass, and the
    default's shifts differ from the precise path's by more than 3 predicted sigma on an
    axis no more often than the expected fraction of a normal variable (0.54 %: 1 of 200;
    measured 0: the two differ by ~0.5 sigma rms)."""
    ref, cur, _ = texture_pairs(200, 128, np.random.default_rng(3501), snr=10.0)
    default = measure_shift(ref, cur, rewindow=None)
    precise = measure_shift(ref, cur, rewindow=True)
    assert default.valid.all() and precise.valid.all()
    assert default.precise.mean() < 0.1 and precise.precise.all()
    outside = np.any(np.abs(default.shift - precise.shift) > 3.0 * precise.crlb, axis=1)
    assert outside.sum() <= np.floor(OUTSIDE_3_SIGMA * len(ref))


def test_adaptive_decision_sends_smooth_blocks_to_the_precise_passes():
    """From the block's own first pass: smooth low-contrast blocks (1/f^3 texture, std 15 %
    of the mean, SNR 10; predicted errors 0.05-0.2 px) take the common-content passes, strong
    texture at SNR 10 (0.007 px) keeps the first pass (but the few, ~2 %, whose first pass
    and fixed windows disagree by more than a predicted sigma); each of the rule's reasons
    on its own."""
    ref, cur, _ = _smooth_pairs(24, 3502)
    assert measure_shift(ref, cur, rewindow=None).precise.mean() >= 0.9
    ref, cur, _ = texture_pairs(24, 128, np.random.default_rng(3503), snr=10.0)
    # 2 of 24 here: their windows differ
    assert measure_shift(ref, cur, rewindow=None).precise.mean() <= 0.1
    ok, sharp, hi = np.ones(1, bool), np.full((1, 2), 0.93), np.array([20.0])
    crlb, zero = np.full((1, 2), 0.01), np.array([0.0])

    def rule(crlb=crlb, psr=hi, settled=ok, gap=zero, rho=sharp):
        return bool(Correlator._needs_precise(crlb, psr, settled, gap, rho)[0])

    assert not rule()  # a strong block keeps its first pass
    assert rule(crlb=crlb * 10)  # a large predicted error
    assert rule(crlb=crlb / 10)  # so small that the first pass's window bias dominates
    assert rule(psr=np.array([6.0]))  # near the PSR floor
    assert rule(settled=~ok)  # not settled
    assert rule(gap=np.array([0.02]))  # the first pass and the fixed windows disagree
    assert rule(rho=np.full((1, 2), 0.97))  # a broad peak: smooth texture
    assert rule(rho=np.full((1, 2), np.nan))


def test_mixed_batch_accuracy_within_ten_percent_of_the_precise_path():
    """64 strong (SNR 10) and 64 smooth pairs in one batch: the default's RMS error (over the
    pairs both paths call valid) within 10 % of the precise path's on each part and its
    valid-and-within-0.5-px count no lower, with only the smooth part's blocks (about half)
    re-windowed."""
    ref_s, cur_s, d_s = texture_pairs(64, 128, np.random.default_rng(3504), snr=10.0)
    ref_m, cur_m, d_m = _smooth_pairs(64, 3505, beta=2.5, contrast=0.08)
    ref, cur, d = (np.concatenate(a) for a in ((ref_s, ref_m), (cur_s, cur_m), (d_s, d_m)))
    default = measure_shift(ref, cur, rewindow=None)
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
    assert CorrelatorOptions().rewindow is True  # the precise path stays the default
    with pytest.raises(ValueError, match="rewindow"):
        CorrelatorOptions(rewindow="auto")

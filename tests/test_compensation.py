import numpy as np
import pytest
from scipy.special import j0

from compensation import motion_mtf, residual_metrics


def test_motion_mtf_of_linear_smear_is_sinc():
    for d in (0.35, 0.5, 1.0):
        r = np.column_stack([np.linspace(-d / 2, d / 2, 20001), np.zeros(20001)])
        assert motion_mtf(r, axis=0) == pytest.approx(abs(np.sinc(0.5 * d)), abs=1e-4)
        assert motion_mtf(r, axis=1) == pytest.approx(1.0)


def test_motion_mtf_of_sinusoid_is_bessel_j0():
    t = np.linspace(0, 1, 100000, endpoint=False)
    for a in (0.14, 0.2, 1.0):
        r = np.column_stack([np.zeros_like(t), a * np.sin(2 * np.pi * 3 * t)])
        assert motion_mtf(r, axis=1) == pytest.approx(abs(j0(np.pi * a)), abs=1e-4)


def test_residual_metrics_of_a_sinusoid():
    t = np.arange(0, 1, 1e-3)
    r = np.column_stack([np.sin(2 * np.pi * 2 * t), 0.5 * np.ones_like(t)])
    m = residual_metrics(t, r, window_s=0.5)
    assert m.rms_px[0] == pytest.approx(np.sqrt(0.5), rel=1e-3)
    assert m.rms_px[1] == pytest.approx(0.5)
    assert m.peak_to_peak_px[0] == pytest.approx(2.0, rel=1e-3)
    assert m.mtf_nyquist[1] == pytest.approx(1.0)  # a constant offset does not blur
    assert m.window_s == pytest.approx(0.5)

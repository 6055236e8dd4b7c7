"""Jitter generators: PSD reproduced by Welch, sinusoids and wheel harmonics as specified."""

import numpy as np
import pytest
from scipy.signal import welch

from orbit.jitter import JitterTerm, RandomJitter, WheelJitter, realize_jitter


@pytest.mark.parametrize("slope", [0.0, -2.0])
def test_random_jitter_reproduces_its_psd_within_10_percent(slope):
    spec = RandomJitter("pitch", rms_rad=1e-6, f_min_hz=1.0, f_max_hz=50.0, slope=slope)
    series = realize_jitter([spec], 64.0, np.random.default_rng(7))
    fs = 125.0
    t = np.arange(0.0, 64.0, 1.0 / fs)
    x = series.rotvec_rad(t)[:, 1]
    assert x.std() == pytest.approx(1e-6, rel=0.03)
    f, p = welch(x, fs=fs, nperseg=1024)
    # Welch's own scatter is ~25 % per 0.12 Hz bin with 15 segments; over 5 Hz bands (40
    # bins) it is ~4 %, so the PSD must be met within 10 % in every band
    for lo in np.arange(2.0, 45.0, 5.0):
        band = (f >= lo) & (f < lo + 5.0)
        ratio = p[band].mean() / spec.psd_rad2_hz(f[band]).mean()
        assert ratio == pytest.approx(1.0, abs=0.10), (lo, ratio)
    inside = (f > 2.0) & (f < 45.0)
    assert p[f > 60.0].max() < 1e-3 * p[inside].min()  # nothing outside the band


def test_random_jitter_is_seeded():
    spec = [RandomJitter("roll", 1e-6, 0.1, 10.0)]
    a = realize_jitter(spec, 10.0, np.random.default_rng(1)).rotvec_rad(np.linspace(0, 5, 50))
    b = realize_jitter(spec, 10.0, np.random.default_rng(1)).rotvec_rad(np.linspace(0, 5, 50))
    c = realize_jitter(spec, 10.0, np.random.default_rng(2)).rotvec_rad(np.linspace(0, 5, 50))
    assert np.array_equal(a, b) and not np.allclose(a, c)


def test_sinusoid_and_wheel_harmonics_and_their_rates():
    terms = [JitterTerm("roll", 0.65, 2e-6, 0.3),
             WheelJitter("yaw", 30.0, ((1.0, 1e-7), (2.0, 5e-8)), speed_rate_hz_s=3.0,
                         phases_rad=(0.0, 1.0))]
    s = realize_jitter(terms, 1.0, np.random.default_rng(0))
    t = np.linspace(0.0, 2.0, 2001)
    rv = s.rotvec_rad(t)
    assert np.allclose(rv[:, 0], 2e-6 * np.sin(2 * np.pi * 0.65 * t + 0.3), atol=1e-18)
    assert np.all(rv[:, 1] == 0.0)
    w = 30.0 + 3.0 * t  # wheel speed ramps; amplitude grows with speed squared
    phase = 2 * np.pi * (30.0 * t + 1.5 * t**2)
    expect = (w / 30.0) ** 2 * (1e-7 * np.sin(phase) + 5e-8 * np.sin(2 * phase + 1.0))
    assert np.allclose(rv[:, 2], expect, atol=1e-18)
    dt = 1e-6
    fd = (s.rotvec_rad(t + dt) - s.rotvec_rad(t - dt)) / (2 * dt)
    assert np.allclose(s.rate_rad_s(t), fd, atol=1e-9)  # rad/s; rates ~4e-5


def test_bad_jitter_terms_are_value_errors():
    with pytest.raises(ValueError, match="axis"):
        JitterTerm("spin", 1.0, 1e-6)
    with pytest.raises(ValueError, match="f_min_hz < f_max_hz"):
        RandomJitter("roll", 1e-6, 5.0, 1.0)
    with pytest.raises(ValueError, match="one phase per"):
        WheelJitter("roll", 30.0, ((1, 1e-7),), phases_rad=(0.0, 1.0))

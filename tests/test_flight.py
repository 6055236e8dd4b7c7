"""The flight test's two-record procedure on short seeded runs: the difference of two records
estimates their error when the errors are independent, and misses a blur both share."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from imc.scenario import parse_scenario
from imc.studies.flight import FlightConfig, run_session
from imc.wiring.build import build_models

FLIGHT = Path(__file__).resolve().parents[1] / "scenarios" / "flight_test.yaml"
FRAMES = 48


def _session(seed: int, **changes):
    data = yaml.safe_load(FLIGHT.read_text())
    data.update(seed=seed, duration_s=FRAMES / 60.0)
    data["scene"].update(size_m=512, texel_m=0.25, relief_rms_m=0.0)
    for section, values in changes.items():
        data[section].update(values)
    m = build_models(parse_scenario(data, "flight"))
    return run_session(m, FlightConfig(), FRAMES)


def test_difference_estimates_independent_errors_on_flat_ground():
    """Flat ground, the suspended camera, 2 ms exposures: across track the records' errors are
    the tracker's own, independent between fragment sets, so sigma_diff / sqrt(2) estimates the
    true error of the frame-to-frame records. With 47 increments a sigma is known to ~10 %
    (1 / sqrt(2 N)), a ratio of two to ~15 %: 0.6 .. 1.5 is a 3-sigma band (seeds 1-6:
    0.83 .. 1.08). Along track, where the ground flows 2.5 px a frame, both sets see the
    content at the same sub-pixel phase, and the part of their error that follows the phase
    (the correlator's and the renderer's fixed pixel quadrature's, as a detector's aliasing
    would) is shared, so the difference reads low (seeds 1-6: 0.58 .. 0.89 at 4 samples a
    pixel, 0.60 .. 0.95 at 16): 0.45 .. 1.2. And the tracker works near its bound: an increment
    is the difference of two shifts, so its true error stays within 1.5 x sqrt(2) x the
    correlator's predicted error of a frame's mean shift (seeds 1-6: 0.50 .. 1.01 x)."""
    s = _session(3)
    st = s.stats
    assert st["valid_fraction"] == [1.0, 1.0]
    ratio = np.array(st["per_frame"]["ratio"])
    assert 0.45 < ratio[0] < 1.2 and 0.6 < ratio[1] < 1.5, ratio
    crlb = np.sqrt(2.0) * np.max(st["crlb_px"], axis=0)
    assert np.all(np.array(st["per_frame"]["true_rms"]) < 1.5 * crlb)
    # the two truths agree on flat ground up to the field's second-order rotation terms
    frag = np.array(st["terms"]["fragments_vs_line"]["a"])
    assert np.all(frag < 0.01), frag


def test_difference_cannot_see_a_blur_both_records_share():
    """A rigid mount, exposures of a whole frame period (1/60 s) and a 106 Hz vibration of
    60 urad (0.32 px): each frame shows the vibration's exposure mean, the same for every
    fragment. The true error of both records is that mean's departure from the mid-exposure
    position, A |1 - sinc(f T)| / sqrt(2) rms (0.254 px; within 15 %, the tracker adding
    < 0.05 px in quadrature), while their difference stays at the tracker's noise: the paper's
    estimate misses more than three quarters of the error."""
    amp_urad, f_hz, exposure_s = 60.0, 106.0, 1.0 / 60.0
    jitter = {"sinusoids": [{"axis": "pitch", "frequency_hz": f_hz,
                             "amplitude_urad": amp_urad, "phase_deg": 20.0}]}
    s = _session(4, attitude={"suspension": None, "jitter": jitter},
                 camera={"tracker": {**yaml.safe_load(FLIGHT.read_text())["camera"]["tracker"],
                                     "exposure_s": None}})
    st = s.stats
    ifov = 20.625e-6 / 0.110
    expected = amp_urad * 1e-6 / ifov * abs(1.0 - np.sinc(f_hz * exposure_s)) / np.sqrt(2.0)
    assert expected == pytest.approx(0.254, abs=0.002)
    true = st["true_rms"][0]
    assert true == pytest.approx(expected, rel=0.15)
    assert st["terms"]["blur"]["common"][0] == pytest.approx(expected, rel=0.05)
    assert st["inferred"][0] < 0.25 * true

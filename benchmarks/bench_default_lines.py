"""Lines nobody listed, with the Kalman predictor's defaults (issue 35, item 3): the family of
cases the defaults were chosen on (none of them a bundled scenario), before and after.

    .venv/bin/python benchmarks/bench_default_lines.py ['{"window_s": 2.0, ...}'] [case,...]

A 1 kHz loop on the analytic plant (one block, its measurement noise as given), the quickstart's
predictor (Kalman, order 3, 12 Hz, half a frame's lead), an ideal ramping stage, one frame of
latency; a wheel line (fixed, or swept 1 %/s) nobody listed beside a slow roll on the other
axis; 1.5 s, main-imager exposures of 0.1 s from 0.1 s. Printed per case: the RMS reduction
from 0.1 s, the exposures whose motion MTF at Nyquist (both axes' product) the loop made
worse than open by more than 0.001, the worst difference, the lines the predictor ends with.
The optional JSON argument overrides the predictor's parameters (the earlier defaults:
``{"handover": "full", "track_gain": 0.0, "prune_snr": null, "window_s": 2.0,
"every_s": 1.0}``). ~5 s a case on 2 cores.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from compensation.actuators import IdealStage  # noqa: E402
from compensation.analytic_plant import AnalyticPlant  # noqa: E402
from compensation.controllers import KalmanPredictor  # noqa: E402
from compensation.estimators import MeanEstimator  # noqa: E402
from compensation.loop import Timeline, simulate  # noqa: E402
from compensation.metrics import motion_mtf  # noqa: E402
from compensation.transport import Transport  # noqa: E402

RATE_HZ = 1000.0
DURATION_S = 1.5
START_S = 0.1
EXPOSURE_S = 0.1


def wheel(f0_hz: float, sweep_per_s: float = 0.0, amps_px: tuple[float, ...] = (0.05, 0.05),
          roll: tuple[float, float] = (0.5, 0.65), axis: int = 0
          ) -> Callable[[np.ndarray], np.ndarray]:
    """Motion (N, 1, 2) px at times (N,) s: a wheel's harmonics (amplitudes px) at
    f0 (1 + sweep t) Hz on ``axis``, a roll (amplitude px, frequency Hz) on the other."""

    def motion(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros((len(t), 1, 2))
        out[:, 0, 1 - axis] = roll[0] * np.sin(2 * np.pi * roll[1] * t)
        phase = 2 * np.pi * f0_hz * (t + 0.5 * sweep_per_s * t * t)
        for h, a in enumerate(amps_px, 1):
            out[:, 0, axis] += a * np.sin(h * phase + 0.3 * h)
        return out

    return motion


#: name: (motion, measurement noise px)
CASES = {
    "47 Hz": (wheel(47.0), 0.01),
    "33 Hz, 0.08 px, roll 0.9 Hz": (wheel(33.0, amps_px=(0.08,), roll=(0.4, 0.9)), 0.015),
    "62 Hz, 0.03 + 0.02 px": (wheel(62.0, amps_px=(0.03, 0.02)), 0.01),
    "55 Hz, 0.1 px, col axis": (wheel(55.0, amps_px=(0.1,), roll=(0.3, 0.4), axis=1), 0.02),
    "38 Hz swept 1 %/s": (wheel(38.0, 0.01, amps_px=(0.05, 0.03)), 0.01),
    "75 Hz swept 1 %/s": (wheel(75.0, 0.01, amps_px=(0.04,)), 0.01),
    "30 Hz swept 1 %/s": (wheel(30.0, 0.01, amps_px=(0.06, 0.04)), 0.015),
}


def run_case(motion: Callable[[np.ndarray], np.ndarray], noise_px: float, seed: int = 3,
             **params) -> dict:
    """One run; -> reduction, exposures worse, worst MTF difference, final lines (Hz)."""
    n = int(DURATION_S * RATE_HZ)
    ft = np.arange(n) / RATE_HZ
    plant = AnalyticPlant(motion, np.zeros((1, 2)), noise_px, ft, 1 / RATE_HZ, seed=(seed,))
    ctl = KalmanPredictor(rate_hz=RATE_HZ, order=3, bandwidth_hz=12.0, lead_s=0.5 / RATE_HZ,
                          **params)
    res = simulate(plant, MeanEstimator(), ctl, IdealStage(ramp=True, ramp_s=1 / RATE_HZ),
                   Transport(latency_s=1 / RATE_HZ),
                   Timeline(ft, 1 / RATE_HZ, n / RATE_HZ, np.zeros((n, 2)), 1 / RATE_HZ))
    ts = (np.arange(n * 8) + 0.5) / (RATE_HZ * 8)
    ref = motion(np.arange(8) / (8 * RATE_HZ) + 1 / (16 * RATE_HZ))[:, 0, :].mean(axis=0)
    opened = motion(ts)[:, 0, :] - ref
    r = opened - res.trajectory(ts)
    sel = ts >= START_S
    red = float(np.sqrt((opened[sel] ** 2).sum(1).mean() / (r[sel] ** 2).sum(1).mean()))
    diffs = []
    for i in range(int((DURATION_S - START_S) / EXPOSURE_S + 1e-9)):
        w = (ts >= START_S + i * EXPOSURE_S) & (ts < START_S + (i + 1) * EXPOSURE_S)
        mo = motion_mtf(opened[w], axis=0) * motion_mtf(opened[w], axis=1)
        mc = motion_mtf(r[w], axis=0) * motion_mtf(r[w], axis=1)
        diffs.append(float(mc - mo))
    d = np.array(diffs)
    return {"reduction": red, "worse": int(np.sum(d < -1e-3)), "n": len(d),
            "worst": float(min(d.min(), 0.0)),
            "lines_hz": [round(float(f), 2) for f in res.states["controller"].lines_hz]}


def main() -> None:
    params = json.loads(sys.argv[1]) if len(sys.argv) > 1 else {}
    names = sys.argv[2].split(",") if len(sys.argv) > 2 else list(CASES)
    for name in names:
        motion, noise = CASES[name]
        d = run_case(motion, noise, **params)
        print(f"| {name} | {d['reduction']:.1f}x | {d['worse']} of {d['n']} | "
              f"{d['worst']:+.4f} | {d['lines_hz']} |", flush=True)


if __name__ == "__main__":
    main()

"""A chained tracker's links against the camera model's truth on the texture plant (issue 33):
each block's error, the links' mean (their bias) with its standard error, their scatter and
lag-1 correlation, and the mean per quarter of the strip (a bias that grows along it).

The plant's frames are made and tracked as a run makes them (``TrackerPlant.measure``, the
chain re-referenced every frame) with the stage at rest and no loop; each block's error is
its measured shift less the exposure-mean motion of its content (``imc.wiring.truth``).
``--noise-free``: the frames without the sensor's noise (the plant's geometry and the
correlator's own bias). Measured here, never asserted in tests.

    .venv/bin/python benchmarks/bench_link_bias.py FILE [--noise-free] [--out benchmarks/out]

FILE: a scanning scenario on any plant (run here on the texture plant), e.g. the chosen
design `imc design scenarios/designs/smallsat_pushbroom.yaml` writes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import yaml

from imc.io import write_json
from imc.scenario import parse_scenario
from imc.wiring import rendered_plant
from imc.wiring.build import build_models
from imc.wiring.truth import exposure_times

ROOT = Path(__file__).resolve().parents[1]


class _AtRest:
    """A stage that never moves (the trajectory protocol the plant asks)."""

    samples = (np.array([0.0, 1e9]), np.zeros((2, 2)))

    def __call__(self, t):
        return np.zeros(np.shape(t) + (2,))

    def mean(self, t0: float, t1: float) -> np.ndarray:
        return np.zeros(2)


def chain_errors(m, noise_free: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Each block's error (T, B, 2) px against the truth (NaN where not valid; frame 0 NaN)
    and the bound (T, B, 2) px, of the texture plant's chain."""
    if noise_free:  # the optics and the gain only, scaled up so rounding stays far below
        rendered_plant.expose_frame = lambda mm, rad, gain, rng: np.clip(
            np.rint(mm.optics.apply(rad) * gain * 50.0), 0, 65535)
    plant = rendered_plant.TexturePlant(m)
    n, nb = len(m.frame_t_s), len(m.corners)
    s = m.scenario.metrics.samples_per_frame
    err = np.full((n, nb, 2), np.nan)
    crlb = np.full((n, nb, 2), np.nan)
    still = _AtRest()
    for k in range(n):
        meas = plant.measure(k, still, np.ones(nb, bool))
        if k > 0:
            r = int(meas.ref_frame[0])
            g = m.camera.ground_points(meas.centers_px, float(m.frame_mid_s[r]),
                                       m.terrain.height_at)
            times = np.concatenate([exposure_times(m, r, s), exposure_times(m, k, s)])
            mo = m.camera.image_motion_px(g, times, float(m.frame_mid_s[r]))
            true = mo[s:].mean(axis=0) - mo[:s].mean(axis=0)
            err[k] = np.where(meas.valid[:, None], meas.shift_px - true, np.nan)
            crlb[k] = np.where(meas.valid[:, None], meas.sigma_px, np.nan)
        if m.chain:
            plant.rereference(k)
    return err, crlb


def summary(err: np.ndarray, crlb: np.ndarray) -> dict:
    """The blocks' and the links' figures (px, per axis row / col)."""
    e = err[1:]
    link = np.nanmean(e, axis=1)
    ok = np.all(np.isfinite(link), axis=1)
    n = int(ok.sum())
    lk = link[ok]
    return {
        "links": n, "valid_blocks": float(np.isfinite(e[..., 0]).mean()),
        "block_mean_px": np.nanmean(e, axis=0).tolist(),
        "block_sd_px": np.nanstd(e, axis=0).tolist(),
        "link_mean_px": lk.mean(axis=0).tolist(),
        "link_mean_se_px": (lk.std(axis=0) / np.sqrt(max(n, 1))).tolist(),
        "link_sd_px": lk.std(axis=0).tolist(),
        "link_lag1": [float(np.corrcoef(lk[:-1, i], lk[1:, i])[0, 1]) for i in range(2)],
        "crlb_median_px": np.nanmedian(crlb[1:], axis=(0, 1)).tolist(),
        "link_mean_by_quarter_px": [lk[q].mean(axis=0).tolist()
                                    for q in np.array_split(np.arange(n), 4)]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("file", type=Path)
    ap.add_argument("--noise-free", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out"))
    a = ap.parse_args()
    d = yaml.safe_load(a.file.read_text())
    d.pop("expect", None)
    d["plant"] = {"fidelity": "texture"}
    t0 = time.perf_counter()
    m = build_models(parse_scenario(d))
    t1 = time.perf_counter()
    err, crlb = chain_errors(m, a.noise_free)
    out = {"scenario": str(a.file), "noise_free": a.noise_free, "build_s": t1 - t0,
           "plant_and_chain_s": time.perf_counter() - t1, **summary(err, crlb)}
    print(json.dumps(out, indent=1), flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    write_json(Path(a.out) / f"link_bias{'_noise_free' if a.noise_free else ''}.json", out)


if __name__ == "__main__":
    main()

"""Optical correlator emulation: accuracy against the digital JTC across SNR and block size,
the cost of each hardware effect, and the emulation's own speed.

    .venv/bin/python benchmarks/bench_optical.py [--pairs 16] [--out benchmarks/out/optical]

Writes optical.json and optical.md. SNR = mean / noise sigma of each image (the paper's
definition; 1.6 is its "SNR 4 dB" case). Figures are measured, never asserted in tests.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from correlator import measure_shift
from correlator.optical import EFFECTS, JtocModel
from correlator.testimages import texture_pairs
from correlator.timing import PipelineTiming
from imc.io import write_json


def _rms(res, d) -> float:
    """RMS error (px, both components) of the valid results."""
    ok = res.valid
    return float(np.sqrt(np.mean((res.shift[ok] - d[ok]) ** 2))) if ok.any() else float("nan")


def _rms_all(res, d) -> float:
    """RMS error (px) of every result, valid or not (the paper's noise study reports all)."""
    return float(np.sqrt(np.mean((res.shift - d) ** 2)))


def accuracy(pairs: int, seed: int) -> list[dict]:
    rows = []
    for block in (64, 128, 256):
        for snr in (1.6, 3.0, 10.0, 20.0):
            rng = np.random.default_rng([seed, block, int(snr * 10)])
            ref, cur, d = texture_pairs(pairs, block, rng, snr=snr, max_shift_px=block / 16)
            dig = measure_shift(ref, cur)
            t = time.perf_counter()
            opt = measure_shift(ref, cur, method="optical", rng=np.random.default_rng(seed))
            dt = time.perf_counter() - t
            ideal = measure_shift(ref, cur, method="optical", optical=JtocModel.ideal())
            rows.append({
                "block_px": block, "snr": snr,
                "digital_rms_px": _rms(dig, d), "digital_valid": float(dig.valid.mean()),
                "optical_rms_px": _rms(opt, d), "optical_valid": float(opt.valid.mean()),
                "digital_rms_all_px": _rms_all(dig, d), "optical_rms_all_px": _rms_all(opt, d),
                "optical_ideal_com_rms_px": _rms(ideal, d),
                "crlb_px": float(np.median(dig.crlb.max(axis=1))),
                "optical_pairs_per_s": pairs / dt,
            })
            print(rows[-1], flush=True)
    return rows


def effect_costs(pairs: int, seed: int, block: int = 64, snr: float = 10.0) -> list[dict]:
    """Error with every effect on, and with each one switched off (its cost = the drop)."""
    rng = np.random.default_rng([seed, 99])
    ref, cur, d = texture_pairs(pairs, block, rng, snr=snr, max_shift_px=block / 16)
    m = JtocModel()

    def err(model):
        return _rms(measure_shift(ref, cur, method="optical", optical=model,
                                  rng=np.random.default_rng(seed)), d)

    base = err(m)
    rows = [{"effect": "(all on)", "rms_px": base, "cost_px": 0.0}]
    for e in EFFECTS:
        v = err(m.without(e))
        rows.append({"effect": e, "rms_px": v, "cost_px": base - v})
        print(rows[-1], flush=True)
    rows.append({"effect": "(all off: digital JTC, centre of mass)",
                 "rms_px": err(JtocModel.ideal()), "cost_px": float("nan")})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out/optical"))
    a = ap.parse_args()
    t0 = time.perf_counter()
    acc = accuracy(a.pairs, a.seed)
    cost = effect_costs(a.pairs, a.seed)
    seed_dev, fast = PipelineTiming(), PipelineTiming.fast()
    timing = {name: {"correlations_per_s": t.correlations_per_s, "latency_s": t.latency_s}
              for name, t in (("seed hardware model", seed_dev), ("fast (claimed)", fast))}
    res = {"accuracy": acc, "effects": cost, "timing": timing,
           "wall_s": time.perf_counter() - t0}
    a.out.mkdir(parents=True, exist_ok=True)
    write_json(a.out / "optical.json", res)
    md = ["| block | SNR | digital JTC rms px (valid) | all | optical rms px (valid) | all "
          "| ideal optics, COM | CRLB px | emulated pairs/s |",
          "|---|---|---|---|---|---|---|---|---|"]
    md += [f"| {r['block_px']} | {r['snr']:g} | {r['digital_rms_px']:.4f} "
           f"({r['digital_valid']:.0%}) | {r['digital_rms_all_px']:.3f} | "
           f"{r['optical_rms_px']:.4f} ({r['optical_valid']:.0%}) | "
           f"{r['optical_rms_all_px']:.3f} | "
           f"{r['optical_ideal_com_rms_px']:.4f} | {r['crlb_px']:.4f} | "
           f"{r['optical_pairs_per_s']:.1f} |" for r in acc]
    md += ["", "| effect switched off | rms px | cost px |", "|---|---|---|"]
    md += [f"| {r['effect']} | {r['rms_px']:.4f} | {r['cost_px']:+.4f} |" for r in cost]
    (a.out / "optical.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    print(json.dumps(timing))
    print(f"wall {res['wall_s']:.0f} s")


if __name__ == "__main__":
    main()

"""Predicted against measured false-valid rate of the correlator's validity (issue 25).

Usage: python benchmarks/bench_validity.py [--pairs N] [--seed S] [--rate R] [--max-crlb C]
    [--psr-floor Z ...]

Grid: texture (strong, medium, weak) x SNR (0.5-10) x block (32^2-256^2), default options,
shifts within +-4 px. Per cell: flagged valid, measured false-valid (valid with an error
>= 0.5 px on an axis), and the predicted false-valid rate: the mean over the pairs of
valid x (P_fa + P_sub), P_fa the detection's probability that the peak is a noise peak
(``ShiftResult.p_false``, :mod:`correlator.detection`), P_sub = 1 - prod_axes (1 - 2 Q(0.5 /
crlb)) the Gaussian tail of the block's own predicted error beyond 0.5 px. Then noise-only
pairs (how many are flagged valid). The correlator runs without its PSR floor
(``psr_threshold=0``) at ``--rate`` (``false_valid_rate``) and ``--max-crlb``; the columns
are the results that also reach each PSR floor (0, the default safeguard 5.5, and
``--psr-floor``), post-filtered from the same runs. A loose rate and error limit (e.g.
``--rate 0.05 --max-crlb 0.3``) puts the predicted rate above 0.1 % in many cells, where the
prediction can be checked. Nothing here is fitted.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import special, stats

from correlator.core import PSR_SAFEGUARD, measure_shift
from correlator.testimages import texture_pairs

SNRS = (0.5, 1.0, 1.6, 3.0, 10.0)
BLOCKS = (32, 64, 128, 256)
TEXTURES = ("strong", "medium", "weak")


def predicted_wrong(res, linear: bool = False) -> np.ndarray:
    """P(error >= 0.5 px on an axis) of each result: ``ShiftResult.p_wrong`` (the detection's
    P_fa and the sub-pixel tail with its restoring ratio, :mod:`correlator.tail`), or with
    ``linear`` the linearised tail (restoring ratio 1) instead."""
    if not linear:
        return np.nan_to_num(res.p_wrong, nan=1.0)
    c = np.where(np.isfinite(res.crlb), res.crlb, np.inf)
    tail = 1.0 - np.prod(1.0 - 2.0 * special.ndtr(-0.5 / np.maximum(c, 1e-12)), axis=1)
    return np.minimum(1.0, np.nan_to_num(res.p_false, nan=1.0) + tail)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=200, help="pairs per cell at 128^2 (x4 at "
                    "32^2, x2 at 64^2, /2 at 256^2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise-pairs", type=int, default=2000)
    ap.add_argument("--psr-floor", type=float, nargs="*", default=[])
    ap.add_argument("--rate", type=float, default=5e-3, help="false_valid_rate")
    ap.add_argument("--max-crlb", type=float, default=0.0, help="max_crlb_px (0: none)")
    ap.add_argument("--linear", action="store_true", help="predict with the linearised tail")
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    opts = {"psr_threshold": 0.0, "false_valid_rate": a.rate, "max_crlb_px": a.max_crlb or None}
    floors = [0.0, PSR_SAFEGUARD, *a.psr_floor]
    scale = {32: 4.0, 64: 2.0, 128: 1.0, 256: 0.5}
    tot = {f: [0, 0, 0.0, 0] for f in floors}
    print("| texture | block | SNR | pairs | " + " | ".join(
        f"valid / false-valid meas. / pred. (PSR >= {f:g})" for f in floors) + " |")
    print("|---|---|---|---|" + "---|" * len(floors))
    t0 = time.perf_counter()
    for tex in TEXTURES:
        for b in BLOCKS:
            for snr in SNRS:
                n = max(20, int(a.pairs * scale[b]))
                ref, cur, d = texture_pairs(n, b, rng, snr=snr, texture=tex)
                r = measure_shift(ref, cur, **opts)
                wrong = np.abs(r.shift - d).max(axis=1) >= 0.5
                pw = predicted_wrong(r, a.linear)
                cells = []
                for f in floors:
                    v = r.valid & (r.peak >= f)
                    meas, pred = (v & wrong).mean(), (v * pw).mean()
                    tot[f][0] += n
                    tot[f][1] += int((v & wrong).sum())
                    tot[f][2] += float((v * pw).sum())
                    tot[f][3] += int(v.sum())
                    flag = ""
                    if max(meas, pred) > 1e-3:
                        flag = " ok" if 0.5 <= (meas + 1e-12) / (pred + 1e-12) <= 2 else " OUT"
                        # a count that a rate within 2x of the prediction makes likely (5 %)
                        lam = (v * pw).sum()
                        k = int((v & wrong).sum())
                        if flag == " OUT" and (stats.poisson.cdf(k, 2 * lam) > 0.025
                                               and stats.poisson.sf(k - 1, lam / 2) > 0.025):
                            flag = " ok (counts)"
                    cells.append(f"{100 * v.mean():.1f} % / {100 * meas:.2f} % / "
                                 f"{100 * pred:.3f} %{flag}")
                print(f"| {tex} | {b} | {snr:g} | {n} | " + " | ".join(cells) + " |", flush=True)
    for f in floors:
        n, nw, pw, nv = tot[f]
        print(f"PSR >= {f:g}: all cells {n} pairs, {nv} valid, {nw} valid and wrong "
              f"({100 * nw / n:.3f} %), predicted {pw:.1f} ({100 * pw / n:.3f} %)")
    for b in BLOCKS:
        m = max(50, int(a.noise_pairs * scale[b] / 2))
        x = rng.normal(100.0, 10.0, (m, b, b))
        y = rng.normal(100.0, 10.0, (m, b, b))
        r = measure_shift(x, y, **opts)
        print(f"noise-only {b}^2: " + ", ".join(
            f"PSR >= {f:g}: {int((r.valid & (r.peak >= f)).sum())} valid of {m}"
            for f in floors) + f"; P_fa <= {a.rate:g}: {int((r.p_false <= a.rate).sum())} "
            f"(predicted {a.rate * m:.1f})", flush=True)
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()

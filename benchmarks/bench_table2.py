"""The seed paper's Table 2 on rendered scenes: success % and std of error per scene class.

Usage: python benchmarks/bench_table2.py [--quick] [--classes urban,rural,...];
writes benchmarks/out/table2.json (the paper's protocol by default: 256^2 blocks,
36 references x 81 shifts within +-144 px, >= 40 % overlap, mean 100, noise sigma 10).
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

from imc.io import write_json
from imc.studies.table2 import PAPER_TABLE2, Table2Config, run_class

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="6 references x 27 shifts")
    ap.add_argument("--classes", default=",".join(PAPER_TABLE2))
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    cfg = Table2Config(n_refs=6, n_shifts=27) if args.quick else Table2Config()
    t0 = time.perf_counter()
    rows = [run_class(k, cfg, args.seed, log=lambda s: print(s, flush=True))
            for k in args.classes.split(",")]
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"total {time.perf_counter() - t0:.0f} s, peak RSS {peak_mb:.0f} MB")
    out = ROOT / "benchmarks" / "out" / ("table2_quick.json" if args.quick else "table2.json")
    write_json(out, {"config": cfg.__dict__, "rows": rows, "peak_rss_mb": peak_mb,
                     "wall_s": time.perf_counter() - t0})
    print(json.dumps([{k: r[k] for k in ("kind", "success_pct", "std_px")} for r in rows]))


if __name__ == "__main__":
    main()

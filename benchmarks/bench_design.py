"""Benchmark of `imc design`'s search: candidates per second of the fast predictors (the
issue's target: >= 10,000 candidates in <= 60 s on 2 cores), on the bundled quickstart
design. Prints the counts and the times; never asserted in a test.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_design.py [--workers 2]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from imc.workflow.design import choose, evaluate, load_design, pareto_front

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--design", default=str(ROOT / "scenarios" / "designs" /
                                            "quickstart_frame.yaml"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--crlb-px", type=float, default=None,
                    help="the tracker's bound per block (default: from the base scene)")
    args = ap.parse_args()
    d = load_design(args.design)
    t0 = time.perf_counter()
    c = evaluate(d, crlb_px=args.crlb_px, workers=args.workers)
    t_eval = time.perf_counter() - t0
    front = pareto_front(c.cost, c.worst)
    chosen, why = choose(c, d.config.margin)
    print(f"{d.config.name}: {len(c)} candidates ({c.n_loops} loops, {args.workers} "
          f"workers) in {t_eval:.1f} s (loops {c.loop_s:.1f} s, the base's bound included): "
          f"{len(c) / t_eval:.0f} candidates/s; {int(c.feasible.sum())} feasible, "
          f"{len(front)} on the Pareto front")
    if chosen is not None:
        print(f"chosen: {c.row(chosen)['cost']:.3g} cost, margin {c.worst[chosen]:.2f} ({why})")


if __name__ == "__main__":
    main()

"""Correlator benchmark (same as `imc bench correlator`): accuracy, validity, speed vs peers.

Usage: python benchmarks/bench_correlator.py [--pairs N] [--quick]
Writes benchmarks/out/correlator/{correlator.json, correlator.md, noise_curve.png,
block_size_curve.png}. Peers (scikit-image, OpenCV) and plots need `pip install -e '.[bench]'`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from imc.studies.correlator_peers import run

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=300)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out/correlator"))
    a = ap.parse_args()
    run(a.out, pairs=a.pairs, quick=a.quick)

"""The rendered tracker's pixel-integration floor per scenario, against the correlator's bound.

For each scenario: :func:`imc.wiring.rendered_plant.render_floor_px` (frame 0's pose rendered
at three sub-pixel focal-plane offsets, no sensor noise, 64-px-class blocks, the default
digital correlator) and the correlator's median predicted error on a rendered frame 0
(:func:`imc.wiring.rendered_plant.predicted_sigma_px`); their ratio is what a rendered run's
``tracker.render_floor.over_crlb`` reports. Measured here, never asserted in tests.

Usage::

    python benchmarks/bench_render_floor.py [SCENARIO ...] [--spp N] [--monte-carlo]
        [--out benchmarks/out]

SCENARIO: a bundled name (``quickstart``) or a YAML path; default every bundled scenario
with a rendered tracker. ``--spp`` overrides ``scene.spp``; ``--monte-carlo`` sets
``scene.quadrature: false``. Writes OUT/render_floor.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from imc.io import write_json
from imc.scenario import load_scenario
from imc.wiring.build import build_models
from imc.wiring.rendered_plant import (
    KEYFRAMES,
    RenderedPlant,
    predicted_sigma_px,
    render_floor_px,
)
from scene.pinhole import ray_keyframes

ROOT = Path(__file__).resolve().parents[1]
#: bundled scenarios whose tracker is rendered (no_stage and stage_ground share one scene;
#: seed_device and wheel_unknown run the analytic plant)
BUNDLED = ("quickstart", "wheel_khz", "long_stare", "ikonos_tdi_scan", "ikonos_tdi_jitter",
           "optical", "flight_test", "measured_attitude", "olinda", "no_stage")


def floor_of(path: Path, spp: int | None, monte_carlo: bool) -> dict:
    """One scenario's floor, bound (median over blocks) and ratio, px (row, col)."""
    t0 = time.perf_counter()
    sc = load_scenario(path)
    upd = {}
    if spp is not None:
        upd["spp"] = int(spp)
    if monte_carlo:
        upd["quadrature"] = False
    if upd:
        sc = sc.model_copy(update={"scene": sc.scene.model_copy(update=upd)})
    m = build_models(sc)
    plant = RenderedPlant(m)
    try:
        floor = render_floor_px(m, plant=plant)
        times = float(m.frame_t_s[0]) + np.linspace(0.0, m.exposure_s, KEYFRAMES)
        kf = ray_keyframes(m.camera.pose(times), m.camera.focal_plane, np.zeros(2),
                           plant.renderer.z_start_m)
        bound = np.nanmedian(predicted_sigma_px(m, radiance=plant.renderer.render(kf, 1)),
                             axis=0)
    finally:
        plant.close()
    return {"scenario": sc.name, "spp": int(sc.scene.spp),
            "quadrature": bool(sc.scene.quadrature), "floor_px": floor.tolist(),
            "bound_px": bound.tolist(), "over_bound": (floor / bound).tolist(),
            "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenarios", nargs="*", help="bundled names or YAML paths")
    ap.add_argument("--spp", type=int, default=None, help="override scene.spp")
    ap.add_argument("--monte-carlo", action="store_true", help="scene.quadrature: false")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out"))
    a = ap.parse_args()
    rows = []
    for name in a.scenarios or BUNDLED:
        p = Path(name) if name.endswith((".yaml", ".yml")) else \
            ROOT / "scenarios" / f"{name}.yaml"
        r = floor_of(p, a.spp, a.monte_carlo)
        rows.append(r)
        print(f"{r['scenario']:<20} spp {r['spp']:>3} "
              f"{'quadrature' if r['quadrature'] else 'Monte Carlo'}: floor "
              f"{r['floor_px'][0]:.4f} / {r['floor_px'][1]:.4f} px, bound "
              f"{r['bound_px'][0]:.4f} / {r['bound_px'][1]:.4f} px, "
              f"{r['over_bound'][0]:.2f} / {r['over_bound'][1]:.2f}x", flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    write_json(Path(a.out) / "render_floor.json", {"rows": rows})
    print(json.dumps({"wrote": str(Path(a.out) / "render_floor.json")}))


if __name__ == "__main__":
    main()

"""Render speed: seconds per frame of the exact moving pinhole sensor vs a bare Mitsuba render.

Usage: python benchmarks/bench_render.py [--quick]; writes benchmarks/out/render.json.
Both renderers are timed alternately and the medians compared (this machine's speed drifts
by up to 2x within minutes).
"""

from __future__ import annotations

import argparse
import functools
import json
import resource
import time
from pathlib import Path

import numpy as np

from imc.scenario import load_scenario
from imc.wiring.build import build_models
from scene.kernel import Renderer, Sun, load_mitsuba
from scene.pinhole import ray_keyframes

ROOT = Path(__file__).resolve().parents[1]


def bare_perspective_scene(mi, terrain_mesh_scene: dict, size: int, spp: int):
    """Mitsuba's stock perspective sensor looking down from 688 km on the same scene."""
    d = dict(terrain_mesh_scene)
    d["sensor"] = {
        "type": "perspective", "fov": float(np.degrees(size * 1.2e-6)), "far_clip": 1e7,
        "to_world": mi.ScalarTransform4f().look_at([0, 0, 688e3], [0, 0, 0], [0, 1, 0]),
        "film": {"type": "hdrfilm", "width": size, "height": size,
                 "rfilter": {"type": "gaussian"}},
        "sampler": {"type": "stratified", "sample_count": spp},
    }
    return mi.load_dict(d)


def _bare_render(mi, scene, seed: int) -> np.ndarray:
    return np.asarray(mi.render(scene, seed=seed))


def interleaved_s(ours, bare, budget_s: float) -> tuple[float, float, int]:
    """Median seconds per frame of two renderers timed alternately (after one warm-up each,
    then as many pairs as fit ``budget_s``, 5 to 40), so that the machine's drifting speed
    hits both alike. Returns (ours, bare, pairs)."""
    ours(0)
    t0 = time.perf_counter()
    bare(0)
    reps = int(np.clip(budget_s / (2.0 * (time.perf_counter() - t0)), 5, 40))
    t_ours, t_bare = [], []
    for k in range(1, reps + 1):
        t0 = time.perf_counter()
        ours(k)
        t1 = time.perf_counter()
        bare(k)
        t2 = time.perf_counter()
        t_ours.append(t1 - t0)
        t_bare.append(t2 - t1)
    return float(np.median(t_ours)), float(np.median(t_bare)), reps


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="a smaller time budget per setting")
    args = ap.parse_args()
    budget_s = 6.0 if args.quick else 20.0
    sc = load_scenario(ROOT / "scenarios" / "quickstart.yaml")
    models = build_models(sc)
    mi, _, choice = load_mitsuba()
    rows = []
    for size in (256, 512):
        fp = type(models.camera.focal_plane)(10.0, 12e-6, size, size)
        r = Renderer(models.terrain, Sun(), size, size, spp=4)
        times = models.frame_t_s[0] + np.linspace(0, sc.exposure_s, 5)
        kf = ray_keyframes(models.camera.pose(times), fp, (0.0, 0.0), r.z_start_m)
        base = {k: v for k, v in r._scene_dict.items() if k not in ("sensor",)}
        for spp in (4, 16, 64):
            r.spp = spp
            scene = bare_perspective_scene(mi, base, size, spp)
            ours, bare, reps = interleaved_s(functools.partial(r.render, kf),
                                             functools.partial(_bare_render, mi, scene),
                                             budget_s)
            rows.append({"size": size, "spp": spp, "s_per_frame": ours, "bare_s": bare,
                         "overhead": ours / bare, "pairs_timed": reps})
            print(f"{choice.variant:12s} {size}x{size} spp {spp:3d}: {ours:.3f} s/frame "
                  f"({1 / ours:.1f} frames/s), bare perspective {bare:.3f} s, "
                  f"overhead {ours / bare:.2f}x ({reps} pairs)", flush=True)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak RSS {peak_mb:.0f} MB")
    out = ROOT / "benchmarks" / "out"
    out.mkdir(parents=True, exist_ok=True)
    (out / "render.json").write_text(json.dumps({"variant": choice.variant, "rows": rows,
                                                 "peak_rss_mb": peak_mb}, indent=2))


if __name__ == "__main__":
    main()

"""Strip rendering speed: rays per second of the ray caster, and a 2,048 x 2,048 TDI product.

Usage: python benchmarks/bench_strip.py [--quick]; writes benchmarks/out/strip.json.

1. Rays per second (texture lookup, per-face shading and a shadow ray included; one batch of
   2^20 rays per call, best and median of ``reps``) on a 513^2 and a 1025^2 vertex terrain
   mesh (2,048 m tiles, 4096^2 albedo texels), nadir view from 681 km, for the caster's
   'terrain' and 'general' paths, with the first-cast hit fraction.
2. A 2,048-line x 2,048-column TDI strip (32 stages, 8 samples per line, truth included) on
   the 1024^2 mesh: wall time.
3. Peak resident memory of 1,024 and 4,096 lines of the same strip streamed chunk by chunk
   (:func:`scene.strip.iter_strip`, chunks discarded): the peak is reset between the two
   through /proc/self/clear_refs, so both are this process's peak during that run alone.

This is a shared machine: the load average is printed beside the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from camera.geometry import FocalPlane
from camera.imager import TdiImager
from camera.linescan import imager_camera
from camera.motion import CameraModel
from orbit.attitude import Attitude, orbit_looking_at
from orbit.frames import LocalFrame
from orbit.jitter import JitterTerm
from orbit.kepler import sun_synchronous_inclination_deg
from scene.kernel import RayCaster, Renderer, Sun
from scene.pinhole import ray_keyframes
from scene.strip import iter_strip, render_strip
from scene.terrain import Terrain, fractal_noise

ROOT = Path(__file__).resolve().parents[1]
EPOCH = np.datetime64("2026-06-21T10:30:00")


def bench_terrain(dem_nodes: int, spacing_m: float, texel_m: float, seed: int) -> Terrain:
    """A (dem_nodes + 1)^2 fractal DEM (15 m RMS) under a fractal albedo (FFT synthesis:
    seconds even at 4096^2 texels)."""
    rng = np.random.default_rng(seed)
    size = dem_nodes * spacing_m
    n = int(round(size / texel_m))
    albedo = np.clip(0.3 + 0.08 * fractal_noise((n, n), 2.0, rng, 2.0), 0.02, 0.95)
    dem = 15.0 * fractal_noise((dem_nodes + 1, dem_nodes + 1), 3.5, rng, 1.0)
    return Terrain(albedo.astype(np.float32), texel_m, dem.astype(np.float32), spacing_m)


def camera(cols: int, stages: int) -> CameraModel:
    orbit = orbit_looking_at(35.0, 10.0, 681e3, sun_synchronous_inclination_deg(681e3), EPOCH)
    fp = FocalPlane(10.0, 12e-6, stages, cols)
    jit = (JitterTerm("pitch", 4.3, 0.5 * fp.ifov_rad), JitterTerm("roll", 0.65, 1.2e-6))
    return CameraModel(orbit, Attitude("nadir", yaw_steering=True, jitter=jit),
                       LocalFrame(35.0, 10.0, 0.0), fp)


def _status_mb(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def peak_rss_mb() -> float:
    """This process's peak resident memory since start or the last :func:`reset_peak`."""
    return _status_mb("VmHWM")


def reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def rays_per_s(caster: RayCaster, cam: CameraModel, imager: TdiImager, reps: int):
    """(best, median) rays/s and hit fraction of one 2^20-ray batch: 512 instants x 2048
    columns over the middle of the tile."""
    c2 = imager_camera(cam, imager)
    rate = 8296.0
    t = (np.arange(512) - 256) / rate
    kf = ray_keyframes(c2.pose(t), c2.focal_plane, np.zeros((len(t), 2)), caster.z_start_m)
    qx = (np.arange(imager.cols) + 0.5) / imager.cols - 0.5
    caster.cast_radiance(kf, qx)  # compile
    times, first, rays = [], 0, 0
    for _ in range(reps):
        t0 = time.perf_counter()
        res = caster.cast_radiance(kf, qx)
        times.append(time.perf_counter() - t0)
        first, rays = first + res.first_hits, rays + res.rays
    return res.rays / min(times), res.rays / float(np.median(times)), first / rays


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer repetitions, 512-line product")
    args = ap.parse_args()
    reps = 3 if args.quick else 5
    cols, stages, spl = 2048, 32, 8
    imager = TdiImager(cols=cols, stages=stages)
    cam = camera(cols, stages)
    sun = Sun(50.0, 140.0)
    out: dict = {"load_average_start": os.getloadavg()}
    rows = []
    sky_view = None
    for dem_nodes in (512, 1024):  # both tiles 2,048 m wide: the strip's 1.7 km fit
        t0 = time.perf_counter()
        terr = bench_terrain(dem_nodes, 2048.0 / dem_nodes, 0.5, seed=dem_nodes)
        r = Renderer(terr, sun, 8, 8, spp=1)
        build = time.perf_counter() - t0
        sky_view = None
        for path in ("terrain", "general"):
            caster = RayCaster(r, path=path, sky_view=sky_view)
            sky_view = caster.sky_view
            best, med, hit = rays_per_s(caster, cam, imager, reps)
            rows.append({"mesh": f"{dem_nodes + 1}^2", "path": path, "best_mrays_s": best / 1e6,
                         "median_mrays_s": med / 1e6, "hit_fraction": hit,
                         "scene_build_s": build, "sky_view_bake_s": caster.sky_view_s})
    out["rays"] = rows
    # the product, on the 1024^2 mesh
    caster = RayCaster(r, path="terrain", sky_view=sky_view)
    n_lines = 512 if args.quick else 2048
    t_mid = 0.0
    t0_s = t_mid - (n_lines / 2 + stages / 2) / 8296.0
    col_ids = np.arange(cols)
    reset_peak()
    t0 = time.perf_counter()
    res = render_strip(caster, imager_camera(cam, imager), imager, t0_s, n_lines, col_ids, spl)
    wall = time.perf_counter() - t0
    out["product"] = {"lines": n_lines, "cols": cols, "samples_per_line": spl,
                      "wall_s": wall, "rays": res.rays, "hit_fraction": res.hit_fraction,
                      "hits_after_recast": res.hits / res.rays,
                      "mrays_s": res.rays / wall / 1e6, "peak_rss_mb": peak_rss_mb(),
                      "line_offset_rms_px": np.sqrt(np.mean(res.line_offset_px**2, 0)).tolist()}
    mem = {}
    can_reset = True
    for n in ((256, 1024) if args.quick else (1024, 4096)):
        can_reset &= reset_peak()
        before = _status_mb("VmRSS")
        t0 = time.perf_counter()
        t0_s = -(n / 2 + stages / 2) / 8296.0
        acc = 0.0
        for ch in iter_strip(caster, imager_camera(cam, imager), imager, t0_s, n, col_ids,
                             spl):
            acc += float(ch.radiance.sum())  # use the chunk, then drop it
        mem[n] = {"wall_s": time.perf_counter() - t0, "rss_before_mb": before,
                  "peak_rss_mb": peak_rss_mb()}
    out["streamed"] = mem
    out["peak_reset_worked"] = can_reset
    out["load_average_end"] = os.getloadavg()

    print(f"load average at start {out['load_average_start'][0]:.1f}, "
          f"end {out['load_average_end'][0]:.1f} (2 cores, shared)")
    print(f"{'mesh':>8} {'path':>8} {'best Mrays/s':>13} {'median':>8} {'hit fraction':>14} "
          f"{'build s':>8} {'sky bake s':>10}")
    for row in rows:
        print(f"{row['mesh']:>8} {row['path']:>8} {row['best_mrays_s']:13.2f} "
              f"{row['median_mrays_s']:8.2f} {row['hit_fraction']:14.8f} "
              f"{row['scene_build_s']:8.1f} {row['sky_view_bake_s']:10.1f}")
    p = out["product"]
    print(f"product {p['lines']} x {p['cols']} x {p['samples_per_line']} samples: "
          f"{p['wall_s']:.1f} s ({p['mrays_s']:.2f} Mrays/s), hit fraction "
          f"{p['hit_fraction']:.8f} ({p['hits_after_recast']:.8f} after re-cast), "
          f"peak RSS {p['peak_rss_mb']:.0f} MB")
    for n, m in mem.items():
        print(f"streamed {n:5d} lines: {m['wall_s']:.1f} s, resident before "
              f"{m['rss_before_mb']:.0f} MB, peak {m['peak_rss_mb']:.0f} MB")
    dest = ROOT / "benchmarks" / "out"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "strip.json").write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()

"""Benchmarks of `imc design`: its search's speed, its predictors against full runs of the
bundled scenarios, and the correlator efficiency the tracker predictor uses. Prints the
figures (and writes them under benchmarks/out/design/); never asserted in a test.

    # the search: candidates per second (target: >= 10,000 candidates in <= 60 s, 2 cores)
    PYTHONPATH=. .venv/bin/python benchmarks/bench_design.py [--workers 2]
    # the same on both bundled designs (each free bandwidth range densified to >= 10,000
    # candidates), 1 and 2 workers, each evaluation in its own process (wall and CPU s,
    # the workers' included, the load before and after), against another tree's code
    # (e.g. a copy of main: `git archive main | tar -x -C /tmp/base`) run alternately,
    # the two trees' predictions, feasible sets, Pareto fronts and choices compared
    PYTHONPATH=. .venv/bin/python benchmarks/bench_design.py --speed --workers 1 2 \
        --compare /tmp/base
    # predicted against measured on the bundled scenarios (runs what --runs lacks)
    PYTHONPATH=. .venv/bin/python benchmarks/bench_design.py --bundled --runs DIR
    # the correlator's efficiency on scene classes and SNRs outside the bundled scenarios
    PYTHONPATH=. .venv/bin/python benchmarks/bench_design.py --calibrate texture
    # its dependence on the block size (a 256 px tracker, 32-96 px blocks, SNR 20)
    PYTHONPATH=. .venv/bin/python benchmarks/bench_design.py --calibrate rendered \
        --classes procedural --snrs 20 --blocks 32 48 64 96 --tracker-px 256
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from pathlib import Path

import numpy as np
import yaml

from imc.workflow.design import choose, evaluate, load_design, pareto_front, within_target

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "out" / "design"

#: the bundled scenarios the predictors are judged on, and those only reported
JUDGED = ("quickstart", "long_stare", "wheel_khz", "ikonos_tdi_scan", "ikonos_tdi_jitter",
          "no_stage")
REPORTED = ("optical", "flight_test", "seed_device", "wheel_unknown")
# ------------------------------------------------------------------------------ calibration

#: the calibration's scene classes and tracker SNRs: outside the bundled scenarios (their
#: scenes are the procedural tile), so the efficiency is not fitted to what it is judged on
CAL_CLASSES = ("urban", "rural", "mountain")
CAL_SNRS = (10.0, 20.0, 40.0)
CAL_SEEDS = (101, 202)


def calibration_case(kind: str, snr: float, fidelity: str, seed: int = 101,
                     block_px: int = 48, tracker_px: int = 128) -> dict:
    """A calibration scenario: the quickstart's camera and loop on a scene class, no jitter
    (the residual is the tracker's noise through the loop), a ``tracker_px`` square tracker
    (128; 256: a 512 m tile) with 4 blocks of ``block_px`` (48), 0.6 s, the tracker's SNR
    (additive noise) as given."""
    d = yaml.safe_load((ROOT / "scenarios" / "quickstart.yaml").read_text())
    d.pop("expect")
    d.update(name=f"cal_{kind}_{snr:g}_{block_px}_{tracker_px}", seed=seed, duration_s=0.6)
    d["attitude"]["jitter"] = {"sinusoids": []}
    d["scene"].update(kind=kind, size_m=300 if tracker_px <= 128 else 512, texel_m=0.5)
    d["scene"].pop("relief_rms_m", None)
    d["camera"]["tracker"].update(rows=tracker_px, cols=tracker_px, mean_signal_dn=100,
                                  noise_sigma_dn=100.0 / snr)
    d["correlator"].update(block_px=block_px, n_blocks=4)
    d["plant"] = {"fidelity": fidelity}
    d["metrics"]["blur_images"] = False
    return d


def calibrate(fidelity: str, out: Path, classes=CAL_CLASSES, snrs=CAL_SNRS,
              seeds=CAL_SEEDS, blocks=(48,), tracker_px: int = 128) -> dict:
    """The correlator's efficiency on the calibration cases: per case the tracker's measured
    error over the predictor's bound (``predicted_sigma_px``, per block) and the loop's
    residual over the predictor's noise residual at efficiency 1 (noise gain x bound /
    sqrt(blocks)); their mean and spread, and with several ``blocks`` sizes the exponent of
    the loop's efficiency against the block's side (:func:`block_exponent`)."""
    from imc.pipeline import run_scenario
    from imc.scenario import parse_scenario
    from imc.workflow.predict import predict_scenario

    rows = []
    for kind, snr, seed, bp in itertools.product(classes, snrs, seeds, blocks):
        sc = parse_scenario(calibration_case(kind, snr, fidelity, seed, bp, tracker_px))
        p = predict_scenario(sc, fidelity, efficiency=1.0)  # the bound itself
        t0 = time.perf_counter()
        m, _ = run_scenario(sc, out / f"{kind}_{snr:g}_{seed}_{bp}_{tracker_px}", rerun=False)
        crlb = np.array(p["parts"]["crlb_px"])
        trk = np.array(m["tracker"]["rms_error_px"], float)
        loop = np.array(m["with_compensation"]["rms_px"], float)
        rows.append({"kind": kind, "snr": snr, "seed": seed, "block_px": bp,
                     "tracker_px": tracker_px, "crlb_px": crlb.tolist(),
                     "run_median_crlb_px": m["tracker"]["median_crlb_px"],
                     "tracker_rms_px": trk.tolist(),
                     "valid_fraction": m["tracker"]["valid_fraction"],
                     "residual_px": loop.tolist(),
                     "predicted_residual_px": p["with_compensation.rms_px"],
                     "tracker_efficiency": (trk / crlb).tolist(),
                     "loop_efficiency": (loop / np.array(
                         p["with_compensation.rms_px"])).tolist(),
                     "run_s": time.perf_counter() - t0})
        r = rows[-1]
        print(f"{fidelity} {kind:9s} SNR {snr:4g} seed {seed} {bp} px on {tracker_px} px: "
              f"bound {crlb.mean():.4f} px, tracker "
              f"{trk.mean():.4f} px (x{np.mean(r['tracker_efficiency']):.2f}), residual "
              f"{loop.mean():.4f} px (x{np.mean(r['loop_efficiency']):.2f}), valid "
              f"{r['valid_fraction']:.2f}, {r['run_s']:.0f} s", flush=True)
    summary = {}
    for key in ("tracker_efficiency", "loop_efficiency"):
        v = np.array([x for r in rows for x in r[key] if np.isfinite(x)])
        summary[key] = {"mean": float(v.mean()), "std": float(v.std(ddof=1)),
                        "min": float(v.min()), "max": float(v.max()), "n": int(v.size)}
    if len(set(blocks)) > 1:
        summary["block_exponent"] = block_exponent(rows)
    return {"fidelity": fidelity, "cases": rows, "summary": summary}


def block_exponent(rows: list[dict], reference_px: int = 48) -> dict:
    """The loop efficiency's power law in the block's side, ``(b / reference_px)^gamma``:
    each case's efficiency (both axes' mean) over its own (kind, SNR, seed, tracker) group's
    at ``reference_px`` (so the scene, seed and SNR cancel), least squares in log-log through
    the origin; gamma, its standard error and the ratios per block size."""
    ref = {(r["kind"], r["snr"], r["seed"], r["tracker_px"]): np.mean(r["loop_efficiency"])
           for r in rows if r["block_px"] == reference_px}
    x, y, per = [], [], {}
    for r in rows:
        key = (r["kind"], r["snr"], r["seed"], r["tracker_px"])
        if key not in ref or r["block_px"] == reference_px:
            continue
        ratio = float(np.mean(r["loop_efficiency"]) / ref[key])
        x.append(np.log(r["block_px"] / reference_px))
        y.append(np.log(ratio))
        per.setdefault(int(r["block_px"]), []).append(ratio)
    x, y = np.array(x), np.array(y)
    if x.size < 2:
        return {"gamma": 0.0, "se": float("nan"), "ratios": per}
    gamma = float(x @ y / (x @ x))
    res = y - gamma * x
    se = float(np.sqrt(res @ res / max(x.size - 1, 1) / (x @ x)))
    return {"gamma": gamma, "se": se, "reference_px": reference_px,
            "ratios": {b: [float(v) for v in vals] for b, vals in sorted(per.items())}}


# ------------------------------------------------------------------------------ bundled


def judge(kind: str, predicted: float, measured: float) -> tuple[bool | None, str]:
    """Whether a prediction meets its target (:func:`imc.workflow.design.within_target`;
    None: no target, reported), and the error as printed. ``kind``: rms, mtf (values are
    losses, 1 - MTF), geometry or niirs."""
    if not (math.isfinite(predicted) and math.isfinite(measured)):
        return False, "n/a"
    if kind == "geometry":
        ok = within_target("product.geometry.open.after.rms_px", predicted, measured)
        return ok, f"x{predicted / measured:.2f}" if measured > 0 else "n/a"
    if kind == "mtf":
        ok = within_target("with_compensation.mtf_nyquist_worst", 1 - predicted, 1 - measured)
    elif kind == "rms":
        ok = within_target("with_compensation.rms_px", predicted, measured)
    else:
        ok = None
    err = abs(predicted - measured)
    pct = 100 * err / max(abs(measured), 1e-12)
    return ok, f"{err:.4f} ({pct:.0f} %)"


def measured_metrics(name: str, runs: Path, run_missing: bool) -> dict | None:
    """The metrics.json of a bundled scenario's run under ``runs``, run if missing."""
    path = runs / name / "metrics.json"
    if not path.exists():
        if not run_missing:
            return None
        from imc.pipeline import run_scenario
        from imc.scenario import load_scenario

        run_scenario(load_scenario(ROOT / "scenarios" / f"{name}.yaml"), runs / name,
                     rerun=False)
    return json.loads(path.read_text())


def bundled_rows(name: str, metrics: dict, fidelity: str | None = None) -> list[dict]:
    """Predicted against measured per judged metric and axis for one scenario (the
    correlator efficiency of ``fidelity``; default: the scenario's plant's)."""
    from imc.scenario import load_scenario
    from imc.workflow.predict import predict_scenario

    sc = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    t0 = time.perf_counter()
    p = predict_scenario(sc, fidelity)
    pred_s = time.perf_counter() - t0
    rows = []
    w = metrics["with_compensation"]
    for ax, axis in enumerate(("row", "col")):
        rows.append(("rms", f"residual RMS {axis} px", p["with_compensation.rms_px"][ax],
                     w["rms_px"][ax]))
        rows.append(("mtf", f"motion MTF loss {axis}",
                     1.0 - p["with_compensation.mtf_nyquist_worst"][ax],
                     1.0 - w["mtf_nyquist_worst"][ax]))
    geo = metrics.get("product", {}).get("geometry", {}).get("open")
    if geo is not None:
        for ax, axis in enumerate(("row", "col")):
            rows.append(("geometry", f"geometry after a constant {axis} px",
                         p["product.geometry.open.after.rms_px"][ax],
                         geo["after"]["rms_px"][ax]))
            rows.append(("geometry", f"geometry after an affine {axis} px",
                         p["product.geometry.open.affine.rms_px"][ax],
                         geo["affine"]["rms_px"][ax]))
    quality = metrics.get("product", {}).get("quality")
    if quality is not None:
        for version in ("closed", "open"):
            if version in quality and quality[version].get("niirs_loss") is not None:
                rows.append(("niirs", f"NIIRS loss, {version} product",
                             p[f"product.quality.{version}.niirs_loss"],
                             quality[version]["niirs_loss"]))
    out = []
    for kind, what, pv, mv in rows:
        ok, err = judge(kind, float(pv), float(mv))
        out.append({"scenario": name, "metric": what, "kind": kind, "predicted": float(pv),
                    "measured": float(mv), "error": err, "meets": ok, "predict_s": pred_s,
                    "efficiency": p["parts"]["efficiency"]})
    return out


def bundled(runs: Path, run_missing: bool, names=JUDGED + REPORTED,
            fidelity: str | None = None) -> list[dict]:
    """Every bundled scenario's rows (those of REPORTED marked not judged)."""
    rows = []
    for name in names:
        try:
            metrics = measured_metrics(name, runs, run_missing)
        except Exception as e:  # noqa: BLE001 - a scenario that cannot run is reported
            print(f"{name}: not run ({e})")
            continue
        if metrics is None:
            print(f"{name}: no run under {runs} (give --run-missing)")
            continue
        try:
            new = bundled_rows(name, metrics, fidelity)
        except Exception as e:  # noqa: BLE001 - no predictor (a measured series, yaw)
            print(f"{name}: no prediction ({str(e)[:150]})")
            continue
        for r in new:
            r["judged"] = name in JUDGED
        rows += new
    return rows


def table(rows: list[dict]) -> str:
    """The rows as a markdown table."""
    lines = ["| scenario | metric | predicted | measured | error | target |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        verdict = "reported"
        if r["judged"] and r["meets"] is not None:
            verdict = "met" if r["meets"] else "MISSED"
        lines.append(f"| {r['scenario']} | {r['metric']} | {r['predicted']:.4g} | "
                     f"{r['measured']:.4g} | {r['error']} | {verdict} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------ speed

#: what one speed measurement runs in a fresh process of a tree (its code on PYTHONPATH):
#: the design, its bandwidth range densified until it has at least MIN candidates, one
#: evaluate; prints a JSON line (times, load) and saves the results (NPZ) to compare
_SPEED_CHILD = r"""
import dataclasses, json, os, resource, sys, time
import numpy as np
from imc.workflow.design import (RangeConfig, _values, choose, evaluate, load_design,
                                 loop_choices, pareto_front)
path, workers, min_n, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
crlb = None if sys.argv[5] == "none" else float(sys.argv[5])
d = load_design(path)
def count(free):
    per = len(free.block_px) * len(free.n_blocks) * len(free.ground)
    k = len(_values(free.piezo_stroke_px))
    return sum(per * (k if ch.stage == "piezo" else 1) for ch in loop_choices(free))
free = d.config.free
bw = free.bandwidth_hz
while count(free) < min_n:  # the bandwidths denser, the same span
    v = _values(bw)
    bw = RangeConfig(min=min(v), max=max(v), n=len(v) + 1,
                     scale=bw.scale if isinstance(bw, RangeConfig) else "log")
    free = free.model_copy(update={"bandwidth_hz": bw})
d = dataclasses.replace(d, config=d.config.model_copy(update={"free": free}))
load0 = os.getloadavg()[0]
c0, t0 = time.process_time(), time.perf_counter()
c = evaluate(d, crlb_px=crlb, workers=workers)
wall = time.perf_counter() - t0
cpu = time.process_time() - c0
kids = resource.getrusage(resource.RUSAGE_CHILDREN)
me = resource.getrusage(resource.RUSAGE_SELF)
front = pareto_front(c.cost, c.worst)
chosen, _ = choose(c, d.config.margin)
np.savez(out, feasible=c.feasible, worst=c.worst, cost=c.cost, front=front,
         chosen=-1 if chosen is None else chosen, limiting=c.limiting.astype(str),
         **{"p:" + k: v for k, v in c.predicted.items()})
print(json.dumps({"n": len(c), "loops": c.n_loops, "wall_s": wall, "cpu_s": cpu,
                  "cpu_children_s": kids.ru_utime + kids.ru_stime, "loop_s": c.loop_s,
                  "sys_s": me.ru_stime, "sys_children_s": kids.ru_stime,
                  "max_rss_mb": me.ru_maxrss / 1024, "max_rss_children_mb": kids.ru_maxrss / 1024,
                  "base_s": getattr(c, "base_s", None), "feasible": int(c.feasible.sum()),
                  "front": len(front), "chosen": chosen, "load_before": load0,
                  "load_after": os.getloadavg()[0], "bandwidths": len(_values(bw))}))
"""


def speed_run(tree: Path, design: str, workers: int, min_n: int, out: Path,
              crlb_px: float | None) -> dict:
    """One evaluation of a bundled design (``design``: its file's stem) in a fresh process
    with ``tree``'s code: the child's JSON line (wall and CPU s, the workers' CPU, load)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(tree), RERUN_TELEMETRY_ENABLED="0")
    path = tree / "scenarios" / "designs" / f"{design}.yaml"
    res = subprocess.run([sys.executable, "-c", _SPEED_CHILD, str(path), str(workers),
                          str(min_n), str(out), "none" if crlb_px is None else str(crlb_px)],
                         env=env, cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def same_results(a: Path, b: Path) -> dict:
    """Two speed runs' results compared: the largest relative difference of any predicted
    value, and whether the feasible sets, limits, Pareto fronts and choices are equal."""
    x, y = np.load(a), np.load(b)
    rel = 0.0
    for k in x.files:
        if k.startswith("p:"):
            u, v = x[k], y[k]
            if not np.array_equal(np.isfinite(u), np.isfinite(v)):
                return {"identical": False, "why": f"{k}: finite where the other is not"}
            f = np.isfinite(v) & (v != 0)
            if f.any():
                rel = max(rel, float(np.max(np.abs(u[f] - v[f]) / np.abs(v[f]))))
    eq = {k: bool(np.array_equal(x[k], y[k])) for k in ("feasible", "limiting", "front",
                                                        "chosen", "cost")}
    return {"max_relative_difference": rel, **eq, "identical": all(eq.values())}


def speed(designs: list[str], workers: list[int], min_n: int, compare: Path | None,
          crlb_px: float | None) -> list[dict]:
    """Each design x workers evaluated with this tree's code and, alternately, with
    ``compare``'s; printed as they come."""
    trees = [("this", ROOT)] + ([("compare", compare)] if compare is not None else [])
    rows = []
    for design, nw in itertools.product(designs, workers):
        pair = {}
        for name, tree in trees:
            out = OUT / f"speed_{design}_{nw}_{name}.npz"
            r = speed_run(tree, design, nw, min_n, out, crlb_px)
            r.update(design=design, workers=nw, tree=name, path=str(tree))
            pair[name] = out
            rows.append(r)
            print(f"{design} {name} ({tree}), {nw} worker(s): {r['n']} candidates "
                  f"({r['loops']} loops) in {r['wall_s']:.1f} s wall, "
                  f"{r['cpu_s'] + r['cpu_children_s']:.1f} s CPU ({r['cpu_children_s']:.1f} "
                  f"in workers; system {r['sys_s'] + r['sys_children_s']:.1f}), peak RSS "
                  f"{r['max_rss_mb']:.0f} MB (a worker's {r['max_rss_children_mb']:.0f}): "
                  f"{r['n'] / r['wall_s']:.0f} candidates/s; load "
                  f"{r['load_before']:.1f} -> {r['load_after']:.1f}; {r['feasible']} "
                  f"feasible, front {r['front']}, chosen {r['chosen']}", flush=True)
        if compare is not None:
            a, b = rows[-2], rows[-1]
            cmp = same_results(pair["this"], pair["compare"])
            a["versus_compare"] = {"wall_ratio": b["wall_s"] / a["wall_s"], "cpu_ratio": (
                b["cpu_s"] + b["cpu_children_s"]) / (a["cpu_s"] + a["cpu_children_s"]), **cmp}
            print(f"  -> {design}, {nw} worker(s): compare / this: wall x"
                  f"{a['versus_compare']['wall_ratio']:.1f}, CPU x"
                  f"{a['versus_compare']['cpu_ratio']:.1f}; results {cmp}", flush=True)
    return rows


#: one side of the bound's equivalence in a fresh process: the base's frame 0 from the
#: whole tile ('whole': build_models + base_image, what the search did) or from the
#: albedo under the footprint ('footprint': bound_frame0), then the bound per block size
_BOUND_CHILD = r"""
import json, os, resource, sys, time
import numpy as np
from imc.workflow.design import load_design
from imc.workflow.predict import bound_frame0, tracker_bound, tracker_bounds
path, how, out = sys.argv[1], sys.argv[2], sys.argv[3]
d = load_design(path)
fid = d.config.verify.fidelity
load0 = os.getloadavg()[0]
c0, t0 = time.process_time(), time.perf_counter()
if how == "whole":
    from imc.wiring.build import build_models
    from imc.wiring.rendered_plant import base_image
    m = build_models(d.base)
    rad = base_image(m, 0)
else:
    m, rad = bound_frame0(d.base, fid)
scene_cpu = time.process_time() - c0
table = tracker_bounds(m, d.config.free.block_px, fid, radiance=rad)
crlb, kept = tracker_bound(m, fid, radiance=rad)
me = resource.getrusage(resource.RUSAGE_SELF)
np.save(out, rad)
print(json.dumps({"how": how, "wall_s": time.perf_counter() - t0,
                  "cpu_s": time.process_time() - c0, "scene_cpu_s": scene_cpu,
                  "user_s": me.ru_utime, "sys_s": me.ru_stime,
                  "max_rss_mb": me.ru_maxrss / 1024, "load_before": load0,
                  "load_after": os.getloadavg()[0],
                  "bounds": {str(k): list(v) for k, v in table.items()},
                  "base_bound": [float(x) for x in crlb], "base_kept": kept}))
"""


def bound_equivalence(designs: list[str]) -> list[dict]:
    """The tracker's bound per block size (and the record's base bound) of each bundled
    design from frame 0 made on the whole tile and on the albedo under the footprint only
    (:func:`imc.workflow.predict.bound_frame0`), each in a fresh process: their CPU time,
    peak RSS, and the largest relative difference of the bounds."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(ROOT), RERUN_TELEMETRY_ENABLED="0")
    rows = []
    for design in designs:
        path = ROOT / "scenarios" / "designs" / f"{design}.yaml"
        got = {}
        for how in ("footprint", "whole"):
            out = OUT / f"frame0_{design}_{how}.npy"
            res = subprocess.run([sys.executable, "-c", _BOUND_CHILD, str(path), how,
                                  str(out)], env=env, cwd=ROOT, capture_output=True,
                                 text=True, check=True)
            got[how] = json.loads(res.stdout.strip().splitlines()[-1])
            r = got[how]
            print(f"{design} {how}: {r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU (the "
                  f"scene and frame 0 {r['scene_cpu_s']:.1f}; process user {r['user_s']:.1f}"
                  f" + system {r['sys_s']:.1f}), peak RSS {r['max_rss_mb']:.0f} MB, load "
                  f"{r['load_before']:.1f} -> {r['load_after']:.1f}; bound per block size "
                  + ", ".join(f"{k} px {v[0]:.6f} (valid {v[1]:.4f})"
                              for k, v in r["bounds"].items()), flush=True)
        a, b = got["footprint"], got["whole"]
        rel = max([abs(a["bounds"][k][0] / b["bounds"][k][0] - 1.0) for k in b["bounds"]]
                  + [abs(x / y - 1.0) for x, y in zip(a["base_bound"], b["base_bound"],
                                                     strict=True)])
        same = bool(np.array_equal(np.load(OUT / f"frame0_{design}_footprint.npy"),
                                   np.load(OUT / f"frame0_{design}_whole.npy")))
        print(f"  -> {design}: frame 0 bit-identical {same}; largest relative difference of "
              f"the bounds {rel:.1e}; p_valid equal "
              f"{all(a['bounds'][k][1] == b['bounds'][k][1] for k in b['bounds'])}; "
              f"CPU whole / footprint x{b['cpu_s'] / a['cpu_s']:.1f}, peak RSS "
              f"x{b['max_rss_mb'] / a['max_rss_mb']:.1f}", flush=True)
        rows.append({"design": design, "footprint": a, "whole": b, "frame0_identical": same,
                     "max_relative_difference": rel})
    return rows


# ------------------------------------------------------------------------------ main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--design", default=str(ROOT / "scenarios" / "designs" /
                                            "quickstart_frame.yaml"))
    ap.add_argument("--workers", type=int, nargs="*", default=[2])
    ap.add_argument("--bounds", action="store_true", help="the tracker's bound per block "
                    "size on the whole tile against the footprint's albedo (--designs)")
    ap.add_argument("--speed", action="store_true", help="the search's speed on the bundled "
                    "designs (--designs), each in its own process, against --compare")
    ap.add_argument("--designs", nargs="*", default=["quickstart_frame",
                                                     "smallsat_pushbroom"])
    ap.add_argument("--min-candidates", type=int, default=10000)
    ap.add_argument("--compare", default=None, help="another tree (its code on PYTHONPATH: "
                    "e.g. a copy of main) to time alternately and compare results with")
    ap.add_argument("--crlb-px", type=float, default=None,
                    help="the tracker's bound per block (default: from the base scene)")
    ap.add_argument("--bundled", action="store_true", help="predicted against measured on "
                    "the bundled scenarios")
    ap.add_argument("--runs", default=str(OUT / "runs"), help="the bundled scenarios' runs "
                    "(one folder each, named as the scenario)")
    ap.add_argument("--run-missing", action="store_true", help="run what --runs lacks")
    ap.add_argument("--only", nargs="*", default=None, help="these bundled scenarios only")
    ap.add_argument("--efficiency-of", default=None, help="predict with this plant's "
                    "correlator efficiency (default: each scenario's plant's)")
    ap.add_argument("--calibrate", choices=("texture", "rendered"), default=None,
                    help="the correlator's efficiency on the calibration cases")
    ap.add_argument("--classes", nargs="*", default=list(CAL_CLASSES))
    ap.add_argument("--snrs", nargs="*", type=float, default=list(CAL_SNRS))
    ap.add_argument("--seeds", nargs="*", type=int, default=list(CAL_SEEDS))
    ap.add_argument("--blocks", nargs="*", type=int, default=[48], help="the calibration's "
                    "block sizes, px (several: the efficiency's exponent in the block size)")
    ap.add_argument("--tracker-px", type=int, default=128, help="the calibration tracker's "
                    "side, px (256: a 512 m tile)")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    if args.calibrate:
        res = calibrate(args.calibrate, OUT / f"cal_{args.calibrate}", args.classes,
                        args.snrs, args.seeds, args.blocks, args.tracker_px)
        tag = "" if args.blocks == [48] else "_blocks"
        (OUT / f"efficiency_{args.calibrate}{tag}.json").write_text(json.dumps(res, indent=1))
        for k, s in res["summary"].items():
            if k == "block_exponent":
                print(f"block exponent: {s['gamma']:.3f} +- {s['se']:.3f}, ratios to "
                      f"{s.get('reference_px', 48)} px: {s['ratios']}")
                continue
            print(f"{k}: {s['mean']:.3f} +- {s['std']:.3f} (min {s['min']:.3f}, max "
                  f"{s['max']:.3f}, n {s['n']})")
        return
    if args.bundled:
        rows = bundled(Path(args.runs), args.run_missing,
                       tuple(args.only) if args.only else JUDGED + REPORTED,
                       args.efficiency_of)
        (OUT / "bundled.json").write_text(json.dumps(rows, indent=1))
        print(table(rows))
        judged = [r for r in rows if r["judged"] and r["meets"] is not None]
        print(f"judged: {sum(r['meets'] for r in judged)} of {len(judged)} within target")
        return
    if args.bounds:
        rows = bound_equivalence(args.designs)
        (OUT / "bounds.json").write_text(json.dumps(rows, indent=1))
    if args.speed:
        rows = speed(args.designs, args.workers, args.min_candidates,
                     Path(args.compare) if args.compare else None, args.crlb_px)
        (OUT / "speed.json").write_text(json.dumps(rows, indent=1))
        return
    d = load_design(args.design)
    t0, c0 = time.perf_counter(), time.process_time()
    c = evaluate(d, crlb_px=args.crlb_px, workers=args.workers[0])
    t_eval = time.perf_counter() - t0
    front = pareto_front(c.cost, c.worst)
    chosen, why = choose(c, d.config.margin)
    print(f"{d.config.name}: {len(c)} candidates ({c.n_loops} loops, {args.workers[0]} "
          f"workers) in {t_eval:.1f} s (the loops' predictions in at {c.loop_s:.1f} s; the "
          f"base's models and bounds {c.base_s:.1f} s, overlapping them): "
          f"{len(c) / t_eval:.0f} candidates/s; {time.process_time() - c0:.1f} CPU s in this "
          f"process (workers not counted); {int(c.feasible.sum())} feasible, "
          f"{len(front)} on the Pareto front")
    if chosen is not None:
        print(f"chosen: {c.row(chosen)['cost']:.3g} cost, margin {c.worst[chosen]:.2f} ({why})")


if __name__ == "__main__":
    main()

"""The sweep engine's benchmark: Dask speed-up, per-point overhead, kill -9 and restart, and
the 1,000-point analytic sweep.

    .venv/bin/python benchmarks/bench_sweep.py [--quick] [--out benchmarks/out/sweep]

Writes sweep.json and sweep.md (the table quoted in docs/benchmarks.md). Figures are measured here,
never asserted in tests. About 20 minutes on 2 cores (--quick: without the 1,000 points,
~8 minutes). The machine's other load shows in every figure: run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imc.io import atomic_write, write_json  # noqa: E402
from imc.workflow.distribute import runner  # noqa: E402
from imc.workflow.sweep import SweepConfig, expand, load_sweep, run_sweep  # noqa: E402

IMC = str(Path(sys.executable).parent / "imc")
SWEEP_1000 = ROOT / "scenarios" / "sweeps" / "analytic_1000.yaml"
ENV = {**os.environ, "RERUN_TELEMETRY_ENABLED": "0"}


def small_sweep(n_gain: int, n_freq: int, duration_s: float, name: str) -> SweepConfig:
    """The 1,000-point sweep's base cut to n_gain x n_freq points of ``duration_s``."""
    spec = yaml.safe_load(SWEEP_1000.read_text())
    spec["base"] = str(SWEEP_1000.parent / spec["base"])
    spec["name"] = name
    spec["set"]["duration_s"] = duration_s
    spec["axes"] = {"compensation.controller.gain": {"log": [0.05, 0.9, n_gain]},
                    "attitude.jitter.sinusoids.0.frequency_hz": {"log": [0.3, 8.0, n_freq]}}
    return SweepConfig.model_validate(spec)


def write_sweep_file(cfg: SweepConfig, path: Path) -> Path:
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
    return path


# ------------------------------------------------------------------------------ speed


def timed_sweep(cfg: SweepConfig, out: Path, workers: int) -> dict:
    """One sweep in this process's client: cluster start, sweep wall time, the points' own
    run times."""
    sw = expand(cfg)
    t0 = time.perf_counter()
    with runner(workers, memory_limit="4GiB") as r:
        t1 = time.perf_counter()
        s = run_sweep(sw, out, r)
        t2 = time.perf_counter()
    recs = [json.loads(p.read_text()) for p in (out / "points").glob("*.json")]
    run_s = [r["run_wall_s"] for r in recs if "run_wall_s" in r]
    n = len(sw.points)
    return {"workers": workers, "points": n, "failed": s.failed, "start_s": t1 - t0,
            "sweep_s": t2 - t1, "total_s": time.perf_counter() - t0,
            "points_per_hour": 3600.0 * n / (t2 - t1),
            "points_per_hour_with_start": 3600.0 * n / (t2 - t0),
            "mean_run_s": sum(run_s) / max(len(run_s), 1),
            "overhead_per_point_s": (t2 - t1) * max(workers, 1) / n
            - sum(run_s) / max(len(run_s), 1)}


_HALF = """
import json, sys, time
sys.path.insert(0, {bench!r})
from bench_sweep import small_sweep
from imc.workflow.sweep import expand, run_point
points = expand(small_sweep({g}, {f}, 2.0, "speed")).points[{part}::2]
run_point(points[0].scenario, {work!r} + "/warm", False)  # imports, first-run caches
t = time.perf_counter()
for p in points:
    run_point(p.scenario, {work!r} + "/p", False)
print(json.dumps({{"n": len(points), "s": time.perf_counter() - t}}))
"""


def two_processes(tmp: Path, g: int, f: int) -> dict:
    """The machine's own scaling for this work, no Dask: two plain processes, each warmed
    up, each running half of the points one after another, at the same time."""
    procs = [subprocess.Popen([sys.executable, "-c", _HALF.format(
        bench=str(ROOT / "benchmarks"), g=g, f=f, part=i, work=str(tmp / f"half{i}"))],
        stdout=subprocess.PIPE, text=True, env=ENV) for i in (0, 1)]
    outs = [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]
    n = sum(o["n"] for o in outs)
    wall = max(o["s"] for o in outs)
    return {"points": n, "sweep_s": wall, "points_per_hour": 3600.0 * n / wall}


def speed(tmp: Path, log) -> dict:
    """Serial (in process, warmed up) against 2 single-threaded workers (warmed up at the
    cluster's start) on the same 48 points; the per-point overhead with 1 worker and in
    process; and two plain processes (no Dask) as the machine's own bound."""
    g, f = 8, 6
    cfg = small_sweep(g, f, 2.0, "speed")
    from imc.workflow.sweep import run_point

    run_point(expand(cfg).points[0].scenario, str(tmp / "warm"), False)  # as the workers
    res = {}
    for label, w in (("serial", 0), ("dask_1", 1), ("dask_2", 2)):
        res[label] = timed_sweep(cfg, tmp / label, w)
        log(f"  {label}: {res[label]['points']} points in {res[label]['sweep_s']:.1f} s "
            f"(+{res[label]['start_s']:.1f} s start), {res[label]['points_per_hour']:.0f} "
            f"points/h; mean run {res[label]['mean_run_s']:.2f} s, overhead "
            f"{res[label]['overhead_per_point_s']:.3f} s/point")
    res["two_processes"] = two_processes(tmp, g, f)
    log(f"  two plain processes (no Dask): {res['two_processes']['points']} points in "
        f"{res['two_processes']['sweep_s']:.1f} s, "
        f"{res['two_processes']['points_per_hour']:.0f} points/h")
    res["speedup_two_processes_vs_serial"] = (res["two_processes"]["points_per_hour"]
                                              / res["serial"]["points_per_hour"])
    res["speedup_2_vs_serial"] = (res["dask_2"]["points_per_hour"]
                                  / res["serial"]["points_per_hour"])
    res["speedup_2_vs_serial_with_start"] = (res["dask_2"]["points_per_hour_with_start"]
                                             / res["serial"]["points_per_hour_with_start"])
    return res


# ------------------------------------------------------------------------------ kill -9


def _points(out: Path) -> dict[str, float]:
    d = out / "points"
    return {p.stem: p.stat().st_mtime_ns for p in d.glob("*.json")} if d.exists() else {}


def _tree(pid: int) -> list[psutil.Process]:
    try:
        p = psutil.Process(pid)
        return [p, *p.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def kill_trial(sweep_file: Path, out: Path, delay_s: float, target: str, log) -> dict:
    """Start `imc sweep` (2 workers), kill -9 the client (or one worker) after delay_s, then
    run it again to the end: every point exactly once, none rerun."""
    n = len(load_sweep(sweep_file).points)
    cmd = [IMC, "sweep", str(sweep_file), "--out", str(out), "--workers", "2", "--no-report"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=ENV, start_new_session=True)
    time.sleep(delay_s)
    tree = _tree(proc.pid)
    before_kill = _points(out)
    orphans = 0
    if target == "client":
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        time.sleep(3.0)
        alive = [p for p in tree[1:] if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
        orphans = len(alive)
        for p in alive:  # what the kill left: the cluster's processes
            p.kill()
        rc_first = -9
    else:
        workers = [p for p in tree[1:] if "spawn_main" in " ".join(p.cmdline())
                   and "resource_tracker" not in " ".join(p.cmdline())]
        victim = workers[-1] if workers else tree[-1]
        victim.kill()
        rc_first = proc.wait()
    after_first = _points(out)
    t0 = time.perf_counter()
    second = subprocess.run(cmd, capture_output=True, text=True, env=ENV)
    rerun_s = time.perf_counter() - t0
    final = _points(out)
    digests = {p.digest for p in load_sweep(sweep_file).points}
    rerun_points = [d for d in after_first if final.get(d) != after_first[d]]
    res = {"target": target, "delay_s": delay_s, "points": n,
           "done_at_kill": len(before_kill), "done_after_first_call": len(after_first),
           "first_exit_code": rc_first, "orphan_processes": orphans,
           "second_exit_code": second.returncode, "second_s": rerun_s,
           "final_points": len(final), "exactly_once": set(final) == digests
           and not rerun_points and len(final) == n, "points_rerun": len(rerun_points),
           "stray_tmp_files": len(list((out / "points").glob(".*")))}
    log(f"  kill -9 {target} at {delay_s:.1f} s: {res['done_after_first_call']} of {n} done, "
        f"{orphans} orphans; restart {rerun_s:.1f} s -> {len(final)} points, exactly once: "
        f"{res['exactly_once']}")
    return res


def kills(tmp: Path, log, seed: int = 14) -> list[dict]:
    rng = random.Random(seed)
    cfg = small_sweep(6, 5, 0.5, "kill")
    f = write_sweep_file(cfg, tmp / "kill.yaml")
    trials = []
    for i, target in enumerate(("client", "client", "client", "worker")):
        trials.append(kill_trial(f, tmp / f"kill{i}", rng.uniform(8.0, 25.0), target, log))
    return trials


# ------------------------------------------------------------------------------ 1,000 points


def big(tmp: Path, log) -> dict:
    """The 1,000-point analytic sweep through `imc sweep --workers 2`: wall time and the
    peak memory of the client and its workers together (psutil, every 0.5 s)."""
    out = tmp / "big"
    cmd = [IMC, "sweep", str(SWEEP_1000), "--out", str(out), "--workers", "2"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            env=ENV, text=True)
    peak = {"total": 0, "largest": 0}
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            rss = []
            for p in _tree(proc.pid):
                try:
                    rss.append(p.memory_info().rss)
                except psutil.NoSuchProcess:
                    pass
            peak["total"] = max(peak["total"], sum(rss))
            peak["largest"] = max([peak["largest"], *rss])
            stop.wait(0.5)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    stdout, _ = proc.communicate()
    stop.set()
    th.join()
    wall = time.perf_counter() - t0
    recs = [json.loads(p.read_text()) for p in (out / "points").glob("*.json")]
    ok = sum(r["status"] == "ok" for r in recs)
    run_s = [r["run_wall_s"] for r in recs if "run_wall_s" in r]
    res = {"points": len(recs), "ok": ok, "exit_code": proc.returncode, "wall_s": wall,
           "points_per_hour": 3600.0 * len(recs) / wall,
           "mean_run_s": sum(run_s) / max(len(run_s), 1),
           "peak_rss_total_mb": peak["total"] / 1e6,
           "peak_rss_largest_process_mb": peak["largest"] / 1e6,
           "results_nc_kb": (out / "results.nc").stat().st_size / 1e3,
           "report": str(out / "report.html"), "last_line": stdout.strip().splitlines()[-1]}
    log(f"  1,000 points: {wall:.0f} s ({res['points_per_hour']:.0f} points/h), {ok} ok, "
        f"peak memory {res['peak_rss_total_mb']:.0f} MB (all processes), largest process "
        f"{res['peak_rss_largest_process_mb']:.0f} MB")
    keep = ROOT / "benchmarks" / "out" / "sweep" / "analytic_1000"
    shutil.rmtree(keep, ignore_errors=True)
    keep.mkdir(parents=True)
    for name in ("report.html", "results.nc", "results.parquet", "results.csv"):
        shutil.copy(out / name, keep / name)
    return res


def markdown(r: dict) -> str:
    s = r["speed"]
    lines = ["| figure | value |", "|---|---|",
             f"| {s['serial']['points']} analytic points (2 s each), serial in process | "
             f"{s['serial']['points_per_hour']:.0f} points/h |",
             f"| the same, Dask LocalCluster 2 workers x 1 thread | "
             f"{s['dask_2']['points_per_hour']:.0f} points/h "
             f"(+{s['dask_2']['start_s']:.1f} s cluster start) |",
             f"| speed-up, 2 workers vs serial | {s['speedup_2_vs_serial']:.2f}x "
             f"({s['speedup_2_vs_serial_with_start']:.2f}x counting the cluster start) |",
             f"| the machine's own bound: two plain processes (no Dask), half the points "
             f"each | {s['two_processes']['points_per_hour']:.0f} points/h, "
             f"{s['speedup_two_processes_vs_serial']:.2f}x serial |",
             f"| per-point overhead, 1 Dask worker (analytic plant) | "
             f"{s['dask_1']['overhead_per_point_s']:.3f} s (run itself "
             f"{s['dask_1']['mean_run_s']:.2f} s) |",
             f"| per-point overhead, in process | {s['serial']['overhead_per_point_s']:.3f} s |"]
    for k in r["kills"]:
        lines.append(f"| kill -9 {k['target']} at {k['delay_s']:.1f} s "
                     f"({k['done_after_first_call']}/{k['points']} done), restart | "
                     f"{'every point exactly once' if k['exactly_once'] else 'NOT exactly once'}"
                     f", {k['points_rerun']} rerun, {k['orphan_processes']} orphan processes |")
    if "big" in r:
        b = r["big"]
        lines.append(f"| 1,000-point analytic sweep, 2 workers | {b['wall_s']:.0f} s wall "
                     f"({b['points_per_hour']:.0f} points/h, {b['ok']} ok), peak memory "
                     f"{b['peak_rss_total_mb']:.0f} MB all processes "
                     f"({b['peak_rss_largest_process_mb']:.0f} MB largest) |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="leave out the 1,000 points")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "sweep")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    res: dict = {"cpus": os.cpu_count(), "load_avg_at_start": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as d:
        tmp = Path(d)
        print("speed: serial vs Dask workers", flush=True)
        res["speed"] = speed(tmp, lambda s: print(s, flush=True))
        print("kill -9 and restart", flush=True)
        res["kills"] = kills(tmp, lambda s: print(s, flush=True))
        if not a.quick:
            print("1,000-point analytic sweep", flush=True)
            res["big"] = big(tmp, lambda s: print(s, flush=True))
    res["load_avg_at_end"] = os.getloadavg()
    write_json(a.out / "sweep.json", res)
    md = markdown(res)
    atomic_write(a.out / "sweep.md", lambda p: p.write_text(md))
    print(md)


if __name__ == "__main__":
    main()

"""Fuzz imcsim's inputs as a new user would and count tracebacks, hangs and silent wrong values.

Classes (issue 17): scenarios mutated from the bundled ones (types, NaN / inf / huge numbers,
YAML tags, duplicate keys, deep nesting, anchors, long strings, epochs), in-range extremes
(every numeric field at its bounds and at +-1e12, +-1e-300) through ``imc validate`` and
through ``imc run`` on a small scenario, bad command-line arguments, bad ``--out`` paths, and
damaged checkpoints. Every case runs ``imc`` in a subprocess with a time limit.

    .venv/bin/python scripts/fuzz_inputs.py --cases 400 --seed 1 --out runs/fuzz

A case is a *traceback* when "Traceback" is printed or the exit code is neither 0 nor 2
(an internal error, exit 1, counts here too), a *hang* when it passes its time limit, and a
*silent wrong value* when an input that is invalid by construction ends in exit 0, or when a
resumed run's metrics differ from an uninterrupted run's. Exit 2 must be one line.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import random
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
IMC = [str(Path(sys.executable).parent / "imc")]
ENV = {**os.environ, "RERUN_TELEMETRY_ENABLED": "0", "COLUMNS": "200"}


def run(args: list[str], timeout: float, cwd: Path | None = None) -> dict:
    t = time.perf_counter()
    try:
        p = subprocess.run(IMC + args, capture_output=True, text=True, timeout=timeout,
                           env=ENV, cwd=cwd)
    except subprocess.TimeoutExpired:
        return {"rc": None, "hang": True, "wall_s": time.perf_counter() - t, "stderr": "",
                "stdout": ""}
    return {"rc": p.returncode, "hang": False, "wall_s": time.perf_counter() - t,
            "stderr": p.stderr, "stdout": p.stdout}


def verdict(res: dict, invalid: bool) -> str:
    """ok / traceback / hang / silent / multiline."""
    if res["hang"]:
        return "hang"
    text = res["stderr"] + res["stdout"]
    if "Traceback" in text or res["rc"] not in (0, 2):
        return "traceback"
    if res["rc"] == 0 and invalid:
        return "silent"
    if res["rc"] == 2 and len([ln for ln in res["stderr"].splitlines() if ln.strip()]) != 1:
        return "multiline"
    return "ok"


# ------------------------------------------------------------------ mutated scenarios
def leaves(node, path=()):
    if isinstance(node, dict):
        for k, v in node.items():
            yield from leaves(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from leaves(v, path + (i,))
    else:
        yield path, node


def set_at(data, path, value):
    node = data
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value


BAD_NUMBERS = [float("nan"), float("inf"), float("-inf"), 1e308, -1e308, 10**30, "abc",
               [1, 2], {"a": 1}, None, True, "", "1e400"]
BAD_STRINGS = [[1], {"x": 1}, 12345, None, "x" * 100_000, "nonsense_kind"]


def mutate(rng: random.Random, base: dict) -> tuple[str, str, bool]:
    """(kind, YAML text, invalid by construction)."""
    data = copy.deepcopy(base)
    choice = rng.random()
    lv = [(p, v) for p, v in leaves(data) if p and p[0] != "name"]
    if choice < 0.45:  # a leaf gets a value of the wrong kind
        path, v = rng.choice(lv)
        if isinstance(v, bool):
            new = rng.choice([[1], {"x": 1}, "maybe", 7, None])
            invalid = new is not None
        elif isinstance(v, int | float):
            new = rng.choice(BAD_NUMBERS)
            invalid = not (new is None and path[-1] in ("exposure_s", "subpixel"))
        else:
            new = rng.choice(BAD_STRINGS)
            invalid = not (new is None and path[-1] in ("subpixel",))
        set_at(data, path, new)
        return f"leaf {'.'.join(map(str, path))}={str(new)[:20]}", yaml.safe_dump(data), invalid
    if choice < 0.55:  # an unknown key, or a section replaced by a scalar / list
        path, _ = rng.choice(lv)
        if rng.random() < 0.5 and len(path) > 1:
            node = data
            for k in path[:-1]:
                node = node[k]
            if isinstance(node, dict):
                node["unknown_field_x"] = 1
                return "unknown key", yaml.safe_dump(data), True
        if isinstance(data[path[0]], dict):  # a section (seed, name, duration_s are leaves)
            data[path[0]] = rng.choice([5, [1, 2], "text"])
            return f"section {path[0]}", yaml.safe_dump(data), True
        data[path[0]] = {"x": 1}
        return f"mapping for {path[0]}", yaml.safe_dump(data), True
    text = yaml.safe_dump(data)
    lines = text.splitlines()
    kind = rng.choice(["tag", "dup", "nest", "bomb", "bigint", "date", "epoch", "longstr",
                       "recursive", "binary", "control"])
    if kind == "tag":
        tag = rng.choice(["!!float abc", "!!int x1", "!!timestamp notadate", "!!bool maybe",
                          "!!python/object:os.system ls", "!custom 5", "!!set {a, b}",
                          "!!binary aGVsbG8=", "!!omap [a: 1]", "!!float .nan"])
        return f"tag {tag}", text + f"seed: {tag}\n", True
    if kind == "dup":
        sec = rng.choice([k for k in data if isinstance(data[k], dict)] or ["orbit"])
        return f"duplicate {sec}", text + f"{sec}: {{}}\n", True
    if kind == "nest":
        n = rng.choice([40, 300, 3000])
        return f"nesting {n}", text + "extra: " + "[" * n + "]" * n + "\n", True
    if kind == "bomb":
        bomb = "a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
            f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, "
            f"*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}]\n" for i in range(1, 9))
        return "alias bomb", bomb + text, True
    if kind == "bigint":
        return "5000-digit int", text + "seed: " + "9" * 5000 + "\n", True
    if kind == "date":
        d = rng.choice(["2026-13-01", "2026-02-30", "2026-06-21T25:00:00", "0000-01-01"])
        data.setdefault("orbit", {})["epoch_utc"] = "PLACEHOLDER"
        return f"date {d}", yaml.safe_dump(data).replace("PLACEHOLDER", d), True
    if kind == "epoch":
        e, invalid = rng.choice([("2300-01-01T00:00:00", True), ("1500-01-01", True),
                                 ("0", True), ("2026-06-21T10:30:00Z", False),
                                 ("2026-06-21T12:30:00+02:00", False), ("'tomorrow'", True),
                                 ("9999-12-31T23:59:59-12:00", True)])
        data.setdefault("orbit", {})["epoch_utc"] = "PLACEHOLDER"
        return f"epoch {e}", yaml.safe_dump(data).replace("'PLACEHOLDER'", e).replace(
            "PLACEHOLDER", e), invalid
    if kind == "longstr":
        return "long name", text.replace(f"name: {data.get('name')}",
                                         "name: " + "n" * 100_000), True
    if kind == "recursive":
        return "recursive alias", text + "extra: &r [*r]\n", True
    if kind == "binary":
        i = rng.randrange(len(lines))
        lines.insert(i, "\x00\x01\x02 garbage")
        return "binary bytes", "\n".join(lines) + "\n", True
    i = rng.randrange(len(lines))
    lines[i] = lines[i] + " \t\u202e: ]"
    return "control characters", "\n".join(lines) + "\n", True


def extremes(base: dict) -> list[tuple[str, str, bool]]:
    """Every numeric field of the schema at its bounds (valid or just outside)."""
    from imc.scenario import Scenario, _Model

    out = []

    def walk(model, prefix):
        for name, f in model.model_fields.items():
            ann = f.annotation
            sub = [a for a in (ann, *getattr(ann, "__args__", ())) if isinstance(a, type)
                   and issubclass(a, _Model)]
            if sub and prefix.count(".") < 4 and not str(ann).startswith("tuple"):
                walk(sub[0], f"{prefix}{name}.")
                continue
            if "float" in str(ann):  # in the schema's range unless a bound says otherwise
                for v in (1e12, -1e12, 1e-300, -1e-300):
                    out.append((f"{prefix}{name}", v, False))
            for m in f.metadata:
                for attr, inside in (("ge", True), ("le", True), ("gt", False), ("lt", False)):
                    b = getattr(m, attr, None)
                    if b is None or isinstance(b, bool):
                        continue
                    vals = [(b, inside)]
                    if isinstance(b, float | int):
                        step = 1 if isinstance(b, int) and "float" not in str(ann) else (
                            abs(b) * 1e-6 + 1e-9)
                        outside = b - step if attr in ("ge", "gt") else b + step
                        vals.append((outside, False))
                    for v, ok in vals:
                        out.append((f"{prefix}{name}", v, not ok))

    walk(Scenario, "")
    cases = []
    for path, v, invalid in out:
        data = copy.deepcopy(base)
        node = data
        keys = path.split(".")
        for k in keys[:-1]:
            node = node.setdefault(k, {}) if isinstance(node, dict) else node
        if isinstance(node, dict):
            node[keys[-1]] = v
            cases.append((f"bound {path}={v}", yaml.safe_dump(data), invalid))
    return cases


# -------------------------------------------------------------------- CLI arguments
def cli_cases(tmp: Path, scen: Path) -> list[tuple[str, list[str], bool]]:
    (tmp / "afile").write_text("x")
    (tmp / "adir").mkdir(exist_ok=True)
    fifo = tmp / "fifo.yaml"
    if not fifo.exists():
        os.mkfifo(fifo)
    long = "x" * 5000
    bad = (tmp / "metrics_bad").mkdir(exist_ok=True) or tmp / "metrics_bad"
    (bad / "metrics.json").write_text('{"scenario": "x", "without_compensation": [1, 2]}')
    nan_json = (tmp / "metrics_nan").mkdir(exist_ok=True) or tmp / "metrics_nan"
    (nan_json / "metrics.json").write_text("{\"a\": NaN}")
    s = str(scen)
    return [
        ("no args", [], False), ("unknown command", ["frobnicate"], True),
        ("validate no file", ["validate"], True),
        ("validate missing", ["validate", str(tmp / "none.yaml")], True),
        ("validate dir", ["validate", str(tmp / "adir")], True),
        ("validate fifo", ["validate", str(fifo)], True),
        ("validate /dev/zero", ["validate", "/dev/zero"], True),
        ("validate long path", ["validate", long], True),
        ("validate extra arg", ["validate", s, "extra"], True),
        ("validate bad option", ["validate", s, "--bogus"], True),
        ("run unknown option", ["run", s, "--outt", "x"], True),
        ("run --out empty", ["run", s, "--out", ""], True),
        ("run --out file", ["run", s, "--out", str(tmp / "afile")], True),
        ("run --out under file", ["run", s, "--out", str(tmp / "afile" / "sub")], True),
        ("run --out /proc", ["run", s, "--out", "/proc/imc-fuzz"], True),
        ("run --out /sys", ["run", s, "--out", "/sys/imc-fuzz"], True),
        ("run --out long", ["run", s, "--out", str(tmp / long)], True),
        ("run --out component too long", ["run", s, "--out", str(tmp / ("y" * 300))], True),
        ("run missing scenario", ["run", str(tmp / "none.yaml")], True),
        ("metrics missing", ["metrics", str(tmp / "none")], True),
        ("metrics of a file", ["metrics", str(tmp / "afile")], True),
        ("metrics wrong shape", ["metrics", str(bad)], True),
        ("metrics NaN json", ["metrics", str(nan_json)], True),
        ("metrics long path", ["metrics", long], True),
        ("loop --points 1", ["loop", s, "--points", "1"], True),
        ("loop --points x", ["loop", s, "--points", "x"], True),
        ("loop --amplitude-px nan", ["loop", s, "--amplitude-px", "nan"], True),
        ("loop --amplitude-px inf", ["loop", s, "--amplitude-px", "inf"], True),
        ("loop --out file", ["loop", s, "--out", str(tmp / "afile")], True),
        ("bench --seed -1", ["bench", "correlator", "--seed", "-1"], True),
        ("bench --pairs 1e20", ["bench", "correlator", "--pairs", "1e20"], True),
        ("bench --pairs 10**12", ["bench", "correlator", "--pairs", str(10**12)], True),
        ("bench --out file", ["bench", "correlator", "--out", str(tmp / "afile")], True),
        ("bench --out ''", ["bench", "correlator", "--out", ""], True),
        ("bench unknown", ["bench", "nothing"], True),
        ("emulator missing link dir", ["device-emulator", s, "--link",
                                       str(tmp / "nodir" / "link")], True),
        ("emulator link is dir", ["device-emulator", s, "--link", str(tmp / "adir")], True),
        ("emulator --speed nan", ["device-emulator", s, "--speed", "nan"], True),
        ("emulator --corrupt 2", ["device-emulator", s, "--corrupt", "2"], True),
        ("device-read missing port", ["device-read", str(tmp / "noport")], True),
        ("device-read --seconds -1", ["device-read", "x", "--seconds", "-1"], True),
        ("device-read --seconds inf", ["device-read", "x", "--seconds", "inf"], True),
        ("device-read --baudrate 0", ["device-read", "x", "--baudrate", "0"], True),
        ("validate --force typo", ["validate", s, "--forc"], True),
    ]


# ------------------------------------------------------------------ damaged checkpoints
CKPT_SCENARIO = {"name": "ckpt", "seed": 3, "duration_s": 0.6, "plant": {"fidelity": "analytic"},
                 "camera": {"tracker": {"frame_rate_hz": 100}}}


def checkpoint_cases(tmp: Path) -> list[dict]:
    scen = tmp / "ckpt.yaml"
    scen.write_text(yaml.safe_dump(CKPT_SCENARIO))
    ref = tmp / "ckpt_ref"
    shutil.rmtree(ref, ignore_errors=True)
    r = run(["run", str(scen), "--out", str(ref), "--no-rerun"], 300)
    if r["rc"] != 0:
        return [{"case": "reference run", "verdict": verdict(r, False), "detail": r["stderr"]}]
    want = json.loads((ref / "metrics.json").read_text())
    chunks = sorted((ref / "checkpoint").glob("chunk_*.npz"))

    def keep_first(d, n):
        for c in sorted((d / "checkpoint").glob("chunk_*.npz"))[n:]:
            c.unlink()

    damages = {
        "truncated chunk": lambda d: (d / "checkpoint" / chunks[2].name).write_bytes(
            (d / "checkpoint" / chunks[2].name).read_bytes()[:500]),
        "flipped byte": lambda d: _flip(d / "checkpoint" / chunks[1].name),
        "missing middle chunk": lambda d: (d / "checkpoint" / chunks[1].name).unlink(),
        "empty chunk": lambda d: (d / "checkpoint" / chunks[3].name).write_bytes(b""),
        "garbage meta": lambda d: (d / "checkpoint" / "meta.json").write_text("{not json"),
        "meta is a list": lambda d: (d / "checkpoint" / "meta.json").write_text("[1]"),
        "other digest": lambda d: (d / "checkpoint" / "meta.json").write_text(
            '{"digest": "0000000000000000"}'),
        "no meta": lambda d: (d / "checkpoint" / "meta.json").unlink(),
        "killed after 2 chunks": lambda d: keep_first(d, 2),
        "chunk is a folder": lambda d: ((d / "checkpoint" / chunks[2].name).unlink(),
                                        (d / "checkpoint" / chunks[2].name).mkdir()),
        "stale temp files": lambda d: ((d / ".metrics.json.imctmp-abc.json").write_text("x"),
                                       (d / ".recording.rrd.imctmp-x.rrd").write_text("x"),
                                       (d / "checkpoint" / ".chunk_0000050.npz.imctmp-q.npz")
                                       .write_text("x")),
    }
    out = [_killed_run(tmp, scen, want)]
    for name, damage in damages.items():
        d = tmp / f"ckpt_{name.replace(' ', '_')}"
        shutil.rmtree(d, ignore_errors=True)
        shutil.copytree(ref, d)
        (d / "metrics.json").unlink()
        damage(d)
        r = run(["run", str(scen), "--out", str(d), "--no-rerun"], 300)
        v = verdict(r, False)
        detail = r["stderr"].strip()[-300:]
        if v == "ok" and r["rc"] == 0:
            got = json.loads((d / "metrics.json").read_text())
            where = _differs(got, want)
            if where:
                v = "silent"
                detail = f"resumed metrics differ from the uninterrupted run's at {where}"
            if any(p.name.find(".imctmp-") >= 0 for p in d.rglob("*")):
                v = "silent"
                detail = "stale temp files left"
        out.append({"case": name, "verdict": v, "rc": r["rc"], "detail": detail})
    return out


def _killed_run(tmp: Path, scen: Path, want: dict) -> dict:
    """kill -9 once 3 chunks are written, then run again: the resumed metrics must match."""
    import signal

    d = tmp / "ckpt_killed"
    shutil.rmtree(d, ignore_errors=True)
    p = subprocess.Popen(IMC + ["run", str(scen), "--out", str(d), "--no-rerun"], env=ENV,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and p.poll() is None:
        if len(list((d / "checkpoint").glob("chunk_*.npz"))) >= 3:
            p.send_signal(signal.SIGKILL)
            break
        time.sleep(0.01)
    p.wait()
    killed = p.returncode == -signal.SIGKILL
    r = run(["run", str(scen), "--out", str(d), "--no-rerun"], 300)
    v = verdict(r, False)
    detail = r["stdout"].strip().splitlines()[-2:] if r["stdout"] else r["stderr"][-300:]
    if v == "ok":
        where = _differs(json.loads((d / "metrics.json").read_text()), want)
        if where:
            v, detail = "silent", f"resumed metrics differ at {where}"
    return {"case": f"kill -9 after 3 chunks ({'killed' if killed else 'ran to the end'})",
            "verdict": v, "rc": r["rc"], "detail": str(detail)}


def _flip(p: Path) -> None:
    b = bytearray(p.read_bytes())
    b[len(b) // 2] ^= 0x10
    p.write_bytes(bytes(b))


def _differs(a, b, path="metrics", rel=0.0) -> str | None:
    """Where two metrics differ (numbers beyond ``rel``; 0: bit for bit, which FFTW's wisdom
    file makes possible across processes, see correlator.fftbackend), or None."""
    if isinstance(a, dict):
        if not isinstance(b, dict) or a.keys() != b.keys():
            return path
        return next((w for k in a if (w := _differs(a[k], b[k], f"{path}.{k}", rel))), None)
    if isinstance(a, list):
        if not isinstance(b, list) or len(a) != len(b):
            return path
        return next((w for i, (x, y) in enumerate(zip(a, b, strict=True))
                     if (w := _differs(x, y, f"{path}[{i}]", rel))), None)
    if isinstance(a, float) and isinstance(b, float):
        return None if abs(a - b) <= rel * max(abs(a), abs(b), 1e-9) else path
    return None if a == b else path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=400, help="mutated scenarios")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "fuzz")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--runs", type=int, default=0,
                    help="run only this many of the in-range extremes through imc run (a "
                    "seeded sample; 0: all 700+, about an hour on 2 cores)")
    ap.add_argument("--skip", default="",
                    help="comma list: mutated,extremes,runs,cli,checkpoints")
    args = ap.parse_args()
    tmp = args.out
    tmp.mkdir(parents=True, exist_ok=True)
    skip = set(args.skip.split(","))
    rng = random.Random(args.seed)
    bases = {p.stem: yaml.safe_load(p.read_text()) for p in sorted((ROOT / "scenarios")
                                                                   .glob("*.yaml"))}
    results: dict[str, list] = {}

    def one(i_case):
        i, (label, text, invalid, timeout) = i_case
        f = tmp / f"case_{i:04d}.yaml"
        f.write_text(text)
        r = run(["validate", str(f)], timeout)
        v = verdict(r, invalid)
        return {"case": label, "file": f.name, "verdict": v, "rc": r["rc"],
                "wall_s": round(r["wall_s"], 2),
                "detail": (r["stderr"] + r["stdout"]).strip()[-300:]}

    if "mutated" not in skip:
        cases = []
        for _ in range(args.cases):
            name = rng.choice(sorted(bases))
            label, text, invalid = mutate(rng, bases[name])
            cases.append((f"{name}: {label}", text, invalid, 60))
        with ThreadPoolExecutor(args.jobs) as pool:
            results["mutated"] = list(pool.map(one, enumerate(cases)))
    if "extremes" not in skip:
        cases = [(f"quickstart: {lb}", t, inv, 60) for lb, t, inv in
                 extremes(bases["quickstart"])]
        with ThreadPoolExecutor(args.jobs) as pool:
            results["extremes"] = list(pool.map(one, enumerate(cases, start=5000)))
    if "runs" not in skip:  # in-range extremes through `imc run` (small, fast scenario)
        tiny = {"name": "tiny", "duration_s": 0.05, "camera": {"tracker": {"rows": 64,
                                                                           "cols": 64}},
                "correlator": {"block_px": 32, "n_blocks": 1},
                "scene": {"size_m": 256, "texel_m": 0.4, "dem_spacing_m": 4,
                          "sun_elevation_deg": 50, "sun_azimuth_deg": 140}}
        cases = list(enumerate(extremes(tiny), start=8000))
        if 0 < args.runs < len(cases):
            cases = sorted(rng.sample(cases, args.runs))

        def run_one(i_case):
            i, (label, text, invalid) = i_case
            data = yaml.safe_load(text)
            data.setdefault("plant", {})["fidelity"] = "rendered" if i % 2 else "texture"
            f = tmp / f"run_{i:04d}.yaml"
            f.write_text(yaml.safe_dump(data))
            r = run(["run", str(f), "--out", str(tmp / f"run_{i:04d}"), "--no-rerun"], 300)
            v = verdict(r, invalid)
            detail = (r["stderr"] + r["stdout"]).strip()[-300:]
            if v == "ok" and r["rc"] == 0:
                m = json.loads((tmp / f"run_{i:04d}" / "metrics.json").read_text())
                if m["with_compensation"]["rms_total_px"] is None:
                    v, detail = "suspicious", "exit 0 with no residual RMS"
                shutil.rmtree(tmp / f"run_{i:04d}", ignore_errors=True)
            return {"case": f"tiny {data['plant']['fidelity']}: {label}", "verdict": v,
                    "rc": r["rc"], "wall_s": round(r["wall_s"], 2), "detail": detail}

        with ThreadPoolExecutor(args.jobs) as pool:
            results["runs"] = list(pool.map(run_one, cases))
    if "cli" not in skip:
        def cli_one(c):
            label, argv, invalid = c
            r = run(argv, 60, cwd=tmp)
            return {"case": label, "verdict": verdict(r, invalid), "rc": r["rc"],
                    "detail": (r["stderr"] + r["stdout"]).strip()[-300:]}

        with ThreadPoolExecutor(args.jobs) as pool:
            results["cli"] = list(pool.map(cli_one, cli_cases(tmp, ROOT / "scenarios" /
                                                               "quickstart.yaml")))
    if "checkpoints" not in skip:
        results["checkpoints"] = checkpoint_cases(tmp)
    summary = {}
    for cls, rs in results.items():
        counts: dict[str, int] = {}
        for r in rs:
            counts[r["verdict"]] = counts.get(r["verdict"], 0) + 1
        summary[cls] = {"cases": len(rs), **counts}
        if "wall_s" in (rs[0] if rs else {}):
            summary[cls]["max_wall_s"] = max(r["wall_s"] for r in rs)
    (tmp / "fuzz_results.json").write_text(json.dumps({"summary": summary, "results": results},
                                                      indent=1))
    print(json.dumps(summary, indent=1))
    for cls, rs in results.items():
        for r in rs:
            if r["verdict"] != "ok":
                print(f"[{cls}] {r['verdict']}: {r['case']} (rc {r.get('rc')}): "
                      f"{r['detail'][-200:]}")


if __name__ == "__main__":
    main()

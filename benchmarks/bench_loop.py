"""The compensation loop's benchmark: every target of the loop issue, measured.

    .venv/bin/python benchmarks/bench_loop.py [--quick] [--out benchmarks/out/loop]

Writes loop.json and loop.md (the tables quoted in docs/loop-targets.md) and rejection PNGs.
Figures are measured here, never asserted in tests. About 10 minutes on 2 cores (--quick: the
analytic studies only, ~3 minutes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from compensation.actuators import IdealStage, PiezoStage  # noqa: E402
from compensation.analytic import (  # noqa: E402
    LoopModel,
    design_lines,
    max_integrator_gain,
    measured_rejection,
)
from compensation.analytic_plant import AnalyticPlant, sinusoids  # noqa: E402
from compensation.controllers import PII, Integrator, KalmanPredictor, Line, Notch  # noqa: E402
from compensation.estimators import MeanEstimator  # noqa: E402
from compensation.loop import Timeline, simulate  # noqa: E402
from compensation.transport import Transport  # noqa: E402
from imc.io import write_json  # noqa: E402
from imc.outputs.loopplot import delay_s, loop_study  # noqa: E402

SCEN = ROOT / "scenarios"


def db(x):
    return float(20 * np.log10(np.maximum(np.abs(x), 1e-300)))


# ----------------------------------------------------------------------------- analytic


def rejection_agreement(out: Path) -> list[dict]:
    """Sine sweep vs analytic |S(f)| up to a quarter of the rate, several loops."""
    r = 1000.0
    line = Integrator(rate_hz=r, gain=0.3, lines=(Line(65.0, 0.05),))
    cases = [
        ("integrator 0.45, 1 kHz, 2 frames", Integrator(rate_hz=r, gain=0.45), IdealStage(),
         1 / r, r),
        ("integrator + 65 Hz line", line, IdealStage(), 1 / r, r),
        ("Smith integrator 1.0", Integrator(rate_hz=r, gain=1.0, smith=True), IdealStage(),
         1 / r, r),
        ("PII, 414 Hz, 0.5 frame", PII(rate_hz=414.0, kp=0.257, ki=0.674, kii=0.289),
         IdealStage(), 0.5 / 414, 414.0),
        ("Kalman o3 30 Hz, 414 Hz, ramp", KalmanPredictor(rate_hz=414.0, order=3,
                                                          bandwidth_hz=30.0, identify=False,
                                                          noise_px=0.02, lead_s=0.5 / 414),
         IdealStage(ramp=True, ramp_s=1 / 414), 0.5 / 414, 414.0),
        ("integrator 0.44, piezo 500 Hz", Integrator(rate_hz=r, gain=0.44),
         PiezoStage(update_hz=10_000.0, resonance_hz=500.0, stroke_px=None, dac_bits=None),
         1 / r, r),
        ("integrator 0.40, piezo 300 Hz + drive notch (5 % off)", Integrator(rate_hz=r,
                                                                             gain=0.40),
         PiezoStage(update_hz=6_000.0, resonance_hz=300.0, stroke_px=None, dac_bits=None,
                    drive_notch_hz=315.0), 1 / r, r),
    ]
    rows = []
    for name, ctl, act, lat, rate in cases:
        model = LoopModel(rate, 1 / rate, lat, ctl, act)
        if getattr(ctl, "lines", ()):
            model = dataclasses.replace(model, controller=design_lines(ctl, model))
        f = np.geomspace(0.5, rate / 4, 10)
        meas = measured_rejection(model, f, settle_s=2.0, periods=6)
        err = [db(a / b) for a, b in zip(meas, np.abs(model.rejection(f)), strict=True)]
        rows.append({"loop": name, "max_error_db": float(np.max(np.abs(err))),
                     "up_to_hz": rate / 4})
    loop_study(LoopModel(r, 1 / r, 1 / r, Integrator(rate_hz=r, gain=0.45), IdealStage()),
               out / "integrator_1khz", n_sweep=14, title="integrator 0.45, 1 kHz, 2 frames")
    return rows


def khz_integrator() -> list[dict]:
    """1 kHz, 2 frames of delay: |S(10 Hz)|, 0 dB crossover, peak |S|."""
    r = 1000.0
    rows = []
    for name, ctl in (("integrator 0.45", Integrator(rate_hz=r, gain=0.45)),
                      ("integrator 0.48", Integrator(rate_hz=r, gain=0.48)),
                      ("integrator 1.0, Smith (today's law)",
                       Integrator(rate_hz=r, gain=1.0, smith=True))):
        m = LoopModel(r, 1 / r, 1 / r, ctl, IdealStage())
        mg = m.margins()
        rows.append({"controller": name, "S_10Hz": float(abs(m.rejection([10.0])[0])),
                     "crossover_hz": mg.crossover_hz, "peak_S": mg.peak_rejection,
                     "gain_margin_db": mg.gain_margin_db,
                     "phase_margin_deg": mg.phase_margin_deg,
                     "delay_bound_10Hz": float(abs(1 - np.exp(-2j * np.pi * 10 * delay_s(m))))})
    return rows


def phi_spec() -> list[dict]:
    """Solar Orbiter PHI's stabiliser spec at 300 and 414 Hz, 0.5 frame extra latency:
    the least rejection below 5 Hz and over 5-10 Hz."""
    rows = []
    for rate in (300.0, 414.0):
        cases = [("PII", PII(rate_hz=rate, kp=0.257, ki=0.674, kii=0.289), IdealStage()),
                 ("Kalman o3 35 Hz, hold", KalmanPredictor(
                     rate_hz=rate, order=3, bandwidth_hz=35.0, identify=False, noise_px=0.02,
                     lead_s=0.0), IdealStage()),
                 ("Kalman o3 35 Hz, ramp", KalmanPredictor(
                     rate_hz=rate, order=3, bandwidth_hz=35.0, identify=False, noise_px=0.02,
                     lead_s=0.5 / rate), IdealStage(ramp=True, ramp_s=1 / rate))]
        for name, ctl, act in cases:
            m = LoopModel(rate, 1 / rate, 0.5 / rate, ctl, act)
            mg = m.margins()
            low = np.abs(m.rejection(np.linspace(0.2, 5.0, 50))).max()
            mid = np.abs(m.rejection(np.linspace(5.0, 10.0, 30))).max()
            rows.append({"rate_hz": rate, "controller": name, "rejection_below_5Hz": 1 / low,
                         "rejection_5_10Hz": 1 / mid, "peak_S": mg.peak_rejection,
                         "phase_margin_deg": mg.phase_margin_deg,
                         "noise_rms_px_per_0.02": m.noise_rms_px(0.02)})
    return rows


def _run(ctl, motion, dur, rate=1000.0, latency=None, act=None, sigma=0.0, seed=3):
    n = int(dur * rate)
    t_per = 1 / rate
    ft = np.arange(n) * t_per
    plant = AnalyticPlant(motion, np.zeros((1, 2)), max(sigma, 1e-6), ft, t_per, seed=(seed,),
                          noise_scale=1.0 if sigma else 0.0)
    tl = Timeline(ft, t_per, n * t_per, np.zeros((n, 2)), t_per)
    return simulate(plant, MeanEstimator(), ctl, act or IdealStage(),
                    Transport(latency_s=t_per if latency is None else latency), tl)


def _residual(res, motion, t0, t1, rate=1000.0, per=16):
    ts = np.arange(int(t0 * rate * per), int(t1 * rate * per)) / (rate * per) + 0.5 / (
        rate * per)
    ref = motion(np.arange(8) / (8 * rate) + 1 / (16 * rate))[:, 0, 0].mean()
    return motion(ts)[:, 0, 0] - ref - res.trajectory(ts)[:, 0], ts


def wheel_line() -> dict:
    """A known 65 Hz wheel line: rejection at the line, at +-1 % and following a 1 %/s
    sweep (integrator 0.3 + one resonant term, 1 kHz, 2 frames)."""
    r = 1000.0
    ctl = Integrator(rate_hz=r, gain=0.3, lines=(Line(65.0, 0.05),))
    m = LoopModel(r, 1 / r, 1 / r, ctl, IdealStage())
    ctl = design_lines(ctl, m)
    m = dataclasses.replace(m, controller=ctl)
    mg = m.margins()
    out = {"S_line_analytic_db": db(m.rejection([65.0])[0]),
           "S_line_measured_db": db(measured_rejection(m, [65.0], settle_s=3.0)[0]),
           "S_minus1pct_db": db(m.rejection([65.0 * 0.99])[0]),
           "S_plus1pct_db": db(m.rejection([65.0 * 1.01])[0]),
           "S_minus1pct_measured_db": db(measured_rejection(m, [65.0 * 0.99], settle_s=3.0)[0]),
           "S_plus1pct_measured_db": db(measured_rejection(m, [65.0 * 1.01], settle_s=3.0)[0]),
           "peak_S": mg.peak_rejection, "phase_margin_deg": mg.phase_margin_deg,
           "modulus_margin": mg.modulus_margin}

    def swept(t):
        ph = 2 * np.pi * 65.0 * (t + 0.5 * 0.01 * t**2)
        o = np.zeros((len(t), 1, 2))
        o[:, 0, 0] = 0.1 * np.sin(ph)
        return o

    for adaptive in (False, True):
        c = dataclasses.replace(ctl, lines=(dataclasses.replace(ctl.lines[0],
                                                                adaptive=adaptive),))
        res = _run(c, swept, 12.0)
        r_t, ts = _residual(res, swept, 2.0, 12.0)
        ph = 2 * np.pi * 65.0 * (ts + 0.5 * 0.01 * ts**2)
        line = 2 * abs(np.mean(r_t * np.exp(-1j * ph)))  # residual at the swept line
        key = "adaptive" if adaptive else "fixed"
        out[f"swept_1pct_s_{key}_db"] = db(line / 0.1)
        out[f"swept_final_hz_{key}"] = float(res.states["controller"].omega[0] / 2 / np.pi)
    out["swept_true_final_hz"] = 65.0 * 1.12
    return out


def three_lines() -> list[dict]:
    """0.5 px at 1 Hz + 0.3 px at 7 Hz + 0.1 px at 65 Hz, 0.02 px noise, 1 kHz, 2 frames:
    residual RMS over 3-10 s (after the predictor's 2 s identification window), and the
    same loop's residual from the noise alone (its measurement-noise floor)."""
    motion = sinusoids([(0.5, 1.0, 0.3, 0), (0.3, 7.0, 1.0, 0), (0.1, 65.0, 2.0, 0)])
    still = sinusoids([])
    r = 1000.0
    line3 = Integrator(rate_hz=r, gain=0.3, lines=(Line(1.0, 0.01), Line(7.0, 0.02),
                                                   Line(65.0, 0.05)))
    line3 = design_lines(line3, LoopModel(r, 1 / r, 1 / r, line3, IdealStage()))
    ramp = IdealStage(ramp=True, ramp_s=1 / r)
    cases = [("integrator 0.45", Integrator(rate_hz=r, gain=0.45), IdealStage()),
             ("integrator 0.3 + resonant terms at 1, 7, 65 Hz (known)", line3, IdealStage()),
             ("Kalman o2 10 Hz, lines identified, ramp",
              KalmanPredictor(rate_hz=r, order=2, bandwidth_hz=10.0, lead_s=0.5 / r), ramp),
             ("Kalman o2 5 Hz, lines known (1, 7, 65 Hz), ramp",
              KalmanPredictor(rate_hz=r, order=2, bandwidth_hz=5.0, identify=False,
                              lines_hz=(1.0, 7.0, 65.0), lead_s=0.5 / r), ramp)]
    rows = []
    for name, ctl, act in cases:
        res = _run(ctl, motion, 10.0, act=act, sigma=0.02)
        total = float(np.sqrt(np.mean(_residual(res, motion, 3.0, 10.0)[0] ** 2)))
        noise = _run(ctl, still, 10.0, act=act, sigma=0.02)
        floor = float(np.sqrt(np.mean(_residual(noise, still, 3.0, 10.0)[0] ** 2)))
        lines = getattr(res.states["controller"], "lines_hz", None)
        rows.append({"controller": name, "residual_rms_px": total, "noise_floor_px": floor,
                     "ratio_to_floor": total / floor,
                     "lines_hz": [round(float(f), 3) for f in lines] if lines is not None
                     else None})
    return rows


def piezo() -> dict:
    """Stage dynamics against the rigid stage: rejection at 10 Hz with every loop tuned to
    the same robustness (largest integrator gain with peak |S| <= 2), and the residual on
    the three-line disturbance with the gain fixed; Bouc-Wen hysteresis."""
    r = 1000.0

    def tuned(ctl, act):
        m = LoopModel(r, 1 / r, 1 / r, ctl, act)
        g = max_integrator_gain(m)
        m = dataclasses.replace(m, controller=dataclasses.replace(ctl, gain=g))
        return float(1 / abs(m.rejection([10.0])[0])), g

    stage = {"rigid": IdealStage()}
    for f in (700.0, 500.0, 357.0, 300.0, 200.0):
        stage[f"piezo {f:g} Hz"] = PiezoStage(update_hz=20 * f, resonance_hz=f, stroke_px=None,
                                              dac_bits=None)
    rows = []
    base = None
    for name, act in stage.items():
        rej, g = tuned(Integrator(rate_hz=r), act)
        base = base or rej
        rows.append({"stage": name, "gain": g, "rejection_10Hz": rej,
                     "vs_rigid": rej / base})
    for f in (300.0, 200.0):
        act = PiezoStage(update_hz=20 * f, resonance_hz=f, stroke_px=None, dac_bits=None)
        for w, d in ((20.0, 20.0), (60.0, 30.0), (100.0, 30.0)):
            rej, g = tuned(Integrator(rate_hz=r, notch=Notch(f, w, d)), act)
            rows.append({"stage": f"piezo {f:g} Hz + notch {w:g} Hz wide, {d:g} dB",
                         "gain": g, "rejection_10Hz": rej, "vs_rigid": rej / base})
        act = PiezoStage(update_hz=20 * f, resonance_hz=f, damping=0.3, stroke_px=None,
                         dac_bits=None)
        rej, g = tuned(Integrator(rate_hz=r), act)
        rows.append({"stage": f"piezo {f:g} Hz, damping 0.3", "gain": g,
                     "rejection_10Hz": rej, "vs_rigid": rej / base})
        # the drive electronics' notch at the DAC rate: the mode (identified exactly, or 5 %
        # off) replaced by a damped one at 3 x its frequency
        for err in (1.0, 0.95, 1.05):
            act = PiezoStage(update_hz=20 * f, resonance_hz=f, stroke_px=None, dac_bits=None,
                             drive_notch_hz=f * err)
            rej, g = tuned(Integrator(rate_hz=r), act)
            rows.append({"stage": f"piezo {f:g} Hz + drive notch (identified at {f * err:g} "
                                  f"Hz, to {3 * f * err:g} Hz, damping 0.7)", "gain": g,
                         "rejection_10Hz": rej, "vs_rigid": rej / base})
    motion = sinusoids([(0.5, 1.0, 0.3, 0), (0.3, 7.0, 1.0, 0), (0.1, 65.0, 2.0, 0)])
    fixed = []
    base_rms = None
    for name, act in (("rigid", IdealStage()),
                      ("piezo 500 Hz", PiezoStage(update_hz=10_000.0, resonance_hz=500.0)),
                      ("piezo 300 Hz", PiezoStage(update_hz=6_000.0, resonance_hz=300.0)),
                      ("piezo 300 Hz + drive notch", PiezoStage(update_hz=6_000.0,
                                                                resonance_hz=300.0,
                                                                drive_notch_hz=300.0)),
                      ("piezo 700 Hz, hysteresis 0 %", PiezoStage(update_hz=14_000.0,
                                                                  resonance_hz=700.0)),
                      ("piezo 700 Hz, hysteresis 2 %", PiezoStage(update_hz=14_000.0,
                                                                  resonance_hz=700.0,
                                                                  hysteresis_pct=2.0)),
                      ("piezo 700 Hz, hysteresis 12 %", PiezoStage(update_hz=14_000.0,
                                                                   resonance_hz=700.0,
                                                                   hysteresis_pct=12.0))):
        res = _run(Integrator(rate_hz=r, gain=0.45), motion, 4.0, act=act, sigma=0.02)
        rms = float(np.sqrt(np.mean(_residual(res, motion, 1.0, 4.0)[0] ** 2)))
        base_rms = base_rms or rms
        fixed.append({"stage": name, "residual_rms_px": rms, "vs_rigid": rms / base_rms})
    return {"equal_robustness": rows, "fixed_gain_0.45": fixed}


# ---------------------------------------------------------------------------- scenarios


def run_cli(path: Path, out: Path, overrides: dict | None = None) -> dict:
    """imc run a scenario (with overrides) as a process: metrics, wall time, peak memory."""
    data = yaml.safe_load(path.read_text())
    for key, value in (overrides or {}).items():
        node = data
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    with tempfile.NamedTemporaryFile("w", suffix=".yaml", dir=path.parent, delete=False) as f:
        yaml.safe_dump(data, f)
        tmp = Path(f.name)
    try:
        cmd = ["/usr/bin/time", "-v", str(ROOT / ".venv" / "bin" / "imc"), "run", str(tmp),
               "--out", str(out), "--fresh", "--no-rerun"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        wall = time.perf_counter() - t0
    finally:
        tmp.unlink()
    if proc.returncode != 0:
        raise RuntimeError(f"{path.name}: {proc.stderr[-2000:]}")
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr)
    metrics = json.loads((out / "metrics.json").read_text())
    ckpt = sum(p.stat().st_size for p in (out / "checkpoint").glob("chunk_*.npz"))
    return {"metrics": metrics, "wall_s": wall,
            "peak_rss_mb": int(rss.group(1)) / 1024 if rss else None,
            "checkpoint_bytes": ckpt}


def summary(r: dict) -> dict:
    m = r["metrics"]
    t = m["tracker"]
    return {"open_rms_px": m["without_compensation"]["rms_total_px"],
            "closed_rms_px": m["with_compensation"]["rms_total_px"],
            "reduction": m["rms_reduction"],
            "mtf_nyquist_open": m["without_compensation"]["mtf_nyquist_worst"],
            "mtf_nyquist_closed": m["with_compensation"]["mtf_nyquist_worst"],
            "tracker_rms_px": t["rms_error_px"], "tracker_crlb_px": t["median_crlb_px"],
            "tracker_over_crlb": [a / b if a and b else None
                                  for a, b in zip(t["rms_error_px"], t["median_crlb_px"],
                                                  strict=True)],
            "rereferences": t["rereferences"], "lines_hz": m["loop"]["lines_hz"],
            "wall_s": r["wall_s"], "peak_rss_mb": r["peak_rss_mb"],
            "checkpoint_mb": r["checkpoint_bytes"] / 1e6}


def scenarios(tmp: Path) -> dict:
    out = {}
    old = {"compensation.controller": {"kind": "integrator", "gain": 0.8},
           "compensation.actuator": {"kind": "ideal"},
           "compensation.estimator": {"kind": "mean"}}
    for fid in ("rendered", "texture", "analytic"):
        out[f"quickstart/{fid}"] = summary(run_cli(SCEN / "quickstart.yaml", tmp / f"q_{fid}",
                                                   {"plant.fidelity": fid}))
    out["quickstart/rendered, today's loop"] = summary(run_cli(
        SCEN / "quickstart.yaml", tmp / "q_old", old))
    for name in ("ikonos_tdi_scan", "ikonos_tdi_jitter"):
        out[name] = summary(run_cli(SCEN / f"{name}.yaml", tmp / name))
        out[f"{name}, today's loop"] = summary(run_cli(SCEN / f"{name}.yaml", tmp / f"{name}_o",
                                                       old))
    for fid in ("rendered", "analytic"):
        out[f"seed_device/{fid}"] = summary(run_cli(SCEN / "seed_device.yaml",
                                                    tmp / f"seed_{fid}",
                                                    {"plant.fidelity": fid}))
    out["seed_device/analytic, Smith integrator 1.0"] = summary(run_cli(
        SCEN / "seed_device.yaml", tmp / "seed_smith",
        {"plant.fidelity": "analytic", "compensation.controller":
         {"kind": "integrator", "gain": 1.0, "smith": True},
         "compensation.actuator": {"kind": "ideal"}}))
    out["wheel_khz"] = summary(run_cli(SCEN / "wheel_khz.yaml", tmp / "wheel"))
    out["wheel_khz, no resonant terms"] = summary(run_cli(
        SCEN / "wheel_khz.yaml", tmp / "wheel_plain",
        {"compensation.controller": {"kind": "integrator", "gain": 0.3}}))
    for dur in (1.0, 2.5, 5.0, 10.0):
        out[f"long_stare/{dur:g} s"] = summary(run_cli(SCEN / "long_stare.yaml",
                                                       tmp / f"stare_{dur:g}",
                                                       {"duration_s": dur}))
    return out


def markdown(res: dict) -> str:
    """The results as tables (one per study)."""
    lines = ["# Loop benchmark", ""]
    for key, val in res.items():
        lines.append(f"## {key}\n")
        if isinstance(val, dict) and val and all(isinstance(v, dict) for v in val.values()):
            rows = [{"case": k, **v} for k, v in val.items()]
        elif isinstance(val, dict) and any(isinstance(v, list) for v in val.values()):
            for sub, rows in val.items():
                lines.append(f"### {sub}\n")
                lines.extend(_table(rows))
            continue
        elif isinstance(val, dict):
            rows = [val]
        elif isinstance(val, list):
            rows = val
        else:
            lines.append(f"{_fmt(val)}\n")
            continue
        lines.extend(_table(rows))
    return "\n".join(lines)


def _table(rows: list[dict]) -> list[str]:
    cols = list(rows[0])
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |" for r in rows]
    return out + [""]


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return " / ".join(_fmt(x) for x in v)
    return str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "loop")
    ap.add_argument("--quick", action="store_true", help="the analytic studies only")
    args = ap.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    res: dict = {}
    t0 = time.perf_counter()
    for name, fn in (("analytic vs simulated rejection", lambda: rejection_agreement(out)),
                     ("1 kHz, 2 frames of delay", khz_integrator),
                     ("PHI spec, 300-414 Hz", phi_spec), ("wheel line", wheel_line),
                     ("three lines + noise", three_lines), ("piezo stage", piezo)):
        t = time.perf_counter()
        res[name] = fn()
        print(f"{name}: {time.perf_counter() - t:.0f} s", flush=True)
        write_json(out / "loop.json", res)
    if not args.quick:
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            res["scenarios"] = scenarios(Path(tmp))
            print(f"scenarios: {time.perf_counter() - t:.0f} s", flush=True)
    res["wall_s"] = time.perf_counter() - t0
    write_json(out / "loop.json", res)
    (out / "loop.md").write_text(markdown(res))
    print((out / "loop.md").read_text())


if __name__ == "__main__":
    main()

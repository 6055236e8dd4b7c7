"""The ``imc`` command line: run, validate, info."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from imc.scenario import ScenarioError, load_scenario

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="imcsim: satellite focal-plane image-motion-compensation simulator.")
err = Console(stderr=True)
out = Console()


def _fail(msg: str, code: int = 2) -> None:
    err.print(f"[bold red]error:[/] {msg}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


@app.command()
def info() -> None:
    """Print the Mitsuba variant imcsim will use and the library versions."""
    import numpy
    import scipy

    from scene.kernel import versions
    from scene.variant import VariantError, choose_variant

    try:
        choice = choose_variant()
    except VariantError as e:
        _fail(str(e))
    v = versions()
    out.print(f"imcsim 0.1.0  python {sys.version.split()[0]}  numpy {numpy.__version__}  "
              f"scipy {scipy.__version__}  mitsuba {v['mitsuba']}  drjit {v['drjit']}")
    out.print(f"mitsuba variant: {choice.variant}  ({choice.reason})")
    out.print(f"libLLVM for Dr.Jit: {choice.libllvm_path or 'none usable'}")


@app.command()
def validate(scenario: Path = typer.Argument(..., help="scenario YAML")) -> None:
    """Check a scenario file, its geometry and its loop design without rendering."""
    from imc.build import build_loop, build_models

    try:
        sc = load_scenario(scenario)
        parts = build_loop(build_models(sc))
    except ScenarioError as e:
        _fail(str(e))
    mg = parts.margins
    out.print(f"{scenario}: ok ({sc.n_frames} frames, {sc.correlator.n_blocks} blocks; "
              f"loop {sc.compensation.controller.kind}: {_margins_text(mg)})")


def _margins_text(mg) -> str:
    def num(v, unit):
        return "inf" if v is None or not float("-inf") < v < float("inf") else f"{v:.1f}{unit}"

    return (f"gain margin {num(mg.gain_margin_db, ' dB')}, phase margin "
            f"{num(mg.phase_margin_deg, ' deg')}, peak |S| {mg.peak_rejection:.2f} at "
            f"{mg.peak_hz:.1f} Hz")


def _table(metrics: dict) -> Table:
    tab = Table(title=f"imcsim: {metrics['scenario']} residual image motion (px)")
    tab.add_column("")
    tab.add_column("without compensation", justify="right")
    tab.add_column("with compensation", justify="right")
    o, c = metrics["without_compensation"], metrics["with_compensation"]

    def pair(v):
        return f"{v[0]:.3f} / {v[1]:.3f}"

    tab.add_row("RMS row / col", pair(o["rms_px"]), pair(c["rms_px"]))
    tab.add_row("RMS total", f"{o['rms_total_px']:.3f}", f"{c['rms_total_px']:.3f}")
    tab.add_row("peak-to-peak row / col", pair(o["peak_to_peak_px"]), pair(c["peak_to_peak_px"]))
    tab.add_row(f"motion MTF @Nyquist row / col ({o['window_s']:.3g} s)",
                pair(o["mtf_nyquist"]), pair(c["mtf_nyquist"]))
    tab.add_row("worst-window MTF row / col", pair(o["mtf_nyquist_worst"]),
                pair(c["mtf_nyquist_worst"]))
    return tab


@app.command()
def run(
    scenario: Path = typer.Argument(..., help="scenario YAML"),
    out_dir: Path = typer.Option(Path("runs/out"), "--out", help="output folder"),
    save_frames: bool = typer.Option(False, "--save-frames", help="also write frames.npz"),
    fresh: bool = typer.Option(False, "--fresh", help="ignore a checkpoint in --out"),
    no_rerun: bool = typer.Option(False, "--no-rerun", help="skip recording.rrd"),
) -> None:
    """Run a scenario: render, track, compensate; write metrics, tracks and a recording."""
    from rich.progress import Progress

    from imc.pipeline import run_scenario
    from scene.variant import VariantError, choose_variant

    try:
        sc = load_scenario(scenario)
        choice = choose_variant()
    except (ScenarioError, VariantError) as e:
        _fail(str(e))
    if choice.variant.startswith("scalar"):
        err.print(f"[yellow]warning:[/] rendering with Mitsuba {choice.variant}: {choice.reason}",
                  highlight=False, soft_wrap=True)
    try:
        with Progress(console=err, transient=True) as prog:
            task = prog.add_task(f"{sc.name}: frames", total=sc.n_frames)
            metrics, run_info = run_scenario(
                sc, out_dir, save_frames=save_frames, fresh=fresh, rerun=not no_rerun,
                progress=lambda done, n: prog.update(task, completed=done),
                warn=lambda msg: err.print(f"[yellow]warning:[/] {msg}", highlight=False,
                                           soft_wrap=True))
    except ScenarioError as e:
        _fail(str(e))
    out.print(_table(metrics))
    t = metrics["tracker"]
    out.print(f"tracker: {t['valid_fraction'] * 100:.1f} % valid, error RMS row/col "
              f"{t['rms_error_px'][0]:.4f} / {t['rms_error_px'][1]:.4f} px "
              f"(CRLB {t['median_crlb_px'][0]:.4f} / {t['median_crlb_px'][1]:.4f} px)")
    out.print(f"residual RMS reduced {metrics['rms_reduction']:.1f}x by the loop")
    lp = metrics["loop"]
    out.print(f"loop: {lp['fidelity']} plant, {lp['estimator']} estimator, {lp['controller']} "
              f"controller, {lp['actuator']} stage; {lp['measurement_rate_hz']:g} "
              f"measurements/s, latency {lp['latency_s'] * 1e3:.1f} ms; stage at its stroke "
              f"{lp['stage_saturation_fraction'] * 100:.1f} % of the time"
              + (f"; lines {', '.join(f'{f:.2f}' for f in lp['lines_hz'])} Hz"
                 if lp["lines_hz"] else ""))
    if "correlator_device" in metrics:
        d = metrics["correlator_device"]
        out.print(f"correlator device: {d['correlations_per_s']:g} correlations/s, latency "
                  f"{d['latency_s'] * 1e3:.0f} ms; {d['pairs_processed']} pairs correlated, "
                  f"{d['pairs_dropped']} dropped; {d['frames_measured']} frames measured")
    if "link" in metrics:
        lk = metrics["link"]
        out.print(f"serial link: {lk['records']} records, {lk['lost']} lost, "
                  f"{lk['crc_errors']} CRC errors, {lk['reconnects']} reconnects")
    resumed = run_info["resumed_from_frame"]
    out.print(f"wall time {run_info['wall_s']:.1f} s (rendering {run_info['render_s']:.1f} s; "
              f"checkpoint {run_info['checkpoint_bytes'] / 1e6:.1f} MB)"
              + (f", resumed at frame {resumed}" if resumed else ""))
    out.print("wrote " + ", ".join(run_info["files"]))


@app.command(name="metrics")
def show_metrics(out_dir: Path = typer.Argument(..., help="a run's output folder")) -> None:
    """Print the summary table of a finished run."""
    try:
        metrics = json.loads((out_dir / "metrics.json").read_text())
    except (OSError, json.JSONDecodeError) as e:
        _fail(f"{out_dir}/metrics.json: cannot read ({e})")
    out.print(_table(metrics))


@app.command(name="device-emulator")
def device_emulator(
    scenario: Path = typer.Argument(..., help="scenario YAML (its correlator section is used)"),
    link: Path = typer.Option(Path("/tmp/imc-jtoc"), "--link",
                              help="symlink to the pseudo-terminal the device serves"),
    speed: float = typer.Option(1.0, min=0.0, help="device time / wall time (0: no waiting)"),
    linger_s: float = typer.Option(2.0, min=0.0, help="heartbeats after the last record, s"),
    corrupt: float = typer.Option(0.0, min=0.0, max=0.99, help="chance of a flipped bit"),
    drop: float = typer.Option(0.0, min=0.0, max=0.99, help="chance a record is lost"),
) -> None:
    """Serve a scenario's image-motion records like the hardware correlator, on a pty.

    The scenario runs open loop through the optical emulation and the device's pipeline
    timing; each record is written when the device would deliver it. Read it with
    `imc device-read LINK` or correlator.driver.Driver.
    """
    import time

    import numpy as np

    from compensation.loop import simulate
    from correlator.driver import PtyDevice, motion_records
    from imc import streams
    from imc.build import build_loop, build_models
    from imc.plants import RenderedPlant

    try:
        sc = load_scenario(scenario)
        c = sc.correlator.model_copy(update={
            "method": "optical", "subpixel": (sc.correlator.subpixel
                                              if sc.correlator.method == "optical" else None),
            "timing": sc.correlator.timing.model_copy(update={"enabled": True}),
            "link": sc.correlator.link.model_copy(update={"kind": "direct"})})
        sc = sc.model_copy(update={"correlator": c, "compensation": sc.compensation.model_copy(
            update={"enabled": False})})
        m = build_models(sc)
    except ScenarioError as e:
        _fail(str(e))
    with PtyDevice(link, streams.rng(sc.seed, "device_emulator"), corrupt_probability=corrupt,
                   drop_probability=drop) as dev:
        out.print(f"device on {link} -> {link.resolve()} ({m.timing.correlations_per_s:g} "
                  f"correlations/s); rendering and correlating {sc.n_frames} frames ...")
        parts = build_loop(m)
        rec = simulate(RenderedPlant(m), parts.estimator, parts.controller, parts.actuator,
                       parts.transport, parts.timeline, enabled=False).record
        sched = m.schedule
        kk, bb = np.nonzero(sched.done)
        order = np.argsort(sched.deliver_s[kk, bb], kind="stable")
        t0 = time.monotonic()
        for i in order:
            k, b = int(kk[i]), int(bb[i])
            t_dev = float(sched.deliver_s[k, b])
            if speed > 0:
                time.sleep(max(0.0, t0 + t_dev / speed - time.monotonic()))
            dev.send(motion_records(k, np.array([1e6 * t_dev]), rec.shift_px[k, b][None],
                                    rec.valid[k, b][None], rec.peak[k, b][None], [b]))
        end = time.monotonic() + linger_s
        while time.monotonic() < end:
            dev.heartbeat()
            time.sleep(0.25)
        dev.heartbeat()
        out.print(f"sent {dev.seq} records ({len(order)} motion) on {link}")


@app.command(name="device-read")
def device_read(
    port: str = typer.Argument(..., help="serial port, pty link or pyserial URL"),
    seconds: float = typer.Option(5.0, min=0.0, help="how long to listen"),
    baudrate: int = typer.Option(115200, help="line speed"),
) -> None:
    """Print the image-motion records a correlator sends, then the link's counters."""
    import time

    from correlator.driver import Driver, DriverError

    try:
        drv = Driver(port, baudrate=baudrate)
    except Exception as e:  # pyserial raises several types for a missing port
        _fail(f"{port}: cannot open ({e}); start `imc device-emulator` or check the cable")
    end = time.monotonic() + seconds
    try:
        with drv:
            while time.monotonic() < end:
                for r in drv.read(min(0.2, max(0.0, end - time.monotonic()))):
                    out.print(f"seq {r.seq:6d}  t {r.timestamp_us / 1e6:9.4f} s  frame "
                              f"{r.frame:5d}  block {r.block:3d}  shift {r.shift_px[0]:+8.4f} "
                              f"{r.shift_px[1]:+8.4f} px  psr {r.peak:6.1f}  "
                              f"{'valid' if r.valid else 'INVALID'}", highlight=False)
    except DriverError as e:
        _fail(str(e))
    s = drv.stats
    out.print(f"{s.records} records, {len(s.lost)} lost, {s.crc_errors} CRC errors, "
              f"{s.garbage_bytes} garbage bytes, {s.duplicates} duplicates, "
              f"{s.reconnects} reconnects")


@app.command(name="loop")
def loop_cmd(
    scenario: Path = typer.Argument(..., help="scenario YAML (its loop: rates, latency, "
                                    "controller, actuator)"),
    out_dir: Path = typer.Option(Path("runs/loop"), "--out", help="folder for loop.png and "
                                 "loop.json"),
    points: int = typer.Option(12, min=2, max=200, help="sine-sweep frequencies"),
    amplitude_px: float = typer.Option(0.1, min=1e-4, max=10.0,
                                       help="sine-sweep amplitude, px"),
) -> None:
    """Plot the loop's rejection |S(f)| (analytic model) beside a sine sweep of the same
    loop on the analytic plant, with the delay bound; write loop.png and loop.json."""
    from imc.build import build_loop, build_models
    from imc.loopplot import loop_study

    try:
        sc = load_scenario(scenario)
        parts = build_loop(build_models(sc))
    except ScenarioError as e:
        _fail(str(e))
    res = loop_study(parts.model, out_dir, n_sweep=points, amplitude_px=amplitude_px,
                     title=sc.name)
    mg = parts.margins
    out.print(f"{sc.name}: {_margins_text(mg)}; 0 dB crossover {mg.crossover_hz:.1f} Hz")
    out.print(f"sine sweep vs analytic |S|: largest difference {res['max_error_db']:.2f} dB "
              f"up to {res['f_max_compared_hz']:.1f} Hz (a quarter of the measurement rate)")
    out.print(f"wrote {res['png']} and {res['json']}")


bench_app = typer.Typer(add_completion=False, no_args_is_help=True,
                        help="Benchmarks (figures for README; never asserted in tests).")
app.add_typer(bench_app, name="bench")


@bench_app.command(name="correlator")
def bench_correlator(
    out_dir: Path = typer.Option(Path("benchmarks/out/correlator"), "--out",
                                 help="folder for correlator.json/.md and the PNG plots"),
    pairs: int = typer.Option(300, min=20, help="pairs per method table"),
    quick: bool = typer.Option(False, help="fewer block sizes, SNRs and repeats"),
    seed: int = typer.Option(0, help="seed of every random draw"),
) -> None:
    """Accuracy, validity and speed of every method and of the peers on the same pairs."""
    from correlator.bench import run as run_bench

    run_bench(out_dir, pairs=pairs, quick=quick, seed=seed, log=out.print)


def main() -> None:
    app()


if __name__ == "__main__":
    main()

"""The ``imc`` command line.

Commands: ``info`` (versions, the Mitsuba variant), ``validate`` (check a scenario, estimate
its size, the loop's margins; renders nothing), ``run`` (one scenario end to end: metrics,
tracks, report, Rerun recording), ``metrics`` (a run's metrics table), ``loop`` (the loop's
analytic and measured rejection), ``sweep`` (a parameter sweep on Dask), ``check`` (every
scenario against its ``expect:`` section, JUnit), ``design`` (requirements in, the cheapest
configuration out), ``report`` (a run's or sweep's report again), ``view`` (the Rerun
viewer), ``device-emulator`` / ``device-read`` (the hardware correlator's serial protocol on
a pseudo-terminal), ``bench correlator`` (the correlator against its bounds and its peers).

Every command ends in one line on bad input (exit 2: the scenario, a file or an argument,
named with the fix); an internal error (a bug) prints one line saying so and where the full
traceback was written (``imc-error.log`` in the output folder, or the system's temporary
folder), exit 1.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from imc.scenario import ScenarioError, error_line, installed_version, load_scenario
from imc.yamlload import YamlInputError, load_yaml, read_text, short

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="imcsim: satellite focal-plane image-motion-compensation simulator.")
err = Console(stderr=True)
out = Console()

ERROR_LOG = "imc-error.log"
#: the commands' parameters that name their output folder (where an internal error's
#: traceback goes when the folder exists)
OUT_PARAMETERS = ("out_raw", "out_dir")


def _log_dirs(kwargs: dict) -> tuple[Path, ...]:
    """The running command's output folder, if it names one that exists."""
    for name in OUT_PARAMETERS:
        raw = kwargs.get(name)
        if raw is not None and str(raw).strip():
            with contextlib.suppress(OSError):
                if Path(raw).is_dir():
                    return (Path(raw),)
    return ()


def _fail(msg: str, code: int = 2) -> None:
    err.print(f"[bold red]error:[/] {_one_line(msg)}", highlight=False, soft_wrap=True,
              markup=True)
    raise typer.Exit(code)


def _one_line(msg: str, limit: int = 600) -> str:
    """msg on one line, long words (paths, values) shortened, at most ``limit`` characters;
    rich markup in it is shown as text."""
    from rich.markup import escape

    words = [w if len(w) <= 120 else short(w, 100) for w in str(msg).split()]
    return escape(short(" ".join(words), limit))


def _internal_error(e: BaseException, folders: tuple[Path, ...] = ()) -> None:
    """One line for a bug, the traceback written to a log (in the first of ``folders`` that
    takes it, else the system's temporary folder); exit 1."""
    text = "".join(traceback.format_exception(e))
    where = None
    for folder in (*folders, Path(tempfile.gettempdir())):
        try:
            log = Path(folder) / ERROR_LOG
            log.write_text(f"imcsim {time.strftime('%Y-%m-%d %H:%M:%S')} {sys.argv!r}\n{text}")
            where = log
            break
        except OSError:
            continue
    what = f"{e.__class__.__name__}: {e}" if str(e) else e.__class__.__name__
    saved = f"; the full traceback is in {where}" if where else ""
    kind = ("ran out of memory (lower the sizes `imc validate` reports)"
            if isinstance(e, MemoryError) else "internal error (a bug in imcsim; please report "
            "it)")
    _fail(f"{kind}: {what}{saved}", code=1)


def _guarded(fn):
    """A command whose unexpected exceptions end in one line (see the module docstring)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (typer.Exit, typer.Abort, typer.TyperException, SystemExit):
            raise
        except KeyboardInterrupt:
            _fail("interrupted", code=130)
        except ScenarioError as e:
            _fail(str(e))
        except OSError as e:  # the disk, a folder that went away: not a bug, not the input
            name = f"{short(str(e.filename), 200)}: " if e.filename else ""
            _fail(f"{name}{e.strerror or e} (a file system error)", code=1)
        except BaseException as e:  # noqa: BLE001 (every other exception is a bug)
            _internal_error(e, _log_dirs(kwargs))

    return wrapper


def _finite(value: float | None) -> float | None:
    """Option callback: a number option must be finite (nan / inf are refused)."""
    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"{value} is not a finite number")
    return value


def _out_dir(raw: str, option: str = "--out") -> Path:
    """The output folder, created and checked writable before any work (exit 2 if not)."""
    if not raw.strip():
        _fail(f"{option}: the path is empty (it would write into the current folder); give a "
              "folder")
    p = Path(raw)
    name = short(raw, 120)
    try:
        if p.exists() and not p.is_dir():
            _fail(f"{option} {name}: is a file; give a folder")
        p.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=p, prefix=".imc-probe-"):
            pass
    except (NotADirectoryError, FileExistsError):
        _fail(f"{option} {name}: a part of the path is a file; give a folder")
    except PermissionError:
        _fail(f"{option} {name}: not writable (permission denied); choose another folder")
    except OSError as e:
        _fail(f"{option} {name}: cannot use it as a folder ({e.strerror or e})")
    return p


def _size_check(sc, force: bool):
    """The run's estimate (imc.wiring.budget), refused above the budget unless ``force``."""
    from imc.wiring.budget import check_run_size, estimate_run
    from scene.geotiff import GeoTiffError

    try:
        est = estimate_run(sc)
    except GeoTiffError as e:
        _fail(str(e))
    check_run_size(sc, est, force)
    return est


def _num(v, fmt: str = ".3f") -> str:
    """A number of metrics.json (null: a quantity that could not be computed) as text."""
    return "n/a" if v is None else format(v, fmt)


@app.command()
@_guarded
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
    out.print(f"imcsim {installed_version()}  python {sys.version.split()[0]}  "
              f"numpy {numpy.__version__}  "
              f"scipy {scipy.__version__}  mitsuba {v['mitsuba']}  drjit {v['drjit']}")
    out.print(f"mitsuba variant: {choice.variant}  ({choice.reason})")
    out.print(f"libLLVM for Dr.Jit: {choice.libllvm_path or 'none usable'}")


@app.command()
@_guarded
def validate(
    scenario: Path = typer.Argument(..., help="scenario YAML"),
    force: bool = typer.Option(False, "--force", help="check a run larger than the memory "
                               "budget or the frame limit anyway"),
) -> None:
    """Check a scenario file, its geometry and its loop design without rendering; print the
    run's size (frames, peak memory)."""
    from imc.wiring.advisories import advisories
    from imc.wiring.budget import LIGHT_TEXELS
    from imc.wiring.build import build_loop, build_models

    sc = load_scenario(scenario)
    est = _size_check(sc, force)
    models = build_models(sc, light=True)
    parts = build_loop(models)
    if sc.product.enabled:
        from imc.wiring.product import plan_product

        plan_product(models)
    figures, warnings = advisories(models, parts)
    mg = parts.margins
    name = short(str(scenario), 200)
    loop = (f"loop {sc.compensation.controller.kind}: {_margins_text(mg)}"
            if sc.compensation.enabled else "loop off: compensation.enabled is false")
    out.print(f"{name}: ok ({sc.n_frames} frames, {sc.correlator.n_blocks} blocks; {loop})",
              highlight=False, soft_wrap=True)
    out.print(f"run size: {est.text()}", highlight=False, soft_wrap=True)
    if sc.compensation.enabled:
        out.print(_lock_text(figures["lock"], sc), highlight=False, soft_wrap=True)
    for line in warnings:
        err.print(f"[yellow]warning:[/] {line}", highlight=False, soft_wrap=True)
    if est.texels > LIGHT_TEXELS and sc.scene.kind != "geotiff":
        out.print(f"terrain not built ({est.texels / 1e6:.1f} M texels): the geometry was "
                  "checked on a flat tile of the same size; `imc run` checks it on the terrain",
                  highlight=False, soft_wrap=True)


def _product_text(p: dict) -> str:
    """The product's headline figures, a few lines."""
    q, g = p["quality"], p["geometry"]
    lines = [f"product: {p['kind']} {p['lines']} x {p['cols']} px, {p['rays'] / 1e6:.1f} M "
             f"rays at {p['rays_per_s'] / 1e6:.1f} M/s (hit fraction {p['hit_fraction']:.7f})"]
    for name, d in q.items():
        lines.append(f"  {name:20s} MTF@Nyquist {_num(d['mtf_nyquist'][0], '.3f')} / "
                     f"{_num(d['mtf_nyquist'][1], '.3f')}  NIIRS {_num(d['niirs'], '.3f')}"
                     f" (loss {_num(d['niirs_loss'], '.3f')})  SSIM {_num(d['ssim'], '.4f')}")
    for name, e in g.items():
        lines.append(f"  {name} lines' offset error RMS row/col px: before "
                     f"{_num(e['before']['rms_px'][0], '.4f')} / "
                     f"{_num(e['before']['rms_px'][1], '.4f')}, after a constant "
                     f"{_num(e['after']['rms_px'][0], '.4f')} / "
                     f"{_num(e['after']['rms_px'][1], '.4f')}, after an affine "
                     f"{_num(e['affine']['rms_px'][0], '.4f')} / "
                     f"{_num(e['affine']['rms_px'][1], '.4f')}, perfect record "
                     f"{_num(e['after_perfect_record']['rms_px'][0], '.4f')} / "
                     f"{_num(e['after_perfect_record']['rms_px'][1], '.4f')}")
        if "control_points" in e:
            cp = e["control_points"]["rms_px"]
            lines.append(f"    with the control points, nothing removed: {_num(cp[0], '.4f')}"
                         f" / {_num(cp[1], '.4f')}")
    rec = p.get("record", {})
    if "predicted" in rec:
        r = rec.get("restitution", {})
        lines.append(f"  record: {r.get('baselines')} baselines, {r.get('links')} links"
                     f"{' + ' + ' + '.join(r['aiding']) if r.get('aiding') else ''}; "
                     f"predicted error after a constant "
                     f"{_num(rec['predicted']['constant_px'][0], '.4f')} / "
                     f"{_num(rec['predicted']['constant_px'][1], '.4f')}, after an affine "
                     f"{_num(rec['predicted']['affine_px'][0], '.4f')} / "
                     f"{_num(rec['predicted']['affine_px'][1], '.4f')} px")
    return "\n".join(lines)


def _lock_text(lock: dict, sc) -> str:
    """The loop's lock time against the main imager's start, one line."""
    t = lock["analytic_s"]
    text = (f"loop locks in {t:.3g} s (analytic step response within {lock['band']:.0%})"
            if t is not None else "loop never locks (analytic model)")
    if lock.get("measured_s") is not None:
        text += f", {lock['measured_s']:.3g} s in this run"
    return text + f"; main imager from {sc.camera.main_imager.start_s:g} s"


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
        return f"{_num(v[0])} / {_num(v[1])}"

    tab.add_row("RMS row / col", pair(o["rms_px"]), pair(c["rms_px"]))
    tab.add_row("RMS total", _num(o["rms_total_px"]), _num(c["rms_total_px"]))
    tab.add_row("peak-to-peak row / col", pair(o["peak_to_peak_px"]), pair(c["peak_to_peak_px"]))
    tab.add_row(f"motion MTF @Nyquist row / col ({_num(o['window_s'], '.3g')} s)",
                pair(o["mtf_nyquist"]), pair(c["mtf_nyquist"]))
    tab.add_row("worst-window MTF row / col", pair(o["mtf_nyquist_worst"]),
                pair(c["mtf_nyquist_worst"]))
    return tab


@app.command()
@_guarded
def run(
    scenario: Path = typer.Argument(..., help="scenario YAML"),
    out_raw: str = typer.Option("runs/out", "--out", help="output folder"),
    save_frames: bool = typer.Option(False, "--save-frames", help="also write frames.npz"),
    fresh: bool = typer.Option(False, "--fresh", help="ignore a checkpoint in --out"),
    no_rerun: bool = typer.Option(False, "--no-rerun", help="skip recording.rrd"),
    force: bool = typer.Option(False, "--force", help="run even above the memory budget or "
                               "the frame limit (see imc validate)"),
    no_report: bool = typer.Option(False, "--no-report", help="skip report.html and its "
                                   "figures"),
) -> None:
    """Run a scenario: render, track, compensate; write metrics, tracks, a recording and
    report.html. With an `expect:` section, print its pass/fail table; exit 1 on a fail."""
    from rich.progress import Progress

    from imc.io import remove_stale_temps
    from imc.pipeline import run_scenario
    from scene.variant import VariantError, choose_variant

    sc = load_scenario(scenario)
    out_dir = _out_dir(out_raw)
    _size_check(sc, force)
    for folder in (out_dir, out_dir / "checkpoint"):  # what a killed write left
        remove_stale_temps(folder)
    try:
        choice = choose_variant()
    except VariantError as e:
        _fail(str(e))
    if choice.variant.startswith("scalar"):
        err.print(f"[yellow]warning:[/] rendering with Mitsuba {choice.variant}: {choice.reason}",
                  highlight=False, soft_wrap=True)
    try:
        with Progress(console=err, transient=True) as prog:
            task = prog.add_task(f"{sc.name}: frames", total=sc.n_frames)
            metrics, run_info = run_scenario(
                sc, out_dir, save_frames=save_frames, fresh=fresh, rerun=not no_rerun,
                report_figures=not no_report, parallel_outputs=True,
                progress=lambda done, n: prog.update(task, completed=done),
                warn=lambda msg: err.print(f"[yellow]warning:[/] {msg}", highlight=False,
                                           soft_wrap=True))
    except ScenarioError as e:
        _fail(str(e))
    out.print(_table(metrics))
    t = metrics["tracker"]
    out.print(f"tracker: {t['valid_fraction'] * 100:.1f} % valid, error RMS row/col "
              f"{_num(t['rms_error_px'][0], '.4f')} / {_num(t['rms_error_px'][1], '.4f')} px "
              f"(CRLB {_num(t['median_crlb_px'][0], '.4f')} / "
              f"{_num(t['median_crlb_px'][1], '.4f')} px)")
    out.print(f"residual RMS reduced {_num(metrics['rms_reduction'], '.1f')}x by the loop")
    lp = metrics["loop"]
    if sc.compensation.enabled:
        ex = metrics["exposures"]
        out.print(_lock_text(lp["lock"], sc) + f"; {ex['worse_than_open']} of {ex['n']} "
                  "main-imager exposures worse with the loop than without", highlight=False)
        for d in lp.get("supervisor", {}).get("decisions", []):
            err.print(f"[yellow]warning:[/] supervisor at {d['t_s']:.3f} s: {d['action']} "
                      f"({d['reason']})", highlight=False, soft_wrap=True, markup=True)
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
    if "product" in metrics:
        out.print(_product_text(metrics["product"]), highlight=False)
    resumed = run_info["resumed_from_frame"]
    out.print(f"wall time {run_info['wall_s']:.1f} s (build, render and loop "
              f"{run_info['loop_s']:.1f} s, of it rendering {run_info['render_s']:.1f} s; "
              f"checkpoint {run_info['checkpoint_bytes'] / 1e6:.1f} MB)"
              + (f", resumed at frame {resumed}" if resumed else ""))
    out.print("wrote " + ", ".join(run_info["files"]))
    _finish_run(sc, out_dir, metrics, report=not no_report, drawn=run_info.get("figures"))


def _finish_run(sc, out_dir: Path, metrics: dict, report: bool, drawn=None) -> None:
    """The expectations' table (exit 1 when one fails) and the report of a finished run
    (``drawn``: its figures, as the run drew them)."""
    import dataclasses

    from imc.io import write_json
    from imc.outputs.htmlreport import EXPECTATIONS, write_run_report
    from imc.workflow.expect import judge

    outcomes = judge(sc.expect, metrics)
    path = Path(out_dir) / EXPECTATIONS
    if outcomes:
        write_json(path, [dataclasses.asdict(o) for o in outcomes])
    else:
        path.unlink(missing_ok=True)
    if report:
        out.print(f"report: {write_run_report(out_dir, drawn)}")
    if outcomes:
        out.print(_expect_table(sc.name, outcomes))
        bad = sum(not o.passed for o in outcomes)
        if bad:
            err.print(f"[bold red]{bad} of {len(outcomes)} expectations failed[/]",
                      highlight=False)
            raise typer.Exit(1)


def _expect_table(name: str, outcomes) -> Table:
    tab = Table(title=f"{name}: expectations")
    for col in ("metric", "expected", "value", "result"):
        tab.add_column(col, justify="left" if col == "metric" else "right")
    for o in outcomes:
        tab.add_row(o.path, o.bound, o.value, "[green]pass[/]" if o.passed else
                    f"[bold red]FAIL[/]{': ' + o.note if o.note else ''}")
    return tab


@app.command(name="metrics")
@_guarded
def show_metrics(out_dir: Path = typer.Argument(..., help="a run's output folder")) -> None:
    """Print the summary table of a finished run."""
    path, name = out_dir, short(str(out_dir), 200)
    try:
        if out_dir.is_dir():
            path = out_dir / "metrics.json"
            name = short(str(path), 200)
        if path.stat().st_size > 50_000_000:
            _fail(f"{name}: larger than any metrics.json of imcsim; give a run's folder")
        metrics = json.loads(path.read_text(encoding="utf-8"))
        table = _table(metrics)
    except FileNotFoundError:
        _fail(f"{name}: not found; give the --out folder of a finished `imc run`")
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        _fail(f"{name}: cannot read it ({e.__class__.__name__}: {e})")
    except (KeyError, TypeError, IndexError, AttributeError) as e:
        _fail(f"{name}: not a metrics file of `imc run` ({e.__class__.__name__}: {e} is "
              "missing or of the wrong type)")
    out.print(table)


@app.command(name="device-emulator")
@_guarded
def device_emulator(
    scenario: Path = typer.Argument(..., help="scenario YAML (its correlator section is used)"),
    link: Path = typer.Option(Path("/tmp/imc-jtoc"), "--link",
                              help="symlink to the pseudo-terminal the device serves"),
    speed: float = typer.Option(1.0, min=0.0, max=1e6, callback=_finite,
                                help="device time / wall time (0: no waiting)"),
    linger_s: float = typer.Option(2.0, min=0.0, max=86400.0, callback=_finite,
                                   help="heartbeats after the last record, s"),
    corrupt: float = typer.Option(0.0, min=0.0, max=0.99, callback=_finite,
                                  help="chance of a flipped bit"),
    drop: float = typer.Option(0.0, min=0.0, max=0.99, callback=_finite,
                               help="chance a record is lost"),
    force: bool = typer.Option(False, "--force", help="serve a run above the memory budget "
                               "or the frame limit"),
) -> None:
    """Serve a scenario's image-motion records like the hardware correlator, on a pty.

    The scenario runs open loop through the optical emulation and the device's pipeline
    timing; each record is written when the device would deliver it. Read it with
    `imc device-read LINK` or correlator.driver.Driver.
    """
    import time

    from correlator.driver import PtyDevice
    from imc.wiring import streams
    from imc.wiring.build import build_models
    from imc.wiring.emulator import as_device, device_records

    sc = as_device(load_scenario(scenario))
    _size_check(sc, force)
    _link_folder(link)
    m = build_models(sc)
    with PtyDevice(link, streams.rng(sc.seed, "device_emulator"), corrupt_probability=corrupt,
                   drop_probability=drop) as dev:
        out.print(f"device on {link} -> {link.resolve()} ({m.timing.correlations_per_s:g} "
                  f"correlations/s); rendering and correlating {sc.n_frames} frames ...")
        t0 = time.monotonic()
        n_motion = 0
        for t_dev, records in device_records(m):
            if speed > 0:
                time.sleep(max(0.0, t0 + t_dev / speed - time.monotonic()))
            dev.send(records)
            n_motion += 1
        end = time.monotonic() + linger_s
        while time.monotonic() < end:
            dev.heartbeat()
            time.sleep(0.25)
        dev.heartbeat()
        out.print(f"sent {dev.seq} records ({n_motion} motion) on {link}")


def _link_folder(link: Path) -> None:
    """The folder of --link must exist and be writable (the device's symlink goes there)."""
    folder = link.parent
    name = short(str(link), 120)
    try:
        if link.is_dir():
            _fail(f"--link {name}: is a folder; give the path of the symlink to create")
        if not folder.is_dir():
            _fail(f"--link {name}: the folder {short(str(folder), 120)} does not exist; create "
                  "it or choose another path")
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".imc-probe-"):
            pass
    except PermissionError:
        _fail(f"--link {name}: its folder is not writable; choose another path")
    except OSError as e:
        _fail(f"--link {name}: cannot use it ({e.strerror or e})")


@app.command(name="device-read")
@_guarded
def device_read(
    port: str = typer.Argument(..., help="serial port, pty link or pyserial URL"),
    seconds: float = typer.Option(5.0, min=0.0, max=1e7, callback=_finite,
                                  help="how long to listen"),
    baudrate: int = typer.Option(115200, min=50, max=10_000_000, help="line speed"),
) -> None:
    """Print the image-motion records a correlator sends, then the link's counters."""
    import time

    from correlator.driver import Driver, DriverError

    try:
        drv = Driver(port, baudrate=baudrate)
    except Exception as e:  # pyserial raises several types for a missing port
        _fail(f"{short(port, 120)}: cannot open ({e}); start `imc device-emulator` or check "
              "the cable")
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
@_guarded
def loop_cmd(
    scenario: Path = typer.Argument(..., help="scenario YAML (its loop: rates, latency, "
                                    "controller, actuator)"),
    out_raw: str = typer.Option("runs/loop", "--out", help="folder for loop.png and "
                                "loop.json"),
    points: int = typer.Option(12, min=2, max=200, help="sine-sweep frequencies"),
    amplitude_px: float = typer.Option(0.1, min=1e-4, max=10.0, callback=_finite,
                                       help="sine-sweep amplitude, px"),
    force: bool = typer.Option(False, "--force", help="build a run above the memory budget "
                               "or the frame limit"),
) -> None:
    """Plot the loop's rejection |S(f)| (analytic model) beside a sine sweep of the same
    loop on the analytic plant, with the delay bound; write loop.png and loop.json."""
    from imc.outputs.loopplot import loop_study
    from imc.wiring.build import build_loop, build_models

    sc = load_scenario(scenario)
    out_dir = _out_dir(out_raw)
    _size_check(sc, force)
    parts = build_loop(build_models(sc, light=True))
    res = loop_study(parts.model, out_dir, n_sweep=points, amplitude_px=amplitude_px,
                     title=sc.name)
    mg = parts.margins
    out.print(f"{sc.name}: {_margins_text(mg)}; 0 dB crossover {mg.crossover_hz:.1f} Hz")
    off = " (line identification off)" if res["sweep_identification_off"] else ""
    out.print(f"sine sweep{off} vs analytic |S|: largest difference {res['max_error_db']:.2f} "
              f"dB up to {res['f_max_compared_hz']:.1f} Hz (a quarter of the measurement rate)")
    if res["sweep_measured_adaptive"] is not None:
        import numpy as np

        gain = np.array(res["sweep_analytic"]) / np.maximum(res["sweep_measured_adaptive"], 1e-12)
        inside = np.array(res["sweep_hz"]) <= res["f_max_compared_hz"]
        out.print(f"with identification the sine is found as a line: up to "
                  f"{20 * np.log10(gain[inside].max()):.1f} dB below |S(f)|")
    out.print(f"wrote {res['png']} and {res['json']}")


_WORKERS_HELP = ("worker processes of a local Dask cluster (one thread each; default: one "
                 "per core; 0: run in this process)")
_SCHEDULER_HELP = ("address of a running Dask scheduler (tcp://HOST:8786), started with "
                   "`dask scheduler` and `dask worker ADDRESS --nthreads 1`")
_MEMORY_HELP = "memory limit of each local worker (e.g. 4GiB; auto: the machine's / workers)"


@app.command()
@_guarded
def sweep(
    sweep_file: Path = typer.Argument(..., help="sweep YAML (base scenario, axes, mode, "
                                      "seeds, metrics)"),
    out_dir: Path = typer.Option(..., "--out", help="sweep folder (points/, results.*, "
                                 "report.html); a rerun into it skips finished points"),
    workers: int | None = typer.Option(None, "--workers", min=0, help=_WORKERS_HELP),
    scheduler: str | None = typer.Option(None, "--scheduler", help=_SCHEDULER_HELP),
    memory_limit: str = typer.Option("auto", "--memory-limit", help=_MEMORY_HELP),
    retry_failed: bool = typer.Option(False, "--retry-failed", help="run failed points "
                                      "again"),
    fresh: bool = typer.Option(False, "--fresh", help="run every point again, each earlier "
                               "result replaced as its point finishes (a point is known by "
                               "its scenario and the code's source, so a code change already "
                               "runs it again)"),
    no_report: bool = typer.Option(False, "--no-report", help="skip report.html"),
    force: bool = typer.Option(False, "--force", help="run points above the memory budget "
                               "or the frame limit, or more points than the sweep limit"),
) -> None:
    """Run a parameter sweep on Dask: every point's metrics in OUT/points/, results as
    NetCDF (xarray), Parquet and CSV, and report.html with line plots and heat maps."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from imc.outputs.htmlreport import write_sweep_report
    from imc.workflow.distribute import SchedulerError, runner
    from imc.workflow.sweep import SweepError, load_sweep, run_sweep

    try:
        sw = load_sweep(sweep_file, force)
    except SweepError as e:
        _fail(str(e))
    out_dir = _out_dir(str(out_dir))
    n = len({p.digest for p in sw.points})
    out.print(f"{sw.config.name}: {len(sw.points)} points ({n} distinct scenarios) over "
              + " x ".join(f"{a} ({len(v)})" for a, v in sw.axes.items())
              + f", {sw.config.seeds} seed(s), mode {sw.config.mode}")
    try:
        with runner(workers, scheduler, memory_limit) as run_on:
            out.print(f"running on {run_on.description}")
            with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                          TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                          console=err, transient=True) as prog:
                task = prog.add_task("points", total=n)
                started: list[int] = []

                def progress(done: int, total: int) -> None:
                    if not started:  # the ETA counts the points run here, not those skipped
                        started.append(done)
                        prog.reset(task, total=total - done, completed=0)
                    prog.update(task, completed=done - started[0])

                summary = run_sweep(sw, out_dir, run_on, progress=progress,
                                    retry_failed=retry_failed, fresh=fresh)
    except SchedulerError as e:
        _fail(str(e))
    out.print(f"{summary.ran} points run, {summary.skipped} already done, {summary.failed} "
              f"failed, {len(summary.lost)} lost (rerun to retry) in {summary.wall_s:.1f} s")
    if summary.skipped:
        out.print(f"{summary.skipped} points kept from {out_dir}/points/ (run by this "
                  "code): --fresh runs them again")
    for line in summary.errors[:10]:
        err.print(f"[yellow]failed:[/] {line}", highlight=False, soft_wrap=True)
    for line in summary.lost[:10]:
        err.print(f"[yellow]lost:[/] {line}", highlight=False, soft_wrap=True)
    files = list(summary.files)
    if not no_report:
        files.append(str(write_sweep_report(out_dir)))
    out.print("wrote " + ", ".join(files))


@app.command()
@_guarded
def design(
    design_file: Path = typer.Argument(..., help="design YAML (base scenario, requirements, "
                                       "free parameters, cost)"),
    out_dir: Path = typer.Option(..., "--out", help="design folder (design.json, design.html"
                                 ", the chosen design's scenario, verify*/ runs)"),
    no_verify: bool = typer.Option(False, "--no-verify", help="skip the full runs of the "
                                   "best designs"),
    workers: int = typer.Option(2, "--workers", min=1, help="processes for the search"),
) -> None:
    """From requirements to the cheapest configuration that meets them: fast predictions of
    every candidate, the Pareto front, the best few run in full; exit 1 when no candidate
    meets every requirement (the closest one and what limits it in one line)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from imc.workflow.design import closest_line, load_design, run_design

    d = load_design(design_file)
    out_dir = _out_dir(str(out_dir))
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=err, transient=True) as prog:
        task = prog.add_task("loops", total=None)

        def progress(done: int, total: int) -> None:
            prog.update(task, completed=done, total=total)

        res = run_design(d, out_dir, verify_runs=not no_verify, progress=progress,
                         log=lambda s: out.print(s, highlight=False, soft_wrap=True),
                         workers=workers)
    for v in res.verified:
        table = Table(title=f"{v['design']}: predicted against measured "
                      f"({v['seeds_passed']} of {len(next(iter(v['measured'].values())))} "
                      "seeds meet every requirement)")
        for col in ("requirement", "predicted", "measured (seeds)", "error"):
            table.add_column(col)
        for p, pv in v["predicted"].items():
            table.add_row(p, f"{pv:.4g}", ", ".join(f"{x:.4g}" for x in v["measured"][p]),
                          f"{100 * v['relative_error'][p]:.0f} %")
        out.print(table)
    if res.verified:
        errs = [e for v in res.verified for e in v["margin_error"].values()
                if math.isfinite(e)]
        missed = [v["design"] for v in res.verified if not v["all_seeds_pass"]]
        worst = max(errs) if errs else math.nan
        out.print(f"validated margin error {worst:.3f} (|predicted - measured margin|, the "
                  f"worst); the chosen design's predicted margin "
                  f"{res.candidates.worst[res.chosen]:.3f}"
                  + ("; designs that MISSED in a full run: " + "; ".join(missed)
                     if missed else "; every verified design met every requirement"),
                  highlight=False, soft_wrap=True)
    out.print("wrote " + ", ".join(res.files))
    if res.chosen is None:
        _fail(closest_line(res.candidates), code=1)


def _scenario_files(paths: list[Path]) -> list[Path]:
    """The scenario YAMLs under the paths (folders searched recursively; sweep and design
    files left out), in order, each once."""

    from imc.workflow.design import is_design_file
    from imc.workflow.sweep import is_sweep_file

    def sweep_like(f: Path) -> bool:
        try:
            data = load_yaml(read_text(f))
            return is_sweep_file(data) or is_design_file(data)
        except YamlInputError:
            return False  # load_scenario names the problem

    found: list[Path] = []
    for p in paths:
        if not p.exists():
            _fail(f"{p}: no such file or folder")
        for f in sorted(p.rglob("*.yaml")) + sorted(p.rglob("*.yml")) if p.is_dir() else [p]:
            # a file named on the command line is a scenario; in a folder, sweeps and designs
            # are skipped
            if not (p.is_dir() and sweep_like(f)) and f not in found:
                found.append(f)
    return found


def _missing_inputs(sc) -> list[Path]:
    """The input files a scenario names that are not on disk (its GeoTIFFs, series, OEM)."""
    from pydantic import BaseModel

    missing: list[Path] = []

    def walk(v) -> None:
        if isinstance(v, Path):
            if not v.exists():
                missing.append(v)
        elif isinstance(v, BaseModel):
            for name in type(v).model_fields:
                walk(getattr(v, name))
        elif isinstance(v, list | tuple):
            for x in v:
                walk(x)
        elif isinstance(v, dict):
            for x in v.values():
                walk(x)

    walk(sc)
    return missing


@app.command()
@_guarded
def check(
    paths: list[Path] = typer.Argument(..., help="scenario files or folders (searched for "
                                       "*.yaml; sweep and design files are skipped)"),
    junit: Path | None = typer.Option(None, "--junit", help="write JUnit XML here (one "
                                      "testcase per scenario)"),
    out_dir: Path = typer.Option(Path("runs/check"), "--out", help="folder of the runs "
                                 "(one subfolder per scenario)"),
    workers: int | None = typer.Option(None, "--workers", min=0, help="run on a local Dask "
                                       "cluster of this many workers (default: one after "
                                       "another in this process)"),
    scheduler: str | None = typer.Option(None, "--scheduler", help=_SCHEDULER_HELP),
    memory_limit: str = typer.Option("auto", "--memory-limit", help=_MEMORY_HELP),
    report: bool = typer.Option(False, "--report", help="also write each run's report.html"),
    force: bool = typer.Option(False, "--force", help="run scenarios above the memory "
                               "budget or the frame limit"),
) -> None:
    """Run every scenario under PATHS and judge its `expect:` section; exit 1 when an
    expectation fails or a run errs. --junit writes the results for a CI system."""
    from imc.workflow.distribute import SchedulerError, Task, runner
    from imc.workflow.expect import CaseResult, Outcome, check_one, write_junit

    out_dir = _out_dir(str(out_dir))
    files = _scenario_files(paths)
    if not files:
        _fail(f"no scenario files under {', '.join(map(str, paths))}")
    scenarios = []
    for f in files:
        try:
            sc = load_scenario(f)
            missing = _missing_inputs(sc)
            if missing:  # user data `make data` fetches (the Olinda case): not a failure
                out.print(f"skipped  {sc.name} ({f}): its input {missing[0]} is not there "
                          "(`make data` fetches the bundled cases' data)", highlight=False,
                          soft_wrap=True)
                continue
            _size_check(sc, force)
            scenarios.append((f, sc))
        except ScenarioError as e:
            if junit is not None:
                write_junit(junit, [CaseResult(f.stem, str(f), 0.0, error=str(e))])
            _fail(str(e))
    names = [sc.name for _, sc in scenarios]
    dirs = [f"{sc.name}" if names.count(sc.name) == 1 else f"{sc.name}_{i}"
            for i, (_, sc) in enumerate(scenarios)]
    tasks = [Task(str(i), check_one, (str(f), str(out_dir / d), report))
             for i, ((f, _), d) in enumerate(zip(scenarios, dirs, strict=True))]
    results: dict[int, CaseResult] = {}
    try:
        with runner(0 if workers is None and scheduler is None else workers, scheduler,
                    memory_limit) as run_on:
            out.print(f"checking {len(tasks)} scenarios on {run_on.description}")
            for key, res in run_on.run(tasks):
                f, sc = scenarios[int(key)]
                if isinstance(res, BaseException):
                    res = {"name": sc.name, "source": str(f), "time_s": 0.0,
                           "error": error_line(res)}
                case = CaseResult(res["name"], res["source"], res["time_s"],
                                  tuple(Outcome(**o) for o in res.get("outcomes", ())),
                                  res.get("error"))
                results[int(key)] = case
                verdict = ("[green]pass[/]" if case.passed else "[bold red]ERROR[/]"
                           if case.error else "[bold red]FAIL[/]")
                out.print(f"{verdict}  {case.name} ({f}, {case.time_s:.1f} s"
                          + (f", {len(case.outcomes)} expectations)" if case.outcomes
                             else ", no expectations)"), highlight=False)
                for line in ([case.error] if case.error else
                             [o.line() for o in case.outcomes if not o.passed]):
                    out.print(f"      {line}", highlight=False, soft_wrap=True)
    except SchedulerError as e:
        _fail(str(e))
    cases = [results[i] for i in sorted(results)]
    if junit is not None:
        write_junit(junit, cases)
        out.print(f"wrote {junit}")
    bad = sum(not c.passed for c in cases)
    out.print(f"{len(cases) - bad} of {len(cases)} scenarios passed")
    if bad:
        raise typer.Exit(1)


@app.command(name="report")
@_guarded
def report_cmd(run_dir: Path = typer.Argument(..., help="a run folder (metrics.json) or a "
                                              "sweep folder (results.nc)")) -> None:
    """Write report.html and its PNG figures again for a run or a sweep folder."""
    from imc.outputs.htmlreport import write_run_report, write_sweep_report

    if (run_dir / "sweep.json").exists() and (run_dir / "results.nc").exists():
        out.print(f"wrote {write_sweep_report(run_dir)}")
    elif (run_dir / "metrics.json").exists():
        out.print(f"wrote {write_run_report(run_dir)}")
    else:
        _fail(f"{run_dir}: neither a run folder (metrics.json) nor a sweep folder "
              "(sweep.json, results.nc); run `imc run` or `imc sweep` first")


@app.command()
@_guarded
def view(
    run_dir: Path = typer.Argument(..., help="a run folder (recording.rrd) or a .rrd file"),
    web: bool = typer.Option(False, "--web", help="serve the web viewer instead of "
                             "opening a window"),
) -> None:
    """Open a run's Rerun recording (with its layout) in the Rerun viewer."""
    import os
    import shutil
    import subprocess

    rrd = run_dir if run_dir.suffix == ".rrd" else run_dir / "recording.rrd"
    if not rrd.is_file():
        _fail(f"{rrd}: no recording (run `imc run` without --no-rerun first)")
    exe = Path(sys.executable).parent / "rerun"
    exe_s = str(exe) if exe.exists() else shutil.which("rerun")
    if exe_s is None:
        _fail("the Rerun viewer is not installed: pip install rerun-sdk")
    if not web and sys.platform.startswith("linux") and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        _fail("no display for the viewer window: use `imc view --web`, or copy "
              f"{rrd} to a machine with one and run `rerun {rrd.name}`")
    cmd = [exe_s, *(["--web-viewer"] if web else []), str(rrd)]
    out.print(" ".join(cmd))
    raise typer.Exit(subprocess.call(cmd))


bench_app = typer.Typer(add_completion=False, no_args_is_help=True,
                        help="Benchmarks (figures for docs/; never asserted in tests).")
app.add_typer(bench_app, name="bench")


@bench_app.command(name="correlator")
@_guarded
def bench_correlator(
    out_raw: str = typer.Option("benchmarks/out/correlator", "--out",
                                help="folder for correlator.json/.md and the PNG plots"),
    pairs: int = typer.Option(300, min=20, max=5000, help="pairs per method table"),
    quick: bool = typer.Option(False, help="fewer block sizes, SNRs and repeats"),
    seed: int = typer.Option(0, min=0, max=2**63 - 1, help="seed of every random draw"),
) -> None:
    """Accuracy, validity and speed of every method and of the peers on the same pairs."""
    from imc.studies.correlator_peers import run as run_bench

    run_bench(_out_dir(out_raw), pairs=pairs, quick=quick, seed=seed, log=out.print)


def main(argv: list[str] | None = None) -> None:
    """The ``imc`` entry point: bad arguments end in one line too (exit 2)."""
    try:
        code = app(argv, prog_name="imc", standalone_mode=False)
    except typer.TyperException as e:
        if type(e).__name__ == "NoArgsIsHelpError":  # `imc` or `imc bench` alone: the help
            out.print(str(e), highlight=False, markup=False)
            raise SystemExit(0) from None
        ctx = getattr(e, "ctx", None)
        where = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        with contextlib.suppress(typer.Exit):
            _fail(f"{e.format_message()}{where}", code=getattr(e, "exit_code", 2) or 2)
        raise SystemExit(getattr(e, "exit_code", 2) or 2) from None
    except (KeyboardInterrupt, typer.Abort):
        err.print("[bold red]error:[/] interrupted", highlight=False)
        raise SystemExit(130) from None
    raise SystemExit(code or 0)


#: commands after which the ``imc`` process ends without the interpreter's teardown (those
#: that leave nothing running: not sweep, check, view or the device commands)
QUICK_EXIT_COMMANDS = frozenset({"run", "validate", "metrics", "report", "info"})


def entry() -> None:
    """The ``imc`` console script: :func:`main`; after the commands of
    :data:`QUICK_EXIT_COMMANDS` the process then ends without the interpreter's teardown
    (after ``imc run`` ~0.5 s of freeing numba's and Dr.Jit's compilers and the run's arrays,
    after ``imc validate`` ~0.1 s), its output flushed: every file a command writes is
    closed and renamed into place before it returns, and a run's helper process has
    ended."""
    try:
        main()
    except SystemExit as e:
        if sys.argv[1:2] and sys.argv[1] not in QUICK_EXIT_COMMANDS:
            raise
        code = e.code
    else:  # main() always ends in SystemExit
        code = 0
    if not isinstance(code, int):  # SystemExit's own rule: a message is printed, status 1
        if code is not None:
            print(code, file=sys.stderr)
        code = 0 if code is None else 1
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe (`imc ... | head`)
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()

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
    """Check a scenario file and its geometry without rendering."""
    from imc.pipeline import build_models

    try:
        sc = load_scenario(scenario)
        build_models(sc)
    except ScenarioError as e:
        _fail(str(e))
    out.print(f"{scenario}: ok ({sc.n_frames} frames, {sc.correlator.n_blocks} blocks)")


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
                progress=lambda done, n: prog.update(task, completed=done))
    except ScenarioError as e:
        _fail(str(e))
    out.print(_table(metrics))
    t = metrics["tracker"]
    out.print(f"tracker: {t['valid_fraction'] * 100:.1f} % valid, error RMS row/col "
              f"{t['rms_error_px'][0]:.4f} / {t['rms_error_px'][1]:.4f} px "
              f"(CRLB {t['median_crlb_px'][0]:.4f} / {t['median_crlb_px'][1]:.4f} px)")
    out.print(f"residual RMS reduced {metrics['rms_reduction']:.1f}x by the loop")
    resumed = run_info["resumed_from_frame"]
    out.print(f"wall time {run_info['wall_s']:.1f} s (rendering {run_info['render_s']:.1f} s)"
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

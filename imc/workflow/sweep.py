"""Parameter sweeps: a base scenario, axes of dotted field paths, points run on Dask.

A sweep file::

    name: tradeoff
    base: ../seed_device.yaml          # a scenario file (relative to this file) or a mapping
    set: {duration_s: 5.0}             # fixed changes to the base (dotted paths)
    mode: grid                         # grid: every combination; zip: the i-th of each axis
    seeds: 2                           # repeats with seed = base seed + 0, 1, ...
    axes:
      correlator.timing.transforms_per_s: [15, 30, 60]
      compensation.transport.latency_s: {linear: [0.0, 0.1, 5]}
      attitude.jitter.sinusoids.0.frequency_hz: {log: [0.2, 5.0, 6]}
    metrics: [with_compensation.rms_total_px, with_compensation.mtf_nyquist_worst.0]

Every point is validated by the scenario schema before anything runs (an error names the
axis and the field). Each finished point is written atomically to
``OUT/points/<digest>.json`` (digest: the point's full scenario and imcsim's source,
`imc.scenario.code_digest`); a restarted sweep of the same code skips them, so a kill loses
at most the points in flight, and a sweep after a code change runs every point again.
Results: ``results.nc`` (xarray, one dimension per axis and ``seed``; ``point`` and ``seed``
for zip), ``results.parquet`` and ``results.csv`` (one row per point).
"""

from __future__ import annotations

import copy
import itertools
import json
import math
import os
import shutil
import socket
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from imc.io import atomic_write, write_json
from imc.scenario import (
    Scenario,
    ScenarioError,
    check_metric_path,
    error_line,
    format_validation_error,
    load_scenario,
    parse_scenario,
)
from imc.workflow.distribute import Lost, Runner, Task
from imc.yamlload import YamlInputError, load_yaml, read_text, short

#: metrics plotted when a sweep names none
DEFAULT_METRICS = ("with_compensation.rms_total_px", "with_compensation.mtf_nyquist_worst.0",
                   "rms_reduction")


#: the most points (axis combinations x seeds) a sweep may have without --force
MAX_SWEEP_POINTS = 100_000


class SweepError(ValueError):
    """A sweep file that cannot be used; the message is one line naming the axis and field."""


class AxisRange(BaseModel):
    """``{linear: [start, stop, num]}`` or ``{log: [start, stop, num]}`` (both ends in)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    linear: tuple[float, float, int] | None = None
    log: tuple[float, float, int] | None = None

    def values(self) -> list[float]:
        if (self.linear is None) == (self.log is None):
            raise ValueError("give one of linear: [start, stop, num] or log: [start, stop, "
                             "num]")
        a, b, n = self.linear or self.log
        if n < 1:
            raise ValueError("num must be at least 1")
        if n > MAX_SWEEP_POINTS:
            raise ValueError(f"num {n:,} is more than a sweep's {MAX_SWEEP_POINTS:,} points")
        if self.log is not None:
            if a <= 0 or b <= 0:
                raise ValueError("a log range needs start and stop > 0")
            v = np.geomspace(a, b, n)
        else:
            v = np.linspace(a, b, n)
        return [float(f"{x:.12g}") for x in v]


class SweepConfig(BaseModel):
    """The sweep file's schema."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    name: str = Field("sweep", min_length=1, description="sweep name (report titles)")
    base: str | dict[str, Any] = Field(description="the base scenario: a YAML path "
                                       "(relative to the sweep file) or a mapping")
    set: dict[str, Any] = Field(default_factory=dict, description="dotted scenario field "
                                "-> value applied to the base before the axes")
    axes: dict[str, list[Any] | AxisRange] = Field(
        min_length=1, description="dotted scenario field -> values (a list, or linear / log "
        "range)")
    mode: Literal["grid", "zip"] = Field("grid", description="grid (every combination) or "
                                         "zip (axes of equal length, taken together)")
    seeds: int = Field(1, ge=1, le=10_000, description="repeats of every point with seed = "
                       "base seed + 0, 1, ...")
    metrics: tuple[str, ...] = Field(DEFAULT_METRICS, min_length=1, description="metric paths "
                                     "of metrics.json the report plots")
    keep_runs: bool = Field(False, description="keep every point's run folder (tracks.csv, "
                            "blur.npz, recording) under runs/")

    @field_validator("metrics")
    @classmethod
    def _paths(cls, v):
        for p in v:
            check_metric_path(p)
        return v

    @field_validator("axes")
    @classmethod
    def _axes(cls, v: dict):
        for name, spec in v.items():
            if isinstance(spec, list) and not spec:
                raise ValueError(f"axis {name!r} has no values")
            if name == "seed":
                raise ValueError("axis 'seed': use seeds: N for repeats (seed = base seed + "
                                 "0 .. N-1)")
        return v


@dataclass(frozen=True)
class Point:
    """One scenario of a sweep: its axis values (and seed index), digest and scenario."""

    index: int
    coords: dict[str, Any]
    digest: str
    scenario: dict = field(repr=False)


@dataclass(frozen=True)
class Sweep:
    """A validated sweep: its config, the values of each axis, and every point."""

    config: SweepConfig
    source: str
    axes: dict[str, list]
    points: tuple[Point, ...]

    @property
    def dims(self) -> tuple[str, ...]:
        return (*self.axes, "seed") if self.config.mode == "grid" else ("point", "seed")


# ------------------------------------------------------------------------------ loading


def _set_path(raw: dict, full: dict, path: str, value) -> None:
    """Set ``path`` (dotted; ints index lists) in the scenario mapping ``raw``, taking a
    section that ``raw`` leaves at its default from ``full`` (the scenario with defaults)."""
    parts = path.split(".")
    node, dflt = raw, full
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        here = ".".join(parts[:i]) or "the scenario"
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise SweepError(f"{here} is a list of {len(node)}: index it with 0.."
                                 f"{len(node) - 1}, not {part!r}")
            j = int(part)
            if last:
                node[j] = value
                return
            node, dflt = node[j], (dflt[j] if isinstance(dflt, list) and j < len(dflt)
                                   else None)
            continue
        if not isinstance(node, dict):
            raise SweepError(f"{here} is a value, not a section: it has no field {part!r}")
        if last:
            node[part] = value
            return
        sub_default = dflt.get(part) if isinstance(dflt, dict) else None
        if node.get(part) is not None and not isinstance(node[part], dict | list):
            raise SweepError(f"{'.'.join(parts[:i + 1])} is a value, not a section: it has "
                             f"no field {parts[i + 1]!r}")
        if not isinstance(node.get(part), dict | list):
            node[part] = (copy.deepcopy(sub_default) if isinstance(sub_default, dict | list)
                          else {})
        node, dflt = node[part], sub_default


def _value_text(v) -> str:
    return json.dumps(v) if isinstance(v, str | dict | list) else f"{v:g}" if isinstance(
        v, float) else str(v)


def _point_error(source: str, axes: dict[str, Any], e: Exception) -> SweepError:
    """The first problem of a point, naming the axis (or all axes) and the field."""
    msg = str(e)
    mark = "\x00point"
    loc_msg = msg.split(f"{mark}: ", 1)[1] if mark in msg else msg
    loc = loc_msg.split(":", 1)[0]
    named = [a for a in axes if a == loc or a.startswith(loc + ".") or loc.startswith(a + ".")]
    which = named or list(axes)
    where = ", ".join(f"{a} = {_value_text(axes[a])}" for a in which)
    word = "axis" if len(which) == 1 else "axes"
    return SweepError(f"{source}: {word} {where}: {loc_msg}")


def _base(cfg: SweepConfig, source: Path | None) -> Scenario:
    if isinstance(cfg.base, dict):
        return parse_scenario(cfg.base, f"{source or 'sweep'}: base")
    p = Path(cfg.base)
    if not p.is_absolute() and source is not None:
        p = source.parent / p
    return load_scenario(p)


def expand(cfg: SweepConfig, source: Path | None = None, force: bool = False) -> Sweep:
    """Every point of a sweep, each validated by the scenario schema and by the run-size
    check of imc.wiring.budget (SweepError if not; ``force`` skips the size limits)."""
    from imc.wiring.budget import check_run_size, estimate_run

    src = str(source) if source is not None else "sweep"
    try:
        base = _base(cfg, source)
    except ScenarioError as e:
        raise SweepError(f"{src}: base: {e}") from None
    raw = base.model_dump(mode="json", exclude_unset=True, exclude={"expect"})
    full = base.model_dump(mode="json", exclude={"expect"})
    raw_json = json.dumps(raw)
    axes: dict[str, list] = {}
    for name, spec in cfg.axes.items():
        try:
            axes[name] = spec.values() if isinstance(spec, AxisRange) else list(spec)
        except ValueError as e:
            raise SweepError(f"{src}: axis {name}: {e}") from None
    if cfg.mode == "zip":
        lengths = {len(v) for v in axes.values()}
        if len(lengths) > 1:
            raise SweepError(f"{src}: mode zip needs axes of equal length; got "
                             + ", ".join(f"{a}: {len(v)}" for a, v in axes.items()))
        combos = list(zip(*axes.values(), strict=True))
        n_combos = len(next(iter(axes.values())))
    else:
        n_combos = math.prod(len(v) for v in axes.values())
    if n_combos * cfg.seeds > MAX_SWEEP_POINTS and not force:
        raise SweepError(f"{src}: axes x seeds = {n_combos:,} x {cfg.seeds} = "
                         f"{n_combos * cfg.seeds:,} points, more than {MAX_SWEEP_POINTS:,}; "
                         "use fewer values or seeds (--force to run it)")
    if cfg.mode == "grid":
        combos = list(itertools.product(*axes.values()))
    clash = set(cfg.set) & set(axes)
    if clash:
        raise SweepError(f"{src}: {', '.join(sorted(clash))} is both in set and in axes")
    points = []
    for combo in combos:
        values = dict(zip(axes, combo, strict=True))
        for s in range(cfg.seeds):
            data = json.loads(raw_json)  # a deep copy, faster than copy.deepcopy
            try:
                for a, v in {**cfg.set, **values}.items():
                    _set_path(data, full, a, v)
            except SweepError as e:
                raise SweepError(f"{src}: {'set' if a in cfg.set else 'axis'} {a}: {e}") from None
            data["seed"] = base.seed + s
            try:
                sc = parse_scenario(data, "\x00point")
                check_run_size(sc, estimate_run(sc), force)
            except ScenarioError as e:
                raise _point_error(src, {**cfg.set, **values}, e) from None
            points.append(Point(len(points), {**values, "seed": s}, sc.digest(),
                                sc.model_dump(mode="json", exclude_unset=True)))
    return Sweep(cfg, src, axes, tuple(points))


def load_sweep(path: str | Path, force: bool = False) -> Sweep:
    """Read (strict YAML: imc.yamlload), validate and expand a sweep file; every problem
    becomes a one-line SweepError."""
    p = Path(path)
    try:
        data = load_yaml(read_text(p))
    except YamlInputError as e:
        raise SweepError(f"{short(str(p), 200)}: {e}") from None
    if not isinstance(data, dict):
        raise SweepError(f"{p}: a sweep file is a mapping (name, base, axes, mode, seeds, "
                         "metrics)")
    try:
        cfg = SweepConfig.model_validate(data)
    except ValidationError as e:
        raise SweepError(format_validation_error(e, str(p)).replace(
            "docs/scenario.md", "docs/workflow.md")) from None
    return expand(cfg, p, force)


def is_sweep_file(data: object) -> bool:
    """Whether a parsed YAML document is a sweep (it has ``axes`` and ``base``)."""
    return isinstance(data, dict) and "axes" in data and "base" in data


# ------------------------------------------------------------------------------ running


def run_point(scenario: dict, work_dir: str, keep: bool) -> dict:
    """Run one point (on a worker): its metrics, or its one-line error and traceback. The run
    folder (its checkpoint lets a point in flight resume) is removed unless ``keep``."""
    from imc.pipeline import run_scenario

    t0 = time.perf_counter()
    warnings: list[str] = []
    out: dict[str, Any] = {"worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        metrics, info = run_scenario(parse_scenario(scenario), Path(work_dir), rerun=keep,
                                     warn=warnings.append)
        out.update(status="ok", metrics=metrics, run_wall_s=info["wall_s"])
    except Exception as e:  # a point that fails is a result; the sweep goes on
        out.update(status="error", error=error_line(e), traceback=traceback.format_exc())
    finally:
        if not keep:
            shutil.rmtree(work_dir, ignore_errors=True)
    out.update(wall_s=time.perf_counter() - t0, warnings=warnings)
    return out


@dataclass
class SweepSummary:
    """What a sweep call did: points skipped (done before), run, failed, lost."""

    total: int
    skipped: int = 0
    ran: int = 0
    failed: int = 0
    lost: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    files: list[str] = field(default_factory=list)


ProgressFn = Callable[[int, int], None]


def point_path(out_dir: Path, digest: str) -> Path:
    return Path(out_dir) / "points" / f"{digest}.json"


def read_point(out_dir: Path, digest: str) -> dict | None:
    """A finished point's record, or None (missing or unreadable)."""
    try:
        return json.loads(point_path(out_dir, digest).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def write_manifest(sweep: Sweep, out_dir: Path) -> None:
    write_json(Path(out_dir) / "sweep.json", {
        "name": sweep.config.name, "source": sweep.source,
        "config": sweep.config.model_dump(mode="json"), "dims": list(sweep.dims),
        "axes": sweep.axes, "points": [{"index": p.index, "coords": p.coords,
                                        "digest": p.digest} for p in sweep.points]})


def run_sweep(sweep: Sweep, out_dir: Path, runner: Runner, progress: ProgressFn | None = None,
              retry_failed: bool = False, fresh: bool = False) -> SweepSummary:
    """Run the points not finished in ``out_dir`` (the failed ones too with
    ``retry_failed``; every point with ``fresh``; a point's digest holds its scenario and
    the code's source, so a code change runs it again anyway), writing each
    as it finishes (an earlier result is replaced only then); then the results tables."""
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    (out_dir / "points").mkdir(parents=True, exist_ok=True)
    write_manifest(sweep, out_dir)
    todo: dict[str, Point] = {}
    summary = SweepSummary(total=len({p.digest for p in sweep.points}))
    for p in sweep.points:
        if p.digest in todo:
            continue
        rec = read_point(out_dir, p.digest)
        if not fresh and rec is not None and (rec.get("status") == "ok" or not retry_failed):
            continue
        todo[p.digest] = p
    summary.skipped = summary.total - len(todo)
    if progress:
        progress(summary.skipped, summary.total)
    keep = sweep.config.keep_runs
    tasks = [Task(f"point-{d}", run_point, (p.scenario, str(out_dir / "runs" / d), keep))
             for d, p in todo.items()]
    for key, res in runner.run(tasks):
        p = todo[key.removeprefix("point-")]
        if isinstance(res, Lost):
            summary.lost.append(f"point {p.index}: {res}")
            continue
        if isinstance(res, BaseException):  # raised outside run_point's guard
            res = {"status": "error", "error": error_line(res)}
        rec = {"digest": p.digest, "index": p.index, "coords": p.coords,
               "finished_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"), **res}
        write_json(point_path(out_dir, p.digest), rec)
        summary.ran += 1
        if rec["status"] != "ok":
            summary.failed += 1
            summary.errors.append(f"point {p.index} ({_coords_text(p.coords)}): "
                                  f"{rec['error']}")
        if progress:
            progress(summary.skipped + summary.ran, summary.total)
    try:
        (out_dir / "runs").rmdir()  # left only when runs are kept or points are in flight
    except OSError:
        pass
    summary.files = [str(f) for f in write_results(sweep, out_dir)]
    summary.wall_s = time.perf_counter() - t0
    return summary


def _coords_text(coords: dict) -> str:
    return ", ".join(f"{k}={_value_text(v)}" for k, v in coords.items())


# ------------------------------------------------------------------------------ results


def flatten(d, prefix: str = "") -> dict[str, float]:
    """Numeric leaves of a metrics mapping by dotted path (list items by index); None -> NaN,
    bools -> 0/1, strings left out."""
    out: dict[str, float] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(flatten(v, f"{prefix}{k}."))
    elif isinstance(d, list | tuple):
        for i, v in enumerate(d):
            out.update(flatten(v, f"{prefix}{i}."))
    elif d is None:
        out[prefix[:-1]] = math.nan
    elif isinstance(d, bool | int | float):
        out[prefix[:-1]] = float(d)
    return out


def _coord_value(v):
    return v if isinstance(v, bool | int | float | str) else json.dumps(v)


def table(sweep: Sweep, out_dir: Path):
    """The tidy table (pandas DataFrame): one row per point (and seed) of the sweep, its axis
    values, status, error, wall time and every numeric metric."""
    import pandas as pd

    rows = []
    for p in sweep.points:
        rec = read_point(out_dir, p.digest) or {"status": "pending"}
        row = {"point": p.index, **{a: _coord_value(p.coords[a]) for a in sweep.axes},
               "seed": p.coords["seed"], "scenario_seed": p.scenario.get("seed", 0),
               "digest": p.digest, "status": rec.get("status", "pending"),
               "error": rec.get("error", ""), "wall_s": rec.get("wall_s", math.nan)}
        row.update(flatten(rec.get("metrics") or {}))
        rows.append(row)
    return pd.DataFrame(rows)


def dataset(sweep: Sweep, df):
    """The results as an xarray Dataset: one dimension per axis and ``seed`` (grid), or
    ``point`` and ``seed`` (zip, with the axes as coordinates along ``point``)."""
    import xarray as xr

    meta = ["digest", "status", "error", "wall_s", "scenario_seed"]
    metric_cols = [c for c in df.columns if c not in (*sweep.axes, "seed", "point", *meta)]
    if sweep.config.mode == "grid":
        idx = [*sweep.axes, "seed"]
        ds = xr.Dataset.from_dataframe(df.drop(columns=["point"]).set_index(idx))
        for a, vals in sweep.axes.items():  # the axis order of the sweep file, not sorted
            ds = ds.reindex({a: [_coord_value(v) for v in vals]})
    else:
        df = df.assign(point=df["point"] // sweep.config.seeds)
        ds = xr.Dataset.from_dataframe(
            df.drop(columns=list(sweep.axes)).set_index(["point", "seed"]))
        first = df[df["seed"] == 0].set_index("point")
        ds = ds.assign_coords({a: ("point", first[a].to_numpy()) for a in sweep.axes})
    ds.attrs.update(name=sweep.config.name, source=sweep.source, mode=sweep.config.mode,
                    metrics=json.dumps(list(sweep.config.metrics)))
    for c in metric_cols:
        if c in ds:
            ds[c].attrs["metric_path"] = c
    for v in ("status", "error", "digest"):
        ds[v] = ds[v].fillna("").astype(str)
    return ds


def write_results(sweep: Sweep, out_dir: Path) -> list[Path]:
    """results.nc, results.parquet and results.csv, atomically."""
    df = table(sweep, out_dir)
    ds = dataset(sweep, df)
    out_dir = Path(out_dir)
    atomic_write(out_dir / "results.nc", lambda p: ds.to_netcdf(p, engine="h5netcdf"))
    atomic_write(out_dir / "results.parquet", lambda p: df.to_parquet(p, index=False))
    atomic_write(out_dir / "results.csv", lambda p: df.to_csv(p, index=False))
    return [out_dir / f"results.{x}" for x in ("nc", "parquet", "csv")]

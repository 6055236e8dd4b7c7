"""report.html: a self-contained page (PNGs inline as data URIs) per run and per sweep."""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path

from imc.io import atomic_write, load_sweep_results
from imc.outputs.figures import Figure, run_figures, sweep_figures
from imc.outputs.product_report import (
    differences_path,
    product_html,
    quicklook_path,
    write_quicklook,
)

CSS = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;color:#222;padding:0 1em}
h1{font-size:1.5em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
.pass{color:#17702e;font-weight:600}.fail{color:#b3261e;font-weight:600}
figure{margin:1.2em 0}figcaption{font-size:.85em;color:#555}img{max-width:100%}
.small{font-size:.85em;color:#666}
"""

#: name of the file `imc run` / `imc check` leave beside metrics.json for the report
EXPECTATIONS = "expectations.json"


def _img(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(Path(path).name)}">'


def _table(header: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _num(v, fmt: str = ".4g") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, list | tuple):
        return " / ".join(_num(x, fmt) for x in v)
    return format(v, fmt) if isinstance(v, int | float) else html.escape(str(v))


def _page(title: str, parts: Sequence[str]) -> str:
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><style>{CSS}</style></head><body><h1>{html.escape(title)}</h1>"
            + "\n".join(parts) + f"<p class='small'>imcsim report, {stamp}</p></body></html>")


def _figures_html(figs: Sequence[Figure]) -> list[str]:
    return [f"<h2>{html.escape(f.title)}</h2><figure>{_img(f.path)}<figcaption>"
            f"{html.escape(f.caption)} ({html.escape(f.path.name)})</figcaption></figure>"
            for f in figs]


def expectations_html(outcomes: Sequence[dict]) -> str:
    rows = [(html.escape(o["path"]), html.escape(o["bound"]), html.escape(o["value"]),
             f"<span class='{'pass' if o['passed'] else 'fail'}'>"
             f"{'pass' if o['passed'] else 'FAIL'}</span>", html.escape(o.get("note", "")))
            for o in outcomes]
    return "<h2>Expectations</h2>" + _table(("metric", "expected", "value", "", "note"), rows)


def write_run_report(run_dir: Path, drawn: Sequence[Figure] | None = None) -> Path:
    """report.html and the figures (fig_*.png) of a run folder; returns the HTML's path.
    ``drawn``: the run's figures (and the product's quicklook) as the run drew them
    (:func:`imc.outputs.figures.draw_run_figures`), else they are drawn now."""
    run_dir = Path(run_dir)
    m = json.loads((run_dir / "metrics.json").read_text())
    o, c = m["without_compensation"], m["with_compensation"]
    lp, tr = m.get("loop", {}), m.get("tracker", {})
    parts = [f"<p>{m.get('frames')} tracker frames, {m.get('blocks')} blocks; "
             f"{html.escape(str(lp.get('fidelity')))} plant, "
             f"{html.escape(str(lp.get('estimator')))} estimator, "
             f"{html.escape(str(lp.get('controller')))} controller, "
             f"{html.escape(str(lp.get('actuator')))} stage; "
             f"{_num(lp.get('measurement_rate_hz'))} measurements/s, latency "
             f"{_num(1e3 * lp['latency_s'] if 'latency_s' in lp else None)} ms.</p>"]
    parts.append("<h2>Residual image motion at the main imager (px)</h2>" + _table(
        ("", "without compensation", "with compensation"),
        [("RMS total", _num(o["rms_total_px"]), _num(c["rms_total_px"])),
         ("RMS row / col", _num(o["rms_px"]), _num(c["rms_px"])),
         ("peak-to-peak row / col", _num(o["peak_to_peak_px"]), _num(c["peak_to_peak_px"])),
         ("motion MTF at Nyquist row / col", _num(o["mtf_nyquist"]), _num(c["mtf_nyquist"])),
         ("worst-window MTF row / col", _num(o["mtf_nyquist_worst"]),
          _num(c["mtf_nyquist_worst"]))])
        + f"<p>RMS reduced {_num(m.get('rms_reduction'), '.3g')}x by the loop; stage at its "
        f"stroke {_num(100 * lp.get('stage_saturation_fraction', 0.0), '.3g')} % of the "
        f"time.</p>")
    an = lp.get("analytic") or {}
    parts.append("<h2>Tracker and loop</h2>" + _table(("", "value"), [
        ("valid measurements", f"{_num(100 * tr.get('valid_fraction', math.nan), '.1f')} %"),
        ("error RMS row / col (px)", _num(tr.get("rms_error_px"))),
        ("median CRLB row / col (px)", _num(tr.get("median_crlb_px"))),
        ("estimate error RMS (px)", _num(lp.get("estimate_rms_error_px"))),
        *((html.escape(k.replace("_", " ")), _num(v)) for k, v in an.items()
          if isinstance(v, int | float | type(None)))]))
    ex, lock = m.get("exposures"), lp.get("lock")
    if ex and lock and m.get("compensation_enabled"):
        worse = ", ".join(f"{w['start_s']:.3g} s" for w in ex.get("worse", []))
        parts.append(f"<p>The loop locks in {_num(lock.get('analytic_s'), '.3g')} s (analytic "
                     f"model), {_num(lock.get('measured_s'), '.3g')} s in this run; the main "
                     f"imager starts at {_num(m.get('main_imager_start_s'), '.3g')} s. "
                     f"{_num(ex.get('worse_than_open'))} of {_num(ex.get('n'))} main-imager "
                     "exposures are worse with the loop than without"
                     + (f" (from {html.escape(worse)})" if worse else "") + ".</p>")
    exp = run_dir / EXPECTATIONS
    if exp.exists():
        parts.append(expectations_html(json.loads(exp.read_text())))
    if m.get("product"):
        parts.append(product_html(m, _table))
        quick = write_quicklook(run_dir) if drawn is None else quicklook_path(run_dir)
        if quick is not None:
            parts.extend(_figures_html([Figure(quick, "The product, side by side", (
                "The main imager's product static, open and closed loop, ground corrected "
                "and restored (one grey scale), over each line's offset on the nominal grid: "
                "the camera model's truth and the ground's estimate from the loop's "
                "record."))]))
        diffs = differences_path(run_dir)
        if diffs is not None:
            parts.extend(_figures_html([Figure(diffs, "Where the difference shows", (
                "Each version orthorectified through its RPCs and the scene's DEM onto one "
                "map grid, its difference against the static orthoimage on one stated "
                "scale, and the slanted-square target's edge at full resolution."))]))
    parts.extend(_figures_html(run_figures(run_dir, drawn)))
    out = run_dir / "report.html"
    page = _page(f"imcsim run: {m.get('scenario', run_dir.name)}", parts)
    atomic_write(out, lambda p: p.write_text(page, encoding="utf-8"))
    return out


def write_sweep_report(sweep_dir: Path) -> Path:
    """report.html and figures/*.png of a sweep folder (results.nc, sweep.json)."""
    sweep_dir = Path(sweep_dir)
    ds = load_sweep_results(sweep_dir)
    meta = json.loads((sweep_dir / "sweep.json").read_text())
    metrics = json.loads(ds.attrs.get("metrics", "[]"))
    status = ds["status"].values.ravel()
    n_ok, n_err = int((status == "ok").sum()), int((status == "error").sum())
    n_pend = int(status.size - n_ok - n_err)
    axes_rows = [(html.escape(a), len(v), html.escape(", ".join(
        f"{x:g}" if isinstance(x, float) else str(x) for x in v[:12])
        + (" ..." if len(v) > 12 else ""))) for a, v in meta["axes"].items()]
    parts = [f"<p>{html.escape(meta['source'])}: mode {html.escape(ds.attrs.get('mode', ''))}"
             f", {meta['config']['seeds']} seed(s); {status.size} points: {n_ok} ok, "
             f"{n_err} failed, {n_pend} not run.</p>",
             "<h2>Axes</h2>" + _table(("field", "values", ""), axes_rows)]
    import pandas as pd

    df = pd.read_parquet(sweep_dir / "results.parquet")
    parts.append(_best_table(df, metrics, list(meta["axes"])))
    errs = _errors(df)
    if errs:
        parts.append("<h2>Failed points</h2>" + _table(("point", "error"), errs[:50]))
    parts.extend(_figures_html(sweep_figures(sweep_dir, ds, metrics)))
    out = sweep_dir / "report.html"
    page = _page(f"imcsim sweep: {meta['name']}", parts)
    atomic_write(out, lambda p: p.write_text(page, encoding="utf-8"))
    return out


def _best_table(df, metrics: Sequence[str], axes: Sequence[str]) -> str:
    """Per metric, the best and worst point (lowest / highest, over seeds' mean) of the
    sweep's tidy table ``df``."""
    ok = df[df["status"] == "ok"]
    rows = []
    for metric in metrics:
        if metric not in ok or ok[metric].isna().all():
            continue
        g = ok.groupby(list(axes), dropna=False)[metric].mean()
        for label, idx in (("lowest", g.idxmin()), ("highest", g.idxmax())):
            key = idx if isinstance(idx, tuple) else (idx,)
            at = ", ".join(f"{a} = {v}" for a, v in zip(axes, key, strict=True))
            rows.append((html.escape(metric), label, _num(float(g.loc[idx])), html.escape(at)))
    return "<h2>Extremes (mean over seeds)</h2>" + _table(("metric", "", "value", "at"), rows)


def _errors(df) -> list[tuple[str, str]]:
    bad = df[df["status"] == "error"]
    return [(str(r.point), html.escape(str(r.error))) for r in bad.itertuples()]

"""Restitution on no_stage.yaml (issue 32's figures): the record's error budget, the geometry
after a constant and after an affine against the number of baselines K (measured and as the
network's covariance predicts it), with a gyro and with control points, and the analytic
plant's geometry against the rendered tracker's at three strip lengths.

Measured here, never asserted in tests. One rendered loop of no_stage.yaml (~4 min on 2
cores with the terrain's build) and one analytic loop; every other figure re-solves the same
links. ``--quick``: the analytic plant only.

    .venv/bin/python benchmarks/bench_restitution.py [--quick] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import yaml

from compensation.loop import simulate
from ground.network import geometry_rms
from imc.io import write_json
from imc.scenario import parse_scenario
from imc.wiring.build import build_loop, build_models
from imc.wiring.links import measure_links
from imc.wiring.product import Versions, perfect_jitter, plan_product, truth_offsets
from imc.wiring.product import line_offsets as offsets_from
from imc.wiring.rendered_plant import build_plant
from imc.wiring.restitution import restitute
from imc.wiring.truth import compute_truth

ROOT = Path(__file__).resolve().parents[1]
#: strip lengths (lines) of the analytic-against-rendered comparison: 0.24, 0.72, 1.54 s
LENGTHS = (2000, 6000, 12800)


def _scenario(**product) -> dict:
    d = yaml.safe_load((ROOT / "scenarios" / "no_stage.yaml").read_text())
    d.pop("expect", None)
    d["product"].update(render=False, **product)
    return d


def _run(d: dict):
    """(models, plant, loop result, links) of one scenario."""
    m = build_models(parse_scenario(d))
    plant = build_plant(m)
    sigma = float(np.mean(plant.sigma_px)) if hasattr(plant, "sigma_px") else None
    parts = build_loop(m, None, sigma)
    res = simulate(plant, parts.estimator, parts.controller, parts.actuator, parts.transport,
                   parts.timeline, enabled=m.scenario.compensation.enabled,
                   supervisor=parts.supervisor)
    truth = compute_truth(m, res.record, res.trajectory)
    links = measure_links(m, res.record, plant, truth.stage_mean_px, 6)
    return m, plant, res, links


def _from_run(d: dict, run: Path):
    """(models, plant, loop result, links) from a rendered run of the same scenario written
    by ``imc run --save-frames`` (tracks.csv, series.npz, frames.npz): the loop is not run
    again, the ground's extra baselines are measured on its frames."""
    from types import SimpleNamespace

    m = build_models(parse_scenario(d))
    r = np.genfromtxt(run / "tracks.csv", delimiter=",", names=True)
    n_f, n_b = int(r["frame"].max()) + 1, int(r["block"].max()) + 1

    def col(name):
        return r[name].reshape(n_f, n_b)

    with np.load(run / "series.npz") as se, np.load(run / "frames.npz") as fr:
        centers, frames = se["centers_px"], fr["frames"]
    rec = SimpleNamespace(
        shift_px=np.stack([col("meas_row_px"), col("meas_col_px")], -1),
        sigma_px=np.stack([col("crlb_row_px"), col("crlb_col_px")], -1),
        valid=col("valid").astype(bool), ref_frame=col("ref_frame").astype(int),
        centers_px=centers, measured=np.ones((n_f, n_b), bool), arrive_s=m.frame_mid_s.copy())
    plant = SimpleNamespace(frames=frames, stage_mean=np.zeros((n_f, 2)))
    res = SimpleNamespace(record=rec)
    links = measure_links(m, rec, plant, plant.stage_mean, 6)
    return m, plant, res, links


def _geometry(m, links, lines: int, **product) -> dict:
    """The open (no stage) strip's geometry after a constant and an affine, measured and
    predicted, from the links re-solved with ``product`` settings."""
    d = m.scenario.model_dump(mode="json", exclude={"expect"})
    d["product"].update(lines=lines, **product)
    mm = dataclasses.replace(m, scenario=parse_scenario(d))
    plan = plan_product(mm)
    rest = restitute(mm, links, np.array([plan.line_t_s[0], plan.line_t_s[-1]]))
    versions = Versions.of_run(None)
    true = truth_offsets(mm, plan, versions, 8)["open"]
    est = offsets_from(plan, rest.record, None)
    t = plan.line_t_s + 0.5 * plan.integration_s
    g = geometry_rms(est - true, t)
    p = rest.predicted_geometry(t)
    perf = offsets_from(plan, perfect_jitter(mm, rest.record), None)
    return {"lines": lines, "baselines": rest.baselines, "aiding": list(rest.aiding),
            "constant_px": g["constant"].tolist(), "affine_px": g["affine"].tolist(),
            "absolute_px": np.sqrt(np.mean((est - true) ** 2, axis=0)).tolist(),
            "predicted_constant_px": p["constant_px"], "predicted_affine_px": p["affine_px"],
            "perfect_record_px": geometry_rms(perf - true, t)["constant"].tolist()}


def budget(m, res, plant) -> dict:
    """The loop's own links against the truth: each link's random error (the blocks'
    scatter), its systematic part (the mean) and the correlation of neighbouring links."""
    from imc.wiring.truth import measurement_truth

    rec = res.record
    true = measurement_truth(m, rec, plant.stage_mean)
    e = np.where(rec.valid[..., None], rec.shift_px - true, np.nan)[1:]
    link = np.nanmean(e, axis=1)
    ok = np.all(np.isfinite(link), axis=1)
    lag1 = [float(np.corrcoef(link[:-1][ok[:-1] & ok[1:], i],
                              link[1:][ok[:-1] & ok[1:], i])[0, 1]) for i in range(2)]
    return {"block_error_std_px": np.nanstd(e, axis=(0, 1)).tolist(),
            "link_error_std_px": np.nanstd(link, axis=0).tolist(),
            "link_error_mean_px": np.nanmean(link, axis=0).tolist(),
            "link_lag1_correlation": lag1,
            "crlb_median_px": np.nanmedian(np.where(rec.valid[..., None], rec.sigma_px,
                                                    np.nan)[1:], axis=(0, 1)).tolist()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="the analytic plant only")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out"))
    ap.add_argument("--run", type=Path, default=None, help="the rendered record of `imc run "
                    "scenarios/no_stage.yaml --save-frames --out RUN` instead of a new loop")
    a = ap.parse_args()
    out: dict = {}
    fids = ("analytic",) if a.quick else ("rendered", "analytic")
    for fid in fids:
        t0 = time.perf_counter()
        d = _scenario()
        d["plant"] = {"fidelity": fid}
        m, plant, res, links = (_from_run(d, a.run) if fid == "rendered" and a.run
                                else _run(d))
        r = {"loop_s": time.perf_counter() - t0,
             "efficiency": links.efficiency.tolist(), "links": int(links.valid.sum())}
        if fid == "rendered":
            r["budget"] = budget(m, res, plant)
        r["baselines"] = [_geometry(m, links, 12800, restitution={"baselines": k,
                                                                  "smoother": sm})
                          for k in (1, 2, 3, 4) for sm in (False, True)]
        r["aided"] = [_geometry(m, links, 12800, **extra) for extra in (
            {"gyro": {}}, {"ground_control": {"points": 4, "sigma_px": 0.02}},
            {"gyro": {}, "ground_control": {"points": 4, "sigma_px": 0.02}})]
        r["lengths"] = [_geometry(m, links, n) for n in LENGTHS]
        out[fid] = r
        print(json.dumps({fid: r}, indent=1), flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    write_json(Path(a.out) / "restitution.json", out)


if __name__ == "__main__":
    main()

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
#: the true lines' offsets per (models, lines): every figure of one record shares them
_TRUTH: dict = {}


def _scenario(**product) -> dict:
    d = yaml.safe_load((ROOT / "scenarios" / "no_stage.yaml").read_text())
    d.pop("expect", None)
    d["product"].update(render=False, **product)
    return d


def _run(d: dict, floor: bool = False, efficiency: bool = False,
         rendered_sigma: bool = False):
    """(models, plant, loop result, links) of one scenario; ``floor``: an analytic plant
    whose links also carry the rendered tracker's Monte Carlo floor
    (:func:`imc.wiring.rendered_plant.render_floor_px`, measured on this scene), and with
    ``efficiency`` its bound's part drawn at the correlator's efficiency on the scene
    (:func:`scene_efficiency`); ``rendered_sigma``: its bound and that efficiency from frame 0
    as the renderer draws it (:func:`imc.wiring.rendered_plant.render_pose`), not the
    flat-shaded albedo."""
    m = build_models(parse_scenario(d))
    if floor and m.scenario.plant.fidelity == "analytic":
        from imc.wiring.rendered_plant import (
            analytic_plant,
            efficiency_on_scene,
            predicted_sigma_px,
            render_floor_px,
            rendered_noise,
        )

        if rendered_sigma:  # frame 0 as the renderer draws it: plant.noise 'rendered'
            noise = rendered_noise(m)
        else:
            noise = {"sigma_px": predicted_sigma_px(m), "floor_px": render_floor_px(m),
                     "efficiency": (np.asarray(efficiency_on_scene(m)["over_crlb"])
                                    if efficiency else np.ones(2))}
        if not efficiency:
            noise["efficiency"] = np.ones(2)
        print(json.dumps({k: np.asarray(v).tolist() for k, v in noise.items()}), flush=True)
        plant = analytic_plant(m, **noise)
    else:
        plant = build_plant(m)
    sigma = float(np.mean(plant.sigma_px)) if hasattr(plant, "sigma_px") else None
    parts = build_loop(m, None, sigma)
    res = simulate(plant, parts.estimator, parts.controller, parts.actuator, parts.transport,
                   parts.timeline, enabled=m.scenario.compensation.enabled,
                   supervisor=parts.supervisor)
    truth = compute_truth(m, res.record, res.trajectory)
    links = measure_links(m, res.record, plant, truth.stage_mean_px, 6)
    return m, plant, res, links


def _from_run(d: dict, run: Path, links_npz: Path | None = None):
    """(models, plant, loop result, links) from a rendered run of the same scenario written
    by ``imc run --save-frames`` (tracks.csv, series.npz, frames.npz): the loop is not run
    again, the ground's extra baselines are measured on its frames (or read from
    ``links_npz``, a table this function wrote there before: ``--links``)."""
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
    if links_npz is not None and links_npz.exists():
        from imc.wiring.links import LinkTable

        with np.load(links_npz) as z:
            arr = {k: z[k] for k in z.files}
        for k in ("block_px", "cell_px"):
            if k in arr:
                arr[k] = int(arr[k])
        return m, plant, res, LinkTable(**arr)
    links = measure_links(m, rec, plant, plant.stage_mean, 6)
    if links_npz is not None:
        np.savez(links_npz, **links.arrays())
    return m, plant, res, links


def _geometry(m, links, lines: int, **product) -> dict:
    """The open (no stage) strip's geometry after a constant and an affine, measured and
    predicted, from the links re-solved with ``product`` settings."""
    d = m.scenario.model_dump(mode="json", exclude={"expect"})
    d["product"].update(lines=lines, **product)
    mm = dataclasses.replace(m, scenario=parse_scenario(d))
    plan = plan_product(mm)
    rest = restitute(mm, links, np.array([plan.line_t_s[0], plan.line_t_s[-1]]))
    key = (id(m), lines)
    if key not in _TRUTH:  # the camera model's offsets of these lines, computed once
        _TRUTH[key] = truth_offsets(mm, plan, Versions.of_run(None), 8)["open"]
    true = _TRUTH[key]
    est = offsets_from(plan, rest.record, None)
    t = plan.line_t_s + 0.5 * plan.integration_s
    g = geometry_rms(est - true, t)
    p = rest.predicted_geometry(t)
    perf = offsets_from(plan, perfect_jitter(mm, rest.record), None)
    return {"lines": lines, "baselines": rest.baselines, "aiding": list(rest.aiding),
            "independent_fraction": rest.independent_fraction,
            "constant_px": g["constant"].tolist(), "affine_px": g["affine"].tolist(),
            "absolute_px": np.sqrt(np.mean((est - true) ** 2, axis=0)).tolist(),
            "predicted_constant_px": p["constant_px"], "predicted_affine_px": p["affine_px"],
            "predicted_constant_5_95_px": p["constant_5_95_px"],
            "predicted_affine_5_95_px": p["affine_5_95_px"],
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


def orthoimage_figure(run: Path, points: int = 16) -> dict:
    """no_stage.yaml with ground control from a reference orthoimage (4x the GSD, chips of
    32 reference px at ``points`` places), on a rendered run's record and product renders
    (``imc run scenarios/no_stage.yaml --save-frames --out RUN``: its tracks, frames and
    product chunks, nothing rendered again): the run's product path
    (:func:`imc.wiring.product.run_study`) with ``product.ground_control.kind:
    orthoimage``; metrics.json's product geometry and the fixes' own figures."""
    from imc.outputs.product_files import product_metrics
    from imc.wiring.product import run_study

    d = yaml.safe_load((ROOT / "scenarios" / "no_stage.yaml").read_text())
    d.pop("expect", None)
    d["product"]["ground_control"] = {"kind": "orthoimage", "points": points}
    m, plant, res, links = _from_run(d, run)
    plan = plan_product(m)
    rest = restitute(m, links, np.array([plan.line_t_s[0], plan.line_t_s[-1]
                                         + plan.integration_s]))
    store = next((run / "product" / "chunks").iterdir())  # the run's renders
    ds, _ = run_study(m, res, plan, m.scenario.product.samples, store, rest)
    prod = product_metrics(ds)
    return {"ground_control": ds.attrs.get("ground_control"),
            "geometry": prod["geometry"], "record": prod["record"]}


def correlator_efficiency(pairs: int = 150, seed: int = 32) -> dict:
    """The correlator's actual error against its own predicted error (the CRLB it reports,
    what the analytic plant draws its noise at) on textures other than the bundled scenes:
    1/f^beta fields (beta 2, 2.5, 3; contrast 0.15) and the strong / medium synthetic
    textures, 64-px blocks as no_stage.yaml's tracker, shifts within +-2 px, SNR 30 and 100:
    RMS error / RMS CRLB per axis over the valid pairs within 0.5 px."""
    from correlator.core import measure_shift
    from correlator.testimages import image_pairs, powerlaw_images, texture_pairs

    rng = np.random.default_rng(seed)
    out = {}
    cases = [(f"powerlaw {beta}", beta) for beta in (2.0, 2.5, 3.0)] + [
        ("strong", None), ("medium", None)]
    for name, beta in cases:
        imgs = powerlaw_images(6, 256, beta, rng) if beta is not None else None
        for snr in (30.0, 100.0):
            if imgs is not None:
                ref, cur, d = image_pairs(imgs, pairs, 64, rng, snr=snr, contrast=0.15,
                                          max_shift_px=2.0)
            else:
                ref, cur, d = texture_pairs(pairs, 64, rng, snr=snr, texture=name,
                                            max_shift_px=2.0)
            r = measure_shift(ref, cur)
            err = r.shift - d
            ok = r.valid & (np.abs(err).max(axis=1) < 0.5)
            out[f"{name}, SNR {snr:g}"] = {
                "efficiency": (np.sqrt(np.mean(err[ok] ** 2, axis=0))
                               / np.sqrt(np.mean(r.crlb[ok] ** 2, axis=0))).tolist(),
                "crlb_px": float(np.sqrt(np.mean(r.crlb[ok] ** 2))),
                "valid": float(ok.mean())}
    return out


def scene_efficiency(m=None, draws: int = 24, radiance: np.ndarray | None = None) -> dict:
    """The correlator's error against its bound on no_stage.yaml's own texture
    (:func:`imc.wiring.rendered_plant.efficiency_on_scene`: the flat-shaded albedo, or
    ``radiance``, e.g. a rendered frame 0)."""
    from imc.wiring.rendered_plant import efficiency_on_scene

    if m is None:
        d = _scenario()
        d["plant"] = {"fidelity": "analytic"}
        m = build_models(parse_scenario(d))
    return efficiency_on_scene(m, radiance, draws)


def solve_timing(frames: tuple[int, ...] = (331, 2000), k_max: int = 4) -> dict:
    """Seconds of one network solve (estimate and covariance) of a synthetic chained tracker
    like no_stage.yaml's (4 blocks of 64 px on a 256-px sensor, the content moving 41.5 px a
    frame, pairs cut as :func:`imc.wiring.links.pair_corners` cuts them) with the links'
    shared noise (generalised least squares, the saddle-point system) and weighed as
    independent (the normal equations), at ``frames`` frames and K = ``k_max``."""
    from ground.network import Links, SharedNoise, solve_network
    from imc.wiring.links import pair_corners

    grid = np.array([[32, 32], [32, 160], [160, 32], [160, 160]])
    out = {}
    for n in frames:
        pairs = np.array([(b - j, b) for b in range(1, n) for j in range(1, min(k_max, b) + 1)])
        reg = np.zeros((len(pairs), 4, 2, 2), int)
        used = np.zeros((len(pairs), 4), bool)
        for i, (a, b) in enumerate(pairs):
            st = np.tile([41.5 * (b - a), 0.3 * (b - a)], (4, 1))
            ref, used[i] = pair_corners(grid, st, 64, np.array([192, 192]))
            reg[i, :, 0], reg[i, :, 1] = ref, ref + np.rint(st).astype(int)
        share = np.where(used[..., None], 0.01, 0.0) * np.ones(2)
        valid = used.any(axis=1)
        shared = SharedNoise.from_blocks(pairs[:, 0], pairs[:, 1], reg[:, :, 0], reg[:, :, 1],
                                         share, 64)
        sigma = np.sqrt(np.sum(share**2, axis=1)) + np.where(valid, 0.0, 1.0)[:, None]
        d = np.zeros((len(pairs), 2))
        row = {}
        for name, links in (("shared_s", Links(pairs[:, 0], pairs[:, 1], d, 0.0 * sigma, valid,
                                                shared=shared)),
                            ("independent_s", Links(pairs[:, 0], pairs[:, 1], d, sigma, valid))):
            t0 = time.perf_counter()
            solve_network(links, n)
            row[name] = time.perf_counter() - t0
        out[str(n)] = {"links": int(valid.sum()), **row}
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="the analytic plant only")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out"))
    ap.add_argument("--run", type=Path, default=None, help="the rendered record of `imc run "
                    "scenarios/no_stage.yaml --save-frames --out RUN` instead of a new loop")
    ap.add_argument("--seed", type=int, default=None, help="the scenario's seed (its noise "
                    "streams: another realisation of the same strip); default the YAML's")
    ap.add_argument("--fidelity", choices=("rendered", "analytic"), default=None,
                    help="one plant only")
    ap.add_argument("--efficiency", action="store_true", help="only the correlator's "
                    "efficiency on synthetic textures")
    ap.add_argument("--orthoimage", action="store_true", help="only the reference "
                    "orthoimage's ground control on --run's record and product renders")
    ap.add_argument("--baselines", action="store_true", help="only the geometry against K, "
                    "with the links' shared noise and weighed as independent")
    ap.add_argument("--links", type=Path, default=None, help="with --run: the links measured "
                    "on its frames, read from this .npz (written there by the first call)")
    ap.add_argument("--scene-efficiency", action="store_true", help="only the correlator's "
                    "error over its bound on the analytic plant's view of the scene")
    ap.add_argument("--scene-eff", action="store_true", help="with --render-floor: the "
                    "bound's part drawn at the correlator's efficiency on the scene")
    ap.add_argument("--lengths", action="store_true", help="only the geometry at the three "
                    "strip lengths")
    ap.add_argument("--rendered-sigma", action="store_true", help="with --render-floor: "
                    "the analytic plant's bound (and --scene-eff's efficiency) from frame 0 as "
                    "the renderer draws it, not the flat-shaded albedo")
    ap.add_argument("--render-floor", action="store_true", help="the analytic plant's "
                    "links with the rendered tracker's Monte Carlo floor measured on the scene")
    ap.add_argument("--timing", action="store_true", help="only the network solve's time "
                    "with and without the links' shared noise")
    a = ap.parse_args()
    if a.rendered_sigma and not a.render_floor:
        ap.error("--rendered-sigma needs --render-floor (the analytic plant it changes)")
    out: dict = {}
    if a.timing:
        out["timing"] = solve_timing()
        print(json.dumps(out, indent=1), flush=True)
        return
    if a.orthoimage:
        out["orthoimage"] = orthoimage_figure(a.run)
        print(json.dumps(out, indent=1, default=str), flush=True)
        Path(a.out).mkdir(parents=True, exist_ok=True)
        write_json(Path(a.out) / "restitution_orthoimage.json", out)
        return
    if a.scene_efficiency:
        out["scene_efficiency"] = scene_efficiency()
        print(json.dumps(out, indent=1), flush=True)
        return
    if a.efficiency:
        out["efficiency"] = correlator_efficiency()
        print(json.dumps(out, indent=1), flush=True)
        Path(a.out).mkdir(parents=True, exist_ok=True)
        write_json(Path(a.out) / "restitution_efficiency.json", out)
        return
    fids = ("analytic",) if a.quick else (a.fidelity,) if a.fidelity else ("rendered",
                                                                             "analytic")
    for fid in fids:
        t0 = time.perf_counter()
        d = _scenario()
        d["plant"] = {"fidelity": fid}
        if a.seed is not None:
            d["seed"] = int(a.seed)
        m, plant, res, links = (_from_run(d, a.run, a.links) if fid == "rendered" and a.run
                                else _run(d, a.render_floor, a.scene_eff, a.rendered_sigma))
        r = {"loop_s": time.perf_counter() - t0,
             "efficiency": links.efficiency.tolist(), "links": int(links.valid.sum())}
        if fid == "rendered":
            r["budget"] = budget(m, res, plant)
        if a.lengths:
            r["lengths"] = [_geometry(m, links, n) for n in LENGTHS]
            out[fid] = r
            print(json.dumps({fid: r}, indent=1), flush=True)
            continue
        r["baselines"] = [_geometry(m, links, 12800, restitution={"baselines": k,
                                                                  "smoother": sm})
                          for k, sm in ((1, False), (1, True), (2, True), (3, True),
                                        (4, True))]
        if links.regions is not None:  # the same links weighed as independent (before)
            alone = dataclasses.replace(links, regions=None, share_px=None)
            r["baselines_independent"] = [
                _geometry(m, alone, 12800, restitution={"baselines": k, "smoother": sm})
                for k, sm in ((1, False), (1, True), (2, True), (3, True), (4, True))]
        if a.baselines:
            out[fid] = r
            print(json.dumps({fid: r}, indent=1), flush=True)
            continue
        r["aided"] = [_geometry(m, links, 12800, **extra) for extra in (
            {"gyro": {}}, {"ground_control": {"points": 4, "sigma_px": 0.02}},
            {"gyro": {}, "ground_control": {"points": 4, "sigma_px": 0.02}})]
        r["lengths"] = [_geometry(m, links, n) for n in LENGTHS]
        out[fid] = r
        print(json.dumps({fid: r}, indent=1), flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    tag = ("_" + a.fidelity if a.fidelity else "") + ("_floor" if a.render_floor else "") \
        + ("_eff" if a.scene_eff else "") + ("_rsig" if a.rendered_sigma else "") \
        + (f"_seed{a.seed}" if a.seed is not None else "")
    write_json(Path(a.out) / f"restitution{tag}.json", out)


if __name__ == "__main__":
    main()

"""The ground's pairs (baselines 1-4) on a rendered chained record against the camera model's
truth, per candidate cause of their bias (issue 32): each pair cut as
:func:`imc.wiring.links.pair_corners` cuts it, the current block brought to the predicted
motion five ways (the correlator's own sub-pixel estimate on the integer cut, as the links
are since 2026-12-05, and resampled by a cubic spline, as they were before, a quintic spline,
bilinear interpolation and a Fourier shift),
and the truth at the block's centre against its mean over a 5 x 5 grid across the block (a
field-dependent motion). Per baseline: the links' mean error and its standard error, each
block's mean, and the slope of the error on the true jitter increment (a scale error).

``FRAMES`` (an .npz) and ``KEYS``: frames other than the run's own, e.g. the same scene
rendered again with other noise seeds, or without the sensor's noise, to tell a systematic
bias from the one realisation's noise; ``--rerender SEED`` renders them here (Mitsuba, ~1
min on 2 cores). Measured here, never asserted in tests.

    .venv/bin/python benchmarks/bench_pair_bias.py --run RUN [--frames FILE --keys a,b]
        [--rerender SEED] [--geometry] [--out benchmarks/out]

RUN: ``imc run scenarios/no_stage.yaml --save-frames --out RUN``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import fourier_shift, map_coordinates, spline_filter

from correlator.core import measure_shift
from correlator.tracker import BlockTracker, extract_blocks
from imc.io import write_json
from imc.scenario import parse_scenario
from imc.wiring import streams
from imc.wiring.build import build_models, predicted_px
from imc.wiring.links import pair_corners
from imc.wiring.truth import exposure_times

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_restitution import _scenario  # noqa: E402

#: how the current block is brought to the predicted motion
VARIANTS = ("integer", "cubic", "quintic", "bilinear", "fourier")
#: baselines measured, frames
BASELINES = (1, 2, 3, 4)


def pair_errors(m, frames: np.ndarray) -> list[dict]:
    """Each pair's per-block error (B, 2) px against the truth, per variant, with its cut,
    the predicted motion and the truth at the centre and over the block's 5 x 5 grid."""
    b = m.scenario.correlator.block_px
    fp = m.camera.focal_plane
    lim = np.array([fp.rows - b, fp.cols - b])
    grid = BlockTracker.centers_from(m.corners, b)
    s = m.scenario.metrics.samples_per_frame
    q = np.stack(np.meshgrid(np.arange(b), np.arange(b), indexing="ij"), -1)
    half = (b - 1) / 2.0
    off = np.stack(np.meshgrid(np.linspace(-half, half, 5), np.linspace(-half, half, 5),
                               indexing="ij"), -1).reshape(-1, 2)
    z = np.zeros(2)
    rows = []
    for k in range(max(BASELINES), len(m.frame_t_s)):
        fk = frames[k].astype(np.float64)
        coeffs = {3: spline_filter(fk, order=3), 5: spline_filter(fk, order=5)}
        spectrum = np.fft.fft2(fk)
        for j in BASELINES:
            a = k - j
            corners, used = pair_corners(m.corners, predicted_px(m, grid, a, k, z, z), b, lim)
            centers = BlockTracker.centers_from(corners, b)
            pred = predicted_px(m, centers, a, k, z, z)
            times = np.concatenate([exposure_times(m, a, s), exposure_times(m, k, s)])
            pts = np.concatenate([centers, (centers[:, None] + off[None]).reshape(-1, 2)])
            g = m.camera.ground_points(pts, float(m.frame_mid_s[a]), m.terrain.height_at)
            mo = m.camera.image_motion_px(g, times, float(m.frame_mid_s[a]))
            true_all = mo[s:].mean(0) - mo[:s].mean(0)
            true = true_all[:len(centers)]
            true_grid = true_all[len(centers):].reshape(len(centers), -1, 2).mean(1)
            tr = BlockTracker(frames[a].astype(np.float64), corners, b, m.correlator)
            src = q[None] + corners[:, None, None, :] + pred[:, None, None, :]
            idx = [src[..., 0].ravel(), src[..., 1].ravel()]
            r = tr.update(fk, pred, None)
            err = {"integer": (r.shift - true, r.valid)}
            fourier = np.stack([extract_blocks(np.real(np.fft.ifft2(fourier_shift(
                spectrum, -p))), corners, b)[i] for i, p in enumerate(pred)])
            for name, cur in (
                    ("cubic", map_coordinates(coeffs[3], idx, order=3, mode="nearest",
                                              prefilter=False)),
                    ("quintic", map_coordinates(coeffs[5], idx, order=5, mode="nearest",
                                                prefilter=False)),
                    ("bilinear", map_coordinates(fk, idx, order=1, mode="nearest")),
                    ("fourier", fourier)):
                rr = tr.correlator.measure(cur.reshape(len(corners), b, b))
                err[name] = (rr.shift + pred - true, rr.valid)
            rows.append({"j": j, "k": k, "used": used, "pred": pred, "true": true,
                         "grid_minus_centre": true_grid - true,
                         **{n: np.where((v & used)[:, None], e, np.nan)
                            for n, (e, v) in err.items()}})
    return rows


def floor_errors(m, sets: dict[str, np.ndarray], k_max: int = 4) -> list[dict]:
    """Each pair's per-block error (B, 2) px against the camera model's truth on each set of
    frames (e.g. ``noisy`` and ``clean``, the same radiance with and without the sensor's
    noise), measured as the ground's links are (the pair cut by
    :func:`imc.wiring.links.pair_corners`, the current block resampled at the predicted
    motion, :meth:`correlator.tracker.BlockTracker.update` with ``flow``), with the bound
    the correlator reports on each set and the pair's predicted step (B, 2) px (its
    fractional part is the frames' sub-pixel sampling phase)."""
    b = m.scenario.correlator.block_px
    fp = m.camera.focal_plane
    lim = np.array([fp.rows - b, fp.cols - b])
    grid = BlockTracker.centers_from(m.corners, b)
    s = m.scenario.metrics.samples_per_frame
    z = np.zeros(2)
    rows = []
    for k in range(k_max, len(m.frame_t_s)):
        for j in range(1, k_max + 1):
            a = k - j
            corners, used = pair_corners(m.corners, predicted_px(m, grid, a, k, z, z), b, lim)
            centers = BlockTracker.centers_from(corners, b)
            pred = predicted_px(m, centers, a, k, z, z)
            times = np.concatenate([exposure_times(m, a, s), exposure_times(m, k, s)])
            g = m.camera.ground_points(centers, float(m.frame_mid_s[a]), m.terrain.height_at)
            mo = m.camera.image_motion_px(g, times, float(m.frame_mid_s[a]))
            true = mo[s:].mean(0) - mo[:s].mean(0)
            flow = np.broadcast_to(pred[:, None, None, :], (len(pred), b, b, 2))
            row = {"j": j, "k": k, "pred": pred, "true": true}
            for key, fr in sets.items():
                tr = BlockTracker(fr[a].astype(np.float64), corners, b, m.correlator)
                r = tr.update(fr[k].astype(np.float64), pred, None, flow=flow)
                ok = (r.valid & used)[:, None]
                row[key] = np.where(ok, r.shift - true, np.nan)
                row[key + "_crlb"] = np.where(ok, r.crlb, np.nan)
            rows.append(row)
    return rows


def floor_summary(rows: list[dict], keys: tuple[str, ...], noisy: str = "noisy",
                  clean: str = "clean") -> dict:
    """Per baseline: each set's block error RMS about the set's mean (row, col) px, the RMS
    bound the correlator reports on the noisy frames, the noiseless floor f0 (the clean
    set's RMS) and sqrt(crlb^2 + f0^2) / crlb against the measured noisy RMS / crlb; and the
    clean error against the pair's sub-pixel phase (|frac(step)| in 5 bins per axis)."""
    out = {}
    for j in sorted({r["j"] for r in rows}):
        rr = [r for r in rows if r["j"] == j]
        step = np.stack([r["true"] for r in rr])
        fig = {"pairs": len(rr)}
        for key in keys:
            e = np.stack([r[key] for r in rr])
            fig[key + "_rms_px"] = np.sqrt(np.nanmean((e - np.nanmean(e, axis=(0, 1))) ** 2,
                                                      axis=(0, 1))).tolist()
            fig[key + "_mean_px"] = np.nanmean(e, axis=(0, 1)).tolist()
        crlb = np.sqrt(np.nanmean(np.stack([r[noisy + "_crlb"] for r in rr]) ** 2,
                                  axis=(0, 1)))
        fig["crlb_rms_px"] = crlb.tolist()
        if noisy in keys and clean in keys:
            f0, tot = np.array(fig[clean + "_rms_px"]), np.array(fig[noisy + "_rms_px"])
            fig["measured_over_crlb"] = (tot / crlb).tolist()
            fig["sqrt_crlb2_f02_over_crlb"] = (np.sqrt(crlb ** 2 + f0 ** 2) / crlb).tolist()
            for key in keys:  # the sensor noise's own part: the same radiance's error removed
                if key != clean:
                    part = np.stack([r[key] - r[clean] for r in rr])
                    c = np.sqrt(np.nanmean(np.stack([r[key + "_crlb"] for r in rr]) ** 2,
                                           axis=(0, 1)))
                    fig[key + "_less_clean_over_crlb"] = (np.sqrt(np.nanmean(
                        part ** 2, axis=(0, 1))) / c).tolist()
            e = np.stack([r[clean] for r in rr])
            frac = np.abs(step - np.rint(step))  # (n, B, 2) sub-pixel phase, 0..0.5
            bins = np.linspace(0.0, 0.5, 6)
            fig["clean_rms_by_phase_px"] = [[
                float(np.sqrt(np.nanmean(e[..., i][(frac[..., i] >= lo) & (frac[..., i] < hi)]
                                         ** 2)))
                if np.any((frac[..., i] >= lo) & (frac[..., i] < hi)) else None
                for lo, hi in zip(bins[:-1], bins[1:], strict=True)] for i in range(2)]
            fig["phase_counts"] = [np.histogram(frac[..., i], bins)[0].tolist()
                                   for i in range(2)]
        out[str(j)] = fig
    return out


def _in_dn(noisy: np.ndarray, clean: np.ndarray) -> tuple[np.ndarray, float]:
    """The clean frames on the noisy ones' DN scale (a least-squares gain and offset: the
    re-render's clean frames are the optics' output times the exposure gain, before the
    sensor's conversion) and the sensor noise's mean variance, DN^2."""
    x, y = clean.ravel()[::97].astype(np.float64), noisy.ravel()[::97].astype(np.float64)
    g, o = np.polyfit(x, y, 1)
    dn = g * clean.astype(np.float64) + o
    return dn, float(np.var(noisy.astype(np.float64) - dn))


def noise_kind(noisy: np.ndarray, clean: np.ndarray, block_px: int = 64, step: int = 8,
               seed: int = 7) -> dict:
    """The correlator's error against its bound on the rendered content alone: every
    ``step``-th clean frame cut into a grid of blocks, each block against itself with two
    independent noise draws (true shift 0: no Monte Carlo floor, no interpolation), the
    sensor's signal-dependent noise (its variance's linear fit on the clean level, from
    noisy - clean) and white noise of the same mean power: RMS error / RMS bound per axis."""
    dn, var = _in_dn(noisy[::step], clean[::step])
    r = noisy[::step].astype(np.float64) - dn
    edges = np.quantile(dn, np.linspace(0, 1, 11))
    idx = np.digitize(dn, edges[1:-1])
    lvl = np.array([dn[idx == i].mean() for i in range(10)])
    slope, icpt = np.polyfit(lvl, [r[idx == i].var() for i in range(10)], 1)
    b = block_px
    n = dn.shape[-1] // b
    blocks = dn[:, :n * b, :n * b].reshape(len(dn), n, b, n, b).transpose(0, 1, 3, 2, 4) \
        .reshape(-1, b, b)
    rng = np.random.default_rng(seed)
    out = {"noise_var_dn2": [float(icpt), float(slope)], "blocks": len(blocks)}
    for name, sd in (("physical", np.sqrt(np.maximum(icpt + slope * blocks, 1e-6))),
                     ("white", np.full(blocks.shape, np.sqrt(var)))):
        x = np.rint(blocks + sd * rng.standard_normal(blocks.shape))
        y = np.rint(blocks + sd * rng.standard_normal(blocks.shape))
        res = measure_shift(x, y)
        ok = res.valid
        out[name] = {"valid": float(ok.mean()),
                     "rms_px": np.sqrt(np.mean(res.shift[ok] ** 2, axis=0)).tolist(),
                     "crlb_px": np.sqrt(np.mean(res.crlb[ok] ** 2, axis=0)).tolist()}
        out[name]["over_crlb"] = (np.array(out[name]["rms_px"])
                                  / np.array(out[name]["crlb_px"])).tolist()
    return out


def render_phase(m, frames=(5, 60, 120, 180, 240, 300), spps=(4, 32)) -> dict:
    """Aliasing against the renderer's Monte Carlo noise: each frame's pose rendered (no
    sensor noise, the optics applied) with sampler seed 101, then with seed 202 at the same
    pose, and with the stage (the principal point) moved by exactly 0.5 and 1.0 px along
    track and 0.5 px across, at ``spps`` samples a pixel (Mitsuba's stratified sampler
    rounds 32 to 36); the run's 4 blocks correlated against the first render: RMS error
    about its mean (row, col) px over frames and blocks. Aliasing grows at the half pixel
    and vanishes at the whole one; the sampling noise does not care."""
    from imc.wiring import rendered_plant
    from scene.pinhole import ray_keyframes

    plant = rendered_plant.RenderedPlant(m)
    r, fp, b = plant.renderer, m.camera.focal_plane, m.scenario.correlator.block_px
    cases = {"seed": ((0.0, 0.0), 202), "row_0.5": ((0.5, 0.0), 202),
             "row_1.0": ((1.0, 0.0), 202), "col_0.5": ((0.0, 0.5), 202)}
    err = {f"{c}_{spp}": [] for c in cases for spp in spps}
    for k in frames:
        t = float(m.frame_t_s[k]) + np.linspace(0.0, m.exposure_s, rendered_plant.KEYFRAMES)

        def img(off, seed, spp, t=t):
            r.spp = spp
            kf = ray_keyframes(m.camera.pose(t), fp, np.tile(off, (len(t), 1)), r.z_start_m)
            return m.optics.apply(r.render(kf, seed))

        for spp in spps:
            ref = img((0.0, 0.0), 101, spp)
            tr = BlockTracker(ref, m.corners, b, m.correlator)
            for c, (off, seed) in cases.items():
                res = tr.update(img(off, seed, spp), np.zeros((len(m.corners), 2)))
                err[f"{c}_{spp}"].append(np.where(res.valid[:, None], res.shift, np.nan))
    out = {}
    for key, e in err.items():
        e = np.concatenate(e)
        out[key] = np.nanstd(e, axis=0).tolist()
    return out


def rerender(m, seed: int) -> dict[str, np.ndarray]:
    """The run's tracker frames rendered again from the true pose (no stage) with the render
    and sensor noise of scenario seed ``seed`` (the scene and the motion unchanged):
    ``noisy`` (DN) and ``clean`` (the same radiance through the optics, without the sensor's
    noise; the renderer's own sampling noise stays)."""
    from bench_link_bias import _AtRest

    from imc.wiring import rendered_plant, streams

    plant = rendered_plant.RenderedPlant(m)
    render_seed = streams.render_seed
    rendered_plant.streams.render_seed = lambda _s, k, name="render": render_seed(seed, k, name)
    try:
        still = _AtRest()
        n, fp = len(m.frame_t_s), m.camera.focal_plane
        noisy = np.zeros((n, fp.rows, fp.cols), np.uint16)
        clean = np.zeros((n, fp.rows, fp.cols))
        gain = 0.0
        for k in range(n):
            rad = plant.radiance(k, still)
            gain = m.sensor.gain_for(m.optics.apply(rad)) if k == 0 else gain
            noisy[k] = rendered_plant.expose_frame(m, rad, gain, streams.rng(seed, "sensor", k))
            clean[k] = m.optics.apply(rad) * gain
    finally:
        rendered_plant.streams.render_seed = render_seed
    return {"noisy": noisy, "clean": clean}


def geometry(m, frames: np.ndarray, k_max: int = 4) -> list[dict]:
    """The strip's geometry (after a constant / an affine, measured and predicted, K = 1 ..
    ``k_max`` smoothed) from links measured on ``frames``: every baseline, the first too,
    cut by :func:`imc.wiring.links.pair_corners` (``links._extra_blocks``), the first flagged
    as the loop's; the product's solve (``bench_restitution._geometry``)."""
    from bench_restitution import _geometry

    from imc.wiring.links import LinkTable, _extra_blocks, combine_blocks

    n = len(m.frame_t_s)
    a, b, d, s, v, reg = _extra_blocks(m, frames, np.zeros((n, 2)), k_max, first=1)
    mean, sig, nblk, chi2 = combine_blocks(d, s, v)
    ok = nblk >= 2
    eff = np.sqrt(np.maximum(chi2[ok].sum(0) / max(int((nblk[ok] - 1).sum()), 1), 1.0))
    share = np.where(v[..., None], sig[:, None] ** 2 / np.maximum(s, 1e-12), 0.0) * eff
    valid = (nblk >= 1) & np.all(np.isfinite(mean), axis=1)
    links = LinkTable(a, b, mean, sig * eff, valid, m.frame_mid_s[b], b - a, nblk, b - a == 1,
                      eff, reg, share, int(m.scenario.correlator.block_px), 1)
    return [_geometry(m, links, m.scenario.product.lines,
                      restitution={"baselines": k, "smoother": True})
            for k in range(1, k_max + 1)]


def summary(rows: list[dict]) -> dict:
    """Per baseline and variant: the links' mean error (row, col) px and its standard error,
    each block's mean, and the error's slope on the true jitter increment."""
    out = {}
    for j in BASELINES:
        rr = [r for r in rows if r["j"] == j]
        inc = np.stack([r["true"] - r["pred"] for r in rr])
        fig = {"pairs": len(rr),
               "blocks_used": float(np.mean([r["used"].sum() for r in rr])),
               "truth_grid_minus_centre_px": np.stack([r["grid_minus_centre"] for r in rr])
               .mean(axis=(0, 1)).tolist()}
        for v in VARIANTS:
            e = np.stack([r[v] for r in rr])
            link = np.nanmean(e, axis=1)
            n = np.isfinite(link).sum(axis=0)
            ok = np.isfinite(e[..., 1])
            slope = np.polyfit(inc[..., 1][ok], e[..., 1][ok], 1)[0]
            fig[v] = {"link_mean_px": np.nanmean(link, axis=0).tolist(),
                      "link_mean_se_px": (np.nanstd(link, axis=0) / np.sqrt(n)).tolist(),
                      "block_mean_col_px": [float(x) if np.isfinite(x) else None
                                            for x in np.nanmean(e[..., 1], axis=0)],
                      "col_slope_on_increment": float(slope)}
        out[str(j)] = fig
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", type=Path, required=True)
    ap.add_argument("--frames", type=Path, default=None, help="an .npz of other frames")
    ap.add_argument("--keys", default="frames", help="comma-separated arrays of --frames")
    ap.add_argument("--rerender", type=int, default=None, help="measure the frames "
                    "rendered again with this noise seed (noisy and without sensor noise)")
    ap.add_argument("--geometry", action="store_true", help="also the strip's geometry "
                    "against K from links measured on each set of frames")
    ap.add_argument("--floor", action="store_true", help="each link's error RMS on the "
                    "noisy and the noiseless frames (--rerender, or --keys noisy,clean) "
                    "against the bound, as the ground measures them: the noiseless floor")
    ap.add_argument("--white", action="store_true", help="with --floor: also the clean "
                    "frames plus white Gaussian noise of the sensor noise's mean power")
    ap.add_argument("--phase", action="store_true", help="only the renders of one pose "
                    "with other sampler seeds and sub-pixel steps, at 4 and 32 spp")
    ap.add_argument("--noise-kind", action="store_true", help="only the correlator's error "
                    "over its bound on --frames' clean content (keys noisy, clean) with the "
                    "sensor's noise and white noise, true shift 0 (no model is built)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "out"))
    a = ap.parse_args()
    if a.noise_kind:
        with np.load(a.frames) as f:
            out = noise_kind(f["noisy"], f["clean"])
        print(json.dumps(out, indent=1), flush=True)
        return
    d = _scenario()
    d["plant"] = {"fidelity": "rendered"}
    m = build_models(parse_scenario(d))
    if a.rerender is not None:
        z, keys = rerender(m, a.rerender), ("noisy", "clean")
    else:
        src = a.frames if a.frames is not None else a.run / "frames.npz"
        with np.load(src) as f:
            keys = a.keys.split(",")
            z = {k: f[k] for k in keys}
    out = {}
    if a.phase:
        out = render_phase(m)
        print(json.dumps(out, indent=1), flush=True)
        return
    if a.floor:
        if a.white and "clean" in z:  # the same radiance with white noise of the same power
            rng = streams.rng(m.scenario.seed, "sensor", 10 ** 6)  # no frame has it
            dn, var = _in_dn(z["noisy"], z["clean"])
            z["white"] = np.rint(dn + rng.normal(0.0, np.sqrt(var), dn.shape))
            keys = (*keys, "white")
        t0 = time.perf_counter()
        rows = floor_errors(m, z)
        out = {"floor": floor_summary(rows, tuple(keys)), "s": time.perf_counter() - t0}
        print(json.dumps(out, indent=1), flush=True)
        Path(a.out).mkdir(parents=True, exist_ok=True)
        write_json(Path(a.out) / "pair_floor.json", out)
        return
    for key in keys:
        t0 = time.perf_counter()
        out[key] = {**summary(pair_errors(m, z[key])), "s": time.perf_counter() - t0}
        if a.geometry:
            out[key]["geometry"] = geometry(m, z[key])
        print(json.dumps({key: out[key]}, indent=1), flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    write_json(Path(a.out) / "pair_bias.json", out)


if __name__ == "__main__":
    main()

"""The main imager's image product of a run, and its ground processing.

The imager is rendered as it forms its image (:mod:`scene.strip`: a TDI strip line by line,
or a frame window, every sample's line of sight from the true orbit, attitude and jitter and
the stage's trajectory, cast through the scene kernel's :class:`scene.kernel.RayCaster`),
three times from the same scene and noise stream: **static** (the nominal, jitter-free pose,
the stage at rest), **open** (the true pose, no stage) and **closed** (the true pose and the
loop's stage trajectory). Each goes through the optics' MTF, the detector, noise and
quantisation as the tracker's frames do (:func:`scene.strip.expose`).

On the ground (:mod:`ground`), from the loop's **record** (what it received: the estimator's
motion at the main imager's field point, valid samples only, never the truth), less the
orbit / attitude prediction, plus the stage's own position record for the closed loop:

- the per-line line-of-sight offset on the nominal grid (exact averages over each line's
  integration of a cubic interpolant of the record) and the product resampled onto the
  nominal grid (``*_gc``: ground corrected, the SmartScan method);
- the residual-motion PSF of each run of lines from the same record and a Wiener
  deconvolution with it (``*_gc_restored``).

The same correction from a **perfect record** (the camera model's jitter at the record's own
sample times and the true stage) shows the record's own share of the error. The record counts
from the tracker's reference frame, whose own offset it cannot see: that one constant per axis
is set as ground control points set it (``ground_control_px``, the mean of the corrected
offset's error), so the geometric errors (``rms_px``, ``peak_to_peak_px``) are the strip's
distortion, line to line.

Image quality of every product is measured on a second scene rendered through the very same
lines of sight and ground processing: a flat slanted-square target (a dark ground with a bright
square turned 5 degrees, centred on the product): slanted-edge MTF at Nyquist, RER and
overshoot along and across, noise gain and SNR on the square's flat inside, NIIRS by GIQE 5
(pyBSM); PSNR and SSIM against the static product on the scene itself.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imc.io import atomic_write, write_npz
from imc.scenario import ScenarioError
from imc.wiring import streams
from imc.wiring.build import Models

#: the rendered versions of the product (rendered from the same scene and noise stream)
RENDERED = ("static", "open", "closed")
#: the target's albedo (dark ground, bright square) and its turn against the image axes, deg
TARGET_ALBEDO = (0.12, 0.5)
TARGET_ANGLE_DEG = 5.0
#: half-width of an edge's region of interest across the edge, px
EDGE_HALF_PX = 32
#: the record's per-line motion model (:func:`ground.record.line_motion`)
RECORD_METHOD = "cubic"
#: residual samples per line (or exposure) for the restoration PSF
PSF_SUBSAMPLES = 32


@dataclass(frozen=True)
class ProductPlan:
    """What the product covers: ``kind`` 'tdi' or 'frame'; ``line_t_s`` (L,) the start of
    each line's integration (a frame: L rows, all ``t0_s``), ``integration_s``; the detector
    ``cols`` (C,) and, for a frame, ``rows`` (L,); the line rate (TDI), Hz."""

    kind: str
    t0_s: float
    line_t_s: np.ndarray
    integration_s: float
    cols: np.ndarray
    rows: np.ndarray | None
    line_rate_hz: float | None

    @property
    def n_lines(self) -> int:
        return len(self.line_t_s)

    @property
    def sign(self) -> np.ndarray:
        """(row, col) factors from the residual image motion r = jitter - stage to the
        line-of-sight offset on the nominal grid (``strip[l] ~ static[l + off]``): a TDI line
        counts against the image flow along rows, a frame pixel with it (docs/conventions.md;
        pinned by tests/test_product.py)."""
        return np.array([1.0, -1.0]) if self.kind == "tdi" else np.array([-1.0, -1.0])


def target_window(plan: ProductPlan) -> slice:
    """The lines the quality target is rendered over: the strip's middle, as many lines as it
    has columns (at least 256; a frame: all), so the target's tile does not grow with a long
    strip."""
    n = min(plan.n_lines, max(len(plan.cols), 256))
    a = (plan.n_lines - n) // 2
    return slice(a, a + n)


def sub_plan(plan: ProductPlan, lines: slice) -> ProductPlan:
    """The plan of a window of the product's lines."""
    if plan.kind == "frame":
        return plan
    t = plan.line_t_s[lines]
    return ProductPlan(plan.kind, float(t[0]), t, plan.integration_s, plan.cols, None,
                       plan.line_rate_hz)


def plan_product(m: Models) -> ProductPlan:
    """The product's lines, columns and times for the scenario's ``product`` section; a
    product that does not fit the run or the imager is a ScenarioError naming the field."""
    p = m.scenario.product
    sc = m.scenario
    imager = m.imager
    n_cols = imager.cols
    if p.cols > n_cols:
        raise ScenarioError(f"product.cols: {p.cols} columns, the main imager has {n_cols}; "
                            "lower it")
    cols = np.arange(p.cols) + (n_cols - p.cols) // 2
    start = sc.camera.main_imager.start_s if p.start_s is None else p.start_s
    if m.line_rate_hz is not None:
        period = 1.0 / m.line_rate_hz
        integration = imager.stages * period
        if p.start_s is None:
            start = max(start, _centre_time(m) - 0.5 * (p.lines + imager.stages) * period)
        line_t = start + np.arange(p.lines) * period
        end = line_t[-1] + integration
        rows, kind, rate = None, "tdi", m.line_rate_hz
    else:
        if p.lines > imager.rows:
            raise ScenarioError(f"product.lines: {p.lines} rows, the main imager has "
                                f"{imager.rows}; lower it")
        integration = imager.exposure_s
        line_t = np.full(p.lines, float(start))
        end = start + integration
        rows = np.arange(p.lines) + (imager.rows - p.lines) // 2
        kind, rate = "frame", None
    if end > sc.duration_s + 1e-9:
        what = "lines" if kind == "tdi" else "start_s"
        raise ScenarioError(
            f"product.{what}: the product ends at {end:.4g} s, after the run ({sc.duration_s:g}"
            f" s): lower product.lines, start it earlier (product.start_s) or raise "
            "duration_s")
    plan = ProductPlan(kind, float(start), line_t, float(integration), cols, rows, rate)
    _check_coverage(m, plan)
    return plan


def _check_coverage(m: Models, plan: ProductPlan) -> None:
    """The scene tile must hold the product's footprint (its nominal corners)."""
    from camera.linescan import ground_points, imager_camera

    cam = imager_camera(m.camera, m.imager)
    fp = cam.focal_plane
    li = np.array([0, plan.n_lines - 1])
    ci = np.array([plan.cols[0], plan.cols[-1]], dtype=np.float64)
    ll, cc = (a.ravel() for a in np.meshgrid(li, ci, indexing="ij"))
    t = plan.line_t_s[ll] + 0.5 * plan.integration_s
    rows = (np.full(len(ll), fp.center_px[0]) if plan.rows is None
            else plan.rows[ll].astype(np.float64))
    g = ground_points(cam.pose(t, nominal=True), fp, np.column_stack([rows, cc]),
                      m.terrain.height_at)
    if not np.all(m.terrain.contains(g[:, 0], g[:, 1])):
        need = 2.0 * float(np.max(np.abs(g[:, :2])))
        raise ScenarioError(f"product.lines: the product's footprint reaches {need / 2:.0f} m "
                            f"from the scene centre, beyond the {m.scenario.scene.size_m:g} m "
                            "tile; lower product.lines / product.cols or raise scene.size_m")


def _centre_time(m: Models) -> float:
    """When the imager centre's nominal line of sight passes closest to the scene centre,
    s (0 for a staring camera): the strip is centred there by default (the tile's middle)."""
    from camera.linescan import ground_points, imager_camera

    cam = imager_camera(m.camera, m.imager)
    t = np.linspace(0.0, m.scenario.duration_s, 201)
    g = ground_points(cam.pose(t, nominal=True), cam.focal_plane,
                      np.broadcast_to(cam.focal_plane.center_px, (len(t), 2)),
                      m.terrain.height_at)
    return float(t[np.argmin(np.hypot(g[:, 0], g[:, 1]))])


# ------------------------------------------------------------------------------ rendering


def _render(m: Models, caster, plan: ProductPlan, stage, nominal: bool, samples: int,
            store: Path):
    """(radiance (L, C), line_offset_px (L, 2), rays, first hits) of one version. A strip's
    chunks are written to ``store`` as they are done (atomically) and a run that was killed
    resumes after the last one written; a frame is one chunk."""
    from scene.strip import iter_strip, render_frame

    store.mkdir(parents=True, exist_ok=True)
    if plan.kind == "frame":
        path = store / "frame.npz"
        if not path.exists():
            r = render_frame(caster, m.camera, m.imager, plan.t0_s, plan.rows, plan.cols,
                             samples, stage_offset_px=stage, nominal=nominal)
            write_npz(path, radiance=r.radiance, offset=r.offset_px.mean(axis=0),
                      counts=np.array([r.rays, r.first_hits]))
        with np.load(path) as f:
            off = np.broadcast_to(f["offset"], (plan.n_lines, 2)).copy()
            return f["radiance"], off, int(f["counts"][0]), int(f["counts"][1])
    done = sorted(store.glob("lines_*.npz"))
    first = 0
    if done:
        with np.load(done[-1]) as f:
            first = int(f["first_line"]) + len(f["radiance"])
    if first < plan.n_lines:
        for ch in iter_strip(caster, m.camera, m.imager, plan.t0_s, plan.n_lines, plan.cols,
                             samples, stage_offset_px=stage, nominal=nominal,
                             line_rate_hz=plan.line_rate_hz, first_line=first):
            write_npz(store / f"lines_{ch.first_line:07d}.npz", first_line=ch.first_line,
                      radiance=ch.radiance, offset=ch.line_offset_px,
                      counts=np.array([ch.rays, ch.first_hits]))
    rad, off, rays, hits = [], [], 0, 0
    for path in sorted(store.glob("lines_*.npz")):
        with np.load(path) as f:
            rad.append(f["radiance"])
            off.append(f["offset"])
            rays, hits = rays + int(f["counts"][0]), hits + int(f["counts"][1])
    return np.concatenate(rad), np.concatenate(off), rays, hits


def target_terrain(m: Models, plan: ProductPlan, gsd_m: float):
    """The flat slanted-square target under the product: a bright square, half the product's
    smaller side, turned :data:`TARGET_ANGLE_DEG` against the imager's axes, centred where the
    product's middle line of sight meets the ground."""
    from camera.linescan import ground_points, imager_camera
    from scene.terrain import Terrain

    cam = imager_camera(m.camera, m.imager)
    fp = cam.focal_plane
    t_mid = float(plan.line_t_s[plan.n_lines // 2] + 0.5 * plan.integration_s)
    c_mid = float(plan.cols[len(plan.cols) // 2])
    r_mid = float(plan.rows[len(plan.rows) // 2]) if plan.rows is not None else fp.center_px[0]
    pix = np.array([[r_mid, c_mid], [r_mid, c_mid + 50.0], [r_mid + 50.0, c_mid]])
    g = ground_points(cam.pose(np.full(3, t_mid), nominal=True), fp, pix, m.terrain.height_at)
    across = (g[1] - g[0])[:2] / np.linalg.norm((g[1] - g[0])[:2])
    a = np.deg2rad(TARGET_ANGLE_DEG)
    u = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ across
    v = np.array([-u[1], u[0]])
    extent_px = max(plan.n_lines, len(plan.cols))
    half_side = 0.25 * min(plan.n_lines, len(plan.cols)) * gsd_m
    texel = gsd_m / 5.0
    size = 2.0 * (np.hypot(*g[0, :2]) + 0.75 * extent_px * gsd_m)
    n = int(np.ceil(size / texel))
    xs = (np.arange(n) + 0.5) * texel - 0.5 * n * texel
    east, north = np.meshgrid(xs, -xs)
    de, dn = east - g[0, 0], north - g[0, 1]
    inside = (np.abs(de * u[0] + dn * u[1]) < half_side) & (np.abs(de * v[0] + dn * v[1])
                                                            < half_side)
    albedo = np.where(inside, TARGET_ALBEDO[1], TARGET_ALBEDO[0]).astype(np.float32)
    return Terrain(albedo, texel, np.zeros((17, 17), np.float32), n * texel / 16.0)


# ------------------------------------------------------------------------------ the record


def jitter_truth_px(m: Models, t_s: np.ndarray) -> np.ndarray:
    """The true image motion (T, 2) px at the imager's centre against the nominal pose: where
    the true camera sees the ground the nominal one sees at the centre, at times t_s."""
    from camera.geometry import project
    from camera.linescan import ground_points, imager_camera

    cam = imager_camera(m.camera, m.imager)
    fp = cam.focal_plane
    t = np.asarray(t_s, dtype=np.float64)
    centre = np.broadcast_to(fp.center_px, (len(t), 2))
    g = ground_points(cam.pose(t, nominal=True), fp, centre, m.terrain.height_at)
    return project(g, cam.pose(t), fp) - centre


def record_jitter(m: Models, res):
    """The loop's record as the ground receives it: the estimator's motion at the field point
    (valid and delivered samples, at each tracker exposure's mid-time) less the orbit /
    attitude prediction there, made zero-mean (its constant, the reference frame's own
    offset, is unobservable): a :class:`ground.record.MotionRecord` of the jitter, px."""
    from ground.record import MotionRecord

    rec = res.record
    cam = m.main_camera
    t0 = float(m.frame_mid_s[0])
    ground = cam.ground_points(cam.focal_plane.center_px[None], t0, m.terrain.height_at)
    nominal = cam.image_motion_px(ground, m.frame_mid_s, t0, nominal=True)[:, 0]
    jit = rec.motion_px - nominal
    valid = rec.motion_valid & np.isfinite(rec.arrive_s)
    valid[0] = True  # the reference itself: motion 0 by definition
    jit = jit - jit[valid].mean(axis=0)
    return MotionRecord(m.frame_mid_s, jit, valid)


def perfect_jitter(m: Models, record):
    """The record a perfect tracker would have delivered: the camera model's jitter averaged
    over each tracker exposure, at the record's sample times (its gaps kept)."""
    from ground.record import MotionRecord

    sub = (np.arange(8) + 0.5) / 8.0 * m.exposure_s
    t = (m.frame_t_s[:, None] + sub[None]).ravel()
    j = jitter_truth_px(m, t).reshape(len(m.frame_t_s), len(sub), 2).mean(axis=1)
    return MotionRecord(m.frame_mid_s, j, record.valid)


def line_offsets(plan: ProductPlan, record, stage) -> np.ndarray:
    """Each line's line-of-sight offset (L, 2) on the nominal grid from a jitter record and the
    stage trajectory (None: at rest): the sign-mapped average of jitter minus stage over the
    line's integration."""
    from ground.record import exposure_average, line_motion

    jit = line_motion(record, plan.line_t_s, plan.integration_s, RECORD_METHOD)
    if stage is not None:
        sub = (np.arange(PSF_SUBSAMPLES) + 0.5) / PSF_SUBSAMPLES * plan.integration_s
        t = np.unique((plan.line_t_s[:, None] + sub[None]).ravel())
        jit = jit - exposure_average(t, stage(t), plan.line_t_s, plan.integration_s)
    return jit * plan.sign


def residual_samples(plan: ProductPlan, record, stage) -> tuple[np.ndarray, np.ndarray]:
    """(t (n,), residual (n, 2)) px: jitter minus stage sampled densely over the product's
    lines from the record (the restoration's PSF input), in nominal-grid axes."""
    from ground.record import line_motion

    sub = (np.arange(PSF_SUBSAMPLES) + 0.5) / PSF_SUBSAMPLES * plan.integration_s
    t = np.unique((plan.line_t_s[:, None] + sub[None]).ravel())
    r = line_motion(record, t, 0.0, RECORD_METHOD)
    if stage is not None:
        r = r - stage(t)
    if len(t) < 2:  # a frame exposure sampled once: a second instant at its end
        t = np.array([t[0], t[0] + max(plan.integration_s, 1e-6)])
        r = np.repeat(r, 2, axis=0)
    return t, r * plan.sign


# ------------------------------------------------------------------------------ the study


def product_study(m: Models, res, out: Path, fresh: bool = False) -> dict:
    """Render, process and judge the run's main-imager product; write ``product/`` (GeoTIFFs,
    per-line offsets, arrays) and return its metrics (``metrics.json`` product). A killed run
    resumes from the chunks written (``fresh``: renders anew)."""
    from ground.quality import image_quality
    from ground.rectify import geometric_error
    from ground.restore import run_psfs
    from scene.kernel import RayCaster, Renderer, Sun
    from scene.strip import expose

    sc = m.scenario
    p = sc.product
    plan = plan_product(m)
    folder = Path(out) / "product"
    chunks = folder / "chunks" / sc.digest()[:16]
    for old in (folder / "chunks").glob("*"):  # another scenario's chunks
        if (old != chunks or fresh) and old.is_dir():
            shutil.rmtree(old)
    stage = res.trajectory if sc.compensation.enabled else None
    sun = Sun(*m.sun_deg)
    gsd = _gsd_m(m)
    t_start = time.perf_counter()
    window = target_window(plan)
    plans = {"scene": plan, "target": sub_plan(plan, window)}
    scenes = {"scene": RayCaster(Renderer(m.terrain, sun, 16, 16, spp=1, clouds=m.clouds)),
              "target": RayCaster(Renderer(target_terrain(m, plans["target"], gsd), sun, 16,
                                           16, spp=1), sky_view_dirs=0)}
    t_built = time.perf_counter()
    versions = {"static": (None, True), "open": (None, False), "closed": (stage, False)}
    if stage is None:
        versions.pop("closed")
    radiance, truth_off, rays, hits = {}, {}, 0, 0
    for scene, caster in scenes.items():
        for name, (st, nominal) in versions.items():
            rad, off, n, h = _render(m, caster, plans[scene], st, nominal, p.samples,
                                     chunks / f"{scene}_{name}")
            radiance[scene, name] = rad
            rays, hits = rays + n, hits + h
            if scene == "scene":
                truth_off[name] = off
    t_rendered = time.perf_counter()

    # the detector: one noise stream per scene, the same draws for every version
    images = {}
    for scene in scenes:
        gain = m.sensor.gain_for(radiance[scene, "static"])
        for name in versions:
            pad = _pad(radiance[scene, name])
            dn = expose(pad, m.optics, m.sensor, streams.rng(sc.seed, "product",
                                                              _scene_id(scene)),
                        plan.integration_s, gain_e=gain)
            images[scene, name] = _crop(dn.astype(np.float64), radiance[scene, name].shape)

    # the ground: the record (and, to compare, a perfect one) -> offsets, correction, PSFs
    record = record_jitter(m, res)
    perfect = perfect_jitter(m, record)
    est_off, perf_off, geometry = {}, {}, {}
    true_stage = res.trajectory if stage is not None else None
    for name in versions:
        if name == "static":
            continue
        st = stage if name == "closed" else None
        true = truth_off[name]
        est = line_offsets(plan, record, st)
        perf = line_offsets(plan, perfect, true_stage if name == "closed" else None)
        # the constant no record sees is what ground control points fix
        est_off[name] = est - (est - true).mean(axis=0)
        perf_off[name] = perf - (perf - true).mean(axis=0)
        geometry[name] = {
            "before": geometric_error(np.zeros_like(true), true - true.mean(axis=0)).to_dict(),
            "after": geometric_error(est_off[name], true).to_dict(),
            "after_perfect_record": geometric_error(perf_off[name], true).to_dict(),
            "ground_control_px": _floats((est - true).mean(axis=0)),
        }
    nsr = 1.0 / max(m.sensor.snr(exposure_s=plan.integration_s), 1.0)
    products = {(s, n): images[s, n] for s in scenes for n in versions}
    shifts, valid, on_grid = {}, {}, {}
    for name in est_off:
        st = stage if name == "closed" else None
        # the distortion is resampled away; the constant offset goes into the georeference
        # (a resampling by a fraction of a pixel would cost MTF near Nyquist for nothing)
        shifts[name] = est_off[name].mean(axis=0)
        for scene, sp in plans.items():
            lines = slice(None) if scene == "scene" else window
            runs = np.arange(0, sp.n_lines, max(1, min(p.run_lines, sp.n_lines)))
            t_r, r = residual_samples(sp, record, st)
            kernels = [q.pixel for q in run_psfs(t_r, r, sp.line_t_s, sp.integration_s, runs)]
            off = est_off[name][lines]
            gc = _corrected(images[scene, name], off - shifts[name], kernels, runs, p.restore,
                            nsr)
            products[scene, f"{name}_gc"], products[scene, f"{name}_gc_restored"] = gc[:2]
            if scene == "scene":  # on the nominal grid itself, to compare with the static
                grid = _corrected(images[scene, name], off, kernels, runs, p.restore, nsr)
                on_grid[f"{name}_gc"], on_grid[f"{name}_gc_restored"] = grid[:2]
                valid[f"{name}_gc"] = valid[f"{name}_gc_restored"] = grid[2]
    t_ground = time.perf_counter()

    # quality
    rois = _target_rois(images["target", "static"])
    sigma_in = float(np.std(images["target", "static"][rois["flat"]], ddof=1))
    elevation = np.deg2rad(90.0 - _off_nadir_deg(m))
    quality = {}
    names = [n for (s, n) in products if s == "scene"]
    for name in names:
        v = valid.get(name)
        q_target = image_quality(_fill(products["target", name]), edge_roi_along=rois["along"],
                                 edge_roi_across=rois["across"], flat_roi=rois["flat"],
                                 noise_sigma_in=sigma_in, gsd_m=gsd, elevation_rad=elevation)
        q_scene = image_quality(_fill(on_grid.get(name, products["scene", name])),
                                images["scene", "static"], valid=v)
        d = q_target.to_dict()
        d.update(psnr_db=q_scene.psnr_db, ssim=q_scene.ssim)
        quality[name] = d
    static_niirs = quality["static"]["niirs"]
    for d in quality.values():
        d["niirs_loss"] = (static_niirs - d["niirs"]
                           if d["niirs"] is not None and static_niirs is not None else None)
    t_quality = time.perf_counter()

    files = _write_files(m, plan, folder, products, shifts, truth_off, est_off, perf_off)
    render_s = t_rendered - t_built
    return {
        "kind": plan.kind, "lines": plan.n_lines, "cols": int(len(plan.cols)),
        "samples": p.samples, "start_s": plan.t0_s, "integration_s": plan.integration_s,
        "line_rate_hz": plan.line_rate_hz, "gsd_m": gsd,
        "rays": int(rays), "hit_fraction": float(hits / max(rays, 1)),
        "scene_build_s": t_built - t_start, "render_s": render_s,
        "rays_per_s": float(rays / max(render_s, 1e-9)),
        "ground_s": t_ground - t_rendered, "quality_s": t_quality - t_ground,
        "record": _record_error(record, perfect),
        "geometry": geometry, "quality": quality,
        "restoration": _restoration_gain(quality),
        "files": [str(f) for f in files],
    }


def _record_error(record, perfect) -> dict:
    """The record's own error at the main imager: its jitter samples against the perfect
    record's (the camera model's exposure means) at the same times, about the mean (the
    constant is ground control's), px."""
    ok = record.valid & perfect.valid
    e = record.motion_px[ok] - perfect.motion_px[ok]
    e = e - e.mean(axis=0)
    return {"rms_px": _floats(np.sqrt(np.mean(e**2, axis=0))), "samples": int(ok.sum()),
            "rate_hz": float(ok.sum() / max(np.ptp(record.t_s[ok]), 1e-9))}


def _corrected(image: np.ndarray, offsets: np.ndarray, kernels: list, runs: np.ndarray,
               method: str, nsr: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(corrected, corrected and restored (NaN outside the strip), valid) of one product."""
    from ground.rectify import rectify
    from ground.restore import restore_strip

    gc = rectify(image, offsets, fill=np.nan)
    filled = np.where(gc.valid, gc.image, np.nanmean(gc.image))
    restored = restore_strip(filled, kernels, runs, method=method, nsr=nsr)
    return (np.where(gc.valid, gc.image, np.nan), np.where(gc.valid, restored, np.nan),
            gc.valid)


def _floats(v) -> list[float]:
    return [float(x) for x in np.atleast_1d(v)]


def _scene_id(scene: str) -> int:
    return 0 if scene == "scene" else 1


def _gsd_m(m: Models) -> float:
    """Ground sample distance at t = 0, m (the slant range times the IFOV)."""
    cam = m.main_camera
    pose = cam.pose(np.array([0.0]))
    g = cam.ground_points(cam.focal_plane.center_px[None], 0.0, m.terrain.height_at)
    return float(np.linalg.norm(pose.position_m[0] - g[0]) * cam.focal_plane.ifov_rad)


def _off_nadir_deg(m: Models) -> float:
    return float(m.main_camera.attitude.off_nadir_deg(m.main_camera.orbit, 0.0))


def _pad(img: np.ndarray, n: int = 16) -> np.ndarray:
    """Mirror padding, so the optics' periodic filter leaves the edges clean."""
    return np.pad(img, n, mode="reflect")


def _crop(img: np.ndarray, shape: tuple[int, int], n: int = 16) -> np.ndarray:
    return img[n:n + shape[0], n:n + shape[1]]


def _fill(img: np.ndarray) -> np.ndarray:
    """NaN (outside a corrected product's coverage) filled with the image's mean."""
    return np.where(np.isfinite(img), img, np.nanmean(img))


def _target_rois(static: np.ndarray) -> dict[str, tuple[slice, slice]]:
    """Regions of interest on the target: the square's upper edge (nearly along the rows'
    direction: the MTF along the columns... across the lines), its left edge, its flat inside;
    found on the static product."""
    h, w = static.shape
    band_r = slice(h // 2 - max(h // 6, 24), h // 2 + max(h // 6, 24))
    band_c = slice(w // 2 - max(w // 6, 24), w // 2 + max(w // 6, 24))
    rows = static[:, band_c].mean(axis=1)
    cols = static[band_r, :].mean(axis=0)
    r_edge = int(np.argmax(np.abs(np.diff(rows[: h // 2])))) + 1
    c_edge = int(np.argmax(np.abs(np.diff(cols[: w // 2])))) + 1
    e = EDGE_HALF_PX
    inner = slice(max(r_edge + e, h // 2 - h // 8), h // 2 + h // 8)
    return {"along": (slice(max(r_edge - e, 0), r_edge + e), band_c),
            "across": (band_r, slice(max(c_edge - e, 0), c_edge + e)),
            "flat": (inner, slice(max(c_edge + e, w // 2 - w // 8), w // 2 + w // 8))}


def _restoration_gain(quality: dict) -> dict:
    """What the deconvolution gained on each corrected product: MTF at Nyquist (along,
    across) before and after, noise gain, overshoot."""
    out = {}
    for name in ("open", "closed"):
        a, b = quality.get(f"{name}_gc"), quality.get(f"{name}_gc_restored")
        if a is None or b is None:
            continue
        out[name] = {"mtf_nyquist_before": a["mtf_nyquist"], "mtf_nyquist_after":
                     b["mtf_nyquist"], "noise_gain": (b["noise_sigma"] / a["noise_sigma"]
                                                      if a["noise_sigma"] else None),
                     "overshoot_h": b["overshoot_h"]}
    return out


def _write_files(m: Models, plan: ProductPlan, folder: Path, products: dict, shifts: dict,
                 truth_off: dict, est_off: dict, perf_off: dict) -> list[Path]:
    """GeoTIFFs of the scene products (a corrected one on the nominal grid displaced by its
    constant offset ``shifts``, (row, col) px), the per-line offsets (CSV), all arrays
    (product.npz); the quicklook is drawn by imc.outputs."""
    from affine import Affine

    from imc.io import write_csv

    files = []
    transform, crs = _georeference(m, plan)
    for (scene, name), img in products.items():
        if scene != "scene":
            continue
        sh = shifts.get(name.split("_gc")[0], np.zeros(2)) if "_gc" in name else np.zeros(2)
        path = folder / f"{name}.tif"
        _write_tif(path, img.astype(np.float32),
                   transform @ Affine.translation(float(sh[1]), float(sh[0])), crs)
        files.append(path)
    header = ["line", "t_s"] + [f"{k}_{n}_{a}" for k in ("true", "record", "perfect")
                                for n in est_off for a in ("row", "col")]
    cols = [np.arange(plan.n_lines), plan.line_t_s]
    for src in (truth_off, est_off, perf_off):
        for n in est_off:
            cols += [src[n][:, 0], src[n][:, 1]]
    write_csv(folder / "lines.csv", header, np.column_stack(cols).tolist())
    files.append(folder / "lines.csv")
    write_npz(folder / "product.npz", **{f"{s}/{n}": v.astype(np.float32)
                                         for (s, n), v in products.items()},
              **{f"offset/true/{n}": v for n, v in truth_off.items()},
              **{f"offset/record/{n}": v for n, v in est_off.items()},
              **{f"offset/perfect/{n}": v for n, v in perf_off.items()},
              line_t_s=plan.line_t_s)
    files.append(folder / "product.npz")
    return files


def _georeference(m: Models, plan: ProductPlan):
    """An affine (rasterio) from the nominal grid's (col, row) to a transverse Mercator
    centred on the scene centre (the scene's ENU plane within a millimetre over the tile),
    fitted to the nominal lines of sight at the grid's corners and centre, and its CRS."""
    from affine import Affine

    from camera.linescan import ground_points, imager_camera

    cam = imager_camera(m.camera, m.imager)
    fp = cam.focal_plane
    li = np.array([0, plan.n_lines // 2, plan.n_lines - 1])
    ci = np.array([0, len(plan.cols) // 2, len(plan.cols) - 1])
    ll, cc = (a.ravel() for a in np.meshgrid(li, ci, indexing="ij"))
    t = plan.line_t_s[ll] + 0.5 * plan.integration_s
    det_r = (np.full(len(ll), fp.center_px[0]) if plan.rows is None
             else plan.rows[ll].astype(np.float64))
    pix = np.column_stack([det_r, plan.cols[cc].astype(np.float64)])
    g = ground_points(cam.pose(t, nominal=True), fp, pix, m.terrain.height_at)
    a = np.column_stack([cc, ll, np.ones(len(ll))])
    ce, *_ = np.linalg.lstsq(a, g[:, 0], rcond=None)
    cn, *_ = np.linalg.lstsq(a, g[:, 1], rcond=None)
    # pixel centres at integer (col, row): the corner of pixel (0, 0) is half a pixel before
    transform = Affine(ce[0], ce[1], ce[2] - 0.5 * (ce[0] + ce[1]),
                       cn[0], cn[1], cn[2] - 0.5 * (cn[0] + cn[1]))
    lat, lon = m.scenario.scene.center_lat_deg, m.scenario.scene.center_lon_deg
    crs = f"+proj=tmerc +lat_0={lat} +lon_0={lon} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m"
    return transform, crs


def _write_tif(path: Path, img: np.ndarray, transform, crs: str) -> None:
    from scene.geotiff import write_geotiff

    atomic_write(path, lambda tmp: write_geotiff(tmp, img, 0.0, 0.0, 1.0, 1.0, crs=crs,
                                                 nodata=float("nan"), transform=transform))

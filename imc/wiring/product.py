"""The main imager's rendered study: its image product and ground processing, for frame and
TDI imagers alike, as a short composition of pure steps with typed hand-offs.

1. :func:`plan_product`: what the product covers (lines, columns, times), asked of the imager.
2. :func:`render_versions`: each version rendered as the camera forms it (:mod:`scene.strip`,
   every sample's line of sight from the true orbit, attitude and jitter and the stage's
   trajectory, cast through :class:`scene.kernel.RayCaster`) from the same scene: **static**
   (the nominal pose, the stage at rest), **open** (the true pose, no stage), **closed** (the
   true pose and the loop's stage); on the scene and on the slanted-square target
   (:func:`scene.targets.slanted_square`). A killed run resumes from the chunks written.
3. :func:`expose_versions`: the optics, the detector, noise and quantisation
   (:func:`camera.exposure.expose`), one noise stream per scene, the same draws per version.
4. :func:`ground_versions`: on the ground (:mod:`ground`), from the loop's **record** (what it
   received, less the orbit / attitude prediction, never the truth) and the stage's own
   position record: each line's offset on the nominal grid, the product resampled onto it
   (``*_gc``) and a Wiener deconvolution with the record's residual PSF (``*_gc_restored``);
   the same from a **perfect record** (:func:`imc.wiring.truth.jitter_px` at the record's own
   sample times) shows the record's own share. The constant no record sees is set as ground
   control points set it (``ground_control_px``).
5. :func:`measure_quality`: slanted-edge MTF at Nyquist, RER and overshoot both ways, noise
   gain and SNR on the square's flat inside, NIIRS by GIQE 5 (pyBSM) on the target; PSNR and
   SSIM against the static product on the scene.
6. :func:`imc.wiring.level1.level1_study` (a TDI strip): the product as a Level-1 product,
   RPCs fitted to the geometry the ground knows for each version, every version
   orthorectified through GDAL's RPC transformer with the scene's DEM, and its geolocation
   in metres (CE90, relative accuracy, misregistration against the static) at check points
   whose true ground positions the camera model gives.

:func:`product_study` composes them into one labelled :class:`xarray.Dataset` (dims
``version``, ``moving``, ``source``, ``stage``, ``axis``, ``direction``, ``line``, ``col``);
:mod:`imc.outputs.product_files` writes metrics.json's ``product`` section, lines.csv,
product.npz and the GeoTIFFs from it. :func:`picture_study` is the frame imager's picture
(``metrics.blur_images``: main_imager.png) from the same steps: its edges measured without
detector noise against the truth's motion MTF.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import xarray as xr

from imc.io import write_npz
from imc.scenario import ScenarioError
from imc.wiring import streams
from imc.wiring.build import Models
from imc.wiring.truth import jitter_px

#: the rendered versions of the product (rendered from the same scene and noise stream)
RENDERED = ("static", "open", "closed")
#: the rendered scenes: the scene itself and the slanted-square target
SCENES = ("scene", "target")
#: half-width of an edge's region of interest across the edge, px
EDGE_HALF_PX = 32
#: the record's per-line motion model (:func:`ground.record.line_motion`)
RECORD_METHOD = "cubic"
#: residual samples per line (or exposure) for the restoration PSF
PSF_SUBSAMPLES = 32
#: edge_mtf's margin (px) cut on every side of the picture's edge region
EDGE_MARGIN_PX = 8


@dataclass(frozen=True)
class ProductPlan:
    """What the product covers: the ``imager`` (it answers kind, line rate, sign);
    ``line_t_s`` (L,) the start of each line's integration (a frame: L rows, all ``t0_s``),
    ``integration_s``; the detector ``cols`` (C,) and, for a frame, ``rows`` (L,)."""

    imager: object
    t0_s: float
    line_t_s: np.ndarray
    integration_s: float
    cols: np.ndarray
    rows: np.ndarray | None

    @property
    def kind(self) -> str:
        return self.imager.kind

    @property
    def line_rate_hz(self) -> float | None:
        return self.imager.line_rate_hz

    @property
    def n_lines(self) -> int:
        return len(self.line_t_s)

    @property
    def sign(self) -> np.ndarray:
        """(row, col) factors from the residual image motion r = jitter - stage to the
        line-of-sight offset on the nominal grid (``strip[l] ~ static[l + off]``), the
        imager's (docs/conventions.md; pinned by tests/test_product.py)."""
        return np.asarray(self.imager.product_sign, dtype=np.float64)

    def window(self, lines: slice) -> ProductPlan:
        """The plan of a window of the product's lines (a frame: the whole exposure)."""
        if not self.imager.scanning:
            return self
        t = self.line_t_s[lines]
        return replace(self, t0_s=float(t[0]), line_t_s=t)


def target_window(plan: ProductPlan) -> slice:
    """The lines the quality target is rendered over: the strip's middle, as many lines as it
    has columns (at least 256; a frame: all), so the target's tile does not grow with a long
    strip."""
    n = min(plan.n_lines, max(len(plan.cols), 256))
    a = (plan.n_lines - n) // 2
    return slice(a, a + n)


def plan_product(m: Models, lines: int | None = None, cols: int | None = None,
                 start_s: float | None = None) -> ProductPlan:
    """The product's lines, columns and times for the scenario's ``product`` section (or the
    ``lines`` x ``cols`` window from ``start_s`` given here); a product that does not fit the
    run or the imager is a ScenarioError naming the field."""
    p, sc, imager = m.scenario.product, m.scenario, m.imager
    n_lines = p.lines if lines is None else lines
    n_cols = p.cols if cols is None else cols
    if n_cols > imager.cols:
        raise ScenarioError(f"product.cols: {n_cols} columns, the main imager has "
                            f"{imager.cols}; lower it")
    col_idx = np.arange(n_cols) + (imager.cols - n_cols) // 2
    start = start_s if start_s is not None else p.start_s
    integration = imager.integration_s()
    if imager.scanning:
        period = 1.0 / imager.line_rate_hz
        if start is None:
            start = max(sc.camera.main_imager.start_s,
                        _centre_time(m) - 0.5 * (n_lines + imager.stages) * period)
        line_t = start + np.arange(n_lines) * period
        rows, what = None, "lines"
    else:
        if n_lines > imager.rows:
            raise ScenarioError(f"product.lines: {n_lines} rows, the main imager has "
                                f"{imager.rows}; lower it")
        start = sc.camera.main_imager.start_s if start is None else start
        line_t = np.full(n_lines, float(start))
        rows, what = np.arange(n_lines) + (imager.rows - n_lines) // 2, "start_s"
    end = line_t[-1] + integration
    if end > sc.duration_s + 1e-9:
        raise ScenarioError(
            f"product.{what}: the product ends at {end:.4g} s, after the run ({sc.duration_s:g}"
            f" s): lower product.lines, start it earlier (product.start_s) or raise "
            "duration_s")
    plan = ProductPlan(imager, float(start), line_t, float(integration), col_idx, rows)
    _check_coverage(m, plan)
    return plan


def _nominal_ground(m: Models, plan: ProductPlan, li: np.ndarray, ci: np.ndarray
                    ) -> np.ndarray:
    """Ground points (N, 3) the nominal lines of sight of product lines ``li`` and columns
    ``ci`` (index arrays, broadcast) see at mid-integration."""
    cam = m.main_camera
    fp = cam.focal_plane
    t = plan.line_t_s[li] + 0.5 * plan.integration_s
    rows = (np.full(len(li), fp.center_px[0]) if plan.rows is None
            else plan.rows[li].astype(np.float64))
    pix = np.column_stack([rows, plan.cols[ci].astype(np.float64)])
    return cam.ground_points_posed(cam.pose(t, nominal=True), pix, m.terrain.height_at)


def _corners(plan: ProductPlan, n: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """(line, col) index pairs of an n x n grid over the product (corners, n = 3: + middles)."""
    li = np.linspace(0, plan.n_lines - 1, n).round().astype(int)
    ci = np.linspace(0, len(plan.cols) - 1, n).round().astype(int)
    ll, cc = np.meshgrid(li, ci, indexing="ij")
    return ll.ravel(), cc.ravel()


def _check_coverage(m: Models, plan: ProductPlan) -> None:
    """The scene tile must hold the product's footprint (its nominal corners)."""
    g = _nominal_ground(m, plan, *_corners(plan))
    if not np.all(m.terrain.contains(g[:, 0], g[:, 1])):
        need = float(np.max(np.abs(g[:, :2])))
        raise ScenarioError(f"product.lines: the product's footprint reaches {need:.0f} m "
                            f"from the scene centre, beyond the {m.scenario.scene.size_m:g} m "
                            "tile; lower product.lines / product.cols or raise scene.size_m")


def _centre_time(m: Models) -> float:
    """When the imager centre's nominal line of sight passes closest to the scene centre,
    s (0 for a staring camera): the strip is centred there by default (the tile's middle)."""
    cam = m.main_camera
    t = np.linspace(0.0, m.scenario.duration_s, 201)
    g = cam.ground_points_posed(cam.pose(t, nominal=True),
                                np.broadcast_to(cam.focal_plane.center_px, (len(t), 2)),
                                m.terrain.height_at)
    return float(t[np.argmin(np.hypot(g[:, 0], g[:, 1]))])


def gsd_m(m: Models) -> float:
    """Ground sample distance at t = 0, m (the slant range times the IFOV)."""
    cam = m.main_camera
    pose = cam.pose(np.array([0.0]))
    g = cam.ground_points(cam.focal_plane.center_px[None], 0.0, m.terrain.height_at)
    return float(np.linalg.norm(pose.position_m[0] - g[0]) * cam.focal_plane.ifov_rad)


def target_terrain(m: Models, plan: ProductPlan, gsd: float):
    """The slanted-square target under the product (:func:`scene.targets.slanted_square`):
    half the product's smaller side, centred where its middle line of sight meets the
    ground, its sides 5 degrees off the imager's axes."""
    from scene.targets import slanted_square

    mid = np.array([plan.n_lines // 2] * 2)
    ci = np.array([len(plan.cols) // 2, min(len(plan.cols) - 1, len(plan.cols) // 2 + 50)])
    g = _nominal_ground(m, plan, mid, ci)
    extent_px = max(plan.n_lines, len(plan.cols))
    size = 2.0 * (np.hypot(*g[0, :2]) + 0.75 * extent_px * gsd)
    return slanted_square(g[0, :2], (g[1] - g[0])[:2],
                          0.25 * min(plan.n_lines, len(plan.cols)) * gsd, size, gsd / 5.0)


# ------------------------------------------------------------------------------ the steps


@dataclass(frozen=True)
class Versions:
    """The versions rendered: each name's stage trajectory (None: at rest) and pose
    (``nominal``)."""

    stage: dict
    nominal: dict

    @classmethod
    def of_run(cls, stage) -> Versions:
        names = RENDERED if stage is not None else RENDERED[:2]
        st = {"static": None, "open": None, "closed": stage}
        return cls({n: st[n] for n in names}, {n: n == "static" for n in names})

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.stage)


@dataclass(frozen=True)
class Rendered:
    """Radiance (L, C) per (scene, version), the true line offsets (L, 2) per version on the
    scene, the plans per scene, ray counts and timings, s."""

    plans: dict
    radiance: dict
    truth_offset_px: dict
    rays: int
    hits: int
    build_s: float
    render_s: float


@dataclass(frozen=True)
class Exposed:
    """The detector's images (float64 DN) per (scene, version)."""

    images: dict


@dataclass(frozen=True)
class Ground:
    """The ground's results: offsets (L, 2) per source ('true', 'record', 'perfect') and
    moving version; geometry figures; every product image per (scene, name) (corrected ones
    on the nominal grid displaced by ``shift_px``); the scene's corrected images on the
    nominal grid itself and their valid masks."""

    offsets: dict
    geometry: dict
    products: dict
    on_grid: dict
    valid: dict
    shift_px: dict
    record_error: dict
    seconds: float


def _render_one(m: Models, caster, plan: ProductPlan, stage, nominal: bool, samples: int,
                store: Path):
    """(radiance (L, C), line_offset_px (L, 2), rays, first hits) of one version. A strip's
    chunks are written to ``store`` as they are done (atomically) and a run that was killed
    resumes after the last one written; a frame is one chunk."""
    from scene.strip import iter_strip, render_frame

    store.mkdir(parents=True, exist_ok=True)
    if not plan.imager.scanning:
        path = store / "frame.npz"
        if not path.exists():
            r = render_frame(caster, m.main_camera, plan.imager, plan.t0_s, plan.rows,
                             plan.cols, samples, stage_offset_px=stage, nominal=nominal)
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
        for ch in iter_strip(caster, m.main_camera, plan.imager, plan.t0_s, plan.n_lines,
                             plan.cols, samples, stage_offset_px=stage, nominal=nominal,
                             first_line=first):
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


def render_versions(m: Models, plan: ProductPlan, versions: Versions, samples: int,
                    store: Path) -> Rendered:
    """Step 2: every version of the scene and of the target (over :func:`target_window`)."""
    from scene.kernel import RayCaster, Renderer, Sun

    t0 = time.perf_counter()
    sun = Sun(*m.sun_deg)
    plans = {"scene": plan, "target": plan.window(target_window(plan))}
    casters = {"scene": RayCaster(Renderer(m.terrain, sun, 16, 16, spp=1, clouds=m.clouds)),
               "target": RayCaster(Renderer(target_terrain(m, plans["target"], gsd_m(m)),
                                            sun, 16, 16, spp=1), sky_view_dirs=0)}
    t1 = time.perf_counter()
    radiance, truth, rays, hits = {}, {}, 0, 0
    for scene, caster in casters.items():
        for name in versions.names:
            rad, off, n, h = _render_one(m, caster, plans[scene], versions.stage[name],
                                         versions.nominal[name], samples,
                                         store / f"{scene}_{name}")
            radiance[scene, name] = rad
            rays, hits = rays + n, hits + h
            if scene == "scene":
                truth[name] = off
    return Rendered(plans, radiance, truth, rays, hits, t1 - t0, time.perf_counter() - t1)


def expose_versions(m: Models, plan: ProductPlan, rendered: Rendered) -> Exposed:
    """Step 3: the detector, one noise stream per scene, the same draws for every version;
    the optics' periodic filter sees a mirror-padded image, so the edges stay clean."""
    from camera.exposure import expose

    images = {}
    for i, scene in enumerate(SCENES):
        gain = m.sensor.gain_for(rendered.radiance[scene, "static"])
        for (s, name), rad in rendered.radiance.items():
            if s != scene:
                continue
            dn = expose(np.pad(rad, 16, mode="reflect"), m.optics, m.sensor,
                        streams.rng(m.scenario.seed, "product", i), plan.integration_s,
                        gain_e=gain)
            images[scene, name] = dn[16:16 + rad.shape[0], 16:16 + rad.shape[1]].astype(
                np.float64)
    return Exposed(images)


# ------------------------------------------------------------------------------ the record


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


def exposure_jitter(m: Models) -> np.ndarray:
    """The truth's jitter (:func:`imc.wiring.truth.jitter_px`) averaged over each tracker
    exposure, (T, 2) px: what a perfect tracker measures of frame k."""
    sub = (np.arange(8) + 0.5) / 8.0 * m.exposure_s
    t = (m.frame_t_s[:, None] + sub[None]).ravel()
    return jitter_px(m, t).reshape(len(m.frame_t_s), len(sub), 2).mean(axis=1)


def perfect_jitter(m: Models, record):
    """The record a perfect tracker would have delivered: :func:`exposure_jitter` at the
    record's sample times (its gaps kept)."""
    from ground.record import MotionRecord

    return MotionRecord(m.frame_mid_s, exposure_jitter(m), record.valid)


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


def record_error(record, perfect) -> dict:
    """The record's own error at the main imager: its jitter samples against the perfect
    record's (the camera model's exposure means) at the same times, about the mean (the
    constant is ground control's), px."""
    ok = record.valid & perfect.valid
    e = record.motion_px[ok] - perfect.motion_px[ok]
    e = e - e.mean(axis=0)
    return {"rms_px": [float(x) for x in np.sqrt(np.mean(e**2, axis=0))],
            "samples": int(ok.sum()),
            "rate_hz": float(ok.sum() / max(np.ptp(record.t_s[ok]), 1e-9))}


# ------------------------------------------------------------------------------ the ground


def _geometry(est: np.ndarray, perf: np.ndarray, true: np.ndarray, t_s: np.ndarray,
              absolute: bool) -> tuple[dict, dict]:
    """(the offsets from the record and the perfect record with ground control's constant
    set, the geometry figures) of one version: before and after correction about a constant
    (``before``, ``after``, ``after_perfect_record``), after an affine ground control (bias and
    linear trend in time per axis: ``affine``), and with control points fused in the record
    the absolute error, nothing removed (``control_points``)."""
    from ground.network import geometry_rms
    from ground.rectify import geometric_error

    est_c, perf_c = est - (est - true).mean(axis=0), perf - (perf - true).mean(axis=0)
    figures = {
        "before": geometric_error(np.zeros_like(true), true - true.mean(axis=0)).to_dict(),
        "after": geometric_error(est_c, true).to_dict(),
        "after_perfect_record": geometric_error(perf_c, true).to_dict(),
        "ground_control_px": [float(x) for x in (est - true).mean(axis=0)],
        "affine": {"rms_px": [float(x) for x in geometry_rms(est - true, t_s)["affine"]],
                   "perfect_record_rms_px": [float(x) for x in
                                             geometry_rms(perf - true, t_s)["affine"]]},
    }
    if absolute:
        figures["control_points"] = {"rms_px": geometric_error(est, true).to_dict()["rms_px"]}
    return {"record": est_c if not absolute else est, "perfect": perf_c}, figures


def correct_image(image: np.ndarray, offsets: np.ndarray, kernels: list, runs: np.ndarray,
                  method: str, nsr: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(corrected, corrected and restored (NaN outside the strip), valid) of one product:
    :func:`ground.rectify.rectify` by the lines' ``offsets`` (L, 2) px, then
    :func:`ground.restore.restore_strip` with the runs' PSF ``kernels``."""
    from ground.rectify import rectify
    from ground.restore import restore_strip

    gc = rectify(image, offsets, fill=np.nan)
    filled = np.where(gc.valid, gc.image, np.nanmean(gc.image))
    restored = restore_strip(filled, kernels, runs, method=method, nsr=nsr)
    return (np.where(gc.valid, gc.image, np.nan), np.where(gc.valid, restored, np.nan),
            gc.valid)


def _correct_version(m: Models, rendered: Rendered, images: dict, name: str, offsets,
                     record, stage, nsr: float) -> tuple[dict, dict, dict, np.ndarray]:
    """Resample one version's scene and target by its offsets (less their constant, which
    goes into the georeference: a sub-pixel resampling would cost MTF near Nyquist for
    nothing) and restore it: (products, on-grid scene images, valid masks, the constant)."""
    from ground.restore import run_psfs

    p = m.scenario.product
    shift = offsets.mean(axis=0)
    products, on_grid, valid = {}, {}, {}
    window = target_window(rendered.plans["scene"])
    for scene, sp in rendered.plans.items():
        off = offsets if scene == "scene" else offsets[window]
        runs = np.arange(0, sp.n_lines, max(1, min(p.run_lines, sp.n_lines)))
        t_r, r = residual_samples(sp, record, stage)
        kernels = [q.pixel for q in run_psfs(t_r, r, sp.line_t_s, sp.integration_s, runs)]
        gc = correct_image(images[scene, name], off - shift, kernels, runs, p.restore, nsr)
        products[scene, f"{name}_gc"], products[scene, f"{name}_gc_restored"] = gc[:2]
        if scene == "scene":  # on the nominal grid itself, to compare with the static
            grid = correct_image(images[scene, name], off, kernels, runs, p.restore, nsr)
            on_grid[f"{name}_gc"], on_grid[f"{name}_gc_restored"] = grid[:2]
            valid[f"{name}_gc"] = valid[f"{name}_gc_restored"] = grid[2]
    return products, on_grid, valid, shift


def line_geometry(plan: ProductPlan, versions: Versions, truth_px: dict, record, perfect,
                  true_stage, restitution=None) -> tuple[dict, dict, dict]:
    """The lines' offsets and the geometry of every moving version, from the record (and the
    perfect record) against the truth's offsets ``truth_px`` {version: (L, 2)}: (offsets
    {source: {version: (L, 2)}}, geometry {version: figures}, the record's error). With a
    stage and a restitution, the correction is the band-wise blend (stage + ground never
    worse than the stage alone)."""
    from ground.record import line_motion

    t_mid = plan.line_t_s + 0.5 * plan.integration_s
    absolute = restitution is not None and restitution.absolute
    offsets: dict = {"true": {}, "record": {}, "perfect": {}}
    geometry = {}
    for name in versions.names[1:]:
        stage = versions.stage[name]
        true = truth_px[name]
        blend = None
        est = line_offsets(plan, record, stage)
        if stage is not None and restitution is not None:
            # what the blend leaves out of the record's estimate of the stage's residual is
            # not applied; the stage itself enters exactly at each line's instants
            left_out, blend = restitution.stage_correction(stage)
            est = est - line_motion(left_out, plan.line_t_s, plan.integration_s,
                                    RECORD_METHOD) * plan.sign
        perf = line_offsets(plan, perfect, true_stage if stage is not None else None)
        fixed, geometry[name] = _geometry(est, perf, true, t_mid, absolute)
        if blend is not None:
            geometry[name]["blend"] = blend
        offsets["true"][name] = true
        offsets["record"][name], offsets["perfect"][name] = fixed["record"], fixed["perfect"]
    err = record_error(record, perfect)
    if restitution is not None:
        err["predicted"] = restitution.predicted_geometry(t_mid)
        offsets["predicted"] = restitution.predicted_px(t_mid)
    return offsets, geometry, err


def ground_versions(m: Models, rendered: Rendered, exposed: Exposed, versions: Versions,
                    record, perfect, true_stage, restitution=None) -> Ground:
    """Step 4: the lines' offsets and geometry (:func:`line_geometry`), the corrected and
    restored products; ``restitution`` (:class:`imc.wiring.restitution.Restitution`, the
    record's source) adds the record's predicted error."""
    t0 = time.perf_counter()
    plan = rendered.plans["scene"]
    nsr = 1.0 / max(m.sensor.snr(exposure_s=plan.integration_s), 1.0)
    offsets, geometry, err = line_geometry(plan, versions, rendered.truth_offset_px, record,
                                           perfect, true_stage, restitution)
    products, on_grid, valid, shifts = dict(exposed.images), {}, {}, {}
    for name in versions.names[1:]:
        prod, grid, ok, shifts[name] = _correct_version(m, rendered, exposed.images, name,
                                                        offsets["record"][name], record,
                                                        versions.stage[name], nsr)
        products.update(prod)
        on_grid.update(grid)
        valid.update(ok)
    return Ground(offsets, geometry, products, on_grid, valid, shifts, err,
                  time.perf_counter() - t0)


def truth_offsets(m: Models, plan: ProductPlan, versions: Versions, samples: int) -> dict:
    """Each moving version's true line offsets (L, 2) px from the camera model alone (no
    rendering): what :func:`render_versions` records beside its radiance, for the
    geometry-only product (``product.render: false``)."""
    from camera.linescan import frame_offset_px, line_offset_px
    from scene.strip import probe_columns

    cam, imager = m.main_camera, plan.imager
    smp = imager.sampling(samples)
    probes = probe_columns(plan.cols)
    out = {}
    for name in versions.names[1:]:
        st = versions.stage[name]
        if imager.scanning:
            off = line_offset_px(cam, imager, smp, plan.t0_s, np.arange(plan.n_lines), probes,
                                 m.terrain.height_at, st).mean(axis=1)
        else:
            rc = np.column_stack([np.full(len(probes), plan.rows.mean()), probes])
            off = np.broadcast_to(frame_offset_px(cam, imager, smp, plan.t0_s, rc,
                                                  m.terrain.height_at, st).mean(axis=0),
                                  (plan.n_lines, 2)).copy()
        out[name] = off
    return out


# ------------------------------------------------------------------------------ quality


def target_rois(static: np.ndarray) -> dict[str, tuple[slice, slice]]:
    """Regions of interest on the target: the square's upper edge (nearly along the rows'
    direction: the MTF along the rows, across the lines), its left edge, its flat inside;
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


def _fill(img: np.ndarray) -> np.ndarray:
    """NaN (outside a corrected product's coverage) filled with the image's mean."""
    return np.where(np.isfinite(img), img, np.nanmean(img))


def measure_quality(m: Models, ground: Ground) -> dict:
    """Step 5: each product's quality (:func:`ground.quality.image_quality`): the edges and
    the flat on the target, PSNR and SSIM against the static on the scene; and NIIRS loss
    against the static product, NIIRS."""
    from ground.quality import image_quality

    products = ground.products
    static_t = products["target", "static"]
    rois = target_rois(static_t)
    sigma_in = float(np.std(static_t[rois["flat"]], ddof=1))
    elevation = np.deg2rad(90.0 - float(m.main_camera.attitude.off_nadir_deg(
        m.main_camera.orbit, 0.0)))
    gsd = gsd_m(m)
    quality = {}
    for name in [n for (s, n) in products if s == "scene"]:
        q_target = image_quality(_fill(products["target", name]), edge_roi_along=rois["along"],
                                 edge_roi_across=rois["across"], flat_roi=rois["flat"],
                                 noise_sigma_in=sigma_in, gsd_m=gsd, elevation_rad=elevation)
        q_scene = image_quality(_fill(ground.on_grid.get(name, products["scene", name])),
                                products["scene", "static"], valid=ground.valid.get(name))
        quality[name] = q_target.to_dict() | {"psnr_db": q_scene.psnr_db,
                                              "ssim": q_scene.ssim}
    static_niirs = quality["static"]["niirs"]
    for d in quality.values():
        d["niirs_loss"] = (static_niirs - d["niirs"]
                           if d["niirs"] is not None and static_niirs is not None else None)
    return quality


# ------------------------------------------------------------------------------ the result

#: the geometry figures per moving version and stage of correction
GEOMETRY_STAGES = ("before", "after", "after_perfect_record")
GEOMETRY_FIGURES = ("rms_px", "peak_to_peak_px", "bias_px", "max_abs_px")
#: the quality figures with an along / across pair, and the scalar ones
QUALITY_PAIRS = ("mtf_nyquist", "rer", "overshoot_h")
QUALITY_SCALARS = ("noise_sigma", "noise_gain", "snr", "niirs", "gsd_m", "elevation_rad",
                   "psnr_db", "ssim", "niirs_loss")


def _nan(v) -> float:
    return np.nan if v is None else float(v)


def product_dataset(rendered: Rendered, ground: Ground, quality: dict, samples: int
                    ) -> xr.Dataset:
    """The product's results as one labelled Dataset: images (``version``, ``line``,
    ``col``; the target's on ``target_line``, ``target_col``), the lines' offsets
    (``source``, ``moving``, ``line``, ``axis``), the geometry (``moving``, ``stage``,
    ``axis``), the quality (``version`` [, ``direction``]); None figures are NaN; the
    run-level facts in ``attrs``."""
    plan = rendered.plans["scene"]
    names = [n for (s, n) in ground.products if s == "scene"]
    moving = list(ground.geometry)
    axis = ["row", "col"]
    data = {}
    if names:  # a geometry-only product has no images
        data["image"] = (("version", "line", "col"), np.stack(
            [ground.products["scene", n] for n in names]).astype(np.float32))
        data["target_image"] = (("version", "target_line", "target_col"), np.stack(
            [ground.products["target", n] for n in names]).astype(np.float32))
    data |= {
        "offset_px": (("source", "moving", "line", "axis"), np.array(
            [[ground.offsets[s][n] for n in moving] for s in ("true", "record", "perfect")])
            .reshape(3, len(moving), plan.n_lines, 2)),
        "shift_px": (("moving", "axis"), np.array([ground.shift_px[n] for n in moving])
                     .reshape(len(moving), 2)),
        "ground_control_px": (("moving", "axis"), np.array(
            [ground.geometry[n]["ground_control_px"] for n in moving]).reshape(-1, 2)),
        "geometry_n": (("moving", "stage"), np.array(
            [[ground.geometry[n][st]["n"] for st in GEOMETRY_STAGES] for n in moving])
            .reshape(len(moving), 3)),
        "record_rms_px": (("axis",), np.array(ground.record_error["rms_px"])),
        "geometry_affine_rms_px": (("moving", "axis"), np.array(
            [ground.geometry[n]["affine"]["rms_px"] for n in moving]).reshape(-1, 2)),
        "geometry_affine_perfect_rms_px": (("moving", "axis"), np.array(
            [ground.geometry[n]["affine"]["perfect_record_rms_px"] for n in moving])
            .reshape(-1, 2)),
        "control_points_rms_px": (("moving", "axis"), np.array(
            [ground.geometry[n].get("control_points", {}).get("rms_px", [np.nan] * 2)
             for n in moving], dtype=np.float64).reshape(-1, 2)),
    }
    pred = ground.record_error.get("predicted")
    if pred is not None:
        data["predicted_constant_px"] = (("axis",), np.array(pred["constant_px"]))
        data["predicted_affine_px"] = (("axis",), np.array(pred["affine_px"]))
        data["predicted_line_px"] = (("line", "axis"), ground.offsets["predicted"])
    for fig in GEOMETRY_FIGURES:
        data[f"geometry_{fig}"] = (("moving", "stage", "axis"), np.array(
            [[ground.geometry[n][st][fig] for st in GEOMETRY_STAGES] for n in moving])
            .reshape(len(moving), 3, 2))
    for q in QUALITY_PAIRS if names else ():
        data[q] = (("version", "direction"), np.array(
            [[_nan(x) for x in quality[n][q]] for n in names]))
    for q in QUALITY_SCALARS if names else ():
        data[q] = (("version",), np.array([_nan(quality[n][q]) for n in names]))
    coords = {"version": names, "moving": moving, "source": ["true", "record", "perfect"],
              "stage": list(GEOMETRY_STAGES), "axis": axis,
              "direction": ["along", "across"], "line_t_s": ("line", plan.line_t_s)}
    blends = {n: ground.geometry[n]["blend"] for n in moving if "blend" in ground.geometry[n]}
    attrs = {"blend": blends, "kind": plan.kind, "lines": plan.n_lines,
             "cols": int(len(plan.cols)), "samples": samples, "start_s": plan.t0_s,
             "integration_s": plan.integration_s, "line_rate_hz": plan.line_rate_hz,
             "gsd_m": quality["static"]["gsd_m"] if quality else np.nan,
             "rays": int(rendered.rays), "hit_fraction": float(rendered.hits
                                                                / max(rendered.rays, 1)),
             "scene_build_s": rendered.build_s, "render_s": rendered.render_s,
             "ground_s": ground.seconds, "record_samples": ground.record_error["samples"],
             "record_rate_hz": ground.record_error["rate_hz"]}
    return xr.Dataset(data, coords=coords, attrs=attrs)


def georeference(m: Models, plan: ProductPlan) -> tuple[tuple[float, ...], str]:
    """The nominal grid's georeference: an affine (rasterio's 6 coefficients) from (col, row)
    to a transverse Mercator centred on the scene centre (the scene's ENU plane within a
    millimetre over the tile), fitted to the nominal lines of sight at the grid's corners,
    middles and centre, and its CRS."""
    ll, cc = _corners(plan, 3)
    g = _nominal_ground(m, plan, ll, cc)
    a = np.column_stack([cc, ll, np.ones(len(ll))])
    ce, *_ = np.linalg.lstsq(a, g[:, 0], rcond=None)
    cn, *_ = np.linalg.lstsq(a, g[:, 1], rcond=None)
    # pixel centres at integer (col, row): the corner of pixel (0, 0) is half a pixel before
    transform = (float(ce[0]), float(ce[1]), float(ce[2] - 0.5 * (ce[0] + ce[1])),
                 float(cn[0]), float(cn[1]), float(cn[2] - 0.5 * (cn[0] + cn[1])))
    from imc.wiring.level1 import MapFrame

    return transform, MapFrame.of(m).crs


def _chunk_store(out: Path, digest: str, fresh: bool) -> Path:
    """The run's chunk folder (product/chunks/<digest>), other scenarios' chunks removed."""
    chunks = Path(out) / "product" / "chunks" / digest[:16]
    for old in (Path(out) / "product" / "chunks").glob("*"):
        if (old != chunks or fresh) and old.is_dir():
            shutil.rmtree(old)
    return chunks


def geometry_study(m: Models, res, plan: ProductPlan, samples: int, restitution=None
                   ) -> xr.Dataset:
    """The geometry-only product (``product.render: false``): the lines' offsets and the
    geometry from the record against the camera model's truth, no image rendered (for
    trade studies over long strips)."""
    t0 = time.perf_counter()
    stage = res.trajectory if m.scenario.compensation.enabled else None
    versions = Versions.of_run(stage)
    truth = truth_offsets(m, plan, versions, samples)
    record = restitution.record if restitution is not None else record_jitter(m, res)
    offsets, geometry, err = line_geometry(plan, versions, truth, record,
                                           perfect_jitter(m, record), stage, restitution)
    ground = Ground(offsets, geometry, {}, {}, {}, {n: np.zeros(2) for n in geometry}, err,
                    time.perf_counter() - t0)
    rendered = Rendered({"scene": plan}, {}, truth, 0, 0, 0.0, 0.0)
    ds = product_dataset(rendered, ground, {}, samples)
    ds.attrs["transform"], ds.attrs["crs"] = georeference(m, plan)
    return ds


def run_study(m: Models, res, plan: ProductPlan, samples: int, store: Path,
              restitution=None) -> tuple[xr.Dataset, Rendered]:
    """Steps 2-5 on one plan: (the labelled result, the renders); the record is
    ``restitution``'s (:mod:`imc.wiring.restitution`) when given, else the loop's own."""
    stage = res.trajectory if m.scenario.compensation.enabled else None
    versions = Versions.of_run(stage)
    rendered = render_versions(m, plan, versions, samples, store)
    exposed = expose_versions(m, plan, rendered)
    gc = m.scenario.product.ground_control
    if restitution is not None and gc is not None and gc.kind == "orthoimage":
        from imc.wiring.orthocontrol import orthoimage_control

        restitution = orthoimage_control(m, plan, rendered, exposed, restitution)
    record = restitution.record if restitution is not None else record_jitter(m, res)
    ground = ground_versions(m, rendered, exposed, versions, record,
                             perfect_jitter(m, record), stage, restitution)
    t0 = time.perf_counter()
    quality = measure_quality(m, ground)
    ds = product_dataset(rendered, ground, quality, samples)
    if restitution is not None and restitution.control:
        ds.attrs["ground_control"] = restitution.control
    ds.attrs["quality_s"] = time.perf_counter() - t0
    ds.attrs["transform"], ds.attrs["crs"] = georeference(m, plan)
    if plan.imager.scanning:  # step 6: the Level-1 product (RPCs, ortho, geolocation)
        from imc.wiring.level1 import add_level1, level1_study

        ds = add_level1(ds, level1_study(m, plan, versions, ground, samples, gsd_m(m)))
    return ds, rendered


def product_study(m: Models, res, out: Path, fresh: bool = False, restitution=None,
                  plan: ProductPlan | None = None) -> tuple[xr.Dataset, Rendered]:
    """Render, process and judge the run's main-imager product (the scenario's ``product``
    section); a killed run resumes from the chunks written (``fresh``: renders anew).
    Returns the labelled result (:func:`product_dataset`) and the renders;
    :func:`imc.outputs.product_files.write_product` writes them."""
    plan = plan_product(m) if plan is None else plan
    if not m.scenario.product.render:
        return geometry_study(m, res, plan, m.scenario.product.samples, restitution), None
    return run_study(m, res, plan, m.scenario.product.samples,
                     _chunk_store(out, m.scenario.digest(), fresh), restitution)


# ------------------------------------------------------------------------------ the picture

#: the picture's versions as main_imager.png names them
PICTURE_NAMES = {"static": "static", "open": "open loop", "closed": "closed loop"}


def _noiseless(m: Models, radiance: np.ndarray) -> np.ndarray:
    """A render through the optics' MTF alone (mirror-padded), no detector noise."""
    return m.optics.apply(np.pad(radiance, 16, mode="reflect"))[16:-16, 16:-16]


def picture_study(m: Models, res, truth, blurs: tuple[dict, dict], figures: dict,
                  rendered: Rendered | None, out: Path, spp: int, size_px: int = 192
                  ) -> tuple[dict, dict]:
    """The frame imager's picture (``metrics.blur_images``) from the product's own steps:
    the product's renders when the run made one (``rendered``), else a ``size_px`` square
    frame product over the worst open-loop exposure (``figures`` from
    :func:`imc.wiring.blur.write_blur_npz`) at ``spp`` samples a pixel. The target's edge is
    measured through the optics without detector noise (ISO 12233) against the static edge
    times the truth's motion MTF over the exposure. Returns (metrics.json's
    ``main_imager_blur``, the arrays of :func:`imc.outputs.figures.fig_main_imager`)."""
    from compensation.metrics import NYQUIST, motion_mtf
    from ground.quality import edge_mtf, value_at

    if rendered is None:
        plan = plan_product(m, size_px, size_px, figures["worst_window_start_s"])
        with tempfile.TemporaryDirectory(dir=out) as tmp:
            stage = res.trajectory if m.scenario.compensation.enabled else None
            rendered = render_versions(m, plan, Versions.of_run(stage), spp, Path(tmp))
    plan = rendered.plans["scene"]
    t0, t1 = plan.t0_s, plan.t0_s + plan.integration_s
    starts = np.array([truth.t_s[truth.window == w][0] for w in np.unique(truth.window)])
    w = int(np.argmin(np.abs(starts - 0.5 * (truth.t_s[1] - truth.t_s[0]) - t0)))
    sel = truth.window == w
    edges = {k: _noiseless(m, rendered.radiance["target", k]) for k in PICTURE_NAMES
             if ("target", k) in rendered.radiance}
    roi = target_rois(edges["static"])["along"]
    curves = {PICTURE_NAMES[k]: edge_mtf(v[roi], margin=EDGE_MARGIN_PX) for k, v in
              edges.items()}
    f_static, mtf_static = curves["static"]
    result = {"window_start_s": t0, "window_s": t1 - t0, "spp": int(
        m.scenario.product.samples if m.scenario.product.enabled else spp)}
    motions = {}
    for key, traj in (("open", None), ("closed", res.trajectory)):
        motion = motions[key] = motion_mtf(truth.residual_px(traj)[sel], f_static[:, None])
        if PICTURE_NAMES[key] in curves:
            f, mtf = curves[PICTURE_NAMES[key]]
            result[f"edge_mtf_nyquist_{key}"] = value_at(f, mtf, NYQUIST)
        result[f"predicted_mtf_nyquist_{key}"] = value_at(f_static, mtf_static * motion,
                                                          NYQUIST)
        result[f"motion_mtf_nyquist_{key}"] = value_at(f_static, motion, NYQUIST)
    result["edge_mtf_nyquist_static"] = value_at(f_static, mtf_static, NYQUIST)
    result["optics_mtf_nyquist"] = float(m.optics.mtf(NYQUIST))
    result.update(figures)
    picture = {"title": f"{m.scenario.name}: main imager, exposure {t0:.2f}-{t1:.2f} s",
               "patches": {PICTURE_NAMES[k]: _noiseless(m, rendered.radiance["scene", k])
                           for k in PICTURE_NAMES if ("scene", k) in rendered.radiance},
               "curves": curves,
               "psf": {key: (blur["psf"][w], float(blur["psf_bin_px"]))
                       for key, blur in zip(("open", "closed"), blurs, strict=True)},
               "predicted_open": (f_static, mtf_static * motions["open"]),
               "nyquist": NYQUIST}
    return result, picture

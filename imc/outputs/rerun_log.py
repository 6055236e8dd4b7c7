"""Rerun recording of a run, with a default blueprint (layout) sent in the same file.

Entity paths (timeline ``time``, seconds from the scenario's t = 0):

- ``tracker/frame`` (image, when the plant renders frames), ``tracker/frame/blocks`` (boxes,
  green valid / red invalid), ``tracker/frame/tracks`` (each block's measured track as a line
  strip around its centre, magnified by the factor in its label);
- ``motion/{row,col}/{true,estimate,stage,residual}``: the true image motion at the main
  imager's centre, the loop's estimate, the stage and what is left (px);
- ``tracker/error/block_<b>/{row,col}`` and ``.../crlb_{row,col}`` (``+-``): each block's
  measured minus true shift against its predicted error (px);
- ``main_imager/{open,closed}/psf``: the residual PSF of every main-imager exposure;
  ``main_imager/rendered``: main_imager.png (static, open and closed render) when written;
- ``world/...`` (ENU metres around the scene centre): ``terrain`` (mesh coloured by albedo),
  ``orbit`` (the arc), ``satellite``, ``line_of_sight``, ``footprint/{tracker,main_imager}``.

The blueprint is :func:`blueprint`; :data:`ENTITY_PATHS` lists what every recording holds.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from imc.io import atomic_write
from imc.outputs.product_report import log_product

if TYPE_CHECKING:
    from compensation.loop import LoopResult
    from imc.wiring.build import Models
    from imc.wiring.truth import Truth

APP_ID = "imcsim"
AXES = ("row", "col")
SERIES = ("true", "estimate", "stage", "residual")
#: entity paths every recording holds (the frame image only with a rendered / texture plant)
ENTITY_PATHS = (
    "tracker/frame/blocks", "tracker/frame/tracks",
    *(f"motion/{a}/{s}" for a in AXES for s in SERIES),
    "tracker/error/block_0/row", "tracker/error/block_0/crlb_row",
    "main_imager/open/psf", "main_imager/closed/psf",
    "world/terrain", "world/orbit", "world/satellite", "world/line_of_sight",
    "world/footprint/tracker", "world/footprint/main_imager")
#: orbit arc drawn either side of the run, s
ARC_S = 60.0
#: most time steps of the 3-D view (satellite, line of sight, footprints)
MAX_POSES = 200
_COLORS = {"true": (220, 60, 50), "estimate": (120, 120, 120), "stage": (240, 160, 30),
           "residual": (40, 110, 220)}


def blueprint(n_blocks: int, has_render: bool, has_product: bool = False):
    """The default layout: tracker frame and main imager left, motion and tracker errors in
    the middle, the 3-D views right."""
    import rerun.blueprint as rrb

    left = [rrb.Spatial2DView(name="tracker frame: blocks and tracks", origin="tracker/frame")]
    imager = [rrb.Spatial2DView(name="main imager PSF, open loop", origin="main_imager/open"),
              rrb.Spatial2DView(name="main imager PSF, closed loop",
                                origin="main_imager/closed")]
    if has_render:
        imager.append(rrb.Spatial2DView(name="main imager rendered (static, open, closed)",
                                        origin="main_imager/rendered"))
    if has_product:
        imager.append(rrb.Spatial2DView(name="product (static, open, closed, corrected)",
                                        origin="product", contents=["+ product/*"]))
        imager.append(rrb.TimeSeriesView(name="product: each line's offset (px)",
                                         origin="product/offset"))
    left.append(rrb.Tabs(*imager))
    motion = [rrb.TimeSeriesView(name=f"{a} motion at the main imager (px)",
                                 origin=f"motion/{a}") for a in AXES]
    errors = rrb.Tabs(*(rrb.TimeSeriesView(name=f"block {b}: error vs CRLB (px)",
                                           origin=f"tracker/error/block_{b}")
                        for b in range(n_blocks)))
    world = rrb.Tabs(
        rrb.Spatial3DView(name="footprint on the terrain", origin="world",
                          contents=["+ world/terrain", "+ world/footprint/**"]),
        rrb.Spatial3DView(name="orbit arc, satellite, line of sight", origin="world"))
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(*left, row_shares=[3, 2]),
                       rrb.Vertical(*motion, errors), world, column_shares=[3, 4, 3]),
        rrb.TimePanel(state="expanded"), collapse_panels=False)


def _gray_u8(img: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(img, [0.5, 99.5])
    return np.clip((img - lo) / max(hi - lo, 1e-12) * 255.0, 0, 255).astype(np.uint8)


def _log_tracker(rec, rr, m: Models, res: LoopResult, truth: Truth,
                 frames: np.ndarray | None, ref_corners: np.ndarray | None) -> None:
    r = res.record
    b = float(m.scenario.correlator.block_px)
    corners = ref_corners if ref_corners is not None else np.repeat(
        np.asarray(m.corners, float)[None], len(m.frame_t_s), axis=0)
    n_b = corners.shape[1]
    for k, t in enumerate(m.frame_t_s):
        rec.set_time("time", duration=float(t))
        if frames is not None:
            rec.log("tracker/frame", rr.Image(_gray_u8(frames[k])))
        colors = np.where(r.valid[k][:, None], [[40, 220, 80]], [[230, 40, 40]])
        rec.log("tracker/frame/blocks",
                rr.Boxes2D(mins=corners[k][:, ::-1].astype(np.float32) - 0.5,
                           sizes=np.full((n_b, 2), b, np.float32),
                           labels=[f"block {i}" for i in range(n_b)],
                           colors=colors.astype(np.uint8)))
    shift = np.where(r.valid[..., None], r.shift_px, np.nan)
    mag = max(1.0, round(0.25 * b / max(float(np.nanmax(np.abs(shift))), 1e-6)))
    centres = corners[0] + 0.5 * b
    strips = [(centres[j] + mag * np.nan_to_num(shift[:, j]))[:, ::-1] for j in range(n_b)]
    rec.log("tracker/frame/tracks",
            rr.LineStrips2D(strips, labels=[f"block {j} track x{mag:g}" for j in range(n_b)],
                            radii=0.4), static=True)
    # per-block error against the CRLB
    tcol = rr.TimeColumn("time", duration=m.frame_t_s[1:])
    err = (r.shift_px - truth.meas_px)[1:]
    ok = r.valid[1:]
    for j in range(n_b):
        base = f"tracker/error/block_{j}"
        for i, a in enumerate(AXES):
            e = np.where(ok[:, j], err[:, j, i], np.nan)
            s = np.where(ok[:, j], r.sigma_px[1:, j, i], np.nan)
            rec.log(f"{base}/{a}", rr.SeriesLines(names=f"{a} error", widths=1.2),
                    static=True)
            rec.send_columns(f"{base}/{a}", indexes=[tcol],
                             columns=rr.Scalars.columns(scalars=e))
            rec.log(f"{base}/crlb_{a}", rr.SeriesLines(
                colors=[(150, 150, 150)] * 2, names=[f"+CRLB {a}", f"-CRLB {a}"]),
                static=True)
            rec.send_columns(f"{base}/crlb_{a}", indexes=[tcol],
                             columns=rr.Scalars.columns(scalars=np.stack([s, -s], axis=1)))


def _log_motion(rec, rr, m: Models, res: LoopResult, series: dict) -> None:
    from imc.outputs.figures import estimate_px

    t, mo, st = series["t_s"], series["motion_px"], series["stage_px"]
    fine = rr.TimeColumn("time", duration=t)
    frame_t = rr.TimeColumn("time", duration=m.frame_t_s)
    values = {"true": (fine, mo), "stage": (fine, st), "residual": (fine, mo - st),
              "estimate": (frame_t, estimate_px(m, res))}
    for i, a in enumerate(AXES):
        for name in SERIES:
            tcol, v = values[name]
            path = f"motion/{a}/{name}"
            rec.log(path, rr.SeriesLines(colors=_COLORS[name], names=name), static=True)
            rec.send_columns(path, indexes=[tcol], columns=rr.Scalars.columns(
                scalars=v[:, i]))


def _log_imager(rec, rr, out_dir: Path) -> bool:
    """The residual PSF of every exposure, open and closed, and main_imager.png; returns
    whether the rendered image was there."""
    blur = out_dir / "blur.npz"
    if blur.exists():
        with np.load(blur) as z:
            for key in ("open", "closed"):
                psf, t0 = z[f"{key}_psf"], z[f"{key}_window_start_s"]
                for k in range(len(psf)):
                    rec.set_time("time", duration=float(t0[k]))
                    img = psf[k] / max(float(psf[k].max()), 1e-12)
                    rec.log(f"main_imager/{key}/psf",
                            rr.Image((np.sqrt(img) * 255).astype(np.uint8)))
    png = out_dir / "main_imager.png"
    if png.exists():
        rec.log("main_imager/rendered", rr.EncodedImage(path=png), static=True)
        return True
    return False


def _terrain_mesh(rr, m: Models, n_max: int = 64):
    ter = m.terrain
    w, h = ter.size_m
    dem = ter.dem_m
    step = max(1, int(np.ceil(max(dem.shape) / n_max)))
    rows, cols = np.arange(0, dem.shape[0], step), np.arange(0, dem.shape[1], step)
    e = -0.5 * w + cols * ter.dem_spacing_m
    n = 0.5 * h - rows * ter.dem_spacing_m
    ee, nn = np.meshgrid(e, n)
    z = dem[np.ix_(rows, cols)]
    ai = np.clip(((0.5 * h - nn) / ter.texel_m).astype(int), 0, ter.albedo.shape[0] - 1)
    aj = np.clip(((ee + 0.5 * w) / ter.texel_m).astype(int), 0, ter.albedo.shape[1] - 1)
    alb = np.clip(ter.albedo[ai, aj] * 255, 0, 255).astype(np.uint8)
    verts = np.stack([ee, nn, z], axis=-1).reshape(-1, 3)
    nr, nc = ee.shape
    i = np.arange(nr - 1)[:, None] * nc + np.arange(nc - 1)[None, :]
    tris = np.concatenate([np.stack([i, i + nc, i + 1], -1).reshape(-1, 3),
                           np.stack([i + 1, i + nc, i + nc + 1], -1).reshape(-1, 3)])
    return rr.Mesh3D(vertex_positions=verts, triangle_indices=tris,
                     vertex_colors=np.repeat(alb.reshape(-1, 1), 3, axis=1))


def _footprint(cam, t: float, height_fn) -> np.ndarray:
    fp = cam.focal_plane
    c = np.array([[0, 0], [0, fp.cols], [fp.rows, fp.cols], [fp.rows, 0], [0, 0]], float)
    return cam.ground_points(c - 0.5, t, height_fn)


def _log_world(rec, rr, m: Models) -> None:
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # ENU
    rec.log("world/terrain", _terrain_mesh(rr, m), static=True)
    cam, hfn = m.camera, m.terrain.height_at
    end = float(m.frame_t_s[-1] + m.exposure_s)
    arc_t = np.linspace(-ARC_S, end + ARC_S, 241)
    rec.log("world/orbit", rr.LineStrips3D([cam.pose(arc_t).position_m],
                                           colors=[(200, 200, 255)],
                                           labels=[f"orbit, +-{ARC_S:g} s"]), static=True)
    times = np.linspace(0.0, end, min(MAX_POSES, len(m.frame_t_s) + 1))
    pos = cam.pose(times).position_m
    centre = cam.focal_plane.center_px[None]
    for k, t in enumerate(times):
        rec.set_time("time", duration=float(t))
        g = cam.ground_points(centre, float(t), hfn)[0]
        rec.log("world/satellite", rr.Points3D([pos[k]], radii=2000.0,
                                               colors=[(255, 220, 80)], labels=["satellite"]))
        rec.log("world/line_of_sight", rr.LineStrips3D([[pos[k], g]], colors=[(255, 120, 60)]))
        rec.log("world/footprint/tracker", rr.LineStrips3D(
            [_footprint(cam, float(t), hfn)], colors=[(60, 230, 120)], labels=["tracker"]))
        rec.log("world/footprint/main_imager", rr.LineStrips3D(
            [_footprint(m.main_camera, float(t), hfn)], colors=[(80, 160, 255)],
            labels=["main imager"]))


def write_recording(path: Path, m: Models, res: LoopResult, truth: Truth,
                    frames: np.ndarray | None, ref_corners: np.ndarray | None) -> None:
    """Write ``recording.rrd`` (atomically) with its default blueprint; open it with
    ``imc view OUT`` or ``rerun recording.rrd``. Reads series.npz, blur.npz and
    main_imager.png beside it when they are there."""
    import rerun as rr

    from imc.outputs.figures import uniform_motion

    path = Path(path)
    s_path = path.parent / "series.npz"
    if s_path.exists():
        with np.load(s_path) as z:
            series = {k: z[k] for k in ("t_s", "motion_px", "stage_px")}
    else:
        t, mo, st = uniform_motion(m, res.trajectory)
        series = {"t_s": t, "motion_px": mo, "stage_px": st}
    has_render = (path.parent / "main_imager.png").exists()
    has_product = (path.parent / "product" / "product.npz").exists()
    bp = blueprint(res.record.shift_px.shape[1], has_render, has_product)

    def write(tmp: Path) -> None:
        rec = rr.RecordingStream(APP_ID, recording_id=m.scenario.name)
        rec.save(str(tmp), default_blueprint=bp)
        _log_tracker(rec, rr, m, res, truth, frames, ref_corners)
        _log_motion(rec, rr, m, res, series)
        _log_imager(rec, rr, path.parent)
        log_product(rec, rr, path.parent)
        _log_world(rec, rr, m)
        rec.flush()
        rec.disconnect()

    atomic_write(path, write, suffix=".rrd")

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
        imager.append(rrb.Spatial2DView(name="product: orthoimages on one map grid",
                                        origin="product/ortho"))
        imager.append(rrb.Spatial2DView(name="product: each version less the static "
                                        "(scale in product/ortho_diff/scale)",
                                        origin="product/ortho_diff"))
        imager.append(rrb.Spatial2DView(name="product: the target's edge at full resolution",
                                        origin="product/edge_crop"))
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
    """An image as 8-bit grey, stretched between its 0.5 and 99.5 percentiles."""
    lo, hi = np.percentile(img, [0.5, 99.5])
    return np.clip((img - lo) / max(hi - lo, 1e-12) * 255.0, 0, 255).astype(np.uint8)


def _send_images(rec, rr, path: str, times: np.ndarray, imgs: np.ndarray) -> None:
    """8-bit grey images (N, H, W) at ``times`` as one column (their format logged once)."""
    n, h, w = imgs.shape
    rec.log(path, rr.Image.from_fields(format=rr.components.ImageFormat(
        width=w, height=h, color_model="L", channel_datatype="U8")), static=True)
    rec.send_columns(path, indexes=[rr.TimeColumn("time", duration=times)],
                     columns=rr.Image.columns(buffer=imgs.reshape(n, -1)))


def _tracker_data(m: Models, res: LoopResult, truth: Truth, frames: np.ndarray | None,
                  ref_corners: np.ndarray | None) -> dict:
    """What the tracker's entities show, as arrays."""
    r = res.record
    corners = ref_corners if ref_corners is not None else np.repeat(
        np.asarray(m.corners, float)[None], len(m.frame_t_s), axis=0)
    n_t = len(m.frame_t_s)
    return {"block_px": float(m.scenario.correlator.block_px), "frame_t_s": m.frame_t_s,
            "frames_u8": (np.stack([_gray_u8(f) for f in frames[:n_t]])
                          if frames is not None else None),
            "corners": corners, "valid": r.valid, "shift_px": r.shift_px,
            "error_px": r.shift_px - truth.meas_px, "sigma_px": r.sigma_px}


def _log_tracker(rec, rr, d: dict) -> None:
    b, frame_t = d["block_px"], d["frame_t_s"]
    corners, valid, sigma = d["corners"], d["valid"], d["sigma_px"]
    n_t, n_b = len(frame_t), corners.shape[1]
    if d["frames_u8"] is not None:
        _send_images(rec, rr, "tracker/frame", frame_t, d["frames_u8"])
    # the blocks: sizes and labels once, centres and colours (valid / invalid) per frame
    half = np.full((n_b, 2), b, np.float32) / 2.0
    rec.log("tracker/frame/blocks", rr.Boxes2D.from_fields(
        half_sizes=half, labels=[f"block {i}" for i in range(n_b)]), static=True)
    mins = corners[:n_t, :, ::-1].astype(np.float32) - 0.5
    colors = np.where(valid[:n_t, :, None], [[40, 220, 80]], [[230, 40, 40]])
    rec.send_columns("tracker/frame/blocks",
                     indexes=[rr.TimeColumn("time", duration=frame_t)],
                     columns=rr.Boxes2D.columns(
                         centers=(mins + half).reshape(-1, 2),
                         colors=colors.astype(np.uint8).reshape(-1, 3)).partition(
                             np.full(n_t, n_b)))
    shift = np.where(valid[..., None], d["shift_px"], np.nan)
    mag = max(1.0, round(0.25 * b / max(float(np.nanmax(np.abs(shift))), 1e-6)))
    centres = corners[0] + 0.5 * b
    strips = [(centres[j] + mag * np.nan_to_num(shift[:, j]))[:, ::-1] for j in range(n_b)]
    rec.log("tracker/frame/tracks",
            rr.LineStrips2D(strips, labels=[f"block {j} track x{mag:g}" for j in range(n_b)],
                            radii=0.4), static=True)
    # per-block error against the CRLB
    tcol = rr.TimeColumn("time", duration=frame_t[1:])
    err = d["error_px"][1:]
    ok = valid[1:]
    for j in range(n_b):
        base = f"tracker/error/block_{j}"
        for i, a in enumerate(AXES):
            e = np.where(ok[:, j], err[:, j, i], np.nan)
            s = np.where(ok[:, j], sigma[1:, j, i], np.nan)
            rec.log(f"{base}/{a}", rr.SeriesLines(names=f"{a} error", widths=1.2),
                    static=True)
            rec.send_columns(f"{base}/{a}", indexes=[tcol],
                             columns=rr.Scalars.columns(scalars=e))
            rec.log(f"{base}/crlb_{a}", rr.SeriesLines(
                colors=[(150, 150, 150)] * 2, names=[f"+CRLB {a}", f"-CRLB {a}"]),
                static=True)
            rec.send_columns(f"{base}/crlb_{a}", indexes=[tcol],
                             columns=rr.Scalars.columns(scalars=np.stack([s, -s], axis=1)))


def _log_motion(rec, rr, series: dict) -> None:
    t, mo, st = series["t_s"], series["motion_px"], series["stage_px"]
    fine = rr.TimeColumn("time", duration=t)
    frame_t = rr.TimeColumn("time", duration=series["frame_t_s"])
    values = {"true": (fine, mo), "stage": (fine, st), "residual": (fine, mo - st),
              "estimate": (frame_t, series["estimate_px"])}
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
                if not len(psf):
                    continue
                img = psf / np.maximum(psf.max(axis=(1, 2)), 1e-12)[:, None, None]
                _send_images(rec, rr, f"main_imager/{key}/psf", t0,
                             (np.sqrt(img) * 255).astype(np.uint8))
    png = out_dir / "main_imager.png"
    if png.exists():
        rec.log("main_imager/rendered", rr.EncodedImage(path=png), static=True)
        return True
    return False


def _terrain_mesh(m: Models, n_max: int = 64) -> dict:
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
    return {"vertex_positions": verts, "triangle_indices": tris,
            "vertex_colors": np.repeat(alb.reshape(-1, 1), 3, axis=1)}


def _ground_points(cam, pixel_rc: np.ndarray, t_s: np.ndarray, height_fn) -> np.ndarray:
    """ENU points (T, P, 3) seen at pixels (P, 2) at each of the times (T,)
    (:meth:`camera.motion.CameraModel.ground_points`, all times at once)."""
    return cam.ground_points(np.asarray(pixel_rc, dtype=np.float64),
                             np.asarray(t_s, dtype=np.float64), height_fn)


def _footprint(cam, t_s: np.ndarray, height_fn) -> np.ndarray:
    """The focal plane's outline on the ground (T, 5, 3) at each of the times (T,)."""
    fp = cam.focal_plane
    c = np.array([[0, 0], [0, fp.cols], [fp.rows, fp.cols], [fp.rows, 0], [0, 0]], float)
    return _ground_points(cam, c - 0.5, t_s, height_fn)


def _world_data(m: Models) -> dict:
    """What the 3-D view shows (ENU m), as arrays."""
    cam, hfn = m.camera, m.terrain.height_at
    end = float(m.frame_t_s[-1] + m.exposure_s)
    lo, hi = getattr(cam.orbit, "span_s", (-np.inf, np.inf))  # an ephemeris: its states
    arc_t = np.linspace(max(-ARC_S, lo), min(end + ARC_S, hi), 241)
    times = np.linspace(0.0, end, min(MAX_POSES, len(m.frame_t_s) + 1))
    label = (f"orbit, +-{ARC_S:g} s" if arc_t[0] == -ARC_S and arc_t[-1] == end + ARC_S
             else f"orbit, {arc_t[0]:g} .. {arc_t[-1]:g} s (the ephemeris' span)")
    return {"terrain": _terrain_mesh(m), "orbit_m": cam.pose(arc_t).position_m,
            "orbit_label": label,
            "times_s": times, "satellite_m": cam.pose(times).position_m,
            "ground_m": _ground_points(cam, cam.focal_plane.center_px[None], times, hfn)[:, 0],
            "footprint_tracker_m": _footprint(cam, times, hfn),
            "footprint_main_imager_m": _footprint(m.main_camera, times, hfn)}


def _log_world(rec, rr, d: dict) -> None:
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # ENU
    rec.log("world/terrain", rr.Mesh3D(**d["terrain"]), static=True)
    label = d.get("orbit_label", f"orbit, +-{ARC_S:g} s")
    rec.log("world/orbit", rr.LineStrips3D([d["orbit_m"]], colors=[(200, 200, 255)],
                                           labels=[label]), static=True)
    pos = d["satellite_m"]
    # each path's style once (static), its geometry per time step as one column
    tcol = rr.TimeColumn("time", duration=d["times_s"])
    rec.log("world/satellite", rr.Points3D.from_fields(
        radii=[2000.0], colors=[(255, 220, 80)], labels=["satellite"]), static=True)
    rec.send_columns("world/satellite", indexes=[tcol],
                     columns=rr.Points3D.columns(positions=pos))
    strips = {"world/line_of_sight": (np.stack([pos, d["ground_m"]], axis=1),
                                      (255, 120, 60), None),
              "world/footprint/tracker": (d["footprint_tracker_m"], (60, 230, 120),
                                          "tracker"),
              "world/footprint/main_imager": (d["footprint_main_imager_m"],
                                              (80, 160, 255), "main imager")}
    for path, (xyz, color, label) in strips.items():
        rec.log(path, rr.LineStrips3D.from_fields(
            colors=[color], labels=[label] if label else None), static=True)
        rec.send_columns(path, indexes=[tcol],
                         columns=rr.LineStrips3D.columns(strips=list(xyz)))


def recording_data(m: Models, res: LoopResult, truth: Truth, frames: np.ndarray | None,
                   ref_corners: np.ndarray | None, series: dict) -> dict:
    """Everything the recording shows beyond the files of the run folder, as arrays (numpy
    only, picklable: :func:`write_recording` may run on a helper process); ``series``:
    series.npz's arrays (:func:`imc.outputs.figures.write_series`)."""
    return {"name": m.scenario.name, "n_blocks": int(res.record.shift_px.shape[1]),
            "product": bool(m.scenario.product.enabled),  # not a product/ an older run left
            "tracker": _tracker_data(m, res, truth, frames, ref_corners),
            "series": {k: series[k] for k in ("t_s", "motion_px", "stage_px", "frame_t_s",
                                              "estimate_px")},
            "world": _world_data(m)}


def write_recording(path: Path, data: dict) -> Path:
    """Write ``recording.rrd`` (atomically) with its default blueprint from
    :func:`recording_data` and the blur.npz, main_imager.png and product files beside it;
    open it with ``imc view OUT`` or ``rerun recording.rrd``. Returns its path."""
    import rerun as rr

    path = Path(path)
    has_render = (path.parent / "main_imager.png").exists()
    has_product = (data.get("product", True)
                   and (path.parent / "product" / "product.npz").exists())
    bp = blueprint(data["n_blocks"], has_render, has_product)

    def write(tmp: Path) -> None:
        rec = rr.RecordingStream(APP_ID, recording_id=data["name"])
        rec.save(str(tmp), default_blueprint=bp)
        _log_tracker(rec, rr, data["tracker"])
        _log_motion(rec, rr, data["series"])
        _log_imager(rec, rr, path.parent)
        if has_product:
            log_product(rec, rr, path.parent)
        _log_world(rec, rr, data["world"])
        rec.flush()
        rec.disconnect()

    atomic_write(path, write, suffix=".rrd")
    return path


def warm_up() -> None:
    """Write a recording of two frames, one block, into a temporary folder: Rerun's first
    use (its file sink, the archetypes' converters, the blueprint) costs ~0.25 s, which a
    helper process spends while the loop runs (:mod:`imc.outputs.jobs`)."""
    import tempfile

    two = np.array([0.0, 0.01])
    zeros = np.zeros((2, 1, 2))
    data = {"name": "warm-up", "n_blocks": 1,
            "tracker": {"block_px": 8.0, "frame_t_s": two,
                        "frames_u8": np.zeros((2, 4, 4), np.uint8), "corners": zeros,
                        "valid": np.ones((2, 1), bool), "shift_px": zeros, "error_px": zeros,
                        "sigma_px": zeros + 0.1},
            "series": {"t_s": two, "motion_px": np.zeros((2, 2)), "stage_px": np.zeros((2, 2)),
                       "frame_t_s": two, "estimate_px": np.zeros((2, 2))},
            "world": {"terrain": {"vertex_positions": np.eye(3),
                                  "triangle_indices": np.array([[0, 1, 2]]),
                                  "vertex_colors": np.zeros((3, 3), np.uint8)},
                      "orbit_m": np.ones((2, 3)), "times_s": two, "satellite_m": np.ones((2, 3)),
                      "ground_m": np.zeros((2, 3)), "footprint_tracker_m": np.zeros((2, 5, 3)),
                      "footprint_main_imager_m": np.zeros((2, 5, 3))}}
    with tempfile.TemporaryDirectory(prefix="imc-warm-") as folder:
        write_recording(Path(folder) / "recording.rrd", data)

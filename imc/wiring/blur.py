"""The main imager's blur as an image: residual-motion PSF and MTF per exposure, and (for a
frame imager) rendered patches and a slanted edge, open and closed loop.

The PSF of a residual trajectory r(t) over one exposure is the time it spends at each
position (a 2-D histogram); its MTF is |mean_t exp(-2 pi i f . r(t))| (Wulich & Kopeika
1987). The slanted-edge MTF follows ISO 12233's method: the edge's position per line, a
straight-line fit, every pixel binned at a quarter pixel by its distance to the edge (the
edge spread function), its derivative (line spread), a Hamming window, the FFT, corrected for
the finite difference. The prediction is the static render's edge MTF (optics, pixel,
reconstruction filter) times the residual's motion MTF along the edge normal. The arrays
only: main_imager.png is drawn from them by :func:`imc.outputs.figures.fig_main_imager`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from compensation.loop import Trajectory
from compensation.metrics import NYQUIST, motion_mtf
from ground.quality import ESF_HALF_PX, edge_mtf, value_at
from imc.io import write_npz
from imc.wiring.build import Models
from imc.wiring.truth import Truth

#: PSF grid: bin size (px; coarser when the residual is large), half-width (px) at least,
#: and the most bins a side (a diverging loop's residual of tens of px stays a small image)
PSF_BIN_PX = 0.02
PSF_MIN_HALF_PX = 0.5
PSF_MAX_BINS = 201
#: frequencies of the 2-D MTF, cycles/px (0 .. 1, Nyquist at the middle)
MTF_FREQS = np.linspace(-1.0, 1.0, 41)
#: samples per pixel of the scene patches, which are only shown (main_imager.png), at most
PICTURE_SPP = 16
#: edge_mtf's margin (px) cut on every side of the edge's image
EDGE_MARGIN_PX = 8
#: the slanted edge's angle to the columns (deg) and the slack (px) each side of the rows
#: the edge spread function reads, for the motion during the exposure
EDGE_ANGLE_DEG = 5.0
EDGE_SLACK_PX = 8
#: rows of the edge tile's albedo computed at a time
EDGE_BAND_ROWS = 256


def psf_image(r_px: np.ndarray, half_px: float, bin_px: float = PSF_BIN_PX) -> np.ndarray:
    """Time-weighted histogram (G, G) of a residual trajectory r (N, 2) (row, col) px on a
    grid of ``bin_px`` centred on its mean, ``half_px`` each side; sums to 1."""
    n = int(np.ceil(half_px / bin_px))
    edges = (np.arange(-n, n + 1)) * bin_px
    r = np.asarray(r_px) - np.mean(r_px, axis=0)
    h, _, _ = np.histogram2d(r[:, 0], r[:, 1], bins=[edges, edges])
    return h / max(h.sum(), 1.0)


def mtf_image(r_px: np.ndarray, freqs: np.ndarray = MTF_FREQS) -> np.ndarray:
    """Motion MTF (F, F) of a trajectory r (N, 2) on a grid of (f_row, f_col), cycles/px."""
    r = np.asarray(r_px)
    ph_r = np.exp(-2j * np.pi * freqs[:, None] * r[None, :, 0])  # (F, N)
    ph_c = np.exp(-2j * np.pi * freqs[:, None] * r[None, :, 1])
    return np.abs(ph_r @ ph_c.T) / len(r)


def window_blur(truth: Truth, trajectory: Trajectory | None) -> dict[str, np.ndarray]:
    """PSF and MTF images of every main-imager exposure (integration window)."""
    r = truth.residual_px(trajectory)
    wins = np.unique(truth.window)
    groups = [r[truth.window == w] for w in wins]
    span = max(PSF_MIN_HALF_PX, 1.05 * max(float(np.max(np.abs(g - g.mean(axis=0))))
                                           for g in groups))
    bin_px = max(PSF_BIN_PX, 2.0 * span / (PSF_MAX_BINS - 2))
    psf = np.stack([psf_image(g, span, bin_px) for g in groups])
    mtf = np.stack([mtf_image(g) for g in groups])
    return {"psf": psf, "mtf": mtf, "psf_bin_px": np.array(bin_px),
            "mtf_freqs": MTF_FREQS, "window_start_s": np.array(
                [truth.t_s[truth.window == w][0] for w in wins]) - 0.5 * (
                truth.t_s[1] - truth.t_s[0])}


def write_blur_npz(path: Path, truth: Truth, trajectory: Trajectory,
                   blurs: tuple[dict, dict] | None = None) -> dict:
    """blur.npz: open- and closed-loop PSF and MTF images per exposure (``blurs``: the two
    :func:`window_blur` results when the caller has them); returns the worst exposure's
    figures."""
    open_, closed = blurs or (window_blur(truth, None), window_blur(truth, trajectory))
    nyq = np.argmin(np.abs(MTF_FREQS - NYQUIST))
    zero = np.argmin(np.abs(MTF_FREQS))
    worst = int(np.argmin(open_["mtf"][:, nyq, zero]))
    write_npz(path, **{f"open_{k}": v for k, v in open_.items()},
              **{f"closed_{k}": v for k, v in closed.items() if k not in ("mtf_freqs",)})
    return {"worst_window": worst,
            "worst_window_start_s": float(open_["window_start_s"][worst]),
            "mtf_nyquist_row_open": float(open_["mtf"][worst, nyq, zero]),
            "mtf_nyquist_row_closed": float(closed["mtf"][worst, nyq, zero]),
            "mtf_nyquist_col_open": float(open_["mtf"][worst, zero, nyq]),
            "mtf_nyquist_col_closed": float(closed["mtf"][worst, zero, nyq])}


# ------------------------------------------------------------------------ rendered patches


def _flat(east: np.ndarray, north: np.ndarray) -> np.ndarray:
    """The edge tile's height (m): 0 everywhere."""
    return np.zeros(np.broadcast(east, north).shape)


def edge_terrain(m: Models, angle_deg: float = EDGE_ANGLE_DEG, albedo=(0.15, 0.6),
                 size_m: float = 320.0, texel_m: float = 0.1, t_s: float | None = None):
    """A flat tile with a straight albedo edge at ``angle_deg`` to the main imager's columns
    (so its normal runs nearly along the rows), through the ground point seen at the imager's
    centre at ``t_s`` (None: through the scene centre)."""
    from scene.terrain import Terrain

    cam = m.main_camera
    c = cam.focal_plane.center_px
    t_ref = 0.0 if t_s is None else float(t_s)
    g = cam.ground_points(np.array([c + [0.0, -50.0], c + [0.0, 50.0], c]), t_ref, _flat)
    along = (g[1] - g[0])[:2]
    along /= np.linalg.norm(along)
    a = np.deg2rad(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    normal = rot @ np.array([-along[1], along[0]])
    through = np.zeros(2) if t_s is None else g[2, :2]
    n = int(round(size_m / texel_m))
    xs = (np.arange(n) + 0.5) * texel_m - size_m / 2
    # the signed distance east * normal_e + north * normal_n on the (north, east) grid, row 0
    # the north edge, as an outer sum (the same sums as on two meshgrids, without them), a
    # band of rows at a time into float32 (what the renderer's texture holds): no 80 MB
    # float64 temporaries to page in
    north_d, east_d, offset = -xs * normal[1], xs * normal[0], float(through @ normal)
    alb = np.empty((n, n), np.float32)
    lo, hi = np.float32(albedo[0]), np.float32(albedo[1])
    for r0 in range(0, n, EDGE_BAND_ROWS):
        d = np.add.outer(north_d[r0:r0 + EDGE_BAND_ROWS], east_d) - offset
        alb[r0:r0 + EDGE_BAND_ROWS] = np.where(d > 0, hi, lo)
    spacing = size_m / 40.0
    return Terrain(alb, texel_m, np.zeros((41, 41)), spacing)


def edge_rows(cols: int, angle_deg: float = EDGE_ANGLE_DEG) -> int:
    """Film rows of the edge render, ``cols`` wide: the edge's run across the width
    (cols tan angle), the ESF's +-ESF_HALF_PX, edge_mtf's margin each side and
    :data:`EDGE_SLACK_PX`, even; at most ``cols``."""
    run = cols * np.tan(np.deg2rad(angle_deg))
    rows = int(np.ceil(run + 2 * (ESF_HALF_PX + EDGE_MARGIN_PX + EDGE_SLACK_PX)))
    return min(cols, rows + rows % 2)


def render_patch(m: Models, renderer, t0_s: float, t1_s: float,
                 stage: Trajectory | None, moving: bool = True, keyframes: int = 65
                 ) -> np.ndarray:
    """One exposure [t0, t1] of a patch of the main imager (the renderer's film) around its
    centre: the poses move (or are frozen at mid-exposure), the stage follows ``stage`` (or
    rests); the optics' MTF is applied."""
    from camera.geometry import FocalPlane
    from scene.pinhole import ray_keyframes

    cam = m.main_camera
    fp0 = cam.focal_plane
    fp = FocalPlane(fp0.focal_length_m, fp0.pixel_pitch_m, renderer.rows, renderer.cols,
                    fp0.center_offset_px)
    times = np.linspace(t0_s, t1_s, keyframes)
    pose_t = times if moving else np.full(keyframes, 0.5 * (t0_s + t1_s))
    offsets = stage(times) if stage is not None else np.zeros((keyframes, 2))
    kf = ray_keyframes(cam.pose(pose_t), fp, offsets, renderer.z_start_m)
    img = renderer.render(kf, seed=int(1e6 * t0_s) & 0x7FFFFFFF)
    return m.optics.apply(img)


def main_imager_study(m: Models, trajectory: Trajectory, truth: Truth,
                      blurs: tuple[dict, dict], figures: dict, spp: int = 64,
                      size_px: int = 192) -> tuple[dict, dict]:
    """Render the main imager's worst exposure (open loop; ``figures`` from
    :func:`write_blur_npz`, ``blurs`` the open and closed :func:`window_blur`) as a patch of
    the scene and of a slanted edge: static, open and closed loop; measure the edge MTF at
    Nyquist against the prediction. Returns (the figures for metrics.json, the picture's
    arrays for :func:`imc.outputs.figures.fig_main_imager`)."""
    from scene.kernel import Renderer, Sun

    w = figures["worst_window"]
    t0 = figures["worst_window_start_s"]
    t1 = t0 + truth.window_s
    sun = Sun(*m.sun_deg)
    # the scene patches are pictures only (main_imager.png): PICTURE_SPP samples a pixel at
    # most; the edges, which are measured, get spp
    scene_r = Renderer(m.terrain, sun, size_px, size_px, spp=min(spp, PICTURE_SPP),
                       clouds=m.clouds)
    patches = {name: render_patch(m, scene_r, t0, t1, stage, moving)
               for name, stage, moving in (("static", None, False), ("open loop", None, True),
                                           ("closed loop", trajectory, True))}
    # the edge's film: the full width, and the rows that the ISO 12233 binning reads (the
    # edge's slant across the width, the ESF's half-window, the margin, and slack for the
    # motion); the pixels beyond are outside the ESF's window
    edge_r = Renderer(edge_terrain(m, t_s=0.5 * (t0 + t1)), sun, edge_rows(size_px),
                      size_px, spp=spp)
    edges = {name: render_patch(m, edge_r, t0, t1, stage, moving)
             for name, stage, moving in (("static", None, False), ("open loop", None, True),
                                         ("closed loop", trajectory, True))}
    curves = {k: edge_mtf(v, margin=EDGE_MARGIN_PX) for k, v in edges.items()}
    f_static, mtf_static = curves["static"]
    sel = truth.window == w
    result = {"window_start_s": t0, "window_s": truth.window_s, "spp": spp}
    motions = {}
    for name, traj in (("open loop", None), ("closed loop", trajectory)):
        motion = motions[name] = motion_mtf(truth.residual_px(traj)[sel], f_static[:, None])
        f, mtf = curves[name]
        key = name.split()[0]
        result[f"edge_mtf_nyquist_{key}"] = value_at(f, mtf, NYQUIST)
        result[f"predicted_mtf_nyquist_{key}"] = value_at(f_static, mtf_static * motion, NYQUIST)
        result[f"motion_mtf_nyquist_{key}"] = value_at(f_static, motion, NYQUIST)
    result["edge_mtf_nyquist_static"] = value_at(f_static, mtf_static, NYQUIST)
    result["optics_mtf_nyquist"] = float(m.optics.mtf(NYQUIST))
    result.update(figures)
    picture = {"title": f"{m.scenario.name}: main imager, exposure {t0:.2f}-{t1:.2f} s "
                        "(the worst open-loop one)",
               "patches": patches, "curves": curves,
               "psf": {key: (blur["psf"][w], float(blur["psf_bin_px"]))
                       for key, blur in zip(("open", "closed"), blurs, strict=True)},
               "predicted_open": (f_static, mtf_static * motions["open loop"]),
               "nyquist": NYQUIST}
    return result, picture

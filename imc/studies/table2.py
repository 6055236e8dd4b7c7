"""The seed paper's scene-robustness study (its Table 2) on rendered scenes.

Protocol (Janschek, Tchernykh & Dyblenko): 256 x 256 blocks; 36 references x 81 shifts within
+-144 px with at least 40 % overlap; images scaled to a mean brightness of 100 with Gaussian
noise of sigma 10 added to each image (SNR 20 dB); success rate and standard deviation of the
error per scene class.

Here each class is a procedural tile (:mod:`scene.classes`) rendered at nadir from 681 km by
the exact camera. The references sit side by side on one rendered canvas; each shift is an
integer crop offset plus a sub-pixel stage offset of one of a few extra renders of the same
canvas, so the true shift is known exactly (stage offset s moves the content by -s) and the
two images of a pair carry independent Monte Carlo noise. A result is a *success* when the
correlator calls it valid and both error components are below ``success_px``; *wrong* when it
is valid but outside; otherwise *invalid*.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camera.geometry import FocalPlane
from camera.motion import CameraModel
from correlator.core import Correlator, CorrelatorOptions
from orbit.attitude import Attitude, orbit_looking_at
from orbit.frames import LocalFrame
from scene.classes import cloud_cell_m, cloud_layer, scene_class
from scene.pinhole import ray_keyframes

#: the paper's Table 2: class -> (success %, std of error px)
PAPER_TABLE2 = {"urban": (100.0, 0.0127), "rural": (91.9, 0.0166), "mountain": (93.1, 0.0332),
                "waves": (98.2, 0.0062), "calm_water": (28.6, 0.1061)}
#: each class draws from its own seed stream
SCENE_INDEX = {k: i for i, k in enumerate(PAPER_TABLE2)}


@dataclass(frozen=True)
class Table2Config:
    """Study parameters (the paper's by default); sizes in px, brightness in grey levels."""

    block_px: int = 256
    n_refs: int = 36
    n_shifts: int = 81
    max_shift_px: int = 144
    min_overlap: float = 0.4
    mean_level: float = 100.0
    noise_sigma: float = 10.0
    success_px: float = 0.5
    spp: int = 16
    #: Monte Carlo pixel sampling, as the texture map (:class:`imc.studies.texture_map.
    #: TextureMapConfig`): the pairs are renders at random sub-pixel phases
    quadrature: bool = False
    n_phases: int = 4
    texel_m: float = 0.4
    dem_spacing_m: float = 2.0
    sun_deg: tuple[float, float] = (50.0, 140.0)


def _shifts(n: int, cfg: Table2Config, rng: np.random.Generator) -> np.ndarray:
    """Integer shifts (n, 2) within +-max_shift with the overlap fraction >= min_overlap."""
    out = np.empty((0, 2), int)
    b = cfg.block_px
    while len(out) < n:
        d = rng.integers(-cfg.max_shift_px, cfg.max_shift_px + 1, size=(4 * n, 2))
        ov = (1 - np.abs(d[:, 0]) / b) * (1 - np.abs(d[:, 1]) / b)
        out = np.concatenate([out, d[ov >= cfg.min_overlap]])
    return out[:n]


def run_class(kind: str, cfg: Table2Config, seed: int,
              log: Callable[[str], None] | None = None) -> dict:
    """Run the protocol on one scene class; returns counts, error statistics and timings."""
    from scene.kernel import Renderer, Sun

    rng = np.random.default_rng([seed, SCENE_INDEX[kind]])
    b, m = cfg.block_px, cfg.max_shift_px
    g = int(np.ceil(np.sqrt(cfg.n_refs)))
    canvas = g * b + 2 * m + 4
    fp = FocalPlane(10.0, 12e-6, canvas, canvas)
    epoch = np.datetime64("2026-06-21T10:30:00")
    cam = CameraModel(orbit_looking_at(35.0, 10.0, 681e3, 98.1, epoch),
                      Attitude("nadir"), LocalFrame(35.0, 10.0, 0.0), fp)
    pose = cam.pose(np.array([0.0, 0.0]), nominal=True)
    gsd = float(pose.position_m[0, 2]) * fp.ifov_rad
    size = cfg.dem_spacing_m * np.ceil(1.15 * canvas * gsd / cfg.dem_spacing_m)
    t0 = time.perf_counter()
    terrain = scene_class(kind, size, cfg.texel_m, cfg.dem_spacing_m, rng,
                          sun_azimuth_deg=cfg.sun_deg[1])
    clouds = None
    if kind == "mountain":  # the paper's mountain scene has snow and clouds
        base = float(terrain.dem_m.max()) + 1000.0
        clouds = cloud_layer(size + 4 * base, cloud_cell_m(size + 4 * base, 2.0), 0.2, base,
                             rng)
    r = Renderer(terrain, Sun(*cfg.sun_deg), canvas, canvas, spp=cfg.spp, clouds=clouds,
                 quadrature=cfg.quadrature)
    phases = np.vstack([[0.0, 0.0], rng.uniform(0.0, 1.0, size=(cfg.n_phases, 2))])
    renders = [r.render(ray_keyframes(pose, fp, tuple(ph), r.z_start_m), seed=seed * 100 + k)
               for k, ph in enumerate(phases)]
    t_render = time.perf_counter() - t0
    opts = CorrelatorOptions(max_shift_px=m + 4.0)
    errs, valid, crlbs, corr_s = [], [], [], 0.0
    for i in range(cfg.n_refs):
        r0, c0 = m + 2 + (i // g) * b, m + 2 + (i % g) * b
        ref = renders[0][r0:r0 + b, c0:c0 + b].astype(np.float64)
        gain = cfg.mean_level / ref.mean()
        ref = ref * gain + rng.normal(0.0, cfg.noise_sigma, ref.shape)
        n = _shifts(cfg.n_shifts, cfg, rng)
        p = rng.integers(1, cfg.n_phases + 1, size=cfg.n_shifts)
        cur = np.stack([renders[pk][r0 - dr:r0 - dr + b, c0 - dc:c0 - dc + b]
                        for (dr, dc), pk in zip(n, p, strict=True)]).astype(np.float64)
        cur = cur * gain + rng.normal(0.0, cfg.noise_sigma, cur.shape)
        truth = n - phases[p]
        t1 = time.perf_counter()
        res = Correlator(np.broadcast_to(ref, cur.shape), opts).measure(cur)
        corr_s += time.perf_counter() - t1
        errs.append(res.shift - truth)
        valid.append(res.valid)
        crlbs.append(res.crlb)
    err, ok = np.concatenate(errs), np.concatenate(valid)
    good = ok & (np.abs(err) < cfg.success_px).all(axis=1)
    e = err[good]
    bound = np.concatenate(crlbs)[good]
    out = {
        "kind": kind, "pairs": int(len(err)),
        "success_pct": 100.0 * good.mean(),
        "wrong_pct": 100.0 * (ok & ~good).mean(),
        "invalid_pct": 100.0 * (~ok).mean(),
        "std_px": float(np.std(e)) if len(e) > 1 else float("nan"),
        "std_row_col_px": [float(v) for v in e.std(axis=0)] if len(e) > 1 else [np.nan] * 2,
        # the error an efficient estimator would have on these pairs (RMS of their bounds)
        "crlb_rms_px": float(np.sqrt(np.mean(bound**2))) if len(e) else float("nan"),
        "bias_row_col_px": [float(v) for v in e.mean(axis=0)] if len(e) else [np.nan] * 2,
        "paper_success_pct": PAPER_TABLE2[kind][0], "paper_std_px": PAPER_TABLE2[kind][1],
        "render_s": t_render, "correlate_s": corr_s,
        "correlations_per_s": len(err) / corr_s,
        "canvas_px": canvas, "variant": r.variant,
    }
    if log:
        log(format_row(out))
    return out


def format_row(row: dict) -> str:
    """One printed line: success, std of error (the paper's and the pairs' bound), counts."""
    return (f"{row['kind']:11s} success {row['success_pct']:5.1f} % (paper "
            f"{row['paper_success_pct']:5.1f})  std {row['std_px']:.4f} px (paper "
            f"{row['paper_std_px']:.4f}, bound {row['crlb_rms_px']:.4f})  wrong "
            f"{row['wrong_pct']:4.1f} %  invalid "
            f"{row['invalid_pct']:5.1f} %  [{row['pairs']} pairs, render {row['render_s']:.0f} s,"
            f" {row['correlations_per_s']:.0f} corr/s]")

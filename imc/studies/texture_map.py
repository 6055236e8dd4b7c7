"""The seed paper's texture-robustness map (its Fig. 9): the correlator's shift error per block
over a large rendered scene, beside the error it predicts (its CRLB).

Protocol (the paper's): fragments rendered at 0.25 m and resampled to 0.75 m per pixel, the
sub-pixel shifts applied before resampling, motion blur in the Fourier domain, 128^2 blocks,
grey levels 0..255 with noise of sigma 20; the error of a block is |bias| + 1 sigma over its
successful trials (valid, and within ``success_px`` = 0.5 px of the truth on both axes: the
correlator's own validity with a ``max_crlb_px`` of 0.15 px, its former default); a block where
fewer than half the trials succeed is flagged (NaN), and the trials called valid but off by more
than 0.5 px are counted apart (``wrong``).

Here the scene (urban by default, or a user GeoTIFF) is seen at nadir from an aircraft at
2,400 m through the exact renderer, one block at a time: each block's area is rendered at
0.25 m with the focal-plane stage at rest (twice: the renderer's own noise) and at
``n_phases`` random sub-pixel offsets, so the sub-pixel shift is exact geometry, not an
interpolation. Every render is resampled to 0.75 m two ways: ``box``, the detector
integrating 3 x 3 fine pixels (it passes 64 % at the coarse Nyquist frequency: aliased), and
``bandlimited``, an alias-free low-pass to the coarse band sampled at the same pixel centres
(a shift before it is exactly a shift after it). A trial cuts the reference from the rest
render and the current block from a shifted render moved by a whole number of coarse pixels,
smears both by the same linear motion (a sinc along a random direction, in the Fourier
domain), maps radiance to grey levels (the scene's 0.5th and 99.5th percentiles to a
variant's levels), adds independent noise of sigma 20 and quantises to 8 bits. True shift = whole
crop offset - stage offset / 3 (a stage offset s moves the content by -s fine pixels).

Per trial the correlator predicts its error (its CRLB, H^-1 J H^-1 from the pair's spectra);
the clean texture's Cramer-Rao bound, 2 sigma^2 (sum g g^T)^-1 with band-limited gradients of
the noise-free reference and sigma^2 = 20^2 + quantisation (1/12) + the renderer's noise, is
what no estimator can beat. A block's predicted error and bound are the RMS over its trials;
every map is per axis, sqrt((e_row^2 + e_col^2) / 2).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from camera.geometry import FocalPlane
from camera.motion import CameraModel
from correlator.bounds import correlation_bound_px, crlb_px
from correlator.core import measure_shift
from imc.wiring import streams
from orbit.aircraft import Aircraft, AircraftAttitude
from orbit.frames import LocalFrame
from scene.terrain import Terrain

#: the paper's texture study: error per block from strong to weak texture, and its mean, px
PAPER_ERROR_PX = {"strong": 0.013, "weak": 0.104, "mean": 0.027}

Log = Callable[[str], None]


@dataclass(frozen=True)
class TextureMapConfig:
    """Study parameters (the paper's protocol by default; sizes in coarse 0.75 m pixels).

    ``grid``: blocks per side of the map; ``trials``: shifted pairs per block;
    ``max_shift_px``: whole-pixel shifts within +-this; ``max_blur_px``: smear lengths
    uniform in [0, this]; ``variants``: (name, resampling, (black, white)): the grey levels
    of the scene's 0.5th and 99.5th radiance percentiles. The first two keep a black pedestal
    of 2 sigma (an ADC offset) so the noise does not clip at 0; the full range 0..255 puts
    34 % of the urban scene's pixels below 30 grey levels, where the clipped noise is not the
    Gaussian noise the correlator's error model (and the bound) assume.
    """

    block_px: int = 128
    factor: int = 3
    fine_m: float = 0.25
    grid: int = 8
    trials: int = 128
    n_phases: int = 6
    max_shift_px: int = 4
    max_blur_px: float = 1.0
    noise_sigma: float = 20.0
    variants: tuple[tuple[str, str, tuple[float, float]], ...] = (
        ("bandlimited", "bandlimited", (40.0, 255.0)), ("box", "box", (40.0, 255.0)),
        ("bandlimited_0_255", "bandlimited", (0.0, 255.0)))
    spp: int = 4
    #: Monte Carlo pixel sampling (not the renderer's default fixed quadrature): each trial
    #: moves the fine render by its own sub-pixel phase, where a fixed quadrature's
    #: phase-dependent error would be a per-trial error the 3 x 3 resampling does not
    #: average (measured 1.41x the predicted error on a GeoTIFF block against <= 1.3x),
    #: while Monte Carlo noise is averaged by it
    quadrature: bool = False
    height_m: float = 2400.0
    focal_length_m: float = 0.110
    sun_deg: tuple[float, float] = (50.0, 140.0)
    max_crlb_px: float = 0.15
    success_px: float = 0.5

    @property
    def coarse_m(self) -> float:
        return self.fine_m * self.factor

    @property
    def pad_px(self) -> int:
        """Coarse pixels around a block: the whole-pixel shifts plus the blur's wrap."""
        return self.max_shift_px + 8

    @property
    def window_px(self) -> int:
        """Side of a block's fine render."""
        return (self.block_px + 2 * self.pad_px) * self.factor

    @property
    def scene_m(self) -> float:
        """Ground the map covers, m."""
        return self.grid * self.block_px * self.coarse_m


@dataclass(frozen=True)
class BlockResult:
    """One block's trials (N of them): errors (N, 2) px, validity (N,), the correlator's
    predicted error of each pair (its CRLB, H^-1 J H^-1 from the pair's spectra) and the
    clean texture's Cramer-Rao bound (N, 2) px, and the noise sigma in grey levels."""

    errors: np.ndarray
    valid: np.ndarray
    predicted: np.ndarray
    bound: np.ndarray
    noise_sigma: float
    success_px: float = 0.5
    corr_bound: np.ndarray | None = None  # (N, 2) px: correlation_bound_px of each pair

    @property
    def success(self) -> np.ndarray:
        """Valid trials whose error is below ``success_px`` on both axes (N,)."""
        return self.valid & np.all(np.abs(self.errors) < self.success_px, axis=-1)

    @property
    def wrong(self) -> float:
        """Fraction of the trials called valid with an error beyond ``success_px``."""
        return float(np.mean(self.valid & ~self.success))

    @property
    def measured(self) -> bool:
        """At least half the trials succeeded: the block has an error to map."""
        return bool(self.success.mean() >= 0.5)

    def error_px(self) -> float:
        """|bias| + 1 sigma per axis over the successful trials, combined as the RMS of the
        axes (NaN when fewer than half succeeded: a block the correlator flags)."""
        e = self.errors[self.success]
        if not self.measured or len(e) < 2:
            return float("nan")
        per_axis = np.abs(e.mean(axis=0)) + e.std(axis=0)
        return float(np.sqrt(np.mean(per_axis**2)))

    def predicted_px(self) -> float:
        """RMS of the successful trials' predicted errors, per axis (NaN as error_px)."""
        p = self.predicted[self.success]
        return float(np.sqrt(np.mean(p**2))) if self.measured else float("nan")

    def bound_px(self) -> float:
        """RMS of the trials' clean-texture bounds, per axis."""
        return float(np.sqrt(np.mean(self.bound**2)))

    def corr_bound_px(self) -> float:
        """RMS of the trials' correlation bounds (the least error a correlation estimator
        reaches at this noise), per axis; NaN when not computed."""
        if self.corr_bound is None:
            return float("nan")
        return float(np.sqrt(np.mean(self.corr_bound**2)))


def motion_blur(blocks: np.ndarray, length_px: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Linear motion smear of ``length_px`` (N,) along ``angle_rad`` (N,) from the row axis,
    applied in the Fourier domain (circular: pad the blocks), blocks (N, H, W)."""
    h, w = blocks.shape[-2:]
    fy = sfft.fftfreq(h)[None, :, None]
    fx = sfft.rfftfreq(w)[None, None, :]
    proj = fy * np.cos(angle_rad)[:, None, None] + fx * np.sin(angle_rad)[:, None, None]
    tf = np.sinc(length_px[:, None, None] * proj)
    return sfft.irfft2(sfft.rfft2(blocks, axes=(-2, -1)) * tf, s=(h, w), axes=(-2, -1))


def bin_fine(img: np.ndarray, factor: int) -> np.ndarray:
    """Mean over factor x factor cells (the detector integrating the fine render)."""
    h, w = img.shape[-2] // factor, img.shape[-1] // factor
    x = img[..., :h * factor, :w * factor]
    return x.reshape(*x.shape[:-2], h, factor, w, factor).mean(axis=(-3, -1))


class SceneRenderer:
    """The scene at nadir from an aircraft, rendered block by block at the fine pixel."""

    def __init__(self, terrain: Terrain, cfg: TextureMapConfig):
        from scene.kernel import Renderer, Sun

        self.cfg = cfg
        self.terrain = terrain
        frame = LocalFrame(0.0, 0.0, 0.0)  # geometry only: the scene's place does not matter
        ground = float(np.median(terrain.dem_m))
        plane = Aircraft.over_point(frame, ground + cfg.height_m, 50.0, 0.0,
                                    np.datetime64("2026-06-21T10:30:00"), 0.0, ground)
        self.pitch_m = cfg.fine_m * cfg.focal_length_m / cfg.height_m
        n = cfg.window_px
        self.camera = CameraModel(plane, AircraftAttitude("nadir"), frame,
                                  FocalPlane(cfg.focal_length_m, self.pitch_m, n, n))
        self.pose = self.camera.pose(np.array([0.0, 0.0]), nominal=True)
        self.renderer = Renderer(terrain, Sun(*cfg.sun_deg), n, n, spp=cfg.spp,
                                 ceiling_m=float(self.pose.position_m[0, 2]),
                                 quadrature=cfg.quadrature)
        self.render_s = 0.0

    def block_centre_px(self, i: int, j: int) -> tuple[float, float]:
        """Centre of block (i, j) relative to the principal point, fine px."""
        c = self.cfg
        step = c.block_px * c.factor
        half = 0.5 * (c.grid - 1)
        return ((i - half) * step, (j - half) * step)

    def render(self, i: int, j: int, stage_px, seed: int) -> np.ndarray:
        """Fine render (n, n) of block (i, j)'s window with the stage at ``stage_px``."""
        from scene.pinhole import ray_keyframes

        t0 = time.perf_counter()
        n = self.cfg.window_px
        fp = FocalPlane(self.cfg.focal_length_m, self.pitch_m, n, n, self.block_centre_px(i, j))
        kf = ray_keyframes(self.pose, fp, np.asarray(stage_px, dtype=np.float64),
                           self.renderer.z_start_m)
        out = self.renderer.render(kf, seed)
        self.render_s += time.perf_counter() - t0
        return out

    def overview(self) -> np.ndarray:
        """The whole map at the coarse pixel (for the white level and the PNG)."""
        from scene.kernel import Renderer, Sun
        from scene.pinhole import ray_keyframes

        c = self.cfg
        n = c.grid * c.block_px
        fp = FocalPlane(c.focal_length_m, self.pitch_m * c.factor, n, n)
        r = Renderer(self.terrain, Sun(*c.sun_deg), n, n, spp=c.spp,
                     ceiling_m=float(self.pose.position_m[0, 2]), quadrature=c.quadrature)
        return r.render(ray_keyframes(self.pose, fp, (0.0, 0.0), r.z_start_m), 1)


def resample_bandlimited(img: np.ndarray, factor: int, taper_from: float = 0.7) -> np.ndarray:
    """Alias-free resampling of a fine image to pixels ``factor`` times larger: a low-pass flat
    to ``taper_from`` x the coarse Nyquist frequency and rolling off (cos^2) to zero at it,
    applied on the mirror extension (no wrap edge), then sampled at the coarse pixels'
    centres (the same grid as :func:`bin_fine`)."""
    h, w = img.shape[-2] // factor * factor, img.shape[-1] // factor * factor
    x = img[..., :h, :w]
    x = np.concatenate([x, x[..., ::-1, :]], axis=-2)
    x = np.concatenate([x, x[..., ::-1]], axis=-1)
    nyq = 0.5 / factor

    def taper(f: np.ndarray) -> np.ndarray:
        u = np.clip((np.abs(f) / nyq - taper_from) / (1.0 - taper_from), 0.0, 1.0)
        return np.cos(0.5 * np.pi * u) ** 2

    tf = taper(sfft.fftfreq(2 * h))[:, None] * taper(sfft.rfftfreq(2 * w))[None, :]
    y = sfft.irfft2(sfft.rfft2(x, axes=(-2, -1)) * tf, s=(2 * h, 2 * w), axes=(-2, -1))
    c = factor // 2
    return y[..., c:h:factor, c:w:factor]


#: how a fine render becomes 0.75 m pixels: the detector integrating 3 x 3 fine pixels
#: (aliased: the box passes 64 % at Nyquist), or an alias-free low-pass and sampling
RESAMPLING = {"box": bin_fine, "bandlimited": resample_bandlimited}


def run_block(sr: SceneRenderer, i: int, j: int, levels: dict[str, tuple[float, float]],
              seed: int, index: int) -> dict[str, BlockResult]:
    """All trials of block (i, j), for each variant: renders, pairs, correlations, errors
    and bounds. ``levels``: each variant's (scale, offset) from radiance to grey levels."""
    c = sr.cfg
    rng = streams.rng(seed, "texture_map", index)
    f, b, pad = c.factor, c.block_px, c.pad_px
    phases = rng.uniform(0.0, f, size=(c.n_phases, 2))  # stage offsets, fine px
    render_seeds = rng.integers(0, 2**31 - 1, size=c.n_phases + 2)
    fine = [sr.render(i, j, (0.0, 0.0), int(s)) for s in render_seeds[:2]]
    fine += [sr.render(i, j, ph, int(s)) for ph, s in zip(phases, render_seeds[2:],
                                                          strict=True)]
    n = c.trials
    shifts = rng.integers(-c.max_shift_px, c.max_shift_px + 1, size=(n, 2))
    which = rng.integers(0, c.n_phases, size=n)
    blur = rng.uniform(0.0, c.max_blur_px, size=n)
    angle = rng.uniform(0.0, np.pi, size=n)
    noise = rng.normal(0.0, c.noise_sigma, size=(2, n, b, b))
    truth = shifts - phases[which] / f
    side = b + 2 * (pad - c.max_shift_px)  # padded block that every shift can cut
    m0, k0 = c.max_shift_px, pad - c.max_shift_px
    inner = (slice(None), slice(k0, k0 + b), slice(k0, k0 + b))
    out = {}
    resampled = {kind: [resample(x, f) for x in fine] for kind, resample in RESAMPLING.items()}
    for name, kind, _ in c.variants:
        scale, offset = levels[name]
        coarse = [x * scale + offset for x in resampled[kind]]
        # the renderer's own noise at the coarse pixel, in grey levels
        mc = float(np.std((coarse[0] - coarse[1])[pad:-pad, pad:-pad]) / np.sqrt(2.0))
        sigma = float(np.sqrt(c.noise_sigma**2 + 1.0 / 12.0 + mc**2))
        ref = np.broadcast_to(coarse[0][m0:m0 + side, m0:m0 + side], (n, side, side))
        cur = np.stack([coarse[2 + p][m0 - dr:m0 - dr + side, m0 - dc:m0 - dc + side]
                        for (dr, dc), p in zip(shifts, which, strict=True)])
        ref, cur = motion_blur(ref, blur, angle)[inner], motion_blur(cur, blur, angle)[inner]
        crlb = crlb_px(ref, sigma)
        corr = correlation_bound_px(ref, sigma)
        expose = [np.clip(np.rint(x + e), 0, 255).astype(np.float32)
                  for x, e in zip((ref, cur), noise, strict=True)]
        res = measure_shift(*expose, max_crlb_px=c.max_crlb_px)
        out[name] = BlockResult(res.shift - truth, res.valid, res.crlb, crlb, sigma,
                                c.success_px, corr)
    return out


@dataclass(frozen=True)
class TextureMap:
    """The study's maps (grid, grid), px per axis: the measured error, the correlator's
    predicted error (its CRLB), the clean texture's Cramer-Rao bound (NaN where fewer than
    half the trials succeeded: blocks the correlator flags); the fractions of successful and
    of wrong (valid but beyond ``success_px``) trials, the noise sigma (grey levels) and the
    scene's coarse overview in grey levels."""

    error_px: np.ndarray
    predicted_px: np.ndarray
    bound_px: np.ndarray
    success: np.ndarray
    wrong: np.ndarray
    noise_sigma: np.ndarray
    overview: np.ndarray
    render_s: float
    correlate_s: float
    corr_bound_px: np.ndarray

    @property
    def ratio(self) -> np.ndarray:
        """Measured / predicted error per block."""
        return self.error_px / self.predicted_px

    def summary(self, tolerance: float = 0.3) -> dict:
        """Mean, best and worst block error; the maps' means; how many blocks sit within
        ``tolerance`` of their predicted error and of their bound."""
        e = self.error_px

        def within(ref: np.ndarray) -> int:
            r = e / ref
            return int(np.sum(np.abs(r[np.isfinite(r)] - 1.0) <= tolerance))

        r, rb, rc = self.ratio, e / self.bound_px, e / self.corr_bound_px
        return {
            "blocks": int(e.size), "measured_blocks": int(np.isfinite(e).sum()),
            "mean_px": float(np.nanmean(e)),
            "min_px": float(np.nanmin(e)), "max_px": float(np.nanmax(e)),
            "predicted_mean_px": float(np.nanmean(self.predicted_px)),
            "bound_mean_px": float(np.nanmean(self.bound_px)),
            "ratio_min": float(np.nanmin(r)), "ratio_median": float(np.nanmedian(r)),
            "ratio_max": float(np.nanmax(r)), "within_predicted": within(self.predicted_px),
            "bound_ratio_min": float(np.nanmin(rb)), "bound_ratio_median":
            float(np.nanmedian(rb)), "bound_ratio_max": float(np.nanmax(rb)),
            "within_bound": within(self.bound_px), "tolerance": tolerance,
            "corr_bound_mean_px": float(np.nanmean(self.corr_bound_px)),
            "corr_bound_ratio_min": float(np.nanmin(rc)),
            "corr_bound_ratio_median": float(np.nanmedian(rc)),
            "corr_bound_ratio_max": float(np.nanmax(rc)),
            "success_fraction": float(np.mean(self.success)),
            "wrong_fraction": float(np.mean(self.wrong)),
            "noise_sigma_mean": float(np.nanmean(self.noise_sigma)), "paper_px": PAPER_ERROR_PX}


def grey_levels(overview: np.ndarray, levels: tuple[float, float]) -> tuple[float, float]:
    """(scale, offset) taking the scene's 0.5th and 99.5th radiance percentiles to
    ``levels`` (black, white)."""
    lo, hi = np.percentile(overview, [0.5, 99.5])
    scale = (levels[1] - levels[0]) / float(hi - lo)
    return scale, levels[0] - scale * float(lo)


def run_map(terrain: Terrain, cfg: TextureMapConfig = TextureMapConfig(), seed: int = 1,
            log: Log | None = None) -> dict[str, TextureMap]:
    """Tile the scene with ``grid`` x ``grid`` blocks and measure every one, for each
    variant."""
    need = cfg.scene_m + 2 * cfg.pad_px * cfg.coarse_m
    if min(terrain.size_m) < need:
        raise ValueError(f"the scene ({terrain.size_m[0]:.0f} x {terrain.size_m[1]:.0f} m) is "
                         f"smaller than the {cfg.grid} x {cfg.grid} blocks need ({need:.0f} m);"
                         " lower the grid")
    sr = SceneRenderer(terrain, cfg)
    over = sr.overview()
    levels = {name: grey_levels(over, lv) for name, _, lv in cfg.variants}
    g = cfg.grid
    keys = ("error", "predicted", "bound", "success", "wrong", "sigma", "corr_bound")
    maps = {name: {k: np.full((g, g), np.nan) for k in keys} for name in levels}
    t_corr = 0.0
    for i in range(g):
        for j in range(g):
            t0 = time.perf_counter()
            r0 = sr.render_s
            res = run_block(sr, i, j, levels, seed, i * g + j)
            t_corr += time.perf_counter() - t0 - (sr.render_s - r0)
            for name, r in res.items():
                vals = (r.error_px(), r.predicted_px(), r.bound_px(), r.success.mean(),
                        r.wrong, r.noise_sigma, r.corr_bound_px())
                for k, v in zip(keys, vals, strict=True):
                    maps[name][k][i, j] = v
        if log:
            log(f"  row {i + 1}/{g} (error/predicted px): " + "; ".join(
                f"{name} " + " ".join(f"{e:.4f}/{p:.4f}" for e, p in zip(
                    mp["error"][i], mp["predicted"][i], strict=True))
                for name, mp in maps.items()))
    grey = {name: np.clip(over * lv[0] + lv[1], 0, 255) for name, lv in levels.items()}
    return {name: TextureMap(mp["error"], mp["predicted"], mp["bound"], mp["success"],
                             mp["wrong"], mp["sigma"], grey[name], sr.render_s, t_corr,
                             mp["corr_bound"])
            for name, mp in maps.items()}


def plot_map(tm: TextureMap, path, title: str = "") -> None:
    """PNG over the scene: the measured error map, the predicted error (CRLB) map beside it,
    their ratio, and the clean texture's bound."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    g = tm.error_px.shape[0]
    n = tm.overview.shape[0]
    ext = (0, n, n, 0)
    lo = float(np.nanmin([tm.error_px, tm.predicted_px, tm.bound_px]))
    hi = float(np.nanmax([tm.error_px, tm.predicted_px, tm.bound_px]))
    err_norm = LogNorm(lo, hi)
    fig, ax = plt.subplots(2, 2, figsize=(13, 12.5))
    panels = [(tm.error_px, "measured error, |bias| + 1 sigma (px)", err_norm, "viridis", 3),
              (tm.predicted_px, "predicted error, CRLB of the pairs (px)", err_norm, "viridis",
               3),
              (tm.ratio, "measured / predicted", plt.Normalize(0.4, 1.6), "coolwarm", 2),
              (tm.bound_px, "clean-texture Cramer-Rao bound (px)", err_norm, "viridis", 3)]
    cell = n / g
    for a, (val, name, norm, cmap, digits) in zip(ax.ravel(), panels, strict=True):
        a.imshow(tm.overview, cmap="gray", extent=ext, vmin=0, vmax=255)
        im = a.imshow(val, cmap=cmap, norm=norm, alpha=0.5, extent=ext, interpolation="nearest")
        for i in range(g):
            for j in range(g):
                txt = f"{val[i, j]:.{digits}f}" if np.isfinite(val[i, j]) else "flagged"
                a.text((j + 0.5) * cell, (i + 0.5) * cell, txt,
                       ha="center", va="center", fontsize=7, color="white",
                       bbox={"facecolor": "black", "alpha": 0.35, "pad": 1, "lw": 0})
        a.set_title(name)
        a.set_xticks([])
        a.set_yticks([])
        fig.colorbar(im, ax=a, fraction=0.046, pad=0.02)
    s = tm.summary()
    fig.suptitle(f"{title}: mean error {s['mean_px']:.4f} px (paper 0.027, target <= 0.0135); "
                 f"within 30 % of the predicted error: {s['within_predicted']} of "
                 f"{s['measured_blocks']} blocks measured ({s['blocks']} in all)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)

"""The report's figures (matplotlib, PNG): per run from its output folder, per sweep from its
results.

A run's figures read metrics.json, tracks.csv, blur.npz and series.npz (written by
:func:`write_series` with the run: the true motion at the main imager's centre and the stage
over the whole run on a uniform grid, the loop model's |S(f)|, one tracker frame with its
blocks). Each figure function returns the PNG's path, or None when the run lacks its data
(an analytic plant has no tracker frame).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from imc.io import atomic_write, write_npz

if TYPE_CHECKING:
    from compensation.loop import LoopResult
    from imc.wiring.build import Models
    from imc.wiring.truth import Truth

#: most samples of the uniform series (a 10 s run at 100 Hz x 8: 8,000)
MAX_SERIES = 20_000
AXES = ("row", "col")


@dataclass(frozen=True)
class Figure:
    """A written figure: its file, title and a one-sentence caption."""

    path: Path
    title: str
    caption: str


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def sparse_log_ticks(*axes) -> None:
    """Minor ticks at 2 and 5 of each decade, unlabelled, on the log axes of ``axes``
    (matplotlib's default of 8 a decade makes a log-log figure cost ~0.3 s more to draw)."""
    from matplotlib.ticker import LogLocator, NullFormatter

    for ax in axes:
        for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
            if scale == "log":
                axis.set_minor_locator(LogLocator(10.0, subs=(2.0, 5.0)))
                axis.set_minor_formatter(NullFormatter())


def save(fig, path: Path) -> Path:
    """Save a matplotlib figure as PNG atomically and close it."""
    atomic_write(Path(path), lambda p: fig.savefig(p, format="png"))
    _plt().close(fig)
    return Path(path)


# ------------------------------------------------------------------------------ run data


def uniform_motion(m: Models, trajectory, n_max: int = MAX_SERIES
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t (N,), true motion (N, 2), stage (N, 2)) at the main imager's centre over the whole
    run on a uniform grid (samples_per_frame per tracker frame, at most ``n_max``): the ground
    seen there at t = 0 relative to t = 0, less what the imager follows itself (TDI)."""
    sc = m.scenario
    end = float(m.frame_t_s[-1] + m.exposure_s)
    n = int(min(n_max, max(64, round(end * m.rate_hz * sc.metrics.samples_per_frame))))
    t = (np.arange(n) + 0.5) * end / n
    cam = m.main_camera
    ground = cam.ground_points(cam.focal_plane.center_px[None], 0.0, m.terrain.height_at)
    motion = cam.image_motion_px(ground, t, 0.0)[:, 0] - m.charge_px(t)
    return t, motion - motion[0], trajectory(t)


def estimate_px(m: Models, res: LoopResult) -> np.ndarray:
    """The loop's motion estimate (T, 2) less what the imager follows itself (TDI charge
    transfer since frame 0), comparable with :func:`uniform_motion`; NaN where invalid."""
    mid = m.frame_mid_s
    est = res.record.motion_px - (m.charge_px(mid) - m.charge_px(mid[:1]))
    return np.where(res.record.motion_valid[:, None], est, np.nan)


def write_series(out: Path, m: Models, res: LoopResult, truth: Truth, loop_model=None,
                 frames: np.ndarray | None = None, ref_corners: np.ndarray | None = None
                 ) -> tuple[Path, dict[str, np.ndarray]]:
    """series.npz: what the report and the recording need beyond tracks.csv and blur.npz;
    returns its path and arrays."""
    t, motion, stage = uniform_motion(m, res.trajectory)
    arrays: dict[str, np.ndarray] = {
        "t_s": t, "motion_px": motion, "stage_px": stage,
        "imager_start_s": np.array(m.scenario.camera.main_imager.start_s),
        "frame_t_s": m.frame_t_s, "estimate_px": estimate_px(m, res),
        "centers_px": res.record.centers_px,
        "block_px": np.array(m.scenario.correlator.block_px),
        "rate_hz": np.array(m.rate_hz)}
    if loop_model is not None:
        f = np.geomspace(m.rate_hz * 1e-3, 0.5 * m.rate_hz, 400)
        arrays.update(rejection_f_hz=f, rejection=np.abs(loop_model.rejection(f)))
    if frames is not None and len(frames):
        k = len(frames) // 2
        arrays.update(frame=np.asarray(frames[k], np.float32), frame_index=np.array(k))
        if ref_corners is not None:
            arrays["frame_corners_px"] = np.asarray(ref_corners[k])
    path = Path(out) / "series.npz"
    write_npz(path, **arrays)
    return path, arrays


def _load(run_dir: Path, name: str):
    p = Path(run_dir) / name
    if not p.exists():
        return None
    if p.suffix == ".npz":
        with np.load(p) as z:
            return {k: z[k] for k in z.files}
    if p.suffix == ".json":
        return json.loads(p.read_text())
    with open(p, newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------------ run figures


def fig_motion(run_dir: Path, s: dict) -> Path:
    """Residual motion over time, open loop (the true motion) and closed loop."""
    plt = _plt()
    t, mo, st = s["t_s"], s["motion_px"], s["stage_px"]
    fig, axes = plt.subplots(2, 1, figsize=(8, 5), dpi=110, sharex=True)
    for i, ax in enumerate(axes):
        ax.plot(t, mo[:, i], color="C3", lw=1.0, label="open loop (true motion)")
        ax.plot(t, mo[:, i] - st[:, i], color="C0", lw=1.0, label="closed loop (residual)")
        ax.plot(s["frame_t_s"], s["estimate_px"][:, i], ".", ms=2, color="0.4",
                label="loop's estimate")
        ax.axvspan(float(s["imager_start_s"]), t[-1], color="0.93", zorder=-1)
        ax.set_ylabel(f"{AXES[i]} (px)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper right", ncol=3)
    axes[0].set_title("image motion at the main imager (shaded: its exposures)")
    axes[1].set_xlabel("time (s)")
    fig.tight_layout()
    return save(fig, Path(run_dir) / "fig_motion.png")


def periodogram(x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """(f, one-sided power spectral density) of the columns of x (N, ...), a linear trend
    removed and a periodic Hann window applied, without importing scipy.signal (a second):
    ``scipy.signal.periodogram(x, fs, window="hann", detrend="linear", axis=0)`` as its
    ``_spectral_helper`` computed it, step by step (the same numbers); scipy's current
    ShortTimeFFT path agrees to rounding (relative 1e-9 where the motion has power, 2e-5 in
    bins 1e-12 below the peak)."""
    import scipy.fft as sfft
    from scipy import linalg

    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    if n <= 1:
        raise ValueError("a periodogram needs at least two samples")
    flat = x.reshape(n, -1).copy()
    a = np.ones((n, 2))
    a[:, 0] = np.arange(1, n + 1, dtype=np.float64) / n
    coef = linalg.lstsq(a, flat)[0]
    flat = flat - a @ coef
    fac = np.linspace(-np.pi, np.pi, n + 1, dtype=np.float64)
    win = np.zeros(n + 1)
    for k, ak in enumerate(np.asarray([0.5, 1.0 - 0.5])):
        win += ak * np.cos(k * fac)
    win = win[:-1]
    spec = sfft.rfft((win * flat.T).real, n=n)
    p = np.conjugate(spec) * spec
    p *= 1.0 / (fs * (win * win).sum())
    p[:, 1:-1 if n % 2 == 0 else None] *= 2
    return sfft.rfftfreq(n, 1 / fs), p.real.T.reshape((-1, *x.shape[1:]))


def fig_spectrum(run_dir: Path, s: dict) -> Path:
    """Amplitude spectra of the open- and closed-loop motion, and their ratio beside the loop
    model's rejection |S(f)|."""
    from matplotlib.ticker import NullFormatter

    plt = _plt()
    t, mo, st = s["t_s"], s["motion_px"], s["stage_px"]
    fs = 1.0 / (t[1] - t[0])
    f, p_open = periodogram(mo, fs)
    _, p_closed = periodogram(mo - st, fs)
    po, pc = p_open.sum(axis=1), p_closed.sum(axis=1)
    keep = f > 0
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4), dpi=110)
    a1.loglog(f[keep], np.sqrt(po[keep]), color="C3", lw=1, label="open loop")
    a1.loglog(f[keep], np.sqrt(pc[keep]), color="C0", lw=1, label="closed loop")
    a1.set_xlabel("frequency (Hz)")
    a1.set_ylabel("amplitude spectral density (px / sqrt Hz)")
    a1.set_title("residual motion spectrum (row + col)")
    a1.grid(True, which="both", alpha=0.3)
    a1.legend(fontsize=8)
    strong = keep & (po > 1e-3 * po[keep].max())
    a2.loglog(f[strong], np.sqrt(pc[strong] / po[strong]), ".", ms=4, color="C2",
              label="closed / open (where the motion has power)")
    if "rejection" in s:
        a2.loglog(s["rejection_f_hz"], s["rejection"], color="C0", label="analytic |S(f)|")
    a2.axhline(1.0, color="0.7", lw=0.8)
    a2.set_xlim(min(f[keep][0], float(s.get("rejection_f_hz", [np.inf])[0])),
                0.5 * float(s["rate_hz"]))
    a2.xaxis.set_minor_formatter(NullFormatter())
    a2.set_xlabel("frequency (Hz)")
    a2.set_ylabel("rejection")
    a2.set_title("the loop's rejection")
    a2.grid(True, which="both", alpha=0.3)
    a2.legend(fontsize=8)
    sparse_log_ticks(a1, a2)
    fig.tight_layout()
    return save(fig, Path(run_dir) / "fig_spectrum.png")


def fig_psf(run_dir: Path, blur: dict, metrics: dict) -> Path:
    """The residual PSF of the worst main-imager exposure, open and closed loop."""
    plt = _plt()
    w = int((metrics.get("main_imager_blur") or {}).get("worst_window", 0))
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.2), dpi=110)
    for ax, key, title in zip(axes, ("open", "closed"), ("open loop", "closed loop"),
                              strict=True):
        psf = blur[f"{key}_psf"][min(w, len(blur[f"{key}_psf"]) - 1)]
        half = 0.5 * psf.shape[0] * float(blur[f"{key}_psf_bin_px"])
        mtf = blur[f"{key}_mtf"][min(w, len(blur[f"{key}_mtf"]) - 1)]
        freqs = blur["open_mtf_freqs"]
        nyq, zero = np.argmin(np.abs(freqs - 0.5)), np.argmin(np.abs(freqs))
        im = ax.imshow(psf, extent=(-half, half, half, -half), cmap="magma",
                       interpolation="nearest")
        ax.set_title(f"{title}: motion MTF at Nyquist row {mtf[nyq, zero]:.3f}, "
                     f"col {mtf[zero, nyq]:.3f}", fontsize=8)
        ax.set_xlabel("col (px)")
        ax.set_ylabel("row (px)")
        fig.colorbar(im, ax=ax, fraction=0.046, label="fraction of the exposure")
    fig.suptitle(f"residual-motion PSF of the worst exposure (#{w})", fontsize=10)
    fig.tight_layout()
    return save(fig, Path(run_dir) / "fig_psf.png")


def _tracks(rows: list[dict]) -> dict[str, np.ndarray]:
    """tracks.csv as arrays (T, B[, 2])."""
    n_b = max(int(r["block"]) for r in rows) + 1
    n_t = len(rows) // n_b

    def arr(*names):
        a = np.array([[float(r[n]) for n in names] for r in rows])
        return a.reshape(n_t, n_b, len(names)).squeeze(-1) if len(names) == 1 else a.reshape(
            n_t, n_b, len(names))

    return {"t": arr("t_s")[:, 0], "true": arr("true_row_px", "true_col_px"),
            "meas": arr("meas_row_px", "meas_col_px"), "crlb": arr("crlb_row_px",
                                                                   "crlb_col_px"),
            "valid": arr("valid").astype(bool), "frame": arr("frame")[:, 0]}


def fig_tracker(run_dir: Path, tr: dict[str, np.ndarray]) -> Path:
    """Each block's tracking error against its predicted error (CRLB): RMS per block, and the
    errors over time inside the ±CRLB band. ``tr``: tracks.csv as arrays (:func:`_tracks`)."""
    plt = _plt()
    ok = tr["valid"].copy()
    ok[0] = False  # frame 0 is the reference
    err = tr["meas"] - tr["true"]
    n_b = err.shape[1]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4), dpi=110,
                                 gridspec_kw={"width_ratios": [1, 1.6]})
    x = np.arange(n_b)
    for i in range(2):
        rms = [np.sqrt(np.mean(err[ok[:, b], b, i] ** 2)) if ok[:, b].any() else np.nan
               for b in range(n_b)]
        crlb = [np.median(tr["crlb"][ok[:, b], b, i]) if ok[:, b].any() else np.nan
                for b in range(n_b)]
        a1.bar(x + (i - 0.5) * 0.38, rms, 0.36, color=f"C{i}", alpha=0.8,
               label=f"RMS error {AXES[i]}")
        a1.plot(x + (i - 0.5) * 0.38, crlb, "k_", ms=14, mew=2,
                label="median CRLB" if i == 0 else None)
    a1.set_xticks(x, [str(b) for b in x])
    a1.set_xlabel("block")
    a1.set_ylabel("px")
    a1.set_title("tracker error vs CRLB per block")
    a1.legend(fontsize=7)
    for b in range(n_b):
        e = np.where(ok[:, b], err[:, b, 0], np.nan)
        a2.plot(tr["t"], e, lw=0.8, color=f"C{b % 10}", label=f"block {b}")
    rows_ok = ok.any(axis=1)
    band = np.nanmedian(np.where(ok[rows_ok], tr["crlb"][rows_ok, :, 0], np.nan),
                                axis=1) if rows_ok.any() else np.zeros(0)
    a2.fill_between(tr["t"][rows_ok], -band, band, color="0.85", label="±CRLB (row, median)")
    a2.set_xlabel("time (s)")
    a2.set_ylabel("row error (px)")
    a2.set_title("measured - true shift, rows (valid measurements)")
    a2.legend(fontsize=7, ncol=2)
    a2.grid(alpha=0.3)
    fig.tight_layout()
    return save(fig, Path(run_dir) / "fig_tracker.png")


def fig_frame(run_dir: Path, s: dict, tr: dict[str, np.ndarray]) -> Path | None:
    """The middle tracker frame with its blocks and each block's track (magnified)."""
    if "frame" not in s:
        return None
    from matplotlib.patches import Rectangle

    plt = _plt()
    img, b = s["frame"], float(s["block_px"])
    fig, ax = plt.subplots(figsize=(6, 6), dpi=110)
    ax.imshow(img, cmap="gray", interpolation="nearest")
    corners = s.get("frame_corners_px")
    centres = s["centers_px"][int(s["frame_index"])]
    mag = 0.25 * b / max(float(np.nanmax(np.abs(tr["meas"]))), 1e-6)
    for j, c in enumerate(centres):
        if corners is not None:
            r0, c0 = corners[j]
            ax.add_patch(Rectangle((c0 - 0.5, r0 - 0.5), b, b, fill=False, lw=1.2,
                                   color=f"C{j % 10}"))
        path = c + mag * np.where(tr["valid"][:, j, None], tr["meas"][:, j], np.nan)
        ax.plot(path[:, 1], path[:, 0], lw=1.0, color=f"C{j % 10}")
        ax.text(c[1], c[0] - 0.5 * b + 3, f"{j}", color=f"C{j % 10}", fontsize=8,
                ha="center", va="top")
    ax.set_title(f"tracker frame {int(s['frame_index'])}: blocks and their measured tracks "
                 f"(x{mag:.0f})", fontsize=9)
    fig.tight_layout()
    return save(fig, Path(run_dir) / "fig_frame.png")


def fig_main_imager(path: Path, picture: dict) -> Path:
    """main_imager.png: the rendered patches (static, open, closed loop), the worst
    exposure's residual PSF open and closed, and the slanted-edge MTF; ``picture`` from
    :func:`imc.wiring.blur.main_imager_study`."""
    plt = _plt()
    patches, nyquist = picture["patches"], picture["nyquist"]
    fig, axes = plt.subplots(2, 3, figsize=(10.5, 7.2), dpi=110)
    lo, hi = np.percentile(patches["static"], 1), np.percentile(patches["static"], 99)
    for ax, (name, img) in zip(axes[0], patches.items(), strict=True):
        ax.imshow(img, cmap="gray", vmin=lo, vmax=hi)
        ax.set_title(name)
        ax.axis("off")
    for ax, key in ((axes[1][0], "open"), (axes[1][1], "closed")):
        psf, bin_px = picture["psf"][key]
        half = 0.5 * psf.shape[0] * bin_px
        ax.imshow(psf, cmap="magma", extent=[-half, half, half, -half])
        ax.set_title(f"residual PSF, {key} loop", fontsize=9)
        ax.set_xlabel("col (px)")
        ax.set_ylabel("row (px)")
    ax = axes[1][2]
    for name, (f, mtf) in picture["curves"].items():
        ax.plot(f, mtf, label=f"{name} (edge)")
    ax.plot(*picture["predicted_open"], "k:", label="predicted, open loop")
    ax.axvline(nyquist, color="0.7", lw=0.8)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("cycles/px (across the edge: rows)")
    ax.set_title("slanted-edge MTF", fontsize=9)
    ax.legend(fontsize=7)
    fig.suptitle(picture["title"], fontsize=10)
    fig.tight_layout()
    return save(fig, Path(path))


def draw_run_figures(run_dir: Path, metrics: dict | None = None) -> list[Figure]:
    """The figures drawn from a run's data files (series.npz, blur.npz, tracks.csv), written
    into run_dir; ``metrics`` (default: metrics.json) needs ``main_imager_blur`` only."""
    run_dir = Path(run_dir)
    if metrics is None:
        metrics = _load(run_dir, "metrics.json") or {}
    s, rows, blur = (_load(run_dir, "series.npz"), _load(run_dir, "tracks.csv"),
                     _load(run_dir, "blur.npz"))
    figs: list[Figure] = []
    if s is not None:
        figs.append(Figure(fig_motion(run_dir, s), "Residual motion",
                           "True image motion at the main imager (open loop) and what the "
                           "stage leaves of it (closed loop), with the loop's estimate."))
        figs.append(Figure(fig_spectrum(run_dir, s), "Spectrum and rejection",
                           "Amplitude spectra of the motion open and closed; their ratio "
                           "beside the analytic rejection |S(f)| of the loop's model."))
    if blur is not None:
        figs.append(Figure(fig_psf(run_dir, blur, metrics), "Residual PSF",
                           "Where the image spends the worst main-imager exposure, open and "
                           "closed loop (blur.npz)."))
    if rows:
        tr = _tracks(rows)
        figs.append(Figure(fig_tracker(run_dir, tr), "Tracker error vs CRLB",
                           "Each block's error (measured - true shift) against its predicted "
                           "error, the Cramer-Rao bound."))
        if s is not None and (p := fig_frame(run_dir, s, tr)) is not None:
            figs.append(Figure(p, "Tracker frame", "The middle tracker frame, the blocks "
                               "and each block's measured track, magnified."))
    return figs


def run_figures(run_dir: Path, drawn: Sequence[Figure] | None = None) -> list[Figure]:
    """Every figure a run's files allow: ``drawn`` (what :func:`draw_run_figures` returned
    for this run) or those drawn now, then main_imager.png and the loop study's figure when
    they are there."""
    run_dir = Path(run_dir)
    figs = list(drawn) if drawn is not None else draw_run_figures(run_dir)
    if (run_dir / "main_imager.png").exists():
        figs.append(Figure(run_dir / "main_imager.png", "Main imager, rendered",
                           "The worst exposure rendered static, open and closed loop, and "
                           "the slanted-edge MTF (metrics.blur_images)."))
    if (run_dir / "loop" / "loop.png").exists():
        figs.append(Figure(run_dir / "loop" / "loop.png", "Loop rejection (sine sweep)",
                           "imc loop: analytic |S(f)| and a sine sweep on the analytic plant."))
    return figs


# ------------------------------------------------------------------------------ sweep figures


def _is_numeric(values) -> bool:
    try:
        np.asarray(values, dtype=float)
        return True
    except (TypeError, ValueError):
        return False


def _positions(values) -> tuple[np.ndarray, list[str] | None]:
    """Plot positions of an axis's values (the values, or 0..n-1 for categories)."""
    if _is_numeric(values):
        return np.asarray(values, dtype=float), None
    return np.arange(len(values), dtype=float), [str(v) for v in values]


def _log_axis(values) -> bool:
    """An axis whose positive values span a ratio of 20 or more reads best on a log scale."""
    if not _is_numeric(values):
        return False
    v = np.asarray(values, dtype=float)
    return bool(len(v) > 2 and np.all(v > 0) and v.max() / v.min() >= 20)


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def fig_sweep_line(out_dir: Path, ds, metric: str, axis: str, others: Sequence[str]) -> Path:
    """A metric against one axis: mean over seeds (and the other axes, one line per value of
    the first other axis when there is one), min-max shaded."""
    plt = _plt()
    da = ds[metric]
    x, labels = _positions(ds[axis].values)
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=110)
    group = others[0] if others else None
    series = ([(None, da)] if group is None else
              [(v, da.sel({group: v})) for v in ds[group].values])
    for i, (gv, d) in enumerate(series):
        rest = [dim for dim in d.dims if dim != axis]
        mean = d.mean(dim=rest, skipna=True).values if rest else d.values
        lo = d.min(dim=rest, skipna=True).values if rest else d.values
        hi = d.max(dim=rest, skipna=True).values if rest else d.values
        lab = f"{group} = {gv}" if group else "mean over seeds"
        ax.plot(x, mean, "o-", color=f"C{i % 10}", ms=4, lw=1.2, label=lab)
        ax.fill_between(x, lo, hi, color=f"C{i % 10}", alpha=0.15)
    if labels:
        ax.set_xticks(x, labels, rotation=20)
    elif _log_axis(ds[axis].values):
        ax.set_xscale("log")
    ax.set_xlabel(axis)
    ax.set_ylabel(metric)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, title="shaded: min-max over seeds"
              + (" and other axes" if len(others) > 1 else ""), title_fontsize=7)
    fig.tight_layout()
    return save(fig, Path(out_dir) / f"line_{_safe(metric)}__{_safe(axis)}.png")


def fig_sweep_heat(out_dir: Path, ds, metric: str, ax_y: str, ax_x: str,
                   facet: str | None) -> Path:
    """A metric over two axes as a heat map (mean over seeds and the remaining axes), one
    panel per value of ``facet`` when given."""
    plt = _plt()
    import matplotlib.colors

    da = ds[metric]
    facets = [None] if facet is None else list(ds[facet].values)
    n = len(facets)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols + 1.2, 3.6 * rows + 0.8),
                             dpi=110, squeeze=False, gridspec_kw={"hspace": 0.45, "wspace": 0.4})
    vmin, vmax = float(np.nanmin(da.values)), float(np.nanmax(da.values))
    if not np.isfinite(vmin):
        vmin, vmax = 0.0, 1.0
    # a positive metric over more than a decade (a ratio such as rms_reduction): log colours
    log = vmin > 0 and vmax / vmin > 10
    norm = (matplotlib.colors.LogNorm(vmin, vmax) if log
            else matplotlib.colors.Normalize(vmin, vmax))
    mid = np.sqrt(vmin * vmax) if log else 0.5 * (vmin + vmax)

    def short(dim: str) -> str:  # the field's last words: panels stay readable
        return ".".join([p for p in dim.split(".") if not p.isdigit()][-2:])

    im = None
    for i, fv in enumerate(facets):
        ax = axes[i // cols][i % cols]
        d = da if fv is None else da.sel({facet: fv})
        rest = [dim for dim in d.dims if dim not in (ax_y, ax_x)]
        grid = d.mean(dim=rest, skipna=True).transpose(ax_y, ax_x).values if rest else (
            d.transpose(ax_y, ax_x).values)
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", norm=norm,
                       interpolation="nearest")
        for (r, c), v in np.ndenumerate(grid):
            if np.isfinite(v):
                ax.text(c, r, f"{v:.3g}", ha="center", va="center", fontsize=6,
                        color="w" if v < mid else "k")
        ax.set_xticks(range(grid.shape[1]), [f"{v:.3g}" if _is_numeric([v]) else str(v)
                                             for v in ds[ax_x].values], fontsize=7,
                      rotation=30)
        ax.set_yticks(range(grid.shape[0]), [f"{v:.3g}" if _is_numeric([v]) else str(v)
                                             for v in ds[ax_y].values], fontsize=7)
        ax.set_xlabel(short(ax_x), fontsize=7)
        ax.set_ylabel(short(ax_y), fontsize=7)
        if fv is not None:
            ax.set_title(f"{short(facet)} = {fv:.3g}" if _is_numeric([fv])
                         else f"{short(facet)} = {fv}", fontsize=8)
    for j in range(n, rows * cols):
        axes[j // cols][j % cols].axis("off")
    fig.colorbar(im, ax=axes.ravel().tolist(), label=metric, shrink=0.9)
    fig.suptitle(f"{metric} (mean over seeds" + (" and other axes)" if len(
        [d for d in da.dims if d not in (ax_y, ax_x, facet, "seed")]) else ")")
        + f"\nrows: {ax_y}; columns: {ax_x}" + (f"; panels: {facet}" if facet else ""),
        fontsize=9)
    name = f"heat_{_safe(metric)}__{_safe(ax_y)}__{_safe(ax_x)}"
    return save(fig, Path(out_dir) / (name + (f"__by_{_safe(facet)}" if facet else "")
                                      + ".png"))


def sweep_figures(out_dir: Path, ds, metrics: Sequence[str]) -> list[Figure]:
    """Per metric: a line plot against each axis; with two axes or more, heat maps of the
    first two (one panel per value of the third when there is one)."""
    axes = [d for d in ds.dims if d not in ("seed", "point")]
    if "point" in ds.dims:  # zip: the axes run together along 'point'
        axes = ["point"]
    fig_dir = Path(out_dir) / "figures"
    figs: list[Figure] = []
    for metric in metrics:
        if metric not in ds or not np.isfinite(ds[metric].values).any():
            continue
        for a in axes:
            others = [o for o in axes if o != a]
            figs.append(Figure(fig_sweep_line(fig_dir, ds, metric, a, others),
                               f"{metric} vs {a}", "Mean over seeds"
                               + (f", one line per {others[0]}" if others else "")
                               + "; shaded: min to max."))
        if len(axes) >= 2:
            facet = axes[2] if len(axes) >= 3 else None
            figs.append(Figure(fig_sweep_heat(fig_dir, ds, metric, axes[0], axes[1], facet),
                               f"{metric} over {axes[0]} x {axes[1]}",
                               "Mean over seeds" + (f"; one panel per {facet}" if facet
                                                    else "") + "."))
    return figs

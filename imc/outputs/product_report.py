"""The main imager's product in a run's outputs: the quicklook (products side by side and the
per-line offsets), the report's quality and geometry tables, the Rerun recording's images and
offset series. Reads ``product/product.npz`` and metrics.json's ``product`` section
(:mod:`imc.outputs.product_files` writes them from :mod:`imc.wiring.product`'s result)."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from imc.io import atomic_write

#: the product quicklook's file in the run's product/ folder
QUICKLOOK = "quicklook.png"
#: the products shown side by side, in the order a reader compares them
SHOWN = ("static", "open", "closed", "open_gc", "closed_gc", "closed_gc_restored")
TITLES = {"static": "static", "open": "open loop", "closed": "closed loop (stage)",
          "open_gc": "open + ground correction (no stage)",
          "open_gc_restored": "open + ground correction + restoration",
          "closed_gc": "stage + ground correction",
          "closed_gc_restored": "stage + ground correction + restoration"}


def _load(run_dir: Path) -> dict[str, np.ndarray] | None:
    path = Path(run_dir) / "product" / "product.npz"
    if not path.exists():
        return None
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def quicklook_path(run_dir: Path) -> Path | None:
    """product/quicklook.png of a run folder, None when it is not there."""
    path = Path(run_dir) / "product" / QUICKLOOK
    return path if path.exists() else None


def quicklook_panels(run_dir: Path) -> dict[str, np.ndarray]:
    """The quicklook's panels as drawn: each shown product of the scene (a long strip: its
    middle square) on one 8-bit grey scale, the static product's 1-99 % range; {} without a
    product."""
    z = _load(run_dir)
    if z is None or "scene/static" not in z:  # no product, or a geometry-only one
        return {}
    static = z["scene/static"]
    h, w = static.shape
    rows = slice((h - w) // 2, (h + w) // 2) if h > 2 * w else slice(None)
    lo, hi = np.nanpercentile(static, [1, 99])
    scale = 255.0 / max(hi - lo, 1e-12)
    return {n: np.clip((np.nan_to_num(z[f"scene/{n}"][rows], nan=lo) - lo) * scale, 0,
                       255).astype(np.uint8) for n in SHOWN if f"scene/{n}" in z}


def write_quicklook(run_dir: Path) -> Path | None:
    """product/quicklook.png: the scene's products side by side (:func:`quicklook_panels`)
    over the per-line offsets, true and from the record."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = _load(run_dir)
    panels = quicklook_panels(run_dir)
    if z is None or not panels:
        return None
    side = 2.6  # inches a product
    aspect = next(iter(panels.values())).shape[0] / z["scene/static"].shape[1]
    fig = plt.figure(figsize=(side * len(panels), side * min(aspect, 2.0) + 2.6), dpi=100)
    grid = fig.add_gridspec(2, len(panels), height_ratios=[side * min(aspect, 2.0), 2.6])
    for i, (name, img) in enumerate(panels.items()):
        ax = fig.add_subplot(grid[0, i])
        ax.imshow(img, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        ax.set_title(TITLES.get(name, name), fontsize=8)
        ax.axis("off")
    kinds = [k for k in ("open", "closed") if f"offset/true/{k}" in z]
    bottom = grid[1, :].subgridspec(1, 2)
    for j, axis in enumerate(("row (along)", "col (across)")):
        ax = fig.add_subplot(bottom[0, j])
        for k in kinds:
            true, rec = z[f"offset/true/{k}"][:, j], z[f"offset/record/{k}"][:, j]
            ax.plot(true, label=f"{k}: true")
            ax.plot(rec, "--", label=f"{k}: from the record")
        ax.set_xlabel("line")
        ax.set_ylabel(f"{axis} offset (px)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    out = Path(run_dir) / "product" / QUICKLOOK
    atomic_write(out, lambda p: fig.savefig(p, format="png"), suffix=".png")
    plt.close(fig)
    return out


def _num(v, fmt: str = ".3g") -> str:
    if v is None:
        return "-"
    if isinstance(v, list | tuple):
        return " / ".join(_num(x, fmt) for x in v)
    return format(v, fmt) if np.isfinite(v) else "-"


def product_html(m: dict, table) -> str:
    """The report's section on the product (``table(header, rows)`` draws a table)."""
    p = m.get("product")
    if not p:
        return ""
    rows = []
    for name, q in p["quality"].items():
        rows.append((html.escape(TITLES.get(name, name)), _num(q["mtf_nyquist"]),
                     _num(q["rer"]), _num(q["overshoot_h"]), _num(q["noise_gain"]),
                     _num(q["snr"]), _num(q["niirs"], ".3f"), _num(q["niirs_loss"], ".3f"),
                     _num(q["psnr_db"]), _num(q["ssim"], ".4f")))
    quality = table(("product", "MTF @Nyquist along / across", "RER along / across",
                     "overshoot H", "noise gain", "SNR", "NIIRS (GIQE 5)", "NIIRS loss",
                     "PSNR dB", "SSIM"), rows)
    geo_rows = []
    for name, g in p["geometry"].items():
        for stage in ("before", "after", "after_perfect_record"):
            e = g[stage]
            geo_rows.append((f"{html.escape(name)}: {stage.replace('_', ' ')}",
                             _num(e["rms_px"]), _num(e["peak_to_peak_px"])))
    geometry = table(("lines' offset error", "RMS row / col (px)", "peak-to-peak (px)"),
                     geo_rows)
    head = (f"<p>{p['kind'].upper()} product, {p['lines']} x {p['cols']} px, {p['samples']} "
            f"samples per line, from {p['start_s']:.4g} s; {p['rays'] / 1e6:.1f} M rays, "
            f"hit fraction {p['hit_fraction']:.7f}, {p['rays_per_s'] / 1e6:.1f} M rays/s. "
            "Quality on the slanted-square target rendered through the same lines of sight; "
            "PSNR / SSIM against the static product on the scene. Geometry: each line's "
            "offset on the nominal grid against the camera model's truth, about its mean "
            "(ground control fixes the constant).</p>")
    quick = Path("product") / "quicklook.png"
    return ("<h2>The main imager's product</h2>" + head + quality
            + "<h3>Geometry (px)</h3>" + geometry + f"<p class='small'>{quick}</p>")


def log_product(rec, rr, run_dir: Path) -> bool:
    """The products as images (``product/<name>``) and each line's offsets as series
    (``product/offset/<axis>/<true | record>_<open | closed>``, by line index)."""
    z = _load(run_dir)
    if z is None or "scene/static" not in z:
        return False
    static = z["scene/static"]
    lo, hi = np.nanpercentile(static, [1, 99])
    for key, img in z.items():
        if key.startswith("scene/"):
            u8 = np.clip((np.nan_to_num(img, nan=lo) - lo) / max(hi - lo, 1e-12) * 255, 0, 255)
            rec.log(f"product/{key.split('/', 1)[1]}", rr.Image(u8.astype(np.uint8)),
                    static=True)
    lines = np.arange(len(z["line_t_s"]))
    for kind in ("open", "closed"):
        for src in ("true", "record"):
            key = f"offset/{src}/{kind}"
            if key not in z:
                continue
            for j, axis in enumerate(("row", "col")):
                rec.send_columns(f"product/offset/{axis}/{src}_{kind}",
                                 indexes=[rr.TimeColumn("line", sequence=lines)],
                                 columns=rr.Scalars.columns(scalars=z[key][:, j]))
    return True

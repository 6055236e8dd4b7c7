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
#: the quicklook where the difference shows: orthoimages, their differences, edge crops
DIFFERENCES = "differences.png"
#: the edge crop's side at full resolution, px
CROP_PX = 48
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


def difference_panels(run_dir: Path) -> dict:
    """What :data:`DIFFERENCES` draws, {} without orthoimages: ``ortho`` {version: the
    orthoimage}, ``diff`` {version: it less the static's, on the same map grid},
    ``scale_dn`` (the differences' common colour scale: the 99th percentile of their
    absolute values, 2 digits), ``crop`` {version: the target's edge at full resolution,
    :data:`CROP_PX` square, where the static's upper edge crosses its middle}, ``crop_box``
    (rows, cols) in the target image."""
    from imc.wiring.product import target_rois

    z = _load(run_dir)
    if z is None or "ortho/static" not in z:
        return {}
    names = [n for n in SHOWN if f"ortho/{n}" in z]
    static = z["ortho/static"]
    ortho = {n: z[f"ortho/{n}"] for n in names}
    diff = {n: ortho[n] - static for n in names if n != "static"}
    vals = np.concatenate([np.abs(d[np.isfinite(d)]) for d in diff.values()] or [np.zeros(1)])
    scale = float(f"{max(np.percentile(vals, 99), 1e-9):.2g}")
    target = z["target/static"]
    roi = target_rois(target)["along"]
    r = (roi[0].start + roi[0].stop) // 2
    c = (roi[1].start + roi[1].stop) // 2
    h = CROP_PX // 2
    box = (slice(max(r - h, 0), r + h), slice(max(c - h, 0), c + h))
    crop = {n: z[f"target/{n}"][box] for n in names if f"target/{n}" in z}
    return {"ortho": ortho, "diff": diff, "scale_dn": scale, "crop": crop, "crop_box": box}


def write_differences(run_dir: Path) -> Path | None:
    """product/differences.png, where the difference shows: each version's orthoimage (one
    grey scale, the static's 1-99 %), it less the static's on the same map grid (one
    diverging scale for all, stated), and the slanted-square target's edge at full
    resolution (:func:`difference_panels`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = difference_panels(run_dir)
    if not p:
        return None
    names = list(p["ortho"])
    lo, hi = np.nanpercentile(p["ortho"]["static"], [1, 99])
    clo, chi = np.nanpercentile(p["crop"]["static"], [1, 99]) if p["crop"] else (lo, hi)
    s = p["scale_dn"]
    fig, axes = plt.subplots(len(names), 3, figsize=(3 * 2.7, 2.7 * len(names)), dpi=100,
                             squeeze=False)
    for i, n in enumerate(names):
        a = axes[i]
        a[0].imshow(p["ortho"][n], cmap="gray", vmin=lo, vmax=hi, interpolation="nearest")
        a[0].set_title(f"{TITLES.get(n, n)}: ortho", fontsize=7)
        if n in p["diff"]:
            im = a[1].imshow(p["diff"][n], cmap="RdBu_r", vmin=-s, vmax=s,
                             interpolation="nearest")
            a[1].set_title(f"{n} - static, scale +-{s:g} DN", fontsize=7)
            fig.colorbar(im, ax=a[1], fraction=0.046, pad=0.02).ax.tick_params(labelsize=6)
        else:
            a[1].text(0.5, 0.5, "the reference", ha="center", va="center", fontsize=8)
        if n in p["crop"]:
            a[2].imshow(p["crop"][n], cmap="gray", vmin=clo, vmax=chi, interpolation="nearest")
            a[2].set_title(f"target edge, {CROP_PX} px at 1:1", fontsize=7)
        for ax in a:
            ax.axis("off")
    fig.suptitle(f"Orthoimages on one map grid, differences against the static "
                 f"(+-{s:g} DN), the target's edge at full resolution", fontsize=9)
    fig.tight_layout()
    out = Path(run_dir) / "product" / DIFFERENCES
    atomic_write(out, lambda q: fig.savefig(q, format="png"), suffix=".png")
    plt.close(fig)
    return out


def differences_path(run_dir: Path) -> Path | None:
    """product/differences.png of a run folder, None when it is not there."""
    path = Path(run_dir) / "product" / DIFFERENCES
    return path if path.exists() else None


def write_quicklook(run_dir: Path) -> Path | None:
    """product/quicklook.png: the scene's products side by side (:func:`quicklook_panels`)
    over the per-line offsets, true and from the record; and product/differences.png
    (:func:`write_differences`) when the product has orthoimages."""
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
    write_differences(run_dir)
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
            + "<h3>Geometry (px)</h3>" + geometry + geolocation_html(p, table)
            + f"<p class='small'>{quick}</p>")


def geolocation_html(p: dict, table) -> str:
    """The Level-1 section: the RPC fit, and per version CE90, mean, relative accuracy,
    misregistration against the static and the lines' offsets in metres ("" without)."""
    g = p.get("geolocation")
    if not g:
        return ""
    rows = []
    for name, v in g["versions"].items():
        fl = v.get("from_lines", {})
        rows.append((html.escape(TITLES.get(name, name)), _num(v["ce90_m"]),
                     _num(v["mean_m"]), _num(v["relative_rms_m"]), _num(v["relative_ce90_m"]),
                     _num(v.get("misregistration_m")), _num(fl.get("ce90_m"))))
    f = g["rpc_fit"]
    head = (f"<p>Each version's GeoTIFF carries RPC00B coefficients fitted to the geometry "
            f"the ground knows (nominal lines of sight; a corrected version: the corrected "
            f"grid) over {f['height_range_m'][0]:.0f} to {f['height_range_m'][1]:.0f} m above "
            f"the ellipsoid: fit error at independent points {_num(f['check_max_px'])} px "
            f"(max, line / sample). Orthorectified through GDAL's RPC transformer with the "
            f"scene's DEM (product/dem.tif) onto one {g['cell_m']:.3f} m grid (lines "
            f"{g['ortho_lines'][0]}-{g['ortho_lines'][1]}); {g['check_points']} check points, "
            "their true ground positions from the camera model. Errors east / north, m.</p>")
    return ("<h3>Geolocation (Level-1 product)</h3>" + head + table(
        ("product", "CE90 (m)", "mean (m)", "relative RMS (m)", "relative CE90 (m)",
         "misregistration vs static (m)", "CE90 from the lines' offsets (m)"), rows))


def log_product(rec, rr, run_dir: Path) -> bool:
    """The products as images (``product/<name>``), each line's offsets as series
    (``product/offset/<axis>/<true | record>_<open | closed>``, by line index), and where the
    difference shows (:func:`difference_panels`): ``product/ortho/<name>``,
    ``product/ortho_diff/<name>`` (grey 128 = no difference, 0 / 255 = -+ the scale stated in
    ``product/ortho_diff/scale``) and ``product/edge_crop/<name>``."""
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
    _log_differences(rec, rr, run_dir, lo, hi)
    return True


def _log_differences(rec, rr, run_dir: Path, lo: float, hi: float) -> None:
    p = difference_panels(run_dir)
    if not p:
        return

    def u8(img, a, b):
        return np.clip((np.nan_to_num(img, nan=a) - a) / max(b - a, 1e-12) * 255, 0,
                       255).astype(np.uint8)

    s = p["scale_dn"]
    for n, img in p["ortho"].items():
        rec.log(f"product/ortho/{n}", rr.Image(u8(img, lo, hi)), static=True)
    for n, d in p["diff"].items():
        rec.log(f"product/ortho_diff/{n}", rr.Image(u8(d, -s, s)), static=True)
    rec.log("product/ortho_diff/scale", rr.TextDocument(
        f"differences against the static orthoimage: grey 128 = 0, 0 = -{s:g} DN, "
        f"255 = +{s:g} DN"), static=True)
    clo, chi = np.nanpercentile(p["crop"]["static"], [1, 99]) if p["crop"] else (lo, hi)
    for n, c in p["crop"].items():
        rec.log(f"product/edge_crop/{n}", rr.Image(u8(c, clo, chi)), static=True)

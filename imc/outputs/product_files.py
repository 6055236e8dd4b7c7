"""The main imager's product written from its labelled result
(:func:`imc.wiring.product.product_dataset`): metrics.json's ``product`` section
(:func:`product_metrics`, every key as before, and ``geolocation``: the Level-1 figures), and
in ``product/`` the GeoTIFFs of the scene's products (each with its RPC00B coefficients),
``dem.tif`` (the scene's heights above the ellipsoid the RPCs are orthorectified with),
``lines.csv`` (each line's offsets) and ``product.npz`` (all arrays, the orthoimages too),
each written atomically (:func:`write_product`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from imc.io import atomic_write, write_csv, write_npz


def _value(v):
    """A Dataset value as JSON: NaN -> None, numpy scalars -> float, arrays -> lists."""
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 0:
        return None if not np.isfinite(a) else float(a)
    return [_value(x) for x in a]


def _geometry(ds: xr.Dataset, name: str) -> dict:
    g = ds.sel(moving=name)
    out = {}
    for stage in ds.stage.values:
        s = g.sel(stage=stage)
        out[str(stage)] = {"rms_px": _value(s.geometry_rms_px),
                           "peak_to_peak_px": _value(s.geometry_peak_to_peak_px),
                           "bias_px": _value(s.geometry_bias_px),
                           "max_abs_px": _value(s.geometry_max_abs_px),
                           "n": int(s.geometry_n)}
    out["ground_control_px"] = _value(g.ground_control_px)
    out["affine"] = {"rms_px": _value(g.geometry_affine_rms_px),
                     "perfect_record_rms_px": _value(g.geometry_affine_perfect_rms_px)}
    if name in ds.attrs.get("blend", {}):
        out["blend"] = ds.attrs["blend"][name]
    if np.all(np.isfinite(g.control_points_rms_px.values)):
        out["control_points"] = {"rms_px": _value(g.control_points_rms_px)}
    return out


def _quality(ds: xr.Dataset, name: str) -> dict:
    q = ds.sel(version=name)
    pairs = ("mtf_nyquist", "rer", "overshoot_h")
    out = {k: _value(q[k]) for k in pairs}
    out.update({k: _value(q[k]) for k in ("noise_sigma", "noise_gain", "snr", "niirs",
                                          "gsd_m", "elevation_rad", "psnr_db", "ssim",
                                          "niirs_loss")})
    return out


def restoration_gain(quality: dict) -> dict:
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


def _record(ds: xr.Dataset) -> dict:
    """The record's own error and, when the ground solved it, its predicted error and how."""
    a = ds.attrs
    out = {"rms_px": _value(ds.record_rms_px), "samples": int(a["record_samples"]),
           "rate_hz": float(a["record_rate_hz"])}
    if "predicted_constant_px" in ds:
        out["predicted"] = {"constant_px": _value(ds.predicted_constant_px),
                            "affine_px": _value(ds.predicted_affine_px)}
    if "restitution" in a:
        out["restitution"] = a["restitution"]
    return out


def product_metrics(ds: xr.Dataset, files: list[Path] | None = None) -> dict:
    """metrics.json's ``product`` section from the labelled result (the keys of earlier
    imcsim runs kept: expectations, sweeps and users' CI read them)."""
    a = ds.attrs
    render_s = float(a["render_s"])
    quality = ({str(n): _quality(ds, str(n)) for n in ds.version.values} if "image" in ds
               else {})
    return {
        "kind": a["kind"], "lines": int(a["lines"]), "cols": int(a["cols"]),
        "samples": int(a["samples"]), "start_s": float(a["start_s"]),
        "integration_s": float(a["integration_s"]), "line_rate_hz": a["line_rate_hz"],
        "gsd_m": _value(a["gsd_m"]), "rays": int(a["rays"]),
        "hit_fraction": float(a["hit_fraction"]), "scene_build_s": float(a["scene_build_s"]),
        "render_s": render_s, "rays_per_s": float(a["rays"] / max(render_s, 1e-9)),
        "ground_s": float(a["ground_s"]), "quality_s": float(a.get("quality_s", 0.0)),
        "record": _record(ds),
        "geometry": {str(n): _geometry(ds, str(n)) for n in ds.moving.values},
        "quality": quality,
        "restoration": restoration_gain(quality),
        "geolocation": _json(a.get("geolocation")),
        "files": [str(f) for f in (files or [])],
    }


def _json(v):
    """Nested figures as strict JSON: NaN and inf -> None, numpy numbers -> float."""
    if isinstance(v, dict):
        return {str(k): _json(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_json(x) for x in v]
    if isinstance(v, bool | str) or v is None:
        return v
    if isinstance(v, int | np.integer):
        return int(v)
    f = float(v)
    return f if np.isfinite(f) else None


def write_product(ds: xr.Dataset, folder: Path) -> list[Path]:
    """``folder``'s GeoTIFFs of the scene's products (a corrected one on the nominal grid
    displaced by its constant offset ``shift_px``, (row, col) px), lines.csv and
    product.npz; returns the paths written."""
    from affine import Affine

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    transform, crs = Affine(*ds.attrs["transform"]), ds.attrs["crs"]
    for name in ds.version.values if "image" in ds else ():
        base = str(name).split("_gc")[0]
        sh = (ds.shift_px.sel(moving=base).values if "_gc" in str(name)
              else np.zeros(2))
        path = folder / f"{name}.tif"
        _write_tif(path, ds.image.sel(version=name).values.astype(np.float32),
                   transform @ Affine.translation(float(sh[1]), float(sh[0])), crs,
                   ds.attrs.get("rpc", {}).get(str(name)))
        files.append(path)
    if "dem_m" in ds:  # the DEM the RPCs are orthorectified with: heights above the ellipsoid
        _write_tif(folder / "dem.tif", ds.dem_m.values, Affine(*ds.attrs["dem_transform"]),
                   ds.attrs["ortho_crs"])
        files.append(folder / "dem.tif")
    moving = [str(n) for n in ds.moving.values]
    header = ["line", "t_s"] + [f"{k}_{n}_{a}" for k in ("true", "record", "perfect")
                                for n in moving for a in ("row", "col")]
    cols = [np.arange(ds.sizes["line"]), ds.line_t_s.values]
    for src in ("true", "record", "perfect"):
        for n in moving:
            off = ds.offset_px.sel(source=src, moving=n).values
            cols += [off[:, 0], off[:, 1]]
    if "predicted_line_px" in ds:  # the record's predicted error per line (absolute)
        header += ["predicted_row", "predicted_col"]
        cols += [ds.predicted_line_px.values[:, 0], ds.predicted_line_px.values[:, 1]]
    write_csv(folder / "lines.csv", header, np.column_stack(cols).tolist())
    files.append(folder / "lines.csv")
    arrays = {}
    if "image" in ds:
        arrays = {f"scene/{n}": ds.image.sel(version=n).values for n in ds.version.values}
        arrays |= {f"target/{n}": ds.target_image.sel(version=n).values
                   for n in ds.version.values}
    for src in ("true", "record", "perfect"):
        arrays |= {f"offset/{src}/{n}": ds.offset_px.sel(source=src, moving=n).values
                   for n in moving}
    if "ortho" in ds:  # the orthoimages on one map grid, the check points' errors
        arrays |= {f"ortho/{n}": ds.ortho.sel(version=n).values for n in ds.version.values}
        arrays |= {f"check_error/{n}": ds.check_error_m.sel(version=n).values
                   for n in ds.version.values}
        arrays["check_xy_m"] = ds.check_xy_m.values
        arrays["ortho_transform"] = np.asarray(ds.attrs["ortho_transform"])
    write_npz(folder / "product.npz", **arrays, line_t_s=ds.line_t_s.values)
    files.append(folder / "product.npz")
    return files


def _write_tif(path: Path, img: np.ndarray, transform, crs: str, rpc: dict | None = None
               ) -> None:
    """A GeoTIFF (float, NaN nodata) on ``transform``; with ``rpc`` (GDAL's RPC keys) its
    RPC00B coefficients too (rasterio's ``dataset.rpcs``: GDAL writes the RPC tag)."""
    from rasterio.rpc import RPC

    from scene.geotiff import write_geotiff

    def write(tmp):
        write_geotiff(tmp, img, 0.0, 0.0, 1.0, 1.0, crs=crs, nodata=float("nan"),
                      transform=transform, rpcs=None if rpc is None else RPC.from_gdal(rpc))

    atomic_write(path, write)

"""GeoTIFFs in any CRS: written by rasterio here, read by rasterio, placed by pyproj.

The placement is checked end to end with ramp images whose pixel values are their own
column (or row) index: bilinear resampling reproduces a linear function exactly, so each
texel of the placed tile says which file position it was sampled from. That position,
through the file's affine and pyproj, must be the texel's own WGS84 position (its ENU centre
through imcsim's LocalFrame) within 1e-7 deg.
"""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS, Transformer

from orbit.frames import LocalFrame, ecef_to_geodetic
from scene.geotiff import GeoTiffError, place_geotiff, raster_shape, read_geotiff, write_geotiff

H, W = 160, 220

# (name, CRS as written, upper-left corner x0, y0, pixel size dx, dy, resampled?)
CASES = [
    ("utm_central_meridian", 32632, 499_950.0, 4_000_000.0, 0.5, 0.5, False),
    ("utm_zone_edge", 32632, 780_000.0, 4_000_000.0, 0.5, 0.5, True),
    ("geographic", 4326, 10.0, 35.0005, 4e-6, 4e-6, True),
    ("web_mercator", 3857, 1_113_194.9, 4_163_881.0, 0.6, 0.6, True),  # not conformal
    ("british_national_grid", 27700, 530_000.0, 180_000.0, 0.5, 0.5, True),
    ("lambert_wkt", CRS.from_proj4("+proj=lcc +lat_0=46 +lon_0=3 +lat_1=44 +lat_2=49 "
                                   "+x_0=700000 +y_0=6600000 +ellps=GRS80 +units=m "
                                   "+no_defs").to_wkt(),
     900_000.0, 6_500_000.0, 0.5, 0.5, True),
]


def _ramps(tmp_path, name, crs, x0, y0, dx, dy, **kw):
    """Two files: pixel value = (col + 1) / (W + 2) and (row + 1) / (H + 2)."""
    cols = np.broadcast_to((np.arange(W) + 1.0) / (W + 2), (H, W)).astype(np.float32)
    rows = np.broadcast_to(((np.arange(H) + 1.0) / (H + 2))[:, None], (H, W)).astype(np.float32)
    pc, pr = tmp_path / f"{name}_col.tif", tmp_path / f"{name}_row.tif"
    write_geotiff(pc, cols, x0, y0, dx, dy, crs=crs, **kw)
    write_geotiff(pr, rows, x0, y0, dx, dy, crs=crs, **kw)
    return pc, pr


def _sampled(pc, pr, dem_spacing_m=2.0):
    gc = place_geotiff(pc, None, dem_spacing_m)
    gr = place_geotiff(pr, None, dem_spacing_m)
    col = gc.terrain.albedo.astype(np.float64) * (W + 2) - 1.0
    row = gr.terrain.albedo.astype(np.float64) * (H + 2) - 1.0
    return gc, row, col


@pytest.mark.parametrize("name, crs, x0, y0, dx, dy, resampled", CASES, ids=[c[0] for c in CASES])
def test_every_texel_lands_where_pyproj_puts_it(tmp_path, name, crs, x0, y0, dx, dy, resampled):
    pc, pr = _ramps(tmp_path, name, crs, x0, y0, dx, dy)
    g, row, col = _sampled(pc, pr)
    assert g.resampled == resampled
    t = g.terrain
    to_geo = Transformer.from_crs(CRS.from_user_input(crs), CRS.from_epsg(4326),
                                  always_xy=True)
    # the centre: the file's centre (or, cropped, the crop's) through pyproj
    if resampled:
        cx, cy = x0 + W / 2 * dx, y0 - H / 2 * dy
    else:
        cx = x0 + (g.col0 + t.albedo.shape[1] / 2) * dx
        cy = y0 - (g.row0 + t.albedo.shape[0] / 2) * dy
    lon_c, lat_c = to_geo.transform(cx, cy)
    assert g.centre == pytest.approx((lat_c, lon_c), abs=1e-7)
    # every sampled texel, through the file's affine and pyproj, is the texel's own place
    rng = np.random.default_rng(0)
    ny, nx = t.albedo.shape
    ii, jj = rng.integers(0, ny, 200), rng.integers(0, nx, 200)
    ii[:4], jj[:4] = [0, 0, ny - 1, ny - 1], [0, nx - 1, 0, nx - 1]
    x = x0 + (col[ii, jj] + 0.5) * dx
    y = y0 - (row[ii, jj] + 0.5) * dy
    lon_f, lat_f = to_geo.transform(x, y)
    e = (jj + 0.5 - nx / 2) * t.texel_m
    n = (ny / 2 - ii - 0.5) * t.texel_m
    frame = LocalFrame(*g.centre)
    lat_t, lon_t, _ = ecef_to_geodetic(frame.enu_to_ecef(np.stack([e, n, 0 * e], -1)))
    assert np.abs(lat_t - lat_f).max() < 1e-7
    assert np.abs(lon_t - lon_f).max() < 1e-7
    # square texels of the pixel's ground area; most of the image kept
    assert t.albedo.shape[0] >= 0.85 * H and t.albedo.shape[1] >= 0.85 * W


def test_grid_convergence_and_scale_factor_are_applied(tmp_path):
    """At a UTM zone's edge the grid turns by ~1.8 deg against true north and map metres are
    1.0006 ground metres: the placed tile's columns of constant file column turn by pyproj's
    convergence, and its texel is the pixel divided by pyproj's scale factor."""
    pc, pr = _ramps(tmp_path, "edge", 32632, 780_000.0, 4_000_000.0, 0.5, 0.5)
    g, row, col = _sampled(pc, pr)
    f = g.factors
    assert 1.5 < f["convergence_deg"] < 2.2 and f["meridional_scale"] > 1.0005
    # file column as a plane over the tile: its gradient points along grid east
    ny, nx = col.shape
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    a = np.linalg.lstsq(np.c_[jj.ravel(), -ii.ravel(), np.ones(jj.size)], col.ravel(),
                        rcond=None)[0]
    grid_east_deg = np.degrees(np.arctan2(a[1], a[0]))  # north of true east
    assert -grid_east_deg == pytest.approx(f["convergence_deg"], abs=2e-3)
    assert g.terrain.texel_m == pytest.approx(0.5 / f["meridional_scale"], rel=2e-5)
    assert np.hypot(a[0], a[1]) == pytest.approx(1.0, rel=2e-5)  # one file column a texel


@pytest.mark.parametrize("dtype", ["uint8", "uint16", "int16", "float32", "float64"])
def test_tiled_compressed_any_dtype_with_nodata_and_overviews(tmp_path, dtype):
    rng = np.random.default_rng(1)
    info = np.iinfo(dtype) if np.dtype(dtype).kind in "ui" else None
    top = float(info.max) if info else 1.0
    img = (rng.random((600, 700)) * 0.8 * top + 0.1 * top).astype(dtype)
    p = tmp_path / f"t_{dtype}.tif"
    write_geotiff(p, img, 500_000.0, 4_000_000.0, 0.5, 0.5, nodata=0, tiled=True,
                  compress="deflate", overviews=(2, 4))
    assert raster_shape(p) == (600, 700)
    r = read_geotiff(p)
    assert r.dtype == dtype and np.allclose(r.data, img.astype(np.float64))
    t, centre = place_geotiff(p, None, 2.0).terrain, None
    assert np.allclose(t.albedo, np.clip(img.astype(np.float64) / top, 0, 1)[:t.albedo.shape[0],
                       :t.albedo.shape[1]], atol=1e-6)
    # a decimated read (imc validate) uses the overviews: same extent, 4x the pixel
    small = place_geotiff(p, None, 2.0, max_side=200)
    assert small.terrain.texel_m == pytest.approx(4 * t.texel_m, rel=1e-6)
    assert small.centre == pytest.approx(place_geotiff(p, None, 2.0).centre, abs=1e-7)
    del centre
    # a nodata pixel under the tile is masked, filled with the image's mean and noted (the
    # run refuses it only where the tracker looks: tests/test_geotiff_inputs.py)
    img2 = img.copy()
    img2[300, 350] = 0
    write_geotiff(p, img2, 500_000.0, 4_000_000.0, 0.5, 0.5, nodata=0, tiled=True,
                  compress="lzw")
    t2 = place_geotiff(p, None, 2.0).terrain
    assert t2.nodata_albedo.sum() == 1 and t2.nodata_albedo[300, 350]
    assert t2.albedo[300, 350] == pytest.approx(t2.albedo[~t2.nodata_albedo].mean(), rel=1e-3)
    assert len(t2.notes) == 1 and "1 nodata texels" in t2.notes[0]


def test_rgba_bands_are_averaged_and_alpha_is_a_hole(tmp_path):
    rng = np.random.default_rng(2)
    rgb = (rng.random((3, 64, 64)) * 200 + 20).astype(np.uint8)
    alpha = np.full((1, 64, 64), 255, np.uint8)
    p = tmp_path / "rgba.tif"
    import rasterio
    from affine import Affine
    from rasterio.enums import ColorInterp

    with rasterio.open(p, "w", driver="GTiff", height=64, width=64, count=4, dtype="uint8",
                       crs="EPSG:32632", transform=Affine(0.5, 0, 5e5, 0, -0.5, 4e6)) as ds:
        ds.write(np.concatenate([rgb, alpha]))
        ds.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue,
                          ColorInterp.alpha]
    r = read_geotiff(p)
    assert np.allclose(r.data, rgb.astype(np.float64).mean(axis=0))
    with rasterio.open(p, "r+") as ds:
        alpha[0, 10, 20] = 0
        ds.write(alpha[0], 4)
    assert np.isnan(read_geotiff(p).data[10, 20]) and np.isnan(read_geotiff(p).data).sum() == 1


def test_dem_in_another_crs_is_sampled_where_pyproj_puts_it(tmp_path):
    """Orthophoto in UTM 32N, DEM in lat/lon with height = 1000 m x (lon - 12): every DEM
    node's height gives its longitude back (pyproj's answer for the node's place)."""
    pc, _ = _ramps(tmp_path, "o", 32632, 780_000.0, 4_000_000.0, 0.5, 0.5)
    g0 = place_geotiff(pc, None, 2.0)
    lat0, lon0 = g0.centre
    lons = lon0 - 0.01 + (np.arange(400) + 0.5) * 5e-5
    dem = np.broadcast_to(1000.0 * (lons - 12.0), (400, 400)).astype(np.float64)
    write_geotiff(tmp_path / "dem.tif", dem, lon0 - 0.01, lat0 + 0.01, 5e-5, 5e-5, crs=4326)
    g = place_geotiff(pc, tmp_path / "dem.tif", 2.0)
    t = g.terrain
    my, mx = t.dem_m.shape
    e = np.arange(mx) * t.dem_spacing_m - t.size_m[0] / 2
    n = t.size_m[1] / 2 - np.arange(my) * t.dem_spacing_m
    ee, nn = np.meshgrid(e, n)
    frame = LocalFrame(*g.centre)
    _, lon, _ = ecef_to_geodetic(frame.enu_to_ecef(np.stack([ee, nn, 0 * ee], -1)))
    assert np.abs(t.dem_m - 1000.0 * (lon - 12.0)).max() < 1e-4  # 1e-7 deg of longitude


@pytest.mark.parametrize("y0, words", [(95.0, "not on the Earth"), (89.9, r"within \+-89 deg")])
def test_a_file_off_the_earth_is_named(tmp_path, y0, words):
    img = np.full((32, 32), 100, np.uint8)
    write_geotiff(tmp_path / "g.tif", img, 10.0, y0, 1e-5, 1e-5, crs=4326)
    with pytest.raises(GeoTiffError, match=words) as e:
        place_geotiff(tmp_path / "g.tif", None, 2.0)
    assert "pixel" not in str(e.value).split(":", 1)[1][:40] and "\n" not in str(e.value)


def test_unusable_files_and_paths_are_one_line(tmp_path):
    long = tmp_path / ("x" * 5000 + ".tif")
    with pytest.raises(GeoTiffError, match="cannot use this path") as e:
        place_geotiff(long, None, 2.0)
    assert len(str(e.value)) < 400
    (tmp_path / "d").mkdir()
    with pytest.raises(GeoTiffError, match="not a file"):
        place_geotiff(tmp_path / "d", None, 2.0)
    (tmp_path / "trunc.tif").write_bytes(b"II*\x00" + b"\x00" * 20)
    with pytest.raises(GeoTiffError, match="cannot read it as a TIFF"):
        place_geotiff(tmp_path / "trunc.tif", None, 2.0)
    import rasterio
    from affine import Affine

    with rasterio.open(tmp_path / "nocrs.tif", "w", driver="GTiff", height=32, width=32,
                       count=1, dtype="uint8", transform=Affine(1, 0, 100, 0, -1, 900)) as ds:
        ds.write(np.ones((1, 32, 32), np.uint8))
    with pytest.raises(GeoTiffError, match="no CRS"):
        place_geotiff(tmp_path / "nocrs.tif", None, 2.0)


@pytest.mark.parametrize("dtype", [bool, np.float16])
def test_write_geotiff_refuses_a_dtype_gdal_cannot_store(tmp_path, dtype):
    from scene.geotiff import write_geotiff

    with pytest.raises(ValueError, match=f"dtype {np.dtype(dtype)}"):
        write_geotiff(tmp_path / "m.tif", np.zeros((4, 4), dtype), 0.0, 4.0, 1.0, 1.0)

"""User terrain from GeoTIFFs: an orthophoto (albedo) and an optional DEM. Pure numpy.

The orthophoto's georeferencing (ModelPixelScale + ModelTiepoint, north-up) fixes the tile:
its pixel size is the texel size, its centre the ENU origin. WGS84 / UTM files (EPSG
326zz north, 327zz south) are placed at their own centre (the inverse transverse Mercator,
Krueger's series) and their map metres become ground metres (the grid's scale factor,
0.9996-1.0010, measured with GeographicLib geodesics); the grid's convergence (up to ~2 deg
at a zone edge at mid latitudes) is not applied: the tile's grid north is taken as north.
Other projected CRSs (metres) are used as they are and placed at the scenario's
``scene.center_lat_deg/lon_deg``. Geographic CRSs (degrees) are converted to metres at the
tile centre (WGS84 radii of curvature), and the centre comes from the file. The DEM (any
pixel size, same CRS) is sampled bilinearly onto the tile's node grid; it must cover the
orthophoto and have no holes there.

Every problem raises :class:`GeoTiffError` with a one-line message that names the file and
the fix.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from geographiclib.geodesic import Geodesic
from scipy import ndimage

from scene.terrain import Terrain

_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3
_WGS84_F = 1.0 / 298.257223563
_UTM_K0 = 0.9996


def utm_zone(epsg: int | None) -> tuple[int, bool] | None:
    """(zone, southern) of a WGS84 / UTM EPSG code (32601-32660, 32701-32760), else None."""
    if epsg is not None and (32601 <= epsg <= 32660 or 32701 <= epsg <= 32760):
        return epsg % 100, epsg >= 32701
    return None


def utm_to_geodetic(zone: int, southern: bool, easting_m, northing_m):
    """Latitude and longitude (deg) of UTM coordinates (m), WGS84.

    Krueger's series to third order in n (accurate to a few mm within a zone), as given by
    Karney, "Transverse Mercator with an accuracy of a few nanometers", J. Geod. 85 (2011).
    """
    n = _WGS84_F / (2.0 - _WGS84_F)
    big_a = _WGS84_A / (1.0 + n) * (1.0 + n**2 / 4.0 + n**4 / 64.0)
    beta = (n / 2.0 - 2.0 * n**2 / 3.0 + 37.0 * n**3 / 96.0,
            n**2 / 48.0 + n**3 / 15.0,
            17.0 * n**3 / 480.0)
    delta = (2.0 * n - 2.0 * n**2 / 3.0 - 2.0 * n**3,
             7.0 * n**2 / 3.0 - 8.0 * n**3 / 5.0,
             56.0 * n**3 / 15.0)
    xi = (np.asarray(northing_m, np.float64) - (1e7 if southern else 0.0)) / (_UTM_K0 * big_a)
    eta = (np.asarray(easting_m, np.float64) - 5e5) / (_UTM_K0 * big_a)
    xi1, eta1 = xi.copy(), eta.copy()
    for j, b in enumerate(beta, start=1):
        xi1 = xi1 - b * np.sin(2 * j * xi) * np.cosh(2 * j * eta)
        eta1 = eta1 - b * np.cos(2 * j * xi) * np.sinh(2 * j * eta)
    chi = np.arcsin(np.sin(xi1) / np.cosh(eta1))
    lat = chi + sum(d * np.sin(2 * j * chi) for j, d in enumerate(delta, start=1))
    lon0 = 6.0 * zone - 183.0
    lon = lon0 + np.degrees(np.arctan2(np.sinh(eta1), np.cos(xi1)))
    return np.degrees(lat), lon


def utm_ground_scale(zone: int, southern: bool, easting_m: float, northing_m: float,
                     step_m: float = 1000.0) -> float:
    """Ground metres per UTM map metre at a point (1 / the grid scale factor), from the
    geodesic lengths of map steps east and north."""
    lat0, lon0 = utm_to_geodetic(zone, southern, easting_m, northing_m)
    out = []
    for de, dn in ((step_m, 0.0), (0.0, step_m)):
        lat1, lon1 = utm_to_geodetic(zone, southern, easting_m + de, northing_m + dn)
        out.append(Geodesic.WGS84.Inverse(float(lat0), float(lon0), float(lat1),
                                          float(lon1))["s12"] / step_m)
    return float(np.mean(out))


class GeoTiffError(ValueError):
    """A GeoTIFF that cannot be used as imcsim terrain."""


@dataclass(frozen=True)
class GeoRaster:
    """One band (H, W) float64 with a north-up affine georeference.

    ``x0, y0``: map coordinates of the outer upper-left corner of pixel (0, 0); ``dx, dy``:
    pixel size (> 0; rows run toward -y). ``geographic``: coordinates in degrees (lon, lat).
    ``dtype``: the file's pixel type (before conversion to float64).
    """

    data: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float
    geographic: bool
    crs: int | None
    path: str
    dtype: str

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the outer pixel edges, map units."""
        h, w = self.data.shape
        return self.x0, self.x0 + w * self.dx, self.y0 - h * self.dy, self.y0

    def pixel_of(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) of map points, pixel centres at integers."""
        return (self.y0 - y) / self.dy - 0.5, (x - self.x0) / self.dx - 0.5


def _geokeys(meta: dict) -> tuple[bool, int | None]:
    model = meta.get("GTModelTypeGeoKey")
    model = getattr(model, "value", model)
    proj = meta.get("ProjectedCSTypeGeoKey")
    geog = meta.get("GeographicTypeGeoKey")
    proj = getattr(proj, "value", proj)
    geog = getattr(geog, "value", geog)
    geographic = model == 2 or (model is None and proj is None and geog is not None)
    crs = geog if geographic else proj
    return geographic, (int(crs) if crs is not None else None)


def read_geotiff(path: str | Path, what: str = "GeoTIFF") -> GeoRaster:
    """Read the first image of a GeoTIFF: one band (RGB averaged), nodata as NaN."""
    import tifffile

    p = Path(path)
    if not p.is_file():
        raise GeoTiffError(f"{what} {p}: file not found")
    try:
        with tifffile.TiffFile(p) as tif:
            page = tif.pages.first
            data = page.asarray()
            meta = tif.geotiff_metadata or {}
            nodata = page.tags.get("GDAL_NODATA")
            nodata = nodata.value if nodata is not None else None
    except Exception as e:  # tifffile raises many types for corrupt files
        raise GeoTiffError(f"{what} {p}: cannot read it as a TIFF ({e.__class__.__name__}: "
                           f"{e}); write it with GDAL or tifffile") from None
    if "ModelTransformation" in meta:
        m = np.asarray(meta["ModelTransformation"], float).reshape(4, 4)
        if abs(m[0, 1]) > 0 or abs(m[1, 0]) > 0:
            raise GeoTiffError(f"{what} {p}: rotated or sheared rasters are not supported; "
                               "warp it north-up (gdalwarp)")
        scale, tie = (m[0, 0], -m[1, 1], 0.0), (0.0, 0.0, 0.0, m[0, 3], m[1, 3], 0.0)
    elif "ModelPixelScale" in meta and "ModelTiepoint" in meta:
        scale, tie = meta["ModelPixelScale"], meta["ModelTiepoint"]
    else:
        raise GeoTiffError(f"{what} {p}: no georeferencing (ModelPixelScale + ModelTiepoint "
                           "tags); export it as a GeoTIFF")
    dx, dy = float(scale[0]), float(scale[1])
    if not (dx > 0 and dy > 0):
        raise GeoTiffError(f"{what} {p}: pixel scale ({dx}, {dy}) must be positive (north-up)")
    data = np.asarray(data)
    file_dtype = str(data.dtype)  # before RGB averaging turns it into float
    if data.ndim == 3:
        bands_last = data.shape[-1] <= 4
        data = data.mean(axis=-1 if bands_last else 0)
    if data.ndim != 2:
        raise GeoTiffError(f"{what} {p}: expected a 2-D single-band or RGB image, got shape "
                           f"{data.shape}")
    raw = data
    data = data.astype(np.float64)
    if nodata is not None:
        try:
            data[raw == float(str(nodata).strip())] = np.nan
        except ValueError:
            pass
    i, j = float(tie[0]), float(tie[1])
    x0, y0 = float(tie[3]) - i * dx, float(tie[4]) + j * dy
    pixel_is_point = meta.get("GTRasterTypeGeoKey")
    if getattr(pixel_is_point, "value", pixel_is_point) == 2:  # RasterPixelIsPoint
        x0, y0 = x0 - dx / 2.0, y0 + dy / 2.0
    geographic, crs = _geokeys(meta)
    return GeoRaster(data, x0, y0, dx, dy, geographic, crs, str(p), file_dtype)


def _holes(data: np.ndarray, row0: int = 0, col0: int = 0) -> str | None:
    bad = ~np.isfinite(data)
    if not bad.any():
        return None
    r, c = np.argwhere(bad)[0]
    return f"{int(bad.sum())} NaN / nodata pixels (first at row {r + row0}, col {c + col0})"


def terrain_from_geotiff(ortho_path: str | Path, dem_path: str | Path | None,
                         dem_spacing_m: float, albedo_scale: float | None = None
                         ) -> tuple[Terrain, tuple[float, float] | None]:
    """Terrain from an orthophoto and an optional DEM; and (lat, lon) of its centre if known.

    The orthophoto is cropped (centred) to a whole number of DEM cells of ``dem_spacing_m``
    (rounded to whole texels). ``albedo_scale`` multiplies the pixel values (default: 1 for
    float images, 1 / the dtype's maximum for integer images); the result is clipped to [0, 1].
    """
    ortho = read_geotiff(ortho_path, "scene.geotiff.ortho")
    where = _holes(ortho.data)
    if where:
        raise GeoTiffError(f"scene.geotiff.ortho {ortho.path}: {where}; fill them "
                           "(gdal_fillnodata.py) or crop the image")
    lat0 = lon0 = None
    x_c = ortho.x0 + ortho.data.shape[1] * ortho.dx / 2.0
    y_c = ortho.y0 - ortho.data.shape[0] * ortho.dy / 2.0
    if ortho.geographic:
        lon0, lat0 = x_c, y_c
        s = np.sin(np.deg2rad(lat0))
        n_rad = _WGS84_A / np.sqrt(1 - _WGS84_E2 * s * s)
        m_rad = _WGS84_A * (1 - _WGS84_E2) / (1 - _WGS84_E2 * s * s) ** 1.5
        sx = np.deg2rad(1.0) * n_rad * np.cos(np.deg2rad(lat0))  # metres per degree east
        sy = np.deg2rad(1.0) * m_rad
    elif (zone := utm_zone(ortho.crs)) is not None:
        lat0, lon0 = (float(v) for v in utm_to_geodetic(*zone, x_c, y_c))
        sx = sy = utm_ground_scale(*zone, x_c, y_c)
    else:
        sx = sy = 1.0
    tx, ty = ortho.dx * sx, ortho.dy * sy
    if abs(tx - ty) > 0.01 * max(tx, ty):
        raise GeoTiffError(f"scene.geotiff.ortho {ortho.path}: pixels are {tx:.3f} x {ty:.3f} m;"
                           " resample to square pixels (gdalwarp -tr)")
    texel_m = float(np.sqrt(tx * ty))
    step = max(1, int(round(dem_spacing_m / texel_m)))
    h, w = ortho.data.shape
    nh, nw = (h // step) * step, (w // step) * step
    if nh < 2 * step or nw < 2 * step or nh < 16 or nw < 16:
        raise GeoTiffError(f"scene.geotiff.ortho {ortho.path}: {h} x {w} px is smaller than 2 "
                           f"DEM cells of {dem_spacing_m} m; lower scene.dem_spacing_m")
    r0, c0 = (h - nh) // 2, (w - nw) // 2
    img = ortho.data[r0:r0 + nh, c0:c0 + nw]
    if albedo_scale is None:
        raw_dtype = np.dtype(ortho.dtype)
        albedo_scale = 1.0 / np.iinfo(raw_dtype).max if raw_dtype.kind in "ui" else 1.0
    albedo = np.clip(img * albedo_scale, 0.0, 1.0).astype(np.float32)
    if albedo.max() <= 0.0:
        raise GeoTiffError(f"scene.geotiff.ortho {ortho.path}: the image is black after "
                           "scaling; check scene.geotiff.albedo_scale")
    spacing = step * texel_m
    my, mx = nh // step + 1, nw // step + 1
    if dem_path is None:
        return (Terrain(albedo, texel_m, np.zeros((my, mx), np.float32), spacing),
                None if lat0 is None else (lat0, lon0))
    dem = read_geotiff(dem_path, "scene.geotiff.dem")
    if dem.geographic != ortho.geographic or (
            dem.crs is not None and ortho.crs is not None and dem.crs != ortho.crs):
        raise GeoTiffError(f"scene.geotiff.dem {dem.path}: CRS {dem.crs} differs from the "
                           f"orthophoto's {ortho.crs}; reproject it (gdalwarp -t_srs)")
    # node map coordinates: the cropped tile's outer edges are the outer nodes
    xs = ortho.x0 + (c0 + np.arange(mx) * step) * ortho.dx
    ys = ortho.y0 - (r0 + np.arange(my) * step) * ortho.dy
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    rr, cc = dem.pixel_of(xx, yy)
    dh, dw = dem.data.shape
    tol = 0.5 + 1e-6
    if rr.min() < -tol or cc.min() < -tol or rr.max() > dh - 1 + tol or cc.max() > dw - 1 + tol:
        ex = dem.extent
        raise GeoTiffError(
            f"scene.geotiff.dem {dem.path}: its extent x {ex[0]:.6g}..{ex[1]:.6g}, y "
            f"{ex[2]:.6g}..{ex[3]:.6g} does not cover the orthophoto's x {xs[0]:.6g}.."
            f"{xs[-1]:.6g}, y {ys[-1]:.6g}..{ys[0]:.6g}; use a DEM that covers it")
    rr, cc = np.clip(rr, 0, dh - 1), np.clip(cc, 0, dw - 1)
    r_lo, r_hi = int(np.floor(rr.min())), int(np.ceil(rr.max())) + 1
    c_lo, c_hi = int(np.floor(cc.min())), int(np.ceil(cc.max())) + 1
    where = _holes(dem.data[r_lo:r_hi, c_lo:c_hi], r_lo, c_lo)
    if where:
        raise GeoTiffError(f"scene.geotiff.dem {dem.path}: {where} under the orthophoto; fill "
                           "them (gdal_fillnodata.py)")
    z = ndimage.map_coordinates(dem.data, [rr, cc], order=1, mode="nearest")
    return (Terrain(albedo, texel_m, z.astype(np.float32), spacing),
            None if lat0 is None else (lat0, lon0))


def write_geotiff(path: str | Path, data: np.ndarray, x0: float, y0: float, dx: float,
                  dy: float, crs: int = 32632, geographic: bool = False,
                  nodata: float | None = None) -> None:
    """Write a north-up single-band GeoTIFF (for examples and tests; GDAL reads it).

    ``x0, y0``: upper-left outer corner; ``dx, dy`` > 0 pixel size in map units; ``crs`` an
    EPSG code (projected, or geographic with ``geographic=True``).
    """
    import tifffile

    model, key = (2, 2048) if geographic else (1, 3072)
    keys = [1, 1, 0, 3, 1024, 0, 1, model, 1025, 0, 1, 1, key, 0, 1, int(crs)]
    extratags = [
        (33550, "d", 3, (float(dx), float(dy), 0.0), False),
        (33922, "d", 6, (0.0, 0.0, 0.0, float(x0), float(y0), 0.0), False),
        (34735, "H", len(keys), keys, False),
    ]
    if nodata is not None:
        extratags.append((42113, "s", 0, f"{nodata:g}", False))
    tifffile.imwrite(path, np.asarray(data), extratags=extratags)

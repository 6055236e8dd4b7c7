"""User terrain from GeoTIFFs: an orthophoto (albedo) and an optional DEM, in any CRS.

Files are read with rasterio (GDAL): tiled or striped, compressed, any real dtype, several
bands (one picked, or averaged; an alpha band and nodata become holes), internal masks, overviews (a
decimated read for ``imc validate``). They are placed with pyproj: any CRS with an EPSG
code or a WKT definition (projected or geographic, any datum PROJ can relate to WGS84).

Placement: the tile's centre is the orthophoto's centre (pyproj: map coordinates to WGS84
latitude and longitude), the origin of imcsim's local ENU frame (orbit.frames.LocalFrame).
Every ENU point maps exactly to the file: ENU -> ECEF -> WGS84 (orbit.frames) -> the file's
CRS (pyproj) -> pixel (the file's affine transform). So the grid convergence (the angle
between the file's grid north and true north, up to a few degrees at a UTM zone's edge),
the grid's scale factor (UTM 0.9996-1.001; Web Mercator 1 / cos(lat)) and pixels that are
not square on the ground (a lat/lon grid) are applied. When the simple placement (rows
along north, one texel size) is within 0.01 px of the exact one over the whole image the
pixels are used as they are; otherwise the image is resampled (bilinear) onto a north-up
ENU grid of square texels with the pixel's ground area, inside the image's footprint. The
DEM (any CRS, any pixel size) is sampled bilinearly at the tile's DEM nodes the same way; it
must cover the orthophoto: up to one DEM pixel short is edge-extended with a note (real DEMs
and orthos routinely differ by a pixel at their edges), more is refused. Holes (nodata) in
either file are filled, masked on the terrain and noted; the run refuses them where the
tracker looks (:func:`nodata_in_view`). The tile is a plane tangent at the centre
(Earth curvature, 8 cm at 1 km, is not modelled; neither are vertical datums: DEM values
are heights in m).

Every problem raises :class:`GeoTiffError` with a one-line message that names the file and
the fix.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orbit.frames import LocalFrame, ecef_to_geodetic, geodetic_to_ecef
from scene.terrain import Terrain

#: largest deviation (px) of the simple placement for which the pixels are used as they are
EXACT_TOLERANCE_PX = 0.01
#: ENU -> pixel is computed exactly every this many texels and interpolated in between
_COARSE = 32


class GeoTiffError(ValueError):
    """A GeoTIFF that cannot be used as imcsim terrain."""


def _name(path) -> str:
    text = str(path)
    return text if len(text) <= 160 else f"{text[:70]} ... {text[-70:]}"


@dataclass(frozen=True)
class GeoRaster:
    """One band (H, W) float64 (NaN: nodata) with its georeference.

    ``transform``: the affine (rasterio/affine) from (col, row) of pixel edges to map x, y;
    ``crs``: a pyproj CRS; ``dtype``: the file's pixel type; ``decimation``: 1, or the
    factor of a reduced read (overviews).
    """

    data: np.ndarray
    transform: object
    crs: object
    path: str
    dtype: str
    decimation: int = 1

    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape

    def _matrix(self) -> tuple[np.ndarray, np.ndarray]:
        a, b, c, d, e, f = tuple(self.transform)[:6]
        return np.array([[a, b], [d, e]], np.float64), np.array([c, f], np.float64)

    def pixel_of(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) array indices of map points, pixel centres at integers."""
        m, t = self._matrix()
        inv = np.linalg.inv(m)
        dx, dy = np.asarray(x, np.float64) - t[0], np.asarray(y, np.float64) - t[1]
        col = inv[0, 0] * dx + inv[0, 1] * dy
        row = inv[1, 0] * dx + inv[1, 1] * dy
        return row - 0.5, col - 0.5

    def map_of(self, row: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map (x, y) of fractional array indices (pixel centres at integers)."""
        m, t = self._matrix()
        c, r = np.asarray(col, np.float64) + 0.5, np.asarray(row, np.float64) + 0.5
        return m[0, 0] * c + m[0, 1] * r + t[0], m[1, 0] * c + m[1, 1] * r + t[1]


def _open(path, what: str):
    """rasterio dataset of path; GeoTiffError naming it if it cannot be opened."""
    import rasterio
    from rasterio.errors import RasterioError

    p = Path(path)
    try:
        if not p.is_file():
            raise GeoTiffError(f"{what} {_name(p)}: file not found" if not p.exists() else
                               f"{what} {_name(p)}: not a file")
    except (OSError, ValueError) as e:
        raise GeoTiffError(f"{what} {_name(p)}: cannot use this path "
                           f"({getattr(e, 'strerror', None) or e})") from None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return rasterio.open(p)
    except (RasterioError, OSError, ValueError) as e:
        msg = " ".join(str(e).split())[:160]
        raise GeoTiffError(f"{what} {_name(p)}: cannot read it as a TIFF ({msg}); write it "
                           "with GDAL, rasterio or tifffile") from None


def _georeference(ds, what: str):
    """(transform, pyproj CRS) of an open dataset, or GeoTiffError."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    name = _name(ds.name)
    t = ds.transform
    if ds.crs is None and t.is_identity:
        raise GeoTiffError(f"{what} {name}: no georeferencing (no CRS, no pixel scale or tie "
                           "point); export it as a GeoTIFF (gdal_translate -a_srs -a_ullr)")
    if ds.crs is None:
        raise GeoTiffError(f"{what} {name}: no CRS; assign one (gdal_edit.py -a_srs EPSG:...)")
    if not all(math.isfinite(v) for v in tuple(t)[:6]) or abs(t.determinant) == 0.0:
        raise GeoTiffError(f"{what} {name}: its pixel transform {tuple(t)[:6]} is degenerate; "
                           "fix its georeferencing")
    try:
        crs = CRS.from_user_input(ds.crs.to_wkt())
    except CRSError as e:
        raise GeoTiffError(f"{what} {name}: PROJ does not understand its CRS ({e}); "
                           "reproject it (gdalwarp -t_srs EPSG:4326)") from None
    return t, crs


def raster_shape(path, what: str = "scene.geotiff.ortho") -> tuple[int, int]:
    """(rows, cols) of a GeoTIFF from its header (nothing read)."""
    with _open(path, what) as ds:
        return int(ds.height), int(ds.width)


def read_geotiff(path: str | Path, what: str = "GeoTIFF", max_side: int | None = None,
                 band: int | None = None) -> GeoRaster:
    """One band of a GeoTIFF (``band``, 1-based, or the bands averaged; alpha and nodata as
    NaN) and its georeference.

    ``max_side``: read a decimated image (from the overviews where the file has them) with
    at most this many pixels a side.
    """
    from affine import Affine
    from rasterio.enums import ColorInterp, Resampling
    from rasterio.errors import RasterioError

    with _open(path, what) as ds:
        name = _name(ds.name)
        transform, crs = _georeference(ds, what)
        dtype = np.dtype(ds.dtypes[0])
        if dtype.kind not in "uif":
            raise GeoTiffError(f"{what} {name}: pixel type {dtype} is not a real number; "
                               "convert it (gdal_translate -ot Float32)")
        alpha = [i + 1 for i, c in enumerate(ds.colorinterp) if c == ColorInterp.alpha]
        bands = [b for b in range(1, ds.count + 1) if b not in alpha] or [1]
        if band is not None:
            if not 1 <= band <= ds.count:
                raise GeoTiffError(f"scene.geotiff.band: {band}, but {what} {name} has "
                                   f"{ds.count} band{'s' if ds.count > 1 else ''}; pick one "
                                   f"of 1..{ds.count}")
            bands = [band]
        h, w = ds.height, ds.width
        f = 1
        if max_side is not None and max(h, w) > max_side:
            f = int(math.ceil(max(h, w) / max_side))
        shape = (len(bands), max(1, h // f), max(1, w // f))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                arr = ds.read(bands, out_shape=shape, masked=True,
                              resampling=Resampling.average if f > 1 else Resampling.nearest)
                if alpha:
                    a = ds.read(alpha[0], out_shape=shape[1:], resampling=Resampling.nearest)
        except (RasterioError, OSError, ValueError, MemoryError) as e:
            msg = " ".join(str(e).split())[:160]
            raise GeoTiffError(f"{what} {name}: cannot read its pixels ({msg}); check the "
                               "file (gdalinfo -checksum)") from None
        if f > 1:  # the same extent in fewer, larger pixels
            sx, sy = w / shape[2], h / shape[1]
            a, b, c, d, e, g = tuple(transform)[:6]
            transform = Affine(a * sx, b * sy, c, d * sx, e * sy, g)
    data = np.ma.getdata(arr).astype(np.float64)
    bad = np.ma.getmaskarray(arr).any(axis=0) | ~np.isfinite(data).all(axis=0)
    if alpha:
        bad |= a == 0
    data = data.mean(axis=0)
    data[bad] = np.nan
    return GeoRaster(data, transform, crs, name, str(dtype), f)


class Placement:
    """Where the pixels of a raster lie in the local ENU frame centred at (lat0, lon0)."""

    def __init__(self, raster: GeoRaster, lat0: float, lon0: float, what: str):
        from pyproj import CRS, Transformer

        self.raster, self.what = raster, what
        self.frame = LocalFrame(float(lat0), float(lon0), 0.0)
        wgs84 = CRS.from_epsg(4326)
        self._to_geo = Transformer.from_crs(raster.crs, wgs84, always_xy=True)
        self._from_geo = Transformer.from_crs(wgs84, raster.crs, always_xy=True)

    def lonlat_of_pixel(self, row, col) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 (lon, lat) deg of fractional array indices."""
        x, y = self.raster.map_of(row, col)
        lon, lat = self._to_geo.transform(x, y, errcheck=False)
        return np.asarray(lon, np.float64), np.asarray(lat, np.float64)

    def enu_of_pixel(self, row, col) -> tuple[np.ndarray, np.ndarray]:
        """ENU (east, north) m of fractional array indices (on the ellipsoid)."""
        lon, lat = self.lonlat_of_pixel(row, col)
        self._check(lat, lon)
        enu = self.frame.ecef_to_enu(geodetic_to_ecef(lat, lon, 0.0))
        return enu[..., 0], enu[..., 1]

    def pixel_of_enu(self, east, north) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) array indices of ENU points (on the tangent plane)."""
        e, n = np.broadcast_arrays(np.asarray(east, np.float64), np.asarray(north, np.float64))
        ecef = self.frame.enu_to_ecef(np.stack([e, n, np.zeros_like(e)], axis=-1))
        lat, lon, _ = ecef_to_geodetic(ecef)
        x, y = self._from_geo.transform(lon, lat, errcheck=False)
        row, col = self.raster.pixel_of(np.asarray(x), np.asarray(y))
        if not (np.all(np.isfinite(row)) and np.all(np.isfinite(col))):
            raise GeoTiffError(f"{self.what} {self.raster.path}: the tile reaches places its "
                               "CRS cannot represent; use a smaller image or another CRS")
        return row, col

    def _check(self, lat, lon) -> None:
        ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0)
        if not np.all(ok):
            raise GeoTiffError(f"{self.what} {self.raster.path}: its pixels do not all lie on "
                               "the Earth in its CRS (latitude beyond +-90 deg or a point PROJ "
                               "cannot convert); check its georeferencing")

    def jacobian(self, row: float, col: float) -> np.ndarray:
        """d(east, north) / d(col, row) at a pixel, m per pixel (2, 2)."""
        e, n = self.enu_of_pixel(np.array([row, row, row - 0.5, row + 0.5]),
                                 np.array([col - 0.5, col + 0.5, col, col]))
        return np.array([[e[1] - e[0], e[3] - e[2]], [n[1] - n[0], n[3] - n[2]]])

    def factors(self) -> dict[str, float]:
        """Grid convergence (deg, grid north east of true north positive) and scale factor
        (map units per ground metre, meridional and parallel) at the centre, by pyproj;
        empty for a geographic CRS."""
        from pyproj import Proj

        if self.raster.crs.is_geographic:
            return {}
        f = Proj(self.raster.crs).get_factors(self.frame.lon_deg, self.frame.lat_deg,
                                              errcheck=False)
        return {"convergence_deg": float(f.meridian_convergence),
                "meridional_scale": float(f.meridional_scale),
                "parallel_scale": float(f.parallel_scale)}


def _centre(raster: GeoRaster, row: float, col: float, what: str) -> tuple[float, float]:
    """WGS84 (lat, lon) of fractional array indices, checked to be on the Earth."""
    from pyproj import CRS, Transformer

    x, y = raster.map_of(row, col)
    tr = Transformer.from_crs(raster.crs, CRS.from_epsg(4326), always_xy=True)
    lon, lat = tr.transform(float(x), float(y), errcheck=False)
    if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90.0):
        raise GeoTiffError(f"{what} {raster.path}: its centre (map {float(x):.6g}, "
                           f"{float(y):.6g}) is not on the Earth in its CRS "
                           f"({raster.crs.name}); check its georeferencing")
    if abs(lat) > 89.0:
        raise GeoTiffError(f"{what} {raster.path}: its centre is at latitude {lat:.4f} deg; "
                           "imcsim places scenes within +-89 deg")
    return float(lat), float(((lon + 180.0) % 360.0) - 180.0)


@dataclass(frozen=True)
class GeoTerrain:
    """A placed GeoTIFF tile: the terrain, its centre (lat, lon) deg, whether the pixels were
    resampled, the CRS's factors at the centre (see :meth:`Placement.factors`), and the
    placement (ENU <-> file pixels)."""

    terrain: Terrain
    centre: tuple[float, float]
    resampled: bool
    factors: dict
    placement: Placement
    row0: float  # array index of the tile's first texel centre (not resampled), else nan
    col0: float


def place_geotiff(ortho_path: str | Path, dem_path: str | Path | None, dem_spacing_m: float,
                  albedo_scale: float | None = None, max_side: int | None = None,
                  band: int | None = None) -> GeoTerrain:
    """Terrain from an orthophoto and an optional DEM, placed by pyproj (module docstring).

    The tile is cropped (centred) to a whole number of DEM cells of ``dem_spacing_m``
    (rounded to whole texels). ``albedo_scale`` multiplies the pixel values (default: 1 for
    float images, 1 / the dtype's maximum for integer images); the result is clipped to
    [0, 1]. ``max_side``: read the orthophoto decimated to at most this many pixels a side;
    ``band``: the orthophoto's band (1-based; None: the bands averaged).

    Nodata (and alpha) pixels of the orthophoto are filled with the image's mean and nodata
    DEM pixels with their nearest valid neighbour; both are masked on the terrain
    (``Terrain.nodata_albedo``, ``nodata_dem``) and reported in ``Terrain.notes``, so the run
    can refuse them where the tracker looks (:func:`nodata_in_view`). A DEM up to one DEM
    pixel short of the orthophoto is edge-extended, with a note.
    """
    what = "scene.geotiff.ortho"
    ortho = read_geotiff(ortho_path, what, max_side, band)
    h, w = ortho.shape
    if h < 16 or w < 16:
        raise GeoTiffError(f"{what} {ortho.path}: {h} x {w} px is too small (16 x 16 at least)")
    lat0, lon0 = _centre(ortho, (h - 1) / 2.0, (w - 1) / 2.0, what)
    place = Placement(ortho, lat0, lon0, what)
    jac = place.jacobian((h - 1) / 2.0, (w - 1) / 2.0)
    texel_m = float(np.sqrt(abs(np.linalg.det(jac))))
    if not (math.isfinite(texel_m) and texel_m > 0):
        raise GeoTiffError(f"{what} {ortho.path}: its pixels have no ground size; check its "
                           "georeferencing")
    step = max(1, int(round(dem_spacing_m / texel_m)))
    # the simple placement: rows along north, columns along east, one texel size
    rr = np.array([0.0, 0.0, h - 1.0, h - 1.0, (h - 1) / 2.0, 0.0, h - 1.0, (h - 1) / 2.0])
    cc = np.array([0.0, w - 1.0, 0.0, w - 1.0, 0.0, (w - 1) / 2.0, (w - 1) / 2.0, w - 1.0])
    e, n = place.enu_of_pixel(rr, cc)
    dev = np.hypot(e - (cc - (w - 1) / 2.0) * texel_m, n - ((h - 1) / 2.0 - rr) * texel_m)
    resample = float(dev.max()) / texel_m > EXACT_TOLERANCE_PX
    if resample:
        albedo, nh, nw, r0, c0 = _resampled(ortho, place, texel_m, step, dem_spacing_m, what)
    else:
        nh, nw = (h // step) * step, (w // step) * step
        _check_cells(ortho, h, w, nh, nw, step, dem_spacing_m, what)
        r0, c0 = (h - nh) // 2, (w - nw) // 2
        albedo = ortho.data[r0:r0 + nh, c0:c0 + nw]
        if (h - nh) % 2 or (w - nw) % 2:  # the crop's centre is the ENU origin
            lat0, lon0 = _centre(ortho, r0 + (nh - 1) / 2.0, c0 + (nw - 1) / 2.0, what)
            place = Placement(ortho, lat0, lon0, what)
    notes: list[str] = []
    holes = ~np.isfinite(albedo)
    nodata_albedo = None
    if holes.all():
        raise GeoTiffError(f"{what} {ortho.path}: every pixel of the tile is nodata; check its "
                           "nodata value or pick another scene.geotiff.band")
    if holes.any():
        albedo = np.where(holes, float(np.mean(albedo[~holes])), albedo)
        nodata_albedo = holes
        notes.append(f"{what} {ortho.path}: {int(holes.sum())} nodata texels "
                     f"({holes.mean():.2%} of the tile) masked and filled with the image's mean"
                     " (outside the tracker's view)")
    if albedo_scale is None:
        raw = np.dtype(ortho.dtype)
        albedo_scale = 1.0 / np.iinfo(raw).max if raw.kind in "ui" else 1.0
    albedo = np.clip(albedo * albedo_scale, 0.0, 1.0).astype(np.float32)
    if albedo.max() <= 0.0:
        raise GeoTiffError(f"{what} {ortho.path}: the image is black after scaling; check "
                           "scene.geotiff.albedo_scale")
    spacing = step * texel_m
    my, mx = nh // step + 1, nw // step + 1
    nodata_dem = None
    if dem_path is None:
        dem_m = np.zeros((my, mx), np.float32)
    else:
        east = (np.arange(mx) * step - nw / 2.0) * texel_m
        north = (nh / 2.0 - np.arange(my) * step) * texel_m
        dem_m, nodata_dem, dem_notes = _dem_at(dem_path, place, east, north)
        notes += dem_notes
    terrain = Terrain(albedo, texel_m, dem_m, spacing, nodata_albedo, nodata_dem, tuple(notes))
    return GeoTerrain(terrain, (place.frame.lat_deg, place.frame.lon_deg), resample,
                      place.factors(), place, float("nan") if resample else float(r0),
                      float("nan") if resample else float(c0))


def _check_cells(ortho, h, w, nh, nw, step, dem_spacing_m, what) -> None:
    if nh < 2 * step or nw < 2 * step or nh < 16 or nw < 16:
        raise GeoTiffError(f"{what} {ortho.path}: {h} x {w} px is smaller than 2 DEM cells of "
                           f"{dem_spacing_m} m; lower scene.dem_spacing_m")


def _resampled(ortho: GeoRaster, place: Placement, texel_m: float, step: int,
               dem_spacing_m: float, what: str):
    """The orthophoto on a north-up ENU grid of square texels inside its footprint:
    (albedo (nh, nw), nh, nw, 0, 0)."""
    from scipy import ndimage

    h, w = ortho.shape
    jac = place.jacobian((h - 1) / 2.0, (w - 1) / 2.0)
    a0, b0 = w * np.hypot(*jac[:, 0]) / 2.0, h * np.hypot(*jac[:, 1]) / 2.0

    def inside(s: float) -> bool:
        e = np.array([-1.0, 1.0, -1.0, 1.0, 0.0, 0.0, -1.0, 1.0]) * s * a0
        n = np.array([-1.0, -1.0, 1.0, 1.0, -1.0, 1.0, 0.0, 0.0]) * s * b0
        r, c = place.pixel_of_enu(e, n)
        return bool(np.all((r >= 0.5) & (r <= h - 1.5) & (c >= 0.5) & (c <= w - 1.5)))

    lo, hi = 0.0, 1.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if inside(mid) else (lo, mid)
    nh = (int(2.0 * lo * b0 / texel_m) // step) * step
    nw = (int(2.0 * lo * a0 / texel_m) // step) * step
    _check_cells(ortho, h, w, nh, nw, step, dem_spacing_m, what)
    # exact pixel positions on a coarse grid of texel centres, bilinear in between
    ci = np.unique(np.r_[np.arange(0, nh, _COARSE), nh - 1]).astype(np.float64)
    cj = np.unique(np.r_[np.arange(0, nw, _COARSE), nw - 1]).astype(np.float64)
    ee = (cj + 0.5 - nw / 2.0) * texel_m
    nn = (nh / 2.0 - ci - 0.5) * texel_m
    rows, cols = place.pixel_of_enu(ee[None, :], nn[:, None])
    albedo = np.empty((nh, nw), np.float64)
    jj = np.interp(np.arange(nw), cj, np.arange(len(cj)))
    for i0 in range(0, nh, 256):
        ii = np.interp(np.arange(i0, min(nh, i0 + 256)), ci, np.arange(len(ci)))
        gi, gj = np.meshgrid(ii, jj, indexing="ij")
        r = ndimage.map_coordinates(rows, [gi, gj], order=1)
        c = ndimage.map_coordinates(cols, [gi, gj], order=1)
        albedo[i0:i0 + len(ii)] = ndimage.map_coordinates(ortho.data, [r, c], order=1,
                                                          mode="nearest", prefilter=False)
    return albedo, nh, nw, 0, 0


def _edges(dem: GeoRaster, over: dict[str, float]) -> str:
    """The DEM's edges named by compass direction for a north-up file, else by row / column."""
    a, b, _, d, e, _ = tuple(dem.transform)[:6]
    north_up = b == 0 and d == 0 and a > 0 and e < 0
    names = ({"first_row": "north", "last_row": "south", "first_col": "west", "last_col": "east"}
             if north_up else {"first_row": "first-row", "last_row": "last-row",
                               "first_col": "first-column", "last_col": "last-column"})
    return " and ".join(names[k] for k in over)


def _dem_at(dem_path, place: Placement, east: np.ndarray, north: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """DEM heights (len(north), len(east)) m at ENU nodes, bilinear, any CRS; the nodes that
    drew on nodata DEM pixels (None: none) and the notes on how the DEM was taken.

    A DEM up to one DEM pixel short of the nodes is edge-extended (its outer pixels repeated);
    shorter: GeoTiffError. Nodata pixels are filled from their nearest valid neighbour."""
    from scipy import ndimage

    what = "scene.geotiff.dem"
    dem = read_geotiff(dem_path, what)
    dplace = Placement(dem, place.frame.lat_deg, place.frame.lon_deg, what)
    rr, cc = dplace.pixel_of_enu(east[None, :], north[:, None])
    dh, dw = dem.shape
    # how far (DEM px) the nodes reach past each outer edge of the DEM (its pixels' edges)
    over = {"first_row": -0.5 - float(rr.min()), "last_row": float(rr.max()) - (dh - 0.5),
            "first_col": -0.5 - float(cc.min()), "last_col": float(cc.max()) - (dw - 0.5)}
    over = {k: v for k, v in over.items() if v > 1e-6}
    notes = []
    if over and max(over.values()) > 1.0 + 1e-6:
        x0, y0 = dem.map_of(np.array([-0.5, dh - 0.5]), np.array([-0.5, dw - 0.5]))
        xs, ys = dem.map_of(np.array([rr.min(), rr.max()]), np.array([cc.min(), cc.max()]))
        raise GeoTiffError(
            f"{what} {dem.path}: its extent x {min(x0):.6g}..{max(x0):.6g}, y "
            f"{min(y0):.6g}..{max(y0):.6g} does not cover the orthophoto's x {min(xs):.6g}.."
            f"{max(xs):.6g}, y {min(ys):.6g}..{max(ys):.6g} (in the DEM's CRS; "
            f"{max(over.values()):.3g} DEM px short, one is edge-extended); use a DEM that "
            "covers it")
    if over:
        jac = dplace.jacobian((dh - 1) / 2.0, (dw - 1) / 2.0)
        px_m = {"row": float(np.hypot(*jac[:, 1])), "col": float(np.hypot(*jac[:, 0]))}
        short_m = max(v * px_m["row" if "row" in k else "col"] for k, v in over.items())
        notes.append(f"{what} {dem.path}: stops up to {short_m:.0f} m "
                     f"({max(over.values()):.2f} DEM px) short of the orthophoto at its "
                     f"{_edges(dem, over)} edge; edge-extended (its outer pixels repeated)")
    rr, cc = np.clip(rr, 0, dh - 1), np.clip(cc, 0, dw - 1)
    r_lo, r_hi = int(np.floor(rr.min())), int(np.ceil(rr.max())) + 1
    c_lo, c_hi = int(np.floor(cc.min())), int(np.ceil(cc.max())) + 1
    data = dem.data
    holes = ~np.isfinite(data)
    nodes = None
    if holes[r_lo:r_hi, c_lo:c_hi].any():
        if holes[r_lo:r_hi, c_lo:c_hi].all():
            raise GeoTiffError(f"{what} {dem.path}: every DEM pixel under the orthophoto is "
                               "nodata; check its nodata value")
        idx = ndimage.distance_transform_edt(holes, return_distances=False,
                                             return_indices=True)
        data = data[tuple(idx)]
        touched = ndimage.map_coordinates(holes.astype(np.float64), [rr, cc], order=1,
                                          mode="nearest") > 0.0
        if touched.any():
            nodes = touched
            notes.append(f"{what} {dem.path}: {int(touched.sum())} DEM nodes of the tile "
                         f"({touched.mean():.2%}) drew on nodata pixels; masked and filled "
                         "from the nearest valid pixel (outside the tracker's view)")
    z = ndimage.map_coordinates(data, [rr, cc], order=1, mode="nearest")
    return z.astype(np.float32), nodes, notes


def nodata_in_view(terrain: Terrain, quads_en_m: np.ndarray) -> str | None:
    """A one-line refusal if any masked (nodata) texel or DEM node of ``terrain`` lies inside
    one of the ground quadrilaterals ``quads_en_m`` (T, 4, 2) (ENU east, north; corners in
    order around), else None."""
    w, h = terrain.size_m
    pts, kinds = [], []
    if terrain.nodata_albedo is not None:
        i, j = np.nonzero(terrain.nodata_albedo)
        pts.append(np.stack([(j + 0.5) * terrain.texel_m - w / 2.0,
                             h / 2.0 - (i + 0.5) * terrain.texel_m], axis=-1))
        kinds.append(np.zeros(len(i), int))
    if terrain.nodata_dem is not None:
        i, j = np.nonzero(terrain.nodata_dem)
        pts.append(np.stack([j * terrain.dem_spacing_m - w / 2.0,
                             h / 2.0 - i * terrain.dem_spacing_m], axis=-1))
        kinds.append(np.ones(len(i), int))
    if not pts:
        return None
    p, kind = np.concatenate(pts), np.concatenate(kinds)
    q = np.asarray(quads_en_m, np.float64)
    inside = np.zeros(len(p), bool)
    for quad in q:
        edge = np.roll(quad, -1, axis=0) - quad  # (4, 2)
        rel = p[:, None, :] - quad[None]  # (P, 4, 2)
        cross = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
        inside |= np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)
    if not inside.any():
        return None
    n_t, n_d = int(np.sum(inside & (kind == 0))), int(np.sum(inside & (kind == 1)))
    near = p[inside][np.argmin(np.hypot(*p[inside].T))]
    what = " and ".join(x for x in (f"{n_t} nodata texels of scene.geotiff.ortho" if n_t else "",
                                    f"{n_d} nodata DEM nodes of scene.geotiff.dem" if n_d
                                    else "") if x)
    return (f"scene.geotiff: {what} lie where the tracker looks during the run (the nearest "
            f"{near[0]:.0f} m east, {near[1]:.0f} m north of the scene centre); fill them "
            "(gdal_fillnodata.py) or use files without holes there")


def terrain_from_geotiff(ortho_path: str | Path, dem_path: str | Path | None,
                         dem_spacing_m: float, albedo_scale: float | None = None,
                         max_side: int | None = None, band: int | None = None
                         ) -> tuple[Terrain, tuple[float, float]]:
    """Terrain and its centre (lat, lon) deg from an orthophoto and an optional DEM (see
    :func:`place_geotiff`)."""
    g = place_geotiff(ortho_path, dem_path, dem_spacing_m, albedo_scale, max_side, band)
    return g.terrain, g.centre


def write_geotiff(path: str | Path, data: np.ndarray, x0: float, y0: float, dx: float,
                  dy: float, crs: int | str = 32632, geographic: bool = False,
                  nodata: float | None = None, tiled: bool = False,
                  compress: str | None = None, overviews: tuple[int, ...] = (),
                  transform=None, rpcs=None) -> None:
    """Write a GeoTIFF with rasterio: north-up from ``x0, y0, dx, dy``, or on any affine grid
    (``transform``, a rasterio/affine ``Affine``: a rotated image product).

    ``data``: (H, W) or (bands, H, W); ``x0, y0``: upper-left outer corner; ``dx, dy`` > 0
    pixel size in map units; ``crs``: an EPSG code or a WKT / PROJ string (``geographic`` is
    kept for older callers: the CRS says it); ``tiled``, ``compress`` ('deflate', 'lzw', ...)
    and ``overviews`` (decimation factors) as GDAL writes them; ``rpcs`` (a
    :class:`rasterio.rpc.RPC`): RPC00B coefficients in the file's RPC tag.
    """
    import rasterio
    from affine import Affine
    from rasterio.dtypes import check_dtype

    del geographic
    arr = np.asarray(data)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.size == 0:
        raise ValueError(f"data: a GeoTIFF needs a non-empty (H, W) or (bands, H, W) array, "
                         f"got shape {arr.shape}")
    if not check_dtype(arr.dtype):
        hint = ("convert a mask with data.astype(np.uint8)" if arr.dtype == bool else
                "convert it to uint8, int16, int32, float32 or float64")
        raise ValueError(f"data: GeoTIFF cannot store dtype {arr.dtype} (GDAL's types only); "
                         f"{hint}")
    profile = {"driver": "GTiff", "height": arr.shape[1], "width": arr.shape[2],
               "count": arr.shape[0], "dtype": arr.dtype,
               "crs": f"EPSG:{crs}" if isinstance(crs, int) else crs,
               "transform": transform if transform is not None
               else Affine(dx, 0.0, x0, 0.0, -dy, y0)}
    if nodata is not None:
        profile["nodata"] = nodata
    if tiled:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    if compress:
        profile["compress"] = compress
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(arr)
        if rpcs is not None:
            ds.rpcs = rpcs
        if overviews:
            from rasterio.enums import Resampling

            ds.build_overviews(list(overviews), Resampling.average)

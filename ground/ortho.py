"""Orthorectification through GDAL's RPC transformer, and a Level-1 product's geometric
quality as it is stated: horizontal geolocation error in metres (CE90), relative accuracy,
misregistration between products.

* :func:`orthorectify`: product bands (an image and, beside it, any coordinate rasters) onto
  a map grid by ``rasterio.warp.reproject`` with the product's RPCs and a DEM of heights
  above the ellipsoid (``RPC_DEM``: what ``gdalwarp -rpc -to RPC_DEM=dem.tif`` does);
* :func:`rpc_pixels`: GDAL's RPC transformer with the DEM on its own, exact: the product
  pixel a ground point maps to (the warper interpolates that mapping between exact points,
  to 0.125 px by default: ``rasterio.warp.reproject`` offers no way to turn that off with an
  ``RPC_DEM``; the check points therefore ask the transformer itself);
* :func:`dem_dataset`: the DEM as GDAL reads it, in memory (``/vsimem``), pixel centres on
  the given grid's nodes;
* :func:`geolocation`: CE90 (the 90th percentile of the horizontal error's length), its mean
  (the bias ground control would remove) and the relative accuracy (the spread after the
  mean is removed: RMS per axis and CE90);
* :func:`misregistration_m`: the shift of one orthoimage against another by phase
  correlation (scikit-image, sub-pixel by upsampling), in metres east / north.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

#: sub-pixel precision of the phase correlation: 1 / UPSAMPLE map cells
UPSAMPLE = 200


@contextlib.contextmanager
def dem_dataset(heights_m: np.ndarray, transform, crs: str) -> Iterator[str]:
    """A DEM GeoTIFF in GDAL's memory file system, yielded as its path (for ``RPC_DEM``).

    Parameters
    ----------
    heights_m : (H, W) heights above the WGS84 ellipsoid, m (no vertical datum is attached:
        GDAL's RPC transformer then takes them as ellipsoidal, as RPCs expect).
    transform : the raster's affine (rasterio's ``Affine``), pixel corners.
    crs : its horizontal CRS (WKT / PROJ / EPSG string).
    """
    import rasterio
    from rasterio.io import MemoryFile

    h = np.asarray(heights_m, dtype=np.float64)
    with MemoryFile() as mem:
        with mem.open(driver="GTiff", height=h.shape[0], width=h.shape[1], count=1,
                      dtype="float64", crs=crs, transform=transform) as ds:
            ds.write(h[None])
        with rasterio.Env():
            yield mem.name


def orthorectify(bands: np.ndarray, rpc, dem_path: str, dst_transform, dst_shape: tuple,
                 dst_crs: str, resampling: str = "bilinear") -> np.ndarray:
    """Product bands (B, H, W) (or one (H, W)) onto a map grid through GDAL's RPC transformer.

    Parameters
    ----------
    bands : the product's pixels; NaN is nodata.
    rpc : the product's RPC (:class:`rasterio.rpc.RPC`).
    dem_path : a DEM of heights above the ellipsoid covering the grid (:func:`dem_dataset`).
    dst_transform, dst_shape, dst_crs : the map grid (affine, (rows, cols), CRS).
    resampling : a ``rasterio.enums.Resampling`` name (bilinear: a coordinate raster's linear
        ramp comes through exactly).

    Returns
    -------
    numpy.ndarray, (B, rows, cols) or (rows, cols) float64, NaN outside the product.
    """
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    src = np.asarray(bands, dtype=np.float64)
    one = src.ndim == 2
    src = src[None] if one else src
    dst = np.full((src.shape[0], *dst_shape), np.nan)
    reproject(src, dst, rpcs=rpc, src_crs="EPSG:4326", src_nodata=np.nan,
              dst_transform=dst_transform, dst_crs=dst_crs, dst_nodata=np.nan,
              resampling=Resampling[resampling], RPC_DEM=dem_path,
              RPC_DEMINTERPOLATION="bilinear")
    return dst[0] if one else dst


def rpc_pixels(rpc, lon_deg: np.ndarray, lat_deg: np.ndarray, dem_path: str
               ) -> np.ndarray:
    """GDAL's RPC transformer, exact (no warper in between): the product pixels (N, 2)
    (line, sample; 0 at the first pixel's centre) that ground points at WGS84 (lon, lat)
    deg on the DEM (heights above the ellipsoid) map to."""
    from rasterio.transform import RPCTransformer

    with RPCTransformer(rpc, RPC_DEM=dem_path, RPC_DEMINTERPOLATION="bilinear") as tr:
        rows, cols = tr.rowcol(np.ravel(lon_deg), np.ravel(lat_deg), op=lambda v: v)
    # GDAL counts from the first pixel's corner
    return np.column_stack([np.asarray(rows, float) - 0.5, np.asarray(cols, float) - 0.5])


def ce90(err_m: np.ndarray) -> float:
    """CE90: the 90th percentile of the horizontal errors' lengths (N, 2) m."""
    e = np.asarray(err_m, dtype=np.float64).reshape(-1, 2)
    return float(np.percentile(np.hypot(e[:, 0], e[:, 1]), 90.0))


@dataclass(frozen=True)
class Geolocation:
    """A product's horizontal geolocation at check points, m (east, north).

    Attributes
    ----------
    ce90_m : CE90 of the errors as they are (absolute).
    mean_m : their mean (east, north): the bias ground control removes.
    rms_m : their RMS per axis (absolute).
    relative_rms_m : RMS per axis after the mean is removed (relative accuracy).
    relative_ce90_m : CE90 after the mean is removed.
    n : check points.
    """

    ce90_m: float
    mean_m: tuple[float, float]
    rms_m: tuple[float, float]
    relative_rms_m: tuple[float, float]
    relative_ce90_m: float
    n: int

    def to_dict(self) -> dict:
        return {"ce90_m": self.ce90_m, "mean_m": list(self.mean_m), "rms_m": list(self.rms_m),
                "relative_rms_m": list(self.relative_rms_m),
                "relative_ce90_m": self.relative_ce90_m, "n": self.n}


def geolocation(err_m: np.ndarray) -> Geolocation:
    """The figures of horizontal errors (N, 2) (east, north) m at check points: the feature
    at its true place ``X_true`` seen at ``X`` in the product, ``err = X - X_true``."""
    e = np.asarray(err_m, dtype=np.float64).reshape(-1, 2)
    if len(e) == 0:
        raise ValueError("geolocation: no check points")
    mean = e.mean(axis=0)
    rel = e - mean
    return Geolocation(ce90(e), (float(mean[0]), float(mean[1])),
                       tuple(float(x) for x in np.sqrt(np.mean(e ** 2, axis=0))),
                       tuple(float(x) for x in np.sqrt(np.mean(rel ** 2, axis=0))),
                       ce90(rel), int(len(e)))


def common_box(*images: np.ndarray) -> tuple[slice, slice]:
    """The largest square, centred on the middle of the cells where every image is finite,
    that is finite in all of them (a rotated strip's ortho has no fully finite row), as
    slices; none is a ValueError."""
    ok = np.all([np.isfinite(i) for i in images], axis=0)
    r, c = np.nonzero(ok)
    if len(r) == 0:
        raise ValueError("common_box: the images share no finite cell")
    r0, c0 = int(np.median(r)), int(np.median(c))
    lo, hi = 0, min(ok.shape) // 2 + 1
    while hi - lo > 1:  # the square's half-side, by bisection (a grown square contains it)
        k = (lo + hi) // 2
        box = ok[max(r0 - k, 0):r0 + k + 1, max(c0 - k, 0):c0 + k + 1]
        lo, hi = (k, hi) if box.shape == (2 * k + 1,) * 2 and box.all() else (lo, k)
    if lo < 8:
        raise ValueError("common_box: the images share less than a 17-cell square")
    return slice(r0 - lo, r0 + lo + 1), slice(c0 - lo, c0 + lo + 1)


def misregistration_m(reference: np.ndarray, image: np.ndarray, cell_m: float
                      ) -> tuple[float, float]:
    """Where ``image``'s content sits against ``reference``'s on the same north-up map grid
    of ``cell_m`` m cells: (east, north) m, by phase correlation
    (``skimage.registration.phase_cross_correlation``, 1 / :data:`UPSAMPLE` cell) over the
    box where both are finite, each less its mean and Hann-windowed."""
    from skimage.registration import phase_cross_correlation

    box = common_box(reference, image)
    a, b = reference[box], image[box]
    w = np.outer(np.hanning(a.shape[0]), np.hanning(a.shape[1]))  # the box's borders would
    # otherwise pull the shift toward 0
    shift, _, _ = phase_cross_correlation((a - a.mean()) * w, (b - b.mean()) * w,
                                          upsample_factor=UPSAMPLE, normalization=None)
    # the shift registers image onto reference: the content sits at -shift (rows run south)
    return float(-shift[1] * cell_m) + 0.0, float(shift[0] * cell_m) + 0.0

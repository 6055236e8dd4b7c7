"""Rational polynomial coefficients (RPC00B): the replacement sensor model a Level-1 product
carries, fitted by least squares to the geometry the ground knows, evaluated ground -> image
and inverted image -> ground. Pure numpy; the coefficients travel as rasterio's
:class:`rasterio.rpc.RPC` (what ``dataset.rpcs`` writes into a GeoTIFF and GDAL's RPC
transformer reads).

RPC00B (NITF STDI-0002, GDAL ``gdal_rpc.cpp``): with the ground normalised as
``L = (lon - LONG_OFF) / LONG_SCALE``, ``P = (lat - LAT_OFF) / LAT_SCALE``,
``H = (h - HEIGHT_OFF) / HEIGHT_SCALE`` (degrees, metres above the WGS84 ellipsoid), the
image is ``line = LINE_OFF + LINE_SCALE * Num_l(L, P, H) / Den_l(L, P, H)`` (samples
likewise), each a cubic of 20 terms in the order :func:`rpc_terms` gives; ``Den(0) = 1``.
Line and sample count from the first pixel's centre (GDAL adds half a pixel to reach its
corner-based raster coordinates).

The fit is the terrain-independent one (Tao & Hu, PE&RS 67(12), 2001): ground points on a
grid of image positions and height layers from the rigorous model, the rational function
linearised (``Num - y Den = 0``), solved by weighted least squares re-weighted by the
denominator (twice) with a small Tikhonov term (the denominators are nearly redundant with
the numerators over a small scene: without it the normal equations are singular).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: the Tikhonov weight on the normalised coefficients, relative to the design's scale
RIDGE = 1e-10
#: re-weighting passes of the linearised fit (1 / Den^2)
REWEIGHT = 2
#: image -> ground: Newton steps on (lon, lat), and the stop, px
INVERT_STEPS = 20
INVERT_TOL_PX = 1e-9


def rpc_terms(lon_n: np.ndarray, lat_n: np.ndarray, h_n: np.ndarray) -> np.ndarray:
    """The 20 RPC00B terms (..., 20) of normalised longitude, latitude and height, in the
    standard's order (1, L, P, H, LP, LH, PH, L^2, P^2, H^2, PLH, L^3, LP^2, LH^2, L^2P,
    P^3, PH^2, L^2H, P^2H, H^3)."""
    lo, la, h = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64)
                                      for x in (lon_n, lat_n, h_n)))
    return np.stack([np.ones_like(lo), lo, la, h, lo * la, lo * h, la * h, lo * lo, la * la,
                     h * h, la * lo * h, lo ** 3, lo * la * la, lo * h * h, lo * lo * la,
                     la ** 3, la * h * h, lo * lo * h, la * la * h, h ** 3], axis=-1)


def _normalise(x: np.ndarray) -> tuple[float, float]:
    """(offset, scale) mapping x onto [-1, 1] (a constant: scale 1)."""
    lo, hi = float(np.min(x)), float(np.max(x))
    return 0.5 * (lo + hi), max(0.5 * (hi - lo), 1e-12) if hi > lo else 1.0


def _fit_axis(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(numerator (20,), denominator (20,)) of y ~ Num / Den over the terms t (N, 20)."""
    w = np.ones(len(y))
    num = den = None
    for _ in range(REWEIGHT + 1):
        a = np.hstack([t, -y[:, None] * t[:, 1:]]) * w[:, None]
        b = y * w
        lam = RIDGE * np.sum(a * a) / a.shape[1]
        coef = np.linalg.solve(a.T @ a + lam * np.eye(a.shape[1]), a.T @ b)
        num, den = coef[:20], np.concatenate([[1.0], coef[20:]])
        w = 1.0 / np.abs(t @ den)
    return num, den


@dataclass(frozen=True)
class RpcFit:
    """A fitted RPC and how well it reproduces the geometry it was fitted to.

    Attributes
    ----------
    rpc : the coefficients (:class:`rasterio.rpc.RPC`).
    fit_rms_px, fit_max_px : (line, sample) RMS and largest residual at the fitting points.
    check_rms_px, check_max_px : the same at independent check points (between the fitting
        grid's nodes and layers), None when none were given.
    height_range_m : (min, max) of the fitting points' heights above the ellipsoid.
    """

    rpc: object
    fit_rms_px: tuple[float, float]
    fit_max_px: tuple[float, float]
    check_rms_px: tuple[float, float] | None
    check_max_px: tuple[float, float] | None
    height_range_m: tuple[float, float]

    def to_dict(self) -> dict:
        return {"fit_rms_px": list(self.fit_rms_px), "fit_max_px": list(self.fit_max_px),
                "check_rms_px": None if self.check_rms_px is None else list(self.check_rms_px),
                "check_max_px": None if self.check_max_px is None else list(self.check_max_px),
                "height_range_m": list(self.height_range_m)}


def _stats(rpc, lon, lat, h, line, samp) -> tuple[tuple[float, float], tuple[float, float]]:
    pl, ps = rpc_image(rpc, lon, lat, h)
    e = np.stack([pl - line, ps - samp], axis=-1).reshape(-1, 2)
    return (tuple(float(x) for x in np.sqrt(np.mean(e ** 2, axis=0))),
            tuple(float(x) for x in np.max(np.abs(e), axis=0)))


def fit_rpc(lon_deg: np.ndarray, lat_deg: np.ndarray, h_m: np.ndarray, line_px: np.ndarray,
            samp_px: np.ndarray, check: tuple[np.ndarray, ...] | None = None) -> RpcFit:
    """Fit RPC00B coefficients to ground points and their image positions.

    Parameters
    ----------
    lon_deg, lat_deg, h_m : (N,) ground points: WGS84 longitude, latitude (deg) and height
        above the ellipsoid (m); spread over the image and the height range (a 3-D grid).
    line_px, samp_px : (N,) their image positions (0 at the first pixel's centre), px.
    check : optional (lon, lat, h, line, samp) of independent points the fit is judged on.

    Returns
    -------
    RpcFit
        The coefficients and the residuals in px.
    """
    import rasterio.rpc

    lon, lat, h, line, samp = (np.ravel(np.asarray(x, dtype=np.float64))
                               for x in (lon_deg, lat_deg, h_m, line_px, samp_px))
    if not all(np.all(np.isfinite(x)) for x in (lon, lat, h, line, samp)):
        raise ValueError("fit_rpc: the fitting points must be finite")
    if len(lon) < 39:
        raise ValueError(f"fit_rpc: {len(lon)} points, RPC00B needs at least 39 per axis")
    off = {k: _normalise(v) for k, v in (("long", lon), ("lat", lat), ("height", h),
                                         ("line", line), ("samp", samp))}
    t = rpc_terms((lon - off["long"][0]) / off["long"][1], (lat - off["lat"][0]) / off["lat"][1],
                  (h - off["height"][0]) / off["height"][1])
    ln, ld = _fit_axis(t, (line - off["line"][0]) / off["line"][1])
    sn, sd = _fit_axis(t, (samp - off["samp"][0]) / off["samp"][1])
    rpc = rasterio.rpc.RPC(
        height_off=off["height"][0], height_scale=off["height"][1],
        lat_off=off["lat"][0], lat_scale=off["lat"][1],
        long_off=off["long"][0], long_scale=off["long"][1],
        line_off=off["line"][0], line_scale=off["line"][1],
        samp_off=off["samp"][0], samp_scale=off["samp"][1],
        line_num_coeff=[float(x) for x in ln], line_den_coeff=[float(x) for x in ld],
        samp_num_coeff=[float(x) for x in sn], samp_den_coeff=[float(x) for x in sd])
    fit_rms, fit_max = _stats(rpc, lon, lat, h, line, samp)
    chk = _stats(rpc, *check) if check is not None else (None, None)
    return RpcFit(rpc, fit_rms, fit_max, chk[0], chk[1], (float(h.min()), float(h.max())))


def rpc_image(rpc, lon_deg, lat_deg, h_m) -> tuple[np.ndarray, np.ndarray]:
    """Ground -> image: (line, sample) px (0 at the first pixel's centre) of WGS84 points
    (lon, lat deg, height above the ellipsoid m), broadcast."""
    t = rpc_terms((np.asarray(lon_deg) - rpc.long_off) / rpc.long_scale,
                  (np.asarray(lat_deg) - rpc.lat_off) / rpc.lat_scale,
                  (np.asarray(h_m) - rpc.height_off) / rpc.height_scale)
    line = t @ np.asarray(rpc.line_num_coeff) / (t @ np.asarray(rpc.line_den_coeff))
    samp = t @ np.asarray(rpc.samp_num_coeff) / (t @ np.asarray(rpc.samp_den_coeff))
    return line * rpc.line_scale + rpc.line_off, samp * rpc.samp_scale + rpc.samp_off


def rpc_ground(rpc, line_px, samp_px, height: float | np.ndarray | Callable = 0.0
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image -> ground: (lon, lat deg, h m) seen at (line, sample) px, on a height above the
    ellipsoid (a number or array), or on a surface ``height(lon, lat) -> h`` (a DEM: the
    height re-read at every step). Newton's method on (lon, lat) with the RPC's Jacobian by
    central differences; a point that does not converge to 1e-9 px is a ValueError."""
    line = np.asarray(line_px, dtype=np.float64)
    samp = np.asarray(samp_px, dtype=np.float64)
    lon = np.full(np.broadcast_shapes(line.shape, samp.shape), float(rpc.long_off))
    lat = np.full_like(lon, float(rpc.lat_off))
    surface = callable(height)
    dl, dp = 1e-4 * rpc.long_scale, 1e-4 * rpc.lat_scale
    for _ in range(INVERT_STEPS):
        h = height(lon, lat) if surface else np.broadcast_to(height, lon.shape)
        r0, c0 = rpc_image(rpc, lon, lat, h)
        rl = rpc_image(rpc, lon + dl, lat, h)
        rl_ = rpc_image(rpc, lon - dl, lat, h)
        rp = rpc_image(rpc, lon, lat + dp, h)
        rp_ = rpc_image(rpc, lon, lat - dp, h)
        j = np.stack([np.stack([(rl[0] - rl_[0]) / (2 * dl), (rp[0] - rp_[0]) / (2 * dp)], -1),
                      np.stack([(rl[1] - rl_[1]) / (2 * dl), (rp[1] - rp_[1]) / (2 * dp)], -1)],
                     -2)
        res = np.stack([line - r0, samp - c0], axis=-1)
        step = np.linalg.solve(j, res[..., None])[..., 0]
        lon, lat = lon + step[..., 0], lat + step[..., 1]
        if np.max(np.abs(res)) < INVERT_TOL_PX:
            break
    else:
        raise ValueError(f"rpc_ground: image -> ground did not converge to {INVERT_TOL_PX} px"
                         f" in {INVERT_STEPS} steps (a point far outside the fitted image?)")
    h = height(lon, lat) if surface else np.broadcast_to(height, lon.shape).astype(float)
    return lon, lat, np.asarray(h, dtype=np.float64)


def shifted(rpc, line_px: float, samp_px: float):
    """The same RPC for an image whose pixel (y, x) is this one's (y + line_px,
    x + samp_px): a product resampled onto the grid displaced by a constant."""
    import attr

    return attr.evolve(rpc, line_off=float(rpc.line_off - line_px),
                       samp_off=float(rpc.samp_off - samp_px))

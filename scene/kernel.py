"""The Mitsuba kernel layer: the only module of imcsim that imports mitsuba / drjit.

The scene (terrain mesh, albedo texture, sun, sky, direct integrator) is built once; each
frame only uploads new pose keyframes (opaque, so nothing recompiles) and a fresh seed.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from scene.classes import CloudLayer
from scene.pinhole import KEYFRAME_FLOATS
from scene.terrain import Terrain
from scene.variant import VariantChoice, choose_variant, prepare_environment


@dataclass(frozen=True)
class Sun:
    """Sun direction and sky: elevation/azimuth in deg (azimuth from north toward east)."""

    elevation_deg: float = 45.0
    azimuth_deg: float = 135.0
    irradiance: float = 1.0
    sky_radiance: float = 0.03

    @property
    def to_sun_enu(self) -> np.ndarray:
        el, az = np.deg2rad(self.elevation_deg), np.deg2rad(self.azimuth_deg)
        return np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])


@contextlib.contextmanager
def _quiet_stderr(active: bool):
    """Silence C-level stderr (Dr.Jit's 'cannot load libLLVM' notes when none is usable)."""
    if not active:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def load_mitsuba(choice: VariantChoice | None = None) -> tuple[Any, Any, VariantChoice]:
    """Import mitsuba and drjit with the variant chosen for this machine."""
    choice = choice or choose_variant()
    prepare_environment(choice)
    with _quiet_stderr(choice.libllvm_path is None):
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(choice.variant)
    return mi, dr, choice


def versions() -> dict[str, str]:
    """Installed mitsuba / drjit versions (without importing them)."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("mitsuba", "drjit"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def _register_pinhole(mi: Any, dr: Any) -> None:
    """Register the 'imc_pinhole' sensor plugin (idempotent per process and variant)."""
    scalar = mi.variant().startswith("scalar")

    class ImcPinhole(mi.Sensor):
        """Exact pinhole rays from float64 host keyframes; pose moves with ray.time."""

        def __init__(self, props):
            super().__init__(props)
            self.n_keyframes = 2
            self.set_keyframes(np.zeros((2, KEYFRAME_FLOATS)))

        def set_keyframes(self, kf: np.ndarray) -> None:
            kf = np.asarray(kf, dtype=np.float64)
            self.n_keyframes = kf.shape[0]
            if scalar:
                self._np = kf.astype(np.float32).ravel()
            else:
                buf = mi.Float(kf.astype(np.float32).ravel())
                dr.make_opaque(buf)
                self._buf = buf

        def _g(self, k, j):
            if scalar:
                return float(self._np[int(k) * KEYFRAME_FLOATS + j])
            return dr.gather(mi.Float, self._buf, k * KEYFRAME_FLOATS + j)

        def _ray(self, k, qx, qy):
            g = self._g
            den = g(k, 9) * qx + g(k, 10) * qy + g(k, 11)
            ox = g(k, 0) + (g(k, 3) * qx + g(k, 4) * qy + g(k, 5)) / den
            oy = g(k, 1) + (g(k, 6) * qx + g(k, 7) * qy + g(k, 8)) / den
            o = mi.Point3f(ox, oy, g(k, 2))
            d = mi.Vector3f(
                g(k, 12) * qx + g(k, 13) * qy + g(k, 14),
                g(k, 15) * qx + g(k, 16) * qy + g(k, 17),
                g(k, 18) * qx + g(k, 19) * qy + g(k, 20),
            )
            return o, d

        def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample,
                       active=True):
            n = self.n_keyframes
            s = dr.clip(time, 0.0, 1.0) * (n - 1)
            k = dr.minimum(mi.UInt32(dr.floor(s)), n - 2)
            a = s - mi.Float(k)
            qx = position_sample.x - 0.5
            qy = position_sample.y - 0.5
            o0, d0 = self._ray(k, qx, qy)
            o1, d1 = self._ray(k + 1, qx, qy)
            o = dr.lerp(o0, o1, a)
            d = dr.normalize(dr.lerp(dr.normalize(d0), dr.normalize(d1), a))
            return mi.Ray3f(o, d, time, []), mi.Spectrum(1.0)

        def sample_ray_differential(self, time, wavelength_sample, position_sample,
                                    aperture_sample, active=True):
            ray, w = self.sample_ray(time, wavelength_sample, position_sample,
                                     aperture_sample, active)
            return mi.RayDifferential3f(ray), w

        def traverse(self, callback):
            pass

    mi.register_sensor("imc_pinhole", lambda props: ImcPinhole(props))


class Renderer:
    """Renders exposures of one terrain tile with the exact moving pinhole sensor.

    Parameters
    ----------
    terrain : the tile (albedo + DEM) in the local ENU frame.
    sun : sun direction and sky level.
    rows, cols : film size in pixels (the tracking sensor).
    spp : samples per pixel (stratified; also samples the exposure time).
    choice : Mitsuba variant; by default :func:`scene.variant.choose_variant`.
    clouds : an optional cloud layer (its own mesh above the terrain: parallax and shadows).
    ceiling_m : the lowest camera height (ENU) it will render from, if known: rays then start
        half-way between the top of the scene and it when 500 m above the top does not fit
        (an aircraft flying low).
    """

    def __init__(self, terrain: Terrain, sun: Sun, rows: int, cols: int, spp: int = 4,
                 choice: VariantChoice | None = None, clouds: CloudLayer | None = None,
                 ceiling_m: float | None = None):
        t0 = time.perf_counter()
        self._mi, self._dr, self.choice = load_mitsuba(choice)
        mi = self._mi
        _register_pinhole(mi, self._dr)
        self.rows, self.cols, self.spp = rows, cols, spp
        top = float(np.max(terrain.dem_m))
        if clouds is not None:
            top = max(top, clouds.top_m)
        self.z_start_m = top + 500.0
        if ceiling_m is not None:
            if ceiling_m <= top:
                raise ValueError(f"camera at {ceiling_m:g} m is not above the scene's top "
                                 f"({top:g} m)")
            self.z_start_m = min(self.z_start_m, 0.5 * (top + ceiling_m))
        scene_dict = {
            "type": "scene",
            "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
            "sensor": {
                "type": "imc_pinhole",
                "shutter_open": 0.0,
                "shutter_close": 1.0,
                "film": {
                    "type": "hdrfilm",
                    "width": cols,
                    "height": rows,
                    "rfilter": {"type": "gaussian"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "stratified", "sample_count": spp},
            },
            "terrain": self._terrain_mesh(terrain),
            "sun": {
                "type": "directional",
                "direction": (-sun.to_sun_enu).tolist(),
                "irradiance": {"type": "rgb", "value": sun.irradiance},
            },
            "sky": {
                "type": "constant",
                "radiance": {"type": "rgb", "value": sun.sky_radiance},
                "sampling_weight": 0.0,
            },
        }
        if clouds is not None and clouds.cover > 0.0:
            verts, faces, uv = clouds.mesh()
            if len(faces):
                scene_dict["clouds"] = self._mesh("clouds", verts, faces, uv, {
                    "type": "diffuse",
                    "reflectance": {
                        "type": "bitmap", "raw": True, "filter_type": "bilinear",
                        "wrap_mode": "clamp",
                        "bitmap": self._mi.Bitmap(np.ascontiguousarray(
                            clouds.albedo_map(), dtype=np.float32)),
                    },
                })
        self._scene_dict = scene_dict
        self._scene = mi.load_dict(scene_dict)
        self._sensor = self._scene.sensors()[0]
        self.build_s = time.perf_counter() - t0

    @property
    def variant(self) -> str:
        return self.choice.variant

    def _terrain_mesh(self, terrain: Terrain):
        mi = self._mi
        my, mx = terrain.dem_m.shape
        w, h = terrain.size_m
        east = -w / 2.0 + np.arange(mx) * terrain.dem_spacing_m
        north = h / 2.0 - np.arange(my) * terrain.dem_spacing_m
        ee, nn = np.meshgrid(east, north)
        verts = np.column_stack([ee.ravel(), nn.ravel(), terrain.dem_m.ravel()])
        uv = np.column_stack([(ee.ravel() + w / 2.0) / w, (h / 2.0 - nn.ravel()) / h])
        idx = np.arange(my * mx).reshape(my, mx)
        a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
        c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        # counter-clockwise seen from above (normals up): a(NW) c(SW) b(NE), b c d
        faces = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])])
        return self._mesh("terrain", verts, faces, uv, {
            "type": "diffuse",
            "reflectance": {
                "type": "bitmap",
                "bitmap": mi.Bitmap(np.ascontiguousarray(terrain.albedo, dtype=np.float32)),
                "raw": True,
                "filter_type": "bilinear",
                "wrap_mode": "clamp",
            },
        })

    def _mesh(self, name: str, verts: np.ndarray, faces: np.ndarray, uv: np.ndarray | None,
              bsdf: dict):
        """A Mitsuba mesh filled from numpy (ENU metres; faces counter-clockwise from above)."""
        mi = self._mi
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(bsdf)
        mesh = mi.Mesh(name, verts.shape[0], faces.shape[0], props=props,
                       has_vertex_normals=False, has_vertex_texcoords=uv is not None)
        params = mi.traverse(mesh)
        arrays = [("vertex_positions", verts.astype(np.float32)),
                  ("faces", faces.astype(np.uint32))]
        if uv is not None:
            arrays.append(("vertex_texcoords", uv.astype(np.float32)))
        for key, arr in arrays:
            params[key] = type(params[key])(arr.ravel())  # dynamic array of any variant
        params.update()
        return mesh

    def render(self, keyframes: np.ndarray, seed: int) -> np.ndarray:
        """Exposure-averaged radiance (rows, cols) float32 for pose keyframes (K >= 2, 21)."""
        kf = np.asarray(keyframes, dtype=np.float64)
        if kf.ndim != 2 or kf.shape[1] != KEYFRAME_FLOATS or kf.shape[0] < 2:
            raise ValueError(f"keyframes must be (K >= 2, {KEYFRAME_FLOATS}), got {kf.shape}")
        self._sensor.set_keyframes(kf)
        img = self._mi.render(self._scene, seed=int(seed) & 0x7FFFFFFF, spp=self.spp)
        arr = np.asarray(img, dtype=np.float32)
        if arr.ndim == 2:
            return arr
        # the channel mean as a sum of slices: numpy's mean over a length-3 last axis costs
        # 60 ms at 512^2, as much as a 1-spp render
        return (arr[..., 0] + arr[..., 1] + arr[..., 2]) * np.float32(1.0 / 3.0)

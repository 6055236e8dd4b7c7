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
from scene.pinhole import KEYFRAME_FLOATS, HitCounts
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


def quadrature_grid(spp: int) -> int:
    """g, the side of the stratified sampler's g x g sub-pixel grid at ``spp`` samples a
    pixel (Mitsuba rounds spp up to g^2)."""
    g = 1
    while g * g < spp:
        g += 1
    return g


def quadrature_multiplier(g: int) -> int:
    """The multiplier h that maps sub-pixel cell index c = i g + j to time stratum c h mod g^2:
    the integer nearest g^2 / golden ratio coprime with g^2 (1 when g = 1)."""
    n2 = g * g
    if n2 == 1:
        return 1
    x = n2 / 1.6180339887498949
    return min((h for h in range(1, n2) if np.gcd(h, n2) == 1), key=lambda h: (abs(h - x), h))


def _register_pinhole(mi: Any, dr: Any) -> None:
    """Register the 'imc_pinhole' sensor plugin (idempotent per process and variant)."""
    scalar = mi.variant().startswith("scalar")

    class ImcPinhole(mi.Sensor):
        """Exact pinhole rays from float64 host keyframes; pose moves with ray.time."""

        def __init__(self, props):
            super().__init__(props)
            self.n_keyframes = 2
            self.quadrature = None
            self.set_keyframes(np.zeros((2, KEYFRAME_FLOATS)))

        def set_quadrature(self, grid: int | None, rows: int, cols: int) -> None:
            """Pair each sub-pixel cell of a ``grid`` x ``grid`` stratification with its own
            exposure-time stratum (None: the sampler's own, per-pixel random pairing)."""
            self.quadrature = None if grid is None else (
                int(grid), int(rows), int(cols), quadrature_multiplier(int(grid)))

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
            if self.quadrature is not None:
                time = self._paired_time(time, position_sample)
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

        def _paired_time(self, time, position_sample):
            """The exposure instant of a sample: its sub-pixel cell (i, j) of the g x g grid
            takes time stratum (i g + j) h mod g^2 (h coprime with g^2, near g^2 / golden
            ratio: the strata not ordered with row), at the sampler's offset in its stratum."""
            g, rows, cols, h = self.quadrature
            n2 = g * g
            fx = position_sample.x * cols
            fy = position_sample.y * rows
            j = dr.minimum(mi.Int32(dr.floor((fx - dr.floor(fx)) * g)), g - 1)
            i = dr.minimum(mi.Int32(dr.floor((fy - dr.floor(fy)) * g)), g - 1)
            k = ((i * g + j) * h) % n2
            u = time * n2
            return (mi.Float(k) + (u - dr.floor(u))) / n2

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
    spp : samples per pixel (stratified over the pixel and the exposure time; Mitsuba rounds
        it up to a square g^2).
    quadrature : True (default): a fixed quadrature of the pixel and the exposure, the same
        for every pixel, frame and seed: the stratified sampler's stratum centres (no jitter),
        each sub-pixel cell paired with its own time stratum (:func:`quadrature_multiplier`).
        A detector integrates its pixel the same way every frame, so two renders of one pose
        agree and a tracker's link carries no Monte Carlo noise, only the quadrature's small,
        shift-dependent error. False: Mitsuba's jittered strata with random pairing (unbiased
        Monte Carlo; its noise falls as 1 / sqrt(spp)).
    choice : Mitsuba variant; by default :func:`scene.variant.choose_variant`.
    clouds : an optional cloud layer (its own mesh above the terrain: parallax and shadows).
    ceiling_m : the lowest camera height (ENU) it will render from, if known: rays then start
        half-way between the top of the scene and it when 500 m above the top does not fit
        (an aircraft flying low).
    """

    def __init__(self, terrain: Terrain, sun: Sun, rows: int, cols: int, spp: int = 4,
                 choice: VariantChoice | None = None, clouds: CloudLayer | None = None,
                 ceiling_m: float | None = None, quadrature: bool = True):
        t0 = time.perf_counter()
        self._mi, self._dr, self.choice = load_mitsuba(choice)
        mi = self._mi
        _register_pinhole(mi, self._dr)
        self.rows, self.cols, self.spp = rows, cols, spp
        self.quadrature = bool(quadrature)
        self.terrain, self.sun, self.clouds = terrain, sun, clouds
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
                "sampler": {"type": "stratified", "sample_count": spp,
                            "jitter": not self.quadrature},
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
        self._sensor.set_quadrature(quadrature_grid(self.spp) if self.quadrature else None,
                                    self.rows, self.cols)
        img = self._mi.render(self._scene, seed=int(seed) & 0x7FFFFFFF, spp=self.spp)
        arr = np.asarray(img, dtype=np.float32)
        if arr.ndim == 2:
            return arr
        # the channel mean as a sum of slices: numpy's mean over a length-3 last axis costs
        # 60 ms at 512^2, as much as a 1-spp render
        return (arr[..., 0] + arr[..., 1] + arr[..., 2]) * np.float32(1.0 / 3.0)


@dataclass(frozen=True, eq=False)  # holds an array
class CastResult(HitCounts):
    """Radiance of a batch of lines of sight and how many of them hit the scene.

    ``radiance`` (K, R, C) float32: one value per keyframe, film row and film column (rays
    that still miss after the nudged re-cast are filled from the nearest hit of their film
    row; NaN only where a whole film row missed). ``rays``: rays cast; ``first_hits``: rays
    that hit on the first (coherent) cast; ``hits``: rays that hit after the re-cast.
    """

    radiance: np.ndarray
    rays: int
    first_hits: int
    hits: int



#: horizontal nudge (m) of a ray's start point for the re-cast of a miss (a ray that slipped
#: between two triangles): 1 mm, 0.0012 px at 0.82 m GSD, for 1-10 rays per million
NUDGE_M = 1e-3


class RayCaster:
    """Batched lines of sight through a :class:`Renderer`'s scene: the main imager's rays.

    Rays are formed inside Dr.Jit from float64-derived keyframes (:func:`scene.pinhole.
    ray_keyframes`, 21 floats each), one keyframe per sampling instant, and film coordinates
    ``qx = (col + 0.5) / cols - 0.5``, ``qy = (row + 0.5) / rows - 0.5`` of the keyframes'
    focal plane, exactly as the tracker's pinhole sensor forms them. Each ray is intersected
    with ``ray_intersect_preliminary(coherent=True)`` (a miss is re-cast once with its start
    nudged by :data:`NUDGE_M`), and its radiance is the direct integrator's mean: the hit
    shape's diffuse reflectance (terrain or cloud texture, bilinear) times
    ``E max(0, n . s) V / pi + L_sky F`` with the geometric normal n, the sun direction s, a
    shadow ray V toward the sun (``shadows``), and the terrain face's sky-view factor F (the
    cosine-weighted unoccluded fraction of its hemisphere, baked once per face from
    ``sky_view_dirs`` rays; 1 on clouds): the same mean as the tracker's ``direct``
    integrator, without its Monte Carlo noise (the surface is Lambertian, so its radiance
    does not depend on the view).

    Every batch has ``batch_rays`` lanes (the last one padded) and the sizes of a call (K,
    R, C, the ray offset) enter as opaque values, so the kernel compiles once per caster
    (checked with Dr.Jit's kernel history: no cache miss across different K and C).

    Parameters
    ----------
    renderer : the scene (terrain mesh, clouds, sun, sky, ray start plane ``z_start_m``).
    batch_rays : rays per kernel launch (fixed), >= 1024.
    shadows : cast a shadow ray per hit (False: no cast shadows, about half the time).
    sky_view_dirs : rays per terrain face for its sky-view factor (0: F = 1, the sky fully
        visible everywhere; +10 % of the sky term on a 27 deg RMS slope terrain).
    sky_view : a per-face sky-view factor already baked (``RayCaster.sky_view`` of another
        caster of this renderer), instead of baking it again.
    path : 'terrain' (no clouds): the hit point's planar uv into the albedo as a
        ``mi.Texture2f`` (bilinear, clamp: the bitmap's own texel convention) and per-face
        sun and sky terms gathered by the primitive index (1.2-1.4x faster here);
        'general': the full surface interaction and the hit shape's BSDF reflectance
        (terrain or clouds); 'auto': 'terrain' unless the renderer has clouds.
    """

    def __init__(self, renderer: Renderer, batch_rays: int = 1 << 20, shadows: bool = True,
                 sky_view_dirs: int = 32, path: str = "auto",
                 sky_view: np.ndarray | None = None):
        if batch_rays < 1024:
            raise ValueError(f"batch_rays must be >= 1024, got {batch_rays}")
        if sky_view_dirs < 0:
            raise ValueError(f"sky_view_dirs must be >= 0, got {sky_view_dirs}")
        self._renderer = renderer
        self._mi, self._dr = renderer._mi, renderer._dr
        self._scene = renderer._scene
        self.batch_rays = int(batch_rays)
        self.shadows = bool(shadows)
        self.terrain = renderer.terrain
        self.z_start_m = renderer.z_start_m
        sun = renderer.sun
        self._to_sun = [float(v) for v in sun.to_sun_enu]
        self._sun_e = float(sun.irradiance)
        self._sky = float(sun.sky_radiance)
        self._terrain_shape = next(sh for sh in self._scene.shapes() if sh.id() == "terrain")
        clouds = renderer.clouds
        has_clouds = clouds is not None and clouds.cover > 0.0
        if path not in ("auto", "terrain", "general"):
            raise ValueError(f"path must be 'auto', 'terrain' or 'general', got {path!r}")
        if path == "terrain" and has_clouds:
            raise ValueError("path 'terrain' cannot see clouds: use 'auto' or 'general'")
        self.path = "general" if (path == "general" or has_clouds) else "terrain"
        t0 = time.perf_counter()
        origins, normals = self._terrain_faces()
        if sky_view is not None:
            sky_view = np.asarray(sky_view, dtype=np.float64)
            if sky_view.shape != (len(normals),):
                raise ValueError(f"sky_view must be ({len(normals)},) (one per terrain face), "
                                 f"got {sky_view.shape}")
        elif sky_view_dirs and self._sky > 0.0:
            sky_view = self._bake_sky_view(origins, normals, sky_view_dirs)
        else:
            sky_view = np.ones(len(normals))
        #: the per-face sky-view factor (pass it to another caster of the same renderer)
        self.sky_view = sky_view
        self.sky_view_mean = float(sky_view.mean())
        self.sky_view_s = time.perf_counter() - t0
        mi, dr = self._mi, self._dr
        self._sky_view = mi.Float(sky_view.astype(np.float32))
        if self.path == "terrain":
            # per face: the sun term E max(0, n . s) / pi and the sky term L_sky F
            cos = np.clip(normals @ np.asarray(self._to_sun), 0.0, None)
            self._face_sun = mi.Float((self._sun_e * cos / np.pi).astype(np.float32))
            self._face_sky = mi.Float((self._sky * sky_view).astype(np.float32))
            terrain = renderer.terrain
            self._size = terrain.size_m
            self._tex = mi.Texture2f(
                mi.TensorXf(np.ascontiguousarray(terrain.albedo, dtype=np.float32)[..., None]),
                use_accel=False, filter_mode=dr.FilterMode.Linear,
                wrap_mode=dr.WrapMode.Clamp)

    @property
    def variant(self) -> str:
        return self._renderer.variant

    def _terrain_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """Terrain face centroids lifted 1 cm along their normals, and unit normals (up)."""
        params = self._mi.traverse(self._terrain_shape)
        v = np.asarray(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
        f = np.asarray(params["faces"]).reshape(-1, 3).astype(np.int64)
        p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        n = np.cross(p1 - p0, p2 - p0)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        n[n[:, 2] < 0] *= -1.0
        return (p0 + p1 + p2) / 3.0 + 0.01 * n, n

    def _bake_sky_view(self, org: np.ndarray, n: np.ndarray, n_dirs: int) -> np.ndarray:
        """Per terrain face: the cosine-weighted fraction of n_dirs hemisphere directions
        (a Fibonacci set, turned per face by a golden-ratio angle) that escape the scene."""
        mi, dr = self._mi, self._dr
        n_faces = len(n)
        j = np.arange(n_dirs)
        r = np.sqrt((j + 0.5) / n_dirs)  # cosine-weighted: uniform on the disc, lifted
        phi = j * 2.399963229728653
        local = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r * r)])
        org_b = mi.Point3f(*[mi.Float(org[:, k].astype(np.float32)) for k in range(3)])
        n_b = mi.Vector3f(*[mi.Float(n[:, k].astype(np.float32)) for k in range(3)])
        loc_b = [mi.Float(local[:, k].astype(np.float32)) for k in range(3)]
        total = n_faces * n_dirs
        free = np.zeros(n_faces)
        u32 = mi.UInt32
        for base in range(0, total, self.batch_rays):
            idx = dr.arange(u32, self.batch_rays) + dr.opaque(u32, base)
            active = idx < dr.opaque(u32, total)
            idx = dr.minimum(idx, dr.opaque(u32, total - 1))
            face = idx // dr.opaque(u32, n_dirs)
            d = idx - face * dr.opaque(u32, n_dirs)
            turn = dr.fma(mi.Float(face), 0.6180339887, 0.0)
            ang = (turn - dr.floor(turn)) * (2.0 * np.pi)
            lx, ly, lz = (dr.gather(mi.Float, b, d) for b in loc_b)
            ca, sa = dr.cos(ang), dr.sin(ang)
            frame = mi.Frame3f(dr.gather(mi.Vector3f, n_b, face))
            w = frame.to_world(mi.Vector3f(ca * lx - sa * ly, sa * lx + ca * ly, lz))
            o = dr.gather(mi.Point3f, org_b, face)
            blocked = self._scene.ray_test(mi.Ray3f(o, w), active)
            ok = dr.select(active & ~blocked, 1.0, 0.0)
            dr.eval(ok)
            cnt = min(self.batch_rays, total - base)
            ids = base + np.arange(cnt)
            free += np.bincount(ids // n_dirs, weights=np.asarray(ok)[:cnt],
                                minlength=n_faces)
        return free / n_dirs

    def _kernel(self, kf, qx, qy, base: int, total: int, n_rows: int, n_cols: int):
        mi, dr = self._mi, self._dr
        u32 = mi.UInt32
        idx = dr.arange(u32, self.batch_rays) + dr.opaque(u32, base)
        total_o = dr.opaque(u32, total)
        active = idx < total_o
        idx = dr.minimum(idx, total_o - 1)
        per_k = dr.opaque(u32, n_rows * n_cols)
        cols_o = dr.opaque(u32, n_cols)
        k = idx // per_k
        rem = idx - k * per_k
        r = rem // cols_o
        c = rem - r * cols_o
        x = dr.gather(mi.Float, qx, c)
        y = dr.gather(mi.Float, qy, r)

        def g(j):
            return dr.gather(mi.Float, kf, k * KEYFRAME_FLOATS + j)

        den = g(9) * x + g(10) * y + g(11)
        o = mi.Point3f(g(0) + (g(3) * x + g(4) * y + g(5)) / den,
                       g(1) + (g(6) * x + g(7) * y + g(8)) / den, g(2))
        d = dr.normalize(mi.Vector3f(g(12) * x + g(13) * y + g(14),
                                     g(15) * x + g(16) * y + g(17),
                                     g(18) * x + g(19) * y + g(20)))
        scene = self._scene
        ray = mi.Ray3f(o, d)
        pi = scene.ray_intersect_preliminary(ray, coherent=True, active=active)
        first = active & pi.is_valid()
        miss = active & ~first
        o2 = o + mi.Vector3f(NUDGE_M, NUDGE_M, 0.0)
        pi2 = scene.ray_intersect_preliminary(mi.Ray3f(o2, d), coherent=False, active=miss)
        second = miss & pi2.is_valid()
        pi = dr.select(second, pi2, pi)
        hit = first | second
        ray = mi.Ray3f(dr.select(second, o2, o), d)
        s = mi.Vector3f(*self._to_sun)
        if self.path == "terrain":
            p = ray.o + pi.t * ray.d
            w, h = self._size
            uv = mi.Point2f((p.x + 0.5 * w) * (1.0 / w), (0.5 * h - p.y) * (1.0 / h))
            albedo = self._tex.eval(uv, hit)[0]
            sun = dr.gather(mi.Float, self._face_sun, pi.prim_index, hit)
            sky = dr.gather(mi.Float, self._face_sky, pi.prim_index, hit)
            if self.shadows:  # start 2 cm toward the sun (off the lit face)
                blocked = scene.ray_test(mi.Ray3f(p + 0.02 * s, s), hit & (sun > 0.0))
                sun = dr.select(blocked, 0.0, sun)
            rad = albedo * (sun + sky)
        else:
            si = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal | mi.RayFlags.UV,
                                                hit)
            refl = si.bsdf().eval_diffuse_reflectance(si, hit)
            albedo = (refl[0] + refl[1] + refl[2]) * (1.0 / 3.0)
            cos = dr.maximum(dr.dot(si.n, s), 0.0)
            lit = mi.Float(1.0)
            if self.shadows:
                blocked = scene.ray_test(si.spawn_ray(s), hit & (cos > 0.0))
                lit = dr.select(blocked, 0.0, 1.0)
            on_terrain = hit & (pi.shape == mi.ShapePtr(self._terrain_shape))
            sky = dr.select(on_terrain, self._sky * dr.gather(
                mi.Float, self._sky_view, pi.prim_index, on_terrain), self._sky)
            rad = albedo * (self._sun_e * cos * lit * (1.0 / np.pi) + sky)
        rad = dr.select(hit, rad, dr.nan)
        return rad, first, hit

    def cast_radiance(self, keyframes: np.ndarray, qx: np.ndarray,
                      qy: np.ndarray | None = None) -> CastResult:
        """Radiance (K, R, C) of the rays of every keyframe x film row qy (R,) x column qx (C,).

        Parameters
        ----------
        keyframes : (K, 21) float64 from :func:`scene.pinhole.ray_keyframes`, one per instant.
        qx : film x coordinates (C,) in [-0.5, 0.5] of the keyframes' focal plane (columns).
        qy : film y coordinates (R,); default one row at qy = 0 (the focal plane's centre row).
        """
        mi, dr = self._mi, self._dr
        kf = np.asarray(keyframes, dtype=np.float64)
        if kf.ndim != 2 or kf.shape[1] != KEYFRAME_FLOATS or len(kf) < 1:
            raise ValueError(f"keyframes must be (K, {KEYFRAME_FLOATS}), got {kf.shape}")
        qx = np.atleast_1d(np.asarray(qx, dtype=np.float64))
        qy = np.zeros(1) if qy is None else np.atleast_1d(np.asarray(qy, dtype=np.float64))
        if qx.ndim != 1 or qy.ndim != 1 or not (np.all(np.isfinite(qx))
                                                and np.all(np.isfinite(qy))):
            raise ValueError("qx and qy must be finite 1-D arrays")
        n_k, n_r, n_c = len(kf), len(qy), len(qx)
        total = n_k * n_r * n_c
        if total >= 2**32 - self.batch_rays:
            raise ValueError(f"{total} rays in one call: split it (< 2^32)")
        kf_buf = mi.Float(kf.astype(np.float32).ravel())
        qx_buf = mi.Float(qx.astype(np.float32))
        qy_buf = mi.Float(qy.astype(np.float32))
        out = np.empty(total, np.float32)
        first_hits = hits = 0
        for base in range(0, total, self.batch_rays):
            rad, first, hit = self._kernel(kf_buf, qx_buf, qy_buf, base, total, n_r, n_c)
            dr.eval(rad, first, hit)
            n = min(self.batch_rays, total - base)
            out[base:base + n] = np.asarray(rad)[:n]
            first_hits += int(np.count_nonzero(np.asarray(first)[:n]))
            hits += int(np.count_nonzero(np.asarray(hit)[:n]))
        img = out.reshape(n_k, n_r, n_c)
        if hits < total:
            img = _fill_misses(img)
        return CastResult(img, total, first_hits, hits)


def _fill_misses(img: np.ndarray) -> np.ndarray:
    """NaNs of (..., C) replaced by the nearest finite value along the last axis (to the
    left, else to the right); a row with no finite value stays NaN."""
    bad = ~np.isfinite(img)
    c = img.shape[-1]
    pos = np.arange(c)
    left = np.maximum.accumulate(np.where(bad, -1, pos), axis=-1)
    right = np.flip(np.minimum.accumulate(np.flip(np.where(bad, c, pos), -1), axis=-1), -1)
    dl = np.where(left >= 0, pos - left, c + 1)
    dr_ = np.where(right < c, right - pos, c + 1)
    src = np.where(dl <= dr_, left, right)
    src = np.clip(src, 0, c - 1)
    filled = np.take_along_axis(img, src, axis=-1)
    return np.where(bad, filled, img)

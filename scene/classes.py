"""The seed paper's five scene classes as seeded procedural tiles (albedo + DEM). Pure numpy.

Janschek, Tchernykh & Dyblenko (Table 2) tested the correlator on IKONOS imagery resampled
from 0.25 m to 0.75 m, in five classes. Each generator here draws a tile in the local ENU
frame (north-up, centred on the origin; see :mod:`scene.terrain`) whose statistics follow the
paper's description:

``urban``
    a street grid, lots and buildings (roof albedo 0.12-0.65, heights 4-30 m in the DEM, so
    the renderer casts their shadows): high contrast spread evenly over the tile.
``rural``
    large fields (80-250 m) in a regular, rotated parcel grid; each field nearly uniform with
    weak crop rows; hedges and tracks on the boundaries; a few strongly textured patches
    (woods, hamlets).
``mountain``
    ridged fractal relief (default RMS 4 % of the tile side: ~30 deg slopes), rock and
    vegetation texture below a noisy snow line, nearly textureless snow (local contrast
    < 1 %) above it, and a cloud layer.
``waves``
    dark water whose brightness follows the sun-facing slope of a directional wind-sea
    spectrum (peak wavelength 20-45 m): a distinct wave pattern, flat DEM.
``calm_water``
    dark water with 0.5 % low-frequency and 0.2 % fine variations: practically no texture.

A :class:`CloudLayer` is a separate surface at a height above the terrain, so clouds move
with parallax against the ground and cast shadows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scene import SCENE_CLASSES
from scene.terrain import Terrain, fractal_noise, procedural_terrain

#: default RMS relief (m) of each class when the scenario does not set one
DEFAULT_RELIEF_M = {"urban": 2.0, "rural": 8.0, "mountain": None, "waves": 0.0,
                    "calm_water": 0.0, "procedural": 15.0}
#: mountain relief when not given: this fraction of the tile side (steep, ~30 deg slopes)
MOUNTAIN_RELIEF_PER_SIZE = 0.04


@dataclass(frozen=True)
class CloudLayer:
    """Clouds as a surface above the terrain, on a square grid centred on the ENU origin.

    ``density`` (M, M) in [0, 1] sits on nodes ``cell_m`` apart, row 0 north. The cloud top is
    at ``base_m + thickness_m * density`` where density > 0; clear cells have no surface.
    ``albedo`` is the mean diffuse reflectance of the cloud top; ``texture`` (M, M), if given,
    multiplies it node by node (the cloud tops' own brightness structure).
    """

    density: np.ndarray
    cell_m: float
    base_m: float
    thickness_m: float = 100.0
    albedo: float = 0.8
    texture: np.ndarray | None = None

    def __post_init__(self) -> None:
        d = self.density
        if d.ndim != 2 or d.shape[0] != d.shape[1] or d.shape[0] < 3:
            raise ValueError("cloud density must be a square (M, M) array, M >= 3")
        if not np.all(np.isfinite(d)) or d.min() < 0.0 or d.max() > 1.0:
            raise ValueError("cloud density must be finite and within [0, 1]")
        if self.texture is not None and self.texture.shape != d.shape:
            raise ValueError("cloud texture must have the density's shape")
        if self.base_m <= 0.0 or self.thickness_m < 0.0 or not 0.0 < self.albedo <= 1.0:
            raise ValueError("cloud base_m must be > 0, thickness_m >= 0, 0 < albedo <= 1")

    @property
    def size_m(self) -> float:
        return (self.density.shape[0] - 1) * self.cell_m

    @property
    def top_m(self) -> float:
        return self.base_m + self.thickness_m

    @property
    def cover(self) -> float:
        """Fraction of the layer's cells with cloud."""
        return float(np.mean(self.density > 0.0))

    def albedo_map(self) -> np.ndarray:
        """Cloud-top albedo per node (M, M), row 0 north."""
        tex = 1.0 if self.texture is None else self.texture
        return np.clip(self.albedo * tex * np.ones_like(self.density), 0.0, 1.0)

    def mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices (V, 3) m (ENU), faces (F, 3) and texture uv (V, 2) of the cloud tops.

        Only cells whose four corners are cloudy get triangles; uv maps the node grid onto
        :meth:`albedo_map` (texel centres on the nodes).
        """
        m = self.density.shape[0]
        half = self.size_m / 2.0
        east = -half + np.arange(m) * self.cell_m
        north = half - np.arange(m) * self.cell_m
        ee, nn = np.meshgrid(east, north)
        z = self.base_m + self.thickness_m * self.density
        verts = np.column_stack([ee.ravel(), nn.ravel(), z.ravel()])
        idx = np.arange(m * m).reshape(m, m)
        cloudy = ((self.density[:-1, :-1] > 0) & (self.density[:-1, 1:] > 0)
                  & (self.density[1:, :-1] > 0) & (self.density[1:, 1:] > 0))
        a, b = idx[:-1, :-1][cloudy], idx[:-1, 1:][cloudy]
        c, d = idx[1:, :-1][cloudy], idx[1:, 1:][cloudy]
        faces = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])])
        jj, ii = np.meshgrid(np.arange(m), np.arange(m))
        uv = np.column_stack([(jj.ravel() + 0.5) / m, (ii.ravel() + 0.5) / m])
        return verts, faces, uv


#: clouds whose layer would need more cells than this per side get coarser cells
MAX_CLOUD_CELLS = 4096


def cloud_cell_m(extent_m: float, cell_m: float) -> float:
    """A cloud layer's cell size, m: ``cell_m``, coarsened so that a layer ``extent_m`` wide
    has at most :data:`MAX_CLOUD_CELLS` cells a side."""
    return max(cell_m, extent_m / MAX_CLOUD_CELLS)


def cloud_layer(size_m: float, cell_m: float, cover: float, base_m: float,
                rng: np.random.Generator, thickness_m: float = 100.0,
                albedo: float = 0.8) -> CloudLayer:
    """Seeded fractal cumulus field covering ``cover`` of a square of side ``size_m``."""
    from scipy import ndimage

    if not 0.0 <= cover < 1.0:
        raise ValueError(f"cloud cover must be within [0, 1), got {cover}")
    m = int(round(size_m / cell_m)) + 1
    if m < 3:
        raise ValueError("cloud layer smaller than 2 cells; lower cell_m")
    # puffs of ~300 m and up: a steep spectrum cut below 300 m wavelength
    field = fractal_noise((m, m), 3.2, rng, cutoff_cycles=max(1.0, m * cell_m / 3000.0))
    field = ndimage.gaussian_filter(field, 15.0 / cell_m, mode="wrap")
    field /= field.std()
    if cover <= 0.0:
        density = np.zeros((m, m))
    else:
        thr = np.quantile(field, 1.0 - cover)
        x = np.clip((field - thr) / 0.8, 0.0, 1.0)
        density = np.where(x > 0, np.maximum(x * x * (3.0 - 2.0 * x), 1e-3), 0.0)
    texture = 1.0 + 0.12 * fractal_noise((m, m), 2.0, rng, cutoff_cycles=4.0)
    return CloudLayer(density.astype(np.float32), cell_m, base_m, thickness_m, albedo,
                      texture.astype(np.float32))


# --------------------------------------------------------------------------- helpers


def _lowpass(shape: tuple[int, int], sigma_texels: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-std Gaussian-filtered white noise with correlation length ~sigma_texels."""
    import scipy.fft as sfft

    spec = sfft.rfft2(rng.standard_normal(shape), workers=-1)
    fy = sfft.fftfreq(shape[0])[:, None]
    fx = sfft.rfftfreq(shape[1])[None, :]
    spec *= np.exp(-2.0 * np.pi**2 * sigma_texels**2 * (fx**2 + fy**2))
    spec[0, 0] = 0.0
    out = sfft.irfft2(spec, s=shape, workers=-1)
    return ((out - out.mean()) / out.std()).astype(np.float32)


def _intervals(n: int, lo: int, hi: int, rng: np.random.Generator) -> np.ndarray:
    """Cumulative cut positions of random lengths in [lo, hi] texels covering 0..n."""
    lengths = rng.integers(lo, hi + 1, size=n // max(lo, 1) + 2)
    cuts = np.concatenate([[0], np.cumsum(lengths)])
    return cuts[: np.searchsorted(cuts, n) + 1]


def _grid_axis(n: int, texel_m: float, rng: np.random.Generator):
    """Along one axis: lot id per texel (-1 on streets) and distance to the lot edge (m)."""
    t = max(texel_m, 1e-9)
    block_cuts = _intervals(n, int(60 / t), int(110 / t), rng)
    street = rng.integers(int(10 / t), int(16 / t) + 1, size=len(block_cuts))
    lot_id = np.full(n, -1, dtype=np.int64)
    edge = np.zeros(n)
    x = np.arange(n)
    next_id = 0
    for b0, b1, w in zip(block_cuts[:-1], block_cuts[1:], street[:-1], strict=True):
        s0 = b0 + w // 2
        s1 = b1 - (w - w // 2)
        if s1 - s0 < 4:
            continue
        # lots of 12-35 m inside the block
        lot_cuts = s0 + _intervals(s1 - s0, int(12 / t), int(35 / t), rng)
        lot_cuts[-1] = s1
        for l0, l1 in zip(lot_cuts[:-1], lot_cuts[1:], strict=True):
            sel = slice(max(l0, 0), min(l1, n))
            lot_id[sel] = next_id
            edge[sel] = np.minimum(x[sel] - l0 + 0.5, l1 - x[sel] - 0.5) * t
            next_id += 1
    return lot_id, edge, next_id


def _dem_nodes(size_m: float, dem_spacing_m: float) -> int:
    m = int(round(size_m / dem_spacing_m)) + 1
    if m < 3:
        raise ValueError("scene tile smaller than 2 DEM cells; lower dem_spacing_m")
    return m


def _sample_at_nodes(field: np.ndarray, texel_m: float, m: int, spacing_m: float) -> np.ndarray:
    """Nearest-texel values of a texel field at the DEM nodes (edges clamped)."""
    n = field.shape[0]
    idx = np.clip(np.floor(np.arange(m) * spacing_m / texel_m).astype(int), 0, n - 1)
    return field[np.ix_(idx, idx)]


def _texels(size_m: float, texel_m: float) -> int:
    n = int(round(size_m / texel_m))
    if n < 16:
        raise ValueError("scene tile smaller than 16 texels; lower texel_m")
    return n


# --------------------------------------------------------------------------- classes


def urban(size_m: float, texel_m: float, dem_spacing_m: float, relief_rms_m: float,
          rng: np.random.Generator) -> Terrain:
    """Street grid, lots and buildings; building heights go into the DEM (their shadows)."""
    from scipy import ndimage

    n = _texels(size_m, texel_m)
    ids_y, edge_y, ny = _grid_axis(n, texel_m, rng)
    ids_x, edge_x, nx = _grid_axis(n, texel_m, rng)
    on_lot = (ids_y[:, None] >= 0) & (ids_x[None, :] >= 0)
    lot = np.where(on_lot, ids_y[:, None] * max(nx, 1) + ids_x[None, :], 0)
    n_lots = max(ny * nx, 1)
    setback = rng.uniform(1.0, 5.0, n_lots)
    roof = rng.uniform(0.12, 0.65, n_lots)
    yard = np.where(rng.random(n_lots) < 0.5, rng.uniform(0.06, 0.12, n_lots),
                    rng.uniform(0.22, 0.35, n_lots))  # vegetation or paving
    height = rng.uniform(4.0, 30.0, n_lots) * (rng.random(n_lots) < 0.85)
    edge = np.minimum(edge_y[:, None], edge_x[None, :])
    is_roof = on_lot & (edge > setback[lot]) & (height[lot] > 0)
    fine = fractal_noise((n, n), 1.0, rng, cutoff_cycles=4.0).astype(np.float32)
    asphalt = 0.09 + 0.015 * fine
    albedo = np.where(on_lot, np.where(is_roof, roof[lot], yard[lot]), asphalt)
    albedo = albedo * (1.0 + 0.06 * fine)
    # road markings and vehicles: sparse small bright / dark spots on the streets
    spots = ndimage.maximum_filter(rng.random((n, n)) > 0.9985, size=max(2, int(2 / texel_m)))
    albedo = np.where(spots & ~on_lot, rng.choice([0.03, 0.6], size=(n, n)), albedo)
    albedo = np.clip(albedo, 0.02, 0.95).astype(np.float32)
    m = _dem_nodes(size_m, dem_spacing_m)
    bld = _sample_at_nodes(np.where(is_roof, height[lot], 0.0), texel_m, m, dem_spacing_m)
    ground = _lowpass((m, m), 60.0 / dem_spacing_m, rng) * relief_rms_m
    return Terrain(albedo, texel_m, (bld + ground).astype(np.float32), dem_spacing_m)


def rural(size_m: float, texel_m: float, dem_spacing_m: float, relief_rms_m: float,
          rng: np.random.Generator) -> Terrain:
    """Large, nearly uniform fields in a regular parcel grid, hedges, and textured patches."""
    n = _texels(size_m, texel_m)
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32) * texel_m
    ang = rng.uniform(0, np.pi / 2)
    u = np.cos(ang) * xx + np.sin(ang) * yy  # parcel grid axes (rotated)
    v = -np.sin(ang) * xx + np.cos(ang) * yy
    pu, pv = rng.uniform(150.0, 250.0), rng.uniform(80.0, 140.0)
    iu, iv = np.floor(u / pu).astype(np.int64), np.floor(v / pv).astype(np.int64)
    nv = int(iv.max() - iv.min()) + 1
    inv = (iu - iu.min()) * nv + (iv - iv.min())
    k = int(inv.max()) + 1
    base = rng.uniform(0.10, 0.35, k)[inv]
    row_period = rng.uniform(3.0, 8.0, k)[inv]
    row_amp = rng.uniform(0.005, 0.03, k)[inv]
    along_u = rng.random(k)[inv] < 0.5
    rows = np.sin(2 * np.pi * np.where(along_u, u, v) / row_period)
    weak = _lowpass((n, n), 20.0 / texel_m, rng)
    albedo = base * (1.0 + row_amp * rows + 0.03 * weak)
    # hedges / tracks on the parcel boundaries (2-4 m, dark or bright)
    du = np.minimum(np.mod(u, pu), pu - np.mod(u, pu))
    dv = np.minimum(np.mod(v, pv), pv - np.mod(v, pv))
    hedge = np.minimum(du, dv) < rng.uniform(1.0, 2.0)
    albedo = np.where(hedge, 0.06 + 0.02 * weak, albedo)
    # strongly textured patches: woods / hamlets covering ~10 % of the tile
    blob = _lowpass((n, n), 40.0 / texel_m, rng)
    patch = blob > np.quantile(blob, 0.90)
    canopy = fractal_noise((n, n), 1.6, rng, cutoff_cycles=8.0)
    albedo = np.where(patch, 0.12 * (1.0 + 0.5 * canopy), albedo)
    albedo = np.clip(albedo, 0.02, 0.95).astype(np.float32)
    m = _dem_nodes(size_m, dem_spacing_m)
    dem = _lowpass((m, m), 60.0 / dem_spacing_m, rng) * relief_rms_m  # gentle: ~8 deg at 8 m
    return Terrain(albedo, texel_m, dem.astype(np.float32), dem_spacing_m)


def mountain(size_m: float, texel_m: float, dem_spacing_m: float, relief_rms_m: float,
             rng: np.random.Generator, snow_fraction: float = 0.4) -> Terrain:
    """Ridged relief; rock / vegetation texture below a noisy snow line, smooth snow above."""
    from scipy import ndimage

    n = _texels(size_m, texel_m)
    m = _dem_nodes(size_m, dem_spacing_m)
    ridged = 1.0 - np.abs(fractal_noise((m, m), 4.4, rng))
    ridged = ndimage.gaussian_filter(ridged, 6.0 / dem_spacing_m, mode="nearest")
    dem = (ridged - ridged.mean()) / max(ridged.std(), 1e-9) * relief_rms_m
    zoom = (n / m, n / m)
    h = ndimage.zoom(dem, zoom, order=1, mode="nearest")[:n, :n]
    if h.shape != (n, n):
        h = np.pad(h, ((0, n - h.shape[0]), (0, n - h.shape[1])), mode="edge")
    wobble = _lowpass((n, n), 15.0 / texel_m, rng) * 0.15 * max(relief_rms_m, 1.0)
    snow = (h + wobble) > np.quantile(h + wobble, 1.0 - snow_fraction)
    rock = 0.22 * (1.0 + 0.45 * fractal_noise((n, n), 1.8, rng, cutoff_cycles=8.0))
    veg = 0.08 * (1.0 + 0.35 * fractal_noise((n, n), 1.4, rng, cutoff_cycles=8.0))
    low = h < np.quantile(h, 0.3)
    ground = np.where(low, veg, rock)
    snow_alb = 0.85 * (1.0 + 0.004 * _lowpass((n, n), 3.0 / texel_m, rng))
    albedo = np.clip(np.where(snow, snow_alb, ground), 0.02, 0.95).astype(np.float32)
    return Terrain(albedo, texel_m, dem.astype(np.float32), dem_spacing_m)


def waves(size_m: float, texel_m: float, dem_spacing_m: float, relief_rms_m: float,
          rng: np.random.Generator, sun_azimuth_deg: float = 140.0) -> Terrain:
    """Dark water brightened on the sun-facing slopes of a directional wind sea."""
    import scipy.fft as sfft
    from scipy import ndimage

    n = _texels(size_m, texel_m)
    wavelength_m = rng.uniform(20.0, 45.0)
    direction = rng.uniform(0.0, 2 * np.pi)
    ky = sfft.fftfreq(n, d=texel_m)[:, None]  # cycles/m, +row = south
    kx = sfft.fftfreq(n, d=texel_m)[None, :]
    k = np.hypot(kx, ky)
    kp = 1.0 / wavelength_m
    theta = np.arctan2(-ky, kx)  # toward north = +y
    spread = np.cos(0.5 * (theta - direction)) ** 16  # cos^2s spreading, one-sided
    spec = np.exp(-0.5 * ((k - kp) / (0.18 * kp)) ** 2) * spread
    white = sfft.fft2(rng.standard_normal((n, n)), workers=-1)
    eta = sfft.ifft2(white * np.sqrt(spec), workers=-1).real
    # slope toward the sun (east-north components of the gradient)
    az = np.deg2rad(sun_azimuth_deg)
    gy, gx = np.gradient(eta)
    slope = gx * np.sin(az) - gy * np.cos(az)  # row grows southward
    slope /= slope.std()
    fine = fractal_noise((n, n), 1.0, rng, cutoff_cycles=8.0)
    albedo = 0.06 * (1.0 + 0.35 * slope + 0.03 * fine)
    crest = eta > np.quantile(eta, 0.997)  # sparse whitecaps
    albedo = np.where(ndimage.binary_dilation(crest), 0.35, albedo)
    albedo = np.clip(albedo, 0.02, 0.95).astype(np.float32)
    m = _dem_nodes(size_m, dem_spacing_m)
    return Terrain(albedo, texel_m, np.zeros((m, m), np.float32), dem_spacing_m)


def calm_water(size_m: float, texel_m: float, dem_spacing_m: float, relief_rms_m: float,
               rng: np.random.Generator) -> Terrain:
    """Dark water with 0.5 % slow and 0.2 % fine brightness variations."""
    n = _texels(size_m, texel_m)
    slow = _lowpass((n, n), 80.0 / texel_m, rng)
    fine = fractal_noise((n, n), 1.0, rng, cutoff_cycles=8.0)
    albedo = (0.05 * (1.0 + 0.005 * slow + 0.002 * fine)).astype(np.float32)
    m = _dem_nodes(size_m, dem_spacing_m)
    return Terrain(albedo, texel_m, np.zeros((m, m), np.float32), dem_spacing_m)


_GENERATORS = {"urban": urban, "rural": rural, "mountain": mountain, "waves": waves,
               "calm_water": calm_water}


def class_relief_m(kind: str, size_m: float, relief_rms_m: float | None = None) -> float:
    """A scene class's RMS relief (m): ``relief_rms_m`` if given, else the class's default
    (a mountain tile's grows with its side ``size_m``)."""
    relief = DEFAULT_RELIEF_M.get(kind, 0.0) if relief_rms_m is None else relief_rms_m
    return MOUNTAIN_RELIEF_PER_SIZE * size_m if relief is None else relief


def scene_class(kind: str, size_m: float, texel_m: float, dem_spacing_m: float,
                rng: np.random.Generator, relief_rms_m: float | None = None,
                sun_azimuth_deg: float = 140.0) -> Terrain:
    """A seeded tile of one scene class ('procedural' is the generic rural/suburban tile)."""
    relief = class_relief_m(kind, size_m, relief_rms_m)
    if kind == "procedural":
        return procedural_terrain(size_m, texel_m, dem_spacing_m, relief, rng)
    if kind not in _GENERATORS:
        raise ValueError(f"unknown scene class {kind!r}; use one of "
                         + ", ".join(("procedural",) + SCENE_CLASSES))
    if kind == "waves":
        return waves(size_m, texel_m, dem_spacing_m, relief, rng, sun_azimuth_deg)
    return _GENERATORS[kind](size_m, texel_m, dem_spacing_m, relief, rng)


def local_contrast(albedo: np.ndarray, window: int) -> np.ndarray:
    """Std / mean of the albedo in non-overlapping windows of ``window`` texels."""
    n0, n1 = (albedo.shape[0] // window) * window, (albedo.shape[1] // window) * window
    a = albedo[:n0, :n1].reshape(n0 // window, window, n1 // window, window)
    return a.std(axis=(1, 3)) / a.mean(axis=(1, 3))

"""Terrain tiles (albedo + DEM) in the scene's local ENU frame. Pure numpy.

A tile is centred on the ENU origin. Array row 0 is the northern edge, column 0 the western
edge (a north-up image). Albedo texels are cells of ``texel_m``; DEM values sit on a node grid
of ``dem_spacing_m`` whose outer nodes lie on the tile edges. ``procedural_draws`` gives a
procedural tile's DEM and any window of its albedo (the same texels) without building the
whole albedo: what a bound on one frame's footprint needs of a large tile.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Terrain:
    """Albedo texture (Ny, Nx) in [0, 1] and DEM heights (My, Mx) in m on one tile."""

    albedo: np.ndarray
    texel_m: float
    dem_m: np.ndarray
    dem_spacing_m: float
    #: texels (albedo's shape) and DEM nodes (dem_m's shape) that were nodata in the user's
    #: files and are filled (scene.geotiff); None: none
    nodata_albedo: np.ndarray | None = None
    nodata_dem: np.ndarray | None = None
    #: one-line notes on how the files were taken (a DEM edge-extended, nodata filled)
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.albedo.ndim != 2 or self.dem_m.ndim != 2:
            raise ValueError("albedo and dem_m must be 2-D arrays")
        if not (np.all(np.isfinite(self.albedo)) and np.all(np.isfinite(self.dem_m))):
            raise ValueError("albedo and dem_m must be finite (no NaN holes)")
        w, h = self.size_m
        if (
            abs((self.dem_m.shape[1] - 1) * self.dem_spacing_m - w) > 1e-6 * w
            or abs((self.dem_m.shape[0] - 1) * self.dem_spacing_m - h) > 1e-6 * h
        ):
            raise ValueError(
                f"DEM node grid {self.dem_m.shape} x {self.dem_spacing_m} m does not span the "
                f"albedo tile {w} x {h} m"
            )
        for mask, ref, name in ((self.nodata_albedo, self.albedo, "nodata_albedo"),
                                (self.nodata_dem, self.dem_m, "nodata_dem")):
            if mask is not None and mask.shape != ref.shape:
                raise ValueError(f"{name} {mask.shape} must have the shape {ref.shape}")

    @property
    def size_m(self) -> tuple[float, float]:
        """(width east-west, height north-south) of the tile, m."""
        return self.albedo.shape[1] * self.texel_m, self.albedo.shape[0] * self.texel_m

    def height_at(self, east_m: np.ndarray, north_m: np.ndarray) -> np.ndarray:
        """Bilinear DEM height (m) at ENU (east, north); clamped at the tile edges."""
        w, h = self.size_m
        col = (np.asarray(east_m) + w / 2.0) / self.dem_spacing_m
        row = (h / 2.0 - np.asarray(north_m)) / self.dem_spacing_m
        my, mx = self.dem_m.shape
        col = np.clip(col, 0.0, mx - 1.000001)
        row = np.clip(row, 0.0, my - 1.000001)
        c0, r0 = np.floor(col).astype(int), np.floor(row).astype(int)
        fc, fr = col - c0, row - r0
        z = self.dem_m
        top = z[r0, c0] * (1 - fc) + z[r0, c0 + 1] * fc
        bot = z[r0 + 1, c0] * (1 - fc) + z[r0 + 1, c0 + 1] * fc
        return top * (1 - fr) + bot * fr

    def contains(self, east_m: np.ndarray, north_m: np.ndarray, margin_m: float = 0.0):
        """True where (east, north) lies inside the tile by at least margin_m."""
        w, h = self.size_m
        return (np.abs(east_m) <= w / 2.0 - margin_m) & (np.abs(north_m) <= h / 2.0 - margin_m)



def flat_terrain(size_m: float, dem_spacing_m: float) -> Terrain:
    """A flat, textureless tile of side ``size_m`` m on a DEM grid of ``dem_spacing_m`` m:
    the stand-in that ``imc validate`` checks a large tile's geometry on."""
    m = int(round(size_m / dem_spacing_m)) + 1
    return Terrain(np.zeros((16, 16), np.float32), size_m / 16.0,
                   np.zeros((m, m), np.float32), dem_spacing_m)

def fractal_noise(
    shape: tuple[int, int], beta: float, rng: np.random.Generator, cutoff_cycles: float = 1.0
) -> np.ndarray:
    """Zero-mean, unit-std Gaussian noise with power spectrum ~ 1 / f**beta (f > cutoff)."""
    import scipy.fft as sfft

    white = rng.standard_normal(shape)
    spec = sfft.rfft2(white, workers=-1)
    fy = sfft.fftfreq(shape[0])[:, None] * shape[0]
    fx = sfft.rfftfreq(shape[1])[None, :] * shape[1]
    f = np.hypot(fy, fx)
    spec *= np.maximum(f, cutoff_cycles) ** (-beta / 2.0)
    spec[0, 0] = 0.0
    out = sfft.irfft2(spec, s=shape, workers=-1)
    return (out - out.mean()) / out.std()


def nearest_seed(seeds: np.ndarray, n: int, block_px: int = 8) -> np.ndarray:
    """The index of the nearest seed to every texel (row, col) of an n x n grid (a Voronoi
    labelling): a k-d tree's query at every texel, made once per block of ``block_px`` texels
    where the block's centre proves its answer.

    A block whose centre's second-nearest seed is farther than its nearest by more than the
    block's diagonal (``2 r``, r the centre's distance to a corner texel) has one nearest
    seed for every texel (for a texel p, |p - s1| <= d1 + r < d2 - r <= |p - s|); the other
    blocks' texels are queried one by one. The result equals the texel-by-texel query
    (`scipy.spatial.cKDTree`), at ~1/4 of its time on field-sized cells.

    Parameters
    ----------
    seeds : (N, 2) float array of (row, col) positions, texels.
    n : the grid's side, texels.
    block_px : the side of the blocks decided from their centre, texels.

    Returns
    -------
    (n, n) int array of indices into ``seeds``.
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(seeds)
    if len(seeds) < 2:
        return np.zeros((n, n), np.intp)
    nb = -(-n // block_px)
    c = np.arange(nb) * block_px + (block_px - 1) / 2.0
    centres = np.stack(np.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
    d, j = tree.query(centres, k=2, workers=-1)
    r = (block_px - 1) / np.sqrt(2.0)
    sure = (d[:, 1] - d[:, 0]) > 2.0 * r + 1e-9 * n
    labels = np.where(sure, j[:, 0], -1).reshape(nb, nb)
    labels = np.repeat(np.repeat(labels, block_px, 0), block_px, 1)[:n, :n]
    rows, cols = np.nonzero(labels < 0)
    if rows.size:
        _, labels[rows, cols] = tree.query(np.column_stack([rows, cols]).astype(np.float64),
                                           workers=-1)
    return labels


#: the procedural tile's two fractal textures: (spectral exponent beta, cutoff in cycles per
#: tile) of the field-scale texture and of the fine grain
_TEXTURE = (2.2, 2.0)
_FINE = (1.2, 4.0)
#: the DEM's (spectral exponent, cutoff in cycles a tile), as _TEXTURE
_DEM = (3.5, 1.0)


def _tile_sizes(size_m: float, texel_m: float, dem_spacing_m: float) -> tuple[int, int]:
    """(texels, DEM posts) a side of a procedural tile; ValueError when too small."""
    n = int(round(size_m / texel_m))
    m = int(round(size_m / dem_spacing_m)) + 1
    if n < 16 or m < 3:
        raise ValueError("scene tile too small for its texel size / DEM spacing")
    return n, m


def _fields(size_m: float, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The procedural tile's field patches: seed points (N, 2) (row, col) texels and each
    field's albedo (N,)."""
    n_fields = max(4, int((size_m / 60.0) ** 2))
    seeds = rng.uniform(0, n, size=(n_fields, 2))
    return seeds, rng.uniform(0.12, 0.45, size=n_fields)


def _roads(n: int, rng: np.random.Generator) -> tuple[tuple[np.ndarray, float], ...]:
    """Three straight roads: a point (row, col) texels and a direction, rad."""
    out = []
    for _ in range(3):
        p = rng.uniform(0, n, size=2)
        out.append((p, rng.uniform(0, np.pi)))
    return tuple(out)


def _mix(fields: np.ndarray, texture: np.ndarray, fine: np.ndarray, roads, yy: np.ndarray,
         xx: np.ndarray, texel_m: float) -> np.ndarray:
    """The procedural albedo (float32) from its parts on a grid of texels (rows ``yy``
    (R, 1), columns ``xx`` (1, C), float32 texel indices): fields x (1 + 0.25 texture) +
    0.04 fine, and the roads ~6 m wide."""
    albedo = fields * (1.0 + 0.25 * texture) + 0.04 * fine
    for p, ang in roads:
        dist = np.abs((yy - p[0]) * np.cos(ang) - (xx - p[1]) * np.sin(ang)) * texel_m
        albedo = np.where(dist < 3.0, 0.55 + 0.02 * fine, albedo)
    return np.clip(albedo, 0.02, 0.95).astype(np.float32)


def procedural_terrain(
    size_m: float,
    texel_m: float,
    dem_spacing_m: float,
    relief_rms_m: float,
    rng: np.random.Generator,
) -> Terrain:
    """A seeded, rural/suburban-looking tile: field patches, fractal texture and roads.

    The albedo mixes Voronoi field patches (each its own brightness), a multi-scale fractal
    texture (power spectrum ~ f^-2.2, natural-image-like) and a few straight roads; the DEM is a
    smooth fractal surface with the requested RMS relief. :func:`procedural_draws` gives the
    same tile's DEM and any window of its albedo without building the whole albedo.
    """
    n, m = _tile_sizes(size_m, texel_m, dem_spacing_m)
    # field patches: nearest of random seed points, each cell its own albedo
    seeds, field_albedo = _fields(size_m, n, rng)
    yy = np.arange(n, dtype=np.float32)[:, None]  # (row, col) of every texel, broadcast
    xx = np.arange(n, dtype=np.float32)[None, :]
    fields = field_albedo[nearest_seed(seeds, n)]
    texture = fractal_noise((n, n), _TEXTURE[0], rng, cutoff_cycles=_TEXTURE[1])
    fine = fractal_noise((n, n), _FINE[0], rng, cutoff_cycles=_FINE[1])
    albedo = _mix(fields, texture, fine, _roads(n, rng), yy, xx, texel_m)
    dem = fractal_noise((m, m), _DEM[0], rng, cutoff_cycles=_DEM[1]) * relief_rms_m
    return Terrain(albedo=albedo, texel_m=texel_m, dem_m=dem.astype(np.float32),
                   dem_spacing_m=dem_spacing_m)


def fractal_noise_window(shape: tuple[int, int], beta: float, rng: np.random.Generator,
                         rows: tuple[int, int], cols: tuple[int, int],
                         cutoff_cycles: float = 1.0, chunk: int = 256,
                         work: np.ndarray | None = None) -> np.ndarray:
    """The window ``[rows[0]:rows[1], cols[0]:cols[1]]`` of :func:`fractal_noise`'s field
    of ``shape`` drawn from ``rng`` (which it advances as that does), without its whole
    inverse transform or any whole-field array but the spectrum: the white noise drawn and
    transformed along the rows in chunks of ``chunk`` rows, then per chunk of columns the
    transform along the columns, the filter, and the inverse along the columns kept at the
    window's rows only; the inverse along the rows at those rows; the unit standard
    deviation from the spectrum's power (Parseval). Equal to
    ``fractal_noise(shape, ...)[window]`` within the transforms' rounding (~1e-13 relative).
    ``work``: a complex128 array of (shape[0], shape[1] // 2 + 1) to hold the spectrum in
    (a second field then faults no fresh pages in), or None.

    Returns
    -------
    (rows, cols) float64 array, unit-std over the whole field, dimensionless.
    """
    import scipy.fft as sfft

    n0, n1 = shape
    h1 = n1 // 2 + 1
    spec = np.empty((n0, h1), np.complex128) if work is None else work
    buf = np.empty((min(chunk, n0), n1))
    for a in range(0, n0, chunk):
        k = min(chunk, n0 - a)
        rng.standard_normal(out=buf[:k])
        spec[a:a + k] = sfft.rfft(buf[:k], axis=1, workers=-1)
    fy = sfft.fftfreq(n0)[:, None] * n0
    fx = sfft.rfftfreq(n1)[None, :] * n1
    half = n0 // 2 + 1  # the filter's rows for ky >= 0; fftfreq's negative rows mirror them
    mirror = np.r_[np.arange(half), n0 - np.arange(half, n0)]
    weight = np.full(h1, 2.0)  # the half spectrum's columns counted twice, but kx = 0, n1 / 2
    weight[0] = 1.0
    if n1 % 2 == 0:
        weight[-1] = 1.0
    y = np.empty((rows[1] - rows[0], h1), np.complex128)
    power = 0.0
    for c in range(0, h1, chunk):
        d = min(h1, c + chunk)
        z = sfft.fft(spec[:, c:d], axis=0, workers=-1)
        z *= (np.maximum(np.hypot(fy[:half], fx[:, c:d]), cutoff_cycles)
              ** (-beta / 2.0))[mirror]
        if c == 0:
            z[0, 0] = 0.0
        power += float(np.sum(weight[c:d] * (z.real ** 2 + z.imag ** 2)))
        y[:, c:d] = sfft.ifft(z, axis=0, workers=-1, overwrite_x=True)[rows[0]:rows[1]]
    out = sfft.irfft(y, n=n1, axis=1, workers=-1)[:, cols[0]:cols[1]]
    return out / (np.sqrt(power) / (n0 * n1))


@dataclass(frozen=True)
class ProceduralDraws:
    """A procedural tile (:func:`procedural_terrain`) as its random draws, without its
    albedo: the tile's geometry (:meth:`geometry`: its DEM and size) and any window of its
    albedo (:meth:`albedo_window`) built from them."""

    size_m: float
    texel_m: float
    dem_spacing_m: float
    #: the albedo's side, texels
    n: int
    seeds: np.ndarray
    field_albedo: np.ndarray
    #: the stream as it stood before the textures' white noise
    noise_rng: np.random.Generator
    roads: tuple
    dem_m: np.ndarray

    def geometry(self) -> Terrain:
        """The tile's DEM and size, with a flat 16 x 16 stand-in albedo (the albedo is
        :meth:`albedo_window`'s): ground points, coverage and flow as on the whole tile."""
        return Terrain(np.zeros((16, 16), np.float32), self.n * self.texel_m / 16.0,
                       self.dem_m, self.dem_spacing_m)

    def albedo_window(self, rows: tuple[int, int], cols: tuple[int, int]) -> np.ndarray:
        """The tile's albedo ``[rows[0]:rows[1], cols[0]:cols[1]]`` (float32, texels):
        :func:`procedural_terrain`'s within its transforms' rounding (a texel's float32
        value may differ by one unit in the last place)."""
        from scipy.spatial import cKDTree

        rng = copy.deepcopy(self.noise_rng)
        shape = (self.n, self.n)
        work = np.empty((self.n, self.n // 2 + 1), np.complex128)  # both fields' spectra
        texture = fractal_noise_window(shape, _TEXTURE[0], rng, rows, cols, _TEXTURE[1],
                                       work=work)
        fine = fractal_noise_window(shape, _FINE[0], rng, rows, cols, _FINE[1], work=work)
        del work
        yy = np.arange(self.n, dtype=np.float32)[rows[0]:rows[1], None]
        xx = np.arange(self.n, dtype=np.float32)[None, cols[0]:cols[1]]
        rr, cc = np.meshgrid(np.arange(rows[0], rows[1]), np.arange(cols[0], cols[1]),
                             indexing="ij")
        _, idx = cKDTree(self.seeds).query(np.column_stack([rr.ravel(), cc.ravel()])
                                           .astype(np.float64))
        fields = self.field_albedo[idx.reshape(rr.shape)]
        return _mix(fields, texture, fine, self.roads, yy, xx, self.texel_m)


def procedural_draws(size_m: float, texel_m: float, dem_spacing_m: float,
                     relief_rms_m: float, rng: np.random.Generator,
                     chunk: int = 256) -> ProceduralDraws:
    """:func:`procedural_terrain`'s tile as its draws from ``rng`` (advanced as that
    advances it): the textures' white noise is drawn in chunks of ``chunk`` rows and
    dropped (:meth:`ProceduralDraws.albedo_window` draws it again), the DEM built."""
    n, m = _tile_sizes(size_m, texel_m, dem_spacing_m)
    seeds, field_albedo = _fields(size_m, n, rng)
    noise_rng = copy.deepcopy(rng)
    buf = np.empty((min(chunk, n), n))
    for _ in range(2):  # the texture's and the fine grain's white noise
        for a in range(0, n, chunk):
            rng.standard_normal(out=buf[:min(chunk, n - a)])
    roads = _roads(n, rng)
    dem = fractal_noise((m, m), _DEM[0], rng, cutoff_cycles=_DEM[1]) * relief_rms_m
    return ProceduralDraws(size_m, texel_m, dem_spacing_m, n, seeds, field_albedo, noise_rng,
                           roads, dem.astype(np.float32))

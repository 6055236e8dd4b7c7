"""Calibration targets on flat ground: the slanted square whose edges the main imager's
quality figures are measured on (ISO 12233's slanted edge, both directions at once).

The caller says where the imager looks (the target's centre on the ground and the direction
of the imager's columns there, from its camera); this module only draws the tile.
"""

from __future__ import annotations

import numpy as np

from scene.terrain import Terrain

#: the target's albedo: dark ground, bright square
SQUARE_ALBEDO = (0.12, 0.5)
#: the square's turn against the imager's axes, deg (ISO 12233 asks for a few degrees)
SQUARE_ANGLE_DEG = 5.0
#: rows of the tile's albedo computed at a time (no tile-sized float64 temporaries)
BAND_ROWS = 256


def slanted_square(centre_en_m: np.ndarray, across_en: np.ndarray, half_side_m: float,
                   size_m: float, texel_m: float, angle_deg: float = SQUARE_ANGLE_DEG,
                   albedo: tuple[float, float] = SQUARE_ALBEDO) -> Terrain:
    """A flat tile with a bright square turned ``angle_deg`` against the imager's axes.

    Parameters
    ----------
    centre_en_m : (2,) the square's centre (east, north), m, in the scene's ENU frame.
    across_en : (2,) the direction (east, north) of the imager's columns on the ground (any
        length): the square's sides run ``angle_deg`` off it and off its normal.
    half_side_m : half the square's side, m.
    size_m : the tile's side, m (centred on the scene's origin; it must hold the square).
    texel_m : the albedo's sampling, m (a fifth of the GSD keeps the edge sharp).
    angle_deg : the square's turn, deg.
    albedo : (outside, inside) albedo.

    Returns
    -------
    Terrain : albedo float32 (n, n) (row 0 north), height 0 everywhere.
    """
    c = np.asarray(centre_en_m, dtype=np.float64)[:2]
    d = np.asarray(across_en, dtype=np.float64)[:2]
    if not (np.all(np.isfinite(c)) and np.linalg.norm(d) > 0):
        raise ValueError("centre_en_m must be finite and across_en a non-zero direction")
    if not (half_side_m > 0 and texel_m > 0 and size_m > 2 * texel_m):
        raise ValueError("half_side_m and texel_m must be > 0 and size_m > 2 texel_m")
    a = np.deg2rad(angle_deg)
    u = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ (d / np.linalg.norm(d))
    v = np.array([-u[1], u[0]])
    n = int(np.ceil(size_m / texel_m))
    xs = (np.arange(n) + 0.5) * texel_m - 0.5 * n * texel_m
    alb = np.empty((n, n), np.float32)
    de = xs - c[0]
    for r0 in range(0, n, BAND_ROWS):
        dn = (-xs[r0:r0 + BAND_ROWS] - c[1])[:, None]
        inside = ((np.abs(de[None] * u[0] + dn * u[1]) < half_side_m)
                  & (np.abs(de[None] * v[0] + dn * v[1]) < half_side_m))
        alb[r0:r0 + BAND_ROWS] = np.where(inside, albedo[1], albedo[0])
    return Terrain(alb, texel_m, np.zeros((17, 17), np.float32), n * texel_m / 16.0)

"""Test images for the correlator: band-limited textures with known sub-pixel shifts.

The seed paper's protocol: a textured scene of mean brightness 100, a copy moved by a known
sub-pixel shift (here by an exact Fourier phase ramp of a larger periodic field, so no
interpolation enters the truth), independent Gaussian noise on both images, SNR = mean / sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

MEAN_LEVEL = 100.0


@dataclass(frozen=True)
class TextureClass:
    """A texture strength: contrast (std / mean) and corner frequency f0 (cycles/px).

    Power spectrum ~ 1 / (1 + (f / f0)^2)^2, cut at 0.45 cycles/px (an optics-limited image).
    """

    name: str
    contrast: float
    f0_cyc_px: float


TEXTURES = {
    "urban": TextureClass("urban", 0.40, 0.20),
    "strong": TextureClass("strong", 0.25, 0.10),
    "medium": TextureClass("medium", 0.12, 0.06),
    "weak": TextureClass("weak", 0.05, 0.03),
}


def texture_pairs(n: int, block_px: int, rng: np.random.Generator, *, snr: float = np.inf,
                  texture: str = "strong", max_shift_px: float = 4.0, field_px: int = 0,
                  return_clean: bool = False):
    """n (ref, cur) block pairs with uniform random shifts in +-max_shift_px.

    Parameters
    ----------
    n, block_px : number and size of the square blocks.
    rng : random generator (textures, shifts and noise).
    snr : mean / noise sigma of each image (inf: noise-free).
    texture : a key of :data:`TEXTURES`.
    max_shift_px : shift range per component, px.
    field_px : size of the periodic field the blocks are cut from (default: block + 2*shift,
        rounded up to a fast FFT size).
    return_clean : also return the noise-free reference blocks.

    Returns
    -------
    ref, cur : (n, B, B) float32; shift : (n, 2) float64 with cur(x) = ref(x - shift);
    and, if asked, the clean ref (n, B, B) float64.
    """
    if texture not in TEXTURES:
        raise ValueError(f"texture must be one of {tuple(TEXTURES)}, got {texture!r}")
    if snr <= 0:
        raise ValueError(f"snr must be > 0, got {snr}")
    tc = TEXTURES[texture]
    size = field_px or sfft.next_fast_len(int(block_px + 2 * np.ceil(max_shift_px) + 16))
    fy = sfft.fftfreq(size)[:, None]
    fx = sfft.rfftfreq(size)[None, :]
    f = np.hypot(fy, fx)
    amp = (f < 0.45) / (1.0 + (f / tc.f0_cyc_px) ** 2)
    amp[0, 0] = 0.0
    shape = (n, size, size // 2 + 1)
    spec = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) * amp
    d = rng.uniform(-max_shift_px, max_shift_px, size=(n, 2))
    ramp = np.exp(-2j * np.pi * (fy[None] * d[:, 0, None, None] + fx[None] * d[:, 1, None, None]))
    a = sfft.irfft2(spec, s=(size, size))
    b = sfft.irfft2(spec * ramp, s=(size, size))
    scale = (tc.contrast * MEAN_LEVEL) / a.std(axis=(1, 2), keepdims=True)
    o = (size - block_px) // 2
    win = (slice(None), slice(o, o + block_px), slice(o, o + block_px))
    return _noisy(a[win] * scale + MEAN_LEVEL, b[win] * scale + MEAN_LEVEL, d, rng, snr,
                  return_clean)


def _noisy(clean: np.ndarray, cur: np.ndarray, d: np.ndarray, rng: np.random.Generator,
           snr: float, return_clean: bool):
    """(ref, cur) float32 with independent noise of sigma = 100 / snr on each, d, [clean]."""
    ref = clean
    if np.isfinite(snr):
        sigma = MEAN_LEVEL / snr
        ref = ref + rng.normal(0.0, sigma, ref.shape)
        cur = cur + rng.normal(0.0, sigma, cur.shape)
    out = (ref.astype(np.float32), cur.astype(np.float32), d)
    return (*out, clean) if return_clean else out


def image_pairs(images, n: int, block_px: int, rng: np.random.Generator, *,
                snr: float = np.inf, contrast: float | None = None, max_shift_px: float = 4.0,
                return_clean: bool = False):
    """n (ref, cur) block pairs cut from natural images, moved by exact sub-pixel shifts.

    Each pair: a random crop of a random image (2-D, or RGB averaged), mirrored into a
    periodic field (no wrap edge), moved by a uniform random shift within +-max_shift_px by a
    Fourier phase ramp; the central blocks are scaled to mean 100 and, if asked, to
    ``contrast`` (std / mean of the reference block), then noise of sigma = 100 / snr is added
    to each.

    Parameters
    ----------
    images : sequence of 2-D (or (H, W, 3)) arrays, each larger than the block plus twice
        the shift range plus 16 px.
    n, block_px, rng, snr, max_shift_px, return_clean : as :func:`texture_pairs`.
    contrast : std / mean of each reference block (None: the image's own).

    Returns
    -------
    As :func:`texture_pairs`.
    """
    if snr <= 0:
        raise ValueError(f"snr must be > 0, got {snr}")
    imgs = [np.asarray(im, dtype=np.float64) for im in images]
    imgs = [im.mean(axis=-1) if im.ndim == 3 else im for im in imgs]
    size = int(block_px + 2 * np.ceil(max_shift_px) + 16)
    if not imgs or any(im.ndim != 2 or min(im.shape) < size for im in imgs):
        raise ValueError(f"images must be 2-D and at least {size} px on a side")
    pick = rng.integers(0, len(imgs), n)
    crops = np.empty((n, size, size))
    for i, k in enumerate(pick):  # one small copy per pair: not a hot path
        h, w = imgs[k].shape
        y0, x0 = rng.integers(0, h - size + 1), rng.integers(0, w - size + 1)
        crops[i] = imgs[k][y0 : y0 + size, x0 : x0 + size]
    field = np.concatenate([crops, crops[:, ::-1]], axis=1)
    field = np.concatenate([field, field[:, :, ::-1]], axis=2)  # even: periodic, continuous
    f = 2 * size
    fy = sfft.fftfreq(f)[:, None]
    fx = sfft.rfftfreq(f)[None, :]
    d = rng.uniform(-max_shift_px, max_shift_px, size=(n, 2))
    ramp = np.exp(-2j * np.pi * (fy[None] * d[:, 0, None, None] + fx[None] * d[:, 1, None, None]))
    spec = sfft.rfft2(field)
    moved = sfft.irfft2(spec * ramp, s=(f, f))
    o = (size - block_px) // 2
    win = (slice(None), slice(o, o + block_px), slice(o, o + block_px))
    a, b = field[win], moved[win]
    mean = a.mean(axis=(1, 2), keepdims=True)
    if contrast is None:
        gain = MEAN_LEVEL / mean
    else:
        gain = contrast * MEAN_LEVEL / np.maximum(a.std(axis=(1, 2), keepdims=True), 1e-12)
    return _noisy((a - mean) * gain + MEAN_LEVEL, (b - mean) * gain + MEAN_LEVEL, d, rng, snr,
                  return_clean)


def powerlaw_images(n: int, size_px: int, beta: float, rng: np.random.Generator,
                    cutoff_cyc_px: float = 0.45) -> np.ndarray:
    """Smooth natural-like textures: Gaussian fields with power spectrum ~ 1 / f^beta.

    Natural scenes have power spectra falling as f^-2 to f^-3.5 (smooth terrain, snow, water
    and haze at the steep end); such a field's variance sits at the lowest frequencies, so a
    block of it is smooth and, scaled to a low contrast, hard to register. Inputs for
    :func:`image_pairs` (which cuts, moves and scales the blocks).

    Parameters
    ----------
    n : number of images.
    size_px : side of each square image, px (at least the block plus twice the shift range
        plus 16 px for :func:`image_pairs`).
    beta : spectral exponent (dimensionless; 2.5-3.5 for smooth texture).
    rng : random generator (the field's phases and amplitudes).
    cutoff_cyc_px : no power at or above this frequency, cycles/px (an optics cut-off).

    Returns
    -------
    (n, size_px, size_px) float64 zero-mean images (arbitrary scale; the lowest frequency
    the image holds is 1 / size_px cycles/px).
    """
    if beta < 0 or not 0 < cutoff_cyc_px <= 0.5:
        raise ValueError(f"beta must be >= 0 and cutoff within (0, 0.5], got {beta}, "
                         f"{cutoff_cyc_px}")
    fy = sfft.fftfreq(size_px)[:, None]
    fx = sfft.rfftfreq(size_px)[None, :]
    f = np.hypot(fy, fx)
    f[0, 0] = 1.0
    amp = f ** (-beta / 2.0) * (f < cutoff_cyc_px)
    amp[0, 0] = 0.0
    shape = (n, *amp.shape)
    spec = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) * amp
    return sfft.irfft2(spec, s=(size_px, size_px))

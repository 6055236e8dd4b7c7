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


def band_limited_gradients(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d/drow, d/dcol (..., H, W) of images by the spectral derivative of their mirror
    extension (continuous, so no wrap edge; exact for band-limited content but for the
    fold, ~0.5 % in a bound)."""
    x = np.concatenate([img, img[..., ::-1, :]], axis=-2)
    x = np.concatenate([x, x[..., ::-1]], axis=-1)
    h, w = x.shape[-2:]
    spec = sfft.rfft2(x, axes=(-2, -1), workers=-1)
    fy = 2j * np.pi * sfft.fftfreq(h)[:, None]
    fx = 2j * np.pi * sfft.rfftfreq(w)[None, :]
    hh, ww = img.shape[-2:]
    gy = sfft.irfft2(spec * fy, s=(h, w), axes=(-2, -1), workers=-1)[..., :hh, :ww]
    gx = sfft.irfft2(spec * fx, s=(h, w), axes=(-2, -1), workers=-1)[..., :hh, :ww]
    return gy, gx


def crlb_px(clean: np.ndarray, sigma: float) -> np.ndarray:
    """Cramer-Rao bound (..., 2) px for shifting blocks (..., H, W) with both images noisy
    (white, sigma per px): sqrt(diag(2 sigma^2 (sum_x g g^T)^-1)).

    The gradients g of the noise-free block are taken spectrally
    (:func:`band_limited_gradients`): exact for band-limited content (the mirror extension's
    fold puts the bound ~0.5 % high). (A central difference,
    which imcsim used before, passes sin(w) for w and understates the gradient of fine
    texture: on the strong test texture it put the bound 1.36x too high.) The bound treats
    the scene as known: at finite SNR per frequency no correlation estimator reaches it
    (:func:`correlation_bound_px`).
    """
    gy, gx = band_limited_gradients(np.asarray(clean, dtype=np.float64))
    a11, a22 = (gy * gy).sum(axis=(-2, -1)), (gx * gx).sum(axis=(-2, -1))
    return np.sqrt(2.0 * sigma**2 * _inverse_diagonal(a11, a22, (gy * gx).sum(axis=(-2, -1))))


def _inverse_diagonal(a11: np.ndarray, a22: np.ndarray, a12: np.ndarray) -> np.ndarray:
    """The diagonal (..., 2) of the inverse of the symmetric 2 x 2 matrices [[a11, a12],
    [a12, a22]]."""
    det = a11 * a22 - a12 * a12
    return np.stack([a22 / det, a11 / det], axis=-1)


def periodic_component(img: np.ndarray) -> np.ndarray:
    """Moisan's periodic component (..., H, W) of images: the image less the smooth field
    that carries its wrap-around edge jumps, so its DFT has no cross of edge artefacts.

    Reference: L. Moisan, "Periodic plus smooth image decomposition", J. Math. Imaging Vis.
    39 (2011) 161-179.
    """
    u = np.asarray(img, dtype=np.float64)
    h, w = u.shape[-2:]
    v = np.zeros_like(u)
    v[..., 0, :] += u[..., -1, :] - u[..., 0, :]
    v[..., -1, :] -= u[..., -1, :] - u[..., 0, :]
    v[..., :, 0] += u[..., :, -1] - u[..., :, 0]
    v[..., :, -1] -= u[..., :, -1] - u[..., :, 0]
    cy = np.cos(2 * np.pi * np.fft.fftfreq(h))[:, None]
    cx = np.cos(2 * np.pi * np.fft.fftfreq(w))[None, :]
    den = 2.0 * cy + 2.0 * cx - 4.0
    den[0, 0] = 1.0
    smooth = np.fft.fft2(v, axes=(-2, -1)) / den
    smooth[..., 0, 0] = 0.0
    return u - np.real(np.fft.ifft2(smooth, axes=(-2, -1)))


def correlation_bound_px(clean: np.ndarray, sigma: float) -> np.ndarray:
    """The error (n, 2) px of the efficient cross-spectrum (correlation) estimator of the
    shift between two copies of clean blocks (n, H, W), each with white noise of sigma per px:
    the weighted correlation with the true spectrum's weights, in its small-error
    (linearised) regime.

    The cross spectrum R* C of bin k carries the texture against the other image's noise
    twice and the two noises once: its phase noise has variance sigma^2 (2 |S_k|^2 +
    sigma^2) / 2 against a slope |S_k|^2 (S the unitary DFT of the block's periodic
    component). With the best weights W_k = |S_k|^2 / (sigma^2 (2 |S_k|^2 + sigma^2)) (the
    oracle's Knapp-Carter weights, Knapp & Carter 1976) the estimate's covariance is A^-1,
    A = sum_k w_k w_k^T |S_k|^4 / (sigma^2 (2 |S_k|^2 + sigma^2)) (w the bin's angular
    frequency, rad/px; the Nyquist row and column, whose bins carry no shift of a real image,
    left out). At high SNR per bin this is :func:`crlb_px`'s 2 sigma^2 (sum g g^T)^-1; where
    the texture is below the noise the noise x noise term makes it larger: the known-scene
    Cramer-Rao bound is not reached by an estimator of this kind at finite SNR. (Far below
    the noise in every bin, other estimators, e.g. phase unwrapping, can do better than this
    linearised figure.)
    """
    c = np.asarray(clean, dtype=np.float64)
    h, w = c.shape[-2:]
    spec = np.fft.fft2(periodic_component(c - c.mean(axis=(-2, -1), keepdims=True)),
                      axes=(-2, -1)) / np.sqrt(h * w)
    p = np.abs(spec) ** 2
    s2 = float(sigma) ** 2
    weight = p * p / (s2 * (2.0 * p + s2))
    if h % 2 == 0:
        weight[..., h // 2, :] = 0.0
    if w % 2 == 0:
        weight[..., :, w // 2] = 0.0
    wy = 2 * np.pi * np.fft.fftfreq(h)[:, None]
    wx = 2 * np.pi * np.fft.fftfreq(w)[None, :]
    return np.sqrt(_inverse_diagonal((weight * wy * wy).sum(axis=(-2, -1)),
                                     (weight * wx * wx).sum(axis=(-2, -1)),
                                     (weight * wy * wx).sum(axis=(-2, -1))))


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

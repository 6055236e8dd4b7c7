"""The shift estimators' error bounds: the known-scene Cramer-Rao bound (:func:`crlb_px`) and
the bound of correlation (cross-spectrum) estimators at finite SNR
(:func:`correlation_bound_px`), for blocks with white noise in both images. Pure numpy.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft


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

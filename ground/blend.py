"""Stage + ground never worse than the stage alone: a per-axis, per-band blend of what the
ground knows about the stage's residual.

With a stage on, the product's geometric error is the stage's residual ``r(t)`` (px). The
ground holds one or more estimates of it, ``x_j = r + e_j`` (the fused record less the
stage's position record, the stage's own residual record, ...), each with a predicted
error covariance ``C_j`` (from :func:`ground.network.solve_network`). A correction ``c``
leaves ``r - c``. Applying an estimate whole adds its error everywhere, its low-frequency
drift included; applying nothing leaves motion the ground measured well. The blend decides
per axis and per frequency band:

* the constant (the DCT's k = 0 term) is left out of everything: no record sees it and
  ground control fixes it, so every figure here is "after a constant";
* the series are split into bands by a complementary crossover filter on the DCT-II
  (even extension, so a drift does not wrap round): masks ``m_b(f)`` with raised-cosine
  transitions of relative half-width ``width`` around each crossover, summing to 1 at
  every frequency, so all gains 1 give back the estimate exactly;
* each estimate's predicted error variance in band b is ``E_jb = tr(F_b C_j F_b^T) / n``
  (F_b the band filter, orthonormal: ``sum_k m_b(f_k)^2 (D C D^T)_kk / n``);
* estimates are combined per band by inverse variance (their errors taken as independent:
  do not pass two estimates built from the same links), ``E_b = 1 / sum_j (1 / E_jb)``;
* the uncorrected product's band variance is estimated from the combined estimate itself,
  ``S_b = max(P_b - E_b, 0)``, P_b its measured band power;
* the gain is Wiener's, ``G_b = S_b / (S_b + E_b)`` (``rule="wiener"``), or 1 where
  ``S_b > E_b`` and 0 elsewhere (``rule="switch"``);
* predicted, the corrected product's band variance is ``(1 - G)^2 S_b + G^2 E_b``, never
  above ``S_b`` (the uncorrected) for either rule: the product is never worse than the stage
  alone beyond the error of these predictions (the band powers' sampling spread).

References
----------
Sehn & Miller, AIAA 84-2046 (Landsat's crossover network blending a gyro below 2 Hz with an
angular displacement sensor above); Wiener, "Extrapolation, Interpolation, and Smoothing of
Stationary Time Series", MIT Press, 1949.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import fft

RULES = ("wiener", "switch")


def band_masks(n: int, dt_s: float, crossover_hz: Sequence[float],
               width: float = 0.25) -> np.ndarray:
    """Complementary band masks (n_bands, n) on the DCT-II frequencies ``k / (2 n dt_s)`` Hz.

    Parameters
    ----------
    n : int
        Series length (samples).
    dt_s : float
        Sample spacing, s.
    crossover_hz : sequence of float
        Increasing crossover frequencies, Hz (n_bands = len + 1).
    width : float
        Relative half-width of each raised-cosine transition, in (0, 1).

    Returns
    -------
    numpy.ndarray
        Masks in [0, 1] summing to 1 over the bands at every frequency.

    References
    ----------
    Sehn & Miller, AIAA 84-2046 (crossover networks).
    """
    if not (isinstance(n, int | np.integer) and n >= 2):
        raise ValueError(f"n must be an int >= 2, got {n!r}")
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be finite and > 0 (s), got {dt_s}")
    fc = np.asarray(crossover_hz, dtype=np.float64).ravel()
    if not (np.all(np.isfinite(fc)) and np.all(fc > 0) and np.all(np.diff(fc) > 0)):
        raise ValueError(f"crossover_hz must be increasing positive frequencies (Hz), got "
                         f"{fc.tolist()}")
    if not (0 < width < 1):
        raise ValueError(f"width must be in (0, 1), got {width}")
    f = np.arange(n) / (2.0 * n * dt_s)
    x = np.clip((f[None, :] / fc[:, None] - 1.0) / width, -1.0, 1.0)
    low = 0.5 * (1.0 - np.sin(0.5 * np.pi * x))  # 1 below, 0 above each crossover
    edges = np.concatenate([np.zeros((1, n)), low, np.ones((1, n))])
    return np.diff(edges, axis=0)


def band_split(x_px: ArrayLike, dt_s: float, crossover_hz: Sequence[float],
               width: float = 0.25) -> np.ndarray:
    """A series split into complementary bands that sum back to it.

    Parameters
    ----------
    x_px : array_like, (n, 2)
        The series (row, col) px on a uniform grid.
    dt_s : float
        Sample spacing, s.
    crossover_hz : sequence of float
        Increasing crossover frequencies, Hz.
    width : float
        Relative half-width of the transitions (:func:`band_masks`).

    Returns
    -------
    numpy.ndarray, (n_bands, n, 2)
        The bands, px (orthonormal DCT-II, masked, inverted).

    References
    ----------
    Sehn & Miller, AIAA 84-2046 (crossover networks).
    """
    x = np.asarray(x_px, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2 or not np.all(np.isfinite(x)):
        raise ValueError(f"x_px must be finite with shape (n, 2), got {x.shape}")
    m = band_masks(x.shape[0], dt_s, crossover_hz, width)
    xc = fft.dct(x, type=2, norm="ortho", axis=0)
    return fft.idct(m[:, :, None] * xc[None], type=2, norm="ortho", axis=1)


def band_error_variance(cov_px2: ArrayLike, dt_s: float, crossover_hz: Sequence[float],
                        width: float = 0.25, *, skip_constant: bool = False) -> np.ndarray:
    """Predicted error variance per band of a series from its error covariance.

    Parameters
    ----------
    cov_px2 : array_like, (2, n, n)
        The series' error covariance per axis (row, col), px^2.
    dt_s : float
        Sample spacing, s.
    crossover_hz : sequence of float
        Increasing crossover frequencies, Hz.
    width : float
        Relative half-width of the transitions (:func:`band_masks`).
    skip_constant : bool
        Leave the series' mean (the DCT's k = 0 term) out.

    Returns
    -------
    numpy.ndarray, (n_bands, 2)
        ``tr(F_b C F_b^T) / n`` = ``sum_k m_b(f_k)^2 (D C D^T)_kk / n``, px^2.

    References
    ----------
    Wiener 1949 (band-limited error variance).
    """
    c = np.asarray(cov_px2, dtype=np.float64)
    if c.ndim != 3 or c.shape[0] != 2 or c.shape[1] != c.shape[2]:
        raise ValueError(f"cov_px2 must have shape (2, n, n), got {c.shape}")
    n = c.shape[1]
    m = band_masks(n, dt_s, crossover_hz, width)
    dcd = fft.dct(fft.dct(c, type=2, norm="ortho", axis=1), type=2, norm="ortho", axis=2)
    diag = np.diagonal(dcd, axis1=1, axis2=2).copy()  # (2, n)
    if skip_constant:
        diag[:, 0] = 0.0
    return (m**2 @ diag.T) / n


@dataclass(frozen=True, eq=False)  # holds arrays
class Blend:
    """The blended correction and its bookkeeping, per band b and axis (row, col).

    ``correction_px`` (n, 2) px, zero-mean, to subtract from the product's error (apply it as
    the estimate would be applied); ``gain`` (n_bands, 2); ``weights`` (n_estimates, n_bands, 2)
    the inverse-variance weights; ``signal_var_px2`` S_b, the uncorrected product's estimated
    band variance; ``error_var_px2`` E_b, the combined estimate's; ``after_var_px2`` the
    corrected product's predicted band variance (all (n_bands, 2) px^2).
    """

    correction_px: np.ndarray
    crossover_hz: tuple[float, ...]
    gain: np.ndarray
    weights: np.ndarray
    signal_var_px2: np.ndarray
    error_var_px2: np.ndarray
    after_var_px2: np.ndarray

    @property
    def predicted_before_px(self) -> np.ndarray:
        """Predicted RMS (2,) px of the uncorrected product after a constant (all bands)."""
        return np.sqrt(self.signal_var_px2.sum(axis=0))

    @property
    def predicted_after_px(self) -> np.ndarray:
        """Predicted RMS (2,) px of the corrected product after a constant (all bands)."""
        return np.sqrt(self.after_var_px2.sum(axis=0))


def blend_correction(estimates_px: Sequence[ArrayLike], error_cov_px2: Sequence[ArrayLike],
                     dt_s: float, crossover_hz: Sequence[float], *, width: float = 0.25,
                     rule: str = "wiener") -> Blend:
    """The correction to apply per axis and band so the product is never worse than the
    stage alone beyond the predicted error (module docstring).

    Parameters
    ----------
    estimates_px : sequence of array_like, each (n, 2)
        Estimates of the stage's residual (row, col) px, on a uniform grid of spacing dt_s.
    error_cov_px2 : sequence of array_like
        Each estimate's predicted error: its covariance (2, n, n) px^2, or its band
        variances (n_bands, 2) px^2 directly (about its mean).
    dt_s : float
        Sample spacing, s.
    crossover_hz : sequence of float
        Increasing crossover frequencies, Hz.
    width : float
        Relative half-width of the crossovers' transitions.
    rule : {"wiener", "switch"}
        Per-band gain: Wiener's S / (S + E), or all-or-nothing where S > E.

    Returns
    -------
    Blend
        The correction (n, 2) px and per-band gains, weights and predicted variances.

    References
    ----------
    Sehn & Miller, AIAA 84-2046; Wiener 1949.
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    xs = [np.asarray(x, dtype=np.float64) for x in estimates_px]
    if not xs or len(xs) != len(error_cov_px2):
        raise ValueError("estimates_px and error_cov_px2 must be non-empty and of the same "
                         f"length, got {len(xs)} and {len(error_cov_px2)}")
    n = xs[0].shape[0]
    for j, x in enumerate(xs):
        if x.shape != (n, 2) or not np.all(np.isfinite(x)):
            raise ValueError(f"estimates_px[{j}] must be finite with shape ({n}, 2), got "
                             f"{x.shape}")
    m = band_masks(n, dt_s, crossover_hz, width)
    nb = m.shape[0]
    ev = []
    for j, c in enumerate(error_cov_px2):
        c = np.asarray(c, dtype=np.float64)
        e = c if c.shape == (nb, 2) else (
            band_error_variance(c, dt_s, crossover_hz, width, skip_constant=True)
            if c.shape == (2, n, n)
            else None)
        if e is None or not np.all(np.isfinite(e) & (e >= 0)):
            raise ValueError(f"error_cov_px2[{j}] must be a covariance (2, {n}, {n}) or band "
                             f"variances ({nb}, 2) px^2, finite and >= 0, got {c.shape}")
        ev.append(np.maximum(e, 1e-30))
    ev = np.stack(ev)  # (n_est, nb, 2)
    inv = 1.0 / ev
    w = inv / inv.sum(axis=0, keepdims=True)
    err = 1.0 / inv.sum(axis=0)
    xc = np.stack([fft.dct(x, type=2, norm="ortho", axis=0) for x in xs])  # (n_est, n, 2)
    xc[:, 0] = 0.0  # the constant: no record sees it, ground control fixes it
    comb = np.einsum("jba,bk,jka->bka", w, m, xc)  # (nb, n, 2) combined, per band
    power = np.sum(comb**2, axis=1) / n
    sig = np.clip(power - err, 0.0, None)
    gain = sig / (sig + err) if rule == "wiener" else (sig > err).astype(np.float64)
    after = (1.0 - gain) ** 2 * sig + gain**2 * err
    corr = fft.idct(np.einsum("ba,bka->ka", gain, comb), type=2, norm="ortho", axis=0)
    return Blend(corr, tuple(float(f) for f in np.ravel(crossover_hz)), gain, w, sig, err,
                 after)

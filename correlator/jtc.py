"""Joint transform correlator (JTC), digitally: joint input plane -> |FFT|^2 -> FFT.

Input plane (2H, 6W): ref at the origin, cur displaced by the separation G = (0, 2W). Its
joint power spectrum (JPS) is

    |F|^2 = |R|^2 + |C|^2 + 2 Re(conj(R) C exp(-i k.G)),

whose second transform holds the two autocorrelations around the origin (cols within +-W),
the cross-correlation of ref and cur at +(G + d) (cols W..3W) and its mirror at -(G + d)
(cols 3W..5W): three disjoint regions, so the read-out window around +G holds the linear
cross-correlation alone, whatever the filter.

Filters (``jtc_filter``):

- ``plain``: the raw JPS, as a square-law sensor records it;
- ``subtract``: the individual power spectra |R|^2, |C|^2 (and with them the DC term)
  removed, leaving the cross terms only: equal to the digital cross-correlation;
- ``fringe``: ``subtract`` followed by the fringe-adjusted filter 1 / (|R|^2 + eps), which
  flattens the reference spectrum and sharpens the peak (Alam & Karim, Appl. Opt. 32, 1993).

References
----------
Weaver & Goodman, "A technique for optically convolving two functions", Appl. Opt. 5 (1966).
Alam & Karim, "Fringe-adjusted joint transform correlation", Appl. Opt. 32 (1993).
"""

from __future__ import annotations

import numpy as np

JTC_FILTERS = ("plain", "subtract", "fringe")


def fringe_eps(power: np.ndarray) -> np.ndarray:
    """Regularisation of the fringe-adjusted filter: 1 % of the mean reference power."""
    return 0.01 * power.mean(axis=(-2, -1), keepdims=True) + 1e-30


def joint_plane_surface(ref_w: np.ndarray, cur_w: np.ndarray, jtc_filter: str,
                        workers: int = 1) -> np.ndarray:
    """Correlation surfaces (N, H, W) read from the JTC output plane, lag 0 at index [0, 0].

    ``ref_w``, ``cur_w``: windowed, zero-mean blocks (N, H, W). The result is laid out like an
    inverse FFT of a cross spectrum (negative lags wrapped to the end), so it can replace the
    fast path's surface directly.
    """
    import scipy.fft as sfft  # here: the options import this module, and validate no FFT

    n, h, w = ref_w.shape
    g = 2 * w
    shape = (2 * h, 6 * w)
    plane = np.zeros((n, *shape), np.float32)
    plane[:, :h, :w] = ref_w
    plane[:, :h, g : g + w] = cur_w
    jps = np.abs(sfft.rfft2(plane, workers=workers)) ** 2
    if jtc_filter in ("subtract", "fringe"):
        solo = np.zeros((n, *shape), np.float32)
        solo[:, :h, :w] = ref_w
        pr = np.abs(sfft.rfft2(solo, workers=workers)) ** 2
        solo[:] = 0.0
        solo[:, :h, g : g + w] = cur_w
        jps -= pr + np.abs(sfft.rfft2(solo, workers=workers)) ** 2
        if jtc_filter == "fringe":
            jps /= pr + fringe_eps(pr)
    out = sfft.irfft2(jps, s=shape, workers=workers)
    ry = np.r_[0 : h - h // 2, 2 * h - h // 2 : 2 * h]  # lags 0..h/2-1, then -h/2..-1
    rx = g + np.r_[0 : w - w // 2, -(w // 2) : 0]
    return out[:, ry[:, None], rx[None, :]]

"""Restoration: the residual-motion PSF and its removal by deconvolution.

The PSF of an exposure (or a run of lines) is the time the image spends at each offset of the
residual motion r(t) (Wulich & Kopeika 1987; imcsim's ``imc/wiring/blur.py``
(:mod:`imc.wiring.blur`) computes the same from the truth): a time-weighted histogram on a fine
grid (bins of a fraction of a px, odd, centred on the mean, since rectification has already
taken the mean offset out). Deconvolution needs it on the image's pixel grid: each sample is
spread over the pixels by a Lanczos-3 kernel (a windowed sinc: the real part of a fractional
shift's band-limited transfer, cos(2 pi f r), is kept to 0.02 up to 0.3 cycles/px and to 0.12
at worst up to Nyquist, against 0.28 for a linear-interpolation "splat"; a 1 px smear's Nyquist
MTF comes out 2/pi to 0.01, where the splat gives 0.5). The pixel kernel is built from the
samples themselves, not the bins.

Deconvolution uses scikit-image (``skimage.restoration``): ``wiener`` (Wiener-Hunt with a
constant regulariser, the balance being the noise-to-signal power ratio nsr^2, or skimage's
Laplacian regulariser), ``unsupervised_wiener`` (Orieux et al., JOSA A 27, 2010: the balance
estimated by Gibbs sampling), ``richardson_lucy``. The image is padded by reflection before
the FFT (skimage's filters are circular).

Measured here (tests/test_ground.py: a slanted edge, Gaussian optics sigma 0.3 px, a 1 px
linear smear along the rows, SNR 50 = contrast / noise sigma, 128 x 384 px; static edge MTF at
Nyquist 0.415, smeared 0.268; "ratio" = restored / static MTF at Nyquist, noise gain on a flat
field, H = GIQE edge overshoot):

=================================  =====  ==========  =====
method                             ratio  noise gain  H
=================================  =====  ==========  =====
wiener, nsr 0.02 (= 1/SNR)         0.996  1.20        1.008
wiener, nsr 0.1                    0.984  1.18        1.007
wiener_laplacian, nsr 0.02         0.984  1.18        1.008
wiener_laplacian, nsr 0.05         0.894  1.10        1.007
richardson_lucy, 10-100 iter.      0.96   1.25        1.031
unsupervised_wiener                0.44   0.16        1.013
=================================  =====  ==========  =====

The constant-regulariser Wiener filter with nsr = 1/SNR is the default: it meets the targets
(>= 0.90 of the static MTF at Nyquist, noise gain <= 1.5) with the least overshoot;
Richardson-Lucy is worse on all three figures, the unsupervised Wiener filter over-smooths.
A 1 px smear is a mild PSF (|H| >= 2/pi up to Nyquist), so the noise gain is set by the
inverse filter's ~1/sinc, not by the balance. A 2 px smear has its transfer zero at Nyquist:
no linear filter restores it there (Wiener nsr 0.02: noise gain 7, the edge MTF at Nyquist
lost in the noise), Richardson-Lucy's positivity recovers some at noise gain > 2.

Space-variant blur along a strip: :func:`restore_strip` restores runs of lines, each with its
own PSF, each run extended by an overlap and blended with its neighbours by linear ramps that
sum to one (no seams).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ground.record import check_series

#: fine PSF bins (px) and the Lanczos order of the pixel-grid kernel
PSF_BIN_PX = 1.0 / 32.0
LANCZOS_A = 3
METHODS = ("wiener", "wiener_laplacian", "unsupervised_wiener", "richardson_lucy")
DEFAULT_METHOD = "wiener"


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields, not objects
class ResidualPsf:
    """Residual-motion PSF: ``fine`` (G, G) time-weighted histogram on ``bin_px`` bins (G
    odd, centred on ``centre_px``), ``pixel`` (K, K) kernel on the pixel grid (K odd), both
    summing to 1; axes (row, col)."""

    fine: np.ndarray
    bin_px: float
    centre_px: tuple[float, float]
    pixel: np.ndarray


def _lanczos(x: np.ndarray, a: int = LANCZOS_A) -> np.ndarray:
    return np.where(np.abs(x) < a, np.sinc(x) * np.sinc(x / a), 0.0)


def residual_psf(r_px, *, weights=None, bin_px: float = PSF_BIN_PX,
                 about_mean: bool = True) -> ResidualPsf:
    """PSF of residual motion samples ``r_px`` (T, 2) (row, col) px over one exposure or run.

    ``weights`` (T,): the time each sample stands for (s, any scale; default equal: samples
    evenly spaced in time). ``about_mean``: centre on the time-weighted mean offset (the part
    rectification removes) or on zero.

    Parameters
    ----------
    r_px : array_like, (T, 2)
        Residual motion samples (row, col), px, finite, T >= 1.
    weights : array_like, (T,), optional
        Time each sample stands for, s (any scale), >= 0, not all zero.
    bin_px : float, optional
        Bin size of the fine histogram, px.
    about_mean : bool, optional
        Centre on the time-weighted mean offset (True) or on zero (False).

    Returns
    -------
    ResidualPsf
        The fine histogram on ``bin_px`` px bins, its centre (row, col) px, and the
        pixel-grid kernel (1 px bins); both sum to 1.

    References
    ----------
    Wulich, D., Kopeika, N. S., "Image resolution limits resulting from mechanical
    vibrations", Optical Engineering 26(6), 1987 (the motion PSF as a time histogram);
    Duchon, C. E., "Lanczos filtering in one and two dimensions", J. Appl. Meteorology 18,
    1979 (the Lanczos kernel); ``numpy.histogram2d``.
    """
    r = np.asarray(r_px, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 2 or r.shape[0] == 0 or not np.all(np.isfinite(r)):
        raise ValueError(f"r_px must be finite samples of shape (T >= 1, 2), got {r.shape}")
    w = np.ones(len(r)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(r),) or not np.all(np.isfinite(w) & (w >= 0)) or w.sum() <= 0:
        raise ValueError(f"weights must be ({len(r)},) finite, >= 0, not all zero")
    if not (np.isfinite(bin_px) and bin_px > 0):
        raise ValueError(f"bin_px must be a finite bin size > 0 px, got {bin_px}")
    w = w / w.sum()
    centre = (w @ r) if about_mean else np.zeros(2)
    d = r - centre
    n = int(np.ceil(np.max(np.abs(d)) / bin_px + 0.5))
    edges = (np.arange(-n, n + 2) - 0.5) * bin_px  # 2n + 1 bins centred on 0
    fine, _, _ = np.histogram2d(d[:, 0], d[:, 1], bins=[edges, edges], weights=w)
    fine /= fine.sum()
    # pixel grid: each sample's weight spread by a separable Lanczos kernel (from the samples
    # themselves, not the bins: no quantisation)
    half = int(np.ceil(np.max(np.abs(d)))) + LANCZOS_A
    k = np.arange(-half, half + 1, dtype=np.float64)
    lr = _lanczos(k[None, :] - d[:, :1])  # (T, K)
    lc = _lanczos(k[None, :] - d[:, 1:])
    pixel = (lr * w[:, None]).T @ lc
    pixel /= pixel.sum()
    return ResidualPsf(fine=fine, bin_px=float(bin_px), centre_px=(float(centre[0]),
                       float(centre[1])), pixel=pixel)


def run_psfs(t_s, residual_px, t_line_s, integration_s: float, run_starts, *,
             n_sub: int = 32, bin_px: float = PSF_BIN_PX) -> list[ResidualPsf]:
    """The PSF of each run of lines from residual-motion samples.

    ``t_s`` (n,) s increasing, ``residual_px`` (n, 2) px (the truth, or the record's estimate);
    line ``l`` integrates over ``[t_line_s[l], t_line_s[l] + integration_s]``, sampled at
    ``n_sub`` evenly spaced instants (linear interpolation of the residual). Each line's
    residual is taken about its own mean (rectification removes that), and the lines of run
    ``i`` (``run_starts[i]`` to ``run_starts[i + 1]``) are pooled into one PSF.

    Parameters
    ----------
    t_s : array_like, (n,)
        Times of the residual samples, s, strictly increasing.
    residual_px : array_like, (n, 2)
        Residual motion (row, col) at ``t_s``, px.
    t_line_s : array_like, (n_lines,)
        Start of each line's integration, s.
    integration_s : float
        Line integration time, s, >= 0.
    run_starts : array_like of int
        First line of each run (lines), starting at 0, strictly increasing.
    n_sub : int, optional
        Instants sampled per line's integration window (>= 1).
    bin_px : float, optional
        Bin size of the fine histograms, px.

    Returns
    -------
    list of ResidualPsf
        One PSF per run (see :func:`residual_psf`).

    References
    ----------
    Wulich, D., Kopeika, N. S., "Image resolution limits resulting from mechanical
    vibrations", Optical Engineering 26(6), 1987; ``numpy.interp``.
    """
    t, r = check_series(t_s, residual_px, "t_s", "residual_px")
    tl = np.asarray(t_line_s, dtype=np.float64)
    if tl.ndim != 1 or tl.size == 0 or not np.all(np.isfinite(tl)):
        raise ValueError(f"t_line_s must be a non-empty finite 1-D array, got {tl.shape}")
    if not (np.isfinite(integration_s) and integration_s >= 0) or n_sub < 1:
        raise ValueError("integration_s must be finite and >= 0, n_sub >= 1")
    starts = np.asarray(run_starts, dtype=int)
    if (starts.ndim != 1 or starts.size == 0 or starts[0] != 0 or np.any(np.diff(starts) <= 0)
            or starts[-1] >= tl.size):
        raise ValueError(f"run_starts must start at 0, increase strictly and stay inside the "
                         f"{tl.size} lines, got {starts.tolist()}")
    inst = tl[:, None] + (np.arange(n_sub) + 0.5) / n_sub * integration_s  # (lines, n_sub)
    win = np.stack([np.interp(inst, t, r[:, k]) for k in range(2)], axis=-1)
    win -= win.mean(axis=1, keepdims=True)
    ends = np.append(starts[1:], tl.size)
    return [residual_psf(win[a:b].reshape(-1, 2), bin_px=bin_px, about_mean=False)
            for a, b in zip(starts, ends, strict=True)]


def _check_psf(psf) -> np.ndarray:
    p = np.asarray(psf, dtype=np.float64)
    if p.ndim != 2 or p.shape[0] % 2 == 0 or p.shape[1] % 2 == 0:
        raise ValueError(f"psf must be a 2-D kernel with odd sides, got shape {p.shape}")
    if not np.all(np.isfinite(p)) or abs(p.sum() - 1.0) > 1e-6:
        raise ValueError("psf must be finite and sum to 1 (normalise it)")
    return p


def deconvolve(image, psf, *, method: str = DEFAULT_METHOD, nsr: float = 0.02,
               num_iter: int = 30, pad_px: int | None = None,
               rng: np.random.Generator | int | None = 0) -> np.ndarray:
    """Deconvolve ``image`` (2-D) by the pixel-grid ``psf`` (odd sides, sums to 1).

    ``method``: ``"wiener"`` (the default: constant regulariser, balance ``nsr``^2, ``nsr``
    the noise-to-signal amplitude ratio 1/SNR, 0.02 for SNR 50), ``"wiener_laplacian"``
    (skimage's Laplacian regulariser, same balance), ``"unsupervised_wiener"`` (balance
    estimated; ``rng`` seeds its sampler), ``"richardson_lucy"`` (``num_iter`` iterations;
    needs a non-negative image; the PSF's negative Lanczos lobes are clipped). The image is
    padded by reflection by ``pad_px`` (default: 4 PSF half-widths, at least 8) so skimage's
    circular filters wrap nothing.

    Parameters
    ----------
    image : array_like, (n_rows, n_cols)
        Image to restore, image (intensity) units, finite, at least 2 px a side.
    psf : array_like, (K, L)
        Pixel-grid PSF (1 px bins), odd sides, summing to 1.
    method : {"wiener", "wiener_laplacian", "unsupervised_wiener", "richardson_lucy"}, optional
        The deconvolution.
    nsr : float, optional
        Noise-to-signal amplitude ratio (1/SNR), dimensionless, > 0; the Wiener balance is
        its square.
    num_iter : int, optional
        Richardson-Lucy iterations.
    pad_px : int, optional
        Reflection padding each side, px (default: 4 PSF half-widths, at least 8; at most
        the image's shorter side less 1).
    rng : numpy.random.Generator or int or None, optional
        Seed of ``unsupervised_wiener``'s Gibbs sampler.

    Returns
    -------
    numpy.ndarray, (n_rows, n_cols)
        The restored image, image units.

    References
    ----------
    ``skimage.restoration.wiener``, ``skimage.restoration.unsupervised_wiener`` (Orieux, F.,
    Giovannelli, J.-F., Rodet, T., "Bayesian estimation of regularization and point spread
    function parameters for Wiener-Hunt deconvolution", JOSA A 27(7), 2010) and
    ``skimage.restoration.richardson_lucy`` (Richardson, W. H., JOSA 62(1), 1972; Lucy,
    L. B., Astronomical Journal 79, 1974), which it wraps.
    """
    from skimage import restoration

    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2 or min(img.shape) < 2:
        raise ValueError(f"image must be 2-D, at least 2 px a side, got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError("image has non-finite pixels: fill them (e.g. rectify's invalid "
                         "pixels) before deconvolving")
    p = _check_psf(psf)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not (np.isfinite(nsr) and nsr > 0):
        raise ValueError(f"nsr must be finite and > 0, got {nsr}")
    pad = max(8, 4 * (max(p.shape) // 2)) if pad_px is None else int(pad_px)
    pad = min(pad, min(img.shape) - 1)
    x = np.pad(img, pad, mode="reflect")
    if method == "wiener":
        out = restoration.wiener(x, p, balance=nsr**2, reg=np.ones((1, 1)), clip=False)
    elif method == "wiener_laplacian":
        out = restoration.wiener(x, p, balance=nsr**2, clip=False)
    elif method == "unsupervised_wiener":
        out, _ = restoration.unsupervised_wiener(x, p, clip=False, rng=rng)
    else:
        if np.any(img < 0):
            raise ValueError("richardson_lucy needs a non-negative image")
        q = np.clip(p, 0.0, None)
        out = restoration.richardson_lucy(x, q / q.sum(), num_iter=num_iter, clip=False)
    return out[pad:pad + img.shape[0], pad:pad + img.shape[1]]


def noise_transfer(psf, shape: tuple[int, int], nsr: float,
                   method: str = "wiener") -> float:
    """Noise gain of the linear Wiener filters: RMS of the filter's transfer over the DFT
    grid of ``shape`` (white input noise: output sigma / input sigma).

    Parameters
    ----------
    psf : array_like, (K, L)
        Pixel-grid PSF (1 px bins), odd sides, summing to 1.
    shape : tuple of int
        The image's (n_rows, n_cols), px, at least the PSF's.
    nsr : float
        Noise-to-signal amplitude ratio (1/SNR), dimensionless; the balance is its square.
    method : {"wiener", "wiener_laplacian"}, optional
        Constant or Laplacian regulariser, as :func:`deconvolve`.

    Returns
    -------
    float
        Noise gain, dimensionless (output over input noise sigma).

    References
    ----------
    ``skimage.restoration.wiener`` (the filter it evaluates) and
    ``skimage.restoration.uft.laplacian``.
    """
    from skimage.restoration import uft

    if method not in ("wiener", "wiener_laplacian"):
        raise ValueError(f"method must be 'wiener' or 'wiener_laplacian', got {method!r}")
    p = _check_psf(psf)
    if len(shape) != 2 or shape[0] < p.shape[0] or shape[1] < p.shape[1]:
        raise ValueError(f"shape must be 2-D and at least the psf's {p.shape}, got {shape}")
    h = np.fft.fft2(np.pad(p, [(0, shape[0] - p.shape[0]), (0, shape[1] - p.shape[1])]))
    reg = np.ones(shape) if method == "wiener" else np.abs(uft.laplacian(2, shape,
                                                                         is_real=False)[0])
    g = np.conj(h) / (np.abs(h) ** 2 + nsr**2 * reg**2)
    return float(np.sqrt(np.mean(np.abs(g) ** 2)))


def _ramp_up(lines: np.ndarray, boundary: float, half: float) -> np.ndarray:
    if half <= 0:
        return (lines >= boundary).astype(np.float64)
    return np.clip((lines + 0.5 - (boundary - half)) / (2 * half), 0.0, 1.0)


def restore_strip(strip, psfs, run_starts, *, overlap_lines: int = 16,
                  method: str = DEFAULT_METHOD, **kwargs) -> np.ndarray:
    """Space-variant restoration of a strip (n_lines, n_cols): run ``i`` covers lines
    ``run_starts[i]`` to ``run_starts[i + 1]`` (``run_starts[0] == 0``) and is restored with
    ``psfs[i]`` (pixel-grid kernels) over the run extended by ``overlap_lines`` plus the
    deconvolution's own padding each side; neighbouring runs are blended by linear ramps
    ``overlap_lines`` wide centred on their boundary (weights sum to 1). ``kwargs`` go to
    :func:`deconvolve`.

    Parameters
    ----------
    strip : array_like, (n_lines, n_cols)
        The strip, image (intensity) units, finite.
    psfs : sequence of array_like
        One pixel-grid PSF (1 px bins, odd sides, summing to 1) per run.
    run_starts : array_like of int
        First line of each run (lines), starting at 0, strictly increasing.
    overlap_lines : int, optional
        Width of the blending ramps, lines (px), in [0, the shortest run].
    method : str, optional
        The deconvolution, as :func:`deconvolve`.
    **kwargs
        Passed to :func:`deconvolve` (``nsr``, ``num_iter``, ``pad_px``, ``rng``).

    Returns
    -------
    numpy.ndarray, (n_lines, n_cols)
        The restored strip, image units.

    References
    ----------
    The ``skimage.restoration`` filters that :func:`deconvolve` wraps.
    """
    s = np.asarray(strip, dtype=np.float64)
    if s.ndim != 2 or s.size == 0:
        raise ValueError(f"strip must be a non-empty 2-D array, got shape {s.shape}")
    starts = np.asarray(run_starts, dtype=int)
    if (starts.ndim != 1 or starts.size == 0 or starts[0] != 0 or np.any(np.diff(starts) <= 0)
            or starts[-1] >= s.shape[0]):
        raise ValueError("run_starts must start at 0, increase strictly and stay inside the "
                         f"strip's {s.shape[0]} lines, got {starts.tolist()}")
    if len(psfs) != starts.size:
        raise ValueError(f"psfs must hold one kernel per run ({starts.size}), got {len(psfs)}")
    ends = np.append(starts[1:], s.shape[0])
    half = overlap_lines / 2.0
    if overlap_lines < 0 or (starts.size > 1 and half > np.min(ends - starts) / 2):
        raise ValueError(f"overlap_lines must be in [0, the shortest run], got {overlap_lines}")
    lines = np.arange(s.shape[0], dtype=np.float64)
    out = np.zeros_like(s)
    for i, (a, b) in enumerate(zip(starts, ends, strict=True)):  # a handful of runs
        p = _check_psf(psfs[i])
        margin = int(np.ceil(half)) + 4 * (max(p.shape) // 2) + 8
        lo, hi = max(0, a - margin), min(s.shape[0], b + margin)
        w = _ramp_up(lines, a, half) if i > 0 else np.ones_like(lines)
        if i < starts.size - 1:
            w = w * (1.0 - _ramp_up(lines, b, half))
        rows = np.flatnonzero(w > 0)
        block = deconvolve(s[lo:hi], p, method=method, **kwargs)
        out[rows] += w[rows, None] * block[rows - lo]
    return out


@dataclass(frozen=True)
class RestorationFigures:
    """What a restoration gained and cost on a slanted edge: MTF at Nyquist of the static,
    blurred and restored edge, the restored over the static (``mtf_ratio``), noise gain
    (output / input noise sigma on a flat field), and the restored edge's overshoot H and
    RER (GIQE)."""

    method: str
    mtf_static: float
    mtf_blurred: float
    mtf_restored: float
    mtf_ratio: float
    noise_gain: float
    overshoot_h: float
    rer_blurred: float
    rer_restored: float

    def to_dict(self) -> dict:
        return asdict(self)


def restoration_figures(static_edge, blurred_edge, psf, noise_sigma: float, *,
                        method: str = DEFAULT_METHOD, rng: np.random.Generator | None = None,
                        **kwargs) -> RestorationFigures:
    """Restore ``blurred_edge`` (noisy, a nearly horizontal edge) with ``psf`` and measure it
    against ``static_edge``; the noise gain is measured on a flat field at the edge image's
    mean level with white noise of ``noise_sigma`` drawn from ``rng`` (seeded default).

    Parameters
    ----------
    static_edge : array_like, (n_rows, n_cols)
        The motion-free edge image, image (intensity) units.
    blurred_edge : array_like, (n_rows, n_cols)
        The blurred, noisy edge image, image units.
    psf : array_like, (K, L)
        Pixel-grid PSF (1 px bins), odd sides, summing to 1.
    noise_sigma : float
        Noise sigma of the flat field, image units, > 0.
    method : str, optional
        The deconvolution, as :func:`deconvolve`.
    rng : numpy.random.Generator, optional
        Stream of the flat field's noise (default: seeded with 0).
    **kwargs
        Passed to :func:`deconvolve`.

    Returns
    -------
    RestorationFigures
        MTF at Nyquist (0.5 cycles/px) of the static, blurred and restored edge and their
        ratio, noise gain, overshoot H and RER (all dimensionless).

    References
    ----------
    ISO 12233:2017 (slanted-edge MTF); Leachtenauer, J. C., et al., "General Image-Quality
    Equation: GIQE", Applied Optics 36(32), 1997 (RER, H); the ``skimage.restoration``
    filters that :func:`deconvolve` wraps.
    """
    from ground.quality import edge_figures

    if not (np.isfinite(noise_sigma) and noise_sigma > 0):
        raise ValueError(f"noise_sigma must be finite and > 0, got {noise_sigma}")
    g = np.random.default_rng(0) if rng is None else rng
    b = np.asarray(blurred_edge, dtype=np.float64)
    st, bl = edge_figures(static_edge), edge_figures(b)
    restored = deconvolve(b, psf, method=method, **kwargs)
    re = edge_figures(restored)
    flat = np.full(b.shape, float(np.mean(b))) + noise_sigma * g.standard_normal(b.shape)
    out = deconvolve(flat, psf, method=method, **kwargs)
    m = max(np.asarray(psf).shape) // 2 + 2  # the borders see the reflection padding
    gain = float(np.std(out[m:-m, m:-m]) / np.std(flat[m:-m, m:-m]))
    return RestorationFigures(method=method, mtf_static=st.mtf_nyquist,
                              mtf_blurred=bl.mtf_nyquist, mtf_restored=re.mtf_nyquist,
                              mtf_ratio=re.mtf_nyquist / st.mtf_nyquist, noise_gain=gain,
                              overshoot_h=re.overshoot_h, rer_blurred=bl.rer,
                              rer_restored=re.rer)

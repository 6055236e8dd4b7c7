"""Image-quality figures of a product as mission engineers state them.

* Slanted-edge MTF (ISO 12233): the edge's position per line, a straight-line fit, every pixel
  binned at a quarter pixel by its distance to the edge (the edge spread function, ESF), its
  derivative (line spread), a Hamming window, the FFT, corrected for the finite difference.
  This is the canonical copy of imcsim's slanted-edge code (formerly ``imc/blur.py``).
* RER, the relative edge response: the normalised ESF's rise between -0.5 and +0.5 px from
  the edge; edge overshoot H: the normalised ESF's maximum 1.0-3.0 px from the edge in 0.25 px
  steps, or its value at 1.25 px when it rises monotonically there (Leachtenauer et al.,
  "General Image-Quality Equation: GIQE", Applied Optics 36(32), 1997).
* NIIRS by GIQE 5 (NGA, 2015) through pyBSM (``pybsm.metrics.functional.giqe5``; LeMaster &
  Eismann, "pyBSM: A Python package for modeling imaging systems", Proc. SPIE 10204, 2017).
* PSNR and SSIM against the static (motion-free) product (``skimage.metrics``).
* A cross-check of ``compensation.metrics.motion_mtf`` against pyBSM's linear-drift OTF
  (IBSM eq. 3-29) and Gaussian-jitter OTF (IBSM eq. 3-28).

Frequencies are in cycles/px, distances in px of the product.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from compensation.metrics import NYQUIST, motion_mtf

#: ESF half-window each side of the edge (px), as in the ISO code below
ESF_HALF_PX = 16
#: the edge's position per column is the centroid of |d/drow| within this distance (px)
EDGE_WINDOW_PX = 8.0
#: the ESF's plateaus (low and high levels) are averaged beyond this distance from the edge
PLATEAU_PX = 5.0


def _check_image(img: np.ndarray, name: str, min_size: int = 1) -> np.ndarray:
    a = np.asarray(img, dtype=np.float64)
    if a.ndim != 2 or min(a.shape) < min_size:
        raise ValueError(f"{name} must be a 2-D image at least {min_size} px a side, "
                         f"got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} has non-finite pixels: crop or fill them first")
    return a


def _edge_bins(img: np.ndarray, oversample: int, margin: int):
    """ISO 12233 binning: (ESF over the whole ROI, bin index of the edge)."""
    if margin < 1 or oversample < 1:
        raise ValueError(f"margin and oversample must be >= 1, got {margin} and {oversample}")
    im = np.asarray(img, dtype=np.float64)[margin:-margin, margin:-margin]
    d = np.diff(im, axis=0)
    rows = np.arange(d.shape[0]) + 0.5
    w = np.abs(d)
    cols = np.arange(im.shape[1])
    # the centroid only within EDGE_WINDOW_PX of a first fit through each column's steepest
    # step (ISO 12233 windows it likewise): the noise of the whole column would pull it
    first = np.polyfit(cols, rows[np.argmax(w, axis=0)], 1)
    w = np.where(np.abs(rows[:, None] - np.polyval(first, cols)) <= EDGE_WINDOW_PX, w, 0.0)
    pos = (w * rows[:, None]).sum(axis=0) / np.maximum(w.sum(axis=0), 1e-12)
    fit = np.polyfit(cols, pos, 1)
    rr, cc = np.mgrid[0:im.shape[0], 0:im.shape[1]]
    dist = (rr - np.polyval(fit, cc)) / np.sqrt(1.0 + fit[0] ** 2)
    b = np.round(dist * oversample).astype(int)
    lo = b.min()
    counts = np.bincount((b - lo).ravel())
    esf = np.bincount((b - lo).ravel(), weights=im.ravel()) / np.maximum(counts, 1)
    keep = counts > 0
    idx = np.flatnonzero(keep)
    esf = np.interp(np.arange(len(esf)), idx, esf[keep])
    return esf, -lo


def edge_mtf(img: np.ndarray, oversample: int = 4, margin: int = 8):
    """(freqs cycles/px, MTF) across a nearly horizontal edge (ISO 12233 slanted edge).

    The MTF is along the image's row axis (across the edge). For the column axis pass the
    transpose of an image with a nearly vertical edge. ``margin`` px are cut on every side.

    Parameters
    ----------
    img : numpy.ndarray, (n_rows, n_cols)
        Image (any intensity units) holding one nearly horizontal edge; rows and columns are
        px.
    oversample : int, optional
        ESF bins per px (4: quarter-px bins, as ISO 12233).
    margin : int, optional
        Border cut off on every side before the fit, px (>= 1).

    Returns
    -------
    freqs : numpy.ndarray
        Spatial frequencies, cycles/px, from 0 to ``oversample / 2``.
    mtf : numpy.ndarray
        MTF at ``freqs`` (dimensionless, 1 at 0), corrected for the finite difference's
        sinc.

    References
    ----------
    ISO 12233:2017, "Photography -- Electronic still picture imaging -- Resolution and
    spatial frequency responses" (slanted-edge SFR).
    """
    esf, centre = _edge_bins(img, oversample, margin)
    half = ESF_HALF_PX * oversample  # +-16 px around the edge
    esf = esf[max(0, centre - half):centre + half]
    lsf = np.diff(esf) * np.hamming(len(esf) - 1)
    spec = np.abs(np.fft.rfft(lsf))
    spec /= spec[0]
    f = np.fft.rfftfreq(len(lsf), 1.0 / oversample)
    corr = np.sinc(f / oversample)  # the finite difference's transfer function
    return f, spec / np.maximum(corr, 1e-6)


def value_at(f: np.ndarray, mtf: np.ndarray, f0: float) -> float:
    """The curve (f, mtf) at frequency f0 (linear interpolation).

    Parameters
    ----------
    f : numpy.ndarray
        Increasing frequencies, cycles/px.
    mtf : numpy.ndarray
        The curve's values at ``f`` (dimensionless).
    f0 : float
        Frequency to read the curve at, cycles/px (held at the end values outside ``f``).

    Returns
    -------
    float
        The curve at ``f0`` (dimensionless).

    References
    ----------
    ``numpy.interp``, which it wraps.
    """
    return float(np.interp(f0, f, mtf))


def edge_spread(img: np.ndarray, oversample: int = 4, margin: int = 8):
    """Normalised edge spread function across a nearly horizontal edge.

    Returns ``(dist_px, esf, contrast)``: distance to the fitted edge (px, increasing toward
    the bright side), the ESF scaled to 0 on the dark plateau and 1 on the bright one (the
    means beyond ``PLATEAU_PX`` from the edge, within +-16 px), and the plateaus' difference
    (image units). Same binning as :func:`edge_mtf`.

    Parameters
    ----------
    img : numpy.ndarray, (n_rows, n_cols)
        Image (any intensity units) holding one nearly horizontal edge; rows and columns are
        px.
    oversample : int, optional
        ESF bins per px (4: quarter-px bins).
    margin : int, optional
        Border cut off on every side before the fit, px (>= 1).

    Returns
    -------
    dist_px : numpy.ndarray
        Distance of each ESF bin to the fitted edge, px, increasing toward the bright side,
        in steps of ``1 / oversample`` px.
    esf : numpy.ndarray
        The ESF at ``dist_px``, dimensionless: 0 on the dark plateau, 1 on the bright one.
    contrast : float
        Bright minus dark plateau, image (intensity) units, > 0.

    References
    ----------
    ISO 12233:2017, "Photography -- Electronic still picture imaging -- Resolution and
    spatial frequency responses" (the slanted edge's binning).
    """
    esf, centre = _edge_bins(img, oversample, margin)
    half = ESF_HALF_PX * oversample
    start = max(0, centre - half)
    esf = esf[start:centre + half]
    dist = (np.arange(len(esf)) + start - centre) / oversample
    below, above = esf[dist <= -PLATEAU_PX], esf[dist >= PLATEAU_PX]
    if below.size == 0 or above.size == 0:
        raise ValueError(f"img: the edge must lie more than {PLATEAU_PX + margin:g} px inside "
                         "the region on both sides")
    low, high = float(np.mean(below)), float(np.mean(above))
    if high < low:  # bright side first: turn it round so the ESF rises
        dist, esf, low, high = -dist[::-1], esf[::-1], high, low
    contrast = high - low
    if contrast <= 0:
        raise ValueError("img has no edge: its two sides have the same mean level")
    return dist, (esf - low) / contrast, contrast


def rer_from_esf(dist_px: np.ndarray, esf: np.ndarray) -> float:
    """Relative edge response: normalised ESF at +0.5 px minus at -0.5 px (GIQE).

    Parameters
    ----------
    dist_px : numpy.ndarray
        Increasing distances to the edge, px (as from :func:`edge_spread`).
    esf : numpy.ndarray
        Normalised ESF at ``dist_px`` (dimensionless, 0 dark, 1 bright).

    Returns
    -------
    float
        RER, dimensionless (the ESF's rise per px across the edge).

    References
    ----------
    Leachtenauer, J. C., et al., "General Image-Quality Equation: GIQE", Applied Optics
    36(32), 1997.
    """
    return float(np.interp(0.5, dist_px, esf) - np.interp(-0.5, dist_px, esf))


def overshoot_from_esf(dist_px: np.ndarray, esf: np.ndarray) -> float:
    """Edge overshoot H (GIQE 4): max of the normalised ESF at 1.0..3.0 px (0.25 px steps),
    or its value at 1.25 px if it rises monotonically there (Leachtenauer et al. 1997).

    Parameters
    ----------
    dist_px : numpy.ndarray
        Increasing distances to the edge, px (as from :func:`edge_spread`).
    esf : numpy.ndarray
        Normalised ESF at ``dist_px`` (dimensionless, 0 dark, 1 bright).

    Returns
    -------
    float
        Overshoot H, dimensionless (1 for an edge without overshoot).

    References
    ----------
    Leachtenauer, J. C., et al., "General Image-Quality Equation: GIQE", Applied Optics
    36(32), 1997.
    """
    er = np.interp(np.arange(1.0, 3.25, 0.25), dist_px, esf)
    return float(er[1] if np.all(np.diff(er) > 0) else np.max(er))


@dataclass(frozen=True)
class EdgeFigures:
    """Slanted-edge figures along one axis: MTF at Nyquist, RER, overshoot H, contrast."""

    mtf_nyquist: float
    rer: float
    overshoot_h: float
    contrast: float

    def to_dict(self) -> dict:
        return asdict(self)


def edge_figures(img: np.ndarray, oversample: int = 4, margin: int = 8) -> EdgeFigures:
    """MTF at Nyquist, RER, overshoot H and contrast across a nearly horizontal edge.

    Parameters
    ----------
    img : numpy.ndarray, (n_rows, n_cols)
        Finite image (any intensity units) holding one nearly horizontal edge, at least
        ``2 * margin + 2 * ESF_HALF_PX`` px a side.
    oversample : int, optional
        ESF bins per px (4: quarter-px bins).
    margin : int, optional
        Border cut off on every side before the fit, px (>= 1).

    Returns
    -------
    EdgeFigures
        MTF at Nyquist (0.5 cycles/px), RER and overshoot H (dimensionless) along the row
        axis, and the edge's contrast (image units).

    References
    ----------
    ISO 12233:2017 (slanted-edge MTF); Leachtenauer, J. C., et al., "General Image-Quality
    Equation: GIQE", Applied Optics 36(32), 1997 (RER, overshoot H).
    """
    a = _check_image(img, "img", min_size=2 * margin + 2 * ESF_HALF_PX)
    f, mtf = edge_mtf(a, oversample, margin)
    dist, esf, contrast = edge_spread(a, oversample, margin)
    return EdgeFigures(mtf_nyquist=value_at(f, mtf, NYQUIST), rer=rer_from_esf(dist, esf),
                       overshoot_h=overshoot_from_esf(dist, esf), contrast=contrast)


def niirs_giqe5(rer_1: float, rer_2: float, gsd_m: float, snr: float,
                elevation_rad: float) -> float:
    """NIIRS by GIQE 5 through pyBSM.

    ``rer_1``, ``rer_2``: RER along two perpendicular axes (pyBSM forms the weighted
    geometric mean (max * min^2)^(1/3)); ``gsd_m``: image-plane geometric-mean GSD (m);
    ``snr``: contrast SNR; ``elevation_rad``: sensor elevation seen from the target (pi/2 at
    nadir). Reference: NGA, "General Image Quality Equation version 5.0", 2015.

    Parameters
    ----------
    rer_1, rer_2 : float
        Relative edge response along two perpendicular axes, dimensionless, > 0.
    gsd_m : float
        Geometric-mean ground sample distance, m, > 0.
    snr : float
        Contrast SNR (edge contrast over noise sigma), dimensionless, > 0.
    elevation_rad : float
        Sensor elevation seen from the target, rad, in (0, pi/2] (pi/2 at nadir).

    Returns
    -------
    float
        NIIRS (the rating scale's units).

    References
    ----------
    NGA, "General Image Quality Equation (GIQE) version 5.0", 2015;
    ``pybsm.metrics.functional.giqe5``, which it wraps (LeMaster & Eismann, "pyBSM: A Python
    package for modeling imaging systems", Proc. SPIE 10204, 2017).
    """
    from pybsm.metrics.functional import giqe5

    for name, v in (("rer_1", rer_1), ("rer_2", rer_2), ("gsd_m", gsd_m), ("snr", snr)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v}")
    if not (0 < elevation_rad <= np.pi / 2):
        raise ValueError(f"elevation_rad must be in (0, pi/2], got {elevation_rad}")
    niirs, _, _ = giqe5(rer_1=float(rer_1), rer_2=float(rer_2), gsd=float(gsd_m),
                        snr=float(snr), elev_angle=float(elevation_rad))
    return float(niirs)


Roi = tuple[slice, slice]


@dataclass(frozen=True)
class ImageQuality:
    """Quality figures of one product (None where the input to measure it was not given).

    ``mtf_nyquist``, ``rer``, ``overshoot_h``: (along, across), i.e. along the row axis (a
    nearly horizontal edge) and along the column axis (a nearly vertical edge).
    ``noise_sigma``: std of the flat region (image units); ``noise_gain``: it over the input
    noise sigma; ``snr``: edge contrast over noise sigma (GIQE's contrast SNR), or the flat
    region's mean over its std without an edge. ``psnr_db``, ``ssim``: against the static
    product over the valid pixels.
    """

    mtf_nyquist: tuple[float | None, float | None]
    rer: tuple[float | None, float | None]
    overshoot_h: tuple[float | None, float | None]
    noise_sigma: float | None
    noise_gain: float | None
    snr: float | None
    niirs: float | None
    gsd_m: float | None
    elevation_rad: float | None
    psnr_db: float | None
    ssim: float | None

    def to_dict(self) -> dict:
        return asdict(self)


def _psnr_ssim(product: np.ndarray, static: np.ndarray, valid: np.ndarray | None,
               data_range: float | None) -> tuple[float, float]:
    from scipy.ndimage import binary_erosion
    from skimage.metrics import structural_similarity

    s = _check_image(static, "static")
    if s.shape != product.shape:
        raise ValueError(f"static must have the product's shape {product.shape}, got {s.shape}")
    ok = np.isfinite(product) if valid is None else np.asarray(valid, bool) & np.isfinite(product)
    if ok.shape != product.shape or not ok.any():
        raise ValueError("valid must be a boolean mask of the product's shape with some True")
    rng = float(np.ptp(s)) if data_range is None else float(data_range)
    if rng <= 0:
        raise ValueError("data_range must be > 0 (static is flat: give data_range)")
    mse = float(np.mean((product[ok] - s[ok]) ** 2))
    psnr = float(10 * np.log10(rng**2 / mse)) if mse > 0 else float("inf")
    filled = np.where(ok, product, s)
    _, smap = structural_similarity(s, filled, data_range=rng, full=True)
    inner = binary_erosion(ok, np.ones((7, 7), bool))  # SSIM's 7 px window wholly valid
    return psnr, float(np.mean(smap[inner] if inner.any() else smap[ok]))


def image_quality(product: np.ndarray, static: np.ndarray | None = None, *,
                  edge_roi_along: Roi | None = None, edge_roi_across: Roi | None = None,
                  flat_roi: Roi | None = None, noise_sigma_in: float | None = None,
                  gsd_m: float | None = None, elevation_rad: float = np.pi / 2,
                  valid: np.ndarray | None = None, data_range: float | None = None
                  ) -> ImageQuality:
    """Quality figures of a product (2-D, rows = lines).

    ``edge_roi_along``: (row slice, col slice) holding a nearly horizontal edge (MTF along the
    rows); ``edge_roi_across``: one holding a nearly vertical edge (MTF along the columns);
    ``flat_roi``: a uniform region (noise); ``noise_sigma_in``: the noise sigma before
    processing (for the noise gain); ``gsd_m`` and ``elevation_rad``: for NIIRS (GIQE 5 needs
    both edges, the flat region and the GSD); ``static`` (and ``valid``): the motion-free
    product for PSNR/SSIM, ``data_range`` defaulting to the static's peak-to-peak.

    Parameters
    ----------
    product : numpy.ndarray, (n_lines, n_cols)
        The product, image (intensity) units; rows are lines, px.
    static : numpy.ndarray, (n_lines, n_cols), optional
        The motion-free product, same units and shape, for PSNR and SSIM.
    edge_roi_along : tuple of slice, optional
        (row slice, col slice), px, of a region holding a nearly horizontal edge.
    edge_roi_across : tuple of slice, optional
        (row slice, col slice), px, of a region holding a nearly vertical edge.
    flat_roi : tuple of slice, optional
        (row slice, col slice), px, of a uniform region (noise, SNR).
    noise_sigma_in : float, optional
        Noise sigma before processing, image units, > 0 (for the noise gain).
    gsd_m : float, optional
        Geometric-mean ground sample distance, m (for NIIRS).
    elevation_rad : float, optional
        Sensor elevation seen from the target, rad (pi/2 at nadir; for NIIRS).
    valid : numpy.ndarray of bool, (n_lines, n_cols), optional
        Pixels that count for PSNR/SSIM (default: the finite ones).
    data_range : float, optional
        Dynamic range for PSNR/SSIM, image units (default: the static's peak-to-peak).

    Returns
    -------
    ImageQuality
        The figures (None where their input was not given): MTF at Nyquist, RER and H
        (dimensionless), noise sigma (image units), noise gain and SNR (dimensionless),
        NIIRS, GSD (m), elevation (rad), PSNR (dB), SSIM (dimensionless).

    References
    ----------
    ISO 12233:2017 (slanted-edge MTF); Leachtenauer, J. C., et al., "General Image-Quality
    Equation: GIQE", Applied Optics 36(32), 1997 (RER, H); NGA, "General Image Quality
    Equation version 5.0", 2015 (NIIRS); Wang, Z., Bovik, A. C., Sheikh, H. R., Simoncelli,
    E. P., "Image quality assessment: from error visibility to structural similarity", IEEE
    Trans. Image Processing 13(4), 2004, through ``skimage.metrics.structural_similarity``
    (SSIM).
    """
    p = np.asarray(product, dtype=np.float64)
    if p.ndim != 2 or p.size == 0:
        raise ValueError(f"product must be a non-empty 2-D image, got shape {p.shape}")
    along = across = None
    if edge_roi_along is not None:
        along = edge_figures(p[edge_roi_along])
    if edge_roi_across is not None:
        across = edge_figures(p[edge_roi_across].T)
    sigma = gain = snr = None
    if flat_roi is not None:
        flat = _check_image(p[flat_roi], "product[flat_roi]", min_size=2)
        sigma = float(np.std(flat, ddof=1))
        if noise_sigma_in is not None:
            if not noise_sigma_in > 0:
                raise ValueError(f"noise_sigma_in must be > 0, got {noise_sigma_in}")
            gain = sigma / noise_sigma_in
        edges = [e for e in (along, across) if e is not None]
        level = np.mean([e.contrast for e in edges]) if edges else float(np.mean(flat))
        snr = float(level / sigma) if sigma > 0 else float("inf")
    niirs = None
    if (along is not None and across is not None and snr is not None and gsd_m is not None
            and along.rer > 0 and across.rer > 0):  # an edge smeared past its ROI: no NIIRS
        niirs = niirs_giqe5(along.rer, across.rer, gsd_m, snr, elevation_rad)
    psnr = ssim = None
    if static is not None:
        psnr, ssim = _psnr_ssim(p, static, valid, data_range)

    def pair(attr):
        return tuple(None if e is None else getattr(e, attr) for e in (along, across))

    return ImageQuality(mtf_nyquist=pair("mtf_nyquist"), rer=pair("rer"),
                        overshoot_h=pair("overshoot_h"), noise_sigma=sigma, noise_gain=gain,
                        snr=snr, niirs=niirs, gsd_m=gsd_m,
                        elevation_rad=elevation_rad if niirs is not None else None,
                        psnr_db=psnr, ssim=ssim)


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields, not objects
class MotionMtfCheck:
    """``motion_mtf`` of a sample set against pyBSM's OTF at the same frequencies."""

    freqs: np.ndarray
    motion_mtf: np.ndarray
    pybsm_otf: np.ndarray
    max_abs_diff: float

    def to_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in asdict(self).items()}


def motion_mtf_vs_pybsm(r_px: np.ndarray, model: str, axis: int = 0,
                        freqs: np.ndarray | None = None, smear_px: float | None = None,
                        sigma_px: float | None = None) -> MotionMtfCheck:
    """Compare ``compensation.metrics.motion_mtf`` of residual samples r (T, 2) px with pyBSM.

    ``model="drift"``: pyBSM's ``drift_OTF`` (IBSM eq. 3-29, sinc(a f)) for a uniform smear
    of ``smear_px`` (default: the samples' peak-to-peak along ``axis`` times T/(T-1), the
    length of a smear sampled at T evenly spaced mid-points). ``model="jitter"``: pyBSM's
    ``jitter_OTF`` (IBSM eq. 3-28, exp(-2 pi^2 s^2 f^2)) for Gaussian jitter of ``sigma_px``
    (default: the samples' RMS about their mean). pyBSM takes angles; with an IFOV of 1 the
    angles are px and the frequencies cycles/px.

    Parameters
    ----------
    r_px : numpy.ndarray, (T, 2)
        Residual motion samples (row, col), px, evenly spaced in time over the exposure,
        T >= 2.
    model : {"drift", "jitter"}
        pyBSM's OTF to compare with.
    axis : int, optional
        0 (row) or 1 (col): the axis of the motion and of the frequencies.
    freqs : numpy.ndarray, optional
        Spatial frequencies, cycles/px (default: 41 from 0 to 1).
    smear_px : float, optional
        Length of the linear smear for ``"drift"``, px.
    sigma_px : float, optional
        Jitter standard deviation for ``"jitter"``, px.

    Returns
    -------
    MotionMtfCheck
        The frequencies (cycles/px), both MTFs (dimensionless) and their largest absolute
        difference.

    References
    ----------
    Wulich, D., Kopeika, N. S., "Image resolution limits resulting from mechanical
    vibrations", Optical Engineering 26(6), 1987 (motion MTF);
    ``pybsm.otf.functional.drift_OTF`` and ``jitter_OTF`` (IBSM eqs. 3-29 and 3-28), which
    it calls (LeMaster & Eismann, Proc. SPIE 10204, 2017).
    """
    from pybsm.otf.functional import drift_OTF, jitter_OTF

    r = np.asarray(r_px, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 2 or r.shape[0] < 2 or not np.all(np.isfinite(r)):
        raise ValueError(f"r_px must be finite samples (T >= 2, 2), got shape {r.shape}")
    if axis not in (0, 1):
        raise ValueError(f"axis must be 0 (row) or 1 (col), got {axis}")
    f = np.linspace(0.0, 1.0, 41) if freqs is None else np.asarray(freqs, dtype=np.float64)
    ours = np.array([float(motion_mtf(r, fi, axis)) for fi in f])  # a few dozen frequencies
    u = np.ascontiguousarray(f[None, :])
    zero = np.zeros_like(u)
    x = r[:, axis]
    if model == "drift":
        a = float(np.ptp(x) * len(x) / (len(x) - 1)) if smear_px is None else float(smear_px)
        theirs = drift_OTF(u=u, v=zero, a_x=a, a_y=0.0)[0]
    elif model == "jitter":
        s = float(np.std(x)) if sigma_px is None else float(sigma_px)
        theirs = jitter_OTF(u=u, v=zero, s_x=s, s_y=0.0)[0]
    else:
        raise ValueError(f"model must be 'drift' or 'jitter', got {model!r}")
    theirs = np.abs(theirs)
    return MotionMtfCheck(freqs=f, motion_mtf=ours, pybsm_otf=theirs,
                          max_abs_diff=float(np.max(np.abs(ours - theirs))))

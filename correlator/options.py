"""The correlator's options: what :func:`correlator.core.measure_shift` and
:class:`correlator.core.Correlator` are asked to do, and their checks.

A light module (numpy only): the scenario's checks (``imc validate``) make and check the
options without importing the correlator's compiled kernels or FFT back end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from correlator.jtc import JTC_FILTERS
from correlator.optical import JtocModel

#: the default PSR floor besides the detection's false-alarm rate (see
#: ``CorrelatorOptions.psr_threshold``), and the optical correlator's PSR threshold (its
#: output plane has no noise model)
PSR_SAFEGUARD = 5.5
OPTICAL_PSR_THRESHOLD = 7.0
#: the optical correlator's largest predicted error of a valid result, px, where
#: ``max_crlb_px`` is None (its output plane has no tail model either)
OPTICAL_MAX_CRLB_PX = 0.15

#: the correlation methods, sub-pixel estimators, weightings and integer-peak detections
METHODS = ("jtc", "xcorr", "phase", "optical")
SUBPIXEL = ("fourier", "gradient", "parabolic", "gaussian", "com")
#: peak fits an optical correlator can do on its output plane
OPTICAL_SUBPIXEL = ("com", "parabolic", "gaussian")
WEIGHTINGS = ("snr", "flat")
DETECTIONS = ("auto", "band", "masked")


@dataclass(frozen=True)
class CorrelatorOptions:
    """Options shared by :func:`measure_shift` and :class:`Correlator`.

    method : 'jtc' (default), 'xcorr' or 'phase': the surface of peak fits and joint planes;
        'optical': the emulated optical correlator (:mod:`correlator.optical`).
    subpixel : 'fourier' (default; 'com', the paper's centre of mass, for 'optical'),
        'gradient', 'parabolic', 'gaussian' or 'com'.
    jtc_filter : 'subtract' (default), 'plain' (joint plane only) or 'fringe'.
    joint_plane : for 'jtc', build the joint input plane explicitly (slower, as the optics do).
    false_valid_rate : a result is valid only when the probability that it is 0.5 px or more
        off on an axis (``ShiftResult.p_wrong``) is at most this: that noise alone put a
        peak as high as its peak in the searched area (``ShiftResult.p_false``,
        :func:`correlator.detection.false_alarm_probability` of its PSR over the searched
        cells) or that the estimate on the true peak lies in its tail
        (:func:`correlator.tail.tail_probability` of its predicted error and restoring
        ratio). 0.005 (default): an axis's predicted error up to ~0.19 px on low-pass
        texture; low-contrast photographs 83.7 % valid and within 0.5 px (scikit-image 83.5 %
        within), weak texture at SNR 10 75 % with 0.17 % false-valid, 0 of 10,000 noise-only
        pairs (``benchmarks/bench_estimator.py``). 0.001: 80.8 % and 27 % (the former
        0.15 px limit alone: 81.4 % and 38 %). Noise peaks alone reach 0.001 at a PSR of 4.8
        (33^2 cells, the quarter-block search of 64^2-256^2 blocks), 4.5 at 32^2 (17^2).
    psr_threshold : the least PSR of a valid result besides ``false_valid_rate``, a
        safeguard. None (default): :data:`PSR_SAFEGUARD` (5.5; 7 for method 'optical', whose
        output plane has no noise model). With the detection gate alone (no PSR floor) 1 of
        10,000 noise-only pairs came out valid at 32^2 and at 64^2 (PSR 4.7 and 5.2: the
        0.001 detection rate leaves ~1e-4 after the other gates), and smooth checkerboards and
        stripes with their period inside the search 0.8 % of 3000 (0.4 % with 5.5, 0.2 %
        with 7); 5.5 (a noise-only false-alarm rate of 2e-5 at 33^2 cells) gave 0 of 30,000
        noise-only pairs. So at the default search the floor, not the 0.001 rate, is the
        binding PSR; the rate binds below ~2e-5 (or beyond ~50,000 searched cells).
    max_shift_px : largest |shift| component searched; default a quarter of the block size.
    max_crlb_px : None (default) or the largest predicted 1-sigma error of a valid result,
        px, besides ``false_valid_rate`` (whose tail term already limits it: at 0.005 no
        result with an axis's predicted error above 0.5 / 2.81 = 0.178 px divided by its
        restoring ratio passes). The former default 0.15 adds nothing measurable at
        a rate of 0.001 (the same results on 1,600 weak and medium pairs).
    weighting : 'snr' (Knapp-Carter weights, default) or 'flat' for the Fourier refinement.
    rewindow : None (default): one FFT per block, then the passes with both windows on the
        common content only for the blocks whose first pass needs them (from the block's own
        predicted error, PSR, peak width and the window bias removed from its first pass:
        ``Correlator._needs_precise``; ``ShiftResult.precise`` says which). The first pass
        removes the bias its unlike windows give (measured on the reference against itself),
        which had kept it several times off on rendered scenes (the flight test's blocks
        0.046 px against a 0.006 px bound; now 0.0065 px, the precise path's 0.0063).
        True: every block gets the passes (the precise path, 2-2.5x the cost on strong
        texture). False: none but blocks moved beyond the exact margin (the first pass).
    iterations : Newton (fourier) or Lucas-Kanade (gradient) iterations.
    workers : threads over the block stack (-1: all cores).
    optical : the hardware model of method 'optical' (default: :class:`JtocModel`()).
    detection : integer-peak search. 'band': the SNR-whitened circular surface (fast; for
        shifts up to a quarter block). 'masked': the overlap-normalised correlation of
        zero-padded blocks (:mod:`correlator.masked`; unambiguous up to the block size, robust
        at small overlap). 'auto' (default): 'masked' when ``max_shift_px`` exceeds a quarter
        of the block, else 'band'.
    min_overlap : smallest fraction of the block area two blocks must share for a lag to be
        searched by the 'masked' detection.
    max_rival_ratio : 'masked' detection only: a result is invalid when another local maximum
        of the overlap-normalised score reaches this fraction of the best (an ambiguous match:
        one straight edge, a repeated pattern). 0.94 keeps > 99 % of the correct matches on
        rendered rural and mountain scenes while rejecting the ambiguous ones. (The band
        detection's test is :data:`BAND_MAX_RIVAL_RATIO` on the PSR scale.)
    trust_prediction_px : None (default): predictions are not used by the correlator.
        A distance, px: ``Correlator.measure(predicted=...)`` (and ``BlockTracker.update``
        with a prediction) starts Newton from the predicted shift and skips the integer search
        for every block whose result settles within this distance of its prediction; the
        others are searched as usual. Needs subpixel 'fourier' and the band detection.
    """

    method: str = "jtc"
    subpixel: str | None = None
    jtc_filter: str = "subtract"
    joint_plane: bool = False
    false_valid_rate: float = 0.005
    psr_threshold: float | None = None
    max_shift_px: float | None = None
    max_crlb_px: float | None = None
    weighting: str = "snr"
    rewindow: bool | None = None
    iterations: int = 3
    workers: int = -1
    optical: JtocModel | None = None
    detection: str = "auto"
    min_overlap: float = 0.25
    max_rival_ratio: float = 0.94
    trust_prediction_px: float | None = None

    def __post_init__(self) -> None:
        if self.subpixel is None:
            object.__setattr__(self, "subpixel", "com" if self.method == "optical" else "fourier")
        if self.method == "optical":
            if self.subpixel not in OPTICAL_SUBPIXEL:
                raise ValueError(f"method 'optical' reads a correlation plane: subpixel must be "
                                 f"one of {OPTICAL_SUBPIXEL}, got {self.subpixel!r}")
            if self.optical is None:
                object.__setattr__(self, "optical", JtocModel())
        for name, allowed in (("method", METHODS), ("subpixel", SUBPIXEL),
                              ("jtc_filter", JTC_FILTERS), ("weighting", WEIGHTINGS),
                              ("detection", DETECTIONS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if self.rewindow not in (None, True, False):
            raise ValueError(f"rewindow must be None, True or False, got {self.rewindow!r}")
        if self.jtc_filter == "plain" and not self.joint_plane:
            raise ValueError("jtc_filter='plain' needs joint_plane=True (the fast path has no "
                             "DC terms to keep)")
        for name in ("false_valid_rate", "psr_threshold", "max_shift_px", "max_crlb_px",
                     "min_overlap",
                     "max_rival_ratio", "trust_prediction_px"):
            v = getattr(self, name)
            if v is not None and not np.isfinite(v):  # NaN would pass every test below
                raise ValueError(f"{name} must be a finite number, got {v}")
        if self.psr_threshold is None:
            object.__setattr__(self, "psr_threshold",
                               OPTICAL_PSR_THRESHOLD if self.method == "optical"
                               else PSR_SAFEGUARD)
        if (self.psr_threshold < 0 or self.iterations < 0
                or (self.max_crlb_px is not None and self.max_crlb_px <= 0)):
            raise ValueError("psr_threshold and iterations must be >= 0, max_crlb_px > 0")
        if not 0.0 < self.false_valid_rate < 1.0:
            raise ValueError(f"false_valid_rate must be within (0, 1), got "
                             f"{self.false_valid_rate}")
        if self.max_shift_px is not None and self.max_shift_px < 0:
            raise ValueError(f"max_shift_px must be >= 0, got {self.max_shift_px}")
        if not 0.0 < self.min_overlap <= 1.0:
            raise ValueError(f"min_overlap must be within (0, 1], got {self.min_overlap}")
        if not 0.0 < self.max_rival_ratio <= 1.0:
            raise ValueError(f"max_rival_ratio must be within (0, 1], got {self.max_rival_ratio}")
        if self.trust_prediction_px is not None:
            if not self.trust_prediction_px > 0:
                raise ValueError(f"trust_prediction_px must be > 0, got "
                                 f"{self.trust_prediction_px}")
            if self.subpixel != "fourier" or self.joint_plane or self.detection == "masked":
                raise ValueError("trust_prediction_px needs subpixel='fourier', no joint plane "
                                 "and the band detection")

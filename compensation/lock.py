"""Lock time: when the loop's residual has settled, from the analytic model or from a run.

Two definitions, one per source:

* :func:`analytic_lock_time` (the design): a unit step of the disturbance (or a disturbance
  that starts) at the start of frame 0; the residual the tracker sees, frame by frame (the
  exposure mean of disturbance minus stage), is the step response of the closed loop's
  sampled sensitivity S_d(z) (the same transfer functions as
  :class:`compensation.analytic.LoopModel`). The lock time is the start time, counted from
  the onset, of the first frame after which every frame's residual stays within ``band`` of
  its final value, ``band`` a fraction of the step (``band=0.02``: the classical 2 % settling
  time). For a first-order loop (integrator of gain k, one frame from exposure to command)
  S_d = (1 - z^-1) / (1 - (1 - k) z^-1): the residual is (1 - k)^j at frame j and the lock
  time is ceil(ln(band) / ln|1 - k|) frames.
* :func:`run_lock_time` (a run): the residual samples' running RMS over a trailing window of
  ``window_s``; the steady-state RMS is the RMS over the last ``steady_fraction`` of the
  samples (or from ``steady_from_s``). The lock time is the first sample time after which the
  running RMS stays at or below ``(1 + band) * steady RMS + floor_px``. Only the upper side
  counts: a residual smaller than its steady state is locked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compensation.controllers import polymul
from compensation.metrics import json_dict


@dataclass(frozen=True)
class AnalyticLock:
    """The analytic model's lock time.

    lock_s : time from the step's onset until the residual stays within ``band`` of its
        final value (inf: the loop is unstable or never settles within the horizon).
    band : the band, a fraction of the step.
    final : the residual's final value (0 with an integrator in the loop).
    slowest_pole : the largest closed-loop pole radius |z| (nan: none).
    time_constant_s : -T / ln(slowest_pole): the slowest pole's time constant.
    pole_lock_s : time_constant_s * ln(1 / band): when the slowest closed-loop mode has decayed
        to ``band`` of its start; the lock time of a disturbance onset that excites that mode
        fully (a resonant term's convergence on a line that starts), where a step may barely
        excite it.
    """

    lock_s: float
    band: float
    final: float
    slowest_pole: float
    time_constant_s: float
    pole_lock_s: float

    def to_dict(self) -> dict:
        return json_dict(self)


def sensitivity_polys(model) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) in z^-1 of the frame-sampled sensitivity S_d of ``model``
    (a :class:`compensation.analytic.LoopModel`): the exposure-mean residual per unit of
    exposure-mean disturbance, S_d = 1 - P(z) U(z), U the command's response
    (:meth:`LoopModel.command_tf`) and P(z) the stage's exposure means per held command.
    den is the closed loop's characteristic polynomial."""
    b, a, predictor = model.controller_tf()
    g, g_pq = model.plant_polys()
    n, _ = model.timing
    p, *_ = model.pulse
    loop = g_pq if predictor else g
    den = _add(a, polymul(b, loop))
    xn_p = np.concatenate([np.zeros(n), p])
    num = _add(den, -polymul(b, xn_p))
    return np.trim_zeros(num, "b"), np.trim_zeros(den, "b")


def _add(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    out = np.zeros(max(len(p), len(q)))
    out[: len(p)] += p
    out[: len(q)] += q
    return out


def analytic_lock_time(model, band: float = 0.02, max_s: float = 600.0) -> AnalyticLock:
    """Lock time of ``model``'s loop after a unit disturbance step (see module docstring).

    band : the settling band, a fraction of the step (0 < band < 1).
    max_s : the longest response computed, s; a loop not settled by then gives inf.
    """
    if not 0.0 < band < 1.0:
        raise ValueError(f"band must be within (0, 1), got {band}")
    if not max_s > 0:
        raise ValueError(f"max_s must be > 0, got {max_s}")
    period = model.period_s
    num, den = sensitivity_polys(model)
    poles = np.roots(den) if len(den) > 1 else np.empty(0)
    radius = float(np.max(np.abs(poles))) if poles.size else float("nan")
    tau = (-period / np.log(radius) if poles.size and 0.0 < radius < 1.0
           else (0.0 if poles.size and radius == 0.0 else float("inf")))
    if model.unstable_roots() > 0 or (poles.size and radius >= 1.0):
        return AnalyticLock(float("inf"), band, float("nan"), radius, float("inf"),
                            float("inf"))
    # long enough for the slowest pole to fall far below the band, and for the longest
    # polynomial to act; capped at max_s
    decay = (0 if not np.isfinite(tau) or tau == 0.0
             else int(np.ceil(tau / period * np.log(1e3 / band))))
    n_max = max(1, int(np.ceil(max_s / period)))
    horizon = min(n_max, len(num) + len(den) + decay + 16)
    r = _step_response(num, den, horizon)
    final = float(np.sum(num) / np.sum(den)) if abs(np.sum(den)) > 0 else float("nan")
    outside = np.flatnonzero(np.abs(r - final) > band)
    if not outside.size:
        lock = 0.0
    elif outside[-1] >= horizon - 1:
        lock = float("inf")
    else:
        lock = float((outside[-1] + 1) * period)
    return AnalyticLock(lock, band, final, radius, float(tau), float(tau * np.log(1.0 / band)))


def _step_response(num: np.ndarray, den: np.ndarray, n: int) -> np.ndarray:
    """The first n samples of the unit-step response of num / den (z^-1 polynomials): the
    difference equation run sample by sample (n is a few thousand at most; scipy.signal's
    lfilter would cost its second-long import in ``imc validate``)."""
    b = np.zeros(max(len(num), len(den)))
    a = np.zeros_like(b)
    b[: len(num)], a[: len(den)] = num, den
    b, a = b / den[0], a / den[0]
    x_hist = np.zeros(len(b))
    y_hist = np.zeros(len(a))
    out = np.empty(n)
    for i in range(n):
        x_hist = np.roll(x_hist, 1)
        x_hist[0] = 1.0
        y = float(b @ x_hist - a[1:] @ y_hist[: len(a) - 1])
        y_hist = np.roll(y_hist, 1)
        y_hist[0] = y
        out[i] = y
    return out


@dataclass(frozen=True)
class RunLock:
    """A run's lock time.

    lock_s : first sample time (the samples' own clock) after which the running RMS stays
        within the band (nan: it never does).
    steady_rms_px : RMS of the residual's steady state (the last ``steady_fraction`` of the
        samples, or from ``steady_from_s``).
    threshold_px : (1 + band) * steady_rms_px + noise_sigmas * scatter_px + floor_px.
    band, window_s, floor_px, noise_sigmas : as given.
    scatter_px : the running RMS's sampling scatter for independent samples,
        steady_rms_px / sqrt(2 d n) (d axes, n samples a window).
    """

    lock_s: float
    steady_rms_px: float
    threshold_px: float
    band: float
    window_s: float
    floor_px: float
    noise_sigmas: float = 0.0
    scatter_px: float = 0.0

    def to_dict(self) -> dict:
        return json_dict(self)


def running_rms(t_s: np.ndarray, r_px: np.ndarray, window_s: float) -> np.ndarray:
    """RMS of |r| (r (N, 2) or (N,)) over the trailing window (t - window_s, t] at each
    sample time (the samples' mean square, so uniform sampling is assumed within a window)."""
    t = np.asarray(t_s, dtype=np.float64)
    r = np.asarray(r_px, dtype=np.float64)
    sq = r**2 if r.ndim == 1 else np.sum(r**2, axis=1)
    c = np.concatenate([[0.0], np.cumsum(sq)])
    hi = np.arange(1, len(t) + 1)
    lo = np.searchsorted(t, t - window_s * (1.0 - 1e-9), side="left")  # rounding-safe
    return np.sqrt((c[hi] - c[lo]) / np.maximum(hi - lo, 1))


def run_lock_time(t_s: np.ndarray, r_px: np.ndarray, window_s: float, band: float = 0.25,
                  steady_fraction: float = 0.25, steady_from_s: float | None = None,
                  floor_px: float = 0.0, noise_sigmas: float = 0.0) -> RunLock:
    """Lock time of a run's residual r (N, 2) (or (N,)) sampled at increasing t_s (N,).

    window_s : the running RMS's trailing window, s (e.g. a few periods of the slowest
        disturbance, or the main imager's exposure).
    band : the running RMS may exceed the steady RMS by this fraction (>= 0).
    steady_fraction : the steady state is the last fraction of the samples (0, 1];
        steady_from_s overrides it with a start time.
    floor_px : an absolute allowance added to the threshold (for residuals at the noise
        floor, where a fraction of a tiny RMS is below what matters).
    noise_sigmas : the running RMS's own sampling scatter allowed, in its standard
        deviations (>= 0). A window of n independent samples of a noise-like residual on d
        axes measures its RMS to 1 / sqrt(2 d n) relatively (16 % at 10 samples on 2 axes),
        so a band of 25 % alone is crossed by chance in the steady state and the run never
        "locks"; 3 allows that scatter. It follows from n and d alone, not from the data, so
        a residual that grows to the end still never locks; a coloured residual (fewer
        independent samples) scatters more than it allows.
    """
    t = np.asarray(t_s, dtype=np.float64)
    r = np.asarray(r_px, dtype=np.float64)
    if t.ndim != 1 or len(t) < 2 or r.shape[0] != len(t):
        raise ValueError("t_s must be (N,) with N >= 2 and r_px (N, 2) or (N,) with the same N")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t_s must increase")
    if not window_s > 0:
        raise ValueError(f"window_s must be > 0, got {window_s}")
    if not band >= 0:
        raise ValueError(f"band must be >= 0, got {band}")
    if not floor_px >= 0:
        raise ValueError(f"floor_px must be >= 0, got {floor_px}")
    if not noise_sigmas >= 0:
        raise ValueError(f"noise_sigmas must be >= 0, got {noise_sigmas}")
    if steady_from_s is None:
        if not 0.0 < steady_fraction <= 1.0:
            raise ValueError(f"steady_fraction must be within (0, 1], got {steady_fraction}")
        i0 = min(len(t) - 1, int(np.floor(len(t) * (1.0 - steady_fraction))))
    else:
        i0 = int(np.searchsorted(t, steady_from_s, side="left"))
        if i0 >= len(t):
            raise ValueError(f"steady_from_s ({steady_from_s}) is after the last sample")
    sq = r**2 if r.ndim == 1 else np.sum(r**2, axis=1)
    steady = float(np.sqrt(np.mean(sq[i0:])))
    run = running_rms(t, r, window_s)
    axes = 1 if r.ndim == 1 else r.shape[1]
    per_window = max(1.0, window_s / float(np.median(np.diff(t))))
    scatter = steady / float(np.sqrt(2.0 * axes * per_window))
    thr = (1.0 + band) * steady + noise_sigmas * scatter + floor_px
    above = np.flatnonzero(run > thr * (1.0 + 1e-12))
    if not above.size:
        lock = float(t[0])
    elif above[-1] == len(t) - 1:
        lock = float("nan")
    else:
        lock = float(t[above[-1] + 1])
    return RunLock(lock, steady, thr, float(band), float(window_s), float(floor_px),
                   float(noise_sigmas), float(scatter))

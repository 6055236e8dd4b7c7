"""Controllers: measured motion in, stage command out (px).

Feedback laws (kinds ``integrator``, ``pi``, ``pii``) act on the error

    e = target - stage          (classic feedback: the residual the tracker saw)
    e = target - last command   (``smith=True``: commands still in flight are counted, the
                                 Smith predictor of a pure delay; today's law when latency > 0)

through a core transfer function C(z) (polynomials in z^-1), plus resonant terms at known
lines (internal model: infinite gain at each line, implemented as rotating phasors so the
line's frequency can follow a swept wheel: adaptive feed-forward cancellation, Bodson &
Douglas, Automatica 33 (1997)), then an optional notch for the stage resonance.

The ``kalman`` predictor is model-based: a Kalman filter on the pseudo-open-loop motion with a
kinematic part (random walk / constant velocity / constant acceleration) and sinusoidal
oscillators (known lines, and lines identified from the measurements' Lomb-Scargle
periodogram), which predicts the motion to the middle of the interval the next command will
hold. Prediction, not feedback, is what beats the delay bound |1 - exp(-j 2 pi f L)|.

Every linear controller also gives its transfer function (:meth:`transfer`), which the
analytic loop model (:mod:`compensation.analytic`) uses for |S(f)| and the stability margins.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from compensation.blocks import ControlInput, register

# ---------------------------------------------------------------------------------------------
# transfer functions as polynomials in x = z^-1


def polymul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return np.convolve(np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64))


def polyadd(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    n = max(len(p), len(q))
    return np.pad(p, (0, n - len(p))) + np.pad(q, (0, n - len(q)))


def polyval(x, c) -> np.ndarray:
    """sum_i c[i] x^i for 1-D ascending coefficients c: the Horner steps of
    ``numpy.polynomial.polynomial.polyval`` (the same values), without importing
    ``numpy.polynomial`` (~30 ms of a command's start)."""
    c = np.asarray(c)
    if c.dtype.char in "?bBhHiIlLqQpP":
        c = c.astype(np.float64)
    if isinstance(x, (tuple, list)):
        x = np.asarray(x)
    c0 = c[-1] + x * 0
    for i in range(2, len(c) + 1):
        c0 = c[-i] + c0 * x
    return c0


def polyval_x(p: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Evaluate a polynomial in x = z^-1 at complex z."""
    x = 1.0 / np.asarray(z, dtype=np.complex128)
    return polyval(x, p)


@dataclass(frozen=True)
class Line:
    """A resonant term at a known disturbance line.

    frequency_hz : the line; gain : convergence per measurement (0 < gain < 1; the notch in
    |S| is about gain * rate / pi wide); adaptive : follow a line whose frequency drifts;
    adapt_gain : fraction of the measured frequency error corrected per measurement;
    min_amplitude_px : adapt only once the term's amplitude exceeds this.
    """

    frequency_hz: float
    gain: float = 0.05
    adaptive: bool = False
    adapt_gain: float = 0.02
    min_amplitude_px: float = 0.002

    def __post_init__(self) -> None:
        if not self.frequency_hz > 0:
            raise ValueError(f"line frequency_hz must be > 0, got {self.frequency_hz}")
        if not 0 < self.gain < 1:
            raise ValueError(f"line gain must be within (0, 1), got {self.gain}")
        if not 0 <= self.adapt_gain < 1:
            raise ValueError(f"line adapt_gain must be within [0, 1), got {self.adapt_gain}")


@dataclass(frozen=True)
class Notch:
    """A second-order notch on the command: centre ``frequency_hz``, -3 dB ``width_hz``,
    ``depth_db`` at the centre (poles at radius r_p, zeros at r_z, unity gain at DC)."""

    frequency_hz: float
    width_hz: float
    depth_db: float = 30.0

    def coefficients(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) in z^-1 for a loop sampled at rate_hz: poles at radius exp(-pi width /
        rate), zeros at the radius that gives exactly ``depth_db`` at the centre once the
        DC gain is normalised to 1 (bisection)."""
        if not 0 < self.frequency_hz < 0.5 * rate_hz:
            raise ValueError(f"notch frequency_hz ({self.frequency_hz:g}) must lie below the "
                             f"loop's Nyquist frequency ({0.5 * rate_hz:g} Hz)")
        w = 2 * np.pi * self.frequency_hz / rate_hz
        rp = float(np.exp(-np.pi * self.width_hz / rate_hz))
        a = np.array([1.0, -2 * rp * np.cos(w), rp * rp])
        z = np.exp(1j * w)
        target = 10 ** (-self.depth_db / 20.0)

        def design(rz: float):
            b = np.array([1.0, -2 * rz * np.cos(w), rz * rz])
            b = b * (a.sum() / b.sum())
            return b, abs(polyval_x(b, z) / polyval_x(a, z))

        lo, hi = rp, 1.0  # depth grows as the zeros approach the unit circle
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if design(mid)[1] > target else (lo, mid)
        return design(0.5 * (lo + hi))[0], a


def _lfilter_step(b: np.ndarray, a: np.ndarray, x_hist: np.ndarray, y_hist: np.ndarray,
                  x: np.ndarray):
    """One Direct-Form-I step on 2 axes; histories (len(b) - 1, 2) and (len(a) - 1, 2),
    newest first. Returns (y, x_hist, y_hist)."""
    acc = b[0] * x
    for i in range(1, len(b)):
        acc = acc + b[i] * x_hist[i - 1]
    for i in range(1, len(a)):
        acc = acc - a[i] * y_hist[i - 1]
    y = acc if a[0] == 1.0 else acc / a[0]
    x_hist = np.concatenate([x[None], x_hist])[: len(b) - 1]
    y_hist = np.concatenate([y[None], y_hist])[: len(a) - 1]
    return y, x_hist, y_hist


@dataclass(frozen=True)
class FeedbackState:
    e_hist: np.ndarray  # (nb - 1, 2) past errors, newest first
    u_hist: np.ndarray  # (na - 1, 2) past core outputs
    phasor: np.ndarray  # (L, 2) complex: resonant terms
    omega: np.ndarray  # (L,) their current frequencies, rad/s
    t_s: float  # time of the last update (nan before the first)
    n_hist_in: np.ndarray  # notch input history (2, 2)
    n_hist_out: np.ndarray  # notch output history (2, 2)


@dataclass(frozen=True)
class FeedbackController:
    """Base of the feedback kinds: core C(z) + resonant lines + notch; see module docstring.

    rate_hz : the nominal measurement rate (for the notch); smith : count commands in flight;
    lines, notch : as :class:`Line` / :class:`Notch`; line_phase_rad, line_mu : each line's
    phase advance and update gain, set from the loop model by
    :func:`compensation.analytic.design_lines` (None: not designed yet); line_alias : each
    line's alias correction (complex, from the same design): the tracker samples the
    residual, so the stage's zero-order-hold images alias onto the line and a plain
    resonator would null the sampled error, not the residual itself (-37 dB at 65 Hz in a
    1 kHz loop). Adding Re(alpha_i b_i) to the error, alpha_i = G(w_i) - z^-n W H / T, moves
    the fixed point to a zero residual at the line.
    """

    WIRED: ClassVar[tuple[str, ...]] = ("rate_hz", "line_phase_rad", "line_mu", "line_alias")

    rate_hz: float = 100.0
    smith: bool = False
    lines: tuple[Line, ...] = ()
    notch: Notch | None = None
    line_phase_rad: tuple[float, ...] | None = None
    line_mu: tuple[float, ...] | None = None
    line_alias: tuple[complex, ...] | None = None

    def core(self) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) of the core law in z^-1."""
        raise NotImplementedError

    # -- transfer function ----------------------------------------------------------------
    def line_transfer(self, i: int, phase: float, mu: float) -> tuple[np.ndarray, np.ndarray]:
        """Resonant term i as (b, a): mu (cos phi - cos(wT - phi) x) / (1 - 2 cos(wT) x + x^2)."""
        wt = 2 * np.pi * self.lines[i].frequency_hz / self.rate_hz
        b = mu * np.array([np.cos(phase), -np.cos(wt - phase)])
        a = np.array([1.0, -2 * np.cos(wt), 1.0])
        return b, a

    def alias_term(self, i: int) -> np.ndarray:
        """Numerator (over line i's denominator) of line i's alias correction K_i(z):
        Re(alpha_i b_i) before the update, b_i the line's phasor."""
        ln = self.lines[i]
        rho = np.exp(2j * np.pi * ln.frequency_hz / self.rate_hz)
        c = 0.5 * self.line_alias[i] * self.line_mu[i] * np.exp(1j * self.line_phase_rad[i]) * rho
        # c x / (1 - rho x) + conj: x (2 Re c - 2 Re(c conj(rho)) x) / (1 - 2 Re(rho) x + x^2)
        return np.array([0.0, 2 * c.real, -2 * (c * np.conj(rho)).real])

    def transfer(self, with_lines: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) in z^-1 from the error e to the command: (core + lines) / (1 - K) * notch,
        K the alias correction; the lines' poles cancel exactly in that ratio, so it is
        formed without them: with A = prod a_i,
        b = b_core A + a_core sum_i b_i A / a_i,  a = a_core (A - sum_i k_i A / a_i)."""
        b, a = self.core()
        if with_lines and self.lines:
            self._check_designed()
            parts = [self.line_transfer(i, self.line_phase_rad[i], self.line_mu[i])
                     for i in range(len(self.lines))]
            prod = np.ones(1)
            for _, ai in parts:
                prod = polymul(prod, ai)
            num_lines, num_k = np.zeros(1), np.zeros(1)
            for i, (bi, _) in enumerate(parts):
                others = np.ones(1)
                for j, (_, aj) in enumerate(parts):
                    if j != i:
                        others = polymul(others, aj)
                num_lines = polyadd(num_lines, polymul(bi, others))
                if self.line_alias is not None:
                    num_k = polyadd(num_k, polymul(self.alias_term(i), others))
            b = polyadd(polymul(b, prod), polymul(a, num_lines))
            a = polymul(a, polyadd(prod, -num_k))
        if self.notch is not None:
            bn, an = self.notch.coefficients(self.rate_hz)
            b, a = polymul(b, bn), polymul(a, an)
        return b, a

    def _check_designed(self) -> None:
        if self.lines and (self.line_phase_rad is None or self.line_mu is None):
            raise ValueError("resonant lines need their phase and gain from the loop model: "
                             "use compensation.analytic.design_lines")

    # -- the block ------------------------------------------------------------------------
    def init(self) -> FeedbackState:
        b, a = self.core()
        n = len(self.lines)
        return FeedbackState(np.zeros((len(b) - 1, 2)), np.zeros((len(a) - 1, 2)),
                             np.zeros((n, 2), complex),
                             np.array([2 * np.pi * ln.frequency_hz for ln in self.lines]),
                             np.nan, np.zeros((2, 2)), np.zeros((2, 2)))

    def update(self, state: FeedbackState, inp: ControlInput):
        if not inp.valid:
            return state, np.asarray(inp.last_command_px, dtype=np.float64)
        ref = inp.last_command_px if self.smith else inp.stage_px
        e = np.asarray(inp.target_px, dtype=np.float64) - ref
        phasor, omega = state.phasor, state.omega
        if self.lines:
            self._check_designed()
            dt = 0.0 if np.isnan(state.t_s) else inp.t_s - state.t_s
            phasor = phasor * np.exp(1j * omega * dt)[:, None]  # rotated to now
            if self.line_alias is not None:
                e = e + (np.array(self.line_alias)[:, None] * phasor).real.sum(axis=0)
        b, a = self.core()
        u, e_hist, u_hist = _lfilter_step(b, a, state.e_hist, state.u_hist, e)
        if self.lines:
            phasor, omega = self._lines_step(phasor, omega, e, dt)
            u = u + phasor.real.sum(axis=0)
        n_in, n_out = state.n_hist_in, state.n_hist_out
        if self.notch is not None:
            bn, an = self.notch.coefficients(self.rate_hz)
            u, n_in, n_out = _lfilter_step(bn, an, n_in, n_out, u)
        new = FeedbackState(e_hist, u_hist, phasor, omega, inp.t_s, n_in, n_out)
        return new, u

    def _lines_step(self, phasor: np.ndarray, omega: np.ndarray, e: np.ndarray, dt: float):
        """Add mu e^{j phi} e to each phasor (already rotated to now); adapt the frequency of
        adaptive lines from the rotation the correction implies (Im(delta conj(b)) / |b|^2
        / dt)."""
        gain = (np.array(self.line_mu) * np.exp(1j * np.array(self.line_phase_rad)))[:, None]
        delta = gain * e[None, :]
        omega = omega.copy()
        if dt > 0:
            for i, ln in enumerate(self.lines):
                if not ln.adaptive:
                    continue
                power = float(np.sum(np.abs(phasor[i]) ** 2))
                if power < ln.min_amplitude_px**2:
                    continue
                dw = float(np.sum((delta[i] * np.conj(phasor[i])).imag)) / power / dt
                omega[i] += ln.adapt_gain * dw
        return phasor + delta, omega


@register("controller", "integrator")
@dataclass(frozen=True)
class Integrator(FeedbackController):
    """Leaky integrator u_j = (1 - leak) u_{j-1} + gain e_j: C(z) = gain / (1 - (1-leak) z^-1).
    With leak 0 and an ideal stage this is today's first-order loop."""

    #: the parameter that sets the loop's gain (named by the wiring's margin checks)
    TUNING: ClassVar[str] = "gain"

    gain: float = 0.8
    leak: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 < self.gain <= 2.0:
            raise ValueError(f"gain must be in (0, 2], got {self.gain}")
        if not 0.0 <= self.leak < 1.0:
            raise ValueError(f"leak must be in [0, 1), got {self.leak}")

    def core(self):
        return np.array([self.gain]), np.array([1.0, -(1.0 - self.leak)])


@register("controller", "pi")
@dataclass(frozen=True)
class PI(FeedbackController):
    """Proportional-integral: C(z) = kp + ki / (1 - z^-1)."""

    TUNING: ClassVar[str] = "kp / ki"

    kp: float = 0.2
    ki: float = 0.5

    def core(self):
        return np.array([self.kp + self.ki, -self.kp]), np.array([1.0, -1.0])


@register("controller", "pii")
@dataclass(frozen=True)
class PII(FeedbackController):
    """Type-2 law (PI-I): C(z) = kp + ki / (1 - z^-1) + kii / (1 - z^-1)^2; two integrators
    follow a ramp without error."""

    TUNING: ClassVar[str] = "kp / ki / kii"

    kp: float = 0.2
    ki: float = 0.4
    kii: float = 0.02

    def core(self):
        b = np.array([self.kp + self.ki + self.kii, -2 * self.kp - self.ki, self.kp])
        return b, np.array([1.0, -2.0, 1.0])


# ---------------------------------------------------------------------------------------------
# the model-based predictor


def _kinematic(order: int, dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition and process covariance of a chain of ``order`` integrators driven by white
    noise of spectral density q on the highest derivative, over dt."""
    from math import factorial

    phi = np.zeros((order, order))
    qd = np.zeros((order, order))
    for i in range(order):
        for j in range(i, order):
            phi[i, j] = dt ** (j - i) / factorial(j - i)
    p = order - 1
    for i in range(order):
        for j in range(order):
            k = 2 * p - i - j + 1
            qd[i, j] = q * dt**k / (factorial(p - i) * factorial(p - j) * k)
    return phi, qd


#: the default identification window in measurement periods: 0.128 s at 1 kHz (a line is
#: followed within 0.12 s of the start), resolution rate / 128, lines looked for above 1.5 x
#: that (11.7 Hz at 1 kHz: below, the kinematic states follow). Chosen on kHz runs with
#: unlisted wheel lines at 30-75 Hz (fixed and swept 1 %/s), docs/loop.md.
IDENTIFY_PERIODS = 128
#: the longest default identification window, s (the window of earlier versions)
IDENTIFY_MAX_S = 2.0


@dataclass(frozen=True)
class KalmanState:
    x: np.ndarray  # (2, n) state per axis
    cov: np.ndarray  # (2, n, n)
    t_s: float  # time of x (the last measured exposure's mid-time); nan before the first
    lines_hz: np.ndarray  # (L,) the oscillators' frequencies (known + identified)
    line_q: np.ndarray  # (L,) their process noise densities, px^2/s
    hist_t: np.ndarray  # (H,) recent measurement times (identification window)
    hist_z: np.ndarray  # (H, 2) the measured motion (feed-forward removed)
    t_identified: float  # last identification (nan: never)
    sigma_nom: float  # the measurement noise the process noise is scaled by (nan: not yet)


@register("controller", "kalman")
@dataclass(frozen=True)
class KalmanPredictor:
    """Kalman filter on the pseudo-open-loop motion, predicting it to the command's time.

    order : kinematic states (1 random walk, 2 constant velocity, 3 constant acceleration).
    bandwidth_hz : how fast the kinematic part follows (sets its process noise from the
        measurement noise: q = (2 pi bw)^(2 order) sigma^2 T); None: a twentieth of the
        measurement rate.
    lines_hz : known lines (e.g. reaction-wheel harmonics), modelled as oscillators.
    identify : add lines found in the measurements (tapered Lomb-Scargle periodogram of the
        last ``window_s`` of the motion, quadratic trend removed, every ``every_s``; peaks
        ``line_snr`` times the median power, at most ``max_lines`` in all, above 1.5 /
        window_s; :func:`find_lines`); a new oscillator starts from a least-squares fit and
        takes its part of the motion over from the kinematic states.
    window_s : the identification's window, s; None: :data:`IDENTIFY_PERIODS` measurement
        periods, at most :data:`IDENTIFY_MAX_S` (0.128 s at 1 kHz: a line is found within
        0.12 s of the start; 1.28 s at 100 Hz; 2 s at 30 Hz). Its resolution is 1 / window_s
        and lines below 1.5 / window_s (11.7 Hz at 1 kHz, where the kinematic states follow)
        are not looked for. See :attr:`identification_window_s`.
    every_s : the interval between identifications, s; None: half the window.
    line_bandwidth_hz : how fast a line's amplitude and phase may wander.
    line_amplitude_px : the amplitude a known line is expected to have (it scales the
        line's process noise; identified lines use their fitted amplitude).
    lead_s : extra prediction lead, s (None: the actuator's lag, set by the wiring: half a
        ramp for a ramping stage, the mode's group delay for a piezo).
    noise_px : nominal measurement noise that scales the kinematic process noise; None: a
        running mean of the measurements' predicted errors.
    nominal_px : the orbit/attitude prediction of the motion (a function of time, (N,) ->
        (N, 2) px), used as feed-forward: the filter models only what it does not predict.
    notch : optional notch on the command (as the feedback kinds).
    rate_hz : the nominal measurement rate.

    Lines nobody configured (on by default since issue 35: the predictor finds, hands over,
    follows and drops lines without being asked; ``handover: full``, ``track_gain: 0``,
    ``prune_snr: null`` give the predictor as it was):

    handover : how a newly identified line's part is taken from the kinematic states:
        'full' (all of it: right for lines well below ``bandwidth_hz``) or 'response' (the
        part the filter's kinematic states actually followed, from its frequency response
        at the line with the current gain: right at any frequency; the kinematic states
        barely follow a wheel line far above their bandwidth, and taking all of it from them
        upsets the prediction by up to (2 pi f)^2 times the line's amplitude).
    track_gain : each line's frequency follows the rotation its update implies (a phase-
        locked loop on the oscillator: Im(b_post conj(b_prior)) / |b_prior|^2 / dt, summed
        over axes), this fraction of it per measurement; 0: fixed frequencies. What follows a
        swept wheel line. Only lines above the kinematic bandwidth are tracked (below it the
        kinematic states share their motion and the rotation is not the line's own).
    track_min_snr : a line's frequency is tracked only while its amplitude stands this many
        times above its own uncertainty (the state's posterior standard deviation) and the
        measurement noise (sigma_nom).
    prune_snr : at every identification, lines (known or identified) whose least-squares
        power over the window, N |a|^2 / (4 sigma^2) (|a| summed over axes, sigma the fit's
        residual RMS per axis), is below this are removed: a configured line that matches
        no disturbance stops costing noise. None: never.
    line_prior_px : the initial 1-sigma of a configured line's state (its amplitude before
        any measurement), px; None: 1 px. The line_amplitude_px a line is expected to have is
        the natural choice: a configured line then costs little before the first pruning.
    """

    WIRED: ClassVar[tuple[str, ...]] = ("rate_hz", "nominal_px")
    TUNING: ClassVar[str] = "bandwidth_hz"

    rate_hz: float = 100.0
    order: int = 2
    bandwidth_hz: float | None = None
    lines_hz: tuple[float, ...] = ()
    identify: bool = True
    window_s: float | None = None
    every_s: float | None = None
    max_lines: int = 4
    line_snr: float = 40.0
    line_bandwidth_hz: float = 0.05
    line_amplitude_px: float = 0.1
    lead_s: float | None = None
    noise_px: float | None = None
    sigma_floor_px: float = 1e-3
    nominal_px: Callable[[np.ndarray], np.ndarray] | None = None
    notch: Notch | None = None
    handover: str = "response"
    track_gain: float = 0.005
    track_min_snr: float = 3.0
    prune_snr: float | None = 10.0
    line_prior_px: float | None = None
    smith: bool = field(default=False, init=False)  # pseudo-open-loop by construction

    def __post_init__(self) -> None:
        if self.handover not in ("full", "response"):
            raise ValueError(f"handover must be 'full' or 'response', got {self.handover!r}")
        if not 0.0 <= self.track_gain < 1.0:
            raise ValueError(f"track_gain must be within [0, 1), got {self.track_gain}")
        if not self.track_min_snr >= 0:
            raise ValueError(f"track_min_snr must be >= 0, got {self.track_min_snr}")
        if self.prune_snr is not None and not self.prune_snr > 0:
            raise ValueError(f"prune_snr must be > 0 (or None), got {self.prune_snr}")
        if self.line_prior_px is not None and not self.line_prior_px > 0:
            raise ValueError(f"line_prior_px must be > 0 (or None), got {self.line_prior_px}")
        if self.order not in (1, 2, 3):
            raise ValueError(f"order must be 1, 2 or 3, got {self.order}")
        if self.bandwidth_hz is not None and not self.bandwidth_hz > 0:
            raise ValueError(f"bandwidth_hz must be > 0, got {self.bandwidth_hz}")
        if (self.window_s is not None and not self.window_s > 0) or (
                self.every_s is not None and not self.every_s > 0):
            raise ValueError("window_s and every_s must be > 0 (or None: from the rate)")
        if any(not f > 0 for f in self.lines_hz):
            raise ValueError(f"lines_hz must hold frequencies > 0 Hz, got {list(self.lines_hz)}")

    # -- identification's timing ------------------------------------------------------------
    @property
    def identification_window_s(self) -> float:
        """The identification's window, s: ``window_s``, or by default
        :data:`IDENTIFY_PERIODS` measurement periods, at most :data:`IDENTIFY_MAX_S`."""
        if self.window_s is not None:
            return float(self.window_s)
        return min(IDENTIFY_PERIODS / self.rate_hz, IDENTIFY_MAX_S)

    @property
    def identification_every_s(self) -> float:
        """The interval between identifications, s: ``every_s``, or half the window."""
        if self.every_s is not None:
            return float(self.every_s)
        return 0.5 * self.identification_window_s

    # -- model ----------------------------------------------------------------------------
    def _bw(self) -> float:
        return self.bandwidth_hz if self.bandwidth_hz is not None else self.rate_hz / 20.0

    def _q_kin(self, sigma: float) -> float:
        w = 2 * np.pi * self._bw()
        return w ** (2 * self.order) * sigma**2 / self.rate_hz

    def model(self, dt: float, lines_hz: np.ndarray, line_q: np.ndarray, sigma: float):
        """(Phi, Q, H) of the whole state over dt."""
        phi_k, q_k = _kinematic(self.order, dt, self._q_kin(sigma))
        n = self.order + 2 * len(lines_hz)
        phi, q = np.zeros((n, n)), np.zeros((n, n))
        phi[: self.order, : self.order], q[: self.order, : self.order] = phi_k, q_k
        h = np.zeros(n)
        h[0] = 1.0
        for i, (f, qi) in enumerate(zip(lines_hz, line_q, strict=True)):
            j = self.order + 2 * i
            c, s = np.cos(2 * np.pi * f * dt), np.sin(2 * np.pi * f * dt)
            phi[j:j + 2, j:j + 2] = [[c, -s], [s, c]]
            q[j:j + 2, j:j + 2] = qi * dt * np.eye(2)
            h[j] = 1.0
        return phi, q, h

    def _initial_cov(self, n_lines: int) -> np.ndarray:
        line = 1.0 if self.line_prior_px is None else self.line_prior_px**2
        d = [1e2, 1e4, 1e6][: self.order] + [line] * (2 * n_lines)
        return np.diag(d)

    # -- the block ------------------------------------------------------------------------
    def init(self) -> KalmanState:
        lines = np.array(self.lines_hz, dtype=np.float64)
        n = self.order + 2 * len(lines)
        cov = np.stack([self._initial_cov(len(lines))] * 2)
        return KalmanState(np.zeros((2, n)), cov, np.nan, lines,
                           np.full(len(lines), self._line_q(self.line_amplitude_px)),
                           np.empty(0),
                           np.empty((0, 2)), np.nan,
                           np.nan if self.noise_px is None else float(self.noise_px))

    def _line_q(self, amplitude_px: float) -> float:
        return 2 * np.pi * self.line_bandwidth_hz * amplitude_px**2

    def _ff(self, t: float) -> np.ndarray:
        if self.nominal_px is None:
            return np.zeros(2)
        return np.asarray(self.nominal_px(np.array([t])), dtype=np.float64).reshape(2)

    def update(self, state: KalmanState, inp: ControlInput):
        st = state
        sigma = np.maximum(np.nan_to_num(np.asarray(inp.sigma_px, float), nan=np.inf,
                                         posinf=1e3), self.sigma_floor_px)
        if inp.valid:
            st = self._track_noise(st, float(sigma.mean()))
            z = np.asarray(inp.target_px, dtype=np.float64) - self._ff(inp.t_meas_s)
            st = self._filter(st, inp.t_meas_s, z, sigma)
            if self.identify:
                st = self._identify(st, inp.t_meas_s, z, st.sigma_nom)
        if np.isnan(st.t_s):
            return st, np.asarray(inp.last_command_px, dtype=np.float64)
        t_goal = inp.t_s + 0.5 * inp.period_s + (self.lead_s or 0.0)
        phi, _, h = self.model(t_goal - st.t_s, st.lines_hz, st.line_q, st.sigma_nom)
        u = (st.x @ phi.T) @ h + self._ff(t_goal)
        return st, u

    def _track_noise(self, st: KalmanState, sigma: float) -> KalmanState:
        """The nominal measurement noise: the given noise_px, else a running mean of the
        measurements' predicted errors (exact reference measurements, at the floor, left
        out; the floor until one arrives)."""
        if self.noise_px is not None:
            return st
        if sigma <= 2.0 * self.sigma_floor_px:
            if np.isnan(st.sigma_nom):
                return dataclasses.replace(st, sigma_nom=self.sigma_floor_px * 2.0)
            return st
        if np.isnan(st.sigma_nom) or st.sigma_nom <= 2.0 * self.sigma_floor_px:
            return dataclasses.replace(st, sigma_nom=sigma)
        return dataclasses.replace(st, sigma_nom=0.95 * st.sigma_nom + 0.05 * sigma)

    def _filter(self, st: KalmanState, t: float, z: np.ndarray, sigma: np.ndarray):
        """Predict to t, update with z."""
        if np.isnan(st.t_s):
            x = st.x.copy()
            x[:, 0] = z
            return dataclasses.replace(st, x=x, t_s=t)
        phi, q, h = self.model(t - st.t_s, st.lines_hz, st.line_q, st.sigma_nom)
        x = st.x @ phi.T
        cov = phi @ st.cov @ phi.T + q
        ph = cov @ h  # (2, n)
        s = ph @ h + sigma**2  # (2,)
        k = ph / s[:, None]
        innovation = z - x @ h
        prior = x
        x = x + k * innovation[:, None]
        cov = cov - k[:, :, None] * ph[:, None, :]
        cov = 0.5 * (cov + np.transpose(cov, (0, 2, 1)))
        if self.track_gain > 0 and len(st.lines_hz) and t > st.t_s:
            return dataclasses.replace(st, x=x, cov=cov, t_s=t,
                                       lines_hz=self._track(st, prior, x, cov, t - st.t_s))
        return dataclasses.replace(st, x=x, cov=cov, t_s=t)

    def _track(self, st: KalmanState, prior: np.ndarray, post: np.ndarray, cov: np.ndarray,
               dt: float) -> np.ndarray:
        """Each line's frequency moved by track_gain times the rotation its update implied
        (the oscillator's phasor b = c + j s, summed over axes; at most 0.5 rad a step), for
        lines above the kinematic bandwidth whose amplitude stands track_min_snr above its
        own uncertainty (the posterior standard deviation of c and s) and the noise."""
        j = self.order + 2 * np.arange(len(st.lines_hz))
        b0 = prior[:, j] + 1j * prior[:, j + 1]  # (2, L)
        b1 = post[:, j] + 1j * post[:, j + 1]
        power = np.sum(np.abs(b0) ** 2, axis=0)
        var = np.sum(cov[:, j, j] + cov[:, j + 1, j + 1], axis=0)  # (L,)
        noise = st.sigma_nom if np.isfinite(st.sigma_nom) else self.sigma_floor_px
        ok = ((power > self.track_min_snr**2 * np.maximum(var, noise**2))
              & (st.lines_hz > self._bw()))
        rot = np.sum((b1 * np.conj(b0)).imag, axis=0) / np.where(ok, power, 1.0)
        rot = np.clip(rot, -0.5, 0.5)
        return st.lines_hz + np.where(ok, self.track_gain * rot / (2 * np.pi * dt), 0.0)

    def _identify(self, st: KalmanState, t: float, z: np.ndarray, sigma: float):
        window = self.identification_window_s
        keep = st.hist_t > t - window
        hist_t = np.append(st.hist_t[keep], t)
        hist_z = np.vstack([st.hist_z[keep], z[None]])
        st = dataclasses.replace(st, hist_t=hist_t, hist_z=hist_z)
        span = hist_t[-1] - hist_t[0]
        due = np.isnan(st.t_identified) or t - st.t_identified >= self.identification_every_s
        if not due or span < 0.9 * window:
            return st
        if self.prune_snr is not None and len(st.lines_hz):
            st = self._prune(dataclasses.replace(st, t_identified=t))
        if len(st.lines_hz) >= self.max_lines:
            return st
        st = dataclasses.replace(st, t_identified=t)
        found = find_lines(hist_t, hist_z, 1.5 / window, self.line_snr,
                           self.max_lines - len(st.lines_hz), st.lines_hz)
        if not len(found):
            return st
        return self._add_lines(st, found, sigma)

    def _prune(self, st: KalmanState) -> KalmanState:
        """Remove the lines whose least-squares power over the window is below prune_snr
        (see the class docstring); their states and covariance go with them."""
        t, z = st.hist_t, st.hist_z
        tc = t - t[-1]
        cols = [np.ones_like(tc), tc, tc**2]
        for f in st.lines_hz:
            cols += [np.cos(2 * np.pi * f * tc), -np.sin(2 * np.pi * f * tc)]
        design = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(design, z, rcond=None)
        resid = z - design @ coef
        var = max(float(np.mean(resid**2)), 1e-30)  # per axis
        amp2 = (coef[3::2] ** 2 + coef[4::2] ** 2).sum(axis=1)  # (L,) over both axes
        keep = len(t) * amp2 / (4.0 * var) >= self.prune_snr
        if keep.all():
            return st
        idx = np.concatenate([np.arange(self.order)]
                             + [self.order + 2 * i + np.arange(2) for i in np.flatnonzero(keep)])
        return dataclasses.replace(st, x=st.x[:, idx], cov=st.cov[:, idx][:, :, idx],
                                   lines_hz=st.lines_hz[keep], line_q=st.line_q[keep])

    def _add_lines(self, st: KalmanState, freqs: np.ndarray, sigma: float) -> KalmanState:
        """New oscillators initialised from a least-squares fit of the window (trend, known
        lines and the new ones); the kinematic states give up the new lines' part (value,
        rate and acceleration now)."""
        t, z = st.hist_t, st.hist_z
        tc = t - t[-1]
        cols = [np.ones_like(tc), tc, tc**2]
        for f in np.concatenate([st.lines_hz, freqs]):
            cols += [np.cos(2 * np.pi * f * tc), -np.sin(2 * np.pi * f * tc)]
        design = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(design, z, rcond=None)
        coef = coef[3 + 2 * len(st.lines_hz):]  # the new lines' (c, s) pairs
        coef = np.concatenate([np.zeros((2, 2)), coef])  # keep the indexing below
        n_old = st.x.shape[1]
        n_new = n_old + 2 * len(freqs)
        x = np.zeros((2, n_new))
        x[:, :n_old] = st.x
        amp = np.zeros(len(freqs))
        followed = (self._kinematic_response(st, freqs, float(np.median(np.diff(t))))
                    if self.handover == "response" else None)
        for i, f in enumerate(freqs):
            c, s = coef[2 + 2 * i], coef[3 + 2 * i]  # (2,), value now = c
            x[:, n_old + 2 * i] = c
            x[:, n_old + 2 * i + 1] = s
            if followed is None:
                w = 2 * np.pi * f
                part = [c, -w * s, -w * w * c][: self.order]  # value, rate, acceleration now
                for j, v in enumerate(part):
                    x[:, j] -= v
            else:  # the part of the line the kinematic states followed
                x[:, : self.order] -= (followed[:, i, :] * (c + 1j * s)[:, None]).real
            amp[i] = float(np.sqrt(np.mean(c**2 + s**2)))
        cov = np.zeros((2, n_new, n_new))
        cov[:, :n_old, :n_old] = st.cov
        for i in range(len(freqs)):
            j = n_old + 2 * i
            cov[:, j:j + 2, j:j + 2] = np.eye(2) * max(sigma**2, 1e-8) * 4.0
        lines = np.concatenate([st.lines_hz, freqs])
        line_q = np.concatenate([st.line_q, [self._line_q(a) for a in amp]])
        # the window's innovations predate the new lines: start a fresh one
        return dataclasses.replace(st, x=x, cov=cov, lines_hz=lines, line_q=line_q,
                                   hist_t=np.empty(0), hist_z=np.empty((0, 2)))

    def _kinematic_response(self, st: KalmanState, freqs: np.ndarray, dt: float
                            ) -> np.ndarray:
        """(2 axes, F, order) complex: the kinematic states' response to a unit phasor
        exp(j w t) in the measurements, at each frequency, from the filter as it is (the
        current covariance's gain, sampling dt): x = (I - (I - K H) Phi e^{-j w dt})^-1 K."""
        phi, q, h = self.model(dt, st.lines_hz, st.line_q, st.sigma_nom)
        n = len(h)
        sig2 = max(st.sigma_nom, self.sigma_floor_px) ** 2
        out = np.zeros((2, len(freqs), self.order), complex)
        for a in range(2):
            pred = phi @ st.cov[a] @ phi.T + q
            k = pred @ h / (h @ pred @ h + sig2)
            a_t = (np.eye(n) - np.outer(k, h)) @ phi
            for i, f in enumerate(freqs):
                m = np.eye(n) - a_t * np.exp(-2j * np.pi * f * dt)
                out[a, i] = np.linalg.solve(m, k.astype(complex))[: self.order]
        return out

    # -- transfer function (steady state, regular sampling) -------------------------------
    def steady_state(self, period_s: float, sigma_px: float, lines_hz=None, line_q=None):
        """Steady-state gain K (n,) and the model (Phi, Q, H) at a regular period."""
        lines = np.array(self.lines_hz if lines_hz is None else lines_hz, dtype=np.float64)
        lq = (np.full(len(lines), self._line_q(self.line_amplitude_px)) if line_q is None
              else np.asarray(line_q, dtype=np.float64))
        phi, q, h = self.model(period_s, lines, lq, sigma_px)
        cov = self._initial_cov(len(lines))
        for _ in range(20000):
            pred = phi @ cov @ phi.T + q
            s = h @ pred @ h + sigma_px**2
            k = pred @ h / s
            new = pred - np.outer(k, h @ pred)
            if np.allclose(new, cov, rtol=1e-12, atol=1e-18):
                break
            cov = new
        return k, phi, q, h

    def transfer_rational(self, period_s: float, horizon_s: float, sigma_px: float,
                          lines_hz=None, line_q=None):
        """(b, a) in z^-1 of the steady-state predictor: u = H Phi(horizon) xhat, xhat =
        (I - (I - K H) Phi z^-1)^-1 K z_meas. Notch included."""
        k, phi, _, h = self.steady_state(period_s, sigma_px, lines_hz, line_q)
        lines = np.array(self.lines_hz if lines_hz is None else lines_hz, dtype=np.float64)
        lq = np.zeros(len(lines)) if line_q is None else line_q
        phi_t, _, _ = self.model(horizon_s, lines, lq, sigma_px)
        a_tilde = (np.eye(len(k)) - np.outer(k, h)) @ phi
        c = h @ phi_t
        # z C (zI - A)^-1 K = z [det(zI - A + K C) - det(zI - A)] / det(zI - A)
        den_z = np.poly(a_tilde)
        num_z = np.poly(a_tilde - np.outer(k, c)) - den_z  # degree <= n - 1
        num_z = np.append(num_z[1:], 0.0)  # times z
        # both of degree n: dividing by z^n, the coefficients (highest power of z first)
        # are those of x = z^-1 in ascending order
        b, a = num_z.copy(), den_z.copy()
        if self.notch is not None:
            bn, an = self.notch.coefficients(self.rate_hz)
            b, a = polymul(b, bn), polymul(a, an)
        return b, a


def lomb_scargle(t: np.ndarray, y: np.ndarray, freqs_hz: np.ndarray) -> np.ndarray:
    """Lomb-Scargle periodogram (Scargle, ApJ 263 (1982)) of y (N,) at freqs (F,), with the
    mean removed; irregular sampling allowed."""
    y = y - y.mean()
    w = 2 * np.pi * freqs_hz[:, None]
    tau = np.arctan2(np.sin(2 * w * t).sum(axis=1), np.cos(2 * w * t).sum(axis=1)) / (2 * w[:, 0])
    arg = w * (t[None, :] - tau[:, None])
    c, s = np.cos(arg), np.sin(arg)
    return 0.5 * ((c @ y) ** 2 / (c * c).sum(axis=1) + (s @ y) ** 2 / (s * s).sum(axis=1))


def _periodogram(t: np.ndarray, y: np.ndarray, oversample: int = 8):
    """(freqs, power) of y (N, 2) summed over axes: FFT of the zero-padded series when the
    sampling is regular, Lomb-Scargle otherwise."""
    span = t[-1] - t[0]
    dt = np.diff(t)
    f_max = 0.45 * (len(t) - 1) / span
    if np.ptp(dt) <= 1e-6 * np.mean(dt):
        n = oversample * len(t)
        spec = np.fft.rfft(y, n=n, axis=0)
        freqs = np.fft.rfftfreq(n, float(np.mean(dt)))
        keep = freqs <= f_max
        return freqs[keep], (np.abs(spec[keep]) ** 2).sum(axis=1)
    freqs = np.arange(0.0, f_max, 1.0 / (oversample * span))[1:]
    return freqs, sum(lomb_scargle(t, y[:, i], freqs) for i in range(y.shape[1]))


def find_lines(t: np.ndarray, z: np.ndarray, f_min_hz: float, snr: float, max_new: int,
               known_hz: np.ndarray) -> np.ndarray:
    """Frequencies (Hz) of up to max_new sinusoids in z (N, 2), by prewhitening: fit the
    quadratic trend and the lines known so far by least squares, take the tallest peak of
    the residual's periodogram (Hann taper) if it stands ``snr`` times above the median
    power and clear of the known lines, refine it (parabola on the log power), add it, refit,
    and repeat. Removing each line before looking for the next keeps a strong line's
    sidelobes from passing for weaker ones."""
    if max_new <= 0 or len(t) < 16:
        return np.empty(0)
    span = t[-1] - t[0]
    res = 1.0 / span
    tc = (t - t.mean()) / span
    taper = np.sin(np.pi * (t - t[0]) / span) ** 2
    lines = [float(f) for f in known_hz]
    out: list[float] = []
    for _ in range(max_new):
        resid = _fit_residual(t, tc, z, lines + out)
        freqs, power = _periodogram(t, resid * taper[:, None])
        ok = freqs >= f_min_hz
        for g in lines + out:
            ok &= np.abs(freqs - g) > 4 * res
        if ok.sum() < 8:
            break
        floor = np.median(power[freqs >= f_min_hz])
        p = int(np.flatnonzero(ok)[np.argmax(power[ok])])
        if not power[p] > snr * floor or p == 0 or p == len(power) - 1:
            break
        lo, mid, hi = np.log(power[p - 1:p + 2])
        den = lo - 2 * mid + hi
        f = freqs[p] + (0.5 * (lo - hi) / den if den < 0 else 0.0) * (freqs[1] - freqs[0])
        out.append(_refine(t, tc, z, lines + out, float(f), 0.5 * res))
    return np.array(out)


def _fit_residual(t, tc, z, freqs_hz: list[float]) -> np.ndarray:
    """z (N, 2) less its least-squares fit by a quadratic trend in tc and a sinusoid at each
    of freqs_hz (Hz, at times t s)."""
    cols = [np.ones_like(tc), tc, tc**2]
    for f in freqs_hz:
        cols += [np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)]
    a = np.column_stack(cols)
    return z - a @ np.linalg.lstsq(a, z, rcond=None)[0]


def _refine(t, tc, z, others: list[float], f: float, half_width: float) -> float:
    """The frequency within f +- half_width that leaves the least squared residual of a
    joint least-squares fit (trend, the other lines, this one); golden-section search."""

    def cost(g: float) -> float:
        r = _fit_residual(t, tc, z, [*others, g])
        return float(np.sum(r * r))

    lo, hi = f - half_width, f + half_width
    ratio = 0.5 * (np.sqrt(5.0) - 1.0)
    x1, x2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    c1, c2 = cost(x1), cost(x2)
    for _ in range(16):
        if c1 < c2:
            hi, x2, c2 = x2, x1, c1
            x1 = hi - ratio * (hi - lo)
            c1 = cost(x1)
        else:
            lo, x1, c1 = x1, x2, c2
            x2 = lo + ratio * (hi - lo)
            c2 = cost(x2)
    return 0.5 * (lo + hi)

"""The analytic loop model: rejection |S(f)|, noise gain and stability margins of any loop.

The loop is sampled: frame k is exposed over [kT, kT + T_e]; its measurement is used by the
controller tick j = k + n, at time (k + n) T + phi = kT + T_e + latency (the command acts
from that instant, held until the next tick). With the stage's response h(t) to one held
unit command (simulated with the actuator block itself, its nonlinear effects switched off),

    p[m] = exposure mean of h over frame m     (what the tracker sees of the stage)
    q[m] = the same for an ideal held command  (what the estimator assumes it did)

and the controller's transfer function C(z) (or a predictor's F(z)), a disturbance
exp(j w t) is measured as W(w) exp(j w k T), W(w) = (exp(j w T_e) - 1) / (j w T_e) (exposure
averaging), the commands follow

    feedback:  U = C z^-n / (1 + C z^-n (P - Q) + C G0),  G0 = z^-1 (smith) or z^-n Q
    predictor: U = F z^-n / (1 + F z^-n (P - Q))

and the residual's component at w is exactly (sampled-data, no approximation)

    S(w) = 1 - W(w) U(e^{jwT}) H(w) / T,   H(w) = Fourier transform of h (ZOH, delay,
                                                   actuator dynamics included).

OOPAO's "cockpit" uses the same ingredients (sensor averaging, delay, zero-order hold,
controller); here they come out of the blocks, so the model cannot drift from the simulation.
The loop transfer for the margins is L = C (z^-n (P - Q) + G0) (predictor: F z^-n (P - Q));
closed-loop stability is decided by the winding number of the characteristic polynomial on
the unit circle (argument principle), so integrators and resonators on the circle are safe.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from compensation.controllers import FeedbackController, KalmanPredictor, polymul, polyval
from compensation.loop import Trajectory
from compensation.metrics import json_dict


def _piecewise_fourier(t: np.ndarray, s: np.ndarray, omega: np.ndarray, interp: str,
                       t_end: float) -> np.ndarray:
    """Integral of a sampled trajectory s(t) (previous or linear interpolation, zero after
    t_end) times exp(-j w t), for each w > 0."""
    w = np.asarray(omega, dtype=np.float64)[:, None]
    if interp == "previous":
        edges = np.append(t, t_end)
        e = np.exp(-1j * w * edges[None, :])
        return ((e[:, :-1] - e[:, 1:]) * s[None, :]).sum(axis=1) / (1j * w[:, 0])
    a, b = t[:-1], t[1:]
    sa, sb = s[:-1], s[1:]
    keep = b > a
    a, b, sa, sb = a[keep], b[keep], sa[keep], sb[keep]
    slope = (sb - sa) / (b - a)
    ea, eb = np.exp(-1j * w * a[None, :]), np.exp(-1j * w * b[None, :])
    jw = 1j * w
    seg = sa * (ea - eb) / jw + slope * (-(b - a) * eb / jw + (ea - eb) / jw**2)
    return seg.sum(axis=1)


def linear_fourier(t_s: np.ndarray, s: np.ndarray, omega: np.ndarray) -> np.ndarray | None:
    """Integral of a trajectory s(t) linearly interpolated between uniformly spaced samples
    (``t_s`` (N,) s, ``s`` (N,)), zero outside them, times exp(-j w t), at each angular
    frequency ``omega`` (F,) rad/s > 0; None when the samples are not uniformly spaced.

    What :func:`_piecewise_fourier` integrates segment by segment, in
    closed form on the uniform grid t_k = t_0 + k h: the sum is A(x) sum_k s_k e^{-j w t_k}
    + B(x) sum_k (s_{k+1} - s_k) e^{-j w t_k}, x = j w h, A = h (1 - e^{-x}) / x,
    B = h ((1 - e^{-x}) / x - e^{-x}) / x (their series below |x| = 0.05, where the closed
    forms cancel), the two sums by baby-step giant-step (e^{-j w h (L q + p)} from F (L +
    Q) exponentials and one matrix product, L Q >= N - 1): F (L + Q) exponentials instead
    of 2 F N, and no recurrence, so the rounding stays at ~1e-11 of the largest value
    (segment by segment in doubles it is ~1e-8 to 1e-7 at the lowest frequencies, against
    the sum in extended precision)."""
    t = np.asarray(t_s, np.float64)
    n = len(t) - 1
    if n < 2:
        return None
    h = (t[-1] - t[0]) / n
    if not h > 0 or np.max(np.abs(t - (t[0] + h * np.arange(n + 1)))) > 1e-9 * h:
        return None
    w = np.asarray(omega, np.float64)
    big = int(np.ceil(np.sqrt(n)))
    small_n = int(np.ceil(n / big))
    coef = np.zeros((2, small_n * big))
    coef[0, :n] = s[:-1]
    coef[1, :n] = np.diff(s)
    e_p = np.exp(-1j * np.outer(w, h * np.arange(big)))  # (F, L)
    e_q = np.exp(-1j * np.outer(w, t[0] + h * big * np.arange(small_n)))  # (F, Q)
    inner = np.einsum("fl,cql->cfq", e_p, coef.reshape(2, small_n, big))
    sums = np.einsum("cfq,fq->cf", inner, e_q)
    x = 1j * w * h
    r = np.exp(-x)
    near = np.abs(x) < 0.05
    xs = np.where(near, 1.0, x)
    phi1 = (1.0 - r) / xs
    g = (phi1 - r) / xs
    ser1 = np.zeros_like(x)
    ser2 = np.zeros_like(x)
    for k in range(10):  # (1 - e^-x) / x and ((1 - e^-x) / x - e^-x) / x
        ser1 = ser1 + (-x) ** k / math.factorial(k + 1)
        ser2 = ser2 + (-1) ** k * (k + 1) / math.factorial(k + 2) * x**k
    phi1 = np.where(near, ser1, phi1)
    g = np.where(near, ser2, g)
    return h * (phi1 * sums[0] + g * sums[1])


def _pulse_trajectory(act, phi: float, period: float, end: float) -> Trajectory:
    """The actuator's trajectory for a unit command (axis 0) from phi to phi + period."""
    st = act.init(0.0)
    traj = Trajectory(act.interpolation, 0.0)
    for t_cmd, u in ((phi, 1.0), (phi + period, 0.0)):
        st, tt, ss = act.advance(st, t_cmd)
        traj.append(tt, ss)
        st = act.command(st, t_cmd, np.array([u, 0.0]))
    st, tt, ss = act.advance(st, end)
    traj.append(tt, ss)
    return traj


@lru_cache(maxsize=64)
def _pulse(actuator, period: float, exposure: float, phi: float):
    """See :attr:`LoopModel.pulse`."""
    act = actuator.linearized()
    res = getattr(act, "resonance_hz", None)
    damp = getattr(act, "damping", 1.0)
    settle = 40.0 / (damp * 2 * np.pi * res) if res else 0.0
    m = min(int(np.ceil(max(0.3, settle) / period)) + 5, 20000)
    traj = _pulse_trajectory(act, phi, period, m * period)
    ideal = _pulse_trajectory(actuator.command_model(), phi, period, m * period)
    p = np.array([traj.mean(k * period, k * period + exposure)[0] for k in range(m)])
    q = np.array([ideal.mean(k * period, k * period + exposure)[0] for k in range(m)])
    t, s = traj.samples
    return p, q, t.copy(), s[:, 0].copy(), act.interpolation


@lru_cache(maxsize=64)
def _stage_response(actuator, period: float, exposure: float, phi: float,
                    f_bytes: bytes) -> np.ndarray:
    """See :meth:`LoopModel.stage_response` (cached per actuator, timing and frequencies)."""
    f = np.frombuffer(f_bytes, dtype=np.float64)
    _, _, t, s, interp = _pulse(actuator, period, exposure, phi)
    if interp == "linear":  # in closed form on a uniform grid
        h = linear_fourier(t, s, 2 * np.pi * f)
        if h is not None:
            return h / period
    out = np.empty(len(f), dtype=np.complex128)
    for i in range(0, len(f), 256):  # bounded memory: (256, samples) at a time
        w = 2 * np.pi * f[i:i + 256]
        out[i:i + 256] = _piecewise_fourier(t, s, w, interp, t[-1] + period) / period
    return out


@dataclass(frozen=True)
class Margins:
    """Stability figures of a loop: gain margin (dB; at -180 deg crossings where |L| < 1),
    phase margin (deg; the angular distance of L from -1 where |L| = 1), modulus margin (the
    least |1 + L|: robust to gain and phase changes together; conditionally stable loops
    with resonant terms have no classical gain margin), closed-loop stability, the
    rejection's 0 dB crossover (Hz) and its peak (value, Hz)."""

    gain_margin_db: float
    phase_margin_deg: float
    modulus_margin: float
    stable: bool
    crossover_hz: float
    peak_rejection: float
    peak_hz: float

    def to_dict(self) -> dict:
        return json_dict(self)


@dataclass(frozen=True)
class LoopModel:
    """A loop as the analytic model sees it.

    rate_hz : tracker frame rate; exposure_s : tracker exposure; latency_s : from the end of
    an exposure to the command (transport); controller : a feedback kind or the Kalman
    predictor; actuator : any actuator block (linearised here); sigma_px : measurement noise
    (the predictor's steady state depends on it).
    """

    rate_hz: float
    exposure_s: float
    latency_s: float
    controller: object
    actuator: object
    sigma_px: float = 0.02

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @cached_property
    def timing(self) -> tuple[int, float]:
        """(n, phi): measurement of frame k drives tick k + n at time (k + n) T + phi."""
        lag = self.exposure_s + self.latency_s
        n = int(np.floor(lag / self.period_s + 1e-9))
        phi = max(0.0, lag - n * self.period_s)
        return n, phi

    @property
    def pulse(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, str]:
        """(p, q, t, s, interpolation): window means of the stage's and the ideal response to
        one unit command held over one period from tick 0, and the stage's trajectory
        (cached per actuator and timing: a design search reuses it)."""
        n, phi = self.timing
        return _pulse(self.actuator, self.period_s, self.exposure_s, phi)

    # -- transfer functions -----------------------------------------------------------------
    def _z(self, f_hz) -> np.ndarray:
        return np.exp(2j * np.pi * np.asarray(f_hz, dtype=np.float64) * self.period_s)

    def controller_tf(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """(b, a, is_predictor) in z^-1."""
        c = self.controller
        if isinstance(c, KalmanPredictor):
            n, phi = self.timing
            lag = self.exposure_s + self.latency_s
            horizon = lag - 0.5 * self.exposure_s + 0.5 * self.period_s + (c.lead_s or 0.0)
            b, a = c.transfer_rational(self.period_s, horizon, self.sigma_px)
            return b, a, True
        if isinstance(c, FeedbackController):
            b, a = c.transfer()
            return b, a, False
        raise TypeError(f"no transfer function for controller {type(c).__name__}")

    def plant_polys(self) -> tuple[np.ndarray, np.ndarray]:
        """The plant as the controller sees it: polynomials in z^-1 (G, G_pq).

        ``G_pq = z^-n (P - Q)``: the commands' effect on the measurement that the estimator
        does not assume, ``P`` and ``Q`` the exposure means (px per px of command) of the
        stage's and of an ideal held command's response to one unit command held one period
        (``p``, ``q`` of :attr:`pulse`), delayed by the ``n`` ticks of :attr:`timing`.
        ``G = G_pq + G0``: the whole plant in a feedback loop, ``G0 = z^-1`` for a Smith
        predictor or ``z^-n Q`` otherwise (then ``G = z^-n P``). The loop transfer is
        ``C G`` (feedback) or ``F G_pq`` (Kalman predictor); see the module docstring.

        Returns
        -------
        g : numpy.ndarray
            Coefficients of ``G`` in ascending powers of z^-1 (dimensionless, px/px).
        g_pq : numpy.ndarray
            Coefficients of ``G_pq`` in ascending powers of z^-1 (dimensionless, px/px).
        """
        n, _ = self.timing
        p, q, *_ = self.pulse
        shift = np.zeros(n)
        g_pq = np.concatenate([shift, p - q])
        smith = getattr(self.controller, "smith", False)
        g0 = np.array([0.0, 1.0]) if smith else np.concatenate([shift, q])
        length = max(len(g_pq), len(g0))
        g = np.pad(g_pq, (0, length - len(g_pq))) + np.pad(g0, (0, length - len(g0)))
        return g, g_pq

    def command_tf(self, f_hz) -> np.ndarray:
        """U / D at frequencies f: the commands' response to a measured disturbance."""
        z = self._z(f_hz)
        x = 1.0 / z
        b, a, predictor = self.controller_tf()
        n, _ = self.timing
        c = polyval(x, b) / polyval(x, a)
        g, g_pq = self.plant_polys()
        lp = polyval(x, g_pq if predictor else g)
        return c * x**n / (1.0 + c * lp)

    def loop_tf(self, f_hz) -> np.ndarray:
        """The loop transfer L at frequencies f (for the margins)."""
        x = 1.0 / self._z(f_hz)
        b, a, predictor = self.controller_tf()
        c = polyval(x, b) / polyval(x, a)
        g, g_pq = self.plant_polys()
        return c * polyval(x, g_pq if predictor else g)

    def stage_response(self, f_hz) -> np.ndarray:
        """H(w) / T: the stage's first-harmonic response to a held command sequence."""
        f = np.atleast_1d(np.asarray(f_hz, dtype=np.float64))
        n, phi = self.timing
        return _stage_response(self.actuator, self.period_s, self.exposure_s, phi,
                               f.tobytes()).copy()

    def averaging(self, f_hz) -> np.ndarray:
        """W(w): the tracker exposure's averaging of a sinusoid."""
        wt = 2j * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=np.float64)) * self.exposure_s
        return np.where(np.abs(wt) > 1e-12, (np.exp(wt) - 1.0) / np.where(wt == 0, 1, wt), 1.0)

    def rejection(self, f_hz) -> np.ndarray:
        """S(f) (complex): residual / disturbance at frequency f (|S| < 1 rejects)."""
        f = np.atleast_1d(np.asarray(f_hz, dtype=np.float64))
        return 1.0 - self.averaging(f) * self.command_tf(f) * self.stage_response(f)

    def noise_rms_px(self, sigma_px: float, f_max_factor: float = 64.0,
                     n_points: int = 65536) -> float:
        """RMS residual caused by white measurement noise of sigma_px per frame (Parseval on
        the stage's response to one noisy measurement)."""
        f = (np.arange(n_points) + 0.5) / n_points * f_max_factor * self.rate_hz
        v = self.command_tf(f) * self.stage_response(f) * self.period_s
        var = sigma_px**2 / self.period_s * 2.0 * np.sum(np.abs(v) ** 2) * (f[1] - f[0])
        return float(np.sqrt(var))

    # -- stability --------------------------------------------------------------------------
    def characteristic(self) -> np.ndarray:
        """Characteristic polynomial in z^-1 (its roots in z^-1 must lie outside |x| = 1)."""
        b, a, predictor = self.controller_tf()
        g, g_pq = self.plant_polys()
        other = polymul(b, g_pq if predictor else g)
        out = np.zeros(max(len(a), len(other)))
        out[: len(a)] += a
        out[: len(other)] += other
        return out

    def unstable_roots(self) -> int:
        """How many closed-loop poles lie on or outside the unit circle (winding number of
        the characteristic polynomial in z^-1 around |z^-1| = 1)."""
        c = np.trim_zeros(self.characteristic(), "b")
        n_fft = 1 << max(16, int(np.ceil(np.log2(len(c) * 8))))
        vals = np.fft.fft(c, n_fft)  # c at x = exp(-2 pi j k / N): the circle, clockwise
        if np.min(np.abs(vals)) < 1e-12 * np.max(np.abs(vals)):
            return 1
        phase = np.unwrap(np.angle(np.append(vals, vals[0])))
        winding = -(phase[-1] - phase[0]) / (2 * np.pi)  # counter-clockwise in x
        return int(round(winding))

    def margins(self, n_points: int = 4001) -> Margins:
        """Gain and phase margins of L, stability, 0 dB crossover and peak of |S|."""
        f = np.concatenate([np.geomspace(1e-4, 0.01, 400), np.linspace(0.01, 0.5, n_points)])
        f = f * self.rate_hz
        lf = self.loop_tf(f)
        mag = np.abs(lf)
        ang = np.angle(lf)
        pm = np.inf
        cross = np.flatnonzero(np.diff(np.sign(mag - 1.0)) != 0)
        for i in cross:  # angular distance of L from -1
            pm = min(pm, 180.0 - abs(np.degrees(ang[i])))
        gm = np.inf
        flips = list(np.flatnonzero((np.diff(np.sign(lf.imag)) != 0) & (lf.real[:-1] < 0)))
        if lf.real[-1] < 0 and abs(lf.imag[-1]) <= 1e-9 * mag[-1]:  # -180 deg at Nyquist
            flips.append(len(lf) - 1)
        for i in flips:
            if mag[i] < 1.0:
                gm = min(gm, -20 * np.log10(max(mag[i], 1e-300)))
        modulus = float(np.min(np.abs(1.0 + lf)))
        s = np.abs(self.rejection(f))
        k = int(np.argmax(s))
        up = np.flatnonzero((s[:-1] < 1.0) & (s[1:] >= 1.0))
        crossover = float(f[up[0]]) if up.size else np.nan
        return Margins(float(gm), float(pm), modulus, self.unstable_roots() == 0, crossover,
                       float(s[k]), float(f[k]))


def design_lines(controller: FeedbackController, model: LoopModel) -> FeedbackController:
    """Phase advance, update gain and alias correction of each resonant line.

    The line's output reaches the error through G (plant, notch); with the alias correction
    alpha_i = G(w_i) - z^-n W H N / T it sees G_i = (G - alpha_i) / (1 + C_core G) at its
    frequency (the rest of the controller closed around it); phi_i = -arg G_i makes its
    update converge without rotation, mu_i = 2 gain_i / |G_i| at ``gain_i`` per measurement.
    """
    if not controller.lines:
        return controller
    bare = dataclasses.replace(controller, lines=(), line_phase_rad=None, line_mu=None,
                               line_alias=None)
    m = dataclasses.replace(model, controller=bare)
    b, a = bare.core()
    g, _ = m.plant_polys()
    n, _ = m.timing
    phases, mus, aliases = [], [], []
    for ln in controller.lines:
        f = ln.frequency_hz
        x = 1.0 / m._z(f)
        notch = 1.0
        if controller.notch is not None:
            bn, an = controller.notch.coefficients(controller.rate_hz)
            notch = (polyval(x, bn)
                     / polyval(x, an))
        gv = polyval(x, g) * notch
        fundamental = x**n * m.averaging(f)[0] * m.stage_response(f)[0] * notch
        alpha = complex(gv - fundamental)
        c = polyval(x, b) / polyval(x, a)
        geff = fundamental / (1.0 + c * gv)
        phases.append(float(-np.angle(geff)))
        mus.append(float(2.0 * ln.gain / max(abs(geff), 1e-9)))
        aliases.append(alpha)
    return dataclasses.replace(controller, line_phase_rad=tuple(phases), line_mu=tuple(mus),
                               line_alias=tuple(aliases))


def measured_rejection(model: LoopModel, freqs_hz, amplitude_px: float = 0.1,
                       settle_s: float | None = None, periods: int = 8,
                       samples_per_frame: int = 16) -> np.ndarray:
    """|S(f)| measured by a sine sweep: the loop of ``model`` (its controller, actuator and
    latency; one block on the analytic plant, no noise) run against a sinusoid at each
    frequency; the residual's component at f over whole periods after ``settle_s`` (default:
    the longer of 0.5 s and 20 periods), divided by the disturbance's."""
    from compensation.analytic_plant import AnalyticPlant, sinusoids
    from compensation.estimators import MeanEstimator
    from compensation.loop import Timeline, simulate
    from compensation.transport import Transport

    out = []
    t_per = model.period_s
    for f in np.atleast_1d(freqs_hz):
        settle = settle_s if settle_s is not None else max(0.5, 20.0 / f)
        n_meas = int(np.ceil(periods / f / t_per))
        n_meas = int(np.ceil(n_meas * t_per * f)) / f / t_per  # whole periods
        n = int(np.ceil(settle / t_per + n_meas)) + 1
        frame_t = np.arange(n) * t_per
        motion = sinusoids([(amplitude_px, float(f), 0.0, 0)])
        plant = AnalyticPlant(motion, np.zeros((1, 2)), model.sigma_px, frame_t,
                              model.exposure_s, noise_scale=0.0)
        end = n * t_per
        tl = Timeline(frame_t, model.exposure_s, end, np.zeros((n, 2)), t_per)
        res = simulate(plant, MeanEstimator(), model.controller, model.actuator,
                       Transport(latency_s=model.latency_s), tl)
        t1 = end
        t0 = t1 - round((t1 - settle) * f) / f
        ts = np.linspace(t0, t1, int(round((t1 - t0) / t_per * samples_per_frame)),
                         endpoint=False)
        ts = ts + 0.5 * (ts[1] - ts[0])
        m = amplitude_px * np.sin(2 * np.pi * f * ts)
        r = m - res.trajectory(ts)[:, 0]
        e = np.exp(-2j * np.pi * f * ts)
        out.append(abs(np.sum(r * e)) / abs(np.sum(m * e)))
    return np.array(out)


def max_integrator_gain(model: LoopModel, peak_max: float = 2.0, lo: float = 1e-3,
                        hi: float = 2.0) -> float:
    """The largest integrator gain whose loop is stable with peak |S| <= peak_max (the same
    robustness for every stage, so their rejections can be compared); bisection."""
    import dataclasses as dc

    def ok(g: float) -> bool:
        c = dc.replace(model.controller, gain=g)
        if getattr(c, "lines", ()):
            c = design_lines(c, dc.replace(model, controller=c))
        mg = dc.replace(model, controller=c).margins()
        return mg.stable and mg.peak_rejection <= peak_max

    if not ok(lo):
        return float("nan")
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo

"""Focal-plane stages: the ideal zero-order hold and a piezo stage with its imperfections.

An actuator owns the stage trajectory s(t) (px, (row, col); the detectors move by +s, so the
content they see moves by -s, docs/conventions.md). The loop advances it to a time, sends it
commands, and records the samples it returns; the renderer's pose keyframes and the truth's
fine samples read s(t) from that record (:class:`compensation.loop.Trajectory`).

References: Bouc-Wen hysteresis of piezo actuators (Low & Guo, J. Microelectromech. Syst. 4
(1995); Rakotondrabe, IEEE T-ASE 8 (2011)); logarithmic creep (Jung & Gweon, Rev. Sci.
Instrum. 71 (2000)); first resonance and stroke of a 2-D focal-plane stage (Micromachines 17
(2026) 87: 54 um = 4.5 px of 12 um, 357 Hz).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property
from typing import ClassVar

import numpy as np

from compensation.blocks import register

#: relative tolerance on times: a command at t acts on every sample at t (1e-12 relative)
TIME_EPS = 1e-12


def _stroke_limit(u: np.ndarray, stroke_px: float | None) -> tuple[np.ndarray, bool]:
    """Clip a command to +-stroke/2 per axis; True if it was clipped."""
    if stroke_px is None:
        return u, False
    half = 0.5 * stroke_px
    c = np.clip(u, -half, half)
    return c, bool(np.any(c != u))


@dataclass(frozen=True)
class IdealState:
    t_s: float  # advanced up to here
    u_px: np.ndarray  # the commanded position (2,)
    start_px: np.ndarray  # where the current ramp started (2,) (= u_px without a ramp)
    t_cmd_s: float  # when the current command arrived
    pend: int  # samples not yet returned: 0, 1 (the command), 2 (command and ramp end)
    saturated: bool  # the applied command is clipped at the stroke
    saturated_s: float  # time spent clipped so far


@register("actuator", "ideal")
@dataclass(frozen=True)
class IdealStage:
    """A stage that goes exactly where it is commanded, without dynamics.

    Zero-order hold (default): it jumps to each command and holds it. ``ramp: true``: it
    moves at constant speed from where it is to the command over ``ramp_s`` (set by the
    wiring to the time between commands: a first-order hold), so it follows a smooth motion
    without the staircase's ripple; predictors then aim at the end of the ramp (``lag_s``).
    stroke_px : total travel per axis (centred on 0), px; None: unlimited. A clipped command
    counts as saturated (reported, never silent).
    """

    WIRED: ClassVar[tuple[str, ...]] = ("ramp_s",)

    stroke_px: float | None = None
    ramp: bool = False
    ramp_s: float | None = None
    kind: str = field(default="ideal", init=False)

    def __post_init__(self) -> None:
        if self.stroke_px is not None and not self.stroke_px > 0:
            raise ValueError(f"stroke_px must be > 0 (or None), got {self.stroke_px}")
        if self.ramp_s is not None and not self.ramp_s > 0:
            raise ValueError(f"ramp_s must be > 0, got {self.ramp_s}")

    @property
    def interpolation(self) -> str:
        return "linear" if self._ramping else "previous"

    @property
    def _ramping(self) -> bool:
        return self.ramp and self.ramp_s is not None

    @property
    def lag_s(self) -> float:
        """How much later than a hold the stage reaches a command, on average, s."""
        return 0.5 * self.ramp_s if self._ramping else 0.0

    def init(self, t0_s: float = 0.0) -> IdealState:
        return IdealState(t0_s, np.zeros(2), np.zeros(2), t0_s, 0, False, 0.0)

    def linearized(self) -> IdealStage:
        return dataclasses.replace(self, stroke_px=None)

    def command_model(self) -> IdealStage:
        """What the loop assumes the stage does with its commands: exactly this."""
        return dataclasses.replace(self, stroke_px=None)

    def clip(self, u_px: np.ndarray) -> np.ndarray:
        """The command the stage can follow (clipped to the stroke), px."""
        return _stroke_limit(np.asarray(u_px, dtype=np.float64), self.stroke_px)[0]

    def saturated_s(self, state: IdealState) -> float:
        return state.saturated_s

    def _position(self, st: IdealState, t_s: float) -> np.ndarray:
        if not self._ramping:
            return st.u_px
        a = min(1.0, max(0.0, (t_s - st.t_cmd_s) / self.ramp_s))
        return st.start_px + (st.u_px - st.start_px) * a

    def command(self, state: IdealState, t_s: float, u_px: np.ndarray) -> IdealState:
        u, sat = _stroke_limit(np.asarray(u_px, dtype=np.float64), self.stroke_px)
        st = self._account(state, t_s)
        start = self._position(st, t_s) if self._ramping else u
        return dataclasses.replace(st, u_px=u, start_px=np.array(start, dtype=np.float64),
                                   t_cmd_s=t_s, pend=2 if self._ramping else 1, saturated=sat)

    def advance(self, state: IdealState, t_s: float):
        """Samples since the last call: the command's start (and, while ramping, the
        ramp's end once reached, or the position at t_s, so the trajectory is complete up
        to t_s)."""
        st = self._account(state, t_s)
        times, pos = [], []
        if st.pend >= 1 and (st.pend == 2 or not self._ramping):
            times.append(st.t_cmd_s)
            pos.append(st.start_px if self._ramping else st.u_px)
        pend = 0
        if self._ramping and st.pend >= 1:
            end = st.t_cmd_s + self.ramp_s
            if t_s >= end:
                times.append(end)
                pos.append(st.u_px)
            else:
                if t_s > st.t_cmd_s:
                    times.append(t_s)
                    pos.append(self._position(st, t_s))
                pend = 1
        st = dataclasses.replace(st, pend=pend)
        if not times:
            return st, np.empty(0), np.empty((0, 2))
        return st, np.array(times), np.array(pos, dtype=np.float64).reshape(-1, 2)

    def _account(self, state: IdealState, t_s: float) -> IdealState:
        if t_s <= state.t_s:
            return state
        extra = (t_s - state.t_s) if state.saturated else 0.0
        return dataclasses.replace(state, t_s=t_s, saturated_s=state.saturated_s + extra)


def expm_small(a: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small square matrix (scaling and squaring, Taylor series)."""
    a = np.asarray(a, dtype=np.float64)
    norm = np.abs(a).sum(axis=1).max()
    s = max(0, int(np.ceil(np.log2(norm / 0.25))) if norm > 0.25 else 0)
    x = a / 2.0**s
    out = np.eye(len(a))
    term = np.eye(len(a))
    for k in range(1, 18):
        term = term @ x / k
        out = out + term
    for _ in range(s):
        out = out @ out
    return out


#: time constants of the creep elements (one per decade), s
CREEP_TAUS_S = (0.01, 0.1, 1.0, 10.0, 100.0)


@dataclass(frozen=True)
class PiezoState:
    tick: int  # DAC ticks done (time = tick / update_hz)
    u_cmd: np.ndarray  # latest command (2,)
    drive: np.ndarray  # amplifier output after DAC and slew limit (2,)
    hyst: np.ndarray  # Bouc-Wen variable (2,)
    creep: np.ndarray  # creep elements (2, n)
    x: np.ndarray  # mode position (2,)
    v: np.ndarray  # mode velocity (2,)
    saturated_ticks: int
    shaper: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))  # drive notch (2, 2)


@register("actuator", "piezo")
@dataclass(frozen=True)
class PiezoStage:
    """A 2-axis piezo stage driven open loop through a DAC and an amplifier.

    Per axis, at every DAC tick (``update_hz``): the command is clipped to the stroke
    (counted as saturation) and quantised to ``dac_bits`` over the stroke; the amplifier
    follows it at most at ``slew_px_s``; the ceramic adds Bouc-Wen rate-independent
    hysteresis (``hysteresis_pct``: the widest gap between the rising and falling branches of
    a full-stroke cycle, % of the stroke) and logarithmic creep (``creep_pct_per_decade``,
    five first-order elements 0.01-100 s); the stage's first mode is a second-order low-pass
    (``resonance_hz``, ``damping``), integrated exactly over each tick; ``cross_coupling``
    moves each axis by that fraction of the other.

    ``drive_notch_hz`` (None: off) is the drive electronics' notch, a pole-zero filter
    running at the DAC rate in front of the DAC, as digital piezo controllers have: its zeros
    cancel the mode as identified (``drive_notch_hz``, ``drive_notch_damping``, default the
    stage's own damping: give other values to model an identification error) and its poles
    put a well-damped mode in its place (``drive_target_hz``, default 3 x drive_notch_hz;
    ``drive_target_damping``, default 0.7). The loop then sees a faster, damped stage; a
    1 kHz loop's notch (controller ``notch``) cannot do this, since it acts below the loop's
    Nyquist frequency and adds its phase lag at the crossover. The filter boosts the drive above the
    mode (up to (target / notch)^2): the stroke (the DAC's range) clips the shaped drive, and a
    clipped tick counts as saturated; a slew limit then limits it too (not counted).

    A command acts from the first tick at or after its time, so choose ``update_hz`` a
    multiple of the tracker's frame rate (None: the wiring picks the smallest multiple of
    the frame rate at or above 20 x resonance_hz and 4 x the drive notch's frequencies).
    """

    update_hz: float | None = None
    stroke_px: float | None = 4.5
    resonance_hz: float = 357.0
    damping: float = 0.05
    slew_px_s: float | None = None
    hysteresis_pct: float = 0.0
    creep_pct_per_decade: float = 0.0
    dac_bits: int | None = 16
    cross_coupling: float = 0.0
    drive_notch_hz: float | None = None
    drive_notch_damping: float | None = None
    drive_target_hz: float | None = None
    drive_target_damping: float | None = None
    kind: str = field(default="piezo", init=False)
    interpolation: str = field(default="linear", init=False)

    def __post_init__(self) -> None:
        checks = (("update_hz", self.update_hz is None or self.update_hz > 0),
                  ("resonance_hz", self.resonance_hz > 0),
                  ("damping", self.damping > 0),
                  ("hysteresis_pct", 0 <= self.hysteresis_pct < 50),
                  ("creep_pct_per_decade", 0 <= self.creep_pct_per_decade < 10),
                  ("cross_coupling", abs(self.cross_coupling) < 0.5))
        for name, ok in checks:
            if not ok:
                raise ValueError(f"{name} out of range: {getattr(self, name)}")
        if self.stroke_px is not None and not self.stroke_px > 0:
            raise ValueError(f"stroke_px must be > 0 (or None), got {self.stroke_px}")
        if self.slew_px_s is not None and not self.slew_px_s > 0:
            raise ValueError(f"slew_px_s must be > 0 (or None), got {self.slew_px_s}")
        if self.dac_bits is not None and not 1 <= self.dac_bits <= 32:
            raise ValueError(f"dac_bits must be within 1..32 (or None), got {self.dac_bits}")
        if (self.hysteresis_pct or self.dac_bits is not None) and self.stroke_px is None:
            raise ValueError("hysteresis_pct and dac_bits are relative to the stroke: give "
                             "stroke_px")
        if self.update_hz is not None and self.update_hz < 8.0 * self.resonance_hz:
            raise ValueError(f"update_hz ({self.update_hz:g}) must be >= 8 x resonance_hz "
                             f"({self.resonance_hz:g}) to integrate the mode")
        if self.drive_notch_hz is None:
            for name in ("drive_notch_damping", "drive_target_hz", "drive_target_damping"):
                if getattr(self, name) is not None:
                    raise ValueError(f"{name} shapes the drive notch: give drive_notch_hz "
                                     "too")
            return
        notch = (("drive_notch_hz", self.drive_notch_hz > 0),
                 ("drive_notch_damping", self.drive_notch_damping is None
                  or 0 < self.drive_notch_damping < 1),
                 ("drive_target_hz", self.drive_target_hz is None or self.drive_target_hz > 0),
                 ("drive_target_damping", self.drive_target_damping is None
                  or 0 < self.drive_target_damping <= 2))
        for name, ok in notch:
            if not ok:
                raise ValueError(f"{name} out of range: {getattr(self, name)}")
        top = self.drive_top_hz
        if self.update_hz is not None and self.update_hz < 4.0 * top:
            raise ValueError(f"update_hz ({self.update_hz:g}) must be >= 4 x the drive "
                             f"notch's frequencies ({top:g} Hz) to place them")

    # -- derived constants -----------------------------------------------------------------
    @property
    def dt_s(self) -> float:
        if self.update_hz is None:
            raise ValueError("PiezoStage.update_hz is not set")
        return 1.0 / self.update_hz

    @cached_property
    def _mode(self) -> tuple[np.ndarray, np.ndarray]:
        return self._mode_matrices()

    @cached_property
    def _hysteresis(self) -> tuple[float, float]:
        return self._bouc_wen()

    def _mode_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact zero-order-hold discretisation (A_d 2x2, B_d 2) of the mode over one tick."""
        w = 2.0 * np.pi * self.resonance_hz
        m = np.zeros((3, 3))
        m[0, 1] = 1.0
        m[1, 0] = -w * w
        m[1, 1] = -2.0 * self.damping * w
        m[1, 2] = w * w
        e = expm_small(m * self.dt_s)
        return e[:2, :2], e[:2, 2]

    def _bouc_wen(self) -> tuple[float, float]:
        """(alpha, beta) with beta = gamma = 2 / stroke, alpha giving ``hysteresis_pct``."""
        if not self.hysteresis_pct:
            return 0.0, 0.0
        beta = 2.0 / self.stroke_px
        target = self.hysteresis_pct / 100.0 * self.stroke_px
        lo, hi = 0.0, 0.99
        for _ in range(50):  # the full-cycle loop width grows monotonically with alpha
            mid = 0.5 * (lo + hi)
            if _cycle_width(mid, beta, self.stroke_px) < target:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi), beta

    @property
    def target_damping(self) -> float:
        """The drive notch's new mode's damping (0.7 unless given)."""
        return 0.7 if self.drive_target_damping is None else self.drive_target_damping

    @property
    def target_hz(self) -> float:
        """The drive notch's new mode, Hz (3 x drive_notch_hz unless given)."""
        if self.drive_notch_hz is None:
            return self.resonance_hz
        return self.drive_target_hz or 3.0 * self.drive_notch_hz

    @property
    def drive_top_hz(self) -> float:
        """The drive notch's highest frequency (its zeros' or its target's), Hz; 0 when off:
        the DAC must run at 4 x it or more."""
        return 0.0 if self.drive_notch_hz is None else max(self.drive_notch_hz, self.target_hz)

    @cached_property
    def _shaper(self) -> tuple[np.ndarray, np.ndarray] | None:
        return self._shaper_coefficients()

    def _shaper_coefficients(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(b, a) in z^-1 of the drive notch at the DAC rate, unity gain at DC: zeros at the
        identified mode's poles mapped exactly (z = exp(s dt), as the mode's zero-order-hold
        discretisation has them), poles at the target mode's; None when off."""
        if self.drive_notch_hz is None:
            return None

        def poly(f_hz: float, zeta: float) -> np.ndarray:
            w = 2.0 * np.pi * f_hz
            if zeta >= 1.0:  # two real poles
                r1 = np.exp((-zeta + np.sqrt(zeta * zeta - 1.0)) * w * self.dt_s)
                r2 = np.exp((-zeta - np.sqrt(zeta * zeta - 1.0)) * w * self.dt_s)
                return np.array([1.0, -(r1 + r2), r1 * r2])
            root = np.exp((-zeta + 1j * np.sqrt(1.0 - zeta * zeta)) * w * self.dt_s)
            return np.array([1.0, -2.0 * root.real, abs(root) ** 2])

        zeta = self.damping if self.drive_notch_damping is None else self.drive_notch_damping
        b = poly(self.drive_notch_hz, zeta)
        a = poly(self.target_hz, self.target_damping)
        return b * (a.sum() / b.sum()), a

    @property
    def lag_s(self) -> float:
        """Low-frequency group delay of the mode (2 zeta / omega_n; with the drive notch, of
        the target mode it puts in the mode's place), s."""
        if self.drive_notch_hz is not None:
            return 2.0 * self.target_damping / (2.0 * np.pi * self.target_hz)
        return 2.0 * self.damping / (2.0 * np.pi * self.resonance_hz)

    def command_model(self) -> IdealStage:
        """What the loop assumes the stage does with its commands: hold them (no sensor)."""
        return IdealStage()

    def linearized(self) -> PiezoStage:
        """The same stage without its nonlinear effects (for the analytic loop model)."""
        return dataclasses.replace(self, stroke_px=None, slew_px_s=None, hysteresis_pct=0.0,
                                   dac_bits=None)

    # -- the block -------------------------------------------------------------------------
    def init(self, t0_s: float = 0.0) -> PiezoState:
        z2 = np.zeros(2)
        return PiezoState(int(round(t0_s / self.dt_s)), z2, z2, z2,
                          np.zeros((2, len(CREEP_TAUS_S))), z2, z2, 0, np.zeros((2, 2)))

    def clip(self, u_px: np.ndarray) -> np.ndarray:
        """The command the stage can follow (clipped to the stroke), px."""
        return _stroke_limit(np.asarray(u_px, dtype=np.float64), self.stroke_px)[0]

    def command(self, state: PiezoState, t_s: float, u_px: np.ndarray) -> PiezoState:
        return dataclasses.replace(state, u_cmd=np.asarray(u_px, dtype=np.float64).copy())

    def advance(self, state: PiezoState, t_s: float):
        """Integrate every tick up to and including t_s; samples at the ticks."""
        n_to = int(np.floor(t_s * self.update_hz * (1.0 + TIME_EPS) + 1e-9))
        n = n_to - state.tick
        if n <= 0:
            return state, np.empty(0), np.empty((0, 2))
        ad, bd = self._mode
        alpha, beta = self._hysteresis
        u, sat = _stroke_limit(state.u_cmd, self.stroke_px)
        q = None if self.dac_bits is None else self.stroke_px / 2.0**self.dac_bits
        shaper = self._shaper
        if q is not None and shaper is None:
            u = np.round(u / q) * q
        sh = state.shaper.copy()
        if shaper is not None:
            (b0, b1, b2), (_, a1, a2) = shaper
        slew = np.inf if self.slew_px_s is None else self.slew_px_s * self.dt_s
        gamma = self.creep_pct_per_decade / 100.0
        decay = np.exp(-self.dt_s / np.array(CREEP_TAUS_S))
        gain = 1.0 / (1.0 - 2.0 * alpha / (2.0 * beta) / self.stroke_px) if alpha else 1.0
        out = np.empty((n, 2))
        sat_ticks = n if sat else 0
        drive, hyst = state.drive.copy(), state.hyst.copy()
        creep, x, v = state.creep.copy(), state.x.copy(), state.v.copy()
        for i in range(n):
            dac = u
            if shaper is not None:  # transposed direct form II, per axis; then the DAC
                shaped = b0 * u + sh[:, 0]
                sh = np.stack([b1 * u - a1 * shaped + sh[:, 1], b2 * u - a2 * shaped], axis=1)
                dac, clipped = _stroke_limit(shaped, self.stroke_px)  # the DAC's range
                sat_ticks += int(clipped and not sat)
                if q is not None:
                    dac = np.round(dac / q) * q
            step = np.clip(dac - drive, -slew, slew)
            if alpha:
                hyst = _bouc_wen_step(hyst, step, alpha, beta)
            drive = drive + step
            w = (drive - hyst) * gain
            if gamma:
                creep = w[:, None] + (creep - w[:, None]) * decay
                w = (1.0 - gamma * len(decay)) * w + gamma * creep.sum(axis=1)
            xv0 = ad[0, 0] * x + ad[0, 1] * v + bd[0] * w
            v = ad[1, 0] * x + ad[1, 1] * v + bd[1] * w
            x = xv0
            out[i] = x
        if self.cross_coupling:
            out = out + self.cross_coupling * out[:, ::-1]
        times = (state.tick + 1 + np.arange(n)) / self.update_hz
        new = PiezoState(n_to, state.u_cmd, drive, hyst, creep, x, v,
                         state.saturated_ticks + sat_ticks, sh)
        return new, times, out

    def saturated_s(self, state: PiezoState) -> float:
        return state.saturated_ticks / self.update_hz


def _bouc_wen_step(h: np.ndarray, du: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """Bouc-Wen (n = 1, beta = gamma) over an input step du, integrated exactly per branch:
    dh/du = alpha - beta sgn(du) h - beta |h|: relaxes toward +-alpha / (2 beta) when h has
    the sign of du, grows linearly (slope alpha) otherwise."""
    out = h.copy()
    for j in range(len(h)):
        d, hj = float(du[j]), float(h[j])
        if d == 0.0:
            continue
        s = 1.0 if d > 0 else -1.0
        lim = s * alpha / (2.0 * beta)
        if hj * s < 0.0:  # linear part until h crosses 0
            need = -hj / (alpha * s)  # |du| to reach h = 0
            if abs(d) <= need:
                out[j] = hj + alpha * d
                continue
            d -= s * need
            hj = 0.0
        out[j] = lim + (hj - lim) * np.exp(-2.0 * beta * abs(d))
    return out


def _cycle_width(alpha: float, beta: float, stroke: float, n: int = 400) -> float:
    """Largest gap between the rising and falling branches of a full-stroke cycle (output
    u - h, normalised to the stroke as the stage does), px."""
    up = np.linspace(-stroke / 2, stroke / 2, n)
    h = np.zeros(2)
    # settle on the loop: two cycles
    path = np.concatenate([np.linspace(0, -stroke / 2, n // 2), up, up[::-1], up, up[::-1]])
    hs = np.empty(len(path))
    prev = 0.0
    for i, u in enumerate(path):
        h = _bouc_wen_step(h, np.array([u - prev, 0.0]), alpha, beta)
        hs[i] = h[0]
        prev = u
    gain = 1.0 / (1.0 - alpha / beta / stroke) if alpha else 1.0
    rise = (up - hs[-2 * n:-n]) * gain
    fall = (up[::-1] - hs[-n:]) * gain
    return float(np.max(np.abs(rise - fall[::-1])))

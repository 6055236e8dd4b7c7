"""The supervisor: an optional block that stops a loop from amplifying what it should reject.

At each delivered measurement it sees what the controller saw (:class:`ControlInput`) and the
command the controller proposes. It keeps two running mean squares with the time constant
``window_s`` (exponential forgetting):

    closed = |target - stage|^2   the residual the tracker saw (the loop as it is)
    open   = |target|^2           the pseudo-open-loop motion: the residual with the stage
                                  at rest, i.e. what the tracker would have seen open loop

and, once ``warmup_s`` has passed since its first measurement, trips when

    sqrt(closed) > margin * sqrt(open) + floor_px.

With the main imager's exposure ``exposure_s`` and start ``blur_from_s`` (wired from the
scenario), it also watches the blur from that start on: two more running means (same time
constant) of the variance about their own mean, over the last ``exposure_s``, of the same two
series (what an exposure's motion MTF loses, both axes summed), less the measurements'
predicted noise variance (which both series carry), and trips as well, from one ``window_s``
and one exposure after that start, when

    sqrt(blur closed) > blur_margin * sqrt(blur open) + blur_floor_px,

a loop that shakes the exposures more than the motion it was given would (a line it amplifies
above its band), though its total residual is smaller (the slow motion it removes).
It decides from what the loop sees (its measurements and its own commands), never the truth.

What it then does (``action``):

* ``hold``: freezes the command at the last one it let through while the loop was healthy
  (closed <= open); latched for the rest of the run.
* ``open``: returns the stage to rest (command 0): the open loop exactly; latched.
* ``derate``: scales the changes of the controller's command by ``derate_factor`` (for an
  integrator: its gain), restarting from the last healthy command, and judges again after
  ``window_s`` with fresh statistics; each further trip multiplies the factor again, and
  below ``min_factor`` it holds.

Every trip is a decision (time, action, reason, the two RMS, the factor), kept in the state
(so a checkpoint holds them) and listed by :meth:`ResidualSupervisor.decisions`. Until it
trips, its output is the controller's command unchanged, bit for bit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from compensation.blocks import ControlInput, register

ACTIONS = ("hold", "open", "derate")
_NORMAL, _HOLD, _OPEN, _DERATE = 0, 1, 2, 3
_NAMES = {_HOLD: "hold", _OPEN: "open", _DERATE: "derate"}


@dataclass(frozen=True)
class SupervisorState:
    t_s: float  # last measurement used (nan before the first)
    t0_s: float  # first measurement (nan before it)
    judge_from_s: float  # no trip before this time
    ms_closed: float  # running mean square of the residual, px^2
    ms_open: float  # running mean square of the pseudo-open-loop motion, px^2
    mode: int  # 0 normal, 1 hold, 2 open, 3 derated
    factor: float  # scale of the controller's command changes
    held_px: np.ndarray  # (2,) the command held (hold / open)
    good_px: np.ndarray  # (2,) the last command let through while healthy
    prev_raw_px: np.ndarray  # (2,) the controller's previous command (nan: none)
    prev_out_px: np.ndarray  # (2,) the previous command out
    dec_t_s: np.ndarray  # (D,) decision times
    dec_action: np.ndarray  # (D,) 1 hold, 2 open, 3 derate
    dec_closed_px: np.ndarray  # (D,) residual RMS at the decision
    dec_open_px: np.ndarray  # (D,) open-loop RMS at the decision
    dec_factor: np.ndarray  # (D,) the factor after the decision
    win_t: np.ndarray = dataclasses.field(default_factory=lambda: np.empty(0))  # (M,) s
    win_closed: np.ndarray = dataclasses.field(  # (M, 2) residuals of the last exposure_s, px
        default_factory=lambda: np.empty((0, 2)))
    win_open: np.ndarray = dataclasses.field(  # (M, 2) pseudo-open-loop motion, px
        default_factory=lambda: np.empty((0, 2)))
    win_noise: np.ndarray = dataclasses.field(  # (M,) their predicted noise variance, px^2
        default_factory=lambda: np.empty(0))
    ms_blur_closed: float = np.nan  # running mean of the residual's in-exposure variance, px^2
    ms_blur_open: float = np.nan  # the same of the pseudo-open-loop motion, px^2
    dec_blur: np.ndarray = dataclasses.field(  # (D,) the decision was the blur's
        default_factory=lambda: np.empty(0, dtype=bool))


@register("supervisor", "residual")
@dataclass(frozen=True)
class ResidualSupervisor:
    """Residual against pseudo-open-loop monitoring; see the module docstring.

    window_s : time constant of the running mean squares, s.
    margin : trip when the residual RMS exceeds ``margin`` times the open-loop RMS (> 1).
    floor_px : an absolute allowance added to the trip level (noise-level motion), px.
    action : 'hold', 'open' or 'derate'.
    derate_factor : the factor each de-rating multiplies the command's changes by (0, 1).
    min_factor : below this factor a de-rating holds instead (0, 1).
    warmup_s : no trip before this long after the first measurement (None: window_s).
    blur_margin : trip when the residual's in-exposure RMS exceeds this times the open
        loop's (> 1).
    exposure_s : the main imager's exposure, s (wired; None: the blur is not watched).
    blur_from_s : the blur is watched from this time on, s (wired: the main imager's start;
        the loop's acquisition before it is no exposure's concern), and judged from one
        ``window_s`` and one exposure later.
    blur_floor_px : an absolute allowance on the in-exposure RMS, px (0.003 px costs an
        exposure ~5e-5 of its motion MTF at Nyquist: a loop at the noise level never trips).
    """

    WIRED: ClassVar[tuple[str, ...]] = ("exposure_s", "blur_from_s")

    window_s: float = 0.5
    margin: float = 1.5
    floor_px: float = 0.0
    action: str = "hold"
    derate_factor: float = 0.5
    min_factor: float = 0.1
    warmup_s: float | None = None
    blur_margin: float = 1.05
    exposure_s: float | None = None
    blur_from_s: float = 0.0
    blur_floor_px: float = 0.003

    def __post_init__(self) -> None:
        if not self.window_s > 0:
            raise ValueError(f"window_s must be > 0, got {self.window_s}")
        if not self.margin > 1:
            raise ValueError(f"margin must be > 1, got {self.margin}")
        if not self.floor_px >= 0:
            raise ValueError(f"floor_px must be >= 0, got {self.floor_px}")
        if self.action not in ACTIONS:
            raise ValueError(f"action must be one of {ACTIONS}, got {self.action!r}")
        if not 0 < self.derate_factor < 1:
            raise ValueError(f"derate_factor must be within (0, 1), got {self.derate_factor}")
        if not 0 < self.min_factor < 1:
            raise ValueError(f"min_factor must be within (0, 1), got {self.min_factor}")
        if self.warmup_s is not None and not self.warmup_s >= 0:
            raise ValueError(f"warmup_s must be >= 0, got {self.warmup_s}")
        if not self.blur_margin > 1:
            raise ValueError(f"blur_margin must be > 1, got {self.blur_margin}")
        if not self.blur_floor_px >= 0:
            raise ValueError(f"blur_floor_px must be >= 0, got {self.blur_floor_px}")
        if self.exposure_s is not None and not self.exposure_s > 0:
            raise ValueError(f"exposure_s must be > 0 (or None), got {self.exposure_s}")

    def init(self) -> SupervisorState:
        z = np.zeros(2)
        return SupervisorState(np.nan, np.nan, np.nan, 0.0, 0.0, _NORMAL, 1.0, z.copy(),
                               z.copy(), np.full(2, np.nan), z.copy(), np.empty(0),
                               np.empty(0, dtype=np.int64), np.empty(0), np.empty(0),
                               np.empty(0))

    def update(self, state: SupervisorState, inp: ControlInput, u_px: np.ndarray
               ) -> tuple[SupervisorState, np.ndarray]:
        """-> (state, the command to apply) for one delivered measurement."""
        u_raw = np.asarray(u_px, dtype=np.float64)
        st = state
        if not inp.valid and st.mode == _DERATE:
            # a feedback law returns the applied command when its input is invalid, not its
            # own output: hold, and keep its last output for the next increment
            return st, st.prev_out_px.copy()
        if inp.valid:
            st = self._observe(st, inp)
            if st.mode in (_NORMAL, _DERATE) and inp.t_s >= st.judge_from_s:
                closed, opened = np.sqrt(st.ms_closed), np.sqrt(st.ms_open)
                b_closed, b_open = np.sqrt(st.ms_blur_closed), np.sqrt(st.ms_blur_open)
                if closed > self.margin * opened + self.floor_px:
                    st = self._trip(st, inp.t_s, closed, opened, False)
                elif (b_closed > self.blur_margin * b_open + self.blur_floor_px  # nan: not yet
                      and inp.t_s >= self.blur_from_s + self.window_s + (self.exposure_s or 0)):
                    st = self._trip(st, inp.t_s, b_closed, b_open, True)
        if st.mode in (_HOLD, _OPEN):
            out = st.held_px.copy()
        elif st.mode == _DERATE:
            prev = np.where(np.isnan(st.prev_raw_px), u_raw, st.prev_raw_px)
            out = st.prev_out_px + st.factor * (u_raw - prev)
        else:
            out = u_raw
        healthy = st.mode in (_NORMAL, _DERATE) and st.ms_closed <= st.ms_open
        good = out.copy() if healthy else st.good_px
        st = dataclasses.replace(st, prev_raw_px=u_raw.copy(), prev_out_px=out.copy(),
                                 good_px=good)
        return st, out

    def _observe(self, st: SupervisorState, inp: ControlInput) -> SupervisorState:
        target = np.asarray(inp.target_px, dtype=np.float64)
        closed = target - np.asarray(inp.stage_px, dtype=np.float64)
        c2 = float(np.sum(closed**2))
        o2 = float(np.sum(target**2))
        if self.exposure_s is not None and inp.t_s >= self.blur_from_s:
            noise = float(np.sum(np.minimum(np.asarray(inp.sigma_px, dtype=np.float64), 1e3)
                                 ** 2)) if inp.valid else 0.0
            st = self._window(st, inp.t_s, closed, target, noise)
        if np.isnan(st.t_s):
            warm = self.window_s if self.warmup_s is None else self.warmup_s
            return dataclasses.replace(st, t_s=inp.t_s, t0_s=inp.t_s,
                                       judge_from_s=inp.t_s + warm, ms_closed=c2, ms_open=o2)
        a = 1.0 - float(np.exp(-max(inp.t_s - st.t_s, 0.0) / self.window_s))
        st = self._blur(st, a)
        return dataclasses.replace(st, t_s=inp.t_s,
                                   ms_closed=st.ms_closed + a * (c2 - st.ms_closed),
                                   ms_open=st.ms_open + a * (o2 - st.ms_open))

    def _window(self, st: SupervisorState, t: float, closed: np.ndarray, target: np.ndarray,
                noise: float) -> SupervisorState:
        """The last ``exposure_s`` of residuals and pseudo-open-loop motion, px, and their
        predicted noise variance (both axes), px^2."""
        keep = st.win_t > t - self.exposure_s
        noise_hist = (st.win_noise[keep] if len(st.win_noise) == len(st.win_t)
                      else np.zeros(int(keep.sum())))
        return dataclasses.replace(
            st, win_t=np.append(st.win_t[keep], t),
            win_closed=np.vstack([st.win_closed[keep], closed[None]]),
            win_open=np.vstack([st.win_open[keep], target[None]]),
            win_noise=np.append(noise_hist, noise))

    def _blur(self, st: SupervisorState, a: float) -> SupervisorState:
        """The running means of the two series' variance about their mean over the window
        (both axes summed, px^2), once the window spans 0.8 of an exposure (3 samples at least)."""
        if len(st.win_t) < 3 or st.win_t[-1] - st.win_t[0] < 0.8 * self.exposure_s:
            return st
        noise = float(np.mean(st.win_noise)) if len(st.win_noise) == len(st.win_t) else 0.0
        vc = max(float(np.var(st.win_closed, axis=0).sum()) - noise, 0.0)
        vo = max(float(np.var(st.win_open, axis=0).sum()) - noise, 0.0)
        if np.isnan(st.ms_blur_closed):
            return dataclasses.replace(st, ms_blur_closed=vc, ms_blur_open=vo)
        return dataclasses.replace(st, ms_blur_closed=st.ms_blur_closed + a * (
            vc - st.ms_blur_closed), ms_blur_open=st.ms_blur_open + a * (vo - st.ms_blur_open))

    def _trip(self, st: SupervisorState, t: float, closed: float, opened: float,
              blur: bool) -> SupervisorState:
        if self.action == "derate" and st.factor * self.derate_factor >= self.min_factor:
            # restart from the last healthy command with a smaller gain and fresh statistics
            mode, factor, held = _DERATE, st.factor * self.derate_factor, st.held_px
            st = dataclasses.replace(st, prev_out_px=st.good_px.copy(), ms_closed=st.ms_open,
                                     ms_blur_closed=st.ms_blur_open,
                                     judge_from_s=t + self.window_s)
        elif self.action == "open":
            mode, factor, held = _OPEN, st.factor, np.zeros(2)
        else:
            mode, factor, held = _HOLD, st.factor, st.good_px.copy()
        return dataclasses.replace(
            st, mode=mode, factor=factor, held_px=held,
            dec_t_s=np.append(st.dec_t_s, t),
            dec_action=np.append(st.dec_action, mode).astype(np.int64),
            dec_closed_px=np.append(st.dec_closed_px, closed),
            dec_open_px=np.append(st.dec_open_px, opened),
            dec_factor=np.append(st.dec_factor, factor),
            dec_blur=np.append(st.dec_blur, blur).astype(bool))

    def decisions(self, state: SupervisorState) -> list[dict]:
        """The decisions so far: time, action, reason, the two RMS, the factor after it."""
        out = []
        blur = (state.dec_blur if len(state.dec_blur) == len(state.dec_t_s)
                else np.zeros(len(state.dec_t_s), bool))
        for t, a, c, o, f, b in zip(state.dec_t_s, state.dec_action, state.dec_closed_px,
                                    state.dec_open_px, state.dec_factor, blur, strict=True):
            what, margin, floor = (
                ("in-exposure residual RMS", self.blur_margin, self.blur_floor_px) if b
                else ("residual RMS", self.margin, self.floor_px))
            reason = (f"{what} {c:.3g} px > {margin:g} x open-loop {o:.3g} px"
                      + (f" + {floor:g} px" if floor else "")
                      + f" (as the loop measures it; running, {self.window_s:g} s"
                      + (f", over {self.exposure_s:g} s exposures" if b else "") + ")")
            out.append({"t_s": float(t), "action": _NAMES[int(a)], "reason": reason,
                        "closed_rms_px": float(c), "open_rms_px": float(o),
                        "factor": float(f)})
        return out

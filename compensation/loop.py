"""The loop that steps time: plant -> transport -> estimator -> controller -> actuator.

One small loop over tracker frames (python-control's ``input_output_response``, OOPAO's
``run_cl``): before frame k is exposed, every measurement that arrives earlier is processed
(estimate, command, the actuator moves from that instant); the actuator is advanced to the
end of the exposure, the plant exposes and measures the frame with the stage trajectory
the actuator produced, and the transport decides when the measurement arrives. Nothing here
knows a renderer or a correlator: the plant does.

Times are seconds from the scenario's t = 0; positions are tracker pixels (row, col).
The run can stop after any chunk of frames and resume from the chunk's snapshot exactly
(:class:`Chunk`: the frames' records, the trajectory samples they added, every block's state).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from compensation.actuators import TIME_EPS
from compensation.blocks import BlockMeasurements, ControlInput, MotionEstimate
from compensation.state import from_arrays, to_arrays


class Trajectory:
    """A stage trajectory from samples: 'previous' (a step at each sample) or 'linear'.

    Before the first sample the stage is at the first sample's value (0 by construction).
    Samples live in buffers that double when full, so appending is amortised O(1).
    """

    def __init__(self, interpolation: str, t0_s: float = 0.0):
        if interpolation not in ("previous", "linear"):
            raise ValueError(f"interpolation must be 'previous' or 'linear', got "
                             f"{interpolation!r}")
        self.interpolation = interpolation
        self._t = np.empty(256)
        self._s = np.empty((256, 2))
        self._t[0] = t0_s
        self._s[0] = 0.0
        self._n = 1

    def append(self, t_s: np.ndarray, s_px: np.ndarray) -> None:
        k = len(t_s)
        if not k:
            return
        need = self._n + k
        if need > len(self._t):
            cap = max(need, 2 * len(self._t))
            self._t = np.concatenate([self._t[: self._n], np.empty(cap - self._n)])
            self._s = np.concatenate([self._s[: self._n], np.empty((cap - self._n, 2))])
        self._t[self._n:need] = t_s
        self._s[self._n:need] = np.asarray(s_px, dtype=np.float64).reshape(-1, 2)
        self._n = need

    @property
    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """(times (N,), positions (N, 2)): views of the samples so far."""
        return self._t[: self._n], self._s[: self._n]

    def __call__(self, t_s) -> np.ndarray:
        """Stage position (..., 2) at times t_s (...)."""
        t, s = self.samples
        q = np.asarray(t_s, dtype=np.float64)
        if self.interpolation == "previous":
            i = np.searchsorted(t, q + TIME_EPS * np.maximum(1.0, np.abs(q)), side="right")
            return s[np.clip(i - 1, 0, len(t) - 1)]
        return np.stack([np.interp(q, t, s[:, 0]), np.interp(q, t, s[:, 1])], axis=-1)

    def mean(self, t0_s: float, t1_s: float) -> np.ndarray:
        """Exact mean (2,) over [t0, t1] of the interpolated trajectory."""
        t, _ = self.samples
        eps = TIME_EPS * max(1.0, abs(t1_s))
        if not t1_s - t0_s > eps:  # an instant (an exposure far shorter than TIME_EPS)
            at = t0_s if self.interpolation == "previous" else 0.5 * (t0_s + t1_s)
            return self(np.array([at]))[0].copy()
        lo, hi = np.searchsorted(t, [t0_s + eps, t1_s - eps], side="right")
        inside = t[lo:hi]
        inside = inside[inside > t0_s + eps]
        knots = np.concatenate([[t0_s], inside, [t1_s]])
        vals = self(knots)
        if self.interpolation == "previous":
            if len(knots) == 2:
                return vals[0].copy()  # one segment: exactly the held value
            return (vals[:-1] * np.diff(knots)[:, None]).sum(axis=0) / (t1_s - t0_s)
        return np.trapezoid(vals, knots, axis=0) / (t1_s - t0_s)


@dataclass(frozen=True)
class Timeline:
    """When frames are exposed and what the main imager follows by itself.

    frame_t_s : (T,) exposure starts; exposure_s : exposure; end_s : end of the run.
    charge_px : (T, 2) motion the main imager follows itself (TDI charge transfer) at each
        exposure's mid-time, since frame 0's; zeros for a frame imager.
    period_s : nominal time between delivered measurements (for predictors).
    """

    frame_t_s: np.ndarray
    exposure_s: float
    end_s: float
    charge_px: np.ndarray
    period_s: float

    @property
    def n_frames(self) -> int:
        return len(self.frame_t_s)

    @property
    def mid_s(self) -> np.ndarray:
        return self.frame_t_s + 0.5 * self.exposure_s


@dataclass
class LoopRecord:
    """Per-frame records of a run (arrays over T frames and B blocks)."""

    shift_px: np.ndarray  # (T, B, 2) measured shift against the reference
    sigma_px: np.ndarray  # (T, B, 2) predicted error
    valid: np.ndarray  # (T, B) valid as measured
    peak: np.ndarray  # (T, B)
    ref_frame: np.ndarray  # (T, B)
    centers_px: np.ndarray  # (T, B, 2) block centres in their reference frame
    measured: np.ndarray  # (T, B) the correlator processed the block
    delivered: np.ndarray  # (T, B) valid as the controller received it
    motion_px: np.ndarray  # (T, 2) estimated motion since frame 0 at the field point
    motion_sigma_px: np.ndarray  # (T, 2)
    motion_valid: np.ndarray  # (T,)
    used: np.ndarray  # (T, B) blocks in the fit
    outliers: np.ndarray  # (T, B) rejected as outliers
    stage_cmd_px: np.ndarray  # (T, 2) commanded stage mean over each exposure
    arrive_s: np.ndarray  # (T,) when the measurement reached the controller (nan: never)
    rereferenced: np.ndarray  # (T,) the frame became the reference

    @classmethod
    def empty(cls, n_frames: int, n_blocks: int) -> LoopRecord:
        t, b = n_frames, n_blocks
        return cls(np.full((t, b, 2), np.nan), np.full((t, b, 2), np.inf), np.zeros((t, b), bool),
                   np.zeros((t, b)), np.zeros((t, b), int), np.zeros((t, b, 2)),
                   np.zeros((t, b), bool), np.zeros((t, b), bool), np.zeros((t, 2)),
                   np.full((t, 2), np.inf), np.zeros(t, bool), np.zeros((t, b), bool),
                   np.zeros((t, b), bool), np.zeros((t, 2)), np.full(t, np.nan),
                   np.zeros(t, bool))

    def fields(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


@dataclass(frozen=True)
class Chunk:
    """What frames [start, stop) added to a run, and every state at ``stop``: enough to
    resume exactly. ``arrays`` holds record slices (``rec/...``), trajectory samples
    (``traj/t``, ``traj/s``, ``cmd/t``, ``cmd/s``), block states, the pending deliveries and
    the plant's own arrays (``plant/...``)."""

    start: int
    stop: int
    arrays: dict[str, np.ndarray]


@dataclass
class LoopResult:
    """A finished (or partial) run: records, the stage trajectory, the commands."""

    record: LoopRecord
    trajectory: Trajectory
    commanded: Trajectory
    done: int
    saturated_s: float = 0.0
    states: dict[str, Any] = field(default_factory=dict)
    transport_stats: dict[str, int] = field(default_factory=dict)
    supervisor: list[dict] = field(default_factory=list)  # its decisions (none: no block)


def simulate(plant, estimator, controller, actuator, transport, timeline: Timeline,
             enabled: bool = True, resume: list[Chunk] | None = None,
             on_chunk: Callable[[Chunk], None] | None = None, chunk_frames: int = 10,
             progress: Callable[[int, int], None] | None = None,
             supervisor=None) -> LoopResult:
    """Run (or continue) the loop over every frame of ``timeline``.

    ``resume``: the chunks of an interrupted run (in order); the run continues after the
    last one. ``on_chunk`` receives a :class:`Chunk` every ``chunk_frames`` frames and at the
    end. ``enabled`` False: open loop (measured and estimated, the stage never moves).
    ``supervisor``: an optional block (:class:`compensation.blocks.Supervisor`) that sees each
    measurement and the controller's command and may replace it; its decisions come back in
    ``LoopResult.supervisor``. None: no supervisor (the loop as it was, bit for bit).
    """
    n, nb = timeline.n_frames, plant.n_blocks
    rec = LoopRecord.empty(n, nb)
    model = actuator.command_model()
    traj = Trajectory(actuator.interpolation, 0.0)
    cmd = Trajectory(model.interpolation, 0.0)
    est_state = estimator.init(nb)
    ctl_state = controller.init()
    act_state = actuator.init(0.0)
    mod_state = model.init(0.0)
    tr_state = transport.init()
    sup_state = supervisor.init() if supervisor is not None else None
    pending: list[tuple[float, BlockMeasurements]] = []
    last_cmd = np.zeros(2)
    start = 0
    if resume:
        start, est_state, ctl_state, act_state, mod_state, tr_state, pending, last_cmd = \
            _restore(resume, rec, traj, cmd, plant, estimator, controller, actuator, model,
                     transport)
        if supervisor is not None:
            sup_state = from_arrays("state/supervisor", type(sup_state), resume[-1].arrays)
    chunk_start = start
    marks = {"traj": len(traj.samples[0]), "cmd": len(cmd.samples[0])}

    def advance(t_s: float) -> None:
        nonlocal act_state, mod_state
        act_state, t, s = actuator.advance(act_state, t_s)
        traj.append(t, s)
        mod_state, t, s = model.advance(mod_state, t_s)
        cmd.append(t, s)

    def deliver(t_a: float, meas: BlockMeasurements) -> None:
        nonlocal est_state, ctl_state, act_state, mod_state, last_cmd, sup_state
        k = meas.frame
        ref = meas.ref_frame
        ref_stage = rec.stage_cmd_px[np.clip(ref, 0, n - 1)]
        est_state, est = estimator.update(est_state, meas, rec.stage_cmd_px[k], ref_stage)
        _record_estimate(rec, est, t_a, meas)
        if not enabled:
            return
        advance(t_a)
        inp = ControlInput(t_a, float(timeline.mid_s[k]), est.motion_px - timeline.charge_px[k],
                           rec.stage_cmd_px[k], last_cmd, est.sigma_px, est.valid,
                           timeline.period_s)
        ctl_state, u_raw = controller.update(ctl_state, inp)
        u_raw = np.asarray(u_raw, dtype=np.float64)
        if supervisor is not None:
            sup_state, u_raw = supervisor.update(sup_state, inp, u_raw)
            u_raw = np.asarray(u_raw, dtype=np.float64)
        u = actuator.clip(u_raw)  # what the stage can do: what the loop assumes it did
        if not np.array_equal(u, last_cmd) or not np.array_equal(u, u_raw):
            act_state = actuator.command(act_state, t_a, u_raw)  # it clips and counts
            mod_state = model.command(mod_state, t_a, u)
            last_cmd = u

    def deliver_until(t_s: float) -> None:
        """Deliver every pending measurement that arrives before t_s, in time order."""
        pending.sort(key=lambda p: p[0])
        while pending and pending[0][0] < t_s - TIME_EPS * max(1.0, t_s):
            deliver(*pending.pop(0))

    def finish() -> None:
        deliver_until(timeline.end_s)
        advance(timeline.end_s)

    for k in range(start, n):
        t0 = float(timeline.frame_t_s[k])
        t1 = t0 + timeline.exposure_s
        deliver_until(t1)
        advance(t1)
        rec.stage_cmd_px[k] = cmd.mean(t0, t1)
        blocks = transport.blocks(k, nb)
        meas = plant.measure(k, traj, blocks)
        _record_measurement(rec, meas, blocks)
        est_state, reref = estimator.rereference(est_state, meas)
        if reref:
            plant.rereference(k)
            rec.rereferenced[k] = True
        if blocks.any():
            tr_state, t_a, delivered = transport.send(tr_state, meas, t1)
            if t_a is not None:
                pending.append((t_a, delivered))
        if k > 0 and not rec.motion_valid[k] and np.isnan(rec.arrive_s[k]):
            rec.motion_px[k] = rec.motion_px[k - 1]
        if progress is not None:
            progress(k + 1, n)
        last = k == n - 1
        if on_chunk is not None and (k + 1 - chunk_start >= chunk_frames or last):
            if last:
                finish()  # the last chunk holds the run's end
            on_chunk(_make_chunk(chunk_start, k + 1, rec, traj, cmd, marks, plant, pending,
                                 est_state, ctl_state, act_state, mod_state, tr_state,
                                 last_cmd, sup_state))
            chunk_start = k + 1
    if on_chunk is None or start >= n:
        finish()
    states = {"estimator": est_state, "controller": ctl_state, "actuator": act_state}
    decisions: list[dict] = []
    if supervisor is not None:
        states["supervisor"] = sup_state
        decisions = supervisor.decisions(sup_state)
    return LoopResult(rec, traj, cmd, n, actuator.saturated_s(act_state), states,
                      dataclasses.asdict(tr_state), decisions)


def _record_measurement(rec: LoopRecord, meas: BlockMeasurements, blocks: np.ndarray) -> None:
    k = meas.frame
    rec.shift_px[k] = meas.shift_px
    rec.sigma_px[k] = meas.sigma_px
    rec.valid[k] = meas.valid
    rec.peak[k] = meas.peak
    rec.ref_frame[k] = meas.ref_frame
    rec.centers_px[k] = meas.centers_px
    rec.measured[k] = blocks


def _record_estimate(rec: LoopRecord, est: MotionEstimate, t_a: float,
                     meas: BlockMeasurements) -> None:
    k = est.frame
    rec.motion_px[k] = est.motion_px
    rec.motion_sigma_px[k] = est.sigma_px
    rec.motion_valid[k] = est.valid
    rec.used[k] = est.used
    rec.outliers[k] = est.outliers
    rec.arrive_s[k] = t_a
    rec.delivered[k] = meas.valid


def _make_chunk(a, b, rec, traj, cmd, marks, plant, pending, est_state, ctl_state, act_state,
                mod_state, tr_state, last_cmd, sup_state=None) -> Chunk:
    arrays: dict[str, np.ndarray] = {}
    for name, arr in rec.fields().items():
        arrays[f"rec/{name}"] = arr[a:b].copy()
    # estimates of earlier frames can arrive later: keep the whole (small) estimate arrays
    for name in ("motion_px", "motion_sigma_px", "motion_valid", "used", "outliers",
                 "arrive_s", "delivered"):
        arrays[f"late/{name}"] = getattr(rec, name)[:b].copy()
    for key, tr in (("traj", traj), ("cmd", cmd)):
        t, s = tr.samples
        arrays[f"{key}/t"] = t[marks[key]:].copy()
        arrays[f"{key}/s"] = s[marks[key]:].copy()
        marks[key] = len(t)
    arrays.update(to_arrays("state/estimator", est_state))
    arrays.update(to_arrays("state/controller", ctl_state))
    arrays.update(to_arrays("state/actuator", act_state))
    arrays.update(to_arrays("state/model", mod_state))
    arrays.update(to_arrays("state/transport", tr_state))
    if sup_state is not None:
        arrays.update(to_arrays("state/supervisor", sup_state))
    arrays["state/last_cmd"] = np.asarray(last_cmd).copy()
    arrays["pending/t"] = np.array([p[0] for p in pending])
    for i, (_, m) in enumerate(pending):
        arrays.update(to_arrays(f"pending/{i}", m))
    for name, arr in plant.chunk_arrays(a, b).items():
        arrays[f"plant/{name}"] = arr
    return Chunk(a, b, arrays)


def _restore(chunks, rec, traj, cmd, plant, estimator, controller, actuator, model,
             transport):
    """Fill the record and trajectories from chunks; return the states at the last one."""
    for c in chunks:
        for name in rec.fields():
            getattr(rec, name)[c.start:c.stop] = c.arrays[f"rec/{name}"]
        traj.append(c.arrays["traj/t"], c.arrays["traj/s"])
        cmd.append(c.arrays["cmd/t"], c.arrays["cmd/s"])
    last = chunks[-1].arrays
    for name in ("motion_px", "motion_sigma_px", "motion_valid", "used", "outliers",
                 "arrive_s", "delivered"):
        v = last[f"late/{name}"]
        getattr(rec, name)[: len(v)] = v
    est = from_arrays("state/estimator", type(estimator.init(plant.n_blocks)), last)
    ctl = from_arrays("state/controller", type(controller.init()), last)
    act = from_arrays("state/actuator", type(actuator.init(0.0)), last)
    mod = from_arrays("state/model", type(model.init(0.0)), last)
    trs = from_arrays("state/transport", type(transport.init()), last)
    pending = [(float(t), from_arrays(f"pending/{i}", BlockMeasurements, last))
               for i, t in enumerate(last["pending/t"])]
    plant.restore([{k[len("plant/"):]: v for k, v in c.arrays.items()
                    if k.startswith("plant/")} for c in chunks])
    return (chunks[-1].stop, est, ctl, act, mod, trs, pending,
            np.asarray(last["state/last_cmd"], dtype=np.float64))

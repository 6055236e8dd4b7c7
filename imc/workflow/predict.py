"""Fast predictions of a candidate design's metrics (milliseconds per candidate), from the
models imcsim already has; what `imc design` searches with.

- The loop (:class:`compensation.analytic.LoopModel`, built here as
  :func:`imc.wiring.build.build_loop` builds it): the sinusoids' residual is the linear loop
  run from the first frame (:func:`sinusoid_residual`: the commands through the loop's
  transfer, the stage's held-command response summed: acquisition and the ripple between
  commands included, which |S(f)| alone, the fundamental, misses); a random (PSD) term's
  variance is
  the integral of PSD |S|^2; the tracker's white error of sigma per frame gives the loop's
  noise RMS (:meth:`LoopModel.noise_rms_px`, linear in sigma). A Kalman predictor with a
  stated ``bandwidth_hz`` has a noise-independent gain (its process noise scales with
  sigma^2), so one loop model serves every block size and count.
- The tracker: the Cramer-Rao bound of the base scene's texture at the tracker's SNR
  (:func:`imc.wiring.rendered_plant.predicted_sigma_px`, once per design), scaled by
  block_px0 / block_px (the bound goes as one over the block's side), divided by
  sqrt(n_blocks) (the motion-field fit averages the blocks), times the correlator's
  efficiency (measured error / bound; 1 by construction for the analytic plant, which
  draws its noise at the bound).
- Motion MTF at Nyquist per exposure (:func:`compensation.metrics.motion_mtf`): the
  sinusoids' residual over each main-imager exposure from ``start_s`` on, times the
  Gaussian factor exp(-pi^2 sigma^2 / 2) of the random and noise residual (its whole
  variance counted within one exposure: conservative).
- Lock time: :func:`compensation.lock.analytic_lock_time` of the same model.
- Geometry after ground correction by the record: the record's network
  (:meth:`ground.network.Links.baselines` on a synthetic series of the product's tracker
  frames, :func:`ground.network.solve_network`) and its covariance through
  :func:`ground.network.geometry_rms` (after a constant and after an affine).

Not predicted (refused in a design's requirements): NIIRS loss (needs the product's
rendered edge response), yaw jitter (a rotation about the line of sight), measured jitter
series and suspensions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from compensation.analytic import LoopModel
from compensation.metrics import motion_mtf
from imc.scenario import Scenario, ScenarioError

#: axis index of a body axis's image motion (pitch: rows, roll: columns)
AXIS = {"pitch": 0, "roll": 1}
#: Nyquist, cycles/px
NYQUIST = 0.5
#: the requirement paths a design may bound, and what predicts each
SUPPORTED: dict[str, str] = {
    "with_compensation.rms_total_px": "loop: jitter through |S(f)| + tracker noise gain",
    "with_compensation.rms_px": "loop, per axis (row, col)",
    "with_compensation.rms_px.0": "loop, row",
    "with_compensation.rms_px.1": "loop, col",
    "with_compensation.mtf_nyquist_worst": "worst exposure's motion MTF at Nyquist (row, col)",
    "with_compensation.mtf_nyquist_worst.0": "worst exposure's motion MTF at Nyquist, row",
    "with_compensation.mtf_nyquist_worst.1": "worst exposure's motion MTF at Nyquist, col",
    "loop.lock.analytic_s": "the loop's analytic lock time",
    "product.geometry.open.after.rms_px": "record network covariance, after a constant",
    "product.geometry.open.affine.rms_px": "record network covariance, after an affine",
}
@dataclass(frozen=True, eq=False)
class Disturbance:
    """The base scenario's jitter as the predictor sees it (image px, per axis).

    sin_axis, sin_f_hz, sin_a_px, sin_phase_rad : the sinusoids (wheel harmonics included,
        phase 0: their phases are random in a run). rnd_f_hz (F,), rnd_psd_px2_hz (F, 2) :
        the random terms' one-sided PSD on a shared frequency grid.
    """

    sin_axis: np.ndarray
    sin_f_hz: np.ndarray
    sin_a_px: np.ndarray
    sin_phase_rad: np.ndarray
    rnd_f_hz: np.ndarray
    rnd_psd_px2_hz: np.ndarray

    @classmethod
    def from_scenario(cls, sc: Scenario) -> Disturbance:
        """The jitter of ``sc`` (a ScenarioError for what has no predictor)."""
        jit = sc.attitude.jitter
        if jit.series is not None or sc.attitude.suspension is not None:
            raise ScenarioError("base.attitude: a measured jitter series or a suspension has "
                                "no predictor; give the jitter as sinusoids, random and wheels")
        ifov_urad = sc.camera.pixel_pitch_m / sc.camera.focal_length_m * 1e6

        def px(v_px, v_urad):
            return float(v_px) if v_px is not None else float(v_urad) / ifov_urad

        ax, fs, amps, ph = [], [], [], []
        for s in jit.sinusoids:
            if s.axis in AXIS:
                ax.append(AXIS[s.axis])
                fs.append(s.frequency_hz)
                amps.append(px(s.amplitude_px, s.amplitude_urad))
                ph.append(np.radians(s.phase_deg))
        for w in jit.wheels:
            if w.axis in AXIS:
                for h in w.harmonics:
                    ax.append(AXIS[w.axis])
                    fs.append(w.speed_hz * h.number)
                    amps.append(px(h.amplitude_px, h.amplitude_urad))
                    ph.append(0.0)
        f = np.geomspace(1e-3, 1e3, 1)
        psd = np.zeros((1, 2))
        if jit.random:
            lo = min(r.f_min_hz for r in jit.random)
            hi = max(r.f_max_hz for r in jit.random)
            f = np.geomspace(lo, hi, 400)
            psd = np.zeros((len(f), 2))
            for r in jit.random:
                if r.axis not in AXIS:
                    continue
                band = (f >= r.f_min_hz) & (f <= r.f_max_hz)
                shape = np.where(band, f**r.slope, 0.0)
                rms = px(r.rms_px, r.rms_urad)
                psd[:, AXIS[r.axis]] += rms**2 * shape / np.trapezoid(shape, f)
        return cls(np.array(ax, int), np.array(fs, float), np.array(amps, float),
                   np.array(ph, float), f, psd)

    def open_peak_px(self, duration_s: float, t_ref_s: float = 0.0) -> np.ndarray:
        """The open-loop motion's largest excursion from its value at ``t_ref_s`` (frame 0,
        the stage's zero) over the run, per axis, plus 3 sigma of the random terms (px): what
        half of a stage's stroke must hold."""
        t = np.linspace(0.0, duration_s, 20001)
        r = np.zeros((len(t), 2))
        for a, f, p, k in zip(self.sin_a_px, self.sin_f_hz, self.sin_phase_rad,
                              self.sin_axis, strict=True):
            r[:, k] += a * (np.sin(2 * np.pi * f * t + p) - np.sin(2 * np.pi * f * t_ref_s + p))
        rnd = np.sqrt(np.trapezoid(self.rnd_psd_px2_hz, self.rnd_f_hz, axis=0))
        return np.abs(r).max(axis=0) + 3.0 * np.sqrt(2.0) * rnd


@dataclass(frozen=True)
class LoopChoice:
    """The loop part of a candidate: tracker rate, controller, stage.

    rate_hz : tracker frame rate, Hz; controller : 'integrator' or 'kalman';
    bandwidth_hz : the Kalman predictor's bandwidth, or the integrator's (gain = 2 pi bw T);
    stage : 'none', 'ideal' or 'piezo'; resonance_hz : the piezo's first mode, Hz.
    """

    rate_hz: float
    controller: str
    bandwidth_hz: float
    stage: str
    resonance_hz: float = 0.0


@dataclass(frozen=True)
class LoopPrediction:
    """What one loop does to the base's jitter: ``ok`` (stable with the base's margins, or
    why not), the deterministic residual RMS per axis, the random terms' residual variance
    per axis, the noise RMS per px of tracker sigma, the sinusoids' worst-exposure motion
    MTF per axis, and the analytic lock time (s)."""

    ok: bool
    why: str
    rms_det_px: tuple[float, float]
    var_rnd_px2: tuple[float, float]
    noise_gain: float
    mtf_det_worst: tuple[float, float]
    lock_s: float


def controller_block(choice: LoopChoice, base: Scenario) -> dict:
    """The scenario's compensation.controller mapping for a loop choice."""
    if choice.controller == "kalman":
        order = base.compensation.controller.params().get("order", 2) \
            if base.compensation.controller.kind == "kalman" else 2
        return {"kind": "kalman", "order": int(order), "bandwidth_hz": float(choice.bandwidth_hz),
                "identify": False}
    gain = min(1.0, 2.0 * np.pi * choice.bandwidth_hz / choice.rate_hz)
    return {"kind": "integrator", "gain": float(round(gain, 6))}


def actuator_block(choice: LoopChoice, base: Scenario, stroke_px: float | None) -> dict:
    """The scenario's compensation.actuator mapping (the base's ideal-stage options kept)."""
    if choice.stage == "piezo":
        return {"kind": "piezo", "resonance_hz": float(choice.resonance_hz),
                "stroke_px": None if stroke_px is None else float(stroke_px)}
    params = base.compensation.actuator.params() if base.compensation.actuator.kind == "ideal" \
        else {}
    return {"kind": "ideal", **params}


def tracker_exposure_s(base: Scenario, rate_hz: float) -> float:
    """The tracker's exposure at a rate: the base's if it fits the period, else the period."""
    e = base.camera.tracker.exposure_s
    return 1.0 / rate_hz if e is None or e > 1.0 / rate_hz else e


@dataclass(frozen=True)
class FastLoopModel(LoopModel):
    """A LoopModel whose controller transfer function is computed once (a Kalman
    predictor's steady state is a Riccati solve; the search asks for it many times)."""

    @cached_property
    def _controller_tf(self) -> tuple[np.ndarray, np.ndarray, bool]:
        return LoopModel.controller_tf(self)

    def controller_tf(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """(b, a, is_predictor) in z^-1, cached."""
        return self._controller_tf


def loop_model(choice: LoopChoice, base: Scenario):
    """The analytic LoopModel of a choice (None for stage 'none'), wired as
    :func:`imc.wiring.build.build_loop` wires it."""
    from compensation.registry import make_block
    from imc.wiring.build import piezo_update_hz

    if choice.stage == "none":
        return None
    period = 1.0 / choice.rate_hz
    wired = {"field_point_px": (0.0, 0.0), "ramp_s": period, "rate_hz": choice.rate_hz}
    act = actuator_block(choice, base, 1e3)  # linearised: the stroke is checked apart
    actuator = make_block("actuator", act.pop("kind"), act, wired)
    if getattr(actuator, "update_hz", 0.0) is None:
        actuator = dataclasses.replace(actuator, update_hz=piezo_update_hz(
            choice.rate_hz, actuator.resonance_hz, actuator.drive_top_hz))
    ctl = controller_block(choice, base)
    kind = ctl.pop("kind")
    if kind == "kalman":
        ctl["lead_s"] = actuator.lag_s
    controller = make_block("controller", kind, ctl, wired)
    tr = base.compensation.transport
    latency = tr.latency_s + tr.latency_frames / choice.rate_hz
    return FastLoopModel(choice.rate_hz, tracker_exposure_s(base, choice.rate_hz), latency,
                     controller, actuator, 0.02)


def exposure_windows(base: Scenario) -> tuple[float, float, float]:
    """(start_s, end_s, window_s) of the main imager's exposures the metrics judge."""
    mi = base.camera.main_imager
    window = mi.exposure_s
    if mi.kind == "tdi":
        line = mi.line_rate_hz or nominal_line_rate_hz(base)
        window = mi.stages / line
    return mi.start_s, base.duration_s, window


def nominal_line_rate_hz(base: Scenario) -> float:
    """A TDI imager's synchronous line rate at nadir (ground speed / GSD), Hz."""
    gm, r_e = 3.986004418e14, 6.371e6
    h = base.orbit.altitude_m
    v_ground = np.sqrt(gm / (r_e + h)) * r_e / (r_e + h)
    gsd = h * base.camera.pixel_pitch_m / base.camera.focal_length_m
    return float(v_ground / gsd)


def predict_loop(choice: LoopChoice, base: Scenario, dist: Disturbance,
                 samples_per_window: int = 32, lock: bool = True) -> LoopPrediction:
    """The loop's part of the predictions (see the module docstring); ``lock``: the lock
    time too (an eigenvalue problem of the plant's order: skipped when not asked for)."""
    from compensation.lock import analytic_lock_time

    model = loop_model(choice, base)
    start, end, window = exposure_windows(base)
    n_win = max(1, int(np.floor((end - start) / window + 1e-9)))
    t = start + (np.arange(n_win * samples_per_window) + 0.5) * window / samples_per_window
    if model is None:
        s_rnd = np.ones(len(dist.rnd_f_hz))
        ok, why, noise, lock_s = True, "", 0.0, 0.0
    else:
        mg = model.margins(n_points=501)
        comp = base.compensation
        ok = bool(mg.stable and mg.phase_margin_deg >= comp.min_phase_margin_deg
                  and mg.modulus_margin >= comp.min_modulus_margin
                  and mg.peak_rejection * comp.min_modulus_margin <= 1.0)
        why = "" if ok else (f"loop refused (stable {mg.stable}, phase margin "
                             f"{mg.phase_margin_deg:.0f} deg, peak |S| {mg.peak_rejection:.2f})")
        if not ok:
            nan2 = (np.nan, np.nan)
            return LoopPrediction(False, why, nan2, nan2, np.nan, nan2, np.inf)
        s_rnd = np.abs(model.rejection(dist.rnd_f_hz)) ** 2
        noise = model.noise_rms_px(1.0, f_max_factor=4.0, n_points=1024)
        lock_s = (float(analytic_lock_time(model, band=0.05, max_s=60.0).lock_s) if lock
                  else np.nan)
    r = sinusoid_residual(model, dist, end, t, tracker_exposure_s(base, choice.rate_hz))
    rms = np.mean(r**2, axis=0)
    # each exposure about its own mean is what blurs; the metric's phase is relative to 0
    win = r.reshape(n_win, samples_per_window, 2)
    mtf = np.stack([motion_mtf(win, NYQUIST, 0), motion_mtf(win, NYQUIST, 1)], -1).min(0)
    var_rnd = (np.trapezoid(dist.rnd_psd_px2_hz * s_rnd[:, None], dist.rnd_f_hz, axis=0)
               if len(dist.rnd_f_hz) > 1 else np.zeros(2))
    return LoopPrediction(ok, why, tuple(np.sqrt(rms)), tuple(var_rnd), float(noise),
                          tuple(mtf), lock_s)


def _exposure_means(dist: Disturbance, t0_s: np.ndarray, exposure_s: float) -> np.ndarray:
    """The sinusoids' mean over [t0, t0 + exposure] (N, 2) px: what the tracker measures."""
    w = 2 * np.pi * dist.sin_f_hz
    wt = 1j * w * exposure_s
    avg = np.where(np.abs(wt) > 1e-12, (np.exp(wt) - 1.0) / np.where(wt == 0, 1, wt), 1.0)
    rot = np.exp(1j * (w[None, :] * t0_s[:, None] + dist.sin_phase_rad[None, :]))
    out = np.zeros((len(t0_s), 2))
    for i, k in enumerate(dist.sin_axis):
        out[:, k] += (dist.sin_a_px[i] * avg[i] * rot[:, i]).imag
    return out


def sinusoid_residual(model, dist: Disturbance, duration_s: float, t_s: np.ndarray,
                      exposure_s: float) -> np.ndarray:
    """The residual (T, 2) px of the sinusoids at times t_s, the loop run linearly from the
    first frame: each frame's exposure mean against frame 0's (the tracker's reference)
    through the command transfer C z^-n / (1 + C G) (:meth:`LoopModel.plant_polys`), the
    stage's response to the held commands (:attr:`LoopModel.pulse`, its trajectory) summed,
    and the continuous motion minus the stage. Exact for the linear loop: acquisition,
    the stage's staircase or ramp between commands and its dynamics included. ``model``
    None: the open loop (the motion against frame 0)."""
    from scipy.signal import lfilter

    from compensation.controllers import polymul

    d_t = np.zeros((len(t_s), 2))
    for a, f, p, k in zip(dist.sin_a_px, dist.sin_f_hz, dist.sin_phase_rad, dist.sin_axis,
                          strict=True):
        d_t[:, k] += a * np.sin(2 * np.pi * f * t_s + p)
    d0 = _exposure_means(dist, np.zeros(1), exposure_s)[0]
    if model is None:
        return d_t - d0
    period = model.period_s
    n = int(np.ceil(duration_s / period)) + 1
    d_k = _exposure_means(dist, np.arange(n) * period, exposure_s) - d0
    b, a, predictor = model.controller_tf()
    g, g_pq = model.plant_polys()
    n_del, _ = model.timing
    num = np.concatenate([np.zeros(n_del), b])
    lp = polymul(b, g_pq if predictor else g)
    den = np.zeros(max(len(a), len(lp)))
    den[: len(a)] += a
    den[: len(lp)] += lp
    u = lfilter(num, den, d_k, axis=0)  # the command at each tick
    _, _, th, sh, interp = model.pulse
    lag = t_s[:, None] - np.arange(n)[None, :] * period
    if interp == "previous":
        idx = np.searchsorted(th, lag, side="right") - 1
        h = np.where((idx >= 0) & (lag <= th[-1]), sh[np.clip(idx, 0, len(sh) - 1)], 0.0)
    else:
        h = np.interp(lag, th, sh, left=0.0, right=0.0)
    return d_t - d0 - h @ u


@lru_cache(maxsize=64)
def record_geometry_unit(rate_hz: float, duration_s: float, baselines: int = 1,
                         max_frames: int = 1500) -> tuple[float, float]:
    """(after a constant, after an affine) geometry RMS (px, per axis alike) of the record of
    a tracker at ``rate_hz`` over ``duration_s`` with 1 px of error per link (``baselines``
    0: a fixed reference, each frame's error independent): the network
    (:meth:`ground.network.Links.baselines`, :func:`ground.network.solve_network`) and its
    covariance through :func:`ground.network.geometry_rms`. Scales linearly with the link
    error. Frames beyond ``max_frames`` are decimated (the rate is kept per link)."""
    from ground.network import Links, geometry_rms, solve_network

    n = int(np.clip(round(rate_hz * duration_s), 4, max_frames))
    if baselines <= 0:  # every frame against one reference: independent errors
        return float(np.sqrt(1.0 - 1.0 / n)), float(np.sqrt(1.0 - 2.0 / n))
    k = int(min(baselines, n - 1))
    links = Links.baselines(np.zeros((n, 2)), k, 1.0)
    sol = solve_network(links, n)
    t = np.arange(n) / rate_hz
    g = geometry_rms(np.zeros((n, 2)), t, cov_px2=sol.cov_px2)
    return float(g["predicted_constant"][0]), float(g["predicted_affine"][0])


def _predict_group(args) -> list[tuple[int, LoopPrediction]]:
    group, base, dist, lock = args
    return [(i, predict_loop(ch, base, dist, lock=lock)) for i, ch in group]


def predict_loops(choices: list[LoopChoice], base: Scenario, dist: Disturbance,
                  lock: bool = True, workers: int = 1,
                  progress=None) -> list[LoopPrediction]:
    """:func:`predict_loop` for every choice; grouped by (rate, stage, resonance) so the
    stage's response is computed once per group, on ``workers`` processes (fork)."""
    groups: dict[tuple, list[tuple[int, LoopChoice]]] = {}
    for i, ch in enumerate(choices):
        groups.setdefault((ch.rate_hz, ch.stage, ch.resonance_hz), []).append((i, ch))
    jobs = [(g, base, dist, lock) for g in groups.values()]
    out: list[LoopPrediction | None] = [None] * len(choices)
    done = 0
    if workers > 1 and len(jobs) > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as ex:
            futs = [ex.submit(_predict_group, j) for j in jobs]
            for f in as_completed(futs):
                for i, p in f.result():
                    out[i] = p
                    done += 1
                if progress is not None:
                    progress(done, len(choices))
    else:
        for j in jobs:
            for i, p in _predict_group(j):
                out[i] = p
                done += 1
            if progress is not None:
                progress(done, len(choices))
    return out  # type: ignore[return-value]

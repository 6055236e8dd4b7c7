"""Fast predictions of a candidate design's metrics (milliseconds per candidate), from the
models imcsim already has; what `imc design` searches with, and what
:func:`predict_scenario` predicts a whole scenario with (its own loop as a run wires it,
and a Kalman predictor that identifies lines following the jitter's findable sinusoids from
its first identification on: :func:`identified_prediction`).

- The loop (:class:`compensation.analytic.LoopModel`, built here as
  :func:`imc.wiring.build.build_loop` builds it): the sinusoids' residual is the linear loop
  run from the first frame (:func:`sinusoid_residual`: the commands through the loop's
  transfer, the stage's held-command response summed: acquisition and the ripple between
  commands included, which |S(f)| alone, the fundamental, misses); a random (PSD) term's
  variance is the integral of PSD |S|^2; the tracker's white error of sigma per frame goes
  through the loop's noise density (:meth:`LoopModel.noise_rms_px`'s Parseval, linear in
  sigma). A TDI line's residual counts from the line's start, as ``imc.wiring.truth``
  measures it (:func:`window_weights`). A Kalman predictor with a stated ``bandwidth_hz``
  has a noise-independent gain (its process noise scales with sigma^2), so one loop model
  serves every block size and count.
- The tracker: the Cramer-Rao bound of the base scene's texture at the tracker's SNR over
  the blocks the correlator keeps (:func:`tracker_bound`, once per design; the rendered
  plant's on a rendered frame 0), scaled by block_px0 / block_px (the bound goes as one
  over the block's side), divided by sqrt(n_blocks) (the motion-field fit averages the
  blocks), times the correlator's efficiency (:data:`CORRELATOR_EFFICIENCY`: per plant and
  scene kind against SNR and block size, calibrated by ``benchmarks/bench_design.py
  --calibrate``; 1 by construction for the analytic plant, which draws its noise at the
  bound).
- Motion MTF at Nyquist per exposure (:func:`compensation.metrics.motion_mtf`): the
  sinusoids' residual over each main-imager exposure from ``start_s`` on, times the
  Gaussian factor exp(-pi^2 var / 2) of the random and noise residual's variance about the
  exposure's mean.
- Lock time: :func:`compensation.lock.analytic_lock_time` of the same model.
- Geometry after ground correction by the record (:func:`record_prediction`): the record's
  network as the run's restitution makes it (:func:`record_links`: every baseline of the
  overlap, the links' blocks cut as the run cuts them, :class:`ChainGeometry`, sharing
  their frames' pixels, :class:`ground.network.SharedNoise`, with :data:`RECORD_OWN_FRACTION`
  of each link's error its own), solved (:func:`ground.network.solve_network`) and smoothed
  (:func:`record_geometry`), over the product's lines (after a constant and after an
  affine, :func:`ground.network.geometry_rms`), plus the perfect record's floor
  (:func:`record_floor_px`); the design search (:func:`search_record_geometry`) the same
  network unsmoothed over the product's span.
- NIIRS loss (:class:`NiirsInputs`): GIQE 5 (:func:`ground.quality.niirs_giqe5`) of the RER
  of the static system MTF and of it times the worst exposure's motion MTF.

The search (:class:`LoopJobs`) groups the loops by rate and stage: what a group shares is
computed once (:class:`StageShare`: the actuator, the stage's response on each frequency
grid, in closed form on its uniform time grid by
:func:`compensation.analytic.linear_fourier`), the plant's
polynomials there, the stage's response to the held commands at the metrics' times), a
Kalman predictor's steady state once per rate and bandwidth (:class:`SharedSteadyKalman`),
and each loop then costs its controller's polynomials on those grids. The predictions are
those of :class:`compensation.analytic.LoopModel` alone (``fast=False``, the reference) to
~1e-13 (tests/test_design.py).

Not predicted (refused in a design's requirements): yaw jitter (a rotation about the line
of sight), measured jitter series and suspensions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from compensation.analytic import LoopModel
from compensation.controllers import KalmanPredictor
from compensation.metrics import motion_mtf
from imc.scenario import Scenario, ScenarioError

#: axis index of a body axis's image motion (pitch: rows, roll: columns)
AXIS = {"pitch": 0, "roll": 1}
#: Nyquist, cycles/px
NYQUIST = 0.5
#: the frequencies (cycles/px) over which the NIIRS predictor integrates the edge response
#: (past the IKONOS-like optics' cutoff, 1.24 cycles/px; the detector's sinc beyond 4
#: cycles/px moves the RER by < 0.01, alike with and without motion)
NIIRS_FREQS = np.linspace(0.0, 4.0, 257)
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
    "product.quality.closed.niirs_loss": "GIQE 5 (pyBSM) of the RER of the static system MTF "
    "times the worst exposure's motion MTF (a candidate without a stage: the open product)",
}
#: the NIIRS loss requirement's path (a candidate without a stage is measured on
#: ``product.quality.open.niirs_loss``: it has no closed product)
NIIRS_PATH = "product.quality.closed.niirs_loss"

@dataclass(frozen=True)
class Efficiency:
    """The correlator's efficiency on a plant and scene kind: the loop's noise residual over
    what the predictor gives at efficiency 1 (noise gain x the bound over the kept blocks),
    dimensionless, as ``factor`` at a tracker SNR of 20 and blocks of ``block_px`` (48) px,
    plus ``slope`` per decade of SNR (the SNR held to the calibrated 10-40), times
    ``(block / block_px) ** block_exponent`` (the block size held to the calibrated
    32-96 px), the residuals' standard deviation ``spread`` about that line, and where the
    figures come from."""

    factor: float
    slope: float
    spread: float
    source: str
    block_exponent: float = 0.0
    block_px: int = 48

    def at(self, snr: float, block_px=None):
        """The factor at a tracker SNR (mean signal over noise sigma) and block size (px,
        scalar or array; None: ``block_px``), dimensionless (an array for an array of
        sizes)."""
        s = float(np.clip(snr, 10.0, 40.0)) if np.isfinite(snr) else 20.0
        base = max(0.1, self.factor + self.slope * np.log10(s / 20.0))
        if block_px is None or self.block_exponent == 0.0:
            return base if block_px is None or np.ndim(block_px) == 0 \
                else np.full(np.shape(block_px), base)
        b = np.clip(np.asarray(block_px, float), 32.0, 96.0)
        out = base * (b / self.block_px) ** self.block_exponent
        return float(out) if np.ndim(out) == 0 else out


_TEXTURE = "texture plant, benchmarks/bench_design.py --calibrate texture"
_RENDERED = "rendered plant, benchmarks/bench_design.py --calibrate rendered"
_BLOCKS = (" --classes procedural --snrs 20 --blocks 32 48 64 96 --tracker-px 256 (its factor "
           "and block exponent; the SNR slope from the 128 px set)")
#: the efficiency's power law in the block's side per plant: measured on the procedural
#: kind, a 256 px tracker, blocks of 32 / 48 / 64 / 96 px, SNR 20, seeds 101 and 202 (each
#: case over its seed's 48 px case): texture -0.55 +- 0.16, rendered -0.12 +- 0.09
BLOCK_EXPONENT = {"texture": -0.55, "rendered": -0.12}
#: the correlator's efficiency per plant fidelity and scene kind ('*': every kind, for a
#: kind not calibrated), calibrated on cases outside the ones the predictions are judged
#: on: the quickstart's camera and loop on tiles of each kind (seeds 101 and 202, not the
#: bundled scenarios' scenes), no jitter. The procedural kind's factor and every kind's
#: block exponent come from a 256 px tracker (512 m tiles; blocks 32-96 px, SNR 20: 16
#: values); the SNR slopes and the other kinds' factors from a 128 px tracker with 4 x 48
#: px (300 m tiles; SNR 10, 20, 40: 12 values per kind), whose blocks sit 8 px from the
#: frame's edges (the 48 px procedural factor there: texture 0.78, rendered 1.51; on the
#: 256 px tracker, 40 px inside: 0.97 and 1.37). The analytic plant draws its noise at the
#: bound: 1.
CORRELATOR_EFFICIENCY: dict[str, dict[str, Efficiency]] = {
    "analytic": {"*": Efficiency(1.0, 0.0, 0.0, "by construction: the analytic plant draws "
                                 "its noise at the bound (plant.noise 'albedo', which "
                                 "imc design's verification uses; 'rendered' draws at the "
                                 "efficiency it measures, not modelled here)")},
    "texture": {
        "procedural": Efficiency(1.01, -0.56, 0.22, _TEXTURE + _BLOCKS, BLOCK_EXPONENT["texture"]),
        "urban": Efficiency(0.97, -0.20, 0.20, _TEXTURE, BLOCK_EXPONENT["texture"]),
        "rural": Efficiency(0.89, -0.70, 0.28, _TEXTURE, BLOCK_EXPONENT["texture"]),
        "mountain": Efficiency(1.40, -1.15, 0.18, _TEXTURE, BLOCK_EXPONENT["texture"]),
        "*": Efficiency(1.01, -0.65, 0.32, _TEXTURE + " (the 48 values of all four kinds)",
                        BLOCK_EXPONENT["texture"]),
    },
    # on the bound of a rendered frame 0 (tracker_bound); the rendered plant's error has a
    # floor the bound does not carry where the scene has 3-D structure (urban buildings'
    # parallax and shadows, mountain clouds: residual 0.025-0.05 px at SNR 40 against a
    # bound of 0.005-0.008 px), so efficiency grows with SNR and those kinds fit poorly
    # (seed 101 only: 6 values each)
    "rendered": {
        "procedural": Efficiency(1.33, 1.35, 0.16, _RENDERED + _BLOCKS, BLOCK_EXPONENT["rendered"]),
        "rural": Efficiency(1.33, 0.70, 0.42, _RENDERED, BLOCK_EXPONENT["rendered"]),
        "urban": Efficiency(4.60, 8.09, 0.52, _RENDERED, BLOCK_EXPONENT["rendered"]),
        "mountain": Efficiency(4.96, 6.15, 1.77, _RENDERED, BLOCK_EXPONENT["rendered"]),
        "*": Efficiency(2.78, 3.53, 1.99, _RENDERED + " (the 30 values of all four kinds)",
                        BLOCK_EXPONENT["rendered"]),
    },
}


def correlator_efficiency(fidelity: str, kind: str = "*") -> Efficiency:
    """The calibrated :class:`Efficiency` of a plant fidelity on a scene kind (the kinds'
    pooled one for a kind not calibrated; a ScenarioError for a plant not calibrated)."""
    try:
        table = CORRELATOR_EFFICIENCY[fidelity]
    except KeyError:
        raise ScenarioError(f"plant.fidelity {fidelity!r}: the correlator's efficiency is "
                            f"calibrated for {', '.join(CORRELATOR_EFFICIENCY)} only") from None
    return table.get(kind, table["*"])


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
    MTF per axis, the analytic lock time (s), the worst exposure's motion MTF (F, 2) at
    :data:`NIIRS_FREQS` per axis (the NIIRS predictor's; None when refused), and the noise
    gain and random terms' variance of the residual about each exposure's mean (what blurs;
    the RMS counts the residual against the reference, or a TDI line's start)."""

    ok: bool
    why: str
    rms_det_px: tuple[float, float]
    var_rnd_px2: tuple[float, float]
    noise_gain: float
    mtf_det_worst: tuple[float, float]
    lock_s: float
    mtf_det_curve: np.ndarray | None = dataclasses.field(default=None, compare=False)
    noise_gain_blur: float = np.nan
    var_rnd_blur_px2: tuple[float, float] = (np.nan, np.nan)


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


@dataclass(frozen=True, eq=False)
class PlantGrid:
    """What every loop of one stage and timing shares on one frequency grid: the grid
    ``f_hz`` (F,), x = z^-1 and x^n (the measurement's delay in ticks), the stage's response
    H / T (:meth:`LoopModel.stage_response`), the exposure's averaging W, and the plant's
    polynomials G and G_pq (:meth:`LoopModel.plant_polys`) evaluated at x."""

    f_hz: np.ndarray
    x: np.ndarray
    x_n: np.ndarray
    stage: np.ndarray
    averaging: np.ndarray
    g: np.ndarray
    g_pq: np.ndarray


class StageShare:
    """The work a group of loops with one stage, rate, exposure and latency share (only the
    controller differs): the plant on each frequency grid asked for (:class:`PlantGrid`,
    per grid and Smith flag) and the stage's response to the held commands at each sample
    time (:func:`held_response`), each computed once, on the group's first ask."""

    def __init__(self) -> None:
        self._grids: dict[tuple[bytes, bool], PlantGrid] = {}
        self._held: dict[tuple[bytes, int], np.ndarray] = {}
        self._actuators: dict[tuple, object] = {}

    def actuator(self, choice: LoopChoice, base: Scenario):
        """:func:`stage_actuator` of a choice, built once per rate, stage and resonance."""
        key = (choice.rate_hz, choice.stage, choice.resonance_hz)
        if key not in self._actuators:
            self._actuators[key] = stage_actuator(choice, base)
        return self._actuators[key]

    def grid(self, model: LoopModel, f_hz) -> PlantGrid:
        """The :class:`PlantGrid` of ``model``'s plant at frequencies ``f_hz`` (Hz)."""
        f = np.atleast_1d(np.asarray(f_hz, np.float64))
        smith = bool(getattr(model.controller, "smith", False))
        key = (f.tobytes(), smith)
        if key not in self._grids:
            from compensation.controllers import polyval

            n, phi = model.timing
            x = 1.0 / model._z(f)
            g, g_pq = model.plant_polys()
            stage = LoopModel.stage_response(model, f)
            self._grids[key] = PlantGrid(f, x, x**n, stage, LoopModel.averaging(model, f),
                                         polyval(x, g), polyval(x, g_pq))
        return self._grids[key]

    def held(self, model: LoopModel, t_s: np.ndarray, n: int) -> np.ndarray:
        """:func:`held_response` of ``model`` at ``t_s`` for ``n`` ticks, once."""
        key = (np.asarray(t_s, np.float64).tobytes(), int(n))
        if key not in self._held:
            self._held[key] = held_response(model, t_s, n)
        return self._held[key]


@dataclass(frozen=True)
class FastLoopModel(LoopModel):
    """A LoopModel whose controller transfer function and plant polynomials are computed
    once (a Kalman predictor's steady state is a Riccati solve; the search asks for them
    many times), and whose plant on a frequency grid (stage response, exposure averaging,
    plant polynomials) comes from ``share``, the :class:`StageShare` of the loops with the
    same stage and timing: the same transfer functions as :class:`LoopModel`'s, the stage's
    response integrated in closed form (:func:`compensation.analytic.linear_fourier`)."""

    share: StageShare = dataclasses.field(default_factory=StageShare, compare=False,
                                          hash=False, repr=False)

    @cached_property
    def _controller_tf(self) -> tuple[np.ndarray, np.ndarray, bool]:
        return LoopModel.controller_tf(self)

    def controller_tf(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """(b, a, is_predictor) in z^-1, cached."""
        return self._controller_tf

    @cached_property
    def _plant_polys(self) -> tuple[np.ndarray, np.ndarray]:
        return LoopModel.plant_polys(self)

    def plant_polys(self) -> tuple[np.ndarray, np.ndarray]:
        """(G, G_pq) in z^-1 (:meth:`LoopModel.plant_polys`), cached."""
        return self._plant_polys

    def _controller_at(self, grid: PlantGrid) -> tuple[np.ndarray, np.ndarray]:
        from compensation.controllers import polyval

        b, a, predictor = self.controller_tf()
        return polyval(grid.x, b) / polyval(grid.x, a), (grid.g_pq if predictor else grid.g)

    def command_tf(self, f_hz) -> np.ndarray:
        """U / D at frequencies f (:meth:`LoopModel.command_tf`)."""
        grid = self.share.grid(self, f_hz)
        c, lp = self._controller_at(grid)
        return c * grid.x_n / (1.0 + c * lp)

    def loop_tf(self, f_hz) -> np.ndarray:
        """The loop transfer L at frequencies f (:meth:`LoopModel.loop_tf`)."""
        c, lp = self._controller_at(self.share.grid(self, f_hz))
        return c * lp

    def stage_response(self, f_hz) -> np.ndarray:
        """H(w) / T (:meth:`LoopModel.stage_response`, once per frequency grid)."""
        return self.share.grid(self, f_hz).stage.copy()

    def averaging(self, f_hz) -> np.ndarray:
        """W(w) (:meth:`LoopModel.averaging`), shared."""
        return self.share.grid(self, f_hz).averaging.copy()


def stage_actuator(choice: LoopChoice, base: Scenario):
    """The actuator block of a choice (its stage, linearised: the stroke is checked apart),
    wired as :func:`imc.wiring.build.build_loop` wires it."""
    from compensation.registry import make_block
    from imc.wiring.build import piezo_update_hz

    wired = {"field_point_px": (0.0, 0.0), "ramp_s": 1.0 / choice.rate_hz,
             "rate_hz": choice.rate_hz}
    act = actuator_block(choice, base, 1e3)
    actuator = make_block("actuator", act.pop("kind"), act, wired)
    if getattr(actuator, "update_hz", 0.0) is None:
        actuator = dataclasses.replace(actuator, update_hz=piezo_update_hz(
            choice.rate_hz, actuator.resonance_hz, actuator.drive_top_hz))
    return actuator


def loop_model(choice: LoopChoice, base: Scenario, share: StageShare | None = None,
               fast: bool = True):
    """The analytic LoopModel of a choice (None for stage 'none'), wired as
    :func:`imc.wiring.build.build_loop` wires it: a :class:`FastLoopModel` with ``share``
    (the :class:`StageShare` of the choices of its rate and stage: their actuator built
    once; None: its own) and a Kalman predictor's steady state shared
    (:class:`SharedSteadyKalman`), or with ``fast`` False
    :class:`compensation.analytic.LoopModel` itself (the reference)."""
    from compensation.registry import make_block

    if choice.stage == "none":
        return None
    share = share if share is not None else StageShare()
    actuator = share.actuator(choice, base) if fast else stage_actuator(choice, base)
    wired = {"field_point_px": (0.0, 0.0), "ramp_s": 1.0 / choice.rate_hz,
             "rate_hz": choice.rate_hz}
    ctl = controller_block(choice, base)
    kind = ctl.pop("kind")
    if kind == "kalman":
        ctl["lead_s"] = actuator.lag_s
    controller = make_block("controller", kind, ctl, wired)
    tr = base.compensation.transport
    latency = tr.latency_s + tr.latency_frames / choice.rate_hz
    args = (choice.rate_hz, tracker_exposure_s(base, choice.rate_hz), latency, controller,
            actuator, 0.02)
    if not fast:
        return LoopModel(*args)
    if type(controller) is KalmanPredictor:
        controller = SharedSteadyKalman(**{f.name: getattr(controller, f.name)
                                           for f in dataclasses.fields(controller) if f.init})
    return FastLoopModel(*args[:3], controller, *args[4:], share=share)


@dataclass(frozen=True)
class SharedSteadyKalman(KalmanPredictor):
    """A :class:`compensation.controllers.KalmanPredictor` whose steady state (its gain and
    model at a period and noise: a Riccati iteration that does not depend on the lead) is
    solved once per predictor less its lead (:func:`kalman_steady_state`): a search's loops
    of one rate and bandwidth differ in their stage's lead alone."""

    def steady_state(self, period_s: float, sigma_px: float, lines_hz=None, line_q=None):
        """:meth:`KalmanPredictor.steady_state`, computed once per (predictor less its lead,
        period s, sigma px) when the predictor's own lines are meant."""
        if lines_hz is not None or line_q is not None:
            return KalmanPredictor.steady_state(self, period_s, sigma_px, lines_hz, line_q)
        return kalman_steady_state(dataclasses.replace(self, lead_s=None), float(period_s),
                                   float(sigma_px))


@lru_cache(maxsize=256)
def kalman_steady_state(predictor: KalmanPredictor, period_s: float, sigma_px: float):
    """:meth:`KalmanPredictor.steady_state` (K, Phi, Q, H) of ``predictor`` at a period (s)
    and measurement noise (px), cached."""
    return KalmanPredictor.steady_state(predictor, period_s, sigma_px)


def exposure_windows(base: Scenario) -> tuple[float, float, float]:
    """(start_s, end_s, window_s) of the main imager's exposures the metrics judge."""
    mi = base.camera.main_imager
    window = mi.exposure_s
    if mi.kind == "tdi":
        line = mi.line_rate_hz or nominal_line_rate_hz(base)
        window = mi.stages / line
    return mi.start_s, base.duration_s, window


def product_span_s(base: Scenario) -> float:
    """The time the main imager's product spans, s: a TDI strip's lines over the line rate
    (the ground corrects those lines from the record's frames within it), else the run."""
    mi = base.camera.main_imager
    if mi.kind != "tdi":
        return base.duration_s
    line = mi.line_rate_hz or nominal_line_rate_hz(base)
    return float(min(base.duration_s, base.product.lines / line))


def nominal_line_rate_hz(base: Scenario) -> float:
    """A TDI imager's synchronous line rate at nadir (ground speed / GSD), Hz."""
    gm, r_e = 3.986004418e14, 6.371e6
    h = base.orbit.altitude_m
    v_ground = np.sqrt(gm / (r_e + h)) * r_e / (r_e + h)
    gsd = h * base.camera.pixel_pitch_m / base.camera.focal_length_m
    return float(v_ground / gsd)


def predict_loop(choice: LoopChoice, base: Scenario, dist: Disturbance,
                 samples_per_window: int = 32, lock: bool = True,
                 share: StageShare | None = None, fast: bool = True) -> LoopPrediction:
    """The loop's part of the predictions (see the module docstring); ``lock``: the lock
    time too (an eigenvalue problem of the plant's order: skipped when not asked for);
    ``share``, ``fast``: as :func:`loop_model` takes them (``fast`` False: the reference,
    every transfer function computed by :class:`compensation.analytic.LoopModel`)."""
    return predict_model(loop_model(choice, base, share, fast), base, dist,
                         tracker_exposure_s(base, choice.rate_hz), samples_per_window, lock)


def predict_model(model, base: Scenario, dist: Disturbance, exposure_s: float,
                  samples_per_window: int = 32, lock: bool = True) -> LoopPrediction:
    """:func:`predict_loop` of a built :class:`LoopModel` (None: no stage, the open loop):
    what a candidate and a bundled scenario's own loop (:func:`predict_scenario`) share;
    ``exposure_s``: the tracker's exposure, s."""
    from compensation.lock import analytic_lock_time

    start, end, window = exposure_windows(base)
    n_win = max(1, int(np.floor((end - start) / window + 1e-9)))
    t = start + (np.arange(n_win * samples_per_window) + 0.5) * window / samples_per_window
    tdi = base.camera.main_imager.kind == "tdi"
    w_rms, w_blur = window_weights(window, tdi)
    if model is None:
        s_rnd = np.ones(len(dist.rnd_f_hz))
        ok, why, noise, noise_blur, lock_s = True, "", 0.0, 0.0, 0.0
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
        # the noise's residual density per unit sigma^2 (LoopModel.noise_rms_px's Parseval)
        f = (np.arange(1024) + 0.5) / 1024 * 4.0 * model.rate_hz
        dens = 2.0 * model.period_s * np.abs(model.command_tf(f) * model.stage_response(f)) ** 2
        df = f[1] - f[0]
        noise = float(np.sqrt(np.sum(dens * w_rms(f)) * df))
        noise_blur = float(np.sqrt(np.sum(dens * w_blur(f)) * df))
        lock_s = (float(analytic_lock_time(model, band=0.05, max_s=60.0).lock_s) if lock
                  else np.nan)
    if tdi:  # each line's residual counts from the line's start (imc.wiring.truth)
        starts = start + np.arange(n_win) * window
        r_all = sinusoid_residual(model, dist, end, np.concatenate([t, starts]), exposure_s)
        r = r_all[: len(t)] - np.repeat(r_all[len(t):], samples_per_window, axis=0)
    else:
        r = sinusoid_residual(model, dist, end, t, exposure_s)
    rms = np.mean(r**2, axis=0)
    # each exposure about its own mean is what blurs; the metric's phase is relative to 0
    win = r.reshape(n_win, samples_per_window, 2)
    per_win = np.stack([motion_mtf(win, NYQUIST, 0), motion_mtf(win, NYQUIST, 1)], -1)
    mtf = per_win.min(0)
    worst = win[per_win.argmin(0), :, [0, 1]]  # (2, S): each axis's worst exposure
    curve = np.abs(np.exp(-2j * np.pi * NIIRS_FREQS[:, None, None] * worst[None]).mean(-1))
    def rnd(weight):
        if len(dist.rnd_f_hz) < 2:
            return np.zeros(2)
        fr = dist.rnd_f_hz
        return np.trapezoid(dist.rnd_psd_px2_hz * (s_rnd * weight(fr))[:, None], fr, axis=0)

    return LoopPrediction(ok, why, tuple(np.sqrt(rms)), tuple(rnd(w_rms)), float(noise),
                          tuple(mtf), lock_s, curve, noise_blur, tuple(rnd(w_blur)))


def window_weights(window_s: float, tdi: bool):
    """(w_rms, w_blur): the share of a residual sinusoid's variance at f (Hz) that the
    residual RMS counts (1 against a fixed reference; a TDI line's residual counts from the
    line's start: 2 (1 - sinc(2 f w)), the mean over the line of 1 - cos 2 pi f tau) and
    that blurs one exposure (about its mean: 1 - sinc(f w)^2), random phases."""
    def w_rms(f):
        f = np.asarray(f, float)
        return 2.0 * (1.0 - np.sinc(2.0 * f * window_s)) if tdi else np.ones_like(f)

    def w_blur(f):
        return 1.0 - np.sinc(np.asarray(f, float) * window_s) ** 2

    return w_rms, w_blur


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
    h = (model.share.held(model, t_s, n) if isinstance(model, FastLoopModel)
         else held_response(model, t_s, n))
    return d_t - d0 - h @ u


def held_response(model: LoopModel, t_s: np.ndarray, n: int) -> np.ndarray:
    """The stage's position (T, n) px at times ``t_s`` (T,) s for one unit command held
    from each of the ticks 0 .. n - 1 (:attr:`LoopModel.pulse`'s trajectory): the residual
    of :func:`sinusoid_residual` is the motion less this times the commands."""
    _, _, th, sh, interp = model.pulse
    lag = np.asarray(t_s, float)[:, None] - np.arange(n)[None, :] * model.period_s
    if interp == "previous":
        idx = np.searchsorted(th, lag, side="right") - 1
        return np.where((idx >= 0) & (lag <= th[-1]), sh[np.clip(idx, 0, len(sh) - 1)], 0.0)
    return np.interp(lag, th, sh, left=0.0, right=0.0)


def record_floor_px(dist: Disturbance, rate_hz: float, exposure_s: float,
                    duration_s: float, line_t_s: np.ndarray, integration_s: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The geometry (after a constant, after an affine) (2,) px per axis that ground
    correction leaves from a perfect record of the sinusoids of ``dist``: the tracker's
    frames at ``rate_hz`` over ``duration_s`` measure each exposure's mean (``exposure_s``,
    sampled at its middle), the ground interpolates them as the product does
    (:func:`ground.record.line_motion` with :data:`imc.wiring.product.RECORD_METHOD`) over
    each line's integration (lines from ``line_t_s``, ``integration_s``), against the lines'
    true exposure means (:func:`ground.network.geometry_rms`). What the record's network
    covariance (:func:`record_geometry_unit`) does not hold: the jitter between its
    samples, which grows with the jitter's frequency against the frame rate."""
    from ground.network import geometry_rms
    from ground.record import MotionRecord, line_motion
    from imc.wiring.product import RECORD_METHOD

    t0 = np.arange(int(np.floor(duration_s * rate_hz - 1e-9)) + 1) / rate_hz
    t0 = t0[t0 + exposure_s <= duration_s + 1e-9]
    rec = MotionRecord(t0 + 0.5 * exposure_s, _exposure_means(dist, t0, exposure_s),
                       np.ones(len(t0), bool))
    line_t = np.asarray(line_t_s, float)
    err = line_motion(rec, line_t, integration_s, RECORD_METHOD) \
        - _exposure_means(dist, line_t, integration_s)
    g = geometry_rms(err, line_t)
    return np.asarray(g["constant"]), np.asarray(g["affine"])


#: the share of each link's error that is its own rather than its frames' pixels' (the rest
#: enters every link measured on the same pixels: :class:`ground.network.SharedNoise`), the
#: record predictor's stated default: the run's own REML estimate
#: (:func:`ground.network.estimate_independent_fraction`) on no_stage.yaml's rendered strip
#: is 0.11 / 0.07 (row / col)
RECORD_OWN_FRACTION = 0.1
#: the most frames :func:`record_geometry_unit` solves a shared-pixel network on (the
#: design search calls it per rate, baselines, block size and count)
SHARED_FRAMES = 100


@dataclass(frozen=True)
class ChainGeometry:
    """A scanning tracker's blocks as its record's links cut them: ``n_blocks`` blocks of
    ``block_px`` placed on the ``rows`` x ``cols`` px sensor by
    :func:`correlator.tracker.block_grid`, the content moving by ``step_px`` (rows, cols)
    px per frame (rounded to 0.1 px: it is a cache key). Baseline 1 (the loop's link) is
    cut as the loop's chain cuts it (:func:`imc.wiring.links.chain_corners`), baselines >= 2
    as the ground's extra links (:func:`imc.wiring.links.pair_corners`)."""

    rows: int
    cols: int
    block_px: int
    n_blocks: int
    step_px: tuple[float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "step_px", tuple(round(float(v), 1) for v in self.step_px))

    def cut(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The blocks of a link of baseline ``k`` frames: reference corners (B, 2), current
        corners (B, 2) px, and whether each block is measured (B,)."""
        from correlator.tracker import block_grid
        from imc.wiring.links import chain_corners, pair_corners

        b = int(self.block_px)
        corners = block_grid(self.rows, self.cols, b, self.n_blocks)
        step = np.broadcast_to(k * np.asarray(self.step_px, float), corners.shape)
        if k == 1:
            return chain_corners(corners, step, b, (self.rows, self.cols))
        ref, used = pair_corners(corners, step, b, np.array([self.rows - b, self.cols - b]))
        return ref, ref + np.rint(step).astype(int), used


@lru_cache(maxsize=128)
def record_links(n_frames: int, baselines: int, geometry: ChainGeometry | None = None,
                 own_fraction: float = RECORD_OWN_FRACTION):
    """The record's links over ``n_frames`` frames, every baseline 1..``baselines``, each
    of baseline 1 with 1 px of error (:class:`ground.network.Links`, no motion): with
    ``geometry`` the links share their frames' pixels as the run's do
    (:meth:`imc.wiring.links.LinkTable.network`: each block's error half its reference
    region's noise and half its current region's, :meth:`ground.network.SharedNoise.
    from_blocks`; blocks of equal error, so a link of baseline k has n_1 / n_k times the
    variance of the loop's, n_k its measured blocks), ``own_fraction`` of each link's
    variance its own (:func:`ground.network.with_independent_fraction`, as the run applies
    its REML estimate where the links are redundant); without, independent links of 1 px.
    Links without a measured block are left out. Cached per (frames, baselines, geometry,
    fraction)."""
    from ground.network import Links, SharedNoise, with_independent_fraction

    n, kmax = int(n_frames), int(min(baselines, n_frames - 1))
    if geometry is None:
        return Links.baselines(np.zeros((n, 2)), kmax, 1.0)
    cuts = [geometry.cut(k) for k in range(1, kmax + 1)]
    n1 = max(int(cuts[0][2].sum()), 1)
    a, b, ref, cur, share = [], [], [], [], []
    for k, (r, c, used) in enumerate(cuts, start=1):
        nk = int(used.sum())
        if nk == 0:
            continue
        aa = np.arange(n - k)
        a.append(aa)
        b.append(aa + k)
        ref.append(np.broadcast_to(r, (aa.size,) + r.shape))
        cur.append(np.broadcast_to(c, (aa.size,) + c.shape))
        # a block's share: its weight 1 / n_k times its error sqrt(n_1) (baseline 1: 1 px)
        sh = np.where(used[:, None], np.sqrt(n1) / nk, 0.0)
        share.append(np.broadcast_to(sh, (aa.size,) + sh.shape))
    a, b = np.concatenate(a), np.concatenate(b)
    shared = SharedNoise.from_blocks(a, b, np.concatenate(ref), np.concatenate(cur),
                                     np.concatenate(share), int(geometry.block_px))
    links = Links(a, b, np.zeros((a.size, 2)), np.zeros((a.size, 2)), shared=shared)
    if a.size > n + 2:  # redundant links: the run estimates and applies the own share
        links = with_independent_fraction(links, own_fraction)
    return links


def _scaled_links(unit, sigma_px: np.ndarray, d_px: np.ndarray, t_s: np.ndarray):
    """``unit`` (:func:`record_links`) with the loop's link error ``sigma_px`` (2,) px per
    axis, the displacements ``d_px`` (n, 2) px and the frame times ``t_s``."""
    from ground.network import Links, SharedNoise

    sig = np.asarray(sigma_px, float)
    sh = unit.shared
    if sh is not None:
        sh = SharedNoise(sh.link, sh.frame, sh.corner_px, sh.coef_px * sig, sh.block_px,
                         sh.cell_px)
    return Links(unit.a, unit.b, d_px, unit.sigma_px * sig, unit.valid, t_s, shared=sh)


def record_geometry(sigma_px, rate_hz: float, exposure_s: float, duration_s: float,
                    line_t_s: np.ndarray, baselines: int, dist: Disturbance | None = None,
                    geometry: ChainGeometry | None = None, smoother: bool = True,
                    own_fraction: float = RECORD_OWN_FRACTION, max_lines: int = 512
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The geometry (after a constant, after an affine) (2,) px per axis that the record's
    errors leave in a product's lines, as the run's restitution
    (:func:`imc.wiring.restitution.restitute`) makes the record: the tracker's frames over
    ``duration_s`` at ``rate_hz`` (exposure ``exposure_s``), the links of
    :func:`record_links` (baselines 1..``baselines``; shared pixels with ``geometry``)
    with the loop's link error ``sigma_px`` (scalar or (2,) px), solved as a network
    (:func:`ground.network.solve_network`) and, with ``smoother``, smoothed
    (:func:`ground.network.smooth_network`) with the prior the run would estimate from its
    record (:func:`ground.network.estimate_prior` on the solution of the noise-free links
    of the sinusoids of ``dist``, with the network's covariance). The smoothed error is
    the smoother's bias on the sinusoids (its estimate of the noise-free links less the
    truth) plus its noise, of covariance ``C - C P C`` (C the posterior covariance, P the
    prior's precision: the linear smoother's ``M R M^T``, without the prior's own
    variance, which the jitter does not follow). Both are carried to the lines' times
    ``line_t_s`` (at most ``max_lines`` of them) by the interpolation between frames and
    measured as :func:`ground.network.geometry_rms` measures the run. Random jitter terms
    are not in the truth the smoother sees (sinusoids only)."""
    from scipy import sparse

    from ground.network import (
        NetworkSolution,
        _difference_operator,
        _prior_scale,
        estimate_prior,
        geometry_rms,
        smooth_network,
        solve_network,
    )

    t0 = np.arange(int(np.floor(duration_s * rate_hz - 1e-9)) + 1) / rate_hz
    t0 = t0[t0 + exposure_s <= duration_s + 1e-9]
    n = int(t0.size)
    t = t0 + 0.5 * exposure_s
    s = np.zeros((n, 2))
    if dist is not None and len(dist.sin_f_hz):
        s = _exposure_means(dist, t0, exposure_s)
        s = s - s[0]
    unit = record_links(n, int(max(1, baselines)), geometry, float(own_fraction))
    sig = np.broadcast_to(np.asarray(sigma_px, float), (2,))
    links = _scaled_links(unit, sig, s[unit.b] - s[unit.a], t)
    sol = solve_network(links, n)
    cov = sol.cov_px2
    if smoother and n >= 5:
        prior = estimate_prior(sol, 2)
        sol = smooth_network(links, n, prior=prior)
        dop = _difference_operator(n, 2)
        c = _prior_scale(t, 2)
        cov = np.empty_like(sol.cov_px2)
        for ax in range(2):
            p = (dop.T @ sparse.diags(1.0 / (c * prior.q_px2[ax])) @ dop).toarray()
            cc = sol.cov_px2[ax]
            cov[ax] = cc - cc @ p @ cc
    err = NetworkSolution(sol.s_px - s, cov, t, "first")
    lt = np.asarray(line_t_s, float)
    lt = lt[np.unique(np.linspace(0, lt.size - 1, min(lt.size, max_lines)).astype(int))]
    e, _ = err.at(lt)
    g = geometry_rms(e, lt, err.covariance_at(lt))
    return (np.hypot(g["constant"], g["predicted_constant"]),
            np.hypot(g["affine"], g["predicted_affine"]))


@lru_cache(maxsize=256)
def record_geometry_unit(rate_hz: float, duration_s: float, baselines: int = 1,
                         max_frames: int = 1500, geometry: ChainGeometry | None = None,
                         own_fraction: float = RECORD_OWN_FRACTION) -> tuple[float, float]:
    """(after a constant, after an affine) geometry RMS (px, per axis alike) of the record of
    a tracker at ``rate_hz`` over ``duration_s`` with 1 px of error per link of baseline 1
    (``baselines`` 0: a fixed reference, each frame's error independent): the network of
    :func:`record_links` (with ``geometry``: the links share their frames' pixels, with
    ``own_fraction`` their own; without: independent), solved
    (:func:`ground.network.solve_network`), its covariance through
    :func:`ground.network.geometry_rms`; unsmoothed (:func:`record_geometry` smooths).
    Scales linearly with the link error. Frames beyond ``max_frames`` are cut (the rate is
    kept per link). With ``geometry``, a record longer than :data:`SHARED_FRAMES` frames
    takes the independent network's figures times the shared one's ratio to them on
    :data:`SHARED_FRAMES` frames (the chain is stationary: on 120 frames the ratio is within
    1 % of 332 frames' on 4 x 64 px at K = 4 and 2 x 48 px at K = 2, 5 % low on 8 x 32 px
    at K = 10; 10 % low there on 60 frames).
    Cached per (rate, span, baselines, geometry, fraction)."""
    from ground.network import geometry_rms, solve_network

    n = int(np.clip(round(rate_hz * duration_s), 4, max_frames))
    if baselines <= 0:  # every frame against one reference: independent errors
        return float(np.sqrt(1.0 - 1.0 / n)), float(np.sqrt(1.0 - 2.0 / n))
    k = int(min(baselines, n - 1))
    if geometry is not None and n > SHARED_FRAMES:  # the shared network's ratio, scaled
        ind = np.array(record_geometry_unit(rate_hz, duration_s, k, max_frames))
        short = SHARED_FRAMES / rate_hz
        ratio = np.array(record_geometry_unit(rate_hz, short, k, max_frames, geometry,
                                              own_fraction)) \
            / np.array(record_geometry_unit(rate_hz, short, k, max_frames))
        return float(ind[0] * ratio[0]), float(ind[1] * ratio[1])
    links = record_links(n, k, geometry, float(own_fraction))
    sol = solve_network(links, n)
    t = np.arange(n) / rate_hz
    g = geometry_rms(np.zeros((n, 2)), t, cov_px2=sol.cov_px2)
    return float(g["predicted_constant"][0]), float(g["predicted_affine"][0])


def _predict_group(args) -> list[tuple[int, LoopPrediction]]:
    group, base, dist, lock, fast = args
    share = StageShare()  # one rate and stage: the plant's work done once for the group
    return [(i, predict_loop(ch, base, dist, lock=lock, share=share, fast=fast))
            for i, ch in group]


class LoopJobs:
    """:func:`predict_loop` for every choice, grouped by (rate, stage, resonance) so what a
    group shares (:class:`StageShare`) is computed once, on ``workers`` processes (fork),
    started at construction so that the caller's own work overlaps them; :meth:`results`
    collects them (with one worker it runs them then). The largest groups go first (the
    workers then finish together); ``fast`` False: each loop alone with
    :class:`compensation.analytic.LoopModel` (the reference the fast search is checked
    against)."""

    def __init__(self, choices: list[LoopChoice], base: Scenario, dist: Disturbance,
                 lock: bool = True, workers: int = 1, progress=None, fast: bool = True
                 ) -> None:
        groups: dict[tuple, list[tuple[int, LoopChoice]]] = {}
        for i, ch in enumerate(choices):
            groups.setdefault((ch.rate_hz, ch.stage, ch.resonance_hz), []).append((i, ch))
        order = sorted(groups, key=lambda k: (-len(groups[k]), -k[0]))
        self._jobs = [(groups[k], base, dist, lock, fast) for k in order]
        self._n = len(choices)
        self._progress = progress
        self._pool = None
        self._futures: list = []
        if workers > 1 and len(self._jobs) > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            import scipy.signal  # noqa: F401 - imported once here, not in each worker

            self._pool = ProcessPoolExecutor(min(workers, len(self._jobs)),
                                             mp_context=mp.get_context("fork"))
            self._futures = [self._pool.submit(_predict_group, j) for j in self._jobs]

    def results(self) -> list[LoopPrediction]:
        """Every choice's prediction, in the choices' order."""
        out: list[LoopPrediction | None] = [None] * self._n
        done = 0

        def take(pairs) -> None:
            nonlocal done
            for i, p in pairs:
                out[i] = p
                done += 1
            if self._progress is not None:
                self._progress(done, self._n)

        if self._pool is not None:
            from concurrent.futures import as_completed

            try:
                for f in as_completed(self._futures):
                    take(f.result())
            finally:
                self.close()
        else:
            for j in self._jobs:
                take(_predict_group(j))
        return out  # type: ignore[return-value]

    def close(self) -> None:
        """Stop the workers: the groups not started are cancelled (a caller that fails
        before :meth:`results` does not wait for them)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> LoopJobs:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def predict_loops(choices: list[LoopChoice], base: Scenario, dist: Disturbance,
                  lock: bool = True, workers: int = 1,
                  progress=None, fast: bool = True) -> list[LoopPrediction]:
    """:func:`predict_loop` for every choice (:class:`LoopJobs`, collected at once)."""
    return LoopJobs(choices, base, dist, lock, workers, progress, fast).results()


def residual_figures(det_px: np.ndarray, var_rnd_px2: np.ndarray, noise_gain: np.ndarray,
                     sigma_px: np.ndarray, mtf_det: np.ndarray, var_rnd_blur_px2: np.ndarray,
                     noise_gain_blur: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The residual's figures from the loop's parts: RMS per axis (..., 2) px, total RMS (...)
    px, and the worst exposure's motion MTF at Nyquist per axis (..., 2).

    det_px (..., 2) : the sinusoids' residual RMS; var_rnd_px2 (..., 2) : the random terms'
    residual variance; noise_gain (...) : residual RMS per px of tracker sigma; sigma_px
    (...) or (..., 2) : the tracker's error per frame after the block fit; mtf_det (..., 2) :
    the sinusoids' worst-exposure MTF, times the Gaussian factor exp(-pi^2 var / 2) at
    Nyquist of the random and noise residual's variance about an exposure's mean
    (``var_rnd_blur_px2`` (..., 2), ``noise_gain_blur`` (...)). Also returns that variance
    (..., 2) px^2 (the NIIRS predictor's Gaussian).
    """
    sig = np.asarray(sigma_px, float)
    gain = np.asarray(noise_gain, float)
    if sig.ndim == gain.ndim:
        sig = sig[..., None]
    noise2 = (gain[..., None] * sig) ** 2
    var = det_px**2 + var_rnd_px2 + noise2
    blur = var_rnd_blur_px2 + (np.asarray(noise_gain_blur, float)[..., None] * sig) ** 2
    return (np.sqrt(var), np.sqrt(var.sum(axis=-1)), mtf_det * np.exp(-(np.pi**2) * blur / 2),
            blur)


def tracker_snr(m) -> float:
    """The tracker's SNR (mean signal over noise sigma at its exposure), dimensionless."""
    return float(m.sensor.snr(exposure_s=m.exposure_s))


def bound_frame0(sc: Scenario, fidelity: str = "texture"):
    """The base's built run and frame 0's radiance as the tracker's bound reads it
    (:func:`tracker_bound`, :func:`tracker_bounds`): at 'rendered' fidelity Mitsuba's frame
    0 on the whole tile; else the albedo under frame 0's footprint. A procedural tile is
    then not built whole: its DEM and the albedo's window under the footprint only
    (:func:`imc.wiring.build.procedural_draws`; the same image within one float32 unit of
    the albedo's last place, bit for bit on the tested scenes: the
    smallsat's 12.2 km tile in ~1/5 of its CPU time); ``Models.terrain`` is then its
    geometry with a stand-in albedo (geometry, coverage and flow as on the whole tile).

    Returns
    -------
    (Models, (rows, cols) frame 0: the albedo's units on the texture plant, the renderer's
    radiance on the rendered one).
    """
    from imc.wiring.build import build_models, procedural_draws
    from imc.wiring.rendered_plant import albedo_span, albedo_texels, base_image

    draws = procedural_draws(sc) if fidelity != "rendered" else None
    if draws is None:
        m = build_models(sc)
        return m, _rendered_frame0(m) if fidelity == "rendered" else base_image(m, 0)
    m = build_models(sc, terrain=draws.geometry())
    row, col, sig = albedo_texels(m, 0, texel_m=draws.texel_m)
    rows, cols = albedo_span(row, col, sig, (draws.n, draws.n))
    window = (draws.albedo_window(rows, cols), draws.texel_m, (rows[0], cols[0]))
    return m, base_image(m, 0, window=window)


def tracker_bound(m, fidelity: str = "texture", radiance: np.ndarray | None = None
                  ) -> tuple[np.ndarray, float]:
    """The tracker's bound on a built run's base scene
    (:func:`imc.wiring.rendered_plant.predicted_sigma_px`): the per-block bound (2,) px
    that, over the kept blocks, gives their inverse-variance fit (the motion-field fit's
    weights): ``fit * sqrt(n_kept)``; and the fraction of blocks the correlator keeps (a
    textureless block is refused in a run, so it does not average). ``fidelity``
    'rendered': on frame 0 as Mitsuba renders it (the relief's shading is texture the flat
    albedo lacks: the quickstart's bound is 0.65x the albedo's); else on the albedo.
    ``radiance``: frame 0 as :func:`bound_frame0` gives it (default: made from ``m``)."""
    from imc.wiring.rendered_plant import predicted_sigma_px

    rad = radiance if radiance is not None else (
        _rendered_frame0(m) if fidelity == "rendered" else None)
    crlb = predicted_sigma_px(m, fill=False, radiance=rad)
    ok = np.isfinite(crlb).all(axis=1)
    if not ok.any():
        raise ScenarioError("base: the correlator refuses every block of the base scene at "
                            "the tracker's SNR (no texture): no tracker predictor; raise "
                            "camera.tracker.mean_signal_dn or choose a textured scene")
    fit = 1.0 / np.sqrt(np.sum(1.0 / crlb[ok] ** 2, axis=0))
    return fit * np.sqrt(ok.sum()), float(ok.mean())


def tracker_bounds(m, sizes, fidelity: str = "texture", n_blocks: int | None = None,
                   radiance: np.ndarray | None = None) -> dict[int, tuple[float, float]]:
    """The tracker's per-block bound (px, mean of the axes) at each block size of ``sizes``
    on the base scene, as :func:`tracker_bound` gives it over the kept blocks, over the
    square root of the kept fraction (a refused block does not average), measured on a grid
    of ``n_blocks`` blocks of that size (None: the sensor tiled by the block, at least 9;
    inf where the correlator keeps none, or the block exceeds the sensor); and the
    probability that a block is valid (:func:`block_valid_probability` of the grid's
    blocks as the real correlator judged them). ``radiance``: frame 0 as
    :func:`bound_frame0` gives it (default: made from ``m``, once)."""
    from correlator.tracker import block_grid
    from imc.wiring.rendered_plant import base_image, predicted_sigma_px

    rad = radiance if radiance is not None else (
        _rendered_frame0(m) if fidelity == "rendered" else base_image(m, 0))
    fp = m.camera.focal_plane
    out = {}
    for b in sorted({int(x) for x in sizes}):
        if b > min(fp.rows, fp.cols):
            out[b] = (np.inf, 0.0)
            continue
        n = n_blocks or max(9, (fp.rows // b) * (fp.cols // b))
        sc_b = m.scenario.model_copy(update={
            "correlator": m.scenario.correlator.model_copy(update={"block_px": b})})
        mb = dataclasses.replace(m, scenario=sc_b, corners=block_grid(fp.rows, fp.cols, b, n))
        crlb, psr = predicted_sigma_px(mb, fill=False, radiance=rad, with_psr=True)
        ok = np.isfinite(crlb).all(axis=1)
        p_valid = block_valid_probability(ok, psr, m.correlator.psr_threshold)
        if not ok.any():
            out[b] = (np.inf, p_valid)
            continue
        fit = 1.0 / np.sqrt(np.sum(1.0 / crlb[ok] ** 2, axis=0))
        out[b] = (float(np.mean(fit * np.sqrt(ok.sum())) / np.sqrt(ok.mean())), p_valid)
    return out


def block_valid_probability(valid: np.ndarray, psr: np.ndarray, psr_threshold: float
                            ) -> float:
    """The probability that a block of the scene is valid, from a sample of blocks the
    correlator measured (``valid`` (n,), their PSR ``psr`` (n,)): one less the largest of
    the refused fraction's Jeffreys estimate ((refused + 0.5) / (n + 1): a sample of n with
    none refused does not certify odds below ~1/(2n); the smallsat's 1 x 48 px chain lost
    2 of 139 frames at PSR 7.8 and 12.1 where 25 of 25 static blocks were valid) and the
    chance that a block's PSR falls below the correlator's threshold (``psr_threshold``;
    the sample's PSRs taken as log-normal). In a scan every frame brings new ground under
    each block, so this is the odds of each block in each frame."""
    from scipy.stats import norm

    valid = np.asarray(valid, bool)
    p_refused = (float((~valid).sum()) + 0.5) / (valid.size + 1.0)
    z = np.log(np.asarray(psr, float)[np.asarray(psr, float) > 0])
    if z.size >= 3 and np.std(z) > 0:
        p_refused = max(p_refused, float(norm.cdf((np.log(psr_threshold) - z.mean())
                                                  / np.std(z, ddof=1))))
    return 1.0 - p_refused


def image_flow_px_per_s(m) -> np.ndarray:
    """The nominal image motion's rate (2,) px/s (rows, cols) at the tracker's centre
    (:func:`imc.wiring.build.predicted_px` between two frames mid-run: orbit, attitude and
    DEM, no jitter, no stage): a scanning tracker's flow; a frame's step is it over the
    frame rate."""
    from imc.wiring.build import predicted_px

    n = len(m.frame_t_s)
    if n < 2:
        return np.zeros(2)
    k = max(1, n // 2)
    z = np.zeros(2)
    step = predicted_px(m, np.array([m.camera.focal_plane.center_px]), k - 1, k, z, z)[0]
    return step / float(m.frame_mid_s[k] - m.frame_mid_s[k - 1])


def chain_overlap(rows: int, cols: int, block_px: int, n_blocks: int,
                  step_px: np.ndarray) -> int:
    """How many of a scanning tracker's blocks keep their content in the next frame: the
    blocks where the tracker places them (:func:`correlator.tracker.block_grid`), cut as
    the loop's chain cuts them (:func:`imc.wiring.links.chain_corners`) with the flow
    ``step_px`` (2,) px per frame; 0 where the grid does not fit the sensor."""
    from correlator.tracker import block_grid
    from imc.wiring.links import chain_corners

    if block_px > min(rows, cols):
        return 0
    corners = block_grid(rows, cols, block_px, n_blocks)
    step = np.broadcast_to(np.asarray(step_px, float), corners.shape)
    return int(chain_corners(corners, step, block_px, (rows, cols))[2].sum())


def min_valid_fraction(base: Scenario) -> float:
    """The fraction of blocks that must be valid for the estimator to make a frame the next
    reference (its ``min_valid_fraction``; an estimator without one: any block)."""
    from compensation.registry import make_block

    est = base.compensation.estimator
    block = make_block("estimator", est.kind, est.params(), {"field_point_px": (0.0, 0.0)})
    return float(getattr(block, "min_valid_fraction", 0.0))


def chain_break_probability(n_overlap: np.ndarray, n_blocks: np.ndarray,
                            p_valid: np.ndarray, min_fraction: float) -> np.ndarray:
    """The chance, per frame, that a scanning tracker's chain breaks: fewer than
    ``min_fraction`` of its ``n_blocks`` blocks valid (the estimator then keeps the old
    reference, whose content soon leaves the sensor) when ``n_overlap`` of them overlap the
    next frame and each is valid with probability ``p_valid`` (binomial)."""
    from scipy.stats import binom

    nb = np.asarray(n_blocks, float)
    need = np.maximum(1, np.ceil(min_fraction * nb - 1e-9))
    return np.where(np.asarray(n_overlap) >= need,
                    binom.cdf(need - 1, np.asarray(n_overlap), np.asarray(p_valid)), 1.0)


def _rendered_frame0(m) -> np.ndarray:
    """Frame 0's radiance as the rendered plant renders it (the stage at rest)."""
    from compensation.loop import Trajectory
    from imc.wiring.rendered_plant import RenderedPlant

    plant = RenderedPlant(m)
    try:
        return plant.radiance(0, Trajectory("previous"))
    finally:
        plant.close()


def chain_geometry(m) -> ChainGeometry | None:
    """The :class:`ChainGeometry` of a built run's scanning tracker (its sensor, blocks and
    the nominal flow per frame, :func:`image_flow_px_per_s`); None for a staring one."""
    if not m.chain:
        return None
    fp = m.camera.focal_plane
    step = image_flow_px_per_s(m) / m.rate_hz
    return ChainGeometry(int(fp.rows), int(fp.cols), int(m.scenario.correlator.block_px),
                         len(m.corners), (float(step[0]), float(step[1])))


def record_prediction(m, sigma_px, dist: Disturbance, baselines: int
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The geometry after ground correction (after a constant, after an affine) (2,) px of
    a built run whose tracker errs by ``sigma_px`` (2,) px per frame, and the perfect
    record's floor (after a constant, after an affine) (2, 2) px: a scanning tracker's
    record as the run's restitution makes it (:func:`record_geometry`: shared pixels, the
    smoother where ``product.restitution.smoother``) over the product's lines
    (:func:`imc.wiring.product.plan_product`); a staring tracker (``baselines`` 0: every
    frame against one reference) the network's covariance over the product's span
    (:func:`record_geometry_unit`); the floor (:func:`record_floor_px`: the jitter between
    the record's samples, 0 without a product) added in quadrature."""
    sc = m.scenario
    sigma = np.broadcast_to(np.asarray(sigma_px, float), (2,))
    geometry = chain_geometry(m)
    if not sc.product.enabled:  # as the search predicts it (search_record_geometry)
        c_u, a_u = record_geometry_unit(m.rate_hz, product_span_s(sc), int(baselines),
                                        geometry=geometry if baselines > 0 else None)
        return c_u * sigma, a_u * sigma, np.zeros((2, 2))
    from imc.wiring.product import plan_product

    plan = plan_product(m)
    if baselines <= 0 or geometry is None:
        c_u, a_u = record_geometry_unit(m.rate_hz, product_span_s(sc), int(baselines))
        c, a = c_u * sigma, a_u * sigma
    else:
        c, a = record_geometry(sigma, m.rate_hz, m.exposure_s, sc.duration_s, plan.line_t_s,
                               int(baselines), dist, geometry, sc.product.restitution.smoother)
    floor = np.array(record_floor_px(dist, m.rate_hz, m.exposure_s, sc.duration_s,
                                     plan.line_t_s, plan.integration_s))
    return np.hypot(c, floor[0]), np.hypot(a, floor[1]), floor


def identified_prediction(model, controller, sc: Scenario, dist: Disturbance, m
                          ) -> LoopPrediction:
    """:func:`predict_model` of a run's loop whose Kalman predictor identifies lines
    (``identify``): the jitter's sinusoids it can find (at or above 1.5 / its window and
    below half the frame rate, not already listed) are followed from its first
    identification on (0.9 of its window, as :func:`imc.wiring.advisories.lock_summary`
    says it), so the exposures before it are predicted with the listed lines only and those
    after it with the found lines added (at the largest found amplitude's process noise),
    the figures combined over the exposures: variances by their count, the worst MTF the
    worse of the two. Any other loop: :func:`predict_model` alone."""
    import dataclasses as dc

    plain = predict_model(model, sc, dist, m.exposure_s)
    if not getattr(controller, "identify", False) or not len(dist.sin_f_hz):
        return plain
    window_s = float(controller.identification_window_s)
    t_id = 0.9 * window_s
    listed = {round(float(f), 6) for f in controller.lines_hz}
    inband = (dist.sin_f_hz >= 1.5 / window_s) & (dist.sin_f_hz < 0.5 * m.rate_hz)
    found = sorted({round(float(f), 6) for f in dist.sin_f_hz[inband]} - listed)
    start, end, _ = exposure_windows(sc)
    if not found or t_id >= end:
        return plain
    amp = float(np.max(dist.sin_a_px[inband]))
    ctl = dc.replace(controller, lines_hz=tuple(controller.lines_hz) + tuple(found),
                     line_amplitude_px=max(amp, float(controller.line_amplitude_px)))
    mi = sc.camera.main_imager
    after_sc = sc.model_copy(update={"camera": sc.camera.model_copy(update={
        "main_imager": mi.model_copy(update={"start_s": max(float(mi.start_s), t_id)})})})
    after = predict_model(dc.replace(model, controller=ctl), after_sc, dist, m.exposure_s,
                          lock=False)
    if not after.ok:  # no prediction of the loop with the found lines: the listed ones'
        return plain
    w_b = float(np.clip((t_id - start) / (end - start), 0.0, 1.0))
    if w_b <= 0.0:
        return dc.replace(after, lock_s=plain.lock_s)
    before = plain if w_b >= 1.0 else predict_model(
        model, sc.model_copy(update={"duration_s": t_id}), dist, m.exposure_s)
    w_a = 1.0 - w_b

    def mix(b, a):
        return tuple(np.sqrt(w_b * np.square(b) + w_a * np.square(a)).tolist())

    def mean(b, a):
        return tuple((w_b * np.asarray(b) + w_a * np.asarray(a)).tolist())

    curve = None if before.mtf_det_curve is None or after.mtf_det_curve is None else \
        np.minimum(before.mtf_det_curve, after.mtf_det_curve)
    return LoopPrediction(
        before.ok and after.ok, before.why or after.why, mix(before.rms_det_px,
                                                             after.rms_det_px),
        mean(before.var_rnd_px2, after.var_rnd_px2),
        float(np.sqrt(w_b * before.noise_gain ** 2 + w_a * after.noise_gain ** 2)),
        tuple(np.minimum(before.mtf_det_worst, after.mtf_det_worst).tolist()),
        plain.lock_s, curve,
        float(np.sqrt(w_b * before.noise_gain_blur ** 2 + w_a * after.noise_gain_blur ** 2)),
        mean(before.var_rnd_blur_px2, after.var_rnd_blur_px2))


def search_record_geometry(base: Scenario, m, dist: Disturbance, rate_hz: np.ndarray,
                           baselines: np.ndarray, block_px: np.ndarray,
                           n_blocks: np.ndarray, sigma_px: np.ndarray, use: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The design search's geometry after ground correction (after a constant, after an affine)
    (n, 2) px per candidate (NaN where not ``use``), then the same two without the floor (the
    network's part alone, which other jitter frequencies share): the network's covariance over
    the product's span (:func:`record_geometry_unit`, once per rate, baselines and, for a
    scanning tracker, block size and count: the links share their frames' pixels as the blocks
    are cut, :class:`ChainGeometry` with the base's nominal flow per frame) times the
    candidate's tracker error ``sigma_px`` (n,), the perfect record's floor
    (:func:`record_floor_px`, once per rate) added in quadrature. Unlike
    :func:`record_prediction` the smoother is not modelled here (it needs a solve per tracker
    error): the search's geometry is the unsmoothed record's, which the smoother only lowers."""
    out_c = np.full((len(rate_hz), 2), np.nan)
    out_a = np.full((len(rate_hz), 2), np.nan)
    net_c, net_a = out_c.copy(), out_a.copy()
    if not use.any():
        return out_c, out_a, net_c, net_a
    span = product_span_s(base)
    flow = image_flow_px_per_s(m) if m.chain else None
    plan = None
    if base.product.enabled:
        from imc.wiring.product import plan_product

        plan = plan_product(m)
    fp = base.camera.tracker
    floors: dict[float, np.ndarray] = {}
    keys = set(zip(rate_hz[use].tolist(), baselines[use].tolist(), block_px[use].tolist(),
                   n_blocks[use].tolist(), strict=True))
    for r_hz, k_b, b_px, n_b in keys:
        geometry = None
        if flow is not None and k_b > 0:
            step = flow / r_hz
            geometry = ChainGeometry(int(fp.rows), int(fp.cols), int(b_px), int(n_b),
                                     (float(step[0]), float(step[1])))
        c_u, a_u = record_geometry_unit(float(r_hz), span, int(k_b), geometry=geometry)
        if r_hz not in floors:
            floors[r_hz] = np.zeros((2, 2)) if plan is None else np.array(record_floor_px(
                dist, r_hz, tracker_exposure_s(base, r_hz), base.duration_s, plan.line_t_s,
                plan.integration_s))
        sel = use & (rate_hz == r_hz) & (baselines == k_b) & (block_px == b_px) \
            & (n_blocks == n_b)
        sg = sigma_px[sel][:, None]
        net_c[sel], net_a[sel] = c_u * sg, a_u * sg
        out_c[sel] = np.hypot(net_c[sel], floors[r_hz][0][None])
        out_a[sel] = np.hypot(net_a[sel], floors[r_hz][1][None])
    return out_c, out_a, net_c, net_a


def predict_scenario(sc: Scenario, fidelity: str | None = None,
                     efficiency: float | None = None) -> dict[str, object]:
    """A scenario predicted as `imc design` predicts a candidate, with the scenario's own
    loop (:func:`imc.wiring.build.build_loop`: its controller, lines, latency and stage as
    wired for a run): the metrics of :data:`SUPPORTED` (per axis where the run reports a
    pair) and the parts they are built from. ``fidelity``: the plant whose bound and
    correlator efficiency the tracker's error is (default: the scenario's); ``efficiency``:
    this factor instead of the plant's calibrated one (the calibration's 1)."""
    from imc.wiring.build import build_loop, build_models

    m = build_models(sc)
    parts = build_loop(m)
    model = parts.model if sc.compensation.enabled else None
    dist = Disturbance.from_scenario(sc)
    p = identified_prediction(model, parts.controller, sc, dist, m) if model is not None \
        else predict_model(model, sc, dist, m.exposure_s)
    fid = fidelity or sc.plant.fidelity
    crlb, kept = tracker_bound(m, fid)
    eff = correlator_efficiency(fid, sc.scene.kind) if efficiency is None else Efficiency(
        efficiency, 0.0, 0.0, "given")
    snr = tracker_snr(m)
    block = int(sc.correlator.block_px)
    sigma = crlb * eff.at(snr, block) / np.sqrt(len(m.corners) * kept)
    rms, total, mtf, blur = residual_figures(
        np.array(p.rms_det_px), np.array(p.var_rnd_px2), np.array(p.noise_gain), sigma,
        np.array(p.mtf_det_worst), np.array(p.var_rnd_blur_px2), np.array(p.noise_gain_blur))
    from imc.wiring.links import overlap_baselines

    kmax = sc.product.restitution.baselines or overlap_baselines(m)
    staring = sc.attitude.mode == "target"
    geo_c, geo_a, floor = record_prediction(m, sigma, dist, 0 if staring else kmax)
    ni = NiirsInputs.from_models(m)
    niirs = ni.loss(p.mtf_det_curve, blur)
    po = predict_model(None, sc, dist, m.exposure_s, lock=False)  # the open loop's product
    niirs_open = ni.loss(po.mtf_det_curve, np.array(po.var_rnd_blur_px2))
    return {"with_compensation.rms_px": rms.tolist(),
            "with_compensation.rms_total_px": float(total),
            "with_compensation.mtf_nyquist_worst": mtf.tolist(),
            "loop.lock.analytic_s": float(p.lock_s),
            "product.quality.closed.niirs_loss": niirs[0],
            "product.quality.open.niirs_loss": niirs_open[0],
            "product.geometry.open.after.rms_px": geo_c.tolist(),
            "product.geometry.open.affine.rms_px": geo_a.tolist(),
            "parts": {"crlb_px": crlb.tolist(), "kept_fraction": kept, "tracker_snr": snr,
                      "noise_gain_blur": float(p.noise_gain_blur),
                      "efficiency": eff.at(snr, block), "efficiency_spread": eff.spread,
                      "record_floor_px": floor.tolist(),
                      "sigma_px": sigma.tolist(), "noise_gain": float(p.noise_gain),
                      "rms_det_px": list(p.rms_det_px), "var_rnd_px2": list(p.var_rnd_px2),
                      "mtf_det_worst": list(p.mtf_det_worst), "loop_ok": p.ok,
                      "niirs": {"rer_static": ni.rer_static(), "rer_closed": niirs[1].tolist(),
                                "rer_open": niirs_open[1].tolist(), "snr": ni.snr,
                                "gsd_m": ni.gsd_m}}}


# ------------------------------------------------------------------------------ NIIRS


def rer_from_mtf(f_cyc_px: np.ndarray, mtf: np.ndarray) -> np.ndarray:
    """The relative edge response (GIQE's RER: the edge response's rise from -0.5 to +0.5 px)
    of a symmetric system with this MTF along the last axis (frequencies ``f_cyc_px``,
    cycles/px, from 0): (2 / pi) integral of MTF(f) sin(pi f) / f df, dimensionless."""
    f = np.asarray(f_cyc_px, float)
    kernel = np.where(f > 0, np.sin(np.pi * f) / np.where(f > 0, f, 1.0), np.pi)
    return (2.0 / np.pi) * np.trapezoid(np.asarray(mtf) * kernel, f, axis=-1)


@dataclass(frozen=True, eq=False)
class NiirsInputs:
    """What the NIIRS predictor holds fixed for a base scenario's product: the static
    system MTF (F,) at :data:`NIIRS_FREQS` (the optics, :meth:`camera.optics.Optics.mtf`,
    times the detector's box footprint |sinc f|), the GSD (m,
    :func:`imc.wiring.product.gsd_m`), the product target's contrast SNR and the elevation
    (rad) as the product measures them (:func:`imc.wiring.product.measure_quality`)."""

    static_mtf: np.ndarray
    gsd_m: float
    snr: float
    elevation_rad: float

    @classmethod
    def from_models(cls, m) -> NiirsInputs:
        """The inputs of a built run (``imc.wiring.build.build_models``).

        The contrast SNR is the product target's (:func:`scene.targets.slanted_square`: its
        square, half the product's smaller side, of albedo SQUARE_ALBEDO[1] on
        SQUARE_ALBEDO[0], the product's mean set to the sensor's mean level): the two
        albedos' difference in DN over the sensor's noise at the square's level, for the
        main imager's integration time.
        """
        from imc.wiring.product import gsd_m
        from scene.targets import SQUARE_ALBEDO

        sc = m.scenario
        lines, cols = sc.product.lines, sc.product.cols
        n = min(lines, max(cols, 256))  # the target's lines (imc.wiring.product.target_window)
        frac = (0.5 * min(n, cols)) ** 2 / (n * cols)
        lo, hi = SQUARE_ALBEDO
        mean_albedo = lo + (hi - lo) * frac
        s = m.sensor
        dn_hi = s.mean_signal_dn * hi / mean_albedo
        contrast = s.mean_signal_dn * (hi - lo) / mean_albedo
        sigma = float(s.noise_sigma_dn_at(dn_hi * s.gain_e_per_dn,
                                          float(m.imager.integration_s())))
        off_nadir = float(m.main_camera.attitude.off_nadir_deg(m.main_camera.orbit, 0.0))
        f = NIIRS_FREQS
        return cls(m.optics.mtf(f) * np.abs(np.sinc(f)), gsd_m(m), contrast / sigma,
                   float(np.deg2rad(90.0 - off_nadir)))

    def rer_static(self) -> float:
        """The static product's RER (both axes alike), dimensionless."""
        return float(rer_from_mtf(NIIRS_FREQS, self.static_mtf))

    def loss(self, motion_mtf: np.ndarray, var_px2) -> tuple[float, np.ndarray]:
        """NIIRS loss (GIQE 5, :func:`ground.quality.niirs_giqe5`) of the product against
        the static one, and the RER per axis (2,) with the motion: the worst exposure's
        motion MTF ``motion_mtf`` (F, 2) at :data:`NIIRS_FREQS` times the Gaussian of the
        random and noise residual of variance ``var_px2`` (2,) px^2, times the static
        system MTF; the GSD, SNR and elevation unchanged."""
        loss, rer = self.losses(motion_mtf, np.asarray(var_px2, float)[None, :])
        return float(loss[0]), rer[0]

    def losses(self, motion_mtf: np.ndarray, var_px2: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`loss` of one motion MTF ``motion_mtf`` (F, 2) with each of the residual
        variances ``var_px2`` (n, 2) px^2: the NIIRS losses (n,) (inf where an RER is not
        positive) and the RERs (n, 2); the static product's NIIRS computed once."""
        from ground.quality import niirs_giqe5

        f = NIIRS_FREQS
        var = np.asarray(var_px2, float)
        gauss = np.exp(-2.0 * np.pi**2 * var[:, None, :] * f[None, :, None] ** 2)
        rer = rer_from_mtf(f, np.swapaxes(self.static_mtf[None, :, None] * motion_mtf[None]
                                          * gauss, 1, 2))
        r0 = self.rer_static()
        n0 = niirs_giqe5(r0, r0, self.gsd_m, self.snr, self.elevation_rad)
        out = np.full(len(var), np.inf)
        for i in np.flatnonzero(np.all(rer > 0, axis=1)):  # pyBSM's GIQE 5 takes scalars
            out[i] = n0 - niirs_giqe5(rer[i, 0], rer[i, 1], self.gsd_m, self.snr,
                                      self.elevation_rad)
        return out, rer

"""Design: from requirements to the cheapest configuration that meets them (`imc design`).

A design file names a ``base`` scenario (the fixed parts: orbit, attitude and jitter,
scene, main imager), ``requirements`` (bounds, as ``expect:`` states them, on the metric
paths of :data:`imc.workflow.predict.SUPPORTED`), the ``free`` parameters (choices, or
ranges ``{min, max, n, scale}``) and the ``cost`` weights. The search evaluates every
combination with the fast predictors of :mod:`imc.workflow.predict` (the loops once each,
the tracker and ground parts vectorised over them), keeps the feasible set and the Pareto
front (cost against the worst relative margin), picks the cheapest candidate whose worst
predicted margin is at least ``margin`` (the predictor's validated error), runs the best
``verify.designs`` candidates as full scenarios with ``verify.seeds`` seeds, and writes
design.json, design.html and the chosen design as a scenario YAML with its requirements as
``expect:``.

Relative margin of a requirement: (bound - value) / |bound| for a maximum, (value - bound) /
|bound| for a minimum; for a motion-MTF minimum it is on the loss: (value - bound) / (1 -
bound). Negative: the requirement is missed.
"""

from __future__ import annotations

import copy
import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from imc.scenario import (
    BoundConfig,
    Scenario,
    ScenarioError,
    format_validation_error,
    parse_scenario,
)
from imc.workflow.predict import (
    NIIRS_PATH,
    SUPPORTED,
    Disturbance,
    LoopChoice,
    LoopJobs,
    NiirsInputs,
    actuator_block,
    bound_frame0,
    chain_break_probability,
    chain_overlap,
    controller_block,
    correlator_efficiency,
    image_flow_px_per_s,
    min_valid_fraction,
    nominal_line_rate_hz,
    product_span_s,
    residual_figures,
    search_record_geometry,
    tracker_bound,
    tracker_bounds,
    tracker_snr,
)

#: the most designs a verification runs (each with its seeds)
MAX_VERIFY = 3
#: the default predicted margin a chosen design keeps (the 25 % target of the predictors)
DEFAULT_MARGIN = 0.25
#: the most frames of a run, expected, where a scanning tracker's chain breaks (too few
#: blocks valid to re-reference) or a fixed reference's frame has no valid block
MAX_EXPECTED_BREAKS = 0.1
#: the checks besides the requirements, as a candidate's limiting reason names them
CHECKS = ("loop stability", "block grid",
          "frame overlap (too few blocks' content reaches the next frame)",
          "blocks valid per frame (the tracker's chain or record breaks)", "stage stroke")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class RangeConfig(_Model):
    """A numeric range sampled at ``n`` points (``scale`` log or linear), ends included."""

    min: float = Field(gt=0.0, description="lowest value")
    max: float = Field(gt=0.0, description="highest value")
    n: int = Field(5, ge=1, le=200, description="points")
    scale: Literal["log", "linear"] = Field("log", description="log or linear spacing")

    @model_validator(mode="after")
    def _order(self) -> RangeConfig:
        if self.max < self.min:
            raise ValueError("max is below min; give min <= max")
        return self

    def values(self) -> list[float]:
        if self.n == 1 or self.max == self.min:
            return [self.min]
        f = np.geomspace if self.scale == "log" else np.linspace
        return [float(round(v, 9)) for v in f(self.min, self.max, self.n)]


Numbers = tuple[float, ...] | RangeConfig


def _values(v: Numbers) -> list[float]:
    return v.values() if isinstance(v, RangeConfig) else [float(x) for x in v]


class FreeConfig(_Model):
    """The free parameters: lists of choices, or numeric ranges."""

    frame_rate_hz: Numbers = Field((100.0,), description="tracker frame rates, Hz")
    block_px: tuple[int, ...] = Field((64,), min_length=1, description="block sides, px")
    n_blocks: tuple[int, ...] = Field((4,), min_length=1, description="block counts")
    controller: tuple[Literal["integrator", "kalman"], ...] = Field(
        ("kalman",), min_length=1, description="controller kinds")
    bandwidth_hz: Numbers = Field((10.0,), description="controller bandwidths, Hz (integrator:"
                                  " gain = 2 pi bandwidth / rate)")
    stage: tuple[Literal["none", "ideal", "piezo"], ...] = Field(
        ("ideal",), min_length=1, description="stages (none: open loop)")
    piezo_resonance_hz: Numbers = Field((357.0,), description="piezo first resonance, Hz")
    piezo_stroke_px: Numbers = Field((4.5,), description="piezo stroke, px")
    ground: tuple[Literal["none", "correction"], ...] = Field(
        ("none",), min_length=1, description="ground processing: none, or correction by the "
        "motion record (a geometry-only product)")

    @field_validator("frame_rate_hz", "bandwidth_hz", "piezo_resonance_hz", "piezo_stroke_px",
                     mode="before")
    @classmethod
    def _range_or_list(cls, v):
        if isinstance(v, dict):
            try:
                return RangeConfig.model_validate(v)
            except ValidationError as e:
                first = e.errors()[0]
                where = ".".join(str(p) for p in first["loc"])
                msg = first["msg"].removeprefix("Value error, ")
                raise ValueError(f"{where + ': ' if where else ''}{msg} (a range is "
                                 "{min, max, n, scale})") from None
        if isinstance(v, int | float):
            return (v,)
        if not isinstance(v, list | tuple):
            raise ValueError("give a list of values or a range {min, max, n, scale}")
        return v

    @field_validator("frame_rate_hz", "bandwidth_hz", "piezo_resonance_hz", "piezo_stroke_px")
    @classmethod
    def _positive(cls, v):
        vals = _values(v)
        if not vals or any(not (x > 0 and math.isfinite(x)) for x in vals):
            raise ValueError("give positive finite values (a list, or {min, max, n})")
        return v

    @field_validator("block_px", "n_blocks")
    @classmethod
    def _ints(cls, v):
        if any(x < 1 for x in v):
            raise ValueError("give positive integers")
        return v


class CostConfig(_Model):
    """Cost weights (dimensionless units). Default: hardware rates and the stage count.

    cost = rate * rate_hz / 100 + correlator * rate_hz n_blocks block_px^2 / (100 * 4 * 64^2)
         + stage[kind] + stroke * stroke_px / 4.5 + resonance * resonance_hz / 1000 (piezo)
         + controller[kind] + ground[kind]
    """

    rate: float = Field(1.0, ge=0.0, description="per 100 Hz of tracker frame rate")
    correlator: float = Field(1.0, ge=0.0, description="per 4 blocks of 64^2 px at 100 Hz")
    stage: dict[str, float] = Field({"none": 0.0, "piezo": 2.0, "ideal": 4.0},
                                    description="presence of a stage, per kind")
    stroke: float = Field(0.5, ge=0.0, description="per 4.5 px of piezo stroke")
    resonance: float = Field(0.5, ge=0.0, description="per kHz of piezo resonance")
    controller: dict[str, float] = Field({"integrator": 0.0, "kalman": 0.2},
                                         description="per controller kind")
    ground: dict[str, float] = Field({"none": 0.0, "correction": 0.5},
                                     description="per ground processing kind")


class VerifyConfig(_Model):
    designs: int = Field(MAX_VERIFY, ge=0, le=MAX_VERIFY, description="designs run in full")
    seeds: int = Field(3, ge=1, le=10, description="seeds per design")
    fidelity: Literal["texture", "rendered", "analytic"] = Field(
        "texture", description="the plant of the runs; the tracker predictor scales the bound "
        "by this plant's calibrated correlator efficiency (imc.workflow.predict."
        "CORRELATOR_EFFICIENCY; analytic: 1 by construction)")


class DesignConfig(_Model):
    """A design file (see the module docstring)."""

    name: str = Field("design", min_length=1, max_length=200)
    base: str | dict = Field(description="the base scenario: a file (relative to the design) "
                             "or a mapping")
    requirements: dict[str, BoundConfig] = Field(min_length=1)
    free: FreeConfig = FreeConfig()
    cost: CostConfig = CostConfig()
    margin: float = Field(DEFAULT_MARGIN, ge=0.0, le=1.0, description="the predicted relative "
                          "margin the chosen design keeps (the predictors' validated error)")
    tracker_crlb_px: float | None = Field(None, gt=0.0, description="the tracker's bound per "
                                          "block at the base's block_px (none: computed from "
                                          "the base scene)")
    verify: VerifyConfig = VerifyConfig()

    @field_validator("requirements")
    @classmethod
    def _paths(cls, v: dict) -> dict:
        for path in v:
            if path not in SUPPORTED:
                raise ValueError(f"{path!r} has no predictor; supported: "
                                 "with_compensation.rms_total_px, with_compensation.rms_px "
                                 "(.0 row, .1 col), with_compensation.mtf_nyquist_worst (.0, "
                                 ".1), loop.lock.analytic_s, product.geometry.open.after.rms_px"
                                 ", product.geometry.open.affine.rms_px, "
                                 "product.quality.closed.niirs_loss")
        return v


@dataclass(frozen=True)
class Design:
    """A loaded design: its config, the base scenario and its raw mapping, and the folder
    relative paths start from."""

    config: DesignConfig
    base: Scenario
    base_raw: dict
    folder: Path


def parse_design(data: object, source: str = "design", folder: Path = Path(".")) -> Design:
    """Validate a mapping into a Design (a one-line ScenarioError naming the field)."""
    from imc.yamlload import load_yaml, read_text

    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: the top level must be a mapping (name, base, "
                            "requirements, free, cost, margin, verify)")
    try:
        cfg = DesignConfig.model_validate(data)
    except ValidationError as e:
        raise ScenarioError(format_validation_error(e, source, data)) from None
    if isinstance(cfg.base, str):
        path = (folder / cfg.base)
        raw = load_yaml(read_text(path))
        sc_folder = path.parent
    else:
        raw, sc_folder = copy.deepcopy(cfg.base), folder
    if not isinstance(raw, dict):
        raise ScenarioError(f"{source}: base: must be a scenario mapping or file")
    try:
        base = parse_scenario(raw, f"{source}: base")
    except ScenarioError as e:
        raise ScenarioError(str(e)) from None
    Disturbance.from_scenario(base)  # refuse a jitter with no predictor now
    return Design(cfg, base, raw, sc_folder)


def load_design(path: str | Path) -> Design:
    """A design file (YAML) loaded and validated."""
    from imc.yamlload import load_yaml, read_text

    p = Path(path)
    return parse_design(load_yaml(read_text(p)), str(p), p.parent)


# ------------------------------------------------------------------------------ candidates


@dataclass(frozen=True, eq=False)
class Candidates:
    """Every evaluated candidate as columns (index i), its predictions and margins."""

    columns: dict[str, np.ndarray]
    predicted: dict[str, np.ndarray]  # requirement path -> (n,) value (worse axis)
    margins: np.ndarray  # (n, R) relative margins
    feasible: np.ndarray  # (n,) bool: every margin >= 0 and the extra checks pass
    limiting: np.ndarray  # (n,) object: the requirement (or check) that limits
    worst: np.ndarray  # (n,) worst margin
    cost: np.ndarray
    eval_s: float  # the whole evaluation, s
    n_loops: int
    loop_s: float  # until the loops' predictions were all in (the base's part overlapping), s
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    base_crlb_px: float | None = None  # the tracker's bound per block at the base's size
    base_s: float = 0.0  # the base's models and the tracker's bounds, s

    def __len__(self) -> int:
        return len(self.cost)

    def row(self, i: int) -> dict:
        """Candidate i as a plain mapping (parameters, cost, predictions, margins)."""
        out = {k: _plain(v[i]) for k, v in self.columns.items()}
        out["cost"] = float(self.cost[i])
        out["predicted"] = {k: float(v[i]) for k, v in self.predicted.items()}
        out["worst_margin"] = float(self.worst[i])
        out["limiting"] = str(self.limiting[i])
        out["feasible"] = bool(self.feasible[i])
        return out


def _plain(v):
    if isinstance(v, np.generic):
        return v.item()
    return v


def base_crlb_px(design: Design) -> float:
    """The tracker's bound per block (px) at the base's block size, mean of the axes
    (:func:`imc.workflow.predict.tracker_bound` on the base scene), over the square root of
    the fraction of blocks the correlator keeps there (a refused block does not average)."""
    if design.config.tracker_crlb_px is not None:
        return design.config.tracker_crlb_px
    fid = design.config.verify.fidelity
    m, rad = bound_frame0(design.base, fid)
    crlb, kept = tracker_bound(m, fid, radiance=rad)
    return float(np.mean(crlb) / np.sqrt(kept))


def base_tracker_snr(design: Design) -> float:
    """The base's tracker SNR (:func:`imc.workflow.predict.tracker_snr`; the correlator's
    efficiency depends on it)."""
    from imc.wiring.build import build_models

    return tracker_snr(build_models(design.base, light=True))


def loop_choices(free: FreeConfig) -> list[LoopChoice]:
    """Every distinct loop of the free parameters (stage 'none': one per rate)."""
    out = []
    for rate in _values(free.frame_rate_hz):
        for stage in free.stage:
            if stage == "none":
                out.append(LoopChoice(rate, "integrator", 0.0, "none"))
                continue
            res = _values(free.piezo_resonance_hz) if stage == "piezo" else [0.0]
            for ctl, bw, r in itertools.product(free.controller, _values(free.bandwidth_hz),
                                                res):
                out.append(LoopChoice(rate, ctl, bw, stage, r))
    return out


def margin_of(path: str, bound: BoundConfig, v: np.ndarray) -> np.ndarray:
    """Relative margins of values ``v`` against a bound (see the module docstring)."""
    lo, hi = bound.lo_hi
    m = np.full(v.shape, np.inf)
    if math.isfinite(hi):
        m = np.minimum(m, (hi - v) / max(abs(hi), 1e-12))
    if math.isfinite(lo):
        den = (1.0 - lo) if "mtf" in path and lo < 1.0 else max(abs(lo), 1e-12)
        m = np.minimum(m, (v - lo) / den)
    return np.where(np.isfinite(v), m, -np.inf)


def evaluate(design: Design, progress: Callable[[int, int], None] | None = None,
             crlb_px: float | None = None, workers: int = 1, fast: bool = True
             ) -> Candidates:
    """Every candidate of the free parameters predicted, with margins, feasibility, the
    limiting requirement and the cost; ``fast`` False: the reference evaluation (each loop
    alone, :func:`imc.workflow.predict.predict_loops`'s reference)."""
    cfg, base = design.config, design.base
    free, w = cfg.free, cfg.cost
    t0 = time.perf_counter()
    dist = Disturbance.from_scenario(base)
    crlb = crlb_px if crlb_px is not None else cfg.tracker_crlb_px
    b0 = base.correlator.block_px
    rate0 = base.camera.tracker.frame_rate_hz
    radiometric = base.camera.tracker.signal == "radiometric"
    loops = loop_choices(free)
    # the loops on the workers; the base's models and the tracker's bounds meanwhile here
    with LoopJobs(loops, base, dist, lock="loop.lock.analytic_s" in cfg.requirements,
                  workers=workers, progress=progress, fast=fast) as jobs:
        # the candidates: each loop x blocks x counts x strokes x ground
        cols: dict[str, list] = {k: [] for k in ("loop", "stroke_px", "block_px", "n_blocks",
                                                 "ground")}
        strokes = _values(free.piezo_stroke_px)
        for li, ch in enumerate(loops):
            st = strokes if ch.stage == "piezo" else [0.0]
            for b, n, s, g in itertools.product(free.block_px, free.n_blocks, st, free.ground):
                cols["loop"].append(li)
                cols["stroke_px"].append(s)
                cols["block_px"].append(b)
                cols["n_blocks"].append(n)
                cols["ground"].append(g)
        li = np.array(cols["loop"], int)
        b = np.array(cols["block_px"], float)
        nb = np.array(cols["n_blocks"], float)
        stroke = np.array(cols["stroke_px"], float)
        ground = np.array(cols["ground"], object)
        rate = np.array([c.rate_hz for c in loops])[li]
        stage = np.array([c.stage for c in loops], object)[li]
        ctl = np.array([c.controller for c in loops], object)[li]
        bw = np.array([c.bandwidth_hz for c in loops])[li]
        res = np.array([c.resonance_hz for c in loops])[li]
        # the tracker: bound x efficiency x (b0 / b) / sqrt(n); radiometric signal: shot noise
        # with exposure
        efficiency = correlator_efficiency(cfg.verify.fidelity, base.scene.kind)
        from imc.wiring.build import build_models

        t_base = time.perf_counter()
        if crlb is None:  # each block size's own bound on the base scene's frame 0 (built
            # once: a procedural tile only under the footprint)
            m, rad = bound_frame0(base, cfg.verify.fidelity)
            eff = efficiency.at(tracker_snr(m), b)
            table = tracker_bounds(m, free.block_px, cfg.verify.fidelity, radiance=rad)
            per_block = np.array([table[int(x)][0] for x in b])
            p_kept = np.array([table[int(x)][1] for x in b])
            # the record's base bound
            crlb0, kept0 = tracker_bound(m, cfg.verify.fidelity, radiance=rad)
            base_crlb = float(np.mean(crlb0) / np.sqrt(kept0))
        else:  # a given bound at the base's block size, as one over the block's side
            m = build_models(base, light=True)
            eff = efficiency.at(tracker_snr(m), b)
            per_block = crlb * (b0 / b)
            p_kept = np.ones(len(b))
            base_crlb = float(crlb)
        rows, cols_px = base.camera.tracker.rows, base.camera.tracker.cols
        grid_ok = nb <= np.floor(rows / b) * np.floor(cols_px / b)
        if m.chain:  # a scanning tracker: each frame against the one before (the loop's chain)
            # the blocks whose content reaches the next frame, placed and cut as the tracker
            # does; the chain holds while the estimator finds enough of them valid in every
            # frame: the expected number of frames of the run where it breaks stays below
            # MAX_EXPECTED_BREAKS (it does not recover: the old reference's content leaves)
            flow = image_flow_px_per_s(m)
            n_eff = np.zeros(len(b))
            for r_hz, b_px, n_b in set(zip(rate.tolist(), b.tolist(), nb.tolist(), strict=True)):
                sel = (rate == r_hz) & (b == b_px) & (nb == n_b)
                n_eff[sel] = chain_overlap(rows, cols_px, int(b_px), int(n_b), flow / r_hz) \
                    if grid_ok[sel][0] else 0
            p_break = chain_break_probability(n_eff, nb, p_kept, min_valid_fraction(base))
            overlap_ok = p_break < 1.0
            breaks = p_break * rate * base.duration_s
        else:  # a fixed reference: the record's network needs a valid block in every frame of
            # the product's span (ground correction)
            n_eff = nb.copy()
            overlap_ok = np.ones(len(b), bool)
            breaks = np.where(ground == "correction",
                              (1.0 - p_kept) ** nb * rate * product_span_s(base), 0.0)
        kept_ok = np.isfinite(per_block) & (breaks <= MAX_EXPECTED_BREAKS)
        # the motion-field fit averages the blocks that overlap (each valid with p_kept: the
        # per-block bound carries it)
        sigma = np.where(kept_ok & overlap_ok, per_block, np.nan) * eff \
            / np.sqrt(np.maximum(n_eff, 1.0))
        if radiometric:
            sigma = sigma * np.sqrt(rate / rate0)
        base_s = time.perf_counter() - t_base
        preds = jobs.results()
    loop_s = time.perf_counter() - t0
    ok = np.array([p.ok for p in preds])[li]
    det = np.array([p.rms_det_px for p in preds], float)[li]
    var_rnd = np.array([p.var_rnd_px2 for p in preds], float)[li]
    var_rnd_blur = np.array([p.var_rnd_blur_px2 for p in preds], float)[li]
    gain = np.array([p.noise_gain for p in preds], float)[li]
    gain_blur = np.array([p.noise_gain_blur for p in preds], float)[li]
    mtf_det = np.array([p.mtf_det_worst for p in preds], float)[li]
    lock = np.array([p.lock_s for p in preds], float)[li]
    rms, total, mtf, blur = residual_figures(det, var_rnd, gain, sigma, mtf_det, var_rnd_blur,
                                             gain_blur)
    # the record's geometry after correction over the product's span (a TDI strip's lines)
    staring = base.attitude.mode == "target"
    if staring:
        kmax = np.zeros(len(li), int)  # every frame against one reference
    elif base.product.restitution.baselines:
        kmax = np.full(len(li), int(base.product.restitution.baselines))
    else:  # the overlap's baselines (imc.wiring.links.overlap_baselines)
        from imc.wiring.links import OVERLAP_MARGIN_PX

        room = base.camera.tracker.rows - b - OVERLAP_MARGIN_PX
        kmax = np.maximum(1, np.floor(room / (nominal_line_rate_hz(base) / rate))).astype(int)
    corr = ground == "correction"
    geo_c, geo_a, net_c, net_a = search_record_geometry(base, m, dist, rate, kmax, b, nb,
                                                        sigma, corr & np.isfinite(sigma))
    values = {
        "with_compensation.rms_px": rms,
        "with_compensation.rms_px.0": rms[:, 0],
        "with_compensation.rms_px.1": rms[:, 1],
        "with_compensation.rms_total_px": total,
        "with_compensation.mtf_nyquist_worst": mtf,
        "with_compensation.mtf_nyquist_worst.0": mtf[:, 0],
        "with_compensation.mtf_nyquist_worst.1": mtf[:, 1],
        "loop.lock.analytic_s": lock,
        "product.geometry.open.after.rms_px": geo_c,
        "product.geometry.open.affine.rms_px": geo_a,
    }
    if NIIRS_PATH in cfg.requirements:
        values[NIIRS_PATH] = niirs_losses(m, preds, li, ok, blur)
    reqs = list(cfg.requirements.items())
    predicted, margins = {}, []
    for path, bound in reqs:
        v = values[path]
        if v.ndim == 2:  # a per-axis list: the worse axis decides
            m2 = np.stack([margin_of(path, bound, v[:, k]) for k in range(2)], 1)
            k = np.argmin(m2, axis=1)
            v = v[np.arange(len(v)), k]
            m = m2.min(axis=1)
        else:
            m = margin_of(path, bound, v)
        predicted[path] = v
        margins.append(m)
    marg = np.stack(margins, 1)
    names = np.array(list(CHECKS) + [p for p, _ in reqs], object)
    # the stroke spans -stroke / 2 .. stroke / 2 about frame 0's position; 10 % to spare
    peak = dist.open_peak_px(base.duration_s, 0.5 / rate0).max()
    stroke_ok = (stage != "piezo") | (stroke >= 2.2 * peak)
    passes = [ok, grid_ok, grid_ok & overlap_ok, grid_ok & overlap_ok & kept_ok, stroke_ok]
    extra = np.stack([np.where(x, np.inf, -np.inf) for x in passes], 1)
    # a failed check limits before a requirement (whose value it may leave undefined)
    allm = np.concatenate([extra, marg], 1)
    k = np.argmin(allm, axis=1)
    worst = marg.min(axis=1)
    checks = np.logical_and.reduce(passes)
    worst = np.where(checks, worst, -np.inf)
    feasible = checks & (marg.min(axis=1) >= 0.0)
    # cost
    piezo = stage == "piezo"
    cost = (w.rate * rate / 100.0 + w.correlator * rate * nb * b**2 / (100.0 * 4 * 64**2)
            + np.array([w.stage.get(s, 0.0) for s in stage])
            + np.where(piezo, w.stroke * stroke / 4.5 + w.resonance * res / 1000.0, 0.0)
            + np.array([0.0 if s == "none" else w.controller.get(c, 0.0)
                        for s, c in zip(stage, ctl, strict=True)])
            + np.array([w.ground.get(g, 0.0) for g in ground]))
    columns = {"frame_rate_hz": rate, "block_px": b.astype(int), "n_blocks": nb.astype(int),
               "controller": np.where(stage == "none", "-", ctl), "bandwidth_hz": bw,
               "stage": stage, "piezo_resonance_hz": res, "piezo_stroke_px": stroke,
               "ground": ground}
    return Candidates(columns, predicted, marg, feasible, names[k], worst, cost,
                      time.perf_counter() - t0, len(loops), loop_s,
                      {"sigma_px": sigma, "blocks_overlapping": n_eff,
                       "block_valid_probability": p_kept, "expected_breaks": breaks,
                       # (n, 2 constant / affine, 2 axes) px: the record's network part
                       "geometry_net_px": np.stack([net_c, net_a], axis=1)},
                      base_crlb, base_s)


def niirs_losses(m, preds: list, li: np.ndarray, ok: np.ndarray,
                 blur_px2: np.ndarray) -> np.ndarray:
    """Each candidate's predicted NIIRS loss (:class:`imc.workflow.predict.NiirsInputs`:
    the base's product from its built models ``m``, the candidate loop's worst-exposure
    motion MTF and its noise and random residual's variance ``blur_px2`` (n, 2) about an
    exposure's mean); NaN for a refused loop."""
    ni = NiirsInputs.from_models(m)
    out = np.full(len(li), np.nan)
    for j in np.unique(li[ok]):  # each loop's motion MTF with its candidates' variances
        sel = np.flatnonzero(ok & (li == j))
        out[sel] = ni.losses(preds[j].mtf_det_curve, blur_px2[sel])[0]
    return out


def pareto_front(cost: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """Indices of the Pareto front: no other candidate is cheaper (or as cheap) with a
    larger (or as large) margin; sorted by cost."""
    order = np.lexsort((-margin, cost))
    front, best = [], -np.inf
    for i in order:
        if margin[i] > best:
            front.append(i)
            best = margin[i]
    return np.array(front, int)


def choose(c: Candidates, margin: float) -> tuple[int | None, str]:
    """The chosen candidate: the cheapest whose worst margin >= ``margin`` (ties: the
    larger margin); else the cheapest feasible one (said so); None if none is feasible."""
    keep = np.flatnonzero(c.feasible & (c.worst >= margin))
    if keep.size:
        i = keep[np.lexsort((-c.worst[keep], c.cost[keep]))[0]]
        return int(i), "cheapest with the predicted margin"
    keep = np.flatnonzero(c.feasible)
    if keep.size:
        i = keep[np.lexsort((-c.worst[keep], c.cost[keep]))[0]]
        return int(i), (f"cheapest feasible; its margin {c.worst[i]:.2f} is below the "
                        f"predictors' validated error {margin:.2f}")
    return None, "no candidate meets every requirement"


def closest_line(c: Candidates) -> str:
    """One line: the closest candidate (largest worst margin) and what limits it."""
    finite = np.where(np.isfinite(c.worst), c.worst, -1e300)
    i = int(np.argmax(finite))
    r = c.row(i)
    pred = r["predicted"].get(r["limiting"])
    shown = f" = {pred:.4g}" if pred is not None and math.isfinite(pred) else ""
    return (f"no candidate meets every requirement; the closest ({describe(r)}) is limited "
            f"by {r['limiting']}{shown} (margin {r['worst_margin']:.2f})")


def describe(r: dict) -> str:
    """A candidate's parameters in a few words."""
    st = r["stage"]
    parts = [f"{r['frame_rate_hz']:g} Hz", f"{r['n_blocks']} x {r['block_px']} px"]
    if st != "none":
        parts.append(f"{r['controller']} {r['bandwidth_hz']:.3g} Hz")
    parts.append(st + (f" {r['piezo_resonance_hz']:g} Hz {r['piezo_stroke_px']:g} px"
                       if st == "piezo" else ""))
    parts.append(f"ground {r['ground']}")
    return ", ".join(parts)


def best_few(c: Candidates, chosen: int | None, margin: float, cap: int) -> list[int]:
    """The chosen design and the next cheapest distinct designs with the margin (cap)."""
    if chosen is None or cap <= 0:
        return []
    out = [chosen]
    keep = np.flatnonzero(c.feasible & (c.worst >= margin))
    for i in keep[np.lexsort((-c.worst[keep], c.cost[keep]))]:
        if len(out) >= cap:
            break
        if int(i) not in out:
            out.append(int(i))
    return out


# ------------------------------------------------------------------------------ scenarios


def candidate_mapping(design: Design, r: dict, seed_offset: int = 0,
                      fidelity: str | None = None) -> dict:
    """The scenario mapping of a candidate row (the base's raw mapping, the free parameters
    set, the requirements as ``expect:``)."""
    m = copy.deepcopy(design.base_raw)
    base = design.base
    m["name"] = f"{design.config.name}_design"
    m["seed"] = int(base.seed) + seed_offset
    cam = m.setdefault("camera", {})
    tr = cam.setdefault("tracker", {})
    rate = float(r["frame_rate_hz"])
    tr["frame_rate_hz"] = rate
    if tr.get("exposure_s") is not None and tr["exposure_s"] > 1.0 / rate:
        tr.pop("exposure_s")
    co = m.setdefault("correlator", {})
    co["block_px"], co["n_blocks"] = int(r["block_px"]), int(r["n_blocks"])
    comp = m.setdefault("compensation", {})
    comp.pop("gain", None)
    if "latency_frames" in comp:
        comp.setdefault("transport", {})["latency_frames"] = comp.pop("latency_frames")
    ch = LoopChoice(rate, r["controller"] if r["stage"] != "none" else "integrator",
                    float(r["bandwidth_hz"]) or 1.0,
                    r["stage"], float(r["piezo_resonance_hz"]))
    comp["enabled"] = r["stage"] != "none"
    if r["stage"] != "none":
        comp["controller"] = controller_block(ch, base)
        comp["actuator"] = actuator_block(ch, base, float(r["piezo_stroke_px"]) or None)
    m.setdefault("plant", {})["fidelity"] = fidelity or design.config.verify.fidelity
    for key in ("sigma_px", "noise", "noise_texel_m"):  # the bound the prediction assumes
        m["plant"].pop(key, None)
    m.setdefault("metrics", {})["blur_images"] = False
    niirs = NIIRS_PATH in design.config.requirements
    if r["ground"] == "correction" or niirs:
        prod = m.setdefault("product", {})
        prod["enabled"] = True
        if niirs:  # NIIRS is measured on the rendered product
            prod["render"] = True
        else:
            prod.setdefault("render", False)
    elif isinstance(m.get("product"), dict):
        m["product"]["enabled"] = False
    m["expect"] = {measured_path(p, r["stage"]): b.model_dump(exclude_none=True)
                   for p, b in design.config.requirements.items()}
    for b in m["expect"].values():
        if "within" in b:
            b["within"] = list(b["within"])
    return m


#: the predictors' validation targets (issue 33): residual RMS within 25 % or 0.003 px;
#: motion-MTF loss (1 - MTF) within 25 % or 0.005; geometry within 1.5x
TARGET_RMS = (0.25, 0.003)
TARGET_MTF_LOSS = (0.25, 0.005)
TARGET_GEOMETRY = 1.5


def within_target(path: str, predicted: float, measured: float) -> bool | None:
    """Whether a prediction is within its validation target of a measured value (None: the
    metric has no target, e.g. lock time and NIIRS loss, reported only)."""
    if not (math.isfinite(predicted) and math.isfinite(measured)):
        return False
    if "rms_px" in path and "geometry" not in path or path.endswith("rms_total_px"):
        rel, ab = TARGET_RMS
        return abs(predicted - measured) <= max(rel * abs(measured), ab)
    if "mtf_nyquist" in path:
        rel, ab = TARGET_MTF_LOSS
        lp, lm = 1.0 - predicted, 1.0 - measured
        return abs(lp - lm) <= max(rel * abs(lm), ab)
    if "geometry" in path:
        return measured > 0 and 1.0 / TARGET_GEOMETRY <= predicted / measured <= TARGET_GEOMETRY
    return None


def measured_path(path: str, stage: str) -> str:
    """The metric path a requirement is measured on in a candidate's run: without a stage
    there is no closed product, so the NIIRS loss is the open product's."""
    if path == NIIRS_PATH and stage == "none":
        return "product.quality.open.niirs_loss"
    return path


def reduce_measured(path: str, bound: BoundConfig, value) -> float:
    """A measured metric reduced as the predictions are (the worse axis of a list)."""
    if isinstance(value, list | tuple):
        vals = [math.nan if v is None else float(v) for v in value]
        m = [float(margin_of(path, bound, np.array(v))) for v in vals]
        return vals[int(np.argmin(m))]
    return math.nan if value is None else float(value)


def verify(design: Design, c: Candidates, picks: list[int], out_dir: Path,
           log: Callable[[str], None] = print) -> list[dict]:
    """Run each picked candidate as a full scenario with the design's seeds; predicted
    against measured per requirement, and whether every seed met every requirement."""
    from imc.pipeline import run_scenario
    from imc.workflow.expect import lookup

    cfg = design.config
    rows = []
    for rank, i in enumerate(picks):
        r = c.row(i)
        measured: dict[str, list[float]] = {p: [] for p in cfg.requirements}
        passed, failures = [], []
        for s in range(cfg.verify.seeds):
            sc = parse_scenario(candidate_mapping(design, r, s), f"{cfg.name} candidate {i}")
            t0 = time.perf_counter()
            try:
                metrics, _ = run_scenario(sc, out_dir / f"verify{rank}" / f"seed{s}",
                                          rerun=False)
            except (ValueError, ScenarioError) as e:  # a run that breaks misses, reported
                why = str(e).splitlines()[0][:300]
                failures.append(f"seed {s}: {why}")
                for p in cfg.requirements:
                    measured[p].append(math.nan)
                passed.append(False)
                log(f"  design {rank} seed {s}: MISSES: the run failed ({why})")
                continue
            ok = True
            for p, b in cfg.requirements.items():
                try:
                    v = reduce_measured(p, b, lookup(metrics, measured_path(p, r["stage"])))
                except KeyError:
                    v = math.nan
                measured[p].append(v)
                ok &= bool(float(margin_of(p, b, np.array(v))) >= 0.0)
            passed.append(ok)
            log(f"  design {rank} seed {s}: {'meets' if ok else 'MISSES'} its requirements "
                f"({time.perf_counter() - t0:.1f} s)")
        err, merr, target = {}, {}, {}
        for p, b in cfg.requirements.items():
            pv, mv = r["predicted"][p], float(np.nanmean(measured[p]))
            err[p] = abs(pv - mv) / max(abs(mv), 1e-12) if math.isfinite(mv) else math.nan
            target[p] = within_target(p, pv, mv)
            merr[p] = abs(float(margin_of(p, b, np.array(pv)))
                          - float(margin_of(p, b, np.array(mv)))) if math.isfinite(mv) \
                else math.nan
        rows.append({"index": i, "rank": rank, "design": describe(r), "cost": r["cost"],
                     "predicted": r["predicted"], "measured": measured,
                     "relative_error": err, "margin_error": merr,
                     "within_target": target,
                     "all_seeds_pass": all(passed), "failed_runs": failures,
                     "seeds_passed": int(sum(passed))})
    return rows


# ------------------------------------------------------------------------------ outputs


@dataclass(frozen=True, eq=False)
class DesignResult:
    """What `imc design` found: the candidates, the front, the chosen one (None: none
    feasible), why, the verification rows and the files written."""

    candidates: Candidates
    front: np.ndarray
    chosen: int | None
    reason: str
    verified: list[dict]
    files: tuple[str, ...]

    @property
    def exit_code(self) -> int:
        return 0 if self.chosen is not None else 1


def _yaml_text(mapping: dict, header: str) -> str:
    import yaml

    body = yaml.safe_dump(mapping, sort_keys=False, default_flow_style=None, width=95)
    return "".join(f"# {line}\n" for line in header.splitlines()) + body


def sensitivity(c: Candidates, i: int) -> dict[str, list[dict]]:
    """The chosen design's sensitivity to each free parameter: the candidates that differ
    from candidate i in that parameter alone, with their worst margin, cost and limit."""
    out = {}
    for name, col in c.columns.items():
        same = np.ones(len(c), bool)
        for other, oc in c.columns.items():
            if other != name:
                same &= oc == oc[i]
        idx = np.flatnonzero(same)
        if len(idx) > 1:
            idx = idx[np.argsort(col[idx].astype(str) if col.dtype == object else col[idx],
                                 kind="stable")]
            out[name] = [{"value": _plain(col[j]), "worst_margin": float(c.worst[j]),
                          "cost": float(c.cost[j]), "limiting": str(c.limiting[j])}
                         for j in idx]
    return out


def correction_limit(design: Design, c: Candidates, n_freqs: int = 48) -> dict | None:
    """Up to which jitter frequency ground correction suffices without a stage: the
    cheapest feasible candidate with no stage and ground correction, its jitter's sinusoids
    (the base's amplitudes, axes and phases) moved together to each frequency from the
    base's to half the frame rate (log spaced), re-predicted: the geometry after correction
    adds the perfect record's interpolation floor (:func:`imc.workflow.predict.
    record_floor_px`) to the record's network error in quadrature; the residual RMS and the
    worst exposure's motion MTF are the open loop's at that frequency (a TDI line's blur,
    which no ground correction removes). Returns the highest frequency (Hz) below which
    every requirement so predicted holds, the requirement that fails above it, and the
    table; None when no such candidate is feasible or the base has no sinusoid. Lock time
    and NIIRS loss are not re-predicted (listed under ``not_repredicted``)."""
    import dataclasses

    from imc.wiring.build import build_models
    from imc.wiring.product import plan_product
    from imc.workflow.predict import predict_model, record_floor_px, tracker_exposure_s

    base, cfg = design.base, design.config
    dist = Disturbance.from_scenario(base)
    keep = np.flatnonzero(c.feasible & (c.columns["stage"] == "none")
                          & (c.columns["ground"] == "correction"))
    if not keep.size or not len(dist.sin_f_hz):
        return None
    i = int(keep[np.lexsort((-c.worst[keep], c.cost[keep]))[0]])
    r = c.row(i)
    rate = float(r["frame_rate_hz"])
    exposure = tracker_exposure_s(base, rate)
    plan = plan_product(build_models(base, light=True))
    f0 = float(dist.sin_f_hz.max())
    freqs = np.geomspace(f0, 0.5 * rate, n_freqs)
    sigma = float(c.extras["sigma_px"][i])
    # the record's network part (search_record_geometry's, without the base's floor)
    c_net, a_net = np.nan_to_num(c.extras["geometry_net_px"][i])
    table, f_max, why = [], f0, None
    for f in freqs:
        dist_f = dataclasses.replace(dist, sin_f_hz=dist.sin_f_hz * (f / f0))
        floor_c, floor_a = record_floor_px(dist_f, rate, exposure, base.duration_s,
                                           plan.line_t_s, plan.integration_s)
        p = predict_model(None, base, dist_f, exposure, lock=False)
        rms, total, mtf, _ = residual_figures(
            np.array(p.rms_det_px), np.array(p.var_rnd_px2), np.array(p.noise_gain), sigma,
            np.array(p.mtf_det_worst), np.array(p.var_rnd_blur_px2),
            np.array(p.noise_gain_blur))
        values = {"with_compensation.rms_px": rms, "with_compensation.rms_px.0": rms[0],
                  "with_compensation.rms_px.1": rms[1],
                  "with_compensation.rms_total_px": total,
                  "with_compensation.mtf_nyquist_worst": mtf,
                  "with_compensation.mtf_nyquist_worst.0": mtf[0],
                  "with_compensation.mtf_nyquist_worst.1": mtf[1],
                  "product.geometry.open.after.rms_px": np.hypot(c_net, floor_c),
                  "product.geometry.open.affine.rms_px": np.hypot(a_net, floor_a)}
        margins = {q: float(np.min(margin_of(q, b, np.atleast_1d(values[q]))))
                   for q, b in cfg.requirements.items() if q in values}
        worst_q = min(margins, key=margins.get) if margins else None
        table.append({"f_hz": float(f), "geometry_after_px": float(values[
            "product.geometry.open.after.rms_px"].max()), "geometry_affine_px": float(
            values["product.geometry.open.affine.rms_px"].max()),
            "mtf_nyquist_worst": float(mtf.min()), "worst_margin": margins.get(worst_q),
            "limiting": worst_q})
        if worst_q is not None and margins[worst_q] < 0.0:
            why = worst_q
            break
        f_max = float(f)
    return {"design": describe(r), "index": i, "frame_rate_hz": rate,
            "sinusoids": [{"axis": ("row", "col")[int(k)], "f_hz": float(f),
                           "amplitude_px": float(a)} for k, f, a in
                          zip(dist.sin_axis, dist.sin_f_hz, dist.sin_a_px, strict=True)],
            "base_f_hz": f0, "f_max_hz": f_max,
            "limited_by": why or "none up to half the frame rate",
            "not_repredicted": [q for q in cfg.requirements if q not in (
                "product.geometry.open.after.rms_px", "product.geometry.open.affine.rms_px")
                and not q.startswith("with_compensation.")],
            "table": table}


def design_json(design: Design, c: Candidates, front: np.ndarray, chosen: int | None,
                reason: str, verified: list[dict], crlb_px: float) -> dict:
    """The design's record (design.json)."""
    eff = correlator_efficiency(design.config.verify.fidelity, design.base.scene.kind)
    snr = base_tracker_snr(design)
    errs = [e for v in verified for e in v["margin_error"].values() if math.isfinite(e)]
    validated = max(errs) if errs else None
    return {
        "name": design.config.name,
        "requirements": {p: b.text() for p, b in design.config.requirements.items()},
        "predictors": {p: SUPPORTED[p] for p in design.config.requirements},
        "tracker_crlb_px": crlb_px,
        "tracker_snr": snr,
        "correlator_efficiency": eff.at(snr, design.base.correlator.block_px),
        "correlator_efficiency_at": "the base's block size (each candidate's own in "
                                    "its sigma_px)",
        "correlator_efficiency_spread": eff.spread,
        "correlator_efficiency_note": f"{design.config.verify.fidelity}: {eff.source}",
        "margin_required": design.config.margin,
        "candidates": len(c), "feasible": int(c.feasible.sum()), "loops": c.n_loops,
        "eval_s": c.eval_s, "loop_s": c.loop_s,
        "chosen": None if chosen is None else c.row(chosen),
        "sensitivity": {} if chosen is None else sensitivity(c, chosen),
        "reason": reason if chosen is not None else closest_line(c),
        "pareto": [c.row(int(i)) for i in front],
        "limiting_counts": {str(k): int(v) for k, v in zip(
            *np.unique(c.limiting.astype(str), return_counts=True), strict=True)},
        "verified": verified,
        # the predictors' validated error in margin units (|predicted - measured margin|,
        # the worst over the verified designs and requirements) and whether the chosen
        # design's predicted margin is at least that
        "validated_margin_error": validated,
        "chosen_margin_covers_validated_error": (None if chosen is None or validated is None
                                                 else bool(c.worst[chosen] >= validated)),
    }


def _fig_png(fig) -> str:
    import base64
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def design_html(record: dict, c: Candidates, front: np.ndarray, chosen: int | None) -> str:
    """design.html: the Pareto plot, the chosen design's margins, predicted against
    measured."""
    import html

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    w = np.clip(np.where(np.isfinite(c.worst), c.worst, -1.0), -1.0, None)
    ax.scatter(c.cost[~c.feasible], w[~c.feasible], s=4, c="0.75", label="infeasible")
    ax.scatter(c.cost[c.feasible], w[c.feasible], s=5, c="tab:blue", label="feasible")
    ax.plot(c.cost[front], w[front], "-o", c="tab:orange", ms=3, label="Pareto front")
    if chosen is not None:
        ax.plot([c.cost[chosen]], [w[chosen]], "r*", ms=14, label="chosen")
    ax.axhline(0.0, c="k", lw=0.7)
    ax.set_xlabel("cost (cost weights)")
    ax.set_ylabel("worst relative margin (predicted; clipped at -1)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    pareto_png = _fig_png(fig)
    plt.close(fig)
    esc = html.escape
    parts = [f"<h1>imc design: {esc(record['name'])}</h1>",
             f"<p>{record['candidates']} candidates ({record['loops']} loops) predicted in "
             f"{record['eval_s']:.2f} s; {record['feasible']} feasible. "
             f"{esc(record['reason'])}</p>",
             f'<img src="data:image/png;base64,{pareto_png}" alt="Pareto front">']
    ch = record["chosen"]
    if ch is not None:
        parts.append(f"<h2>Chosen: {esc(describe(ch))} (cost {ch['cost']:.3g})</h2><table>"
                     "<tr><th>requirement</th><th>bound</th><th>predicted</th><th>margin</th>"
                     "</tr>")
        for k, (p, b) in enumerate(record["requirements"].items()):
            parts.append(f"<tr><td>{esc(p)}</td><td>{esc(b)}</td><td>"
                         f"{ch['predicted'][p]:.4g}</td><td>"
                         f"{c.margins[chosen, k]:.2f}</td></tr>")
        parts.append("</table>")
    for name, rows in record.get("sensitivity", {}).items():
        parts.append(f"<h3>Sensitivity to {esc(name)} (the rest as chosen)</h3><table><tr>"
                     "<th>value</th><th>worst margin</th><th>cost</th><th>limited by</th>"
                     "</tr>" + "".join(
                         f"<tr><td>{esc(str(r['value']))}</td><td>{r['worst_margin']:.2f}"
                         f"</td><td>{r['cost']:.3g}</td><td>{esc(r['limiting'])}</td></tr>"
                         for r in rows) + "</table>")
    if record["verified"]:
        parts.append("<h2>Predicted against measured (full runs)</h2><p>Prediction target: "
                     "residual RMS within 25 % or 0.003 px, motion-MTF loss within 25 % or "
                     "0.005, geometry within 1.5x (others reported). A design whose run "
                     "misses a requirement, and a prediction off its target, are flagged."
                     "</p><table><tr><th>design</th><th>requirement</th><th>predicted</th>"
                     "<th>measured (seeds)</th><th>error</th><th>prediction</th>"
                     "<th>all seeds pass</th></tr>")
        for v in record["verified"]:
            for p in record["requirements"]:
                ms = ", ".join(f"{x:.4g}" for x in v["measured"][p])
                t = v.get("within_target", {}).get(p)
                verdict = "reported" if t is None else ("within target" if t else "MISSED")
                parts.append(f"<tr><td>{esc(v['design'])}</td><td>{esc(p)}</td><td>"
                             f"{v['predicted'][p]:.4g}</td><td>{ms}</td><td>"
                             f"{100 * v['relative_error'][p]:.0f} %</td><td>{verdict}</td><td>"
                             f"{'yes' if v['all_seeds_pass'] else 'NO'}</td></tr>")
        parts.append("</table>")
    parts.append("<h2>Limiting requirement (all candidates)</h2><table>" + "".join(
        f"<tr><td>{esc(k)}</td><td>{n}</td></tr>" for k, n in
        record["limiting_counts"].items()) + "</table>")
    style = ("<style>body{font-family:sans-serif;max-width:60em;margin:auto}"
             "td,th{border:1px solid #ccc;padding:2px 6px}table{border-collapse:collapse}"
             "</style>")
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>imc design "
            f"{esc(record['name'])}</title>{style}</head><body>" + "\n".join(parts)
            + "</body></html>\n")


def run_design(design: Design, out_dir: Path, verify_runs: bool = True,
               progress: Callable[[int, int], None] | None = None,
               log: Callable[[str], None] = print, crlb_px: float | None = None,
               workers: int = 1) -> DesignResult:
    """Search, choose, verify and write design.json, design.html and the chosen design's
    scenario (``<name>_design.yaml``)."""
    from imc.io import atomic_write, write_json

    c = evaluate(design, progress, crlb_px=crlb_px, workers=workers)
    crlb = c.base_crlb_px if c.base_crlb_px is not None else base_crlb_px(design)
    front = pareto_front(c.cost, c.worst)
    chosen, reason = choose(c, design.config.margin)
    log(f"{len(c)} candidates ({c.n_loops} loops) predicted in {c.eval_s:.2f} s; "
        f"{int(c.feasible.sum())} feasible; {len(front)} on the Pareto front")
    verified: list[dict] = []
    files = []
    if chosen is not None:
        r = c.row(chosen)
        log(f"chosen: {describe(r)} (cost {r['cost']:.3g}, worst margin "
            f"{r['worst_margin']:.2f}, limited by {r['limiting']}); {reason}")
        mapping = candidate_mapping(design, r)
        parse_scenario(mapping, "the chosen design")  # it must validate
        path = out_dir / f"{design.config.name}_design.yaml"
        text = _yaml_text(mapping, f"imc design {design.config.name}: {describe(r)}\n"
                          f"predicted worst margin {r['worst_margin']:.2f} "
                          f"(limited by {r['limiting']})")
        atomic_write(path, lambda p: p.write_text(text))
        files.append(str(path))
        if verify_runs:
            picks = best_few(c, chosen, design.config.margin, design.config.verify.designs)
            log(f"verifying {len(picks)} design(s) x {design.config.verify.seeds} seeds "
                f"({design.config.verify.fidelity} plant)")
            verified = verify(design, c, picks, out_dir, log)
    record = design_json(design, c, front, chosen, reason, verified, crlb)
    limit = correction_limit(design, c)
    record["ground_correction_limit"] = limit
    if limit is not None:
        log(f"ground correction without a stage ({limit['design']}) meets the requirements "
            f"up to {limit['f_max_hz']:.3g} Hz of jitter at the base's amplitude (above: "
            f"{limit['limited_by']})")
    write_json(out_dir / "design.json", record)
    page = design_html(record, c, front, chosen)
    atomic_write(out_dir / "design.html", lambda p: p.write_text(page))
    files += [str(out_dir / "design.json"), str(out_dir / "design.html")]
    return DesignResult(c, front, chosen, reason, verified, tuple(files))


def is_design_file(data: object) -> bool:
    """Whether a parsed YAML document is a design file (it has ``base`` and
    ``requirements``): ``imc check`` on a folder leaves it out, as it leaves out sweeps."""
    return isinstance(data, dict) and "requirements" in data and "base" in data

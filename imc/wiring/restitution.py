"""Restitution: the motion record made as good as the ground can make it.

From every link of the run (:mod:`imc.wiring.links`: the loop's own and the extra baselines)
the ground solves the image-motion series at every tracker frame as a network
(:func:`ground.network.solve_network`; the noise links share through their frames' pixels
modelled, the part of it that is each link's own estimated from the record's consistency,
:func:`ground.network.estimate_independent_fraction`), smooths it two-sidedly with a prior
estimated from the record itself (:func:`ground.network.smooth_network`) and fuses the
aiding configured in the same solve: a body gyro (``product.gyro``, :mod:`ground.aiding`,
whose readings are simulated here from the truth's attitude jitter with the stream
``gyro``) and ground control points (``product.ground_control``, absolute positions at
instants spread over the product, each with its accuracy, stream ``ground_control``). The
sensors are simulated from the truth; the solve sees only their readings and stated
accuracies, never the truth or the scenario's jitter spectrum.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ground.aiding import Absolute, GyroModel, gyro_aiding, simulate_absolute, simulate_gyro
from ground.network import (
    NetworkSolution,
    estimate_independent_fraction,
    smooth_network,
    solve_network,
    with_independent_fraction,
)
from ground.record import MotionRecord
from imc.wiring import streams
from imc.wiring.build import Models
from imc.wiring.links import LinkTable, overlap_baselines
from imc.wiring.truth import jitter_px

#: truth samples per tracker frame for the simulated gyro and control points
TRUTH_PER_FRAME = 8
#: draws and seed of the predicted geometry's spread (one strip's RMS under the covariance)
SPREAD_DRAWS = 1000
SPREAD_SEED = 32


@dataclass(frozen=True, eq=False)  # holds arrays
class Restitution:
    """The ground's record: ``record`` (the jitter at each tracker frame's mid-time, px, with
    its predicted error as ``sigma_px``), the network ``solution`` (covariance), the
    ``baselines`` used, the links used, what aided it, the run's ``links`` (for a re-solve
    with fixes measured later: :func:`restitute`'s ``absolute``), the ground control's
    own figures ``control`` (a reference orthoimage's fixes) and the fraction of each link's
    error found to be its own rather than its frames' pixels' ``independent_fraction``
    (row, col; None where the links share nothing)."""

    record: MotionRecord
    solution: NetworkSolution
    baselines: int
    links_used: int
    aiding: tuple[str, ...]
    absolute: bool
    links: LinkTable | None = None
    control: dict = field(default_factory=dict)
    independent_fraction: tuple[float, float] | None = None

    def predicted_px(self, t_s: np.ndarray) -> np.ndarray:
        """The record's predicted error (q, 2) px at times t_s (q,) s."""
        return self.solution.at(np.asarray(t_s, dtype=np.float64))[1]

    def stage_correction(self, stage) -> tuple[MotionRecord, dict]:
        """What the ground leaves out of its correction of a stage's product (stage + ground
        never worse than the stage alone): the record's estimate of the stage's residual (the
        record less the stage's position record, at the tracker frames) is blended per axis
        and per frequency band by what the record knows better than the residual is large
        (:func:`ground.blend.blend_correction`, Wiener gains from the predicted errors).
        Returns the part not applied (the estimate less the blended correction) as a record
        (px) and the blend's predicted figures."""
        from ground.blend import blend_correction

        t = self.record.t_s
        x = self.record.motion_px - np.asarray(stage(t), dtype=np.float64)
        dt = float(np.median(np.diff(t)))
        span = float(t[-1] - t[0])
        top = 0.25 / dt
        lo = min(2.0 / max(span, dt), top / 2)
        crossover = np.geomspace(lo, top, max(2, int(np.log2(top / lo)) + 1))
        blend = blend_correction([x], [self.solution.cov_px2], dt, crossover)
        left_out = x - x.mean(axis=0) - blend.correction_px
        figures = {"crossover_hz": [float(f) for f in crossover],
                   "gain": blend.gain.tolist(),
                   "predicted_before_px": [float(v) for v in blend.predicted_before_px],
                   "predicted_after_px": [float(v) for v in blend.predicted_after_px]}
        return MotionRecord(t, left_out, np.ones(len(t), bool)), figures

    def predicted_geometry(self, t_s: np.ndarray, max_samples: int = 512) -> dict:
        """The record's predicted geometry error over lines at times t_s, s, per axis: RMS
        about a constant (``constant_px``) and after an affine in time (``affine_px``), and
        absolute (``absolute_px``): the solution's covariance carried to (at most
        ``max_samples`` of) the lines by the interpolation weights and projected
        (:func:`ground.network.geometry_rms`)."""
        from ground.network import geometry_rms

        t = np.asarray(t_s, dtype=np.float64)
        t = t[np.unique(np.linspace(0, len(t) - 1, min(len(t), max_samples)).astype(int))]
        cov = self.solution.covariance_at(t)  # (2, q, q)
        g = geometry_rms(np.zeros((len(t), 2)), t, cov)
        absolute = np.sqrt(np.einsum("aqq->a", cov) / len(t))
        return {"constant_px": [float(x) for x in g["predicted_constant"]],
                "affine_px": [float(x) for x in g["predicted_affine"]],
                "absolute_px": [float(x) for x in absolute],
                **self._spread(t, cov)}

    @staticmethod
    def _spread(t: np.ndarray, cov: np.ndarray, draws: int = SPREAD_DRAWS) -> dict:
        """The 5th and 95th percentiles (2,) px of one strip's RMS after a constant and after
        an affine when its error is drawn from the predicted covariance ``cov`` (2, q, q) at
        times t (q,): how far one realisation's figure may fall from the RMS prediction.
        Drawn from a fixed seed (a property of the covariance, not of the run)."""
        from ground.network import trend_basis

        rng = np.random.default_rng(SPREAD_SEED)
        out: dict[str, list] = {}
        for key in ("constant", "affine"):
            q = trend_basis(t, key)
            lo, hi = [], []
            for c in cov:
                w, v = np.linalg.eigh(0.5 * (c + c.T))
                x = (v * np.sqrt(np.clip(w, 0.0, None))) @ rng.standard_normal((len(t), draws))
                r = x - q @ (q.T @ x)
                rms = np.sqrt(np.mean(r ** 2, axis=0))
                lo.append(float(np.percentile(rms, 5)))
                hi.append(float(np.percentile(rms, 95)))
            out[f"{key}_5_95_px"] = [lo, hi]
        return out


def _truth_series(m: Models) -> tuple[np.ndarray, np.ndarray]:
    """The true jitter (against the nominal pose) densely over the run, (t (n,), px (n, 2))."""
    t = np.linspace(float(m.frame_mid_s[0]), float(m.frame_mid_s[-1]),
                    TRUTH_PER_FRAME * len(m.frame_mid_s))
    return t, jitter_px(m, t)


def restitute(m: Models, links: LinkTable, control_t_s: np.ndarray | None = None,
              absolute: Absolute | None = None) -> Restitution:
    """The ground's best record from the run's links and the configured aiding.

    Parameters
    ----------
    m : the run's models (``product.restitution``, ``product.gyro``,
        ``product.ground_control``).
    links : every link of the run.
    control_t_s : (2,) the span the control points are spread over, s (default: the run's).
    absolute : absolute fixes measured on the product (a reference orthoimage's,
        :mod:`imc.wiring.orthocontrol`), fused in place of simulated control points.

    Returns
    -------
    Restitution
    """
    p = m.scenario.product
    t = m.frame_mid_s
    k_max = p.restitution.baselines or overlap_baselines(m)
    net = links.network(t, k_max)
    fraction = None
    if net.shared is not None and len(net.a) > len(t) + 2:  # redundant links tell the split
        fraction = estimate_independent_fraction(net, len(t))
        net = with_independent_fraction(net, fraction)
    gyro = None
    aiding: list[str] = [] if absolute is None else ["orthoimage"]
    ifov = m.main_camera.focal_plane.ifov_rad
    points = p.ground_control is not None and p.ground_control.kind == "points" \
        and absolute is None
    if p.gyro is not None or points:
        tt, truth = _truth_series(m)
    if p.gyro is not None:
        g = GyroModel(p.gyro.arw_deg_rt_h, p.gyro.bias_instability_deg_h, p.gyro.rate_hz,
                      p.gyro.white_noise_urad)
        readings = simulate_gyro(g, tt, truth, ifov, streams.rng(m.scenario.seed, "gyro"))
        gyro = gyro_aiding(g, readings, t, ifov)
        aiding.append("gyro")
    if points:
        lo, hi = (t[0], t[-1]) if control_t_s is None else np.clip(control_t_s, t[0], t[-1])
        n = p.ground_control.points
        at = lo + (np.arange(n) + 0.5) / n * (hi - lo)
        absolute = simulate_absolute(at, tt, truth, p.ground_control.sigma_px, t,
                                     streams.rng(m.scenario.seed, "ground_control"))
        aiding.append("ground_control")
    solve = smooth_network if p.restitution.smoother else solve_network
    sol = solve(net, len(t), gyro=gyro, absolute=absolute)
    s = sol.s_px if sol.s_px.ndim == 2 else sol.s_px[..., 0]
    record = MotionRecord(t, s, np.ones(len(t), bool), np.maximum(sol.sigma_px, 1e-6))
    return Restitution(record, sol, int(k_max), int(net.valid.sum()), tuple(aiding),
                       absolute is not None, links,
                       independent_fraction=None if fraction is None
                       else (float(fraction[0]), float(fraction[1])))

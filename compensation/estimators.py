"""Estimators: the blocks' shifts -> the content motion at the main imager's field point.

Every block measures the shift d_b of its content against the reference frame; adding back
the stage's change between the two exposures gives the content's motion (pseudo-open-loop).
``mean`` averages the valid blocks (today's estimator). ``motion_field`` first removes what
orbit, attitude and the DEM predict for each block (relief parallax and perspective: the
blocks see other ground than the main imager), fits a motion-field model to what is left
(the jitter, nearly rigid),

    u(c) = t + A (c - c_f),      c_f the field point (the main imager's centre, tracker px)

with A = 0 (translation), A = [[s, r], [-r, s]] (similarity: scale s, rotation r) or a full
2 x 2 (affine), by least squares weighted with each block's predicted error, rejecting
outliers one at a time by their leave-one-out residual, and adds the prediction at the field
point back: t is the unpredicted motion there and its covariance the predicted error
(inflated by the fit's chi^2 when the model does not fit). Both add the estimate at the
reference frame, so the motion counts from frame 0.

Reference management (both kinds): a block's reference goes stale as perspective changes it
(long stares) or its content leaves the sensor (scans). :meth:`rereference` decides, at
measurement time, to make the measured frame every block's new reference when a block is
leaving, its predicted deformation exceeds ``max_deform_px`` or its predicted error has grown
``crlb_growth`` times since its reference; the motion stays continuous (measurements against
the new reference start from the estimate at that frame).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from compensation.blocks import BlockMeasurements, MotionEstimate, register

MODELS = ("auto", "translation", "similarity", "affine")
#: unknowns per model
N_PARAMS = {"translation": 2, "similarity": 4, "affine": 6}


@dataclass(frozen=True)
class EstimatorState:
    ref_frames: np.ndarray  # (2,) frames whose estimates are kept: [current, pending] (-1)
    ref_motion: np.ndarray  # (2, 2) the estimates at those frames
    pending: int  # frame chosen as the next reference, not yet delivered (-1: none)
    current: int  # the plant's current reference frame
    sigma0: np.ndarray  # (B, 2) each block's first predicted error against the current ref
    last_motion: np.ndarray  # (2,) last valid estimate (held while invalid)


@dataclass(frozen=True)
class ReferencingEstimator:
    """Common reference management; see the module docstring.

    field_point_px : (row, col) of the main imager's centre in tracker pixels.
    max_deform_px : largest predicted deformation of a block before re-referencing, px.
    crlb_growth : re-reference when a block's predicted error grows this many times.
    min_valid_fraction : a frame becomes a reference only if this fraction of blocks is valid.
    """

    WIRED: ClassVar[tuple[str, ...]] = ("field_point_px",)

    field_point_px: tuple[float, float] = (0.0, 0.0)
    max_deform_px: float = 0.25
    crlb_growth: float = 2.0
    min_valid_fraction: float = 0.5

    def __post_init__(self) -> None:
        if not self.max_deform_px > 0 or not self.crlb_growth > 1:
            raise ValueError("max_deform_px must be > 0 and crlb_growth > 1")
        if not 0 < self.min_valid_fraction <= 1:
            raise ValueError(f"min_valid_fraction must be within (0, 1], got "
                             f"{self.min_valid_fraction}")

    def init(self, n_blocks: int = 1) -> EstimatorState:
        return EstimatorState(np.array([0, -1]), np.zeros((2, 2)), -1, 0,
                              np.full((n_blocks, 2), np.nan), np.zeros(2))

    def rereference(self, state: EstimatorState, meas: BlockMeasurements):
        if meas.ref_frame.size and int(meas.ref_frame[0]) == meas.frame:
            return state, False  # the reference itself
        ok = meas.valid
        s0 = state.sigma0
        if len(s0) != meas.n_blocks:
            s0 = np.full((meas.n_blocks, 2), np.nan)
        if meas.ref_frame.size and int(meas.ref_frame[0]) != state.current:
            s0 = np.full((meas.n_blocks, 2), np.nan)  # a new reference: restart the memory
        s0 = np.where(np.isnan(s0) & ok[:, None], meas.sigma_px, s0)
        grown = ok & np.any(meas.sigma_px > self.crlb_growth * s0, axis=1)
        stale = ok & (meas.deform_px > self.max_deform_px)
        need = bool(np.any(meas.leaving) or np.any(grown) or np.any(stale))
        usable = ok.mean() >= self.min_valid_fraction if ok.size else False
        st = dataclasses.replace(state, sigma0=s0,
                                 current=int(meas.ref_frame[0]) if meas.ref_frame.size
                                 else state.current)
        if need and usable and meas.frame != st.current:
            return dataclasses.replace(st, pending=meas.frame, current=meas.frame,
                                       sigma0=np.full_like(s0, np.nan)), True
        return st, False

    # -- the estimate at a reference frame ------------------------------------------------
    def _ref_motion(self, state: EstimatorState, ref: int) -> np.ndarray | None:
        hit = np.flatnonzero(state.ref_frames == ref)
        return state.ref_motion[hit[0]] if hit.size else None

    def _store(self, state: EstimatorState, frame: int, motion: np.ndarray) -> EstimatorState:
        """Keep the estimate of a frame chosen as the next reference; remember the last."""
        if frame == state.pending:
            state = dataclasses.replace(
                state, ref_frames=np.array([state.ref_frames[0], frame]),
                ref_motion=np.stack([state.ref_motion[0], motion]), pending=-1)
        return dataclasses.replace(state, last_motion=np.array(motion, dtype=np.float64))

    def _retire(self, state: EstimatorState, ref: int) -> EstimatorState:
        """Measurements against ``ref`` arrive: older references are no longer needed."""
        if state.ref_frames[1] == ref:
            return dataclasses.replace(
                state, ref_frames=np.array([ref, -1]),
                ref_motion=np.stack([state.ref_motion[1], np.zeros(2)]))
        return state

    def _pending_lost(self, state: EstimatorState, meas: BlockMeasurements) -> EstimatorState:
        """The reference frame's own measurement never arrived: take the last estimate."""
        if 0 <= state.pending < meas.frame:
            return self._store(state, state.pending, state.last_motion)
        return state


def _invalid(meas: BlockMeasurements, state: EstimatorState, model: str) -> MotionEstimate:
    b = meas.n_blocks
    return MotionEstimate(meas.frame, meas.t_s, state.last_motion.copy(), np.full(2, np.inf),
                          False, np.zeros(b, bool), np.zeros(b, bool), model)


@register("estimator", "mean")
@dataclass(frozen=True)
class MeanEstimator(ReferencingEstimator):
    """The plain mean of the valid blocks' shifts (today's estimator; no prediction)."""

    kind: str = field(default="mean", init=False)

    def update(self, state: EstimatorState, meas: BlockMeasurements, stage_px: np.ndarray,
               ref_stage_px: np.ndarray):
        state = self._pending_lost(state, meas)
        ref = int(meas.ref_frame[0])
        base = self._ref_motion(state, ref)
        ok = meas.valid & np.all(np.isfinite(meas.shift_px), axis=1)
        if base is None or not ok.any():
            return state, _invalid(meas, state, "mean")
        state = self._retire(state, ref)
        d = meas.shift_px[ok].mean(axis=0)
        motion = base + d + stage_px - ref_stage_px[0]
        sigma = np.sqrt(np.sum(meas.sigma_px[ok] ** 2, axis=0)) / ok.sum()
        state = self._store(state, meas.frame, motion)
        return state, MotionEstimate(meas.frame, meas.t_s, motion, sigma, True, ok,
                                     np.zeros_like(ok), "mean")


@register("estimator", "motion_field")
@dataclass(frozen=True)
class MotionFieldEstimator(ReferencingEstimator):
    """Weighted motion-field fit of the unpredicted motion, outliers rejected; see the module
    docstring.

    model : 'auto' (translation below 3 valid blocks, similarity below 6, affine from 6),
        'translation', 'similarity' or 'affine'.
    outlier_sigma : a block whose leave-one-out residual exceeds this many predicted sigmas
        (and ``outlier_min_px``) is rejected, one at a time.
    """

    model: str = "auto"
    outlier_sigma: float = 5.0
    outlier_min_px: float = 0.05
    kind: str = field(default="motion_field", init=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")
        if not self.outlier_sigma > 0:
            raise ValueError(f"outlier_sigma must be > 0, got {self.outlier_sigma}")

    def _model_for(self, n: int) -> str:
        if self.model != "auto":
            return self.model
        return "translation" if n < 3 else "similarity" if n < 6 else "affine"

    def update(self, state: EstimatorState, meas: BlockMeasurements, stage_px: np.ndarray,
               ref_stage_px: np.ndarray):
        state = self._pending_lost(state, meas)
        ref = int(meas.ref_frame[0])
        base = self._ref_motion(state, ref)
        ok = (meas.valid & np.all(np.isfinite(meas.shift_px), axis=1)
              & np.all(np.isfinite(meas.sigma_px) & (meas.sigma_px > 0), axis=1))
        if base is None or not ok.any():
            return state, _invalid(meas, state, "none")
        state = self._retire(state, ref)
        # the content motion of each block since its reference that was not predicted
        unpred = (np.nan_to_num(meas.shift_px) + (stage_px[None, :] - ref_stage_px)
                  - meas.predicted_px)
        used = ok.copy()
        outliers = np.zeros_like(ok)
        model = self._model_for(int(used.sum()))
        coef, cov, chi2 = self._fit(unpred[used], meas.sigma_px[used], meas.centers_px[used],
                                    model)
        # look for outliers only when the fit leaves residuals the errors do not explain
        while chi2 > self.outlier_sigma**2:
            worst, score = self._worst(unpred, meas, used, model)
            if worst < 0 or score <= self.outlier_sigma:
                break
            used[worst] = False
            outliers[worst] = True
            model = self._model_for(int(used.sum()))
            coef, cov, chi2 = self._fit(unpred[used], meas.sigma_px[used],
                                        meas.centers_px[used], model)
        dof = 2 * int(used.sum()) - N_PARAMS[model]
        inflate = max(1.0, chi2 / dof) if dof > 0 else 1.0
        sigma = np.sqrt(np.diag(cov)[:2] * inflate)
        motion = base + meas.field_predicted_px + coef[:2]
        state = self._store(state, meas.frame, motion)
        return state, MotionEstimate(meas.frame, meas.t_s, motion, sigma, True, used,
                                     outliers, model)

    def _design(self, centers: np.ndarray, model: str) -> np.ndarray:
        """(2B, P) rows: row equations then column equations, per block interleaved."""
        d = np.asarray(centers, dtype=np.float64) - np.asarray(self.field_point_px)
        n = len(d)
        x = np.zeros((n, 2, N_PARAMS[model]))
        x[:, 0, 0] = 1.0
        x[:, 1, 1] = 1.0
        if model == "similarity":  # row: s dr + r dc; col: -r dr + s dc
            x[:, 0, 2], x[:, 0, 3] = d[:, 0], d[:, 1]
            x[:, 1, 2], x[:, 1, 3] = d[:, 1], -d[:, 0]
        elif model == "affine":
            x[:, 0, 2], x[:, 0, 3] = d[:, 0], d[:, 1]
            x[:, 1, 4], x[:, 1, 5] = d[:, 0], d[:, 1]
        return x.reshape(2 * n, -1)

    def _fit(self, pol: np.ndarray, sigma: np.ndarray, centers: np.ndarray, model: str):
        """Weighted least squares: (coef, covariance, chi^2)."""
        x = self._design(centers, model)
        w = 1.0 / sigma.reshape(-1)
        y = pol.reshape(-1)
        xw = x * w[:, None]
        info = xw.T @ xw
        try:
            cov = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(info)
        coef = cov @ (xw.T @ (y * w))
        chi2 = float(np.sum(((x @ coef - y) * w) ** 2))
        return coef, cov, chi2

    def _worst(self, pol, meas, used, model):
        """(index, score) of the block with the largest leave-one-out residual in sigmas."""
        idx = np.flatnonzero(used)
        if len(idx) <= max(2, N_PARAMS[model] // 2):
            return -1, 0.0
        best, score = -1, 0.0
        for b in idx:
            rest = used.copy()
            rest[b] = False
            coef, cov, _ = self._fit(pol[rest], meas.sigma_px[rest], meas.centers_px[rest],
                                     model)
            xb = self._design(meas.centers_px[b:b + 1], model)
            pred = xb @ coef
            var = np.einsum("ij,jk,ik->i", xb, cov, xb) + meas.sigma_px[b] ** 2
            res = pol[b] - pred
            if np.max(np.abs(res)) < self.outlier_min_px:
                continue
            s = float(np.sqrt(np.sum(res**2 / var) / 2.0))
            if s > score:
                best, score = int(b), s
        return best, score

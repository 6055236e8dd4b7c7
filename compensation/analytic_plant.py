"""The analytic plant: measurements are the true shifts plus the correlator's predicted noise.

No images: the fastest plant, for loop design, sweeps and the loop's own tests. The true
content motion of each block is a function of time (from the camera model, or a synthetic
disturbance); a frame's measurement is its exposure-mean motion minus its reference's, minus
the stage's exposure-mean change between the two, plus Gaussian noise of ``sigma_px``
(drawn from ``numpy.random.default_rng([*seed, k])`` for frame k, so a resumed run is exact).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from compensation.blocks import BlockMeasurements

MotionFn = Callable[[np.ndarray], np.ndarray]


class AnalyticPlant:
    """Analytic measurements of B blocks.

    motion_px : t (N,) -> (N, B, 2) true content motion at each block centre, px (any fixed
        origin). centers_px : (B, 2) block centres on the tracker. sigma_px : (B, 2) or
        scalar 1-sigma noise. frame_t_s, exposure_s : the frames. samples : points per
        exposure for the exposure means (midpoint rule). deform_px : (B,) predicted
        deformation per second since the reference, or None. noise_scale : the noise
        actually added, as a fraction of sigma_px (0: noiseless measurements that still report
        sigma_px, for sine sweeps). nominal_px, field_nominal_px : the orbit/attitude
        prediction of the blocks' motion (t -> (N, B, 2)) and of the field point's (t ->
        (N, 2)), reported with each measurement; None: nothing is predicted.
    """

    def __init__(self, motion_px: MotionFn, centers_px: np.ndarray, sigma_px,
                 frame_t_s: np.ndarray, exposure_s: float, seed: tuple[int, ...] = (0,),
                 samples: int = 8, deform_px_per_s: np.ndarray | None = None,
                 noise_scale: float = 1.0, nominal_px: MotionFn | None = None,
                 field_nominal_px: MotionFn | None = None):
        self.centers_px = np.atleast_2d(np.asarray(centers_px, dtype=np.float64))
        self.n_blocks = len(self.centers_px)
        self.sigma_px = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64),
                                        (self.n_blocks, 2)).copy()
        if np.any(self.sigma_px < 0) or not np.all(np.isfinite(self.sigma_px)):
            raise ValueError("sigma_px must be finite and >= 0")
        self.frame_t_s = np.asarray(frame_t_s, dtype=np.float64)
        self.exposure_s = float(exposure_s)
        self.seed = tuple(seed)
        self.noise_scale = float(noise_scale)
        frac = (np.arange(samples) + 0.5) / samples
        times = (self.frame_t_s[:, None] + frac[None, :] * self.exposure_s).ravel()
        m = np.asarray(motion_px(times), dtype=np.float64)
        self.motion_mean = m.reshape(len(self.frame_t_s), samples, self.n_blocks, 2).mean(axis=1)
        self.deform_px_per_s = (np.zeros(self.n_blocks) if deform_px_per_s is None
                                else np.asarray(deform_px_per_s, dtype=np.float64))
        self.stage_mean = np.zeros((len(self.frame_t_s), 2))
        self.ref = 0
        mid = self.frame_t_s + 0.5 * self.exposure_s
        n = len(mid)
        self.nominal = (np.zeros((n, self.n_blocks, 2)) if nominal_px is None
                        else np.asarray(nominal_px(mid), dtype=np.float64))
        self.field_nominal = (np.zeros((n, 2)) if field_nominal_px is None
                              else np.asarray(field_nominal_px(mid), dtype=np.float64))

    def measure(self, k: int, stage, blocks: np.ndarray) -> BlockMeasurements:
        t0 = float(self.frame_t_s[k])
        self.stage_mean[k] = stage.mean(t0, t0 + self.exposure_s)
        r = self.ref
        truth = (self.motion_mean[k] - self.motion_mean[r]
                 - (self.stage_mean[k] - self.stage_mean[r])[None, :])
        noise = np.random.default_rng([*self.seed, k]).standard_normal((self.n_blocks, 2))
        shift = truth + noise * (self.sigma_px * self.noise_scale)
        on = np.asarray(blocks, dtype=bool)
        dt = float(self.frame_t_s[k] - self.frame_t_s[r])
        return BlockMeasurements(
            frame=k, t_s=t0 + 0.5 * self.exposure_s,
            ref_frame=np.full(self.n_blocks, r), centers_px=self.centers_px.copy(),
            shift_px=np.where(on[:, None], shift, np.nan),
            sigma_px=np.where(on[:, None], np.maximum(self.sigma_px, 1e-12), np.inf),
            valid=on.copy(), peak=np.where(on, np.inf, 0.0),
            deform_px=self.deform_px_per_s * dt, leaving=np.zeros(self.n_blocks, bool),
            predicted_px=self.nominal[k] - self.nominal[r],
            field_predicted_px=self.field_nominal[k] - self.field_nominal[r])

    def rereference(self, k: int) -> None:
        self.ref = k

    def chunk_arrays(self, start: int, stop: int) -> dict[str, np.ndarray]:
        return {"ref": np.array(self.ref), "stage_mean": self.stage_mean[start:stop].copy()}

    def restore(self, chunks: list[dict[str, np.ndarray]]) -> None:
        stop = 0
        for c in chunks:
            n = len(c["stage_mean"])
            self.stage_mean[stop:stop + n] = c["stage_mean"]
            stop += n
        self.ref = int(chunks[-1]["ref"])


def sinusoids(terms: list[tuple[float, float, float, int]], n_blocks: int = 1) -> MotionFn:
    """A motion function: sum of a sin(2 pi f t + phase) on an axis, the same on every block.
    ``terms``: (amplitude_px, frequency_hz, phase_rad, axis)."""

    def motion(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros((len(t), n_blocks, 2))
        for a, f, ph, axis in terms:
            out[:, :, axis] += (a * np.sin(2 * np.pi * f * t + ph))[:, None]
        return out

    return motion

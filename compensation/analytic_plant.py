"""The analytic plant: measurements are the true shifts plus the correlator's predicted noise.

No images: the fastest plant, for loop design, sweeps and the loop's own tests. The true
content motion of each block is a function of time (from the camera model, or a synthetic
disturbance); a frame's measurement is its exposure-mean motion minus its reference's, minus
the stage's exposure-mean change between the two, plus Gaussian noise of ``sigma_px``
(drawn from ``numpy.random.default_rng([*seed, k])`` for frame k, so a resumed run is exact).

In a scanning view (``chain``) it re-references as the image plants do: every block is
``leaving``, the loop's estimator re-references each frame and the record is a chain of
frame-to-frame links. Links that share a frame then share that frame's noise: a link's noise
is ``sigma (sqrt(1 - 2 rho) e + sqrt(rho) (nu_b - nu_a))`` with ``nu_k`` frame k's own draw
(``default_rng([*seed, k, 1])``) and ``rho`` :data:`SHARED_FRACTION`, so its variance stays
``sigma^2`` and consecutive links correlate by ``-rho``. :meth:`AnalyticPlant.pair_links`
gives the links of every baseline 1..K the ground's network uses (the loop's own noise for
baseline 1), each longer baseline with the blocks its pair keeps on the sensor. Where the
pairs' block regions are known (``pair_regions``, as the image plants' loop and ground cut
them), a chained link's noise is instead each frame's noise field over the blocks it is
measured on, half the variance from each frame: links that use the same pixels of a frame
share that frame's part in proportion to their overlap (measured on no_stage.yaml's rendered
frames: the ground's pairs from one reference region correlate by 0.4-0.53, pairs on other
regions of the same frames by 0.0-0.16).

``floor_px``: a link error the correlator's reported bound does not see, drawn with the same
sharing as the sensor's (each frame's own part over the pixels its pairs use) and never
reported: a rendered tracker's Monte Carlo pixel integration (each frame rendered with its own
sampler seed) is such a per-frame noise; on no_stage.yaml's rendered frames at 4 samples a
pixel it is 0.0064 / 0.0056 px (row / col) per pair of frames, against a reported bound of
0.011 px (docs/product.md). The record's consistency (the blocks' scatter) then reports it as
the rendered record does.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from compensation.blocks import BlockMeasurements

MotionFn = Callable[[np.ndarray], np.ndarray]

#: cells across a block of a frame's noise field (a chain with known pair regions)
REGION_CELLS = 8
#: the share of a chained link's noise variance that each of its two frames carries (the
#: lag-1 correlation of consecutive links, negated): measured -0.08 / -0.12 (row / col) on
#: the rendered no_stage.yaml tracker's 331 links
SHARED_FRACTION = 0.1


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
        (N, 2)), reported with each measurement; None: nothing is predicted. pair_regions :
        (a, b) -> (reference corners (B, 2), current corners (B, 2), used (B,)) of the blocks
        a pair of frames a < b is measured on (the loop's cut, and the ground's longer
        baselines kept on the sensor); with ``frame_shape`` (rows, cols) and ``block_px`` a
        chain's noise is then the frames' noise over those regions (below); None: the
        shared-fraction model and every block. floor_px : (B, 2) or scalar, px: the
        per-link error the reported sigma_px leaves out (module docstring), drawn with the
        sensor's noise (scaled by noise_scale too); 0: none. efficiency : (2,) or scalar,
        the correlator's actual error over its reported bound on the scene's texture
        (measured, e.g. 1.12 on no_stage.yaml's): the drawn noise is efficiency x sigma_px,
        the reported one sigma_px; 1: the bound.
    """

    def __init__(self, motion_px: MotionFn, centers_px: np.ndarray, sigma_px,
                 frame_t_s: np.ndarray, exposure_s: float, seed: tuple[int, ...] = (0,),
                 samples: int = 8, deform_px_per_s: np.ndarray | None = None,
                 noise_scale: float = 1.0, nominal_px: MotionFn | None = None,
                 field_nominal_px: MotionFn | None = None, chain: bool = False,
                 shared_fraction: float = SHARED_FRACTION,
                 predict_between: Callable[[int, int], tuple[np.ndarray, np.ndarray]]
                 | None = None,
                 pair_regions: Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]
                 | None = None, frame_shape: tuple[int, int] | None = None,
                 block_px: int | None = None, floor_px=0.0, efficiency=1.0):
        if not 0.0 <= shared_fraction <= 0.5:
            raise ValueError(f"shared_fraction must be in [0, 0.5], got {shared_fraction}")
        self.chain = bool(chain)
        self.shared_fraction = float(shared_fraction)
        self.predict_between = predict_between
        self.pair_regions = pair_regions
        if pair_regions is not None and (frame_shape is None or block_px is None):
            raise ValueError("pair_regions needs frame_shape and block_px")
        self.frame_shape = frame_shape
        self.cell_px = max(1, int(block_px) // REGION_CELLS) if block_px else 1
        self.block_px = block_px
        self.centers_px = np.atleast_2d(np.asarray(centers_px, dtype=np.float64))
        self.n_blocks = len(self.centers_px)
        self.sigma_px = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64),
                                        (self.n_blocks, 2)).copy()
        if np.any(self.sigma_px < 0) or not np.all(np.isfinite(self.sigma_px)):
            raise ValueError("sigma_px must be finite and >= 0")
        self.floor_px = np.broadcast_to(np.asarray(floor_px, dtype=np.float64),
                                        (self.n_blocks, 2)).copy()
        if np.any(self.floor_px < 0) or not np.all(np.isfinite(self.floor_px)):
            raise ValueError("floor_px must be finite and >= 0")
        self.frame_t_s = np.asarray(frame_t_s, dtype=np.float64)
        self.exposure_s = float(exposure_s)
        self.seed = tuple(seed)
        self.noise_scale = float(noise_scale)
        #: the noise each link carries (B, 2) px: the bound and the unreported floor
        self.efficiency = np.broadcast_to(np.asarray(efficiency, dtype=np.float64), (2,)).copy()
        if np.any(self.efficiency <= 0) or not np.all(np.isfinite(self.efficiency)):
            raise ValueError("efficiency must be finite and > 0")
        self.drawn_px = np.hypot(self.sigma_px * self.efficiency, self.floor_px) \
            * self.noise_scale
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
        pred, field = self.nominal[k] - self.nominal[r], self.field_nominal[k] - \
            self.field_nominal[r]
        truth = (self.motion_mean[k] - self.motion_mean[r]
                 - (self.stage_mean[k] - self.stage_mean[r])[None, :])
        if self.chain and self.predict_between is not None and r != k:
            # a chain measures the content under the blocks in frame r, not the ground they
            # saw at the start: its own prediction, the same jitter (a rotation)
            now, now_field = self.predict_between(r, k)
            truth = truth - pred + now
            pred, field = np.asarray(now, dtype=np.float64), np.asarray(now_field,
                                                                        dtype=np.float64)
        shift = truth + self._noise(k, r) * self.drawn_px
        on = np.asarray(blocks, dtype=bool)
        dt = float(self.frame_t_s[k] - self.frame_t_s[r])
        return BlockMeasurements(
            frame=k, t_s=t0 + 0.5 * self.exposure_s,
            ref_frame=np.full(self.n_blocks, r), centers_px=self.centers_px.copy(),
            shift_px=np.where(on[:, None], shift, np.nan),
            sigma_px=np.where(on[:, None], np.maximum(self.sigma_px, 1e-12), np.inf),
            valid=on.copy(), peak=np.where(on, np.inf, 0.0),
            deform_px=self.deform_px_per_s * dt, leaving=np.full(self.n_blocks, self.chain),
            predicted_px=pred, field_predicted_px=field)

    def _frame_draw(self, k: int) -> np.ndarray:
        """nu_k (B, 2): frame k's own noise draw (shared by its links in a chain)."""
        return np.random.default_rng([*self.seed, k, 1]).standard_normal((self.n_blocks, 2))

    def _field(self, k: int) -> np.ndarray:
        """Frame k's noise field (2, rows / cell, cols / cell): unit normals per cell."""
        n = -(-np.asarray(self.frame_shape) // self.cell_px)
        return np.random.default_rng([*self.seed, k, 3]).standard_normal((2, *n))

    def _region(self, field: np.ndarray, corners: np.ndarray) -> np.ndarray:
        """Unit-variance noise (B, 2) of blocks at ``corners`` (B, 2): the mean of the field's
        cells they cover, times the square root of their count."""
        c = self.cell_px
        w = max(1, self.block_px // c)
        out = np.empty((len(corners), 2))
        for i, (r0, c0) in enumerate(np.clip(np.rint(np.asarray(corners) / c).astype(int), 0,
                                             np.array(field.shape[1:]) - w)):
            out[i] = field[:, r0:r0 + w, c0:c0 + w].sum(axis=(1, 2)) / w
        return out

    def _region_noise(self, r: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """A pair's unit noise (B, 2) from frames r < k measured on their regions: half the
        variance the reference frame's noise over the reference blocks, half the current
        frame's over the current ones (pairs that share a frame's pixels share that part,
        in proportion to the overlap), and the blocks used (B,)."""
        ref, cur, used = self.pair_regions(r, k)
        e = (self._region(self._field(k), cur) - self._region(self._field(r), ref)) / np.sqrt(2)
        return e, np.asarray(used, dtype=bool)

    def _noise(self, k: int, r: int, j: int | None = None) -> np.ndarray:
        """A link's unit noise (B, 2) from frame r to k: the loop's own (``j`` None) or the
        ground's extra baseline j's independent draw, with the shared frame terms in a
        chain (:meth:`_region_noise` where the pairs' regions are known)."""
        if self.chain and r != k and self.pair_regions is not None:
            return self._region_noise(r, k)[0]
        key = [*self.seed, k] if j is None else [*self.seed, k, j, 2]
        e = np.random.default_rng(key).standard_normal((self.n_blocks, 2))
        if not self.chain or r == k:
            return e
        rho = self.shared_fraction
        return np.sqrt(1.0 - 2.0 * rho) * e + np.sqrt(rho) * (self._frame_draw(k)
                                                              - self._frame_draw(r))

    def pair_links(self, k_max: int) -> tuple[np.ndarray, ...]:
        """Every link of baselines 1..k_max the ground's network uses, per block: (a (n,),
        b (n,), the jitter's increment (n, B, 2) px (the content's motion less the nominal,
        noise included), its sigma (n, B, 2) px, valid (n, B)); baseline 1 with the loop's
        own noise (the loop re-references every frame in a chain)."""
        jit = self.motion_mean - self.nominal
        n = len(self.frame_t_s)
        pairs = [(b - j, b, j) for b in range(1, n) for j in range(1, min(k_max, b) + 1)]
        a = np.array([p[0] for p in pairs], dtype=int)
        b = np.array([p[1] for p in pairs], dtype=int)
        noise = np.stack([self._noise(bb, aa, None if j == 1 else j) for aa, bb, j in pairs]) \
            if pairs else np.zeros((0, self.n_blocks, 2))
        d = jit[b] - jit[a] + noise * self.drawn_px
        sigma = np.broadcast_to(np.maximum(self.sigma_px, 1e-12), d.shape).copy()
        valid = np.ones(d.shape[:2], bool)
        if self.pair_regions is not None:  # the blocks a longer baseline keeps on the sensor
            for i, (aa, bb, j) in enumerate(pairs):
                if j > 1:
                    valid[i] = np.asarray(self.pair_regions(aa, bb)[2], dtype=bool)
        return a, b, d, sigma, valid

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

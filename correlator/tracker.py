"""Multi-block tracker: fixed reference blocks from one frame, measured in later frames."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the correlator (numba, FFTW) is imported when a tracker is made
    from correlator.core import CorrelatorOptions, ShiftResult


def block_grid(rows: int, cols: int, block_px: int, n_blocks: int) -> np.ndarray:
    """Top-left corners (n, 2) of n blocks spread on a near-square grid over the sensor."""
    if block_px > min(rows, cols):
        raise ValueError(f"block size {block_px} px exceeds the sensor ({rows} x {cols})")
    ny = int(np.floor(np.sqrt(n_blocks)))
    while n_blocks % ny:
        ny -= 1
    nx = n_blocks // ny
    cy = (np.arange(ny) + 0.5) * rows / ny
    cx = (np.arange(nx) + 0.5) * cols / nx
    yy, xx = np.meshgrid(cy, cx, indexing="ij")
    tl = np.column_stack([yy.ravel(), xx.ravel()]) - block_px / 2.0
    tl = np.clip(np.rint(tl), 0, [rows - block_px, cols - block_px]).astype(int)
    return tl


def extract_blocks(frame: np.ndarray, corners: np.ndarray, block_px: int) -> np.ndarray:
    """Blocks (n, B, B) cut from frame (H, W) at top-left corners (n, 2)."""
    r = corners[:, 0, None, None] + np.arange(block_px)[None, :, None]
    c = corners[:, 1, None, None] + np.arange(block_px)[None, None, :]
    return np.asarray(frame)[r, c]


class BlockTracker:
    """Tracks N blocks of a reference frame in later frames of the same sensor.

    ``update(frame)`` returns the shift of each block's content relative to the reference
    frame (docs/conventions.md sign), its validity, PSR and CRLB.
    """

    def __init__(self, reference_frame: np.ndarray, corners: np.ndarray, block_px: int,
                 options: CorrelatorOptions | None = None):
        self.corners = np.asarray(corners, dtype=int)
        self.block_px = int(block_px)
        from correlator.core import Correlator, CorrelatorOptions

        self.correlator = Correlator(
            extract_blocks(reference_frame, self.corners, self.block_px),
            options or CorrelatorOptions(),
        )

    @property
    def centers_px(self) -> np.ndarray:
        """Block centres (n, 2) in sensor pixel coordinates (row, col)."""
        return self.centers_from(self.corners, self.block_px)

    @staticmethod
    def centers_from(corners: np.ndarray, block_px: int) -> np.ndarray:
        """Centres (n, 2) of blocks with top-left corners (n, 2)."""
        return np.asarray(corners) + (block_px - 1) / 2.0

    def update(self, frame: np.ndarray, predicted_px: np.ndarray | None = None,
               rng: np.random.Generator | None = None,
               index: np.ndarray | None = None,
               flow: np.ndarray | None = None) -> ShiftResult:
        """Shifts of the reference blocks' content in ``frame``.

        ``predicted_px`` (n, 2), optional: the motion expected from orbit and attitude. Each
        block is then cut from ``frame`` at its corner moved by the rounded prediction, and that
        whole-pixel offset is added back, so the correlator only sees the unpredicted part. A
        block moved off the sensor comes back invalid (shift NaN). With
        ``options.trust_prediction_px`` set, the correlator also starts Newton from the
        prediction's sub-pixel remainder and skips the integer search where the result settles
        within that distance of it. ``rng``: noise of an emulated optical correlator;
        ``index``: measure only these blocks (results for them).

        ``flow`` (n, B, B, 2), optional: the predicted motion of every pixel q of each
        reference block, where perspective and relief parallax deform the content since the
        reference (long stares). Each block of ``frame`` is then resampled (cubic spline) at
        q + flow(q), so the correlator sees the reference's geometry and measures only the
        unpredicted translation; the result is that plus the flow at the block's centre.
        """
        frame = np.asarray(frame)
        sel = np.arange(len(self.corners)) if index is None else np.asarray(index, dtype=int)
        base = self.corners[sel]
        if flow is not None:
            return self._warped(frame, np.asarray(flow, dtype=np.float64)[sel], sel, rng,
                                index)
        if predicted_px is None:
            return self.correlator.measure(extract_blocks(frame, base, self.block_px), rng,
                                           index)
        pred = np.asarray(predicted_px, dtype=np.float64)[sel]
        step = np.rint(pred).astype(int)
        corners = base + step
        h, w = frame.shape
        inside = np.all((corners >= 0) & (corners + self.block_px <= [h, w]), axis=1)
        safe = np.where(inside[:, None], corners, base)
        # with options.trust_prediction_px the correlator starts from the sub-pixel remainder
        trusted = self.correlator.options.trust_prediction_px is not None
        res = self.correlator.measure(extract_blocks(frame, safe, self.block_px), rng, index,
                                      predicted=(pred - step) if trusted else None)
        shift = np.where(inside[:, None], res.shift + step, np.nan)
        return type(res)(shift, res.valid & inside, np.where(inside, res.peak, 0.0),
                           np.where(inside[:, None], res.crlb, np.inf),
                           np.where(inside, res.p_false, 1.0),
                           np.where(inside, res.p_wrong, 1.0), res.precise)

    def _warped(self, frame, flow, sel, rng, index) -> ShiftResult:
        """:meth:`update` through a predicted flow (see there)."""
        from scipy.ndimage import map_coordinates, spline_filter

        b = self.block_px
        base = self.corners[sel]
        q = np.stack(np.meshgrid(np.arange(b), np.arange(b), indexing="ij"), axis=-1)
        src = q[None] + base[:, None, None, :] + flow  # (n, B, B, 2)
        h, w = frame.shape
        inside = np.all((src.min(axis=(1, 2)) >= 0) & (src.max(axis=(1, 2)) <= [h - 1, w - 1]),
                        axis=1)
        coeffs = spline_filter(frame.astype(np.float64), order=3)
        blocks = map_coordinates(coeffs, [src[..., 0].ravel(), src[..., 1].ravel()], order=3,
                                 mode="nearest", prefilter=False).reshape(len(sel), b, b)
        res = self.correlator.measure(blocks, rng, index)
        c = (b - 1) / 2.0  # the flow at the block centre (bilinear between the 4 middle pixels)
        lo, hi = int(np.floor(c)), int(np.ceil(c))
        centre = 0.25 * (flow[:, lo, lo] + flow[:, lo, hi] + flow[:, hi, lo] + flow[:, hi, hi])
        shift = np.where(inside[:, None], res.shift + centre, np.nan)
        return type(res)(shift, res.valid & inside, np.where(inside, res.peak, 0.0),
                           np.where(inside[:, None], res.crlb, np.inf),
                           np.where(inside, res.p_false, 1.0),
                           np.where(inside, res.p_wrong, 1.0), res.precise)

"""The motion record as the ground receives it: every link the tracker measured, with its
predicted error and delivery time, and the extra baselines a chained (scanning) tracker can
measure while a block's content is still on the sensor.

A scanning tracker re-references every frame: the loop measures frame k against frame k - 1
(its causal short baseline, kept as is: the loop's figures do not change). The ground has
the whole record, so the device also correlates frame k against frames k - 2 .. k - K where
the content is still on the sensor (:func:`overlap_baselines`): the same block grid, each
block cut at half the predicted motion in both frames, as the loop's chain cuts it, and
measured as the loop measures (:func:`measure_pair`: the integer cut, no resampling). Each link
is the blocks' inverse-variance mean of the measured shift less the orbit / attitude / DEM
prediction (and the stage's known change): the jitter's increment ``s(t_b) - s(t_a)`` at the
tracker's blocks, in tracker pixels (the main imager shares the focal plane and its scale).

Its predicted error is the blocks' Cramer-Rao bound scaled by the record's own consistency:
the blocks of one link measure the same increment, so their scatter about the link's mean
(a chi-square with B - 1 degrees of freedom per axis) says how far the bound is from the
errors the correlator really makes; never the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from correlator.options import CorrelatorOptions
from correlator.tracker import BlockTracker
from ground.network import Links, SharedNoise
from imc.wiring import streams
from imc.wiring.build import Models, predicted_px

#: pixels kept between a block and the sensor's edge when deciding the overlap's baselines
OVERLAP_MARGIN_PX = 8


@dataclass(frozen=True, eq=False)  # holds arrays
class LinkTable:
    """Every link of a run: reference ``a`` and current ``b`` frames (n,), the jitter's
    increment ``d_px`` (n, 2) px, its predicted error ``sigma_px`` (n, 2) px (CRLB scaled by
    ``efficiency``), ``valid`` (n,), the delivery time ``deliver_s`` (n,) s (NaN: never),
    the ``baseline`` b - a (n,), the blocks that made each link ``blocks`` (n,), ``loop`` (n,)
    True for the loop's own links, and the per-axis ``efficiency`` (2,) the record's
    consistency gave the bound. A chained tracker's table also keeps where each block was
    measured, ``regions`` (n, B, 2, 2) px (the top-left corner in the reference frame, then
    in the current one), each block's share of its link's error ``share_px`` (n, B, 2) px
    (its weight in the mean times its error, efficiency included; 0 where not used), the
    blocks' side ``block_px`` and the frames' noise cell ``cell_px`` (1: the sensor's
    pixels): links that use the same pixels of a frame share that frame's noise there
    (:class:`ground.network.SharedNoise`)."""

    a: np.ndarray
    b: np.ndarray
    d_px: np.ndarray
    sigma_px: np.ndarray
    valid: np.ndarray
    deliver_s: np.ndarray
    baseline: np.ndarray
    blocks: np.ndarray
    loop: np.ndarray
    efficiency: np.ndarray
    regions: np.ndarray | None = None
    share_px: np.ndarray | None = None
    block_px: int = 0
    cell_px: int = 1

    def network(self, t_s: np.ndarray, k_max: int | None = None) -> Links:
        """The loop's links and the extra ones of baselines up to ``k_max`` (None: all) as a
        :class:`ground.network.Links` on frame times ``t_s``, s: with the table's
        ``regions``, each block's noise half its reference frame's over its reference region
        and half its current frame's over its current one (all of a link's error shared,
        :meth:`ground.network.SharedNoise.from_blocks`); without, every link independent."""
        keep = np.ones(len(self.a), bool) if k_max is None else (self.loop
                                                                 | (self.baseline <= k_max))
        a, b, v = self.a[keep], self.b[keep], self.valid[keep]
        d = np.nan_to_num(self.d_px[keep])
        if self.regions is None:
            return Links(a, b, d, np.where(v[:, None], self.sigma_px[keep], 1.0), v, t_s)
        reg = self.regions[keep]
        shared = SharedNoise.from_blocks(a, b, reg[:, :, 0], reg[:, :, 1],
                                         np.where(v[:, None, None], self.share_px[keep], 0.0),
                                         self.block_px, self.cell_px)
        return Links(a, b, d, np.where(v[:, None], 0.0, np.ones((1, 2))), v, t_s,
                     shared=shared)

    def arrays(self) -> dict[str, np.ndarray]:
        """The table as named arrays (``links.npz``)."""
        out = {k: getattr(self, k) for k in ("a", "b", "d_px", "sigma_px", "valid",
                                              "deliver_s", "baseline", "blocks", "loop",
                                              "efficiency")}
        if self.regions is not None:
            out.update(regions=self.regions, share_px=self.share_px,
                       block_px=np.array(self.block_px), cell_px=np.array(self.cell_px))
        return out


def overlap_baselines(m: Models) -> int:
    """The most baselines K a chained tracker's block keeps whole on the sensor: frames over
    which the predicted motion at the sensor's centre stays within rows (cols) less a block
    and a margin (:data:`OVERLAP_MARGIN_PX`); 1 for a staring tracker (no chain)."""
    if not m.chain or len(m.frame_t_s) < 3:
        return 1
    fp = m.camera.focal_plane
    b = m.scenario.correlator.block_px
    mid = len(m.frame_t_s) // 2
    step = np.abs(predicted_px(m, np.array([fp.center_px]), mid - 1, mid, np.zeros(2),
                               np.zeros(2))[0])
    room = np.array([fp.rows, fp.cols]) - b - OVERLAP_MARGIN_PX
    per = np.where(step > 1e-9, room / np.maximum(step, 1e-9), np.inf)
    return int(max(1, min(np.floor(per.min()), len(m.frame_t_s) - 1)))


def combine_blocks(d: np.ndarray, sigma: np.ndarray, valid: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Blocks (n, B, 2) -> links: inverse-variance mean, its sigma (CRLB), the blocks used
    and the chi-square of the blocks about the mean per axis (n, 2)."""
    w = np.where(valid[..., None], 1.0 / np.maximum(sigma, 1e-12) ** 2, 0.0)
    sw = w.sum(axis=1)
    mean = np.where(sw > 0, (w * np.nan_to_num(d)).sum(axis=1) / np.maximum(sw, 1e-300),
                    np.nan)
    chi2 = (w * (np.nan_to_num(d) - np.nan_to_num(mean)[:, None]) ** 2).sum(axis=1)
    return mean, 1.0 / np.sqrt(np.maximum(sw, 1e-300)), valid.sum(axis=1), chi2


def _loop_blocks(m: Models, rec, stage_mean: np.ndarray):
    """The loop's own links (frame k against its reference) per block: (a, b, d (n, B, 2),
    sigma, valid, regions (n, B, 2, 2): each block's corner in the reference frame (its
    recorded centre) and in the current one (moved by the rounded prediction, as
    :meth:`correlator.tracker.BlockTracker.update` cuts it))."""
    ks = np.flatnonzero(rec.measured.any(axis=1) & (np.arange(len(m.frame_t_s)) > 0))
    a = rec.ref_frame[ks, 0].astype(int)
    d = np.full((len(ks), rec.shift_px.shape[1], 2), np.nan)
    reg = np.zeros((len(ks), rec.shift_px.shape[1], 2, 2), int)
    half = (m.scenario.correlator.block_px - 1) / 2.0
    for i, (r, k) in enumerate(zip(a, ks, strict=True)):
        pred = predicted_px(m, rec.centers_px[k], int(r), int(k), stage_mean[r],
                            stage_mean[k])
        d[i] = rec.shift_px[k] - pred
        reg[i, :, 0] = np.rint(rec.centers_px[k] - half)
        reg[i, :, 1] = reg[i, :, 0] + np.rint(pred)
    valid = rec.valid[ks] & rec.measured[ks] & np.all(np.isfinite(d), axis=-1)
    keep = a < ks
    return a[keep], ks[keep], d[keep], rec.sigma_px[ks][keep], valid[keep], reg[keep]


def chain_corners(corners: np.ndarray, step_px: np.ndarray, block_px: int,
                  shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The loop's chain cut of a scanning tracker (each frame measured against the one
    before, :class:`imc.wiring.rendered_plant.TrackerPlant`): each block of the grid
    ``corners`` (B, 2) is cut in the reference frame half the predicted motion ``step_px``
    (B, 2) px before its place, clipped to the sensor (``shape``: rows, cols), and in the
    current frame at that corner moved by the rounded motion. Returns the reference corners
    (B, 2), the current ones (B, 2) and whether the current block lies whole on the sensor
    (B,): one that does not is refused (:meth:`correlator.tracker.BlockTracker.update`), so
    a block's content is either all in common with the next frame or not measured."""
    step = np.asarray(step_px, dtype=np.float64)
    lim = np.asarray(shape, dtype=int) - int(block_px)
    half = np.rint(step / 2.0).astype(int)
    ref = np.clip(np.asarray(corners, dtype=int) - half, 0, lim)
    cur = ref + np.rint(step).astype(int)
    inside = np.all((cur >= 0) & (cur <= lim), axis=1)
    return ref, cur, inside


def pair_corners(corners: np.ndarray, step_px: np.ndarray, block_px: int, lim: np.ndarray,
                 margin: int = OVERLAP_MARGIN_PX) -> tuple[np.ndarray, np.ndarray]:
    """Reference corners (B, 2) of a pair whose content moves by ``step_px`` (B, 2) px: the
    loop's chain cut (half the motion before the block's place, half after) moved, where it
    would not fit, just far enough that the reference block and the current one both stay
    ``margin`` px inside the sensor (``lim`` (2,): rows, cols less a block), and whether each
    block is used (B,): one that cannot fit, or whose reference overlaps an earlier one's by
    more than half a block on both axes (the same content twice: not an independent block),
    is not.

    The frames' edges are not the scene: the optics' MTF is applied to each rendered frame
    with periodic boundaries, so its first and last rows and columns carry the opposite edge's
    content. Clipped to the edge, the ground's baselines of 2-4 frames measured on no_stage.yaml
    erred by -0.0018 px (row) a link against -0.0005 px for the loop's cut 11 px inside: a
    per-link bias the network turned into the record's along-track drift."""
    step = np.rint(np.asarray(step_px, dtype=np.float64)).astype(int)
    want = np.asarray(corners, dtype=int) - np.rint(step / 2.0).astype(int)
    lo = np.maximum(margin, margin - step)
    hi = np.minimum(lim - margin, lim - margin - step)
    out = np.clip(want, lo, np.maximum(lo, hi))
    used = np.all(hi >= lo, axis=1)
    for i in range(1, len(out)):
        near = np.all(np.abs(out[:i] - out[i]) < block_px // 2, axis=1) & used[:i]
        used[i] &= not near.any()
    return out, used


def measure_pair(ref_frame: np.ndarray, cur_frame: np.ndarray, corners: np.ndarray,
                 predicted_px: np.ndarray, block_px: int,
                 options: CorrelatorOptions | None = None,
                 rng: np.random.Generator | None = None):
    """One pair of the ground's network: the blocks at ``corners`` (B, 2) of ``ref_frame``
    found in ``cur_frame`` near ``predicted_px`` (B, 2) px, as the loop measures its own links:
    each current block cut at the rounded prediction, the sub-pixel part left to the
    correlator's own estimate (:meth:`correlator.tracker.BlockTracker.update`). Returns its
    :class:`correlator.core.ShiftResult` (shift (B, 2) px, from the reference).

    The current block is not resampled at the predicted motion first. A cubic spline
    resampling a block at a fractional shift phi moves its content by phi plus an error of
    its own, odd in phi about the whole pixel: +2.1..+4.1e-3 px at phi = 0.25
    and -0.9..-1.8e-3 px at 0.93 on band-limited textures, against <= 0.23e-3 px for the
    correlator's estimate on the integer cut (``tests/test_restitution_wiring.py``). A
    chain's links share one phase per baseline, so that error added up to the record's
    along-track drift (issue 32; docs/product.md, "The ground's pairs are no longer
    resampled")."""
    tracker = BlockTracker(ref_frame, corners, block_px, options)
    return tracker.update(cur_frame, predicted_px, rng)


def _extra_blocks(m: Models, frames: np.ndarray, stage_mean: np.ndarray, k_max: int,
                  first: int = 2):
    """Links of baselines ``first``..k_max per block, measured on the stored frames with the
    loop's chain's block cut (at half the predicted motion) kept inside the sensor's margin
    (:func:`pair_corners`), each pair by :func:`measure_pair`."""
    b = m.scenario.correlator.block_px
    fp = m.camera.focal_plane
    lim = np.array([fp.rows - b, fp.cols - b])
    grid = BlockTracker.centers_from(m.corners, b)
    out_a, out_b, out_d, out_s, out_v, out_r = [], [], [], [], [], []
    for k in range(first, len(m.frame_t_s)):
        for j in range(first, min(k_max, k) + 1):
            a = k - j
            step = predicted_px(m, grid, a, k, stage_mean[a], stage_mean[k])
            corners, inside = pair_corners(m.corners, step, b, lim)
            centers = BlockTracker.centers_from(corners, b)
            pred = predicted_px(m, centers, a, k, stage_mean[a], stage_mean[k])
            res = measure_pair(frames[a], frames[k], corners, pred, b, m.correlator,
                               streams.rng(m.scenario.seed, "links", k, j))
            out_a.append(a)
            out_b.append(k)
            out_d.append(res.shift - pred)
            out_s.append(np.where(res.valid[:, None], res.crlb, np.inf))
            out_v.append(res.valid & inside & np.all(np.isfinite(res.shift), axis=1))
            out_r.append(np.stack([corners, corners + np.rint(pred).astype(int)], axis=1))
    if not out_a:
        nb = len(m.corners)
        return (np.zeros(0, int), np.zeros(0, int), np.zeros((0, nb, 2)),
                np.zeros((0, nb, 2)), np.zeros((0, nb), bool), np.zeros((0, nb, 2, 2), int))
    return (np.array(out_a), np.array(out_b), np.stack(out_d), np.stack(out_s),
            np.stack(out_v), np.stack(out_r))


def measure_links(m: Models, rec, plant, stage_mean: np.ndarray,
                  k_max: int | None = None) -> LinkTable:
    """Every link of a run: the loop's own and, for a chained tracker, the baselines 2..K
    (``k_max``; None: :func:`overlap_baselines`): measured on an image plant's stored frames,
    or given by a plant that models its links (the analytic plant's ``pair_links``).

    Parameters
    ----------
    m : the run's models.
    rec : the loop's record (:class:`compensation.loop.LoopRecord`).
    plant : the run's plant (its ``frames`` (T, rows, cols) or ``pair_links``; None: the
        loop's links only).
    stage_mean : (T, 2) the stage's mean over each tracker exposure, px.
    k_max : the most baselines.

    Returns
    -------
    LinkTable
    """
    k_max = overlap_baselines(m) if k_max is None else int(k_max)
    frames = getattr(plant, "frames", None)
    pairs = getattr(plant, "pair_links", None)
    regions_of = getattr(plant, "pair_regions", None)
    if m.chain and frames is None and pairs is not None:
        parts = [pairs(k_max)]
        if regions_of is not None:  # where the analytic plant draws each pair's noise
            parts[0] = (*parts[0], np.stack([np.stack(regions_of(int(i), int(j))[:2], axis=1)
                                             for i, j in zip(*parts[0][:2], strict=True)])
                        if len(parts[0][0]) else np.zeros((0, len(m.corners), 2, 2), int))
        loop_flag = [parts[0][1] - parts[0][0] == 1]
    else:
        parts = [_loop_blocks(m, rec, stage_mean)]
        loop_flag = [np.ones(len(parts[0][0]), bool)]
        if frames is not None and m.chain and k_max >= 2:
            parts.append(_extra_blocks(m, frames, stage_mean, k_max))
            loop_flag.append(np.zeros(len(parts[1][0]), bool))
    loop = np.concatenate(loop_flag)
    with_regions = m.chain and all(len(p) == 6 for p in parts)
    a, b, d, s, v = (np.concatenate(x) for x in list(zip(*parts, strict=False))[:5])
    mean, sig, nblk, chi2 = combine_blocks(d, s, v)
    ok = nblk >= 2
    dof = np.maximum(nblk - 1, 0)
    # the record's consistency: the blocks' scatter against their bounds, pooled (>= 1)
    eff = np.sqrt(np.maximum(chi2[ok].sum(axis=0) / max(dof[ok].sum(), 1), 1.0)) if ok.any() \
        else np.ones(2)
    deliver = np.asarray(rec.arrive_s, dtype=np.float64)[b]
    valid = (nblk >= 1) & np.all(np.isfinite(mean), axis=1)
    if not with_regions:
        return LinkTable(a, b, mean, sig * eff, valid, deliver, b - a, nblk, loop, eff)
    # each block's part of its link's error: its inverse-variance weight times its error
    share = np.where(v[..., None], sig[:, None] ** 2 / np.maximum(s, 1e-12), 0.0) * eff
    return LinkTable(a, b, mean, sig * eff, valid, deliver, b - a, nblk, loop, eff,
                     np.concatenate([p[5] for p in parts]), share,
                     int(m.scenario.correlator.block_px), int(getattr(plant, "cell_px", 1)))

"""Ground control from a coarser reference orthoimage (``product.ground_control.kind:
orthoimage``): absolute fixes of the record measured by correlating the corrected product
against a reference of the scene, fused with the record's links in the same solve.

The reference is the scene at ``gsd_factor`` times the product's GSD on the product's nominal
(motion-free) grid: the static version's radiance (the nominal lines of sight, before any
detector) averaged over ``gsd_factor`` x ``gsd_factor`` pixels (a coarse detector's pixel
aperture) after its own exposure on the stream ``reference``: its noise is never the
product's. The ground-only product corrected by the record (``open``, rectified onto the
nominal grid by the record's line offsets, the same binning) is correlated against it by the
run's correlator in chips of ``chip_px`` reference pixels, as many across the product as fit,
at ``points`` places along the strip. Where the record errs by ``off_true - off_est`` the
corrected product shows the static content displaced by that difference, so each chip row
measures the record's mean error over its lines: one absolute fix of the jitter
(:class:`ground.aiding.Absolute`) at the lines' mean time. Its accuracy is each chip's
least-squares error from the pair's own residual (:func:`chip_sigma`; reference pixels x
``gsd_factor``) scaled up by the fixes' own consistency (the chips of a row measure the same
offset; their scatter against their errors), never by the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from correlator.tracker import BlockTracker
from ground.aiding import Absolute, frame_position
from imc.scenario import ScenarioError
from imc.wiring import streams
from imc.wiring.build import Models
from imc.wiring.links import combine_blocks

#: passes of each chip resampled at its estimate (the correlator's pull toward zero removed)
WARP_PASSES = 3


@dataclass(frozen=True, eq=False)  # holds arrays
class OrthoFixes:
    """The reference orthoimage's fixes: ``absolute`` (the fixes, px), the product lines each
    chip row covers ``lines`` (m, 2) [first, stop), the chips used per row ``chips`` (m,),
    the consistency factor on the bound ``efficiency`` (2,), and the reference's shape."""

    absolute: Absolute
    lines: np.ndarray
    chips: np.ndarray
    efficiency: np.ndarray
    reference_shape: tuple[int, int]


def bin_image(image: np.ndarray, factor: int) -> np.ndarray:
    """The mean over ``factor`` x ``factor`` pixels (a coarse pixel's aperture); NaN where any
    pixel of the bin is NaN; the image cropped to whole bins."""
    f = int(factor)
    h, w = (np.asarray(image.shape) // f) * f
    return np.asarray(image, dtype=np.float64)[:h, :w].reshape(h // f, f, w // f, f).mean(
        axis=(1, 3))


def reference_orthoimage(m: Models, static_radiance: np.ndarray, integration_s: float
                         ) -> np.ndarray:
    """The reference at ``gsd_factor`` x the product's GSD (DN, float64): the static radiance
    exposed with the product's optics and detector on the stream ``reference`` (its own noise),
    binned ``gsd_factor`` x ``gsd_factor``."""
    from camera.exposure import expose

    f = m.scenario.product.ground_control.gsd_factor
    gain = m.sensor.gain_for(static_radiance)
    dn = expose(np.pad(static_radiance, 16, mode="reflect"), m.optics, m.sensor,
                streams.rng(m.scenario.seed, "reference"), integration_s, gain_e=gain)
    dn = dn[16:16 + static_radiance.shape[0], 16:16 + static_radiance.shape[1]]
    return bin_image(dn.astype(np.float64), f)


def chip_corners(shape: tuple[int, int], chip: int, points: int, margin: int = 1
                 ) -> np.ndarray:
    """Top-left corners (points, across, 2) of the chips: ``points`` rows spread evenly along
    the lines (centred in equal parts), as many chips across as fit within ``margin`` pixels
    of the edges (centred); a ScenarioError naming the field when none fits."""
    rows, cols = shape
    across = (cols - 2 * margin) // chip
    if across < 1 or rows < chip + 2 * margin:
        raise ScenarioError(f"product.ground_control.chip_px: {chip} reference pixels do not fit "
                            f"the {rows} x {cols} reference (product.cols / gsd_factor); lower "
                            "it")
    centre = (np.arange(points) + 0.5) / points * rows
    r0 = np.clip(np.rint(centre - chip / 2.0).astype(int), margin, rows - chip - margin)
    c0 = (cols - across * chip) // 2 + np.arange(across) * chip
    return np.stack(np.broadcast_arrays(r0[:, None], c0[None, :]), axis=-1)


def chip_sigma(reference: np.ndarray, current: np.ndarray, corner: np.ndarray, chip: int,
               shift_px: np.ndarray) -> np.ndarray:
    """The least-squares error (2,) px of a chip's shift from the pair's own residual: the
    current image sampled at the chip's pixels moved by the estimate (``cur(x) ~ ref(x -
    d)``, cubic spline) less the reference chip has variance s^2 (both images' noise and
    whatever else they do not share), and the shift's covariance is ``s^2 (J^T J)^-1`` with J
    the chips' mean gradient (Lucas-Kanade). Unlike a noise estimate from one image, the
    texture an aliased coarse chip carries at the pixel scale cancels in the residual."""
    from scipy import ndimage

    r0, c0 = (int(x) for x in corner)
    ref = reference[r0:r0 + chip, c0:c0 + chip]
    qr, qc = np.mgrid[r0:r0 + chip, c0:c0 + chip].astype(np.float64)
    cur = ndimage.map_coordinates(current, [qr + shift_px[0], qc + shift_px[1]], order=3,
                                  mode="nearest")
    res = cur - ref
    res = res - res.mean()
    gr, gc = np.gradient(0.5 * (cur + ref))
    jtj = np.array([[np.sum(gr * gr), np.sum(gr * gc)], [np.sum(gr * gc), np.sum(gc * gc)]])
    s2 = float(np.sum(res ** 2) / max(res.size - 3, 1))
    return np.sqrt(np.clip(np.diag(s2 * np.linalg.pinv(jtj)), 0.0, None))


def orthoimage_fixes(reference: np.ndarray, corrected: np.ndarray, est_offsets_px: np.ndarray,
                     line_t_s: np.ndarray, sign: np.ndarray, frame_t_s: np.ndarray,
                     factor: int, chip: int, points: int, correlator=None,
                     rng: np.random.Generator | None = None) -> OrthoFixes:
    """The fixes of the record from the product corrected by it against the reference.

    Parameters
    ----------
    reference : (L / factor, C / factor) the reference orthoimage, DN.
    corrected : (L, C) the product corrected by the record onto the nominal grid, DN (NaN
        where its source left the strip).
    est_offsets_px : (L, 2) the lines' offsets the record gave (with its constant), px.
    line_t_s : (L,) each line's mid-integration time, s.
    sign : (2,) the imager's factors from the jitter to the lines' offsets (+-1).
    frame_t_s : (N,) the network's frame times, s.
    factor : the reference's GSD over the product's.
    chip : a chip's side, reference pixels.
    points : chip rows along the strip.
    correlator : :class:`correlator.core.CorrelatorOptions` (None: the defaults).
    rng : an emulated optical correlator's noise (the stream ``ground_control``).

    Returns
    -------
    OrthoFixes
    """
    f = int(factor)
    coarse = bin_image(corrected, f)
    # the corrected product's edges, where its source left the strip, are not chipped
    margin = int(np.ceil(np.max(np.abs(est_offsets_px)) / f)) + 1
    corners = chip_corners(reference.shape, chip, points, margin)  # (P, A, 2)
    p_n, a_n = corners.shape[:2]
    flat = corners.reshape(-1, 2)
    tracker = BlockTracker(reference, flat, chip, correlator)
    cur = np.nan_to_num(coarse, nan=float(np.nanmean(coarse)))
    res = tracker.update(cur, None, rng)
    # the correlator's estimate at a few hundredths of a reference pixel is pulled toward
    # zero on a coarse (aliased) chip: each chip is resampled at its estimate and measured
    # again until the estimate settles (the remainder's pull then vanishes with it)
    for _ in range(WARP_PASSES):
        d0 = np.where(np.isfinite(res.shift), res.shift, 0.0)
        flow = np.broadcast_to(d0[:, None, None, :], (len(d0), chip, chip, 2))
        res = tracker.update(cur, None, rng, flow=flow)
    whole = np.array([np.all(np.isfinite(coarse[r:r + chip, c:c + chip])) for r, c in flat])
    valid = res.valid & whole & np.all(np.isfinite(res.shift), axis=1)
    bound = np.stack([chip_sigma(reference, cur, c, chip, d) if ok else np.full(2, np.inf)
                      for c, d, ok in zip(flat, res.shift, valid, strict=True)])
    # cur(x) ~ ref(x - d) and corrected[y] ~ static[y + (off_true - off_est)]: the record's
    # error in the lines' offsets is -d, in reference pixels
    d = np.where(valid[:, None], -res.shift * f, np.nan).reshape(p_n, a_n, 2)
    sig = np.where(valid[:, None], bound * f, np.inf).reshape(p_n, a_n, 2)
    mean, sigma, used, chi2 = combine_blocks(d, sig, valid.reshape(p_n, a_n))
    # the fixes' consistency: the chips of a row measure the same lines' offset, so their
    # scatter against their bounds scales the bound up (never down: a bias common to the
    # chips, e.g. the correlator's at small sub-pixel shifts, does not scatter)
    ok = used >= 2
    dof = int(np.maximum(used - 1, 0)[ok].sum())
    eff = np.sqrt(np.maximum(chi2[ok].sum(axis=0) / max(dof, 1), 1.0)) if dof else np.ones(2)
    keep = (used >= 1) & np.all(np.isfinite(mean), axis=1)
    if not keep.any():
        raise ScenarioError("product.ground_control: no chip of the reference orthoimage "
                            "correlated with the product; use more points or larger chips "
                            "(chip_px)")
    lines = np.stack([corners[:, 0, 0] * f, (corners[:, 0, 0] + chip) * f], axis=1)[keep]
    sg = np.asarray(sign, dtype=np.float64)
    # the jitter's line average the record gave, corrected by the measured error
    s_fix = np.array([((est_offsets_px[lo:hi] + err) * sg).mean(axis=0)
                      for (lo, hi), err in zip(lines, mean[keep], strict=True)])
    t_fix = np.array([line_t_s[lo:hi].mean() for lo, hi in lines])
    fixes = Absolute(frame_position(t_fix, frame_t_s), s_fix, sigma[keep] * eff)
    return OrthoFixes(fixes, lines, used[keep], eff, tuple(int(x) for x in reference.shape))


def orthoimage_control(m: Models, plan, rendered, exposed, restitution):
    """The restitution re-solved with the reference orthoimage's fixes: the ground-only
    product (``open``) corrected by ``restitution``'s record, correlated against the reference
    (:func:`orthoimage_fixes`), the fixes fused with the same links
    (:func:`imc.wiring.restitution.restitute`). Its ``control`` holds the fixes' figures:
    their count, predicted accuracy and, for the report only, their error against the
    rendering's true offsets (the solve never sees it).

    Parameters
    ----------
    m : the run's models.
    plan : the product's plan.
    rendered, exposed : the product's renders and detector images
        (:class:`imc.wiring.product.Rendered`, :class:`imc.wiring.product.Exposed`).
    restitution : the record's restitution without ground control (its ``links`` set).

    Returns
    -------
    imc.wiring.restitution.Restitution
    """
    from dataclasses import replace

    from ground.rectify import rectify
    from imc.wiring.product import line_offsets
    from imc.wiring.restitution import restitute

    est = line_offsets(plan, restitution.record, None)
    corrected = rectify(exposed.images["scene", "open"], est, fill=np.nan).image
    reference = reference_orthoimage(m, rendered.radiance["scene", "static"],
                                     plan.integration_s)
    gc = m.scenario.product.ground_control
    fx = orthoimage_fixes(reference, corrected, est, plan.line_t_s + 0.5 * plan.integration_s,
                          plan.sign, m.frame_mid_s, gc.gsd_factor, gc.chip_px, gc.points,
                          m.correlator, streams.rng(m.scenario.seed, "ground_control"))
    rest = restitute(m, restitution.links, absolute=fx.absolute)
    true = rendered.truth_offset_px["open"]
    err = np.array([((true[lo:hi] - est[lo:hi]) * plan.sign).mean(axis=0)
                    for lo, hi in fx.lines])
    meas = fx.absolute.s_px - np.array([(est[lo:hi] * plan.sign).mean(axis=0)
                                        for lo, hi in fx.lines])
    control = {"kind": "orthoimage", "fixes": int(len(fx.lines)),
               "gsd_factor": gc.gsd_factor, "chip_px": gc.chip_px,
               "chips": int(fx.chips.sum()),
               "reference_shape": [int(x) for x in fx.reference_shape],
               "efficiency": [float(x) for x in fx.efficiency],
               "predicted_rms_px": [float(x) for x in
                                    np.sqrt(np.mean(fx.absolute.sigma_px ** 2, axis=0))],
               "error_rms_px": [float(x) for x in np.sqrt(np.mean((meas - err) ** 2,
                                                                  axis=0))]}
    return replace(rest, control=control)

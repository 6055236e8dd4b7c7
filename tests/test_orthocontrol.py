"""Ground control from a coarser reference orthoimage (imc.wiring.orthocontrol): the fixes a
reference at 4x the GSD measures on a product corrected by an erring record recover that
record's error, and the option refuses a product without images."""

import numpy as np
import pytest
from scipy import ndimage

from ground.rectify import rectify
from imc.scenario import ScenarioError, parse_scenario
from imc.wiring.orthocontrol import bin_image, chip_corners, orthoimage_fixes
from tests.test_product import TDI


def _synthetic(seed: int = 5, lines: int = 1024, cols: int = 160):
    """A textured static scene, a strip displaced by true offsets, the record's offsets that
    err by a known smooth error e, the strip corrected by them and a 4x coarser reference
    with its own noise: (reference, corrected, est, e)."""
    rng = np.random.default_rng(seed)
    static = ndimage.gaussian_filter(rng.normal(size=(lines + 64, cols + 64)), 1.5)
    static = 1000.0 + 300.0 * static / static.std()
    li = np.arange(lines)
    ph = 2 * np.pi * li / lines
    off = np.stack([0.3 + 0.8 * np.sin(ph), -0.2 + 0.5 * np.cos(ph)], axis=1)
    e = np.stack([0.10 + 0.10 * li / lines, -0.12 + 0.04 * np.sin(ph)], axis=1)
    ll, cc = np.meshgrid(li, np.arange(cols), indexing="ij")
    strip = ndimage.map_coordinates(static, [ll + 32 + off[:, :1], cc + 32 + off[:, 1:]],
                                    order=3) + rng.normal(0.0, 10.0, (lines, cols))
    reference = bin_image(static[32:32 + lines, 32:32 + cols]
                          + rng.normal(0.0, 10.0, (lines, cols)), 4)
    est = off - e
    corrected = rectify(strip, est, fill=np.nan).image
    return reference, corrected, est, e


def test_a_reference_orthoimage_recovers_the_records_error_at_its_chips():
    reference, corrected, est, e = _synthetic()
    t = np.arange(len(est)) * 1e-4
    frames = np.arange(0.0, t[-1] + 0.01, 0.005)
    fx = orthoimage_fixes(reference, corrected, est, t, np.array([1.0, -1.0]), frames,
                          4, 16, 6)
    assert len(fx.lines) == 6 and fx.chips.sum() >= 10
    sign = np.array([1.0, -1.0])
    measured = fx.absolute.s_px - np.array([(est[a:b] * sign).mean(axis=0) for a, b in fx.lines])
    true = np.array([(e[a:b] * sign).mean(axis=0) for a, b in fx.lines])
    # the record errs by 0.10-0.20 px (row) and 0.08-0.16 px (col); the fixes recover it to
    # a few thousandths
    print("fix error", measured - true, "predicted", fx.absolute.sigma_px)
    assert np.min(np.abs(true)) > 0.08
    assert np.max(np.abs(measured - true)) < 0.02
    # the predicted accuracy holds: normalised errors of RMS within 3
    z = (measured - true) / fx.absolute.sigma_px
    assert np.sqrt(np.mean(z ** 2)) < 3.0
    # fixes at the chips' mean times, as fractional frame positions
    t_fix = np.array([t[a:b].mean() for a, b in fx.lines])
    assert np.allclose(np.interp(fx.absolute.frame, np.arange(len(frames)), frames), t_fix)


def test_chips_fit_the_reference_or_the_field_is_named():
    c = chip_corners((200, 40), 16, 4, margin=2)
    assert c.shape == (4, 2, 2) and c[..., 1].min() >= 2 and c[..., 1].max() + 16 <= 38
    with pytest.raises(ScenarioError, match="product.ground_control.chip_px"):
        chip_corners((200, 40), 64, 4)


def test_an_orthoimage_needs_the_rendered_product():
    d = {**TDI, "product": {**TDI["product"], "render": False,
                            "ground_control": {"kind": "orthoimage"}}}
    with pytest.raises(Exception, match="ground_control.kind 'orthoimage'.*product.render"):
        parse_scenario(d)


def test_a_runs_orthoimage_fixes_enter_the_solve_and_are_reported(tmp_path):
    # the TDI test strip (300 lines x 128 columns, analytic tracker): the product corrected
    # by the record, correlated against the static scene at 4x the GSD in 16-px chips, the
    # fixes fused in the solve and reported
    from imc.pipeline import run_scenario

    d = {**TDI, "product": {**TDI["product"], "samples": 4,
                            "ground_control": {"kind": "orthoimage", "points": 3,
                                               "chip_px": 16}}}
    metrics, _ = run_scenario(parse_scenario(d), tmp_path / "run", rerun=False)
    rest = metrics["product"]["record"]["restitution"]
    gc = rest["ground_control"]
    assert "orthoimage" in rest["aiding"] and gc["fixes"] >= 1
    # the fixes are not over-confident: their real error within 3x their predicted one
    # (one 16 x 16 chip of this small strip: 0.007 / 0.11 px against 0.04 / 0.06 predicted)
    pred, err = np.array(gc["predicted_rms_px"]), np.array(gc["error_rms_px"])
    assert np.all(err < 3 * pred)
    # absolute geometry (nothing removed) from the fixes
    assert "control_points" in metrics["product"]["geometry"]["open"]

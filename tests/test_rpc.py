"""The product as a Level-1 product (ground.rpc, ground.ortho, imc.wiring.level1): RPCs
fitted to the nominal lines of sight, a round trip ground -> image -> ground, GDAL's RPC
transformer against the fit's own evaluation, orthorectification of a static product
against the camera model's truth, and the geolocation of a known shift.

The product here is a small synthetic TDI strip: each version's pixel is an analytic albedo
sampled where the camera model says the pixel's content lies (no renderer), so the images
carry exactly the geometry the check points' truth has."""

from __future__ import annotations

import numpy as np
import pytest

from camera.linescan import line_offset_px
from ground.ortho import ce90, dem_dataset, geolocation, rpc_pixels
from ground.rpc import fit_rpc, rpc_ground, rpc_image, shifted
from imc.scenario import parse_scenario
from imc.wiring.build import build_models
from imc.wiring.level1 import MapFrame, _truth_fn, fit_nominal_rpc, level1_study, scene_dem
from imc.wiring.product import Ground, Versions, gsd_m, plan_product
from tests.test_product import _tdi

SAMPLES = 4
#: the closed version's constant stage offset (row, col), px: a known shift of the content
SHIFT_PX = (0.6, -0.8)


def _albedo(e, n):
    return (0.4 + 0.2 * np.sin(2 * np.pi * e / 9.3 + 0.3) * np.cos(2 * np.pi * n / 7.1)
            + 0.1 * np.sin(2 * np.pi * (e + n) / 13.7))


def _stage(t):
    t = np.asarray(t, dtype=np.float64)
    return np.broadcast_to(np.array(SHIFT_PX), t.shape + (2,)).copy()


@pytest.fixture(scope="module")
def strip():
    """Models, plan, versions (static; open: the true pose with 0.3 px jitter; closed: the
    nominal pose and a constant stage offset) and their synthetic images."""
    m = build_models(parse_scenario(_tdi(lines=200, cols=128)))
    plan = plan_product(m)
    versions = Versions({"static": None, "open": None, "closed": _stage},
                        {"static": True, "open": False, "closed": True})
    ll, cc = (a.ravel() for a in np.mgrid[0:plan.n_lines, 0:len(plan.cols)].astype(float))
    products, truth = {}, {}
    smp = plan.imager.sampling(SAMPLES)
    for name in versions.names:
        g = _truth_fn(m, plan, versions.stage[name], versions.nominal[name], SAMPLES)(ll, cc)
        products["scene", name] = _albedo(g[:, 0], g[:, 1]).reshape(plan.n_lines, -1)
        if name != "static":
            probes = np.array([plan.cols[0], plan.cols[-1]], dtype=np.float64)
            truth[name] = line_offset_px(m.main_camera, plan.imager, smp, plan.t0_s,
                                         np.arange(plan.n_lines), probes, m.terrain.height_at,
                                         versions.stage[name],
                                         versions.nominal[name]).mean(axis=1)
    ground = Ground({"true": truth, "record": {}}, {}, products, {}, {}, {}, {}, 0.0)
    return m, plan, versions, ground


@pytest.fixture(scope="module")
def level1(strip):
    m, plan, versions, ground = strip
    return level1_study(m, plan, versions, ground, SAMPLES, gsd_m(m))


def test_ce90_of_known_errors():
    e = np.tile([[0.3, -0.4]], (50, 1))
    g = geolocation(e)
    assert g.ce90_m == pytest.approx(0.5, abs=1e-12)
    assert g.relative_ce90_m == pytest.approx(0.0, abs=1e-12)
    # a ring of radius 1 plus nothing else: CE90 is its radius; the 90th percentile of 1..100
    ring = np.column_stack([np.cos(np.arange(40)), np.sin(np.arange(40))])
    assert ce90(ring) == pytest.approx(1.0, abs=1e-12)
    assert ce90(np.column_stack([np.arange(1.0, 101.0), np.zeros(100)])) == pytest.approx(90.1)


def test_rpc_fit_and_round_trip_through_gdal(strip):
    m, plan, _, _ = strip
    mf = MapFrame.of(m)
    dem = scene_dem(m, mf, (-300.0, -300.0, 300.0, 300.0))
    nominal = fit_nominal_rpc(m, plan, SAMPLES, mf, dem)
    fit = nominal.fit
    # against the camera model's nominal lines of sight, at points between the fit's nodes
    assert max(fit.check_max_px) < 0.01
    assert fit.height_range_m[1] - fit.height_range_m[0] > 20.0  # the relief is spanned
    # ground -> image -> ground at heights across the range, away from the fit's nodes
    rng = np.random.default_rng(5)
    line = rng.uniform(0, plan.n_lines - 1, 200)
    samp = rng.uniform(0, len(plan.cols) - 1, 200)
    h = rng.uniform(*fit.height_range_m, 200)
    lon, lat, _ = rpc_ground(fit.rpc, line, samp, h)
    back = np.column_stack(rpc_image(fit.rpc, lon, lat, h))
    assert np.max(np.abs(back - np.column_stack([line, samp]))) < 1e-6
    # the ground point the RPC gives against the camera model's, in pixels
    from camera.linescan import pixel_ground_m

    smp = plan.imager.sampling(SAMPLES)
    xy_rpc = mf.xy(lon, lat)
    xy_true = mf.xy_of_enu(np.concatenate([pixel_ground_m(
        m.main_camera, plan.imager, smp, plan.t0_s, line[i:i + 1],
        samp[i:i + 1] + plan.cols[0], mf.layer(h[i]), None, True) for i in range(20)]))
    err_px = np.hypot(*(xy_rpc[:20] - xy_true).T) / gsd_m(m)
    assert err_px.max() < 0.01
    # GDAL's RPC transformer reads the same coefficients the same way (pixel centres)
    with dem_dataset(np.zeros_like(dem.heights_m), dem.transform, dem.crs) as path:
        lon0, lat0, _ = rpc_ground(fit.rpc, line, samp, 0.0)
        gd = rpc_pixels(fit.rpc, lon0, lat0, path)
    assert np.max(np.abs(gd - np.column_stack([line, samp]))) < 1e-6


def test_a_shifted_rpc_moves_the_pixels_by_the_shift():
    lon, lat = np.meshgrid(np.linspace(10.0, 10.01, 9), np.linspace(35.0, 35.01, 9))
    h = np.zeros_like(lon)
    line, samp = 1000 * (35.01 - lat) / 0.01, 1000 * (lon - 10.0) / 0.01 + 0.02 * h
    hs = np.concatenate([h.ravel() - 50, h.ravel() + 50])
    fit = fit_rpc(np.tile(lon.ravel(), 2), np.tile(lat.ravel(), 2), hs,
                  np.tile(line.ravel(), 2), np.tile(samp.ravel(), 2) + 0.02 * hs)
    a = np.column_stack(rpc_image(fit.rpc, lon.ravel(), lat.ravel(), 0.0))
    b = np.column_stack(rpc_image(shifted(fit.rpc, 2.5, -1.25), lon.ravel(), lat.ravel(), 0.0))
    assert np.allclose(b - a, [-2.5, 1.25], atol=1e-9)


def test_the_orthorectified_static_product_lands_on_the_truth(strip, level1):
    m = strip[0]
    gsd = gsd_m(m)
    g = level1.geolocation["static"]
    assert g["n"] >= 100
    assert g["ce90_m"] <= 0.1 * gsd
    assert max(level1.fit["check_max_px"]) < 0.01
    # GDAL's warper interpolates the transformer between exact points (0.125 px by default)
    assert level1.fit["warp_deviation_px"] < 0.125
    # the orthoimages themselves: the static's content against the albedo on the map grid
    o = level1.ortho["static"]
    assert np.isfinite(o).mean() > 0.3


def test_geolocation_of_a_known_shift_and_of_the_jitter(strip, level1):
    m, plan, _, _ = strip
    gsd = gsd_m(m)
    c = level1.geolocation["closed"]
    # a constant stage offset moves every pixel's content by the same ground distance
    expect = np.array(c["from_lines"]["mean_m"])
    assert np.hypot(*expect) > 0.8 * gsd  # (0.6, -0.8) px: 1 px
    assert np.allclose(c["mean_m"], expect, atol=0.01 * gsd)
    assert c["ce90_m"] == pytest.approx(np.hypot(*expect), rel=0.02)
    assert max(c["relative_rms_m"]) < 0.01 * gsd
    # the orthoimages see the same shift by correlation
    assert np.allclose(c["misregistration_m"], expect, atol=0.05 * gsd)
    # the open product's jitter: its geolocation is the lines' offsets in metres
    o = level1.geolocation["open"]
    assert o["ce90_m"] > 0.2 * gsd
    assert o["ce90_m"] == pytest.approx(o["from_lines"]["ce90_m"], rel=0.1)


def test_a_long_strip_is_orthorectified_over_its_middle(strip, monkeypatch):
    # the window's rows counted from the product's line 0: the same figures on its middle
    import imc.wiring.level1 as level1_mod

    m, plan, versions, ground = strip
    monkeypatch.setattr(level1_mod, "ORTHO_LINES", 100)  # 128 of the 200 lines (the cols)
    l1 = level1_study(m, plan, versions, ground, SAMPLES, gsd_m(m))
    assert l1.ortho_lines == (36, 164)
    gsd = gsd_m(m)
    assert l1.geolocation["static"]["ce90_m"] <= 0.1 * gsd
    c = l1.geolocation["closed"]
    assert np.allclose(c["mean_m"], c["from_lines"]["mean_m"], atol=0.01 * gsd)
    assert np.allclose(c["misregistration_m"], c["from_lines"]["mean_m"], atol=0.05 * gsd)

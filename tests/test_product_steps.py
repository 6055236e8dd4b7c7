"""The main imager's product through its own steps (imc.wiring.product), with figures that
fail when the product is wrong: the record-based geometry against an injected record error,
the restoration's MTF and noise gain on a known smear, the NIIRS loss of a known blur, and
the product's report pieces (quicklook panels, HTML section, Rerun entities)."""

from pathlib import Path

import numpy as np
import pytest
from scipy.special import ndtr

from camera.linescan import line_offset_px
from ground.quality import niirs_giqe5
from ground.record import MotionRecord
from imc.outputs.product_files import restoration_gain
from imc.scenario import parse_scenario
from imc.wiring.build import build_models
from imc.wiring.product import (
    Exposed,
    Ground,
    Rendered,
    Versions,
    correct_image,
    ground_versions,
    measure_quality,
    perfect_jitter,
    plan_product,
    target_window,
)
from tests.test_product import TDI, _record

#: the synthetic target: side, square half-side (px), albedo contrast (DN), optics sigma (px)
SIDE, HALF, LEVELS, SIGMA_OPT = 192, 48, (240.0, 1000.0), 0.45
SUPER = 8


@pytest.fixture(scope="module")
def models():
    return build_models(parse_scenario(TDI))


def _square(smear_px: float = 0.0) -> np.ndarray:
    """A slanted square (5 deg) of SIDE px, supersampled SUPER x (the pixel's area), through a
    Gaussian optics of SIGMA_OPT px and a box smear of ``smear_px`` along rows; DN."""
    from scipy.ndimage import gaussian_filter, uniform_filter1d

    n = SIDE * SUPER
    x = (np.arange(n) + 0.5) / SUPER - SIDE / 2
    r, c = np.meshgrid(x, x, indexing="ij")
    a = np.deg2rad(5.0)
    u, v = r * np.cos(a) + c * np.sin(a), -r * np.sin(a) + c * np.cos(a)
    img = np.where((np.abs(u) < HALF) & (np.abs(v) < HALF), LEVELS[1], LEVELS[0])
    img = gaussian_filter(img, SIGMA_OPT * SUPER, mode="nearest")
    if smear_px:
        img = uniform_filter1d(img, int(round(smear_px * SUPER)), axis=0, mode="nearest")
    return img.reshape(SIDE, SUPER, SIDE, SUPER).mean(axis=(1, 3))


def _rer(smear_px: float) -> float:
    """The RER of the same edge, analytically: ESF of Gaussian * pixel box * smear box,
    ESF(+0.5) - ESF(-0.5)."""
    x = np.linspace(-6, 6, 24001)
    dx = x[1] - x[0]
    esf = ndtr(x / SIGMA_OPT)
    for width in (1.0, smear_px):
        if width:
            k = max(1, int(round(width / dx)))
            esf = np.convolve(np.pad(esf, k, mode="edge"), np.ones(k) / k, "same")[k:-k]
    return float(np.interp(0.5, x, esf) - np.interp(-0.5, x, esf))


def _ground(products: dict) -> Ground:
    return Ground({}, {}, products, {}, {}, {}, {}, 0.0)


def test_geometry_after_correction_shows_an_injected_record_error(models):
    # a known jitter (the TDI scenario's 30 / 23 Hz, 0.3 px) and a record carrying an injected
    # 20 Hz error of 0.06 / 0.04 px: the lines' error after correction is the injected error
    # through each line's average, more than 10x the perfect record's floor, from both sides
    m = models
    plan = plan_product(m)
    perfect = perfect_jitter(m, _record(m))
    amp = np.array([0.06, 0.04])
    err = amp * np.sin(2 * np.pi * 20.0 * perfect.t_s[:, None] + np.array([0.3, 1.1]))
    record = MotionRecord(perfect.t_s, perfect.motion_px + err, perfect.valid)
    smp = m.imager.sampling(m.scenario.product.samples)
    probes = np.array([plan.cols[0], plan.cols[-1]], dtype=np.float64)
    true = line_offset_px(m.main_camera, m.imager, smp, plan.t0_s, np.arange(plan.n_lines),
                          probes, m.terrain.height_at).mean(axis=1)
    n = plan.n_lines
    radiance = {(s, v): np.ones((n if s == "scene" else target_window(plan).stop
                                 - target_window(plan).start, len(plan.cols)), np.float32)
                for s in ("scene", "target") for v in ("static", "open")}
    rendered = Rendered({"scene": plan, "target": plan.window(target_window(plan))}, radiance,
                        {"open": true}, 0, 0, 0.0, 0.0)
    images = Exposed({k: 100.0 + np.random.default_rng(1).normal(0, 1, v.shape)
                      for k, v in radiance.items()})
    ground = ground_versions(m, rendered, images, Versions.of_run(None), record, perfect, None)
    after = np.array(ground.geometry["open"]["after"]["rms_px"])
    floor = np.array(ground.geometry["open"]["after_perfect_record"]["rms_px"])
    t_mid = plan.line_t_s + 0.5 * plan.integration_s
    e = amp * np.sin(2 * np.pi * 20.0 * t_mid[:, None] + np.array([0.3, 1.1])) * plan.sign
    expected = np.sqrt(np.mean((e - e.mean(axis=0)) ** 2, axis=0))
    assert np.all(expected > 10 * floor)
    np.testing.assert_allclose(after, expected, rtol=0.1)
    # the geometry before correction is the jitter itself: far above either
    before = np.array(ground.geometry["open"]["before"]["rms_px"])
    assert np.all(before > 3 * after)


def test_the_restoration_step_gains_the_wiener_mtf_and_noise_on_a_known_smear(models):
    from ground.restore import run_psfs

    smear, noise, nsr = 1.5, 0.5, 0.05
    rng = np.random.default_rng(7)
    static = _square() + rng.normal(0, noise, (SIDE, SIDE))
    smeared = _square(smear) + rng.normal(0, noise, (SIDE, SIDE))
    # the record's residual: a linear smear of 1.5 px along rows over each line's exposure
    t_line = np.zeros(SIDE)
    t = np.linspace(0.0, 1.0, 64)
    r = np.column_stack([smear * (t - 0.5), np.zeros_like(t)])
    kernels = [q.pixel for q in run_psfs(t, r, t_line, 1.0, np.array([0]))]
    gc, restored, _ = correct_image(smeared, np.zeros((SIDE, 2)), kernels, np.array([0]),
                                    "wiener", nsr)
    products = {(s, k): img for s in ("scene", "target") for k, img in
                (("static", static), ("open_gc", gc), ("open_gc_restored", restored))}
    quality = measure_quality(models, _ground(products))
    gain = restoration_gain(quality)["open"]
    h = np.sinc(0.5 * smear)  # the smear's transfer at Nyquist along rows
    mtf_ratio = gain["mtf_nyquist_after"][0] / gain["mtf_nyquist_before"][0]
    assert mtf_ratio == pytest.approx(h / (h**2 + nsr**2), rel=0.2)
    # across the smear nothing to restore: the across MTF stays within 10 %
    assert gain["mtf_nyquist_after"][1] / gain["mtf_nyquist_before"][1] == pytest.approx(
        1.0, abs=0.1)
    f = np.fft.fftfreq(SIDE)
    hh = np.sinc(smear * f)[:, None] * np.ones(SIDE)[None]
    expected_noise = np.sqrt(np.mean(np.abs(hh / (hh**2 + nsr**2)) ** 2))
    assert gain["noise_gain"] == pytest.approx(expected_noise, rel=0.2)
    assert gain["noise_gain"] > 1.5


def test_niirs_loss_of_a_known_blur_has_its_sign_and_size(models):
    # GIQE 5 weighs the RER by (1 - exp(-1.9 / SNR)) and (log10 RER)^4: at an SNR of ~75 a
    # 4 px smear along rows is what costs an analyst's tenth of a NIIRS
    rng = np.random.default_rng(3)
    noise, smear = 10.0, 4.0
    products = {(s, k): img for s in ("scene", "target") for k, img in
                (("static", _square() + rng.normal(0, noise, (SIDE, SIDE))),
                 ("open", _square(smear) + rng.normal(0, noise, (SIDE, SIDE))))}
    quality = measure_quality(models, _ground(products))
    q_s, q_o = quality["static"], quality["open"]
    assert q_s["rer"][0] == pytest.approx(_rer(0.0), rel=0.05)
    assert q_o["rer"][0] == pytest.approx(_rer(smear), rel=0.05)
    gsd, snr, el = q_s["gsd_m"], q_s["snr"], q_s["elevation_rad"]
    expected = (niirs_giqe5(_rer(0.0), _rer(0.0), gsd, snr, el)
                - niirs_giqe5(_rer(smear), _rer(0.0), gsd, snr, el))
    assert expected > 0.1  # an analyst sees it
    assert q_o["niirs_loss"] == pytest.approx(expected, rel=0.25)
    assert q_s["niirs_loss"] == 0.0


# ------------------------------------------------------------------------------ the report


@pytest.fixture(scope="module")
def product_run(tmp_path_factory):
    from imc.pipeline import run_scenario

    out = tmp_path_factory.mktemp("product_run")
    metrics, _ = run_scenario(parse_scenario(TDI), out, rerun=False)
    return out, metrics


def test_the_quicklook_shows_the_versions_and_their_differences(product_run):
    from imc.outputs.product_report import SHOWN, quicklook_panels, write_quicklook

    out, _ = product_run
    panels = quicklook_panels(out)
    assert list(panels) == [n for n in SHOWN if n in panels]  # the reader's order
    assert {"static", "open", "closed", "open_gc", "closed_gc"} <= set(panels)
    for name, img in panels.items():
        assert img.dtype == np.uint8 and np.std(img) > 10, name  # not blank
    # the 0.3 px jitter moves the open product against the static where the texture is
    diff = np.abs(panels["open"].astype(float) - panels["static"].astype(float))
    assert np.mean(diff) > 2.0
    path = write_quicklook(out)
    from PIL import Image

    png = np.asarray(Image.open(path).convert("L"), dtype=float)
    assert png.shape[1] > 600 and np.std(png) > 20
    # where the difference shows: orthoimages on one grid, differences on one stated scale
    from imc.outputs.product_report import difference_panels, differences_path

    d = difference_panels(out)
    assert set(d["ortho"]) >= {"static", "open", "closed", "open_gc", "closed_gc"}
    assert "static" not in d["diff"] and d["scale_dn"] > 0
    ok = np.isfinite(d["diff"]["open"]) & np.isfinite(d["diff"]["open_gc"])
    # the ground correction removes most of the jitter's difference against the static
    assert np.std(d["diff"]["open_gc"][ok]) < 0.7 * np.std(d["diff"]["open"][ok])
    assert d["crop"]["static"].shape == (48, 48)
    diffs = differences_path(out)
    assert diffs is not None and np.std(np.asarray(Image.open(diffs).convert("L"),
                                                   dtype=float)) > 20


def test_the_report_section_and_rerun_entities_name_the_versions(product_run):
    from imc.outputs.product_report import TITLES, log_product, product_html

    out, metrics = product_run
    page = product_html(metrics, lambda head, rows: "".join(
        "<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows))
    for name in metrics["product"]["quality"]:
        assert TITLES[name] in page
    assert "quicklook.png" in page

    class Rec:
        def __init__(self):
            self.paths = []

        def log(self, path, *a, **k):
            self.paths.append(path)

        def send_columns(self, path, **k):
            self.paths.append(path)

    import rerun as rr

    rec = Rec()
    assert log_product(rec, rr, out)
    for name in metrics["product"]["quality"]:
        assert f"product/{name}" in rec.paths
    assert "product/offset/row/true_open" in rec.paths
    assert "product/offset/col/record_closed" in rec.paths
    assert {"product/ortho/static", "product/ortho_diff/open", "product/ortho_diff/scale",
            "product/edge_crop/closed_gc"} <= set(rec.paths)
    assert "Geolocation (Level-1 product)" in page and "RPC00B" in page


def test_metrics_are_written_from_the_labelled_result(product_run):
    out, metrics = product_run
    import json

    written = json.loads((out / "metrics.json").read_text())["product"]
    assert written["geometry"].keys() == {"open", "closed"}
    assert written["quality"]["static"]["niirs_loss"] == 0.0
    assert Path(written["files"][0]).exists()
    assert set(written) >= {"kind", "lines", "cols", "record", "restoration", "rays_per_s"}
    # the section is the labelled result's: written again from the saved arrays' offsets
    with np.load(out / "product" / "product.npz") as z:
        true, rec = z["offset/true/open"], z["offset/record/open"]
    rms = np.sqrt(np.mean((rec - true) ** 2, axis=0))
    np.testing.assert_allclose(written["geometry"]["open"]["after"]["rms_px"], rms, rtol=1e-5)
    # the Level-1 product: RPCs in each GeoTIFF, the DEM beside them, geolocation figures
    import rasterio

    geo = written["geolocation"]
    assert max(geo["rpc_fit"]["check_max_px"]) < 0.01
    assert geo["versions"]["static"]["ce90_m"] < 0.1 * written["gsd_m"]
    assert geo["versions"]["open"]["ce90_m"] == pytest.approx(
        geo["versions"]["open"]["from_lines"]["ce90_m"], rel=0.1)
    # the ground's correction shows in metres too (0.3 px jitter: 0.31 m relative CE90 open,
    # 0.006 m corrected, measured)
    v = geo["versions"]
    assert v["open_gc"]["relative_ce90_m"] < 0.1 * v["open"]["relative_ce90_m"]
    assert v["closed_gc"]["relative_ce90_m"] < 0.1 * v["closed"]["relative_ce90_m"]
    with rasterio.open(out / "product" / "open_gc.tif") as ds:
        assert ds.rpcs is not None and abs(ds.rpcs.line_off) > 0
    with rasterio.open(out / "product" / "dem.tif") as ds:
        assert np.all(np.isfinite(ds.read(1)))
        dem_crs = ds.crs.to_wkt()
    # as a user orthorectifies the files: open.tif's RPCs and dem.tif through GDAL give the
    # run's own orthoimage
    from affine import Affine

    from ground.ortho import orthorectify

    with np.load(out / "product" / "product.npz") as z:
        mine, t = z["ortho/open"], Affine(*z["ortho_transform"])
    with rasterio.open(out / "product" / "open.tif") as ds:
        img, rpcs = ds.read(1).astype(np.float64), ds.rpcs
    again = orthorectify(img, rpcs, str(out / "product" / "dem.tif"), t, mine.shape, dem_crs)
    ok = np.isfinite(mine) & np.isfinite(again)
    assert ok.mean() > 0.3 and np.max(np.abs(again[ok] - mine[ok])) < 1e-3

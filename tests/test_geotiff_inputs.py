"""Real GeoTIFFs as they come: a DEM a fraction of a pixel short, nodata, several bands, and
the Olinda case (a Landsat-7 scene and its own DEM, from Debian's r-cran-stars; `make data`).

The synthetic files are UTM 32N centred on the central meridian (used as they are):
an orthophoto of 1,024 x 1,024 px at 0.5 m (512 m: the quickstart's tile) and a DEM of 4 m
pixels whose height is its northing in m / 100 (a ramp, so an edge-extended node shows).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from conftest import ROOT, tiny_base

from imc.scenario import ScenarioError, parse_scenario
from imc.wiring.build import build_models
from scene.geotiff import GeoTiffError, place_geotiff, write_geotiff

X0, Y0, PX, N = 499_744.0, 3_874_000.0, 0.5, 1024  # upper-left corner (m), pixel (m), side
DEM_PX = 4.0


def _ortho(path, holes=(), bands=1):
    rng = np.random.default_rng(7)
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(rng.random((N, N)), 2.0, mode="wrap")
    img = ((img - img.min()) / np.ptp(img) * 180 + 40).astype(np.uint8)
    for r, c, s in holes:
        img[r:r + s, c:c + s] = 0
    data = np.stack([img // (b + 1) + (b > 0) for b in range(bands)]) if bands > 1 else img
    write_geotiff(path, data, X0, Y0, PX, PX, crs=32632, nodata=0)
    return data


def _dem(path, short_south_m=0.0, holes=()):
    """A DEM over the orthophoto plus 2 pixels on every side, short_south_m short of its
    south edge (the rest of the extent covers it)."""
    y_top = Y0 + 2 * DEM_PX
    south = Y0 - N * PX + short_south_m
    rows = int(round((y_top - south) / DEM_PX))
    cols = int(N * PX / DEM_PX) + 4
    dy = (y_top - south) / rows  # exactly short_south_m short
    north = y_top - (np.arange(rows) + 0.5) * dy
    z = np.broadcast_to(((north - Y0) / 100.0)[:, None], (rows, cols)).astype(np.float32)
    z = z.copy()
    for r, c, s in holes:
        z[r:r + s, c:c + s] = -9999.0
    write_geotiff(path, z, X0 - 2 * DEM_PX, y_top, DEM_PX, dy, crs=32632, nodata=-9999.0)
    return z


def test_a_dem_half_a_pixel_short_is_edge_extended_with_a_warning(tmp_path):
    _ortho(tmp_path / "o.tif")
    _dem(tmp_path / "d.tif", short_south_m=0.5 * DEM_PX)
    g = place_geotiff(tmp_path / "o.tif", tmp_path / "d.tif", DEM_PX)
    assert not g.resampled and g.terrain.albedo.shape == (N, N)  # the nodes reach its edges
    t = g.terrain
    assert len(t.notes) == 1
    assert t.notes[0].endswith("stops up to 2 m (0.50 DEM px) short of the orthophoto at its "
                               "south edge; edge-extended (its outer pixels repeated)")
    # the south nodes take the last DEM row's height (its pixel centre, 0.5 px inside the
    # DEM's edge: 0.04 m above the ramp's value at the tile's edge); the others the ramp
    rows, south = 130, Y0 - N * PX + 0.5 * DEM_PX
    z_last = (south + 0.5 * (Y0 + 2 * DEM_PX - south) / rows - Y0) / 100.0
    assert np.abs(t.dem_m[-1] - z_last).max() < 1e-5
    step = np.diff(t.dem_m[:-1, 0].astype(np.float64))
    assert np.abs(step - step.mean()).max() < 1e-4 and step.mean() == pytest.approx(
        -DEM_PX / 100.0, rel=1e-3)


def test_a_dem_ten_pixels_short_is_refused_in_one_line(tmp_path):
    _ortho(tmp_path / "o.tif")
    _dem(tmp_path / "d.tif", short_south_m=10 * DEM_PX)
    with pytest.raises(GeoTiffError) as e:
        place_geotiff(tmp_path / "o.tif", tmp_path / "d.tif", DEM_PX)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("scene.geotiff.dem ")
    assert "does not cover the orthophoto" in msg
    short = float(msg.split("(in the DEM's CRS; ")[1].split(" DEM px short")[0])
    assert 9.5 < short <= 10.0  # the tile's nodes stop within a texel of the image's edge
    assert msg.endswith("use a DEM that covers it")


def _scenario(tmp_path, **geotiff):
    d = copy.deepcopy(tiny_base())  # IKONOS-like, 128 x 128 tracker (105 m) at the centre
    d["scene"] = {"kind": "geotiff", "dem_spacing_m": DEM_PX, "sun_elevation_deg": 50,
                  "sun_azimuth_deg": 140,
                  "geotiff": {"ortho": str(tmp_path / "o.tif"), **geotiff}}
    return parse_scenario(d)


def test_nodata_away_from_the_tracker_is_masked_and_reported(tmp_path):
    _ortho(tmp_path / "o.tif", holes=[(10, 10, 20)])  # a 10 m hole 240 m from the centre
    _dem(tmp_path / "d.tif", holes=[(3, 3, 4)])
    m = build_models(_scenario(tmp_path, dem=str(tmp_path / "d.tif")))
    t = m.terrain
    assert t.nodata_albedo.sum() == 400 and t.nodata_dem.any()
    assert [n.split(": ", 1)[1].split(" (")[0] for n in t.notes] == [
        "400 nodata texels", f"{int(t.nodata_dem.sum())} DEM nodes of the tile"]
    from imc.wiring.advisories import advisories
    from imc.wiring.build import build_loop

    assert set(t.notes) <= set(advisories(m, build_loop(m))[1])  # imc run warns with them


@pytest.mark.parametrize("where", ["ortho", "dem"])
def test_nodata_where_the_tracker_looks_is_refused_in_one_line(tmp_path, where):
    c = N // 2
    _ortho(tmp_path / "o.tif", holes=[(c - 4, c - 4, 8)] if where == "ortho" else ())
    k = int(N * PX / DEM_PX / 2) + 2  # the DEM pixel under the centre
    _dem(tmp_path / "d.tif", holes=[(k, k, 1)] if where == "dem" else ())
    with pytest.raises(ScenarioError) as e:
        build_models(_scenario(tmp_path, dem=str(tmp_path / "d.tif")))
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("scene.geotiff: ")
    assert (f"nodata {'texels of scene.geotiff.ortho' if where == 'ortho' else 'DEM nodes'}"
            in msg)
    assert "lie where the tracker looks during the run" in msg
    assert msg.endswith("fill them (gdal_fillnodata.py) or use files without holes there")


def test_a_band_is_picked_or_refused_in_one_line(tmp_path):
    data = _ortho(tmp_path / "o.tif", bands=3)
    from scene.geotiff import read_geotiff

    r = read_geotiff(tmp_path / "o.tif", band=2)
    assert np.array_equal(r.data, data[1].astype(np.float64))
    assert np.allclose(read_geotiff(tmp_path / "o.tif").data, data.mean(axis=0))
    with pytest.raises(ScenarioError, match=r"^scene\.geotiff\.band: 4, but scene\.geotiff\.ortho "
                       r".*o\.tif has 3 bands; pick one of 1\.\.3$"):
        build_models(_scenario(tmp_path, band=4))


OLINDA = ROOT / "scenarios" / "data" / "olinda"


@pytest.mark.skipif(not (OLINDA / "L7_ETMs.tif").is_file(),
                    reason="real data not on this machine: scenarios/data/olinda/ is filled by "
                           "`make data` from Debian's r-cran-stars package (apt-get), which "
                           "this machine could not reach; run `make data` to include it")
def test_olinda_runs_with_its_real_dem_and_the_loop_reduces_the_wobble(tmp_path):
    """scenarios/olinda.yaml, shortened to 0.5 s: the DEM's south edge is edge-extended with
    a warning, and the loop reduces the 1 Hz / 3 Hz wobble at least 5x (the full run: 35.6x)."""
    from imc.pipeline import run_scenario
    from imc.scenario import load_scenario

    sc = load_scenario(ROOT / "scenarios" / "olinda.yaml")
    sc = sc.model_copy(update={"duration_s": 0.5, "metrics": sc.metrics.model_copy(
        update={"blur_images": False})})
    warned: list[str] = []
    met, _ = run_scenario(sc, tmp_path / "olinda", fresh=True, rerun=False, warn=warned.append)
    edge = [w for w in warned if w.startswith("scene.geotiff.dem ")]
    assert len(edge) == 1 and "short of the orthophoto at its south edge; edge-extended" in edge[0]
    assert met["without_compensation"]["rms_total_px"] / met["with_compensation"][
        "rms_total_px"] >= 5.0

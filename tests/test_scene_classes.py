"""Scene classes (statistics the seed paper describes), cloud layers and user GeoTIFFs."""

from __future__ import annotations

import numpy as np
import pytest

from scene.classes import SCENE_CLASSES, cloud_layer, local_contrast, scene_class
from scene.geotiff import GeoTiffError, terrain_from_geotiff, write_geotiff

WINDOW = 80  # 32 m windows of 0.4 m texels (~40 px of 0.8 m: a small tracking block)


@pytest.fixture(scope="module")
def tiles():
    return {k: scene_class(k, 512.0, 0.4, 2.0, np.random.default_rng(1)) for k in SCENE_CLASSES}


def test_classes_are_seeded(tiles):
    again = scene_class("urban", 512.0, 0.4, 2.0, np.random.default_rng(1))
    assert np.array_equal(again.albedo, tiles["urban"].albedo)
    assert np.array_equal(again.dem_m, tiles["urban"].dem_m)
    other = scene_class("urban", 512.0, 0.4, 2.0, np.random.default_rng(2))
    assert not np.array_equal(other.albedo, tiles["urban"].albedo)


def test_class_statistics_follow_the_paper(tiles):
    lc = {k: local_contrast(t.albedo, WINDOW) for k, t in tiles.items()}
    # urban: high contrast, evenly spread (even the least textured windows are contrasted)
    assert np.quantile(lc["urban"], 0.1) > 0.3
    assert tiles["urban"].dem_m.max() > 15.0  # buildings stand in the DEM (shadows)
    # rural: many nearly uniform windows (fields) and some strongly textured ones
    assert np.mean(lc["rural"] < 0.05) > 0.15
    assert np.mean(lc["rural"] > 0.3) > 0.05
    # mountain: high global contrast, very low local contrast in the snow
    a = tiles["mountain"].albedo
    assert a.std() / a.mean() > 0.5
    snow = a > 0.8
    assert 0.25 < snow.mean() < 0.55
    snow_windows = local_contrast(np.where(snow, a, np.nan), WINDOW)
    assert np.nanmedian(snow_windows[np.isfinite(snow_windows)]) < 0.01
    assert tiles["mountain"].dem_m.std() == pytest.approx(0.04 * 512.0, rel=0.01)
    # waves: a distinct pattern, i.e. a spectral peak at one wavelength
    w = tiles["waves"].albedo - tiles["waves"].albedo.mean()
    p = np.abs(np.fft.fft2(w)) ** 2
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(w.shape[0]), np.fft.fftfreq(w.shape[1]),
                              indexing="ij")) / 0.4  # cycles / m
    kp = f.ravel()[np.argmax(p.ravel())]
    assert 1 / 45.0 < kp * 1.1 and kp * 0.9 < 1 / 20.0
    assert p[np.abs(f - kp) < 0.3 * kp].sum() > 0.5 * p.sum()
    # calm water: practically no texture
    assert np.quantile(lc["calm_water"], 0.9) < 0.005
    assert lc["calm_water"].max() < 0.2 * np.quantile(lc["waves"], 0.1)


def test_cloud_layer_cover_and_mesh():
    c = cloud_layer(2000.0, 4.0, 0.3, 1500.0, np.random.default_rng(4))
    assert c.cover == pytest.approx(0.3, abs=0.02)
    verts, faces, uv = c.mesh()
    assert verts[:, 2].min() >= 1500.0 and verts[:, 2].max() <= c.top_m + 1e-6
    assert faces.max() < len(verts) and len(uv) == len(verts)
    assert 0 < len(faces) < 2 * (c.density.shape[0] - 1) ** 2
    with pytest.raises(ValueError, match="cover"):
        cloud_layer(2000.0, 4.0, 1.2, 1500.0, np.random.default_rng(4))


def test_clouds_move_with_parallax(camera_model):
    """A cloud layer 1.5 km up moves against the ground as h v dt / H predicts."""
    from camera.geometry import FocalPlane, project
    from correlator import measure_shift
    from scene.kernel import Renderer, Sun
    from scene.pinhole import ray_keyframes

    terrain = scene_class("urban", 512.0, 0.4, 4.0, np.random.default_rng(1), 0.0)
    clouds = cloud_layer(6000.0, 4.0, 0.5, 1500.0, np.random.default_rng(3), thickness_m=0.0)
    fp = FocalPlane(10.0, 12e-6, 128, 128)
    r_clear = Renderer(terrain, Sun(60.0, 140.0), 128, 128, spp=16)
    r = Renderer(terrain, Sun(60.0, 140.0), 128, 128, spp=16, clouds=clouds)
    dt = 0.05
    poses = [camera_model.pose(np.array([t, t]), nominal=True) for t in (0.0, dt)]
    clear = r_clear.render(ray_keyframes(poses[0], fp, (0, 0), r_clear.z_start_m), 1)
    imgs = [r.render(ray_keyframes(p, fp, (0, 0), r.z_start_m), s)
            for p, s in zip(poses, (1, 2), strict=True)]
    assert imgs[0].mean() > 2.0 * clear.mean()  # bright cloud tops in view
    res = measure_shift(imgs[0][16:112, 16:112], imgs[1][16:112, 16:112])
    # the ground (target) stays put; the cloud layer's image moves by h v dt / (H GSD)
    centre = np.array([[63.5, 63.5]])
    g = camera_model.ground_points(centre, 0.0, lambda e, n: 0.0 * e + 1500.0)
    cloud_motion = (project(g, poses[1][0], fp) - project(g, poses[0][0], fp))[0]
    assert np.linalg.norm(cloud_motion) > 0.5
    assert np.abs(res.shift - cloud_motion).max() < 0.05


def _write_pair(tmp_path, dem=None, dem_origin=(499990.0, 4000010.0), nodata=None):
    rng = np.random.default_rng(0)
    img = (rng.random((200, 300)) * 255).astype(np.uint8)
    write_geotiff(tmp_path / "o.tif", img, 500000.0, 4000000.0, 0.5, 0.5)
    if dem is None:
        dem = (rng.random((40, 60)) * 10).astype(np.float32)
    write_geotiff(tmp_path / "d.tif", dem, *dem_origin, 3.0, 3.0, nodata=nodata)
    return img, dem


def test_geotiff_terrain_round_trip(tmp_path):
    img, dem = _write_pair(tmp_path)
    t, centre = terrain_from_geotiff(tmp_path / "o.tif", tmp_path / "d.tif", 2.0)
    # UTM 32N (the writer's default CRS): placed at its own centre, 75 m east of the central
    # meridian 9 E and 4,000,000 - 50 m north; map metres are 1 / 0.9996 ground metres there
    from pyproj import Transformer

    lon, lat = Transformer.from_crs(32632, 4326, always_xy=True).transform(500075.0, 3999950.0)
    assert centre == pytest.approx((float(lat), float(lon)), abs=1e-12)
    assert 36.1 < centre[0] < 36.2 and centre[1] == pytest.approx(9.0008, abs=1e-4)
    assert t.texel_m == pytest.approx(0.5 / 0.9996, rel=1e-6)
    assert t.dem_spacing_m == pytest.approx(4 * t.texel_m) and t.albedo.shape == (200, 300)
    assert np.allclose(t.albedo, img / 255.0, atol=1e-6)
    # the DEM node at the orthophoto's upper-left corner: map (500000, 4000000) to ~1 mm (the
    # exact placement turns the tile by the grid convergence there, 0.0005 deg)
    r, c = (4000010.0 - 4000000.0) / 3.0 - 0.5, (500000.0 - 499990.0) / 3.0 - 0.5
    r0, c0 = int(r), int(c)
    fr, fc = r - r0, c - c0
    want = (dem[r0, c0] * (1 - fr) * (1 - fc) + dem[r0, c0 + 1] * (1 - fr) * fc
            + dem[r0 + 1, c0] * fr * (1 - fc) + dem[r0 + 1, c0 + 1] * fr * fc)
    assert t.dem_m[0, 0] == pytest.approx(want, rel=1e-3)
    flat, _ = terrain_from_geotiff(tmp_path / "o.tif", None, 2.0)
    assert not flat.dem_m.any()


def test_geotiff_errors_name_the_file_and_the_fix(tmp_path):
    _, dem = _write_pair(tmp_path)
    dem[5, 5] = -9999
    write_geotiff(tmp_path / "holes.tif", dem, 499990.0, 4000010.0, 3.0, 3.0, nodata=-9999)
    write_geotiff(tmp_path / "far.tif", dem, 500100.0, 4000010.0, 3.0, 3.0)
    (tmp_path / "bad.tif").write_bytes(b"not a tiff")
    o = tmp_path / "o.tif"
    # a DEM hole is masked, filled and noted (refused only where the tracker looks: the
    # wiring's check, tests/test_geotiff_inputs.py)
    holed = terrain_from_geotiff(o, tmp_path / "holes.tif", 2.0)[0]
    assert holed.nodata_dem.any() and any("DEM nodes" in n for n in holed.notes)
    with pytest.raises(GeoTiffError, match=r"far.tif: its extent .* does not cover"):
        terrain_from_geotiff(o, tmp_path / "far.tif", 2.0)
    with pytest.raises(GeoTiffError, match=r"bad.tif: cannot read it as a TIFF"):
        terrain_from_geotiff(tmp_path / "bad.tif", None, 2.0)
    with pytest.raises(GeoTiffError, match="file not found"):
        terrain_from_geotiff(tmp_path / "missing.tif", None, 2.0)
    import tifffile

    tifffile.imwrite(tmp_path / "plain.tif", np.ones((32, 32), np.uint8))
    with pytest.raises(GeoTiffError, match="no georeferencing"):
        terrain_from_geotiff(tmp_path / "plain.tif", None, 2.0)


def test_geographic_geotiff_gives_its_centre(tmp_path):
    lat = 35.0
    deg_m = 111_000.0
    img = np.full((64, 64), 100, np.uint8)
    img[::7] = 200
    dlon = 0.5 / deg_m / np.cos(np.radians(lat))
    write_geotiff(tmp_path / "g.tif", img, 10.0, lat + 0.0002, dlon, 0.5 / deg_m, crs=4326,
                  geographic=True)
    t, centre = terrain_from_geotiff(tmp_path / "g.tif", None, 2.0)
    assert t.texel_m == pytest.approx(0.5, rel=0.01)
    assert centre[0] == pytest.approx(lat + 0.0002 - 32 * 0.5 / deg_m, abs=1e-9)

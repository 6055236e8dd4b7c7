"""The main imager's strip rendered line by line (scene.strip, scene.kernel.RayCaster,
camera.linescan): geometry against the camera model, jitter against the truth, misses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import map_coordinates, spline_filter

from camera.geometry import FocalPlane, Pose
from camera.imager import FrameImager, TdiImager
from camera.linescan import imager_camera as icam
from camera.linescan import (
    line_offset_px,
    subpixel_lattice,
    tdi_sampling,
)
from camera.motion import CameraModel
from orbit.attitude import Attitude, orbit_looking_at
from orbit.frames import LocalFrame
from orbit.jitter import JitterTerm
from orbit.kepler import sun_synchronous_inclination_deg
from scene.terrain import Terrain

EPOCH = np.datetime64("2026-06-21T10:30:00")
TILE_M, TEXEL_M, DEM_M = 256.0, 0.2, 2.0
#: albedo waves: (amplitude, wavelength m, direction deg from east, phase rad); 13-17 px
WAVES = ((0.10, 11.0, 35.0, 0.3), (0.10, 14.0, -60.0, 1.1), (0.05, 23.0, 100.0, 2.0))
N_LINES, N_COLS, STAGES, S = 128, 128, 8, 8
JITTER_PX = 0.3


def albedo_fn(east, north):
    a = 0.35
    for amp, lam, ang, ph in WAVES:
        k = 2 * np.pi / lam * np.array([np.cos(np.radians(ang)), np.sin(np.radians(ang))])
        a = a + amp * np.sin(k[0] * east + k[1] * north + ph)
    return a


def height_fn(east, north):
    return 4.0 * np.sin(2 * np.pi * east / 110.0) * np.cos(2 * np.pi * north / 90.0)


@pytest.fixture(scope="module")
def terrain():
    n = int(TILE_M / TEXEL_M)
    x = -TILE_M / 2 + (np.arange(n) + 0.5) * TEXEL_M  # texel centres; row 0 north
    e, nn = np.meshgrid(x, -x)
    m = int(TILE_M / DEM_M) + 1
    g = -TILE_M / 2 + np.arange(m) * DEM_M
    ge, gn = np.meshgrid(g, -g)
    return Terrain(albedo_fn(e, nn).astype(np.float32), TEXEL_M,
                   height_fn(ge, gn).astype(np.float32), DEM_M)


def make_camera(jitter=()):
    orbit = orbit_looking_at(35.0, 10.0, 681e3, sun_synchronous_inclination_deg(681e3), EPOCH)
    fp = FocalPlane(10.0, 12e-6, STAGES, 256)
    att = Attitude("nadir", yaw_steering=True, jitter=tuple(jitter))
    return CameraModel(orbit, att, LocalFrame(35.0, 10.0, 0.0), fp)


@pytest.fixture(scope="module")
def caster(terrain):
    from scene.kernel import RayCaster, Renderer, Sun

    # no sun, a unit sky seen whole: the radiance is the albedo itself (shading-free
    # geometry checks)
    r = Renderer(terrain, Sun(50.0, 140.0, irradiance=0.0, sky_radiance=1.0), 8, 8, spp=1)
    return RayCaster(r, batch_rays=1 << 18, sky_view_dirs=0)


IMAGER = TdiImager(cols=256, stages=STAGES)
COLS = np.arange(64, 64 + N_COLS)


def t0_for(camera, rate):
    """Line 0's start so the strip's middle line is centred on the scene at t = 0."""
    return -(N_LINES / 2 + STAGES / 2) / rate


# --------------------------------------------------------------------------- sampling


def test_sampling_is_stratified_and_centred():
    lat = subpixel_lattice(8)
    for k in range(2):  # one sample per stratum in rows and in columns (Latin)
        assert np.array_equal(np.sort(np.floor((lat[:, k] + 0.5) * 8)), np.arange(8))
    for p in (0, 1, 3):
        im = TdiImager(cols=16, stages=12, clock_phases=p)
        smp = tdi_sampling(im, 5000.0, 8)
        assert np.all(smp.tau_s >= 0) and np.all(smp.tau_s < 12 / 5000.0)
        # the packet's mean position over the integration is the stage plane's centre row
        fine = tdi_sampling(im, 5000.0, 12 * 64 * max(p, 1), footprint=False)
        assert fine.packet_row_px.mean() == pytest.approx(5.5, abs=2e-3)
        assert np.all(np.diff(fine.packet_row_px) >= 0)
    stepped = tdi_sampling(TdiImager(cols=16, stages=32, clock_phases=1), 5000.0, 8)
    # N p / S = 4 is an integer: the instants still spread over the clock step's phase
    phase = np.mod(stepped.tau_s * 5000.0, 1.0)
    assert np.ptp(phase) > 0.8
    with pytest.raises(ValueError, match="samples_per_line"):
        tdi_sampling(IMAGER, 5000.0, 0)
    with pytest.raises(ValueError, match="line_rate_hz"):
        tdi_sampling(IMAGER, -1.0, 8)


def test_truth_offset_signs_for_stage_and_nominal():
    """Nominal and stage-free: zero offset; a stage at +s makes the detectors look at +s,
    i.e. at ground of line l - s_row and column c + s_col (the image moved by -s)."""
    cam = make_camera()
    rate = 8296.0
    smp = tdi_sampling(IMAGER, rate, S)
    lines = np.arange(0, 40, 7)
    zero = line_offset_px(icam(cam, IMAGER), IMAGER, smp, -0.01, lines, COLS[::40], height_fn,
                          nominal=True)
    assert np.abs(zero).max() < 1e-7
    stage = (0.25, -0.4)
    off = line_offset_px(icam(cam, IMAGER), IMAGER, smp, -0.01, lines, COLS[::40], height_fn,
                         stage_offset_px=lambda t: np.broadcast_to(stage, t.shape + (2,)),
                         nominal=True)
    # rows per line ~1 (synchronous within the 8296 Hz guess): 2 % tolerance
    assert off[..., 0] == pytest.approx(np.full(off.shape[:-1], -0.25), rel=0.02)
    assert off[..., 1] == pytest.approx(np.full(off.shape[:-1], -0.4), abs=1e-6)
    # a frame imager: the detector at p looks at p + s, the static frame's pixel p + s
    from camera.linescan import frame_offset_px, frame_sampling

    fim = FrameImager(rows=64, cols=64, exposure_s=1e-3)
    foff = frame_offset_px(icam(cam, fim), fim, frame_sampling(fim, 4), 0.0,
                           np.array([[0.0, 0.0], [63.0, 40.0]]), height_fn,
                           stage_offset_px=lambda t: np.broadcast_to(stage, t.shape + (2,)),
                           nominal=True)
    assert np.abs(foff - stage).max() < 1e-6


# --------------------------------------------------------------------------- rendering


def fit_line_shifts(img, ref_fn, iterations=3):
    """Per-line (d_line, d_col) with img[l, c] ~ ref(l + d_line, c + d_col): Gauss-Newton on
    all lines at once; ref_fn(dl (L,), dc (L,)) -> (L, C) evaluates the reference."""
    n = img.shape[0]
    d = np.zeros((n, 2))
    h = 0.02
    for _ in range(iterations):
        r0 = ref_fn(d[:, 0], d[:, 1])
        jl = (ref_fn(d[:, 0] + h, d[:, 1]) - ref_fn(d[:, 0] - h, d[:, 1])) / (2 * h)
        jc = (ref_fn(d[:, 0], d[:, 1] + h) - ref_fn(d[:, 0], d[:, 1] - h)) / (2 * h)
        res = img - r0
        a11, a12, a22 = (jl * jl).sum(1), (jl * jc).sum(1), (jc * jc).sum(1)
        b1, b2 = (jl * res).sum(1), (jc * res).sum(1)
        det = a11 * a22 - a12**2
        d[:, 0] += (a22 * b1 - a12 * b2) / det
        d[:, 1] += (a11 * b2 - a12 * b1) / det
    return d


def test_static_strip_lines_sit_where_the_camera_model_says(caster):
    """A nadir static strip (relief +-4 m) against the analytic pushbroom geometry: the
    rendered lines sit where the camera model's float64 projection puts them, < 0.01 px RMS
    (measured ~1e-3: float32 start points on the 500 m plane, bilinear texels of 0.25 px)."""
    from scene.strip import render_strip

    cam = make_camera()
    res = render_strip(caster, icam(cam, IMAGER), IMAGER, 0.0, 1, COLS[:4], S,
                       nominal=True)  # the rate
    rate = res.line_rate_hz
    t0 = t0_for(cam, rate)
    static = render_strip(caster, icam(cam, IMAGER), IMAGER, t0, N_LINES, COLS, S, nominal=True)
    assert static.hits == static.rays and static.hit_fraction > 0.999999
    assert np.isfinite(static.radiance).all()
    lines = np.arange(N_LINES)

    def ref(dl, dc):
        """The camera model's static strip: the analytic albedo at the float64 ground
        points of every sample, lines shifted by dl (L,), columns by dc (L,)."""
        c2 = icam(cam, IMAGER)
        smp = tdi_sampling(IMAGER, rate, S)
        t = smp.times_s(t0, lines + dl)  # (L, S)
        det = smp.detector_rc(COLS.astype(float))  # (S, C, 2)
        det = np.broadcast_to(det, t.shape + det.shape[1:]).copy()
        det[..., 1] += dc[:, None, None]
        poses = c2.pose(t, nominal=True)
        p4 = Pose(poses.position_m[:, :, None], poses.enu_from_cam[:, :, None])
        x = c2.ground_points_posed(p4, det, height_fn)
        return albedo_fn(x[..., 0], x[..., 1]).mean(axis=1)

    d = fit_line_shifts(static.radiance.astype(np.float64), ref)
    rms = np.sqrt(np.mean(d**2, axis=0))
    assert rms[0] < 0.01 and rms[1] < 0.01, rms
    # the fit can see a wrong geometry: a model shifted by 0.05 line / -0.03 col is found
    shifted = ref(np.full(N_LINES, 0.05), np.full(N_LINES, -0.03))
    d2 = fit_line_shifts(shifted, ref)
    assert np.abs(d2 - [0.05, -0.03]).max() < 2e-3
    # the truth of the static strip itself is zero
    assert np.abs(static.line_offset_px).max() < 1e-6


@pytest.fixture(scope="module")
def jitter_strips(caster):
    from scene.strip import render_strip

    ifov = 1.2e-6
    jit = (JitterTerm("pitch", 130.0, JITTER_PX * ifov, 0.4),
           JitterTerm("roll", 97.0, JITTER_PX * ifov, 1.3))
    cam = make_camera(jit)
    rate = render_strip(caster, icam(cam, IMAGER), IMAGER, 0.0, 1, COLS[:4], S,
                        nominal=True).line_rate_hz
    t0 = t0_for(cam, rate)
    margin = 4  # the static strip is rendered wider, so it can be interpolated at l + off
    static = render_strip(caster, icam(cam, IMAGER), IMAGER, t0 - margin / rate,
                          N_LINES + 2 * margin,
                          np.arange(COLS[0] - margin, COLS[-1] + margin + 1), S, nominal=True)
    true = render_strip(caster, icam(cam, IMAGER), IMAGER, t0, N_LINES, COLS, S, nominal=False,
                        lines_per_chunk=48)
    return cam, rate, t0, margin, static, true


def stage_fn(t):
    """A stage trajectory (row, col) px that moves inside the lines (70 and 50 Hz)."""
    t = np.asarray(t, dtype=np.float64)
    return np.stack([0.2 * np.sin(2 * np.pi * 70.0 * t) + 0.1,
                     0.15 * np.cos(2 * np.pi * 50.0 * t) - 0.05], axis=-1)


def measure_against_static(img, static, margin):
    coef = spline_filter(static.radiance.astype(np.float64), order=5)
    rows = np.arange(img.shape[0])[:, None] + margin
    cols = np.arange(img.shape[1])[None, :] + margin

    def ref(dl, dc):
        return map_coordinates(coef, [rows + dl[:, None] + 0 * cols,
                                      cols + dc[:, None] + 0 * rows],
                               order=5, prefilter=False, mode="nearest")

    return fit_line_shifts(img.astype(np.float64), ref)


def test_jitter_line_offsets_match_the_truth(jitter_strips):
    """0.3 px sinusoids on pitch (130 Hz) and roll (97 Hz): the per-line offset of the
    rendered strip against the rendered static strip (Gauss-Newton on a quintic spline of the
    static strip) equals line_offset_px within 0.01 px RMS; the signs follow the conventions
    (+pitch moves the image toward +row, as a stage at -pitch would: the line sees the ground
    of line l + pitch_px, a positive row offset; +roll moves it toward +col: the line sees
    column c - roll_px)."""
    cam, rate, t0, margin, static, true = jitter_strips
    assert true.hit_fraction > 0.999999 and np.isfinite(true.radiance).all()
    measured = measure_against_static(true.radiance, static, margin)
    truth = true.line_offset_px
    err = measured - truth
    rms = np.sqrt(np.mean(err**2, axis=0))
    assert rms.max() < 0.01, rms
    # a real signal: ~0.3 px sinusoids (attenuated by the 8-line integration)
    assert np.all(truth.std(axis=0) > 0.15)
    # signs: offsets against the jitter's mean over each line's samples, in px
    smp = tdi_sampling(IMAGER, rate, S)
    jit = cam.attitude.jitter.rotvec_rad(smp.times_s(t0, np.arange(N_LINES))).mean(axis=1)
    jit_px = jit / cam.focal_plane.ifov_rad
    assert np.corrcoef(truth[:, 0], jit_px[:, 1])[0, 1] > 0.99  # pitch -> +row offset
    assert np.corrcoef(truth[:, 1], -jit_px[:, 0])[0, 1] > 0.99  # roll -> -col offset
    expected = np.stack([jit_px[:, 1], -jit_px[:, 0]], axis=-1)
    assert np.abs(truth - expected).max() < 0.02


def test_closed_loop_stage_offsets_match_the_truth(caster, jitter_strips):
    """The same jitter with a stage moving inside the lines (the closed-loop call): the
    rendered strip's offset against the static strip equals line_offset_px (< 0.01 px RMS),
    and differs from the open-loop one by about -stage_row, +stage_col."""
    from scene.strip import render_strip

    cam, rate, t0, margin, static, true = jitter_strips
    closed = render_strip(caster, icam(cam, IMAGER), IMAGER, t0, N_LINES, COLS, S,
                          stage_offset_px=stage_fn)
    measured = measure_against_static(closed.radiance, static, margin)
    rms = np.sqrt(np.mean((measured - closed.line_offset_px) ** 2, axis=0))
    assert rms.max() < 0.01, rms
    smp = tdi_sampling(IMAGER, rate, S)
    st = stage_fn(smp.times_s(t0, np.arange(N_LINES))).mean(axis=1)
    diff = closed.line_offset_px - true.line_offset_px
    assert np.abs(diff - st * [-1.0, 1.0]).max() < 0.01


def test_chunks_resume_identically(caster, jitter_strips):
    from scene.strip import iter_strip

    cam, rate, t0, _, _, true = jitter_strips
    chunks = list(iter_strip(caster, icam(cam, IMAGER), IMAGER, t0, N_LINES, COLS, S, first_line=96,
                             lines_per_chunk=48))
    assert [c.first_line for c in chunks] == [96]
    assert np.array_equal(chunks[0].radiance, true.radiance[96:])
    assert np.array_equal(chunks[0].line_offset_px, true.line_offset_px[96:])


def test_misses_are_filled_and_counted(caster):
    """Columns beyond the tile's edge miss: counted in the hit fraction, filled (no NaN)."""
    from scene.kernel import _fill_misses
    from scene.strip import render_strip

    cam = make_camera()
    wide = TdiImager(cols=512, stages=STAGES)  # 512 px x 0.82 m > 256 m: the edges miss
    res = render_strip(caster, icam(cam, wide), wide, -0.002, 4, np.arange(0, 512, 2), 2,
                       nominal=True)
    assert np.isfinite(res.radiance).all()
    assert 0.3 < res.hit_fraction < 0.7 and res.hits == res.first_hits
    # filled from the nearest hit of its own row
    a = np.array([[np.nan, 1.0, np.nan, np.nan, 4.0, np.nan]])
    assert np.array_equal(_fill_misses(a), [[1.0, 1.0, 1.0, 4.0, 4.0, 4.0]])


def test_mean_level_matches_a_tracker_render():
    """The caster's radiance model (reflectance x (E cos V / pi + sky x sky view)) against the
    tracker's Mitsuba render (direct integrator, spp 16, Monte Carlo) of the same ground, 27 deg
    RMS slopes: mean within 1 % (measured < 0.1 %; without the sky-view factor +1.4 %), and the
    same picture (the render's Gaussian pixel filter and its noise keep r below 1). The two
    kernel paths (planar uv + per-face terms; full surface interaction + BSDF) agree pixel by
    pixel but where a shadow edge crosses a sample (their shadow rays start differently)."""
    from scene.kernel import RayCaster, Renderer, Sun
    from scene.pinhole import ray_keyframes
    from scene.strip import render_frame
    from scene.terrain import procedural_terrain

    terr = procedural_terrain(512.0, 0.4, 4.0, 15.0, np.random.default_rng(3))
    cam = make_camera()
    n = 64
    fp = FocalPlane(10.0, 12e-6, n, n)
    # Monte Carlo (unbiased): the fixed quadrature's 16 sky directions see nothing near a
    # slope's horizon, +1.1 % on these slopes (docs/scenes.md)
    r = Renderer(terr, Sun(50.0, 140.0), n, n, spp=16, quadrature=False)
    poses = cam.pose(np.zeros(2), nominal=True)
    frame = r.render(ray_keyframes(poses, fp, (0.0, 0.0), r.z_start_m), seed=5)
    im = FrameImager(rows=n, cols=n, exposure_s=1e-6)
    out = {}
    for path in ("terrain", "general"):
        caster = RayCaster(r, batch_rays=1 << 16, path=path)
        assert caster.path == path
        assert 0.7 < caster.sky_view_mean < 0.98  # the bake did something
        res = render_frame(caster, icam(cam, im), im, 0.0, np.arange(n), np.arange(n), 8,
                           nominal=True)
        assert res.hit_fraction == 1.0
        assert res.radiance.mean() == pytest.approx(frame.mean(), rel=0.01)
        assert np.corrcoef(res.radiance.ravel(), frame.ravel())[0, 1] > 0.9
        out[path] = res.radiance.astype(np.float64)
    rel = np.abs(out["terrain"] / out["general"] - 1.0)
    assert np.median(rel) < 1e-4 and np.mean(rel > 1e-3) < 0.02


def test_expose_as_the_tracker_frames():
    """Optics MTF, electrons, noise and quantisation through the sensor model, seeded."""
    from camera.exposure import expose
    from camera.optics import Optics
    from camera.sensor import Radiometry, SensorModel

    rad = 0.08 + 0.02 * np.sin(np.arange(64 * 64).reshape(64, 64) / 7.0)
    sensor = SensorModel(mean_signal_dn=400.0, noise_sigma_dn=2.0)
    optics = Optics()
    gain = sensor.gain_for(optics.apply(rad))
    a = expose(rad, optics, sensor, np.random.default_rng(1), 32 / 8296.0, gain_e=gain)
    b = expose(rad, optics, sensor, np.random.default_rng(1), 32 / 8296.0, gain_e=gain)
    assert a.dtype == np.uint16 and np.array_equal(a, b)
    assert a.mean() == pytest.approx(400.0, abs=1.0)
    assert np.std(a.astype(float) - optics.apply(rad) * gain / 4.0) == pytest.approx(2.0, rel=0.1)
    radiometry, t_int = Radiometry(), 4 / 8296.0  # 4 stages: below the full well here
    phys = expose(rad, optics, SensorModel(noise_model="physical"), np.random.default_rng(2),
                  t_int, radiometry=radiometry)
    e = radiometry.electrons_per_s(optics.apply(rad), optics.f_number, optics.transmission,
                                   optics.pixel_pitch_m, optics.wavelength_m) * t_int
    assert e.max() < 20000.0
    assert phys.mean() == pytest.approx(e.mean() / 4.0 + 50.0 * t_int / 4.0, rel=0.01)
    with pytest.raises(ValueError, match="exactly one"):
        expose(rad, optics, sensor, np.random.default_rng(1), 1e-3)


def test_frame_jitter_offset_matches_the_truth(caster):
    """A staring frame imager (1 ms exposure) under 0.3 px pitch and roll jitter: the
    frame's shift against the static (nominal) frame, measured by Gauss-Newton on a quintic
    spline, equals frame_offset_px within 0.01 px; a frame's offset is in its own pixels:
    +pitch moves the image toward +row, so the detector at p sees the static pixel
    p - pitch_px (and p - roll_px in columns)."""
    from scene.strip import render_frame

    frame = LocalFrame(35.0, 10.0, 0.0)
    orbit = orbit_looking_at(35.0, 10.0, 681e3, sun_synchronous_inclination_deg(681e3), EPOCH)
    ifov = 1.2e-6
    jit = (JitterTerm("pitch", 30.0, JITTER_PX * ifov), JitterTerm("roll", 20.0,
                                                                  JITTER_PX * ifov, 0.5))
    att = Attitude("target", target_ecef_m=tuple(frame.origin_ecef_m.tolist()), jitter=jit)
    cam = CameraModel(orbit, att, frame, FocalPlane(10.0, 12e-6, 96, 96))
    n, m, t0 = 96, 4, 0.004
    small, big = FrameImager(n, n, 1e-3), FrameImager(n + 2 * m, n + 2 * m, 1e-3)
    static = render_frame(caster, icam(cam, big), big, t0, np.arange(n + 2 * m),
                          np.arange(n + 2 * m), S,
                          nominal=True)
    true = render_frame(caster, icam(cam, small), small, t0, np.arange(n), np.arange(n), S)
    assert true.hit_fraction > 0.999999 and static.hit_fraction > 0.999999
    coef = spline_filter(static.radiance.astype(np.float64), order=5)
    rr, cc = np.mgrid[0:n, 0:n] + float(m)
    img = true.radiance.astype(np.float64)
    d = np.zeros(2)

    def ref(dr_, dc_):
        return map_coordinates(coef, [rr + dr_, cc + dc_], order=5, prefilter=False)

    for _ in range(3):
        h = 0.02
        jr = (ref(d[0] + h, d[1]) - ref(d[0] - h, d[1])) / (2 * h)
        jc = (ref(d[0], d[1] + h) - ref(d[0], d[1] - h)) / (2 * h)
        jac = np.stack([jr.ravel(), jc.ravel()], axis=1)
        d += np.linalg.lstsq(jac, (img - ref(*d)).ravel(), rcond=None)[0]
    truth = true.offset_px
    assert np.ptp(truth, axis=0).max() < 0.005  # one shift over this small frame
    assert np.abs(d - truth.mean(axis=0)).max() < 0.01, (d, truth.mean(axis=0))
    smp_t = t0 + (np.arange(S) + 0.5) / S * 1e-3
    jp = cam.attitude.jitter.rotvec_rad(smp_t).mean(axis=0) / ifov
    assert np.abs(truth.mean(axis=0) - (-jp[1], -jp[0])).max() < 0.02
    assert np.abs(truth.mean(axis=0)).min() > 0.15  # a real signal


def test_clouds_take_the_cloud_albedo_and_cast_shadows():
    """With a cloud layer the caster takes its 'general' path: rays that hit a cloud top
    take the cloud's albedo and shading, the terrain under it its shadow (40 % cover at
    600-700 m): the same picture as the tracker's render (measured: mean +0.7 %, r 0.998)."""
    from scene.classes import cloud_layer
    from scene.kernel import RayCaster, Renderer, Sun
    from scene.pinhole import ray_keyframes
    from scene.strip import render_frame
    from scene.terrain import procedural_terrain

    terr = procedural_terrain(512.0, 0.5, 4.0, 10.0, np.random.default_rng(3))
    clouds = cloud_layer(512.0, 8.0, 0.4, 600.0, np.random.default_rng(4), 100.0)
    cam = make_camera()
    n = 256
    r = Renderer(terr, Sun(50.0, 140.0), n, n, spp=4, clouds=clouds)
    poses = cam.pose(np.zeros(2), nominal=True)
    frame = r.render(ray_keyframes(poses, FocalPlane(10.0, 12e-6, n, n), (0.0, 0.0),
                                   r.z_start_m), seed=5)
    caster = RayCaster(r, batch_rays=1 << 18)
    assert caster.path == "general"
    with pytest.raises(ValueError, match="clouds"):
        RayCaster(r, path="terrain", sky_view=caster.sky_view)
    im = FrameImager(rows=n, cols=n, exposure_s=1e-6)
    res = render_frame(caster, icam(cam, im), im, 0.0, np.arange(n), np.arange(n), 4, nominal=True)
    assert res.hit_fraction > 0.999999
    assert np.mean(res.radiance > 0.2) > 0.03  # cloud tops (albedo 0.8) in view
    assert res.radiance.mean() == pytest.approx(frame.mean(), rel=0.02)
    assert np.corrcoef(res.radiance.ravel(), frame.ravel())[0, 1] > 0.98


def test_stepped_clock_off_rate_offsets_match_the_truth(caster):
    """32 stages clocked in half-pixel steps at a line rate 1 % off the image's: the
    per-line offsets still match the truth (measured 0.003 px RMS: the 32-line integration
    blurs the jitter, which a pure shift describes to second order only)."""
    from scene.strip import render_strip

    im = TdiImager(cols=256, stages=32, clock_phases=2)
    cam = make_camera((JitterTerm("pitch", 130.0, JITTER_PX * 1.2e-6, 0.4),
                       JitterTerm("roll", 97.0, JITTER_PX * 1.2e-6, 1.3)))
    rate, m = 8296.0 * 1.01, 4
    t0 = -(N_LINES / 2 + 16) / rate
    static = render_strip(caster, icam(cam, im), im, t0 - m / rate, N_LINES + 2 * m,
                          np.arange(COLS[0] - m, COLS[-1] + m + 1), S, nominal=True,
                          line_rate_hz=rate)
    true = render_strip(caster, icam(cam, im), im, t0, N_LINES, COLS, S, line_rate_hz=rate)
    assert true.line_rate_hz == rate
    err = measure_against_static(true.radiance, static, m) - true.line_offset_px
    assert np.sqrt(np.mean(err**2, axis=0)).max() < 0.01
    assert np.all(true.line_offset_px.std(axis=0) > 0.1)


@pytest.mark.parametrize("n", [8, 16, 32])
def test_footprint_offsets_are_not_ordered_with_time(n):
    # a motion during the exposure must convolve with the footprint, not add to it: with
    # the row offsets in time order a linear smear and the pixel become one longer box
    lat = subpixel_lattice(n)
    s = np.arange(n)
    for k in range(2):
        assert abs(np.corrcoef(s, lat[:, k])[0, 1]) < 0.5

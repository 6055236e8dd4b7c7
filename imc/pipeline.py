"""The closed loop: orbit -> render -> optics -> sensor -> correlator -> compensation -> metrics.

Truth comes from the camera model's exact projection of the true trajectory onto the
terrain, never from the estimates. Every random draw takes a generator derived from the
scenario seed and the frame index, so a run (or a resumed run) is reproducible.

Tracking: the blocks are cut where the orbit and nominal attitude predict their content
(``BlockTracker.update(frame, predicted_px)``). While the predicted motion over the run keeps
every block on the sensor, all frames are measured against frame 0 ("fixed" reference: no error
accumulates); a scanning view (nadir / off-nadir, ~83 px per 10 ms) is tracked frame to frame
("chain") and the increments are summed.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camera.geometry import FocalPlane, Pose, project
from camera.imager import FrameImager, MainImager, TdiImager, synchronous_line_rate_hz
from camera.motion import CameraModel
from camera.optics import Optics
from camera.sensor import Radiometry, SensorModel
from compensation.controller import FirstOrderLoop
from compensation.metrics import residual_metrics
from correlator.core import CorrelatorOptions
from correlator.driver import LoopbackLink
from correlator.optical import OpticalJtc
from correlator.timing import PipelineTiming, Schedule
from correlator.tracker import BlockTracker, block_grid
from imc.io import write_csv, write_json, write_npz
from imc.scenario import CloudsConfig, Scenario, ScenarioError
from orbit.attitude import Attitude, orbit_looking_at
from orbit.frames import LocalFrame
from orbit.jitter import JitterTerm, RandomJitter, WheelJitter, realize_jitter
from orbit.kepler import EarthOrbit, Orbit
from orbit.sun import sun_elevation_azimuth_deg
from orbit.tle import TleOrbit
from scene.classes import CloudLayer, cloud_layer, scene_class
from scene.geotiff import GeoTiffError, terrain_from_geotiff
from scene.pinhole import ray_keyframes
from scene.terrain import Terrain

KEYFRAMES_PER_EXPOSURE = 5
CHECKPOINT_EVERY = 10


@dataclass(frozen=True)
class Models:
    """Everything a run needs, built from a Scenario (no rendering yet)."""

    scenario: Scenario
    camera: CameraModel  # the tracker sensor's view
    main_camera: CameraModel  # the main imager's view (same orbit and attitude)
    imager: MainImager
    line_rate_hz: float | None
    main_velocity_px_s: np.ndarray  # predicted (nominal) image velocity at the imager centre
    terrain: Terrain
    clouds: CloudLayer | None
    sun_deg: tuple[float, float]  # (elevation, azimuth from north to east)
    optics: Optics
    radiometry: Radiometry
    sensor: SensorModel
    controller: FirstOrderLoop
    correlator: CorrelatorOptions
    corners: np.ndarray
    frame_t_s: np.ndarray
    exposure_s: float
    chain: bool
    timing: PipelineTiming | None = None  # the correlator device's pipeline, if modelled
    schedule: Schedule | None = None  # which (frame, block) pairs it correlates, and when

    @property
    def frame_mid_s(self) -> np.ndarray:
        return self.frame_t_s + 0.5 * self.exposure_s


def build_orbit(sc: Scenario) -> EarthOrbit:
    """The scenario's orbit; circular and sun-synchronous ones placed to see the scene at t = 0."""
    o, a = sc.orbit, sc.attitude
    try:
        if o.kind == "tle":
            return TleOrbit(o.tle_line1, o.tle_line2, sc.epoch)
        if o.kind == "elements":
            return Orbit(o.semi_major_axis_m, o.eccentricity, o.inclination_deg, o.raan_deg,
                         o.arg_perigee_deg, o.mean_anomaly_deg, sc.epoch, o.j2)
    except ValueError as e:
        raise ScenarioError(f"orbit: {e}") from None
    if o.kind == "sun_synchronous":
        from orbit.kepler import sun_synchronous_inclination_deg

        inc = sun_synchronous_inclination_deg(o.altitude_m)
    else:
        inc = o.inclination_deg
    # a staring camera sees the scene centre at t = 0; a scanning one half-way through the run,
    # so the tile is used symmetrically
    t_mid = 0.0 if a.mode == "target" else 0.5 * sc.duration_s
    try:
        orbit = orbit_looking_at(sc.scene.center_lat_deg, sc.scene.center_lon_deg,
                                 o.altitude_m, inc,
                                 sc.epoch + np.timedelta64(int(round(t_mid * 1e9)), "ns"),
                                 o.pass_direction == "descending", a.roll_deg, a.pitch_deg, o.j2)
        back = np.rad2deg([orbit.raan_rate_rad_s, orbit.arg_perigee_rate_rad_s,
                           orbit.mean_anomaly_rate_rad_s]) * t_mid
        return dataclasses.replace(orbit, epoch_utc=sc.epoch,
                                   raan_deg=orbit.raan_deg - back[0],
                                   arg_perigee_deg=orbit.arg_perigee_deg - back[1],
                                   mean_anomaly_deg=orbit.mean_anomaly_deg - back[2])
    except ValueError as e:
        raise ScenarioError(f"scene.center_lat_deg: {e}; lower it, raise orbit.inclination_deg "
                            "or change attitude.roll_deg / pitch_deg") from None


def build_jitter(sc: Scenario, ifov_rad: float):
    """The jitter realisation of this scenario (seeded by ``default_rng([seed, 3])``)."""
    j = sc.attitude.jitter

    def rad(urad, px):
        return urad * 1e-6 if urad is not None else px * ifov_rad

    terms: list = [JitterTerm(s.axis, s.frequency_hz, rad(s.amplitude_urad, s.amplitude_px),
                              np.deg2rad(s.phase_deg)) for s in j.sinusoids]
    terms += [RandomJitter(r.axis, rad(r.rms_urad, r.rms_px), r.f_min_hz, r.f_max_hz, r.slope)
              for r in j.random]
    terms += [WheelJitter(w.axis, w.speed_hz,
                          tuple((h.number, rad(h.amplitude_urad, h.amplitude_px))
                                for h in w.harmonics), w.speed_rate_hz_per_s)
              for w in j.wheels]
    return realize_jitter(terms, sc.duration_s, np.random.default_rng([sc.seed, 3]))


#: clouds whose layer would need more cells than this per side get coarser cells
MAX_CLOUD_CELLS = 4096


def build_scene(sc: Scenario) -> tuple[Terrain, CloudLayer | None, tuple[float, float],
                                       tuple[float, float]]:
    """Terrain, cloud layer, centre (lat, lon) deg and sun (elevation, azimuth) deg."""
    s = sc.scene
    centre = (s.center_lat_deg, s.center_lon_deg)
    if s.kind == "geotiff":
        g = s.geotiff
        try:
            terrain, file_centre = terrain_from_geotiff(g.ortho, g.dem, s.dem_spacing_m,
                                                        g.albedo_scale)
        except GeoTiffError as e:
            raise ScenarioError(str(e)) from None
        centre = file_centre or centre
    if s.sun_elevation_deg is not None:
        sun = (float(s.sun_elevation_deg), float(s.sun_azimuth_deg))
    else:
        el, az = sun_elevation_azimuth_deg(centre[0], centre[1], sc.epoch, 0.0)
        if el < 5.0:
            raise ScenarioError(
                f"scene: the sun is {float(el):.1f} deg above the horizon at orbit.epoch_utc "
                f"{sc.orbit.epoch_utc} at ({centre[0]}, {centre[1]}); choose a daytime epoch "
                "or set scene.sun_elevation_deg and sun_azimuth_deg")
        sun = (float(el), float(az))
    if s.kind != "geotiff":
        terrain = scene_class(s.kind, s.size_m, s.texel_m, s.dem_spacing_m,
                              np.random.default_rng([sc.seed, 0]), s.relief_rms_m,
                              sun_azimuth_deg=sun[1])
    cfg = s.clouds
    if cfg is None and s.kind == "mountain":
        cfg = CloudsConfig()  # the paper's mountain class has snow and clouds
    clouds = None
    if cfg is not None and cfg.cover > 0.0:
        base = float(np.max(terrain.dem_m)) + cfg.base_height_m
        # wide enough for a 56 deg off-nadir view and a 34 deg sun through the layer
        extent = max(terrain.size_m) + 3.0 * (base + cfg.thickness_m - float(terrain.dem_m.min()))
        cell = max(cfg.cell_m, extent / MAX_CLOUD_CELLS)
        clouds = cloud_layer(extent, cell, cfg.cover, base, np.random.default_rng([sc.seed, 4]),
                             cfg.thickness_m, cfg.albedo)
    return terrain, clouds, centre, sun


def build_models(sc: Scenario) -> Models:
    """Build orbit, attitude, camera, terrain and loop models; validate the geometry."""
    terrain, clouds, centre, sun = build_scene(sc)
    if centre != (sc.scene.center_lat_deg, sc.scene.center_lon_deg):
        sc = sc.model_copy(update={"scene": sc.scene.model_copy(
            update={"center_lat_deg": centre[0], "center_lon_deg": centre[1]})})
    orbit = build_orbit(sc)
    frame = LocalFrame(sc.scene.center_lat_deg, sc.scene.center_lon_deg, 0.0)
    c, t = sc.camera, sc.camera.tracker
    fp = FocalPlane(c.focal_length_m, c.pixel_pitch_m, t.rows, t.cols, t.center_offset_px)
    a = sc.attitude
    try:
        attitude = Attitude(
            mode=a.mode,
            roll_deg=a.roll_deg if a.mode == "off_nadir" else 0.0,
            pitch_deg=a.pitch_deg if a.mode == "off_nadir" else 0.0,
            target_ecef_m=tuple(frame.origin_ecef_m.tolist()) if a.mode == "target" else None,
            yaw_steering=a.yaw_steering,
            jitter=build_jitter(sc, fp.ifov_rad),
        )
    except ValueError as e:
        raise ScenarioError(f"attitude: {e}") from None
    cam = CameraModel(orbit, attitude, frame, fp)
    if a.mode == "target":
        r, _ = orbit.state_ecef(0.0)
        up = frame.ecef_to_enu(r)
        if up[2] <= 0 or np.degrees(np.arctan2(np.hypot(up[0], up[1]), up[2])) > 70.0:
            raise ScenarioError("attitude.mode: the scene is below 20 deg elevation from the "
                                "satellite at t = 0; change orbit or orbit.epoch_utc")
    mi = c.main_imager
    if mi.kind == "tdi":
        imager: MainImager = TdiImager(
            stages=mi.stages, line_rate_hz=mi.line_rate_hz, clock_phases=mi.clock_phases,
            center_offset_px=mi.center_offset_px)
    else:
        imager = FrameImager(exposure_s=mi.exposure_s, center_offset_px=mi.center_offset_px)
    main_cam = dataclasses.replace(cam, focal_plane=imager.focal_plane(c.focal_length_m,
                                                                      c.pixel_pitch_m))
    velocity = main_cam.velocity_field_px_s(main_cam.focal_plane.center_px, 0.0,
                                            terrain.height_at, nominal=True)[0]
    line_rate = None
    if mi.kind == "tdi":
        line_rate = mi.line_rate_hz
        if line_rate is None:
            try:
                line_rate = synchronous_line_rate_hz(velocity)
            except ValueError as e:
                raise ScenarioError(f"camera.main_imager: {e}") from None
    o = c.optics
    frame_t = np.arange(sc.n_frames) / t.frame_rate_hz
    corners = block_grid(t.rows, t.cols, sc.correlator.block_px, sc.correlator.n_blocks)
    models = Models(
        scenario=sc,
        camera=cam,
        main_camera=main_cam,
        imager=imager,
        line_rate_hz=line_rate,
        main_velocity_px_s=velocity,
        terrain=terrain,
        clouds=clouds,
        sun_deg=sun,
        optics=Optics(c.focal_length_m, o.aperture_m, o.wavelength_m, c.pixel_pitch_m,
                      o.blur_sigma_px, o.transmission, o.diffraction),
        radiometry=Radiometry(**c.radiometry.model_dump()),
        sensor=SensorModel(t.mean_signal_dn, t.noise_sigma_dn, t.adc_bits, t.noise_model,
                           t.gain_e_per_dn, t.full_well_e, t.read_noise_e,
                           t.dark_current_e_per_s),
        controller=FirstOrderLoop(sc.compensation.gain, sc.compensation.latency_frames),
        correlator=_correlator_options(sc),
        corners=corners,
        frame_t_s=frame_t,
        exposure_s=sc.exposure_s,
        chain=False,
        timing=sc.correlator.pipeline_timing(),
    )
    if models.timing is not None:  # a frame is ready for the device when it is read out
        models = dataclasses.replace(models, schedule=models.timing.schedule(
            frame_t + sc.exposure_s, len(corners)))
    models = dataclasses.replace(models, chain=_needs_chain(models))
    _check_coverage(models)
    return models


def _correlator_options(sc: Scenario) -> CorrelatorOptions:
    """The correlator's options; an optical model that cannot hold the blocks is a
    ScenarioError naming the field."""
    c = sc.correlator
    try:
        opts = CorrelatorOptions(
            method=c.method, subpixel=c.subpixel, psr_threshold=c.psr_threshold,
            max_crlb_px=c.max_crlb_px, rewindow=c.rewindow,
            optical=c.jtoc_model() if c.method == "optical" else None)
        if c.method == "optical":
            OpticalJtc(opts.optical, c.block_px, c.block_px, c.block_px // 4)
    except ValueError as e:
        raise ScenarioError(f"correlator: {e}") from None
    return opts


def predicted_px(m: Models, centers_px: np.ndarray, k_ref: int, k: int,
                 offsets: np.ndarray) -> np.ndarray:
    """Nominal (jitter-free) motion (B, 2) of the content at sensor pixels ``centers_px`` in
    frame k_ref to frame k, with the stage offsets the two frames were taken with."""
    fp_px = np.asarray(centers_px, dtype=np.float64) + offsets[k_ref]
    ground = m.camera.ground_points(fp_px, float(m.frame_mid_s[k_ref]), m.terrain.height_at)
    mo = m.camera.image_motion_px(ground, m.frame_mid_s[k:k + 1], float(m.frame_mid_s[k_ref]),
                                  nominal=True)[0]
    return mo - (offsets[k] - offsets[k_ref])


def _needs_chain(m: Models) -> bool:
    """True if the predicted motion over the run moves a block off the sensor."""
    n = len(m.frame_t_s)
    ks = np.unique(np.linspace(0, n - 1, min(n, 16)).astype(int))
    centers = BlockTracker.centers_from(m.corners, m.scenario.correlator.block_px)
    zero = np.zeros((n, 2))
    fp = m.camera.focal_plane
    b = m.scenario.correlator.block_px
    for k in ks:
        step = np.rint(predicted_px(m, centers, 0, int(k), zero)).astype(int)
        c = m.corners + step
        # keep a 4 px margin for jitter and the stage
        if np.any(c < 4) or np.any(c + b > np.array([fp.rows, fp.cols]) - 4):
            return True
    return False


def _check_coverage(m: Models) -> None:
    """The tile must hold every ray of every frame, with margin for the stage and jitter."""
    fp = m.camera.focal_plane
    margin = 8.0
    corners = np.array([[-margin, -margin], [-margin, fp.cols - 1 + margin],
                        [fp.rows - 1 + margin, -margin],
                        [fp.rows - 1 + margin, fp.cols - 1 + margin]])
    times = np.concatenate([m.frame_t_s, m.frame_t_s + m.exposure_s])
    times = np.unique(np.concatenate([times[:: max(1, len(times) // 64)], times[-1:]]))
    pts = np.stack([m.camera.ground_points(corners, float(t), m.terrain.height_at)
                    for t in times])
    inside = m.terrain.contains(pts[..., 0], pts[..., 1], margin_m=4.0 * m.terrain.dem_spacing_m)
    if not np.all(inside):
        need = 2.0 * float(np.max(np.abs(pts[..., :2]))) + 8.0 * m.terrain.dem_spacing_m
        hint = (f" (attitude.mode '{m.scenario.attitude.mode}' sweeps the ground at ~6.8 km/s:"
                " use mode 'target' or a shorter duration_s)"
                if m.scenario.attitude.mode != "target" else "")
        raise ScenarioError(
            f"scene.size_m: the {m.scenario.scene.size_m:g} m tile does not cover the ground "
            f"the tracker sees during the run; it needs >= {need:.0f} m{hint}")


def frame_seeds(seed: int, k: int) -> tuple[np.random.Generator, int]:
    """Noise generator and render seed of frame k, derived from the scenario seed."""
    render_seed = int(np.random.SeedSequence([seed, 2, k]).generate_state(1)[0] & 0x7FFFFFFF)
    return np.random.default_rng([seed, 1, k]), render_seed


@dataclass
class LoopState:
    """Per-frame records of a run (the loop's whole state, so a run can resume)."""

    frames: np.ndarray  # (T, H, W) uint16
    offsets: np.ndarray  # (T, 2) stage offset used for each frame, px
    ref_index: np.ndarray  # (T,) the frame each measurement is against
    ref_corners: np.ndarray  # (T, B, 2) block corners in the reference frame
    shifts: np.ndarray  # (T, B, 2) measured shift of each block vs its reference, px
    valid: np.ndarray  # (T, B)
    peaks: np.ndarray  # (T, B)
    crlb: np.ndarray  # (T, B, 2)
    estimate: np.ndarray  # (T, 2) estimated image motion since frame 0 (stage removed), px
    gain: float  # electrons per radiance unit (mean_level signal)
    done: int
    render_s: float
    link_stats: dict | None = None  # the serial link's counters (link.kind 'emulator')

    _FIELDS = ("frames", "offsets", "ref_index", "ref_corners", "shifts", "valid", "peaks",
               "crlb", "estimate")

    @classmethod
    def empty(cls, m: Models) -> LoopState:
        n, b = len(m.frame_t_s), len(m.corners)
        fp = m.camera.focal_plane
        return cls(np.zeros((n, fp.rows, fp.cols), np.uint16), np.zeros((n, 2)),
                   np.zeros(n, int), np.zeros((n, b, 2), int), np.zeros((n, b, 2)),
                   np.zeros((n, b), bool), np.zeros((n, b)), np.zeros((n, b, 2)),
                   np.zeros((n, 2)), 0.0, 0, 0.0)

    def save(self, path: Path, digest: str) -> None:
        write_npz(path, compress=False, digest=np.array(digest),
                  **{f: getattr(self, f) for f in self._FIELDS},
                  gain=np.array(self.gain), done=np.array(self.done),
                  render_s=np.array(self.render_s))

    @classmethod
    def load(cls, path: Path, digest: str, m: Models) -> LoopState | None:
        """The saved state if it belongs to this exact scenario, else None."""
        try:
            with np.load(path) as z:
                if str(z["digest"]) != digest:
                    return None
                st = cls(*(z[f] for f in cls._FIELDS), float(z["gain"]), int(z["done"]),
                         float(z["render_s"]))
        except (OSError, KeyError, ValueError):
            return None
        fp = m.camera.focal_plane
        expected = (len(m.frame_t_s), fp.rows, fp.cols)
        return st if st.frames.shape == expected and st.shifts.shape[1] == len(m.corners) else None


ProgressFn = Callable[[int, int], None]


def charge_motion_px(m: Models, t_s: np.ndarray) -> np.ndarray:
    """Motion (..., 2) the main imager follows by itself since t = 0: TDI charge transfer along
    rows, zero for a frame imager. Continuous (clock steps left out): the stage is driven to
    follow the mean charge motion."""
    t = np.asarray(t_s, dtype=np.float64)
    if m.line_rate_hz is None:
        return np.zeros(t.shape + (2,))
    return np.stack([t * m.line_rate_hz, np.zeros_like(t)], axis=-1)


def expose_frame(m: Models, radiance: np.ndarray, gain: float, rng) -> np.ndarray:
    """Rendered radiance -> optics MTF -> photo-electrons -> digital frame."""
    img = m.optics.apply(radiance)
    if m.scenario.camera.tracker.signal == "radiometric":
        electrons = m.radiometry.electrons_per_s(
            img, m.optics.f_number, m.optics.transmission, m.optics.pixel_pitch_m,
            m.optics.wavelength_m) * m.exposure_s
    else:
        electrons = img * gain
    return m.sensor.expose(electrons, rng, m.exposure_s)


def run_loop(m: Models, state: LoopState | None = None, checkpoint: Path | None = None,
             progress: ProgressFn | None = None, renderer=None) -> LoopState:
    """Run (or continue) the closed loop over all tracker frames."""
    from scene.kernel import Renderer, Sun  # the Mitsuba layer, loaded only when rendering

    sc = m.scenario
    st = state or LoopState.empty(m)
    fp = m.camera.focal_plane
    b = sc.correlator.block_px
    if renderer is None:
        renderer = Renderer(m.terrain, Sun(*m.sun_deg), fp.rows, fp.cols, spp=sc.scene.spp,
                            clouds=m.clouds)
    grid_centers = BlockTracker.centers_from(m.corners, b)
    sched = m.schedule
    arrive_s = sched.frame_deliver_s() if sched is not None else None
    n = len(m.frame_t_s)
    processed = sched.done if sched is not None else np.ones((n, len(m.corners)), bool)
    measured = [k for k in range(1, st.done) if processed[k].any()]
    last_measured = measured[-1] if measured else 0
    tracker = None
    if st.done > 0 and not m.chain:
        tracker = BlockTracker(st.frames[0], m.corners, b, m.correlator)
    lk = sc.correlator.link
    link = (LoopbackLink(np.random.default_rng([sc.seed, 4]), lk.corrupt_probability,
                         lk.drop_probability) if lk.kind == "emulator" else None)
    try:
        for k in range(st.done, n):
            t0 = time.perf_counter()
            times = m.frame_t_s[k] + np.linspace(0.0, m.exposure_s, KEYFRAMES_PER_EXPOSURE)
            kf = ray_keyframes(m.camera.pose(times), fp, st.offsets[k], renderer.z_start_m)
            rng, render_seed = frame_seeds(sc.seed, k)
            radiance = renderer.render(kf, render_seed)
            st.render_s += time.perf_counter() - t0
            if k == 0:
                st.gain = m.sensor.gain_for(m.optics.apply(radiance))
            st.frames[k] = expose_frame(m, radiance, st.gain, rng)
            if k == 0:
                st.ref_corners[0] = m.corners
                st.valid[0] = True
                st.peaks[0] = np.inf
                if not m.chain:
                    tracker = BlockTracker(st.frames[0], m.corners, b, m.correlator)
            elif not processed[k].any():  # the device was busy: no measurement of frame k
                st.ref_index[k], st.ref_corners[k] = st.ref_index[k - 1], st.ref_corners[k - 1]
                st.shifts[k], st.valid[k], st.peaks[k], st.crlb[k] = np.nan, False, 0.0, np.inf
                st.estimate[k] = st.estimate[k - 1]
            else:
                if m.chain:
                    k_ref = last_measured
                    half = np.rint(predicted_px(m, grid_centers, k_ref, k, st.offsets) / 2.0)
                    lim = np.array([fp.rows - b, fp.cols - b])
                    ref_corners = np.clip(m.corners - half.astype(int), 0, lim)
                    tracker = BlockTracker(st.frames[k_ref], ref_corners, b, m.correlator)
                else:
                    k_ref, ref_corners = 0, m.corners
                pred = predicted_px(m, BlockTracker.centers_from(ref_corners, b), k_ref, k,
                                    st.offsets)
                todo = np.flatnonzero(processed[k])
                res = tracker.update(st.frames[k], pred, np.random.default_rng([sc.seed, 3, k]),
                                     todo if len(todo) < len(m.corners) else None)
                shift, valid, peak = res.shift, res.valid, res.peak
                if link is not None:
                    t_us = np.rint(1e6 * (sched.deliver_s[k, todo] if sched is not None
                                          else np.full(len(todo), m.frame_t_s[k]))).astype(int)
                    shift, valid, peak, _ = link.roundtrip(k, t_us, todo, shift, valid, peak)
                st.ref_index[k], st.ref_corners[k] = k_ref, ref_corners
                st.shifts[k], st.valid[k], st.peaks[k], st.crlb[k] = np.nan, False, 0.0, np.inf
                st.shifts[k, todo], st.valid[k, todo] = shift, valid
                st.peaks[k, todo], st.crlb[k, todo] = peak, res.crlb
                ok = st.valid[k]
                d = st.shifts[k][ok].mean(axis=0) if ok.any() else pred.mean(axis=0)
                # content motion since the reference = image motion - stage change
                st.estimate[k] = st.estimate[k_ref] + d + st.offsets[k] - st.offsets[k_ref]
                last_measured = k
            if sc.compensation.enabled and st.valid[k].any():
                target = st.estimate[k] - (charge_motion_px(m, m.frame_mid_s[k])
                                           - charge_motion_px(m, m.frame_mid_s[0]))
                if arrive_s is None or k == 0:
                    m.controller.update(st.offsets, k, target, True)
                else:  # acts from the first frame exposed after the device delivers
                    j = int(np.searchsorted(m.frame_t_s, arrive_s[k] - 1e-9))
                    m.controller.apply(st.offsets, max(j, k + 1), target, True)
            st.done = k + 1
            if checkpoint is not None and (st.done % CHECKPOINT_EVERY == 0 or st.done == n):
                st.save(checkpoint, sc.digest())
            if progress is not None:
                progress(st.done, n)
    finally:
        if link is not None:
            st.link_stats = link.stats()
            link.close()
    return st


@dataclass(frozen=True)
class Truth:
    """True image motion from the camera model (px).

    ``t_s`` samples the main imager's integration windows (``window`` index of each sample);
    ``motion_px`` is the image motion of the ground at the main imager's centre (a frame imager:
    the ground seen there at t = 0, relative to t = 0; TDI: the ground entering each line,
    relative to the line's start), ``charge_px`` what the imager follows itself (TDI charge
    transfer within the line), ``meas_px`` the truth of every tracker measurement (T, B, 2).
    """

    t_s: np.ndarray
    window: np.ndarray
    window_s: float
    motion_px: np.ndarray
    charge_px: np.ndarray
    meas_px: np.ndarray
    per_window_reset: bool

    def stage_px(self, m: Models, offsets: np.ndarray) -> np.ndarray:
        """The stage offset (N, 2) at each sample (zero-order hold over tracker frames), with
        the window-start value removed for TDI lines."""
        k = np.clip(np.floor(self.t_s * m.scenario.camera.tracker.frame_rate_hz + 1e-9)
                    .astype(int), 0, len(offsets) - 1)
        s = offsets[k]
        if self.per_window_reset:
            first = np.r_[0, np.flatnonzero(np.diff(self.window)) + 1]
            s = s - np.repeat(s[first], np.diff(np.r_[first, len(s)]), axis=0)
        return s

    def residual_px(self, m: Models, offsets: np.ndarray) -> np.ndarray:
        return self.motion_px - self.stage_px(m, offsets) - self.charge_px


def exposure_times(m: Models, k: int, n: int) -> np.ndarray:
    """n times (s) spread evenly (cell centres) over frame k's exposure."""
    return m.frame_t_s[k] + (np.arange(n) + 0.5) / n * m.exposure_s


def _meas_truth(m: Models, st: LoopState) -> np.ndarray:
    """True shift (T, B, 2) of every tracker measurement: exposure-mean motion of the ground at
    each reference block centre, minus the stage change between the two frames."""
    s = m.scenario.metrics.samples_per_frame
    b = m.scenario.correlator.block_px
    out = np.zeros(st.shifts.shape)
    grounds: dict[tuple[int, bytes], np.ndarray] = {}  # a fixed reference is intersected once
    for k in range(1, len(m.frame_t_s)):
        kr = int(st.ref_index[k])
        key = (kr, st.ref_corners[k].tobytes())
        if key not in grounds:
            centers = BlockTracker.centers_from(st.ref_corners[k], b) + st.offsets[kr]
            grounds[key] = m.camera.ground_points(centers, float(m.frame_mid_s[kr]),
                                                  m.terrain.height_at)
        ground = grounds[key]
        times = np.concatenate([exposure_times(m, kr, s), exposure_times(m, k, s)])
        mo = m.camera.image_motion_px(ground, times, float(m.frame_mid_s[kr]))
        out[k] = mo[s:].mean(axis=0) - mo[:s].mean(axis=0) - (st.offsets[k] - st.offsets[kr])
    return out


def compute_truth(m: Models, st: LoopState) -> Truth:
    """True motion at the main imager over its integration windows, and of every measurement."""
    sc = m.scenario
    duration = len(m.frame_t_s) / sc.camera.tracker.frame_rate_hz
    cam = m.main_camera
    centre = cam.focal_plane.center_px[None]
    tdi = m.line_rate_hz is not None
    window = m.imager.integration_s(m.line_rate_hz)
    n_win = max(1, int(np.floor(duration / window + 1e-9)))
    if not tdi and window > duration:
        window, n_win = duration, 1
    dt = min(1.0 / sc.camera.tracker.frame_rate_hz / sc.metrics.samples_per_frame,
             window / 16.0)
    per = max(2, int(np.ceil(window / dt)))
    frac = (np.arange(per) + 0.5) / per
    t_s = ((np.arange(n_win)[:, None] + frac[None, :]) * window).ravel()
    win = np.repeat(np.arange(n_win), per)
    if tdi:
        starts = np.arange(n_win) * window
        ground = np.stack([cam.ground_points(centre, float(t0), m.terrain.height_at)[0]
                           for t0 in starts])  # (W, 3)
        pose = cam.pose(np.concatenate([starts, t_s]))
        p0 = project(ground, pose[:n_win], cam.focal_plane)  # (W, 2)
        moving = Pose(pose.position_m[n_win:].reshape(n_win, per, 3),
                      pose.enu_from_cam[n_win:].reshape(n_win, per, 3, 3))
        pw = project(ground[:, None, :], moving, cam.focal_plane)  # (W, per, 2)
        motion = (pw - p0[:, None, :]).reshape(-1, 2)
        charge = m.imager.charge_motion_px(t_s - starts[win], m.line_rate_hz)
    else:
        ground = cam.ground_points(centre, 0.0, m.terrain.height_at)
        motion = cam.image_motion_px(ground, t_s, 0.0)[:, 0]
        charge = np.zeros_like(motion)
    return Truth(t_s, win, window, motion, charge, _meas_truth(m, st), tdi)


def summarize(m: Models, st: LoopState, truth: Truth) -> dict:
    """Metrics with and without compensation, the tracker's accuracy, and the geometry."""
    sc = m.scenario
    zero = np.zeros_like(st.offsets)
    m_open = residual_metrics(truth.t_s, truth.residual_px(m, zero), truth.window_s)
    m_closed = residual_metrics(truth.t_s, truth.residual_px(m, st.offsets), truth.window_s)
    err = (st.shifts - truth.meas_px)[1:]
    ok = st.valid[1:]
    nan2 = np.array([np.nan] * 2)
    rms_err = np.sqrt(np.mean(err[ok] ** 2, axis=0)) if ok.any() else nan2
    crlb = np.median(st.crlb[1:][ok], axis=0) if ok.any() else nan2
    out = {
        "scenario": sc.name,
        "frames": int(len(m.frame_t_s)),
        "blocks": int(len(m.corners)),
        "compensation_enabled": sc.compensation.enabled,
        "without_compensation": m_open.to_dict(),
        "with_compensation": m_closed.to_dict(),
        "rms_reduction": m_open.rms_total_px / max(m_closed.rms_total_px, 1e-12),
        "tracker": {
            "reference": "chain" if m.chain else "fixed",
            "valid_fraction": float(ok.mean()),
            "rms_error_px": [float(v) for v in rms_err],
            "median_crlb_px": [float(v) for v in crlb],
            "bias_px": [float(v) for v in (err[ok].mean(axis=0) if ok.any() else nan2)],
        },
        "geometry": geometry_summary(m),
    }
    if m.schedule is not None:
        done = m.schedule.done[1:]
        lat = (m.schedule.deliver_s - (m.frame_t_s + m.exposure_s)[:, None])[1:][done]
        out["correlator_device"] = {
            "correlations_per_s": m.timing.correlations_per_s,
            "latency_s": m.timing.latency_s,
            "pairs_processed": int(done.sum()),
            "pairs_dropped": int((~done).sum()),
            "frames_measured": int(done.any(axis=1).sum()),
            "mean_result_age_s": float(lat.mean()) if lat.size else None,
        }
    if st.link_stats is not None:
        out["link"] = dict(st.link_stats)
    return out


def geometry_summary(m: Models) -> dict:
    """Orbit, pointing, imager and sensor figures of the run (SI units in the key names)."""
    orbit, cam = m.camera.orbit, m.camera
    lat, lon, h = orbit.ground_point(0.0)
    fp = cam.focal_plane
    ground = cam.ground_points(fp.center_px[None], 0.0, m.terrain.height_at)
    rng_m = float(np.linalg.norm(ground[0] - cam.pose(np.array(0.0)).position_m))
    jit = cam.attitude.jitter.rotvec_rad(np.linspace(0.0, m.frame_t_s[-1] + m.exposure_s, 2001))
    out = {
        "orbit_period_s": float(getattr(orbit, "period_s", np.nan)),
        "satellite_height_m": float(h),
        "subsatellite_lat_lon_deg": [float(lat), float(lon)],
        "ground_speed_mps": float(orbit.ground_speed_mps(0.0)),
        "heading_deg": float(orbit.heading_deg(0.0)),
        "off_nadir_deg": float(cam.attitude.off_nadir_deg(orbit, 0.0)),
        "slant_range_m": rng_m,
        "gsd_m": rng_m * fp.ifov_rad,
        "image_velocity_px_s": [float(v) for v in m.main_velocity_px_s],
        "jitter_rms_px": [float(v) for v in (jit.std(axis=0) / fp.ifov_rad)],
        "tracker_snr": m.sensor.snr(exposure_s=m.exposure_s)
        if m.scenario.camera.tracker.signal == "mean_level" else None,
        "scene_kind": m.scenario.scene.kind,
        "scene_center_lat_lon_deg": [m.scenario.scene.center_lat_deg,
                                     m.scenario.scene.center_lon_deg],
        "sun_elevation_azimuth_deg": list(m.sun_deg),
        "cloud_cover": m.clouds.cover if m.clouds is not None else 0.0,
        "main_imager": m.imager.kind,
        "line_rate_hz": m.line_rate_hz,
    }
    if hasattr(orbit, "local_time_of_ascending_node_h"):
        out["local_time_of_ascending_node_h"] = float(orbit.local_time_of_ascending_node_h)
    return out


def write_outputs(m: Models, st: LoopState, truth: Truth, metrics: dict, out: Path,
                  save_frames: bool, rerun: bool = True) -> list[Path]:
    """metrics.json, tracks.csv, recording.rrd and (optionally) frames.npz, atomically."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    rows = []
    for k, t in enumerate(m.frame_t_s):
        for b in range(len(m.corners)):
            rows.append([f"{t:.6f}", k, b, int(st.ref_index[k]),
                         f"{truth.meas_px[k, b, 0]:.5f}", f"{truth.meas_px[k, b, 1]:.5f}",
                         f"{st.shifts[k, b, 0]:.5f}", f"{st.shifts[k, b, 1]:.5f}",
                         f"{st.offsets[k, 0]:.5f}", f"{st.offsets[k, 1]:.5f}",
                         f"{st.estimate[k, 0]:.5f}", f"{st.estimate[k, 1]:.5f}",
                         int(st.valid[k, b]), f"{st.peaks[k, b]:.3f}"])
    header = ["t_s", "frame", "block", "ref_frame", "true_row_px", "true_col_px",
              "meas_row_px", "meas_col_px", "stage_row_px", "stage_col_px",
              "estimate_row_px", "estimate_col_px", "valid", "psr"]
    write_csv(out / "tracks.csv", header, rows)
    written.append(out / "tracks.csv")
    write_json(out / "metrics.json", metrics)
    written.append(out / "metrics.json")
    if save_frames:
        write_npz(out / "frames.npz", frames=st.frames, t_s=m.frame_t_s,
                  stage_offset_px=st.offsets, ref_index=st.ref_index,
                  ref_corners=st.ref_corners, true_shift_px=truth.meas_px,
                  exposure_s=np.array(m.exposure_s))
        written.append(out / "frames.npz")
    if rerun:
        from imc.rerun_log import write_recording

        write_recording(out / "recording.rrd", m, st, truth)
        written.append(out / "recording.rrd")
    return written


def run_scenario(sc: Scenario, out: Path, save_frames: bool = False, fresh: bool = False,
                 progress: ProgressFn | None = None, rerun: bool = True) -> tuple[dict, dict]:
    """Run a scenario end to end; returns (metrics, run info). Resumes a matching checkpoint."""
    t_start = time.perf_counter()
    m = build_models(sc)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "checkpoint.npz"
    state = (None if fresh or not ckpt.exists()
             else LoopState.load(ckpt, m.scenario.digest(), m))
    resumed_from = state.done if state is not None else 0
    st = run_loop(m, state, ckpt, progress)
    truth = compute_truth(m, st)
    metrics = summarize(m, st, truth)
    files = write_outputs(m, st, truth, metrics, out, save_frames, rerun)
    info = {"wall_s": time.perf_counter() - t_start, "render_s": st.render_s,
            "resumed_from_frame": resumed_from, "files": [str(f) for f in files]}
    return metrics, info

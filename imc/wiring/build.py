"""Build a run's models from a scenario: orbit, attitude, scene, camera, correlator options,
and the compensation loop's blocks (picked by kind from compensation's registry).

Nothing is rendered here; :func:`build_models` is what ``imc validate`` runs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from camera.geometry import FocalPlane
from camera.imager import IMAGERS, MainImager
from camera.linescan import imager_camera
from camera.motion import CameraModel
from camera.optics import Optics
from camera.sensor import Radiometry, SensorModel
from compensation.registry import block_class, make_block
from correlator.optical import OpticalJtc
from correlator.options import CorrelatorOptions
from correlator.timing import PipelineTiming, Schedule
from correlator.tracker import BlockTracker, block_grid
from imc.scenario import CloudsConfig, Scenario, ScenarioError
from imc.wiring import streams
from imc.wiring.budget import LIGHT_TEXELS
from imc.wiring.device_budget import budget_warning, correlator_budget
from orbit.aircraft import Aircraft, AircraftAttitude
from orbit.attitude import Attitude, orbit_looking_at
from orbit.frames import LocalFrame
from orbit.jitter import JitterTerm, RandomJitter, WheelJitter, realize_jitter
from orbit.kepler import EarthOrbit, Orbit
from orbit.sun import sun_elevation_azimuth_deg
from orbit.suspension import Suspension
from orbit.tle import TleOrbit
from scene.classes import CloudLayer, class_relief_m, cloud_cell_m, cloud_layer, scene_class
from scene.geotiff import GeoTiffError, nodata_in_view, terrain_from_geotiff
from scene.terrain import ProceduralDraws, Terrain, flat_terrain
from scene.terrain import procedural_draws as scene_procedural_draws


@dataclass(frozen=True)
class Models:
    """Everything a run needs, built from a Scenario (no rendering yet)."""

    scenario: Scenario
    camera: CameraModel  # the tracker sensor's view
    main_camera: CameraModel  # the main imager's view (same orbit and attitude)
    imager: MainImager
    main_velocity_px_s: np.ndarray  # predicted (nominal) image velocity at the imager centre
    terrain: Terrain
    clouds: CloudLayer | None
    sun_deg: tuple[float, float]  # (elevation, azimuth from north to east)
    optics: Optics
    radiometry: Radiometry
    sensor: SensorModel
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

    @property
    def rate_hz(self) -> float:
        return float(self.scenario.camera.tracker.frame_rate_hz)

    @property
    def field_point_px(self) -> tuple[float, float]:
        """The main imager's centre in tracker pixels (row, col)."""
        pp = self.camera.focal_plane.principal_point_px
        off = self.scenario.camera.main_imager.center_offset_px
        return (float(pp[0] + off[0]), float(pp[1] + off[1]))

    @property
    def line_rate_hz(self) -> float | None:
        """The main imager's clocked line rate, Hz (None: a frame imager)."""
        return self.imager.line_rate_hz

    def charge_px(self, t_s: np.ndarray) -> np.ndarray:
        """Motion (..., 2) the main imager follows by itself since t = 0: TDI charge transfer
        along rows at its line rate, continuous (the stage follows the mean charge motion),
        zero for a frame imager."""
        t = np.asarray(t_s, dtype=np.float64)
        return t[..., None] * np.asarray(self.imager.charge_velocity_px_s)


def build_orbit(sc: Scenario, terrain: Terrain | None = None) -> EarthOrbit:
    """The scenario's orbit; circular and sun-synchronous ones placed to see the scene at t = 0
    (an aircraft: over the scene centre half-way through the run, above ``terrain``)."""
    o, a = sc.orbit, sc.attitude
    if o.kind == "aircraft":
        return build_aircraft(sc, terrain)
    try:
        if o.kind == "tle":
            return TleOrbit(o.tle_line1, o.tle_line2, sc.epoch)
        if o.kind == "elements":
            return Orbit(o.semi_major_axis_m, o.eccentricity, o.inclination_deg, o.raan_deg,
                         o.arg_perigee_deg, o.mean_anomaly_deg, sc.epoch, o.j2)
        if o.kind == "oem":
            return build_oem(sc)
    except ValueError as e:
        raise ScenarioError(e if str(e).startswith("orbit.") else f"orbit: {e}") from None
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


def build_oem(sc: Scenario):
    """The orbit of ``orbit.oem_file``, refused in one line unless it spans the run."""
    from orbit.oem_orbit import read_oem

    orbit = read_oem(sc.orbit.oem_file, sc.epoch)
    if not orbit.covers(0.0, sc.duration_s):
        raise ValueError(f"orbit.oem_file: {orbit.source} has states for t = "
                         f"{orbit.t_s[0]:.6g} .. {orbit.t_s[-1]:.6g} s, not the run's 0 .. "
                         f"{sc.duration_s:g} s (t = 0 at orbit.epoch_utc); give states over the "
                         "run or move orbit.epoch_utc")
    return orbit


def build_aircraft(sc: Scenario, terrain: Terrain | None) -> Aircraft:
    """The scenario's flight over ``terrain``; refuses an aircraft at or below the highest
    terrain or the cloud tops, and a speed and height that move the image across the tracker
    within one frame."""
    o, a, c = sc.orbit, sc.attitude, sc.camera
    ground = float(np.median(terrain.dem_m)) if terrain is not None else 0.0
    z = ground + o.height_m
    top = float(np.max(terrain.dem_m)) if terrain is not None else ground
    if z <= top + 1.0:
        raise ScenarioError(f"orbit.height_m: the aircraft at {o.height_m:g} m above the ground "
                            f"is not above the highest terrain ({top - ground:.0f} m above it);"
                            " raise orbit.height_m")
    rows = c.tracker.rows
    flow_px = (o.ground_speed_mps * c.focal_length_m / (c.pixel_pitch_m * (z - top))
               / c.tracker.frame_rate_hz)
    if flow_px >= rows - sc.correlator.block_px:
        raise ScenarioError(
            f"orbit.ground_speed_mps: at {o.ground_speed_mps:g} m/s and {o.height_m:g} m the "
            f"image moves {flow_px:.0f} px per tracker frame, leaving no "
            f"{sc.correlator.block_px} px block on the {rows}-row tracker; lower "
            "orbit.ground_speed_mps, raise orbit.height_m or camera.tracker.frame_rate_hz")
    t_mid = 0.5 * sc.duration_s
    return Aircraft.over_point(LocalFrame(sc.scene.center_lat_deg, sc.scene.center_lon_deg, 0.0),
                               z, o.ground_speed_mps, o.heading_deg, sc.epoch, t_mid, ground,
                               a.roll_deg, a.pitch_deg)


def build_jitter(sc: Scenario, ifov_rad: float, orbit: EarthOrbit | None = None,
                 nominal: Attitude | None = None):
    """The jitter realisation of this scenario (stream 'jitter'), or its measured series
    (attitude.jitter.series; an AEM's is taken against ``nominal`` on ``orbit``)."""
    j = sc.attitude.jitter
    if j.series is not None:
        return build_jitter_series(sc, ifov_rad, orbit, nominal)

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
    series = realize_jitter(terms, sc.duration_s, streams.rng(sc.seed, "jitter"))
    if sc.attitude.suspension is not None:  # what the camera sees through its mount
        s = sc.attitude.suspension
        series = Suspension(s.cutoff_hz, s.damping).apply(series)
    return series


def build_jitter_series(sc: Scenario, ifov_rad: float, orbit: EarthOrbit | None,
                        nominal: Attitude | None):
    """attitude.jitter.series as a SampledJitter, refused in one line unless it covers the run
    at the tracker's frame rate."""
    from orbit.attitude_series import (
        AttitudeSeriesError,
        jitter_from_attitude,
        read_aem,
        read_jitter_csv,
    )

    s = sc.attitude.jitter.series
    what = "attitude.jitter.series.file"
    try:
        if s.format == "csv":
            series = read_jitter_csv(s.file, sc.epoch, ifov_rad, what)
        else:
            if orbit is None or nominal is None:
                raise ValueError("an AEM's jitter needs the orbit and the nominal attitude")
            series = jitter_from_attitude(
                read_aem(s.file, sc.epoch, what),
                lambda t: nominal.eci_from_body(orbit, t, nominal=True), sc.epoch)
        series.check_covers(0.0, sc.duration_s, sc.camera.tracker.frame_rate_hz,
                            "attitude.jitter.series")
    except AttitudeSeriesError as e:
        raise ScenarioError(str(e)) from None
    except ValueError as e:  # the orbit does not span the AEM's times
        raise ScenarioError(f"attitude.jitter.series: {e}") from None
    return series


def build_scene(sc: Scenario, light: bool = False, terrain: Terrain | None = None
                ) -> tuple[Terrain, CloudLayer | None, tuple[float, float], tuple[float, float]]:
    """Terrain, cloud layer, centre (lat, lon) deg and sun (elevation, azimuth) deg.
    ``light`` (imc validate): a tile above budget.LIGHT_TEXELS is a flat stand-in of the same
    size and DEM grid, a GeoTIFF is read decimated (<= 2048 px a side), and no cloud layer is
    built. ``terrain``: a tile built already (e.g. :func:`procedural_draws`'s geometry, the
    scene's DEM without its albedo), used instead of building one."""
    s = sc.scene
    centre = (s.center_lat_deg, s.center_lon_deg)
    if terrain is not None:
        pass
    elif s.kind == "geotiff":
        g = s.geotiff
        try:
            terrain, file_centre = terrain_from_geotiff(g.ortho, g.dem, s.dem_spacing_m,
                                                        g.albedo_scale,
                                                        max_side=2048 if light else None,
                                                        band=g.band)
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
    if terrain is not None:
        pass
    elif s.kind != "geotiff" and light and round(s.size_m / s.texel_m) ** 2 > LIGHT_TEXELS:
        terrain = flat_terrain(s.size_m, s.dem_spacing_m)
    elif s.kind != "geotiff":
        try:
            terrain = scene_class(s.kind, s.size_m, s.texel_m, s.dem_spacing_m,
                                  streams.rng(sc.seed, "terrain"), s.relief_rms_m,
                                  sun_azimuth_deg=sun[1])
        except ValueError as e:
            raise ScenarioError(f"scene: {e}") from None
    cfg = s.clouds
    if cfg is None and s.kind == "mountain":
        cfg = CloudsConfig()  # the paper's mountain class has snow and clouds
    clouds = None
    if cfg is not None and cfg.cover > 0.0 and not light:
        base = float(np.max(terrain.dem_m)) + cfg.base_height_m
        # wide enough for a 56 deg off-nadir view and a 34 deg sun through the layer
        extent = max(terrain.size_m) + 3.0 * (base + cfg.thickness_m - float(terrain.dem_m.min()))
        cell = cloud_cell_m(extent, cfg.cell_m)
        clouds = cloud_layer(extent, cell, cfg.cover, base, streams.rng(sc.seed, "clouds"),
                             cfg.thickness_m, cfg.albedo)
    return terrain, clouds, centre, sun


def procedural_draws(sc: Scenario) -> ProceduralDraws | None:
    """The scenario's procedural tile as its draws from the scene's stream
    (:func:`scene.terrain.procedural_draws`: the tile's DEM, and any window of the albedo
    :func:`build_scene` would build); None for the other scene kinds."""
    s = sc.scene
    if s.kind != "procedural":
        return None
    try:
        return scene_procedural_draws(s.size_m, s.texel_m, s.dem_spacing_m,
                                      class_relief_m(s.kind, s.size_m, s.relief_rms_m),
                                      streams.rng(sc.seed, "terrain"))
    except ValueError as e:
        raise ScenarioError(f"scene: {e}") from None


def build_models(sc: Scenario, light: bool = False, terrain: Terrain | None = None
                 ) -> Models:
    """Build orbit, attitude, camera, terrain and loop models; validate the geometry
    (``light``, ``terrain``: see :func:`build_scene`)."""
    terrain, clouds, centre, sun = build_scene(sc, light, terrain)
    if centre != (sc.scene.center_lat_deg, sc.scene.center_lon_deg):
        sc = sc.model_copy(update={"scene": sc.scene.model_copy(
            update={"center_lat_deg": centre[0], "center_lon_deg": centre[1]})})
    orbit = build_orbit(sc, terrain)
    frame = LocalFrame(sc.scene.center_lat_deg, sc.scene.center_lon_deg, 0.0)
    c, t = sc.camera, sc.camera.tracker
    fp = FocalPlane(c.focal_length_m, c.pixel_pitch_m, t.rows, t.cols, t.center_offset_px)
    a = sc.attitude
    if clouds is not None and isinstance(orbit, Aircraft) and orbit.height_enu_m <= clouds.top_m:
        raise ScenarioError(f"orbit.height_m: the aircraft flies below the cloud tops "
                            f"({clouds.top_m:.0f} m); raise orbit.height_m or set "
                            "scene.clouds.cover: 0")
    attitude_cls = AircraftAttitude if isinstance(orbit, Aircraft) else Attitude
    try:
        nominal = attitude_cls(
            mode=a.mode,
            roll_deg=a.roll_deg if a.mode == "off_nadir" else 0.0,
            pitch_deg=a.pitch_deg if a.mode == "off_nadir" else 0.0,
            target_ecef_m=tuple(frame.origin_ecef_m.tolist()) if a.mode == "target" else None,
            yaw_steering=a.yaw_steering,
        )
        attitude = dataclasses.replace(nominal, jitter=build_jitter(sc, fp.ifov_rad, orbit,
                                                                    nominal))
    except ScenarioError:
        raise
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
    # the imager's camera: built here once, asked for as Models.main_camera
    imager: MainImager = IMAGERS[mi.kind].from_config(mi)
    main_cam = imager_camera(cam, imager)
    velocity = main_cam.velocity_field_px_s(main_cam.focal_plane.center_px, 0.0,
                                            terrain.height_at, nominal=True)[0]
    try:
        imager = imager.with_line_rate(velocity)
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
        correlator=correlator_options(sc),
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


def correlator_options(sc: Scenario) -> CorrelatorOptions:
    """The correlator's options; an optical model that cannot hold the blocks is a
    ScenarioError naming the field."""
    c = sc.correlator
    try:
        opts = CorrelatorOptions(
            method=c.method, subpixel=c.subpixel, psr_threshold=c.psr_threshold,
            false_valid_rate=c.false_valid_rate,
            max_crlb_px=c.max_crlb_px, rewindow=c.rewindow,
            trust_prediction_px=c.trust_prediction_px,
            optical=c.jtoc_model() if c.method == "optical" else None)
        if c.method == "optical":
            OpticalJtc(opts.optical, c.block_px, c.block_px, c.block_px // 4)
    except ValueError as e:
        msg = str(e)  # the optical model names its field from correlator on
        raise ScenarioError(f"correlator.{msg}" if msg.startswith("optical.")
                            else f"correlator: {msg}") from None
    return opts


def predicted_px(m: Models, centers_px: np.ndarray, k_ref: int, k: int,
                 stage_ref_px: np.ndarray, stage_px: np.ndarray) -> np.ndarray:
    """Nominal (jitter-free) motion (B, 2) of the content at sensor pixels ``centers_px`` in
    frame k_ref to frame k, with the stage offsets (2,) the two frames were taken with."""
    fp_px = np.asarray(centers_px, dtype=np.float64) + stage_ref_px
    ground = m.camera.ground_points(fp_px, float(m.frame_mid_s[k_ref]), m.terrain.height_at)
    mo = m.camera.image_motion_px(ground, m.frame_mid_s[k:k + 1], float(m.frame_mid_s[k_ref]),
                                  nominal=True)[0]
    return mo - (stage_px - stage_ref_px)


def _needs_chain(m: Models) -> bool:
    """True if the predicted motion over the run moves a block off the sensor."""
    n = len(m.frame_t_s)
    ks = np.array(sorted({int(k) for k in np.linspace(0, n - 1, min(n, 16))}))
    centers = BlockTracker.centers_from(m.corners, m.scenario.correlator.block_px)
    fp = m.camera.focal_plane
    b = m.scenario.correlator.block_px
    # predicted_px (no stage) from frame 0 to every frame of ks at once: (K, B, 2)
    t_ref = float(m.frame_mid_s[0])
    ground = m.camera.ground_points(np.asarray(centers, dtype=np.float64), t_ref,
                                    m.terrain.height_at)
    motion = m.camera.image_motion_px(ground, m.frame_mid_s[ks], t_ref, nominal=True)
    c = m.corners[None] + np.rint(motion).astype(int)
    # keep a 4 px margin for jitter and the stage
    return bool(np.any(c < 4) or np.any(c + b > np.array([fp.rows, fp.cols]) - 4))


def _check_coverage(m: Models) -> None:
    """The tile must hold every ray of every frame, with margin for the stage and jitter."""
    fp = m.camera.focal_plane
    margin = 8.0
    corners = np.array([[-margin, -margin], [-margin, fp.cols - 1 + margin],
                        [fp.rows - 1 + margin, -margin],
                        [fp.rows - 1 + margin, fp.cols - 1 + margin]])
    times = np.concatenate([m.frame_t_s, m.frame_t_s + m.exposure_s])
    times = np.sort(np.concatenate([times[:: max(1, len(times) // 64)], times[-1:]]))
    times = times[np.r_[True, np.diff(times) > 0]]  # unique (np.unique imports numpy.ma)
    pts = m.camera.ground_points(corners, times, m.terrain.height_at)
    holes = nodata_in_view(m.terrain, pts[:, [0, 1, 3, 2], :2])  # user files' nodata
    if holes:
        raise ScenarioError(holes)
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
    """Noise generator and render seed of frame k (streams 'sensor' and 'render')."""
    return streams.rng(seed, "sensor", k), streams.render_seed(seed, k)


# ---------------------------------------------------------------------------------------------
# the loop's blocks


@dataclass(frozen=True)
class LoopParts:
    """The loop's blocks and clock, built from the scenario's compensation section, and the
    analytic model's verdict on the design."""

    estimator: object
    controller: object
    actuator: object
    transport: object
    timeline: object
    model: object  # compensation.analytic.LoopModel (regular-sampling approximation)
    margins: object  # compensation.analytic.Margins
    supervisor: object | None = None  # compensation.supervisor block, if the scenario has one


def piezo_update_hz(rate_hz: float, resonance_hz: float, drive_hz: float = 0.0) -> float:
    """The smallest multiple of the frame rate at or above 20 x the resonance and 4 x the
    drive notch's highest frequency (``drive_hz``, 0 without one)."""
    need = max(20.0 * resonance_hz, 4.0 * drive_hz)
    return rate_hz * max(1, int(np.ceil(need / rate_hz - 1e-9)))


def build_loop(m: Models, channel=None, plant_sigma_px: float | None = None) -> LoopParts:
    """Estimator, controller, actuator, transport and timeline of a run; the design is
    checked on the analytic loop model (unstable or marginal: a ScenarioError naming the
    field and the margin)."""
    from compensation.analytic import LoopModel, design_lines
    from compensation.controllers import FeedbackController
    from compensation.loop import Timeline
    from compensation.transport import Transport

    sc = m.scenario
    comp = sc.compensation
    n = len(m.frame_t_s)
    rate = m.rate_hz
    deliver = processed = None
    period = 1.0 / rate
    device_lag = 0.0
    if m.schedule is not None:
        deliver = m.schedule.frame_deliver_s()
        processed = m.schedule.done
        ok = np.isfinite(deliver)
        if ok.sum() >= 2:
            period = float(np.median(np.diff(deliver[ok])))
            device_lag = float(np.median(deliver[ok] - (m.frame_t_s + m.exposure_s)[ok]))
    charge = m.charge_px(m.frame_mid_s) - m.charge_px(m.frame_mid_s[:1])
    end = n / rate
    timeline = Timeline(m.frame_t_s, m.exposure_s, end, charge, period)
    latency = comp.transport.latency_s + comp.transport.latency_frames / rate
    transport = Transport(latency_s=latency, deliver_s=deliver, processed=processed,
                          drop_probability=comp.transport.drop_probability,
                          seed=tuple(streams.key(sc.seed, "drops")), channel=channel)
    # the values the wiring derives from the rest of the scenario; each block takes the ones
    # its class names in WIRED
    wired = {"field_point_px": m.field_point_px, "ramp_s": period, "rate_hz": 1.0 / period,
             # the main imager's exposure and start (the supervisor's blur watch)
             "exposure_s": float(m.imager.integration_s()),
             "blur_from_s": float(sc.camera.main_imager.start_s)}
    if comp.controller.option("feedforward"):
        wired["nominal_px"] = nominal_target(m)
    try:
        estimator = make_block("estimator", comp.estimator.kind, comp.estimator.params(), wired)
        actuator = make_block("actuator", comp.actuator.kind, comp.actuator.params(), wired)
        if getattr(actuator, "update_hz", 0.0) is None:  # a stage with its own DAC rate
            actuator = dataclasses.replace(actuator, update_hz=piezo_update_hz(
                rate, actuator.resonance_hz, actuator.drive_top_hz))
        cparams = comp.controller.params()
        if "lead_s" in _field_names(comp.controller.kind) and cparams.get("lead_s") is None:
            cparams["lead_s"] = actuator.lag_s  # a predictor's lead: the stage's own lag
        controller = make_block("controller", comp.controller.kind, cparams, wired)
        supervisor = (make_block("supervisor", comp.supervisor.kind, comp.supervisor.params(),
                                 wired) if comp.supervisor is not None else None)
    except (TypeError, ValueError) as e:
        raise ScenarioError(f"compensation: {str(e).replace('@', '')}") from None
    sigma = (plant_sigma_px or getattr(controller, "noise_px", None) or 0.02)
    model = LoopModel(1.0 / period, m.exposure_s, latency + device_lag, controller, actuator,
                      float(sigma))
    if isinstance(controller, FeedbackController) and controller.lines:
        controller = design_lines(controller, model)
        model = dataclasses.replace(model, controller=controller)
    margins = model.margins()
    if comp.enabled:
        try:
            _check_margins(comp, margins, getattr(controller, "TUNING", "kind"))
        except ScenarioError as e:  # say too when the correlator cannot keep up with the run
            over = budget_warning(m, correlator_budget(m))
            raise ScenarioError(f"{e}; and {over}" if over else str(e)) from None
    return LoopParts(estimator, controller, actuator, transport, timeline, model, margins,
                     supervisor)


def _field_names(controller_kind: str) -> set[str]:
    """The parameters of a controller kind."""
    return {f.name for f in dataclasses.fields(block_class("controller", controller_kind))}


def _check_margins(comp, mg, knob: str) -> None:
    """Refuse an unstable or marginal design, naming the field to change (``knob``: the
    controller's parameter that sets its gain, its class's TUNING)."""
    where = f"compensation.controller.{knob}"
    if not mg.stable:
        raise ScenarioError(f"{where}: the closed loop is unstable (analytic loop model: "
                            f"gain margin {mg.gain_margin_db:.1f} dB, phase margin "
                            f"{mg.phase_margin_deg:.0f} deg); lower it, or count the latency "
                            "with compensation.controller.smith: true")
    if mg.phase_margin_deg < comp.min_phase_margin_deg:
        raise ScenarioError(f"{where}: phase margin {mg.phase_margin_deg:.1f} deg is below "
                            f"compensation.min_phase_margin_deg ({comp.min_phase_margin_deg:g}"
                            "); lower it")
    if mg.modulus_margin < comp.min_modulus_margin:
        raise ScenarioError(f"{where}: the loop passes within {mg.modulus_margin:.2f} of -1 "
                            f"(modulus margin; compensation.min_modulus_margin is "
                            f"{comp.min_modulus_margin:g}); lower it")
    # a predictor (pseudo-open loop) has no -1 point to pass near: its robustness is the
    # peak of |S| itself (for a plain feedback loop 1 / peak |S| is the modulus margin)
    if mg.peak_rejection * comp.min_modulus_margin > 1.0:
        raise ScenarioError(f"{where}: the loop amplifies motion near {mg.peak_hz:.3g} Hz "
                            f"{mg.peak_rejection:.1f}x (peak |S|; at most 1 / "
                            f"compensation.min_modulus_margin = "
                            f"{1.0 / comp.min_modulus_margin:.3g}x); lower it, or shorten the "
                            "latency")


def nominal_target(m: Models):
    """The orbit/attitude prediction of the controller's target: the nominal (jitter-free)
    image motion at the main imager's centre since frame 0's exposure mid-time, minus the
    motion the imager follows by itself. A function t (N,) -> (N, 2) px."""
    cam = m.main_camera
    t0 = float(m.frame_mid_s[0])
    ground = cam.ground_points(cam.focal_plane.center_px[None], t0, m.terrain.height_at)

    def nominal(t_s: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        mo = cam.image_motion_px(ground, t, t0, nominal=True)[:, 0]
        return mo - (m.charge_px(t) - m.charge_px(np.array(t0)))

    return nominal

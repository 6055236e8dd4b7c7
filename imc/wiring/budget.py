"""What a run will cost, from the scenario alone (nothing allocated): frames and peak memory.

``imc validate`` prints the estimate; ``imc run`` (and every command that builds a run)
refuses, before anything is allocated, a scenario whose estimate exceeds this machine's
memory budget or :data:`MAX_FRAMES`, naming the fields whose product decides it
(``--force`` for the deliberate case). The figures are upper-end estimates from measured
costs per texel, per pixel and per frame (measured on imcsim's own generators and
``/usr/bin/time -v`` runs; see tests/test_robustness.py), not guarantees.

``imc validate`` itself stays cheap: above :data:`LIGHT_TEXELS` it checks the geometry on a
flat stand-in of the tile (:func:`scene.terrain.flat_terrain`: same size and DEM grid) instead of
generating the terrain, and reads a GeoTIFF decimated; ``imc run`` checks the geometry again
on the real terrain before the first frame.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from camera.imager import IMAGERS
from imc.scenario import Scenario, ScenarioError

#: the most tracker frames a run may have without --force (the loop steps frame by frame)
MAX_FRAMES = 1_000_000
#: share of the machine's memory (or of the container's limit) a run may plan to use
MEMORY_SHARE = 0.8
#: terrain generation peak, bytes per albedo texel, per scene kind (measured, rounded up)
TERRAIN_BYTES_PER_TEXEL = {"procedural": 95.0, "urban": 75.0, "rural": 170.0,
                           "mountain": 90.0, "waves": 140.0, "calm_water": 55.0,
                           "geotiff": 48.0}
#: the cloud layer's generation, bytes per cell; its Mitsuba mesh, bytes per cell
CLOUD_BYTES_PER_CELL = 75.0
CLOUD_MESH_BYTES_PER_CELL = 48.0
#: the texture plant's albedo image of the t = 0 view, bytes per pixel at its build's peak
#: (the rays through the DEM; measured with tracemalloc: 810 MB for smallsat_pushbroom's
#: 13,896 x 292 px), and the flow's largest across-track share (a crab of ~4 degrees)
TEXTURE_BYTES_PER_BASE_PX = 200.0
CRAB = 0.07
#: the interpreter with numpy, scipy, numba, matplotlib (validate, analytic and texture runs)
#: and with Mitsuba / Dr.Jit (rendered runs). Measured (VmHWM, 128^2 tracker, 0.1 s, no report,
#: no blur images; numpy 2.4, mitsuba 3.9): 439 MB analytic, 516 MB rendered
BASE_BYTES = 420e6
RENDER_BASE_BYTES = 600e6
#: a validate builds the full terrain up to this many texels; above, a flat stand-in
LIGHT_TEXELS = 1024 * 1024
#: the truth's samples (pose, projection, motion, charge), bytes per sample
TRUTH_BYTES_PER_SAMPLE = 400.0
#: loop record and checkpoint chunk copies, bytes per frame and per frame and block
RECORD_BYTES_PER_FRAME = 200.0
RECORD_BYTES_PER_FRAME_BLOCK = 260.0
#: the correlator's reference spectra, windows and pass caches, bytes per block pixel
CORRELATOR_BYTES_PER_PX = 48.0
#: the optical emulation: bytes per sensor / SLM pixel of each block in a batch
OPTICAL_BYTES_PER_PX = 40.0
#: metrics.blur_images: the side of the rendered patches (imc.wiring.blur), px; the figure and the
#: slanted edge's terrain, bytes (measured: +110-430 MB over the run without them; the 0.1 s
#: run of tests/test_robustness.py peaks at 937-942 MB with them, 439-516 MB without)
BLUR_PATCH_PX = 192
BLUR_IMAGES_BYTES = 300e6
#: the main imager's product (imc.wiring.product): bytes per product pixel (rendered,
#: exposed, corrected and restored versions of the scene and the target, the resampling's
#: coordinates and the deconvolution's spectra), and the two ray casters' batches and scenes
PRODUCT_BYTES_PER_PX = 400.0
PRODUCT_BASE_BYTES = 400e6
#: report.html, its figures and the recording (matplotlib, Rerun), bytes: drawn by `imc run`
#: on a helper process (imc.outputs.jobs; measured 241 MB resident on the quickstart, the
#: run's own process then 108 MB below drawing them itself)
REPORT_BYTES = 250e6
#: the jitter's evaluation chunk (orbit.jitter._CHUNK) times its components, 4 float arrays
JITTER_CHUNK = 4096
JITTER_MAX_COMPONENTS = 20000


@dataclass(frozen=True)
class RunEstimate:
    """Frames and planned peak memory of a run; ``parts`` the memory by component (bytes)."""

    frames: int
    peak_bytes: float
    parts: dict[str, float] = field(default_factory=dict)
    texels: int = 0
    budget_bytes: float = 0.0

    def largest(self) -> str:
        return max(self.parts, key=self.parts.get) if self.parts else ""

    def parts_text(self, n: int = 3) -> str:
        """The n largest parts of the memory estimate."""
        top = sorted(self.parts.items(), key=lambda kv: -kv[1])[:n]
        return ", ".join(f"{k} {_gb(v)}" for k, v in top)

    def text(self) -> str:
        """One line: frames, peak memory and its largest parts."""
        return (f"{self.frames:,} frames, peak memory ~{_gb(self.peak_bytes)} of "
                f"{_gb(self.budget_bytes)} allowed ({self.parts_text()})")


def _gb(b: float) -> str:
    return f"{b / 1e9:.2f} GB" if b >= 1e8 else f"{b / 1e6:.0f} MB"


@functools.cache
def memory_budget_bytes() -> float:
    """MEMORY_SHARE of the physical memory, or of the cgroup's limit when that is lower."""
    try:
        total = float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        total = 8e9
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            limit = Path(path).read_text().strip()
        except OSError:
            continue
        if limit.isdigit() and 0 < int(limit) < total:
            total = float(int(limit))
    return MEMORY_SHARE * total


def tile_texels(sc: Scenario) -> int:
    """Albedo texels of the scene tile (a GeoTIFF: its pixels, from the header)."""
    s = sc.scene
    if s.kind == "geotiff":
        from scene.geotiff import raster_shape

        h, w = raster_shape(s.geotiff.ortho)
        return int(h) * int(w)
    n = int(round(s.size_m / s.texel_m))
    return n * n


def _cloud_cells(sc: Scenario) -> int:
    from imc.scenario import CloudsConfig
    from scene.classes import cloud_cell_m

    s = sc.scene
    cfg = s.clouds if s.clouds is not None else (CloudsConfig() if s.kind == "mountain" else None)
    if cfg is None or cfg.cover <= 0.0:
        return 0
    relief = s.relief_rms_m if s.relief_rms_m is not None else 0.04 * s.size_m
    extent = s.size_m + 3.0 * (cfg.base_height_m + cfg.thickness_m + 6.0 * relief)
    cell = cloud_cell_m(extent, cfg.cell_m)
    return (int(round(extent / cell)) + 1) ** 2


def _jitter_components(sc: Scenario) -> int:
    j = sc.attitude.jitter
    n = len(j.sinusoids) + sum(len(w.harmonics) for w in j.wheels)
    for r in j.random:
        band = r.f_max_hz - r.f_min_hz
        n += int(min(max(math.ceil(band * max(sc.duration_s, 1.0 / band)), 64),
                     JITTER_MAX_COMPONENTS))
    return n


def _truth_samples(sc: Scenario) -> float:
    """Samples of the main imager's truth (imc.wiring.truth.compute_truth)."""
    t, mi = sc.camera.tracker, sc.camera.main_imager
    span = max(sc.duration_s - mi.start_s, 0.0)
    per_frame = 1.0 / t.frame_rate_hz / sc.metrics.samples_per_frame
    if IMAGERS[mi.kind].scanning:
        rate = mi.line_rate_hz or _tdi_line_rate_hz(sc)
        window = mi.stages / rate
    else:
        window = min(mi.exposure_s, span) if span > 0 else mi.exposure_s
    dt = min(per_frame, window / 16.0)
    return span / dt + 16.0


def _ground_flow(sc: Scenario) -> tuple[float, float]:
    """(ground speed m/s, nadir ground sample distance m), roughly, from the orbit."""
    o, c = sc.orbit, sc.camera
    if o.kind == "aircraft":
        h = o.height_m or 1000.0
        return o.ground_speed_mps or 0.0, h * c.pixel_pitch_m / c.focal_length_m
    alt = o.altitude_m if o.kind in ("sun_synchronous", "circular") else (
        (o.semi_major_axis_m or 6_378_137.0 + 681e3) - 6_378_137.0 if o.kind == "elements"
        else 681e3)
    alt = max(alt, 150e3)
    mu, r_e = 3.986004418e14, 6_378_137.0
    v_ground = math.sqrt(mu / (r_e + alt)) * r_e / (r_e + alt)
    return v_ground, alt * c.pixel_pitch_m / c.focal_length_m


def _tdi_line_rate_hz(sc: Scenario) -> float:
    """The synchronous line rate, roughly: ground speed over the ground sample distance."""
    v, gsd = _ground_flow(sc)
    return v / gsd


def _reach_px(sc: Scenario) -> tuple[float, float]:
    """How far (px) the image moves over the run, roughly (the texture plant's margins): the
    ground's flow when scanning (along the rows, from one side) and the jitter's amplitudes
    plus a margin (on both sides of each axis)."""
    c = sc.camera
    ifov = c.pixel_pitch_m / c.focal_length_m
    v, gsd = _ground_flow(sc)
    flow = 0.0 if sc.attitude.mode == "target" else v * sc.duration_s / gsd
    j = sc.attitude.jitter

    def px(urad, p):
        return p if p is not None else urad * 1e-6 / ifov

    amp = sum(px(s.amplitude_urad, s.amplitude_px) for s in j.sinusoids)
    amp += sum(4.0 * px(r.rms_urad, r.rms_px) for r in j.random)
    amp += sum(px(h.amplitude_urad, h.amplitude_px) * (1.0 + abs(w.speed_rate_hz_per_s)
                                                      * sc.duration_s / w.speed_hz) ** 2
               for w in j.wheels for h in w.harmonics)
    return flow, amp + 32.0


def estimate_run(sc: Scenario) -> RunEstimate:
    """Frames and peak memory of ``imc run`` on ``sc``."""
    t, c = sc.camera.tracker, sc.correlator
    frames = sc.n_frames
    texels = tile_texels(sc)
    kind = sc.scene.kind
    fidelity = sc.plant.fidelity
    px = t.rows * t.cols
    parts: dict[str, float] = {}
    parts["terrain"] = texels * TERRAIN_BYTES_PER_TEXEL[kind]
    dem_nodes = (sc.scene.size_m / sc.scene.dem_spacing_m + 1) ** 2 if kind != "geotiff" else 0
    parts["terrain"] += 64.0 * dem_nodes
    cells = _cloud_cells(sc)
    parts["clouds"] = cells * CLOUD_BYTES_PER_CELL
    parts["jitter"] = 4 * 8.0 * JITTER_CHUNK * _jitter_components(sc)
    parts["record"] = frames * (RECORD_BYTES_PER_FRAME + RECORD_BYTES_PER_FRAME_BLOCK * c.n_blocks)
    renders = fidelity == "rendered" or (fidelity == "analytic" and sc.plant.noise == "rendered"
                                         and sc.plant.sigma_px is None)
    base = RENDER_BASE_BYTES if renders else BASE_BYTES
    parts["truth"] = _truth_samples(sc) * TRUTH_BYTES_PER_SAMPLE
    if fidelity != "analytic":
        parts["frames"] = 2.0 * frames * px  # uint16 frames kept for re-referencing
        parts["correlator"] = CORRELATOR_BYTES_PER_PX * c.n_blocks * c.block_px ** 2
        if c.method == "optical":
            o = c.optical
            sensor_px = sum(s.rows * s.cols for s in (o.input_slm, o.jps_sensor, o.slm2,
                                                      o.output_sensor))
            parts["correlator"] += OPTICAL_BYTES_PER_PX * 4 * sensor_px
    if fidelity == "rendered" or (renders and sc.plant.noise_texel_m is None):
        # Mitsuba (an analytic plant's rendered noise: the scene's own tile, once): the
        # albedo bitmap and texture, the DEM and cloud meshes, film and wavefront
        parts["renderer"] = (8.0 * texels + 48.0 * dem_nodes + CLOUD_MESH_BYTES_PER_CELL * cells
                             + px * (24.0 + 4.0 * sc.scene.spp))
    elif fidelity == "texture":
        # the albedo image of the t = 0 view over the sensor and its reach, built through
        # the DEM at TEXTURE_BYTES_PER_BASE_PX at its peak; across track the flow's share
        # without yaw steering (Earth's rotation crabs it by up to ~4 degrees)
        flow, amp = _reach_px(sc)
        crab = 0.0 if sc.attitude.yaw_steering or sc.orbit.kind == "aircraft" else CRAB
        base_px = (t.rows + flow + 2 * amp) * (t.cols + 2 * (amp + crab * flow))
        parts["plant"] = px * 64.0 + 96.0 * frames * 4 + TEXTURE_BYTES_PER_BASE_PX * base_px
    if sc.metrics.blur_images and not IMAGERS[sc.camera.main_imager.kind].scanning:
        # imc.wiring.product.picture_study: Mitsuba (whatever the plant), the target tile's
        # texture, a BLUR_PATCH_PX square frame product of the scene and the target at
        # metrics.blur_spp samples a pixel (upper bound) and the figure
        base = RENDER_BASE_BYTES
        parts["blur images"] = (BLUR_IMAGES_BYTES + 8.0 * texels
                                + 2 * BLUR_PATCH_PX**2 * (24.0 + 4.0 * sc.metrics.blur_spp))
    if sc.product.enabled:
        p = sc.product
        base = RENDER_BASE_BYTES
        target_lines = min(p.lines, max(p.cols, 256))
        target_texels = (7.5 * max(target_lines, p.cols)) ** 2  # its tile, gsd / 5 texels
        parts["product"] = (PRODUCT_BASE_BYTES + 4.0 * target_texels
                            + PRODUCT_BYTES_PER_PX * (p.lines + target_lines) * p.cols)
    parts["report"] = REPORT_BYTES
    parts = {k: v for k, v in parts.items() if v > 0}
    # the terrain's generation temporaries are freed before the loop starts
    steady = sum(v for k, v in parts.items() if k != "terrain") + 4.0 * texels
    peak = base + max(parts.get("terrain", 0.0) + parts.get("jitter", 0.0), steady)
    return RunEstimate(frames, peak, parts, texels, memory_budget_bytes())


def check_run_size(sc: Scenario, est: RunEstimate, force: bool = False) -> None:
    """A ScenarioError naming the fields when the run is larger than allowed (unless force)."""
    if force:
        return
    t = sc.camera.tracker
    if est.frames > MAX_FRAMES:
        raise ScenarioError(
            f"duration_s x camera.tracker.frame_rate_hz = {sc.duration_s:g} s x "
            f"{t.frame_rate_hz:g} Hz = {est.frames:,} frames, more than {MAX_FRAMES:,} "
            f"(estimated peak memory ~{_gb(est.peak_bytes)}); shorten duration_s or lower "
            "frame_rate_hz (--force to run it)")
    if est.peak_bytes > est.budget_bytes:
        raise ScenarioError(f"{_fields_of(sc, est.largest())}: the run would need ~"
                            f"{_gb(est.peak_bytes)} of memory, more than the "
                            f"{_gb(est.budget_bytes)} this machine allows ({est.parts_text()}"
                            f"); reduce them (--force to run it)")


def _fields_of(sc: Scenario, part: str) -> str:
    """The fields whose product decides a part of the estimate, as the user writes them."""
    s, c, t = sc.scene, sc.correlator, sc.camera.tracker
    if part == "terrain":
        if s.kind == "geotiff":
            return f"scene.geotiff.ortho ({s.geotiff.ortho.name}: its pixels)"
        n = int(round(s.size_m / s.texel_m))
        return (f"scene.size_m / scene.texel_m = {s.size_m:g} / {s.texel_m:g} m = {n:,} "
                f"texels a side")
    if part == "clouds":
        return "scene.size_m / scene.clouds.cell_m (cloud cells)"
    if part == "jitter":
        return ("attitude.jitter.random (f_max_hz - f_min_hz) x duration_s (components)")
    if part == "record":
        return (f"duration_s x camera.tracker.frame_rate_hz x correlator.n_blocks = "
                f"{sc.n_frames:,} frames x {c.n_blocks} blocks")
    if part == "truth":
        mi = sc.camera.main_imager
        extra = " / camera.main_imager.stages" if IMAGERS[mi.kind].scanning else ""
        return (f"duration_s x camera.tracker.frame_rate_hz x metrics.samples_per_frame"
                f"{extra} (truth samples)")
    if part == "frames":
        return (f"duration_s x camera.tracker.frame_rate_hz x camera.tracker.rows x cols = "
                f"{sc.n_frames:,} frames of {t.rows} x {t.cols} px")
    if part == "correlator":
        return (f"correlator.n_blocks x correlator.block_px^2 = {c.n_blocks} x "
                f"{c.block_px}^2 px" + (" (and correlator.optical's sensors)"
                                        if c.method == "optical" else ""))
    if part == "renderer":
        return (f"camera.tracker.rows x cols x scene.spp = {t.rows} x {t.cols} x {s.spp} "
                "(and the tile's texels)")
    if part == "blur images":
        return "metrics.blur_images x metrics.blur_spp (the main imager's rendered patches)"
    if part == "product":
        return "product.lines x product.cols (the main imager's product)"
    if part == "report":
        return ("the run's report, figures and recording (imc run draws them on a helper "
                "process)")
    if part == "plant":
        return ("camera.tracker.rows x cols, duration_s and the image's motion (the texture "
                "plant's t = 0 view and its margins; attitude.mode, attitude.jitter)")
    return part


"""The closed loop: orbit -> render -> sensor -> correlator -> compensation -> metrics.

Truth comes from the camera model's exact projection of the true trajectory onto the
terrain, never from the estimates. Every random draw takes a generator derived from the
scenario seed and the frame index, so a run (or a resumed run) is reproducible.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camera.geometry import FocalPlane
from camera.motion import CameraModel
from camera.sensor import SensorModel
from compensation.controller import FirstOrderLoop
from compensation.metrics import residual_metrics
from correlator.core import CorrelatorOptions
from correlator.tracker import BlockTracker, block_grid
from imc.io import write_csv, write_json, write_npz
from imc.scenario import Scenario, ScenarioError
from orbit.attitude import Attitude, JitterTerm
from orbit.frames import LocalFrame
from orbit.kepler import CircularOrbit
from scene.pinhole import ray_keyframes
from scene.terrain import Terrain, procedural_terrain

KEYFRAMES_PER_EXPOSURE = 5
CHECKPOINT_EVERY = 10


@dataclass(frozen=True)
class Models:
    """Everything a run needs, built from a Scenario (no rendering yet)."""

    scenario: Scenario
    camera: CameraModel
    terrain: Terrain
    sensor: SensorModel
    controller: FirstOrderLoop
    correlator: CorrelatorOptions
    corners: np.ndarray
    frame_t_s: np.ndarray
    exposure_s: float


def build_models(sc: Scenario) -> Models:
    """Build orbit, attitude, camera, terrain and loop models; validate the geometry."""
    epoch = sc.epoch
    try:
        orbit = CircularOrbit.over_point(
            sc.scene.center_lat_deg, sc.scene.center_lon_deg, sc.orbit.altitude_m,
            sc.orbit.inclination_deg, epoch, descending=sc.orbit.pass_direction == "descending")
    except ValueError as e:
        raise ScenarioError(f"scene.center_lat_deg: {e}; lower it or raise "
                            "orbit.inclination_deg") from None
    frame = LocalFrame(sc.scene.center_lat_deg, sc.scene.center_lon_deg, 0.0)
    t = sc.camera.tracker
    fp = FocalPlane(sc.camera.focal_length_m, sc.camera.pixel_pitch_m, t.rows, t.cols)
    jitter = tuple(
        JitterTerm(
            axis=j.axis,
            frequency_hz=j.frequency_hz,
            amplitude_rad=(j.amplitude_urad * 1e-6 if j.amplitude_urad is not None
                           else j.amplitude_px * fp.ifov_rad),
            phase_rad=np.deg2rad(j.phase_deg),
        )
        for j in sc.attitude.jitter
    )
    attitude = Attitude(
        mode=sc.attitude.mode,
        target_ecef_m=tuple(frame.origin_ecef_m.tolist()) if sc.attitude.mode == "target"
        else None,
        jitter=jitter,
    )
    cam = CameraModel(orbit, attitude, frame, fp)
    terrain = procedural_terrain(sc.scene.size_m, sc.scene.texel_m, sc.scene.dem_spacing_m,
                                 sc.scene.relief_rms_m, np.random.default_rng([sc.seed, 0]))
    frame_t = np.arange(sc.n_frames) / t.frame_rate_hz
    models = Models(
        scenario=sc,
        camera=cam,
        terrain=terrain,
        sensor=SensorModel(t.mean_signal_dn, t.noise_sigma_dn, t.adc_bits),
        controller=FirstOrderLoop(sc.compensation.gain, sc.compensation.latency_frames),
        correlator=CorrelatorOptions(method=sc.correlator.method,
                                     subpixel=sc.correlator.subpixel,
                                     psr_threshold=sc.correlator.psr_threshold,
                                     max_crlb_px=sc.correlator.max_crlb_px,
                                     rewindow=sc.correlator.rewindow),
        corners=block_grid(t.rows, t.cols, sc.correlator.block_px, sc.correlator.n_blocks),
        frame_t_s=frame_t,
        exposure_s=sc.exposure_s,
    )
    _check_coverage(models)
    return models


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
        hint = (" (attitude.mode 'nadir' sweeps the ground at ~6.8 km/s: use mode 'target' or a"
                " shorter duration_s)" if m.scenario.attitude.mode == "nadir" else "")
        raise ScenarioError(
            f"scene.size_m: the {m.scenario.scene.size_m:g} m tile does not cover the ground "
            f"the tracker sees during the run; it needs >= {need:.0f} m{hint}")


def frame_seeds(seed: int, k: int) -> tuple[np.random.Generator, int]:
    """Noise generator and render seed of frame k, derived from the scenario seed."""
    render_seed = int(np.random.SeedSequence([seed, 2, k]).generate_state(1)[0] & 0x7FFFFFFF)
    return np.random.default_rng([seed, 1, k]), render_seed


def exposure_times(m: Models, k: int, n: int) -> np.ndarray:
    """n times (s) spread evenly (cell centres) over frame k's exposure."""
    return m.frame_t_s[k] + (np.arange(n) + 0.5) / n * m.exposure_s


@dataclass
class LoopState:
    """Per-frame records of a run (the loop's whole state, so a run can resume)."""

    frames: np.ndarray  # (T, H, W) uint16
    offsets: np.ndarray  # (T, 2) stage offset used for each frame, px
    shifts: np.ndarray  # (T, B, 2) tracker shift of each block vs frame 0, px
    valid: np.ndarray  # (T, B)
    peaks: np.ndarray  # (T, B)
    crlb: np.ndarray  # (T, B, 2)
    gain: float
    done: int
    render_s: float

    @classmethod
    def empty(cls, m: Models) -> LoopState:
        n, b = len(m.frame_t_s), len(m.corners)
        fp = m.camera.focal_plane
        return cls(np.zeros((n, fp.rows, fp.cols), np.uint16), np.zeros((n, 2)),
                   np.zeros((n, b, 2)), np.zeros((n, b), bool), np.zeros((n, b)),
                   np.zeros((n, b, 2)), 0.0, 0, 0.0)

    def save(self, path: Path, digest: str) -> None:
        write_npz(path, compress=False, digest=np.array(digest), frames=self.frames,
                  offsets=self.offsets, shifts=self.shifts, valid=self.valid,
                  peaks=self.peaks, crlb=self.crlb,
                  gain=np.array(self.gain), done=np.array(self.done),
                  render_s=np.array(self.render_s))

    @classmethod
    def load(cls, path: Path, digest: str, m: Models) -> LoopState | None:
        """The saved state if it belongs to this exact scenario, else None."""
        try:
            with np.load(path) as z:
                if str(z["digest"]) != digest:
                    return None
                st = cls(z["frames"], z["offsets"], z["shifts"], z["valid"], z["peaks"],
                         z["crlb"], float(z["gain"]), int(z["done"]), float(z["render_s"]))
        except (OSError, KeyError, ValueError):
            return None
        fp = m.camera.focal_plane
        expected = (len(m.frame_t_s), fp.rows, fp.cols)
        return st if st.frames.shape == expected and st.shifts.shape[1] == len(m.corners) else None


ProgressFn = Callable[[int, int], None]


def run_loop(m: Models, state: LoopState | None = None, checkpoint: Path | None = None,
             progress: ProgressFn | None = None, renderer=None) -> LoopState:
    """Run (or continue) the closed loop over all tracker frames."""
    from scene.kernel import Renderer, Sun  # the Mitsuba layer, loaded only when rendering

    sc = m.scenario
    st = state or LoopState.empty(m)
    fp = m.camera.focal_plane
    if renderer is None:
        renderer = Renderer(m.terrain, Sun(sc.scene.sun_elevation_deg, sc.scene.sun_azimuth_deg),
                            fp.rows, fp.cols, spp=sc.scene.spp)
    tracker = None
    if st.done > 0:
        tracker = BlockTracker(st.frames[0], m.corners, sc.correlator.block_px, m.correlator)
    n = len(m.frame_t_s)
    for k in range(st.done, n):
        t0 = time.perf_counter()
        times = m.frame_t_s[k] + np.linspace(0.0, m.exposure_s, KEYFRAMES_PER_EXPOSURE)
        kf = ray_keyframes(m.camera.pose(times), fp, st.offsets[k], renderer.z_start_m)
        rng, render_seed = frame_seeds(sc.seed, k)
        radiance = renderer.render(kf, render_seed)
        st.render_s += time.perf_counter() - t0
        if k == 0:
            st.gain = m.sensor.gain_for(radiance)
        st.frames[k] = m.sensor.expose(radiance, st.gain, rng)
        if k == 0:
            tracker = BlockTracker(st.frames[0], m.corners, sc.correlator.block_px, m.correlator)
            st.valid[0] = True
            st.peaks[0] = np.inf
        else:
            res = tracker.update(st.frames[k])
            st.shifts[k], st.valid[k], st.peaks[k], st.crlb[k] = (
                res.shift, res.valid, res.peak, res.crlb)
        if sc.compensation.enabled and st.valid[k].any():
            # motion estimate relative to frame 0 = tracker shift + the stage offset used
            est = st.shifts[k][st.valid[k]].mean(axis=0) + st.offsets[k] - st.offsets[0]
            m.controller.update(st.offsets, k, est, True)
        st.done = k + 1
        if checkpoint is not None and (st.done % CHECKPOINT_EVERY == 0 or st.done == n):
            st.save(checkpoint, sc.digest())
        if progress is not None:
            progress(st.done, n)
    return st


@dataclass(frozen=True)
class Truth:
    """True image motion (camera model) relative to frame 0's exposure mean, px."""

    t_s: np.ndarray  # (T*S,) fine sample times
    center_px: np.ndarray  # (T*S, 2) motion at the sensor centre
    frame_center_px: np.ndarray  # (T, 2) exposure-mean motion at the sensor centre
    frame_blocks_px: np.ndarray  # (T, B, 2) exposure-mean motion at each block centre

    def per_sample(self, per_frame: np.ndarray) -> np.ndarray:
        """A per-frame quantity (T, ...) held over each frame's truth samples (T*S, ...)."""
        return np.repeat(per_frame, len(self.t_s) // len(self.frame_center_px), axis=0)


def compute_truth(m: Models, block_centers_px: np.ndarray) -> Truth:
    """Exposure-averaged and fine-sampled true image motion of the tracked ground points."""
    s = m.scenario.metrics.samples_per_frame
    n = len(m.frame_t_s)
    fp = m.camera.focal_plane
    pix = np.vstack([fp.center_px[None], block_centers_px])
    ground = m.camera.ground_points(pix, 0.0, m.terrain.height_at)
    t_fine = np.concatenate([exposure_times(m, k, s) for k in range(n)])
    motion = m.camera.image_motion_px(ground, t_fine, 0.0)  # (T*S, 1+B, 2)
    per_frame = motion.reshape(n, s, -1, 2).mean(axis=1)  # (T, 1+B, 2)
    ref = per_frame[0]
    fine = motion - ref[None]
    return Truth(t_fine, fine[:, 0], per_frame[:, 0] - ref[0], per_frame[:, 1:] - ref[None, 1:])


def summarize(m: Models, st: LoopState, truth: Truth) -> dict:
    """Metrics with and without compensation, and the tracker's own accuracy."""
    sc = m.scenario
    stage_fine = truth.per_sample(st.offsets)
    open_loop = truth.center_px
    closed = truth.center_px - stage_fine
    w = sc.metrics.main_exposure_s
    m_open = residual_metrics(truth.t_s, open_loop, w)
    m_closed = residual_metrics(truth.t_s, closed, w)
    measured = st.shifts + st.offsets[:, None, :]
    err = (measured - truth.frame_blocks_px)[1:]
    ok = st.valid[1:]
    rms_err = np.sqrt(np.mean(err[ok] ** 2, axis=0)) if ok.any() else np.array([np.nan] * 2)
    crlb = np.median(st.crlb[1:][ok], axis=0) if ok.any() else np.array([np.nan] * 2)
    return {
        "scenario": sc.name,
        "frames": int(len(m.frame_t_s)),
        "blocks": int(len(m.corners)),
        "compensation_enabled": sc.compensation.enabled,
        "without_compensation": m_open.to_dict(),
        "with_compensation": m_closed.to_dict(),
        "rms_reduction": m_open.rms_total_px / max(m_closed.rms_total_px, 1e-12),
        "tracker": {
            "valid_fraction": float(ok.mean()),
            "rms_error_px": [float(v) for v in rms_err],
            "median_crlb_px": [float(v) for v in crlb],
            "bias_px": [float(v) for v in (err[ok].mean(axis=0) if ok.any() else [np.nan] * 2)],
        },
    }


def write_outputs(m: Models, st: LoopState, truth: Truth, metrics: dict, out: Path,
                  save_frames: bool, rerun: bool = True) -> list[Path]:
    """metrics.json, tracks.csv, recording.rrd and (optionally) frames.npz, atomically."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    measured = st.shifts + st.offsets[:, None, :]
    rows = []
    for k, t in enumerate(m.frame_t_s):
        for b in range(len(m.corners)):
            rows.append([f"{t:.6f}", k, b,
                         f"{truth.frame_blocks_px[k, b, 0]:.5f}",
                         f"{truth.frame_blocks_px[k, b, 1]:.5f}",
                         f"{measured[k, b, 0]:.5f}", f"{measured[k, b, 1]:.5f}",
                         f"{st.offsets[k, 0]:.5f}", f"{st.offsets[k, 1]:.5f}",
                         int(st.valid[k, b]), f"{st.peaks[k, b]:.3f}"])
    header = ["t_s", "frame", "block", "true_row_px", "true_col_px", "meas_row_px",
              "meas_col_px", "stage_row_px", "stage_col_px", "valid", "psr"]
    write_csv(out / "tracks.csv", header, rows)
    written.append(out / "tracks.csv")
    write_json(out / "metrics.json", metrics)
    written.append(out / "metrics.json")
    if save_frames:
        write_npz(out / "frames.npz", frames=st.frames, t_s=m.frame_t_s,
                  true_offset_px=truth.frame_center_px, stage_offset_px=st.offsets,
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
    state = None if fresh or not ckpt.exists() else LoopState.load(ckpt, sc.digest(), m)
    resumed_from = state.done if state is not None else 0
    st = run_loop(m, state, ckpt, progress)
    truth = compute_truth(m, BlockTracker.centers_from(m.corners, sc.correlator.block_px))
    metrics = summarize(m, st, truth)
    files = write_outputs(m, st, truth, metrics, out, save_frames, rerun)
    info = {"wall_s": time.perf_counter() - t_start, "render_s": st.render_s,
            "resumed_from_frame": resumed_from, "files": [str(f) for f in files]}
    return metrics, info

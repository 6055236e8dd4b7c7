"""What a run reports: the metrics (summarize), tracks.csv, series.npz and frames.npz."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from compensation.loop import LoopResult
from compensation.metrics import motion_mtf, residual_metrics
from imc.io import write_csv, write_npz
from imc.wiring.advisories import advisories
from imc.wiring.build import LoopParts, Models
from imc.wiring.truth import Truth


def _floats(v) -> list[float | None]:
    return [float(x) if np.isfinite(x) else None for x in np.atleast_1d(v)]


def summarize(m: Models, res: LoopResult, truth: Truth, parts: LoopParts,
              link_stats: dict | None = None) -> dict:
    """Metrics with and without compensation, the tracker's accuracy, the loop, geometry."""
    sc = m.scenario
    rec = res.record
    m_open = residual_metrics(truth.t_s, truth.residual_px(None), truth.window_s)
    m_closed = residual_metrics(truth.t_s, truth.residual_px(res.trajectory), truth.window_s)
    err = (rec.shift_px - truth.meas_px)[1:]
    measured = rec.measured[1:]
    ok = rec.valid[1:] & measured
    nan2 = np.array([np.nan] * 2)
    rms_err = np.sqrt(np.mean(err[ok] ** 2, axis=0)) if ok.any() else nan2
    crlb = np.median(rec.sigma_px[1:][ok], axis=0) if ok.any() else nan2
    duration = len(m.frame_t_s) / m.rate_hz
    cmd_t, cmd_u = res.commanded.samples
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
            "valid_fraction": float(ok.sum() / max(measured.sum(), 1)),
            "rms_error_px": _floats(rms_err),
            "median_crlb_px": _floats(crlb),
            "bias_px": _floats(err[ok].mean(axis=0) if ok.any() else nan2),
            "rereferences": int(rec.rereferenced.sum()),
        },
        "loop": {
            "fidelity": sc.plant.fidelity,
            "controller": sc.compensation.controller.kind,
            "estimator": sc.compensation.estimator.kind,
            "actuator": sc.compensation.actuator.kind,
            "measurement_rate_hz": float(parts.model.rate_hz),
            "latency_s": float(parts.model.latency_s),
            "analytic": parts.margins.to_dict(),
            "measurements_delivered": int(np.isfinite(rec.arrive_s).sum()),
            "measurements_lost": int(res.transport_stats.get("lost", 0)),
            "estimates_valid": int(rec.motion_valid.sum()),
            "outlier_fraction": float(rec.outliers.sum() / max(rec.used.sum()
                                                               + rec.outliers.sum(), 1)),
            "estimate_rms_error_px": _estimate_error(m, res, truth),
            "commands": int(len(cmd_t) - 1),
            "max_command_px": _floats(np.max(np.abs(cmd_u), axis=0)),
            "stage_saturation_fraction": float(res.saturated_s / duration),
            "lines_hz": _lines(res),
        },
        "main_imager_start_s": float(sc.camera.main_imager.start_s),
        "exposures": exposure_comparison(truth, res.trajectory),
        "geometry": geometry_summary(m),
    }
    figures, _ = advisories(m, parts)
    out["loop"]["lock"] = {**figures["lock"], **run_lock(m, truth)}
    out["loop"]["correlator_budget"] = figures["correlator_budget"]
    if res.supervisor or getattr(parts, "supervisor", None) is not None:
        out["loop"]["supervisor"] = {"decisions": list(res.supervisor)}
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
    if link_stats is not None:
        out["link"] = dict(link_stats)
    return out


#: an exposure counts as worse with the loop than without when its motion MTF at Nyquist, the
#: two axes' product, is lower by more than this (ties near 1 are not counted; an axis the
#: jitter leaves alone may lose 0.001-0.002 to the tracker's noise while the other gains)
WORSE_MTF_TOLERANCE = 1e-3
#: the most worse exposures listed by start time in metrics.json
WORSE_LISTED = 20


def exposure_comparison(truth: Truth, trajectory) -> dict:
    """Per main-imager exposure (integration window), the motion MTF at Nyquist (row, col)
    without and with the loop; the exposures the loop made worse (their two axes' product
    lower), counted and listed (start time s, MTF open, MTF closed)."""
    wins, idx = np.unique(truth.window, return_inverse=True)
    order = np.argsort(idx, kind="stable")
    counts = np.bincount(idx)
    if len(wins) == 0 or np.any(counts != counts[0]):
        return {"n": int(len(wins)), "worse_than_open": None, "worse": []}
    shape = (len(wins), int(counts[0]), 2)
    t = truth.t_s[order].reshape(shape[:2])
    mtf = {}
    for name, traj in (("open", None), ("closed", trajectory)):
        r = truth.residual_px(traj)[order].reshape(shape)
        mtf[name] = np.stack([motion_mtf(r, axis=0), motion_mtf(r, axis=1)], axis=-1)
    both = {k: v.prod(axis=1) for k, v in mtf.items()}
    worse = both["closed"] < both["open"] - WORSE_MTF_TOLERANCE
    listed = [{"start_s": float(t[i, 0]), "mtf_nyquist_open": _floats(mtf["open"][i]),
               "mtf_nyquist_closed": _floats(mtf["closed"][i])}
              for i in np.flatnonzero(worse)[:WORSE_LISTED]]
    return {"n": int(len(wins)), "worse_than_open": int(worse.sum()),
            "tolerance": WORSE_MTF_TOLERANCE,
            "worst_closed_minus_open": float(np.min(both["closed"] - both["open"])),
            "worse": listed}


#: the running RMS's sampling scatter allowed in the run's lock time, standard deviations
LOCK_NOISE_SIGMAS = 3.0


def run_lock(m: Models, truth: Truth) -> dict:
    """The run's own lock time (:func:`compensation.lock.run_lock_time`) on the true residual
    the tracker sees, frame by frame (the blocks' true shifts averaged), s: the running RMS
    within 25 % of the steady state's plus 3 standard deviations of its sampling scatter."""
    from compensation.lock import run_lock_time

    r = np.nanmean(truth.meas_px[1:], axis=1)
    ok = np.all(np.isfinite(r), axis=1)
    window = max(5.0 / m.rate_hz, m.exposure_s)
    if ok.sum() < 10 or not m.scenario.compensation.enabled:
        return {"measured_s": None}
    lock = run_lock_time(m.frame_mid_s[1:][ok], r[ok], window_s=window,
                         noise_sigmas=LOCK_NOISE_SIGMAS)
    return {"measured_s": _floats([lock.lock_s])[0], "measured_band": lock.band,
            "steady_rms_px": float(lock.steady_rms_px),
            "measured_threshold_px": float(lock.threshold_px)}


def _estimate_error(m: Models, res: LoopResult, truth: Truth) -> list[float | None]:
    """RMS error of the loop's motion estimate at the field point against the camera model
    (exposure-mean motion at the main imager's centre since frame 0), valid estimates."""
    rec = res.record
    ok = rec.motion_valid.copy()
    ok[0] = False
    if not ok.any():
        return [None, None]
    cam = m.main_camera
    s = m.scenario.metrics.samples_per_frame
    t0 = float(m.frame_mid_s[0])
    ground = cam.ground_points(cam.focal_plane.center_px[None], t0, m.terrain.height_at)
    ks = np.flatnonzero(ok)
    times = (m.frame_t_s[ks, None] + (np.arange(s) + 0.5) / s * m.exposure_s).ravel()
    mo = cam.image_motion_px(ground, times, t0)[:, 0].reshape(len(ks), s, 2).mean(axis=1)
    t00 = m.frame_t_s[0] + (np.arange(s) + 0.5) / s * m.exposure_s
    mo0 = cam.image_motion_px(ground, t00, t0)[:, 0].mean(axis=0)
    err = rec.motion_px[ks] - (mo - mo0)
    return _floats(np.sqrt(np.mean(err**2, axis=0)))


def _lines(res: LoopResult) -> list[float]:
    st = res.states.get("controller")
    if st is None:
        return []
    if hasattr(st, "lines_hz"):
        return [float(f) for f in st.lines_hz]
    if hasattr(st, "omega"):
        return [float(w / (2 * np.pi)) for w in st.omega]
    return []


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
    if np.isnan(out["orbit_period_s"]):
        out["orbit_period_s"] = None
    if hasattr(orbit, "local_time_of_ascending_node_h"):
        out["local_time_of_ascending_node_h"] = float(orbit.local_time_of_ascending_node_h)
    return out


def write_tables(m: Models, res: LoopResult, truth: Truth, out: Path,
                 frames: np.ndarray | None, ref_corners: np.ndarray | None,
                 save_frames: bool, loop_model=None) -> tuple[list[Path], dict]:
    """tracks.csv, series.npz (for the report and the recording) and (optionally)
    frames.npz, atomically; metrics.json and the recording are the pipeline's. Returns the
    files and series.npz's arrays."""
    out.mkdir(parents=True, exist_ok=True)
    rec = res.record
    written = []
    rows = []
    stage = truth.stage_mean_px
    for k, t in enumerate(m.frame_t_s):
        for b in range(len(m.corners)):
            rows.append([f"{t:.6f}", k, b, int(rec.ref_frame[k, b]),
                         f"{truth.meas_px[k, b, 0]:.5f}", f"{truth.meas_px[k, b, 1]:.5f}",
                         f"{rec.shift_px[k, b, 0]:.5f}", f"{rec.shift_px[k, b, 1]:.5f}",
                         f"{stage[k, 0]:.5f}", f"{stage[k, 1]:.5f}",
                         f"{rec.motion_px[k, 0]:.5f}", f"{rec.motion_px[k, 1]:.5f}",
                         int(rec.valid[k, b]), f"{rec.peak[k, b]:.3f}",
                         f"{rec.sigma_px[k, b, 0]:.5f}", f"{rec.sigma_px[k, b, 1]:.5f}",
                         int(rec.used[k, b]), int(rec.outliers[k, b])])
    header = ["t_s", "frame", "block", "ref_frame", "true_row_px", "true_col_px",
              "meas_row_px", "meas_col_px", "stage_row_px", "stage_col_px",
              "estimate_row_px", "estimate_col_px", "valid", "psr", "crlb_row_px",
              "crlb_col_px", "used", "outlier"]
    write_csv(out / "tracks.csv", header, rows)
    written.append(out / "tracks.csv")
    if save_frames and frames is not None:
        write_npz(out / "frames.npz", frames=frames, t_s=m.frame_t_s,
                  stage_offset_px=stage, ref_index=rec.ref_frame[:, 0],
                  ref_corners=ref_corners, true_shift_px=truth.meas_px,
                  exposure_s=np.array(m.exposure_s))
        written.append(out / "frames.npz")
    from imc.outputs.figures import write_series

    path, series = write_series(out, m, res, truth, loop_model, frames, ref_corners)
    written.append(path)
    return written, series

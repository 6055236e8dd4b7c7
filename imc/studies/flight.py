"""The seed paper's airborne flight test: two image-motion records of the same frames, made
from different fragments, and their difference; and, unlike the paper, their true errors.

Protocol. The frames of both tracker sensors (the scenario's tracker and its mirror image on
the other side of the pushbroom line) are rendered once, open loop (the test had no
compensation). The tracker then runs twice over the same frames, each time with its own set of
fragments (blocks), one set per record. A set holds the same columns in both sensors, placed
symmetrically about the line's centre column, so a rotation or scale change of the field
cancels in its mean. Fragments are cut from a reference frame near the sensor's leading edge
and followed (cut where orbit, attitude, DEM and the last measurement put them) until they
would leave the sensor; the frame before becomes the next reference (a hand-over). A record is
image motion as imcsim defines it: the mean shift of the set's valid fragments against the
reference, plus the record at the reference frame, so both records are 0 at frame 0 (their
initial offset removed).

Truths (from the camera model, never from the estimates):

* ``line``: the image motion at the pushbroom line's centre, the integral of the image
  velocity of the ground under it (the motion compensation has to follow), at each frame's
  mid-exposure;
* ``line_exposure``: the same averaged over each exposure (what any frame-based record can
  see at best: the exposure's blur is shared by every fragment);
* ``fragments``: the exposure-mean motion of each set's own fragments, handed over exactly
  as the record (what the correlator measures; the gap to ``line_exposure`` is relief
  parallax and the field's rotation and scale).

The paper inferred each record's error from the difference: sigma_diff / sqrt(2). That holds
when the two records' errors are independent and alike; :func:`compare` splits each record's
error against the line into the tracker's error, the fragments' offset from the line and the
shared blur, and each into the part common to both records and the part that differs.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camera.geometry import FocalPlane, project
from camera.motion import CameraModel
from correlator.tracker import BlockTracker
from imc.wiring import streams
from imc.wiring.build import Models, frame_seeds
from imc.wiring.rendered_plant import KEYFRAMES, expose_frame

Log = Callable[[str], None]


@dataclass(frozen=True)
class FlightConfig:
    """Fragment sets and hand-over rule of the flight test (pixels of the tracker sensors).

    ``set_a_px`` / ``set_b_px``: column offsets of each record's blocks from the sensor's
    centre column, each used on both sides and in both sensors (the defaults suit a
    288-column sensor with 64 px blocks: an inner pair and an outer pair that do not overlap).
    ``entry_row_px``: where a reference block is cut, from the leading edge; ``margin_px``:
    a hand-over happens before a block comes this close to an edge. ``truth_samples``:
    samples per exposure for exposure means; ``line_steps``: integration steps of the line's
    image velocity per frame period.
    """

    set_a_px: tuple[float, ...] = (32.0,)
    set_b_px: tuple[float, ...] = (104.0,)
    entry_row_px: int = 8
    margin_px: int = 2
    truth_samples: int = 8
    line_steps: int = 8


@dataclass(frozen=True)
class Recording:
    """The frames of every tracker sensor (S, T, H, W) in DN, rendered once."""

    cameras: tuple[CameraModel, ...]
    frames: np.ndarray
    render_s: float


@dataclass(frozen=True)
class Track:
    """One record and what it is made of; (T, 2) arrays in px (row, col), 0 at frame 0.

    ``record_px``: the set's image-motion record; ``dem_px``: the same with each fragment's
    predicted motion (orbit, attitude, DEM: relief parallax included) replaced by the line's;
    ``fragments_px``: the true motion of the same fragments, handed over as the record;
    ``ref_frame``: the reference of each frame; ``n_valid``: valid fragments per frame;
    ``crlb_px``: the correlator's predicted 1-sigma error of the mean shift per frame.
    """

    record_px: np.ndarray
    dem_px: np.ndarray
    fragments_px: np.ndarray
    ref_frame: np.ndarray
    n_valid: np.ndarray
    crlb_px: np.ndarray

    @property
    def handovers(self) -> int:
        return int(np.count_nonzero(np.diff(self.ref_frame)))


def sensor_cameras(m: Models) -> tuple[CameraModel, CameraModel]:
    """The scenario's tracker sensor and its mirror image about the principal point."""
    fp = m.camera.focal_plane
    off = fp.center_offset_px
    twin = FocalPlane(fp.focal_length_m, fp.pixel_pitch_m, fp.rows, fp.cols,
                      (-off[0], -off[1]))
    return m.camera, dataclasses.replace(m.camera, focal_plane=twin)


def _seeds(seed: int, sensor: int, k: int) -> tuple[np.random.Generator, int]:
    """Noise generator and render seed of frame k of a sensor (the first: the pipeline's)."""
    if sensor == 0:
        return frame_seeds(seed, k)
    return (streams.rng(seed, "flight_sensor", k),
            streams.render_seed(seed, k, "flight_render"))


def keyframes_per_exposure(m: Models, per_cycle: int = 16) -> int:
    """Pose keyframes across an exposure: ``per_cycle`` per period of the fastest jitter
    component that moves the image by more than 0.001 px (5 to 65)."""
    j = m.camera.attitude.jitter
    big = j.amplitude_rad > 1e-3 * m.camera.focal_plane.ifov_rad
    f = float(np.max(j.frequency_hz[big])) if np.any(big) else 0.0
    return int(np.clip(np.ceil(per_cycle * f * m.exposure_s) + 1, KEYFRAMES, 65))


def record_frames(m: Models, n_frames: int | None = None, log: Log | None = None) -> Recording:
    """Render and expose every frame of both sensors (stage at rest: open loop)."""
    from scene.kernel import Renderer, Sun
    from scene.pinhole import ray_keyframes

    cams = sensor_cameras(m)
    fp = m.camera.focal_plane
    n = len(m.frame_t_s) if n_frames is None else int(n_frames)
    ceiling = float(np.min(m.camera.pose(m.frame_t_s[:n]).position_m[:, 2]))
    t0 = time.perf_counter()
    r = Renderer(m.terrain, Sun(*m.sun_deg), fp.rows, fp.cols, spp=m.scenario.scene.spp,
                 quadrature=m.scenario.scene.quadrature,
                 clouds=m.clouds, ceiling_m=ceiling)
    frames = np.zeros((len(cams), n, fp.rows, fp.cols), np.uint16)
    n_kf = keyframes_per_exposure(m)
    for s, cam in enumerate(cams):
        gain = 0.0
        for k in range(n):
            times = m.frame_t_s[k] + np.linspace(0.0, m.exposure_s, n_kf)
            rng, seed = _seeds(m.scenario.seed, s, k)
            radiance = r.render(ray_keyframes(cam.pose(times), cam.focal_plane, (0.0, 0.0),
                                              r.z_start_m), seed)
            if k == 0:
                gain = m.sensor.gain_for(m.optics.apply(radiance))
            frames[s, k] = expose_frame(m, radiance, gain, rng)
        if log:
            log(f"  sensor {s + 1}: {n} frames rendered ({time.perf_counter() - t0:.0f} s)")
    return Recording(cams, frames, time.perf_counter() - t0)


def exposure_samples(m: Models, k: int, n: int) -> np.ndarray:
    """n times (s) at the cell centres of frame k's exposure."""
    return m.frame_t_s[k] + (np.arange(n) + 0.5) / n * m.exposure_s


def line_motion(m: Models, t_s: np.ndarray, cfg: FlightConfig,
                nominal: bool = False) -> np.ndarray:
    """Image motion (N, 2) px at the pushbroom line's centre at times t_s since t = 0: the
    image velocity of the ground under it, integrated exactly for any jitter frequency.

    Time is cut into steps of at most 1 / (``line_steps`` x frame rate) with a boundary at
    every requested time; over each step the ground under the centre at the step's middle
    is projected at both ends (a rotation moves it exactly; what is left is the change of
    the field across the fraction of a pixel it travels in a step). nominal: no jitter.
    """
    cam = m.main_camera
    fp = cam.focal_plane
    t = np.asarray(t_s, dtype=np.float64)
    dt = 1.0 / (m.rate_hz * cfg.line_steps)
    grid = np.unique(np.concatenate([np.arange(0.0, float(t.max()) + dt, dt), t]))
    mids = 0.5 * (grid[1:] + grid[:-1])
    pose = cam.pose(mids, nominal)
    ground = cam.ground_points_posed(pose, fp.center_px, m.terrain.height_at)
    ends = cam.pose(grid, nominal)
    step = project(ground, ends[1:], fp) - project(ground, ends[:-1], fp)
    pos = np.vstack([np.zeros((1, 2)), np.cumsum(step, axis=0)])
    return pos[np.searchsorted(grid, t)]


def _nominal(cams, grounds, mid: np.ndarray, r: int, k: int) -> np.ndarray:
    """Predicted (jitter-free) motion (S, B, 2) of the fragments' ground from frame r to k."""
    return np.stack([cam.image_motion_px(g, mid[k:k + 1], float(mid[r]), nominal=True)[0]
                     for cam, g in zip(cams, grounds, strict=True)])


def set_corners(fp: FocalPlane, offsets_px: tuple[float, ...], block_px: int,
                entry_row_px: int) -> np.ndarray:
    """Corners (2 N, 2) of blocks centred ``offsets_px`` either side of the centre column."""
    c = fp.center_px[1]
    cols = np.rint(np.concatenate([c - np.asarray(offsets_px), c + np.asarray(offsets_px)])
                   - (block_px - 1) / 2.0).astype(int)
    if cols.min() < 0 or cols.max() + block_px > fp.cols:
        raise ValueError(f"blocks {offsets_px} px from the centre column do not fit the "
                         f"{fp.cols}-column sensor")
    return np.column_stack([np.full(len(cols), entry_row_px), cols])


def track(m: Models, rec: Recording, offsets_px: tuple[float, ...], cfg: FlightConfig,
          line_nominal: np.ndarray, chain: bool = False) -> Track:
    """Run the tracker over the recorded frames with the fragments ``offsets_px`` either side
    of the centre column (both sensors); ``line_nominal`` (T, 2): the line's nominal motion at
    mid-exposures. ``chain``: hand over at every frame (frame-to-frame records)."""
    b = m.scenario.correlator.block_px
    cams, frames = rec.cameras, rec.frames
    n_s, n = frames.shape[0], frames.shape[1]
    rows, cols = cams[0].focal_plane.rows, cams[0].focal_plane.cols
    corners = set_corners(cams[0].focal_plane, offsets_px, b, cfg.entry_row_px)
    centres = BlockTracker.centers_from(corners, b)
    nb = len(corners)
    mid, s = m.frame_mid_s, cfg.truth_samples
    h = m.terrain.height_at
    rec_px, dem_px, frag_px = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2))
    ref = np.zeros(n, int)
    n_valid = np.zeros(n, int)
    crlb = np.zeros((n, 2))
    n_valid[0] = n_s * nb
    r = -1
    trackers: list[BlockTracker] = []
    grounds: list[np.ndarray] = []
    unpredicted = np.zeros((n_s, nb, 2))
    lo, hi = cfg.margin_px, np.array([rows, cols]) - b - cfg.margin_px
    for k in range(1, n):
        leaving = chain or r < 0
        if r >= 0:
            nominal = _nominal(cams, grounds, mid, r, k)
            at = corners + np.rint(nominal + unpredicted)
            leaving = leaving or bool(np.any((at < lo) | (at > hi)))
        if leaving and r != k - 1:
            r = k - 1  # hand over to the previous frame
            trackers = [BlockTracker(frames[i, r], corners, b, m.correlator) for i in range(n_s)]
            grounds = [cam.ground_points(centres, float(mid[r]), h) for cam in cams]
            unpredicted[:] = 0.0
            nominal = _nominal(cams, grounds, mid, r, k)
        pred = nominal + unpredicted
        shift = np.full((n_s, nb, 2), np.nan)
        valid = np.zeros((n_s, nb), bool)
        sig = np.full((n_s, nb, 2), np.inf)
        for i in range(n_s):
            res = trackers[i].update(frames[i, k], pred[i])
            shift[i], valid[i], sig[i] = res.shift, res.valid, res.crlb
        times = np.concatenate([exposure_samples(m, r, s), exposure_samples(m, k, s)])
        true = np.stack([cam.image_motion_px(g, times, float(mid[r])) for cam, g
                         in zip(cams, grounds, strict=True)])  # (S, 2s, nb, 2)
        true = true[:, s:].mean(axis=1) - true[:, :s].mean(axis=1)
        ref[k], n_valid[k] = r, valid.sum()
        use = valid if valid.any() else np.ones_like(valid)  # none valid: the prediction
        meas = np.where(valid[..., None], shift, pred)
        rec_px[k] = rec_px[r] + meas[use].mean(axis=0)
        frag_px[k] = frag_px[r] + true[use].mean(axis=0)
        dem_px[k] = (dem_px[r] + (meas - nominal)[use].mean(axis=0)
                     + line_nominal[k] - line_nominal[r])
        crlb[k] = np.sqrt(np.sum(np.where(valid[..., None], sig, 0.0) ** 2, axis=(0, 1))) / max(
            1, valid.sum())
        unpredicted = np.where(valid[..., None], shift - nominal, unpredicted)
    return Track(rec_px, dem_px, frag_px, ref, n_valid, crlb)


@dataclass(frozen=True)
class LineTruth:
    """The line's true motion (T, 2) px at mid-exposures and averaged over each exposure,
    and its nominal (jitter-free) motion at mid-exposures; all 0 at frame 0."""

    line_px: np.ndarray
    exposure_px: np.ndarray
    nominal_px: np.ndarray


def line_truth(m: Models, n: int, cfg: FlightConfig) -> LineTruth:
    """The pushbroom line's true and nominal motion over the first n frames."""
    s = cfg.truth_samples
    mid = m.frame_mid_s[:n]
    samples = np.concatenate([exposure_samples(m, k, s) for k in range(n)])
    both = line_motion(m, np.concatenate([mid, samples]), cfg)
    inst, exp = both[:n], both[n:].reshape(n, s, 2).mean(axis=1)
    nom = line_motion(m, mid, cfg, nominal=True)
    return LineTruth(inst - inst[0], exp - exp[0], nom - nom[0])


def _floats(x) -> list[float]:
    return [float(v) for v in np.asarray(x).ravel()]


def _std(x: np.ndarray) -> list[float]:
    return _floats(np.nanstd(x, axis=0))


def _split(ea: np.ndarray, eb: np.ndarray) -> dict:
    """sigma per axis of two error records, of their common part (ea + eb) / 2 and of their
    differing part (ea - eb) / 2."""
    return {"a": _std(ea), "b": _std(eb), "common": _std(0.5 * (ea + eb)),
            "differing": _std(0.5 * (ea - eb))}


def compare_records(ra: np.ndarray, rb: np.ndarray, truth: np.ndarray) -> dict:
    """The paper's figure and its inference for two records (T, 2) against the truth (T, 2);
    sigmas per axis, px.

    ``sigma_diff``: std of record A - record B; ``inferred``: sigma_diff / sqrt(2), the
    paper's estimate of each record's error; ``true``: std of each record's error, of the
    part common to both and of the part that differs; ``true_rms``: the two records' RMS
    true sigma; ``ratio``: inferred / true_rms (1: the inference holds).
    """
    diff = np.nanstd(ra - rb, axis=0)
    ea, eb = ra - truth, rb - truth
    true = np.sqrt(0.5 * (np.nanstd(ea, axis=0) ** 2 + np.nanstd(eb, axis=0) ** 2))
    inferred = diff / np.sqrt(2.0)
    return {"sigma_diff": _floats(diff), "inferred": _floats(inferred), "true": _split(ea, eb),
            "true_rms": _floats(true), "ratio": _floats(inferred / true)}


def compare(a: Track, b: Track, line: LineTruth) -> dict:
    """:func:`compare_records` on the records, the DEM-corrected records and the records'
    frame-to-frame increments (velocity records), against the line's motion; ``terms``
    splits each record's error into the tracker's (record - fragments), the fragments'
    offset from the line (fragments - line_exposure: relief parallax, the field's rotation
    and scale) and the exposure's blur (line_exposure - line, the same for both records)."""
    out = compare_records(a.record_px, b.record_px, line.line_px)
    out["terms"] = {
        "tracker": _split(a.record_px - a.fragments_px, b.record_px - b.fragments_px),
        "fragments_vs_line": _split(a.fragments_px - line.exposure_px,
                                    b.fragments_px - line.exposure_px),
        "blur": _split(line.exposure_px - line.line_px, line.exposure_px - line.line_px),
    }
    out["dem"] = compare_records(a.dem_px, b.dem_px, line.line_px)
    out["per_frame"] = compare_records(np.diff(a.record_px, axis=0),
                                       np.diff(b.record_px, axis=0),
                                       np.diff(line.line_px, axis=0))
    return out


@dataclass(frozen=True)
class Session:
    """One flight-test session: both records (hand-overs as the fragments leave, and
    frame to frame), the truth and the comparisons."""

    seed: int
    t_s: np.ndarray
    a: Track
    b: Track
    chain_a: Track
    chain_b: Track
    line: LineTruth
    stats: dict
    render_s: float
    track_s: float


def run_session(m: Models, cfg: FlightConfig = FlightConfig(), n_frames: int | None = None,
                log: Log | None = None) -> Session:
    """Record the frames once, track them with both fragment sets (and again frame to
    frame), compare with the truth."""
    n = len(m.frame_t_s) if n_frames is None else int(n_frames)
    rec = record_frames(m, n, log)
    t0 = time.perf_counter()
    line = line_truth(m, n, cfg)
    tracks = [track(m, rec, offs, cfg, line.nominal_px, chain)
              for chain in (False, True) for offs in (cfg.set_a_px, cfg.set_b_px)]
    a, b, ca, cb = tracks
    stats = compare(a, b, line)
    stats["chain"] = compare(ca, cb, line)
    per_set = 4 * len(cfg.set_a_px), 4 * len(cfg.set_b_px)  # both sides, both sensors
    stats.update({
        "frames": n, "handovers": [a.handovers, b.handovers],
        "valid_fraction": [float(t.n_valid[1:].mean() / k) for t, k in zip((a, b), per_set,
                                                                          strict=True)],
        "crlb_px": [_floats(np.sqrt(np.mean(t.crlb_px[1:] ** 2, axis=0))) for t in (a, b)]})
    return Session(m.scenario.seed, m.frame_mid_s[:n].copy(), a, b, ca, cb, line, stats,
                   rec.render_s, time.perf_counter() - t0)


def plot_session(sess: Session, path, title: str | None = None) -> None:
    """PNG: both records and the truth (less the nominal motion), their difference, and their
    true errors, along and across the flight direction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, nom = sess.t_s, sess.line.nominal_px
    fig, ax = plt.subplots(3, 2, figsize=(12, 8.5), sharex=True)
    for j, name in enumerate(("along the flight (row)", "across the flight (col)")):
        ax[0, j].plot(t, sess.a.record_px[:, j] - nom[:, j], lw=1.0, label="record A")
        ax[0, j].plot(t, sess.b.record_px[:, j] - nom[:, j], lw=1.0, label="record B")
        ax[0, j].plot(t, sess.line.line_px[:, j] - nom[:, j], "k--", lw=0.8,
                      label="truth (line)")
        ax[0, j].set_title(f"image motion less the nominal, {name}")
        d = sess.a.record_px[:, j] - sess.b.record_px[:, j]
        ax[1, j].plot(t, d, color="C2", lw=1.0)
        ax[1, j].set_title(f"A - B: sigma {np.std(d):.3f} px")
        for tr, lab in ((sess.a, "A"), (sess.b, "B")):
            e = tr.record_px[:, j] - sess.line.line_px[:, j]
            ax[2, j].plot(t, e, lw=1.0, label=f"{lab} - truth: sigma {np.std(e):.3f} px")
        ax[2, j].set_xlabel("t (s)")
        ax[2, j].legend(fontsize=8)
        for i in range(3):
            ax[i, j].set_ylabel("px")
            ax[i, j].grid(alpha=0.3)
    ax[0, 0].legend(fontsize=8)
    fig.suptitle(title or f"flight test, session seed {sess.seed}: two records from "
                 "different fragments of the same frames")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

"""Plants at three fidelities behind one protocol (compensation.blocks.Plant).

``rendered``: Mitsuba renders every tracker frame with the orbit, attitude and the stage's
trajectory inside the exposure; ``texture``: the scene's albedo, seen once through the camera
model at t = 0, each pixel showing the ground point the true camera (and the stage) puts
there at each instant of the exposure, averaged over it, the optics and the sensor noise
applied, in numpy; both are tracked by the
real correlator (BlockTracker), cut where orbit and attitude predict the blocks. ``analytic``:
no images, the true block shifts plus the correlator's predicted noise
(compensation.analytic_plant.AnalyticPlant), predicted on the flat-shaded albedo or, with
``plant.noise: rendered``, on frame 0 rendered once (:func:`rendered_noise`). The loop code
is the same for all three.
"""

from __future__ import annotations

import numpy as np

from camera.exposure import expose
from camera.geometry import Pose, project
from compensation.analytic_plant import AnalyticPlant
from compensation.blocks import BlockMeasurements
from correlator.options import CorrelatorOptions
from correlator.tracker import BlockTracker, extract_blocks
from imc.scenario import ScenarioError, parse_scenario
from imc.wiring import streams
from imc.wiring.build import Models, build_models, frame_seeds, predicted_px
from imc.wiring.links import chain_corners, pair_corners

#: a block's predicted deformation (px across it) beyond which the tracker resamples the
#: current frame through it (long stares), instead of cutting a plain block
WARP_MIN_PX = 0.05

#: pose keyframes per exposure (the attitude's motion inside it), and while the stage moves
#: other than in a straight line inside the exposure (steps, a piezo's transients)
KEYFRAMES = 5
KEYFRAMES_BENT = 33

#: the texture plant traces its rays on a grid of this step (px) and interpolates between
SOURCE_GRID_PX = 4


def expose_frame(m: Models, radiance: np.ndarray, gain: float, rng) -> np.ndarray:
    """A tracker frame: radiance -> optics MTF -> photo-electrons -> digital frame
    (:func:`camera.exposure.expose`, radiometric or at the 'mean_level' gain)."""
    radiometric = m.scenario.camera.tracker.signal == "radiometric"
    return expose(radiance, m.optics, m.sensor, rng, m.exposure_s,
                  radiometry=m.radiometry if radiometric else None,
                  gain_e=None if radiometric else gain)


class TrackerPlant:
    """Frames from an image model (:meth:`radiance`), tracked by the real correlator.

    A fixed reference (frame 0, or the frame the estimator chose) while the predicted motion
    keeps the blocks on the sensor; in a scanning view every block is ``leaving``, so each
    measured frame becomes the next reference and its blocks are cut where the content will
    be half-way (today's chain).
    """

    def __init__(self, m: Models):
        self.m = m
        n = len(m.frame_t_s)
        fp = m.camera.focal_plane
        self.block_px = m.scenario.correlator.block_px
        self.n_blocks = len(m.corners)
        self.frames = np.zeros((n, fp.rows, fp.cols), np.uint16)
        self.ref_corners_rec = np.zeros((n, self.n_blocks, 2), int)
        self.stage_mean = np.zeros((n, 2))
        self.grid_centers = BlockTracker.centers_from(m.corners, self.block_px)
        self.ref = 0
        self.ref_corners = m.corners.copy()
        self.gain = 0.0
        self.tracker: BlockTracker | None = None
        self._ground: dict[str, np.ndarray] = {}  # ground points of the current reference
        self._ground_key: tuple = ()

    # -- the image model, per fidelity --------------------------------------------------------
    def radiance(self, k: int, stage) -> np.ndarray:
        raise NotImplementedError

    # -- the protocol ---------------------------------------------------------------------------
    def measure(self, k: int, stage, blocks: np.ndarray) -> BlockMeasurements:
        m = self.m
        t0 = float(m.frame_t_s[k])
        self.stage_mean[k] = stage.mean(t0, t0 + m.exposure_s)
        rng, _ = frame_seeds(m.scenario.seed, k)
        radiance = self.radiance(k, stage)
        if k == 0:
            self.gain = m.sensor.gain_for(m.optics.apply(radiance))
        self.frames[k] = expose_frame(m, radiance, self.gain, rng)
        b, nb = self.block_px, self.n_blocks
        if k == 0:
            self.tracker = BlockTracker(self.frames[0], m.corners, b, m.correlator)
            self.ref_corners_rec[0] = m.corners
            return BlockMeasurements(0, t0 + 0.5 * m.exposure_s, np.zeros(nb, int),
                                     self.grid_centers.copy(), np.zeros((nb, 2)),
                                     np.full((nb, 2), 1e-6), np.ones(nb, bool),
                                     np.full(nb, np.inf), np.zeros(nb), np.zeros(nb, bool),
                                     np.zeros((nb, 2)), np.zeros(2))
        ref = self.ref
        if m.chain:
            step = predicted_px(m, self.grid_centers, ref, k, self.stage_mean[ref],
                                self.stage_mean[k])
            fp = m.camera.focal_plane
            self.ref_corners = chain_corners(m.corners, step, b, (fp.rows, fp.cols))[0]
            self.tracker = BlockTracker(self.frames[ref], self.ref_corners, b, m.correlator)
        elif self.tracker is None:  # resumed after a re-reference
            self.tracker = BlockTracker(self.frames[ref], self.ref_corners, b, m.correlator)
        centers = BlockTracker.centers_from(self.ref_corners, b)
        pred = predicted_px(m, centers, ref, k, self.stage_mean[ref], self.stage_mean[k])
        deform, content, field = self._prediction(centers, ref, k)
        warp = not m.chain and float(deform.max()) > WARP_MIN_PX
        todo = np.flatnonzero(blocks)
        shift = np.full((nb, 2), np.nan)
        sigma = np.full((nb, 2), np.inf)
        valid = np.zeros(nb, bool)
        peak = np.zeros(nb)
        if len(todo):
            res = self.tracker.update(self.frames[k], pred, streams.rng(m.scenario.seed,
                                                                        "optical", k),
                                      todo if len(todo) < nb else None,
                                      flow=self._flow(ref, k) if warp else None)
            shift[todo], valid[todo], peak[todo] = res.shift, res.valid, res.peak
            sigma[todo] = np.where(res.valid[:, None], res.crlb, np.inf)
        self.ref_corners_rec[k] = self.ref_corners
        # resampled through the predicted flow, a block is no longer deformed
        return BlockMeasurements(k, t0 + 0.5 * m.exposure_s, np.full(nb, ref), centers, shift,
                                 sigma, valid, peak, np.zeros(nb) if warp else deform,
                                 np.full(nb, m.chain), content, field)

    def _flow(self, ref: int, k: int) -> np.ndarray:
        """The predicted motion (B, b, b, 2) of every pixel of every reference block from
        frame ref to k (its own ground point through the DEM: relief parallax included),
        stage change included, px."""
        m, b = self.m, self.block_px
        q = np.stack(np.meshgrid(np.arange(b), np.arange(b), indexing="ij"), axis=-1)
        pix = q[None] + self.ref_corners[:, None, None, :]
        ground = self._ground_of("flow", ref, pix.reshape(-1, 2))
        mo = m.camera.image_motion_px(ground, m.frame_mid_s[k:k + 1],
                                      float(m.frame_mid_s[ref]), nominal=True)[0]
        return mo.reshape(pix.shape) - (self.stage_mean[k] - self.stage_mean[ref])

    def _ground_of(self, name: str, ref: int, pixels: np.ndarray) -> np.ndarray:
        """Ground points (N, 3) seen at reference pixels (N, 2) in frame ref (the stage it
        was exposed with included), intersected once per reference."""
        key = (ref, self.ref_corners.tobytes())
        if key != self._ground_key:
            self._ground, self._ground_key = {}, key
        if name not in self._ground:
            m = self.m
            self._ground[name] = m.camera.ground_points(pixels + self.stage_mean[ref],
                                                        float(m.frame_mid_s[ref]),
                                                        m.terrain.height_at)
        return self._ground[name]

    def _prediction(self, centers: np.ndarray, ref: int, k: int):
        """The orbit/attitude/DEM prediction (no jitter) from frame ref to k: each block's
        deformation (the largest difference between a corner's predicted motion and its
        centre's), each block's content motion, and the field point's motion, px."""
        m = self.m
        h = 0.5 * (self.block_px - 1)
        offs = np.array([[0.0, 0.0], [-h, -h], [-h, h], [h, -h], [h, h]])
        pts = np.vstack([(centers[:, None, :] + offs[None]).reshape(-1, 2),
                         np.asarray(m.field_point_px)[None]])
        ground = self._ground_of("blocks", ref, pts)
        mo = m.camera.image_motion_px(ground, m.frame_mid_s[k:k + 1],
                                      float(m.frame_mid_s[ref]), nominal=True)[0]
        blocks = mo[:-1].reshape(len(centers), 5, 2)
        deform = np.max(np.linalg.norm(blocks[:, 1:] - blocks[:, :1], axis=-1), axis=1)
        return deform, blocks[:, 0].copy(), mo[-1].copy()

    def rereference(self, k: int) -> None:
        self.ref = k
        if not self.m.chain:
            self.ref_corners = self.m.corners.copy()
            self.tracker = BlockTracker(self.frames[k], self.ref_corners, self.block_px,
                                        self.m.correlator)

    def chunk_arrays(self, start: int, stop: int) -> dict[str, np.ndarray]:
        return {"frames": self.frames[start:stop].copy(),
                "ref_corners": self.ref_corners_rec[start:stop].copy(),
                "stage_mean": self.stage_mean[start:stop].copy(),
                "ref": np.array(self.ref), "cur_corners": self.ref_corners.copy(),
                "gain": np.array(self.gain)}

    def restore(self, chunks: list[dict[str, np.ndarray]]) -> None:
        stop = 0
        for c in chunks:
            n = len(c["frames"])
            self.frames[stop:stop + n] = c["frames"]
            self.ref_corners_rec[stop:stop + n] = c["ref_corners"]
            self.stage_mean[stop:stop + n] = c["stage_mean"]
            stop += n
        last = chunks[-1]
        self.ref = int(last["ref"])
        self.ref_corners = np.asarray(last["cur_corners"], dtype=int)
        self.gain = float(last["gain"])
        self.tracker = None  # rebuilt from the reference frame at the next measurement

    def close(self) -> None:
        """Release what the image model holds."""


class RenderedPlant(TrackerPlant):
    """Every frame rendered by Mitsuba with the pose and the stage moving inside it."""

    def __init__(self, m: Models, renderer=None):
        super().__init__(m)
        if renderer is None:
            from scene.kernel import Renderer, Sun  # the Mitsuba layer, only when rendering

            fp = m.camera.focal_plane
            ceiling = float(np.min(m.camera.pose(m.frame_t_s).position_m[:, 2]))
            renderer = Renderer(m.terrain, Sun(*m.sun_deg), fp.rows, fp.cols,
                                spp=m.scenario.scene.spp, clouds=m.clouds, ceiling_m=ceiling,
                                quadrature=m.scenario.scene.quadrature)
        self.renderer = renderer
        self.render_s = 0.0

    def radiance(self, k: int, stage) -> np.ndarray:
        import time

        from scene.pinhole import ray_keyframes

        m = self.m
        t0 = float(m.frame_t_s[k])
        t1 = t0 + m.exposure_s
        t_samples, s_samples = stage.samples
        inner = (t_samples > t0) & (t_samples < t1)
        ends = stage(np.array([t0, t1]))
        bent = False
        if inner.any():  # is the stage a straight line over the exposure?
            a = (t_samples[inner] - t0) / m.exposure_s
            line = ends[0] + a[:, None] * (ends[1] - ends[0])
            bent = bool(np.max(np.abs(stage(t_samples[inner]) - line)) > 1e-6)
        times = t0 + np.linspace(0.0, m.exposure_s, KEYFRAMES_BENT if bent else KEYFRAMES)
        moving = inner.any() or not np.array_equal(ends[0], ends[1])
        offsets = stage(times) if moving else self.stage_mean[k]
        start = time.perf_counter()
        kf = ray_keyframes(m.camera.pose(times), m.camera.focal_plane, offsets,
                           self.renderer.z_start_m)
        out = self.renderer.render(kf, streams.render_seed(m.scenario.seed, k))
        self.render_s += time.perf_counter() - start
        return out


class TexturePlant(TrackerPlant):
    """The scene's albedo as the tracker sees it at t = 0 (through the camera model and the
    DEM), shown at every pixel and instant where the camera model puts it, averaged over
    ``subsamples`` instants of the exposure; flat shading (no sun, no shadows), numpy only.

    Pixel p at instant t shows the ground point the true camera (orbit, attitude, jitter)
    sees there through the DEM, at the detector position p plus the stage; the albedo image
    (:func:`base_image`) holds every ground point at its place in the t = 0 view, so the
    point is looked up there (:meth:`source_px`). Each pixel's content moves as the camera
    model moves it, relief parallax and the field's own distortion included.

    The model this replaces warped the t = 0 image by the motion of the ground point that
    pixel p saw at t = 0, a different point from the one p sees at t once the content has
    moved by thousands of pixels: on ``smallsat_pushbroom``'s chain (166 px a frame at 50 Hz)
    each frame-to-frame link erred by +0.009 / +0.022 px (row / col; the col part growing
    linearly from 0.001 to 0.044 px over 1.66 s), the bias a chained record sums into a drift.
    """

    def __init__(self, m: Models, subsamples: int = 4, margin_px: int = 16):
        from scipy.ndimage import map_coordinates, spline_filter

        super().__init__(m)
        self._map = map_coordinates
        fp = m.camera.focal_plane
        self.t0_s = float(m.frame_mid_s[0])
        self.subsamples = subsamples
        frac = (np.arange(subsamples) + 0.5) / subsamples
        self.times = (m.frame_t_s[:, None] + frac[None, :] * m.exposure_s)  # (T, S)
        rr, cc = np.mgrid[0:fp.rows, 0:fp.cols].astype(np.float64)
        self.pixels = np.stack([rr, cc], axis=-1)  # (H, W, 2)
        self.pose0 = m.camera.pose(np.asarray(self.t0_s))
        # the base image's reach: the sensor's edges' sources over the run, with margin
        edge = np.unique(np.concatenate([self.pixels[[0, -1]].reshape(-1, 2),
                                         self.pixels[:, [0, -1]].reshape(-1, 2)]), axis=0)
        ts = self.times.ravel()
        ts = ts[np.unique(np.linspace(0, len(ts) - 1, min(len(ts), 64)).astype(int))]
        src = self._sources(edge[None], ts, np.zeros((len(ts), 2)))  # (q, E, 2)
        size = np.array([fp.rows, fp.cols]) - 1
        # before the sensor's first row (col) and after its last: a scan's content comes
        # from one side only
        self.margin = np.ceil(np.maximum(-src.min(axis=(0, 1)), 0.0)).astype(int) + margin_px
        after = np.ceil(np.maximum(src.max(axis=(0, 1)) - size, 0.0)).astype(int) + margin_px
        self.base = spline_filter(base_image(m, self.margin, after), order=3)

    def _sources(self, pixels: np.ndarray, t_s: np.ndarray, stage_px: np.ndarray
                 ) -> np.ndarray:
        """Where each detector position (q, ..., 2) px at instants t_s (q,) s, with the stage
        at stage_px (q, 2), finds its ground point in the t = 0 view (q, ..., 2) px: the true
        camera's ray through the DEM, projected by frame 0's true pose."""
        m = self.m
        lead = (1,) * (pixels.ndim - 2)
        pos = pixels + stage_px.reshape(len(t_s), *lead, 2)
        pose = m.camera.pose(np.asarray(t_s, dtype=np.float64))
        pose = Pose(pose.position_m.reshape(len(t_s), *lead, 3),
                    pose.enu_from_cam.reshape(len(t_s), *lead, 3, 3))
        ground = m.camera.ground_points_posed(pose, pos, m.terrain.height_at)
        return project(ground, self.pose0, m.camera.focal_plane)

    def source_px(self, k: int, stage) -> np.ndarray:
        """The t = 0 view's position (S, H, W, 2) px of what every pixel of frame k shows at
        each of its ``subsamples`` instants, the stage trajectory ``stage`` applied: traced
        exactly on a grid of :data:`SOURCE_GRID_PX` and bilinear between (the relief's
        parallax bends it at the DEM's cells; on ``smallsat_pushbroom``'s last frames the
        interpolation errs by 1.1e-4 px RMS, 1.7e-3 px at most, against exact tracing)."""
        t = self.times[k]
        fp = self.m.camera.focal_plane
        step = SOURCE_GRID_PX
        nodes = np.stack(np.meshgrid(np.arange(0, fp.rows + step - 1, step),
                                     np.arange(0, fp.cols + step - 1, step), indexing="ij"),
                         axis=-1).astype(np.float64)
        coarse = self._sources(np.broadcast_to(nodes, (len(t), *nodes.shape)), t,
                               np.asarray(stage(t), dtype=np.float64).reshape(len(t), 2))
        h, w = fp.rows, fp.cols
        idx = np.broadcast_to(np.arange(len(t), dtype=np.float64)[:, None, None], (len(t), h, w))
        at = np.stack([idx, np.broadcast_to(self.pixels[..., 0] / step, idx.shape),
                       np.broadcast_to(self.pixels[..., 1] / step, idx.shape)]).reshape(3, -1)
        return np.stack([self._map(coarse[..., a], at, order=1, mode="nearest")
                         for a in range(2)], axis=-1).reshape(len(t), h, w, 2)

    def radiance(self, k: int, stage) -> np.ndarray:
        src = self.source_px(k, stage) + self.margin  # (S, H, W, 2), base image indices
        acc = self._map(self.base, np.moveaxis(src, -1, 0).reshape(2, -1), order=3,
                        mode="nearest", prefilter=False)
        return acc.reshape(src.shape[:-1]).mean(axis=0)


def albedo_texels(m: Models, margin_px: int | np.ndarray,
                  after_px: int | np.ndarray | None = None, texel_m: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray, float]:
    """Where every tracker pixel at t = 0 (with :func:`base_image`'s margins) falls on the
    scene's albedo (through the camera model and the DEM): its texel coordinates (row, col)
    (texel centres at integers; ``texel_m``: the albedo's texel, default the terrain's),
    and the Gaussian's sigma (texels) that smooths the albedo to the ground sample
    distance (0: none)."""
    cam, fp, terrain = m.camera, m.camera.focal_plane, m.terrain
    mr, mc = (int(v) for v in np.broadcast_to(margin_px, (2,)))
    ar, ac = (int(v) for v in np.broadcast_to(margin_px if after_px is None else after_px,
                                              (2,)))
    gr, gc = np.mgrid[-mr:fp.rows + ar, -mc:fp.cols + ac]
    pts = cam.ground_points(np.stack([gr, gc], axis=-1).astype(np.float64),
                            float(m.frame_mid_s[0]), terrain.height_at)
    gsd = float(np.median(np.linalg.norm(np.diff(pts[:, :, :2], axis=1), axis=-1)))
    texel = terrain.texel_m if texel_m is None else texel_m
    sig = max(0.0, 0.5 * gsd / texel - 0.3)
    # albedo rows run north to south (texel centres at (k + 0.5) / N, row 0 = north edge)
    half = 0.5 * np.array(terrain.size_m)
    col = (pts[..., 0] + half[0]) / texel - 0.5
    row = (half[1] - pts[..., 1]) / texel - 0.5
    return row, col, sig


def albedo_span(row: np.ndarray, col: np.ndarray, sig: float, shape: tuple[int, int]
                ) -> tuple[tuple[int, int], tuple[int, int]]:
    """The texels (rows [r0, r1), cols [c0, c1)) of an albedo of ``shape`` that
    :func:`base_image` reads at the coordinates ``row``, ``col`` (:func:`albedo_texels`):
    their bilinear neighbours and the smoothing Gaussian's reach (``sig`` texels, scipy's
    4 sigma), clipped to the tile."""
    pad = int(4.0 * sig + 0.5) if sig > 0 else 0
    out = []
    for x, n in ((row, shape[0]), (col, shape[1])):
        lo = int(np.floor(np.min(x))) - pad
        hi = int(np.floor(np.max(x))) + 2 + pad
        out.append((max(0, lo), min(n, max(1, hi))))
    return out[0], out[1]


def base_image(m: Models, margin_px: int | np.ndarray,
               after_px: int | np.ndarray | None = None,
               window: tuple[np.ndarray, float, tuple[int, int]] | None = None) -> np.ndarray:
    """The scene's albedo at every tracker pixel at t = 0 (through the camera model and the
    DEM), with ``margin_px`` (rows, cols) before the sensor's first row and column and
    ``after_px`` (default: the same) after its last; the albedo is smoothed to the ground
    sample distance first (no aliasing). Pixel (r, c) of the sensor is element
    (r + margin rows, c + margin cols). ``window``: (albedo, texel_m, (row0, col0)), the
    part of the tile's albedo from texel (row0, col0) that covers :func:`albedo_span`
    (e.g. :meth:`scene.terrain.ProceduralDraws.albedo_window`), read instead of
    ``m.terrain.albedo``: the same image within one float32 unit of the albedo's last
    place (bit for bit on the tested scenes)."""
    from scipy.ndimage import gaussian_filter, map_coordinates

    row, col, sig = albedo_texels(m, margin_px, after_px,
                                  None if window is None else window[1])
    if window is None:
        alb, (r0, c0) = m.terrain.albedo, (0, 0)
    else:
        alb, _, (r0, c0) = window
        n = np.rint(np.array(m.terrain.size_m[::-1]) / window[1]).astype(int)
        (a, b), (c, d) = albedo_span(row, col, sig, (int(n[0]), int(n[1])))
        if a < r0 or c < c0 or b > r0 + alb.shape[0] or d > c0 + alb.shape[1]:
            raise ValueError(f"base_image: the albedo window rows [{r0}, "
                             f"{r0 + alb.shape[0]}), cols [{c0}, {c0 + alb.shape[1]}) does "
                             f"not cover the texels read, rows [{a}, {b}), cols [{c}, {d})")
    if sig > 0:
        alb = gaussian_filter(alb, sig, mode="nearest")
    return map_coordinates(alb, [row - r0, col - c0], order=1, mode="nearest")


def predicted_sigma_px(m: Models, fill: bool = True,
                       radiance: np.ndarray | None = None, with_psr: bool = False):
    """The correlator's predicted 1-sigma error (B, 2) px on this scene: frame 0's content
    (flat shading; or ``radiance``, e.g. a rendered frame 0) exposed twice with independent
    noise, block against block; a block the correlator refuses gets the others' median
    (``fill``; 0.05 px when it refuses every block) or NaN. ``with_psr``: also each block's
    PSR (B,) (``fill`` False only)."""
    rad = base_image(m, 0) if radiance is None else radiance
    gain = m.sensor.gain_for(m.optics.apply(rad))
    a = expose_frame(m, rad, gain, streams.rng(m.scenario.seed, "texture", 0))
    b = expose_frame(m, rad, gain, streams.rng(m.scenario.seed, "texture", 1))
    bp = m.scenario.correlator.block_px
    tracker = BlockTracker(a, m.corners, bp, m.correlator)
    res = tracker.correlator.measure(extract_blocks(b, m.corners, bp))
    crlb = np.where(res.valid[:, None], res.crlb, np.nan)
    if not fill:
        return (crlb, np.asarray(res.peak, float)) if with_psr else crlb
    if not np.isfinite(crlb).any():
        return np.full((len(m.corners), 2), 0.05)
    return np.where(np.isfinite(crlb), crlb, np.nanmedian(crlb))


#: the focal-plane offsets (row, col) px at which :func:`render_floor_px` renders one pose:
#: sub-pixel phases apart, so a pair's error holds the pixel quadrature's phase dependence
FLOOR_OFFSETS_PX = ((0.0, 0.0), (0.5, 0.25), (0.25, 0.5))


def render_pose(m: Models, frame: int = 0, offsets_px=((0.0, 0.0),),
                plant: RenderedPlant | None = None) -> np.ndarray:
    """Frame ``frame``'s pose rendered once per focal-plane offset ``offsets_px`` (n, 2) px
    (the stage held there over the exposure): the radiance (n, rows, cols) before the optics
    and the sensor, each render with its own sampler seed (members of the 'render' stream
    past any frame's). The scene as the rendered tracker sees it, shading and sky included
    (the analytic plant's :func:`predicted_sigma_px` takes it as ``radiance``). ``plant``: a
    run's plant, whose renderer is reused (and left open); None: one is built and closed."""
    from scene.pinhole import ray_keyframes

    offsets = np.atleast_2d(np.asarray(offsets_px, dtype=np.float64))
    fp = m.camera.focal_plane
    t0 = float(m.frame_t_s[frame])
    poses = m.camera.pose(t0 + np.linspace(0.0, m.exposure_s, KEYFRAMES))
    n = len(m.frame_t_s)
    own = plant is None
    if own:
        plant = RenderedPlant(m)
    try:
        return np.stack([plant.renderer.render(
            ray_keyframes(poses, fp, offsets[i], plant.renderer.z_start_m),
            streams.render_seed(m.scenario.seed, n + i)) for i in range(len(offsets))])
    finally:
        if own:
            plant.close()


def render_floor_px(m: Models, seeds: int = 3, frame: int = 0,
                    plant: RenderedPlant | None = None) -> np.ndarray:
    """The rendered tracker's pixel-integration floor (2,) px (row, col): frame ``frame``'s
    pose rendered ``seeds`` times (<= 3), each with its own sampler seed (members of the
    'render' stream past any frame's) and its own sub-pixel focal-plane offset
    (:data:`FLOOR_OFFSETS_PX`), at the scene's samples a pixel and without the sensor's noise;
    every pair correlated by the default digital correlator on a grid of non-overlapping
    blocks, its error taken about the offsets' known difference; the RMS over blocks and
    pairs. The content is the same, so the
    error is what the renderer's pixel integration adds to a link: its Monte Carlo noise
    (falling as 1 / sqrt(samples a pixel); none with the default fixed quadrature) and the
    quadrature's dependence on the content's sub-pixel phase (with the scene's own aliasing,
    which a detector shares). What the reported bound leaves out of a rendered link
    (:class:`compensation.analytic_plant.AnalyticPlant`'s ``floor_px``). ``plant``: a run's
    plant, whose renderer is reused (and left open); None: one is built and closed."""
    from itertools import combinations

    if not 2 <= seeds <= len(FLOOR_OFFSETS_PX):
        raise ValueError(f"seeds must be 2 .. {len(FLOOR_OFFSETS_PX)}, got {seeds}")
    offsets = np.asarray(FLOOR_OFFSETS_PX[:seeds], dtype=np.float64)
    imgs = [m.optics.apply(r) for r in render_pose(m, frame, offsets, plant)]
    fp, bp = m.camera.focal_plane, m.scenario.correlator.block_px
    corners = np.stack(np.meshgrid(np.arange(0, fp.rows - bp + 1, bp),
                                   np.arange(0, fp.cols - bp + 1, bp), indexing="ij"),
                       axis=-1).reshape(-1, 2)
    errs = []
    for i, j in combinations(range(seeds), 2):
        # the default digital correlator: the scenario's own (e.g. an optical one's centre of
        # mass) adds its own phase bias, which is the correlator's, not the renderer's
        res = BlockTracker(imgs[i], corners, bp, CorrelatorOptions()).update(
            imgs[j], np.zeros((len(corners), 2)))
        # a stage offset of +d px moves the content by -d px on the focal plane
        err = res.shift + (offsets[j] - offsets[i])
        errs.append(np.where(res.valid[:, None], err, np.nan))
    return np.sqrt(np.nanmean(np.concatenate(errs) ** 2, axis=0))


#: the renderer's pixel-integration floor, as a fraction of the correlator's median bound,
#: above which a rendered run warns (sqrt(1 + 0.5^2) = 1.12: the tracker's error 12 %
#: pessimistic)
RENDER_FLOOR_WARN = 0.5


def render_floor_check(m: Models, plant: RenderedPlant, crlb_px) -> tuple[dict, str | None]:
    """The rendered tracker's pixel-integration floor (:func:`render_floor_px` on the run's own
    renderer) against the correlator's median bound ``crlb_px`` (2,) px: the figures for
    metrics.json's ``tracker.render_floor`` and, when the floor exceeds
    :data:`RENDER_FLOOR_WARN` of the bound on either axis, one line naming ``scene.spp``
    and the samples a pixel that would bring it there if it fell as 1 / sqrt(samples a pixel)
    (Monte Carlo noise does; the fixed quadrature's phase error falls about as fast or faster,
    measured 1.5-6.5x from 4 to 16 samples; the scene's own aliasing, which a detector shares,
    does not). A detector integrates its pixel exactly: the rest is the simulation's, not the
    camera's, and the rendered tracker's error is pessimistic by up to
    sqrt(1 + (floor / bound)^2)."""
    floor = render_floor_px(m, plant=plant)
    crlb = np.asarray(crlb_px, dtype=np.float64)
    ratio = floor / np.where(crlb > 0, crlb, np.nan)
    spp = int(m.scenario.scene.spp)
    quad = bool(m.scenario.scene.quadrature)
    info = {"floor_px": [float(x) for x in floor], "over_crlb": [float(x) for x in ratio],
            "spp": spp, "quadrature": quad}
    worst = float(np.nanmax(ratio)) if np.any(np.isfinite(ratio)) else 0.0
    if not worst > RENDER_FLOOR_WARN:
        return info, None
    need = int(np.ceil(spp * (worst / RENDER_FLOOR_WARN) ** 2))
    how = "fixed-quadrature" if quad else "Monte Carlo"
    return info, (f"scene.spp = {spp}: the renderer's {how} pixel integration adds "
                  f"{floor[0]:.4f} / {floor[1]:.4f} px (row / col) to each tracker link, "
                  f"{worst:.2f}x the correlator's bound; a detector integrates its pixel "
                  f"exactly, so the rendered tracker's figures are pessimistic by up to "
                  f"{np.sqrt(1.0 + worst ** 2):.2f}x; scene.spp >= {need} brings it below "
                  f"{RENDER_FLOOR_WARN:g}x if it falls as 1 / sqrt(spp) (the scene's own "
                  f"aliasing, which a detector shares, does not fall)")


def analytic_plant(m: Models, sigma_px, floor_px=0.0, efficiency=1.0) -> AnalyticPlant:
    """Measurements = the camera model's true block shifts + noise of ``sigma_px`` (and of
    ``floor_px``, px, that the reported sigma leaves out: e.g. :func:`render_floor_px`; the
    bound's part drawn at ``efficiency`` times it)."""
    cam = m.camera
    t0 = float(m.frame_mid_s[0])
    centers = BlockTracker.centers_from(m.corners, m.scenario.correlator.block_px)
    pts = np.vstack([centers, np.asarray(m.field_point_px)[None]])
    ground = cam.ground_points(pts, t0, m.terrain.height_at)

    def motion(t: np.ndarray) -> np.ndarray:
        return cam.image_motion_px(ground[:-1], t, t0)

    def nominal(t: np.ndarray) -> np.ndarray:
        return cam.image_motion_px(ground[:-1], t, t0, nominal=True)

    def field_nominal(t: np.ndarray) -> np.ndarray:
        return cam.image_motion_px(ground[-1:], t, t0, nominal=True)[:, 0]

    zero = np.zeros(2)

    def between(r: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The chain's prediction from frame r to k of the content under the blocks and the
        field point in frame r (as the image plants predict it)."""
        mo = predicted_px(m, pts, r, k, zero, zero)
        return mo[:-1], mo[-1]

    bp = m.scenario.correlator.block_px
    fp = m.camera.focal_plane

    def pair_regions(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The blocks of the pair (a, b) as the image plants cut them inside the sensor's
        margin: reference corners, current corners, used."""
        step = predicted_px(m, centers, a, b, zero, zero)
        ref, used = pair_corners(m.corners, step, bp, np.array([fp.rows - bp, fp.cols - bp]))
        return ref, ref + np.rint(step).astype(int), used

    return AnalyticPlant(motion, centers, sigma_px, m.frame_t_s, m.exposure_s,
                         seed=tuple(streams.key(m.scenario.seed, "analytic")),
                         samples=m.scenario.metrics.samples_per_frame, nominal_px=nominal,
                         field_nominal_px=field_nominal, chain=m.chain,
                         predict_between=between if m.chain else None,
                         pair_regions=pair_regions if m.chain else None,
                         frame_shape=(fp.rows, fp.cols), block_px=bp, floor_px=floor_px,
                         efficiency=efficiency)


def efficiency_on_scene(m: Models, radiance: np.ndarray | None = None,
                          draws: int = 24) -> dict:
    """The correlator's error against its own bound on this scene: frame 0's content (the
    flat-shaded albedo, :func:`base_image`, or ``radiance``, e.g. :func:`render_pose`'s)
    exposed in ``draws`` pairs of independent sensor-noise draws (the 'texture' stream's
    members past the two :func:`predicted_sigma_px` uses), every block of a grid of
    non-overlapping blocks of the scenario's size, true shift 0. Returns ``over_crlb`` (2,)
    (RMS error / RMS bound per axis, what :func:`analytic_plant` takes as ``efficiency``;
    NaN where no block is valid), ``rms_px``, ``crlb_px`` and ``blocks``, the valid block
    measurements over all draws."""
    rad = base_image(m, 0) if radiance is None else radiance
    gain = m.sensor.gain_for(m.optics.apply(rad))
    fp, bp = m.camera.focal_plane, m.scenario.correlator.block_px
    corners = np.stack(np.meshgrid(np.arange(0, fp.rows - bp + 1, bp),
                                   np.arange(0, fp.cols - bp + 1, bp), indexing="ij"),
                       axis=-1).reshape(-1, 2)
    err, crlb = [], []
    for i in range(draws):
        a = expose_frame(m, rad, gain, streams.rng(m.scenario.seed, "texture", 2 + 2 * i))
        b = expose_frame(m, rad, gain, streams.rng(m.scenario.seed, "texture", 3 + 2 * i))
        res = BlockTracker(a, corners, bp, m.correlator).correlator.measure(
            extract_blocks(b, corners, bp))
        err.append(np.where(res.valid[:, None], res.shift, np.nan))
        crlb.append(np.where(res.valid[:, None], res.crlb, np.nan))
    e, c = np.concatenate(err), np.concatenate(crlb)
    rms, bound = np.sqrt(np.nanmean(e ** 2, axis=0)), np.sqrt(np.nanmean(c ** 2, axis=0))
    return {"blocks": int(np.isfinite(e[:, 0]).sum()), "rms_px": rms.tolist(),
            "crlb_px": bound.tolist(), "over_crlb": (rms / bound).tolist()}


def noise_tile_models(m: Models, texel_m: float) -> Models:
    """The models of the tile that ``plant.noise_texel_m`` asks the analytic plant's noise to
    be predicted on: the scenario's camera, orbit, attitude, tracker and scene kind, relief,
    DEM spacing and sun, over the first three tracker frames (a pass that short is over the
    scene's centre, as the whole run's pass is over it mid-run), on a tile of ``texel_m``
    texels around the centre, 3x the side of the ground the tracker sees in a frame plus
    four DEM cells (at least 256 m, at most the scene's own side), without the main
    imager's product."""
    fp = m.camera.focal_plane
    corners = np.array([[0.0, 0.0], [0.0, fp.cols - 1.0], [fp.rows - 1.0, 0.0],
                        [fp.rows - 1.0, fp.cols - 1.0]])
    pts = m.camera.ground_points(corners, float(m.frame_t_s[0]), m.terrain.height_at)
    span = float(np.max(np.ptp(pts[:, :2], axis=0)))
    sc = m.scenario
    d = sc.model_dump(mode="json", exclude={"expect"})
    dem = float(sc.scene.dem_spacing_m)
    side = float(np.clip(dem * np.ceil((3.0 * span + 4.0 * dem) / dem), 256.0, sc.scene.size_m))
    side = min(dem * np.ceil(side / dem), sc.scene.size_m)  # a whole number of DEM cells
    d["duration_s"] = 3.0 / float(sc.camera.tracker.frame_rate_hz)
    d["scene"].update(size_m=side, texel_m=float(texel_m))
    d["camera"]["main_imager"]["start_s"] = 0.0
    d["product"] = {"enabled": False}
    d["plant"] = {"fidelity": "rendered"}
    return build_models(parse_scenario(d))


def rendered_noise(m: Models) -> dict:
    """The analytic plant's noise as the rendered tracker has it (``plant.noise:
    rendered``): frame 0 rendered once (:func:`render_pose`; on :func:`noise_tile_models`'
    tile when ``plant.noise_texel_m`` is set), the correlator's bound on it (``sigma_px``
    (B, 2), :func:`predicted_sigma_px`), its efficiency there (``efficiency`` (2,),
    :func:`efficiency_on_scene`) and the renderer's floor (``floor_px`` (2,),
    :func:`render_floor_px`), one renderer for all: :func:`analytic_plant`'s arguments."""
    texel = m.scenario.plant.noise_texel_m
    if texel is not None:
        m = noise_tile_models(m, texel)
    renderer = RenderedPlant(m)
    try:
        rad = render_pose(m, plant=renderer)[0]
        sigma = predicted_sigma_px(m, fill=False, radiance=rad)
        if np.isfinite(sigma).any():
            floor = render_floor_px(m, plant=renderer)
            eff = np.asarray(efficiency_on_scene(m, rad)["over_crlb"])
    finally:
        renderer.close()
    if not (np.isfinite(sigma).any() and np.all(np.isfinite(floor))
            and np.all(np.isfinite(eff))):
        raise ScenarioError(
            f"plant.noise: the correlator accepts too few of the {len(sigma)} blocks of frame "
            f"0 as rendered (texels of {m.scenario.scene.texel_m:g} m: too little texture at "
            "the tracker's pixels); use plant.noise 'albedo', set plant.sigma_px, or finer "
            "texels (scene.texel_m, or plant.noise_texel_m for the noise alone)")
    return {"sigma_px": np.where(np.isfinite(sigma), sigma, np.nanmedian(sigma, axis=0)),
            "floor_px": floor, "efficiency": eff}


def build_plant(m: Models):
    """The plant of the scenario's ``plant.fidelity``; an analytic one's noise from
    ``plant.sigma_px``, else predicted on the scene of ``plant.noise``."""
    fid = m.scenario.plant.fidelity
    if fid == "rendered":
        return RenderedPlant(m)
    if fid == "texture":
        return TexturePlant(m)
    sigma = m.scenario.plant.sigma_px
    if sigma is not None:
        return analytic_plant(m, sigma)
    if m.scenario.plant.noise == "rendered":
        return analytic_plant(m, **rendered_noise(m))
    return analytic_plant(m, predicted_sigma_px(m))

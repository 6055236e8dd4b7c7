"""The main imager's product as a Level-1 product: RPCs fitted to the geometry the ground
knows, orthorectification through GDAL's RPC transformer with the scene's DEM, and the
geolocation in metres at check points whose true ground positions the camera model gives.

1. :class:`MapFrame`: the scene's map frame (a transverse Mercator centred on the scene,
   the product's georeference) beside WGS84 (longitude, latitude, height above the
   ellipsoid) and the scene's ENU frame, converted exactly through ECEF (pyproj for the
   projection).
2. :func:`fit_version_rpcs`: one RPC00B fit (:func:`ground.rpc.fit_rpc`) to the **nominal**
   lines of sight (:func:`camera.linescan.pixel_ground_m`, the nominal pose, no stage) over
   a grid of product pixels and layers of constant height above the ellipsoid spanning the
   scene's DEM; a raw version (static, open, closed) carries it as it is: the jitter the
   ground does not know shows as geolocation error, as in real products. A ground-corrected
   version is on the nominal grid displaced by its constant ``shift_px``
   (:func:`imc.wiring.product.ground_versions`): its RPC is the same fit with its offsets
   moved by that constant (:func:`ground.rpc.shifted`). The fit is judged at independent
   points between the grid's nodes and layers.
3. :func:`scene_dem`: the scene's terrain as heights above the ellipsoid on a map grid
   whose nodes are the terrain's own DEM nodes (what GDAL's ``RPC_DEM`` expects).
4. :func:`level1_study`: every version of the scene orthorectified onto one map grid of one
   GSD (:func:`ground.ortho.orthorectify`), with two coordinate rasters (line, column) warped
   in the same call: at each check point (a regular subset of the map cells) they say which
   product pixel GDAL put there, and the camera model says where that pixel's content truly
   lies (the version's own pose, stage and, for a corrected version, the resampling's source
   pixel). The error ``X - X_true`` gives CE90, the mean, the relative accuracy; the same
   from the lines' true offsets alone (``from_lines``: where the nominal model puts the
   pixel the content belongs to) checks it; each version's misregistration against the
   static by phase correlation of the orthoimages.

A long strip is orthorectified over its middle :data:`ORTHO_LINES` lines (all its columns).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from imc.wiring.build import Models

#: RPC fitting grid: image nodes per axis (at least), height layers, the height margin (m)
RPC_NODES = 21
RPC_LAYERS = 7
HEIGHT_MARGIN_M = 10.0
#: the longest stretch of lines orthorectified (the middle of a longer strip)
ORTHO_LINES = 1024
#: check points per map axis (a regular subset of the ortho's cells)
CHECK_POINTS = 24
#: product pixels kept away from the edges for check points (GDAL's interpolation support)
EDGE_PX = 3


@dataclass(frozen=True)
class MapFrame:
    """The scene's map frame: ``crs`` (a transverse Mercator centred on the scene, metres),
    and the scene's ENU ``frame`` (origin on the ellipsoid)."""

    frame: object
    crs: str

    @classmethod
    def of(cls, m: Models) -> MapFrame:
        sc = m.scenario.scene
        crs = (f"+proj=tmerc +lat_0={sc.center_lat_deg} +lon_0={sc.center_lon_deg} +k=1 "
               "+x_0=0 +y_0=0 +ellps=WGS84 +units=m")
        return cls(m.main_camera.frame, crs)

    @cached_property
    def _transformer(self):
        from pyproj import Transformer

        return Transformer.from_crs("EPSG:4326", self.crs, always_xy=True)

    def _proj(self):
        return self._transformer

    def geodetic(self, enu_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lon, lat deg, height above the ellipsoid m) of ENU points (..., 3)."""
        from orbit.frames import ecef_to_geodetic

        lat, lon, h = ecef_to_geodetic(self.frame.enu_to_ecef(enu_m))
        return lon, lat, h

    def xy(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Map coordinates (..., 2) (x east, y north) m of WGS84 longitudes / latitudes."""
        lon, lat = np.broadcast_arrays(np.asarray(lon, float), np.asarray(lat, float))
        x, y = self._proj().transform(lon.ravel(), lat.ravel())
        return np.stack([x, y], axis=-1).reshape(lon.shape + (2,))

    def lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 (lon, lat) deg of map coordinates."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        lon, lat = self._proj().transform(x.ravel(), y.ravel(), direction="INVERSE")
        return np.reshape(lon, x.shape), np.reshape(lat, x.shape)

    def xy_of_enu(self, enu_m: np.ndarray) -> np.ndarray:
        """Map coordinates (..., 2) m of ENU points (..., 3)."""
        lon, lat, _ = self.geodetic(enu_m)
        return self.xy(lon, lat)

    def layer(self, h_m: float):
        """The surface of constant height ``h_m`` above the ellipsoid as an ENU height
        function up(E, N) m (for :func:`camera.motion.intersect_terrain`)."""

        def up(east, north):
            e, n = np.broadcast_arrays(np.asarray(east, float), np.asarray(north, float))
            u = np.full(e.shape, float(h_m))
            for _ in range(2):  # dh/du = 1 - O(1e-6) over a scene: 1e-11 m after two
                _, _, hh = self.geodetic(np.stack([e, n, u], axis=-1))
                u = u + (h_m - hh)
            return u

        return up


def _truth_fn(m: Models, plan, stage, nominal: bool, samples: int):
    """(lines, product cols) -> the ENU ground points (N, 3) of their content on the
    terrain, for one raw version (its pose and stage)."""
    from camera.linescan import pixel_ground_m

    smp = plan.imager.sampling(samples)
    c0 = float(plan.cols[0])

    def at(lines, cols):
        return pixel_ground_m(m.main_camera, plan.imager, smp, plan.t0_s, lines,
                              np.asarray(cols, float) + c0, m.terrain.height_at, stage,
                              nominal)

    return at


@dataclass(frozen=True)
class DemGrid:
    """The scene's DEM as GDAL reads it: heights above the ellipsoid (H, W) m, the affine
    (pixel corners; the pixel centres on the terrain's DEM nodes) and the CRS."""

    heights_m: np.ndarray
    transform: object
    crs: str


def scene_dem(m: Models, mf: MapFrame, box_xy_m: tuple[float, float, float, float]
              ) -> DemGrid:
    """The terrain under the map box (x0, y0, x1, y1) m (plus two nodes) as heights above
    the ellipsoid on the terrain's own DEM nodes: for each node the terrain point whose map
    position it is (three fixed-point steps from ENU = map) and that point's height."""
    from affine import Affine

    t = m.terrain
    s = t.dem_spacing_m
    w, h = t.size_m
    x0, y0, x1, y1 = box_xy_m
    # node k of the terrain sits at -w/2 + k s (east), h/2 - k s (north)
    c0, c1 = np.floor((x0 + w / 2) / s) - 2, np.ceil((x1 + w / 2) / s) + 2
    r0, r1 = np.floor((h / 2 - y1) / s) - 2, np.ceil((h / 2 - y0) / s) + 2
    xs = -w / 2 + np.arange(c0, c1 + 1) * s
    ys = h / 2 - np.arange(r0, r1 + 1) * s
    gx, gy = np.meshgrid(xs, ys)
    e, n = gx.copy(), gy.copy()
    for _ in range(3):
        p = np.stack([e, n, t.height_at(e, n)], axis=-1)
        xy = mf.xy_of_enu(p)
        e, n = e + gx - xy[..., 0], n + gy - xy[..., 1]
    _, _, hh = mf.geodetic(np.stack([e, n, t.height_at(e, n)], axis=-1))
    return DemGrid(hh, Affine(s, 0.0, xs[0] - s / 2, 0.0, -s, ys[0] + s / 2), mf.crs)


@dataclass(frozen=True)
class RpcGeometry:
    """The nominal fit and the heights it spans."""

    fit: object
    height_range_m: tuple[float, float]
    points: int


def fit_nominal_rpc(m: Models, plan, samples: int, mf: MapFrame, dem: DemGrid
                    ) -> RpcGeometry:
    """The RPC fitted to the nominal lines of sight of the whole product over the DEM's
    height range (plus :data:`HEIGHT_MARGIN_M`), judged at the points between its nodes."""
    from camera.linescan import pixel_ground_m
    from ground.rpc import fit_rpc

    smp = plan.imager.sampling(samples)
    c0 = float(plan.cols[0])
    lo = float(dem.heights_m.min()) - HEIGHT_MARGIN_M
    hi = float(dem.heights_m.max()) + HEIGHT_MARGIN_M
    n_l = int(np.clip(plan.n_lines // 256, RPC_NODES, 101))  # a cubic along the orbit
    lines = np.linspace(0.0, plan.n_lines - 1, n_l)
    cols = np.linspace(0.0, len(plan.cols) - 1, RPC_NODES)
    heights = np.linspace(lo, hi, RPC_LAYERS)

    def grid(li, ci, hs):
        out = []
        ll, cc = (a.ravel() for a in np.meshgrid(li, ci, indexing="ij"))
        for hgt in hs:
            g = pixel_ground_m(m.main_camera, plan.imager, smp, plan.t0_s, ll, cc + c0,
                               mf.layer(hgt), None, True)
            lon, lat, h = mf.geodetic(g)
            out.append((lon, lat, h, ll, cc))
        return [np.concatenate(x) for x in zip(*out, strict=True)]

    fit_pts = grid(lines, cols, heights)
    check = grid(0.5 * (lines[1:] + lines[:-1]), 0.5 * (cols[1:] + cols[:-1]),
                 0.5 * (heights[1:] + heights[:-1]))
    return RpcGeometry(fit_rpc(*fit_pts, check=tuple(check)), (lo, hi), len(fit_pts[0]))


@dataclass(frozen=True)
class Level1:
    """The Level-1 results: RPC per version (:class:`rasterio.rpc.RPC`), the nominal fit's
    figures, the orthoimages per version on one map grid (``ortho_transform``, ``crs``),
    the lines orthorectified, the DEM, geolocation figures per version (a dict each), the
    check points' map positions (N, 2) and errors per version (N, 2) m."""

    rpcs: dict
    fit: dict
    ortho: dict
    ortho_transform: tuple
    crs: str
    ortho_lines: tuple[int, int]
    dem: DemGrid
    geolocation: dict
    check_xy_m: np.ndarray
    errors_m: dict
    seconds: float


def _ortho_window(plan) -> slice:
    """The product lines orthorectified: all, or a long strip's middle :data:`ORTHO_LINES`."""
    n = min(plan.n_lines, max(len(plan.cols), ORTHO_LINES))
    a = (plan.n_lines - n) // 2
    return slice(a, a + n)


@dataclass(frozen=True)
class MapGrid:
    """A north-up grid of square ``cell_m`` cells in the map frame: its upper-left corner
    (``x0_m``, ``y1_m``) and ``shape`` (rows, cols)."""

    x0_m: float
    y1_m: float
    cell_m: float
    shape: tuple[int, int]

    @property
    def transform(self):
        from affine import Affine

        return Affine(self.cell_m, 0.0, self.x0_m, 0.0, -self.cell_m, self.y1_m)

    @property
    def box_m(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1), m."""
        h, w = self.shape
        return (self.x0_m, self.y1_m - h * self.cell_m, self.x0_m + w * self.cell_m,
                self.y1_m)

    def centres_m(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Map positions (N, 2) of cell centres (rows, cols)."""
        return np.column_stack([self.x0_m + (cols + 0.5) * self.cell_m,
                                self.y1_m - (rows + 0.5) * self.cell_m])


def _map_grid(mf: MapFrame, static_at, n_c: int, win: slice, cell_m: float) -> MapGrid:
    """The grid over the window's nominal footprint on the terrain, snapped to the cell."""
    n = win.stop - win.start
    edge_l = np.r_[np.full(n_c, win.start), np.full(n_c, win.stop - 1),
                   np.arange(win.start, win.stop), np.arange(win.start, win.stop)]
    edge_c = np.r_[np.arange(n_c), np.arange(n_c), np.zeros(n), np.full(n, n_c - 1)]
    foot = mf.xy_of_enu(static_at(edge_l.astype(float), edge_c.astype(float)))
    x0, y0 = np.floor(foot.min(axis=0) / cell_m) * cell_m
    x1, y1 = np.ceil(foot.max(axis=0) / cell_m) * cell_m
    return MapGrid(float(x0), float(y1), float(cell_m),
                   (int(round((y1 - y0) / cell_m)), int(round((x1 - x0) / cell_m))))


def _orthorectify_versions(products: dict, rpcs: dict, win: slice, grid: MapGrid,
                           dem_path: str, crs: str) -> tuple[dict, dict]:
    """({version: orthoimage}, {version: (2, rows, cols) the product's line and column each
    cell shows}): the versions sharing an RPC and a coverage in one warp, the coordinate
    rasters beside their images."""
    from ground.ortho import orthorectify
    from ground.rpc import shifted

    n_l, n_c = next(iter(products.values())).shape
    ll, cc = np.mgrid[win.start:win.stop, 0:n_c].astype(np.float64)
    groups: dict = {}
    for name, image in products.items():
        img = np.asarray(image, dtype=np.float64)[win]
        key = (rpcs[name].line_off, rpcs[name].samp_off, np.isfinite(img).tobytes())
        groups.setdefault(key, []).append((name, img))
    ortho, coords = {}, {}
    for members in groups.values():
        ok = np.isfinite(members[0][1])
        bands = [img for _, img in members] + [np.where(ok, ll, np.nan),
                                               np.where(ok, cc, np.nan)]
        # the window's rows as the RPC counts them: from the product's line 0
        rpc_w = shifted(rpcs[members[0][0]], float(win.start), 0.0)
        out = orthorectify(np.stack(bands), rpc_w, dem_path, grid.transform, grid.shape, crs)
        for i, (name, _) in enumerate(members):
            ortho[name], coords[name] = out[i], out[-2:]
    return ortho, coords


def _check_points(grid: MapGrid, mf: MapFrame, rpcs: dict, coords: dict, dem_path: str,
                  shape: tuple[int, int]) -> tuple[np.ndarray, dict, float]:
    """(map positions (N, 2), {version: product pixels (2, N)}, the warper's largest
    deviation from the transformer, px) of the check points: a regular subset of the cells
    inside every version's ortho and :data:`EDGE_PX` inside its product; their pixels from
    GDAL's RPC transformer itself."""
    from ground.ortho import rpc_pixels

    ys = np.linspace(0, grid.shape[0] - 1, CHECK_POINTS).round().astype(int)
    xs = np.linspace(0, grid.shape[1] - 1, CHECK_POINTS).round().astype(int)
    gy, gx = (a.ravel() for a in np.meshgrid(ys, xs, indexing="ij"))
    xy = grid.centres_m(gy, gx)
    lon, lat = mf.lonlat(xy[:, 0], xy[:, 1])
    pix = {n: rpc_pixels(r, lon, lat, dem_path).T for n, r in rpcs.items()}
    ok = np.ones(len(gy), bool)
    for name, lc in pix.items():
        ok &= (np.isfinite(coords[name][:, gy, gx]).all(axis=0)
               & np.all((lc >= EDGE_PX) & (lc <= np.array(shape)[:, None] - 1 - EDGE_PX),
                        axis=0))
    if not ok.any():
        raise ValueError("level1: no check point lies inside every version's ortho")
    warp = max(float(np.max(np.abs(coords[n][:, gy[ok], gx[ok]] - lc[:, ok])))
               for n, lc in pix.items())
    return xy[ok], {n: lc[:, ok] for n, lc in pix.items()}, warp


def level1_study(m: Models, plan, versions, ground, samples: int, cell_m: float) -> Level1:
    """Step 6: RPCs, orthoimages and geolocation of every version of the scene (the module
    docstring): ``versions`` (:class:`imc.wiring.product.Versions`) and ``ground``
    (:class:`imc.wiring.product.Ground`: the products, their applied offsets and constant
    shifts); the map grid's cell ``cell_m`` m (the product's GSD)."""
    import time

    from scipy.ndimage import map_coordinates

    from ground.ortho import dem_dataset, geolocation, misregistration_m
    from ground.rectify import source_coordinates
    from ground.rpc import shifted

    t0 = time.perf_counter()
    mf = MapFrame.of(m)
    n_l, n_c = plan.n_lines, len(plan.cols)
    win = _ortho_window(plan)
    static_at = _truth_fn(m, plan, None, True, samples)
    grid = _map_grid(mf, static_at, n_c, win, cell_m)
    dem = scene_dem(m, mf, grid.box_m)
    nominal = fit_nominal_rpc(m, plan, samples, mf, dem)
    products = {n: img for (s, n), img in ground.products.items() if s == "scene"}
    rpcs = {}
    for name in products:  # a corrected version: the nominal grid displaced by its shift
        sh = ground.shift_px[name.split("_gc")[0]] if "_gc" in name else np.zeros(2)
        rpcs[name] = shifted(nominal.fit.rpc, float(sh[0]), float(sh[1]))
    with dem_dataset(dem.heights_m, dem.transform, dem.crs) as dem_path:
        ortho, coords = _orthorectify_versions(products, rpcs, win, grid, dem_path, mf.crs)
        check_xy, pix, warp_px = _check_points(grid, mf, rpcs, coords, dem_path, (n_l, n_c))
    raw_truth = {n: _truth_fn(m, plan, versions.stage[n], versions.nominal[n], samples)
                 for n in versions.names}
    sources: dict = {}
    geo, errors = {}, {}
    for name, lc in pix.items():
        base = name.split("_gc")[0]
        if "_gc" in name:  # the corrected pixel's source in the raw product
            if base not in sources:
                off = ground.offsets["record"][base] - ground.shift_px[base]
                sources[base] = source_coordinates(off, (n_l, n_c))
            lc = np.stack([map_coordinates(s, lc, order=1, mode="nearest")
                           for s in sources[base]])
        errors[name] = check_xy - mf.xy_of_enu(raw_truth[base](lc[0], lc[1]))
        geo[name] = geolocation(errors[name]).to_dict()
        if name != "static":
            geo[name]["misregistration_m"] = list(misregistration_m(
                ortho["static"], ortho[name], grid.cell_m))
    for name in versions.names[1:]:  # the lines' true offsets in metres
        lc, off = pix[name], ground.offsets["true"][name]
        d = np.column_stack([np.interp(lc[0], np.arange(n_l), off[:, k]) for k in range(2)])
        pred = (mf.xy_of_enu(static_at(lc[0], lc[1]))
                - mf.xy_of_enu(static_at(lc[0] + d[:, 0], lc[1] + d[:, 1])))
        g = geolocation(pred)
        geo[name]["from_lines"] = {"ce90_m": g.ce90_m, "mean_m": list(g.mean_m),
                                   "rms_difference_m": float(np.sqrt(np.mean(
                                       np.sum((pred - errors[name]) ** 2, axis=1))))}
    fit = nominal.fit.to_dict() | {"points": nominal.points, "warp_deviation_px": warp_px}
    return Level1(rpcs, fit, ortho, tuple(grid.transform)[:6], mf.crs, (win.start, win.stop),
                  dem, geo, check_xy, errors, time.perf_counter() - t0)


def add_level1(ds, l1: Level1):
    """The product's labelled result with the Level-1 results added: ``ortho`` (version,
    map_y, map_x) on the map grid, ``dem_m`` (dem_y, dem_x), the check points
    (``check_xy_m``, ``check_error_m`` per version), and in ``attrs`` the RPC per version
    (``rpc``: GDAL's keys), the map grid (``ortho_transform``, ``ortho_crs``,
    ``ortho_lines``), the DEM's affine and the figures (``geolocation``)."""
    names = [str(n) for n in ds.version.values]
    ds = ds.assign(
        ortho=(("version", "map_y", "map_x"),
               np.stack([l1.ortho[n] for n in names]).astype(np.float32)),
        dem_m=(("dem_y", "dem_x"), l1.dem.heights_m),
        check_xy_m=(("check", "en"), l1.check_xy_m),
        check_error_m=(("version", "check", "en"), np.stack([l1.errors_m[n] for n in names])))
    ds.attrs["rpc"] = {n: l1.rpcs[n].to_gdal() for n in names}
    ds.attrs["ortho_transform"] = list(l1.ortho_transform)
    ds.attrs["ortho_crs"] = l1.crs
    ds.attrs["dem_transform"] = list(tuple(l1.dem.transform)[:6])
    ds.attrs["geolocation"] = {
        "rpc_fit": l1.fit, "ortho_lines": list(l1.ortho_lines),
        "cell_m": float(l1.ortho_transform[0]), "check_points": int(len(l1.check_xy_m)),
        "seconds": l1.seconds, "versions": l1.geolocation}
    return ds

"""ground/network.py, ground/aiding.py, ground/blend.py: the motion record solved as a network,
smoothed, aided, stated as geometry, and blended with the stage.

Every case is synthetic with known link errors, drawn from fixed seeds; Monte Carlo checks
batch their draws through one factorisation (``Links.d_px`` (n, 2, m)).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from compensation.analytic_plant import REGION_CELLS
from ground.aiding import (
    STAR_TRACKER_SIGMA_PX,
    Absolute,
    GyroModel,
    GyroReadings,
    frame_position,
    gyro_aiding,
    simulate_absolute,
    simulate_gyro,
)
from ground.blend import band_error_variance, band_masks, band_split, blend_correction
from ground.network import (
    Links,
    Prior,
    SharedNoise,
    estimate_prior,
    geometry_rms,
    smooth_network,
    solve_network,
)

RATE_HZ = 200.0  # no_stage.yaml's tracker
IFOV_RAD = 1.2e-6


def wobble(n: int, amp=(1.2, 0.4), f_hz: float = 0.65) -> tuple[np.ndarray, np.ndarray]:
    """ZY-3's 0.65 Hz wobble at the tracker's frame times, zero at frame 0: (t (n,), s (n, 2))."""
    t = np.arange(n) / RATE_HZ
    ph = 2 * np.pi * f_hz * t
    s = np.stack([amp[0] * np.sin(ph), amp[1] * np.sin(ph + 1.0)], axis=1)
    return t, s - s[0]


def batched_links(s_px, k_max, sigma_of_k, m, rng, frame_sigma_px=None, t_s=None) -> Links:
    """All baselines 1..k_max over s, with m independent draws of the link (and frame)
    noise on a trailing axis."""
    exact = Links.baselines(s_px, k_max, sigma_of_k, t_s=t_s, frame_sigma_px=frame_sigma_px)
    d = exact.d_px[..., None] + exact.sigma_px[..., None] * rng.normal(
        0.0, 1.0, exact.sigma_px.shape + (m,))
    if frame_sigma_px is not None:
        nu = np.broadcast_to(frame_sigma_px, s_px.shape)[..., None] * rng.normal(
            0.0, 1.0, s_px.shape + (m,))
        d = d + nu[exact.b] - nu[exact.a]
    return Links(exact.a, exact.b, d, exact.sigma_px, None, t_s, frame_sigma_px)


def overlap_sigma(k: int) -> float:
    """A 256-row tracker crossed in ~6 frames: pair noise grows as the overlap shrinks."""
    return 0.009 * np.sqrt(6.0 / (6.0 - k))


# ------------------------------------------------------------------ the network


def test_a_chain_is_todays_cumulative_sum_with_its_random_walk_covariance():
    rng = np.random.default_rng([32, 1])
    n = 60
    d = rng.normal(0.0, 0.02, (n - 1, 2))
    sig = np.stack([np.full(n - 1, 0.01), rng.uniform(0.005, 0.03, n - 1)], axis=1)
    sol = solve_network(Links.chain(d, sig), n)
    chained = np.vstack([np.zeros((1, 2)), np.cumsum(d, axis=0)])
    np.testing.assert_allclose(sol.s_px, chained, rtol=0, atol=1e-12)
    var = np.vstack([np.zeros((1, 2)), np.cumsum(sig**2, axis=0)])
    k = np.arange(n)
    for ax in range(2):
        np.testing.assert_allclose(sol.cov_px2[ax], var[np.minimum.outer(k, k), ax],
                                   rtol=0, atol=1e-12)
    # at a time between frames: linear weights, the covariance carried through them
    tf = sol.t_s
    s_mid, sig_mid = sol.at([0.25 * tf[10] + 0.75 * tf[11]])
    np.testing.assert_allclose(s_mid[0], 0.25 * chained[10] + 0.75 * chained[11], atol=1e-12)
    np.testing.assert_allclose(sig_mid[0] ** 2, var[10] + 0.75**2 * sig[10] ** 2, atol=1e-12)
    rec = sol.to_record()
    np.testing.assert_allclose(rec.motion_px, chained, atol=1e-12)
    # the mean gauge is the same solution about its mean
    mean = solve_network(Links.chain(d, sig), n, gauge="mean")
    np.testing.assert_allclose(mean.s_px, chained - chained.mean(axis=0), atol=1e-12)


def test_the_network_reproduces_its_predicted_covariance_monte_carlo():
    """K = 3 baselines with a per-frame noise shared by all links of a frame: 2,000 draws."""
    rng = np.random.default_rng([32, 2])
    n, m = 40, 2000
    t, s = wobble(n)
    links = batched_links(s, 3, lambda k: (0.01 * k, 0.02), m, rng,
                          frame_sigma_px=(0.006, 0.004), t_s=t)
    sol = solve_network(links, n)
    err = sol.s_px - s[..., None]  # (n, 2, m)
    tol = 3 * np.sqrt(2.0 / m)
    for ax in range(2):
        c = sol.cov_px2[ax]
        for k in (n // 2, n - 1):
            assert abs(np.mean(err[k, ax] ** 2) / c[k, k] - 1) < tol
        dv = c[10, 10] + c[30, 30] - 2 * c[10, 30]
        assert abs(np.mean((err[30, ax] - err[10, ax]) ** 2) / dv - 1) < tol
        e0 = err[:, ax] - err[:, ax].mean(axis=0)
        pred = geometry_rms(np.zeros((n, 2)), t, sol.cov_px2)["predicted_constant"][ax]
        assert abs(np.mean(e0**2) / pred**2 - 1) < tol
    # treated as independent (the shared noise ignored), the covariance is measurably wrong
    # (neighbouring frames' difference: the shared noise of the two frames is left out)
    naive = solve_network(Links(links.a, links.b, links.d_px, links.sigma_px, t_s=t), n)
    en = naive.s_px - s[..., None]
    measured = np.mean((en[21] - en[20]) ** 2, axis=-1)
    assert np.all(measured / naive.difference_sigma_px(20, 21) ** 2 - 1 > 3 * tol)


# a small chained tracker: 4 blocks of 32 px on a 128-px sensor, the content moving 20.5 px a
# frame; the frames' noise a field of cells, the analytic plant's REGION_CELLS across a block
BLOCK_PX, SENSOR_PX = 32, 128
CELL_PX = BLOCK_PX // REGION_CELLS
GRID = np.array([[16, 16], [16, 80], [80, 16], [80, 80]])
STEP_PX = np.array([20.5, 3.0])
BLOCK_SIGMA_PX = np.array([[0.02, 0.03], [0.02, 0.03], [0.03, 0.02], [0.03, 0.02]])


def pair_regions(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The blocks of the pair (a, b) cut as the image plants cut them (imc.wiring.links)."""
    from imc.wiring.links import pair_corners

    st = np.tile(STEP_PX * (b - a), (len(GRID), 1))
    ref, used = pair_corners(GRID, st, BLOCK_PX, np.full(2, SENSOR_PX - BLOCK_PX), margin=4)
    return ref, ref + np.rint(st).astype(int), used


def region_chain(n: int, k_max: int):
    """Every pair of baselines 1..k_max: (a, b, regions (n, B, 2, 2), each block's share of its
    link's error (n, B, 2) px (the inverse-variance mean of the used blocks), link sigma)."""
    pairs = [(b - j, b) for b in range(1, n) for j in range(1, min(k_max, b) + 1)]
    a = np.array([p[0] for p in pairs])
    b = np.array([p[1] for p in pairs])
    reg = np.zeros((len(pairs), len(GRID), 2, 2), int)
    used = np.zeros((len(pairs), len(GRID)), bool)
    for i, (x, y) in enumerate(pairs):
        ref, cur, u = pair_regions(x, y)
        reg[i, :, 0], reg[i, :, 1], used[i] = ref, cur, u
    w = np.where(used[..., None], 1.0 / BLOCK_SIGMA_PX**2, 0.0)
    share = w / w.sum(axis=1, keepdims=True) * BLOCK_SIGMA_PX
    return a, b, reg, share, np.sqrt(np.sum(share**2, axis=1))


def draw_region_noise(a, b, reg, share, m: int, rng) -> np.ndarray:
    """m draws (n, 2, m) px of the links' noise as the analytic plant draws a chain's
    (compensation/analytic_plant.py, ``_region_noise``): each frame a field of unit cells per
    axis, a block's noise (its current frame's cells over its current region less its
    reference frame's over its reference region) / sqrt(2), the link its blocks' weighted
    sum."""
    w = BLOCK_PX // CELL_PX
    nc = SENSOR_PX // CELL_PX
    r, c, v = [], [], []
    for i in range(len(a)):
        for j in np.flatnonzero(np.any(share[i] > 0, axis=1)):
            for frame, corner, sign in ((a[i], reg[i, j, 0], -1.0), (b[i], reg[i, j, 1], 1.0)):
                r0, c0 = np.clip(np.rint(corner / CELL_PX).astype(int), 0, nc - w)
                rr, cc = np.meshgrid(np.arange(r0, r0 + w), np.arange(c0, c0 + w),
                                     indexing="ij")
                r.append(np.full(w * w, i * len(GRID) + j))
                c.append(frame * nc * nc + (rr * nc + cc).ravel())
                v.append(np.full(w * w, sign / w / np.sqrt(2.0)))
    used, c = np.unique(np.concatenate(c), return_inverse=True)  # only the cells read
    cells = sparse.csr_matrix((np.concatenate(v).astype(np.float32), (np.concatenate(r), c)),
                              shape=(len(a) * len(GRID), used.size))
    out = np.empty((len(a), 2, m))
    for ax in range(2):
        for j in range(0, m, 250):  # 250 draws of every cell at a time
            k = min(m - j, 250)
            z = rng.standard_normal((cells.shape[1], k), dtype=np.float32)
            blocks = (cells @ z).reshape(len(a), len(GRID), k)
            out[:, ax, j:j + k] = np.einsum("lb,lbm->lm", share[:, :, ax], blocks)
    return out


def test_links_sharing_their_frames_pixels_reproduce_their_covariance_monte_carlo():
    """K = 3 pairs whose blocks share their frames' pixels (the analytic plant's noise): the
    solve with the shared noise reproduces its covariance over 2,000 draws; the same links
    weighed as independent predict a drift the draws exceed."""
    rng = np.random.default_rng([32, 8])
    n, m = 40, 2000
    t, s = wobble(n)
    a, b, reg, share, sigma = region_chain(n, 3)
    noise = draw_region_noise(a, b, reg, share, m, rng)
    d = (s[b] - s[a])[..., None] + noise
    shared = SharedNoise.from_blocks(a, b, reg[:, :, 0], reg[:, :, 1], share, BLOCK_PX,
                                     CELL_PX)
    sol = solve_network(Links(a, b, d, np.zeros_like(sigma), t_s=t, shared=shared), n)
    naive = solve_network(Links(a, b, d, sigma, t_s=t), n)
    tol = 3 * np.sqrt(2.0 / m)
    for ax in range(2):
        # the links' own variance: their blocks' where these do not overlap, more where a
        # pair's cut moves its blocks onto each other's pixels
        r = np.diag(shared.covariance(np.arange(len(a)))[ax].toarray())
        assert np.all(r >= sigma[:, ax] ** 2 * (1 - 1e-12))
        assert abs(np.mean(noise[:, ax] ** 2 / r[:, None]) - 1) < tol
        err = sol.s_px[:, ax] - s[:, ax, None]
        c = sol.cov_px2[ax]
        for k in (n // 2, n - 1):
            assert abs(np.mean(err[k] ** 2) / c[k, k] - 1) < tol
        dv = c[10, 10] + c[30, 30] - 2 * c[10, 30]
        assert abs(np.mean((err[30] - err[10]) ** 2) / dv - 1) < tol
        e0 = err - err.mean(axis=0)
        pred = geometry_rms(np.zeros((n, 2)), t, sol.cov_px2)["predicted_constant"][ax]
        assert abs(np.mean(e0**2) / pred**2 - 1) < tol
        # weighed as independent: the drift after a constant exceeds its prediction
        en = naive.s_px[:, ax] - s[:, ax, None]
        en -= en.mean(axis=0)
        pn = geometry_rms(np.zeros((n, 2)), t, naive.cov_px2)["predicted_constant"][ax]
        assert np.mean(en**2) / pn**2 - 1 > 3 * tol
    # K = 1: the shared noise changes the chain's covariance, never its solution
    a1, b1, reg1, share1, sigma1 = region_chain(n, 1)
    d1 = d[np.flatnonzero(b - a == 1), :, 0]
    chain = solve_network(Links(a1, b1, d1, np.zeros_like(sigma1), t_s=t,
                                shared=SharedNoise.from_blocks(a1, b1, reg1[:, :, 0],
                                                               reg1[:, :, 1], share1,
                                                               BLOCK_PX, CELL_PX)), n)
    np.testing.assert_allclose(chain.s_px, np.vstack([np.zeros((1, 2)), np.cumsum(d1, 0)]),
                               rtol=0, atol=1e-10)


def test_the_shared_noise_model_is_the_analytic_plants():
    """The analytic plant's own chain (its pair_links over its pair_regions, 300 frames,
    K = 3): whitened by the links' predicted covariance, its noise has unit variance; weighed
    as independent it does not."""
    from compensation.analytic_plant import AnalyticPlant

    n = 300
    plant = AnalyticPlant(lambda tt: np.zeros((len(tt), len(GRID), 2)), GRID + 15.5,
                          BLOCK_SIGMA_PX, np.arange(n) / RATE_HZ, 1e-4, seed=(7,), chain=True,
                          pair_regions=pair_regions, frame_shape=(SENSOR_PX, SENSOR_PX),
                          block_px=BLOCK_PX)
    assert plant.cell_px == CELL_PX
    a, b, d, sig, valid = plant.pair_links(3)
    w = np.where(valid[..., None], 1.0 / sig**2, 0.0)
    share = w / w.sum(axis=1, keepdims=True) * sig
    link = np.sum(w * d, axis=1) / w.sum(axis=1)
    reg = np.stack([np.stack(pair_regions(int(x), int(y))[:2], axis=1)
                    for x, y in zip(a, b, strict=True)])
    cov = SharedNoise.from_blocks(a, b, reg[:, :, 0], reg[:, :, 1], share, BLOCK_PX,
                                  CELL_PX).covariance(np.arange(len(a)))
    tol = 3 * np.sqrt(2.0 / len(a))
    for ax in range(2):
        chol = np.linalg.cholesky(cov[ax].toarray())
        z = np.linalg.solve(chol, link[:, ax])
        assert abs(np.mean(z**2) - 1) < tol
        # independent links: the same noise reads as far from unit variance
        ind = np.diag(np.diag(cov[ax].toarray()) ** -0.5)
        zi = ind @ link[:, ax]
        assert abs(np.mean(zi**2) - 1) < tol  # each link's own variance is right ...
        x = link[:, ax]
        k1 = np.flatnonzero(b - a == 1)
        pred = cov[ax].toarray()[k1[:-1], k1[1:]] / np.sqrt(np.diag(cov[ax].toarray())[k1[:-1]]
                                                            * np.diag(cov[ax].toarray())[k1[1:]])
        lag1 = np.corrcoef(x[k1[:-1]], x[k1[1:]])[0, 1]
        assert abs(lag1 - pred.mean()) < 3 / np.sqrt(len(k1))  # ... and so is its correlation
        assert pred.mean() < -3 / np.sqrt(len(k1))  # which independence would set to 0


def test_the_links_own_share_of_their_error_is_estimated_from_the_record():
    """A chain of 300 frames, K = 4, whose links carry their frames' shared noise and, in the
    second case, an independent error of half their variance: the restricted likelihood of
    the redundant links finds 0 (< 0.1) and 0.5 (within 0.2) on both axes."""
    from ground.network import estimate_independent_fraction, with_independent_fraction

    n = 300
    t, s = wobble(n)
    a, b, reg, share, sigma = region_chain(n, 4)
    shared = SharedNoise.from_blocks(a, b, reg[:, :, 0], reg[:, :, 1], share, BLOCK_PX,
                                     CELL_PX)
    links = Links(a, b, s[b] - s[a], np.zeros_like(sigma), t_s=t, shared=shared)
    var = np.stack([c.diagonal() for c in shared.covariance(np.arange(len(a)))], axis=1)
    for f_true, seed in ((0.0, 0), (0.5, 1)):
        rng = np.random.default_rng([32, 9, seed])
        noise = np.sqrt(1.0 - f_true) * draw_region_noise(a, b, reg, share, 1, rng)[..., 0] \
            + np.sqrt(f_true * var) * rng.standard_normal(var.shape)
        f = estimate_independent_fraction(
            Links(a, b, links.d_px + noise, links.sigma_px, t_s=t, shared=shared), n)
        assert np.all(np.abs(f - f_true) < (0.1 if f_true == 0 else 0.2)), f
    # the split keeps each link's variance and moves the rest off the shared part
    half = with_independent_fraction(links, 0.5)
    cov = half.shared.covariance(np.arange(len(a)))
    for ax in range(2):
        np.testing.assert_allclose(cov[ax].diagonal() + half.sigma_px[:, ax] ** 2, var[:, ax],
                                   rtol=1e-12)
        np.testing.assert_allclose(cov[ax].diagonal(), 0.5 * var[:, ax], rtol=1e-12)


def test_baselines_1_to_4_cut_the_drift_as_their_covariance_predicts():
    rng = np.random.default_rng([32, 3])
    n, m = 331, 200
    t, s = wobble(n)
    measured, predicted = [], []
    for k_max in (1, 2, 3, 4):
        sol = solve_network(batched_links(s, k_max, overlap_sigma, m, rng, t_s=t), n)
        e = sol.s_px - s[..., None]
        e -= e.mean(axis=0)
        measured.append(np.sqrt(np.mean(e**2, axis=(0, 2))))
        predicted.append(geometry_rms(np.zeros((n, 2)), t, sol.cov_px2)["predicted_constant"])
    measured, predicted = np.array(measured), np.array(predicted)
    assert np.all((measured / predicted > 1 / 1.5) & (measured / predicted < 1.5))
    gain_m, gain_p = measured[-1] / measured[0], predicted[-1] / predicted[0]
    assert np.all((gain_m / gain_p > 1 / 1.5) & (gain_m / gain_p < 1.5))
    assert np.all(gain_p < 0.5)  # a network of 4 baselines leaves well under half the drift
    assert np.all(np.diff(predicted, axis=0) < 0)


def test_invalid_links_are_dropped_and_a_gap_is_named():
    n = 30
    _, s = wobble(n)
    links = Links.baselines(s, 2, 0.01)
    valid = np.ones(links.a.size, bool)
    valid[5] = False  # one chain link: the 2-frame baselines still span it
    sol = solve_network(Links(links.a, links.b, links.d_px, links.sigma_px, valid), n)
    np.testing.assert_allclose(sol.s_px, s, atol=1e-12)
    gap = (links.a <= 10) & (links.b > 10)  # nothing ties frames 11.. to frames ..10
    with pytest.raises(ValueError, match="tied to no datum"):
        solve_network(Links(links.a, links.b, links.d_px, links.sigma_px, ~gap), n)


@pytest.mark.parametrize("kwargs, match", [
    ({"a": [1], "b": [1]}, "a < b"),
    ({"d_px": [[0.0, np.nan]]}, "finite where valid"),
    ({"sigma_px": [[0.0, 0.1]]}, "sigma_px"),
    ({"t_s": [0.0, 0.0]}, "t_s"),
])
def test_links_say_what_is_wrong(kwargs, match):
    base = {"a": [0], "b": [1], "d_px": [[0.1, 0.2]], "sigma_px": [[0.01, 0.01]]}
    with pytest.raises(ValueError, match=match):
        Links(**{**base, **kwargs})


def test_gauges_need_the_right_datum():
    links = Links.chain(np.zeros((3, 2)), np.full((3, 2), 0.01))
    with pytest.raises(ValueError, match="gauge='none' needs absolute"):
        solve_network(links, 4, gauge="none")
    fix = Absolute([1.0], [[0.0, 0.0]], 0.01)
    with pytest.raises(ValueError, match="use gauge='none'"):
        solve_network(links, 4, gauge="first", absolute=fix)


# ------------------------------------------------------------------ geometry metrics


def test_affine_metric_of_a_linear_drift_is_zero_and_of_t_squared_its_closed_form():
    n = 1001
    t = np.linspace(-1.0, 1.0, n)
    drift = np.stack([0.3 + 2.0 * t, -0.1 * t], axis=1)
    g = geometry_rms(drift, t)
    np.testing.assert_allclose(g["affine"], 0.0, atol=1e-13)
    assert np.all(g["constant"] > 0.05)
    # t^2 is even, so its best line on the symmetric grid is its mean: with u_j = n - 1 - 2j,
    # sum u^2 = n (n^2 - 1) / 3 and sum u^4 = n (n^2 - 1)(3 n^2 - 7) / 15, hence
    # mean t^2 = (n + 1) / (3 (n - 1)), mean t^4 = (n + 1)(3 n^2 - 7) / (15 (n - 1)^3)
    m2 = (n + 1) / (3 * (n - 1))
    m4 = (n + 1) * (3 * n**2 - 7) / (15 * (n - 1) ** 3)
    g = geometry_rms(np.stack([t**2, 5 * t**2], axis=1), t)
    np.testing.assert_allclose(g["affine"], np.sqrt(m4 - m2**2) * np.array([1, 5]), rtol=1e-12)
    # the continuous limit: (1/2) int (t^2 - 1/3)^2 dt = 4/45 on [-1, 1]
    np.testing.assert_allclose(g["affine"][0], np.sqrt(4 / 45), rtol=2e-3)


def test_predicted_metrics_are_the_projected_covariance():
    n = 50
    t = np.linspace(0.0, 1.0, n)
    g = geometry_rms(np.zeros((n, 2)), t, np.stack([np.eye(n), 4 * np.eye(n)]))
    np.testing.assert_allclose(g["predicted_constant"], np.array([1, 2]) * np.sqrt((n - 1) / n))
    np.testing.assert_allclose(g["predicted_affine"], np.array([1, 2]) * np.sqrt((n - 2) / n))


# ------------------------------------------------------------------ the smoother


def test_the_smoother_removes_frame_noise_with_a_prior_estimated_from_the_record():
    """Per-frame noise dominates the links: the smoothed record is >= 2x better and its
    predicted error matches the measured one (200 draws, the prior estimated from draw 0)."""
    rng = np.random.default_rng([32, 4])
    n, m = 200, 200
    t, s = wobble(n)
    links = batched_links(s, 3, 0.004, m, rng, frame_sigma_px=0.03, t_s=t)
    raw = solve_network(links, n)
    prior = estimate_prior(raw, order=2)
    assert prior.q_px2[0] > prior.q_px2[1]  # the row axis moves 3x more than the column
    sm = smooth_network(links, n, prior=prior)
    e_raw = raw.s_px - s[..., None]
    e_sm = sm.s_px - s[..., None]
    rms_raw = np.sqrt(np.mean((e_raw - e_raw.mean(axis=0)) ** 2, axis=(0, 2)))
    rms_sm = np.sqrt(np.mean((e_sm - e_sm.mean(axis=0)) ** 2, axis=(0, 2)))
    assert np.all(rms_sm < 0.5 * rms_raw)
    pred = geometry_rms(np.zeros((n, 2)), t, sm.cov_px2)["predicted_constant"]
    assert np.all((rms_sm / pred > 1 / 1.5) & (rms_sm / pred < 1.5))
    np.testing.assert_allclose(sm.sigma_px[0], 0.0, atol=1e-12)  # the gauge: s_0 = 0


@pytest.mark.parametrize("order", [1, 2])
def test_smooth_network_estimates_its_own_prior(order):
    rng = np.random.default_rng([32, 5])
    n = 120
    t, s = wobble(n)
    links = Links.baselines(s, 2, 0.004, rng, t_s=t, frame_sigma_px=0.02)
    raw = solve_network(links, n)
    sm = smooth_network(links, n, order=order)
    assert sm.prior is not None and sm.prior.order == order
    assert sm.prior.q_px2 == estimate_prior(raw, order).q_px2
    rms = [geometry_rms(x.s_px - s, t)["constant"] for x in (raw, sm)]
    assert np.all(rms[1] < rms[0])
    with pytest.raises(ValueError, match="order"):
        Prior(3, (1.0, 1.0))


# ------------------------------------------------------------------ aiding


def test_gyro_units_and_its_simulated_random_walk():
    astrix = GyroModel.pleiades_class()
    assert astrix.arw_px_rts(IFOV_RAD) == pytest.approx(0.0485, rel=1e-3)  # the notes' 0.048
    g = GyroModel(0.0002, 0.0, 100.0)
    t = np.linspace(0.0, 200.0, 3)
    r = simulate_gyro(g, t, np.zeros((3, 2)), IFOV_RAD, np.random.default_rng([32, 6]))
    steps = np.diff(r.angle_px, axis=0)
    tol = 3 * np.sqrt(2.0 / steps.size)
    assert abs(np.var(steps) / (g.arw_px_rts(IFOV_RAD) ** 2 / g.rate_hz) - 1) < tol
    with pytest.raises(ValueError, match="rng must be"):
        simulate_gyro(g, t, np.zeros((3, 2)), IFOV_RAD, 7)
    with pytest.raises(ValueError, match="ifov_rad"):
        g.arw_px_rts(0.0)
    with pytest.raises(ValueError, match="arw_deg_rthr"):
        GyroModel(-1.0, 0.0, 100.0)
    with pytest.raises(ValueError, match="sigma_px"):
        Absolute([1.0], [[0.0, 0.0]], 0.0)


def test_a_noiseless_gyro_makes_the_record_exact_at_low_frequency():
    rng = np.random.default_rng([32, 7])
    n = 331
    t, s = wobble(n)
    links = Links.chain(np.diff(s, axis=0) + rng.normal(0.0, 0.02, (n - 1, 2)),
                        np.full((n - 1, 2), 0.02), t_s=t)
    # the body wobbles at 0.65 Hz; the focal plane adds 0.03 px at 40 Hz the gyro cannot see
    fp = 0.03 * np.sin(2 * np.pi * 40.0 * t)[:, None] * np.array([1.0, 1.0])
    tt = np.linspace(t[0], t[-1], 20 * n)
    body = np.stack([np.interp(tt, t, s[:, k]) for k in range(2)], axis=1)
    perfect = GyroModel(0.0, 0.0, 1000.0)
    readings = simulate_gyro(perfect, tt, body, IFOV_RAD, rng)
    alone = solve_network(links, n)
    fused = solve_network(links, n, gyro=gyro_aiding(perfect, readings, t, IFOV_RAD))
    assert np.all(geometry_rms(alone.s_px - s, t)["constant"] > 0.05)
    assert np.all(geometry_rms(fused.s_px - s, t)["constant"] < 1e-4)
    # with the unseen focal-plane motion in the links, the gyro carries it as frame noise:
    # below 5 Hz the fused record stays exact, above it the links tell
    links_fp = Links.chain(links.d_px + np.diff(fp, axis=0), links.sigma_px, t_s=t)
    aid = gyro_aiding(perfect, readings, t, IFOV_RAD, los_sigma_px=0.03)
    fused_fp = solve_network(links_fp, n, gyro=aid)
    low = band_split(fused_fp.s_px - (s + fp), 1 / RATE_HZ, [5.0])[0]
    assert np.all(np.sqrt(np.mean((low - low.mean(axis=0)) ** 2, axis=0)) < 2e-3)


def test_a_real_gyro_and_the_record_together_beat_either_alone():
    rng = np.random.default_rng([32, 8])
    n = 331
    t, s = wobble(n)
    links = Links.baselines(s, 1, 0.009, rng, t_s=t)
    astrix = GyroModel.pleiades_class(rate_hz=400.0)
    tt = np.linspace(t[0], t[-1], 4 * n)
    body = np.stack([np.interp(tt, t, s[:, k]) for k in range(2)], axis=1)
    aid = gyro_aiding(astrix, simulate_gyro(astrix, tt, body, IFOV_RAD, rng), t, IFOV_RAD)
    alone = geometry_rms(np.zeros((n, 2)), t, solve_network(links, n).cov_px2)
    fused = solve_network(links, n, gyro=aid)
    both = geometry_rms(fused.s_px - s, t, fused.cov_px2)
    # the gyro alone: its ARW over the strip (the bias is a trend, taken as known here)
    gyro_only = Links.chain(np.diff(aid.angle_px, axis=0),
                            np.repeat(aid.step_sigma_px[:, None], 2, axis=1), t_s=t)
    gyro_alone = geometry_rms(np.zeros((n, 2)), t, solve_network(gyro_only, n).cov_px2)
    best = np.minimum(alone["predicted_constant"], gyro_alone["predicted_constant"])
    assert np.all(both["predicted_constant"] < best)
    assert np.all(both["constant"] < 3 * both["predicted_constant"])
    assert fused.bias_sigma_px_s is not None and np.all(fused.bias_sigma_px_s > 0)


def test_ground_control_anchors_the_record_a_star_tracker_only_to_4_over_sqrt_m():
    rng = np.random.default_rng([32, 9])
    n = 331
    t, s = wobble(n)
    s = s + np.array([3.0, -2.0])  # the absolute pointing the links cannot see
    links = Links.baselines(s, 2, 0.009, rng, t_s=t)
    gcp = simulate_absolute(np.linspace(t[0], t[-1], 6), t, s, 0.005, t, rng)
    sol = solve_network(links, n, absolute=gcp)
    assert sol.gauge == "none"
    assert np.all(np.abs((sol.s_px - s).mean(axis=0)) < 0.02)
    st_times = np.arange(t[0], t[-1], 0.1)  # 10 Hz
    star = simulate_absolute(st_times, t, s, STAR_TRACKER_SIGMA_PX, t, rng)
    st = solve_network(links, n, absolute=star)
    sigma_mean = np.sqrt(st.cov_px2.mean(axis=(1, 2)))  # the constant's sigma
    np.testing.assert_allclose(sigma_mean, STAR_TRACKER_SIGMA_PX / np.sqrt(st_times.size),
                               rtol=0.05)
    np.testing.assert_allclose(frame_position([t[3], 0.5 * (t[3] + t[4])], t), [3.0, 3.5])


def test_gyro_readings_must_cover_the_frames():
    r = GyroReadings([0.0, 1.0], np.zeros((2, 2)))
    with pytest.raises(ValueError, match="outside the gyro"):
        gyro_aiding(GyroModel(0.0, 0.0, 1.0), r, [0.5, 2.0], IFOV_RAD)


# ------------------------------------------------------------------ stage + ground


def test_band_masks_are_complementary_and_the_band_variances_add_up():
    m = band_masks(300, 1 / RATE_HZ, [2.0, 20.0])
    np.testing.assert_allclose(m.sum(axis=0), 1.0, atol=1e-15)
    assert np.all((m >= 0) & (m <= 1))
    x = np.random.default_rng([32, 10]).normal(size=(300, 2))
    np.testing.assert_allclose(band_split(x, 1 / RATE_HZ, [2.0, 20.0]).sum(axis=0), x,
                               atol=1e-12)
    white = band_error_variance(np.stack([np.eye(300)] * 2), 1 / RATE_HZ, [2.0, 20.0])
    np.testing.assert_allclose(white.sum(axis=0), (m**2).sum() / 300)


def _stage_case(rng, n, residual, link_sigma):
    """The ground's estimate of a stage residual: the record's network less the stage's own
    position record, so its error is the network's."""
    t = np.arange(n) / RATE_HZ
    links = Links.baselines(residual, 2, link_sigma, rng, t_s=t)
    sol = solve_network(links, n)
    return t, sol.s_px, sol.cov_px2


def test_stage_plus_ground_is_not_worse_than_the_stage_on_a_noisy_record():
    rng = np.random.default_rng([32, 11])
    n = 331
    t = np.arange(n) / RATE_HZ
    # the stage leaves 0.03 px of low-frequency residual; the record drifts ~10x more
    r = 0.03 * np.stack([np.sin(2 * np.pi * 0.65 * t), np.cos(2 * np.pi * 1.1 * t)], axis=1)
    r -= r[0]
    _, est, cov = _stage_case(rng, n, r, 0.03)
    stage = geometry_rms(r, t)["constant"]
    whole = geometry_rms(r - est, t)["constant"]
    assert np.all(whole > 2 * stage)  # applying the record whole makes it worse
    for rule in ("wiener", "switch"):
        b = blend_correction([est], [cov], 1 / RATE_HZ, [2.0, 10.0], rule=rule)
        after = geometry_rms(r - b.correction_px, t)["constant"]
        assert np.all(after <= 1.1 * stage)
        assert np.all(b.predicted_after_px <= b.predicted_before_px + 1e-15)


def test_stage_plus_ground_is_2x_better_where_the_stage_leaves_motion_above_its_bandwidth():
    rng = np.random.default_rng([32, 12])
    n = 331
    t = np.arange(n) / RATE_HZ
    # a 20 Hz loop leaves a 35 Hz wheel line and a small low-frequency wander
    r = np.stack([0.1 * np.sin(2 * np.pi * 35.0 * t) + 0.01 * np.sin(2 * np.pi * 0.65 * t),
                  0.06 * np.sin(2 * np.pi * 41.0 * t + 1.0) + 0.01 * t], axis=1)
    r -= r[0]
    _, ground, cov = _stage_case(rng, n, r, 0.01)
    # the stage's own residual record: its chain is noisier and drifts
    stage_rec = Links.chain(np.diff(r, axis=0) + rng.normal(0.0, 0.02, (n - 1, 2)),
                            np.full((n - 1, 2), 0.02), t_s=t)
    srec = solve_network(stage_rec, n)
    b = blend_correction([srec.s_px, ground], [srec.cov_px2, cov], 1 / RATE_HZ, [2.0, 10.0])
    stage = geometry_rms(r, t)["constant"]
    after = geometry_rms(r - b.correction_px, t)["constant"]
    assert np.all(after < 0.5 * stage)
    assert np.all(b.weights[1] > b.weights[0])  # the ground's network is trusted more
    assert np.all(b.gain[-1] > 0.9)  # above the crossovers the record is applied
    with pytest.raises(ValueError, match="rule"):
        blend_correction([ground], [cov], 1 / RATE_HZ, [2.0], rule="max")

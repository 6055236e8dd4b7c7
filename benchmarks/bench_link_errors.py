"""Every link of no_stage.yaml's record against the truth, per baseline (issue 32's diagnosis).

One loop of ``no_stage.yaml`` (rendered ~3 min, texture ~2 min, analytic < 1 min), its links
measured as the ground measures them (:func:`imc.wiring.links.measure_links`), each link's
error against the truth's jitter increment (the camera model's jitter averaged over each
tracker exposure), per baseline: mean (with its standard error), scatter, the predicted
error, the RMS of error / predicted error, and the error's slope on the true increment (a
gain error); then the baseline-1 links' lag correlation and the chain of baseline-1 links
integrated; and the network's covariance (the frames' shared noise with the ground's REML
split, as :func:`imc.wiring.restitution.restitute` builds it) against the links' true errors:
the whitened RMS and the spread of sums of W consecutive baseline-1 links, measured over
predicted. Measured here, never asserted in tests.

    python benchmarks/bench_link_errors.py [--fidelity rendered|texture|analytic] [--seed S]
        [--noise-dn SIGMA]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from bench_restitution import _run, _scenario

from ground.network import estimate_independent_fraction, with_independent_fraction
from imc.wiring.product import exposure_jitter


def link_errors(fidelity: str, seed: int | None, noise_dn: float | None = None) -> dict:
    """The per-baseline figures of one loop (see the module docstring); ``noise_dn``: the
    tracker's sensor noise replaced by additive noise of that sigma, DN (a near-noiseless
    sensor shows a bias common to the links within one strip)."""
    d = _scenario()
    d["plant"] = {"fidelity": fidelity}
    if seed is not None:
        d["seed"] = int(seed)
    if noise_dn is not None:
        d["camera"]["tracker"].update(noise_model="additive", noise_sigma_dn=float(noise_dn))
    m, _, _, links = _run(d, fidelity == "analytic", fidelity == "analytic")
    jit = exposure_jitter(m)
    a, b = links.a.astype(int), links.b.astype(int)
    true = jit[b] - jit[a]
    ok = links.valid & np.all(np.isfinite(links.d_px), axis=1)
    err = links.d_px - true
    out: dict = {"fidelity": fidelity, "seed": seed, "efficiency": links.efficiency.tolist(),
                 "baselines": []}
    for k in np.unique(links.baseline):
        s = ok & (links.baseline == k)
        if s.sum() < 3:
            continue
        e, tk, sg = err[s], true[s], links.sigma_px[s]
        out["baselines"].append({
            "k": int(k), "links": int(s.sum()), "mean_px": e.mean(0).tolist(),
            "mean_se_px": (e.std(0) / np.sqrt(s.sum())).tolist(), "std_px": e.std(0).tolist(),
            "predicted_px": np.sqrt(np.mean(sg ** 2, axis=0)).tolist(),
            "z_rms": np.sqrt(np.mean((e / sg) ** 2, axis=0)).tolist(),
            "gain_slope": [float(np.polyfit(tk[:, i], e[:, i], 1)[0]) for i in range(2)],
            "true_increment_std_px": tk.std(0).tolist()})
    s = ok & (links.baseline == 1)
    e1 = err[s][np.argsort(links.a[s])]
    out["lag_correlation"] = {lag: [float(np.corrcoef(e1[:-lag, i], e1[lag:, i])[0, 1])
                                    for i in range(2)] for lag in (1, 2, 3, 5, 10)}
    chain = np.cumsum(e1, axis=0)
    out["chain_drift_after_constant_px"] = np.sqrt(np.mean(
        (chain - chain.mean(0)) ** 2, axis=0)).tolist()
    if links.regions is not None:
        out["covariance"] = covariance_check(m, links, jit)
    return out


def covariance_check(m, links, jit: np.ndarray, windows=(1, 5, 20, 80)) -> dict:
    """The network's link covariance against the links' true errors, per axis: the RMS of the
    errors whitened by it (1 if it holds) and, for sums of W consecutive baseline-1 links,
    the measured spread over the predicted."""
    net = links.network(m.frame_mid_s, int(links.baseline.max()))
    f = estimate_independent_fraction(net, len(m.frame_mid_s))
    net = with_independent_fraction(net, f)
    idx = np.flatnonzero(net.valid)
    a, b = net.a[idx].astype(int), net.b[idx].astype(int)
    err = net.d_px[idx] - (jit[b] - jit[a])
    shared = net.shared.covariance(idx)
    k1 = np.flatnonzero(b - a == 1)
    k1 = k1[np.argsort(a[k1])]
    out: dict = {"independent_fraction": f.tolist(), "whitened_rms": [], "windows": {}}
    for ax in range(2):
        cov = shared[ax].toarray() + np.diag(net.sigma_px[idx, ax] ** 2)
        z = np.linalg.solve(np.linalg.cholesky(cov), err[:, ax])
        out["whitened_rms"].append(float(np.sqrt(np.mean(z ** 2))))
        for w in windows:
            pv, mv = [], []
            for s0 in range(0, len(k1) - w + 1, w):
                sel = k1[s0:s0 + w]
                pv.append(cov[np.ix_(sel, sel)].sum())
                mv.append(err[sel, ax].sum() ** 2)
            out["windows"].setdefault(str(w), []).append(float(np.sqrt(np.mean(mv)
                                                                       / np.mean(pv))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fidelity", choices=("rendered", "texture", "analytic"),
                    default="rendered")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--noise-dn", type=float, default=None, help="additive sensor noise of "
                    "this sigma, DN, instead of the scenario's")
    a = ap.parse_args()
    r = link_errors(a.fidelity, a.seed, a.noise_dn)
    for row in r["baselines"]:
        print(f"k={row['k']} links {row['links']}: mean "
              f"{row['mean_px'][0]:+.5f} / {row['mean_px'][1]:+.5f} px (se "
              f"{row['mean_se_px'][0]:.5f} / {row['mean_se_px'][1]:.5f}), std "
              f"{row['std_px'][0]:.4f} / {row['std_px'][1]:.4f}, predicted "
              f"{row['predicted_px'][0]:.4f} / {row['predicted_px'][1]:.4f}, z-rms "
              f"{row['z_rms'][0]:.2f} / {row['z_rms'][1]:.2f}, gain slope "
              f"{row['gain_slope'][0]:+.3f} / {row['gain_slope'][1]:+.3f}")
    print(json.dumps({k: v for k, v in r.items() if k != "baselines"}))


if __name__ == "__main__":
    main()

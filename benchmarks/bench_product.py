"""The main imager's product against the targets of its issue: ground correction with and
without a stage, the perfect record, restoration of a known smear, NIIRS of the bundled
scenarios, and the product's cost.

    .venv/bin/python benchmarks/bench_product.py [--quick] [--out benchmarks/out/product]

Writes product.json and product.md (the tables quoted in docs/product.md). Figures are
measured here, never asserted in tests. About 15 minutes on 2 cores (--quick: the no-stage
strip only and the restoration, ~5 minutes).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imc.io import write_json  # noqa: E402
from imc.pipeline import run_scenario  # noqa: E402
from imc.scenario import parse_scenario  # noqa: E402
from imc.yamlload import with_changes  # noqa: E402

SCENARIOS = ROOT / "scenarios"
#: the bundled scenarios whose open-loop NIIRS loss is printed, with a product of this size
SMALL_PRODUCT = {"enabled": True, "lines": 256, "cols": 256, "samples": 8}


def _scenario(name: str, **changes) -> dict:
    return with_changes(yaml.safe_load((SCENARIOS / f"{name}.yaml").read_text()), changes)


def _run(data: dict, out: Path, label: str) -> dict:
    t = time.perf_counter()
    metrics, info = run_scenario(parse_scenario(data, label), out / label, rerun=False,
                                 fresh=True)
    p = metrics["product"]
    print(f"{label}: {time.perf_counter() - t:.0f} s (product render {p['render_s']:.1f} s, "
          f"{p['rays_per_s'] / 1e6:.1f} M rays/s)", flush=True)
    return {"metrics": metrics, "wall_s": info["wall_s"]}


def geometry_rows(runs: dict) -> list[str]:
    rows = ["| case | strategy | record error RMS row / col (px) | before | after (record) | "
            "after (perfect record) | after / record |", "|---|---|---|---|---|---|---|"]
    for label, r in runs.items():
        p = r["metrics"]["product"]
        rec = p["record"]["rms_px"]
        for name, g in p["geometry"].items():
            strat = {"open": "ground only", "closed": "stage + ground"}[name]
            b, a, pf = (g[k]["rms_px"] for k in ("before", "after", "after_perfect_record"))
            ratio = [x / max(y, 1e-12) for x, y in zip(a, rec, strict=True)]
            rows.append(f"| {label} | {strat} | {rec[0]:.4f} / {rec[1]:.4f} | {b[0]:.4f} / "
                        f"{b[1]:.4f} | {a[0]:.4f} / {a[1]:.4f} | {pf[0]:.4f} / {pf[1]:.4f} | "
                        f"{ratio[0]:.2f} / {ratio[1]:.2f} |")
    return rows


def quality_rows(runs: dict) -> list[str]:
    rows = ["| case | product | MTF@Nyquist along / across | RER along / across | NIIRS | "
            "loss vs static | SSIM |", "|---|---|---|---|---|---|---|"]
    for label, r in runs.items():
        for name, q in r["metrics"]["product"]["quality"].items():
            mtf, rer = q["mtf_nyquist"], q["rer"]
            rows.append(f"| {label} | {name} | {mtf[0]:.3f} / {mtf[1]:.3f} | {rer[0]:.3f} / "
                        f"{rer[1]:.3f} | {q['niirs']:.3f} | {q['niirs_loss']:+.3f} | "
                        f"{q['ssim']:.4f} |")
    return rows


def restoration() -> dict:
    """A 1 px linear smear at SNR 50 on a slanted edge, restored with the known PSF
    (ground.restore.restoration_figures, the figures of tests/test_ground.py)."""
    from scipy.special import erf

    from ground.restore import residual_psf, restoration_figures

    rng = np.random.default_rng(5)
    h, w = 128, 384
    rr, cc = np.mgrid[0:h, 0:w].astype(np.float64)
    dist = (rr - h / 2) - np.tan(np.deg2rad(5.0)) * (cc - w / 2)
    smear = np.linspace(-0.5, 0.5, 65)

    def edge(shifts):
        return np.mean([0.5 * (1 + erf((dist - s) / (0.3 * np.sqrt(2)))) for s in shifts],
                       axis=0)

    static, blurred = edge([0.0]), edge(smear)
    psf = residual_psf(np.column_stack([smear, np.zeros_like(smear)])).pixel
    sigma = 1.0 / 50.0
    f = restoration_figures(static, blurred + rng.normal(0, sigma, blurred.shape), psf, sigma,
                            rng=rng)
    return f.to_dict()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "product"))
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = {"no_stage (ground only)": _run(_scenario("no_stage"), out, "no_stage")}
    if not a.quick:
        runs["no_stage + stage"] = _run(_scenario(
            "no_stage", **{"compensation.enabled": True,
                           "compensation.controller": {"kind": "kalman", "order": 2,
                                                       "bandwidth_hz": 20}}),
            out, "no_stage_with_stage")
        for name in ("quickstart", "ikonos_tdi_scan", "ikonos_tdi_jitter", "wheel_khz",
                     "long_stare", "seed_device", "optical"):
            runs[name] = _run(_scenario(name, product=SMALL_PRODUCT), out, name)
    rest = restoration()
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    md = ["## Geometry: each line's offset on the nominal grid against the camera model "
          "(RMS about the mean, px)", "", *geometry_rows(runs), "",
          "## Image quality (slanted-square target; SSIM on the scene)", "",
          *quality_rows(runs), "",
          "## Restoration of a 1 px linear smear at SNR 50 (known PSF)", "",
          "| figure | value |", "|---|---|",
          *(f"| {k} | {v} |" for k, v in rest.items()), "",
          f"Peak memory of this process: {peak_gb:.2f} GB"]
    text = "\n".join(md) + "\n"
    (out / "product.md").write_text(text)
    write_json(out / "product.json", {"runs": {k: {"wall_s": v["wall_s"], "product":
                                                   v["metrics"]["product"]}
                                               for k, v in runs.items()},
                                      "restoration": rest, "peak_rss_gb": peak_gb})
    print(text)


if __name__ == "__main__":
    main()

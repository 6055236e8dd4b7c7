"""Correlator benchmark: accuracy, validity and speed against the peers, on the same pairs.

Run by ``imc bench correlator`` (and ``benchmarks/bench_correlator.py``). Pairs come from
:func:`correlator.testimages.texture_pairs` (band-limited textures, mean 100, exact Fourier
shifts, independent noise on both images, SNR = mean / sigma as in the seed paper).

Definitions, per row:

- success: flagged valid and |error| < 0.5 px on both axes (peers have no validity flag: every
  result counts as flagged);
- false-valid: flagged valid with an error >= 0.5 px (a defect);
- RMS: per-axis RMS error over successful pairs, px; ``rms_common`` over the pairs every row of
  the table got right;
- bias: the larger per-axis mean error over successful pairs, px;
- RMS/CRLB: RMS over the RMS of the textbook bound 2 sigma^2 (sum g g^T)^-1 of the same pairs;
- pairs/s: independent pairs (each reference new), wall clock, this machine.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from correlator.core import Correlator, measure_shift
from correlator.testimages import MEAN_LEVEL, crlb_px, texture_pairs

Estimator = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def ours(**options) -> Estimator:
    """imcsim's correlator with the given options -> (shift, valid)."""
    def run(ref, cur):
        r = measure_shift(ref, cur, **options)
        return r.shift, r.valid
    return run


def peers() -> dict[str, Estimator]:
    """scikit-image and OpenCV estimators, where installed (the ``bench`` extra)."""
    out: dict[str, Estimator] = {}
    try:
        from skimage.registration import phase_cross_correlation

        def skimage_run(ref, cur):
            # skimage returns the shift that registers moving (cur) onto reference: -d
            s = np.array([phase_cross_correlation(r, c, upsample_factor=100,
                                                  normalization=None)[0]
                          for r, c in zip(ref, cur, strict=True)])
            return -s, np.ones(len(ref), bool)

        out["scikit-image phase_cross_correlation (upsample 100)"] = skimage_run
    except ImportError:
        pass
    try:
        import cv2

        def cv_run(ref, cur, window=False):
            win = cv2.createHanningWindow(ref.shape[1:][::-1], cv2.CV_64F) if window else None
            s = []
            for r, c in zip(ref.astype(np.float64), cur.astype(np.float64), strict=True):
                (dx, dy), _ = cv2.phaseCorrelate(r, c, win)
                s.append((dy, dx))
            return np.array(s), np.ones(len(ref), bool)

        out["OpenCV phaseCorrelate"] = cv_run
        out["OpenCV phaseCorrelate + Hann"] = lambda r, c: cv_run(r, c, True)
    except ImportError:
        pass
    return out


def score(shift, valid, d, crlb) -> dict:
    """Success, false-valid, RMS, bias and RMS/CRLB of one estimator on one set of pairs."""
    err = shift - d
    ok = valid & np.all(np.abs(err) < 0.5, axis=1)
    out = {"success_pct": 100.0 * ok.mean(), "false_valid_pct": 100.0 * (valid & ~ok).mean()}
    if ok.any():
        rms = np.sqrt(np.mean(err[ok] ** 2, axis=0))
        out.update(rms_px=float(np.sqrt(np.mean(rms**2))),
                   bias_px=float(np.abs(err[ok].mean(axis=0)).max()),
                   rms_over_crlb=float(np.sqrt(np.mean(rms**2))
                                       / np.sqrt(np.mean(crlb[ok] ** 2))))
    else:
        out.update(rms_px=float("nan"), bias_px=float("nan"), rms_over_crlb=float("nan"))
    return out, ok


def timed(fn: Estimator, ref, cur):
    fn(ref[:4], cur[:4])  # warm-up (imports, plans)
    t0 = time.perf_counter()
    shift, valid = fn(ref, cur)
    return shift, valid, len(ref) / (time.perf_counter() - t0)


def method_table(n: int, block_px: int, snr: float, texture: str, rng, with_peers=True):
    """Every method of ours and every peer on the same n pairs -> list of rows."""
    ref, cur, d, clean = texture_pairs(n, block_px, rng, snr=snr, texture=texture,
                                       return_clean=True)
    crlb = crlb_px(clean, MEAN_LEVEL / snr)
    rows_in = {
        "imcsim jtc + fourier (precise)": ours(),
        "imcsim jtc + fourier (1 FFT/block)": ours(rewindow=False),
        "imcsim jtc + gradient (Lucas-Kanade)": ours(subpixel="gradient"),
        "imcsim jtc + centre of mass (paper)": ours(subpixel="com"),
        "imcsim xcorr + parabolic": ours(method="xcorr", subpixel="parabolic"),
        "imcsim phase + gaussian": ours(method="phase", subpixel="gaussian"),
        "imcsim jtc joint plane (fringe) + fourier": ours(joint_plane=True, jtc_filter="fringe"),
    }
    if with_peers:
        rows_in.update(peers())
    rows, oks = [], []
    for name, fn in rows_in.items():
        shift, valid, rate = timed(fn, ref, cur)
        sc, ok = score(shift, valid, d, crlb)
        rows.append({"estimator": name, "pairs_per_s": rate, **sc, "_err": shift - d})
        oks.append(ok)
    common = np.all(oks, axis=0)
    for row in rows:
        e = row.pop("_err")[common]
        row["rms_common_px"] = float(np.sqrt(np.mean(e**2))) if common.any() else float("nan")
    return rows, {"block_px": block_px, "snr": snr, "texture": texture, "pairs": n,
                  "crlb_px": float(np.sqrt(np.mean(crlb**2))),
                  "common_pairs": int(common.sum())}


def curves(n: int, blocks, snrs, texture: str, rng, with_peers=True):
    """RMS and success of ours (and the peers) over block size x SNR (the paper's curves)."""
    out = []
    pe = peers() if with_peers else {}
    pe = {k: v for k, v in pe.items() if "Hann" not in k}
    for b in blocks:
        for snr in snrs:
            ref, cur, d, clean = texture_pairs(n, b, rng, snr=snr, texture=texture,
                                               return_clean=True)
            crlb = crlb_px(clean, MEAN_LEVEL / snr)
            for name, fn in {"imcsim": ours(), **pe}.items():
                shift, valid = fn(ref, cur)
                sc, _ = score(shift, valid, d, crlb)
                out.append({"estimator": name, "block_px": b, "snr": snr,
                            "crlb_px": float(np.sqrt(np.mean(crlb**2))), **sc})
    return out


def noise_only(n: int, block_px: int, rng) -> float:
    """Valid flags (%) on pairs of independent noise images: the false-alarm rate."""
    a = rng.normal(MEAN_LEVEL, 10.0, (n, block_px, block_px))
    b = rng.normal(MEAN_LEVEL, 10.0, (n, block_px, block_px))
    return 100.0 * float(measure_shift(a, b).valid.mean())


def tracking_speed(block_px: int, n_blocks: int, repeats: int, rng) -> list[dict]:
    """Correlations/s against fixed references (spectra reused), fast and precise, 1-2 threads."""
    ref, cur, _ = texture_pairs(n_blocks, block_px, rng, snr=10.0)
    rows = []
    for rewindow in (False, True):
        for workers in (1, -1):
            c = Correlator(ref, rewindow=rewindow, workers=workers)
            c.measure(cur)
            t0 = time.perf_counter()
            for _ in range(repeats):
                c.measure(cur)
            rate = repeats * n_blocks / (time.perf_counter() - t0)
            rows.append({"mode": "precise" if rewindow else "1 FFT/block",
                         "threads": "all" if workers == -1 else 1, "block_px": block_px,
                         "correlations_per_s": rate})
    return rows


def markdown(results: dict) -> str:
    """The benchmark tables as Markdown."""
    lines = []
    for tab in results["method_tables"]:
        m = tab["meta"]
        lines += [f"### {m['block_px']}x{m['block_px']}, SNR {m['snr']:g}, {m['texture']} "
                  f"texture, {m['pairs']} pairs within +-4 px (CRLB {m['crlb_px']:.4f} px)", "",
                  "| estimator | RMS (px) | RMS/CRLB | RMS on common pairs | success | "
                  "false-valid | bias (px) | pairs/s |", "|---|---|---|---|---|---|---|---|"]
        for r in tab["rows"]:
            lines.append(f"| {r['estimator']} | {r['rms_px']:.4f} | {r['rms_over_crlb']:.2f} | "
                         f"{r['rms_common_px']:.4f} | {r['success_pct']:.1f} % | "
                         f"{r['false_valid_pct']:.1f} % | {r['bias_px']:.4f} | "
                         f"{r['pairs_per_s']:.0f} |")
        lines.append("")
    lines += ["### Tracking (references fixed, spectra reused)", "",
              "| block | mode | threads | correlations/s |", "|---|---|---|---|"]
    for r in results["tracking"]:
        lines.append(f"| {r['block_px']}² | {r['mode']} | {r['threads']} | "
                     f"{r['correlations_per_s']:.0f} |")
    lines += ["", f"Noise-only pairs flagged valid: {results['noise_only_valid_pct']:.2f} %", ""]
    lines += ["### Block size x SNR (imcsim default)", "",
              "| block | SNR | CRLB (px) | RMS (px) | success | false-valid |",
              "|---|---|---|---|---|---|"]
    for r in results["curves"]:
        if r["estimator"] == "imcsim":
            lines.append(f"| {r['block_px']} | {r['snr']:g} | {r['crlb_px']:.4f} | "
                         f"{r['rms_px']:.4f} | {r['success_pct']:.1f} % | "
                         f"{r['false_valid_pct']:.1f} % |")
    return "\n".join(lines) + "\n"


def plots(results: dict, out: Path) -> list[Path]:
    """PNG plots of the noise and block-size curves (needs matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = results["curves"]
    files = []
    names = sorted({r["estimator"] for r in rows}, key=lambda s: (s != "imcsim", s))
    blocks = sorted({r["block_px"] for r in rows})
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for b in blocks:
        for name in names:
            sel = [r for r in rows if r["block_px"] == b and r["estimator"] == name]
            snr = [r["snr"] for r in sel]
            style = "-o" if name == "imcsim" else ":x"
            axes[0].loglog(snr, [r["rms_px"] for r in sel], style, ms=4,
                           label=f"{name} {b}²" if name == "imcsim" or b == blocks[-1] else None)
            if name == "imcsim":
                axes[0].loglog(snr, [r["crlb_px"] for r in sel], "--", lw=0.8, color="grey")
                axes[1].semilogx(snr, [r["success_pct"] for r in sel], style, ms=4,
                                 label=f"{b}²")
    axes[0].set(xlabel="SNR (mean / sigma)", ylabel="RMS error on successful pairs, px",
                title="Noise curve (dashed: CRLB)")
    axes[0].legend(fontsize=7)
    axes[1].set(xlabel="SNR (mean / sigma)", ylabel="success, %", title="Detection")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    p = out / "noise_curve.png"
    fig.savefig(p, dpi=110)
    files.append(p)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    snrs = sorted({r["snr"] for r in rows})
    for snr in snrs:
        sel = [r for r in rows if r["snr"] == snr and r["estimator"] == "imcsim"]
        ax.loglog([r["block_px"] for r in sel], [r["rms_px"] for r in sel], "-o", ms=4,
                  label=f"SNR {snr:g}")
    ax.set(xlabel="block size, px", ylabel="RMS error, px", title="Block-size curve (imcsim)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    p = out / "block_size_curve.png"
    fig.savefig(p, dpi=110)
    files.append(p)
    plt.close(fig)
    return files


def run(out: Path, pairs: int = 300, quick: bool = False, seed: int = 0,
        log: Callable[[str], None] = print) -> dict:
    """Run every table; write correlator.json, correlator.md and the PNGs under ``out``."""
    from imc.io import atomic_write, write_json

    rng = np.random.default_rng(seed)
    out.mkdir(parents=True, exist_ok=True)
    tables = []
    for block, snr, tex in ((128, 10.0, "strong"), (128, 10.0, "medium"), (128, 1.6, "urban"),
                            (128, 1.6, "strong")):
        log(f"methods at {block}², SNR {snr:g}, {tex} texture ...")
        rows, meta = method_table(pairs, block, snr, tex, rng)
        tables.append({"meta": meta, "rows": rows})
    log("tracking speed ...")
    tracking = tracking_speed(128, 64, 3 if quick else 10, rng)
    log("noise-only false alarms ...")
    fa = noise_only(200 if quick else 1000, 128, rng)
    log("block size x SNR curves ...")
    blocks = (32, 64, 128) if quick else (32, 64, 128, 256)
    snrs = (0.5, 1.6, 10.0, 100.0) if quick else (0.5, 1.0, 1.6, 3.0, 10.0, 30.0, 100.0)
    cv = curves(max(50, pairs // 3), blocks, snrs, "strong", rng)
    results = {"method_tables": tables, "tracking": tracking, "noise_only_valid_pct": fa,
               "curves": cv}
    write_json(out / "correlator.json", results)
    md = markdown(results)
    atomic_write(out / "correlator.md", lambda p: p.write_text(md))
    try:
        files = plots(results, out)
        log("plots: " + ", ".join(str(f) for f in files))
    except ImportError:
        log("matplotlib not installed (pip install -e '.[bench]'): no PNG plots")
    log(md)
    return results


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
- pairs/s: independent pairs (each reference new), wall clock, this machine (the speed table
  below is the careful comparison).

Speed table (:func:`speed_table`): 128^2 pairs at SNR 10, every figure the median of several
timed runs made in the same process (the best run beside it: what a quiet machine gives; a
shared VM's neighbours move the median by up to 30 %): ours tracking (references fixed, 64
blocks per call; with and without a trusted prediction), ours on independent pairs
(``measure_shift`` on stacks of 256), the peers one pair per call on one thread and on a pool
of as many threads as cores (OpenCV ``phaseCorrelate`` float64 with its Hann window made once;
scikit-image ``phase_cross_correlation``), and the FFT bound: one forward and one inverse 128^2
transform per pair with our backend. Natural textures (:func:`natural_tables`, needs
scikit-image): photographs of ``skimage.data`` scaled to a std of 12 % of their mean
(coverage at SNR 10), and the two most textured ones at their own contrast at SNR 1.6 (RMS
over all pairs).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from correlator import fftbackend
from correlator.bounds import correlation_bound_px, crlb_px
from correlator.core import Correlator, measure_shift
from correlator.testimages import MEAN_LEVEL, image_pairs, texture_pairs

Estimator = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def ours(**options) -> Estimator:
    """imcsim's correlator with the given options -> (shift, valid)."""
    def run(ref, cur):
        r = measure_shift(ref, cur, **options)
        return r.shift, r.valid
    return run


def _per_pair(one: Callable, threads: int) -> Estimator:
    """An estimator calling ``one(ref, cur) -> (d_row, d_col)`` once per pair, on the calling
    thread or on a pool of ``threads`` (made once, as a user's service would)."""
    pool = ThreadPoolExecutor(threads) if threads > 1 else None

    def run(ref, cur):
        pairs = list(zip(ref, cur, strict=True))
        # one BLAS thread per caller thread (scikit-image's upsampling is a matrix product)
        with threadpool_limits(1, user_api="blas"):
            out = (list(pool.map(lambda rc: one(*rc), pairs)) if pool
                   else [one(r, c) for r, c in pairs])
        return np.array(out, dtype=np.float64).reshape(-1, 2), np.ones(len(ref), bool)

    return run


def peers(threads: int = 1, hann: bool | None = None) -> dict[str, Estimator]:
    """scikit-image and OpenCV estimators, where installed (the ``bench`` extra), one pair per
    call on one thread or on a pool of ``threads``. OpenCV runs in its native float64 with its
    own parallelism off and, with ``hann``, the Hann window made once per block shape; None:
    both with and without the window."""
    out: dict[str, Estimator] = {}
    pool = f", {threads}-thread pool" if threads > 1 else ""
    try:
        from skimage.registration import phase_cross_correlation

        def skimage_one(r, c):
            # skimage returns the shift that registers moving (cur) onto reference: -d
            return -phase_cross_correlation(r, c, upsample_factor=100, normalization=None)[0]

        out[f"scikit-image phase_cross_correlation (upsample 100){pool}"] = _per_pair(
            skimage_one, threads)
    except ImportError:
        pass
    try:
        import cv2

        cv2.setNumThreads(1)
        windows: dict[tuple, np.ndarray] = {}

        def cv_one(r, c, window):
            win = None
            if window:
                key = r.shape
                if key not in windows:
                    windows[key] = cv2.createHanningWindow(r.shape[::-1], cv2.CV_64F)
                win = windows[key]
            (dx, dy), _ = cv2.phaseCorrelate(np.asarray(r, np.float64), np.asarray(c, np.float64),
                                             win)
            return dy, dx

        for window in ((False, True) if hann is None else (hann,)):
            name = "OpenCV phaseCorrelate" + (" + Hann" if window else "") + pool
            out[name] = _per_pair(lambda r, c, w=window: cv_one(r, c, w), threads)
    except ImportError:
        pass
    return out


def score(shift, valid, d, crlb, corr_bound=None) -> dict:
    """Success, false-valid, RMS, bias, RMS/CRLB and RMS / correlation bound (the least a
    correlation estimator reaches, :func:`correlation_bound_px`) of one estimator on one set
    of pairs."""
    err = shift - d
    ok = valid & np.all(np.abs(err) < 0.5, axis=1)
    out = {"success_pct": 100.0 * ok.mean(), "false_valid_pct": 100.0 * (valid & ~ok).mean()}
    if ok.any():
        rms = np.sqrt(np.mean(err[ok] ** 2, axis=0))
        out.update(rms_px=float(np.sqrt(np.mean(rms**2))),
                   bias_px=float(np.abs(err[ok].mean(axis=0)).max()),
                   rms_over_crlb=float(np.sqrt(np.mean(rms**2))
                                       / np.sqrt(np.mean(crlb[ok] ** 2))))
        if corr_bound is not None:
            out["rms_over_corr_bound"] = float(np.sqrt(np.mean(rms**2))
                                               / np.sqrt(np.mean(corr_bound[ok] ** 2)))
    else:
        out.update(rms_px=float("nan"), bias_px=float("nan"), rms_over_crlb=float("nan"),
                   rms_over_corr_bound=float("nan"))
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
    corr = correlation_bound_px(clean, MEAN_LEVEL / snr)
    rows_in = {
        "imcsim jtc + fourier (default)": ours(),
        "imcsim jtc + fourier (precise)": ours(rewindow=True),
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
        sc, ok = score(shift, valid, d, crlb, corr)
        rows.append({"estimator": name, "pairs_per_s": rate, **sc, "_err": shift - d})
        oks.append(ok)
    common = np.all(oks, axis=0)
    for row in rows:
        e = row.pop("_err")[common]
        row["rms_common_px"] = float(np.sqrt(np.mean(e**2))) if common.any() else float("nan")
    return rows, {"block_px": block_px, "snr": snr, "texture": texture, "pairs": n,
                  "crlb_px": float(np.sqrt(np.mean(crlb**2))),
                  "corr_bound_px": float(np.sqrt(np.mean(corr**2))),
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


#: prediction error (px, per axis, 1 sigma) of the tracking runs that trust a prediction
PRED_SIGMA_PX = 0.2
#: natural textures: photographs of skimage.data (grey or RGB averaged)
PHOTOS = ("camera", "astronaut", "moon", "coffee", "chelsea", "brick", "grass", "gravel")
#: the well-textured ones (SNR 1.6 table)
TEXTURED_PHOTOS = ("grass", "gravel")


def _rates(fn: Callable[[], object], n: int, repeats: int) -> tuple[float, float]:
    """(n / the median, n / the least) wall time of ``repeats`` calls of fn (after one warm-up
    call): the median is the figure; the best shows what a quiet machine gives."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return n / float(np.median(times)), n / float(np.min(times))


def speed_table(rng, repeats: int = 7, block_px: int = 128, n_track: int = 64,
                n_pairs: int = 256) -> list[dict]:
    """Pairs (or correlations) per second of ours and the peers on the same 128^2 pairs at
    SNR 10, all cores, medians of ``repeats`` runs, and the FFT bound (see the module doc)."""
    cores = os.cpu_count() or 1
    ref, cur, d = texture_pairs(n_pairs, block_px, rng, snr=10.0)
    pred = d + rng.normal(0.0, PRED_SIGMA_PX, d.shape)
    rows = []

    def add(name, kind, threads, rates, note=""):
        rows.append({"estimator": name, "kind": kind, "threads": threads, "block_px": block_px,
                     "per_s": rates[0], "per_s_best": rates[1], "note": note})

    rt, ct, pt = ref[:n_track], cur[:n_track], pred[:n_track]
    for threads in sorted({cores, 1}, reverse=True):
        workers = -1 if threads == cores else 1
        for rewindow in (False, None, True):
            mode = {None: "default", True: "precise", False: "1 FFT/block"}[rewindow]
            for trusted in (False, True):
                c = Correlator(rt, rewindow=rewindow, workers=workers,
                               trust_prediction_px=1.0 if trusted else None)
                call = ((lambda c=c: c.measure(ct, predicted=pt)) if trusted
                        else (lambda c=c: c.measure(ct)))
                note = (f"prediction trusted (error {PRED_SIGMA_PX} px rms)" if trusted
                        else "integer search")
                add(f"imcsim tracking, {mode}", "tracking", threads,
                    _rates(call, n_track, repeats), note)
        for rewindow in (False, None, True):
            mode = {None: "default", True: "precise", False: "1 FFT/block"}[rewindow]
            add(f"imcsim measure_shift, {mode}", "independent pairs", threads,
                _rates(lambda rw=rewindow, wk=workers: measure_shift(
                    ref, cur, rewindow=rw, workers=wk), n_pairs, repeats),
                f"{n_pairs} pairs per call")
    r64, c64 = ref.astype(np.float64), cur.astype(np.float64)  # the peers' native type
    for threads in sorted({1, cores}):
        for name, fn in peers(threads, hann=True).items():
            n = n_pairs if "OpenCV" in name else n_pairs // 4  # scikit-image is slow
            add(name, "independent pairs", threads,
                _rates(lambda fn=fn, n=n: fn(r64[:n], c64[:n]), n, repeats),
                "one pair per call")
    # the FFT bound: one forward and one inverse transform per pair, our backend
    x = fftbackend.empty(ref.shape, np.float32)
    x[...] = ref

    def ffts(part):
        spec = fftbackend.rfft2(x[part])
        fftbackend.irfft2(spec, x.shape[1:])

    for threads in sorted({1, cores}):
        parts = [slice(a, b) for a, b in zip(np.linspace(0, n_pairs, threads + 1).astype(int)[:-1],
                                             np.linspace(0, n_pairs, threads + 1).astype(int)[1:],
                                             strict=True)]
        with ThreadPoolExecutor(threads) as ex:
            rate = _rates(lambda ex=ex, parts=parts: list(ex.map(ffts, parts)), n_pairs,
                          repeats)
        add(f"FFT bound ({fftbackend.backend()} float32)", "bound", threads, rate,
            "1 forward + 1 inverse per pair")
    return rows


def photos(names) -> list[np.ndarray]:
    """The named skimage.data photographs as grey float arrays."""
    import skimage.data

    out = []
    for name in names:
        im = np.asarray(getattr(skimage.data, name)(), dtype=np.float64)
        out.append(im.mean(axis=-1) if im.ndim == 3 else im)
    return out


def natural_tables(n: int, rng, block_px: int = 128) -> dict:
    """Coverage on low-contrast photographs (std 12 % of the mean, SNR 10) and accuracy over all
    pairs on the textured ones at SNR 1.6, ours and the peers on the same pairs."""
    low = [(im - im.mean()) / im.std() * 0.12 * MEAN_LEVEL + MEAN_LEVEL
           for im in photos(PHOTOS)]
    ref, cur, d = image_pairs(low, n, block_px, rng, snr=10.0)
    est = {"imcsim (default)": ours(), **peers(1, hann=None)}
    cover = []
    for name, fn in est.items():
        shift, valid = fn(ref, cur)
        err = np.abs(shift - d).max(axis=1)
        cover.append({"estimator": name, "within_pct": 100.0 * float((err < 0.5).mean()),
                      "valid_pct": 100.0 * float(valid.mean()),
                      "valid_within_pct": 100.0 * float((valid & (err < 0.5)).mean()),
                      "false_valid_pct": 100.0 * float((valid & (err >= 0.5)).mean())})
    ref, cur, d, clean = image_pairs(photos(TEXTURED_PHOTOS), n, block_px, rng, snr=1.6,
                                     return_clean=True)
    bound = float(np.sqrt(np.mean(crlb_px(clean, MEAN_LEVEL / 1.6) ** 2)))
    corr = float(np.sqrt(np.mean(correlation_bound_px(clean, MEAN_LEVEL / 1.6) ** 2)))
    est = {"imcsim (default)": ours(), "imcsim precise": ours(rewindow=True),
           "imcsim 1 FFT/block": ours(rewindow=False),
           **peers(1, hann=None)}
    snr16 = []
    for name, fn in est.items():
        shift, valid = fn(ref, cur)
        err = shift - d
        snr16.append({"estimator": name, "rms_all_px": float(np.sqrt(np.mean(err**2))),
                      "valid_pct": 100.0 * float(valid.mean()),
                      "outliers": int((np.abs(err).max(axis=1) >= 0.5).sum())})
    return {"coverage": cover, "snr16": snr16, "pairs": n, "photos": PHOTOS,
            "textured": TEXTURED_PHOTOS, "snr16_crlb_px": bound, "snr16_corr_bound_px": corr}


def markdown(results: dict) -> str:
    """The benchmark tables as Markdown."""
    lines = []
    for tab in results["method_tables"]:
        m = tab["meta"]
        lines += [f"### {m['block_px']}x{m['block_px']}, SNR {m['snr']:g}, {m['texture']} "
                  f"texture, {m['pairs']} pairs within +-4 px (CRLB {m['crlb_px']:.4f} px, "
                  f"correlation bound {m.get('corr_bound_px', float('nan')):.4f} px)", "",
                  "| estimator | RMS (px) | RMS/CRLB | RMS / corr. bound | RMS on common pairs "
                  "| success | false-valid | bias (px) | pairs/s |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in tab["rows"]:
            lines.append(f"| {r['estimator']} | {r['rms_px']:.4f} | {r['rms_over_crlb']:.2f} | "
                         f"{r.get('rms_over_corr_bound', float('nan')):.2f} | "
                         f"{r['rms_common_px']:.4f} | {r['success_pct']:.1f} % | "
                         f"{r['false_valid_pct']:.1f} % | {r['bias_px']:.4f} | "
                         f"{r['pairs_per_s']:.0f} |")
        lines.append("")
    lines += ["### Speed, 128² pairs at SNR 10 (medians of repeated runs, this machine)", "",
              "| estimator | kind | threads | per second | best run | note |",
              "|---|---|---|---|---|---|"]
    for r in results["speed"]:
        lines.append(f"| {r['estimator']} | {r['kind']} | {r['threads']} | {r['per_s']:.0f} | "
                     f"{r.get('per_s_best', float('nan')):.0f} | {r['note']} |")
    nat = results.get("natural")
    if nat:
        lines += ["", f"### Low-contrast photographs (std 12 % of the mean), SNR 10, "
                      f"{nat['pairs']} pairs from {', '.join(nat['photos'])}", "",
                  "| estimator | within 0.5 px | flagged valid | valid and within | "
                  "false-valid |", "|---|---|---|---|---|"]
        for r in nat["coverage"]:
            lines.append(f"| {r['estimator']} | {r['within_pct']:.1f} % | {r['valid_pct']:.1f} % "
                         f"| {r['valid_within_pct']:.1f} % | {r['false_valid_pct']:.2f} % |")
        lines += ["", f"### Textured photographs ({', '.join(nat['textured'])}, own contrast), "
                      f"SNR 1.6: error over all pairs (CRLB {nat['snr16_crlb_px']:.4f} px, "
                      f"correlation bound {nat.get('snr16_corr_bound_px', float('nan')):.4f} px)",
                  "",
                  "| estimator | RMS over all pairs (px) | flagged valid | errors >= 0.5 px |",
                  "|---|---|---|---|"]
        for r in nat["snr16"]:
            lines.append(f"| {r['estimator']} | {r['rms_all_px']:.4f} | {r['valid_pct']:.1f} % | "
                         f"{r['outliers']} |")
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
    log("speed ...")
    speed = speed_table(rng, repeats=3 if quick else 7)
    log("natural textures ...")
    try:
        natural = natural_tables(max(100, pairs), rng)
    except ImportError:
        log("scikit-image not installed (pip install -e '.[bench]'): no natural textures")
        natural = None
    log("noise-only false alarms ...")
    fa = noise_only(200 if quick else 1000, 128, rng)
    log("block size x SNR curves ...")
    blocks = (32, 64, 128) if quick else (32, 64, 128, 256)
    snrs = (0.5, 1.6, 10.0, 100.0) if quick else (0.5, 1.0, 1.6, 3.0, 10.0, 30.0, 100.0)
    cv = curves(max(50, pairs // 3), blocks, snrs, "strong", rng)
    results = {"method_tables": tables, "speed": speed, "natural": natural,
               "noise_only_valid_pct": fa, "curves": cv}
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


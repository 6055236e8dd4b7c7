"""The Fourier estimator's accuracy against its bounds, before and after a change (issue 25).

Usage::

    python benchmarks/bench_estimator.py [--base DIR] [--pairs N] [--noise-pairs M]
        [--seed S] [--rounds R]

Runs the measurements below in a subprocess for each tree (``--base DIR``: an export of the
tree before the change, e.g. ``git archive wip-corr correlator imc | tar -x -C DIR``; and
this tree), on the same draws (same seed, same test-image code), and prints one table:

- strong and medium texture, 128^2, SNR 10: RMS over the valid pairs within 0.5 px against
  the Cramer-Rao bound (:func:`crlb_px`) and the correlation bound
  (:func:`correlation_bound_px`);
- well-textured photographs (skimage ``grass``, ``gravel``) at their own contrast, SNR 1.6:
  RMS over all pairs against the correlation bound;
- low-contrast photographs (the peer benchmark's natural set, std 12 % of the mean, SNR 10):
  valid and within 0.5 px, false-valid, and scikit-image's within 0.5 px on the same pairs;
- weak texture at SNR 10 and medium texture at SNR 3 (128^2): valid and within 0.5 px,
  false-valid, RMS over all pairs against the correlation bound;
- predicted against actual error (RMS error over RMS ``crlb`` of the valid pairs) over SNR;
- noise-only pairs flagged valid;
- speed of the default path (``measure_shift`` on 256 pairs, one thread), timed in
  alternating subprocesses of the two trees (``--rounds`` each; the best run of each: a
  shared machine's neighbours only slow a run down).

Two further modes of this tree alone (issue 35):

- ``--tracking``: the tracking path (one :class:`Correlator` of 64 fixed 128^2 references,
  all cores; strong, medium and a mixed batch, half strong and half smooth 1/f^2.5 texture
  of 8 % contrast), the default (adaptive) against the precise (``rewindow=True``) and the
  one-FFT (``rewindow=False``) paths, timed alternately in one process (``--rounds`` rounds;
  the medians and the median of the per-round ratios), with each path's RMS error over the
  Cramer-Rao bound and the fraction of blocks re-windowed, on the same pairs.
- ``--smooth``: validity on a family of smooth, low-contrast textures generated here
  (:func:`correlator.testimages.powerlaw_images`, 1/f^beta spectra, beta 2.5-3.5, several
  contrasts, 128^2, SNR 10): valid and within 0.5 px, false-valid (valid and 0.5 px or more
  off, over the valid) of the default, precise and one-FFT paths against scikit-image's
  ``phase_cross_correlation`` (upsample 100) within 0.5 px on the same pairs; and
  checkerboards and stripes (periodic, one-directional) flagged valid.
- ``--opencv``: the default path against OpenCV's ``phaseCorrelate`` with a Hann window (made
  once) on the same 128^2 pairs (strong and medium texture, SNR 10, shifts within +-4 px),
  timed alternately in one process, ``--rounds`` rounds (median and best): tracking (one
  :class:`Correlator` of 64 fixed references, batches of 64, both cores and one thread) and
  independent pairs (``measure_shift`` on 256 pairs, both cores and one thread) against
  OpenCV one pair per call on one thread and on a pool of two; the medians of the per-round
  ratios to OpenCV's best of the two, and each one's RMS error over the Cramer-Rao bound.
  Needs ``cv2`` (the ``bench`` extra).
- ``--independent``: the same against OpenCV with independent pairs as a user meets them
  (issue 35): ``measure_shift`` on 256 pairs in batches of 64 (each pair its own reference),
  one thread and both cores, and tracking as in ``--opencv``, on the strong and medium
  textures and on natural photographs at their own contrast (:data:`PHOTOS`), SNR 10, shifts
  within +-4 px, every estimator alternated in one process (``--rounds`` rounds, median and
  best, the median of the per-round ratios to OpenCV's best of one thread and a pool of
  two), with the load average before and after; each one's RMS error over the Cramer-Rao
  bound (valid results within 0.5 px) and the fraction of pairs that took the
  common-content passes. Before/after a change: run it with ``PYTHONPATH`` set to each tree
  (the ratios to OpenCV, measured in the same process, are what compare). With ``--base
  DIR``: instead, the default path's accuracy on the same pairs through both trees
  (:func:`paired_default`: strong, medium, photographs, low-contrast photographs, the smooth
  1/f^beta family; valid and within 0.5 px, false-valid, RMS over the CRLB, re-windowed).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
SNR_GRID = (1.0, 1.6, 3.0, 10.0, 30.0)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else float("nan")


def accuracy(pairs: int, noise_pairs: int, seed: int, options: dict | None = None) -> dict:
    """Every accuracy figure of the tree on PYTHONPATH (see the module doc), the correlator
    run with ``options`` (:class:`CorrelatorOptions` fields) besides its defaults."""
    from functools import partial

    from correlator.bounds import correlation_bound_px, crlb_px
    from correlator.core import measure_shift as _measure_shift

    measure_shift = partial(_measure_shift, **(options or {}))
    from correlator.testimages import MEAN_LEVEL, image_pairs, texture_pairs
    from imc.studies.correlator_peers import PHOTOS, TEXTURED_PHOTOS, peers, photos

    rng = np.random.default_rng(seed)
    out: dict = {}
    for tex in ("strong", "medium"):
        ref, cur, d, clean = texture_pairs(pairs, 128, rng, snr=10.0, texture=tex,
                                           return_clean=True)
        r = measure_shift(ref, cur)
        err = r.shift - d
        ok = r.valid & (np.abs(err).max(axis=1) < 0.5)
        crlb = crlb_px(clean, MEAN_LEVEL / 10.0)
        corr = correlation_bound_px(clean, MEAN_LEVEL / 10.0)
        out[f"{tex}10"] = {"rms": _rms(err[ok]), "crlb": _rms(crlb[ok]), "corr": _rms(corr[ok]),
                           "valid_pct": 100.0 * float(ok.mean())}
    ref, cur, d, clean = image_pairs(photos(TEXTURED_PHOTOS), pairs, 128, rng, snr=1.6,
                                     return_clean=True)
    r = measure_shift(ref, cur)
    err = r.shift - d
    out["photo16"] = {"rms_all": _rms(err), "corr": _rms(correlation_bound_px(clean, 62.5)),
                      "crlb": _rms(crlb_px(clean, 62.5)),
                      "outliers": int((np.abs(err).max(axis=1) >= 0.5).sum())}
    low = [(im - im.mean()) / im.std() * 0.12 * MEAN_LEVEL + MEAN_LEVEL
           for im in photos(PHOTOS)]
    n_low = 3 * pairs
    ref, cur, d = image_pairs(low, n_low, 128, rng, snr=10.0)
    r = measure_shift(ref, cur)
    bad = np.abs(r.shift - d).max(axis=1) >= 0.5
    sk = [fn for name, fn in peers(1, hann=None).items() if name.startswith("scikit")]
    sk_within = float("nan")
    if sk:
        sk_within = 100.0 * float((np.abs(sk[0](ref, cur)[0] - d).max(axis=1) < 0.5).mean())
    out["lowcontrast"] = {"pairs": n_low,
                          "valid_within_pct": 100.0 * float((r.valid & ~bad).mean()),
                          "false_valid_pct": 100.0 * float((r.valid & bad).mean()),
                          "skimage_within_pct": sk_within}
    for key, tex, snr, n in (("weak10", "weak", 10.0, 3 * pairs),
                             ("medium3", "medium", 3.0, pairs)):
        ref, cur, d, clean = texture_pairs(n, 128, rng, snr=snr, texture=tex,
                                           return_clean=True)
        r = measure_shift(ref, cur)
        err = r.shift - d
        bad = np.abs(err).max(axis=1) >= 0.5
        out[key] = {"pairs": n, "valid_within_pct": 100.0 * float((r.valid & ~bad).mean()),
                    "false_valid_pct": 100.0 * float((r.valid & bad).mean()),
                    "rms_all": _rms(err),
                    "corr": _rms(correlation_bound_px(clean, MEAN_LEVEL / snr))}
    ratio = {}
    for tex in ("strong", "medium"):
        for snr in SNR_GRID:
            ref, cur, d = texture_pairs(pairs // 2, 128, rng, snr=snr, texture=tex)
            r = measure_shift(ref, cur)
            err = r.shift - d
            ok = r.valid & (np.abs(err).max(axis=1) < 0.5)
            ratio[f"{tex} {snr:g}"] = _rms(err[ok]) / _rms(r.crlb[ok]) if ok.any() else None
    out["pred_ratio"] = ratio
    valid = 0
    for _ in range(noise_pairs // 1000):
        a = rng.normal(MEAN_LEVEL, 10.0, (1000, 128, 128))
        b = rng.normal(MEAN_LEVEL, 10.0, (1000, 128, 128))
        valid += int(measure_shift(a, b).valid.sum())
    out["noise_only"] = {"pairs": 1000 * (noise_pairs // 1000), "valid": valid}
    import correlator

    out["tree"] = str(Path(correlator.__file__).parent)
    return out


def speed(n: int = 256, repeats: int = 5) -> float:
    """Best pairs/s of ``measure_shift`` (default options, one thread) on n pairs."""
    from correlator.core import measure_shift
    from correlator.testimages import texture_pairs

    ref, cur, _ = texture_pairs(n, 128, np.random.default_rng(7), snr=10.0)
    measure_shift(ref[:8], cur[:8], workers=1)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        measure_shift(ref, cur, workers=1)
        best = min(best, time.perf_counter() - t0)
    return n / best


PATHS = {"default": None, "precise": True, "1 FFT": False}


def tracking(pairs: int, rounds: int, seed: int) -> None:
    """Print the ``--tracking`` table (see the module doc)."""
    from correlator.bounds import crlb_px
    from correlator.core import Correlator
    from correlator.testimages import MEAN_LEVEL, image_pairs, powerlaw_images, texture_pairs

    rng = np.random.default_rng(seed)
    n_track = 64
    print("| texture (SNR 10), 64 blocks of 128^2 | path | correlations/s (median of "
          f"{rounds}) | best | RMS / CRLB | RMS (px) | re-windowed |")
    print("|---|---|---|---|---|---|---|")
    for tex in ("strong", "medium", "mixed"):
        if tex == "mixed":  # half strong, half smooth (1/f^2.5, contrast 8 %), interleaved
            a = texture_pairs(pairs // 2, 128, rng, snr=10.0, return_clean=True)
            b = image_pairs(powerlaw_images(8, 384, 2.5, rng), pairs - pairs // 2, 128, rng,
                            snr=10.0, contrast=0.08, return_clean=True)
            order = rng.permutation(pairs)
            ref, cur, d, clean = (np.concatenate([x, y])[order] for x, y in zip(a, b,
                                                                              strict=True))
        else:
            ref, cur, d, clean = texture_pairs(pairs, 128, rng, snr=10.0, texture=tex,
                                               return_clean=True)
        bound = crlb_px(clean, MEAN_LEVEL / 10.0)
        acc = {}
        for name, rw in PATHS.items():
            r = Correlator(ref, rewindow=rw).measure(cur)
            err = r.shift - d
            ok = r.valid & (np.abs(err).max(axis=1) < 0.5)
            acc[name] = (_rms(err[ok]) / _rms(bound[ok]), _rms(err[ok]), r.precise.mean())
        cs = {k: Correlator(ref[:n_track], rewindow=rw) for k, rw in PATHS.items()}
        for c in cs.values():
            c.measure(cur[:n_track])
        times = {k: [] for k in PATHS}
        for _ in range(rounds):  # alternated: a neighbour's load falls on every path alike
            for k, c in cs.items():
                t0 = time.perf_counter()
                c.measure(cur[:n_track])
                times[k].append(time.perf_counter() - t0)
        for k in PATHS:
            t = np.array(times[k])
            print(f"| {tex} | {k} | {n_track / np.median(t):,.0f} | {n_track / t.min():,.0f} | "
                  f"{acc[k][0]:.3f} | {acc[k][1]:.4f} | {100 * acc[k][2]:.0f} % |")
        ratio = np.array(times["precise"]) / np.array(times["default"])
        ratio_f = np.array(times["1 FFT"]) / np.array(times["default"])
        print(f"| {tex} | default / precise speed, median of per-round ratios | "
              f"{np.median(ratio):.2f}x | | | | |")
        print(f"| {tex} | default / 1 FFT speed, median of per-round ratios | "
              f"{np.median(ratio_f):.2f}x | | | | |")


def smooth(pairs: int, seed: int) -> None:
    """Print the ``--smooth`` table (see the module doc)."""
    from correlator.core import measure_shift
    from correlator.testimages import image_pairs, powerlaw_images
    from imc.studies.correlator_peers import peers

    sk = [fn for name, fn in peers(1, hann=None).items() if name.startswith("scikit")]
    rng = np.random.default_rng(seed)
    family = ((2.5, 0.05), (2.5, 0.08), (3.0, 0.15), (3.0, 0.3), (3.5, 0.3), (3.5, 0.6))
    names = list(PATHS) + (["scikit-image (within 0.5 px)"] if sk else [])
    print("| beta / contrast | " + " | ".join(
        f"{k}: valid & within / false-valid / re-windowed" if k in PATHS else k
        for k in names) + " |")
    print("|---|" + "---|" * len(names))
    pool = {k: np.zeros(3) for k in names}  # valid & within, valid & off, all
    for beta, contrast in family:
        ims = powerlaw_images(8, 384, beta, rng)
        ref, cur, d = image_pairs(ims, pairs, 128, rng, snr=10.0, contrast=contrast)
        cells = []
        for k in names:
            if k in PATHS:
                r = measure_shift(ref, cur, rewindow=PATHS[k])
                bad = np.abs(r.shift - d).max(axis=1) >= 0.5
                good, off = int((r.valid & ~bad).sum()), int((r.valid & bad).sum())
                cells.append(f"{100 * good / pairs:.1f} % / "
                             f"{100 * off / max(good + off, 1):.2f} % / "
                             f"{100 * r.precise.mean():.0f} %")
            else:
                s = sk[0](ref.astype(np.float64), cur.astype(np.float64))[0]
                good, off = int((np.abs(s - d).max(axis=1) < 0.5).sum()), 0
                cells.append(f"{100 * good / pairs:.1f} %")
            pool[k] += (good, off, pairs)
        print(f"| {beta} / {contrast} | " + " | ".join(cells) + " |")
    print("| pooled | " + " | ".join(
        f"{100 * p[0] / p[2]:.1f} % / {100 * p[1] / max(p[0] + p[1], 1):.2f} %"
        if k in PATHS else f"{100 * p[0] / p[2]:.1f} %" for k, p in pool.items()) + " |")
    # periodic and one-directional patterns: never valid
    yy, xx = np.mgrid[0:160, 0:160] + 0.5
    valid = {k: 0 for k in PATHS}
    total = 0
    for period in (6.0, 8.0, 11.0):
        checker = 100 + 20 * np.sign(np.sin(np.pi * yy / (period / 2))
                                     * np.sin(np.pi * xx / (period / 2)))
        stripes = 100 + 20 * np.sin(2 * np.pi * (xx + 0.3 * yy) / period)
        for img in (checker, stripes):
            for _ in range(10):
                dy, dx = rng.integers(-4, 5, 2)
                ref = img[16:144, 16:144] + rng.normal(0, 1.0, (4, 128, 128))
                cur = img[16 - dy:144 - dy, 16 - dx:144 - dx] + rng.normal(0, 1.0, (4, 128, 128))
                for k, rw in PATHS.items():
                    valid[k] += int(measure_shift(ref, cur, rewindow=rw).valid.sum())
                total += 4
    print("periodic / one-directional pairs flagged valid: " + ", ".join(
        f"{k} {v} of {total}" for k, v in valid.items()))


#: natural photographs of ``--independent`` (skimage.data, at their own contrast)
PHOTOS = ("camera", "astronaut", "coffee", "chelsea", "brick", "grass", "gravel")


def _opencv_rows(tex: str, cv: dict, rounds: int, rng: np.random.Generator,
                 batch: int | None = None) -> None:
    """The ``--opencv`` table's rows of one texture (see the module doc); ``batch``: the
    independent pairs in calls of this many (``--independent``; else one call of 256), and
    the texture may be ``photographs``."""
    from correlator.bounds import crlb_px
    from correlator.core import Correlator, measure_shift
    from correlator.testimages import MEAN_LEVEL, image_pairs, texture_pairs

    n_track, n_pairs = 64, 256
    if tex == "photographs":
        from imc.studies.correlator_peers import photos

        ref, cur, d, clean = image_pairs(photos(PHOTOS), n_pairs, 128, rng, snr=10.0,
                                         return_clean=True)
    else:
        ref, cur, d, clean = texture_pairs(n_pairs, 128, rng, snr=10.0, texture=tex,
                                           return_clean=True)
    bound = crlb_px(clean, MEAN_LEVEL / 10.0)
    r64, c64 = ref.astype(np.float64), cur.astype(np.float64)
    track = {w: Correlator(ref[:n_track], workers=w) for w in (-1, 1)}
    step = batch or n_pairs

    def pairs(workers: int):
        parts = [measure_shift(ref[i:i + step], cur[i:i + step], workers=workers)
                 for i in range(0, n_pairs, step)]
        return parts[0] if len(parts) == 1 else type(parts[0])(
            *(None if getattr(parts[0], f) is None
              else np.concatenate([getattr(p, f) for p in parts])
              for f in parts[0].__dataclass_fields__))

    per = f"batches of {step}" if batch else "256 pairs"
    calls = {
        "imcsim tracking, default, 2 threads": (lambda: track[-1].measure(cur[:n_track]),
                                                 n_track),
        "imcsim tracking, default, 1 thread": (lambda: track[1].measure(cur[:n_track]),
                                                n_track),
        f"imcsim measure_shift ({per}), default, 2 threads": (lambda: pairs(-1), n_pairs),
        f"imcsim measure_shift ({per}), default, 1 thread": (lambda: pairs(1), n_pairs),
    }
    for name, fn in cv.items():
        calls[name] = (lambda fn=fn: fn(r64, c64), n_pairs)
    acc, passes = {}, {}
    for name, (fn, n) in calls.items():  # also the warm-up call
        out = fn()
        shift = out.shift if hasattr(out, "shift") else out[0]
        valid = out.valid if hasattr(out, "valid") else np.ones(n, bool)
        ok = valid & (np.abs(shift - d[:n]).max(axis=1) < 0.5)
        acc[name] = _rms(shift[ok] - d[:n][ok]) / _rms(bound[:n][ok])
        passes[name] = (f"{100 * np.mean(out.precise):.0f} %"
                        if getattr(out, "precise", None) is not None else "-")
    rates = {k: [] for k in calls}
    for _ in range(rounds):  # alternated: a neighbour's load falls on every one alike
        for name, (fn, n) in calls.items():
            t0 = time.perf_counter()
            fn()
            rates[name].append(n / (time.perf_counter() - t0))
    best_cv = np.max([rates[k] for k in cv], axis=0)  # OpenCV's best of 1 / 2 per round
    for name in calls:
        r = np.array(rates[name])
        print(f"| {tex} | {name} | {np.median(r):,.0f} | {r.max():,.0f} | "
              f"{np.median(r / best_cv):.2f}x | {acc[name]:.3f} |"
              + (f" {passes[name]} |" if batch else ""))


def opencv(rounds: int, seed: int, independent: bool = False) -> None:
    """Print the ``--opencv`` (or ``--independent``) table (see the module doc)."""
    from imc.studies.correlator_peers import peers

    cv = {n: fn for t in (1, 2) for n, fn in peers(t, hann=True).items()
          if n.startswith("OpenCV")}
    if not cv:
        raise SystemExit("--opencv needs cv2 (pip install opencv-python-headless)")
    rng = np.random.default_rng(seed)
    import correlator

    print(f"tree: {Path(correlator.__file__).parent}; load average before: {os.getloadavg()}")
    print("| texture (SNR 10), 128^2 | estimator | per s (median of "
          f"{rounds}) | best | ÷ OpenCV's best (median of per-round ratios) | RMS / CRLB |"
          + (" re-windowed |" if independent else ""))
    print("|---|---|---|---|---|---|" + ("---|" if independent else ""))
    for tex in ("strong", "medium", "photographs") if independent else ("strong", "medium"):
        _opencv_rows(tex, cv, rounds, rng, batch=64 if independent else None)
    print(f"load average after: {os.getloadavg()}")


def paired_default(pairs: int, seed: int) -> dict:
    """The default path's accuracy on fixed draws (``--independent --base``): per set, the
    fraction valid and within 0.5 px, false-valid (over the valid), RMS of the valid
    results within 0.5 px (and over the CRLB where the clean blocks are known) and the
    fraction re-windowed."""
    from correlator.bounds import crlb_px
    from correlator.core import measure_shift
    from correlator.testimages import MEAN_LEVEL, image_pairs, powerlaw_images, texture_pairs
    from imc.studies.correlator_peers import PHOTOS as LOW
    from imc.studies.correlator_peers import photos

    out = {}

    def score(name, ref, cur, d, clean=None, snr=10.0):
        r = measure_shift(ref, cur)
        err = r.shift - d
        bad = np.abs(err).max(axis=1) >= 0.5
        ok = r.valid & ~bad
        row = {"valid_within": float(ok.mean()),
               "false_valid": float((r.valid & bad).sum() / max(r.valid.sum(), 1)),
               "rms_px": _rms(err[ok]), "precise": float(r.precise.mean())}
        if clean is not None:
            row["rms_over_crlb"] = _rms(err[ok]) / _rms(crlb_px(clean, MEAN_LEVEL / snr)[ok])
        out[name] = row

    rng = np.random.default_rng(seed)
    for t in ("strong", "medium"):
        ref, cur, d, clean = texture_pairs(pairs, 128, rng, snr=10.0, texture=t,
                                           return_clean=True)
        score(t, ref, cur, d, clean)
    for names, snr in ((("grass", "gravel"), 10.0), (("brick", "camera", "astronaut"), 10.0),
                       (("grass", "gravel"), 1.6)):
        ref, cur, d, clean = image_pairs(photos(names), pairs, 128, rng, snr=snr,
                                         return_clean=True)
        score(f"{' + '.join(names)}, SNR {snr:g}", ref, cur, d, clean, snr)
    low = [(im - im.mean()) / im.std() * 0.12 * MEAN_LEVEL + MEAN_LEVEL for im in photos(LOW)]
    ref, cur, d = image_pairs(low, pairs, 128, rng, snr=10.0)
    score("low-contrast photographs", ref, cur, d)
    for beta, c in ((2.5, 0.05), (2.5, 0.08), (3.0, 0.15), (3.0, 0.3), (3.5, 0.3), (3.5, 0.6)):
        ref, cur, d = image_pairs(powerlaw_images(8, 384, beta, rng), pairs // 2, 128, rng,
                                  snr=10.0, contrast=c)
        score(f"1/f^{beta}, contrast {c}", ref, cur, d)
    return out


def _sub(tree: Path, *args: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, __file__, "--child", *args], env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def _f(x, fmt: str = ".4f") -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, fmt)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, help="the tree before the change (an export)")
    ap.add_argument("--pairs", type=int, default=400)
    ap.add_argument("--noise-pairs", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--speed-only", action="store_true", help="only the speed rounds")
    ap.add_argument("--options", default="{}", help="JSON correlator options for the 'after' "
                    "tree, e.g. '{\"false_valid_rate\": 0.005}'")
    ap.add_argument("--smooth-fraction", type=float, default=None,
                    help="correlator.core.SMOOTH_FRACTION for the 'after' tree (the power "
                    "average's box over the block size)")
    ap.add_argument("--tracking", action="store_true", help="the tracking paths' speed and "
                    "accuracy, this tree alone (see the module doc)")
    ap.add_argument("--smooth", action="store_true", help="validity on generated smooth "
                    "textures against scikit-image, this tree alone")
    ap.add_argument("--opencv", action="store_true", help="the default path's speed against "
                    "OpenCV's phaseCorrelate on the same pairs, this tree alone")
    ap.add_argument("--independent", action="store_true", help="independent pairs in "
                    "batches of 64 and tracking against OpenCV, on synthetic textures and "
                    "photographs, this tree alone (see the module doc)")
    ap.add_argument("--child", nargs="*")
    a = ap.parse_args()
    if a.independent and a.base is not None:
        args = ("indacc", "--pairs", str(a.pairs), "--seed", str(a.seed))
        res = {k: _sub(t, *args) for k, t in (("before", a.base), ("after", HERE))}
        print("| pairs (128^2) | valid & within 0.5 px | false-valid | RMS (px) | RMS / CRLB | "
              "re-windowed |  (before / after)")
        print("|---|---|---|---|---|---|")
        for k, b in res["before"].items():
            f = res["after"][k]
            crlb = (f"{b['rms_over_crlb']:.4f} / {f['rms_over_crlb']:.4f}"
                    if "rms_over_crlb" in b else "-")
            print(f"| {k} | {100 * b['valid_within']:.2f} / {100 * f['valid_within']:.2f} % | "
                  f"{100 * b['false_valid']:.2f} / {100 * f['false_valid']:.2f} % | "
                  f"{b['rms_px']:.4f} / {f['rms_px']:.4f} | {crlb} | "
                  f"{100 * b['precise']:.1f} / {100 * f['precise']:.1f} % |")
        return
    if a.opencv or a.independent:
        opencv(a.rounds, a.seed, independent=a.independent)
        return
    if a.tracking or a.smooth:
        if a.tracking:
            tracking(a.pairs, a.rounds, a.seed)
        if a.smooth:
            smooth(a.pairs, a.seed)
        return
    if a.child is not None:
        if a.smooth_fraction is not None:
            import correlator.core

            correlator.core.SMOOTH_FRACTION = a.smooth_fraction
        if a.child[:1] == ["indacc"]:
            res = paired_default(a.pairs, a.seed)
        elif a.child[:1] == ["accuracy"]:
            res = accuracy(a.pairs, a.noise_pairs, a.seed, json.loads(a.options))
        else:
            res = {"pairs_per_s": speed()}
        print(json.dumps(res))
        return
    trees = {"after": HERE} if a.base is None else {"before": a.base, "after": HERE}
    args = ("accuracy", "--pairs", str(a.pairs), "--noise-pairs", str(a.noise_pairs),
            "--seed", str(a.seed))
    rates = {k: [] for k in trees}
    for _ in range(a.rounds):
        for k, t in trees.items():
            rates[k].append(_sub(t, "speed")["pairs_per_s"])
    names = list(trees)
    if a.speed_only:
        print(" ".join(f"{k}: best {max(rates[k]):.0f} pairs/s, median "
                       f"{np.median(rates[k]):.0f}" for k in names) + f" (rounds: {rates})")
        if len(names) == 2:
            print(f"speed ratio after/before: best {max(rates['after']) / max(rates['before']):.3f}"
                  f", median {np.median(rates['after']) / np.median(rates['before']):.3f}")
        return
    extra = ("--options", a.options) + (() if a.smooth_fraction is None
                                        else ("--smooth-fraction", str(a.smooth_fraction)))
    acc = {k: _sub(t, *args, *(extra if k == "after" else ())) for k, t in trees.items()}
    print("| figure | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))

    def row(label, fn):
        print(f"| {label} | " + " | ".join(fn(acc[k]) for k in names) + " |")

    for tex in ("strong", "medium"):
        row(f"{tex} SNR 10: RMS (px) / RMS/CRLB / RMS/corr. bound",
            lambda r, t=tex: f"{_f(r[t + '10']['rms'])} / "
                             f"{_f(r[t + '10']['rms'] / r[t + '10']['crlb'], '.3f')} / "
                             f"{_f(r[t + '10']['rms'] / r[t + '10']['corr'], '.3f')}")
    row("grass+gravel SNR 1.6: RMS all pairs (px) / over corr. bound / errors >= 0.5 px",
        lambda r: f"{_f(r['photo16']['rms_all'])} / "
                  f"{_f(r['photo16']['rms_all'] / r['photo16']['corr'], '.3f')} / "
                  f"{r['photo16']['outliers']}")
    row("low-contrast photos SNR 10: valid & within 0.5 px / false-valid / scikit-image within",
        lambda r: f"{_f(r['lowcontrast']['valid_within_pct'], '.1f')} % / "
                  f"{_f(r['lowcontrast']['false_valid_pct'], '.2f')} % / "
                  f"{_f(r['lowcontrast']['skimage_within_pct'], '.1f')} %")
    for key, label in (("weak10", "weak texture SNR 10"), ("medium3", "medium texture SNR 3")):
        row(f"{label}: valid & within 0.5 px / false-valid / RMS all pairs over corr. bound",
            lambda r, k=key: f"{_f(r[k]['valid_within_pct'], '.1f')} % / "
                             f"{_f(r[k]['false_valid_pct'], '.2f')} % / "
                             f"{_f(r[k]['rms_all'] / r[k]['corr'], '.3f')}")
    for key in acc[names[0]]["pred_ratio"]:
        row(f"actual / predicted error, {key}", lambda r, k=key: _f(r["pred_ratio"][k], ".3f"))
    row("noise-only pairs flagged valid",
        lambda r: f"{r['noise_only']['valid']} of {r['noise_only']['pairs']}")
    print("| default path, one thread, pairs/s (best of rounds) | "
          + " | ".join(f"{max(rates[k]):.0f}" for k in names) + " |")
    if len(names) == 2:
        print(f"speed ratio after/before: best {max(rates['after']) / max(rates['before']):.3f}"
              f", median {np.median(rates['after']) / np.median(rates['before']):.3f} "
              f"(rounds: {rates})")
    ref = acc[names[0]]
    print("trees: " + ", ".join(f"{k} {acc[k]['tree']}" for k in names))
    print(f"bounds: strong 10 CRLB {ref['strong10']['crlb']:.4f}, "
          f"corr {ref['strong10']['corr']:.4f}; "
          f"medium 10 CRLB {ref['medium10']['crlb']:.4f}, corr {ref['medium10']['corr']:.4f}; "
          f"photos 1.6 CRLB {ref['photo16']['crlb']:.4f}, corr {ref['photo16']['corr']:.4f}")


if __name__ == "__main__":
    main()

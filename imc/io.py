"""Atomic file writes: a crash never leaves a half-written output in place; the temporary
files of a killed write are recognisable (``.NAME.imctmp-*``) and removed by the next run;
JSON is strict (a number that is not finite is written as null)."""

from __future__ import annotations

import csv
import json
import math
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

#: marks the temporary files of atomic_write (``.NAME.imctmp-XXXXXXXX.SUFFIX``)
TMP_MARK = ".imctmp-"


def atomic_write(path: Path, writer: Callable[[Path], None], suffix: str = "") -> None:
    """Call writer(tmp_path) on a temporary file next to path, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TMP_MARK}", suffix=suffix or path.suffix,
                               dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    try:
        writer(Path(tmp))
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def remove_stale_temps(folder: Path) -> list[Path]:
    """Remove the temporary files a killed atomic_write left in ``folder``; the removed."""
    gone = []
    for p in Path(folder).glob(f".*{TMP_MARK}*"):
        if p.is_file():
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone


def strict_json(obj: object) -> object:
    """obj with numpy scalars and arrays as Python values and every non-finite float as None
    (JSON has no NaN or Infinity)."""
    if isinstance(obj, dict):
        return {str(k): strict_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [strict_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return strict_json(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json(path: Path, obj: object) -> None:
    """Strict JSON (see :func:`strict_json`), atomically."""
    text = json.dumps(strict_json(obj), indent=2, allow_nan=False)
    atomic_write(path, lambda p: p.write_text(text + "\n"))


def write_npz(path: Path, compress: bool = True, **arrays: np.ndarray) -> None:
    """Write arrays to an .npz file atomically (zlib-compressed unless compress=False)."""

    def w(p: Path) -> None:
        with open(p, "wb") as f:
            (np.savez_compressed if compress else np.savez)(f, **arrays)

    atomic_write(path, w, suffix=".npz")


def write_csv(path: Path, header: list[str], rows: Iterable[Iterable[object]]) -> None:
    def w(p: Path) -> None:
        with open(p, "w", newline="") as f:
            out = csv.writer(f)
            out.writerow(header)
            out.writerows(rows)

    atomic_write(path, w)


def load_sweep_results(out_dir: Path):
    """The results Dataset of a sweep folder."""
    import xarray as xr

    with xr.open_dataset(Path(out_dir) / "results.nc", engine="h5netcdf") as ds:
        return ds.load()

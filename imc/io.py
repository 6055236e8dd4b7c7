"""Atomic file writes: a crash never leaves a half-written output in place."""

from __future__ import annotations

import csv
import json
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np


def atomic_write(path: Path, writer: Callable[[Path], None], suffix: str = "") -> None:
    """Call writer(tmp_path) on a temporary file next to path, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix,
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


def write_json(path: Path, obj: object) -> None:
    atomic_write(path, lambda p: p.write_text(json.dumps(obj, indent=2) + "\n"))


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

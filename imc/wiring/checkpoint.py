"""Checkpoints that grow linearly: one file per chunk of frames, never rewritten.

``OUT/checkpoint/`` holds ``meta.json`` (the scenario's digest) and ``chunk_SSSSSSS.npz`` per
chunk (compensation.loop.Chunk: the chunk's frames and records, the trajectory samples it
added, every block's state at its end; imc.pipeline adds the serial link's state), each
written atomically. A run resumes from the chunks of its own scenario; a damaged chunk is
moved aside (``.bad``) with the ones after it, and the run continues from the last good
one; a damaged meta.json moves the whole folder aside, another scenario's checkpoint is
removed (each with a warning).
"""

from __future__ import annotations

import json
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from compensation.loop import Chunk
from imc.io import write_json, write_npz


class ChunkStore:
    """The chunks of one run in ``folder``, for the scenario with ``digest``."""

    def __init__(self, folder: Path, digest: str, warn: Callable[[str], None] | None = None):
        self.folder = Path(folder)
        self.digest = digest
        self.warn = warn or (lambda msg: None)
        self.bytes_written = 0

    def _chunk_path(self, start: int) -> Path:
        return self.folder / f"chunk_{start:07d}.npz"

    def reset(self) -> None:
        """Forget any earlier chunks (a fresh run)."""
        if self.folder.exists():
            shutil.rmtree(self.folder)

    def load(self) -> list[Chunk]:
        """The contiguous chunks of this scenario from frame 0 (empty: start afresh). A
        checkpoint of another scenario (or imcsim version) is removed, one whose meta.json
        is damaged is moved aside (``checkpoint.bad``), each with a warning."""
        meta = self.folder / "meta.json"
        if not self.folder.is_dir():
            return []
        try:
            digest = json.loads(meta.read_text())["digest"]
            if not isinstance(digest, str):
                raise TypeError("digest is not a string")
        except (OSError, ValueError, KeyError, TypeError) as e:
            if meta.exists() or any(self.folder.glob("chunk_*.npz")):
                bad = self.folder.with_name(self.folder.name + ".bad")
                if bad.exists():
                    shutil.rmtree(bad)
                self.folder.replace(bad)
                self.warn(f"checkpoint {meta} is damaged ({e.__class__.__name__}); moved the "
                          f"checkpoint aside to {bad.name}, starting afresh")
            return []
        if digest != self.digest:
            self.warn(f"the checkpoint in {self.folder} is of another scenario or imcsim "
                      "version; removed it, starting afresh")
            self.reset()
            return []
        chunks: list[Chunk] = []
        paths = sorted(self.folder.glob("chunk_*.npz"))
        expect = 0
        for i, p in enumerate(paths):
            try:
                with np.load(p, allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files}
                start, stop = int(arrays.pop("__start")), int(arrays.pop("__stop"))
                if start != expect or stop <= start:
                    raise ValueError(f"holds frames {start}..{stop}, expected {expect}..")
            except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
                for bad in paths[i:]:
                    bad.replace(bad.with_name(bad.name + ".bad"))
                self.warn(f"checkpoint {p.name} is damaged ({e.__class__.__name__}); moved "
                          f"it and {len(paths) - i - 1} later chunk(s) aside, resuming at "
                          f"frame {expect}")
                break
            chunks.append(Chunk(start, stop, arrays))
            expect = stop
        return chunks

    def write(self, chunk: Chunk) -> None:
        """Write one chunk atomically (and the meta file before the first)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        for stale in self.folder.glob(".chunk_*"):  # temp files of a killed write
            stale.unlink(missing_ok=True)
        meta = self.folder / "meta.json"
        if not meta.exists():
            write_json(meta, {"digest": self.digest})
        path = self._chunk_path(chunk.start)
        write_npz(path, compress=False, __start=np.array(chunk.start),
                  __stop=np.array(chunk.stop), **chunk.arrays)
        self.bytes_written += path.stat().st_size

    def total_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.folder.glob("chunk_*.npz"))


"""FFT backend of the correlator: FFTW through pyfftw, or scipy's pocketfft.

The backend is chosen once, at first use: FFTW (``pyfftw``) when it is installed, else
pocketfft (``scipy.fft``); pyfftw is imported then, not with this module. ``IMC_FFT=pocketfft``
(or ``fftw``) in the environment overrides the choice, and :func:`use` switches it for a block
of code (tests, benchmarks). Both compute the same transforms (float32 in, complex64 out,
unnormalised forward, 1/n inverse, as ``scipy.fft``).

FFTW plans are made once per (transform, batch, shape) and per thread (a plan object carries
its arrays, so threads do not share one), with ``FFTW_MEASURE``; the wisdom FFTW gathers makes
each further batch size cheap to plan. ``FFTW_MEASURE`` alone chooses by timing, which differs
from process to process in the last bits, so the wisdom is kept on disk (:func:`wisdom_path`:
``IMC_FFTW_WISDOM``, else ``~/.cache/imcsim/``), read at the first plan and written after each
new one: once a shape's wisdom is on file, every process on the machine picks the same
algorithm, and a run, the same run again and a resumed run compute bit-identical transforms
(two processes measuring the same new shape at once: the last to write wins). Stacks are
transformed in batches of :data:`BATCH` blocks, so at most ``BATCH`` plans exist per shape and
thread. On this 2-core machine a 128 x 128 real transform costs 23 us with FFTW and 34-42 us
with pocketfft.

References
----------
Frigo & Johnson, "The design and implementation of FFTW3", Proc. IEEE 93 (2005) 216-231.
"""

from __future__ import annotations

import os
import platform
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

import numpy as np
import scipy.fft as sfft


def _import_pyfftw() -> ModuleType | None:
    """pyfftw, or None where it is not installed. Its package imports its Dask interface
    whenever Dask is installed (a second of Dask, pandas and xarray this backend never uses);
    unless Dask's FFT module is already loaded, that interface is skipped here (``import
    pyfftw.interfaces.dask_fft`` still loads it on purpose)."""
    block = "dask.array.fft" not in sys.modules
    if block:
        sys.modules["dask.array.fft"] = None  # type: ignore[assignment]  # -> ImportError
    try:
        import pyfftw as module
    except ImportError:  # pragma: no cover - exercised where pyfftw is missing
        return None
    finally:
        if block and sys.modules.get("dask.array.fft", 0) is None:
            del sys.modules["dask.array.fft"]
    return module


_pyfftw: dict[str, ModuleType | None] = {}


def _fftw() -> ModuleType | None:
    """pyfftw (the optional fast backend), imported on first use; None where it is missing."""
    if "module" not in _pyfftw:
        _pyfftw["module"] = _import_pyfftw()
    return _pyfftw["module"]


BACKENDS = ("fftw", "pocketfft")
#: blocks per FFTW plan execution (a stack is transformed in batches of this many)
BATCH = 8


def available() -> tuple[str, ...]:
    """Backends usable in this environment, fastest first."""
    return BACKENDS if _fftw() is not None else ("pocketfft",)


def _initial() -> str:
    want = os.environ.get("IMC_FFT", "").strip().lower()
    if want:
        if want not in available():
            raise ValueError(f"IMC_FFT must be one of {available()}, got {want!r}")
        return want
    return available()[0]


_state: dict[str, str] = {}
_plans: dict[tuple, object] = {}
_plan_lock = threading.Lock()
_wisdom = {"loaded": False}


def backend() -> str:
    """The backend in use: 'fftw' or 'pocketfft'."""
    if "backend" not in _state:
        _state["backend"] = _initial()
    return _state["backend"]


def set_backend(name: str) -> None:
    """Use backend ``name`` ('fftw' or 'pocketfft') from now on."""
    if name not in available():
        raise ValueError(f"backend must be one of {available()}, got {name!r}")
    _state["backend"] = name


@contextmanager
def use(name: str) -> Iterator[None]:
    """Context manager: run a block of code with backend ``name``."""
    old = backend()
    set_backend(name)
    try:
        yield
    finally:
        _state["backend"] = old


def empty(shape: tuple[int, ...], dtype=np.float32) -> np.ndarray:
    """An uninitialised array aligned for FFTW's SIMD codelets (plain numpy for pocketfft)."""
    pyfftw = _fftw()
    if pyfftw is not None:
        return pyfftw.empty_aligned(shape, dtype=dtype)
    return np.empty(shape, dtype=dtype)


def wisdom_path() -> Path:
    """The file of FFTW's wisdom for this machine and pyfftw version."""
    env = os.environ.get("IMC_FFTW_WISDOM", "").strip()
    if env:
        return Path(env)
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    ver = getattr(_fftw(), "__version__", "0")
    return base / "imcsim" / f"fftw-wisdom-{ver}-{platform.machine()}.npz"


def _import_wisdom_file() -> None:
    """Merge the wisdom file into this process's wisdom (a missing or damaged file: none)."""
    try:
        with np.load(wisdom_path()) as f:
            _fftw().import_wisdom(tuple(f[k].tobytes() for k in ("double", "single", "long")))
    except (OSError, ValueError, KeyError, EOFError):
        pass


def _load_wisdom() -> None:
    """Merge the wisdom file into this process's wisdom (once; a missing or damaged file is
    no wisdom)."""
    if _wisdom["loaded"]:
        return
    _wisdom["loaded"] = True
    _import_wisdom_file()


def _save_wisdom() -> None:
    """Write this process's wisdom, merged with the file's, atomically (best effort: a
    read-only cache only costs the cross-process bit identity)."""
    path = wisdom_path()
    _import_wisdom_file()  # another process's newer wisdom
    d, s, lng = _fftw().export_wisdom()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            np.savez(f, double=np.frombuffer(d, np.uint8), single=np.frombuffer(s, np.uint8),
                     long=np.frombuffer(lng, np.uint8))
        os.replace(tmp, path)
    except OSError:
        pass


def _plan(kind: str, n: int, h: int, w: int):
    """The calling thread's FFTW plan of ``n`` (h, w) transforms ('r2c' or 'c2r')."""
    key = (kind, n, h, w, threading.get_ident())
    plan = _plans.get(key)
    if plan is None:
        with _plan_lock:  # FFTW's planner is not thread-safe
            pyfftw = _fftw()
            _load_wisdom()
            known = pyfftw.export_wisdom()
            real = pyfftw.empty_aligned((n, h, w), dtype=np.float32)
            spec = pyfftw.empty_aligned((n, h, w // 2 + 1), dtype=np.complex64)
            if kind == "r2c":
                plan = pyfftw.FFTW(real, spec, axes=(1, 2), flags=("FFTW_MEASURE",), threads=1)
            else:
                plan = pyfftw.FFTW(spec, real, axes=(1, 2), direction="FFTW_BACKWARD",
                                   flags=("FFTW_MEASURE", "FFTW_DESTROY_INPUT"), threads=1)
            if pyfftw.export_wisdom() != known:  # a new algorithm was measured
                _save_wisdom()
        _plans[key] = plan
    return plan


def _run(plan, src: np.ndarray, dst: np.ndarray) -> None:
    """Execute ``plan`` on src -> dst: in place of the plan's arrays when both are aligned
    and contiguous (no copy, no scaling), else through pyfftw's checked call (copies)."""
    al = _fftw().simd_alignment
    if (src.flags.c_contiguous and dst.flags.c_contiguous and src.ctypes.data % al == 0
            and dst.ctypes.data % al == 0):
        plan.update_arrays(src, dst)
        plan.execute()
    else:  # pyfftw scales the inverse with normalise_idft=True, the forward with False
        plan(src, dst, normalise_idft=plan.direction == "FFTW_FORWARD")


def rfft2(a: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Forward real FFT over the last two axes of a stack (N, h, w) -> (N, h, w//2+1) complex64.

    ``a`` is read as float32; with FFTW it is best allocated by :func:`empty` (an unaligned
    stack is copied batch by batch into the plan's own array). ``out``: where to write the
    result (best from :func:`empty` too).
    """
    a = np.asarray(a, dtype=np.float32)
    n, h, w = a.shape
    if backend() == "pocketfft" or n == 0:
        if out is None:
            return sfft.rfft2(a, workers=1)
        out[...] = sfft.rfft2(a, workers=1)
        return out
    if out is None:
        out = _fftw().empty_aligned((n, h, w // 2 + 1), dtype=np.complex64)
    for i in range(0, n, BATCH):
        j = min(i + BATCH, n)
        _run(_plan("r2c", j - i, h, w), a[i:j], out[i:j])
    return out


def irfft2(x: np.ndarray, s: tuple[int, int], normalise: bool = True) -> np.ndarray:
    """Inverse real FFT of a stack of one-sided spectra (N, h, k) to real (N, h, w) = (N, *s)
    float32, normalised by 1/(h w) (or not: ``normalise=False`` saves a pass where only the
    shape of the result matters). ``x`` may be overwritten (FFTW's c2r destroys its input).
    """
    x = np.asarray(x, dtype=np.complex64)
    n = x.shape[0]
    h, w = s
    if backend() == "pocketfft" or n == 0:
        return sfft.irfft2(x, s=s, workers=1, norm="backward" if normalise else "forward")
    if x.shape[1:] != (h, w // 2 + 1):
        raise ValueError(f"spectra of shape {x.shape[1:]} do not match the output size {s}")
    out = _fftw().empty_aligned((n, h, w), dtype=np.float32)
    for i in range(0, n, BATCH):
        j = min(i + BATCH, n)
        _run(_plan("c2r", j - i, h, w), x[i:j], out[i:j])
    if normalise:
        out *= np.float32(1.0 / (h * w))
    return out

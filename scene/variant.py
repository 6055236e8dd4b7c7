"""Choose the Mitsuba variant without importing Dr.Jit.

Dr.Jit's LLVM backend aborts the whole process (no exception) when it loads Debian's
libLLVM 15, so the choice is made here, before any import of ``drjit``/``mitsuba``:

1. ``IMC_MITSUBA_VARIANT`` if set (validated; an llvm variant still needs libLLVM >= 16);
2. ``cuda_ad_rgb`` when a CUDA driver initialises and reports a device;
3. ``llvm_ad_rgb`` when a libLLVM >= 16 is found and loads;
4. ``scalar_rgb`` otherwise (correct but ~50x slower with imcsim's Python sensor).

:func:`prepare_environment` then pins ``DRJIT_LIBLLVM_PATH`` to the chosen library, or to a
path that does not exist when none is usable, so Dr.Jit can never find libLLVM 15 by itself.
"""

from __future__ import annotations

import ctypes
import glob
import os
import re
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass

KNOWN_VARIANTS = (
    "cuda_ad_rgb",
    "cuda_ad_mono",
    "llvm_ad_rgb",
    "llvm_ad_mono",
    "scalar_rgb",
    "scalar_mono",
)
MIN_LLVM_MAJOR = 16
_NO_LLVM = "/nonexistent/imcsim-no-usable-libLLVM.so"
_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
)


class VariantError(ValueError):
    """The requested Mitsuba variant cannot be used on this machine."""


@dataclass(frozen=True)
class VariantChoice:
    """The variant to use, why, and the libLLVM Dr.Jit must load (None: none usable)."""

    variant: str
    reason: str
    libllvm_path: str | None


def llvm_major(path: str) -> int | None:
    """LLVM major version encoded in a library file name (libLLVM-19.so, libLLVM.so.19.1)."""
    name = os.path.basename(path)
    m = re.match(r"libLLVM[-.]?(\d+)", name) or re.match(r"libLLVM\.so\.(\d+)", name)
    if m is None:
        m = re.match(r"libLLVM\.(?:so|dylib)\.(\d+)", name)
    return int(m.group(1)) if m else None


def find_libllvm(min_major: int = MIN_LLVM_MAJOR) -> str | None:
    """Path of the newest loadable libLLVM with major version >= min_major, or None."""
    found: list[tuple[int, str]] = []
    for pattern in _LLVM_GLOBS:
        for path in glob.glob(pattern):
            major = llvm_major(path)
            if major is not None and major >= min_major:
                found.append((major, path))
    for _, path in sorted(found, reverse=True):
        try:
            ctypes.CDLL(path)
        except OSError:
            continue
        return path
    return None


def cuda_usable() -> bool:
    """True when the CUDA driver loads, initialises and reports at least one device."""
    for name in ("libcuda.so.1", "libcuda.so", "nvcuda.dll"):
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        try:
            if lib.cuInit(0) != 0:
                return False
            count = ctypes.c_int(0)
            return lib.cuDeviceGetCount(ctypes.byref(count)) == 0 and count.value > 0
        except AttributeError:
            return False
    return False


def choose_variant(env: Mapping[str, str] | None = None) -> VariantChoice:
    """Pick the Mitsuba variant for this machine (see the module docstring for the order)."""
    env = os.environ if env is None else env
    user_llvm = env.get("DRJIT_LIBLLVM_PATH")
    if user_llvm and user_llvm != _NO_LLVM:
        major = llvm_major(user_llvm)
        llvm = user_llvm if (major is None or major >= MIN_LLVM_MAJOR) else None
    else:
        llvm = find_libllvm()
    wanted = env.get("IMC_MITSUBA_VARIANT", "").strip()
    if wanted:
        if wanted not in KNOWN_VARIANTS:
            raise VariantError(
                f"IMC_MITSUBA_VARIANT={wanted!r} is not supported; use one of "
                + ", ".join(KNOWN_VARIANTS)
            )
        if wanted.startswith("llvm") and llvm is None:
            raise VariantError(
                f"IMC_MITSUBA_VARIANT={wanted} needs libLLVM >= {MIN_LLVM_MAJOR} "
                "(Debian: apt-get install libllvm19); unset it to fall back to scalar_rgb"
            )
        if wanted.startswith("cuda") and not cuda_usable():
            raise VariantError(f"IMC_MITSUBA_VARIANT={wanted} needs a usable CUDA GPU")
        return VariantChoice(wanted, "IMC_MITSUBA_VARIANT", llvm)
    if cuda_usable():
        return VariantChoice("cuda_ad_rgb", "a CUDA GPU is usable", llvm)
    if llvm is not None:
        return VariantChoice("llvm_ad_rgb", f"libLLVM >= {MIN_LLVM_MAJOR} at {llvm}", llvm)
    return VariantChoice(
        "scalar_rgb",
        f"no GPU and no libLLVM >= {MIN_LLVM_MAJOR} (install Debian libllvm19 for ~50x speed)",
        None,
    )


def prepare_environment(
    choice: VariantChoice, env: MutableMapping[str, str] | None = None
) -> None:
    """Pin Dr.Jit's libLLVM before it is imported, so it never loads libLLVM 15."""
    env = os.environ if env is None else env
    env["DRJIT_LIBLLVM_PATH"] = choice.libllvm_path or _NO_LLVM

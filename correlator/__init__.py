"""Image-motion measurement: block correlation (JTC, cross, phase), sub-pixel, tracking.

Modules: `core` (batched shift measurement), `jtc` (the digital joint transform
correlator), `optical` (the JTOC emulation), `driver` (the serial link and a device
emulator), `timing` (the optical pipeline's schedule), `tracker` (multi-block tracking),
`kernels` (compiled hot path), `fftbackend`, `spectral` (windows and bands), `peaks`
(peak fits, PSR), `gradient` (Lucas-Kanade refinement), `masked` (large shifts), `bounds`
(Cramer-Rao bounds), `detection` and `tail` (validity as probabilities), `options`,
`testimages`.

The names below are loaded on first use (PEP 562): importing a light submodule
(:mod:`correlator.options`, :mod:`correlator.optical`, :mod:`correlator.timing`) does not
import the FFT back-end, pyfftw or the compiled kernels that :mod:`correlator.core` needs.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from correlator.core import Correlator, ShiftResult, measure_shift
    from correlator.options import METHODS, SUBPIXEL, CorrelatorOptions
    from correlator.tracker import BlockTracker, block_grid

#: each public name and the submodule that defines it
_LAZY = {
    "METHODS": "correlator.options",
    "SUBPIXEL": "correlator.options",
    "Correlator": "correlator.core",
    "CorrelatorOptions": "correlator.options",
    "ShiftResult": "correlator.core",
    "measure_shift": "correlator.core",
    "BlockTracker": "correlator.tracker",
    "block_grid": "correlator.tracker",
}

__all__ = [
    "METHODS",
    "SUBPIXEL",
    "BlockTracker",
    "Correlator",
    "CorrelatorOptions",
    "ShiftResult",
    "block_grid",
    "measure_shift",
]


def __getattr__(name: str) -> Any:
    """A public name, imported from its submodule on first use."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'correlator' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

"""Image-motion measurement: block correlation (JTC, cross, phase), sub-pixel, tracking."""

from correlator.core import (
    METHODS,
    SUBPIXEL,
    Correlator,
    CorrelatorOptions,
    ShiftResult,
    measure_shift,
)
from correlator.tracker import BlockTracker, block_grid

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

"""The exposure chain: radiance -> the optics' MTF -> photo-electrons -> digital numbers.
Built once here and used by the tracker's frames and the main imager's product alike."""

from __future__ import annotations

import numpy as np

from camera.optics import Optics
from camera.sensor import Radiometry, SensorModel


def expose(radiance: np.ndarray, optics: Optics, sensor: SensorModel,
           rng: np.random.Generator, integration_s: float,
           radiometry: Radiometry | None = None, gain_e: float | None = None) -> np.ndarray:
    """Radiance -> optics MTF -> photo-electrons -> digital image (uint16 DN): the one
    exposure chain of the tracker's frames and the main imager's product.

    Electrons are ``radiometry.electrons_per_s(...) * integration_s`` (for a TDI line the
    integration is N / line_rate), or ``radiance * gain_e`` (e.g. ``sensor.gain_for`` of a
    reference, the tracker's 'mean_level' signal); give exactly one. The optics' MTF is applied
    with periodic boundaries: pad a strip (or filter overlapping runs of lines) to keep its
    ends clean.
    """
    if (radiometry is None) == (gain_e is None):
        raise ValueError("give exactly one of radiometry or gain_e")
    if not integration_s >= 0:
        raise ValueError(f"integration_s must be >= 0, got {integration_s}")
    img = optics.apply(radiance)
    if radiometry is not None:
        electrons = radiometry.electrons_per_s(img, optics.f_number, optics.transmission,
                                               optics.pixel_pitch_m,
                                               optics.wavelength_m) * integration_s
    else:
        electrons = img * float(gain_e)
    return sensor.expose(electrons, rng, integration_s)

"""The camera suspension: a second-order low-pass between the platform's attitude and the
camera's.

A flexible mount passes slow attitude motion and "suppresses high frequency components" (the
seed paper's flight test). It is modelled as the mass-spring-damper transfer function

    H(s) = w_c^2 / (s^2 + 2 zeta w_c s + w_c^2),   w_c = 2 pi cutoff_hz,

whose gain is 1 well below the cut-off, 1 / (2 zeta) at it (phase -90 deg) and falls as
(cutoff / f)^2 above it. Jitter is a sum of sinusoids (:class:`~orbit.jitter.JitterSeries`),
so the suspension acts exactly on each one: its amplitude is scaled by |H(f)| and its phase
moved by arg H(f) (the steady state: the platform has been flying long before the run
starts). A chirped component (a wheel or propeller speeding up) is filtered at its frequency
at t = 0.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from orbit.jitter import JitterSeries


@dataclass(frozen=True)
class Suspension:
    """Second-order low-pass of cut-off ``cutoff_hz`` (Hz) and damping ratio ``damping``."""

    cutoff_hz: float
    damping: float

    def __post_init__(self) -> None:
        if self.cutoff_hz <= 0.0 or self.damping <= 0.0:
            raise ValueError(f"suspension cut-off and damping must be > 0, got "
                             f"{self.cutoff_hz} Hz, {self.damping}")

    def response(self, f_hz) -> np.ndarray:
        """Complex frequency response H(j 2 pi f) at frequencies f_hz (any shape)."""
        u = np.asarray(f_hz, dtype=np.float64) / self.cutoff_hz
        return 1.0 / (1.0 - u * u + 2j * self.damping * u)

    def apply(self, series: JitterSeries) -> JitterSeries:
        """The jitter the camera sees: every component scaled by |H| and delayed by arg H."""
        if len(series) == 0:
            return series
        h = self.response(series.frequency_hz)
        return dataclasses.replace(series, amplitude_rad=series.amplitude_rad * np.abs(h),
                                   phase_rad=series.phase_rad + np.angle(h))

"""Tracking-sensor model: radiance -> digital numbers with noise and quantisation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    """A linear sensor with additive Gaussian noise and an ADC.

    SNR is defined as in the seed paper: mean signal / noise sigma (both in DN).

    Attributes
    ----------
    mean_signal_dn : the mean signal the gain is set for, DN.
    noise_sigma_dn : additive noise standard deviation (read + shot, lumped), DN.
    adc_bits : quantisation depth; values are rounded and clipped to [0, 2**bits - 1].
    """

    mean_signal_dn: float = 100.0
    noise_sigma_dn: float = 5.0
    adc_bits: int = 12

    @property
    def snr(self) -> float:
        return self.mean_signal_dn / self.noise_sigma_dn if self.noise_sigma_dn > 0 else np.inf

    def gain_for(self, radiance: np.ndarray) -> float:
        """Gain (DN per radiance unit) that maps this exposure's mean to mean_signal_dn."""
        m = float(np.mean(radiance))
        if not np.isfinite(m) or m <= 0.0:
            raise ValueError("cannot set the sensor gain: the rendered exposure is black")
        return self.mean_signal_dn / m

    def expose(self, radiance: np.ndarray, gain: float, rng: np.random.Generator) -> np.ndarray:
        """Digital frame (uint16, DN) from exposure-averaged radiance (H, W)."""
        signal = np.asarray(radiance, dtype=np.float64) * gain
        if self.noise_sigma_dn > 0:
            signal = signal + rng.normal(0.0, self.noise_sigma_dn, size=signal.shape)
        full = 2**self.adc_bits - 1
        return np.clip(np.rint(signal), 0, full).astype(np.uint16)

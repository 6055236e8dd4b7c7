"""Detector model: photo-electrons -> digital numbers with shot, dark and read noise.

SNR follows the seed paper: mean signal / noise sigma, both in DN (its "SNR 1.6" is 4 dB as
20 log10). The noise variance in DN^2 of a pixel with mean signal S electrons is

    (S + I_dark t) / g^2 + sigma_read^2 / g^2 + sigma_add^2 + 1/12

(shot, dark shot, read, the paper's additive Gaussian, ADC quantisation), g in e-/DN.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np


def poisson_draw(mean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Poisson counts (float64) of ``mean`` (>= 0), one uniform draw per pixel.

    ``rng.poisson`` rejects a variable number of candidates per pixel, so a change of one
    ulp in one pixel's mean (Dr.Jit's parallel film accumulation is reproducible only to an
    ulp) could shift the generator for every later pixel. Here each pixel's count is the exact
    quantile of its own uniform u: the smallest k with P(X <= k) >= u, found from the
    skew-corrected normal quantile lam + sqrt(lam) z + (z^2 - 1) / 6 by unit steps (rarely
    more than one).
    """
    from scipy.special import ndtri, pdtr

    lam = np.asarray(mean, dtype=np.float64)
    u = rng.random(lam.shape)
    z = ndtri(np.clip(u, 1e-300, 1.0 - 1e-16))
    k = np.maximum(np.floor(lam + np.sqrt(lam) * z + (z * z - 1.0) / 6.0 + 0.5), 0.0)
    todo = np.arange(lam.size)
    kf, lf, uf = k.reshape(-1), lam.reshape(-1), u.reshape(-1)
    while len(todo):
        kt, lt, ut = kf[todo], lf[todo], uf[todo]
        down = (kt > 0) & (pdtr(kt - 1, lt) >= ut)
        up = ~down & (pdtr(kt, lt) < ut)
        kf[todo] = kt - down + up
        todo = todo[down | up]
    return k


H_PLANCK = 6.62607015e-34
C_LIGHT = 299792458.0


@dataclass(frozen=True)
class Radiometry:
    """Top-of-atmosphere sunlight to photo-electrons per pixel per second.

    The renderer's radiance is for a sun of unit irradiance; times the band's solar spectral
    irradiance and the two-way atmospheric transmittance it is the at-aperture spectral
    radiance L (W m^-2 sr^-1 um^-1). A pixel then collects
    L (pi / 4 N^2) tau A_pix d_lambda QE lambda / (h c) electrons per second.
    """

    solar_irradiance_w_m2_um: float = 1500.0
    atmosphere_transmittance: float = 0.7
    bandwidth_m: float = 0.45e-6
    quantum_efficiency: float = 0.5

    def electrons_per_s(self, radiance: np.ndarray, f_number: float, transmission: float,
                        pixel_pitch_m: float, wavelength_m: float) -> np.ndarray:
        """Photo-electron rate (e-/s) for renderer radiance (unit-irradiance sun)."""
        spectral_l = (np.asarray(radiance, dtype=np.float64) * self.solar_irradiance_w_m2_um
                      * self.atmosphere_transmittance)
        irradiance = spectral_l * np.pi / (4.0 * f_number**2) * transmission
        watts = irradiance * pixel_pitch_m**2 * (self.bandwidth_m * 1e6)
        return watts * wavelength_m / (H_PLANCK * C_LIGHT) * self.quantum_efficiency


@dataclass(frozen=True)
class SensorModel:
    """A linear detector with full well, ADC and noise.

    Attributes
    ----------
    noise_model : 'physical' (shot + dark + read + quantisation, plus ``noise_sigma_dn``)
        or 'additive' (only Gaussian ``noise_sigma_dn`` and quantisation: the paper's protocol).
    mean_signal_dn : the mean signal a 'mean_level' exposure is scaled to, DN.
    noise_sigma_dn : additive Gaussian noise, DN.
    gain_e_per_dn : conversion gain, electrons per DN.
    full_well_e : saturation charge, e-.
    read_noise_e : read noise, e- rms.
    dark_current_e_per_s : dark current, e-/s per pixel.
    adc_bits : quantisation depth; values are clipped to [0, 2**bits - 1].
    """

    mean_signal_dn: float = 100.0
    noise_sigma_dn: float = 5.0
    adc_bits: int = 12
    noise_model: Literal["physical", "additive"] = "additive"
    gain_e_per_dn: float = 4.0
    full_well_e: float = 20000.0
    read_noise_e: float = 10.0
    dark_current_e_per_s: float = 50.0

    def __post_init__(self) -> None:
        if self.noise_model not in ("physical", "additive"):
            raise ValueError(f"noise_model must be 'physical' or 'additive', "
                             f"got {self.noise_model!r}")
        if self.gain_e_per_dn <= 0 or self.full_well_e <= 0:
            raise ValueError("gain_e_per_dn and full_well_e must be > 0")

    @property
    def full_scale_dn(self) -> int:
        return 2**self.adc_bits - 1

    def noise_sigma_dn_at(self, mean_e: float | np.ndarray, exposure_s: float) -> np.ndarray:
        """Total noise sigma (DN) for a mean signal of mean_e electrons."""
        var = self.noise_sigma_dn**2 + 1.0 / 12.0
        if self.noise_model == "physical":
            g = self.gain_e_per_dn
            var = var + (np.asarray(mean_e) + self.dark_current_e_per_s * exposure_s
                         + self.read_noise_e**2) / g**2
        return np.sqrt(var)

    def snr(self, mean_e: float | None = None, exposure_s: float = 0.0) -> float:
        """The paper's SNR: mean signal / noise sigma (DN) at mean_e (default: the mean level)."""
        if mean_e is None:
            mean_e = self.mean_signal_dn * self.gain_e_per_dn
        return float(mean_e / self.gain_e_per_dn / self.noise_sigma_dn_at(mean_e, exposure_s))

    def gain_for(self, radiance: np.ndarray) -> float:
        """Electrons per radiance unit that put this exposure's mean at mean_signal_dn."""
        m = float(np.mean(radiance))
        if not np.isfinite(m) or m <= 0.0:
            raise ValueError("cannot set the sensor gain: the rendered exposure is black")
        return self.mean_signal_dn * self.gain_e_per_dn / m

    def expose(self, signal_e: np.ndarray, rng: np.random.Generator,
               exposure_s: float = 0.0) -> np.ndarray:
        """Digital frame (uint16, DN) from the mean photo-electrons per pixel (H, W)."""
        e = np.asarray(signal_e, dtype=np.float64)
        if self.noise_model == "physical":
            mean = np.clip(e, 0.0, None) + self.dark_current_e_per_s * exposure_s
            e = poisson_draw(mean, rng)
            if self.read_noise_e > 0:
                e = e + rng.normal(0.0, self.read_noise_e, size=e.shape)
        e = np.clip(e, 0.0, self.full_well_e)
        dn = e / self.gain_e_per_dn
        if self.noise_sigma_dn > 0:
            dn = dn + rng.normal(0.0, self.noise_sigma_dn, size=dn.shape)
        return np.clip(np.rint(dn), 0, self.full_scale_dn).astype(np.uint16)

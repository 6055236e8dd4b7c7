"""Telescope optics: aperture, diffraction-limited MTF, optional Gaussian blur, PSF.

The MTF of an aberration-free circular pupil at spatial frequency nu (cycles/m in the focal
plane), with cut-off nu_c = 1 / (lambda N), N = f / D, is

    MTF(x) = 2/pi (arccos x - x sqrt(1 - x^2)),   x = nu / nu_c <= 1

(Goodman, *Introduction to Fourier Optics*, 3rd ed., eq. 6-31). Residual aberrations, defocus
and the platform's static blur are lumped into a Gaussian of ``blur_sigma_px``. The detector
footprint (pixel aperture) is not part of the optics: the renderer integrates each pixel's
area, which is that footprint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Optics:
    """A telescope focusing on a detector of ``pixel_pitch_m``.

    Attributes
    ----------
    focal_length_m : effective focal length, m.
    aperture_m : entrance-pupil diameter, m (IKONOS: 0.70).
    wavelength_m : effective wavelength of the band, m (panchromatic 0.45-0.90 um: 0.675).
    pixel_pitch_m : detector pitch, m (sets the frequency scale in cycles/px).
    blur_sigma_px : extra Gaussian blur (aberrations, defocus), px; 0 for none.
    transmission : optical transmission of the telescope, 0..1 (radiometry).
    diffraction : include the diffraction MTF (False: ideal optics, for ablation).
    """

    focal_length_m: float = 10.0
    aperture_m: float = 0.70
    wavelength_m: float = 0.675e-6
    pixel_pitch_m: float = 12e-6
    blur_sigma_px: float = 0.0
    transmission: float = 0.8
    diffraction: bool = True

    def __post_init__(self) -> None:
        for name in ("focal_length_m", "aperture_m", "wavelength_m", "pixel_pitch_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"optics {name} must be > 0, got {getattr(self, name)}")
        if self.blur_sigma_px < 0 or not 0 < self.transmission <= 1:
            raise ValueError("optics blur_sigma_px must be >= 0 and transmission in (0, 1]")

    @property
    def f_number(self) -> float:
        return self.focal_length_m / self.aperture_m

    @property
    def cutoff_cycles_per_px(self) -> float:
        """Diffraction cut-off 1 / (lambda N) in cycles per pixel (IKONOS: 1.244)."""
        return self.pixel_pitch_m / (self.wavelength_m * self.f_number)

    @property
    def airy_radius_px(self) -> float:
        """Radius of the Airy disc's first dark ring, 1.22 lambda N, px."""
        return 1.22 * self.wavelength_m * self.f_number / self.pixel_pitch_m

    def mtf(self, f_cycles_per_px) -> np.ndarray:
        """Optical MTF (diffraction x Gaussian blur) at radial frequencies in cycles/px."""
        f = np.abs(np.asarray(f_cycles_per_px, dtype=np.float64))
        out = np.exp(-2.0 * np.pi**2 * self.blur_sigma_px**2 * f**2)
        if self.diffraction:
            x = np.clip(f / self.cutoff_cycles_per_px, 0.0, 1.0)
            out = out * (2.0 / np.pi) * (np.arccos(x) - x * np.sqrt(1.0 - x * x))
        return out

    @property
    def is_identity(self) -> bool:
        return not self.diffraction and self.blur_sigma_px == 0.0

    def apply(self, image: np.ndarray) -> np.ndarray:
        """Filter images (..., H, W) by the optical MTF (periodic boundaries), float64.

        The rendered pixel values are area integrals (the detector footprint); this adds the
        telescope's blur on top, in the 2D spectrum of the sampled image.
        """
        import scipy.fft as sfft

        img = np.asarray(image, dtype=np.float64)
        if self.is_identity:
            return img
        h, w = img.shape[-2:]
        fy = sfft.fftfreq(h)[:, None]
        fx = sfft.rfftfreq(w)[None, :]
        tf = self.mtf(np.hypot(fy, fx))
        return sfft.irfft2(sfft.rfft2(img, workers=-1) * tf, s=(h, w), workers=-1)

    def psf(self, size_px: int = 33, oversample: int = 4) -> np.ndarray:
        """Optical PSF (size*oversample square, sum 1) sampled at pitch/oversample.

        The inverse transform of :meth:`mtf` on the oversampled grid.
        """
        import scipy.fft as sfft

        n = size_px * oversample
        f = np.hypot(sfft.fftfreq(n)[:, None], sfft.fftfreq(n)[None, :]) * oversample
        p = np.real(sfft.fftshift(sfft.ifft2(self.mtf(f))))
        p = np.clip(p, 0.0, None)
        return p / p.sum()

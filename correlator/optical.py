"""Joint Transform Optical Correlator (JTOC) emulation: SLM, lens, sensor, SLM, lens, sensor.

The chain, for each block pair (ref, cur), in the order light meets it:

1. **Input SLM** (``input_slm``): ref is written flush left, cur flush right on one
   ``rows x cols`` amplitude modulator (separation G = cols - w px). Effects: ``slm_amplitude``
   (a video SLM shows the raw block, auto-gained to [0, 1] and apodised by the front end, mean
   kept; off: the
   digital correlator's zero-mean apodised blocks, signed), ``slm_quantisation`` (drive bits),
   ``slm_contrast`` (leakage t_min = contrast^-1/2 in amplitude over the whole aperture),
   ``slm_fill_factor`` (pixel aperture sqrt(ff) x pitch: the spectrum is multiplied by
   sinc(a f_y) sinc(a f_x); outside the central order the sensor sees attenuated replicas).
2. **Fourier lens** (``lens1_focal_m``, ``wavelength_m``): the field's Fourier transform lands
   on the joint-power-spectrum (JPS) sensor at frequency step
   df = p_sensor p_slm / (lambda F) cycles/px, i.e. the correlation plane has the period
   L = 1/df px; the sensor's rows x cols samples cover |f| < N df / 2 (``fourier_sampling``;
   off: an exact DFT covering the whole band). A ``dc_stop`` dot blocks frequencies below
   ``dc_stop_cycles`` cycles per block: the zero order, the blocks' mean and their windows.
3. **JPS sensor** (``jps_sensor``): square law |F|^2, auto-exposure that lets the fraction
   ``saturated_fraction`` of pixels reach full well (off: nothing saturates), response curve
   (gamma), shot + read noise, ADC bits.
4. **Second SLM** (``slm2``): the JPS image, one sensor pixel per SLM pixel, as amplitude
   (bits, contrast).
5. **Second lens** (``lens2_focal_m``) and **correlation-plane sensor** (``output_sensor``):
   the output field is the correlation; the sensor records |c|^2 (``output_square_law``; off:
   Re c) around the cross-correlation peak at +(G + d), auto-exposed to its maximum, with
   noise and ADC bits. One output pixel is p_out p_slm2 F1 / (p_sensor p_slm F2) input px
   (lambda cancels); the device is calibrated with that scale.
6. **Peak detection**: the integer maximum within the search range, the peak-to-sidelobe ratio
   against the paper's threshold, and centre of mass (default) over the 3 x 3 neighbourhood.

With every effect off, the output plane is the linear cross-correlation of the digital JTC's
joint plane (``jtc.joint_plane_surface`` with ``jtc_filter='plain'``) and the shift equals the
digital JTC's with the same peak fit (pinned by tests).

Defaults: the seed's hardware model fixes the rates (video-rate SLMs and cameras, 30 transforms
per second); its component data are not published, so the defaults are typical video-rate
parts of that class: 640 x 480 transmissive LCD (20 um, 8 bit, fill 0.6, contrast 100:1),
He-Ne 632.8 nm, F1 = 0.30 m (L = 1283 px), a 1024^2 7.4 um 8-bit CCD (20 ke-, 15 e- read),
a 1024^2 15 um second SLM and F2 = 0.225 m (1 output px = 1 input px).

References
----------
Weaver & Goodman, Appl. Opt. 5 (1966); Goodman, *Introduction to Fourier Optics* (2005), ch. 8.
Janschek, Tchernykh, Dyblenko, "Performances of image motion tracking with optical correlation".
Rabiner, Schafer & Rader, "The chirp z-transform algorithm", IEEE Trans. Audio 17 (1969).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from correlator import peaks, spectral

EFFECTS = (
    "slm_amplitude", "slm_quantisation", "slm_contrast", "slm_fill_factor",
    "fourier_sampling", "dc_stop",
    "jps_response", "jps_saturation", "jps_noise", "jps_quantisation",
    "slm2_quantisation", "slm2_contrast",
    "output_square_law", "output_noise", "output_quantisation",
)
#: blocks emulated at once (memory: ~10 MB per block at the default 1024^2 JPS sensor)
BATCH = 4


@dataclass(frozen=True)
class SlmSpec:
    """A spatial light modulator: pixels, pitch (m), drive bits, fill factor (area), contrast."""

    rows: int
    cols: int
    pitch_m: float
    bits: int = 8
    fill_factor: float = 0.6
    contrast: float = 100.0

    def __post_init__(self) -> None:
        _check_positive(self, ("rows", "cols", "pitch_m", "bits"))
        if not 0.0 < self.fill_factor <= 1.0 or self.contrast < 1.0:
            raise ValueError(f"fill_factor must be in (0, 1] and contrast >= 1, got "
                             f"{self.fill_factor}, {self.contrast}")


@dataclass(frozen=True)
class SensorSpec:
    """A CCD/CMOS camera: pixels, pitch (m), ADC bits, full well and read noise (electrons),
    response gamma (1: linear) and the auto-exposure's saturated pixel fraction."""

    rows: int
    cols: int
    pitch_m: float
    bits: int = 8
    full_well_e: float = 20000.0
    read_noise_e: float = 15.0
    gamma: float = 1.0
    saturated_fraction: float = 0.0

    def __post_init__(self) -> None:
        _check_positive(self, ("rows", "cols", "pitch_m", "bits", "full_well_e", "gamma"))
        if self.read_noise_e < 0 or not 0.0 <= self.saturated_fraction < 0.5:
            raise ValueError("read_noise_e must be >= 0 and saturated_fraction in [0, 0.5)")


def _check_positive(obj, names) -> None:
    for n in names:
        if not getattr(obj, n) > 0:
            raise ValueError(f"{type(obj).__name__}.{n} must be > 0, got {getattr(obj, n)}")


@dataclass(frozen=True)
class JtocModel:
    """The optical correlator's hardware (see the module docstring); ``effects`` lists the
    imperfections that are emulated (default: all of :data:`EFFECTS`)."""

    input_slm: SlmSpec = SlmSpec(480, 640, 20e-6)
    wavelength_m: float = 632.8e-9
    lens1_focal_m: float = 0.30
    jps_sensor: SensorSpec = SensorSpec(1024, 1024, 7.4e-6, saturated_fraction=0.1)
    dc_stop_cycles: float = 6.0
    slm2: SlmSpec = SlmSpec(1024, 1024, 15e-6, fill_factor=1.0)
    lens2_focal_m: float = 0.225
    output_sensor: SensorSpec = SensorSpec(480, 640, 7.4e-6)
    effects: frozenset = field(default_factory=lambda: frozenset(EFFECTS))

    def __post_init__(self) -> None:
        eff = frozenset(self.effects)
        unknown = sorted(eff - set(EFFECTS))
        if unknown:
            raise ValueError(f"unknown optical effects {unknown}; choose from {list(EFFECTS)}")
        object.__setattr__(self, "effects", eff)
        _check_positive(self, ("wavelength_m", "lens1_focal_m", "lens2_focal_m"))
        if self.dc_stop_cycles < 0:
            raise ValueError("dc_stop_cycles must be >= 0")
        if (self.slm2.rows, self.slm2.cols) < (self.jps_sensor.rows, self.jps_sensor.cols):
            raise ValueError(f"slm2 ({self.slm2.rows} x {self.slm2.cols}) must have at least "
                             f"the JPS sensor's pixels ({self.jps_sensor.rows} x "
                             f"{self.jps_sensor.cols}): the JPS image is written 1:1")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def ideal(cls) -> JtocModel:
        """Every effect off: the emulation then equals the digital joint transform correlator."""
        return cls(effects=frozenset())

    def without(self, *effects: str) -> JtocModel:
        """This model with the named effects switched off."""
        return dataclasses.replace(self, effects=self.effects - set(effects))

    def only(self, *effects: str) -> JtocModel:
        """This model's parameters with only the named effects on."""
        return dataclasses.replace(self, effects=frozenset(effects))

    def on(self, name: str) -> bool:
        return name in self.effects

    # ------------------------------------------------------------------- geometry
    @property
    def period_px(self) -> float:
        """Correlation-plane period L = lambda F1 / (p_sensor p_slm), input px."""
        return (self.wavelength_m * self.lens1_focal_m
                / (self.jps_sensor.pitch_m * self.input_slm.pitch_m))

    @property
    def output_step_px(self) -> float:
        """One correlation-plane sensor pixel in input px: p_out p_slm2 F1 / (p_s p_slm F2)."""
        return (self.output_sensor.pitch_m * self.slm2.pitch_m * self.lens1_focal_m
                / (self.jps_sensor.pitch_m * self.input_slm.pitch_m * self.lens2_focal_m))


class OpticalJtc:
    """The JTOC for one block shape (h, w) and search range; :meth:`measure` runs the chain.

    Raises ``ValueError`` when the blocks do not fit the input SLM or the correlation plane
    would alias the cross peak (with the field of the model to change).
    """

    def __init__(self, model: JtocModel, h: int, w: int, max_shift_px: float):
        self.model = mo = model
        slm = mo.input_slm
        s = float(max_shift_px)
        self.h, self.w, self.max_shift_px = h, w, s
        if h > slm.rows or 2 * w + s + 4 > slm.cols:
            raise ValueError(
                f"optical.input_slm: {slm.rows} x {slm.cols} px cannot hold two {h} x {w} "
                f"blocks {s:g} px apart in search range: use >= {h} rows and "
                f">= {int(np.ceil(2 * w + s + 4))} cols, or smaller blocks")
        self.sep = slm.cols - w  # column separation G of cur from ref
        self.row0 = (slm.rows - h) // 2
        need = 2 * self.sep + 2 * s + w + 4  # mirror term clear of the read window
        if mo.on("fourier_sampling"):
            period = mo.period_px
            if period < need:
                raise ValueError(
                    f"optical.lens1_focal_m = {mo.lens1_focal_m} m gives a correlation plane "
                    f"of {period:.0f} px; {need:.0f} px are needed so the mirror peak does not "
                    f"alias: use lens1_focal_m >= {mo.lens1_focal_m * need / period:.3f} m")
            n_rows, n_cols = mo.jps_sensor.rows, mo.jps_sensor.cols
            self.step = mo.output_step_px
        else:
            import scipy.fft as sfft  # lazily: imc.scenario imports this module

            period = float(sfft.next_fast_len(int(np.ceil(need))))
            n_rows = n_cols = int(period)
            self.step = 1.0
        self.period = period
        df = 1.0 / period
        fy = (np.arange(n_rows) - n_rows // 2) * df  # cycles per input px
        fx = (np.arange(n_cols) - n_cols // 2) * df
        self.fy, self.fx = fy, fx
        self.czt_rows = _Czt(slm.rows, fy)
        self.czt_cols = _Czt(slm.cols, fx)
        self.half = int(np.ceil((s + 3.0) / self.step))  # read window +-half output px
        lags = np.arange(-self.half, self.half + 1) * self.step
        # second transform: c(x) = sum_k J_k exp(+2 pi i f_k x) at x = lags (rows), G + lags
        self.inv_rows = np.exp(2j * np.pi * np.outer(lags, fy)).astype(np.complex64)
        inv_cols = np.exp(2j * np.pi * np.outer(fx, self.sep + lags))
        self.inv_cols_re = np.ascontiguousarray(inv_cols.real, np.float32)
        self.inv_cols_im = np.ascontiguousarray(inv_cols.imag, np.float32)
        env = np.ones((n_rows, n_cols), np.float32)
        if mo.on("slm_fill_factor"):
            a = np.sqrt(slm.fill_factor)
            env *= (np.sinc(a * fy)[:, None] * np.sinc(a * fx)[None, :]) ** 2
        if mo.on("dc_stop"):  # radius dc_stop_cycles per block: the blocks' mean and window
            r = mo.dc_stop_cycles / min(h, w)
            env *= (np.hypot(fy[:, None], fx[None, :]) > r)
        self.envelope = env
        # the video front end's apodisation of an amplitude display (a raw block's hard edges
        # and mean would put a pyramid under the peak that no stop removes)
        self.apodise = np.outer(spectral.tukey_1d(h, max(2, h // 8)),
                                spectral.tukey_1d(w, max(2, w // 8))).astype(np.float32)

    # ------------------------------------------------------------------------ chain
    def input_planes(self, blocks_ref: np.ndarray, blocks_cur: np.ndarray) -> np.ndarray:
        """Amplitude transmission (n, rows, cols) of the input SLM for block pairs (n, h, w)."""
        mo, slm = self.model, self.model.input_slm
        n = len(blocks_ref)
        plane = np.zeros((n, slm.rows, slm.cols), np.float32)
        r = slice(self.row0, self.row0 + self.h)
        for b, c0 in ((blocks_ref, 0), (blocks_cur, self.sep)):
            b = b.astype(np.float32)
            if mo.on("slm_amplitude"):  # video AGC: the block's range onto [0, 1]
                lo = b.min(axis=(1, 2), keepdims=True)
                v = (b - lo) / np.maximum(b.max(axis=(1, 2), keepdims=True) - lo, 1e-30)
                v = v * self.apodise
                if mo.on("slm_quantisation"):
                    v = _quantise(v, slm.bits)
            else:  # ideal signed modulator, full drive at the block's largest |value|
                v = b / np.maximum(np.abs(b).max(axis=(1, 2), keepdims=True), 1e-30)
                if mo.on("slm_quantisation"):
                    v = 2.0 * _quantise(0.5 * (v + 1.0), slm.bits) - 1.0
            plane[:, r, c0 : c0 + self.w] = v
        if mo.on("slm_contrast"):
            t_min = 1.0 / np.sqrt(slm.contrast)
            plane = t_min + (1.0 - t_min) * plane
        return plane

    def joint_power_spectrum(self, plane: np.ndarray, rngs: list) -> np.ndarray:
        """What the second SLM shows (n, N_rows, N_cols): the JPS recorded by the sensor."""
        mo, sen = self.model, self.model.jps_sensor
        spec = self.czt_rows(self.czt_cols(plane, axis=-1), axis=-2)
        jps = (spec.real**2 + spec.imag**2) * self.envelope
        jps = _sense(jps, sen, rngs, mo.on("jps_saturation"), mo.on("jps_response"),
                     mo.on("jps_noise"), mo.on("jps_quantisation"))
        s2 = mo.slm2
        if mo.on("slm2_quantisation"):
            jps = _quantise(np.clip(jps, 0.0, 1.0), s2.bits)
        if mo.on("slm2_contrast"):
            t_min = 1.0 / np.sqrt(s2.contrast)
            jps = t_min + (1.0 - t_min) * jps
        return jps.astype(np.float32)

    def output_plane(self, jps: np.ndarray, rngs: list) -> np.ndarray:
        """Correlation-plane sensor image (n, 2 half + 1, 2 half + 1) around the cross peak;
        index [half, half] is lag 0."""
        mo = self.model
        j = jps.astype(np.float32)
        t = np.matmul(j, self.inv_cols_re) + 1j * np.matmul(j, self.inv_cols_im)
        c = np.matmul(self.inv_rows, t.astype(np.complex64))
        img = (c.real**2 + c.imag**2) if mo.on("output_square_law") else c.real
        return _sense(img, mo.output_sensor, rngs, False, False, mo.on("output_noise"),
                      mo.on("output_quantisation")).astype(np.float64)

    def correlate(self, ref: np.ndarray, cur: np.ndarray, rngs: list) -> np.ndarray:
        """Output planes (n, 2 half + 1, 2 half + 1) of block pairs (n, h, w)."""
        out = []
        for i in range(0, len(ref), BATCH):
            sl = slice(i, i + BATCH)
            jps = self.joint_power_spectrum(self.input_planes(ref[sl], cur[sl]), rngs[sl])
            out.append(self.output_plane(jps, rngs[sl]))
        return np.concatenate(out)

    def measure(self, ref: np.ndarray, cur: np.ndarray, rngs: list,
                subpixel: str = "com") -> tuple[np.ndarray, np.ndarray]:
        """Shift (n, 2) px (cur(x) ~ ref(x - d)) and PSR (n,) of block pairs (n, h, w).

        Peak: the integer maximum within the search range; sub-pixel: 'com' (the paper's centre
        of mass), 'parabolic' or 'gaussian' on the 3 x 3 neighbourhood; scaled by the output
        pixel size.
        """
        plane = self.correlate(ref, cur, rngs)
        n, m, _ = plane.shape
        lag = (np.arange(m) - self.half) * self.step
        inside = np.abs(lag) <= self.max_shift_px + 0.5
        masked = np.where((inside[:, None] & inside[None, :])[None], plane, -np.inf)
        iy, ix = np.unravel_index(masked.reshape(n, -1).argmax(axis=1), (m, m))
        frac = peaks.peak_fit(peaks.neighbourhood(plane, iy, ix), subpixel)
        shift = (np.column_stack([iy, ix]) - self.half + frac) * self.step
        return shift, peaks.psr(plane, iy, ix)


def _quantise(v: np.ndarray, bits: int) -> np.ndarray:
    """Values in [0, 1] rounded to 2^bits levels."""
    top = float(2**bits - 1)
    return np.rint(v * top) / top


def _sense(img: np.ndarray, sen: SensorSpec, rngs: list, saturate: bool, response: bool,
           noise: bool, quantise: bool) -> np.ndarray:
    """A camera's reading of intensities (n, ...) as fractions of full scale.

    Auto-exposure: the (1 - saturated_fraction) quantile of each image reaches full well
    (saturating the brightest pixels) when ``saturate``; otherwise its maximum does.
    """
    n = len(img)
    flat = img.reshape(n, -1)
    if saturate and sen.saturated_fraction > 0:
        k = max(1, int(sen.saturated_fraction * flat.shape[1]))
        top = -np.partition(-flat, k - 1, axis=1)[:, k - 1]
    else:
        top = np.abs(flat).max(axis=1)
    v = img / np.maximum(top, 1e-30).reshape((n,) + (1,) * (img.ndim - 1))
    if response and sen.gamma != 1.0:
        v = np.sign(v) * np.abs(v) ** sen.gamma
    if noise:
        e = v * sen.full_well_e
        g = np.stack([r.standard_normal(img.shape[1:], dtype=np.float32) for r in rngs])
        # shot (Poisson, Gaussian at these counts) and read noise in one draw
        e = e + np.sqrt(np.maximum(e, 0.0) + sen.read_noise_e**2) * g
        v = e / sen.full_well_e
    if saturate:
        v = np.clip(v, None, 1.0)
    if quantise:  # ADC over [min(0, darkest), full scale]
        lo = np.minimum(v.reshape(n, -1).min(axis=1), 0.0).reshape((n,) + (1,) * (v.ndim - 1))
        v = lo + _quantise((np.clip(v, lo, 1.0) - lo) / (1.0 - lo), sen.bits) * (1.0 - lo)
    return v


class _Czt:
    """Batched chirp-z transform of length-n signals at frequencies f (cycles/sample), complex64:
    X_k = sum_j x_j exp(-2 pi i f_k j) for uniformly spaced f (Bluestein's algorithm)."""

    def __init__(self, n: int, f: np.ndarray):
        import scipy.fft as sfft  # lazily: imc.scenario imports this module

        m = len(f)
        f0, df = float(f[0]), float(f[1] - f[0]) if m > 1 else 1.0
        self.n, self.m = n, m
        self.nfft = sfft.next_fast_len(n + m - 1)
        j = np.arange(n, dtype=np.float64)
        k = np.arange(m, dtype=np.float64)
        # phases reduced modulo 1 turn in float64 before the cast: exact chirps in complex64
        self.pre = np.exp(-2j * np.pi * np.mod(f0 * j + 0.5 * df * j * j, 1.0)).astype(np.complex64)
        self.post = np.exp(-2j * np.pi * np.mod(0.5 * df * k * k, 1.0)).astype(np.complex64)
        lag = np.arange(-(n - 1), m, dtype=np.float64)
        kern = np.exp(2j * np.pi * np.mod(0.5 * df * lag * lag, 1.0))
        buf = np.zeros(self.nfft, np.complex128)
        buf[: m] = kern[n - 1 :]
        buf[self.nfft - (n - 1) :] = kern[: n - 1]
        self.kern_f = sfft.fft(buf).astype(np.complex64)

    def __call__(self, x: np.ndarray, axis: int = -1) -> np.ndarray:
        import scipy.fft as sfft

        x = np.moveaxis(x, axis, -1)
        y = sfft.fft(x * self.pre, self.nfft, axis=-1, workers=-1)
        y = sfft.ifft(y * self.kern_f, axis=-1, workers=-1)[..., : self.m] * self.post
        return np.moveaxis(y, -1, axis)

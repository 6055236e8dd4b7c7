"""Attitude jitter: sinusoids, random jitter drawn from a PSD, reaction-wheel harmonics.

Every kind is realised as one :class:`JitterSeries`, a sum of (possibly chirped) sinusoids per
body axis, so jitter is a continuous function of time: it can be sampled at any rate, and its
angular rate is analytic.

Random jitter uses spectral synthesis (Shinozuka & Deodatis 1991): the band is cut into bins of
width df <= 1/duration; each bin gets one sinusoid at a random frequency inside it with
amplitude sqrt(2 S(f) df) and a uniform random phase. The one-sided PSD S(f) is reproduced
(Welch) and the series is near-Gaussian; it repeats no sooner than 1/df >= the duration.

Reaction-wheel harmonics: harmonic h of a wheel spinning at w(t) = w0 + w' t excites
A_h (w(t)/w0)^2 sin(2 pi h (w0 t + w' t^2 / 2) + phi): the disturbance force grows with
speed squared (static and dynamic imbalance; Masterson, Miller & Grogan 2002).

References
----------
.. [1] M. Shinozuka, G. Deodatis, "Simulation of stochastic processes by spectral
   representation", Appl. Mech. Rev. 44 (1991).
.. [2] R. A. Masterson, D. W. Miller, R. L. Grogan, "Development and validation of reaction
   wheel disturbance models", J. Sound Vib. 249 (2002).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

AXES = {"roll": 0, "pitch": 1, "yaw": 2}
Axis = Literal["roll", "pitch", "yaw"]
_MAX_COMPONENTS = 20000
_CHUNK = 4096


def _axis(name: str) -> int:
    if name not in AXES:
        raise ValueError(f"jitter axis must be one of {sorted(AXES)}, got {name!r}")
    return AXES[name]


@dataclass(frozen=True)
class JitterTerm:
    """One sinusoid: amplitude_rad * sin(2 pi frequency_hz t + phase_rad) about a body axis."""

    axis: Axis
    frequency_hz: float
    amplitude_rad: float
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        _axis(self.axis)
        if self.frequency_hz < 0 or self.amplitude_rad < 0:
            raise ValueError("jitter frequency and amplitude must be >= 0")


@dataclass(frozen=True)
class RandomJitter:
    """Band-limited random jitter with a power-law PSD S(f) ~ f**slope on [f_min, f_max].

    ``rms_rad`` is the RMS over the band (the PSD's integral is rms_rad**2); slope 0 is
    band-limited white noise, -2 a random walk's spectrum.
    """

    axis: Axis
    rms_rad: float
    f_min_hz: float
    f_max_hz: float
    slope: float = 0.0

    def __post_init__(self) -> None:
        _axis(self.axis)
        if not 0.0 < self.f_min_hz < self.f_max_hz:
            raise ValueError(f"random jitter needs 0 < f_min_hz < f_max_hz, got "
                             f"{self.f_min_hz}, {self.f_max_hz}")
        if self.rms_rad < 0:
            raise ValueError("random jitter rms must be >= 0")

    def psd_rad2_hz(self, f_hz: np.ndarray) -> np.ndarray:
        """One-sided PSD, rad^2/Hz (zero outside the band)."""
        f = np.asarray(f_hz, dtype=np.float64)
        s = self.slope
        lo, hi = self.f_min_hz, self.f_max_hz
        norm = np.log(hi / lo) if s == -1.0 else (hi ** (s + 1) - lo ** (s + 1)) / (s + 1)
        inside = (f >= lo) & (f <= hi)
        with np.errstate(divide="ignore"):
            return np.where(inside, self.rms_rad**2 * np.abs(f) ** s / norm, 0.0)


@dataclass(frozen=True)
class WheelJitter:
    """Harmonics of a reaction wheel: ``harmonics`` = ((number, amplitude_rad), ...) at speed_hz.

    Amplitudes scale with (speed / speed_hz)**2 while the wheel speed ramps at
    ``speed_rate_hz_s``; phases are random (seeded) unless ``phases_rad`` is given.
    """

    axis: Axis
    speed_hz: float
    harmonics: tuple[tuple[float, float], ...]
    speed_rate_hz_s: float = 0.0
    phases_rad: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        _axis(self.axis)
        if self.speed_hz <= 0:
            raise ValueError("wheel speed_hz must be > 0")
        if self.phases_rad is not None and len(self.phases_rad) != len(self.harmonics):
            raise ValueError("give one phase per wheel harmonic")


@dataclass(frozen=True, eq=False)
class JitterSeries:
    """Realised jitter: sum over components k of
    g_k(t) A_k sin(2 pi (f_k t + c_k t^2 / 2) + phi_k) about body axis k, with
    g_k(t) = (1 + rho_k t)^2 (wheel speed-up; 1 for everything else).
    """

    axis: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    frequency_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    amplitude_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    phase_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    chirp_hz_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    growth_per_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self) -> int:
        return len(self.axis)

    def _eval(self, t_s, derivative: bool) -> np.ndarray:
        t = np.asarray(t_s, dtype=np.float64)
        flat = t.ravel()
        out = np.zeros((flat.size, 3))
        if len(self) == 0:
            return out.reshape(t.shape + (3,))
        onehot = np.zeros((len(self), 3))
        onehot[np.arange(len(self)), self.axis] = 1.0
        f, c, a, ph, rho = (self.frequency_hz, self.chirp_hz_s, self.amplitude_rad,
                            self.phase_rad, self.growth_per_s)
        for i in range(0, flat.size, _CHUNK):
            tt = flat[i:i + _CHUNK, None]
            arg = 2.0 * np.pi * (f * tt + 0.5 * c * tt * tt) + ph
            g = (1.0 + rho * tt) ** 2
            if derivative:
                val = a * (2.0 * rho * (1.0 + rho * tt) * np.sin(arg)
                           + g * 2.0 * np.pi * (f + c * tt) * np.cos(arg))
            else:
                val = a * g * np.sin(arg)
            out[i:i + _CHUNK] = val @ onehot
        return out.reshape(t.shape + (3,))

    def rotvec_rad(self, t_s) -> np.ndarray:
        """Jitter rotation vectors (..., 3) = (roll, pitch, yaw) in rad at times t_s."""
        return self._eval(t_s, derivative=False)

    def rate_rad_s(self, t_s) -> np.ndarray:
        """Time derivative (..., 3) of :meth:`rotvec_rad`, rad/s."""
        return self._eval(t_s, derivative=True)

    @classmethod
    def concat(cls, parts: list[JitterSeries]) -> JitterSeries:
        if not parts:
            return cls()
        return cls(*(np.concatenate([getattr(p, n) for p in parts]) for n in
                     ("axis", "frequency_hz", "amplitude_rad", "phase_rad", "chirp_hz_s",
                      "growth_per_s")))


def _series(axis, f, a, ph, c=None, rho=None) -> JitterSeries:
    f = np.atleast_1d(np.asarray(f, dtype=np.float64))
    n = len(f)
    return JitterSeries(np.full(n, axis, int), f, np.broadcast_to(a, (n,)).astype(float),
                        np.broadcast_to(ph, (n,)).astype(float),
                        np.zeros(n) if c is None else np.broadcast_to(c, (n,)).astype(float),
                        np.zeros(n) if rho is None else np.broadcast_to(rho, (n,)).astype(float))


def realize_jitter(terms, duration_s: float, rng: np.random.Generator) -> JitterSeries:
    """One realisation of sinusoidal, random (PSD) and wheel jitter terms over ``duration_s``.

    Parameters
    ----------
    terms : iterable of JitterTerm, RandomJitter or WheelJitter.
    duration_s : the span the random jitter must not repeat within, s (sets df <= 1/duration).
    rng : generator for the random phases and bin frequencies.
    """
    parts = []
    for term in terms:
        if isinstance(term, JitterTerm):
            parts.append(_series(_axis(term.axis), term.frequency_hz, term.amplitude_rad,
                                 term.phase_rad))
        elif isinstance(term, RandomJitter):
            band = term.f_max_hz - term.f_min_hz
            n = int(np.ceil(band * max(duration_s, 1.0 / band)))
            n = int(np.clip(max(n, 64), 64, _MAX_COMPONENTS))
            edges = np.linspace(term.f_min_hz, term.f_max_hz, n + 1)
            df = edges[1] - edges[0]
            f = edges[:-1] + rng.uniform(0.0, 1.0, n) * df
            # amplitude from the PSD averaged over the bin (exact total power for any slope)
            fine = np.linspace(0.0, 1.0, 9)
            s_mean = term.psd_rad2_hz(edges[:-1, None] + fine * df).mean(axis=1)
            amp = np.sqrt(2.0 * s_mean * df)
            amp *= term.rms_rad / max(np.sqrt(0.5 * np.sum(amp**2)), 1e-300)
            parts.append(_series(_axis(term.axis), f, amp, rng.uniform(0, 2 * np.pi, n)))
        elif isinstance(term, WheelJitter):
            h = np.array([hh for hh, _ in term.harmonics], dtype=np.float64)
            a = np.array([aa for _, aa in term.harmonics], dtype=np.float64)
            ph = (np.asarray(term.phases_rad, dtype=np.float64) if term.phases_rad is not None
                  else rng.uniform(0, 2 * np.pi, len(h)))
            parts.append(_series(_axis(term.axis), h * term.speed_hz, a, ph,
                                 h * term.speed_rate_hz_s, term.speed_rate_hz_s / term.speed_hz))
        else:
            raise TypeError(f"not a jitter term: {term!r}")
    return JitterSeries.concat(parts)

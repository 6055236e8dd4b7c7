"""How an imager samples its integration in time and on the focal plane: the instants of a
TDI line or a frame exposure and the sub-pixel offsets that integrate the detector footprint.
Pure numpy, float64; asked of the imager (:meth:`camera.imager.TdiImager.sampling`,
:meth:`camera.imager.FrameImager.sampling`).

A TDI line l (line period T = 1 / line_rate, N stages) integrates over
``[t0 + l T, t0 + (l + N) T)``; its charge packet moves toward +row with the clock
(docs/conventions.md). S instants per line, stratified over the N T: sample s at
``tau_s = (s + 1/2) N T / S`` (a stepped p-phase clock also spreads the instants over one
clock step, so the step's smear is integrated too). At tau the packet's centre is at
focal-plane row ``rho(tau) = q(tau) - 1/2 + 1/(2p)`` (``q`` the imager's charge motion; p = 0,
continuous: ``q - 1/2``): its mean over the integration is the stage plane's centre row
(N - 1) / 2 for any clock.

The detector footprint (the pixel's area) is integrated by the samples themselves: sample s
also carries a sub-pixel offset from an S-point rank-1 (Fibonacci) lattice on the pixel, the
same for every line and column (see :mod:`camera.linescan` for why area sampling).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from camera.imager import FrameImager, TdiImager


def subpixel_lattice(n: int) -> np.ndarray:
    """Sub-pixel offsets (n, 2) (row, col) in px within [-1/2, 1/2) of the n samples taken at
    the time strata s = 0 .. n-1: a rank-1 (Korobov) lattice in (time, row, col) with
    generator (1, g_row, g_col), the integers nearest n / golden ratio and n / golden ratio^2
    coprime with n (distinct where n allows): each row and each column stratum holds one
    sample, and the row offset is not ordered with time, so a motion during the exposure does
    not add coherently to the footprint (with rows in time order a 0.85 px smear and the
    1 px footprint become one 1.7 px box instead of their convolution).
    """
    if n < 1:
        raise ValueError(f"subpixel_lattice needs n >= 1, got {n}")
    s = np.arange(n)
    g_row = _coprime_near(n, n / 1.6180339887498949)
    g_col = _coprime_near(n, n / 2.618033988749895, avoid=g_row)
    rows = ((s * g_row) % n + 0.5) / n - 0.5
    cols = ((s * g_col) % n + 0.5) / n - 0.5
    return np.stack([rows, cols], axis=-1)


def _coprime_near(n: int, x: float, avoid: int = 0) -> int:
    """The integer >= 1 nearest x that is coprime with n and not ``avoid`` (if any is)."""
    for g in sorted(range(1, max(n, 2)), key=lambda k: (abs(k - x), k)):
        if np.gcd(g, n) == 1 and g != avoid:
            return g
    return 1


@dataclass(frozen=True)
class LineSampling:
    """The S sampling instants of a TDI line and where the sampled charge sits.

    Attributes
    ----------
    line_period_s : T = 1 / line_rate, s.
    stages : N, the integrated rows.
    tau_s : (S,) sample instants after the line's start, s, within [0, N T).
    packet_row_px : (S,) the charge packet's centre row on the stage plane at tau_s, px.
    subpixel_px : (S, 2) detector-footprint offsets (row, col) of each sample, px.
    """

    line_period_s: float
    stages: int
    tau_s: np.ndarray
    packet_row_px: np.ndarray
    subpixel_px: np.ndarray

    @property
    def samples(self) -> int:
        return len(self.tau_s)

    @property
    def integration_s(self) -> float:
        return self.stages * self.line_period_s

    def times_s(self, t0_s: float, lines: np.ndarray) -> np.ndarray:
        """Sample instants (L, S), s, of lines (L,) of a strip whose line 0 starts at t0_s."""
        lines = np.asarray(lines, dtype=np.float64)
        return t0_s + lines[..., None] * self.line_period_s + self.tau_s

    def detector_rc(self, cols: np.ndarray) -> np.ndarray:
        """Focal-plane (row, col) (S, C, 2) each sample looks through for detector columns
        (C,), before any stage offset (charge position plus footprint offset)."""
        cols = np.asarray(cols, dtype=np.float64)
        row = np.broadcast_to((self.packet_row_px + self.subpixel_px[:, 0])[:, None],
                              (self.samples, len(cols)))
        col = cols[None, :] + self.subpixel_px[:, 1:2]
        return np.stack([row, col], axis=-1)


def tdi_sampling(imager: TdiImager, line_rate_hz: float, samples_per_line: int = 8,
                 footprint: bool = True) -> LineSampling:
    """The sampling of a TDI line (see the module docstring).

    Parameters
    ----------
    imager : the TDI imager (stages, clock_phases).
    line_rate_hz : the line rate actually clocked, Hz.
    samples_per_line : S, instants per line (>= 1).
    footprint : integrate the pixel area with the lattice offsets (False: point samples).
    """
    if not line_rate_hz > 0:
        raise ValueError(f"line_rate_hz must be > 0, got {line_rate_hz}")
    if samples_per_line < 1:
        raise ValueError(f"samples_per_line must be >= 1, got {samples_per_line}")
    period = 1.0 / line_rate_hz
    s = np.arange(samples_per_line)
    frac = (s + 0.5) / samples_per_line
    tau = frac * imager.stages * period
    p = imager.clock_phases
    if p:
        # spread the instants over one clock step too: its phase is then stratified even
        # when N p / S is an integer (every stratum midpoint on a step boundary otherwise)
        tau = tau + (frac - 0.5) * period / p
        tau = np.clip(tau, 0.0, np.nextafter(imager.stages * period, 0.0))
    rows = imager.charge_motion_px(tau, line_rate_hz)[:, 0]
    rows = rows - 0.5 + (0.5 / p if p else 0.0)
    sub = subpixel_lattice(samples_per_line) if footprint else np.zeros((samples_per_line, 2))
    return LineSampling(period, imager.stages, tau, rows, sub)


@dataclass(frozen=True)
class FrameSampling:
    """The S sampling instants of a frame exposure and their footprint offsets.

    Attributes
    ----------
    exposure_s : exposure time, s.
    tau_s : (S,) instants after the exposure's start, s (strata midpoints).
    subpixel_px : (S, 2) detector-footprint offsets (row, col), px.
    """

    exposure_s: float
    tau_s: np.ndarray
    subpixel_px: np.ndarray

    @property
    def samples(self) -> int:
        return len(self.tau_s)


def frame_sampling(imager: FrameImager, samples: int = 8,
                   footprint: bool = True) -> FrameSampling:
    """A frame exposure sampled at S stratified instants, each with a lattice footprint
    offset (point samples if not ``footprint``)."""
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    tau = (np.arange(samples) + 0.5) / samples * imager.exposure_s
    sub = subpixel_lattice(samples) if footprint else np.zeros((samples, 2))
    return FrameSampling(float(imager.exposure_s), tau, sub)

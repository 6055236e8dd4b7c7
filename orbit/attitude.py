"""Spacecraft attitude: nominal pointing plus sinusoidal jitter.

Body frame (docs/conventions.md): z_b along the line of sight (toward the ground), x_b the
component of the inertial velocity perpendicular to z_b (flight direction), y_b = z_b x x_b.
Jitter is a small rotation vector (roll about x_b, pitch about y_b, yaw about z_b) applied
in the body frame: R_eci_body = R_nominal @ R(jitter).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from orbit.frames import eci_to_ecef_matrix, gmst_rad
from orbit.kepler import CircularOrbit

_AXES = {"roll": 0, "pitch": 1, "yaw": 2}


@dataclass(frozen=True)
class JitterTerm:
    """One sinusoidal attitude-jitter term: amplitude_rad * sin(2 pi frequency_hz t + phase_rad)."""

    axis: Literal["roll", "pitch", "yaw"]
    frequency_hz: float
    amplitude_rad: float
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        if self.axis not in _AXES:
            raise ValueError(f"jitter axis must be one of {sorted(_AXES)}, got {self.axis!r}")


@dataclass(frozen=True)
class Attitude:
    """Nominal pointing ('nadir' or 'target' staring at a fixed ECEF point) plus jitter.

    ``mode='nadir'`` points z_b at the geocentric nadir; ``mode='target'`` keeps it on
    ``target_ecef_m`` (a staring frame camera: the nominal image is still at the target).
    """

    mode: Literal["nadir", "target"] = "nadir"
    target_ecef_m: tuple[float, float, float] | None = None
    jitter: tuple[JitterTerm, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.mode == "target" and self.target_ecef_m is None:
            raise ValueError("attitude mode 'target' needs target_ecef_m")

    def jitter_rotvec_rad(self, t_s: np.ndarray) -> np.ndarray:
        """Jitter rotation vectors (..., 3) = (roll, pitch, yaw) in rad at times t_s."""
        t = np.asarray(t_s, dtype=np.float64)
        out = np.zeros(t.shape + (3,))
        for term in self.jitter:
            out[..., _AXES[term.axis]] += term.amplitude_rad * np.sin(
                2.0 * np.pi * term.frequency_hz * t + term.phase_rad
            )
        return out

    def nominal_eci_from_body(self, orbit: CircularOrbit, t_s: np.ndarray) -> np.ndarray:
        """Nominal (jitter-free) rotations (..., 3, 3) whose columns are x_b, y_b, z_b in ECI."""
        t = np.asarray(t_s, dtype=np.float64)
        r, v = orbit.state_eci(t)
        if self.mode == "nadir":
            los = -r
        else:
            ecef_to_eci = np.swapaxes(eci_to_ecef_matrix(gmst_rad(orbit.epoch_utc, t)), -1, -2)
            target = np.einsum("...ij,j->...i", ecef_to_eci, np.asarray(self.target_ecef_m))
            los = target - r
        z = los / np.linalg.norm(los, axis=-1, keepdims=True)
        x = v - np.sum(v * z, axis=-1, keepdims=True) * z
        x /= np.linalg.norm(x, axis=-1, keepdims=True)
        y = np.cross(z, x)
        return np.stack([x, y, z], axis=-1)

    def eci_from_body(self, orbit: CircularOrbit, t_s: np.ndarray) -> np.ndarray:
        """True rotations (..., 3, 3): nominal pointing with jitter applied in the body frame."""
        t = np.asarray(t_s, dtype=np.float64)
        nominal = self.nominal_eci_from_body(orbit, t)
        if not self.jitter:
            return nominal
        rv = self.jitter_rotvec_rad(t)
        jit = Rotation.from_rotvec(rv.reshape(-1, 3)).as_matrix().reshape(rv.shape[:-1] + (3, 3))
        return nominal @ jit

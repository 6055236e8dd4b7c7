"""Compensation controllers driving the focal-plane stage offset s (px, (row, col))."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FirstOrderLoop:
    """First-order tracking loop with latency, applied to the focal-plane stage.

    After frame k is read out and measured, the motion estimate m_k (px, relative to the
    reference frame: the tracker's shift plus the stage offset frame k was taken with) drives

        s_{k+1+L} = s_{k+L} + gain * (m_k - s_{k+L})

    so with ``latency_frames`` L = 0 the next frame already uses it (one frame of latency:
    the exposure-read-out-correlate cycle). Invalid measurements hold the command.
    The stage is ideal here (zero-order hold between frames); stroke and bandwidth come with
    the compensation issue.
    """

    gain: float = 0.8
    latency_frames: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.gain <= 2.0:
            raise ValueError(f"loop gain must be in (0, 2] for stability, got {self.gain}")
        if self.latency_frames < 0:
            raise ValueError("latency_frames must be >= 0")

    def commands(self, n_frames: int) -> np.ndarray:
        """An empty command history (n_frames, 2) to be filled by :meth:`update`."""
        return np.zeros((n_frames, 2))

    def update(self, offsets: np.ndarray, k: int, estimate: np.ndarray, valid: bool) -> None:
        """Fill offsets[k + 1 + L] (and hold it to the end) from frame k's estimate."""
        self.apply(offsets, k + 1, estimate, valid)

    def apply(self, offsets: np.ndarray, j: int, estimate: np.ndarray, valid: bool) -> None:
        """An estimate that arrives before frame j: acts from frame j + L (held to the end)."""
        j = j + self.latency_frames
        if j >= len(offsets):
            return
        prev = offsets[j - 1]
        nxt = prev + self.gain * (np.asarray(estimate) - prev) if valid else prev
        offsets[j:] = nxt

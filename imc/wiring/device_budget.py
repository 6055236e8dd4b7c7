"""What the correlator is asked to do against what its device delivers: blocks x tracker
frame rate against the configured pipeline's correlations per second, the frames it then
measures and skips. The wiring asks it when it refuses a design (:mod:`imc.wiring.build`),
the advisories print it (:mod:`imc.wiring.advisories`); it needs only the models' tracker
schedule, so neither of them is imported here."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from correlator.timing import PipelineTiming, Schedule


class TrackedModels(Protocol):
    """What the budget reads of :class:`imc.wiring.build.Models`."""

    corners: np.ndarray
    frame_t_s: np.ndarray
    timing: PipelineTiming | None
    schedule: Schedule | None

    @property
    def rate_hz(self) -> float: ...


def correlator_budget(m: TrackedModels) -> dict:
    """Correlations per second the scenario asks for (blocks x tracker frame rate) against
    what the configured device delivers (None: no device model, every pair is correlated),
    the frames the device measures and the effective measurement rate, Hz."""
    n_blocks = len(m.corners)
    asked = n_blocks * m.rate_hz
    out = {"asked_per_s": float(asked), "device_per_s": None,
           "frames_measured": int(len(m.frame_t_s)), "frames_skipped": 0,
           "measurement_rate_hz": float(m.rate_hz)}
    if m.schedule is None:
        return out
    done = m.schedule.done
    measured = done.any(axis=1)
    out["device_per_s"] = float(m.timing.correlations_per_s)
    out["frames_measured"] = int(measured.sum())
    out["frames_skipped"] = int((~measured).sum())
    out["pairs_dropped"] = int((~done).sum())
    duration = len(m.frame_t_s) / m.rate_hz
    out["measurement_rate_hz"] = float(measured.sum() / duration)
    return out


def budget_warning(m: TrackedModels, budget: dict) -> str | None:
    """One line when the correlator is asked for more than its device delivers."""
    device = budget["device_per_s"]
    if device is None or budget["asked_per_s"] <= device * (1.0 + 1e-9):
        return None
    n = len(m.corners)
    total = budget["frames_measured"] + budget["frames_skipped"]
    return (f"correlator.timing: the run asks for {budget['asked_per_s']:g} correlations/s "
            f"({n} blocks x {m.rate_hz:g} frames/s) and the device delivers "
            f"{device:.3g}/s: {budget['pairs_dropped']} block pairs dropped, "
            f"{budget['frames_skipped']} of {total} frames not measured, an effective "
            f"{budget['measurement_rate_hz']:.3g} measurements/s; lower correlator.n_blocks or "
            "camera.tracker.frame_rate_hz, or a faster device (correlator.timing)")

"""What a run should be told before it starts, from the models alone (no rendering): when the
loop locks against when the main imager starts, and what the correlator is asked to do
against what its device delivers. ``imc validate`` prints these lines, ``imc run`` warns
with them and writes the figures to metrics.json (``loop.lock``, ``loop.correlator_budget``).

Lock time (:func:`compensation.lock.analytic_lock_time`): the analytic loop model's step
response settles within :data:`LOCK_BAND` of its final value. A Kalman predictor that
identifies lines rejects them only after its first identification (~0.9 of its
``window_s``), which the linear model does not see: that time is reported beside it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from imc.wiring.device_budget import budget_warning, correlator_budget

if TYPE_CHECKING:
    from imc.wiring.build import LoopParts, Models

#: the settling band of the analytic lock time, a fraction of a step of the disturbance
LOCK_BAND = 0.05


def lock_summary(m: Models, parts: LoopParts) -> dict:
    """The loop's lock time, s, from the analytic model (``analytic_s``, and the slowest
    mode's ``pole_lock_s``) and, for a line-identifying predictor, when its first
    identification is due (``identification_s``)."""
    from compensation.lock import analytic_lock_time

    lock = analytic_lock_time(parts.model, band=LOCK_BAND)
    out = {"band": LOCK_BAND, "analytic_s": _finite(lock.lock_s),
           "pole_lock_s": _finite(lock.pole_lock_s), "identification_s": None}
    ctl = parts.controller
    if getattr(ctl, "identify", False) and m.scenario.compensation.enabled:
        out["identification_s"] = 0.9 * float(ctl.identification_window_s)
    return out


def lock_warning(m: Models, lock: dict) -> str | None:
    """One line naming ``camera.main_imager.start_s`` when the main imager starts before the
    loop has locked (None otherwise, and with the loop open)."""
    sc = m.scenario
    if not sc.compensation.enabled:
        return None
    start = float(sc.camera.main_imager.start_s)
    t_lock = lock["analytic_s"]
    if t_lock is None:
        return None  # an unstable design is refused elsewhere
    if start + 1e-9 < t_lock:
        return (f"camera.main_imager.start_s: the main imager starts at {start:g} s, before the "
                f"loop locks ({t_lock:.3g} s: its step response within {LOCK_BAND:.0%}); its "
                f"first exposures get less than the loop's rejection; start it at >= "
                f"{t_lock:.3g} s")
    ident = lock["identification_s"]
    if ident is not None and start < ident and ident < sc.duration_s:
        return (f"camera.main_imager.start_s: the main imager starts at {start:g} s, before "
                f"the predictor's first line identification ({ident:.3g} s, 0.9 x "
                "compensation.controller.window_s): lines it was not told of are not "
                "rejected before then")
    return None


def advisories(m: Models, parts: LoopParts) -> tuple[dict, list[str]]:
    """The figures ({'lock', 'correlator_budget'}) and the warning lines of a run."""
    lock = lock_summary(m, parts)
    budget = correlator_budget(m)
    lines = [w for w in (budget_warning(m, budget), lock_warning(m, lock)) if w]
    lines += list(m.terrain.notes)  # how user GeoTIFFs were taken (edge-extended, nodata)
    return {"lock": lock, "correlator_budget": budget}, lines


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None

"""The device emulator's run: a scenario made the seed's hardware correlator (optical
emulation, the device's pipeline timing, open loop), and its image-motion records in the order
and at the device times the hardware would deliver them. ``imc device-emulator`` serves them
on a pseudo-terminal (:class:`correlator.driver.PtyDevice`)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from imc.scenario import Scenario


def as_device(sc: Scenario) -> Scenario:
    """The scenario with its correlator as the hardware device (optical method, pipeline
    timing on, a direct link) and the loop open."""
    c = sc.correlator.model_copy(update={
        "method": "optical", "subpixel": (sc.correlator.subpixel
                                          if sc.correlator.method == "optical" else None),
        "timing": sc.correlator.timing.model_copy(update={"enabled": True}),
        "link": sc.correlator.link.model_copy(update={"kind": "direct"})})
    return sc.model_copy(update={"correlator": c, "compensation": sc.compensation.model_copy(
        update={"enabled": False})})


def device_records(m) -> Iterator[tuple[float, list]]:
    """(device time s, [its motion record]) of every correlated (frame, block) of the
    built models ``m`` (of :func:`as_device`'s scenario), in delivery order. Renders and
    correlates the whole run first."""
    from compensation.loop import simulate
    from correlator.driver import motion_records
    from imc.wiring.build import build_loop
    from imc.wiring.rendered_plant import RenderedPlant

    parts = build_loop(m)
    rec = simulate(RenderedPlant(m), parts.estimator, parts.controller, parts.actuator,
                   parts.transport, parts.timeline, enabled=False).record
    sched = m.schedule
    kk, bb = np.nonzero(sched.done)
    order = np.argsort(sched.deliver_s[kk, bb], kind="stable")
    for i in order:
        k, b = int(kk[i]), int(bb[i])
        t_dev = float(sched.deliver_s[k, b])
        yield t_dev, motion_records(k, np.array([1e6 * t_dev]), rec.shift_px[k, b][None],
                                    rec.valid[k, b][None], rec.peak[k, b][None], [b])

"""One scenario end to end: build, run the loop, compute the truth, report. Wiring only.

The models come from :mod:`imc.wiring.build`, the plant from
:mod:`imc.wiring.rendered_plant`, the loop from :mod:`compensation.loop`, the truth from
:mod:`imc.wiring.truth`, the reports from :mod:`imc.outputs.report`, the checkpoints from
:mod:`imc.wiring.checkpoint`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from compensation.loop import simulate
from imc.outputs.report import summarize, write_outputs
from imc.scenario import Scenario
from imc.wiring import streams
from imc.wiring.advisories import advisories
from imc.wiring.build import Models, build_loop, build_models
from imc.wiring.checkpoint import ChunkStore
from imc.wiring.rendered_plant import build_plant
from imc.wiring.truth import compute_truth

#: frames per checkpoint chunk
CHECKPOINT_EVERY = 10

ProgressFn = Callable[[int, int], None]


def link_channel(m: Models, link):
    """The serial link as the transport's channel: each processed block's record goes
    through the driver and the emulated device; lost or corrupted records arrive invalid."""
    sched = m.schedule

    def channel(meas, t_s: float):
        k = meas.frame
        todo = np.flatnonzero(sched.done[k]) if sched is not None else np.arange(meas.n_blocks)
        t_us = np.rint(1e6 * (sched.deliver_s[k, todo] if sched is not None
                              else np.full(len(todo), t_s))).astype(int)
        shift, valid, peak = meas.shift_px.copy(), meas.valid.copy(), meas.peak.copy()
        s, v, p, _ = link.roundtrip(k, t_us, todo, shift[todo], valid[todo], peak[todo])
        shift[todo], valid[todo], peak[todo] = s, v, p
        sigma = np.where(valid[:, None], meas.sigma_px, np.inf)
        return dataclasses.replace(meas, shift_px=shift, valid=valid, peak=peak,
                                   sigma_px=sigma)

    return channel


def run_scenario(sc: Scenario, out: Path, save_frames: bool = False, fresh: bool = False,
                 progress: ProgressFn | None = None, rerun: bool = True,
                 warn: Callable[[str], None] | None = None) -> tuple[dict, dict]:
    """Run a scenario end to end; returns (metrics, run info). Resumes from the checkpoint
    chunks of the same scenario in ``out`` unless ``fresh``."""
    t_start = time.perf_counter()
    m = build_models(sc)
    if sc.product.enabled:  # refuse a product that does not fit before rendering anything
        from imc.wiring.product import plan_product

        plan_product(m)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plant = build_plant(m)
    sigma = float(np.mean(plant.sigma_px)) if hasattr(plant, "sigma_px") else None
    link = None
    lk = sc.correlator.link
    if lk.kind == "emulator":
        from correlator.driver import LoopbackLink

        link = LoopbackLink(streams.rng(sc.seed, "link"), lk.corrupt_probability,
                            lk.drop_probability)
    link_stats = None
    try:
        parts = build_loop(m, link_channel(m, link) if link is not None else None, sigma)
        if warn is not None:
            for line in advisories(m, parts)[1]:
                warn(line)
        store = ChunkStore(out / "checkpoint", m.scenario.digest(), warn)
        if fresh:
            store.reset()
        chunks = store.load()
        on_chunk = store.write
        if link is not None:  # the link's counters and fault generator go with each chunk
            chunks = _restore_link(link, chunks, store, warn)
            on_chunk = _with_link_state(link, store.write)
        resumed_from = chunks[-1].stop if chunks else 0
        res = simulate(plant, parts.estimator, parts.controller, parts.actuator,
                       parts.transport, parts.timeline, enabled=sc.compensation.enabled,
                       resume=chunks or None, on_chunk=on_chunk,
                       chunk_frames=CHECKPOINT_EVERY, progress=progress,
                       supervisor=parts.supervisor)
    finally:
        if link is not None:
            link_stats = link.stats()
            link.close()
    t_loop = time.perf_counter()
    truth = compute_truth(m, res.record, res.trajectory)
    metrics = summarize(m, res, truth, parts, link_stats)
    if sc.metrics.blur_images and m.line_rate_hz is None:
        from imc.wiring.blur import main_imager_study

        metrics["main_imager_blur"] = main_imager_study(m, res.trajectory, truth, out,
                                                        spp=sc.metrics.blur_spp)
    else:
        from imc.wiring.blur import write_blur_npz

        metrics["main_imager_blur"] = write_blur_npz(out / "blur.npz", truth, res.trajectory)
    if sc.product.enabled:
        from imc.wiring.product import product_study

        metrics["product"] = product_study(m, res, out, fresh)
    frames = getattr(plant, "frames", None)
    ref_corners = getattr(plant, "ref_corners_rec", None)
    files = write_outputs(m, res, truth, metrics, out, frames, ref_corners, save_frames, rerun,
                          loop_model=parts.model)
    files.append(out / "blur.npz")
    files.extend(Path(f) for f in metrics.get("product", {}).get("files", ()))
    if (out / "main_imager.png").exists() and sc.metrics.blur_images:
        files.append(out / "main_imager.png")
    info = {"wall_s": time.perf_counter() - t_start, "loop_s": t_loop - t_start,
            "render_s": getattr(plant, "render_s", 0.0), "resumed_from_frame": resumed_from,
            "checkpoint_bytes": store.total_bytes(), "files": [str(f) for f in files]}
    return metrics, info


def _with_link_state(link, write: Callable) -> Callable:
    """on_chunk that adds the link's state (``link/...``) to each chunk before writing it."""

    def on_chunk(chunk) -> None:
        chunk.arrays.update({f"link/{k}": v for k, v in link.state().items()})
        write(chunk)

    return on_chunk


def _restore_link(link, chunks: list, store: ChunkStore, warn) -> list:
    """The chunks to resume from, the link restored to the last one's state; a checkpoint
    without the link's state (an older imcsim) is set aside and the run starts afresh."""
    if not chunks:
        return chunks
    state = {k[len("link/"):]: v for k, v in chunks[-1].arrays.items() if k.startswith("link/")}
    try:
        link.restore(state)
    except (KeyError, ValueError, TypeError):
        if warn is not None:
            warn("checkpoint lacks the serial link's state (written by an older imcsim); "
                 "starting afresh")
        store.reset()
        return []
    return chunks

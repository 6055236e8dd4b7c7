"""One scenario end to end: build, run the loop, compute the truth, report. Wiring only.

The models come from :mod:`imc.wiring.build`, the plant from
:mod:`imc.wiring.rendered_plant`, the loop from :mod:`compensation.loop`, the truth from
:mod:`imc.wiring.truth`, the main imager's blur from :mod:`imc.wiring.blur`, its product and
picture from :mod:`imc.wiring.product`, the reports from
:mod:`imc.outputs` (their drawing and recording as jobs of :mod:`imc.outputs.jobs`), the
checkpoints from :mod:`imc.wiring.checkpoint`.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from camera.imager import IMAGERS
from compensation.loop import simulate
from imc.io import write_json
from imc.outputs.figures import draw_run_figures, fig_main_imager
from imc.outputs.jobs import Jobs, make_jobs
from imc.outputs.product_report import write_quicklook
from imc.outputs.report import summarize, write_tables
from imc.outputs.rerun_log import recording_data, write_recording
from imc.scenario import Scenario
from imc.wiring import streams
from imc.wiring.advisories import advisories
from imc.wiring.blur import window_blur, write_blur_npz
from imc.wiring.build import Models, build_loop, build_models
from imc.wiring.checkpoint import ChunkStore
from imc.wiring.rendered_plant import RenderedPlant, build_plant, render_floor_check
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
                 warn: Callable[[str], None] | None = None, report_figures: bool = False,
                 parallel_outputs: bool = False) -> tuple[dict, dict]:
    """Run a scenario end to end; returns (metrics, run info). Resumes from the checkpoint
    chunks of the same scenario in ``out`` unless ``fresh``. ``report_figures``: also draw
    the report's figures (run info ``figures``, for
    :func:`imc.outputs.htmlreport.write_run_report`); ``parallel_outputs``: draw and record
    on a helper process (:mod:`imc.outputs.jobs`), the same files."""
    t_start = time.perf_counter()
    pictures = sc.metrics.blur_images and not IMAGERS[sc.camera.main_imager.kind].scanning
    jobs = make_jobs(parallel_outputs and (rerun or report_figures or pictures))
    try:
        metrics, info = _run(sc, Path(out), save_frames, fresh, progress, rerun, warn,
                             report_figures, jobs)
    except BaseException:
        jobs.close(cancel=True)
        raise
    jobs.close()
    info["wall_s"] = time.perf_counter() - t_start
    info["loop_s"] = info.pop("loop_done") - t_start
    return metrics, info


def _run(sc: Scenario, out: Path, save_frames: bool, fresh: bool, progress: ProgressFn | None,
         rerun: bool, warn: Callable[[str], None] | None, report_figures: bool,
         jobs: Jobs) -> tuple[dict, dict]:
    m = build_models(sc)
    plan = None
    if sc.product.enabled:  # refuse a product that does not fit before rendering anything
        from imc.wiring.product import plan_product

        plan = plan_product(m)
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
    if isinstance(plant, RenderedPlant):  # the simulation's own noise in the tracker's links
        metrics["tracker"]["render_floor"], line = render_floor_check(
            m, plant, metrics["tracker"]["median_crlb_px"])
        if line is not None and warn is not None:
            warn(line)
    blurs = (window_blur(truth, None), window_blur(truth, res.trajectory))
    metrics["main_imager_blur"] = write_blur_npz(out / "blur.npz", truth, res.trajectory, blurs)
    frames = getattr(plant, "frames", None)
    ref_corners = getattr(plant, "ref_corners_rec", None)
    files, series = write_tables(m, res, truth, out, frames, ref_corners, save_frames,
                                 parts.model)
    files.append(out / "blur.npz")
    # the figures of the files written so far, while the main imager renders
    drawn = (jobs.submit(draw_run_figures, out, copy.deepcopy(metrics)) if report_figures
             else None)
    drawing = []
    rendered = None
    if sc.product.enabled:
        rendered = _product(m, res, truth, plant, plan, out, fresh, metrics, files)
        if report_figures:
            drawing.append(jobs.submit(write_quicklook, out))
    if sc.metrics.blur_images and not m.imager.scanning:  # a TDI product is its own picture
        from imc.wiring.product import picture_study

        metrics["main_imager_blur"], picture = picture_study(
            m, res, truth, blurs, metrics["main_imager_blur"], rendered, out,
            spp=sc.metrics.blur_spp)
        drawing.append(jobs.submit(fig_main_imager, out / "main_imager.png", picture))
    else:  # an earlier run's picture in this folder would show in this run's report
        (out / "main_imager.png").unlink(missing_ok=True)
    if rerun:  # after the main imager's figure and the product: it shows them
        drawing.append(jobs.submit(write_recording, out / "recording.rrd",
                                   recording_data(m, res, truth, frames, ref_corners,
                                                  series)))
    write_json(out / "metrics.json", metrics)
    files.append(out / "metrics.json")
    for ticket in drawing:
        if (path := jobs.result(ticket)) is not None:
            files.append(Path(path))
    info = {"loop_done": t_loop,
            "render_s": getattr(plant, "render_s", 0.0), "resumed_from_frame": resumed_from,
            "checkpoint_bytes": store.total_bytes(), "files": [str(f) for f in files]}
    if drawn is not None:
        info["figures"] = jobs.result(drawn)
    return metrics, info


def _product(m: Models, res, truth, plant, plan, out: Path, fresh: bool, metrics: dict,
             files: list):
    """The main imager's product (:func:`imc.wiring.product.product_study`) from the ground's
    record (:mod:`imc.wiring.links`, :mod:`imc.wiring.restitution`) into ``product/`` and
    metrics.json's ``product``; returns its renders (the picture reuses them)."""
    from imc.io import write_npz
    from imc.outputs.product_files import product_metrics, write_product
    from imc.wiring.links import measure_links
    from imc.wiring.product import product_study
    from imc.wiring.restitution import restitute

    links = measure_links(m, res.record, plant, truth.stage_mean_px,
                          m.scenario.product.restitution.baselines)
    (out / "product").mkdir(parents=True, exist_ok=True)
    write_npz(out / "product" / "links.npz", **links.arrays())
    rest = restitute(m, links, np.array([plan.line_t_s[0], plan.line_t_s[-1]
                                         + plan.integration_s]))
    ds, rendered = product_study(m, res, out, fresh, rest, plan)
    ds.attrs["restitution"] = {"baselines": rest.baselines, "links": rest.links_used,
                               "aiding": list(rest.aiding),
                               "efficiency": [float(x) for x in links.efficiency],
                               "independent_fraction": rest.independent_fraction}
    if "ground_control" in ds.attrs:  # a reference orthoimage's fixes, measured on the product
        ds.attrs["restitution"]["aiding"].append("orthoimage")
        ds.attrs["restitution"]["ground_control"] = ds.attrs.pop("ground_control")
    written = write_product(ds, out / "product")
    metrics["product"] = product_metrics(ds, written + [out / "product" / "links.npz"])
    files.extend(written)
    return rendered


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

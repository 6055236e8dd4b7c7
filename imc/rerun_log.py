"""Rerun recording of a run: frames, block boxes, true / measured / residual motion."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from imc.io import atomic_write

if TYPE_CHECKING:
    from imc.pipeline import LoopState, Models, Truth


def write_recording(path: Path, m: Models, st: LoopState, truth: Truth) -> None:
    """Write ``recording.rrd`` (atomically) for the Rerun viewer: ``rerun recording.rrd``."""
    import rerun as rr

    def write(tmp: Path) -> None:
        rec = rr.RecordingStream("imcsim", recording_id=m.scenario.name)
        rec.save(str(tmp))
        b = m.scenario.correlator.block_px
        scale = 255.0 / (2.0 * m.sensor.mean_signal_dn)
        mins = m.corners[:, ::-1].astype(np.float32)  # (x, y) = (col, row)
        for k, t in enumerate(m.frame_t_s):
            rec.set_time("time", duration=float(t))
            img = np.clip(st.frames[k] * scale, 0, 255).astype(np.uint8)
            rec.log("tracker/frame", rr.Image(img))
            colors = np.where(st.valid[k][:, None], [[40, 220, 80]], [[230, 40, 40]])
            rec.log("tracker/frame/blocks",
                    rr.Boxes2D(mins=mins, sizes=np.full((len(mins), 2), b, np.float32),
                               labels=[f"block {i}" for i in range(len(mins))],
                               colors=colors.astype(np.uint8)))
        frame_t = rr.TimeColumn("time", duration=m.frame_t_s)
        fine_t = rr.TimeColumn("time", duration=truth.t_s)
        measured = st.shifts + st.offsets[:, None, :]
        valid_mean = np.where(st.valid, 1.0, np.nan)
        meas_mean = np.nanmean(measured * valid_mean[..., None], axis=1)
        stage_fine = truth.per_sample(st.offsets)
        series = {
            "motion/true": (fine_t, truth.center_px),
            "motion/measured": (frame_t, meas_mean),
            "motion/stage": (frame_t, st.offsets),
            "motion/residual_closed_loop": (fine_t, truth.center_px - stage_fine),
        }
        for name, (tcol, values) in series.items():
            for axis, label in enumerate(("row_px", "col_px")):
                rec.send_columns(f"{name}/{label}", indexes=[tcol],
                                 columns=rr.Scalars.columns(scalars=values[:, axis]))
        rec.flush()
        rec.disconnect()

    atomic_write(Path(path), write, suffix=".rrd")

"""Rerun recording of a run: frames, block boxes, true / measured / residual motion."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from imc.io import atomic_write

if TYPE_CHECKING:
    from compensation.loop import LoopResult
    from imc.build import Models
    from imc.truth import Truth


def write_recording(path: Path, m: Models, res: LoopResult, truth: Truth,
                    frames: np.ndarray | None, ref_corners: np.ndarray | None) -> None:
    """Write ``recording.rrd`` (atomically) for the Rerun viewer: ``rerun recording.rrd``."""
    import rerun as rr

    rec_ = res.record

    def write(tmp: Path) -> None:
        rec = rr.RecordingStream("imcsim", recording_id=m.scenario.name)
        rec.save(str(tmp))
        b = m.scenario.correlator.block_px
        if frames is not None:
            scale = 255.0 / (2.0 * max(float(frames[0].mean()), 1.0))
            for k, t in enumerate(m.frame_t_s):
                rec.set_time("time", duration=float(t))
                img = np.clip(frames[k] * scale, 0, 255).astype(np.uint8)
                rec.log("tracker/frame", rr.Image(img))
                mins = ref_corners[k][:, ::-1].astype(np.float32)  # (x, y) = (col, row)
                colors = np.where(rec_.valid[k][:, None], [[40, 220, 80]], [[230, 40, 40]])
                rec.log("tracker/frame/blocks",
                        rr.Boxes2D(mins=mins, sizes=np.full((len(mins), 2), b, np.float32),
                                   labels=[f"block {i}" for i in range(len(mins))],
                                   colors=colors.astype(np.uint8)))
        frame_t = rr.TimeColumn("time", duration=m.frame_t_s)
        fine_t = rr.TimeColumn("time", duration=truth.t_s)
        series = {
            "motion/true_main_imager": (fine_t, truth.motion_px - truth.charge_px),
            "motion/estimate": (frame_t, rec_.motion_px),
            "motion/stage": (fine_t, truth.stage_px(res.trajectory)),
            "motion/residual_closed_loop": (fine_t, truth.residual_px(res.trajectory)),
        }
        for name, (tcol, values) in series.items():
            for axis, label in enumerate(("row_px", "col_px")):
                rec.send_columns(f"{name}/{label}", indexes=[tcol],
                                 columns=rr.Scalars.columns(scalars=values[:, axis]))
        rec.flush()
        rec.disconnect()

    atomic_write(Path(path), write, suffix=".rrd")

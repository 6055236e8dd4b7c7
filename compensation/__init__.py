"""The compensation loop: blocks behind protocols, the loop that steps them, the analytic
loop model, and the residual-blur metrics. Numpy and scipy (pydantic for the blocks' parameter
checks in :mod:`compensation.registry`); imports no other imcsim package.

- `blocks`: the loop's signals and the blocks' protocols; `registry`: kind -> class per role;
- `loop`: the loop that steps plant -> transport -> estimator -> controller -> actuator;
- `estimators`, `controllers`, `actuators`, `supervisor`, `transport`: the blocks;
- `analytic`: rejection |S(f)|, noise gain and margins; `analytic_plant`: the plant whose
  measurements are the truth plus the correlator's predicted noise;
- `lock`: lock time; `metrics`: residual RMS, peak-to-peak, motion MTF; `state`: block states
  for checkpoints."""

from compensation.analytic import LoopModel, Margins, design_lines, measured_rejection
from compensation.blocks import (
    Actuator,
    BlockMeasurements,
    ControlInput,
    Controller,
    Estimator,
    MotionEstimate,
    Plant,
    Supervisor,
    Transport,
    register,
)
from compensation.lock import (
    AnalyticLock,
    RunLock,
    analytic_lock_time,
    run_lock_time,
    running_rms,
)
from compensation.loop import Chunk, LoopRecord, LoopResult, Timeline, Trajectory, simulate
from compensation.metrics import ResidualMetrics, motion_mtf, residual_metrics
from compensation.registry import block_class, build, kinds
from compensation.supervisor import ResidualSupervisor

__all__ = [
    "AnalyticLock", "ResidualSupervisor", "RunLock", "Supervisor", "analytic_lock_time",
    "run_lock_time", "running_rms",
    "Actuator", "BlockMeasurements", "Chunk", "ControlInput", "Controller", "Estimator",
    "LoopModel", "LoopRecord", "LoopResult", "Margins", "MotionEstimate", "Plant",
    "ResidualMetrics", "Timeline", "Trajectory", "Transport", "block_class", "build",
    "design_lines", "kinds",
    "measured_rejection", "motion_mtf", "register", "residual_metrics", "simulate",
]

"""Closing the loop: controller + focal-plane actuator, and residual-blur metrics."""

from compensation.controller import FirstOrderLoop
from compensation.metrics import ResidualMetrics, motion_mtf, residual_metrics

__all__ = ["FirstOrderLoop", "ResidualMetrics", "motion_mtf", "residual_metrics"]

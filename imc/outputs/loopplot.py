"""``imc loop``: the loop's rejection from the analytic model beside a measured sine sweep."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from compensation.analytic import LoopModel, measured_rejection
from imc.io import atomic_write, write_json
from imc.outputs.figures import sparse_log_ticks


def delay_s(model: LoopModel) -> float:
    """Effective delay of the loop: from the exposure's middle to the middle of the time the
    resulting command holds, plus the actuator's lag, s."""
    return (0.5 * model.exposure_s + model.latency_s + 0.5 * model.period_s
            + getattr(model.actuator, "lag_s", 0.0))


def loop_study(model: LoopModel, out_dir: Path, n_sweep: int = 12, amplitude_px: float = 0.1,
               title: str = "") -> dict:
    """|S(f)| analytic and by sine sweep (up to a quarter of the measurement rate, and a few
    points beyond), the delay bound; writes loop.png and loop.json in out_dir."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rate = model.rate_hz
    f = np.geomspace(rate * 1e-3, 0.5 * rate, 600)
    s = np.abs(model.rejection(f))
    f_cmp = 0.25 * rate
    f_sweep = np.geomspace(rate * 5e-3, 0.45 * rate, n_sweep)
    adaptive = bool(getattr(model.controller, "identify", False))
    # the analytic model is the loop's linear part: a predictor that identifies lines finds
    # the swept sine itself and rejects it far below |S(f)|, so the model is checked with
    # identification off, and the adaptive loop's own sweep is drawn beside it
    linear = (dataclasses.replace(model, controller=dataclasses.replace(model.controller,
                                                                        identify=False))
              if adaptive else model)
    meas = measured_rejection(linear, f_sweep, amplitude_px=amplitude_px)
    meas_adaptive = (measured_rejection(model, f_sweep, amplitude_px=amplitude_px)
                     if adaptive else None)
    ana = np.abs(model.rejection(f_sweep))
    inside = f_sweep <= f_cmp
    diff_db = 20 * np.log10(np.maximum(meas, 1e-12) / np.maximum(ana, 1e-12))
    lag = delay_s(model)
    bound = np.abs(1.0 - np.exp(-2j * np.pi * f * lag))
    mg = model.margins()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    fig, ax = plt.subplots(figsize=(7.5, 4.6), dpi=120)
    ax.loglog(f, s, label="analytic |S(f)|", color="C0")
    ax.loglog(f, bound, "--", color="0.5", label=f"delay bound (L = {lag * 1e3:.2f} ms)")
    ax.loglog(f_sweep, meas, "o", color="C3", label="sine sweep (analytic plant)"
              + (", line identification off" if adaptive else ""))
    if meas_adaptive is not None:
        ax.loglog(f_sweep, meas_adaptive, "^", color="C2", mfc="none",
                  label="sine sweep, identifying the sine as a line")
    ax.axhline(1.0, color="0.8", lw=0.8)
    ax.axvline(f_cmp, color="0.85", lw=0.8, ls=":")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("residual / disturbance")
    ax.set_title(f"{title}: rejection, {rate:g} measurements/s".strip(": "))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    sparse_log_ticks(ax)
    png = out_dir / "loop.png"

    def save(p: Path) -> None:
        fig.savefig(p, format="png")

    atomic_write(png, save)
    plt.close(fig)
    result = {
        "rate_hz": rate,
        "delay_s": lag,
        "margins": mg.to_dict(),
        "sweep_hz": f_sweep.tolist(),
        "sweep_measured": meas.tolist(),
        "sweep_analytic": ana.tolist(),
        "sweep_identification_off": adaptive,
        "sweep_measured_adaptive": (meas_adaptive.tolist() if meas_adaptive is not None
                                    else None),
        "max_error_db": float(np.max(np.abs(diff_db[inside]))) if inside.any() else None,
        "f_max_compared_hz": f_cmp,
        "png": str(png),
        "json": str(out_dir / "loop.json"),
    }
    write_json(out_dir / "loop.json", result)
    return result

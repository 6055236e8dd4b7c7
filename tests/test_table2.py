"""The Table 2 protocol on rendered scenes, reduced (the full study: benchmarks/bench_table2.py)."""

import numpy as np

from imc.table2 import Table2Config, _shifts, run_class


def test_shift_draws_respect_range_and_overlap():
    cfg = Table2Config()
    d = _shifts(2000, cfg, np.random.default_rng(0))
    assert np.abs(d).max() <= 144
    assert ((1 - np.abs(d[:, 0]) / 256) * (1 - np.abs(d[:, 1]) / 256)).min() >= 0.4
    assert np.abs(d).max() >= 140  # the whole range is used


def test_reduced_protocol_urban_accurate_and_calm_water_flagged_not_wrong():
    """128^2 blocks, 4 refs x 9 shifts: urban succeeds with small error; calm water is never
    reported valid with an error above 0.5 px (it is flagged invalid instead)."""
    cfg = Table2Config(block_px=128, n_refs=4, n_shifts=9, max_shift_px=72, n_phases=2)
    urban = run_class("urban", cfg, seed=1)
    assert urban["success_pct"] >= 90.0 and urban["wrong_pct"] == 0.0
    assert urban["std_px"] < 0.03
    calm = run_class("calm_water", cfg, seed=1)
    assert calm["wrong_pct"] == 0.0

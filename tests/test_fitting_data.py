"""Cells of runs (accelcal.fitting.data) on what real DAQs add: a logged angle with reading
noise, rare spikes; truth from the simulator's scenario."""
from __future__ import annotations

import numpy as np

from accelcal.fitting.data import fit_noise, make_run, reject_spikes
from accelcal.simulate import load_scenario, simulate_campaign


def _tumble(noise, seed=3):
    sc = {"unit": {"serial": "T-1", "model": "M", "output_unit": "m/s2", "coefficients": {"K1": 1.0}},
          "site": {"latitude_deg": 39.9, "g_local_m_s2": 9.80122}, "noise": noise,
          "test": [{"kind": "tumble", "positions": 12, "readings": 40}]}
    r = simulate_campaign(load_scenario(sc), seed)[0]
    return r, make_run(r.meta, r.data)


def test_noisy_logged_angle_keeps_one_cell_per_position():
    r, run = _tumble({"white_m_s2": 2e-6, "angle_log_deg": 1e-3})
    assert run.ncell == 12
    assert np.all(run.n == 40)


def test_spikes_dropped_and_noise_not_inflated():
    noise = {"white_m_s2": 2e-6, "spike_rate": 0.01, "spike_m_s2": 1e-4}
    r, run = _tumble(noise)
    g = 9.80122
    clean = g * np.cos(np.radians(r.data.angle_deg.to_numpy()))
    truth = np.abs(r.data.output.to_numpy() - clean) > 5e-5          # the spikes the simulator made
    n = reject_spikes(run)
    assert n == int(truth.sum()) and n > 0
    assert np.all(run.cid[truth] == -1) and np.all(run.cid[~truth] >= 0)
    fit_noise(run, run.y_rows - clean)
    assert np.sqrt(run.noise.a) < 1.2 * 2e-6


def test_big_frame_cells_are_the_frame_columns(monkeypatch):
    """A run's frame above BLOCK_CELLS is not copied into one block (issue 28: a big run in
    memory once): its float64 columns are used as they are, and the cells are those of the
    block path, bit for bit."""
    from accelcal.fitting import data as fdata
    r, small = _tumble({"white_m_s2": 2e-6})
    monkeypatch.setattr(fdata, "BLOCK_CELLS", 0)
    big = make_run(r.meta, r.data)
    assert np.shares_memory(big.y_rows, r.data["output"].to_numpy())
    for a in ("y", "x", "n", "cid", "lines", "y_rows"):
        assert np.array_equal(getattr(big, a), getattr(small, a)), a
    assert all(np.array_equal(big.cols[c], small.cols[c], equal_nan=True) for c in small.cols)

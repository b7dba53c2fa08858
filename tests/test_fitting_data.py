"""Cells of runs (accelcal.fitting.data) on what real DAQs add: a logged angle with reading
noise, rare spikes; truth from the simulator's scenario."""
from __future__ import annotations

import numpy as np
import pytest

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
    assert np.sqrt(fit_noise(run, run.y_rows - clean).a) < 1.2 * 2e-6


def test_a_runs_float_columns_are_the_frame_columns():
    """make_run takes a frame's float64 columns as they are (a big run is in memory once)."""
    r, small = _tumble({"white_m_s2": 2e-6})
    assert np.shares_memory(small.y_rows, r.data["output"].to_numpy())


# ------------------------------------------------------------------ AR(1) noise (issue 26)

def _ar1(rng, size, rho):
    """AR(1) rows of unit marginal variance, made here with a plain loop (independent of
    the simulator's filter)."""
    e = np.empty(size)
    e[0] = rng.standard_normal()
    for t in range(1, size):
        e[t] = rho * e[t - 1] + np.sqrt(1 - rho * rho) * rng.standard_normal()
    return e


def test_expected_lag1_of_cell_deviations_is_the_matrix_trace():
    """E[sum d_t d_{t+1}] and E[sum d_t^2] of deviations from a cell mean, against
    tr(A C R C) built from the matrices (C = I - 11^T/n, R_ij = rho^|i-j|)."""
    from accelcal.fitting.data import ar1_deviation_lag1
    for n in (3, 8, 25):
        for rho in (-0.3, 0.0, 0.6, 0.9):
            i = np.arange(n)
            R = rho ** np.abs(i[:, None] - i[None, :])
            C = np.eye(n) - 1.0 / n
            S = C @ R @ C
            f1, f0 = ar1_deviation_lag1(n, rho)
            assert f1 == pytest.approx(np.trace(S, offset=1), rel=1e-12, abs=1e-12)
            assert f0 == pytest.approx(np.trace(S), rel=1e-12)


def test_rho_from_short_cells_is_not_biased_low():
    """500 cells of 8 AR(1) readings at rho = 0.9: the plain pooled ratio (+1/n) reads about
    0.5, the moment-matched one within 0.03 of 0.9; the within-cell scatter's dof are
    Satterthwaite's (checked against the simulated variance of the sum of squares)."""
    from accelcal.fitting.data import ar1_from_lag1, ar1_scatter_dof
    rng = np.random.default_rng(26)
    n, cells, rho = 8, 500, 0.9
    e = np.stack([_ar1(rng, n, rho) for _ in range(cells)])
    d = e - e.mean(axis=1, keepdims=True)
    r = float(np.sum(d[:, 1:] * d[:, :-1]) / np.sum(d * d))
    assert r + 1 / n < 0.65                                   # the short-cell bias
    assert ar1_from_lag1(r, np.full(cells, n), np.sum(d * d, axis=1)) == pytest.approx(rho, abs=0.03)
    Q = np.sum(d * d, axis=1)
    nu_mc = 2 * Q.mean() ** 2 / Q.var()
    assert ar1_scatter_dof(np.array([n]), rho)[0] == pytest.approx(nu_mc, rel=0.2)
    assert ar1_scatter_dof(np.array([n]), 0.0)[0] == n - 1
    big = ar1_scatter_dof(np.array([400]), 0.6)[0]
    assert big == pytest.approx(399 * (1 - 0.36) / (1 + 0.36), rel=0.02)   # Bartlett's long-cell limit

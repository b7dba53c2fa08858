"""Power where a family is weak: the pooled sweep-hysteresis contrast and AR(1) noise read
from short cells.  Truth from hand-made residuals and arrays, numpy simulations and closed
forms written here."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from accelcal.fitting.data import ar1_deviation_lag1, fit_noise, make_run, mean_variance
from accelcal.simulate import load_scenario, simulate_campaign


def test_rising_steps_are_matched_to_falling_ones_of_the_same_run_and_level():
    """The top of a sweep and a level met once stay out; each rising step is used once;
    runs are not mixed."""
    from accelcal.diagnosis.localise import sweep_pairs
    run = np.array(["a"] * 7 + ["b"] * 3, object)
    sweep = np.array(["rest", "up", "up", "up", "down", "down", "down", "up", "down", "down"], object)
    level = np.array([0, 1, 5, 9, 5.05, 1, 3, 2, 2.01, 2.0])
    assert sweep_pairs(run, sweep, level).tolist() == [0, 1, 1, 0, -1, -1, 0, 1, -1, 0]


def _ar1_rows(rng, cells, n, rho):
    """cells x n AR(1) readings of unit marginal variance, each cell its own stationary
    series (numpy only)."""
    e = np.empty((cells, n))
    e[:, 0] = rng.standard_normal(cells)
    for t in range(1, n):
        e[:, t] = rho * e[:, t - 1] + math.sqrt(1 - rho * rho) * rng.standard_normal(cells)
    return e


@pytest.mark.parametrize("n,rho", [(8, 0.0), (8, 0.3), (8, 0.9), (10, 0.5), (10, 0.95)])
def test_short_cell_bias_of_the_lag1_ratio(n, rho):
    """The pooled lag-1 ratio of deviations from the cell mean is far below rho in short
    cells (at rho = 0: -1/n exactly); its expectation, the ratio the estimator inverts,
    against 20,000 simulated cells."""
    rng = np.random.default_rng(7)
    e = _ar1_rows(rng, 20000, n, rho)
    d = e - e.mean(axis=1, keepdims=True)
    simulated = np.sum(d[:, 1:] * d[:, :-1]) / np.sum(d * d)
    lag1, squares = ar1_deviation_lag1(n, rho)
    assert lag1 / squares == pytest.approx(simulated, abs=0.01)
    if rho == 0.0:
        assert lag1 / squares == pytest.approx(-1.0 / n, abs=1e-12)
    else:
        assert lag1 / squares < rho - 0.2          # the bias a plain lag-1 ratio would carry


def _tumble_run(rng, rho, n=8, positions=24):
    sc = {"unit": {"serial": "T-1", "model": "M", "output_unit": "m/s2", "coefficients": {"K1": 1.0}},
          "site": {"latitude_deg": 39.9, "g_local_m_s2": 9.80122}, "noise": {},
          "test": [{"kind": "tumble", "positions": positions, "readings": n}]}
    r = simulate_campaign(load_scenario(sc), 0)[0]
    e = _ar1_rows(rng, 1, len(r.data), rho)[0]           # AR(1) across the whole run
    r.data["output"] = r.data["output"] + 2e-6 * e
    run = make_run(r.meta, r.data)
    g = 9.80122
    return run, run.y_rows - g * np.cos(np.radians(r.data["angle_deg"].to_numpy()))


def test_a_weak_rho_is_not_taken_as_zero_by_the_diagnosis():
    """AR(1) at rho = 0.3 in 8-reading cells: the significance gate reads it as 0 in many
    runs, which puts a cell mean's variance about 1.9 times too low; the diagnosis's
    (cautious) noise model keeps its estimate.  Truth: Var(mean) = sigma^2 1'R1 / n^2,
    R_ij = rho^|i-j|."""
    rng = np.random.default_rng(11)
    rho, n = 0.3, 8
    i = np.arange(n)
    true_var = (2e-6) ** 2 * float(np.sum(rho ** np.abs(i[:, None] - i[None, :]))) / n ** 2
    plain, cautious, zeroed = [], [], 0
    for _ in range(40):
        run, res = _tumble_run(rng, rho, n)
        m0, m1 = fit_noise(run, res), fit_noise(run, res, cautious=True)
        zeroed += m0.rho == 0.0
        plain.append(np.median(mean_variance(run, m0)) / true_var)
        cautious.append(np.median(mean_variance(run, m1)) / true_var)
    assert zeroed >= 5
    assert np.median(plain) < 0.8
    assert 0.85 < np.median(cautious) < 1.6


def test_pooled_hysteresis_contrast_on_a_hand_made_residual():
    """A clean IA pair's fit, its whitened residual replaced by c times the part of a
    hysteresis signature the model does not take up (built here from the cells: rising
    steps +a_IA, falling ones -a_IA at the same level, over each cell mean's sigma; the
    projection by least squares on the fit's Jacobian) plus white noise: the contrast's z is
    s_p . z / |s_p| and its estimate c."""
    from accelcal.diagnosis import diagnose
    from accelcal.diagnosis.localise import shape_tests
    from accelcal.validation import diagnosis_benchmark as db
    sc = db.scenario("centrifuge", {})
    sc["test"][0]["mounts"] = db.ia_pa_mounts((0, 180))
    f = diagnose(db.runs_of(sc, 5), db.DEV_BASELINE["centrifuge"])["_fits"]["after"]
    s = []
    for j, r in enumerate(f.model.runs):
        rate = r.cell_mean(r.cols["table_rate_rad_s"])
        order = np.argsort(r.cell_mean(r.cols["time_s"]))
        ranked = rate[order]
        top = int(np.argmax(ranked))
        side = np.zeros(r.ncell)
        for k in range(top + 1, len(ranked)):          # falling step k, its rising twin
            twin = [u for u in range(1, top) if abs(ranked[u] - ranked[k]) < 1e-3 * ranked[k]]
            if twin:
                side[order[twin[0]]], side[order[k]] = 1.0, -1.0
        a_ia = rate ** 2 * float(r.meta["arm_radius_m"]) * math.cos(math.radians(r.meta["mount_angle_deg"]))
        k1 = abs(f.fit.value(f.model.name(r.campaign, "K1")))
        s.append(side * a_ia * k1 / f.model.sig[f.model.rows(j)])
    s = np.concatenate(s)
    J = f.fit.J[:, f.active]
    sp = s - J @ np.linalg.lstsq(J, s, rcond=None)[0]
    c = 4e-7
    noise = np.random.default_rng(3).standard_normal(s.size)
    noise -= J @ np.linalg.lstsq(J, noise, rcond=None)[0]
    z = c * sp + noise
    f2 = replace(f, fit=replace(f.fit, z=z))
    (t,) = shape_tests(f2)
    assert t["z"] == pytest.approx(float(sp @ z) / np.linalg.norm(sp), rel=1e-3)
    assert t["estimate"] == pytest.approx(float(sp @ z) / float(sp @ sp), rel=1e-3)
    assert t["std_uncertainty"] == pytest.approx(1 / np.linalg.norm(sp), rel=1e-3)
    assert t["significant"] == (abs(t["z"]) > 3.29)

"""Drift model and due dates (issue 29): accelcal.drift against independent truth.

* closed forms (a weighted straight line, the normal out-of-tolerance probability);
* suncal's variables method (NCSLI RP-1 V1; GPL, a test-only dependency, called, never
  copied): same series, same drift rate, due interval within the models' difference;
* ten units of a simulator written here from the issue's statement (not from the
  module): four stable, six drifting in K1, yearly tumbles.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats

from accelcal import drift
from accelcal.config import ConfigError, forecast_config


# ------------------------------------------------------------------ closed forms ----

def test_line_is_the_weighted_least_squares_line():
    t = np.array([0.0, 1.0, 2.0, 3.5, 4.0])
    x = np.array([1.0, 1.9, 3.2, 4.4, 5.1])
    u = np.array([0.1, 0.2, 0.1, 0.3, 0.1])
    f = drift.fit_drift(t, x, u)
    var = u ** 2 + f.tau2
    w = 1 / var                                     # normal equations written out
    S, Sx, Sy = w.sum(), (w * t).sum(), (w * x).sum()
    Sxx, Sxy = (w * t * t).sum(), (w * t * x).sum()
    b = (S * Sxy - Sx * Sy) / (S * Sxx - Sx ** 2)
    assert f.b == pytest.approx(b, rel=1e-12)
    assert f.u_b == pytest.approx(math.sqrt(S / (S * Sxx - Sx ** 2)), rel=1e-12)


def test_scatter_estimate_is_dersimonian_laird_for_a_constant():
    # a constant (slope column dropped) is the meta-analysis case: tau^2 = (Q - (n-1)) / c
    x = np.array([0.0, 3.0, -2.0, 4.0, 1.0])
    u = np.array([1.0, 1.0, 2.0, 1.0, 0.5])
    w = 1 / u ** 2
    m = (w * x).sum() / w.sum()
    Q = (w * (x - m) ** 2).sum()
    c = w.sum() - (w ** 2).sum() / w.sum()
    Qm, dof, cm = drift.scatter_moments(np.ones((5, 1)), x, u)
    assert (Qm, dof, cm) == (pytest.approx(Q), 4.0, pytest.approx(c))
    assert (Q - 4) / c > 0


def test_p_out_is_the_normal_two_sided_tail():
    p = drift.p_out(0.3, 0.5, np.inf, 0.0, 1.0)
    assert p == pytest.approx(stats.norm.sf((1 - 0.3) / 0.5) + stats.norm.cdf((-1 - 0.3) / 0.5))


def test_en_between_consecutive_campaigns_is_the_iso13528_form():
    en = drift.en_consecutive([1.0, 1.3], [0.1, 0.2])
    assert en[0] == pytest.approx(0.3 / math.sqrt(0.05))


def test_tolerance_relative_and_absolute():
    assert drift.tolerance_of({"relative": 2e-4}, -0.5) == pytest.approx(1e-4)
    assert drift.tolerance_of({"absolute": 5e-4}, 3.0) == 5e-4
    assert drift.tolerance_of(None, 1.0) is None


# -------------------------------------------------------------- stated bases ----

def test_one_campaign_no_fleet_gives_a_basis_not_a_date():
    f = drift.forecast([2024.0], [1.0], [1e-5], {"relative": 2e-4}, 0.05)
    assert f.due is None and "no due date" in f.basis and f.drift_per_year is None


def test_one_campaign_with_a_fleet_prior_says_so():
    prior = drift.FleetPrior(tau2=1e-12, dof=10, slope_mean=0.0, slope_sd=5e-5, n_units=6)
    f = drift.forecast([2024.0], [1.0], [5e-6], {"relative": 2e-4}, 0.05, prior=prior)
    assert f.basis.startswith(drift.BASIS_FLEET) and f.due is not None
    # eq (4) with the prior's spread: P_out at the due date is the risk
    d = f.due - 2024.0
    s = math.sqrt(5e-6 ** 2 + 1e-12 + (5e-5 * d) ** 2)
    assert 2 * stats.t.sf(2e-4 / s, 5) == pytest.approx(0.05, abs=2e-3)


def test_two_campaigns_a_day_apart_borrow_the_fleets_drift_rate():
    # the sample drops' case: one unit on two centrifuges on consecutive days
    prior = drift.FleetPrior(tau2=1e-12, dof=10, slope_mean=0.0, slope_sd=5e-5, n_units=6)
    t = np.array([2026.0, 2026.0 + 1 / 365.25])
    f = drift.forecast(t, [1.0, 1.0 + 1e-6], [5e-6, 5e-6], {"relative": 2e-4}, 0.05,
                       prior=prior)
    assert f.basis.startswith(drift.BASIS_FLEET) and "less certain" in f.basis
    assert f.drift_per_year == 0.0 and f.u_drift_per_year == 5e-5


def test_missing_tolerance_gives_no_date():
    t = np.arange(5.0)
    f = drift.forecast(t, 1 + 1e-4 * t, np.full(5, 1e-6), None, 0.05)
    assert f.due is None and f.basis.startswith(drift.BASIS_NO_TOL)
    assert f.drift_per_year == pytest.approx(1e-4)


def test_adjustment_starts_a_new_series():
    t = np.arange(6.0)
    x = np.array([1.0, 1.0001, 1.0002, 1.0, 1.0001, 1.0002])   # reset at campaign 4
    u = np.full(6, 2e-6)
    plain = drift.forecast(t, x, u, {"relative": 2e-4}, 0.05)
    adj = drift.forecast(t, x, u, {"relative": 2e-4}, 0.05,
                         adjusted=[False, False, False, True, False, False])
    assert adj.series_start == 3 and adj.n_campaigns == 3
    assert adj.drift_per_year == pytest.approx(1e-4, rel=1e-6)
    assert "adjustment" in adj.basis
    # the same jump without the mark is a step the line cannot explain: flagged
    assert [s.at for s in plain.steps] == [3]


def test_step_is_flagged_and_not_smoothed_over():
    rng = np.random.default_rng(1)
    t = np.arange(7.0)
    u = np.full(7, 1e-6)
    x = 1 + 3e-5 * t + u * rng.standard_normal(7) + 2e-5 * (np.arange(7) >= 4)
    f = drift.forecast(t, x, u, {"relative": 2e-4}, 0.05)
    assert [s.at for s in f.steps] == [4] and f.steps[0].en > 2
    assert f.drift_per_year == pytest.approx(3e-5, rel=0.1)
    stable = 1 + 3e-5 * t + u * rng.standard_normal(7)
    assert drift.forecast(t, stable, u, {"relative": 2e-4}, 0.05).steps == []


def test_due_date_statement_only_when_agreed():
    assert drift.due_date_statement("2027-03-01", "drift fit", 0.05, False) is None
    s = drift.due_date_statement("2027-03-01", "drift fit (6 calibrations)", 0.05, True)
    assert "2027-03-01" in s and "5 %" in s
    s = drift.due_date_statement(None, "no tolerance: none in the config", 0.05, True)
    assert "No recalibration date" in s and "no tolerance" in s


def test_forecast_config(tmp_path):
    p = tmp_path / "accelcal.toml"
    p.write_text('[tolerance."QA-2000"]\nK1 = { relative = 2.0e-4 }\nK0 = { absolute = 5.0e-4 }\n'
                 '[forecast]\nrisk = 0.02\n[certificate]\nstate_due_date = true\n')
    c = forecast_config(p)
    assert c.tolerance("QA-2000", "K1") == {"relative": 2e-4}
    assert c.tolerance("QA-2000", "K2") is None and c.tolerance("other", "K1") is None
    assert c.risk == 0.02 and c.state_due_date is True
    p.write_text('[tolerance."QA-2000"]\nK1 = { relative = -1 }\n')
    with pytest.raises(ConfigError, match=r'tolerance."QA-2000"\] K1'):
        forecast_config(p)


# ------------------------------------------------- suncal's variables method ----

def test_drift_fit_agrees_with_suncal_variables_method():
    """suncal (sandialabs, NCSLI RP-1 Variables Method V1): the drift rate fitted to the
    deviations of all pairs of calibrations (their zero-intercept least squares) is the
    ordinary least-squares slope, so with equal u our weighted line gives the same rate
    to rounding.  The reliability-target interval differs by model: suncal spreads the
    value at the last calibration by its time-of-test u0 and treats the pairs as
    independent; we use the line's own uncertainty there.  Agreement within 20 %."""
    variables = pytest.importorskip("suncal.intervals.variables")
    from scipy.optimize import brentq
    rng = np.random.default_rng(5)
    for _ in range(8):
        n = 8
        t = np.cumsum(np.r_[0, rng.uniform(0.7, 1.3, n - 1)])
        b = 10 * rng.uniform(1, 3)            # ppm/a
        u = np.full(n, 2.0)                   # ppm
        x = b * t + u * rng.standard_normal(n)
        T = 20.0
        pairs = list(itertools.combinations(range(n), 2))
        v = variables.VariablesReliabilityTarget([t[j] - t[i] for i, j in pairs],
                                                 [x[j] - x[i] for i, j in pairs], u0=u[-1])
        fr = v._fitcurve(order=1)
        interval = brentq(lambda s: v.reliability(s, -T, T, fr) - 0.95, 1e-3, 20)
        f = drift.forecast(t, x, u, {"absolute": T}, 0.05)
        assert f.drift_per_year == pytest.approx(fr.b[0], rel=1e-9)
        assert (f.due - t[-1]) / interval == pytest.approx(1.0, abs=0.2)


def _pair_fleet(rng, n_units=12, b=2e-5, u=1e-6, repro=2e-6):
    """Units calibrated twice, a year or so apart: a common drift rate, each value with
    its stated u and a reproducibility error (sd ``repro``) that u does not hold."""
    out = []
    for _ in range(n_units):
        t = np.array([0.0, rng.uniform(0.6, 1.6)])
        x = 1 + b * t + u * rng.standard_normal(2) + repro * rng.standard_normal(2)
        out.append((t, x, np.full(2, u)))
    return out


def test_fleet_reproducibility_from_pairs_is_suncals_variables_residual():
    """A fleet of two-calibration units: the between-calibration scatter is what suncal's
    variables method (NCSLI RP-1 V1) leaves in its residuals.  Its fit of the pairs'
    differences through zero has s^2 = RSS / (n - 1), and a difference holds the scatter
    and the stated u twice: tau^2 = s^2 / 2 - u^2, exactly, with equal u."""
    variables = pytest.importorskip("suncal.intervals.variables")
    rng = np.random.default_rng(43)
    fleet = _pair_fleet(rng)
    v = variables.VariablesData([t[1] - t[0] for t, _, _ in fleet],
                                [x[1] - x[0] for _, x, _ in fleet])
    syx = v._fitcurve(order=1).syx
    prior = drift.fleet_prior(fleet)
    assert prior.tau2 == pytest.approx(syx ** 2 / 2 - 1e-6 ** 2, rel=1e-9)
    assert prior.dof == len(fleet) - 1


def test_two_calibrations_give_the_units_own_rate_with_a_wide_interval():
    """Two calibrations show a drift: the unit's own rate, (x2 - x1) / (t2 - t1), with u
    from both values and the fleet's scatter (sqrt(u1^2 + u2^2 + 2 tau^2) / dt), and a due
    date from it; with four more calibrations on the same line the interval narrows."""
    rng = np.random.default_rng(7)
    prior = drift.fleet_prior(_pair_fleet(rng))
    t = np.array([0.0, 1.0])
    x = np.array([1.0, 1.0 + 6e-5])
    u = np.full(2, 1e-6)
    f = drift.forecast(t, x, u, {"relative": 2e-4}, 0.05, prior=prior)
    assert f.basis.startswith(drift.BASIS_FIT) and "no drift rate" not in f.basis
    assert f.drift_per_year == pytest.approx(6e-5, rel=1e-9)
    assert f.u_drift_per_year == pytest.approx(math.sqrt(2 * 1e-12 + 2 * prior.tau2), rel=1e-6)
    lo, hi = f.due_interval
    assert f.due is not None and lo < f.due and (hi is None or hi > f.due)
    t6 = np.arange(6.0) - 4.0
    more = drift.forecast(t6, 1.0 + 6e-5 * (t6 + 4.0) - 6e-5 * 4 + 6e-5, np.full(6, 1e-6),
                          {"relative": 2e-4}, 0.05, prior=prior)
    assert more.u_drift_per_year < f.u_drift_per_year / 2
    assert (more.due_interval[1] - more.due_interval[0]) < (hi or np.inf) - lo


# ------------------------------------------------- an independent simulator ----

def _independent_fleet(seed: int = 2026):
    """Ten QA-2000 units tumbled once a year for six years (issue 29's statement):
    four stable, six with K1 drifting at 5e-5 .. 2e-4 a year (relative), either sign.
    K1 about 0.1 out/(m/s2); a tumble's u(K1) 4-6 ppm of K1; the unit also wanders
    3 ppm between campaigns (mounting, temperature history)."""
    rng = np.random.default_rng(seed)
    rates = [0.0, 0.0, 0.0, 0.0, 5e-5, 8e-5, 1.1e-4, 1.4e-4, 1.7e-4, 2e-4]
    units = []
    for j, rate in enumerate(rates):
        k1 = 0.1 * (1 + 0.002 * rng.standard_normal())
        years = 2020.0 + np.arange(6) + rng.uniform(-0.05, 0.05, 6)
        sign = -1.0 if j % 2 else 1.0
        truth = k1 * (1 + sign * rate * (years - years[0]))
        u = k1 * rng.uniform(4e-6, 6e-6, 6)
        x = truth + k1 * 3e-6 * rng.standard_normal(6) + u * rng.standard_normal(6)
        units.append((rate, k1, years, x, u, truth))
    return units


def test_ten_units_of_an_independent_simulator():
    units = _independent_fleet()
    prior = drift.fleet_prior([(t, x, u) for _, _, t, x, u, _ in units])
    for rate, k1, t, x, u, truth in units:
        f = drift.forecast(t, x, u, {"relative": 2e-4}, 0.05, prior=prior)
        if rate == 0:
            assert f.due is None or f.due - t[-1] > 3.0
        else:
            # true interval: the true K1 leaves |K1 - K1 in use| <= 2e-4 |K1 in use|
            tol = 2e-4 * abs(x[-1])
            gap = tol - np.sign(truth[-1] - truth[0]) * (truth[-1] - x[-1])
            true_interval = gap / (rate * k1)
            assert f.due is not None
            assert 0.5 <= (f.due - t[-1]) / true_interval <= 1.1, (rate, f.basis)
        assert f.steps == []

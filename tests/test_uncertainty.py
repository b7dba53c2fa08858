"""Tests of the GUM engine (JCGM 100), JCGM 101's numerical tolerance and paper 000's
u(Kip), against closed forms computed by hand here."""
from __future__ import annotations

import math

import pytest

from accelcal.estimators.uncertainty import (kip_uncertainty, linear_budget, numerical_tolerance, uniform_u,
                                             welch_satterthwaite)
from accelcal.results import BudgetTerm


def test_uniform_type_b():
    assert uniform_u(0.3) == pytest.approx(0.3 / math.sqrt(3), rel=1e-15)
    assert uniform_u(-0.3) == pytest.approx(0.17320508075688773, rel=1e-14)


def test_linear_budget_is_the_closed_form():
    # y = 3 a - 2 b + 0.5 c at (1, 2, 4), u = (0.1, 0.2, 0.4): y = 1, u_c^2 = 9 0.01 + 4 0.04 + 0.25 0.16
    terms = [("a", 1.0, 0.1, 3.0, "A", "normal"), ("b", 2.0, 0.2, -2.0, "B", "uniform"),
             ("c", 4.0, 0.4, 0.5, "A", "normal")]
    value, u_c, lines = linear_budget("y", terms, method="m", rig_id="R")
    assert value == pytest.approx(3 - 4 + 2)
    assert u_c == pytest.approx(math.sqrt(9 * 0.01 + 4 * 0.04 + 0.25 * 0.16), rel=1e-12)
    assert all(isinstance(t, BudgetTerm) for t in lines)
    assert [t.contribution for t in lines] == pytest.approx([0.3, 0.4, 0.2], rel=1e-12)
    assert [t.type for t in lines] == ["A", "B", "A"] and lines[1].distribution == "uniform"
    assert {(t.coefficient, t.method, t.rig_id) for t in lines} == {("y", "m", "R")}
    assert linear_budget("y", terms, value=7.0).value == 7.0
    with pytest.raises(ValueError, match="unknown distribution"):
        linear_budget("y", [("a", 1.0, 0.1, 1.0, "B", "cauchy")])


def test_welch_satterthwaite():
    # contributions 0.3 (nu = 4) and 0.4 (nu = inf): nu_eff = 0.25^2 / (0.3^4 / 4)
    nu = welch_satterthwaite([0.3, 0.4], [4, math.inf])
    assert nu == pytest.approx(0.0625 / (0.0081 / 4), rel=1e-12)
    assert welch_satterthwaite([0.3, 0.4], [math.inf, math.inf]) == math.inf


def test_numerical_tolerance_jcgm101():
    assert numerical_tolerance(0.0123, 2) == pytest.approx(0.0005)
    assert numerical_tolerance(1.0, 2) == pytest.approx(0.05)     # 1.0 = 10 x 10^-1
    assert numerical_tolerance(0.0999, 2) == pytest.approx(0.005)  # rounds to 0.10
    assert numerical_tolerance(35.0, 1) == pytest.approx(5.0)       # 4 x 10^1


def test_kip_gum_factor_4_against_printed_2():
    # hand case (s2/m): u(c2) = 3e-9, u(dc2) = 4e-9, u(K2) = 1e-9, u(Kpp) = 2e-9, u(dKpp) = 2e-9
    # printed eq 10: sqrt(2 (9 + 16) + 1 + 4 + 4) e-9 = sqrt(59) e-9
    # GUM (c = 2 on c2, dc2): sqrt(4 (9 + 16) + 9) e-9 = sqrt(109) e-9
    r = kip_uncertainty(3e-9, 4e-9, 1e-9, 2e-9, 2e-9)
    assert r["printed"] == pytest.approx(math.sqrt(59) * 1e-9, rel=1e-12)
    assert r["gum"] == pytest.approx(math.sqrt(109) * 1e-9, rel=1e-9)
    assert r["differ"] is True
    assert [t.sensitivity for t in r["budget"]] == pytest.approx([2, 2, -1, -1, -1], rel=1e-9)
    same = kip_uncertainty(0.0, 0.0, 1e-9, 2e-9, 2e-9)
    assert same["differ"] is False and same["gum"] == pytest.approx(3e-9)


# ----------------------------------------------------------------- JCGM 100:2008 Annex H.1

#: GUM H.1 (end-gauge calibration), the inputs as the annex gives them (SI: m, degC):
#: name, estimate, standard uncertainty, degrees of freedom, distribution.  d = d_bar + d1 + d2
#: (H.1.3.2: repeated observations, random and systematic effects of the comparator) and
#: theta = theta_bar + Delta (H.1.3.3: mean deviation, cyclic variation, arcsine) enter as
#: their components; every input is uncorrelated with every other (H.1.3).
GUM_H1 = [
    ("l_S", 50.000623e-3, 25e-9, 18, "normal"),
    ("d_bar", 215e-9, 5.8e-9, 24, "normal"),
    ("d1", 0.0, 3.9e-9, 5, "normal"),
    ("d2", 0.0, 6.7e-9, 8, "normal"),
    ("alpha_S", 11.5e-6, 1.2e-6, math.inf, "uniform"),
    ("theta_bar", -0.1, 0.2, math.inf, "normal"),
    ("Delta", 0.0, 0.35, math.inf, "arcsine"),
    ("delta_alpha", 0.0, 0.58e-6, 50, "uniform"),
    ("delta_theta", 0.0, 0.029, 2, "uniform"),
]


def test_gum_annex_h1_end_gauge_budget():
    """The budget code on GUM H.1: l = l_S + d - l_S (delta_alpha theta + alpha_S delta_theta)
    = 50.000838 mm, u_c = 32 nm (Table H.1: contributions 25 nm (l_S), 9.7 nm (d), 0 (alpha_S,
    theta: zero sensitivity to first order), 2.9 nm (delta_alpha), 16.6 nm (delta_theta)),
    nu_eff = 16 (H.1.6: 16.7, truncated), U99 = 93 nm.  The sensitivities are the annex's
    partial derivatives at the estimates; the published numbers are the truth."""
    from scipy.stats import t
    x = {name: v for name, v, _, _, _ in GUM_H1}
    lS, theta = x["l_S"], x["theta_bar"] + x["Delta"]
    sens = {"l_S": 1.0, "d_bar": 1.0, "d1": 1.0, "d2": 1.0, "alpha_S": -lS * x["delta_theta"],
            "theta_bar": -lS * x["delta_alpha"], "Delta": -lS * x["delta_alpha"],
            "delta_alpha": -lS * theta, "delta_theta": -lS * x["alpha_S"]}
    terms = [(name, v, u, sens[name], "A" if dist == "normal" else "B", dist) for name, v, u, _, dist in GUM_H1]
    value = lS + x["d_bar"] + x["d1"] + x["d2"] - lS * (x["delta_alpha"] * theta + x["alpha_S"] * x["delta_theta"])
    res = linear_budget("l", terms, method="gum_h1", value=value)
    assert res.value == pytest.approx(50.000838e-3, abs=0.5e-9)
    assert round(res.u_c * 1e9) == 32                                   # nm, as published
    contrib = {b.quantity: b.contribution * 1e9 for b in res.terms}
    assert contrib["l_S"] == pytest.approx(25.0, abs=0.05)
    assert math.sqrt(contrib["d_bar"] ** 2 + contrib["d1"] ** 2 + contrib["d2"] ** 2) == pytest.approx(9.7, abs=0.05)
    assert contrib["alpha_S"] == pytest.approx(0.0, abs=1e-3) and contrib["theta_bar"] == pytest.approx(0.0, abs=1e-3)
    assert contrib["delta_alpha"] == pytest.approx(2.9, abs=0.05)
    assert contrib["delta_theta"] == pytest.approx(16.6, abs=0.1)
    assert all(b.method == "gum_h1" for b in res.terms)
    nu_eff = welch_satterthwaite([b.contribution for b in res.terms], [nu for _, _, _, nu, _ in GUM_H1])
    assert 16 <= nu_eff < 17                                             # H.1.6: 16.7 -> 16
    assert t.ppf(0.995, int(nu_eff)) * res.u_c * 1e9 == pytest.approx(93, abs=1.5)   # t_99(16) u_c

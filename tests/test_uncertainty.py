"""Tests of the GUM engine (JCGM 100), JCGM 101's numerical tolerance and paper 000's
u(Kip), against closed forms computed by hand here."""
from __future__ import annotations

import math

import numpy as np
import pytest

from accelcal.estimators.uncertainty import (gum_budget, kip_uncertainty, linear_budget, numerical_tolerance,
                                             uniform_u, welch_satterthwaite)
from accelcal.results import BudgetTerm


def linear(a, b, c):
    return 3.0 * a - 2.0 * b + 0.5 * c


def test_uniform_type_b():
    assert uniform_u(0.3) == pytest.approx(0.3 / math.sqrt(3), rel=1e-15)
    assert uniform_u(-0.3) == pytest.approx(0.17320508075688773, rel=1e-14)


def test_linear_budget_is_the_closed_form():
    x, u = [1.0, 2.0, 4.0], [0.1, 0.2, 0.4]
    value, u_c, terms = gum_budget(linear, ["a", "b", "c"], x, u, ["normal", "uniform", "normal"],
                                   coefficient="y")
    assert value == pytest.approx(3 - 4 + 2)
    assert u_c == pytest.approx(math.sqrt(9 * 0.01 + 4 * 0.04 + 0.25 * 0.16), rel=1e-10)
    assert all(isinstance(t, BudgetTerm) for t in terms)
    assert [t.sensitivity for t in terms] == pytest.approx([3.0, -2.0, 0.5], rel=1e-10)
    assert [t.contribution for t in terms] == pytest.approx([0.3, 0.4, 0.2], rel=1e-10)
    assert [t.type for t in terms] == ["A", "B", "A"]
    assert terms[1].distribution == "uniform" and terms[0].coefficient == "y"
    res = gum_budget(linear, ["a", "b", "c"], x, u)
    assert res.U == pytest.approx(2 * res.u_c) and res.k == 2.0


def test_correlated_inputs_and_analytic_sensitivities():
    x, u = [1.0, 2.0, 4.0], [0.1, 0.2, 0.4]
    r = np.eye(3)
    r[0, 1] = r[1, 0] = 0.5
    res = gum_budget(linear, ["a", "b", "c"], x, u, correlation=r, sensitivities=[3, -2, 0.5])
    # JCGM 100 eq 13: + 2 c_a c_b u_a u_b r_ab
    expected = 9 * 0.01 + 4 * 0.04 + 0.25 * 0.16 + 2 * 3 * (-2) * 0.1 * 0.2 * 0.5
    assert res.u_c == pytest.approx(math.sqrt(expected), rel=1e-12)


def test_welch_satterthwaite_and_t_coverage():
    # contributions 0.3 (nu = 4) and 0.4 (nu = inf): nu_eff = 0.25^2 / (0.3^4 / 4)
    nu = welch_satterthwaite([0.3, 0.4], [4, math.inf])
    assert nu == pytest.approx(0.0625 / (0.0081 / 4), rel=1e-12)
    res = gum_budget(lambda a, b: a + b, ["a", "b"], [0, 0], [0.3, 0.4], dofs=[4, math.inf],
                     use_t=True, p=0.95)
    assert res.nu_eff == pytest.approx(nu)
    from scipy.stats import t
    assert res.k == pytest.approx(t.ppf(0.975, nu)) and res.U == pytest.approx(res.k * 0.5)


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


def end_gauge(l_S, d_bar, d1, d2, alpha_S, theta_bar, Delta, delta_alpha, delta_theta):
    """GUM H.1 eq (H.3): l = l_S + d - l_S (delta_alpha theta + alpha_S delta_theta)."""
    d = d_bar + d1 + d2
    theta = theta_bar + Delta
    return l_S + d - l_S * (delta_alpha * theta + alpha_S * delta_theta)


def test_gum_annex_h1_end_gauge_budget():
    """The budget code on GUM H.1: l = 50.000838 mm, u_c = 32 nm (Table H.1: contributions
    25 nm (l_S), 9.7 nm (d), 0 (alpha_S, theta: zero sensitivity to first order), 2.9 nm
    (delta_alpha), 16.6 nm (delta_theta)), nu_eff = 16 (H.1.6: 16.7, truncated), U99 = 93 nm.
    The published numbers are the truth; nothing here comes from the code."""
    names, x, u, nu, dist = (list(c) for c in zip(*GUM_H1))
    res = gum_budget(end_gauge, names, x, u, dist, coefficient="l", dofs=nu, use_t=True, p=0.99)
    assert res.value == pytest.approx(50.000838e-3, abs=0.5e-9)
    assert round(res.u_c * 1e9) == 32                                   # nm, as published
    contrib = {t.quantity: t.contribution * 1e9 for t in res.terms}
    assert contrib["l_S"] == pytest.approx(25.0, abs=0.05)
    assert math.sqrt(contrib["d_bar"] ** 2 + contrib["d1"] ** 2 + contrib["d2"] ** 2) == pytest.approx(9.7, abs=0.05)
    assert contrib["alpha_S"] == pytest.approx(0.0, abs=1e-3) and contrib["theta_bar"] == pytest.approx(0.0, abs=1e-3)
    assert contrib["delta_alpha"] == pytest.approx(2.9, abs=0.05)
    assert contrib["delta_theta"] == pytest.approx(16.6, abs=0.1)
    assert 16 <= res.nu_eff < 17                                         # H.1.6: 16.7 -> 16
    assert res.U * 1e9 == pytest.approx(93, abs=1.5)                     # t_99(16) u_c = 2.92 x 32 nm
    # the linear budget the paper methods use, with the annex's sensitivities (Table H.1)
    lS, theta, alpha_S = 50.000623e-3, -0.1, 11.5e-6
    terms = [("l_S", lS, 25e-9, 1.0, "A", "normal"), ("d", 215e-9, 9.7e-9, 1.0, "A", "normal"),
             ("alpha_S", alpha_S, 1.2e-6, 0.0, "B", "uniform"), ("theta", theta, 0.41, 0.0, "A", "normal"),
             ("delta_alpha", 0.0, 0.58e-6, -lS * theta, "B", "uniform"),
             ("delta_theta", 0.0, 0.029, -lS * alpha_S, "B", "uniform")]
    lb = linear_budget("l", terms, method="gum_h1")
    assert round(lb.u_c * 1e9) == 32
    assert all(t.method == "gum_h1" for t in lb.terms)

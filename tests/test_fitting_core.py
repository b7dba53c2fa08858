"""The one fitting core against certified values (NIST StRD) and closed forms."""
import math

import numpy as np
import pytest

from accelcal.fitting import (Parameter, ParameterSet, birge_ratio, finish_fit, gauss_newton,
                              lack_of_fit, linear_fit, lstsq_svd, normalised_error,
                              separable_columns)

import nist_strd as nist


def _lre(got, cert):
    """Log relative error: the number of correct significant digits (NIST's measure)."""
    got, cert = np.asarray(got, float), np.asarray(cert, float)
    with np.errstate(divide="ignore"):
        return -np.log10(np.abs(got - cert) / np.abs(cert))


def test_pontius_certified_values():
    x = np.asarray(nist.PONTIUS_X, float)
    X = np.column_stack([np.ones_like(x), x, x * x])
    f = linear_fit(X, nist.PONTIUS_Y)
    assert np.all(_lre(f.values, nist.PONTIUS_B) > 11)
    assert np.all(_lre(np.sqrt(np.diag(f.cov)), nist.PONTIUS_SD) > 12)
    assert _lre(math.sqrt(f.chi2 / f.dof), nist.PONTIUS_RESIDUAL_SD) > 9


def test_longley_certified_values():
    X = np.column_stack([np.ones(16)] + [np.asarray(c, float) for c in nist.LONGLEY_X])
    f = linear_fit(X, nist.LONGLEY_Y)
    assert np.all(_lre(f.values, nist.LONGLEY_B) > 10), f.values
    assert np.all(_lre(np.sqrt(np.diag(f.cov)), nist.LONGLEY_SD) > 11)
    assert _lre(math.sqrt(f.chi2 / f.dof), nist.LONGLEY_RESIDUAL_SD) > 10
    assert f.rank == 7 and f.estimable.all()


def test_wampler1_exact_polynomial():
    x = np.asarray(nist.WAMPLER1_X, float)
    X = np.column_stack([x ** k for k in range(6)])
    f = linear_fit(X, nist.WAMPLER1_Y)
    np.testing.assert_allclose(f.values, 1.0, rtol=1e-8)


def test_misra1a_gauss_newton_certified():
    x = np.asarray(nist.MISRA1A_X)
    y = np.asarray(nist.MISRA1A_Y)
    params = ParameterSet([Parameter("b1", "b1", scale=100.0), Parameter("b2", "b2", scale=1e-4)])

    def resid(p):
        return y - p[0] * (1 - np.exp(-p[1] * x))

    def jac(p):
        return np.column_stack([1 - np.exp(-p[1] * x), p[0] * x * np.exp(-p[1] * x)])

    gn = gauss_newton(resid, jac, np.array(nist.MISRA1A_START), max_iter=200)
    assert gn.converged
    f = finish_fit(params, gn)
    s2 = f.chi2 / f.dof                       # unit-weight problem: scale by the residual variance
    assert np.all(_lre(f.values, nist.MISRA1A_B) > 6)
    assert np.all(_lre(np.sqrt(np.diag(f.cov_noise) * s2), nist.MISRA1A_SD) > 4)
    assert _lre(math.sqrt(s2), nist.MISRA1A_RESIDUAL_SD) > 6


def test_rank_deficient_design_reports_only_estimable_combinations():
    # y = a + b x + c (2 x): c and b alias; a is still determined
    x = np.linspace(0, 1, 20)
    X = np.column_stack([np.ones_like(x), x, 2 * x])
    sol = lstsq_svd(X, 3 + 5 * x)
    assert sol.rank == 2
    assert sol.estimable.tolist() == [True, False, False]
    assert sol.x[1] + 2 * sol.x[2] == pytest.approx(5.0)


def test_separable_columns_keeps_priority_order():
    x = np.linspace(-1, 1, 30)
    J = np.column_stack([np.ones_like(x), x, 3 * x, x ** 2])
    assert separable_columns(J, [0, 2, 1, 3]) == [0, 2, 3]


def test_lack_of_fit_untestable_and_inadequate():
    assert lack_of_fit(5.0, 0, 10.0, 20).status == "untestable"
    # F = (40/4)/(20/20) = 10 with (4, 20) dof: p ~ 1e-4, inadequate, factor sqrt(10)
    r = lack_of_fit(40.0, 4, 20.0, 20)
    assert r.status == "inadequate" and r.factor == pytest.approx(math.sqrt(10.0))
    assert lack_of_fit(4.0, 4, 20.0, 20).status == "adequate"


def test_birge_ratio_and_en_closed_forms():
    m, um, b, dof = birge_ratio([1.0, 3.0], [1.0, 1.0])
    assert (m, um, dof) == (2.0, pytest.approx(1 / math.sqrt(2)), 1)
    assert b == pytest.approx(math.sqrt(2.0))          # chi2 = 1 + 1 over 1 dof
    assert normalised_error(1.0, 0.3, 0.0, 0.4) == pytest.approx(2.0)


def test_lack_of_fit_reference_of_runs_with_their_own_noise_estimate():
    """Issue 26: each run's cell means weighted by a variance read from that run's own
    scatter.  Under the model, F dof_lof is then sum_j X_j m_j / Y_j with X_j ~ chi2(d_j) and
    Y_j ~ chi2(m_j) independent (not chi2 / pooled F).  Drawn here directly, that sum's
    upper quantiles must get their own tail probability from lack_of_fit with the
    reference's cumulants (within 15 % at 1e-3), where the pooled F(dof_lof, dof_pe) put
    them several times too low."""
    from types import SimpleNamespace as NS

    from accelcal.fitting.model import lack_of_fit_reference

    d, m = np.array([21.0, 21.0, 30.0, 12.0, 21.0, 21.0, 30.0, 14.0]), 80.5
    runs = [NS(noise=NS(source="residuals", n_params=2)) for _ in d]
    ref = lack_of_fit_reference(NS(runs=runs), d, [(0.0, int(2 * m))] * d.size)
    rng = np.random.default_rng(20261126)
    S = (rng.chisquare(d, (400_000, d.size)) * m / rng.chisquare(m, (400_000, d.size))).sum(axis=1)
    dl = float(d.sum())
    for q in (0.95, 0.99, 0.999):
        s = float(np.quantile(S, q))
        p = lack_of_fit(s, int(dl), dl, int(dl), reference=ref).p_value   # chi2_pe / dof_pe = 1
        assert p == pytest.approx(1.0 - q, rel=0.15)
    s = float(np.quantile(S, 0.999))
    assert lack_of_fit(s, int(dl), dl, 1288).p_value < 0.3e-3          # the pooled F: liberal
    # noise known in every run: exactly chi2(dof_lof)
    known = [NS(noise=NS(source="pooled", n_params=1)) for _ in d]
    assert lack_of_fit_reference(NS(runs=known), d, [(0.0, 161)] * d.size) is None
    mixed = lack_of_fit_reference(NS(runs=known[:1] + runs[1:]), d, [(0.0, 161)] * d.size)
    assert mixed[0] > dl and mixed[0] < lack_of_fit_reference(NS(runs=runs), d, [(0.0, 161)] * d.size)[0]

"""The rank decision (accelcal.fitting.identify) against designs whose aliasing is known in
closed form: two identical columns, a column that is a known combination of two others, a
zero column, a weak column, and the radius that only the scale factor can stand in for."""
import numpy as np
import pytest

from accelcal.effects import plausible_size
from accelcal.fitting.identify import (PRIORITY, Column, Combination, Hold, Why, absorbed, alias_cos, combinations,
                                       display_name, holds, mixed_with)


def col(name, key, kind="coef", value=0.0):
    prio = PRIORITY.index(key if key in PRIORITY else "effect")
    return Column(name, kind, key, "u", prio, value)


def design(*cols, m=12, seed=0):
    rng = np.random.default_rng(seed)
    base = np.linalg.qr(rng.normal(size=(m, m)))[0]       # orthonormal directions e_k
    return np.column_stack([sum(f * base[:, k] for k, f in c.items()) if c else np.zeros(m) for c in cols])


def test_two_identical_columns_the_later_one_is_aliased_with_the_first():
    J = design({0: 3.0}, {1: 1.0}, {0: 3.0})
    cols = [col("K1", "K1"), col("K0", "K0"), col("K2", "K2")]
    held = holds(J, cols)
    assert held == {"K2": Hold(Why.ALIASED, 0.0, aliased_with=("K1",), unit="u")}
    assert held["K2"].reason == "aliased with K1"


def test_a_known_combination_is_aliased_with_its_parts_and_they_measure_it():
    # column c = 2 a - 3 b: held; a then measures a + 2 c, b measures b - 3 c (A = [2, -3])
    a, b = {0: 1.0}, {1: 1.0}
    J = design(a, b, {0: 2.0, 1: -3.0})
    cols = [col("K1", "K1"), col("K0", "K0"), col("K2", "K2")]
    held = holds(J, cols)
    assert set(held) == {"K2"} and set(held["K2"].aliased_with) == {"K1", "K0"}
    # b's share of the column (3) is larger than a's (2): named first
    assert held["K2"].aliased_with == ("K0", "K1")
    A = absorbed(J[:, :2], J[:, 2:], np.array([1e-3, 1e-3]), np.array([1.0]))
    np.testing.assert_allclose(A[:, 0], [2.0, -3.0], rtol=1e-12)
    comb = combinations(cols[:2], cols[2:], A, [True])
    assert comb["K1"] == Combination("K1", (("K2", pytest.approx(2.0)),))
    assert display_name("K1", comb["K1"]) == "K1(K2)"
    assert display_name("K0", comb["K0"]) == "K0(K2)"
    assert display_name("K0", None) == "K0"


def test_a_held_term_too_small_to_move_the_estimate_is_not_part_of_it():
    J = design({0: 1.0}, {0: 2.0})
    # A = 2; a typical size of 1 moves the estimate by 2: counts against u = 1, not against u = 3
    assert absorbed(J[:, :1], J[:, 1:], np.array([1.0]), np.array([1.0]))[0, 0] == pytest.approx(2.0)
    assert absorbed(J[:, :1], J[:, 1:], np.array([3.0]), np.array([1.0]))[0, 0] == 0.0


def test_a_zero_column_is_not_excited():
    J = design({0: 1.0}, {})
    held = holds(J, [col("K1", "K1"), col("Kip", "Kip")])
    assert held["Kip"].why is Why.NOT_EXCITED and held["Kip"].reason == "not excited by these runs"


def test_a_column_whose_design_uncertainty_exceeds_its_plausible_size_is_weak():
    # orthonormal directions: u_k = 1 / |J_k|; Kip's column of norm 0.1 / plausible gives
    # u = 10 x plausible; K1 (base) is never held for it however weak
    lim = plausible_size("Kip")
    J = design({0: 1e-30}, {1: 0.1 / lim})
    held = holds(J, [col("K1", "K1"), col("Kip", "Kip")])
    assert list(held) == ["Kip"] and held["Kip"].why is Why.WEAK
    assert held["Kip"].design_u == pytest.approx(10 * lim, rel=1e-9)
    assert held["Kip"].reason == f"weakly determined: design uncertainty {10 * lim:.2g} u exceeds its plausible size"
    assert holds(J, [col("K1", "K1"), col("Kip", "Kip")], keep=("Kip",)) == {}


def test_a_radius_only_the_scale_factor_can_stand_in_for_is_held_not_the_effect():
    # K1 = e0, R = e0 + e1, offset = e1: in priority order R is kept and the offset held; R
    # judged last is K1 + offset, and K1 scales like R, so R is held at its nominal value
    J = design({0: 1.0}, {0: 1e3, 1: 1e3}, {1: 1e6})
    cols = [col("K1", "K1"), col("R", "radius", "radius", 0.5), col("off", "mass_centre_offset", "effect")]
    held = holds(J, cols)
    assert list(held) == ["R"] and held["R"].value == 0.5 and set(held["R"].aliased_with) == {"K1", "off"}
    assert list(holds(J, cols, scale_rule=False)) == ["off"]


def test_a_given_hold_keeps_the_callers_words():
    from accelcal.fitting.identify import as_holds
    h = as_holds({"Koq": "acts on these runs, held"})["Koq"]
    assert h.why is Why.GIVEN and str(h) == "acts on these runs, held"


def test_the_nested_test_is_the_extra_sum_of_squares_f_and_the_likelihood_ratio():
    from types import SimpleNamespace

    from scipy import stats

    from accelcal.fitting.procedure import ModelFit

    def mf(chi2, rank, dof):
        return ModelFit(None, SimpleNamespace(chi2=chi2, rank=rank, dof=dof), {}, 0)

    small, big = mf(130.0, 3, 52), mf(60.0, 5, 50)
    t = big.compare(small, always_scaled=True)           # Draper & Smith §6.1
    F = (130.0 - 60.0) / 2 / (60.0 / 50)
    assert (t.q, t.dof, t.scaled) == (2, 50, True) and t.statistic == pytest.approx(F)
    assert t.p_value == pytest.approx(stats.f.sf(F, 2, 50), rel=1e-10)
    # chi2/dof below 1: the noise model is taken as known, delta chi2 ~ chi2(q)
    t = mf(40.0, 5, 50).compare(small)
    assert not t.scaled and t.p_value == pytest.approx(stats.chi2.sf(90.0, 2), rel=1e-10)
    assert mf(0.0, 5, 0).compare(small).p_value is None


def test_near_aliases_name_the_combination_of_least_variance():
    from accelcal.fitting.identify import near_aliases
    r, u = -0.9995, np.array([3.0, 0.5])
    (na,) = near_aliases(["Kip", "Kpp"], np.array([[1.0, r], [r, 1.0]]), u)
    var = lambda t: u[0] ** 2 + 2 * t * r * u[0] * u[1] + t ** 2 * u[1] ** 2  # noqa: E731
    assert (na.a, na.b, na.r) == ("Kip", "Kpp", r) and var(na.t) < min(var(na.t - 1e-3), var(na.t + 1e-3))
    assert near_aliases(["Kip", "Kpp"], np.array([[1.0, 0.99], [0.99, 1.0]]), u) == []


def test_taken_up_splits_a_direction_over_the_columns_that_make_it():
    from accelcal.fitting.identify import taken_up
    J = design({0: 2.0}, {1: 4.0}, {2: 1.0})
    s = 2.0 * J[:, 0] - 0.5 * J[:, 1]                      # |s|^2 = 16 + 4 = 20
    got = taken_up(J, s)
    assert [k for k, _, _ in got] == [0, 1]
    np.testing.assert_allclose([(sh, x) for _, sh, x in got], [(16 / 20, 2.0), (4 / 20, -0.5)], atol=1e-12)


def test_free_parameters_that_make_up_a_held_column_are_mixed_with_it():
    """A held column e1 + e2/10 is made of both free columns (shares 1 and 0.1, both above
    ALIAS_SHARE); e1 + e2/100 of the first alone (0.01 < 0.05)."""
    Jf = np.eye(4)[:, :2]
    for h, want in ((np.array([1.0, 0.1, 0, 0]), [True, True]), (np.array([1.0, 0.01, 0, 0]), [True, False])):
        Jh = h[:, None] / np.linalg.norm(h)
        assert list(mixed_with(Jf, Jh, np.eye(2))) == want


def test_alias_cos_is_the_cosine_of_two_directions():
    """cos 45 deg for e1 and e1 + e2; 0 for a zero direction."""
    a, b = np.array([1.0, 0.0]), np.array([1.0, 1.0])
    assert alias_cos(a, b) == pytest.approx(np.sqrt(0.5))
    assert alias_cos(a, np.zeros(2)) == 0.0

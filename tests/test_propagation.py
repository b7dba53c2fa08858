"""Propagation of distributions for a linear budget (the JCGM 101 check of the adopted
values' budgets) against closed forms."""
import math

import numpy as np
import pytest

from accelcal.estimators.uncertainty import linear_output_interval, validate_gum_linear


def test_normal_interval_is_the_normal_quantile():
    # a fine grid reaches the quantile to 1e-6 sd; the default grid to 1e-5 sd, 500x inside
    # the two-digit tolerance (0.005 sd) the check compares against
    lo, hi, sd = linear_output_interval([2.0], [0.5], ["normal"], points=1 << 15)
    assert sd == 1.0
    assert (lo, hi) == pytest.approx((-1.959964, 1.959964), abs=1e-6)
    lo, hi, _ = linear_output_interval([2.0], [0.5], ["normal"])
    assert (lo, hi) == pytest.approx((-1.959964, 1.959964), abs=1e-5)


def test_one_uniform_input():
    # half-width a: the 95 % interval is +-0.95 a (JCGM 101 6.4.2)
    a = 3.0
    lo, hi, _ = linear_output_interval([1.0], [a / math.sqrt(3)], ["uniform"])
    assert (lo, hi) == pytest.approx((-0.95 * a, 0.95 * a), rel=2e-4)
    v = validate_gum_linear([1.0], [a / math.sqrt(3)], ["uniform"])
    assert not v["validated"]          # the normal approximation is 19 % too wide here


def test_two_equal_uniforms_give_a_triangle():
    # the sum of two uniforms of half-width 1 is triangular on [-2, 2]:
    # P(|y| > t) = (2 - t)^2 / 4 = 0.05 -> t = 2 (1 - sqrt(0.05))
    exact = 2 * (1 - math.sqrt(0.05))
    lo, hi, _ = linear_output_interval([1.0, 1.0], [1 / math.sqrt(3)] * 2, ["uniform", "uniform"],
                                       points=1 << 15)
    assert hi == pytest.approx(exact, rel=1e-6) and lo == pytest.approx(-hi, rel=1e-9)
    lo, hi, _ = linear_output_interval([1.0, 1.0], [1 / math.sqrt(3)] * 2, ["uniform", "uniform"])
    assert hi == pytest.approx(exact, rel=1e-5)


def test_normal_dominated_budget_validates():
    v = validate_gum_linear([1.0, 1.0], [1.0, 0.05], ["normal", "uniform"])
    assert v["validated"] and v["d_high"] < v["delta"]

"""The AR(1) correlation from the pooled lag-1 ratio (:func:`accelcal.fitting.data.ar1_from_lag1`)
decides most bisection steps on a closed form with a rounding-error bound: it must return the
very float that bisecting on the term-by-term series gives.  The reference below is that
bisection written out here, independent of the module; the bound is checked against a
40-digit evaluation of the series."""
import mpmath
import numpy as np
import pytest

import accelcal.fitting.data as data
from accelcal.fitting.data import ar1_from_lag1

LO, HI = -0.5, 0.95


def _series(n, rho):
    """E[lag-1 sum] / E[sum of squares] of deviations of n AR(1) readings from their mean,
    the geometric sums added term by term (M = 1^T R 1 / n^2, m1 = first row mean)."""
    p = rho ** np.arange(n)
    k = np.arange(1, n)
    M = (n + 2.0 * float(np.sum((n - k) * p[1:]))) / (n * n)
    m1 = float(np.sum(p)) / n
    return ((n - 1) * rho - (n + 1) * M + 2.0 * m1) / (n - n * M)


def _reference(r, n, weight):
    ok = (n >= 3) & (weight > 0)
    if not np.any(ok):
        return 0.0
    vals, inv = np.unique(n[ok].astype(int), return_inverse=True)
    w = np.bincount(inv, weights=weight[ok]) / float(np.sum(weight[ok]))

    def h(rho):
        total = 0.0
        for v, wi in zip(vals, w):
            total += wi * _series(int(v), rho)
        return total - r

    lo, hi = LO, HI
    if h(lo) >= 0:
        return lo
    if h(hi) <= 0:
        return hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if h(mid) < 0 else (lo, mid)
    return 0.5 * (lo + hi)


def _pooled(n, weight, rho):
    """The reference's own pooled ratio at rho: a root placed exactly on a float."""
    ok = (n >= 3) & (weight > 0)
    vals, inv = np.unique(n[ok].astype(int), return_inverse=True)
    w = np.bincount(inv, weights=weight[ok]) / float(np.sum(weight[ok]))
    total = 0.0
    for v, wi in zip(vals, w):
        total += wi * _series(int(v), rho)
    return total


def _cells(rng):
    sizes = np.r_[rng.integers(3, 40, rng.integers(0, 4)), rng.integers(40, 5001, rng.integers(0, 3)),
                  rng.integers(0, 3, rng.integers(0, 2))]           # and cells too short to count
    if not np.any(sizes >= 3):
        sizes = np.r_[sizes, rng.integers(3, 5001)]
    n = rng.choice(sizes, size=int(rng.integers(sizes.size, 4 * sizes.size + 1)))
    weight = rng.exponential(size=n.size) * (rng.uniform(size=n.size) > 0.1)
    if not np.any(weight[n >= 3] > 0):
        weight[n >= 3] = 1.0
    return n, weight


def test_same_float_as_the_series_bisection():
    rng = np.random.default_rng(44)
    mid = np.array([0.5 * (LO + HI)])
    for case in range(160):
        n, weight = _cells(rng)
        kind = case % 4
        if kind == 0:                       # anywhere, beyond the bounds too
            r = float(rng.uniform(-0.8, 1.0))
        elif kind == 1:                     # root near a bound
            rho = (LO, HI)[case % 8 == 1] + float(rng.choice([-1, 1])) * 10.0 ** -rng.uniform(1, 15)
            r = _pooled(n, weight, float(np.clip(rho, -0.55, 0.96)))
        elif kind == 2:                     # root exactly at a bound or on a bisection midpoint
            r = _pooled(n, weight, float(rng.choice([LO, HI, mid[0], 0.5 * (LO + mid[0])])))
        else:                               # root strictly inside
            r = _pooled(n, weight, float(rng.uniform(LO, HI)))
        got = ar1_from_lag1(r, n, weight)
        assert got == _reference(r, n, weight), (case, r, n, weight)


@pytest.mark.parametrize("n", [3, 4, 10, 200, 5000])
def test_short_and_long_cells_near_the_bounds(n):
    cells, weight = np.full(3, n), np.array([1.0, 2.0, 0.5])
    for rho in (LO, LO + 1e-15, -0.123, 0.0, 0.37, 0.9, HI - 1e-15, HI):
        r = _pooled(cells, weight, rho)
        for dr in (0.0, 1e-16, -1e-16, 3e-15):
            assert ar1_from_lag1(r + dr, cells, weight) == _reference(r + dr, cells, weight)


def test_rounding_bound_holds_against_40_digits():
    """|g - g_exact| is within the bound for both the closed form and the series; the bound is
    tight enough to decide all but the steps next to the root: below 1e-11 where 1 - rho^n
    and n (1 - rho) nearly cancel (3 readings, rho = 0.95), below 1e-13 in the long cells
    whose series cost the most."""
    mpmath.mp.dps = 40
    for n in (3, 5, 17, 400, 4999):
        for rho in (-0.5, -0.2, 1e-3, 0.3, 0.8, 0.93, 0.95):
            r = mpmath.mpf(rho)
            p = [r ** k for k in range(n)]
            M = (n + 2 * mpmath.fsum((n - k) * p[k] for k in range(1, n))) / n ** 2
            exact = ((n - 1) * r - (n + 1) * M + 2 * mpmath.fsum(p) / n) / (n - n * M)
            g, bound = data._ar1_lag1_ratio_bounded(n, rho)
            assert abs(g - exact) <= bound
            assert abs(_series(n, rho) - exact) <= bound
            assert bound < (1e-11 if n < 400 else 1e-13)


def test_only_the_steps_next_to_the_root_sum_the_series(monkeypatch):
    calls = []
    series = data.ar1_deviation_lag1
    monkeypatch.setattr(data, "ar1_deviation_lag1", lambda n, rho, p=None: calls.append(n) or series(n, rho, p))
    n, weight = np.array([412, 484, 731, 741] * 5), np.linspace(1.0, 2.0, 20)
    r = _pooled(n, weight, 0.2)
    assert ar1_from_lag1(r, n, weight) == _reference(r, n, weight)
    assert 0 < len(calls) <= 4 * 15            # of 52 evaluations of 4 cell sizes


def test_powers_shared_by_cell_sizes_are_each_cells_own():
    rng = np.random.default_rng(3)
    for _ in range(50):
        rho, m = float(rng.uniform(LO, HI)), int(rng.integers(3, 5001))
        powers = rho ** np.arange(m)
        for n in rng.integers(3, m + 1, 4):
            lag1, squares = data.ar1_deviation_lag1(int(n), rho, powers)
            assert lag1 / squares == _series(int(n), rho)

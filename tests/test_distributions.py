"""accelcal.fitting.distributions returns scipy.stats' very floats (issue 13: results identical)."""
from __future__ import annotations

import numpy as np
from scipy import stats

from accelcal.fitting import distributions as D


def _same(a, b) -> bool:
    a, b = np.float64(a), np.float64(b)
    return bool((np.isnan(a) and np.isnan(b)) or a.tobytes() == b.tobytes())


def test_sf_and_ppf_are_scipys():
    rng = np.random.default_rng(1)
    xs = [float(x) for x in rng.normal(0, 3, 500)] + [0.0, -0.0, 1e-300, 40.0, -40.0, 1e10, np.inf, -np.inf,
                                                       np.nan, 5, 0]
    for x in xs:
        assert _same(D.norm_sf(x), stats.norm.sf(x))
        for df in (1, 2, 3, 7, 29, 30, 175, 3420, 2.5, 0, -1):
            assert _same(D.chi2_sf(abs(x) * df, df), stats.chi2.sf(abs(x) * df, df))
            assert _same(D.f_sf(abs(x), df, 3420), stats.f.sf(abs(x), df, 3420))
            assert _same(D.f_sf(abs(x), 5, df), stats.f.sf(abs(x), 5, df))
    qs = [float(q) for q in rng.uniform(0, 1, 300)] + [0.0, 1.0, 0.5, 0.975, 0.995, 0.025, np.nan, 1e-300]
    for q in qs:
        assert _same(D.norm_ppf(q), stats.norm.ppf(q))
        for df in (1, 2, 3, 7, 29, 30, 175, 3420, 2.5, 0, -1, np.inf):
            assert _same(D.t_ppf(q, df), stats.t.ppf(q, df))

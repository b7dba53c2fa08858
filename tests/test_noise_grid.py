"""The noise model's profile grid evaluated at once gives the loop's very values (issue 13)."""
from __future__ import annotations

import math

import numpy as np

from accelcal.fitting import data


def _loop_vals(S, nu, X):
    sx = max(float(np.max(np.abs(X))), 1e-30)
    u = (np.asarray(X, float) / sx) ** 2
    sn = float(np.sum(nu))

    def profile(t):
        w = np.maximum((1.0 - t) + t * u, 1e-300)
        c = max(float(np.sum(nu * S / w)) / sn, 1e-300)
        return sn * math.log(c) + float(np.sum(nu * np.log(w)))
    return [profile(t) for t in np.concatenate([[0.0], np.geomspace(1e-9, 1.0, 46)[:-1], [1.0 - 1e-12]])]


def test_grid_equals_loop(monkeypatch):
    rng = np.random.default_rng(3)
    seen = []
    orig = data.minimize_scalar

    def spy(f, bounds, **kw):
        seen.append(bounds)
        return orig(f, bounds=bounds, **kw)
    monkeypatch.setattr(data, "minimize_scalar", spy)
    for m in list(range(3, 40)) + [127, 128, 129, 300]:
        X = rng.uniform(0, 300, m) * rng.choice([1e-3, 1.0, 1e3])
        nu = rng.integers(1, 12, m).astype(float)
        S = (1e-8 + 1e-12 * X ** 2) * rng.chisquare(nu) / nu
        ref = _loop_vals(S, nu, X)
        ts = np.concatenate([[0.0], np.geomspace(1e-9, 1.0, 46)[:-1], [1.0 - 1e-12]])
        k = int(np.argmin(ref))
        seen.clear()
        data._fit_variance_function(S, nu, X, True)
        assert seen == [(float(ts[max(k - 1, 0)]), float(ts[min(k + 1, ts.size - 1)]))]
        # and the values themselves, bit for bit
        sx = max(float(np.max(np.abs(X))), 1e-30)
        u = (X / sx) ** 2
        W = np.maximum((1.0 - ts[:, None]) + ts[:, None] * u, 1e-300)
        sn = float(np.sum(nu))
        vals = [sn * math.log(max(float(c) / sn, 1e-300)) + float(lv)
                for c, lv in zip(np.sum(nu * S / W, axis=1), np.sum(nu * np.log(W), axis=1))]
        assert [v.hex() for v in vals] == [v.hex() for v in ref]

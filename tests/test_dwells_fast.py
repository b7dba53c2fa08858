"""The numpy dwell statistics (accelcal.estimators.dwells fast path) are bit for bit the
pandas groupby ones they replace (issue 13: results identical)."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from accelcal.estimators import dwells
from accelcal.schemas.dropformat import read_run


def _pandas_path(monkeypatch):
    monkeypatch.setattr(dwells, "_dwell_columns", lambda *a, **k: None)


def _same(a: pd.DataFrame, b: pd.DataFrame) -> None:
    assert list(a.columns) == list(b.columns)
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    for c in a.columns:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        assert x.dtype == y.dtype, c
        if x.dtype.kind == "f":
            assert np.array_equal(x.view(np.int64), y.view(np.int64)), c   # bits, signed zeros


def _centrifuge_runs(examples):
    runs = [read_run(p) for p in sorted(examples.rglob("*.csv")) if "drop-bad" not in str(p)]
    return [r for r in runs if str(r.meta.get("test")) == "centrifuge"]


def _random_runs(n=40, seed=7):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        k = int(rng.integers(2, 25))
        sizes = rng.integers(1, 12, k)
        keys = rng.permutation(k) * 3 + 1 if rng.random() < 0.25 else np.arange(k) * 2 + 1   # unsorted: pandas path
        step = np.repeat(keys, sizes)
        m = len(step)
        rate = np.where(rng.random(k) < 0.3, 0.0, rng.uniform(1, 20, k))[np.searchsorted(np.unique(step), step)]
        rate = rate + rng.normal(0, 1e-3, m) * (rate != 0)
        data = pd.DataFrame({"time_s": np.cumsum(rng.uniform(0.1, 2, m)) + rng.uniform(0, 1e6),
                             "step": step.astype(np.int64), "table_rate_rad_s": rate,
                             "table_angle_deg": rng.choice([0.0, 90.0, 180.0, 270.0, 90.0004, np.nan], m),
                             "output": rng.normal(3.0, 1e-3, m) * rng.choice([1e-9, 1.0, 1e7]),
                             "line": np.arange(m, dtype=np.int64) + 10})
        out.append(({"rotation_sense": rng.choice(["ccw", "cw"]), "site_latitude_deg": 30.5}, data))
    return out


def test_dwell_table_fast_equals_pandas(examples, monkeypatch):
    cases = [(r.meta, r.data) for r in _centrifuge_runs(examples)] + _random_runs()
    assert cases
    fast = [dwells.dwell_table(m, d) for m, d in cases]
    merged = [dwells.merged_dwell_columns(m, d) for m, d in cases]
    assert sum(x is not None for x in merged) >= len(cases) * 0.6      # the fast path is taken
    _pandas_path(monkeypatch)
    for (m, d), f, mc in zip(cases, fast, merged):
        slow = dwells.dwell_table(m, d)
        _same(f, slow)
        if mc is None:
            continue
        try:
            ms = dwells.merge_rest(slow)
        except ValueError:
            continue
        _same(pd.DataFrame(mc), ms)
        if slow["rest"].any():
            ref = dwells._rest_mean_pandas(slow)
            assert dwells.rest_mean(slow) == ref
            assert dwells._rest_mean_columns({c: slow[c].to_numpy() for c in slow}) == ref


def test_fast_path_declines_nan_and_other_dtypes():
    m, d = _random_runs(1)[0]
    d = d.copy()
    d.loc[3, "output"] = np.nan
    assert dwells._dwell_columns(m, d, {"earth_rate": 1.0}) is None
    assert dwells._dwell_columns(m, d.astype({"output": "float32"}), {}) is None


def test_pair_table_fast_equals_pandas(examples, monkeypatch):
    from accelcal.estimators.radius import PairData
    runs = _centrifuge_runs(examples)
    pairs = [[(a.meta, a.data, 1), (b.meta, b.data, -1)] for a, b in zip(runs[::2], runs[1::2])]
    fast = [PairData.from_runs(p, 1.0).table for p in pairs]
    monkeypatch.setattr("accelcal.estimators.radius.merged_dwell_columns", lambda *a: None)
    for p, f in zip(pairs, fast):
        _same(f, PairData.from_runs(p, 1.0).table)


def _clean_reference(data):
    """accelcal.estimators.tumble._clean as it was (column by column into a frame)."""
    df = pd.DataFrame({k: np.asarray(data[k]) for k in ("angle_deg", "output")})
    for k in ("time_s", "position", "temp_c"):
        try:
            df[k] = np.asarray(data[k])
        except (KeyError, IndexError):
            pass
    df = df[np.isfinite(df["output"].astype(float)) & np.isfinite(df["angle_deg"].astype(float))]
    if "position" not in df:
        df["position"] = pd.factorize(df["angle_deg"].round(9))[0]
    return df.reset_index(drop=True)


def test_tumble_clean_same_frame(examples):
    from accelcal.estimators.tumble import _clean
    runs = [read_run(p) for p in sorted(examples.parent.rglob("*.csv"))
            if "drop-bad" not in str(p) and "diagnosis" not in str(p)]
    tumbles = [r.data for r in runs if str(r.meta.get("test")) == "tumble"]
    assert tumbles
    rng = np.random.default_rng(5)
    for d in list(tumbles):
        d2 = d.copy()
        d2.loc[rng.integers(0, len(d2), 3), "output"] = np.nan
        tumbles.append(d2)
        tumbles.append({k: d[k].to_numpy() for k in ("angle_deg", "output")})   # no position, no time
    for d in tumbles:
        _same(_clean(d), _clean_reference(d))


def test_groups_of_a_long_run_by_counting_and_slices(monkeypatch):
    """Issue 28: integer keys are grouped by counting (np.unique's keys and inverse, the
    same arrays), and the within-dwell sum of squares of a long run is taken a slice of
    whole dwells at a time: the same sums to the last bit as the whole-array form, here
    with the slice lowered to 97 readings."""
    rng = np.random.default_rng(28)
    step = np.repeat(np.arange(40), rng.integers(1, 60, 40))
    v = rng.normal(size=step.size) * 1e-3 + step
    g = dwells._Groups(step)
    keys, inv = np.unique(step, return_inverse=True)
    assert np.array_equal(g.keys, keys) and g.keys.dtype == keys.dtype and np.array_equal(g.ids, inv)
    m = g.mean(v)
    dev = v - m[g.ids]
    whole = g.sum(dev * dev)
    monkeypatch.setattr(dwells, "ROW_SLICE", 97)
    sliced = g.sum_squares_about(v, m)
    assert np.array_equal(sliced, whole)
    # a float key (rounded azimuths) still goes to np.unique
    az = dwells._Groups(np.round(rng.uniform(0, 360, 50), 3))
    assert az.keys.dtype.kind == "f"

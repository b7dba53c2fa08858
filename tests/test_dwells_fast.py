"""The numpy dwell statistics (accelcal.estimators.dwells) against pandas' groupby, an
independent implementation of the same reductions: bit for bit, on the sample drops and on
runs with missing values, steps out of order and interleaved steps."""
from __future__ import annotations

import numpy as np
import pandas as pd

from accelcal.estimators import dwells
from accelcal.physics.rigs import omega_z
from accelcal.schemas.dropformat import read_run


def _same(a, b) -> None:
    a, b = pd.DataFrame(a), pd.DataFrame(b)
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        assert x.dtype == y.dtype, c
        if x.dtype.kind == "f":
            assert np.array_equal(x.view(np.int64), y.view(np.int64)), c   # bits, signed zeros
        else:
            assert np.array_equal(x, y), c


def _pandas_dwell_table(meta, d):
    """The dwell table by pandas' groupby (independent of the numpy reductions)."""
    g = d.groupby("step", sort=True)
    dev = d["output"] - g["output"].transform("mean")
    out = pd.DataFrame({
        "n": g["output"].size(), "mean_output": g["output"].mean(),
        "ss_within": (dev * dev).groupby(d["step"], sort=True).sum(),
        "rate": g["table_rate_rad_s"].mean(), "rate_std": g["table_rate_rad_s"].std(ddof=1).fillna(0.0),
        "time_mid": g["time_s"].mean(), "time_start": g["time_s"].min()})
    out["var_output"] = out["ss_within"] / np.maximum(out["n"] - 1, 1)
    out["azimuth_deg"] = g["table_angle_deg"].mean()
    out["first_line"] = g["line"].min()
    out = out.reset_index().sort_values("time_start").reset_index(drop=True)
    out["rest"] = out["rate"].abs() < 1e-9
    out["omega_z"] = omega_z(meta, out["rate"].to_numpy(), {"earth_rate": 1.0})
    sweep = np.array(["rest"] * len(out), dtype=object)
    moving = np.flatnonzero(~out["rest"].to_numpy())
    if moving.size:
        peak = moving[np.argmax(out["rate"].to_numpy()[moving])]
        sweep[moving[moving <= peak]] = "up"
        sweep[moving[moving > peak]] = "down"
    out["sweep"] = sweep
    return out


def _pandas_rest_mean(dw):
    r = dw[dw["rest"]]
    means = r.groupby(r["azimuth_deg"].fillna(0.0).round(3))["mean_output"].mean().to_numpy()
    n = int(r["n"].sum())
    u = np.sqrt(float(r["ss_within"].sum() / max(n - len(r), 1)) / n)
    if means.size >= 3:
        u = max(u, float(means.std(ddof=1) / np.sqrt(means.size)))
    return float(means.mean()), float(u), n


def _pandas_merge_rest(dw):
    rest, moving = dw[dw["rest"]], dw[~dw["rest"]]
    E0, _, n = _pandas_rest_mean(dw)
    ss = float(rest["ss_within"].sum())
    merged = {"n": n, "mean_output": E0, "ss_within": ss, "var_output": ss / max(n - len(rest), 1),
              "time_mid": float(rest["time_mid"].mean()), "omega_z": float(rest["omega_z"].mean())}
    head = pd.DataFrame({c: [merged[c]] if c in merged else rest[c].to_numpy()[:1] for c in dw.columns})
    out = pd.concat([head, moving], ignore_index=True)
    out["dof_pe"] = np.r_[n - len(rest), moving["n"].to_numpy() - 1]
    return out


def _centrifuge_runs(examples):
    runs = [read_run(p) for p in sorted(examples.rglob("*.csv")) if "drop-bad" not in str(p)]
    return [r for r in runs if str(r.meta.get("test")) == "centrifuge"]


def _random_runs(n=40, seed=7, missing=0.0, longest=12):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        k = int(rng.integers(2, 25))
        sizes = rng.integers(1, longest, k)
        keys = rng.permutation(k) * 3 + 1 if rng.random() < 0.25 else np.arange(k) * 2 + 1
        step = np.repeat(keys, sizes)
        if rng.random() < 0.2:
            step = rng.permutation(step)                     # a dwell's rows not consecutive
        m = len(step)
        rate = np.where(rng.random(k) < 0.3, 0.0, rng.uniform(1, 20, k))[np.searchsorted(np.unique(step), step)]
        rate = rate + rng.normal(0, 1e-3, m) * (rate != 0)
        output = rng.normal(3.0, 1e-3, m) * rng.choice([1e-9, 1.0, 1e7])
        time = np.cumsum(rng.uniform(0.1, 2, m)) + rng.uniform(0, 1e6)
        for col in (output, rate, time):
            col[rng.random(m) < missing] = np.nan
        data = pd.DataFrame({"time_s": time, "step": step.astype(np.int64), "table_rate_rad_s": rate,
                             "table_angle_deg": rng.choice([0.0, 90.0, 180.0, 270.0, 90.0004, np.nan], m),
                             "output": output, "line": np.arange(m, dtype=np.int64) + 10})
        out.append(({"rotation_sense": rng.choice(["ccw", "cw"]), "site_latitude_deg": 30.5}, data))
    return out


def test_dwell_table_equals_pandas_groupby(examples):
    cases = ([(r.meta, r.data) for r in _centrifuge_runs(examples)] + _random_runs()
             + _random_runs(30, 8, missing=0.05) + _random_runs(10, 9, missing=0.02, longest=300))
    for m, d in cases:
        ref = _pandas_dwell_table(m, d)
        _same(dwells.dwell_table(m, d), ref)
        if not ref["rest"].any():
            continue
        assert dwells.rest_mean(ref) == _pandas_rest_mean(ref)
        _same(dwells.merged_dwell_columns(m, d), _pandas_merge_rest(ref))


def test_groups_equal_pandas_groupby():
    """Sums, means, standard deviations and minima by group, keys in and out of order,
    missing values and missing (float) keys, against pandas' groupby."""
    rng = np.random.default_rng(28)
    for key in (np.repeat(np.arange(40), rng.integers(1, 60, 40)), rng.integers(0, 7, 3000),
                np.where(rng.random(500) < 0.1, np.nan, np.round(rng.uniform(0, 4, 500)))):
        v = rng.normal(size=key.size) * 1e-3 + 1e6 * (key % 3 if key.dtype.kind == "i" else 1)
        for missing in (0.0, 0.03):
            w = np.where(rng.random(key.size) < missing, np.nan, v)
            g, ref = dwells.Groups(key), pd.Series(w).groupby(key, sort=True)
            assert np.array_equal(g.keys, ref.size().index.to_numpy())
            assert np.array_equal(g.counts, ref.size().to_numpy())
            for got, want in ((g.sum(w), ref.sum()), (g.mean(w), ref.mean()), (g.std(w), ref.std(ddof=1)),
                              (g.min(w), ref.min())):
                assert np.array_equal(got, want.to_numpy(), equal_nan=True)


def test_pair_table_of_the_merged_dwells(examples):
    from accelcal.estimators.radius import PairData
    runs = _centrifuge_runs(examples)
    for a, b in zip(runs[::2], runs[1::2]):
        table = PairData.from_runs([(a.meta, a.data, 1), (b.meta, b.data, -1)], 1.0).table
        parts = []
        for r, pol in ((a, 1), (b, -1)):
            t = _pandas_merge_rest(_pandas_dwell_table(r.meta, r.data))
            t["pol"], t["run_id"] = pol, str(r.meta.get("run_id", ""))
            parts.append(t)
        _same(table, pd.concat(parts, ignore_index=True))


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


def _pandas_position_means(df):
    grp = df.groupby("position", sort=True)
    out = pd.DataFrame({"angle_deg": grp["angle_deg"].mean(), "n": grp["output"].size(),
                        "mean_output": grp["output"].mean(), "std_output": grp["output"].std(ddof=1)})
    out["sem_output"] = out["std_output"] / np.sqrt(out["n"])
    return out.reset_index()


def test_tumble_position_means_equal_pandas_groupby(examples):
    from accelcal.estimators import tumble
    runs = [read_run(p) for p in sorted(examples.parent.rglob("*.csv"))
            if "drop-bad" not in str(p) and "diagnosis" not in str(p)]
    frames = [tumble._clean(r.data) for r in runs if str(r.meta.get("test")) == "tumble"]
    assert frames
    rng = np.random.default_rng(9)
    for f in list(frames):
        g = f.copy()
        g["position"] = rng.permutation(g["position"].to_numpy())      # not in row order
        frames.append(g)
        frames.append(f[f["position"] != f["position"].iloc[0]].reset_index(drop=True))
    for f in frames:
        _same(tumble.position_means(f), _pandas_position_means(f))

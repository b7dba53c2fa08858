"""Dwell statistics of a stepped-rate centrifuge run (drop-format.md, `centrifuge`).

A centrifuge run is a sequence of dwells (`step`): rest dwells at two or more
table azimuths, then dwells at rising and falling constant rates.  Each row is
the DAQ's mean over a reading window, so the rows of one dwell are replicated
readings: their scatter is the *pure error* of the lack-of-fit test.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from ..fitting.core import lstsq_svd_x
from ..fitting.data import ROW_SLICE, unique_small_ints
from ..physics.rigs import omega_z


def dwell_table(meta: Mapping, data: pd.DataFrame, effects: Mapping[str, float] | None = None) -> pd.DataFrame:
    """Dwell statistics of a stepped-rate centrifuge run.

    Parameters
    ----------
    meta : mapping
        Typed run metadata.
    data : DataFrame
        ``step``, ``output`` [output_unit], ``table_rate_rad_s`` [rad/s], ``time_s`` [s],
        ``table_angle_deg`` [deg], optional ``line``.
    effects : mapping, optional
        Effects for omega_z (default: the earth rate, drop-format.md).

    Returns
    -------
    DataFrame
        One row per dwell: step, n, mean_output [output_unit], ss_within (sum of squares
        about the dwell mean) [output_unit^2], var_output (sample variance), rate (mean logged
        rate) [rad/s], omega_z (:func:`accelcal.physics.rigs.omega_z`) [rad/s], time_mid [s],
        rest (bool), azimuth_deg [deg] (rest only), sweep ('rest', 'up', 'down'), first_line.
    """
    eff = {"earth_rate": 1.0} if effects is None else effects
    cols = _dwell_columns(meta, data, eff)
    if cols is not None:
        return pd.DataFrame(cols)
    d = data
    g = d.groupby("step", sort=True)
    dev = d["output"] - g["output"].transform("mean")       # about each dwell's own mean
    out = pd.DataFrame({
        "n": g["output"].size(),
        "mean_output": g["output"].mean(),
        "ss_within": (dev * dev).groupby(d["step"], sort=True).sum(),
        "rate": g["table_rate_rad_s"].mean(),
        "rate_std": g["table_rate_rad_s"].std(ddof=1).fillna(0.0),
        "time_mid": g["time_s"].mean(),
        "time_start": g["time_s"].min(),
    })
    out["var_output"] = out["ss_within"] / np.maximum(out["n"] - 1, 1)
    az = g["table_angle_deg"].mean() if "table_angle_deg" in d else np.nan
    out["azimuth_deg"] = az
    if "line" in d:
        out["first_line"] = g["line"].min()
    out = out.reset_index().sort_values("time_start").reset_index(drop=True)
    out["rest"] = out["rate"].abs() < 1e-9
    out["omega_z"] = omega_z(meta, out["rate"].to_numpy(), eff)
    sweep = np.array(["rest"] * len(out), dtype=object)
    moving = np.flatnonzero(~out["rest"].to_numpy())
    if moving.size:
        peak = moving[np.argmax(out["rate"].to_numpy()[moving])]
        sweep[moving[moving <= peak]] = "up"
        sweep[moving[moving > peak]] = "down"
    out["sweep"] = sweep
    return out


def merge_rest(dw: pd.DataFrame) -> pd.DataFrame:
    """The dwell table with the rest dwells merged into one group.

    Parameters
    ----------
    dw : DataFrame
        :func:`dwell_table`.

    Returns
    -------
    DataFrame
        The rest group's mean is the mean of the azimuth means (He & Yin 2017, paper 000
        eq 4: averaging over equally spaced azimuths removes the spindle's tilt).  Adds
        ``dof_pe``: pure-error degrees of freedom of each row (n - 1 for a dwell; readings
        minus azimuths for the merged rest group, so the spread between azimuths, which is
        the spindle tilt and not noise, counts in neither term).
    """
    is_rest = dw["rest"].to_numpy()
    moving = dw[~is_rest]
    rest = dw[is_rest]
    if rest.empty:
        out = moving.reset_index(drop=True)
        out["dof_pe"] = out["n"] - 1
        return out
    E0, _, n = rest_mean(rest)
    ss = float(rest["ss_within"].sum())
    merged = {"n": n, "mean_output": E0, "ss_within": ss,
              "var_output": ss / max(n - len(rest), 1),
              "time_mid": float(rest["time_mid"].mean()), "omega_z": float(rest["omega_z"].mean())}
    # column by column (the merged rest group first, then the moving dwells): the same
    # values as a one-row frame concatenated, without pandas' per-cell overhead
    cols = {}
    for c in dw.columns:
        first = np.asarray([merged[c]]) if c in merged else rest[c].to_numpy()[:1]
        cols[c] = np.concatenate([first, moving[c].to_numpy()])
    cols["dof_pe"] = np.concatenate([[n - len(rest)], moving["n"].to_numpy() - 1])
    return pd.DataFrame(cols)


def rest_mean(dw: pd.DataFrame) -> tuple[float, float, int]:
    """E0 of He & Yin 2017 (paper 000) eq 4: the rest output over the table azimuths.

    Parameters
    ----------
    dw : DataFrame
        :func:`dwell_table`.

    Returns
    -------
    (E0, u(E0), n) : (float, float, int)
        The mean of the rest dwells' means over the azimuths [output_unit] (equal weight per
        azimuth, which cancels the spindle's tilt), its standard uncertainty (from the spread
        of the azimuth means when there are >= 3, else from the readings) and the readings.

    Raises
    ------
    ValueError
        The run has no rest dwell.
    """
    if pd.__version__ == _PANDAS_FOLLOWED:
        cols = {c: _plain(dw[c], k) for c, k in (("azimuth_deg", "f"), ("mean_output", "f"), ("n", "i"),
                                                  ("ss_within", "f"))}
        rest = dw["rest"].to_numpy()
        if (all(v is not None for v in cols.values()) and rest.dtype == bool
                and not np.isnan(cols["ss_within"]).any()):          # pandas' sum skips NaN
            return _rest_mean_columns({**cols, "rest": rest})     # the same numbers without pandas
    return _rest_mean_pandas(dw)


def _rest_mean_pandas(dw: pd.DataFrame) -> tuple[float, float, int]:
    r = dw[dw["rest"]]
    if r.empty:
        raise ValueError("run has no rest dwell")
    by_az = r.groupby(r["azimuth_deg"].fillna(0.0).round(3))
    means = by_az["mean_output"].mean().to_numpy()
    E0 = float(means.mean())
    n = int(r["n"].sum())
    pooled_var = float(r["ss_within"].sum() / max(n - len(r), 1))
    u_read = np.sqrt(pooled_var / n)
    u = u_read
    if means.size >= 3:
        u = max(u_read, float(means.std(ddof=1) / np.sqrt(means.size)))
    return E0, float(u), n


def noise_model(level: np.ndarray, var: np.ndarray, n: np.ndarray) -> tuple[float, float]:
    """Reading-noise model of a centrifuge run: white noise plus rate jitter.

    .. math::

        \\sigma^2(a) = s_0^2 + (k a)^2

    Parameters
    ----------
    level : ndarray
        Centripetal level a of each dwell [m/s2].
    var : ndarray
        Within-dwell variance [y unit squared].
    n : ndarray
        Readings per dwell.

    Returns
    -------
    (s0^2, k^2) : (float, float)
        Both >= 0 [y unit^2, (y unit / (m/s2))^2], fitted to the within-dwell variances by
        weighted least squares (Var s^2 = 2 sigma^4/(n-1); the fitting core's solver),
        reweighted three times.
    """
    a2 = np.asarray(level, float) ** 2
    v = np.asarray(var, float)
    dof = np.maximum(np.asarray(n, float) - 1, 1)
    X = np.c_[np.ones_like(a2), a2]
    w = dof / np.maximum(v, 1e-300) ** 2
    beta = np.array([np.median(v[a2 == a2.min()]) if np.any(a2 == a2.min()) else v.min(), 0.0])
    for _ in range(3):
        sw = np.sqrt(w)
        beta = lstsq_svd_x(X * sw[:, None], v * sw)
        beta = np.maximum(beta, [max(v.min() * 1e-3, 1e-300), 0.0])
        pred = X @ beta
        w = dof / pred**2
    return float(beta[0]), float(beta[1])


# ------------------------------------------------------------------ fast path
# The dwell statistics above are pandas groupby reductions over a few hundred rows; their
# cost is pandas' per-call overhead (~4 ms a run, twelve runs a campaign).  The functions
# below compute the very same numbers with numpy and pandas' own cython kernels, taking
# the path pandas takes for each reduction (pandas 3.1: np.<ufunc>.reduceat over the
# segments when the group ids are sorted and the column has no NaN, else the cython
# group_mean / group_sum; group_var for the standard deviation), so that every value is
# bit for bit the one of the pandas path (tests/test_dwells_fast.py checks it).  They apply
# only to plain numpy float64/int64 columns, finite but for the table angle, under the
# pandas version whose code paths they follow; anything else takes the pandas path.

_FLOAT_COLUMNS = ("output", "table_rate_rad_s", "time_s")
#: the pandas release whose groupby code paths the fast path follows
_PANDAS_FOLLOWED = "3.1.1"


def _plain(series, kind: str) -> np.ndarray | None:
    a = series.to_numpy() if isinstance(series.dtype, np.dtype) else None
    if a is None or a.dtype.kind != kind or a.dtype.itemsize != 8:
        return None
    return a


class _Groups:
    """Rows grouped by a key as ``groupby(key, sort=True)`` groups them, with its reductions."""

    def __init__(self, key: np.ndarray):
        # integer keys (a run's steps, a tumble's positions) by counting: np.unique's arrays
        # without sorting a long run's readings (issue 28)
        if key.dtype.kind in "iu":
            self.keys, _, ids = unique_small_ints(key)
        else:
            self.keys, ids = np.unique(key, return_inverse=True)
        self.ids = ids.reshape(-1).astype(np.intp, copy=False)
        self.ngroups = len(self.keys)
        self.counts = np.bincount(self.ids, minlength=self.ngroups).astype(np.int64)
        self.monotonic = bool(np.all(self.ids[1:] >= self.ids[:-1]))
        if self.monotonic:
            self.starts = np.flatnonzero(np.r_[True, self.ids[1:] != self.ids[:-1]])
            self.sizes = np.diff(self.starts, append=self.ids.size)

    def _reduceat(self, v: np.ndarray, how: str) -> np.ndarray | None:
        if not self.monotonic or (v.dtype.kind == "f" and np.isnan(v).any()):
            return None
        if how == "mean":
            return np.add.reduceat(v.astype(np.float64, copy=False), self.starts) / self.sizes.astype(np.float64)
        ufunc = {"sum": np.add, "min": np.minimum}[how]
        return ufunc.reduceat(v, self.starts)

    def _cython(self, kernel, v: np.ndarray, **kw) -> np.ndarray:
        out = np.empty((self.ngroups, 1), dtype=np.float64)
        counts = np.zeros(self.ngroups, dtype=np.int64)
        kernel(out, counts, v[None, :].T, self.ids, mask=None, result_mask=None, is_datetimelike=False,
               **kw)
        return out[:, 0]

    def mean(self, v: np.ndarray) -> np.ndarray:
        r = self._reduceat(v, "mean")
        if r is not None:
            return r
        from pandas._libs import groupby as libgroupby
        return self._cython(libgroupby.group_mean, v, min_count=-1, skipna=True)

    def sum(self, v: np.ndarray) -> np.ndarray:
        r = self._reduceat(v, "sum")
        if r is not None:
            return r
        from pandas._libs import groupby as libgroupby
        return self._cython(libgroupby.group_sum, v, min_count=0, initial=0, skipna=True)

    def std(self, v: np.ndarray, ddof: int = 1) -> np.ndarray:
        from pandas._libs import groupby as libgroupby
        return self._cython(libgroupby.group_var, v, min_count=-1, ddof=ddof, name="std", skipna=True)

    def min(self, v: np.ndarray) -> np.ndarray | None:
        return self._reduceat(v, "min")

    def sum_squares_about(self, v: np.ndarray, mean: np.ndarray) -> np.ndarray:
        """``sum((v - mean[group])**2)`` per group, as :meth:`sum` of the squared
        deviations gives it; the groups of a long run a slice of whole groups at a time
        (each group's sum is the same sequential sum, issue 28)."""
        if not self.monotonic or self.ids.size <= ROW_SLICE or np.isnan(v).any():
            dev = v - mean[self.ids]
            return self.sum(dev * dev)
        out = np.empty(self.ngroups)
        g = 0
        while g < self.ngroups:
            a = self.starts[g]
            h = max(int(np.searchsorted(self.starts, a + ROW_SLICE, side="right")), g + 1)
            b = self.starts[h] if h < self.ngroups else self.ids.size
            dev = v[a:b] - mean[self.ids[a:b]]
            out[g:h] = np.add.reduceat(dev * dev, self.starts[g:h] - a)
            g = h
        return out


def _dwell_columns(meta: Mapping, data, eff: Mapping[str, float]) -> dict[str, np.ndarray] | None:
    """The columns of :func:`dwell_table`, or None where the fast path does not apply."""
    if not isinstance(data, pd.DataFrame) or any(c not in data for c in ("step",) + _FLOAT_COLUMNS):
        return None
    step = _plain(data["step"], "i")
    vals = [_plain(data[c], "f") for c in _FLOAT_COLUMNS]
    has_az, has_line = "table_angle_deg" in data, "line" in data
    az = _plain(data["table_angle_deg"], "f") if has_az else None
    line = _plain(data["line"], "i") if has_line else None
    if (step is None or len(step) == 0 or any(v is None for v in vals) or (has_line and line is None)
            or (has_az and (az is None or np.isinf(az).any()))):
        return None
    if pd.__version__ != _PANDAS_FOLLOWED or not all(np.isfinite(v).all() for v in vals):
        return None
    out_, rate, time = vals
    grp = _Groups(step)
    if not grp.monotonic:
        return None
    mean_out = grp.mean(out_)
    ss = grp.sum_squares_about(out_, mean_out)  # about each dwell's own mean
    n = grp.counts
    rate_std = grp.std(rate)
    rate_std[np.isnan(rate_std)] = 0.0        # fillna(0.0)
    t_start = grp.min(time)
    o = np.argsort(t_start, kind="quicksort")   # sort_values("time_start")
    cols = {"step": grp.keys[o], "n": n[o], "mean_output": mean_out[o], "ss_within": ss[o],
            "rate": grp.mean(rate)[o], "rate_std": rate_std[o], "time_mid": grp.mean(time)[o],
            "time_start": t_start[o]}
    cols["var_output"] = cols["ss_within"] / np.maximum(cols["n"] - 1, 1)
    cols["azimuth_deg"] = grp.mean(az)[o] if has_az else np.full(len(o), np.nan)
    if has_line:
        cols["first_line"] = grp.min(line)[o]
    rate = cols["rate"]
    cols["rest"] = np.abs(rate) < 1e-9
    cols["omega_z"] = omega_z(meta, rate, eff)
    sweep = np.array(["rest"] * len(o), dtype=object)
    moving = np.flatnonzero(~cols["rest"])
    if moving.size:
        peak = moving[np.argmax(rate[moving])]
        sweep[moving[moving <= peak]] = "up"
        sweep[moving[moving > peak]] = "down"
    cols["sweep"] = sweep
    return cols


def _rest_mean_columns(c: Mapping[str, np.ndarray]) -> tuple[float, float, int]:
    """:func:`rest_mean` on the columns of a dwell table (same operations, no pandas)."""
    r = c["rest"]
    if not r.any():
        raise ValueError("run has no rest dwell")
    az = c["azimuth_deg"][r]
    key = np.round(np.where(np.isnan(az), 0.0, az), 3)
    means = _Groups(key).mean(c["mean_output"][r])
    E0 = float(means.mean())
    n = int(c["n"][r].sum())
    pooled_var = float(c["ss_within"][r].sum() / max(n - int(r.sum()), 1))
    u_read = np.sqrt(pooled_var / n)
    u = u_read
    if means.size >= 3:
        u = max(u_read, float(means.std(ddof=1) / np.sqrt(means.size)))
    return E0, float(u), n


def merged_dwell_columns(meta: Mapping, data) -> dict[str, np.ndarray] | None:
    """The columns of ``merge_rest(dwell_table(meta, data))`` computed without pandas, or
    None where the fast path does not apply (then call those two)."""
    c = _dwell_columns(meta, data, {"earth_rate": 1.0})
    if c is None:
        return None
    is_rest = c["rest"]
    mv = ~is_rest
    if not is_rest.any():
        out = {k: v[mv] for k, v in c.items()}
        out["dof_pe"] = out["n"] - 1
        return out
    E0, _, n = _rest_mean_columns(c)
    n_rest = int(is_rest.sum())
    ss_r = c["ss_within"][is_rest]
    ss = float(ss_r.sum())
    merged = {"n": n, "mean_output": E0, "ss_within": ss, "var_output": ss / max(n - n_rest, 1),
              "time_mid": float(c["time_mid"][is_rest].sum() / np.float64(n_rest)),
              "omega_z": float(c["omega_z"][is_rest].sum() / np.float64(n_rest))}
    first = np.flatnonzero(is_rest)[:1]
    out = {}
    for k, v in c.items():
        head = np.asarray([merged[k]]) if k in merged else v[first]
        out[k] = np.concatenate([head, v[mv]])
    out["dof_pe"] = np.concatenate([[n - n_rest], c["n"][mv] - 1])
    return out

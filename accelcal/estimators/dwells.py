"""Dwell statistics of a stepped-rate centrifuge run (drop-format.md, `centrifuge`).

A centrifuge run is a sequence of dwells (`step`): rest dwells at two or more
table azimuths, then dwells at rising and falling constant rates.  Each row is
the DAQ's mean over a reading window, so the rows of one dwell are replicated
readings: their scatter is the *pure error* of the lack-of-fit test.

The per-dwell reductions are :class:`accelcal.fitting.data.Groups`'.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from ..fitting.core import lstsq_svd_x
from ..fitting.data import Groups
from ..physics.rigs import omega_z


def dwell_columns(meta: Mapping, data, eff: Mapping[str, float]) -> dict[str, np.ndarray]:
    """The columns of :func:`dwell_table` as numpy arrays (its parameters; ``eff`` the
    effects for omega_z), for a method that reads them as arrays."""
    grp = Groups(np.asarray(data["step"]))
    out_ = np.asarray(data["output"], np.float64)
    rate_rows = np.asarray(data["table_rate_rad_s"], np.float64)
    time_rows = np.asarray(data["time_s"], np.float64)
    rate = grp.mean(rate_rows)
    mean_out = grp.mean(out_)
    dev = out_ - np.r_[mean_out, np.nan][grp.ids]               # about each dwell's own mean
    rate_std = grp.std(rate_rows)
    t_start = grp.min(time_rows)
    o = np.argsort(t_start)                                       # time order, nan last
    cols = {"step": grp.keys[o], "n": grp.counts[o], "mean_output": mean_out[o],
            "ss_within": grp.sum(dev * dev)[o], "rate": rate[o],
            "rate_std": np.where(np.isnan(rate_std), 0.0, rate_std)[o],
            "time_mid": grp.mean(time_rows)[o], "time_start": t_start[o]}
    cols["var_output"] = cols["ss_within"] / np.maximum(cols["n"] - 1, 1)
    cols["azimuth_deg"] = grp.mean(data["table_angle_deg"])[o] if "table_angle_deg" in data \
        else np.full(len(o), np.nan)
    if "line" in data:
        cols["first_line"] = grp.min(np.asarray(data["line"]))[o]
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


def dwell_table(meta: Mapping, data, effects: Mapping[str, float] | None = None) -> pd.DataFrame:
    """Dwell statistics of a stepped-rate centrifuge run.

    Parameters
    ----------
    meta : mapping
        Typed run metadata.
    data : DataFrame or mapping of arrays
        ``step``, ``output`` [output_unit], ``table_rate_rad_s`` [rad/s], ``time_s`` [s],
        ``table_angle_deg`` [deg], optional ``line``.
    effects : mapping, optional
        Effects for omega_z (default: the earth rate, drop-format.md).

    Returns
    -------
    DataFrame
        One row per dwell, in time order: step, n, mean_output [output_unit], ss_within (sum
        of squares about the dwell mean) [output_unit^2], rate (mean logged rate) [rad/s],
        rate_std [rad/s], time_mid [s], time_start [s], var_output (sample variance),
        azimuth_deg [deg], first_line, rest (bool), omega_z
        (:func:`accelcal.physics.rigs.omega_z`) [rad/s], sweep ('rest', 'up', 'down').
    """
    return pd.DataFrame(dwell_columns(meta, data, {"earth_rate": 1.0} if effects is None else effects))


def rest_mean(dw) -> tuple[float, float, int]:
    """E0 of He & Yin 2017 (paper 000) eq 4: the rest output over the table azimuths.

    Parameters
    ----------
    dw : DataFrame or mapping of arrays
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
    r = np.asarray(dw["rest"], bool)
    if not r.any():
        raise ValueError("run has no rest dwell")
    az = np.asarray(dw["azimuth_deg"], np.float64)[r]
    means = Groups(np.round(np.where(np.isnan(az), 0.0, az), 3)).mean(np.asarray(dw["mean_output"])[r])
    E0 = float(means.mean())
    n = int(np.asarray(dw["n"])[r].sum())
    pooled_var = float(np.nansum(np.asarray(dw["ss_within"], np.float64)[r]) / max(n - int(r.sum()), 1))
    u = u_read = np.sqrt(pooled_var / n)
    if means.size >= 3:
        u = max(u_read, float(means.std(ddof=1) / np.sqrt(means.size)))
    return E0, float(u), n


def merged_dwell_columns(meta: Mapping, data) -> dict[str, np.ndarray]:
    """The columns of :func:`dwell_table` with the rest dwells merged into one group.

    Parameters
    ----------
    meta : mapping
        Typed run metadata.
    data : DataFrame or mapping of arrays
        The run's columns (:func:`dwell_table`).

    Returns
    -------
    dict of str to ndarray
        The merged rest group first, then the moving dwells.  The rest group's mean is the
        mean of the azimuth means (He & Yin 2017, paper 000 eq 4: averaging over equally
        spaced azimuths removes the spindle's tilt).  Adds ``dof_pe``: pure-error degrees of
        freedom of each row (n - 1 for a dwell; readings minus azimuths for the merged rest
        group, so the spread between azimuths, which is the spindle tilt and not noise,
        counts in neither term).
    """
    c = dwell_columns(meta, data, {"earth_rate": 1.0})
    rest = c["rest"]
    if not rest.any():
        return {**c, "dof_pe": c["n"] - 1}
    E0, _, n = rest_mean(c)
    n_rest = int(rest.sum())
    ss = float(np.nansum(c["ss_within"][rest]))
    merged = {"n": n, "mean_output": E0, "ss_within": ss, "var_output": ss / max(n - n_rest, 1),
              "time_mid": float(np.nanmean(c["time_mid"][rest])), "omega_z": float(np.nanmean(c["omega_z"][rest]))}
    first = np.flatnonzero(rest)[:1]
    out = {k: np.concatenate([np.asarray([merged[k]]) if k in merged else v[first], v[~rest]])
           for k, v in c.items()}
    out["dof_pe"] = np.concatenate([[n - n_rest], c["n"][~rest] - 1])
    return out


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

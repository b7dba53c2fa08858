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

from ..fitting.core import lstsq_svd
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
        beta = lstsq_svd(X * sw[:, None], v * sw).x
        beta = np.maximum(beta, [max(v.min() * 1e-3, 1e-300), 0.0])
        pred = X @ beta
        w = dof / pred**2
    return float(beta[0]), float(beta[1])

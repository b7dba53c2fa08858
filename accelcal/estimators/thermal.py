"""Temperature coefficients from a tilted multi-position rotation in a thermal chamber (paper 001).

Paper 001 (Zhang et al., 2021; ``shared/docs/methods.md``): the rotary table's plane is
tilted by gamma; IA lies in the plane, so at table angle theta_k = 360 deg * k / n the
instrument senses g sin(gamma) sin(theta_k) on IA (drop-format.md, ``tilt_rotation``).
At every chamber temperature the n positions give, by least squares on
{1, sin theta, cos theta},

    E_k = a + b sin(theta_k) + c cos(theta_k)
    K1(T) = sigma * b / (g sin gamma)            [output_unit per m/s^2]
    K0(T) = a / K1(T)                              [m/s^2]

(sigma = +-1, the sign of IA in ``sin_axis``; the roles of sin and cos swap when IA is the
``cos_axis``).  The regressors are not rebuilt here: they are the derivatives of the one
forward model (:func:`point_design`, :func:`temperature_design`; tested against central
differences of :func:`accelcal.physics.rigs.rig_output`), and every least-squares solve is
the fitting core's (:func:`accelcal.fitting.core.linear_fit`).  For n = 4: K0 = (E0 + E1 + E2 + E3)/4 / K1 and K1 = (E1 - E3)/(2 g sin gamma).
The other in-plane term, c, measures the misalignment of the sense axis in the table
plane (or, equivalently and indistinguishably, a cross-axis sensitivity on the other
in-plane axis).  Across temperature points the effects.md temperature model

    K0(T) = K0 + K0T (T - 20 degC),     K1(T) = K1 (1 + K1T (T - 20 degC))

is fitted by weighted least squares.  A fixture thermal tilt c_f (rad/degC; effect
``fixture_thermal_tilt``) is the same at all positions of one temperature: it cancels from
K1 but enters K0 as g c_f cos(gamma) per degC, so K0T from this method is the instrument's
bias TC plus g c_f cos(gamma) (paper 001, section 3.2); nothing in one such run separates them.
A base-tilt change d_gamma leaves K0 alone and scales K1 by (gamma + d_gamma)/gamma.

Units: SI as effects.md (K0 m/s^2, K1 output_unit/(m/s^2), K0T m/s^2/degC, K1T 1/degC);
temperatures degC; angles in degrees where the drop format gives degrees.  Every function is
plain (numpy/pandas in, dicts or arrays out); the ``extras`` of :func:`process_thermal_run`
are JSON-able (non-finite numbers become None).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from ..constants import MICRO_G, T_REF_C
from ..effects import CROSS_AXIS_TERM, RIG_INPUTS, SQUARE_TERM, si_unit
from ..fitting.core import lack_of_fit, linear_fit, lstsq_svd, straight_line_slope
from ..fitting.data import unique_small_ints
from ..fitting.distributions import chi2_sf, t_ppf
from ..physics.axes import parse_signed_axis
from ..physics.geometry import geometry_of
from ..physics.instrument import indicated_acceleration, output_derivative
from ..physics.rigs import tilt_rotation_specific_force
from ..rounding import round_gum
from ..results import (BudgetTerm, CoefficientResult, FitCheck, ResidualFigure, ResidualPanel, ResidualSeries,
                       display_number)
from . import uncertainty as unc
from .records import Records, jsonable
from .registry import Estimator, register

METHOD = "tilt_rotation_ls"
METHOD_TWO_POSITION = "tilt_rotation_two_position"


# --------------------------------------------------------------------------- helpers


def rig_geometry(meta: Mapping) -> dict[str, Any]:
    """Geometry of a tilt_rotation run (drop-format.md): which in-plane term carries IA.

    Parameters
    ----------
    meta : mapping
        Typed run metadata (``g_local_m_s2``, ``tilt_deg``, ``sin_axis``, ``cos_axis``,
        ``normal_axis``), read through :func:`accelcal.physics.geometry.geometry_of`.

    Returns
    -------
    dict
        g [m/s2], gamma_rad [rad], ia_term ('sin' if IA is the ``sin_axis``, 'cos' if it is
        the ``cos_axis``), ia_sign (+-1), input_amplitude = g sin(gamma) [m/s2],
        normal_input = g cos(gamma) [m/s2], cross_term: the instrument coefficient of the
        other in-plane axis (Kp or Ko, [rad]).

    Raises
    ------
    ValueError
        IA not in the table plane, or no tilt.
    """
    g = float(meta["g_local_m_s2"])
    tab = geometry_of(meta)
    if tab.sin_axis == 0:
        term, sign, other = "sin", tab.sin_sign, tab.cos_axis
    elif tab.cos_axis == 0:
        term, sign, other = "cos", tab.cos_sign, tab.sin_axis
    else:
        raise ValueError("tilt_rotation: IA is neither the sin_axis nor the cos_axis; "
                         "paper 001 needs IA in the table plane")
    if math.sin(tab.gamma_rad) == 0.0:
        raise ValueError("tilt_rotation: tilt_deg is 0, IA senses no input")
    return {"g": g, "gamma_rad": tab.gamma_rad, "ia_term": term, "ia_sign": int(sign),
            "input_amplitude": g * math.sin(tab.gamma_rad), "normal_input": g * math.cos(tab.gamma_rad),
            "cross_term": CROSS_AXIS_TERM[other]}


#: The per-point parameters of paper 001's rotation fit: K1 K0, K1 and K1 times the cross
#: term of the other in-plane axis (the model is bilinear; the LS is linear in these).
POINT_PARAMS = ("K1*K0", "K1", "K1*Kx")


def specific_force_at(meta: Mapping, theta_deg) -> np.ndarray:
    """Specific force (n, 3) on (IA, PA, OA) [m/s2] at table angles ``theta_deg`` [deg]:
    :func:`accelcal.physics.rigs.tilt_rotation_specific_force` of the nominal table."""
    th = np.asarray(theta_deg, float)
    return tilt_rotation_specific_force(meta, {"rotation_deg": th, "time_s": np.zeros(th.size)})


def point_design(meta: Mapping, theta_deg) -> np.ndarray:
    """Regressors of one temperature point (paper 001, "least squares on {1, sin, cos}").

    Parameters
    ----------
    meta : mapping
        Typed run metadata of the tilt_rotation run.
    theta_deg : array_like
        Table angles [deg].

    Returns
    -------
    (n, 3) ndarray
        Columns for :data:`POINT_PARAMS`: dE/dK0 / K1 = 1, dE/dK1 = a_i and dE/dKx / K1 = a_x
        (a_i, a_x [m/s2] the IA and other in-plane specific force), the derivatives of the
        forward model (:func:`accelcal.physics.instrument.output_derivative` at K1 = 1,
        other coefficients 0).  E = K1 (K0 + a_i + Kx a_x) is linear in (K1 K0, K1, K1 Kx).
    """
    geo = rig_geometry(meta)
    F = specific_force_at(meta, theta_deg)
    unit = {"K1": 1.0}
    return np.column_stack([output_derivative("K0", unit, F), output_derivative("K1", unit, F),
                            output_derivative(geo["cross_term"], unit, F)])


def temperature_design(temp_c) -> np.ndarray:
    """Regressors of the temperature lines (effects.md temperature model, paper 001).

    Returns
    -------
    (N, 2) ndarray
        dE/dK0 and dE/dK0T of the forward model at K1 = 1 (1 and T - T_ref [degC]): the
        columns of K0(T) = K0 + K0T (T - T_ref) and, with p1 = K1 K1T, of
        K1(T) = K1 + p1 (T - T_ref).
    """
    T = np.asarray(temp_c, float)
    F = np.zeros((T.size, 3))
    unit = {"K1": 1.0}
    return np.column_stack([output_derivative("K0", unit, F, T), output_derivative("K0T", unit, F, T)])


# --------------------------------------------------------------------------- segmentation

def _in_time_order(data: pd.DataFrame, fresh: bool = False) -> pd.DataFrame:
    """``data`` sorted by ``time_s`` (stable), with a 0.. index when ``fresh`` (a new frame
    whose columns may be added to).  A run already in time order, as every accepted run is,
    is not copied: the sort would be the identity, and a copy of a day-long run is
    hundreds of MB."""
    if not data["time_s"].is_monotonic_increasing:
        d = data.sort_values("time_s", kind="stable")
        return d.reset_index(drop=True).copy() if fresh else d
    if not fresh:
        return data
    return pd.DataFrame({c: data[c].to_numpy() for c in data.columns}, copy=False)


def segment_run(data: pd.DataFrame, positions: int | None = None) -> pd.DataFrame:
    """Label every reading of a tilt_rotation run with its sweep, temperature point and position.

    A temperature point is a run of consecutive rows with the same ``temp_set_c``; a new
    sweep (repeat) starts when the set-point turns back against the sweep's direction
    (for the usual rising sweeps: when it goes back down).  The position index is
    k = round(theta * n / 360) mod n when n (``positions``) is given, else the rank of the
    distinct rounded angles.  Returns a new frame of ``data``'s columns (sorted by
    ``time_s``; sharing them, not copied, when ``data`` is already in time order) with the
    int columns ``sweep``, ``point`` (0-based, run-wide) and ``position``.
    """
    d = _in_time_order(data, fresh=True)
    sp = d["temp_set_c"].to_numpy(float)
    change = np.r_[True, np.abs(np.diff(sp)) > 1e-9]
    point = np.cumsum(change) - 1
    starts = np.flatnonzero(change)
    sweep_of_point = np.zeros(len(starts), int)
    sweep, direction = 0, 0
    for j in range(1, len(starts)):
        s = 1 if sp[starts[j]] - sp[starts[j - 1]] > 0 else -1
        if direction != 0 and s != direction:
            sweep += 1
            direction = 0
        else:
            direction = s
        sweep_of_point[j] = sweep
    d["point"] = point.astype(int, copy=False)
    d["sweep"] = sweep_of_point[point].astype(int, copy=False)
    th = np.mod(d["rotation_deg"].to_numpy(float), 360.0)
    if positions:
        d["position"] = (np.rint(th * positions / 360.0).astype(int) % int(positions))
    else:
        key = np.round(th, 3)
        key = np.where(np.isclose(key, 360.0), 0.0, key)
        d["position"] = pd.factorize(key, sort=True)[0]
    return d


def position_means(labelled: pd.DataFrame) -> pd.DataFrame:
    """Mean of the readings at every (point, position) of a :func:`segment_run` table.

    Columns: sweep, point, position, theta_deg (circular mean of rotation_deg), time_s,
    temp_set_c, temp_c (mean of the finite ``temp_c``; NaN when none), output (mean,
    output_unit), output_sd (sample standard deviation), count.
    """
    point = labelled["point"].to_numpy()
    position = labelled["position"].to_numpy()
    key = point.astype(np.int64) * (int(position.max(initial=0)) + 1) + position
    uniq, first, gid = unique_small_ints(key)
    del key
    k = uniq.size
    n = np.bincount(gid, minlength=k).astype(float)

    def mean(col):
        return np.bincount(gid, weights=col, minlength=k) / n

    out = labelled["output"].to_numpy(float)
    m_out = mean(out)
    dev = out - m_out[gid]
    sd = np.sqrt(np.bincount(gid, weights=dev * dev, minlength=k) / np.maximum(n - 1, 1))
    del dev                          # (each series of a long run let go once used)
    sd[n < 2] = np.nan
    T = labelled["temp_c"].to_numpy(float)
    fin = np.isfinite(T)
    nT = np.bincount(gid, weights=fin.astype(float), minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        mT = np.bincount(gid, weights=np.where(fin, T, 0.0), minlength=k) / nT
    del fin
    th = np.radians(labelled["rotation_deg"].to_numpy(float))
    s_mean = mean(np.sin(th))
    c_mean = mean(np.cos(th))
    del th
    theta = np.mod(np.degrees(np.arctan2(s_mean, c_mean)), 360.0)
    return pd.DataFrame({
        "point": point[first], "position": position[first],
        "sweep": labelled["sweep"].to_numpy()[first], "time_s": mean(labelled["time_s"].to_numpy(float)),
        "temp_set_c": labelled["temp_set_c"].to_numpy(float)[first], "temp_c": mT, "output": m_out,
        "output_sd": sd, "count": n.astype(int), "theta_deg": theta})


# --------------------------------------------------------------------------- one temperature point

def fit_point(meta: Mapping, theta_deg: Sequence[float], output: Sequence[float],
              sigma_override: float | None = None) -> dict[str, Any]:
    """K0, K1 of one temperature point by least squares over its n positions (paper 001).

    Parameters
    ----------
    meta : mapping
        Typed metadata of the tilt_rotation run (g, tilt and axes: :func:`rig_geometry`).
    theta_deg : sequence of float
        Table angles [deg].
    output : sequence of float
        The mean output at each [output_unit].
    sigma_override : float, optional
        Standard deviation of one position mean [output_unit]; default: from the residuals,
        s^2 = RSS / (n - 3) (NaN uncertainties when n == 3).

    Returns
    -------
    dict
        a [output_unit] and b_sin, b_cos (the coefficients of 1, sin theta, cos theta),
        K0 [m/s2], u_K0, K1 [output_unit/(m/s2)], u_K1, cov_K0_K1, cos_term (= the
        coefficient of the other in-plane term, [output_unit]), u_cos_term, misalignment_rad
        = cos_term / (IA term) [rad] (in-plane misalignment of the sense axis, or a
        cross-axis sensitivity on the other in-plane axis: the two cannot be told apart),
        u_misalignment_rad, rss, dof, s (residual std), n.

    Notes
    -----
    E_k = K1 (K0 + a_i,k + Kx a_x,k) is fitted by ordinary least squares
    (:func:`accelcal.fitting.core.linear_fit`) on the regressors of :func:`point_design`,
    the derivatives of the forward model; with A = g sin(gamma) this is paper 001's
    E = a + b sin(theta) + c cos(theta) with K1 = sigma b / A and K0 = a / K1 (for n = 4:
    K0 = (E0 + E1 + E2 + E3)/4 / K1, K1 = (E1 - E3)/(2 g sin gamma)).

    References
    ----------
    Zhang et al. 2021, temperature model of an ultra-sensitive accelerometer (paper 001,
    tilted multi-position rotation; ``shared/docs/methods.md``).
    """
    th = np.asarray(theta_deg, float)
    E = np.asarray(output, float)
    n = E.size
    if n < 3:
        raise ValueError(f"fit_point needs at least 3 positions, got {n}")
    geo = rig_geometry(meta)
    A = geo["input_amplitude"]
    X = point_design(meta, th)
    res = linear_fit(X, E, 1.0 if sigma_override is None else float(sigma_override), list(POINT_PARAMS),
                     residual_scale=sigma_override is None)
    beta = res.values
    resid = E - X @ beta
    rss = float(resid @ resid)
    dof = n - 3
    if sigma_override is not None:
        s = float(sigma_override)
        cov_b = res.cov_noise
    elif dof > 0:
        s = math.sqrt(rss / dof)
        cov_b = res.cov
    else:
        s = float("nan")
        cov_b = np.full((3, 3), np.nan)
    # paper 001's coefficients (a, b_sin, b_cos) of {1, sin theta, cos theta}: the columns
    # are 1, sigma A sin|cos theta and (the other axis' sign) A cos|sin theta
    ib, io = (1, 2) if geo["ia_term"] == "sin" else (2, 1)
    other_sign = geometry_of(meta).cos_sign if geo["ia_term"] == "sin" else geometry_of(meta).sin_sign
    T = np.zeros((3, 3))
    T[0, 0] = 1.0
    T[ib, 1] = geo["ia_sign"] * A
    T[io, 2] = other_sign * A
    coef = T @ beta
    cov = T @ cov_b @ T.T
    a, bs, bc = coef
    b, c = coef[ib], coef[io]
    K1 = float(beta[1])
    K0 = a / K1
    # gradients for the delta method, parameters (a, bs, bc)
    gK1 = np.zeros(3)
    gK1[ib] = geo["ia_sign"] / A
    gK0 = np.zeros(3)
    gK0[0] = 1.0 / K1
    gK0[ib] = -a / (K1 * K1) * geo["ia_sign"] / A
    gm = np.zeros(3)
    gm[io] = 1.0 / b
    gm[ib] = -c / (b * b)
    # (a NaN covariance, when n = 3 leaves no residual dof, gives NaN uncertainties)
    u = lambda grad: math.sqrt(max(float(grad @ cov @ grad), 0.0))  # noqa: E731
    return {"n": n, "a": float(a), "b_sin": float(bs), "b_cos": float(bc),
            "K0": float(K0), "u_K0": u(gK0), "K1": float(K1), "u_K1": u(gK1),
            "cov_K0_K1": float(gK0 @ cov @ gK1),
            "cos_term": float(c), "u_cos_term": math.sqrt(cov[io, io]),
            "misalignment_rad": float(c / b), "u_misalignment_rad": u(gm),
            "cross_term": float(beta[2] / beta[1]), "cross_term_name": geo["cross_term"],
            "rss": rss, "dof": dof, "s": s}


def closed_form_n4(output_0_90_180_270: Sequence[float], g: float, tilt_deg: float,
                   ia_sign: int = 1) -> dict[str, float]:
    """Paper 001's closed forms for n = 4 positions, IA the sin axis (Zhang et al. 2021).

    .. math::

        K_1 = \\sigma \\frac{E_1 - E_3}{2 g \\sin\\gamma}, \\qquad
        K_0 = \\frac{E_0 + E_1 + E_2 + E_3}{4 K_1}

    Parameters
    ----------
    output_0_90_180_270 : sequence of float
        E0..E3 at 0, 90, 180, 270 deg [output_unit].
    g : float
        [m/s2].
    tilt_deg : float
        gamma [deg].
    ia_sign : int
        sigma, the sign of IA in ``sin_axis``.

    Returns
    -------
    dict
        K1 [output_unit/(m/s2)], K0 [m/s2], mean_output, cos_term (E0 - E2)/2 [output_unit].
    """
    E0, E1, E2, E3 = (float(x) for x in output_0_90_180_270)
    K1 = ia_sign * (E1 - E3) / (2.0 * g * math.sin(math.radians(tilt_deg)))
    mean = (E0 + E1 + E2 + E3) / 4.0
    return {"K1": K1, "K0": mean / K1, "mean_output": mean, "cos_term": (E0 - E2) / 2.0}


def fit_points(meta: Mapping, data: pd.DataFrame) -> tuple[list[dict], pd.DataFrame]:
    """Per-temperature-point K0, K1 of a whole run (paper 001).

    Segments the run (:func:`segment_run`), averages each position (:func:`position_means`)
    and fits each point (:func:`fit_point`).  Each point row carries two uncertainty sets:
    ``u_K0``/``u_K1`` from its own residuals (n - 3 dof) and ``u_K0_pooled``/``u_K1_pooled``
    from the residual variance pooled over all points of the run (sum of n - 3 dof), which
    the temperature fit uses by default (per-point variances on few dof make poor weights).
    Also: sweep, temp_c (mean of temp_c over the point, degC; temp_set_c if temp_c is
    missing), temp_set_c, time_s (mean, s), and for n divisible by 4 the closed-form check
    on the four quadrant positions.  Returns (points, position-means table).
    """
    geo = rig_geometry(meta)
    n_pos = int(meta["positions"]) if meta.get("positions") not in (None, "") else None
    pm = position_means(segment_run(data, n_pos))
    points: list[dict] = []
    fitted: list[tuple[dict, np.ndarray, np.ndarray]] = []     # (row, theta, E) of the fitted points
    col = {c: pm[c].to_numpy() for c in ("point", "position", "sweep", "temp_set_c", "time_s", "count")}
    col.update({c: pm[c].to_numpy(float) for c in ("temp_c", "theta_deg", "output")})
    order = np.lexsort((col["position"], col["point"]))          # each point's positions in turn
    for rows in np.split(order, np.flatnonzero(np.diff(col["point"][order])) + 1) if order.size else []:
        grp = {c: v[rows] for c, v in col.items()}
        T = grp["temp_c"]
        T_mean = float(np.nanmean(T)) if np.isfinite(T).any() else float(grp["temp_set_c"][0])
        row = {"point": int(grp["point"][0]), "sweep": int(grp["sweep"][0]),
               "temp_set_c": float(grp["temp_set_c"][0]), "temp_c": T_mean,
               "time_s": float(np.nanmean(grp["time_s"])), "n_positions": int(rows.size),
               "n_readings": int(grp["count"].sum())}
        theta, E = grp["theta_deg"], grp["output"]
        if rows.size >= 3:
            row.update(fit_point(meta, theta, E))
            fitted.append((row, theta, E))
        # closed-form check on the quadrant positions (0, 90, 180, 270)
        th = np.mod(theta, 360.0)
        quad = []
        for q in (0.0, 90.0, 180.0, 270.0):
            hit = np.flatnonzero(np.abs((th - q + 180.0) % 360.0 - 180.0) < 1e-3)
            quad.append(float(E[hit[0]]) if hit.size else None)
        if all(v is not None for v in quad) and geo["ia_term"] == "sin":
            cf = closed_form_n4(quad, geo["g"], float(meta["tilt_deg"]), geo["ia_sign"])
            row["closed_form_K0"], row["closed_form_K1"] = cf["K0"], cf["K1"]
        points.append(row)
    if fitted:
        dof_tot = sum(p["dof"] for p, _, _ in fitted)
        if dof_tot > 0:
            s_pool = math.sqrt(sum(p["rss"] for p, _, _ in fitted) / dof_tot)
        else:  # n = 3: no residual dof; the within-position scatter of the readings instead
            sd, cnt = pm["output_sd"].to_numpy(float), pm["count"].to_numpy(float)
            ok = np.isfinite(sd) & (cnt > 1)
            s_pool = float(np.sqrt(np.mean(sd[ok] ** 2 / cnt[ok]))) if ok.any() else float("nan")
            dof_tot = int(np.sum(cnt[ok] - 1))
        for p, theta, E in fitted:
            fp = fit_point(meta, theta, E, sigma_override=s_pool)
            p["u_K0_pooled"], p["u_K1_pooled"] = fp["u_K0"], fp["u_K1"]
            p["s_pooled"], p["dof_pooled"] = s_pool, dof_tot
    return points, pm


# --------------------------------------------------------------------------- temperature model

def _wls_line(x, y, u) -> dict[str, Any]:
    """Weighted LS y = p0 + p1 x with weights 1/u^2 (:func:`accelcal.fitting.core.linear_fit` on
    the columns of :func:`temperature_design`, x = T - T_ref).  When the core's
    chi-square test fails at 5 % for nu = N - 2 (the scatter is not explained by the
    per-point uncertainties: base tilt drift, tilt tides, an unmodelled temperature
    dependence) the covariance is multiplied by chi2/nu (the Birge ratio squared)."""
    x, y, u = (np.asarray(v, float) for v in (x, y, u))
    N = x.size
    X = temperature_design(x + T_REF_C)
    res = linear_fit(X, y, u, ["p0", "p1"], residual_scale=False)
    chi2, nu = res.chi2, N - 2
    test = lack_of_fit(chi2, nu, alpha=0.05)
    applied = test.status == "inadequate"
    cov = res.cov_noise * (test.factor ** 2 if applied else 1.0)
    return {"p": res.values, "cov": cov, "chi2": chi2, "nu": nu, "birge_applied": applied,
            "birge_ratio": math.sqrt(chi2 / nu) if nu > 0 else float("nan")}


def fit_temperature_model(temp_c: Sequence[float], K0: Sequence[float], u_K0: Sequence[float],
                          K1: Sequence[float], u_K1: Sequence[float], t_ref: float = T_REF_C,
                          level: float = 0.95, dof_u: float | None = None,
                          levels: Sequence[float] | None = None) -> dict[str, Any]:
    """Fit the effects.md temperature model across temperature points (Zhang et al. 2021,
    paper 001).

    .. math::

        K_0(T) = K_0 + K_{0T} (T - T_{ref}), \\qquad
        K_1(T) = K_1 (1 + K_{1T} (T - T_{ref})) = p_0 + p_1 (T - T_{ref})

    Parameters
    ----------
    temp_c : sequence of float
        Mean temperature of each point [degC].
    K0, u_K0 : sequence of float
        Per-point bias and its standard uncertainty [m/s2].
    K1, u_K1 : sequence of float
        Per-point scale factor and its standard uncertainty [output_unit/(m/s2)].
    t_ref : float
        T_ref [degC].
    level : float
        Coverage probability of the intervals.
    dof_u : float, optional
        Degrees of freedom of the per-point uncertainties.
    levels : sequence of float, optional
        Chamber set point of each point [degC]: the points of one set point share their
        temperature reading's error (``temperature_sensitivity``); default each its own.

    Returns
    -------
    dict
        K0, u_K0, K0T, u_K0T, K1 (= p0), u_K1, K1T (= p1 / p0, u by the delta method with the
        p0-p1 covariance), their dof (N - 2 when scaled or when ``dof_u`` is not given,
        else dof_u), Student-t intervals, chi2 and Birge ratios.  Weighted LS (weights
        1/u^2) through :func:`accelcal.fitting.core.linear_fit` on :func:`temperature_design`.
    """
    T = np.asarray(temp_c, float)
    N = T.size
    if N < 2:
        raise ValueError("the temperature model needs at least two temperature points")
    x = T - t_ref
    f0 = _wls_line(x, K0, u_K0)
    f1 = _wls_line(x, K1, u_K1)
    nu = N - 2
    p0, p1 = f1["p"]
    c = f1["cov"]
    K1T = p1 / p0
    g = np.array([-p1 / p0**2, 1.0 / p0])
    u_K1T = math.sqrt(max(float(g @ c @ g), 0.0))
    out = {"t_ref_c": t_ref, "n_points": N, "level": level,
           "K0": float(f0["p"][0]), "u_K0": math.sqrt(f0["cov"][0, 0]),
           "K0T": float(f0["p"][1]), "u_K0T": math.sqrt(f0["cov"][1, 1]),
           "K1": float(p0), "u_K1": math.sqrt(c[0, 0]),
           "K1T": float(K1T), "u_K1T": u_K1T,
           "birge_ratio_K0": f0["birge_ratio"], "birge_ratio_K1": f1["birge_ratio"],
           "birge_applied_K0": f0["birge_applied"], "birge_applied_K1": f1["birge_applied"],
           "chi2_K0": f0["chi2"], "chi2_K1": f1["chi2"], "nu": nu}
    for k, f in (("K0", f0), ("K0T", f0), ("K1", f1), ("K1T", f1)):
        dof = nu if (f["birge_applied"] or dof_u is None) else float(dof_u)
        tq = float(t_ppf(0.5 + level / 2.0, dof)) if dof > 0 else float("nan")
        v, uu = out[k], out["u_" + k]
        out["dof_" + k] = dof
        out["t_factor_" + k] = tq
        out["interval_" + k] = [v - tq * uu, v + tq * uu] if dof > 0 else [float("nan")] * 2
    out["temperature_sensitivity"] = _temperature_sensitivity(
        x, u_K0, u_K1, f0["p"], f1["p"], np.arange(N) if levels is None else levels)
    return out


def _temperature_sensitivity(x, u_K0, u_K1, p_K0, p_K1, levels) -> dict[str, float]:
    """Root-sum-square over the temperature levels of d(coefficient)/d(T_k) [coefficient
    unit per degC]: the sensitivity to a temperature reading whose error is the same at
    every return to one set point and independent from one set point to the next.

    The weighted line p = A y, A = (X^T W X)^+ X^T W, X = [1, T - T_ref], takes a reading
    error dT_k as a shift of the point's abscissa: dp = -A[:, k] p1 dT_k, summed over the
    points of a level.  K0, K0T are (p0, p1) of K0(T); K1 = p0 and K1T = p1 / p0 of K1(T),
    so dK1T = (dp1 - K1T dp0) / p0.
    """
    X = np.column_stack([np.ones_like(x), x])
    _, level = np.unique(np.asarray(levels, float), return_inverse=True)
    out = {}
    for (n0, n1), u, p in ((("K0", "K0T"), u_K0, p_K0), (("K1", "K1T"), u_K1, p_K1)):
        w = 1.0 / np.asarray(u, float) ** 2
        A = lstsq_svd(np.sqrt(w)[:, None] * X, np.zeros(x.size)).cov @ (w[:, None] * X).T   # (2, N)
        d = np.array([np.bincount(level, weights=-a * p[1]) for a in A])     # dp / dT_level
        if n1 == "K1T":
            out[n0] = float(np.sqrt(np.sum(d[0] ** 2)))
            out[n1] = float(np.sqrt(np.sum(((d[1] - p[1] / p[0] * d[0]) / p[0]) ** 2)))
        else:
            out[n0], out[n1] = (float(np.sqrt(np.sum(r ** 2))) for r in d)
    return out


def _fit_from_points(points: list[dict]) -> dict[str, Any]:
    """:func:`fit_temperature_model` of the fitted points of :func:`fit_points`, weighted by
    their uncertainties from the run's pooled residual variance (per-point variances on few
    dof make poor weights)."""
    pts = [p for p in points if "K1" in p]
    dof_u = pts[0].get("dof_pooled")
    return fit_temperature_model([p["temp_c"] for p in pts], [p["K0"] for p in pts],
                                 [p["u_K0_pooled"] for p in pts], [p["K1"] for p in pts],
                                 [p["u_K1_pooled"] for p in pts], dof_u=dof_u if dof_u and dof_u > 0 else None,
                                 levels=[p.get("temp_set_c", p["temp_c"]) for p in pts])


def sweep_repeatability(points: list[dict]) -> dict[str, Any]:
    """The temperature model fitted to each sweep (repeat) alone, and the spread across sweeps.

    Returns per_sweep (list of fits: K0T, K1T, K0, K1 with uncertainties) and, with two or
    more sweeps, the sample standard deviation across sweeps of each coefficient (the
    repeatability; paper 001 quotes < 0.4 ug/degC and < 30 ppm/degC), also in display units.
    """
    sweeps = sorted({p["sweep"] for p in points if "K1" in p})
    per = []
    for s in sweeps:
        pts = [p for p in points if p["sweep"] == s and "K1" in p]
        if len({round(p["temp_c"], 6) for p in pts}) < 2:
            continue
        f = _fit_from_points(pts)
        per.append({"sweep": s, "n_points": len(pts), **{k: f[k] for k in (
            "K0", "u_K0", "K1", "u_K1", "K0T", "u_K0T", "K1T", "u_K1T")}})
    out: dict[str, Any] = {"per_sweep": per, "n_sweeps": len(per)}
    if len(per) >= 2:
        for k in ("K0", "K1", "K0T", "K1T"):
            out["sd_" + k] = float(np.std(np.array([r[k] for r in per]), ddof=1))
            out["mean_u_" + k] = float(np.mean([r["u_" + k] for r in per]))
        out["sd_K0T_ug_per_degC"] = out["sd_K0T"] / MICRO_G
        out["sd_K1T_ppm_per_degC"] = out["sd_K1T"] * 1e6
    return out


def scale_factor_time_trend(points: list[dict], model: Mapping) -> dict[str, Any]:
    """Trend in time of the per-point K1 left after the temperature model (paper 001: a base-tilt
    change d_gamma scales K1 by (gamma + d_gamma)/gamma, so a steady base tilt drift shows as a K1
    trend in time; with repeated sweeps time and temperature are not collinear).

    Weighted LS of r_j = K1_j / K1(T_j) - 1 on time (h).  Returns slope_ppm_per_h with its standard
    uncertainty (scaled by the Birge ratio when > 1) and ``significant`` (|slope| > 3 u);
    a slope s (1/h) means a base tilt rate of about gamma * s / 3600 rad/s.
    """
    pts = [p for p in points if "K1" in p]
    if len(pts) < 3:
        return {}
    t_h = np.array([p["time_s"] for p in pts]) / 3600.0
    T = np.array([p["temp_c"] for p in pts])
    K1fit = model["K1"] * (1.0 + model["K1T"] * (T - model.get("t_ref_c", T_REF_C)))
    r = np.array([p["K1"] for p in pts]) / K1fit - 1.0
    u = np.array([p["u_K1_pooled"] for p in pts]) / K1fit
    if np.ptp(t_h) == 0 or not np.all(np.isfinite(u)) or np.any(u <= 0):
        return {}
    f = _wls_line(t_h - t_h.mean(), r, u)
    slope, us = float(f["p"][1]), math.sqrt(f["cov"][1, 1])
    return {"slope_ppm_per_h": slope * 1e6, "u_slope_ppm_per_h": us * 1e6,
            "significant": bool(abs(slope) > 3.0 * us), "note": "relative K1 residual vs time"}


# --------------------------------------------------------------------------- fixed-point method

def fixed_point_method(meta: Mapping, pm: pd.DataFrame, s_pos: float | None = None) -> dict[str, Any]:
    """The fixed-point (position-by-position) method on the positions a run holds (paper 001).

    Positions used: '+' where IA senses +g sin(gamma) (theta = 90 deg for sin_axis +IA),
    '-' where it senses -g sin(gamma) (270 deg) and '0' where it senses 0 (0 and 180 deg).
    Per temperature point (A = g sin gamma):
      two-position:  K1 = sigma (E+ - E-) / (2A), K0 = (E+ + E-)/2 / K1;
      zero input:    K0_zero = mean(E0) / K1 (K1 of the two-position pair);
      one position:  K1+ = E+ / A and K1- = -E- / A (the traditional single-position scale
                     factor, bias and fixture tilt included).
    Each series is fitted with the temperature model (:func:`fit_temperature_model`); the
    single-position K1T+ and K1T- differ by about 2 (K0T + g c_f cos gamma) / A, which is the
    fixture deformation the paper warns about.  ``s_pos``: standard deviation of one position
    mean (output_unit), e.g. the pooled residual of the rotation fits; else from the
    within-position scatter.  Returns {} when the run holds no +/- pair.
    """
    geo = rig_geometry(meta)
    A = geo["input_amplitude"]
    dirn = specific_force_at(meta, pm["theta_deg"])[:, 0] / A      # IA input per g sin(gamma)
    if s_pos is None or not math.isfinite(s_pos):
        sd = pm["output_sd"].to_numpy(float) / np.sqrt(pm["count"].to_numpy(float))
        s_pos = float(np.sqrt(np.nanmean(sd**2))) if np.isfinite(sd).any() else float("nan")
    rows = []
    for pt, grp in pm.assign(direction=dirn).groupby("point", sort=True):
        d, E = grp["direction"].to_numpy(), grp["output"].to_numpy(float)
        plus, minus, zero = E[np.abs(d - 1.0) < 1e-6], E[np.abs(d + 1.0) < 1e-6], E[np.abs(d) < 1e-6]
        if plus.size == 0 or minus.size == 0:
            continue
        Ep, Em = float(plus.mean()), float(minus.mean())
        K1 = (Ep - Em) / (2.0 * A)
        K0 = (Ep + Em) / 2.0 / K1
        u_K1 = s_pos * math.sqrt(1.0 / plus.size + 1.0 / minus.size) / (2.0 * A)
        u_mean = s_pos * math.sqrt(1.0 / plus.size + 1.0 / minus.size) / 2.0
        u_K0 = math.hypot(u_mean / K1, K0 / K1 * u_K1)
        T = grp["temp_c"].to_numpy(float)
        row = {"point": int(pt), "sweep": int(grp["sweep"].iloc[0]),
               "temp_c": float(np.nanmean(T)) if np.isfinite(T).any() else float(grp["temp_set_c"].iloc[0]),
               "E_plus": Ep, "E_minus": Em, "K1": K1, "u_K1": u_K1, "K0": K0, "u_K0": u_K0,
               "K1_plus": Ep / A, "K1_minus": -Em / A, "u_K1_single": s_pos / math.sqrt(plus.size) / A}
        if zero.size:
            row["E_zero"] = float(zero.mean())
            row["K0_zero"] = row["E_zero"] / K1
            row["u_K0_zero"] = math.hypot(s_pos / math.sqrt(zero.size) / K1, row["K0_zero"] / K1 * u_K1)
        rows.append(row)
    if len({round(r["temp_c"], 6) for r in rows}) < 2:
        return {"points": rows} if rows else {}

    def model(*keys):       # the temperature model of the rows' K0, u_K0, K1, u_K1 series ``keys``
        return fit_temperature_model([r["temp_c"] for r in rows], *([r[k] for r in rows] for k in keys))
    out: dict[str, Any] = {"s_position_mean": s_pos, "points": rows, "two_position": model("K0", "u_K0", "K1", "u_K1")}
    if all("K0_zero" in r for r in rows):
        z = model("K0_zero", "u_K0_zero", "K1", "u_K1")
        out["zero_input"] = {k: z[k] for k in ("K0", "u_K0", "K0T", "u_K0T", "interval_K0T")}
    for name, key in (("single_plus", "K1_plus"), ("single_minus", "K1_minus")):
        f = model("K0", "u_K0", key, "u_K1_single")
        out[name] = {k: f[k] for k in ("K1", "u_K1", "K1T", "u_K1T", "interval_K1T")}
    return out


# --------------------------------------------------------------------------- compensation

def compensate(output, temp_c, model, input_m_s2=0.0, t_ref: float = T_REF_C) -> np.ndarray:
    """Remove the temperature model from an output series (paper 001, flight-data compensation).

    output: E (output_unit); temp_c: instrument temperature (degC), same length;
    model: K0 (m/s^2), K1 (output_unit/(m/s^2)), K0T (m/s^2/degC), K1T (1/degC) by name (a
    missing one is 0, K1 1); input_m_s2: the known IA input to take out (scalar or series).
    Returns the residual acceleration (m/s^2):

        r = E / (K1 (1 + K1T (T - t_ref))) - (K0 + K0T (T - t_ref)) - input
    """
    m = {k: float(model.get(k, 1.0 if k == "K1" else 0.0)) for k in ("K0", "K1", "K0T", "K1T")}
    dT = np.asarray(temp_c, float) - t_ref
    E = np.asarray(output, float)
    return E / (m["K1"] * (1.0 + m["K1T"] * dT)) - (m["K0"] + m["K0T"] * dT) - np.asarray(input_m_s2, float)


def temperature_correlation(series, temp_c) -> dict[str, float | None]:
    """Output-temperature sensitivity of a series (m/s^2) against temperature (degC).

    Least-squares slope of series on temp_c with its standard uncertainty (from residuals),
    in m/s^2/degC and in ug/degC (1 ug = 1e-6 * 9.80665 m/s^2), and the Pearson
    correlation r.  Paper 001 reports 47 ug/degC before and 1.7 ug/degC after compensation.
    """
    y = np.asarray(series, float)
    T = np.asarray(temp_c, float)
    ok = np.isfinite(y) & np.isfinite(T)
    if not ok.all():                 # (no copies of a long run that has no gaps)
        y, T = y[ok], T[ok]
    n = y.size
    if n < 3 or np.ptp(T) == 0:
        return {"n": int(n), "slope_m_s2_per_degC": None, "u_slope_m_s2_per_degC": None,
                "slope_ug_per_degC": None, "u_slope_ug_per_degC": None, "r": None}
    # r first: np.corrcoef copies both series, which is the peak of a long run
    r = float(np.corrcoef(T, y)[0, 1]) if np.std(y) > 0 else 0.0
    slope, u = straight_line_slope(T, y)
    return {"n": int(n), "slope_m_s2_per_degC": slope, "u_slope_m_s2_per_degC": u,
            "slope_ug_per_degC": slope / MICRO_G, "u_slope_ug_per_degC": u / MICRO_G, "r": r}


# --------------------------------------------------------------------------- one run

def process_thermal_run(meta: Mapping, data: pd.DataFrame, rig_id: str = ""
                        ) -> tuple[list[CoefficientResult], dict[str, Any]]:
    """All of paper 001 on one tilt_rotation run: K0, K1, K0T, K1T and the checks.

    .. math::

        E = K_1(T) (K_0(T) + a_i), \\quad K_0(T) = K_0 + K_{0T}(T - T_{ref}), \\quad
        K_1(T) = K_1 (1 + K_{1T}(T - T_{ref}))

    (Zhang et al. 2021, paper 001; effects.md temperature model, T_ref = 20 degC).

    Parameters
    ----------
    meta : mapping
        Typed metadata: g_local_m_s2 [m/s2], tilt_deg [deg], sin_axis, cos_axis,
        normal_axis, positions, output_unit.
    data : DataFrame
        time_s [s], temp_set_c [degC], temp_c [degC], rotation_deg [deg], output [output_unit].
    rig_id : str

    Returns
    -------
    (coefficients, extras)
        K0 [m/s2], K1 [output_unit/(m/s2)], K0T [m/s2/degC], K1T [1/degC], method
        'tilt_rotation_ls' ('tilt_rotation_two_position' when the run has fewer than 3
        positions); extras (JSON-able): geometry, per-point table, temperature model (95 %
        intervals), per-sweep repeatability, fixed-point method and its comparison with the
        rotation method, closed-form check, compensation (output-temperature sensitivity
        before/after), flags.  :func:`budget_terms` gives their GUM budgets.
    """
    geo = rig_geometry(meta)
    unit = str(meta.get("output_unit", "out"))
    points, pm = fit_points(meta, data)
    flags: list[str] = []
    fitted = [p for p in points if "K1" in p]
    fixed = fixed_point_method(meta, pm, fitted[0]["s_pooled"] if fitted else None)
    c_per_urad = geo["normal_input"] * 1e-6  # m/s2/degC per urad/degC of fixture tilt
    note_k0t = (f"includes any fixture thermal tilt c (effect fixture_thermal_tilt, rad/degC), which enters "
                f"K0T as g*c*cos(gamma) = {c_per_urad:.4g} m/s2/degC per urad/degC here; this method "
                "cannot separate it from the instrument's bias TC (paper 001 sec. 3.2)")
    note_k0 = ("apparent bias at 20 degC: includes g*cos(gamma) times any normal-axis cross-axis "
               "sensitivity or tilt of IA out of the table plane")
    if len({round(p["temp_c"], 6) for p in fitted}) >= 2:
        model = _fit_from_points(fitted)
        method = METHOD
    elif fixed.get("two_position"):
        model = fixed["two_position"]
        method = METHOD_TWO_POSITION
        flags.append("fewer than 3 positions per point: coefficients from the two-position method")
    else:
        raise ValueError("tilt_rotation run has neither >= 2 temperature points with >= 3 positions "
                         "nor a +/- position pair at 2 or more temperatures")
    note_k1t = ("fixture thermal tilt cancels from K1 (paper 001 eq 12); a base-tilt change "
                "d_gamma scales K1 by (gamma + d_gamma)/gamma")
    coeffs = [CoefficientResult(k, model[k], model["u_" + k], si_unit(k, unit), method, rig_id, model["dof_" + k], note)
              for k, note in (("K0", note_k0), ("K1", ""), ("K0T", note_k0t), ("K1T", note_k1t))]
    for k in ("K0", "K1"):
        b = model.get("birge_ratio_" + k)
        if model.get("birge_applied_" + k):
            flags.append(f"{k}(T) scatters {b:.1f} times its per-point uncertainty across temperature "
                         "points (base tilt drift, tilt tides or an unmodelled temperature dependence?)")

    extras: dict[str, Any] = {"geometry": geo, "temperature_model": model}
    extras["temperature_model_display"] = {
        "K0T_ug_per_degC": model["K0T"] / MICRO_G, "u_K0T_ug_per_degC": model["u_K0T"] / MICRO_G,
        "K1T_ppm_per_degC": model["K1T"] * 1e6, "u_K1T_ppm_per_degC": model["u_K1T"] * 1e6,
        "fixture_tilt_K0T_per_urad_per_degC": c_per_urad}
    extras["points"] = points
    if fitted:
        extras["misalignment_rad_mean"] = float(np.mean([p["misalignment_rad"] for p in fitted]))
        K1s = np.array([p["K1"] for p in fitted])
        Kfit = model["K1"] * (1 + model["K1T"] * (np.array([p["temp_c"] for p in fitted]) - T_REF_C))
        extras["scale_factor_scatter_ppm"] = float(np.std(K1s / Kfit - 1.0, ddof=1) * 1e6) if len(K1s) > 2 else None
        tr = extras["scale_factor_time_trend"] = scale_factor_time_trend(fitted, model)
        if tr.get("significant"):
            flags.append(f"K1 drifts with time at {tr['slope_ppm_per_h']:.3g} +- {tr['u_slope_ppm_per_h']:.2g} "
                         "ppm/h beyond the temperature model: base tilt drift (effect base_tilt_drift) "
                         "or instrument drift?")
        cf = [p for p in fitted if "closed_form_K1" in p]
        if cf:
            extras["closed_form_check"] = {
                "n_points": len(cf),
                "max_rel_diff_K1": max(abs(p["closed_form_K1"] / p["K1"] - 1.0) for p in cf),
                "max_abs_diff_K0_m_s2": max(abs(p["closed_form_K0"] - p["K0"]) for p in cf),
                "note": "closed forms on the 0/90/180/270 positions; equal to LS when n = 4"}
    extras["repeatability"] = sweep_repeatability(fitted) if fitted else {}
    if fixed:
        extras["fixed_point"] = fixed
        if method == METHOD and "two_position" in fixed:
            fp = fixed["two_position"]
            comp = {}
            for k in ("K0T", "K1T"):
                comp[k] = {"rotation": model[k], "two_position": fp[k], "difference": fp[k] - model[k],
                           "u_rotation": model["u_" + k], "u_two_position": fp["u_" + k]}
            for k, side in (("K1T", "single_plus"), ("K1T", "single_minus"), ("K0T", "zero_input")):
                if side in fixed:
                    comp[f"{k}_{side}"] = {"value": fixed[side][k], "u": fixed[side]["u_" + k],
                                           "difference": fixed[side][k] - model[k]}
            comp["note"] = ("single-position K1T+ and K1T- take (K0T + g c cos gamma)/(g sin gamma) for a "
                            "scale-factor change with opposite signs (paper 001 Table 3); the rotation method "
                            "and the +/- pair cancel it")
            extras["method_comparison"] = comp
    # compensation on the run itself: the nominal IA input taken out, temperature-free
    # calibration (K0, K1 at 20 degC) before, the full model after
    d = _in_time_order(data)
    T = d["temp_c"].to_numpy(float)
    fin = np.isfinite(T)
    if fin.any():
        if not fin.all():            # (a run with every temperature logged is not copied)
            T = np.where(fin, T, d["temp_set_c"].to_numpy(float))
        del fin
        # the IA input with the fitted in-plane cross term: a_i + Kx a_x of the forward model
        Kx = float(np.mean([p["cross_term"] for p in fitted])) if fitted else 0.0
        inp = indicated_acceleration({geo["cross_term"]: Kx},
                                     specific_force_at(meta, d["rotation_deg"].to_numpy(float)))
        E = d["output"].to_numpy(float)
        # one series of the run's length at a time
        before = temperature_correlation(compensate(E, T, {"K0": model["K0"], "K1": model["K1"]}, inp), T)
        after = temperature_correlation(compensate(E, T, model, inp), T)
        extras["compensation"] = {"series": "run readings minus nominal IA input (m/s2)",
                                  "before": before, "after": after}
    extras["flags"] = flags
    return coeffs, jsonable(extras)


#: How each coefficient of paper 001 scales with g sin(gamma): K1 = b / (g sin gamma) and
#: K0 = a / K1, K0T likewise; K1T = p1 / p0 is a ratio and does not.
_GRAVITY_POWER = {"K0": 1.0, "K0T": 1.0, "K1": -1.0, "K1T": 0.0}


def stated_inputs(coefficients: Sequence[CoefficientResult], model: Mapping[str, Any], meta: Mapping,
                  stated: Mapping[str, float]) -> dict[str, dict[str, tuple[float, float, float]]]:
    """The rig inputs the lab states for this run's rig (:data:`accelcal.effects.RIG_INPUTS`),
    with the sensitivity of paper 001's coefficients to each, in closed form.

    With K1 = sigma b / (g sin gamma) and K0 = a / K1 (paper 001), a coefficient that scales
    as (g sin gamma)^n has dC/dg = n C / g and dC/dgamma = n C cot(gamma); the temperature
    reading's sensitivity is :func:`fit_temperature_model`'s ``temperature_sensitivity``.

    Parameters
    ----------
    coefficients : sequence of CoefficientResult
        K0, K1, K0T, K1T.
    model : mapping
        ``extras['temperature_model']``.
    meta : mapping
        The run's metadata (``g_local_m_s2`` [m/s2], ``tilt_deg`` [deg]).
    stated : mapping
        Input id -> the lab's standard uncertainty (the tilt's in deg, the others in SI).

    Returns
    -------
    dict
        Coefficient -> input id -> (value [SI], standard uncertainty [SI], sensitivity [unit
        per SI unit]) of each stated input that enters it (``temperature``: root-sum-square
        over the points; absent when the model has no such figure, as the two-position
        method).
    """
    g, gamma = float(meta["g_local_m_s2"]), math.radians(float(meta["tilt_deg"]))
    dT = model.get("temperature_sensitivity") or {}
    value = {"g_local": g, "table_tilt": gamma, "temperature": 0.0}
    to_si = {"table_tilt": math.pi / 180.0}
    out: dict[str, dict[str, tuple]] = {}
    for c in coefficients:
        n = _GRAVITY_POWER[c.name]
        sens = {"g_local": n * c.value / g, "table_tilt": n * c.value / math.tan(gamma)}
        if c.name in dT:
            sens["temperature"] = dT[c.name]
        for iid, x in sens.items():
            if iid in stated:
                out.setdefault(c.name, {})[iid] = (value[iid], float(stated[iid]) * to_si.get(iid, 1.0), x)
    return out


def budget_terms(coefficients: Sequence[CoefficientResult], model: Mapping[str, Any],
                 inputs: Mapping[str, Mapping[str, tuple[float, float, float]]] | None = None
                 ) -> list[BudgetTerm]:
    """GUM budget lines of paper 001's coefficients (JCGM 100 §4.2: type A from the fit; the
    stated rig inputs as type B).

    Parameters
    ----------
    coefficients : sequence of CoefficientResult
        K0, K1, K0T, K1T of :func:`process_thermal_run`.
    model : mapping
        Its ``extras['temperature_model']`` (:func:`fit_temperature_model`).
    inputs : mapping, optional
        Coefficient -> input id -> (value [SI], standard uncertainty [SI], sensitivity):
        the lab-stated rig inputs (:func:`stated_inputs`), one normal type-B line each.

    Returns
    -------
    list of BudgetTerm
        Per coefficient the weighted least-squares line over the temperature points with the
        per-point uncertainties, and, when their scatter exceeds them (Birge rule), the
        between-point scatter as a second type-A line; then the rig inputs.  The
        fixture's thermal tilt is not a line: the method cannot tell it from the
        instrument's bias TC (paper 001 §3.2), which the K0T note says.
    """
    out = []
    for c in coefficients:
        line = "K0" if c.name in ("K0", "K0T") else "K1"
        birge = model.get("birge_ratio_" + line)
        applied = bool(model.get("birge_applied_" + line)) and birge is not None and birge > 1
        u0 = c.std_uncertainty / birge if applied else c.std_uncertainty
        terms = [(f"weighted LS of {line}(T) over {model.get('n_points')} temperature points (paper 001), "
                  "per-point uncertainties", c.value, u0, 1.0, "A", "normal")]
        if applied:
            terms.append((f"between-point scatter of {line}(T): Birge ratio {birge:.3g}", 0.0,
                          u0 * math.sqrt(birge * birge - 1.0), 1.0, "A", "normal"))
        for iid, (x, u, sens) in ((inputs or {}).get(c.name) or {}).items():
            if sens != 0.0:
                terms.append((f"{RIG_INPUTS[iid].what} (type B, stated in accelcal.toml)", x, u, sens,
                              "B", "normal"))
        out += unc.linear_budget(c.name, terms, method=c.method, rig_id=c.rig_id, value=c.value).terms
    return out


# --------------------------------------------------------------------------- the campaign's thermal step

def campaign_records(runs: Sequence, steps: Mapping[str, Any]) -> list:
    """Paper 001 on every tilt_rotation run of a campaign (:func:`process_thermal_run`),
    with the GUM budgets of its coefficients; a run that fails is a flag."""
    out = []
    for run in runs:
        try:
            coeffs, extras = process_thermal_run(run.meta, run.data, str(run.meta.get("rig_id", "")))
        except Exception as exc:
            out.append(Records(flags=[f"tilt_rotation {run.meta.get('run_id')}: {type(exc).__name__}: {exc}"]))
            continue
        model = extras["temperature_model"]
        inputs = stated_inputs(coeffs, model, run.meta,
                               (steps.get("rig_uncertainty") or {}).get(str(run.meta.get("rig_id", ""))) or {})
        budget = budget_terms(coeffs, model, inputs)
        coeffs = [replace(c, std_uncertainty=math.sqrt(c.std_uncertainty ** 2 + sum(
            (u * sens) ** 2 for _, u, sens in inputs.get(c.name, {}).values()))) for c in coeffs]
        out.append(Records(coefficients=coeffs, budget=budget,
                           extras={"thermal": {str(run.meta.get("run_id")): extras}}).checked())
    return out


def mc_truth(c: Mapping[str, float], eff: Mapping[str, float], test: Mapping[str, Any], g: float,
             records: Mapping[str, CoefficientResult]) -> dict[tuple[str, str], tuple[float, str]]:
    """What each paper-001 coefficient estimates in a simulated test (tilt gamma, normal axis
    n with sign ns, cos axis c): K0 -> the apparent bias at 20 degC with the normal axis'
    cross and square terms and the mean centripetal-free square term of the tilt plane;
    K1 -> K1; K0T -> K0T + g c cos(gamma) of a fixture thermal tilt c (aliased, paper 001
    §3.2); K1T -> K1T (signature of :data:`accelcal.estimators.registry.TruthMapping`)."""
    rig = str(test["rig_id"])
    gam = math.radians(float(test["tilt_deg"]))
    ni, ns = parse_signed_axis(test.get("normal_axis", "+OA"))
    ci, _ = parse_signed_axis(test.get("cos_axis", "+PA"))
    if ni == 0 or ci == 0:
        return {}
    K0app = (c["K0"] + ns * c[CROSS_AXIS_TERM[ni]] * g * math.cos(gam)
             + c[SQUARE_TERM[ni]] * (g * math.cos(gam)) ** 2
             + (c["K2"] + c[SQUARE_TERM[ci]]) * (g * math.sin(gam)) ** 2 / 2)
    cf = eff.get("fixture_thermal_tilt", 0.0)
    return {("K0", rig): (K0app, "apparent bias at 20 degC (normal-axis terms)"),
            ("K1", rig): (c["K1"], "K1 at 20 degC"),
            ("K0T", rig): (c["K0T"] + g * cf * math.cos(gam), "K0T + g c cos(gamma) (fixture thermal tilt)"),
            ("K1T", rig): (c["K1T"], "instrument value")}


def residual_figures(extras: Mapping[str, Any]) -> list[ResidualFigure]:
    """Per temperature point, the point's K0 and K1 minus the temperature model at its
    temperature, in units of the point's standard uncertainty (paper 001), from what
    :func:`campaign_records` stored (``extras['thermal']``), for the certificate.

    Parameters
    ----------
    extras : mapping
        A stored result's extras.

    Returns
    -------
    list of ResidualFigure
        One ``'points'`` figure (a K0 and a K1 panel, a series per run), or none.
    """
    runs = [(rid, t) for rid, t in (extras.get("thermal") or {}).items()
            if isinstance(t, dict) and t.get("points") and t.get("temperature_model")]
    if not runs:
        return []
    k0, k1 = [], []
    for rid, t in runs:
        m = t["temperature_model"]
        tref = float(m.get("t_ref_c", T_REF_C))
        pts = [p for p in t["points"] if p.get("temp_c") is not None]
        r0 = [(p["temp_c"], (p["K0"] - (m["K0"] + m["K0T"] * (p["temp_c"] - tref))) / p["u_K0"])
              for p in pts if p.get("u_K0")]
        r1 = [(p["temp_c"], (p["K1"] - m["K1"] * (1 + m["K1T"] * (p["temp_c"] - tref))) / p["u_K1"])
              for p in pts if p.get("u_K1")]
        k0.append(ResidualSeries(rid, tuple(x for x, _ in r0), tuple(y for _, y in r0)))
        k1.append(ResidualSeries(rid, tuple(x for x, _ in r1), tuple(y for _, y in r1)))
    return [ResidualFigure("points", "Per temperature point: K0 and K1 minus the temperature model, in "
                           "units of the point's standard uncertainty (dashed: ±3).", tuple(
                               ResidualPanel(f"{name} per point − temperature model",
                                             "instrument temperature / °C", tuple(series))
                               for name, series in (("K0", k0), ("K1", k1))))]


def fit_checks(extras: Mapping[str, Any]) -> list[FitCheck]:
    """The certificate's fit statistics of a stored thermal result: per run the chi-square
    of the K0 and K1 point values about their temperature model, and the trend in time of
    the scale-factor residuals (a K1 drift the model leaves out).

    Parameters
    ----------
    extras : mapping
        The stored result's extras (``extras['thermal'][run]``).

    Returns
    -------
    list of FitCheck
    """
    f = display_number
    out = []
    for run, t in (extras.get("thermal") or {}).items():
        m = (t or {}).get("temperature_model") or {}
        for k in ("K0", "K1"):
            chi2, nu = m.get(f"chi2_{k}"), m.get("nu")
            p = float(chi2_sf(chi2, nu)) if chi2 is not None and nu else None
            out.append(FitCheck("thermal", run, f"temperature model of {k} (χ² of the point values)",
                                f"χ² = {f(chi2, '.3g')}, Birge {f(m.get(f'birge_ratio_{k}'), '.3g')}", f(nu), p))
        tr = (t or {}).get("scale_factor_time_trend") or {}
        if tr:
            # u to two significant digits, the slope to its last digit (GUM 7.2.6)
            r = round_gum(tr.get("slope_ppm_per_h"), tr.get("u_slope_ppm_per_h"))
            out.append(FitCheck("thermal", run, "K1 drift in time (residual trend)",
                                f"{r.value} ± {r.uncertainty} ppm/h",
                                "—", passes=not bool(tr.get("significant")), yes="not significant", no="significant"))
    return out


ESTIMATOR = register(Estimator(
    method=METHOD, tests=("tilt_rotation",),
    certificate=("paper 001 (Zhang et al., 2021): least squares of K0 and K1 over the "
                 "table positions at each temperature point, and a linear temperature model "
                 "for K0T and K1T (T_ref = 20 °C)"),
    # its first pass is the runs themselves: the tumble's records need to know that the
    # campaign measures K0T and K1T (their K0 and K1 are then at the tumble's temperature)
    prepare=lambda runs, steps: tuple(runs),
    records=campaign_records, truth=mc_truth, methods=(METHOD, METHOD_TWO_POSITION), adoption=3,
    main=("K0T", "K1T"), order=2, figures=residual_figures, checks=fit_checks))

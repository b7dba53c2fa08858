"""Where a gap lies and what shape it has.

Localisation: the cells are labelled along several dimensions (run, test, mount, polarity,
g level, sweep, head/table position, IA input, temperature, time).  For each segment of a
dimension the whitened residuals give sum z^2 against its expectation under a model that
is right, sum (1 - h_ii) (h the leverages of the fit); a chi-square test per segment with
Holm's correction over all segments says which segments hold a significant gap, and the
share of the dimension's excess that each holds says where most of it is.

Shape: the residual is regressed on a few simple forms along each numeric dimension
(a quadratic in g level, temperature, time or IA input; first and second harmonics of the
position angle; a sinusoid in time of the best period) and on one offset per run; the form
that explains the largest part of the excess is the gap's shape.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..fitting.core import lstsq_min_norm
from ..fitting.identify import UNOBSERVABLE_FRACTION, design_rank
from ..fitting.procedure import ModelFit
from ..physics.rigs import specific_force
from .fits import basis, project_out

#: expected chi-square (residual degrees of freedom) below which a segment is not tested
MIN_EXPECTED = 0.5


def _labels(f: ModelFit) -> dict[str, np.ndarray]:
    """Per-cell labels (object arrays) of every dimension, and numeric values (float arrays,
    key prefixed '#')."""
    parts: dict[str, list] = {}

    def add(dim, arr):
        parts.setdefault(dim, []).append(np.asarray(arr, object if not dim.startswith("#") else float))

    for r in f.model.runs:
        k, a = r.ncell, r.attrs
        na = np.array(["n/a"] * k, object)
        add("run", [r.run_id] * k)
        add("campaign", [r.campaign] * k)
        add("test", [r.test] * k)
        add("mount", a.get("mount", na))
        add("polarity", a.get("polarity", na))
        add("sweep", a.get("sweep", na))
        g = float(r.meta["g_local_m_s2"])
        ai = (r.cell_mean(specific_force(r.test, r.meta, r.cols)[:, 0]) / g
              if r.test in ("tumble", "tilt_rotation") else None)
        values = {"g_level": a.get("g_level"), "position": a.get("position"), "ia_input": ai,
                  "temperature": a.get("temperature")}
        for dim, v in values.items():
            v = None if v is None else np.asarray(v, float)
            add(dim, na if v is None else _bins(dim, v))
            add("#" + dim, np.full(k, np.nan) if v is None else v)
        # the signed IA input of a centrifuge cell [m/s^2]: the centripetal level along IA
        phi = getattr(r.geometry, "phi_rad", None)
        add("#ia_centrifuge", np.full(k, np.nan) if phi is None or a.get("g_level") is None
            else np.asarray(a["g_level"], float) * g * math.cos(phi))
        q = np.minimum((a["time_frac"] * 4).astype(int), 3)
        add("time", np.array([["first quarter", "second quarter", "third quarter", "last quarter"][i] for i in q],
                             object))
        add("#time", np.asarray(a["time"], float))
    return {d: np.concatenate(v) for d, v in parts.items()}


def _bins(dim: str, v: np.ndarray) -> np.ndarray:
    """Segment labels of a numeric dimension."""
    if dim == "g_level":
        return np.select([v < 0.01, v < 2, v < 5, v < 10, v < 20],
                         ["rest", "0-2 g", "2-5 g", "5-10 g", "10-20 g"], ">20 g").astype(object)
    if dim == "position":
        return np.array([f"{p:.0f} deg" for p in np.floor(((v + 22.5) % 360) / 45.0) * 45.0], object)
    if dim == "ia_input":
        return np.where(v > 0.9, "IA up", np.where(v < -0.9, "IA down", np.where(
            np.abs(v) < 0.1, "IA horizontal", "IA inclined"))).astype(object)
    return np.array([f"{t:.0f} C" for t in np.round(v)], object)


def localise(f: ModelFit, alpha: float = 0.05) -> list[dict]:
    """Every segment of every dimension with its chi-square, expectation, Holm-adjusted
    p-value, share of its dimension's excess and mean residual (whitened and SI).

    Parameters
    ----------
    f : ModelFit
        The fit whose whitened cell residuals are localised.
    alpha : float
        Family-wise significance level of the Holm procedure over all segments [1].

    Returns
    -------
    list of dict
        One per segment (dimensions with one segment are skipped, except ``run``), with
        ``dimension``, ``segment``, ``cells``, ``chi2`` (sum z^2) [1], ``expected``
        (sum 1 - h_ii) [1], ``p_value`` (chi-square, 1 when ``expected`` is below
        :data:`MIN_EXPECTED`), ``p_holm``, ``significant``, ``share`` of the dimension's
        excess [1], ``mean_z`` [1], ``mean_residual_m_s2`` and ``rms_residual_m_s2``
        [m/s^2].

    References
    ----------
    Holm, S., A simple sequentially rejective multiple test procedure, Scand. J. Statist.
    6, 65-70 (1979).
    """
    z = f.fit.z
    U = basis(f)
    e = 1.0 - np.sum(U * U, axis=1)        # 1 - h_ii: h the leverages, the diagonal of U U^T
    lab = _labels(f)
    si = residual_si(f)
    rows = []
    for dim, arr in lab.items():
        if dim.startswith("#"):
            continue
        segs = [s for s in dict.fromkeys(arr) if s != "n/a"]
        if len(segs) < 2 and dim not in ("run",):
            continue
        group = []
        for s in segs:
            m = arr == s
            S = float(np.sum(z[m] ** 2))
            ex = float(max(np.sum(e[m]), 1e-9))
            # a segment the fit determines (its cells' residuals have ~no freedom) is not tested
            p = float(stats.chi2.sf(S, ex)) if ex >= MIN_EXPECTED else 1.0
            group.append({"dimension": dim, "segment": str(s), "cells": int(m.sum()), "chi2": S, "expected": ex,
                          "p_value": p, "mean_z": float(np.mean(z[m])),
                          "mean_residual_m_s2": float(np.mean(si[m])),
                          "rms_residual_m_s2": float(np.sqrt(np.mean(si[m] ** 2)))})
        tot = sum(max(g["chi2"] - g["expected"], 0.0) for g in group)
        for g in group:
            g["share"] = max(g["chi2"] - g["expected"], 0.0) / tot if tot > 0 else 0.0
        rows += group
    order = np.argsort([r["p_value"] for r in rows])
    m = len(rows)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * rows[i]["p_value"]))
        rows[i]["p_holm"] = running
        rows[i]["significant"] = running < alpha
    return rows


def input_scale(f: ModelFit) -> np.ndarray:
    """|K1| of each cell's campaign, which refers an output to the input.

    Parameters
    ----------
    f : ModelFit
        The fit.

    Returns
    -------
    (N,) ndarray
        [output_unit per m/s^2]; 1 where the model has no K1 or its estimate is 0.
    """
    out = np.ones(f.fit.n_obs)
    for j, r in enumerate(f.model.runs):
        name = f.model.name(r.campaign, "K1")
        if name is not None:
            out[f.model.rows(j)] = abs(f.fit.value(name)) or 1.0
    return out


def residual_si(f: ModelFit) -> np.ndarray:
    """Cell residuals referred to the input: whitened residual x sigma / :func:`input_scale`.

    Parameters
    ----------
    f : ModelFit
        The fit.

    Returns
    -------
    (N,) ndarray
        Residual of each cell mean [m/s^2].
    """
    return f.fit.z * f.model.sig / input_scale(f)


#: level of the targeted shape test (:func:`shape_tests`): as strong a claim as
#: the lack-of-fit test's that a gap remains
SHAPE_ALPHA = 0.001
#: centrifuge levels within this fraction of each other are matched (a rising and a falling
#: step of one sweep at the same g level)
MATCH_REL = 0.02
#: the targeted test's name (:func:`shape_tests`)
HYSTERESIS_TEST = "rising minus falling steps, in proportion to the IA input"


def sweep_pairs(run: np.ndarray, sweep: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Each cell's side in the rising-against-falling contrast: +1 for a rising step, -1 for
    a falling one of the same run at a matched level (:data:`MATCH_REL`), 0 for the others
    (rest, the top of the sweep, a level met once); each rising step is matched once.

    Parameters
    ----------
    run, sweep : (N,) ndarray
        Run id and 'up' / 'down' / other of each cell.
    level : (N,) ndarray
        g level of each cell [g].

    Returns
    -------
    (N,) ndarray
        +1, -1 or 0 [1].
    """
    side = np.zeros(len(level))
    for rid in dict.fromkeys(run):
        up = list(np.flatnonzero((run == rid) & (sweep == "up")))
        for d in np.flatnonzero((run == rid) & (sweep == "down")):
            if not up:
                break
            k = int(np.argmin([abs(level[u] - level[d]) for u in up]))
            if abs(level[up[k]] - level[d]) <= MATCH_REL * abs(level[d]):
                side[up.pop(k)], side[d] = 1.0, -1.0
    return side


def shape_tests(f: ModelFit, alpha: float = SHAPE_ALPHA) -> list[dict]:
    """The targeted test of a sweep hysteresis, the shaped gap the omnibus lack-of-fit test
    dilutes over every cell: a centrifuge's rising steps reading h a_IA above its falling
    steps at the same g level (a_IA the centripetal input along IA, signed), pooled over
    every run that sweeps.

    It is the score test of that form: with s its whitened signature (h's output in each
    matched cell, :func:`sweep_pairs`, over the cell mean's noise sigma) and s_p its part
    the model does not take up (projected off the fit's columns), T = s_p . z / |s_p| is a
    standard normal when there is no hysteresis (z the whitened residuals), and the most
    powerful test of that form; h = s_p . z / |s_p|^2, standard uncertainty 1 / |s_p|.
    Each cell counts by its own noise: where the noise grows with rate the quiet low-g
    steps carry most of it.  A flat rising-minus-falling offset is not tested: it is what
    a slow bias wander or a temperature lag makes (the first and last steps of a sweep,
    furthest apart in time, carry it), and a trend in time takes nearly all of it.

    Parameters
    ----------
    f : ModelFit
        The fit whose residuals are tested.
    alpha : float
        Level [1], two-sided.

    Returns
    -------
    list of dict
        Empty when the runs do not test it (no matched rising and falling steps, or the
        model takes the form up); else one: ``test``, ``z`` [1], ``p_value``,
        ``significant``, ``cells`` (rising and falling steps matched), ``estimate`` and
        ``std_uncertainty`` of h [1].
    """
    lab = _labels(f)
    side = sweep_pairs(lab["run"], lab["sweep"], np.nan_to_num(lab["#g_level"], nan=0.0))
    # the output a hysteresis of h = 1 makes in each cell, over its noise
    s = side * np.nan_to_num(lab["#ia_centrifuge"], nan=0.0) * input_scale(f) / f.model.sig
    sp = project_out(basis(f), s)
    n2 = float(sp @ sp)
    if not (side > 0).any() or n2 <= (UNOBSERVABLE_FRACTION * np.linalg.norm(s)) ** 2:
        return []
    T = float(sp @ f.fit.z) / math.sqrt(n2)
    p = float(2 * stats.norm.sf(abs(T)))
    return [{"test": HYSTERESIS_TEST, "z": T, "p_value": p, "significant": p < alpha,
             "cells": [int(np.sum(side > 0)), int(np.sum(side < 0))], "estimate": T / math.sqrt(n2),
             "std_uncertainty": 1.0 / math.sqrt(n2)}]


def where(rows: list[dict]) -> list[dict]:
    """The Holm-significant segments, largest share first.

    Parameters
    ----------
    rows : list of dict
        Segments from :func:`localise`.

    Returns
    -------
    list of dict
        The significant ones, with ``dimension``, ``segment``, ``share`` [1], ``chi2`` [1],
        ``expected`` [1], ``p_holm`` [1], ``significant``, ``mean_residual_m_s2`` [m/s^2]
        and ``cells``; ties in share by dimension name.
    """
    keep = [{k: r[k] for k in ("dimension", "segment", "share", "chi2", "expected", "p_holm", "significant",
                               "mean_residual_m_s2", "cells")} for r in rows if r["significant"]]
    keep.sort(key=lambda w: (-w["share"], w["dimension"]))
    return keep


# ----------------------------------------------------------------------------- shape
def _forms(lab: dict, f: ModelFit) -> list[tuple[str, str, np.ndarray]]:
    """(dimension, description, design) of each simple form."""
    out = []
    runs = lab["run"]
    ids = list(dict.fromkeys(runs))
    if len(ids) > 1:
        out.append(("run", "an offset per run", np.column_stack([(runs == i).astype(float) for i in ids])))
    for dim, words in (("#g_level", "g level"), ("#temperature", "temperature"), ("#time", "time"),
                       ("#ia_input", "IA input")):
        x = lab[dim]
        ok = np.isfinite(x)
        if ok.sum() < 4 or np.ptp(x[ok]) <= 0:
            continue
        u = np.where(ok, (x - np.nanmean(x)) / np.nanstd(x), 0.0)
        out.append((dim[1:], f"linear in {words}", np.column_stack([u * ok])))
        out.append((dim[1:], f"quadratic in {words}", np.column_stack([u * ok, (u * u - 1) * ok])))
    x = lab["#position"]
    ok = np.isfinite(x)
    if ok.sum() >= 4 and np.ptp(x[ok]) > 0:
        th = np.radians(np.where(ok, x, 0.0))
        out.append(("position", "first harmonic of the position angle",
                    np.column_stack([np.cos(th) * ok, np.sin(th) * ok])))
        out.append(("position", "second harmonic of the position angle (even in the angle: horizontal "
                                "against vertical)", np.column_stack([np.cos(2 * th) * ok, np.sin(2 * th) * ok])))
    t = lab["#time"]
    if np.isfinite(t).all() and t.size >= 8 and np.ptp(t) > 0:
        span = float(np.ptp(t))
        dts = np.diff(np.sort(t))
        dt = float(np.median(dts[dts > 0])) if np.any(dts > 0) else span / t.size
        best = None
        for P in np.geomspace(max(3 * dt, span / 200), span, 80):
            X = np.column_stack([np.cos(2 * np.pi * t / P), np.sin(2 * np.pi * t / P)])
            Xw = X / f.model.sig[:, None]
            c = lstsq_min_norm(Xw, f.fit.z)
            gain = float(f.fit.z @ (Xw @ c))
            if best is None or gain > best[0]:
                best = (gain, P, X)
        if best is not None:
            out.append(("time", f"periodic in time, period {best[1]:.4g} s", best[2]))
    return out


def shape(f: ModelFit, top: int = 3) -> list[dict]:
    """The simple forms that explain most of the excess of the residual (share of
    sum z^2 - dof explained by each, after projecting the form off the model's columns).

    Each form's gain in chi-square, less its number of parameters (one more for a
    periodic form, whose period was searched), is divided by the excess chi2 - dof.

    Parameters
    ----------
    f : ModelFit
        The fit whose whitened residual is examined.
    top : int
        Most forms returned [1].

    Returns
    -------
    list of dict
        ``dimension``, ``form`` (words), ``parameters`` [1] and ``explained_fraction`` [1]
        of the forms explaining more than 5 %, the simplest first among those within 5 %
        of each other; empty when there is no excess or dof < 3.
    """
    excess = f.fit.chi2 - f.fit.dof
    if excess <= 0 or f.fit.dof < 3:      # a gap with one or two degrees of freedom has no shape
        return []
    lab = _labels(f)
    U = basis(f)
    out = []
    for dim, words, X in _forms(lab, f):
        Xw = X / f.model.sig[:, None]
        Xp = Xw - U @ (U.T @ Xw)
        if not np.any(np.linalg.norm(Xp, axis=0) > 1e-12 * max(np.linalg.norm(Xw), 1e-300)):
            continue
        k = design_rank(Xp) + (1 if words.startswith("periodic") else 0)
        if k > f.fit.dof - 2:
            continue
        c = lstsq_min_norm(Xp, f.fit.z, rcond=1e-10)
        gain = float(f.fit.z @ (Xp @ c)) - k
        out.append({"dimension": dim, "form": words, "parameters": k,
                    "explained_fraction": float(max(gain, 0.0) / excess)})
    # the simplest of the forms that explain about as much as the best
    out.sort(key=lambda s: (-round(s["explained_fraction"] / 0.05), s["parameters"]))
    return [s for s in out if s["explained_fraction"] > 0.05][:top]


def summary(rows: list[dict], forms: list[dict]) -> str:
    """One sentence: where most of the gap is and its shape.

    Parameters
    ----------
    rows : list of dict
        Segments from :func:`localise`.
    forms : list of dict
        Forms from :func:`shape`, best first.

    Returns
    -------
    str
        The significant segments (at least 10 % share each, up to four) of up to three
        dimensions, the largest share first; a dimension is named when its segments hold
        half its excess or more, or always for position, IA input and g level.  Then the
        best form with its explained percentage.
    """
    sig = [r for r in rows if r["significant"] and r["dimension"] not in ("campaign", "test")]
    parts = []
    by_dim: dict[str, list[dict]] = {}
    for r in sig:
        by_dim.setdefault(r["dimension"], []).append(r)
    ranked = sorted(by_dim.items(), key=lambda kv: -max(x["share"] for x in kv[1]))
    for dim, segs in ranked[:3]:
        segs = sorted([x for x in segs if x["share"] >= 0.1], key=lambda x: -x["share"])
        if not segs:
            continue
        share = sum(x["share"] for x in segs)
        if share >= 0.5 or dim in ("position", "ia_input", "g_level"):
            parts.append(f"{dim} {', '.join(s['segment'] for s in segs[:4])} ({100 * share:.0f} % of its excess)")
    txt = "; ".join(parts) if parts else "spread over the cells (no segment stands out)"
    if forms:
        txt += f"; shape: {forms[0]['form']} ({100 * forms[0]['explained_fraction']:.0f} % of the excess)"
    return txt

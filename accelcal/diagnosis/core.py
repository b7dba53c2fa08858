"""diagnose(): where the sim-to-real gap lies, which catalogue effect causes it, how far
it shrinks (in sample and held out).  See docs in ``accelcal/diagnosis/README.md``.

Statistics (all on whitened cell means z = (y - model) / sigma, sigma from replicates):
- localisation: per segment of each dimension, sum z^2 against chi^2(n * dof/N), Holm
  correction over all segments; share = excess chi^2 of the segment / excess of its dimension;
- screening: the candidate's signature (numerical Jacobian through the physics) projected
  off the span of the fitted model's Jacobian; observable fraction = |P j| / |j|;
- selection: nonlinear refit with the effect, likelihood ratio (delta chi^2) against the
  chi^2_1 quantile at alpha / m (Bonferroni over the m observable candidates), forward;
- aliases: |cos| > 0.95 between projected signatures;
- held-out shrink: leave one run out (linearised refit of the shared parameters on the
  other runs, the left-out run's own bias and scale refitted on it alone), or, for a run
  alone of its kind, leave one half of its cells out (alternate cells).
gap RMS = sqrt(max(0, mean z^2 - expected noise mean square)); shrink = 1 - after / before.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..effects import EFFECTS
from ._blas import single_thread
from .model import EFFECT_STEP, PLAUSIBLE_MAX, CENTRIFUGES, Fit, Model, fit, lstsq_scaled

#: effects the pipeline's own processing already models, per test kind (the default baseline)
DEFAULT_BASELINE = {
    "centrifuge": ["earth_rate", "odd_quadratic", "cubic", "cross_coupling", "mass_centre_offset"],
    "sine_centrifuge": ["earth_rate", "odd_quadratic", "cubic", "cross_coupling", "mass_centre_offset"],
    "tumble": ["initial_misalignment"],
    "tilt_rotation": [],
}
ALIAS_COS = 0.95
UNOBSERVABLE_FRACTION = 1e-3
#: instrument coefficients that are not catalogue effects but can mimic one (reported as aliases)
NON_CATALOGUE = ["Kp", "Ko", "Kpp", "Koo", "Kio", "Kpo"]


def default_baseline(tests) -> list[str]:
    out: list[str] = []
    for t in sorted(set(tests)):
        for e in DEFAULT_BASELINE.get(t, []):
            if e not in out:
                out.append(e)
    return out


def candidates_for(tests, baseline) -> list[str]:
    return [e for e, d in EFFECTS.items() if e not in baseline and any(t in d.tests for t in tests)]


# ------------------------------------------------------------------ helpers
def _basis(J: np.ndarray, rcond=1e-9) -> np.ndarray:
    s = np.linalg.norm(J, axis=0)
    act = s > 0
    if not act.any():
        return np.zeros((J.shape[0], 0))
    U, S, _ = np.linalg.svd(J[:, act] / s[act], full_matrices=False)
    return U[:, S > S[0] * rcond]


def _perp(U, v):
    return v - U @ (U.T @ v)


def gap_rms(z, expected_ms=1.0) -> float:
    return float(np.sqrt(max(np.mean(z ** 2) - expected_ms, 0.0)))


def _shrink(before, after):
    if before <= 0:
        return None
    return float(1.0 - after / before)


@dataclass
class _State:
    effects: list
    fit: Fit


def _fit_set(runs, baseline, effects, prev: Fit | None = None, transverse_scale=True) -> Fit:
    m = Model(runs, baseline, effects, transverse_scale=transverse_scale)
    p0 = m.initial()
    if prev is not None:
        pp = m.initial(prev.model, prev.p)
        for i, q in enumerate(m.params):      # keep the K1 steps of the fresh start
            if q.name in prev.model.index:
                p0[i] = pp[i]
    for i, q in enumerate(m.params):
        if q.kind == "K1":
            q.h = 1e-4 * abs(p0[i]) if p0[i] else 1e-4
    return fit(m, p0)


# ------------------------------------------------------------------ held-out
def heldout_z(f: Fit):
    """Held-out whitened residuals of a fitted model (linearised refits), with the expected
    noise mean square of those residuals."""
    m, J, z = f.model, f.J, f.z
    runs = m.runs
    kinds = {}
    for j, r in enumerate(runs):
        kinds.setdefault(r.test, []).append(j)
    zs, exp_n, exp_d = [], 0.0, 0.0
    for j, r in enumerate(runs):
        rows = np.arange(m.offsets[j], m.offsets[j + 1])
        if len(kinds[r.test]) >= 3:
            train = np.ones(m.N, bool)
            train[rows] = False
            d, _, _ = lstsq_scaled(J[train], z[train])
            zh = z[rows] - J[rows] @ d
            own = [i for i, q in enumerate(m.params) if q.runs == [j]]
            if own:
                dq, _, rk = lstsq_scaled(J[np.ix_(rows, own)], zh)
                zh = zh - J[np.ix_(rows, own)] @ dq
            else:
                rk = 0
            zs.append(zh)
            exp_n += len(rows) - rk
            exp_d += len(rows)
        else:
            for par in (0, 1):
                held = rows[(np.arange(len(rows)) % 2) == par]
                train = np.ones(m.N, bool)
                train[held] = False
                d, _, _ = lstsq_scaled(J[train], z[train])
                zs.append(z[held] - J[held] @ d)
                exp_n += len(held)
                exp_d += len(held)
    zz = np.concatenate(zs) if zs else np.zeros(0)
    return zz, (exp_n / exp_d if exp_d else 1.0)


def heldout_gap(f: Fit) -> float:
    zz, e = heldout_z(f)
    # leaving out inflates the noise of the held-out residuals a little; use the held-out
    # residual mean square of a model that is known to be complete: not available, so the
    # expectation is the number of held-out cells minus the refitted own parameters.
    return gap_rms(zz, e)


# ------------------------------------------------------------------ localisation
def _segments(runs):
    """dimension -> list of (segment label, boolean mask over all cells)."""
    labels: dict[str, list] = {}

    def add(dim, arr):
        labels.setdefault(dim, []).append(np.asarray(arr, object))

    for r in runs:
        k = r.ncell
        a = r.attrs
        add("run", [r.run_id] * k)
        add("test", [r.test] * k)
        add("attitude", a.get("mount", np.array([r.test] * k, object)))
        add("polarity", a.get("polarity", np.array(["n/a"] * k, object)))
        if "g_level" in a:
            gl = a["g_level"]
            lab = np.select([gl < 0.01, gl < 2, gl < 5, gl < 10, gl < 20],
                            ["rest", "0-2 g", "2-5 g", "5-10 g", "10-20 g"], ">20 g").astype(object)
        else:
            lab = np.array(["n/a"] * k, object)
        add("g_level", lab)
        add("sweep", a.get("sweep", np.array(["n/a"] * k, object)))
        if "position" in a:
            pos = np.floor(((a["position"] + 22.5) % 360) / 45.0) * 45.0
            add("position", np.array([f"{p:.0f} deg" for p in pos], object))
        else:
            add("position", np.array(["n/a"] * k, object))
        if "temperature" in a:
            add("temperature", np.array([f"{t:.0f} C" for t in np.round(a["temperature"])], object))
        else:
            add("temperature", np.array(["n/a"] * k, object))
        q = np.minimum((a["time_frac"] * 4).astype(int), 3)
        add("time", np.array([["first quarter", "second quarter", "third quarter", "last quarter"][i]
                              for i in q], object))
    out = {}
    for dim, parts in labels.items():
        lab = np.concatenate(parts)
        segs = [s for s in dict.fromkeys(lab) if s != "n/a"]
        if len(segs) >= 2 or dim == "run":
            out[dim] = [(s, lab == s) for s in segs]
    return out


def localise(f: Fit, alpha=0.05):
    z = f.z
    N = f.model.N
    ratio = f.dof / N
    segs = _segments(f.model.runs)
    rows = []
    for dim, lst in segs.items():
        exc = []
        for s, mask in lst:
            S = float(np.sum(z[mask] ** 2))
            n = int(mask.sum())
            df = max(n * ratio, 1e-9)
            p = float(stats.chi2.sf(S, df))
            exc.append(max(S - df, 0.0))
            rows.append({"dimension": dim, "segment": str(s), "cells": n, "chi2": S, "expected": df,
                         "p_value": p, "rms": float(np.sqrt(S / n))})
        tot = sum(exc)
        for k, e in enumerate(exc):
            rows[len(rows) - len(exc) + k]["share"] = e / tot if tot > 0 else 0.0
    # Holm over all segments
    order = np.argsort([r["p_value"] for r in rows])
    m = len(rows)
    running = 0.0
    for rank, i in enumerate(order):
        adj = min(1.0, (m - rank) * rows[i]["p_value"])
        running = max(running, adj)
        rows[i]["p_holm"] = running
        rows[i]["significant"] = running < alpha
    return rows


# ------------------------------------------------------------------ aliases, separation
def _non_catalogue_signatures(f: Fit):
    """Signatures of instrument coefficients that are not catalogue effects (Kp, Ko, ...)."""
    from ..physics import rig_output
    m, p = f.model, f.p
    out = {}
    for cname in NON_CATALOGUE:
        v = np.zeros(m.N)
        h = 1e-5 if cname in ("Kp", "Ko") else 1e-7
        for j, r in enumerate(m.runs):
            co, eff = m.run_inputs(p, j)
            up = dict(co)
            up[cname] = co.get(cname, 0.0) + h
            dn = dict(co)
            dn[cname] = co.get(cname, 0.0) - h
            rr = m.run_rows(j)
            v[rr] = (r.cell_mean(rig_output(r.test, r.meta, r.cols, up, eff))
                     - r.cell_mean(rig_output(r.test, r.meta, r.cols, dn, eff))) / (2 * h) / m.sig[rr]
        if np.linalg.norm(v) > 0:
            out[cname] = v
    return out


def _clone_run(r, **meta_changes):
    from copy import copy
    q = copy(r)
    q.meta = {**r.meta, **meta_changes}
    q.run_id = r.run_id + "+" + ",".join(f"{k}={v}" for k, v in meta_changes.items())
    return q


def separating_tests(runs, baseline, selected, a: str, b: str, fbase: Fit, limit=3):
    """Extra test points (a new mount / head) that would separate effects a and b: the
    design added, and |cos| of their projected signatures with it."""
    proposals = []
    tests = {r.test for r in runs}
    for t in tests:
        tmpl = next(r for r in runs if r.test == t)
        if t in CENTRIFUGES and (t in EFFECTS[a].tests or t in EFFECTS[b].tests):
            for plane, vert in (("IA-PA", "+OA"), ("IA-OA", "-PA")):
                for ang in (0.0, 45.0, 90.0, 135.0):
                    proposals.append(_clone_run(tmpl, mount_plane=plane, vertical_axis=vert,
                                                mount_angle_deg=ang))
        if t == "tumble" and (t in EFFECTS[a].tests or t in EFFECTS[b].tests):
            for head, ca, sa in (("OA", "+IA", "+PA"), ("IA", "+PA", "+OA"), ("PA", "+OA", "-IA")):
                proposals.append(_clone_run(tmpl, head_axis=head, cos_axis=ca, sin_axis=sa))
    out = []
    others = [e for e in selected if e not in (a, b)]
    for q in proposals:
        rs = list(runs) + [q]
        try:
            m = Model(rs, baseline, others)
            p = m.initial(fbase.model, fbase.p)
            for i, par in enumerate(m.params):       # new run: start from its template's values
                if par.name not in fbase.model.index:
                    tn = par.name.split("[")[0] + "[" + runs[[r.run_id for r in runs].index(
                        q.run_id.split("+")[0])].run_id + "]"
                    if tn in fbase.model.index:
                        p[i] = fbase.p[fbase.model.index[tn]]
            U = _basis(m.jac(p))
            ja, jb = _perp(U, m.signature(p, a)), _perp(U, m.signature(p, b))
            na, nb = np.linalg.norm(ja), np.linalg.norm(jb)
            if na == 0 or nb == 0:
                continue
            c = abs(float(ja @ jb) / (na * nb))
            desc = ({k: q.meta[k] for k in ("mount_plane", "mount_angle_deg", "vertical_axis")}
                    if q.test in CENTRIFUGES else {k: q.meta[k] for k in ("head_axis", "cos_axis", "sin_axis")})
            out.append({"add_run": {"test": q.test, **desc}, "abs_cos": c})
        except Exception:
            continue
    out.sort(key=lambda d: d["abs_cos"])
    return out[:limit]


# ------------------------------------------------------------------ main entry
def diagnose(runs, baseline=None, alpha: float = 0.05, max_effects: int = 6,
             refit_top: int = 3, separate: bool = True, strict_check: bool = True) -> dict:
    """Diagnose the gap between the (baseline) forward model and the runs (RunCells list).

    baseline: None (the pipeline's default for the tests present), 'none' (the bare model)
    or a list of effect ids.  Returns a dict (see :func:`public` for its JSON part)."""
    with single_thread():
        return _diagnose(runs, baseline, alpha, max_effects, refit_top, separate, strict_check)


def _diagnose(runs, baseline, alpha, max_effects, refit_top, separate, strict_check):
    t0 = time.perf_counter()
    tests = sorted({r.test for r in runs})
    if baseline is None:
        baseline = default_baseline(tests)
        base_label = "default"
    elif baseline in ("none", [], ()):
        baseline = []
        base_label = "none"
    else:
        baseline = [b for b in baseline]
        for b in baseline:
            if b not in EFFECTS:
                raise ValueError(f"unknown effect id {b!r} in --baseline (effects.md ids: {sorted(EFFECTS)})")
        base_label = ",".join(baseline)
    cands = candidates_for(tests, baseline)

    f0 = _fit_set(runs, baseline, [])
    N = f0.model.N
    z0 = f0.z
    where_rows = localise(f0, alpha)

    # --- observability of every candidate against the baseline
    U0 = _basis(f0.J)
    sig0 = {c: f0.model.signature(f0.p, c) for c in cands}
    obs = {}
    for c in cands:
        j = sig0[c]
        nj = float(np.linalg.norm(j))
        if nj == 0:
            obs[c] = {"observable_fraction": 0.0, "absorbed_fraction": None, "se": np.inf,
                      "applies": False}
            continue
        jp = _perp(U0, j)
        fr = float(np.linalg.norm(jp) / nj)
        se = 1.0 / max(float(np.linalg.norm(jp)), 1e-300)
        obs[c] = {"observable_fraction": fr, "absorbed_fraction": 1.0 - fr ** 2, "se": se, "applies": True}
    z_thr_all = stats.norm.isf(alpha / (2 * max(len(cands), 1)))
    for c in cands:
        o = obs[c]
        o["min_detectable"] = float(z_thr_all * o["se"]) if np.isfinite(o["se"]) else None
        o["observable"] = bool(o["applies"] and o["observable_fraction"] >= UNOBSERVABLE_FRACTION
                               and o["min_detectable"] is not None and o["min_detectable"] <= PLAUSIBLE_MAX[c])

    # --- forward selection
    state = _State([], f0)
    steps = []
    while len(state.effects) < max_effects:
        f = state.fit
        U = _basis(f.J)
        pool = [c for c in cands if c not in state.effects and obs[c]["observable"]]
        if not pool:
            break
        scores = {}
        for c in pool:
            jp = _perp(U, f.model.signature(f.p, c))
            n2 = float(jp @ jp)
            scores[c] = float((jp @ f.z) ** 2 / n2) if n2 > 0 else 0.0
        top = sorted(pool, key=lambda c: -scores[c])[:refit_top]
        trials = {}
        for c in top:
            ft = _fit_set(runs, baseline, state.effects + [c], prev=f)
            trials[c] = ft
        best = max(top, key=lambda c: f.chi2 - trials[c].chi2)
        dchi = f.chi2 - trials[best].chi2
        thr = float(stats.chi2.isf(alpha / len(pool), 1))
        steps.append({"step": len(state.effects) + 1, "best": best, "delta_chi2": dchi, "threshold": thr,
                      "scores": {c: scores[c] for c in top}})
        if dchi <= thr:
            break
        state = _State(state.effects + [best], trials[best])

    sel = state.effects
    ffinal = state.fit
    # --- gaps
    exp0 = f0.dof / N
    g_before = gap_rms(z0, exp0)
    g_after = gap_rms(ffinal.z, ffinal.dof / N)
    ho_before = heldout_gap(f0)
    ho_after = heldout_gap(ffinal) if sel else ho_before

    # --- ranking: selected (drop-one) then the rest (add-one)
    ranking = []
    Ufin = _basis(ffinal.J)
    chi_scale = max(1.0, ffinal.chi2 / ffinal.dof)
    proj_final = {}
    for c in sel:
        others = [e for e in sel if e != c]
        fprev = _fit_set(runs, baseline, others, prev=ffinal)
        name = f"effect:{c}"
        est, se = ffinal.value(name), ffinal.std(name) * np.sqrt(chi_scale)
        gb, ga = gap_rms(fprev.z, fprev.dof / N), g_after
        hb = heldout_gap(fprev)
        Up = _basis(fprev.J)
        proj_final[c] = _perp(Up, fprev.model.signature(fprev.p, c))
        ranking.append({"effect": c, "estimate": est, "std_uncertainty": float(se),
                        "unit": EFFECTS[c].unit, "z": est / se if se > 0 else None,
                        "delta_chi2": float(fprev.chi2 - ffinal.chi2), "significant": True,
                        "shrink_in_sample": _shrink(gb, ga), "shrink_heldout": _shrink(hb, ho_after),
                        "observable": True, **_obsfields(obs[c]), "aliases": []})
    rest = [c for c in cands if c not in sel]
    rest_scores = {}
    for c in rest:
        if not obs[c]["observable"]:
            continue
        jp = _perp(Ufin, ffinal.model.signature(ffinal.p, c))
        n2 = float(jp @ jp)
        proj_final[c] = jp
        rest_scores[c] = float((jp @ ffinal.z) ** 2 / n2) if n2 > 0 else 0.0
    for k, c in enumerate(sorted(rest_scores, key=lambda c: -rest_scores[c])):
        if k < 3:
            ft = _fit_set(runs, baseline, sel + [c], prev=ffinal)
            name = f"effect:{c}"
            est = ft.value(name)
            se = ft.std(name) * np.sqrt(max(1.0, ft.chi2 / ft.dof))
            dchi = float(ffinal.chi2 - ft.chi2)
            sh = _shrink(g_after, gap_rms(ft.z, ft.dof / N))
            shh = _shrink(ho_after, heldout_gap(ft))
        else:
            jp = proj_final[c]
            n2 = float(jp @ jp)
            est = float(jp @ ffinal.z / n2)
            se = float(1 / np.sqrt(n2))
            dchi, sh, shh = rest_scores[c], None, None
        ranking.append({"effect": c, "estimate": est, "std_uncertainty": float(se), "unit": EFFECTS[c].unit,
                        "z": est / se if se > 0 else None, "delta_chi2": dchi, "significant": False,
                        "shrink_in_sample": sh, "shrink_heldout": shh, "observable": True,
                        **_obsfields(obs[c]), "aliases": []})
    unobservable = []
    for c in cands:
        if obs[c]["observable"]:
            continue
        entry = {"effect": c, "estimate": None, "std_uncertainty": None, "unit": EFFECTS[c].unit,
                 "z": None, "delta_chi2": None, "significant": False, "shrink_in_sample": None,
                 "shrink_heldout": None, "observable": False, **_obsfields(obs[c]), "aliases": []}
        if obs[c]["applies"]:
            entry["absorbed_by"] = _absorbed_by(f0, sig0[c])
            entry["note"] = (f"not observable in these runs: {100 * entry['absorbed_fraction']:.4f} % of its "
                             f"signature is absorbed by the fitted " + ", ".join(
                                 a["group"] for a in entry["absorbed_by"][:2]))
        else:
            entry["note"] = "no run of a test kind it applies to"
        ranking.append(entry)
        unobservable.append(entry)

    # --- aliases (projected signatures, |cos| > 0.95) incl. non-catalogue coefficients
    keys = [c for c in proj_final if np.linalg.norm(proj_final[c]) > 0]
    for e in ranking:
        c = e["effect"]
        if c not in proj_final:
            continue
        a = proj_final[c]
        na = np.linalg.norm(a)
        for d in keys:
            if d == c:
                continue
            b = proj_final[d]
            cs = float(a @ b / (na * np.linalg.norm(b)))
            if abs(cs) > ALIAS_COS:
                e["aliases"].append(d)
                e.setdefault("alias_cos", {})[d] = cs
    if sel:
        Ubase = _basis(f0.J)
        ncs = _non_catalogue_signatures(f0)
        for e in ranking[:len(sel)]:
            a = _perp(Ubase, sig0[e["effect"]])
            for cname, v in ncs.items():
                b = _perp(Ubase, v)
                nb = np.linalg.norm(b)
                if nb > 0 and abs(float(a @ b) / (np.linalg.norm(a) * nb)) > ALIAS_COS:
                    e.setdefault("coefficient_aliases", []).append(
                        {"coefficient": cname, "note": "instrument coefficient, not a catalogue effect"})
        if separate:
            for e in ranking[:len(sel)]:
                if e["aliases"]:
                    e["separating_tests"] = {d: separating_tests(runs, baseline, sel, e["effect"], d, f0)
                                             for d in e["aliases"][:2]}

    verdict = sel[0] if sel else None
    # strict check of the mass-centre offset in transverse mounts (see model.py)
    notes = []
    if strict_check and any(u["effect"] == "mass_centre_offset" for u in unobservable):
        tr = [r for r in runs if r.test in CENTRIFUGES
              and abs(np.cos(np.radians(float(r.meta["mount_angle_deg"])))) < 0.1]
        if tr:
            fs0 = _fit_set(runs, baseline, sel, transverse_scale=False)
            fs1 = _fit_set(runs, baseline, sel + ["mass_centre_offset"], transverse_scale=False, prev=fs0)
            est = fs1.value("effect:mass_centre_offset")
            se = fs1.std("effect:mass_centre_offset") * np.sqrt(max(1.0, fs1.chi2 / fs1.dof))
            chk = {"effect": "mass_centre_offset", "transverse_runs": [r.run_id for r in tr],
                   "estimate": est, "std_uncertainty": float(se), "delta_chi2": float(fs0.chi2 - fs1.chi2),
                   "text": (f"The transverse mounts ({len(tr)} runs, cos phi = 0) do show it: there IA senses "
                            f"omega_z^2 * r, the same sign at both polarities, which no bias, scale or K2-like "
                            f"term of an IA mount produces. If the bare model kept no linear term in transverse "
                            f"mounts it would be found: r = {est * 1e3:.3f} +- {se * 1e3:.3f} mm "
                            f"(delta chi2 {fs0.chi2 - fs1.chi2:.3g}). With the per-run scale (radius) of the "
                            f"baseline it is absorbed, as in the IA 0/180 pair.")}
            for u in unobservable:
                if u["effect"] == "mass_centre_offset":
                    u["transverse_mount_check"] = chk
            notes.append(chk["text"])

    where = [{"dimension": r["dimension"], "segment": r["segment"], "share": r["share"],
              "chi2": r["chi2"], "expected": r["expected"], "p_holm": r["p_holm"], "significant": r["significant"]}
             for r in where_rows if r["significant"]]
    where.sort(key=lambda w: (-w["share"], w["dimension"]))
    K1s = {c: f0.value(f"K1[{c}]") for c in f0.model.camp_index}
    res_si = lambda f: _si_rms(f)  # noqa: E731
    out = {
        "verdict": verdict,
        "verdict_aliases": ranking[0]["aliases"] if sel else [],
        "selected": sel,
        "baseline": {"label": base_label, "effects": baseline,
                     "bare_model": "K1, K2 per campaign; K0 and scale (radius) per run; one K2-like c2 per "
                                   "centrifuge mount orientation; the head-plane cross term per tumble head; "
                                   "K0T, K1T with tilt_rotation runs; earth rate only if in the baseline"},
        "ranking": ranking,
        "unobservable": [{"effect": u["effect"], "absorbed_fraction": u["absorbed_fraction"],
                          "observable_fraction": u["observable_fraction"], "note": u.get("note", ""),
                          **({"transverse_mount_check": u["transverse_mount_check"]}
                             if "transverse_mount_check" in u else {})} for u in unobservable],
        "where": where,
        "where_all": where_rows,
        "gap": {"rms_before": float(np.sqrt(np.mean(z0 ** 2))), "rms_after": float(np.sqrt(np.mean(ffinal.z ** 2))),
                "noise_rms": float(np.sqrt(ffinal.dof / N)),
                "gap_rms_before": g_before, "gap_rms_after": g_after,
                "shrink_in_sample": _shrink(g_before, g_after),
                "heldout_gap_rms_before": ho_before, "heldout_gap_rms_after": ho_after,
                "shrink_heldout": _shrink(ho_before, ho_after),
                "units": "rms_* in units of the noise sigma of a cell mean (whitened); gap_rms = "
                         "sqrt(max(0, mean z^2 - expected noise))",
                "si": {"rms_before_m_s2": res_si(f0), "rms_after_m_s2": res_si(ffinal),
                       "noise_rms_m_s2": _si_noise(f0)},
                "chi2_before": f0.chi2, "dof_before": f0.dof, "chi2_after": ffinal.chi2, "dof_after": ffinal.dof},
        "selection_steps": steps,
        "alpha": alpha,
        "notes": notes,
        "runs": [{"run_id": r.run_id, "test": r.test, "campaign": r.campaign, "cells": r.ncell,
                  "noise_model": r.noise_note} for r in runs],
        "K1": K1s,
        "elapsed_s": None,
    }
    out["_fits"] = {"before": f0, "after": ffinal}
    out["elapsed_s"] = time.perf_counter() - t0
    return out


def _obsfields(o):
    return {"observable_fraction": o["observable_fraction"], "absorbed_fraction": o["absorbed_fraction"],
            "min_detectable": o.get("min_detectable")}


def _absorbed_by(f: Fit, j: np.ndarray):
    """Which groups of baseline parameters absorb a signature (share of its energy)."""
    m = f.model
    d, _, _ = lstsq_scaled(f.J, j)
    groups: dict[str, np.ndarray] = {}
    for i, q in enumerate(m.params):
        if d[i] != 0:
            groups.setdefault(q.group, np.zeros(m.N))
            groups[q.group] += f.J[:, i] * d[i]
    nj = float(j @ j)
    out = [{"group": g, "share": float(v @ j) / nj} for g, v in groups.items()]
    out.sort(key=lambda a: -abs(a["share"]))
    return [a for a in out if abs(a["share"]) > 1e-3]


def _si_rms(f: Fit) -> float:
    m = f.model
    res = []
    for j, r in enumerate(m.runs):
        K1 = abs(f.value(f"K1[{r.campaign}]")) or 1.0
        res.append(f.z[m.run_rows(j)] * m.sig[m.run_rows(j)] / K1)
    return float(np.sqrt(np.mean(np.concatenate(res) ** 2)))


def _si_noise(f: Fit) -> float:
    m = f.model
    res = []
    for j, r in enumerate(m.runs):
        K1 = abs(f.value(f"K1[{r.campaign}]")) or 1.0
        res.append(m.sig[m.run_rows(j)] / K1)
    return float(np.sqrt(np.mean(np.concatenate(res) ** 2)))


def public(result: dict) -> dict:
    """The JSON-able part of a diagnosis."""
    return {k: v for k, v in result.items() if not k.startswith("_")}

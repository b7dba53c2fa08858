"""process_campaign: all the science of one campaign, as plain functions.

Order of work (paper 000 §2–3, paper 003, paper 001, paper 002):
tumble (K0, K1, K2, theta0) -> test radii (static eq 4–6 and iterative eq 7, orders
1–3, g ranges) with their adequacy -> mount-pair fits (eq 9) -> combination (eq 2/3)
-> alignment (§2.2, eq 8) -> GUM budgets with a Monte Carlo check (§3.2, JCGM 101);
thermal runs (paper 001) and sinusoidal-centrifuge campaigns (paper 002) likewise.
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping

import numpy as np

from ..constants import G_STANDARD
from ..physics.axes import parse_plane, parse_signed_axis
from ..results import AdequacyResult, BudgetTerm, CampaignResult, CoefficientResult, RadiusResult
from . import uncertainty as unc
from .adequacy import choose_order
from .crosscoupling import (CROSS, SQUARE, combine_second_order, delta_c2, fit_mount_pair,
                            pair_key, pair_label)
from .radius import (PairData, g_levels, geometric_static_radius, ia_polarity, test_radius_iterative,
                     test_radius_static)

#: g ranges of the radius table, in g (paper 000 Table 2), plus the full range.
RADIUS_RANGES = (7.0, 14.0, 25.0)
RADIUS_ORDERS = (1, 2, 3)
SECOND_ORDER_UNIT = "s2/m"
#: Fixture mount-angle tolerance (rad) behind the type-B eq 8 term: an angle error common
#: to both polarities does not cancel (constants.MOUNT_ANGLE_TOLERANCE_RAD, 1 arc-minute).
from ..constants import MOUNT_ANGLE_TOLERANCE_RAD  # noqa: E402


def _meta(run) -> Mapping:
    return run.meta


def _out_unit(meta: Mapping) -> str:
    return f"{meta.get('output_unit', 'out')}/(m/s2)"


# ------------------------------------------------------------------ tumble

def _process_tumble(runs, res: CampaignResult) -> dict | None:
    """Fit every tumble run (paper 003); return the K0, K1 (and u) used downstream."""
    from .tumble import fit_tumble, separable_extra_terms, tumble_coefficients, two_position
    fits = []
    for run in runs:
        try:
            fit = fit_tumble(run.meta, run.data)
        except Exception as exc:  # a fit that cannot run is a flag, not a crash
            res.flags.append(f"tumble {run.meta.get('run_id')}: fit failed: {exc}")
            continue
        lof = fit.lack_of_fit
        if lof and lof["p"] < 0.01:
            # model adequacy: add the IA cross term with the other in-plane axis (separable
            # from theta0 in one tumble, paper 003) and keep it if it cures the misfit
            cross = tuple(k for k in separable_extra_terms(run.meta) if k in ("Kio", "Kip"))
            try:
                fit2 = fit_tumble(run.meta, run.data, cross)
            except Exception:
                fit2 = None
            if fit2 is not None and fit2.lack_of_fit and fit2.lack_of_fit["p"] > lof["p"]:
                res.extras.setdefault("tumble_model_choice", []).append({
                    "run_id": run.meta.get("run_id"), "basic_lof_p": lof["p"], "extended_terms": list(cross),
                    "extended_lof_p": fit2.lack_of_fit["p"]})
                fit = fit2
            if fit.lack_of_fit and fit.lack_of_fit["p"] < 0.01:
                res.flags.append(f"tumble {run.meta.get('run_id')}: model inadequate (lack-of-fit "
                                 f"p = {fit.lack_of_fit['p']:.2g}); used and flagged")
        fits.append((run, fit))
        tp = {}
        try:
            tp = two_position(run.meta, run.data)
        except Exception as exc:
            tp = {"error": str(exc)}
        res.extras.setdefault("tumble", []).append({
            "run_id": run.meta.get("run_id"), "values": fit.values, "std": fit.std_uncertainties,
            "residual_rms": fit.residual_rms, "dof": fit.dof, "lack_of_fit": fit.lack_of_fit,
            "two_position": tp, "note": fit.note})
    if not fits:
        return None
    # inverse-variance mean over the tumble runs of the campaign
    keys = ("K0", "K1", "K2", "theta0")
    comb = {}
    for k in keys:
        v = np.array([f.values[k] for _, f in fits])
        u = np.array([f.std_uncertainties[k] for _, f in fits])
        w = 1 / np.maximum(u, 1e-300) ** 2
        comb[k] = (float(np.sum(w * v) / np.sum(w)), float(1 / math.sqrt(np.sum(w))))
    run0, fit0 = fits[0]
    rig = str(run0.meta.get("rig_id", ""))
    if len(fits) == 1:
        res.coefficients += tumble_coefficients(fit0, rig)
    else:
        units = {"K0": "m/s2", "K1": _out_unit(run0.meta), "K2": SECOND_ORDER_UNIT, "theta0": "rad"}
        for k in keys:
            res.coefficients.append(CoefficientResult(
                k, comb[k][0], comb[k][1], units[k], "tumble_lm", rig,
                note=f"inverse-variance mean of {len(fits)} tumble runs"))
    return {"K0": comb["K0"][0], "u_K0": comb["K0"][1], "K1": comb["K1"][0], "u_K1": comb["K1"][1],
            "K2": comb["K2"][0], "u_K2": comb["K2"][1]}


# ------------------------------------------------------------------ centrifuge

def _centrifuge_rig(runs, tumble: dict | None, res: CampaignResult) -> None:
    """Radius, adequacy, mount pairs, combination and budgets for the runs of one rig."""
    rig = str(runs[0].meta.get("rig_id", ""))
    by_key = defaultdict(dict)
    for run in runs:
        plane, phi = pair_key(run.meta)
        pol = 1 if float(run.meta["mount_angle_deg"]) % 360.0 < 180.0 else -1
        by_key[(plane, phi)][pol] = run       # newest revision wins upstream
    ia_key = next((k for k, v in by_key.items() if 1 in v and -1 in v and ia_polarity(v[1].meta) is not None), None)
    if ia_key is None:
        res.flags.append(f"{rig}: no IA mount pair (phi = 0/180 deg): test radius and K2 cannot be determined")
        return
    run_p, run_m = by_key[ia_key][1], by_key[ia_key][-1]
    if ia_polarity(run_p.meta) < 0:
        run_p, run_m = run_m, run_p
    if tumble is None:
        res.flags.append(f"{rig}: no tumble run in the campaign: K1, K0 taken from the centrifuge at the "
                         "nominal arm radius; the radius is then not independent")
        pair0 = PairData.from_runs([(run_p.meta, run_p.data, 1), (run_m.meta, run_m.data, -1)], 1.0)
        R0 = float(run_p.meta["arm_radius_m"])
        f, _ = pair0.fit(pair0.inputs(R0), 3, subtract_a=False)
        K1 = 0.5 * (f.value("b+") + f.value("b-"))
        tumble = {"K0": 0.5 * (f.value("K0+") + f.value("K0-")) / K1, "u_K0": 0.0, "K1": K1,
                  "u_K1": 0.0, "K2": 0.0, "u_K2": 0.0}
    K0, K1, uK0, uK1 = tumble["K0"], tumble["K1"], tumble["u_K0"], tumble["u_K1"]

    # --- static back-calculation (eq 4-6)
    static = {}
    for run in (run_p, run_m):
        try:
            s = test_radius_static(run.meta, run.data, K0, K1, uK0, uK1)
            static[s.polarity] = s
            res.radii.append(RadiusResult(rig, s.polarity, "static", None, 1.0, s.radius_m, s.std_uncertainty_m,
                                          note=f"eq 6; printed-form u = {s.std_uncertainty_printed_m:.3e} m"))
        except Exception as exc:
            res.flags.append(f"{rig}: static radius of {run.meta.get('run_id')} failed: {exc}")
    arm = float(run_p.meta["arm_radius_m"])
    R0p = static["+"].radius_m if "+" in static else arm
    R0m = static["-"].radius_m if "-" in static else arm
    res.alignment.append({"kind": "lambda_c", "rig_id": rig,
                          **{f"lambda_c{p}": s.lambda_c_rad for p, s in static.items()},
                          **{f"u_lambda_c{p}": s.u_lambda_c_rad for p, s in static.items()}})
    res.extras.setdefault("static_radius", {})[rig] = {
        p: {"radius_m": s.radius_m, "u_gum_m": s.std_uncertainty_m, "u_printed_m": s.std_uncertainty_printed_m,
            "lambda_c_rad": s.lambda_c_rad, "omega_g": s.omega_g, "a_g": s.a_g, "budget": s.budget}
        for p, s in static.items()}

    # --- iterative regression (eq 7) for orders and g ranges, each with its adequacy
    pair = PairData.from_runs([(run_p.meta, run_p.data, 1), (run_m.meta, run_m.data, -1)], K1)
    levels = g_levels(pair, R0p, R0m)
    top = max(levels) if levels else None
    ranges = [r for r in RADIUS_RANGES if levels and r < top * 0.98 and sum(lv <= r * 1.02 for lv in levels) >= 4]
    ranges.append(None)
    fits = {}
    label = f"radius {ia_key[0]} {ia_key[1]:g}/{ia_key[1] + 180:g}"
    for order in RADIUS_ORDERS:
        for gr in ranges:
            it = test_radius_iterative(pair, R0p, R0m, order, gr, uK1 / abs(K1))
            fits[(order, gr)] = it
            gmax = top if gr is None else gr
            for pol, R, u in (("+", it.R_plus, it.u_plus), ("-", it.R_minus, it.u_minus)):
                res.radii.append(RadiusResult(rig, pol, "iterative", order, gmax, R, u))
            f = it.fit
            res.adequacy.append(AdequacyResult(rig, label, order, gmax, f.f_statistic, f.p_value, f.dof_lof,
                                               f.dof_pe, f.trend_p, f.sweep_p, f.runs_p, f.adequate))
    chosen, ok = choose_order({o: fits[(o, None)].fit for o in RADIUS_ORDERS},
                              {2: ["c2", "d"], 3: ["c3"]})
    if not ok:
        res.flags.append(f"{rig}: no radius model order is adequate over the full range (lack-of-fit or "
                         f"residual checks fail); order {chosen} used and flagged")
    for a in res.adequacy:
        if a.fit == label and a.rig_id == rig and a.model_order == chosen and a.g_max == top:
            a.chosen = True
    best = fits[(chosen, None)]
    Rp, Rm = best.R_plus, best.R_minus

    # --- mount pairs (eq 9) and their combination (eq 2/3)
    pairs = []
    for key, runs_k in sorted(by_key.items()):
        if 1 not in runs_k or -1 not in runs_k:
            res.flags.append(f"{rig}: mount {key[0]} {key[1]:g} has one polarity only; not used")
            continue
        a, b = runs_k[1], runs_k[-1]
        pf = fit_mount_pair((a.meta, a.data), (b.meta, b.data), K1, Rp, Rm)
        pairs.append(pf)
        f = pf.fit
        for order, fo in pf.fits.items():
            res.adequacy.append(AdequacyResult(rig, f"eq9 {pair_label(pf)}", order, top, fo.f_statistic,
                                               fo.p_value, fo.dof_lof, fo.dof_pe, fo.trend_p, fo.sweep_p,
                                               fo.runs_p, fo.adequate, chosen=(order == pf.order)))
        if not pf.adequate:
            res.flags.append(f"{rig}: eq 9 fit of {pair_label(pf)} is not adequate at any order; used and flagged")
    # first pass without type-B terms to get the K's for eq 8, then with them
    comb0 = combine_second_order(pairs)
    u_dc2 = {}
    for pf in pairs:
        g = pf.geometry
        d1 = delta_c2(comb0.values, pf.plane, math.radians(pf.phi0_deg), g.dphi1)
        d2 = delta_c2(comb0.values, pf.plane, math.radians(pf.phi0_deg + 180), g.dphi2)
        # The two polarities' angle errors from the mass-centre offset are opposite, so
        # their eq 8 errors cancel in the pair's common c2 to first order; what is left is
        # (d1 + d2)/2, plus eq 8 for an unknown mount-angle error common to both polarities
        # (fixture tolerance).  Type B, uniform.  The paper's bound max|d| is kept for reference.
        tol = delta_c2(comb0.values, pf.plane, math.radians(pf.phi0_deg), MOUNT_ANGLE_TOLERANCE_RAD)
        half = abs(d1 + d2) / 2 + abs(tol)
        u_dc2[pair_label(pf)] = unc.uniform_u(half)
        res.alignment.append({"kind": "mount", "rig_id": rig, "pair": pair_label(pf), **g.as_dict(),
                              "dc2_1": d1, "dc2_2": d2, "u_dc2_typeB": u_dc2[pair_label(pf)],
                              "dc2_paper_bound": max(abs(d1), abs(d2)), "dc2_tolerance": tol,
                              "c2": pf.c2, "u_c2": pf.u_c2, "order": pf.order})
    comb = combine_second_order(pairs, u_dc2)
    res.extras.setdefault("pairs", {})[rig] = [
        {"pair": pair_label(p), "runs": list(p.run_ids), "order": p.order, "adequate": p.adequate,
         "c2": p.c2, "u_c2": p.u_c2, "d": p.d, "u_d": p.u_d, "c3": p.c3, "u_c3": p.u_c3,
         "noise_s0": p.fit.extra.get("noise_s0"), "noise_k": p.fit.extra.get("noise_k"),
         "dwells": p.dwells[["run_id", "pol", "a", "mean_output", "n", "time_mid", "sweep", "std_resid"]]
         .to_dict(orient="list")} for p in pairs]
    res.extras.setdefault("combination", {})[rig] = comb.design

    for name, value in comb.values.items():
        sens = comb.sensitivities[name]
        names, vals, us, dists, types, cs = [], [], [], [], [], []
        for lab, s in sens.items():
            p = next(p for p in pairs if pair_label(p) == lab)
            names += [f"c2({lab})", f"dc2({lab})"]
            vals += [p.c2, 0.0]
            us += [p.u_c2, u_dc2.get(lab, 0.0)]
            dists += ["normal", "uniform"]
            types += ["A", "B"]
            cs += [s, s]
        keep = [i for i, u in enumerate(us) if u > 0]
        names = [names[i] for i in keep]
        vals = [vals[i] for i in keep]
        us = [us[i] for i in keep]
        dists = [dists[i] for i in keep]
        types = [types[i] for i in keep]
        cs = np.array([cs[i] for i in keep])

        def lin(*x, _c=cs):
            return sum(ci * xi for ci, xi in zip(_c, x))

        gb = unc.gum_budget(lin, names, vals, us, dists, types, name, sensitivities=cs)
        check = unc.validate_gum_with_mc(lin, names, vals, us, dists, n=50_000, seed=12345, sensitivities=cs)
        res.budget += gb.terms
        res.coefficients.append(CoefficientResult(
            name, float(value), float(gb.u_c), SECOND_ORDER_UNIT, "centrifuge_eq9", rig,
            note=(f"eq 2/3 over {len(sens)} mount pair(s); GUM u with type-B eq 8 terms; "
                  f"JCGM 101 MC u = {check['mc'].std:.3e}, validated={check['validated']}")))
        res.extras.setdefault("mc_check", {})[f"centrifuge_eq9:{rig}:{name}"] = {
            "method": "centrifuge_eq9", "rig_id": rig, "coefficient": name, "gum_u": gb.u_c, "mc_u": check["mc"].std, "mc_low": check["mc"].low, "mc_high": check["mc"].high,
            "validated": check["validated"], "delta": check["delta"]}
    # eq 10 as printed vs GUM, for Kip from the 45 deg pair
    kip_pair = next((p for p in pairs if {parse_plane(p.plane)[0], parse_plane(p.plane)[1]} == {0, 1}
                     and abs(p.phi0_deg - 45) < 1e-6), None)
    kpp_pair = next((p for p in pairs if {parse_plane(p.plane)[0], parse_plane(p.plane)[1]} == {0, 1}
                     and abs(p.phi0_deg - 90) < 1e-6), None)
    if kip_pair is not None and "Kip" in comb.values:
        ku = unc.kip_uncertainty(kip_pair.u_c2, u_dc2.get(pair_label(kip_pair), 0.0), comb.std.get("K2", 0.0),
                                 kpp_pair.u_c2 if kpp_pair else 0.0,
                                 u_dc2.get(pair_label(kpp_pair), 0.0) if kpp_pair else 0.0)
        res.extras.setdefault("eq10", {})[rig] = {"printed": ku["printed"], "gum": ku["gum"],
                                                  "differ": ku["differ"], "ratio": ku["ratio"]}
        if ku["differ"]:
            res.flags.append(f"{rig}: u(Kip) by eq 10 as printed is {ku['printed']:.3e}, by the GUM "
                             f"{ku['gum']:.3e} s2/m (the printed factor 2 on u(c2) should be 4); GUM stored")

    # --- odd quadratic and cubic from the IA pair (eq 9), per-polarity bias and scale
    ia = next(p for p in pairs if pair_key(run_p.meta) == (p.plane, p.phi0_deg))
    res.coefficients.append(CoefficientResult("Koq", ia.d, ia.u_d, SECOND_ORDER_UNIT, "centrifuge_eq9", rig,
                                              note="odd quadratic of the IA pair (eq 9)"))
    if ia.c3 is not None:
        res.coefficients.append(CoefficientResult("K3", ia.c3, ia.u_c3, "s4/m2", "centrifuge_eq9", rig,
                                                  note="cubic of the IA pair (eq 9), order-3 model chosen"))
    f = ia.fit
    res.extras.setdefault("polarity_terms", {})[rig] = {
        k: {"value": f.value(k), "u": f.std_error(k)} for k in ("K0+", "K0-", "b+", "b-")}

    # --- radii corrected for the instrument terms: the geometric distance of the mass centre
    vert, vsign = parse_signed_axis(run_p.meta["vertical_axis"])
    g = float(run_p.meta["g_local_m_s2"])
    cross = CROSS.get(frozenset((0, vert)))
    Kiv = comb.values.get(cross, 0.0) if cross else 0.0
    uKiv = comb.std.get(cross, 0.0) if cross else 0.0
    scale = 1.0 + Kiv * vsign * g
    for pol, R, u in (("+", Rp, best.u_plus), ("-", Rm, best.u_minus)):
        Rc = R / scale
        uc = math.hypot(u, R * g * uKiv)
        res.radii.append(RadiusResult(rig, pol, "iterative_corrected", chosen, top, Rc, uc,
                                      note=f"eq 7 radius / (1 + {cross}·a_vertical): cross-coupling with gravity removed"))
    K2c = comb.values.get("K2", tumble["K2"])
    # The paper's radii (eq 6 and eq 7) are effective radii: the instrument's own terms at
    # the reference acceleration leak into them.  Paper 000 §2.1.1 bounds that by the
    # nonlinearity envelope; we state it as a type-B (uniform) term: half-width R |K_iv| g
    # for eq 7 (the cross-coupling with gravity, which no order of eq 7 can absorb) and
    # R (|K2| + |Koq|) |a_g| + R |K_iv| g for eq 6 (which models no nonlinearity at all).
    for r in res.radii:
        if r.rig_id != rig or r.method not in ("static", "iterative"):
            continue
        half = r.radius_m * abs(Kiv) * g
        if r.method == "static":
            half += r.radius_m * (abs(K2c) + abs(ia.d)) * g
        uB = unc.uniform_u(half)
        r.std_uncertainty_m = math.hypot(r.std_uncertainty_m, uB)
        r.note = (r.note + "; " if r.note else "") + (
            f"includes type-B {uB:.2e} m (uniform) for instrument terms the method leaves in the radius")
    for pol, s in static.items():
        # the radius at which the forward model, with K2, Koq, K3 and the IA cross term with
        # gravity, reproduces the measured input of eq 6
        coeffs = {"K2": K2c, "Koq": ia.d, "K3": ia.c3 or 0.0, **({cross: Kiv} if cross else {})}
        Rc = geometric_static_radius((run_p if pol == "+" else run_m).meta, s, coeffs)
        res.radii.append(RadiusResult(rig, pol, "static_corrected", None, 1.0, Rc,
                                      math.hypot(s.std_uncertainty_m, s.radius_m * g * uKiv),
                                      note="eq 6 radius with K2, Koq, K3 and the cross-coupling with gravity removed"))


# ------------------------------------------------------------------ entry point

def process_campaign(runs) -> CampaignResult:
    """Run every estimator that applies to the runs of one campaign (docs/design.md).
    runs: RunFile-like objects with .meta, .data, .sha256 (newest revision of each run_id)."""
    first = runs[0]
    res = CampaignResult(
        campaign=str(first.meta["campaign"]), unit_serial=str(first.meta["unit_serial"]),
        unit_model=str(first.meta.get("unit_model", "")),
        tests=sorted({str(r.meta["test"]) for r in runs}),
        rig_ids=sorted({str(r.meta["rig_id"]) for r in runs}),
        input_sha256=sorted(r.sha256 for r in runs),
        parameters={"radius_orders": list(RADIUS_ORDERS), "radius_ranges_g": list(RADIUS_RANGES),
                    "adequacy_alpha": 0.01, "coverage_factor": 2.0,
                    "mount_angle_tolerance_rad": MOUNT_ANGLE_TOLERANCE_RAD})
    by_test = defaultdict(list)
    for r in sorted(runs, key=lambda r: str(r.meta.get("run_id"))):
        by_test[str(r.meta["test"])].append(r)
    tumble = _process_tumble(by_test["tumble"], res) if by_test.get("tumble") else None
    if by_test.get("centrifuge"):
        by_rig = defaultdict(list)
        for r in by_test["centrifuge"]:
            by_rig[str(r.meta["rig_id"])].append(r)
        for rig_runs in by_rig.values():
            try:
                _centrifuge_rig(rig_runs, tumble, res)
            except Exception as exc:  # never lose the rest of the campaign
                res.flags.append(f"centrifuge {rig_runs[0].meta.get('rig_id')}: processing failed: "
                                 f"{type(exc).__name__}: {exc}")
    if tumble is not None:
        _correct_tumble_K2(by_test["tumble"][0].meta, res)
        _correct_tumble_K1(by_test["tumble"][0].meta, res)
    if by_test.get("tilt_rotation"):
        _thermal(by_test["tilt_rotation"], res)
    if by_test.get("sine_centrifuge"):
        _sine(by_test["sine_centrifuge"], res)
    _joint(runs, res)
    _mark_adopted(res)
    _assess_completeness(res)
    return res


def _joint(runs, res: CampaignResult) -> None:
    """The adopted values: the joint fit of every reading through the forward model
    (:mod:`accelcal.estimators.joint`), compared with the paper methods' values."""
    from . import joint
    try:
        out = joint.campaign_results(sorted(runs, key=lambda r: str(r.meta.get("run_id"))))
    except Exception as exc:  # the paper methods' values stay; the failure is a flag
        res.flags.append(f"joint fit failed ({type(exc).__name__}: {exc}); the paper methods' values are "
                         "adopted instead")
        return
    others = list(res.coefficients)
    res.coefficients += out["coefficients"]
    res.radii += out["radii"]
    res.adequacy += out["adequacy"]
    res.budget += out["budget"]
    res.alignment += out["alignment"]
    res.flags += out["flags"]
    rows, flags = joint.compare_with_methods(out["coefficients"], others, runs)
    res.flags += flags
    res.extras["joint"] = {**out["extras"], "method_comparison": rows}
    res.extras.setdefault("mc_check", {}).update(out["mc_check"])
    res.parameters["joint_effects"] = out["extras"]["effects"]


#: Which method's value is adopted when several give the same coefficient: the joint fit
#: (issue 9); the paper methods only when the joint fit could not run.
ADOPTION_ORDER = ("joint_ml", "centrifuge_eq9", "sine_ls", "tilt_rotation_ls",
                  "tilt_rotation_two_position", "tumble_lm")


def _mark_adopted(res: CampaignResult) -> None:
    """One adopted value per coefficient: the first method of ADOPTION_ORDER."""
    rank = {m: i for i, m in enumerate(ADOPTION_ORDER)}
    best: dict[str, CoefficientResult] = {}
    if any(c.method == "joint_ml" for c in res.coefficients):
        # the joint fit ran: its values are the calibration (theta0 per head included);
        # a paper method's coefficient it does not report is a cross-check only
        for c in res.coefficients:
            c.adopted = c.method == "joint_ml"
        return
    for c in res.coefficients:
        b = best.get(c.name)
        if b is None or rank.get(c.method, 99) < rank.get(b.method, 99):
            best[c.name] = c
    for c in res.coefficients:
        c.adopted = c is best.get(c.name)


def _assess_completeness(res: CampaignResult) -> None:
    """'incomplete' when no coefficient could be determined, or when every tumble fit of a
    tumble-only campaign has no degrees of freedom left to test the model (interim rule)."""
    reasons = []
    if not res.coefficients:
        reasons.append("no coefficient could be determined from these runs")
    lof = res.extras.get("joint", {}).get("lack_of_fit", {})
    if lof.get("status") == "untestable":
        reasons.append("the runs leave no degrees of freedom to test the model of the joint fit "
                       "(as many parameters as distinct inputs)")
    elif not lof and res.tests == ["tumble"]:
        fits = res.extras.get("tumble", [])
        if fits and all(not f.get("lack_of_fit") for f in fits):
            reasons.append("every tumble run has as many head positions as fitted parameters: "
                           "no degrees of freedom to test the model")
    if any("no IA mount pair" in f for f in res.flags):
        reasons.append("no IA mount pair: test radius and K2 cannot be determined")
    res.completeness = "incomplete" if reasons else "complete"
    res.completeness_reasons = reasons


def _correct_tumble_K2(meta: Mapping, res: CampaignResult) -> None:
    """One tumble measures K2 − K_ss, K_ss the square term of the other in-plane axis
    (Koo when OA turns in the vertical plane): K_ss g^2 sin^2 = K_ss g^2 − K_ss g^2 cos^2
    (paper 003 model with effects.md terms).  Add the centrifuge's K_ss when there is one."""
    axes = {parse_signed_axis(meta[k])[0] for k in ("cos_axis", "sin_axis")} - {0}
    if len(axes) != 1:
        return
    other = SQUARE[axes.pop()]
    cen = next((c for c in res.coefficients if c.name == other and c.method == "centrifuge_eq9"), None)
    for c in res.coefficients:
        if c.name == "K2" and c.method == "tumble_lm":
            if cen is None:
                c.note = f"measures K2 − {other} (aliased in one tumble; no centrifuge {other} to correct it)"
            else:
                c.value += cen.value
                c.std_uncertainty = math.hypot(c.std_uncertainty, cen.std_uncertainty)
                c.note = (f"one tumble measures K2 − {other}; {other} = {cen.value:.3e} s2/m from the "
                          "centrifuge added")


def _correct_tumble_K1(meta: Mapping, res: CampaignResult) -> None:
    """The tumble's K1 fits the cos(psi) fundamental of the IA input, which Koq a|a| and
    K3 a^3 also feed: cos|cos| has fundamental 8/(3 pi), cos^3 has 3/4, so
    K1_fitted = K1 (1 + Koq g 8/(3 pi) + K3 g^2 3/4).  With the centrifuge's Koq and K3
    the tumble K1 is corrected (and its u widened by theirs); the geometric (*_corrected)
    radii, which scale as 1/K1, follow.  Without them K1 stays as fitted, said in the note."""
    g = float(meta["g_local_m_s2"])
    koq = next((c for c in res.coefficients if c.name == "Koq" and c.method == "centrifuge_eq9"), None)
    k3 = next((c for c in res.coefficients if c.name == "K3" and c.method == "centrifuge_eq9"), None)
    k1 = next((c for c in res.coefficients if c.name == "K1" and c.method == "tumble_lm"), None)
    if k1 is None:
        return
    if koq is None:
        k1.note = (k1.note + "; " if k1.note else "") + "includes Koq g 8/(3 pi) + K3 g^2 3/4 (no centrifuge values to remove it)"
        return
    a, b = g * 8 / (3 * math.pi), 0.75 * g * g
    delta = koq.value * a + (k3.value * b if k3 else 0.0)
    u_delta = math.hypot(koq.std_uncertainty * a, (k3.std_uncertainty * b) if k3 else 0.0)
    k1.value /= 1.0 + delta
    k1.std_uncertainty = math.hypot(k1.std_uncertainty, abs(k1.value) * u_delta)
    k1.note = (k1.note + "; " if k1.note else "") + (
        f"corrected for Koq and K3 from the centrifuge: fitted K1 = K1 (1 + {delta:.3e})")
    for r in res.radii:
        if r.method.endswith("_corrected"):
            r.radius_m *= 1.0 + delta
            r.std_uncertainty_m = math.hypot(r.std_uncertainty_m, r.radius_m * u_delta)


def _thermal(runs, res: CampaignResult) -> None:
    try:
        from .thermal import process_thermal_run
    except ImportError as exc:
        res.flags.append(f"thermal method unavailable: {exc}")
        return
    for run in runs:
        try:
            coeffs, extras = process_thermal_run(run.meta, run.data, str(run.meta.get("rig_id", "")))
        except Exception as exc:
            res.flags.append(f"tilt_rotation {run.meta.get('run_id')}: {type(exc).__name__}: {exc}")
            continue
        res.coefficients += coeffs
        res.extras.setdefault("thermal", {})[str(run.meta.get("run_id"))] = extras


def _sine(runs, res: CampaignResult) -> None:
    try:
        from .sinusoidal import process_sine_campaign
    except ImportError as exc:
        res.flags.append(f"sinusoidal method unavailable: {exc}")
        return
    by_rig = defaultdict(list)
    for r in runs:
        by_rig[str(r.meta.get("rig_id", ""))].append(r)
    for rig, rr in by_rig.items():
        try:
            coeffs, extras = process_sine_campaign([(r.meta, r.data) for r in rr], rig)
        except Exception as exc:
            res.flags.append(f"sine_centrifuge {rig}: {type(exc).__name__}: {exc}")
            continue
        res.coefficients += coeffs
        res.extras.setdefault("sine", {})[rig] = extras


__all__ = ["process_campaign", "G_STANDARD", "SQUARE", "BudgetTerm"]

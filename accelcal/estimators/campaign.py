"""process_campaign: all the science of one campaign, as plain functions.

Order of work (paper 000 §2–3, paper 003, paper 001, paper 002):
tumble (K0, K1, K2, theta0; runs pooled with the Birge ratio, theta0 per head) -> per
centrifuge rig the pure steps of :mod:`accelcal.estimators.centrifuge` (test radii by eqs 4–6
and eq 7 with their adequacy, mount pairs by eq 9, combination by eq 2/3 with the eq 8
alignment terms, GUM budgets with a JCGM 101 check, corrected radii) -> the tumble's K2 and K1
corrected with the centrifuge's square terms, Koq and K3 -> thermal runs (paper 001) and
sinusoidal-centrifuge campaigns (paper 002) -> the adopted values of the joint fit
(:mod:`accelcal.estimators.joint`).  Every step returns typed results; the records of a
:class:`~accelcal.results.CampaignResult` are built once, from them.
"""
from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

from ..constants import G_STANDARD, MOUNT_ANGLE_TOLERANCE_RAD
from ..results import BudgetTerm, CampaignResult, CoefficientResult
from .centrifuge import RADIUS_ORDERS, RADIUS_RANGES, Reference, RigOutcome, process_rig, rig_records
from .crosscoupling import SQUARE
from .records import Records
from .tumble import TumbleRun, fit_tumble_run, k1_correction, pool_runs, pooling_flags, tumble_records


# ------------------------------------------------------------------ tumble (paper 003)

@dataclass(frozen=True)
class TumbleStep:
    """The campaign's tumble runs, fitted and pooled (:func:`tumble_step`).

    Attributes
    ----------
    runs : tuple of TumbleRun
    pooled : dict
        Record name -> :class:`.tumble.Pooled`.
    flags : tuple of str
    """
    runs: tuple[TumbleRun, ...]
    pooled: dict
    flags: tuple[str, ...]

    @property
    def reference(self) -> Reference:
        """K0, K1 (pooled over the runs, as fitted) and K2 for the centrifuge radius."""
        k2 = next(q for q in self.pooled.values() if q.key == "K2")
        K0, K1 = self.pooled["K0"], self.pooled["K1"]
        return Reference(K0.value, K1.value, K0.u, K1.u, k2.value, k2.u)

    @property
    def g(self) -> float:
        return float(self.runs[0].fit.g_local_m_s2)


def tumble_step(runs: Sequence) -> TumbleStep | None:
    """The campaign's tumble runs (Zhan & Cai, paper 003).

    Parameters
    ----------
    runs : sequence
        RunFile-like tumble runs.

    Returns
    -------
    TumbleStep or None
        Every run fitted (:func:`.tumble.fit_tumble_run`) and pooled
        (:func:`.tumble.pool_runs`: weighted means with the Birge ratio applied and a flag
        when the runs disagree; K2 and theta0 per head axis); None when no run could be fitted.
    """
    fitted, flags = [], []
    for run in runs:
        try:
            tr = fit_tumble_run(run.meta, run.data)
        except Exception as exc:  # a fit that cannot run is a flag, not a crash
            flags.append(f"tumble {run.meta.get('run_id')}: fit failed: {exc}")
            continue
        fitted.append(tr)
        flags += tr.flags
    if not fitted:
        return None
    pooled = pool_runs(fitted)
    return TumbleStep(tuple(fitted), pooled, tuple(flags + pooling_flags(pooled)))


def _tumble_extras(step: TumbleStep) -> dict:
    out = {"tumble": [{"run_id": r.run_id, "values": r.fit.values, "std": r.fit.std_uncertainties,
                       "residual_rms": r.fit.residual_rms, "dof": r.fit.dof, "lack_of_fit": r.fit.lack_of_fit,
                       "adequacy": r.fit.adequacy.status if r.fit.adequacy else None,
                       "two_position": r.two_position, "note": r.fit.note} for r in step.runs]}
    choices = [r.model_choice for r in step.runs if r.model_choice]
    if choices:
        out["tumble_model_choice"] = choices
    if len(step.runs) > 1:
        out["tumble_pooling"] = {n: {"value": q.value, "u": q.u, "u_internal": q.u_internal, "birge": q.birge,
                                     "p": q.p_value, "disagree": q.disagree,
                                     "runs": [r.run_id for r in q.runs]} for n, q in step.pooled.items()}
    return out


# ------------------------------------------------------------------ corrections between methods

def _square_terms(rigs: Sequence[RigOutcome]) -> dict[str, tuple[float, float]]:
    """Kpp, Koo (value, u) of the first rig that gives each: what one tumble aliases into K2."""
    out: dict[str, tuple[float, float]] = {}
    for rig in rigs:
        for name in SQUARE.values():
            c = rig.coefficient(name)
            if c is not None and name not in out:
                out[name] = (c.value, float(c.budget.u_c))
    return out


def _k1_correction(tumble: TumbleStep, rigs: Sequence[RigOutcome]) -> tuple[float, float] | None:
    """(delta, u_delta) of the tumble K1 from the first rig's Koq and K3 (.tumble.k1_correction)."""
    for rig in rigs:
        koq = rig.coefficient("Koq")
        if koq is not None:
            k3 = rig.coefficient("K3")
            return k1_correction(tumble.g, (koq.value, float(koq.budget.u_c)),
                                 (k3.value, float(k3.budget.u_c)) if k3 is not None else None)
    return None


# ------------------------------------------------------------------ entry point

def process_campaign(runs) -> CampaignResult:
    """Run every estimator that applies to the runs of one campaign (docs/design.md).

    Parameters
    ----------
    runs : sequence
        RunFile-like objects with .meta, .data, .sha256 (the newest revision of each run_id).

    Returns
    -------
    CampaignResult
        The paper methods' values (stored as cross-checks) and the adopted joint-fit values.
    """
    from ..fitting.blas import single_thread
    with single_thread():            # small dense algebra: one BLAS thread is the fast one
        return _process_campaign(runs)


def _process_campaign(runs) -> CampaignResult:
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

    tumble = tumble_step(by_test["tumble"]) if by_test.get("tumble") else None
    rigs, rig_flags = [], []
    by_rig = defaultdict(list)
    for r in by_test.get("centrifuge", []):
        by_rig[str(r.meta["rig_id"])].append(r)
    for rig_runs in by_rig.values():
        try:
            out = process_rig(rig_runs, tumble.reference if tumble is not None else None)
        except Exception as exc:  # never lose the rest of the campaign
            rig_flags.append(f"centrifuge {rig_runs[0].meta.get('rig_id')}: processing failed: "
                             f"{type(exc).__name__}: {exc}")
            continue
        if isinstance(out, RigOutcome):
            rigs.append(out)
        else:
            rig_flags += list(out)

    # records, built once from the steps' results
    k1 = _k1_correction(tumble, rigs) if tumble is not None else None
    if tumble is not None:
        coeffs, budget = tumble_records(tumble.pooled, square_terms=_square_terms(rigs), k1=k1, g=tumble.g,
                                        out_unit=str(by_test["tumble"][0].meta.get("output_unit", "out")))
        Records(coefficients=coeffs, budget=budget, extras=_tumble_extras(tumble),
                flags=list(tumble.flags)).checked().add_to(res)
    for out in rigs:
        rig_records(out, k1).checked().add_to(res)
    res.flags += rig_flags
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


def _thermal(runs, res: CampaignResult) -> None:
    """Paper 001 on every tilt_rotation run, with the GUM budgets of its coefficients."""
    try:
        from .thermal import budget_terms, process_thermal_run
    except ImportError as exc:
        res.flags.append(f"thermal method unavailable: {exc}")
        return
    for run in runs:
        try:
            coeffs, extras = process_thermal_run(run.meta, run.data, str(run.meta.get("rig_id", "")))
        except Exception as exc:
            res.flags.append(f"tilt_rotation {run.meta.get('run_id')}: {type(exc).__name__}: {exc}")
            continue
        Records(coefficients=coeffs, budget=budget_terms(coeffs, extras["temperature_model"]),
                extras={"thermal": {str(run.meta.get("run_id")): extras}}).checked().add_to(res)


def _sine(runs, res: CampaignResult) -> None:
    """Paper 002 on the sinusoidal-centrifuge runs of each rig, with the budgets."""
    try:
        from .sinusoidal import budget_terms, process_sine_campaign
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
        Records(coefficients=coeffs, budget=budget_terms(coeffs), extras={"sine": {rig: extras}}).checked().add_to(res)


__all__ = ["process_campaign", "tumble_step", "G_STANDARD", "SQUARE", "BudgetTerm", "CoefficientResult"]

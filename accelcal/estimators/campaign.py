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
from collections.abc import Mapping

from .. import memory
from ..fitting.blas import single_thread
from ..constants import MOUNT_ANGLE_TOLERANCE_RAD
from ..results import CampaignResult, CoefficientResult
from . import registry
from . import uncertainty as unc
from .records import Records
from .centrifuge import RADIUS_ORDERS, RADIUS_RANGES
from .joint import cells_kept
from .priors import apply_priors


# ------------------------------------------------------------------ entry point

@single_thread()                     # small dense algebra: one BLAS thread is the fast one
@cells_kept()                        # each run's cells built once for every fit of its runs
def process_campaign(runs, rig_uncertainty: Mapping[str, Mapping[str, float]] | None = None,
                     priors: Mapping[str, Mapping[str, Mapping[str, float]]] | None = None,
                     unit_priors: Mapping[str, Mapping[str, object]] | None = None) -> CampaignResult:
    """Run every estimator that applies to the runs of one campaign (docs/design.md).

    Parameters
    ----------
    runs : sequence
        RunFile-like objects with .meta, .data, .sha256 (the newest revision of each run_id).
    rig_uncertainty : mapping, optional
        Rig id -> :data:`~accelcal.effects.RIG_INPUTS` id -> the lab's stated standard
        uncertainty of that input [its unit] (accelcal.toml ``[rigs."ID"]``,
        :func:`accelcal.config.rig_uncertainties`): type-B terms of the budgets.  Inputs
        that enter and are not stated are left out, and a flag says which.
    priors : mapping, optional
        Unit model -> coefficient -> ``{"value", "u"}`` [SI] (accelcal.toml
        ``[prior."MODEL"]``, :func:`accelcal.config.priors`): what the lab knows of terms
        a design cannot see; an adopted combination whose every term has one becomes the
        quantity it names (:func:`accelcal.estimators.priors.apply_priors`).
    unit_priors : mapping, optional
        Coefficient -> ``{"value", "u" [SI], "source"}``: what the unit's own last
        calibration that determined each coefficient says of it
        (:func:`accelcal.warehouse.priors.unit_priors`); for a term it gives, it takes
        precedence over ``priors``.

    Returns
    -------
    CampaignResult
        The paper methods' values (stored as cross-checks) and the adopted joint-fit values.
    """
    stated = rig_uncertainty or {}
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
    if stated:
        res.parameters["rig_uncertainty"] = {rig: dict(v) for rig, v in sorted(stated.items())
                                             if rig in res.rig_ids}
    by_test = defaultdict(list)
    for r in sorted(runs, key=lambda r: str(r.meta.get("run_id"))):
        by_test[str(r.meta["test"])].append(r)

    # the paper methods, as the registry declares them: first passes, then records in order
    steps: dict = {"rig_uncertainty": stated}
    taken = {e.method: [r for t in e.tests for r in by_test.get(t, [])] for e in registry.estimators()}
    for est in registry.estimators():
        if taken[est.method] and est.prepare is not None:
            steps[est.method] = est.prepare(taken[est.method], steps)
    for est in registry.estimators():
        if taken[est.method]:
            records = est.records(taken[est.method], steps)
            unc.add_stated_g_local(est, taken[est.method], steps, records, stated)
            for rec in records:
                rec.add_to(res)
    if sum(r.n_rows if hasattr(r, "n_rows") else len(r.data) for r in runs) >= memory.BIG_ROWS:
        memory.give_back()     # what the paper methods freed, before the joint fit
    joint = _joint(runs, res, stated)
    _mark_adopted(res)
    model_priors = (priors or {}).get(res.unit_model) or {}
    if model_priors:
        res.parameters["priors"] = {k: dict(v) for k, v in sorted(model_priors.items())}
    toml = f'accelcal.toml [prior."{res.unit_model}"]'
    known = {**{t: {**v, "source": toml} for t, v in model_priors.items()}, **(unit_priors or {})}
    apply_priors(res, known)
    _assess_completeness(res, joint, steps)
    return res


def _joint(runs, res: CampaignResult, stated: Mapping[str, Mapping[str, float]]):
    """The adopted values: the joint fit of every reading through the forward model
    (:mod:`accelcal.estimators.joint`), compared with the paper methods' values; returns
    the joint fit (:class:`~accelcal.fitting.procedure.ModelFit`), None when it failed."""
    from . import joint
    try:
        out = joint.campaign_results(sorted(runs, key=lambda r: str(r.meta.get("run_id"))),
                                     rig_uncertainty=stated)
    except Exception as exc:  # the paper methods' values stay; the failure is a flag
        res.flags.append(f"joint fit failed ({type(exc).__name__}: {exc}); the paper methods' values are "
                         "adopted instead")
        return None
    rows, flags = joint.compare_with_methods(out["coefficients"], res.coefficients, runs)
    Records(coefficients=out["coefficients"], radii=out["radii"], adequacy=out["adequacy"], budget=out["budget"],
            alignment=out["alignment"], flags=out["flags"] + flags,
            extras={"joint": {**out["extras"], "method_comparison": rows}, "mc_check": out["mc_check"]}).add_to(res)
    res.parameters["joint_effects"] = out["extras"]["effects"]
    return out["fit"]


def _mark_adopted(res: CampaignResult) -> None:
    """One adopted value per coefficient: the joint fit's, or where it could not run the
    first method of :func:`.registry.adoption_order` (the paper methods in the order a
    value is adopted from them: paper 000, 002, 001, 003)."""
    rank = {m: i for i, m in enumerate(registry.adoption_order())}
    best: dict[str, CoefficientResult] = {}
    if any(c.method == registry.ADOPTED for c in res.coefficients):
        # the joint fit ran: its values are the calibration (theta0 per head included);
        # a paper method's coefficient it does not report is a cross-check only
        for c in res.coefficients:
            c.adopted = c.method == registry.ADOPTED
        return
    for c in res.coefficients:
        b = best.get(c.name)
        if b is None or rank.get(c.method, 99) < rank.get(b.method, 99):
            best[c.name] = c
    for c in res.coefficients:
        c.adopted = c is best.get(c.name)


def _assess_completeness(res: CampaignResult, joint=None, steps: Mapping | None = None) -> None:
    """'incomplete' when no coefficient could be determined, when the joint fit (``joint``, a
    :class:`~accelcal.fitting.procedure.ModelFit`) is untestable or, without one, every
    tumble fit of a tumble-only campaign (``steps``, the first passes) has no degrees of
    freedom left to test the model, or for what a paper method found (``Records.incomplete``:
    a rig without an IA mount pair)."""
    reasons = []
    if not res.coefficients:
        reasons.append("no coefficient could be determined from these runs")
    if joint is not None and joint.fit.lof.status == "untestable":
        reasons.append("the runs leave no degrees of freedom to test the model of the joint fit "
                       "(as many parameters as distinct inputs)")
    elif joint is None and res.tests == ["tumble"]:
        fits = [r for step in registry.prepared(steps or {}, "tumble") if step is not None for r in step.runs]
        if fits and all(r.result.lof.status == "untestable" for r in fits):
            reasons.append("every tumble run has as many head positions as fitted parameters: "
                           "no degrees of freedom to test the model")
    reasons += [r for r in res.completeness_reasons if r not in reasons]
    res.completeness = "incomplete" if reasons else "complete"
    res.completeness_reasons = reasons


__all__ = ["process_campaign", "CampaignResult", "CoefficientResult"]

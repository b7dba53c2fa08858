"""The results writer: a batch of computed campaigns, their lineage and detail rows
(coefficients, radii, adequacy, budget, alignment, flags), written column-wise inside one
transaction, with which result is current decided as one-at-a-time stores would."""
from __future__ import annotations

from .columnar import _cp, _insert, _nextvals
from .extras import write_extras
from .lineage import canonical_json


def write_results(con, items, code_version, params_json, flow_run_id,
                  checkpoint, extras_root, own_params=None) -> list[str]:
    """Store (CampaignResult, result_id, inputs) items on ``con``, inside the caller's
    transaction (:meth:`accelcal.warehouse.db.Warehouse.store_results`): the warehouse's
    state for the batch read in three set queries, the statuses decided in Python in
    order, every table one Arrow insert.  ``own_params`` maps a result_id to its own
    parameters JSON where it is not ``params_json``.  Returns each item's status."""
    if not items:
        return []
    camps = sorted({r.campaign for r, _, _ in items})
    current = dict(con.execute(
        "SELECT campaign, arg_max(result_id, seq) FROM result_activations "
        "WHERE list_contains(?, campaign) GROUP BY campaign", [camps]).fetchall())
    stored = {rid for (rid,) in con.execute(
        "SELECT result_id FROM results WHERE list_contains(?, result_id)",
        [sorted({rid for _, rid, _ in items})]).fetchall()}
    real = {u for (u,) in con.execute(
        "SELECT unit_serial FROM real_units WHERE list_contains(?, unit_serial)",
        [sorted({r.unit_serial for r, _, _ in items if r.unit_serial is not None})]).fetchall()}
    statuses: list[str] = []
    fresh: list[tuple] = []             # (result, result_id, inputs, simulated)
    activate: list[tuple[str, str]] = []
    for result, rid, inputs in items:
        simulated = any(bool(i.get("simulated")) for i in inputs)
        if current.get(result.campaign) == rid:
            statuses.append("unchanged")
            continue
        exists = rid in stored
        if not exists:
            stored.add(rid)
            fresh.append((result, rid, inputs, simulated))
            if not simulated and _completeness(result) == "complete":
                real.add(result.unit_serial)
        if simulated and result.unit_serial in real:
            statuses.append("simulated-not-current")
            continue
        activate.append((result.campaign, rid))
        current[result.campaign] = rid
        statuses.append("reactivated" if exists else "new")
    if fresh:
        _insert_results(con, fresh, code_version, params_json, flow_run_id, checkpoint,
                        extras_root, own_params or {})
    if activate:
        _cp(checkpoint, "activate")
        _insert(con, "result_activations", {
            "seq": _nextvals(con, "activation_seq", len(activate)),
            "campaign": [c for c, _ in activate],
            "result_id": [r for _, r in activate],
            "activated_at": None,
            "flow_run_id": [flow_run_id] * len(activate)})
        _cp(checkpoint, "commit")
    return statuses


def _completeness(result) -> str:
    return getattr(result, "completeness", "complete") or "complete"


def _rows(fresh, attr: str, row) -> dict[str, list]:
    """Columns of one detail table for many results: ``row(result_id, seq, campaign, x)``
    gives a dict per item x of ``result.<attr>``."""
    out: dict[str, list] = {}
    for result, rid, _, _ in fresh:
        for k, x in enumerate(getattr(result, attr)):
            for c, v in row(rid, k, result.campaign, x).items():
                out.setdefault(c, []).append(v)
    return out


def _insert_results(con, fresh, code_version, params_json, flow_run_id, checkpoint,
                    extras_root, own_params) -> None:
    """The rows of new results (results, lineage, coefficients, radii, adequacy, budget,
    alignment, flags): one Arrow insert per table, values as the row-wise inserts had.
    The extras files are written (and flushed) first: a row never names a missing file."""
    n = len(fresh)
    extras = write_extras(extras_root, [canonical_json(r.extras) for r, _, _, _ in fresh])
    _cp(checkpoint, "extras")
    _insert(con, "results", {
        "result_id": [rid for _, rid, _, _ in fresh],
        "campaign": [r.campaign for r, _, _, _ in fresh],
        "unit_serial": [r.unit_serial for r, _, _, _ in fresh],
        "unit_model": [r.unit_model for r, _, _, _ in fresh],
        "tests": [canonical_json(list(r.tests)) for r, _, _, _ in fresh],
        "rig_ids": [canonical_json(list(r.rig_ids)) for r, _, _, _ in fresh],
        "computed_at": None,
        "flow_run_id": [flow_run_id] * n,
        "code_version": [code_version] * n,
        "parameters": [own_params.get(rid, params_json) for _, rid, _, _ in fresh],
        "science_parameters": [canonical_json(r.parameters) for r, _, _, _ in fresh],
        "input_sha256": [canonical_json(sorted(i["sha256"] for i in inputs))
                         for _, _, inputs, _ in fresh],
        "extras_sha256": extras,
        "simulated": [bool(s) for _, _, _, s in fresh],
        "completeness": [_completeness(r) for r, _, _, _ in fresh],
        "completeness_reasons": [
            canonical_json(list(getattr(r, "completeness_reasons", []) or []))
            for r, _, _, _ in fresh]})
    _cp(checkpoint, "results")
    lin = [(rid, i) for _, rid, inputs, _ in fresh
           for i in sorted(inputs, key=lambda i: i["sha256"])]
    if lin:
        _insert(con, "lineage", {
            "result_id": [rid for rid, _ in lin],
            "sha256": [i["sha256"] for _, i in lin],
            "run_id": [i.get("run_id") for _, i in lin],
            "revision": [i.get("revision") for _, i in lin],
            "source_path": [i.get("source_path") for _, i in lin],
            "parquet_path": [i.get("parquet_path") for _, i in lin],
            "flow_run_id": [flow_run_id] * len(lin),
            "code_version": [code_version] * len(lin),
            "parameters": [own_params.get(rid, params_json) for rid, _ in lin]})
    _cp(checkpoint, "lineage")
    # per table: the row of one item (result_id, seq, campaign, item); the unit serial of
    # a coefficient row is its result's
    unit = {rid: r.unit_serial for r, rid, _, _ in fresh}
    details = [
        ("coefficient_history", "coefficients", lambda rid, k, camp, c: {
            "result_id": rid, "seq": k, "unit_serial": unit[rid], "campaign": camp,
            "name": c.name, "value": _f(c.value), "std_uncertainty": _f(c.std_uncertainty),
            "unit": c.unit, "method": c.method, "rig_id": c.rig_id, "dof": _f(c.dof),
            "note": c.note, "adopted": bool(getattr(c, "adopted", False)),
            "coverage_factor": _f(getattr(c, "coverage_factor", 2.0)) or 2.0,
            "factors": canonical_json(c.factors) if getattr(c, "factors", None) else None}),
        ("radius_history", "radii", lambda rid, k, camp, r: {
            "result_id": rid, "seq": k, "campaign": camp, "rig_id": r.rig_id,
            "polarity": r.polarity, "method": r.method, "model_order": r.model_order,
            "g_max": _f(r.g_max), "radius_m": _f(r.radius_m),
            "std_uncertainty_m": _f(r.std_uncertainty_m), "note": r.note}),
        ("adequacy_history", "adequacy", lambda rid, k, camp, a: {
            "result_id": rid, "seq": k, "campaign": camp, "rig_id": a.rig_id, "fit": a.fit,
            "model_order": a.model_order, "g_max": _f(a.g_max),
            "f_statistic": _f(a.f_statistic), "p_value": _f(a.p_value),
            "dof_lack_of_fit": a.dof_lack_of_fit, "dof_pure_error": a.dof_pure_error,
            "trend_p": _f(a.trend_p), "sweep_p": _f(a.sweep_p), "runs_p": _f(a.runs_p),
            "adequate": bool(a.adequate), "chosen": bool(a.chosen), "note": a.note}),
        ("budget_history", "budget", lambda rid, k, camp, b: {
            "result_id": rid, "seq": k, "campaign": camp, "coefficient": b.coefficient,
            "quantity": b.quantity, "value": _f(b.value),
            "std_uncertainty": _f(b.std_uncertainty), "sensitivity": _f(b.sensitivity),
            "contribution": _f(b.contribution), "type": b.type,
            "distribution": b.distribution, "method": getattr(b, "method", "")}),
        ("alignment_history", "alignment", lambda rid, k, camp, a: {
            "result_id": rid, "seq": k, "campaign": camp, "record": canonical_json(a)}),
        ("flag_history", "flags", lambda rid, k, camp, f: {
            "result_id": rid, "seq": k, "campaign": camp, "flag": str(f)}),
    ]
    for table, attr, row in details:
        cols = _rows(fresh, attr, row)
        if cols:
            _insert(con, table, cols)
        if table in ("coefficient_history", "radius_history"):
            _cp(checkpoint, "coefficients" if table == "coefficient_history" else "radii")
    _cp(checkpoint, "details")


def _f(x) -> float | None:
    if x is None:
        return None
    try:
        return float(x)
    except (TypeError, ValueError):
        return None

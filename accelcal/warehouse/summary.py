"""What a run's summary says about the campaigns it computed, read back from the
warehouse after the writes (the CLI prints it; ``accelcal run --json`` returns it)."""
from __future__ import annotations

import json
from typing import Any

from .db import Warehouse, roomy


#: Campaigns whose coefficients, radii and flags the run summary carries (the CLI prints
#: them); beyond this only status and result id, so a fleet run's summary stays small.
#: Everything is in the warehouse (unit_history, accelcal report).
SUMMARY_DETAIL_MAX = 50


def fill_campaigns(wh: Warehouse, entries: list[dict[str, Any]]) -> None:
    """Complete a run summary's campaign entries (each with ``campaign`` and ``result_id``)
    from the warehouse, in place: the current result, unit, completeness, exclusion and,
    for the first :data:`SUMMARY_DETAIL_MAX`, its coefficients, radii and flags."""
    with wh.connect() as con, roomy(con):
        camps = [e["campaign"] for e in entries]
        current = {c: rest for c, *rest in con.execute(
            "SELECT campaign, result_id, unit_serial, completeness, completeness_reasons, "
            "simulated FROM results_current WHERE list_contains(?, campaign)", [camps]).fetchall()}
        excluded = dict(con.execute(
            "SELECT campaign, why FROM excluded_campaigns WHERE list_contains(?, campaign)",
            [camps]).fetchall())
        stored = {rid: rest for rid, *rest in con.execute(
            "SELECT result_id, result_id, unit_serial, completeness, completeness_reasons, "
            "simulated FROM results WHERE list_contains(?, result_id)",
            [[e["result_id"] for e in entries]]).fetchall()}
        detail: list[dict[str, Any]] = []
        for k, e in enumerate(entries):
            e["excluded"] = excluded.get(e["campaign"])
            # a simulated result that is never current (the unit has a real calibration)
            # is shown as what it is, apart
            mine = stored.get(e["result_id"])
            row = current.get(e["campaign"]) or (mine if mine and mine[4] else None)
            if row is None:
                e.update(unit_serial=mine[1] if mine else None,
                         current_result_id=None, coefficients=[], radii=[], flags=[])
                continue
            rid, serial, completeness, reasons, simulated = row
            e["current_result_id"] = rid if e["campaign"] in current else None
            e["shown_result_id"], e["unit_serial"] = rid, serial
            e["completeness"], e["simulated"] = completeness, bool(simulated)
            e["completeness_reasons"] = json.loads(reasons or "[]")
            if k < SUMMARY_DETAIL_MAX:
                e.update(coefficients=[], radii=[], flags=[])
                detail.append(e)
        if not detail:
            return
        # three queries for the detailed entries, not three each: a result's rows in the
        # order they were stored (seq), as the current views give them
        by_rid: dict[str, list[dict[str, Any]]] = {}
        for e in detail:
            by_rid.setdefault(e["shown_result_id"], []).append(e)
        rids = list(by_rid)
        for key, sql in (
                ("coefficients", "SELECT result_id, name, value, std_uncertainty, unit, method, "
                                 "rig_id, adopted FROM coefficient_history"),
                ("radii", "SELECT result_id, rig_id, polarity, method, model_order, g_max, "
                          "radius_m, std_uncertainty_m FROM radius_history"),
                ("flags", "SELECT result_id, flag FROM flag_history")):
            q = con.execute(sql + " WHERE list_contains(?, result_id) ORDER BY seq", [rids])
            cols = [d[0] for d in q.description][1:]
            for rid, *row in q.fetchall():
                item = row[0] if key == "flags" else dict(zip(cols, row))
                for e in by_rid[rid]:
                    e[key].append(item)

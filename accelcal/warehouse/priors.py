"""What a unit's earlier calibrations say of its coefficients: the priors of a campaign
whose design determines some coefficients only in combination
(:func:`accelcal.estimators.priors.apply_priors`).

A campaign's priors are, for each coefficient, the value and standard uncertainty of the
unit's last calibration that determined it alone: the adopted row named by the
coefficient (``factors`` NULL) of the ``calibration`` view (current, complete, real, not
excluded) whose data were taken before this campaign's first run (``calibrated_at``
earlier than it; the latest such, ties broken by campaign label).  The choice rests on
the dates of the data, never on the order results were stored in.
"""
from __future__ import annotations

from datetime import timezone
from typing import Any

#: Per campaign: its unit, the start of its first run, whether all its runs are simulated.
_CAMPAIGN_DATES = """
    SELECT p.campaign, any_value(f.unit_serial), min(TRY_CAST(f.started_at AS TIMESTAMPTZ)),
           bool_and(p.simulated)
    FROM ({plan}) p JOIN run_files f USING (sha256)
    GROUP BY p.campaign"""

#: The coefficients the units' calibrations determined alone, oldest first.
_DETERMINED = """
    SELECT unit_serial, name, value, std_uncertainty, campaign, result_id, calibrated_at
    FROM calibration
    WHERE list_contains(?, unit_serial) AND factors IS NULL
      AND value IS NOT NULL AND std_uncertainty > 0
    ORDER BY unit_serial, name, calibrated_at, campaign"""


def campaign_dates(con, plan_sql: str, campaigns: list[str]) -> dict[str, tuple[str, Any, bool]]:
    """Campaign -> (unit serial, start of its first run or None, every run simulated)."""
    if not campaigns:
        return {}
    rows = con.execute(_CAMPAIGN_DATES.format(plan=plan_sql), [list(campaigns)]).fetchall()
    return {c: (str(s), t, bool(sim)) for c, s, t, sim in rows}


def unit_priors(con, dates: dict[str, tuple[str, Any, bool]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Campaign -> coefficient -> ``{"value", "u" [SI], "source", "result_id"}``: per
    coefficient the unit's last calibration dated before the campaign that determined it
    alone.  ``dates`` is :func:`campaign_dates`; a campaign without a date, or whose unit
    has no such calibration, is left out."""
    serials = sorted({s for s, t, _ in dates.values() if t is not None})
    serials = [s for (s,) in con.execute(
        "SELECT unit_serial FROM real_units WHERE list_contains(?, unit_serial) ORDER BY 1",
        [serials]).fetchall()] if serials else []
    if not serials:
        return {}
    by_unit: dict[str, list[tuple]] = {}
    for row in con.execute(_DETERMINED, [serials]).fetchall():
        by_unit.setdefault(row[0], []).append(row[1:])
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for camp, (serial, start, _) in dates.items():
        known: dict[str, dict[str, Any]] = {}
        for name, value, u, src_camp, rid, at in by_unit.get(serial, ()):
            if at is not None and start is not None and at < start and src_camp != camp:
                known[name] = {"value": float(value), "u": float(u), "result_id": rid,
                               "source": f"result {rid[:12]} of {src_camp}, {at.astimezone(timezone.utc).date().isoformat()}"}
        if known:
            out[camp] = known
    return out

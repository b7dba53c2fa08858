"""Campaign status and quarantine: ``accelcal campaign list|show|exclude|include``.

A campaign's current result is shown with what keeps it out of history, En, the fleet
views and the calibration view: ``incomplete`` (its runs cannot determine its test's
coefficients), ``simulated`` (computed from simulated files) or ``excluded`` (an operator
quarantined it with a reason).  Exclusion is an append-only audit trail
(``campaign_actions``): every exclude and include is kept with who, when and why.
"""
from __future__ import annotations

import getpass
import json
import os
from pathlib import Path
from typing import Any

from ..warehouse.db import Warehouse

# Per campaign its current result, or -- for a simulated campaign of a unit with a real
# calibration, whose result is never current -- its latest result.
_LIST_SQL = """
SELECT r.campaign, r.unit_serial, r.result_id, r.completeness, r.completeness_reasons,
       r.simulated, x.why AS excluded_why, x.acted_at AS excluded_at, x.acted_by AS excluded_by,
       d.first_run_at, r.is_current
FROM result_history r
LEFT JOIN excluded_campaigns x USING (campaign)
LEFT JOIN result_dates d USING (result_id)
WHERE r.valid_to IS NULL AND (r.is_current OR r.simulated)
QUALIFY row_number() OVER (PARTITION BY r.campaign
                           ORDER BY r.is_current DESC, r.computed_at DESC) = 1
ORDER BY r.campaign
"""


def campaign_rows(warehouse: str | Path, campaign: str | None = None) -> list[dict[str, Any]]:
    rows = Warehouse(warehouse).query(_LIST_SQL)
    for r in rows:
        r["completeness_reasons"] = json.loads(r.get("completeness_reasons") or "[]")
        r["in_history"] = (r["completeness"] == "complete" and not r["simulated"]
                           and r["excluded_why"] is None)
    return [r for r in rows if campaign is None or r["campaign"] == campaign]


def campaign_log(warehouse: str | Path, campaign: str) -> list[dict[str, Any]]:
    return Warehouse(warehouse).query(
        "SELECT seq, action, why, acted_at, acted_by FROM campaign_actions WHERE campaign = ? "
        "ORDER BY seq", [campaign])


def who() -> str:
    try:
        return getpass.getuser()
    except Exception:
        return os.environ.get("USER") or "unknown"


def set_campaign(warehouse: str | Path, campaign: str, action: str, why: str,
                 by: str | None = None, lock_timeout: float = 60.0) -> dict[str, Any]:
    return Warehouse(warehouse, lock_timeout=lock_timeout).campaign_action(
        campaign, action, why, by or who())

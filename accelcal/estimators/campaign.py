"""process_campaign: all the science of one campaign (stub until the estimators land)."""
from __future__ import annotations

from ..results import CampaignResult


def process_campaign(runs) -> CampaignResult:
    """Run every estimator that applies to the runs of one campaign (docs/design.md)."""
    first = runs[0]
    return CampaignResult(
        campaign=str(first.meta["campaign"]), unit_serial=str(first.meta["unit_serial"]),
        unit_model=str(first.meta.get("unit_model", "")),
        tests=sorted({str(r.meta["test"]) for r in runs}),
        rig_ids=sorted({str(r.meta["rig_id"]) for r in runs}),
        input_sha256=sorted(r.sha256 for r in runs))

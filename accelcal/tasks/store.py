"""Step 8: write to the warehouse (plain functions over accelcal.warehouse)."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..warehouse.db import KnownFile, Warehouse
from . import progress
from .ingest import DropIngest


def known_keys(wh: Warehouse, drop_dir: str) -> dict[tuple[str, str], KnownFile]:
    """(sha256, source_path) -> its latest verdict, for this drop's files."""
    from pathlib import Path
    prefix = str(Path(drop_dir).resolve()).rstrip("/") + "/"
    return wh.latest_verdicts(prefix)


def record_drop(wh: Warehouse, ing: DropIngest, flow_run_id: str | None,
                known: Mapping[tuple[str, str], KnownFile] | None = None) -> list[dict[str, Any]]:
    """Record the drop's new files in one transaction; return every file's stored record
    (``status``, ``reason``, ``campaign``, ``sha256``, ``source_path`` at least), in
    path order.

    A batch with nothing to record whose files are all in ``known`` (:func:`known_keys`,
    read for the drop before its batches) is every file taken as recorded: their records
    are the verdicts read then, which nothing in the run has changed since (one writer),
    so a re-run with nothing new asks the warehouse nothing more."""
    if not ing.records and known is not None and all(k in known for k in ing.keys):
        progress.advance("record", note=ing.drop_name)
        return [known[k]._asdict() for k in sorted(ing.keys, key=lambda k: k[1])]
    wh.record_runs(ing.records, flow_run_id=flow_run_id)
    progress.advance("record", note=ing.drop_name)
    return wh.stored_runs(ing.keys)


def store_campaign(wh: Warehouse, result, *, result_id: str, inputs: list[dict[str, Any]],
                   code_version: str, parameters: dict[str, Any],
                   flow_run_id: str | None) -> str:
    status = wh.store_result(result, result_id=result_id, inputs=inputs,
                             code_version=code_version, parameters=parameters,
                             flow_run_id=flow_run_id)
    progress.advance("store", note=result.campaign)
    return status


def store_campaigns(wh: Warehouse, items: list[tuple], *, code_version: str,
                    parameters: dict[str, Any], flow_run_id: str | None,
                    own_parameters: dict[str, dict[str, Any]] | None = None) -> list[str]:
    """Store several (result, result_id, inputs) in ONE transaction (all or none; a re-run
    stores what a killed one did not), each with the status :func:`store_campaign` gives
    (``own_parameters``: :meth:`Warehouse.store_results`)."""
    statuses = wh.store_results(items, code_version=code_version, parameters=parameters,
                                flow_run_id=flow_run_id, own_parameters=own_parameters)
    for result, _, _ in items:
        progress.advance("store", note=result.campaign)
    return statuses

"""Step 2: validate the parsed runs of a drop (great-expectations, via accelcal.schemas).

A run with any refusal is marked refused with all its reasons; Data Docs go to
``<docs_root>/<drop>``.  Plain function.
"""
from __future__ import annotations

import logging
from pathlib import Path

from ..warehouse.db import Refusal
from . import contracts, progress
from .ingest import DropIngest


def _follow_quiet_parent() -> None:
    """great-expectations pins one module logger to INFO at import; let it inherit instead,
    so a CLI that quietened 'great_expectations' stays quiet."""
    parent = logging.getLogger("great_expectations")
    if parent.level > logging.INFO:
        try:
            import great_expectations.data_context.types.base  # noqa: F401
        except Exception:
            return
        logging.getLogger("great_expectations.data_context.types.base").setLevel(logging.NOTSET)


def validate_drop(ing: DropIngest, docs_root: str) -> DropIngest:
    progress.stage("validate", 1)
    runs = list(ing.parsed.values())
    if runs:
        _follow_quiet_parent()
        verdicts = contracts.validate_runs(runs, docs_root, ing.drop_name)
        by_path = {}
        for k, v in (verdicts or {}).items():
            by_path[str(k)] = v
            try:
                by_path[str(Path(k).resolve())] = v
            except OSError:
                pass
        for rec in ing.records:
            if rec.status != "accepted":
                continue
            refs = by_path.get(rec.source_path) or []
            if refs:
                rec.status = "refused"
                rec.refusals = [Refusal(rule=r.rule, detail=r.detail, line=r.line,
                                        path=str(r.path)) for r in refs]
                ing.parsed.pop(rec.source_path, None)
        docs = Path(docs_root) / ing.drop_name
        ing.docs = str(docs) if docs.exists() else (str(docs_root) if Path(docs_root).exists() else None)
    progress.advance("validate", note=ing.drop_name)
    return ing

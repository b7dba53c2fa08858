"""Step 2: validate the parsed runs of a drop (great-expectations, via accelcal.schemas).

A run with any refusal is marked refused with all its reasons; Data Docs go to
``<docs_root>/<drop>``.  Plain function.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from ..warehouse.db import Refusal
from . import contracts, progress
from .ingest import DropIngest, ingest_files


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


def validate_drop(ing: DropIngest, docs_root: str, part: int | None = None) -> DropIngest:
    """Validate ``ing.parsed``; Data Docs to ``docs_root/<drop>/`` or, for part k of a
    drop streamed in batches, ``docs_root/<drop>/part-k/`` (listed in ``parts.html``).
    The Data Docs list the files the parser refused too."""
    runs = list(ing.parsed.values())
    parse_refusals = [rf for rec in ing.records if rec.status == "refused" for rf in rec.refusals]
    if runs or parse_refusals:
        _follow_quiet_parent()
        folder = contracts.docs_folder_name(ing.drop_name)
        if part is None:
            verdicts = contracts.validate_runs(runs, docs_root, ing.drop_name, parse_refusals)
        else:
            verdicts = contracts.validate_runs(runs, str(Path(docs_root) / folder),
                                               f"part-{part:04d}", parse_refusals)
            contracts.write_drop_index(Path(docs_root) / folder, ing.drop_name)
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
        docs = Path(docs_root) / folder / ("index.html" if part is None else "parts.html")
        ing.docs = str(docs) if docs.exists() else None
    progress.advance("validate", note=ing.drop_name)
    return ing


def intake_batch(drop_dir: str, paths: list[str], parquet_root: str, warehouse_root: str,
                 known: dict[tuple[str, str], str], docs_root: str,
                 part: int | None, allow_simulated: bool = False) -> DropIngest:
    """Steps 1-2 on a batch of one drop's files: hash, parse, write Parquet, validate.

    Returns the verdicts without the parsed data (the science re-reads Parquet), so a
    batch costs memory only while it is processed.  Touches no warehouse table: safe to
    run on any worker; the flow records the verdicts (one writer).
    """
    t0 = time.perf_counter()
    ing = ingest_files(drop_dir, paths, parquet_root, warehouse_root, known, allow_simulated)
    ing = validate_drop(ing, docs_root, part)
    ing.parsed.clear()
    ing.seconds = time.perf_counter() - t0
    return ing

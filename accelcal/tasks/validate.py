"""Step 2: validate the parsed runs of a drop (great-expectations, via accelcal.schemas).

A run with any refusal is marked refused with all its reasons; Data Docs go to
``<docs_root>/<drop>``.  Plain function.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from .. import memory
from ..fileio import StoreError, os_error_text
from ..warehouse.db import Refusal
from ..schemas import datadocs, suites
from . import progress
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
        folder = suites.docs_folder_name(ing.drop_name)
        verdicts = _validate_isolated(ing, runs, docs_root, part, parse_refusals)
        if part is not None:
            datadocs.write_drop_index(Path(docs_root) / folder, ing.drop_name)
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


def _validate_isolated(ing: DropIngest, runs: list, docs_root: str, part: int | None,
                       parse_refusals: list | None = None) -> dict:
    """validate_runs on the batch; if it raises, on each run alone, so one run that makes
    the validation fail (a bug) costs only itself: it is reported, not recorded.  Data
    Docs that cannot be written stop the run (StoreError), as the Parquet store does."""
    if part is None:
        where = (docs_root, ing.drop_name)
    else:
        where = (str(Path(docs_root) / suites.docs_folder_name(ing.drop_name)), f"part-{part:04d}")

    def validate(rs):
        try:
            return suites.validate_runs(rs, *where, parse_refusals)
        except OSError as e:
            raise StoreError(os_error_text(e, f"cannot write Data Docs under {docs_root}")) from None

    try:
        return validate(runs)
    except StoreError:
        raise
    except Exception:
        pass
    verdicts: dict = {}
    for r in runs:
        try:
            verdicts.update(validate([r]))
        except StoreError:
            raise
        except Exception as e:
            ing.errors.append(f"{r.path}: not ingested: validation failed: {type(e).__name__}: {e}")
            ing.parsed.pop(r.path, None)
            ing.records = [x for x in ing.records if x.source_path != r.path]
            ing.keys = [k for k in ing.keys if k[1] != r.path]
    return verdicts


def intake_batch(drop_dir: str, paths: list, parquet_root: str, warehouse_root: str,
                 known: dict[tuple[str, str], str], docs_root: str,
                 part: int | None, allow_simulated: bool = False) -> DropIngest:
    """Steps 1-2 on a batch of one drop's entries (``scan_drop``'s Entry objects, or
    paths): hash, parse, write Parquet, validate.

    Returns the verdicts without the parsed data (the science re-reads Parquet), so a
    batch costs memory only while it is processed.  Touches no warehouse table: safe to
    run on any worker; the flow records the verdicts (one writer).
    """
    t0, c0 = time.perf_counter(), time.process_time()
    ing = ingest_files(drop_dir, paths, parquet_root, warehouse_root, known, allow_simulated)
    t1 = time.perf_counter()
    rows = sum(getattr(r, "n_rows", 0) for r in ing.parsed.values())
    ing = validate_drop(ing, docs_root, part)
    ing.parsed.clear()
    if rows >= memory.BIG_ROWS:
        memory.give_back()   # the validation's frames sit in reference cycles (~500 MB at 4.5 M rows)
    t2 = time.perf_counter()
    ing.seconds = t2 - t0
    ing.stage_seconds = {"ingest": t1 - t0, "validate": t2 - t1,
                         "ingest+validate cpu": time.process_time() - c0}
    return ing

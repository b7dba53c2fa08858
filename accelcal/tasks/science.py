"""Steps 3-7: load a campaign's runs back from Parquet and hand them to the science.

The science itself (accelcal.estimators.campaign.process_campaign) is Prefect-free.
"""
from __future__ import annotations

import hashlib
import time
from pathlib import Path
from typing import Any

from ..schemas import dropformat, tables


def load_campaign_runs(warehouse_root: str, inputs: list[dict[str, Any]]) -> list:
    """RunFiles of the campaign's current runs, from Parquet (so results trace to bytes).

    Falls back to the raw file when its Parquet copy is gone, if its bytes still
    hash to the recorded sha256.
    """
    from ..fitting.data import long_run_blocks     # a long run: block means
    runs = []
    for i in inputs:
        pq = Path(warehouse_root) / i["parquet_path"] if i.get("parquet_path") else None
        if pq is not None and pq.exists():
            run = tables.read_run_parquet(pq, blocks=long_run_blocks)
        else:
            src = Path(i["source_path"])
            if not src.exists() or hashlib.sha256(src.read_bytes()).hexdigest() != i["sha256"]:
                raise FileNotFoundError(
                    f"run {i['run_id']} ({i['sha256'][:12]}): neither its Parquet copy {pq} "
                    f"nor unchanged raw bytes at {src} are available")
            run = dropformat.read_run(src)
        if run.sha256 != i["sha256"]:
            raise ValueError(f"Parquet copy {pq} holds {run.sha256[:12]}, "
                             f"the warehouse expects {i['sha256'][:12]}")
        runs.append(run)
    return runs


def run_science(runs: list, parameters: dict[str, Any] | None = None):
    from ..estimators.campaign import process_campaign
    if parameters:
        return process_campaign(runs, **parameters)
    return process_campaign(runs)


def load_and_process(warehouse_root: str, campaigns: list[list[dict[str, Any]]],
                     parameters: dict[str, Any] | None = None,
                     unit_priors: list[dict[str, Any] | None] | None = None) -> list[tuple]:
    """Load each campaign's runs from Parquet and run the science, on whichever worker runs
    the task (only the run lists travel to the worker, not the data).  Several campaigns
    per task keep the orchestration overhead (~0.1 s per Prefect task) small next to the
    science (~0.3 s per campaign).  ``unit_priors`` gives per campaign what its unit's
    earlier calibrations say of its coefficients (:meth:`Warehouse.unit_priors
    <accelcal.warehouse.db.Warehouse.unit_priors>`), read by the flow process.

    Returns per campaign ``(CampaignResult, {"load": s, "science": s, "load cpu": s,
    "science cpu": s})`` (wall and CPU seconds of the worker process, all its threads: on a
    machine with other work the CPU seconds are the cost), or ``(None, "ErrorType:
    message")`` when that campaign could not be computed (the others still are).
    """
    out: list[tuple] = []
    for k, inputs in enumerate(campaigns):
        own = unit_priors[k] if unit_priors else None
        try:
            t0, c0 = time.perf_counter(), time.process_time()
            runs = load_campaign_runs(warehouse_root, inputs)
            t1, c1 = time.perf_counter(), time.process_time()
            result = run_science(runs, {**(parameters or {}), "unit_priors": own} if own else parameters)
            del runs
            out.append((result, {"load": t1 - t0, "science": time.perf_counter() - t1,
                                 "load cpu": c1 - c0, "science cpu": time.process_time() - c1}))
        except Exception as e:
            out.append((None, f"{type(e).__name__}: {e}"))
    return out

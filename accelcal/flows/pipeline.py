"""The calibration pipeline: ingest -> validate -> group by campaign -> science -> store.

``run_pipeline(drops, warehouse)`` is the entry point.  With ``engine='prefect'``
(the default) the steps run as Prefect tasks inside the ``accelcal-pipeline``
flow; with ``engine='local'`` the same composition calls the plain functions
directly (no Prefect server; used by fast tests and the benchmark).

Campaigns touched by the drops are processed with ALL their current runs in the
warehouse (newest accepted revision of each run_id, earlier drops included),
read back from Parquet.  A campaign whose deterministic result_id is already
current is not recomputed.
"""
from __future__ import annotations

import os
import time
import uuid
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from ..tasks import ingest as _ingest
from ..tasks import progress
from ..tasks import science as _science
from ..tasks import store as _store
from ..tasks import validate as _validate
from ..warehouse.db import Warehouse, WarehouseError
from ..warehouse.lineage import code_version as _code_version
from ..warehouse.lineage import result_id as _result_id

ENGINES = ("prefect", "local")
TASK_RUNNERS = ("thread", "dask")


class PipelineError(RuntimeError):
    """The pipeline could not work at all (bad arguments, unusable warehouse)."""


class _Done:
    """A finished 'future' for the local engine."""

    def __init__(self, fn, *a, **kw):
        try:
            self._value, self._exc = fn(*a, **kw), None
        except Exception as e:  # re-raised by result(), as a Prefect future would
            self._value, self._exc = None, e

    def result(self):
        if self._exc is not None:
            raise self._exc
        return self._value


def _local_steps() -> SimpleNamespace:
    return SimpleNamespace(
        known_keys=_store.known_keys, ingest_drop=_ingest.ingest_drop,
        validate_drop=_validate.validate_drop, record_drop=_store.record_drop,
        load_campaign_runs=_science.load_campaign_runs,
        submit_science=lambda runs, params: _Done(_science.run_science, runs, params),
        store_campaign=_store.store_campaign)


def _prefect_steps() -> SimpleNamespace:
    from ..tasks import prefect_tasks
    t = prefect_tasks()
    return SimpleNamespace(
        known_keys=t.known_keys, ingest_drop=t.ingest_drop, validate_drop=t.validate_drop,
        record_drop=t.record_drop, load_campaign_runs=t.load_campaign_runs,
        submit_science=lambda runs, params: t.run_science.submit(runs, params),
        store_campaign=t.store_campaign)


def check_drops(drops: list[str]) -> list[str]:
    out = []
    for d in drops:
        p = Path(d).expanduser()
        if not p.exists():
            raise PipelineError(f"drop {d} does not exist")
        if not p.is_dir():
            raise PipelineError(f"drop {d} is not a folder")
        out.append(str(p.resolve()))
    if len(set(out)) != len(out):
        out = list(dict.fromkeys(out))
    return out


def pipeline_body(drops: list[str], warehouse: str, *, lock_timeout: float = 60.0,
                  parameters: dict[str, Any] | None = None, steps: SimpleNamespace,
                  flow_run_id: str) -> dict[str, Any]:
    """The composition shared by both engines.  Returns a JSON-able summary."""
    parameters = dict(parameters or {})
    timings: dict[str, float] = {}
    _quiet_libraries()

    def tick(name, t0):
        timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0

    wh = Warehouse(warehouse, lock_timeout=lock_timeout)
    cv = _code_version()
    summary: dict[str, Any] = {"warehouse": str(wh.path), "flow_run_id": flow_run_id,
                               "code_version": cv, "parameters": parameters,
                               "drops": [], "campaigns": [], "timings": timings}
    with wh.lock():
        wh.init()
        touched: set[str] = set()
        ingests = []
        for drop in drops:                       # 1 ingest every drop
            t0 = time.perf_counter()
            known = steps.known_keys(wh, drop)
            ingests.append(steps.ingest_drop(drop, str(wh.parquet_root), str(wh.root), known))
            tick("ingest", t0)
        for k, ing in enumerate(ingests):        # 2 validate (one GE run + Data Docs per drop)
            t0 = time.perf_counter()
            ingests[k] = steps.validate_drop(ing, str(wh.docs_root))
            ingests[k].parsed.clear()   # the science re-reads from Parquet: keep memory bounded
            tick("validate", t0)
        progress.stage("record", len(ingests))
        for ing in ingests:                      # record each drop's files in one transaction
            t0 = time.perf_counter()
            stored = steps.record_drop(wh, ing, flow_run_id)
            tick("record", t0)
            acc = [r for r in stored if r["status"] == "accepted"]
            ref = [r for r in stored if r["status"] == "refused"]
            touched.update(r["campaign"] for r in acc if r["campaign"])
            new_keys = {(r.sha256, r.source_path) for r in ing.records if r.new_content}
            rechecked = sum(1 for r in ing.records if r.rechecked)
            summary["drops"].append({
                "drop": ing.drop_name, "path": ing.drop_path, "files": len(stored),
                "accepted": len(acc), "refused": len(ref),
                "new": sum(1 for r in stored if (r["sha256"], r["source_path"]) in new_keys),
                "refused_files": [{"path": r["source_path"], "reason": r["reason"]} for r in ref],
                "rechecked": rechecked, "errors": ing.errors, "docs": ing.docs})

        # -- group by campaign; plan what needs computing
        campaigns = sorted(touched)
        progress.stage("science", len(campaigns))
        progress.stage("store", len(campaigns))
        plans = []
        for camp in campaigns:
            t0 = time.perf_counter()
            inputs = wh.campaign_inputs(camp)
            rid = _result_id(camp, [i["sha256"] for i in inputs], cv, parameters)
            entry = {"campaign": camp, "result_id": rid, "n_runs": len(inputs), "status": None,
                     "error": None}
            summary["campaigns"].append(entry)
            if wh.current_result_id(camp) == rid:
                entry["status"] = "unchanged"
                progress.advance("science", note=camp)
                progress.advance("store", note=camp)
                tick("plan", t0)
                continue
            try:
                runs = steps.load_campaign_runs(str(wh.root), inputs)
            except Exception as e:
                entry["status"], entry["error"] = "failed", f"{type(e).__name__}: {e}"
                progress.advance("science", note=camp)
                progress.advance("store", note=camp)
                tick("load", t0)
                continue
            tick("load", t0)
            t0 = time.perf_counter()
            plans.append((entry, inputs, steps.submit_science(runs, parameters)))
            tick("science", t0)

        for entry, inputs, fut in plans:
            t0 = time.perf_counter()
            try:
                result = fut.result()
            except Exception as e:
                entry["status"], entry["error"] = "failed", f"{type(e).__name__}: {e}"
                progress.advance("science", note=entry["campaign"])
                progress.advance("store", note=entry["campaign"])
                tick("science", t0)
                continue
            progress.advance("science", note=entry["campaign"])
            tick("science", t0)
            t0 = time.perf_counter()
            missing = set(result.input_sha256) - {i["sha256"] for i in inputs}
            if missing:
                result.flags.append(f"science reported inputs not handed to it: {sorted(missing)}")
            entry["status"] = steps.store_campaign(
                wh, result, result_id=entry["result_id"], inputs=inputs, code_version=cv,
                parameters=parameters, flow_run_id=flow_run_id)
            tick("store", t0)

        # -- what the warehouse now says about these campaigns
        t0 = time.perf_counter()
        _fill_campaigns(wh, summary["campaigns"])
        tick("summary", t0)
    return summary


def _fill_campaigns(wh: Warehouse, entries: list[dict[str, Any]]) -> None:
    with wh.connect() as con:
        for e in entries:
            cur = con.execute(
                "SELECT result_id, unit_serial FROM results_current WHERE campaign = ?",
                [e["campaign"]]).fetchall()
            if not cur:
                e.update(unit_serial=None, current_result_id=None, coefficients=[], radii=[],
                         flags=[])
                continue
            rid, serial = cur[0]
            e["current_result_id"], e["unit_serial"] = rid, serial
            q = con.execute("SELECT name, value, std_uncertainty, unit, method, rig_id "
                            "FROM coefficients WHERE result_id = ?", [rid])
            cols = [d[0] for d in q.description]
            e["coefficients"] = [dict(zip(cols, r)) for r in q.fetchall()]
            q = con.execute("SELECT rig_id, polarity, method, model_order, g_max, radius_m, "
                            "std_uncertainty_m FROM radii WHERE result_id = ?", [rid])
            cols = [d[0] for d in q.description]
            e["radii"] = [dict(zip(cols, r)) for r in q.fetchall()]
            e["flags"] = [r[0] for r in con.execute(
                "SELECT flag FROM flags WHERE result_id = ?", [rid]).fetchall()]


# ------------------------------------------------------------------ prefect --

_FLOW = None


def pipeline_flow():
    """The Prefect flow object (built on first use so importing stays cheap)."""
    global _FLOW
    if _FLOW is None:
        from prefect import flow

        @flow(name="accelcal-pipeline", persist_result=False, validate_parameters=False,
              log_prints=False)
        def accelcal_pipeline(drops: list[str], warehouse: str, lock_timeout: float = 60.0,
                              parameters: dict | None = None) -> dict:
            from prefect.runtime import flow_run
            return pipeline_body(drops, warehouse, lock_timeout=lock_timeout,
                                 parameters=parameters, steps=_prefect_steps(),
                                 flow_run_id=str(flow_run.id))

        _FLOW = accelcal_pipeline
    return _FLOW


def quiet_prefect(level: str = "WARNING") -> None:
    """Quiet logging for an interactive CLI (Prefect, great-expectations).

    Call before prefect is imported: Prefect reads its settings at import.
    """
    import logging
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", level)
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_LOGGING_LEVEL", level)
    os.environ.setdefault("PREFECT_LOGGING_ROOT_LEVEL", level)
    for name in ("great_expectations", "prefect"):
        logging.getLogger(name).setLevel(level)


def _quiet_libraries() -> None:
    """great-expectations logs at INFO through Prefect's handlers; follow Prefect's level."""
    import logging
    level = os.environ.get("PREFECT_LOGGING_LEVEL")
    if level:
        logging.getLogger("great_expectations").setLevel(level.upper())


def _task_runner(name: str):
    """'thread' (Prefect's default), 'dask' (a local Dask cluster) or a Dask scheduler
    address tcp://HOST:PORT (accelcal.ops.runners)."""
    from ..ops.runners import RunnerError, task_runner_for
    try:
        return task_runner_for(name)
    except RunnerError as e:
        raise PipelineError(str(e)) from None


def run_pipeline(drops: list[str], warehouse: str | Path, *, engine: str = "prefect",
                 lock_timeout: float = 60.0, parameters: dict[str, Any] | None = None,
                 task_runner: str = "thread") -> dict[str, Any]:
    """Process drops into a warehouse.  Raises PipelineError / WarehouseError when it cannot work."""
    drops = check_drops(list(drops))
    if not drops:
        raise PipelineError("no drop given")
    warehouse = str(Path(warehouse).expanduser().resolve())
    t0 = time.perf_counter()
    if engine == "local":
        if task_runner != "thread":
            raise PipelineError("--task-runner needs the prefect engine")
        summary = pipeline_body(drops, warehouse, lock_timeout=lock_timeout,
                                parameters=parameters, steps=_local_steps(),
                                flow_run_id=f"local-{uuid.uuid4()}")
    elif engine == "prefect":
        # Fail fast (before the Prefect server starts) when the warehouse is busy.
        wh = Warehouse(warehouse, lock_timeout=lock_timeout)
        runner = _task_runner(task_runner)
        with wh.lock():
            fl = pipeline_flow()
            if runner is not None:
                fl = fl.with_options(task_runner=runner)
            summary = fl(drops=drops, warehouse=warehouse, lock_timeout=lock_timeout,
                         parameters=parameters or {})
    else:
        raise PipelineError(f"unknown engine {engine!r} (choose from {', '.join(ENGINES)})")
    summary["engine"] = engine
    summary["timings"]["total"] = time.perf_counter() - t0
    return summary


__all__ = ["run_pipeline", "pipeline_body", "pipeline_flow", "PipelineError", "WarehouseError",
           "quiet_prefect", "ENGINES", "TASK_RUNNERS"]

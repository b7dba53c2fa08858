"""The calibration pipeline: ingest -> validate -> group by campaign -> science -> store.

``run_pipeline(drops, warehouse)`` is the entry point.  With ``engine='prefect'``
(the default) the steps run as Prefect tasks inside the ``accelcal-pipeline``
flow; with ``engine='local'`` the same composition calls the plain functions
directly (no Prefect server; used by fast tests and the benchmark).  The two are the
``Steps`` of :mod:`accelcal.flows.steps`.

Read :func:`pipeline_body` top to bottom: the intake loop (:func:`_intake`: list and
settle the drops, ingest + validate in batches, record each batch's verdicts), then the
science loop (:func:`_science`: plan the touched campaigns, compute them a few a task,
store them a transaction at a time), then the summary and the snapshot.

A campaign whose design determines a coefficient only in combination takes what its
unit's earlier calibrations say of the other terms (:mod:`accelcal.warehouse.priors`,
chosen by the dates of the data), read when it is planned.  So that the rows do not
depend on which worker finishes first, a unit's touched campaigns are computed in waves,
in the order of their dates: a campaign waits for the real ones of its unit dated before
it (:func:`_waves`).  The source results enter its result_id and stored parameters
(``prior_results``).

Campaigns touched by the drops are processed with ALL their current runs in the
warehouse (newest accepted revision of each run_id, earlier drops included),
read back from Parquet.  A campaign whose deterministic result_id is already
current is not recomputed.
"""
from __future__ import annotations

import contextlib
import os
import time
import uuid
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..schemas import dropscan
from ..tasks import progress
from ..fileio import StoreError, os_error_text, path_text
from ..warehouse.db import Warehouse
from ..warehouse.errors import WarehouseError
from ..warehouse.summary import fill_campaigns
from ..warehouse.lineage import code_version as _code_version
from ..warehouse.lineage import result_id as _result_id
from .steps import LocalSteps, PrefectSteps, Steps

ENGINES = ("prefect", "local")
TASK_RUNNERS = ("thread", "dask")


class PipelineError(RuntimeError):
    """The pipeline could not work at all (bad arguments, unusable warehouse)."""


def local_workers() -> int:
    """Worker processes of the local engine ($ACCELCAL_WORKERS, default 1: the steps run
    in the flow process itself)."""
    return _env_int("ACCELCAL_WORKERS", 1)


def _worker_init() -> None:
    """A local worker leaves Ctrl-C to the flow process, which stops the pool (a worker
    killed mid-task would cost the batch it held, not the run)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _quiet_libraries()


@contextlib.contextmanager
def _local_pool(workers: int):
    """None for one worker; else a pool of ``workers`` processes, started fresh (spawn:
    the flow process holds the warehouse connection and threads, which a fork would copy)
    and stopped with the run, whatever ends it."""
    if workers <= 1:
        yield None
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init,
                               mp_context=multiprocessing.get_context("spawn"))
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def check_drops(drops: list[str]) -> list[str]:
    out = []
    for d in drops:
        p = Path(d).expanduser()
        if not p.exists():
            raise PipelineError(f"drop {path_text(d)} does not exist")
        if not p.is_dir():
            raise PipelineError(f"drop {path_text(d)} is not a folder")
        r = str(p.resolve())
        if path_text(r) != r:
            raise PipelineError(f"the path of drop {path_text(r)} is not UTF-8: rename it")
        if not os.access(r, os.R_OK | os.X_OK):
            raise PipelineError(f"drop {r} cannot be read (no permission)")
        out.append(r)
    if len(set(out)) != len(out):
        out = list(dict.fromkeys(out))
    return out


def _env_int(name: str, default: int) -> int:
    try:
        return max(1, int(os.environ.get(name, default)))
    except ValueError:
        return default


#: Files ingested + validated per task, at most.  A drop of any size is streamed in
#: batches, so memory does not grow with the drop.  great-expectations costs ~0.35 s per
#: batch whatever its size (one suite, built once per batch) plus ~0.3 ms per file, so a
#: batch should hold many files: 200 cost 1.9 ms of validation per file, 1,100 cost 0.6.
BATCH_FILES = 1000

#: ... and at most this many bytes of raw files (the parsed batch and its validation table
#: are a few times that), so a drop of large files is cut into smaller batches.
BATCH_BYTES = 32 << 20


def batch_files() -> int:
    return _env_int("ACCELCAL_BATCH_FILES", BATCH_FILES)


def batch_bytes() -> int:
    return _env_int("ACCELCAL_BATCH_BYTES", BATCH_BYTES)


def file_batches(entries: list, files: int, nbytes: int) -> list[list]:
    """The drop's entries cut, in order, into batches of at most ``files`` files and
    ``nbytes`` bytes (a file larger than that is a batch alone)."""
    out: list[list] = []
    size = 0
    for e in entries:
        n = max(int(getattr(e, "size", 0) or 0), 0)
        if not out or len(out[-1]) >= files or (out[-1] and size + n > nbytes):
            out.append([])
            size = 0
        out[-1].append(e)
        size += n
    return out


#: Campaigns computed per task, by engine.  A Prefect task run costs ~0.1-0.2 s of
#: bookkeeping (flow process, Prefect server, worker), which is taken from the workers when
#: they fill the cores: under the prefect engine a task carries ~25 campaigns (~3 s of
#: science), so that is a few per cent (200 campaigns on a standing cluster of 2 Dask
#: workers, benchmarks/bench_dask_scaling.py: 1.53x the 1-worker speed with 4 a task,
#: 1.56x with 25).  Toward the end of a run the chunks shrink (:func:`guided_chunk`).
#: The local engine's process pool costs next to nothing a task and keeps them small.
CAMPAIGNS_PER_TASK = {"local": 4, "prefect": 25}


def campaigns_per_task(engine: str = "local") -> int:
    """$ACCELCAL_CAMPAIGNS_PER_TASK, else the engine's default (CAMPAIGNS_PER_TASK)."""
    return _env_int("ACCELCAL_CAMPAIGNS_PER_TASK", CAMPAIGNS_PER_TASK[engine])


def guided_chunk(remaining: int, most: int, in_flight: int,
                 least: int = CAMPAIGNS_PER_TASK["local"]) -> int:
    """Campaigns for the next science task: ``most``, shrinking toward the end of the run
    to ``remaining / in_flight`` (guided self-scheduling), never below ``least``.

    With equal chunks the run ends on one worker still computing its last chunk while the
    others wait: with 25 campaigns a task (~3.5 s) that is ~2 s of a 2-worker run, more
    than the few extra task runs of smaller chunks at the end cost.  The chunking does not
    change any result (each campaign is computed alone)."""
    if most <= least:
        return most
    return max(least, min(most, -(-remaining // max(in_flight, 1))))


#: Computed campaigns stored per warehouse transaction (columnar inserts; all or none of
#: them, so a killed run recomputes at most this many).
CAMPAIGNS_PER_STORE = 32


def campaigns_per_store() -> int:
    return _env_int("ACCELCAL_CAMPAIGNS_PER_STORE", CAMPAIGNS_PER_STORE)


#: Campaigns planned (their input runs read from the warehouse) at a time: the plans of
#: a whole fleet would be held for the whole science stage (~10 KB a campaign).  Each
#: window costs two queries over the whole warehouse's current runs (~0.1 s each at
#: 2,000 campaigns), so a window holds ~10 MB of plans rather than a few.
CAMPAIGNS_PER_PLAN = 1024


def campaigns_per_plan() -> int:
    return _env_int("ACCELCAL_CAMPAIGNS_PER_PLAN", CAMPAIGNS_PER_PLAN)


def in_flight() -> int:
    """Tasks submitted ahead of the one the flow waits for (feeds several workers; bounds
    memory to this many batches / campaigns at a time)."""
    return _env_int("ACCELCAL_IN_FLIGHT", max(4, 2 * (os.cpu_count() or 1)))


class _Session:
    """One warehouse connection for a stretch of small writes (Warehouse.session), closed
    and reopened every ``hold_s`` seconds.

    The pipeline holds it for the whole run (hold_s = inf): a reader outside accelcal
    that opened the live file between two reconnects used to make the run fail half-way
    once it had waited --lock-timeout.  Readers use ``accelcal sql`` (which waits for the
    run) or the snapshot each run publishes (never locked by a run)."""

    def __init__(self, wh: Warehouse, hold_s: float = float("inf")):
        self.wh, self.hold_s, self._cm, self._t = wh, hold_s, None, 0.0

    def touch(self) -> None:
        if self._cm is not None and time.monotonic() - self._t > self.hold_s:
            self.close()
        if self._cm is None:
            self._cm = self.wh.session()
            self._cm.__enter__()
            self._t = time.monotonic()

    def close(self) -> None:
        if self._cm is not None:
            cm, self._cm = self._cm, None
            cm.__exit__(None, None, None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


#: Seconds a run file's size and mtime must have been stable before ``run`` reads it
#: (``--settle``; ``ACCELCAL_SETTLE_S``).
SETTLE_S = 2.0


def settle_seconds() -> float:
    try:
        return max(0.0, float(os.environ.get("ACCELCAL_SETTLE_S", SETTLE_S)))
    except ValueError:
        return SETTLE_S


@dataclass
class _Run:
    """What every stage of one run reads: who it is, its parameters and bounds, its clock."""
    steps: Steps
    flow_run_id: str
    parameters: dict[str, Any]
    code_version: str
    allow_simulated: bool
    batch_files: int                 # files per ingest + validate task, at most
    in_flight: int                   # tasks (or campaigns' worth of tasks) submitted ahead
    timings: dict[str, float] = field(default_factory=dict)
    unit_priors: dict[str, dict] = field(default_factory=dict)     # campaign -> its priors
    own_parameters: dict[str, dict] = field(default_factory=dict)  # result_id -> parameters

    def tick(self, name: str, t0: float, dt: float | None = None) -> None:
        """Add the time since ``t0`` (or ``dt`` seconds) to ``timings[name]``."""
        self.timings[name] = self.timings.get(name, 0.0) + (
            time.perf_counter() - t0 if dt is None else dt)


def pipeline_body(drops: list[str], warehouse: str, *, lock_timeout: float = 60.0,
                  parameters: dict[str, Any] | None = None, steps: Steps,
                  flow_run_id: str, settle: float | None = None,
                  snapshot: bool = True, allow_simulated: bool = False) -> dict[str, Any]:
    """The composition shared by both engines.  Returns a JSON-able summary.

    Streams: each drop's files go in batches (ingest + validate as one task, possibly
    on another worker), each batch's verdicts are recorded in one transaction as soon
    as it is done, in file order (:func:`_intake`); then each touched campaign is loaded
    and computed in a task and stored as soon as it is done (:func:`_science`).  At most
    ``in_flight()`` batches or campaigns are held at once, so memory is bounded by the
    batch size, not the drop.  Only the flow process writes to the warehouse.

    Files carrying the simulator's mark are not taken in unless ``allow_simulated``
    (each drop's ``simulated_held`` lists them); even then a simulated result is never
    current for a unit that has a complete real result (Warehouse.store_result).
    Before reading, each drop's files wait until they are settled (``settle`` seconds
    unchanged; a file still being written is held back, listed under ``held``).  A fault
    of the places the run writes (Parquet store, Data Docs, warehouse: disk full,
    read-only) stops the run with StoreError / WarehouseError; what was committed stays
    and a re-run completes the rest exactly once.  At the end, when anything was written,
    a read-only copy ``<stem>-snapshot.duckdb`` is published for readers outside accelcal.
    """
    parameters = dict(parameters or {})
    _quiet_libraries()
    wh = Warehouse(warehouse, lock_timeout=lock_timeout)
    run = _Run(steps=steps, flow_run_id=flow_run_id, parameters=parameters,
               code_version=_code_version(), allow_simulated=allow_simulated,
               batch_files=batch_files(), in_flight=in_flight())
    summary: dict[str, Any] = {"warehouse": str(wh.path), "flow_run_id": flow_run_id,
                               "code_version": run.code_version, "parameters": parameters,
                               "drops": [], "campaigns": [], "timings": run.timings,
                               "warnings": [], "snapshot": None}
    settle = settle_seconds() if settle is None else settle
    with wh.lock():
        wh.init()
        summary["removed_temp_files"] = len(wh.remove_stale_temps())
        with _Session(wh) as sess:
            touched = _intake(wh, sess, drops, settle, summary["drops"], run)
            _science(wh, sess, sorted(touched), summary["campaigns"], run)
            # what the warehouse now says about these campaigns
            t0 = time.perf_counter()
            sess.touch()
            fill_campaigns(wh, summary["campaigns"])
            run.tick("summary", t0)
        wrote = any(d["new"] or d["rechecked"] for d in summary["drops"]) or any(
            c["status"] in ("new", "reactivated") for c in summary["campaigns"])
        if snapshot and (wrote or not wh.snapshot_path.exists()):
            t0 = time.perf_counter()
            try:
                summary["snapshot"] = str(wh.publish_snapshot())
            except WarehouseError as e:
                summary["warnings"].append(f"the results are stored, but {e}")
            run.tick("snapshot", t0)
    return summary


# ------------------------------------------------- steps 1-3: the intake loop --

def _intake(wh: Warehouse, sess: _Session, drops: list[str], settle: float,
            entries: list[dict], run: _Run) -> set[str]:
    """Each drop's settled files, in batches: ingest + validate each batch (a submitted
    task), record its verdicts (flow process) in file order.  Appends one entry per drop
    to ``entries``; returns the campaigns the accepted files belong to."""
    by_drop, held_by, empty = _settled_files(drops, settle, run)
    last = {d: i for i, d in enumerate(drops)}
    pending: deque = deque()             # (drop entry, future of its batch), in file order
    touched: set[str] = set()
    for i, drop in enumerate(drops):
        sess.touch()
        known = run.steps.known_keys(wh, drop)
        entry = {"drop": Path(drop).name, "path": drop, "files": 0, "accepted": 0,
                 "refused": 0, "new": 0, "refused_files": [], "rechecked": 0,
                 "errors": [], "held": held_by[drop], "warnings": [], "docs": None,
                 "simulated_held": [], "campaigns": set()}
        entries.append(entry)
        if drop in empty:
            entry["warnings"].append(f"drop {drop} holds no *.csv file: nothing to do")
        # each drop's list is let go once it is submitted: what the run holds of the
        # listing shrinks as it goes (a fleet's drops list ~10 files a campaign)
        paths = by_drop.pop(drop) if last[drop] == i else by_drop[drop]
        progress.stage("ingest", len(paths))
        batches = file_batches(paths, run.batch_files, batch_bytes()) or [[]]
        nb = len(batches)
        progress.stage("validate", nb)
        progress.stage("record", nb)
        for k, batch in enumerate(batches):
            bset = {path_text(e.path) for e in batch}
            kb = {key: v for key, v in known.items() if key[1] in bset}
            t0 = time.perf_counter()
            pending.append((entry, run.steps.submit_intake(
                drop, batch, str(wh.parquet_root), str(wh.root),
                {key: v.validator_version for key, v in kb.items()}, str(wh.docs_root),
                None if nb == 1 else k, run.allow_simulated), kb))
            run.tick("ingest+validate (submit)", t0)
            while len(pending) >= run.in_flight:
                touched |= _record_batch(wh, sess, *pending.popleft(), run)
    while pending:
        touched |= _record_batch(wh, sess, *pending.popleft(), run)
    for e in entries:
        # a campaign with a file in a failed batch would be computed from part of its
        # runs: every campaign of that drop waits for a run that ingests the whole drop
        campaigns = e.pop("campaigns")
        held_back = sorted(touched & campaigns) if e["errors"] else []
        if held_back:
            touched -= campaigns
            e["warnings"].append(f"{len(held_back)} campaign(s) of drop {e['path']} not computed: a batch of "
                                 f"its files failed, so they may lack runs; run again ({', '.join(held_back[:5])}"
                                 + (", ..." if len(held_back) > 5 else "") + ")")
        e["refused_files"].sort(key=lambda r: r["path"])
        e["simulated_held"].sort(key=lambda r: r["path"])
    return touched


def _settled_files(drops: list[str], settle: float, run: _Run):
    """Every drop listed first, and one settle wait for all of them: (drop -> its settled
    entries, drop -> its held files as text, the drops that list no file)."""
    t0 = time.perf_counter()
    scanned: dict[str, list] = {}
    for drop in drops:
        try:
            scanned[drop] = dropscan.scan_drop(drop)
        except OSError as e:
            raise PipelineError(os_error_text(e, "cannot list drop")) from None
    unique = {e.path: e for es in scanned.values() for e in es}
    ready, held_all = dropscan.settle_wait(list(unique.values()), settle)
    ready_at = {e.path: e for e in ready}
    held_at = {e.path: why for e, why in held_all}
    by_drop = {d: [ready_at[e.path] for e in scanned[d] if e.path in ready_at] for d in drops}
    held_by = {d: [f"{path_text(e.path)}: {held_at[e.path]}" for e in scanned[d]
                   if e.path in held_at] for d in drops}
    empty = {d for d in drops if not scanned[d]}
    run.tick("discover", t0)
    return by_drop, held_by, empty


def _record_batch(wh: Warehouse, sess: _Session, entry: dict, fut, known: dict,
                  run: _Run) -> set[str]:
    """Wait for one batch's ingest + validate, record its verdicts in one transaction and
    count them into the drop's ``entry`` (``known``: the verdicts its files already have,
    :func:`accelcal.tasks.store.known_keys`); returns the campaigns of its accepted files."""
    t0 = time.perf_counter()
    try:
        ing = fut.result()
    except (StoreError, WarehouseError):
        raise                # a place the run writes is unusable: stop, say where
    except Exception as e:   # a bug in a step, not a bad file: report, record nothing
        entry["errors"].append(f"batch failed: {type(e).__name__}: {e}")
        run.tick("ingest+validate (wait)", t0)
        return set()
    run.tick("ingest+validate (wait)", t0)
    run.tick("ingest+validate", 0.0, ing.seconds)
    for k, v in (getattr(ing, "stage_seconds", None) or {}).items():
        run.tick(k, 0.0, v)      # the same time by step: "ingest", "validate"
    t0 = time.perf_counter()
    sess.touch()
    stored = run.steps.record_drop(wh, ing, run.flow_run_id, known)
    run.tick("record", t0)
    new_keys = {(r.sha256, r.source_path) for r in ing.records if r.new_content}
    campaigns: set[str] = set()
    for r in stored:
        entry["files"] += 1
        if r["status"] == "accepted":
            entry["accepted"] += 1
            if r["campaign"]:
                campaigns.add(r["campaign"])
        elif r["status"] == "refused":
            entry["refused"] += 1
            entry["refused_files"].append({"path": r["source_path"], "reason": r["reason"]})
        entry["new"] += (r["sha256"], r["source_path"]) in new_keys
    entry["campaigns"] |= campaigns
    entry["rechecked"] += sum(1 for r in ing.records if r.rechecked)
    entry["errors"].extend(ing.errors)
    entry["simulated_held"].extend(ing.simulated_held)
    entry["held"].extend(ing.held)
    if ing.docs and entry["docs"] is None:
        entry["docs"] = ing.docs
    return campaigns


# ------------------------------------------------ steps 4-8: the science loop --

def _science(wh: Warehouse, sess: _Session, campaigns: list[str], entries: list[dict],
             run: _Run) -> None:
    """Each touched campaign with all its current runs: unchanged when its result is
    already current, else computed a few campaigns per submitted task (load + science)
    and stored in transactions of ``campaigns_per_store()``, wave by wave
    (:func:`_waves`).  Appends one entry per campaign to ``entries``."""
    progress.stage("science", len(campaigns))
    progress.stage("store", len(campaigns))
    most = campaigns_per_task(run.steps.engine)
    for wave, dates in _waves(wh, sess, campaigns, run):
        inflight: deque = deque()           # (chunk, future of its outcomes), in order
        computed: list = []                 # (entry, result, inputs) waiting to be stored
        chunk: list = []                    # (entry, inputs) of the next task
        for k, (camp, inputs, current, left_out) in enumerate(_planned(wh, sess, wave, dates, run)):
            params = run.parameters
            known = run.unit_priors.get(camp)
            if known:
                params = {**params, "prior_results": sorted({v["result_id"] for v in known.values()})}
            rid = _result_id(camp, [i["sha256"] for i in inputs], run.code_version, params)
            if known:
                run.own_parameters[rid] = params
            entry = {"campaign": camp, "result_id": rid, "n_runs": len(inputs), "status": None,
                     "error": None, "simulated_left_out": left_out}
            entries.append(entry)
            if current == rid:
                entry["status"] = "unchanged"
                run.unit_priors.pop(camp, None)
                run.own_parameters.pop(rid, None)
                progress.advance("science", note=camp)
                progress.advance("store", note=camp)
                continue
            if not chunk:
                size = guided_chunk(len(wave) - k, most, run.in_flight)
            chunk.append((entry, inputs))
            if len(chunk) >= size:
                _submit_chunk(wh, sess, chunk, inflight, computed, most, run)
                chunk = []
        if chunk:
            _submit_chunk(wh, sess, chunk, inflight, computed, most, run)
        while inflight:
            _collect_chunk(wh, sess, inflight.popleft(), computed, run)
        _store(wh, sess, computed, run)


def _waves(wh: Warehouse, sess: _Session, campaigns: list[str], run: _Run):
    """The campaigns in waves, with each one's (unit, start of its first run, all
    simulated): a campaign's wave is the number of real campaigns of its unit among
    ``campaigns`` dated before it, so each is computed after every earlier calibration
    of its unit it may take priors from is stored (a simulated result is never one).
    One wave when no unit has two real campaigns here (a fleet of simulated units)."""
    dates: dict = {}
    t0 = time.perf_counter()
    window = campaigns_per_plan()
    for start in range(0, len(campaigns), window):
        sess.touch()
        dates.update(wh.campaign_dates(campaigns[start:start + window]))
    run.tick("plan", t0)
    real: dict[str, list] = {}
    for c, (serial, at, sim) in dates.items():
        if at is not None and not sim:
            real.setdefault(serial, []).append(at)
    waves: dict[int, list[str]] = {}
    for c in campaigns:
        serial, at, _ = dates.get(c, (None, None, True))
        n = 0 if at is None else sum(1 for t in real.get(serial, ()) if t < at)
        waves.setdefault(n, []).append(c)
    for n in sorted(waves):
        yield waves[n], dates


def _planned(wh: Warehouse, sess: _Session, campaigns: list[str], dates: dict, run: _Run):
    """(campaign, its input runs, its current result_id, simulated runs left out) for each
    campaign in order, read from the warehouse a window of ``campaigns_per_plan()`` at a
    time (one plan per campaign), so what the run holds of the plans is bounded by the
    window, not the fleet.  Each campaign's unit priors go to ``run.unit_priors``."""
    window = campaigns_per_plan()
    for start in range(0, len(campaigns), window):
        names = campaigns[start:start + window]
        t0 = time.perf_counter()
        sess.touch()
        plans = wh.campaign_plans(names)
        left_out = wh.simulated_left_out(names)
        run.unit_priors.update(wh.unit_priors({c: dates[c] for c in names if c in dates}))
        run.tick("plan", t0)
        for camp in names:
            inputs, current = plans.pop(camp)
            yield camp, inputs, current, left_out.get(camp, 0)


def _submit_chunk(wh: Warehouse, sess: _Session, chunk: list, inflight: deque,
                  computed: list, most: int, run: _Run) -> None:
    """Submit one chunk's load + science; then collect the oldest chunks until fewer than
    ``in_flight * most`` campaigns are in flight."""
    t0 = time.perf_counter()
    known = [run.unit_priors.pop(e["campaign"], None) for e, _ in chunk]
    inflight.append((chunk, run.steps.submit_campaigns(
        str(wh.root), [inputs for _, inputs in chunk], run.parameters,
        *([known] if any(known) else []))))
    run.tick("science (submit)", t0)
    # bounded in campaigns, not tasks: the guided chunks shrink at the end, and a
    # bound in tasks let the workers run dry behind one long chunk still computing
    while sum(len(c) for c, _ in inflight) >= run.in_flight * most:
        _collect_chunk(wh, sess, inflight.popleft(), computed, run)


def _collect_chunk(wh: Warehouse, sess: _Session, done: tuple, computed: list,
                   run: _Run) -> None:
    """Wait for one chunk's outcomes: a failed campaign's entry says why, a computed one
    joins ``computed``, which is stored once it holds ``campaigns_per_store()``."""
    chunk, fut = done
    t0 = time.perf_counter()
    try:
        outcomes = fut.result()
    except Exception as e:           # the task itself failed: every campaign in it
        outcomes = [(None, f"{type(e).__name__}: {e}")] * len(chunk)
    run.tick("science (wait)", t0)
    for (entry, inputs), (result, info) in zip(chunk, outcomes):
        progress.advance("science", note=entry["campaign"])
        if result is None:
            entry["status"], entry["error"] = "failed", info
            progress.advance("store", note=entry["campaign"])
            continue
        for k, v in info.items():
            run.tick(k, 0.0, v)
        missing = set(result.input_sha256) - {i["sha256"] for i in inputs}
        if missing:
            result.flags.append(f"science reported inputs not handed to it: {sorted(missing)}")
        computed.append((entry, result, inputs))
    if len(computed) >= campaigns_per_store():
        _store(wh, sess, computed, run)


def _store(wh: Warehouse, sess: _Session, computed: list, run: _Run) -> None:
    """Store the computed campaigns waiting in ONE transaction (columnar); empties
    ``computed`` once they are stored."""
    if not computed:
        return
    t0 = time.perf_counter()
    sess.touch()
    own = {e["result_id"]: run.own_parameters.pop(e["result_id"]) for e, _, _ in computed
           if e["result_id"] in run.own_parameters}
    statuses = run.steps.store_campaigns(
        wh, [(r, e["result_id"], i) for e, r, i in computed], code_version=run.code_version,
        parameters=run.parameters, flow_run_id=run.flow_run_id,
        **({"own_parameters": own} if own else {}))
    for (entry, _, _), st in zip(computed, statuses):
        entry["status"] = st
    del computed[:]
    run.tick("store", t0)


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
                              parameters: dict | None = None, settle: float | None = None,
                              snapshot: bool = True, allow_simulated: bool = False) -> dict:
            from prefect.runtime import flow_run
            return pipeline_body(drops, warehouse, lock_timeout=lock_timeout,
                                 parameters=parameters, steps=PrefectSteps(),
                                 flow_run_id=str(flow_run.id), settle=settle,
                                 snapshot=snapshot, allow_simulated=allow_simulated)

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
    address tcp://HOST:PORT (accelcal.flows.runners)."""
    from .runners import RunnerError, task_runner_for
    try:
        return task_runner_for(name)
    except RunnerError as e:
        raise PipelineError(str(e)) from None


#: Seconds Prefect's temporary API server may take to answer (its default, 20 s, is
#: exceeded on a loaded machine; $PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS wins).
SERVER_START_S = 180


@contextlib.contextmanager
def _prefect_api(task_runner: str):
    """Prefect's temporary API server for the flow, started here rather than by the flow's
    client: its start gets time on a loaded machine and its failure is one line; its loss
    during the run stops the run at once (:func:`_watch_server`) instead of Prefect's
    minute of retries.  With a local Dask cluster its address goes to the workers
    (PREFECT_API_URL, inherited when the cluster spawns them), else each worker started a
    server of its own.  Nothing is started when an API is configured."""
    from prefect.settings import (PREFECT_API_URL, PREFECT_SERVER_EPHEMERAL_ENABLED,
                                  PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS)
    if PREFECT_API_URL.value() or not PREFECT_SERVER_EPHEMERAL_ENABLED.value():
        yield
        return
    from prefect.server.api.server import SubprocessASGIServer
    import threading
    server = SubprocessASGIServer()      # the one the flow's client would start (one a process)
    done = threading.Event()
    _spawn_deaf_to_ctrl_c(server, lambda proc: _watch_server(proc, done))
    limit = (PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS.value()
             if "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS" in os.environ else SERVER_START_S)
    try:
        server.start(timeout=limit)
    except Exception as e:
        done.set()
        server.stop()
        why = str(e).split(" stdout:")[0]
        raise PipelineError(f"Prefect's temporary API server did not start ({why}); the "
                            f"machine may be overloaded: run again, or use --engine local") from None
    before = os.environ.get("PREFECT_API_URL")
    if task_runner == "dask":
        os.environ["PREFECT_API_URL"] = server.api_url
    try:
        yield
    finally:
        done.set()
        if task_runner == "dask":
            if before is None:
                os.environ.pop("PREFECT_API_URL", None)
            else:
                os.environ["PREFECT_API_URL"] = before


def _spawn_deaf_to_ctrl_c(server, watch) -> None:
    """Start Prefect's server with SIGINT ignored (inherited through exec): the terminal's
    Ctrl-C reaches the whole foreground group, and a server still importing would print
    its own "Aborted!"; the run stops it itself (accelcal.procguard), and what the server
    prints as it is stopped is dropped (uvicorn takes SIGINT back once it serves, so a
    Ctrl-C starts its own shutdown too).  ``watch(process)`` is called on each server
    process as soon as it is started (its loss during the start too)."""
    import signal
    import threading
    from ..procguard import hushed_when_stopping
    spawn = type(server)._run_uvicorn_command.__get__(server)     # Prefect's own, once
    main = threading.current_thread() is threading.main_thread()

    def deaf():
        before = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            with hushed_when_stopping():
                proc = spawn()
        finally:
            if main:
                signal.signal(signal.SIGINT, before)
        watch(proc)
        return proc
    server._run_uvicorn_command = deaf


def _watch_server(proc, done) -> None:
    """Stop the run at once (accelcal.procguard.stop_now) when Prefect's server process
    ends before the event ``done`` is set (exit code 3, a port taken, is Prefect's to
    retry).  A server ended by SIGINT or its own clean
    shutdown was stopped by the terminal's Ctrl-C, which reaches the foreground group:
    exit 130, as the interrupt itself says (its handler usually acts first); anything
    else is a lost server: exit 1.  Only in a command under the process guard: a flow
    called in another program leaves the loss to Prefect's client."""
    import threading

    from ..procguard import guarded, stop_now
    if not guarded():
        return

    def watch() -> None:
        while not done.wait(0.2):
            rc = proc.poll()
            if rc is None:
                continue
            if rc == 3:
                return
            if done.wait(1.0):        # the run ended meanwhile, or the interrupt acts
                return
            if rc in (0, -2):
                stop_now("interrupted; what was committed stays, a re-run completes the rest", 130)
            stop_now(f"Prefect's API server stopped during the run (exit code {rc}); what was "
                     "committed stays, a re-run completes the rest", 1)

    threading.Thread(target=watch, name="accelcal-prefect-server", daemon=True).start()


def _lost_api(e: BaseException) -> bool:
    """Whether ``e`` says the Prefect API could not be reached (not a fault of the run)."""
    import httpx
    from prefect.exceptions import PrefectHTTPStatusError
    return isinstance(e, (httpx.TransportError, PrefectHTTPStatusError))


def run_pipeline(drops: list[str], warehouse: str | Path, *, engine: str = "prefect",
                 lock_timeout: float = 60.0, parameters: dict[str, Any] | None = None,
                 task_runner: str = "thread", settle: float | None = None,
                 create: bool = True, snapshot: bool = True,
                 allow_simulated: bool = False, workers: int | None = None) -> dict[str, Any]:
    """Process drops into a warehouse.  Raises PipelineError / WarehouseError / StoreError
    (one line each) when it cannot work.  ``create``: make the warehouse's folder if it
    does not exist (the CLI asks for ``--create``).  ``workers`` (local engine; default
    $ACCELCAL_WORKERS or 1): processes that run the ingest/validate batches and the
    campaign science, so a fleet uses every core; the warehouse writes stay in the flow
    process (one writer), and the results are the same whatever the number.  The
    worker processes are spawned, so a script that calls this with workers > 1 must
    guard its entry point (``if __name__ == "__main__":``), as for any spawned pool:
    each worker imports the script's main module."""
    drops = check_drops(list(drops))
    if not drops:
        raise PipelineError("no drop given")
    warehouse = str(Path(warehouse).expanduser().resolve())
    if path_text(warehouse) != warehouse:
        raise PipelineError(f"the warehouse path {path_text(warehouse)} is not UTF-8")
    Warehouse(warehouse, lock_timeout=lock_timeout).check_place(create=create, drops=drops)
    kw = dict(lock_timeout=lock_timeout, parameters=parameters, settle=settle, snapshot=snapshot,
              allow_simulated=allow_simulated)
    t0 = time.perf_counter()
    if engine == "local":
        if task_runner != "thread":
            raise PipelineError("--task-runner needs the prefect engine")
        n = local_workers() if workers is None else workers
        if n < 1:
            raise PipelineError(f"--workers must be at least 1, not {n}")
        with _local_pool(n) as pool:
            summary = pipeline_body(drops, warehouse, steps=LocalSteps(pool),
                                    flow_run_id=f"local-{uuid.uuid4()}", **kw)
        summary["workers"] = n
    elif engine == "prefect":
        if workers not in (None, 1):
            raise PipelineError("--workers is for the local engine (the prefect engine's "
                                "dask runner takes $ACCELCAL_DASK_WORKERS)")
        # Fail fast (before the Prefect server starts) when the warehouse is busy.
        wh = Warehouse(warehouse, lock_timeout=lock_timeout)
        runner = _task_runner(task_runner)
        with wh.lock(), _prefect_api(task_runner):
            fl = pipeline_flow()
            if runner is not None:
                fl = fl.with_options(task_runner=runner)
            try:
                summary = fl(drops=drops, warehouse=warehouse, lock_timeout=lock_timeout,
                             parameters=parameters or {}, settle=settle, snapshot=snapshot,
                             allow_simulated=allow_simulated)
            except Exception as e:
                if not _lost_api(e):
                    raise
                raise PipelineError(f"lost Prefect's API server ({type(e).__name__}: {e}); what "
                                    "was committed stays, a re-run completes the rest") from None
    else:
        raise PipelineError(f"unknown engine {engine!r} (choose from {', '.join(ENGINES)})")
    summary["engine"] = engine
    summary["timings"]["total"] = time.perf_counter() - t0
    return summary


__all__ = ["run_pipeline", "pipeline_body", "pipeline_flow", "PipelineError", "WarehouseError",
           "StoreError",
           "quiet_prefect", "ENGINES", "TASK_RUNNERS"]

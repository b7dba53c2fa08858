"""Scheduled processing of a watched folder: ``accelcal serve --watch DIR``.

What is a drop here
    Every immediate sub-folder of DIR is a drop (drop-format.md: "a folder that
    a DAQ station fills").  If DIR itself directly holds ``*.csv`` files, DIR
    is treated as one drop instead.

When is a drop processed
    A *pass* looks at every drop.  A drop is handed to the pipeline when it has
    new or changed ``*.csv`` files and all its files are *settled*: no
    ``*.part`` file in it, and every ``*.csv`` has the same (size, mtime) as at
    the previous look (or was last modified more than ``settle`` seconds ago).
    A ``*.part`` file unchanged for longer than ``part_stale`` seconds (default an
    hour) is a copy that died, not one under way: it is logged once and the rest
    of the drop goes ahead, as ``accelcal run`` (which reads only ``*.csv``) does.
    A file still being written therefore holds its drop back to the next pass
    (the pipeline works per drop; computing a campaign from half its runs would
    only add a result superseded minutes later).  Each file is processed once:
    the pass remembers the (size, mtime) it processed, and the pipeline itself
    skips bytes it already holds (same sha256 at the same path).

    Pass state is kept in ``<warehouse stem>-watch.json`` next to the warehouse
    (flow runs execute in subprocesses, so it must live on disk); it is written
    atomically and may be deleted at any time (the next pass then re-hashes
    files, adding nothing to the warehouse).  It also holds the last 50 pass
    records (what was seen, processed, held back and why, refused, computed),
    which ``accelcal status`` shows.  They live there, not in the warehouse,
    because status must answer while a pass holds the warehouse (DuckDB lets no
    reader in while the writer has the file open), and they are operations
    records, not results: nothing in the append-only warehouse depends on them.

What a pass says
    Every pass logs (logger ``accelcal.serve``, to stderr) one line with the
    counts, then one line per drop held back (and why), per drop processed, per
    refused file (file:line: rule) and per campaign result.

How passes are triggered
    ``serve()`` builds the Prefect deployment ``accelcal-watch/<name>`` of
    :data:`watch_flow` and serves it from this process (``flow.serve``): a
    cron schedule (``--cron``) and, with ``--poll S``, a file-watch thread that
    looks at DIR every S seconds (stat only) and asks the server for a flow
    run of the deployment (``run_deployment``) when *.csv files appeared or
    changed.  Schedules need a real Prefect server (its scheduler service):
    set ``PREFECT_API_URL`` (see accelcal/warehouse/README.md, "Scheduled
    processing").  Without it Prefect starts an ephemeral server that never
    fires schedules; ``serve`` then warns and relies on ``--poll``.
"""
from __future__ import annotations

import json
import logging
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("accelcal.serve")
#: Refused files named one by one in a pass's log (the rest are counted).
LOG_REFUSALS_MAX = 20


def setup_logging() -> None:
    """Pass logs to stderr at INFO, in the serve process and in each flow-run subprocess
    (Prefect's own loggers stay at their level)."""
    if not any(getattr(h, "_accelcal", False) for h in log.handlers):
        h = logging.StreamHandler()
        h.setFormatter(logging.Formatter("%(asctime)s accelcal.serve %(message)s"))
        h._accelcal = True
        log.addHandler(h)
    log.setLevel(logging.INFO)
    log.propagate = False

FLOW_NAME = "accelcal-watch"
DEFAULT_DEPLOYMENT = "accelcal-watch"
DEFAULT_SETTLE_S = 30.0
#: A *.part file unchanged for this long [s] no longer holds its drop back.
DEFAULT_PART_STALE_S = 3600.0


# ------------------------------------------------------------------ scanning --

def find_drops(watch_dir: str | Path) -> list[Path]:
    root = Path(watch_dir).expanduser().resolve()
    if not root.is_dir():
        return []
    if any(p.suffix.lower() == ".csv" and p.is_file() for p in root.iterdir()):
        return [root]
    return sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))


def snapshot(drop: Path) -> tuple[dict[str, list[int]], list[str]]:
    """({csv path: [size, mtime_ns]}, [partial files]) of one drop, by stat only.

    The run files are those of ``scan_drop`` (shared with ``run``: links are not followed,
    entries it refuses -- links, FIFOs, bad names -- are left to the pipeline, which
    records why); ``*.part`` files are found without following links either."""
    from ..schemas.dropscan import scan_drop
    files: dict[str, list[int]] = {}
    partial: list[str] = []
    try:
        for e in scan_drop(drop):
            if e.refusal is None:
                files[e.path] = [e.size, e.mtime_ns]
    except OSError:            # the drop itself vanished or cannot be listed: next pass
        partial.append(str(drop))
    for folder, dirs, names in os.walk(drop):
        partial += [os.path.join(folder, n) for n in names if n.lower().endswith(".part")]
    return files, sorted(partial)


def state_path_for(warehouse: str | Path) -> Path:
    w = Path(warehouse).expanduser().resolve()
    return w.parent / f"{w.stem}-watch.json"


def load_state(path: Path) -> dict[str, Any]:
    try:
        st = json.loads(path.read_text())
        if isinstance(st, dict):
            st.setdefault("seen", {})
            st.setdefault("processed", {})
            st.setdefault("passes", [])
            return st
    except (OSError, ValueError):
        pass
    return {"seen": {}, "processed": {}, "passes": []}


def save_state(path: Path, st: dict[str, Any]) -> None:
    st["passes"] = st["passes"][-50:]
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(st, indent=1, default=str))
    os.replace(tmp, path)


@dataclass
class PassPlan:
    ready: list[str] = field(default_factory=list)              # drops to process now
    waiting: dict[str, str] = field(default_factory=dict)       # drop -> reason
    unchanged: list[str] = field(default_factory=list)          # drops with nothing new
    stale: dict[str, float] = field(default_factory=dict)        # stale *.part -> age [s], new
    files: dict[str, dict[str, list[int]]] = field(default_factory=dict)


def _fresh_partials(drop: Path, partial: list[str], now: float, part_stale: float,
                    st: dict[str, Any], plan: PassPlan) -> list[str]:
    """The partial files that still hold the drop back; stale ones (unchanged for
    ``part_stale`` s) are noted in ``plan.stale`` the first time they are seen stale."""
    fresh = []
    logged = st.setdefault("stale_parts", {})
    for p in partial:
        try:
            mtime = os.lstat(p).st_mtime if p != str(drop) else now
        except OSError:
            continue                        # gone since the look: it holds nothing back
        age = now - mtime
        if age < part_stale:
            fresh.append(p)
        elif logged.get(p) != mtime:
            logged[p] = mtime
            plan.stale[p] = age
    return fresh


def plan_pass(watch_dir: str | Path, st: dict[str, Any], settle: float = DEFAULT_SETTLE_S,
              now: float | None = None, part_stale: float = DEFAULT_PART_STALE_S) -> PassPlan:
    """Decide which drops are ready; updates st['seen'] (the look) and st['stale_parts']
    (stale partial files already logged) in place."""
    now = time.time() if now is None else now
    plan = PassPlan()
    seen_all: dict[str, list[int]] = {}
    for drop in find_drops(watch_dir):
        files, partial = snapshot(drop)
        partial = _fresh_partials(drop, partial, now, part_stale, st, plan)
        plan.files[str(drop)] = files
        new = {p: sig for p, sig in files.items() if st["processed"].get(p) != sig}
        if not new:
            if partial:
                plan.waiting[str(drop)] = f"partial file {Path(partial[0]).name}"
            else:
                plan.unchanged.append(str(drop))
            seen_all.update(files)
            continue
        if partial:
            plan.waiting[str(drop)] = f"partial file {Path(partial[0]).name} still being written"
        else:
            growing = [p for p, sig in new.items()
                       if st["seen"].get(p) != sig and (now - sig[1] / 1e9) < settle]
            if growing:
                why = ("first look, looking again next pass" if growing[0] not in st["seen"]
                       else "size/mtime changed since the last look")
                plan.waiting[str(drop)] = f"{Path(growing[0]).name}: {why}"
            else:
                plan.ready.append(str(drop))
        seen_all.update(files)
    st["seen"] = seen_all
    return plan


def _pass_summary(summary: dict[str, Any]) -> dict[str, Any]:
    """What a pass record keeps of the pipeline's summary: the counts per drop and, apart
    (bounded: at most LOG_REFUSALS_MAX per drop, the rest counted), the details."""
    drops = [{k: d[k] for k in ("drop", "files", "accepted", "refused", "new")}
             for d in summary["drops"]]
    details = {d["drop"]: {
        "refused_files": [{"path": r["path"], "reason": r["reason"]}
                          for r in d["refused_files"][:LOG_REFUSALS_MAX]],
        "simulated_held": [dict(r) for r in (d.get("simulated_held") or [])[:LOG_REFUSALS_MAX]],
        "errors": list(d.get("errors") or [])[:LOG_REFUSALS_MAX]} for d in summary["drops"]}
    camps = [{k: c.get(k) for k in ("campaign", "status", "n_runs", "current_result_id",
                                     "completeness", "simulated", "error")}
             for c in summary["campaigns"]]
    return {"flow_run_id": summary.get("flow_run_id"), "drops": drops, "details": details,
            "campaigns": camps}


def pass_lines(out: dict[str, Any]) -> list[str]:
    """The log lines of one pass record: counts, then what was held back and why, what
    was processed, every refusal (file:line: rule: detail) and every result."""
    summ = out.get("summary") or {}
    n_seen = len(out.get("ready", [])) + len(out.get("waiting", {})) + int(out.get("unchanged", 0))
    refused = sum(d.get("refused", 0) for d in summ.get("drops", []))
    lines = [f"pass: {n_seen} drop(s) seen, {len(out.get('ready', []))} processed, "
             f"{len(out.get('waiting', {}))} held back, {out.get('unchanged', 0)} unchanged; "
             f"{refused} file(s) refused, {len(summ.get('campaigns', []))} campaign(s) computed"
             + (f"; FAILED: {out['error']}" if out.get("error") else "")
             + f" ({out.get('seconds', 0):.1f} s)"]
    for drop, why in sorted((out.get("waiting") or {}).items()):
        lines.append(f"held back {Path(drop).name}: {why}")
    for part, age in sorted((out.get("stale_parts") or {}).items()):
        lines.append(f"ignored {part}: a partial file unchanged for {age / 3600:.1f} h (a copy that "
                     "stopped); the rest of its drop goes ahead")
    for d in summ.get("drops", []):
        det = (summ.get("details") or {}).get(d["drop"]) or {}
        lines.append(f"processed {d['drop']}: {d['files']} file(s), {d['accepted']} accepted, "
                     f"{d['refused']} refused, {d['new']} new")
        for r in det.get("refused_files", []):
            lines.append(f"refused {r['reason'] or r['path']}")
        if d["refused"] > len(det.get("refused_files", [])):
            lines.append(f"... and {d['refused'] - len(det.get('refused_files', []))} more "
                         f"refused in {d['drop']} (the runs view lists them all)")
        for r in det.get("simulated_held", []):
            lines.append(f"refused {r['path']}:{r['line']}: simulated: simulated data are "
                         "not stored by serve")
        for e in det.get("errors", []):
            lines.append(f"not ingested {e}")
    for c in summ.get("campaigns", []):
        rid = (c.get("current_result_id") or "")[:12]
        extra = [x for x in (c.get("completeness") if c.get("completeness") == "incomplete" else None,
                             "simulated" if c.get("simulated") else None, c.get("error")) if x]
        lines.append(f"result {c['campaign']}: {c['status']}" + (f", current {rid}" if rid else "")
                     + (f" ({'; '.join(extra)})" if extra else ""))
    return lines


def log_pass(out: dict[str, Any]) -> None:
    for line in pass_lines(out):
        log.info("%s", line)


def watch_pass(watch_dir: str, warehouse: str, settle: float = DEFAULT_SETTLE_S,
               engine: str = "local", lock_timeout: float = 600.0,
               task_runner: str = "thread", part_stale: float = DEFAULT_PART_STALE_S) -> dict[str, Any]:
    """One pass: plan, run the pipeline on ready drops, remember what was processed, log
    what happened (:func:`pass_lines`) and keep the record in the state file."""
    from ..flows.pipeline import run_pipeline
    from ..warehouse.lock import warehouse_lock
    sp = state_path_for(warehouse)
    sp.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    # The state file is guarded by the warehouse lock: one pass at a time.
    with warehouse_lock(Path(warehouse).expanduser().resolve(), timeout=lock_timeout):
        st = load_state(sp)
        plan = plan_pass(watch_dir, st, settle=settle, part_stale=part_stale)
        out: dict[str, Any] = {"started": t0, "watch": str(Path(watch_dir).expanduser().resolve()),
                               "ready": plan.ready, "waiting": plan.waiting,
                               "stale_parts": {p: round(a, 1) for p, a in plan.stale.items()},
                               "unchanged": len(plan.unchanged), "summary": None, "error": None}
        if plan.ready:
            try:
                # the lab's stated rig inputs, read each pass (./accelcal.toml or beside the
                # warehouse), so that a corrected file takes effect at the next drop
                from ..config import run_parameters
                summary = run_pipeline(plan.ready, warehouse, engine=engine,
                                       lock_timeout=lock_timeout, task_runner=task_runner,
                                       parameters=run_parameters(None, warehouse))
                out["summary"] = _pass_summary(summary)
                for d in plan.ready:
                    for p, sig in plan.files[d].items():
                        st["processed"][p] = sig
            except Exception as e:   # leave the drops unprocessed: the next pass retries
                out["error"] = f"{type(e).__name__}: {e}"
        out["seconds"] = round(time.time() - t0, 3)
        st["passes"].append(out)
        save_state(sp, st)
    log_pass(out)
    return out


# ------------------------------------------------------------------- prefect --

def _make_flow():
    from prefect import flow

    @flow(name=FLOW_NAME, persist_result=False, validate_parameters=False, log_prints=False)
    def accelcal_watch(watch_dir: str, warehouse: str, settle: float = DEFAULT_SETTLE_S,
                       lock_timeout: float = 600.0, task_runner: str = "thread",
                       part_stale: float = DEFAULT_PART_STALE_S) -> dict:
        """Process the settled new drops of watch_dir into the warehouse (one pass)."""
        from ..flows.pipeline import quiet_prefect
        quiet_prefect(os.environ.get("PREFECT_LOGGING_LEVEL", "WARNING"))
        setup_logging()
        return watch_pass(watch_dir, warehouse, settle=settle, engine="prefect",
                          lock_timeout=lock_timeout, task_runner=task_runner, part_stale=part_stale)

    return accelcal_watch


try:                       # module-level so the runner can load it by module path
    watch_flow = _make_flow()
except ImportError:        # pragma: no cover - prefect missing
    watch_flow = None


def _changed_since(watch_dir: str, last: dict[str, list[int]]) -> tuple[bool, dict]:
    now: dict[str, list[int]] = {}
    for d in find_drops(watch_dir):
        files, partial = snapshot(d)
        now.update(files)
        for p in partial:
            now[p] = [-1, -1]
    return now != last, now


def _poll_loop(deployment: str, watch_dir: str, every: float, stop: threading.Event,
               settle: float) -> None:
    """Trigger a flow run of the deployment when files appear or change (stat only)."""
    from prefect.deployments import run_deployment
    last: dict[str, list[int]] = {}
    pending = False
    while not stop.wait(every):
        try:
            changed, now = _changed_since(watch_dir, last)
            if changed:
                last = now
                pending = True           # wait for one quiet look before triggering
                continue
            if pending:
                pending = False
                # the quiet look above is the settle check: a file unchanged for one
                # poll interval counts as settled in this pass
                run_deployment(deployment, timeout=0, as_subflow=False,
                               parameters={"settle": min(settle, every)},
                               tags=["accelcal", "file-watch"])
                log.info("file-watch: triggered %s", deployment)
        except Exception as e:          # the server may be restarting: keep watching
            log.warning("file-watch: %s: %s", type(e).__name__, e)


def _stop_on_sigterm() -> None:
    """SIGTERM stops serving cleanly.

    Prefect's runner answers SIGTERM by calling its sync ``stop()`` from inside its
    running event loop, where the dispatcher hands back the ``astop()`` coroutine
    unawaited ("coroutine 'Runner.astop' was never awaited") and then exits.  Here the
    handler schedules ``astop()`` on that loop instead: the runner cancels its loops,
    ``flow.serve`` returns and ``serve`` returns normally (the CLI prints "stopped").
    Only the serve process's Runner class is changed, not flow runs.
    """
    import asyncio

    from prefect.runner import Runner

    def handle_sigterm(self, *args, **kwargs):
        log.info("SIGTERM received: stopping")
        loop = asyncio.get_running_loop()       # the runner's loop, in this (main) thread
        self._accelcal_stop = loop.create_task(self.astop())

    Runner.handle_sigterm = handle_sigterm


def serve(watch_dir: str, warehouse: str, *, cron: str | None = None,
          poll: float | None = None, settle: float = DEFAULT_SETTLE_S,
          name: str = DEFAULT_DEPLOYMENT, lock_timeout: float = 600.0,
          task_runner: str = "thread", limit: int | None = 1,
          part_stale: float = DEFAULT_PART_STALE_S) -> None:
    """Serve the watch flow as a deployment from this process until interrupted."""
    from prefect.settings import PREFECT_API_URL
    if watch_flow is None:
        raise RuntimeError("prefect is not installed")
    watch = str(Path(watch_dir).expanduser().resolve())
    wh = str(Path(warehouse).expanduser().resolve())
    if not Path(watch).is_dir():
        raise FileNotFoundError(f"watch folder {watch} does not exist")
    if cron and not PREFECT_API_URL.value():
        log.warning("no PREFECT_API_URL: an ephemeral Prefect server does not run schedules; "
                    "the cron %r will not fire (start `prefect server start` and set "
                    "PREFECT_API_URL); file watching (--poll) still works", cron)
    params = {"watch_dir": watch, "warehouse": wh, "settle": settle,
              "lock_timeout": lock_timeout, "task_runner": task_runner, "part_stale": part_stale}
    stop = threading.Event()
    poller = None
    if poll:
        poller = threading.Thread(target=_poll_loop, name="accelcal-file-watch",
                                  args=(f"{FLOW_NAME}/{name}", watch, float(poll), stop, settle),
                                  daemon=True)
        poller.start()
    from prefect.flows import EntrypointType
    _stop_on_sigterm()
    setup_logging()
    log.info("serving %s: watching %s into %s (cron %s, poll %s s)", f"{FLOW_NAME}/{name}",
             watch, wh, cron or "none", poll or "off")
    try:
        watch_flow.serve(name=name, cron=cron, parameters=params, limit=limit,
                         description=f"accelcal: process settled drops of {watch} into {wh}",
                         tags=["accelcal"], pause_on_shutdown=False,
                         entrypoint_type=EntrypointType.MODULE_PATH)
    finally:
        stop.set()


# -------------------------------------------------------------------- status --

def _holder(warehouse: str | Path) -> str | None:
    """The pid holding the warehouse's writer lock, when a live process holds it."""
    from ..warehouse.lock import lock_path_for
    try:
        txt = lock_path_for(Path(warehouse).expanduser().resolve()).read_text().strip()
        pid = int(txt)
        os.kill(pid, 0)
        return str(pid)
    except (OSError, ValueError):
        return None


def status_lines(warehouse: str | Path, n: int = 5, watch_dir: str | Path | None = None,
                 settle: float = DEFAULT_SETTLE_S,
                 part_stale: float = DEFAULT_PART_STALE_S) -> list[str]:
    """What ``accelcal status`` prints: who holds the warehouse, the last ``n`` passes
    (the lines each logged), and what waits: the last pass's held-back drops, the files
    seen but not yet processed and, with ``watch_dir``, a fresh look (nothing recorded)."""
    import copy
    import datetime as dt
    sp = state_path_for(warehouse)
    out = [f"warehouse {Path(warehouse).expanduser().resolve()}"]
    pid = _holder(warehouse)
    out.append(f"busy: pid {pid} holds the warehouse (a pass or a run is working)" if pid
               else "idle: no process holds the warehouse")
    if not sp.exists():
        out.append(f"no pass recorded ({sp} does not exist): `accelcal serve` has not run here")
        st = load_state(sp)
    else:
        st = load_state(sp)
        passes = st["passes"][-n:]
        out.append(f"last {len(passes)} of {len(st['passes'])} recorded passes ({sp}):")
        for p in passes:
            when = dt.datetime.fromtimestamp(float(p.get("started", 0))).astimezone()
            lines = pass_lines(p)
            out.append(f"  {when:%Y-%m-%d %H:%M:%S %Z} {lines[0]}")
            out.extend(f"      {x}" for x in lines[1:])
        if passes:
            last = passes[-1]
            waiting = last.get("waiting") or {}
            out.append("waiting at the last pass: " + ("nothing" if not waiting else ""))
            out.extend(f"  {Path(d).name}: {why}" for d, why in sorted(waiting.items()))
    pending: dict[str, int] = {}
    for p, sig in st.get("seen", {}).items():
        if st["processed"].get(p) != sig:
            pending[str(Path(p).parent)] = pending.get(str(Path(p).parent), 0) + 1
    if pending:
        out.append("seen but not processed yet:")
        out.extend(f"  {k}: {v} file(s)" for k, v in sorted(pending.items()))
    if watch_dir is not None:
        plan = plan_pass(watch_dir, copy.deepcopy(st), settle=settle, part_stale=part_stale)
        stored = _stored_files(warehouse)
        if stored is None:
            ready, known = plan.ready, []
            out.append("(the warehouse is busy: the watch folder is not compared with it)")
        else:
            known = [d for d in plan.ready
                     if all((p, sig[0]) in stored for p, sig in plan.files[d].items())]
            ready = [d for d in plan.ready if d not in known]
        out.append(f"a pass now would process {len(ready)} drop(s)"
                   + (": " + ", ".join(Path(d).name for d in ready) if ready else ""))
        if known:
            out.append("  already in the warehouse (every file, same path and size): "
                       + ", ".join(Path(d).name for d in known))
        out.extend(f"  held back {Path(d).name}: {why}" for d, why in sorted(plan.waiting.items()))
        out.extend(f"  ignored {p}: a partial file unchanged for {a / 3600:.1f} h"
                   for p, a in sorted(plan.stale.items()))
    return out


def _stored_files(warehouse: str | Path) -> set[tuple[str, int]] | None:
    """(source path, size) of every file the warehouse holds, or None when it cannot be
    read now (a run holds it)."""
    import duckdb

    from ..warehouse.db import Warehouse
    from ..warehouse.errors import WarehouseError
    try:                                    # DuckDB refuses a reader while a writer has it
        rows = Warehouse(Path(warehouse).expanduser().resolve()).query(
            "SELECT DISTINCT source_path, size_bytes FROM run_files")
    except (WarehouseError, OSError, duckdb.Error):
        return None
    return {(r["source_path"], int(r["size_bytes"])) for r in rows}

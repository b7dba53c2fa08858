"""Dask preload: make a standing cluster ready for accelcal's tasks at start.

A lab that processes drops every night keeps a Dask cluster running and points the
pipeline at it (``accelcal run --task-runner tcp://HOST:PORT``).  Start it with

    dask scheduler --preload accelcal.ops.dask_preload
    dask worker tcp://HOST:PORT --nthreads 1 --preload accelcal.ops.dask_preload

Each worker, once, when it starts (not inside the first run's first batch): imports
great-expectations, Prefect's task engine and the science, and validates two of the
bundled demo runs (a tumble and a centrifuge run) without writing anything, which builds
great-expectations' context and the suites' expectation specs (~3 s of CPU a process,
paid by every fresh worker).  The scheduler only imports Prefect and accelcal's tasks:
Dask's scheduler unpickles every task it is sent, and the first one made it import them
(~1.2 s between a run's first submit and its first task's start, measured on a fresh
cluster).  A failure here is logged and the process starts anyway: the tasks then do
the same work on first use.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

log = logging.getLogger(__name__)

#: Two runs of the bundled demo drop: one tumble, one centrifuge.
WARM_RUNS = ("SIM-DH1-DEMO-0001.csv", "SIM-LXJ100-DEMO-0002.csv")


def warm() -> float:
    """Import and exercise what the ingest/validate and science tasks use; returns the
    seconds it took.  Writes nothing."""
    t0 = time.perf_counter()
    warm_scheduler()            # Prefect's task engine and accelcal's tasks
    from ..estimators import campaign  # noqa: F401  (the science, imported once)
    from ..schemas.dropformat import read_run
    from ..schemas.suites import validate_report
    from ..tasks import prefect_tasks
    prefect_tasks()
    demo = Path(__file__).resolve().parents[1] / "demo_data" / "drop-demo"
    validate_report([read_run(demo / name) for name in WARM_RUNS], None, "warm-up")
    return time.perf_counter() - t0


def warm_scheduler() -> float:
    """Import what the scheduler needs to unpickle accelcal's task graphs: Dask's
    scheduler unpickles each submitted task (the Prefect task run and its arguments), and
    the first one imported Prefect and accelcal's tasks there, ~1.2 s between the flow's
    first submit and the first task's start.  Returns the seconds it took."""
    t0 = time.perf_counter()
    import prefect.task_engine  # noqa: F401
    from ..tasks import prefect_tasks, science, store, validate  # noqa: F401
    from ..schemas import dropscan  # noqa: F401  (the drop listing's entries)
    return time.perf_counter() - t0


def dask_setup(server=None) -> None:
    """Called at start by ``dask worker ... --preload accelcal.ops.dask_preload`` (warms
    the worker: :func:`warm`) and by ``dask scheduler --preload accelcal.ops.dask_preload``
    (imports only: :func:`warm_scheduler`)."""
    try:
        from distributed import Scheduler
        seconds = warm_scheduler() if isinstance(server, Scheduler) else warm()
    except Exception as e:      # never stop a worker from starting over a warm-up
        log.warning("accelcal warm-up failed (%s: %s); tasks will warm on first use",
                    type(e).__name__, e)
        return
    log.info("accelcal warm-up done in %.1f s", seconds)

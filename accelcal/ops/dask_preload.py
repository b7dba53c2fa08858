"""Dask worker preload: make a standing worker ready for accelcal's tasks at start.

A lab that processes drops every night keeps a Dask cluster running and points the
pipeline at it (``accelcal run --task-runner tcp://HOST:PORT``).  Start its workers with

    dask worker tcp://HOST:PORT --nthreads 1 --preload accelcal.ops.dask_preload

and each worker, once, when it starts (not inside the first run's first batch):
imports great-expectations and the science, and validates two of the bundled demo
runs (a tumble and a centrifuge run) without writing anything, which builds
great-expectations' context and the suites' expectation specs (~3 s of CPU a
process, paid by every fresh worker).  A failure here is logged and the worker
starts anyway: the tasks then do the same work on first use.
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
    from ..estimators import campaign  # noqa: F401  (the science, imported once)
    from ..schemas.dropformat import read_run
    from ..schemas.suites import validate_report
    from ..tasks import science, validate  # noqa: F401
    demo = Path(__file__).resolve().parents[1] / "demo_data" / "drop-demo"
    validate_report([read_run(demo / name) for name in WARM_RUNS], None, "warm-up")
    return time.perf_counter() - t0


def dask_setup(worker=None) -> None:
    """Called by ``dask worker --preload accelcal.ops.dask_preload`` at worker start."""
    try:
        seconds = warm()
    except Exception as e:      # never stop a worker from starting over a warm-up
        log.warning("accelcal warm-up failed (%s: %s); tasks will warm on first use",
                    type(e).__name__, e)
        return
    log.info("accelcal warm-up done in %.1f s", seconds)

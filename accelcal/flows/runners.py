"""Task-runner selection for scale-out (prefect-dask), without code changes to the flow.

``task_runner_for(spec)``:
    None / "" / "thread"      -> None (Prefect's default ThreadPoolTaskRunner)
    "dask"                    -> DaskTaskRunner() on a local Dask cluster (one worker
                                 process per core by default; ACCELCAL_DASK_WORKERS overrides)
    "dask://HOST:PORT" or
    "tcp://HOST:PORT"         -> DaskTaskRunner(address=...) on an existing scheduler

The science tasks receive RunFiles (pandas DataFrames), which Dask pickles to
the workers; the warehouse writes stay in the flow process (one writer).

A standing cluster (the nightly case) should start its scheduler with
``dask scheduler --preload accelcal.ops.dask_preload`` and its workers with
``dask worker tcp://HOST:PORT --nthreads 1 --preload accelcal.ops.dask_preload``: each
worker then imports and warms great-expectations and the science once, at start, and
the scheduler imports what it needs to unpickle the tasks, instead of inside the first
batch of every run (benchmarks/bench_dask_scaling.py).
"""
from __future__ import annotations

import os


class RunnerError(ValueError):
    pass


def task_runner_for(spec: str | None):
    if spec in (None, "", "thread"):
        return None
    try:
        from prefect_dask import DaskTaskRunner
    except ImportError:
        raise RunnerError("the dask task runner needs prefect-dask: "
                          "pip install prefect-dask distributed") from None
    if spec == "dask":
        n = os.environ.get("ACCELCAL_DASK_WORKERS")
        kwargs = {"n_workers": int(n), "threads_per_worker": 1} if n else {}
        return DaskTaskRunner(cluster_kwargs=kwargs) if kwargs else DaskTaskRunner()
    if spec.startswith("dask://"):
        spec = "tcp://" + spec[len("dask://"):]
    if spec.startswith(("tcp://", "tls://", "inproc://")):
        return DaskTaskRunner(address=spec)
    raise RunnerError(f"unknown task runner {spec!r}: thread, dask, or a scheduler address "
                      "tcp://HOST:PORT")

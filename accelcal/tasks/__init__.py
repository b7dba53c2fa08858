"""Prefect tasks wrapping the pipeline's plain functions.

The plain functions live in the modules of this package (ingest, validate,
science, store) and do not need Prefect; :func:`prefect_tasks` wraps them as
Prefect tasks (no caching of inputs: RunFiles hold DataFrames) on first use.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any


class Sealed:
    """A submitted task's large argument, handed to the worker as it is.

    Prefect walks every nested list, dict and tuple of a submitted task's arguments, twice
    (to resolve futures, to record the task's inputs): for a chunk of 25 campaigns' run
    lists that was ~70 ms of the flow process's CPU a task (stack profile of a 2-worker
    Dask run, 200 campaigns), CPU the workers lose on a machine with as many workers as
    cores.  An instance of a plain class is a leaf to that walk, and Dask pickles it whole.
    (Prefect's own ``quote`` is a namedtuple, which Dask takes apart into a bare tuple on
    the way to the worker.)  Only arguments that hold no futures may be sealed."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value


def intake_batch_sealed(drop_dir: str, paths: Sealed, parquet_root: str, warehouse_root: str,
                        known: Sealed, docs_root: str, part, allow_simulated: bool = False):
    """:func:`accelcal.tasks.validate.intake_batch` with its entry list and its known
    files sealed (:class:`Sealed`)."""
    from .validate import intake_batch
    return intake_batch(drop_dir, paths.value, parquet_root, warehouse_root, known.value,
                        docs_root, part, allow_simulated)


def load_and_process_sealed(warehouse_root: str, campaigns: Sealed, parameters: Sealed,
                            unit_priors: Sealed | None = None):
    """:func:`accelcal.tasks.science.load_and_process` with its run lists, parameters and
    unit priors sealed (:class:`Sealed`)."""
    from .science import load_and_process
    return load_and_process(warehouse_root, campaigns.value, parameters.value,
                            *(() if unit_priors is None else (unit_priors.value,)))


@dataclass(frozen=True)
class PrefectTasks:
    """The pipeline's plain functions as Prefect tasks (:func:`prefect_tasks`), by name."""
    known_keys: Any
    record_drop: Any
    intake_batch: Any
    load_and_process: Any
    store_campaigns: Any


@functools.lru_cache(maxsize=1)
def prefect_tasks() -> PrefectTasks:
    from prefect import task
    from prefect.cache_policies import NO_CACHE

    from . import store

    def wrap(fn, name, **kw):
        return task(fn, name=name, cache_policy=NO_CACHE, persist_result=False, **kw)

    return PrefectTasks(
        known_keys=wrap(store.known_keys, "known-files"),
        record_drop=wrap(store.record_drop, "record-runs"),
        intake_batch=wrap(intake_batch_sealed, "ingest-validate-batch"),
        load_and_process=wrap(load_and_process_sealed, "load-process-campaigns"),
        store_campaigns=wrap(store.store_campaigns, "store-results"),
    )

"""Prefect tasks wrapping the pipeline's plain functions.

The plain functions live in the modules of this package (ingest, validate,
science, store) and do not need Prefect; :func:`prefect_tasks` wraps them as
Prefect tasks (no caching of inputs: RunFiles hold DataFrames) on first use.
"""
from __future__ import annotations

import functools
from types import SimpleNamespace


@functools.lru_cache(maxsize=1)
def prefect_tasks() -> SimpleNamespace:
    from prefect import task
    from prefect.cache_policies import NO_CACHE

    from . import science, store, validate

    def wrap(fn, name, **kw):
        return task(fn, name=name, cache_policy=NO_CACHE, persist_result=False, **kw)

    return SimpleNamespace(
        known_keys=wrap(store.known_keys, "known-files"),
        record_drop=wrap(store.record_drop, "record-runs"),
        intake_batch=wrap(validate.intake_batch, "ingest-validate-batch"),
        load_and_process=wrap(science.load_and_process, "load-process-campaigns"),
        store_campaigns=wrap(store.store_campaigns, "store-results"),
    )

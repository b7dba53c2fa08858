"""The pipeline's steps, behind one small interface with two implementations.

:func:`accelcal.flows.pipeline.pipeline_body` composes five steps; where they run is the
engine's business:

- :class:`LocalSteps` calls the plain functions of ``accelcal.tasks`` (in the flow
  process, or the two heavy ones in a process pool's workers);
- :class:`PrefectSteps` calls the same functions as Prefect tasks
  (``accelcal.tasks.prefect_tasks``).

The two heavy steps (a batch's ingest + validate, a chunk of campaigns' load + science)
are *submitted* and return a future (``.result()``); the other three run in the flow
process, which is the warehouse's one writer.
"""
from __future__ import annotations

from typing import Any, Protocol

from ..fileio import path_text
from ..tasks import science as _science
from ..tasks import store as _store
from ..tasks import validate as _validate
from ..tasks.ingest import DropIngest
from ..warehouse.db import KnownFile, Warehouse
from ..warehouse.lineage import validator_version


class Future(Protocol):
    def result(self) -> Any: ...


class Steps(Protocol):
    """What the pipeline asks of an engine."""

    engine: str   # "local" or "prefect": picks the campaigns a science task carries

    def known_keys(self, wh: Warehouse, drop: str) -> dict[tuple[str, str], KnownFile]:
        """Files of ``drop`` already recorded -> their latest verdict."""

    def submit_intake(self, drop: str, batch: list, parquet_root: str, warehouse_root: str,
                      known: dict, docs_root: str, part: int | None,
                      allow_simulated: bool) -> Future:
        """Ingest + validate one batch of a drop's files (tasks.validate.intake_batch);
        the future gives a DropIngest."""

    def record_drop(self, wh: Warehouse, ing: DropIngest, flow_run_id: str,
                    known: dict[tuple[str, str], KnownFile] | None = None) -> list[dict[str, Any]]:
        """Record a batch's verdicts in one transaction (tasks.store.record_drop)."""

    def submit_campaigns(self, warehouse_root: str, campaigns: list[list[dict[str, Any]]],
                         parameters: dict[str, Any],
                         unit_priors: list[dict[str, Any] | None] | None = None) -> Future:
        """Load + compute a chunk of campaigns (tasks.science.load_and_process), with
        per campaign its unit's priors; the future gives one (result, timings) or (None,
        error) per campaign."""

    def store_campaigns(self, wh: Warehouse, items: list[tuple], *, code_version: str,
                        parameters: dict[str, Any], flow_run_id: str,
                        own_parameters: dict[str, dict[str, Any]] | None = None) -> list[str]:
        """Store computed campaigns in one transaction (tasks.store.store_campaigns)."""


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


class LocalSteps:
    """The plain functions; with ``pool`` (a process pool) the two heavy steps run in its
    worker processes, the rest (every warehouse write) in the flow process."""

    engine = "local"

    def __init__(self, pool=None):
        self._submit = _Done if pool is None else pool.submit
        self._vv: str | None = None

    def known_keys(self, wh, drop):
        return _store.known_keys(wh, drop)

    def submit_intake(self, drop, batch, parquet_root, warehouse_root, known, docs_root, part,
                      allow_simulated):
        # a batch whose every file is recorded with a verdict of this validator is only
        # hashed (a re-run with nothing new): done here, not in a worker process that
        # would be started (and import the science) for it
        submit = _Done if self._all_known(batch, known) else self._submit
        return submit(_validate.intake_batch, drop, batch, parquet_root, warehouse_root,
                      known, docs_root, part, allow_simulated)

    def _all_known(self, batch, known) -> bool:
        if self._submit is _Done or not batch:
            return True
        if self._vv is None:
            self._vv = validator_version()
        paths = {p for (_, p), v in known.items() if v == self._vv}
        return all(path_text(getattr(e, "path", e)) in paths for e in batch)

    def record_drop(self, wh, ing, flow_run_id, known=None):
        return _store.record_drop(wh, ing, flow_run_id, known)

    def submit_campaigns(self, warehouse_root, campaigns, parameters, unit_priors=None):
        return self._submit(_science.load_and_process, warehouse_root, campaigns, parameters,
                            *([unit_priors] if unit_priors else []))

    def store_campaigns(self, wh, items, **kw):
        return _store.store_campaigns(wh, items, **kw)


class PrefectSteps:
    """The steps as Prefect tasks.  The two that run in the flow process (record, store)
    get their large arguments (a batch's records, computed results) under ``quote``, the
    two submitted to workers theirs in a ``Sealed`` (accelcal.tasks): Prefect otherwise
    walks every nested object of a task's arguments twice (resolving futures, collecting
    task inputs) -- 15-19 s of the flow process's CPU at 200 campaigns for record and
    store, ~1 s for the submitted tasks, taken from the workers on a machine with as many
    workers as cores.  The submitted tasks' large arguments are Sealed, not quoted: they
    travel to the workers through Dask, which would unmake a quote."""

    engine = "prefect"

    def __init__(self):
        from prefect.utilities.annotations import quote

        from ..tasks import Sealed, prefect_tasks
        self._t, self._quote, self._sealed = prefect_tasks(), quote, Sealed

    def known_keys(self, wh, drop):
        return self._t.known_keys(wh, drop)

    def submit_intake(self, drop, batch, parquet_root, warehouse_root, known, docs_root, part,
                      allow_simulated):
        S = self._sealed
        return self._t.intake_batch.submit(drop, S(batch), parquet_root, warehouse_root,
                                           S(known), docs_root, part, allow_simulated)

    def record_drop(self, wh, ing, flow_run_id, known=None):
        return self._t.record_drop(wh, self._quote(ing), flow_run_id, self._quote(known))

    def submit_campaigns(self, warehouse_root, campaigns, parameters, unit_priors=None):
        S = self._sealed
        return self._t.load_and_process.submit(warehouse_root, S(campaigns), S(parameters),
                                               *([S(unit_priors)] if unit_priors else []))

    def store_campaigns(self, wh, items, **kw):
        return self._t.store_campaigns(wh, self._quote(items), **kw)

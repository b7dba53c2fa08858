"""The parser team's API (accelcal.schemas), resolved by name at call time.

The contract (docs/design.md): ``read_run``, ``parse_run``, ``discover``, ``scan_drop``,
``Entry``, ``settle_wait``, ``DropFormatError``,
``RunFile`` (schemas.dropformat), ``validate_runs`` (GE suites, Data Docs),
``write_run_parquet`` / ``read_run_parquet`` (Parquet).  Looking the names up
in every schemas module keeps the pipeline independent of which module
finally hosts each function.
"""
from __future__ import annotations

import importlib
from typing import Any

_MODULES = ("accelcal.schemas", "accelcal.schemas.dropformat", "accelcal.schemas.suites",
            "accelcal.schemas.tables", "accelcal.schemas.datadocs")
_OVERRIDES: dict[str, Any] = {}   # tests may substitute an implementation here


def resolve(name: str) -> Any:
    if name in _OVERRIDES:
        return _OVERRIDES[name]
    errors = []
    for mod in _MODULES:
        try:
            m = importlib.import_module(mod)
        except ImportError as e:
            errors.append(f"{mod}: {e}")
            continue
        if hasattr(m, name):
            return getattr(m, name)
    raise ImportError(f"accelcal.schemas provides no {name!r} ({'; '.join(errors) or 'not found'})")


def read_run(path):
    return resolve("read_run")(path)


def discover(drop_dir):
    return resolve("discover")(drop_dir)


def validate_runs(runs, docs_dir, drop_name, parse_refusals=None):
    return resolve("validate_runs")(runs, docs_dir, drop_name, parse_refusals)


def write_drop_index(drop_docs, title):
    return resolve("write_drop_index")(drop_docs, title)


def scan_drop(drop_dir):
    return resolve("scan_drop")(drop_dir)


def settle_wait(entries, settle, max_wait=None):
    return resolve("settle_wait")(entries, settle, max_wait)


def parse_run(fh, path):
    return resolve("parse_run")(fh, path)


def docs_folder_name(drop_name):
    return resolve("docs_folder_name")(drop_name)


def write_run_parquet(run, root):
    return resolve("write_run_parquet")(run, root)


def read_run_parquet(path):
    return resolve("read_run_parquet")(path)


def drop_format_error() -> type[BaseException]:
    return resolve("DropFormatError")


def parse_runs(items):
    """``parse_run`` on many small files held as bytes, [(bytes, path)] -> [RunFile or
    the DropFormatError it raises].  When a test substitutes ``parse_run`` (or the parser
    has no ``parse_runs``), each file goes through ``parse_run`` here, one by one."""
    if "parse_run" not in _OVERRIDES:
        try:
            batch = resolve("parse_runs")
        except ImportError:
            batch = None
        if batch is not None:
            return batch(items)
    import io
    err = drop_format_error()
    out = []
    for raw, path in items:
        try:
            out.append(parse_run(io.BytesIO(raw), path))
        except err as e:
            out.append(e)
    return out

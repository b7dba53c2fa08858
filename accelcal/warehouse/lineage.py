"""Lineage: code version, deterministic result ids, and tracing results to raw bytes.

Plain functions, no Prefect.
"""
from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any, Iterable

_PACKAGE_ROOT = Path(__file__).resolve().parents[1]
_SOURCE_SUFFIXES = (".py", ".sql")


def canonical_json(obj: Any) -> str:
    """JSON with sorted keys and no whitespace: the form that enters hashes."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_json_default,
                      ensure_ascii=False)


def _json_default(obj: Any):
    # numpy scalars/arrays, Paths, sets ... -> plain JSON
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "isoformat"):
        return obj.isoformat()
    return repr(obj)


def package_version() -> str:
    try:
        from importlib.metadata import version
        return version("accelcal")
    except Exception:  # not installed (running from a source tree)
        return "0+unknown"


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """sha256 over every accelcal source file (relative path + bytes), sorted.

    Robust without git: an installed wheel and a checkout of the same code give
    the same digest.  Demo data and caches do not enter it.
    """
    h = hashlib.sha256()
    files = sorted(p for p in _PACKAGE_ROOT.rglob("*")
                   if p.suffix in _SOURCE_SUFFIXES and p.is_file()
                   and "__pycache__" not in p.parts)
    for p in files:
        rel = p.relative_to(_PACKAGE_ROOT).as_posix()
        h.update(rel.encode() + b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


#: What decides whether a file is accepted: the parser, the suites, ingest/validate glue.
_VALIDATOR_GLOBS = ("schemas/*.py", "tasks/ingest.py", "tasks/validate.py")


@functools.lru_cache(maxsize=1)
def validator_version() -> str:
    """Version of the code that gives a file its verdict (accepted/refused).

    A warehouse re-checks a known file when this changes, and adds a verdict.
    """
    h = hashlib.sha256()
    files = sorted({p for g in _VALIDATOR_GLOBS for p in _PACKAGE_ROOT.glob(g) if p.is_file()})
    for p in files:
        h.update(p.relative_to(_PACKAGE_ROOT).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return f"{package_version()}+val.{h.hexdigest()[:16]}"


def code_version() -> str:
    """'<package version>+src.<first 16 hex of the source digest>'."""
    return f"{package_version()}+src.{source_digest()[:16]}"


def result_id(campaign: str, input_sha256: Iterable[str], code_version: str,
              parameters: dict[str, Any]) -> str:
    """Deterministic id of a campaign result: same inputs, code and parameters -> same id."""
    payload = canonical_json({
        "campaign": campaign,
        "inputs": sorted(set(input_sha256)),
        "code_version": code_version,
        "parameters": parameters,
    })
    return hashlib.sha256(payload.encode()).hexdigest()


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def trace(con, result_id: str) -> list[dict[str, Any]]:
    """The input runs of a result: lineage joined with the run records."""
    rows = con.execute(
        """SELECT l.result_id, l.sha256, l.run_id, l.revision, l.flow_run_id, l.code_version,
                  l.parameters, r.source_path, r.status, l.parquet_path
           FROM lineage l LEFT JOIN runs r USING (sha256)
           WHERE l.result_id = ? ORDER BY l.run_id, l.sha256, r.source_path""",
        [result_id]).fetchall()
    cols = ["result_id", "sha256", "run_id", "revision", "flow_run_id", "code_version",
            "parameters", "source_path", "status", "parquet_path"]
    return [dict(zip(cols, r)) for r in rows]


def verify_lineage(con) -> list[str]:
    """Problems found: current coefficients without lineage, lineage to unknown runs.

    An empty list means every coefficient traces to the sha256 of ingested,
    accepted runs.
    """
    problems: list[str] = []
    for (rid, name, campaign) in con.execute(
            """SELECT DISTINCT c.result_id, c.name, c.campaign FROM coefficients c
               WHERE NOT EXISTS (SELECT 1 FROM lineage l WHERE l.result_id = c.result_id)""").fetchall():
        problems.append(f"coefficient {name} of {campaign} (result {rid[:12]}) has no lineage")
    for (rid, sha) in con.execute(
            """SELECT l.result_id, l.sha256 FROM lineage l
               WHERE NOT EXISTS (SELECT 1 FROM runs r WHERE r.sha256 = l.sha256
                                 AND r.status = 'accepted')""").fetchall():
        problems.append(f"result {rid[:12]} rests on {sha[:12]}, which is not an accepted run")
    return problems

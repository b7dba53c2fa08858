"""Upgrade a warehouse written by an older schema to this accelcal's (``accelcal migrate``).

Schema 3 -> 4 adds ``coefficient_history.factors`` and gives every combination row the
structural name (:func:`accelcal.effects.combination_name`): schema 3 named it with its
factors to three digits (``K1+9.55*K3+1.1*Koq``), which moved with the data; the row
becomes ``K1(Koq,K3)`` with ``{"K3": 9.55, "Koq": 1.1}`` (the factors as the old name
gave them), and its budget lines follow.  Every other row and column is kept.

Schema 2 -> 3: schema 2 held each result's extras (the per-pair
fits, residual series and Monte Carlo check the certificate reads, ~48 KB of canonical
JSON a result) in the column ``results.extras``; schema 3 keeps them as immutable files
``<extras_dir>/<sha[:2]>/<sha>.json`` named by ``results.extras_sha256`` (extras.py).
The text of the column is exactly the bytes of the file (both ``canonical_json`` of
``CampaignResult.extras``), so a migrated result names the same file a fresh run of the
same code would write.

What the migration keeps: every row of every table, the activation history (which result
was current when) included -- the thing re-processing the drops into a new warehouse
would not give back.  Before it changes the warehouse it copies the file (with its
write-ahead log, if any, folded in) to ``<stem>.schema-<old>.duckdb`` beside it.  The extras files are written (and flushed)
first; the table change is then one transaction: a run killed at any point leaves the
schema-2 warehouse as it was (plus, at most, extras files nothing names yet), and
``accelcal migrate`` again finishes the job.
"""
from __future__ import annotations

import re
import shutil
from importlib import resources
from pathlib import Path

import duckdb

from ..effects import combination_name
from ..fileio import os_error_text, path_text
from .columnar import _arrow, _registered, _transaction
from .db import SCHEMA_VERSION, Warehouse, schema_version
from .errors import WarehouseError
from .extras import EXTRAS_DIR_KEY, write_extras
from .lineage import canonical_json

#: Results whose extras are read and written as files at a time (~48 KB each).
ROWS_PER_BATCH = 200

#: schema 2's results columns, in order (schema 3 has ``extras_sha256`` for ``extras``).
_COLUMNS_2 = ["result_id", "campaign", "unit_serial", "unit_model", "tests", "rig_ids",
              "computed_at", "flow_run_id", "code_version", "parameters",
              "science_parameters", "input_sha256", "extras", "simulated", "completeness",
              "completeness_reasons"]


def results_ddl(name: str) -> str:
    """schema.sql's ``results`` table definition (this schema's), creating table ``name``."""
    sql = resources.files("accelcal.warehouse").joinpath("schema.sql").read_text()
    m = re.search(r"CREATE TABLE IF NOT EXISTS results \((.*?)\n\);", sql, re.S)
    if m is None:                       # pragma: no cover (schema.sql is part of the package)
        raise MigrationError("schema.sql defines no results table")
    return f"CREATE TABLE {name} ({m.group(1)}\n)"


class MigrationError(WarehouseError):
    """The warehouse cannot be migrated (one line: which file, why)."""


def schema_version_of(path: str | Path) -> str | None:
    """The schema version a warehouse file says it has (None: no schema_info table)."""
    con = duckdb.connect(str(path), read_only=True)
    try:
        return schema_version(con)
    finally:
        con.close()


def migrate(path: str | Path, *, lock_timeout: float = 60.0) -> dict:
    """Bring the warehouse at ``path`` to this accelcal's schema, in place, after copying
    it (checkpointed) to ``<stem>.schema-<old>.duckdb``.

    Returns ``{"warehouse", "from", "to", "results", "extras_files", "backup"}``; a
    warehouse already at this schema is left alone (``from == to``, no backup).  Raises
    MigrationError (one line) for a version this code cannot migrate, and WarehouseError
    when the warehouse is busy (its lock) or cannot be written.
    """
    path = Path(path).expanduser().resolve()
    if not path.is_file():
        raise MigrationError(f"warehouse {path_text(path)} does not exist")
    wh = Warehouse(path, lock_timeout=lock_timeout)
    with wh.lock():
        try:
            have = schema_version_of(path)
        except duckdb.Error as e:
            raise MigrationError(f"{path_text(path)} cannot be read as a warehouse: "
                                 f"{str(e).splitlines()[0]}") from None
        out = {"warehouse": str(path), "from": have, "to": SCHEMA_VERSION, "results": 0,
               "extras_files": 0, "combinations": 0, "backup": None}
        if have == SCHEMA_VERSION:
            return out
        if have not in ("2", "3"):
            raise MigrationError(
                f"warehouse {path_text(path)} has schema version {have}; accelcal migrate "
                f"upgrades schema 2 or 3 to {SCHEMA_VERSION} only: process its drops again "
                "into a new warehouse")
        backup = path.with_name(f"{path.stem}.schema-{have}{path.suffix}")
        if not backup.exists():         # else the interrupted migration's copy is the original
            con = duckdb.connect(str(path))
            try:                        # fold a write-ahead log into the file it copies
                con.execute("CHECKPOINT")
            finally:
                con.close()
            try:
                tmp = backup.with_name(backup.name + ".part")
                shutil.copyfile(path, tmp)
                tmp.replace(backup)
            except OSError as e:
                raise MigrationError(os_error_text(e, f"cannot copy {path_text(path)} before "
                                                      "migrating it")) from None
        out["backup"] = str(backup)
        extras_root = path.parent / f"{path.stem}-extras"
        con = duckdb.connect(str(path))
        try:
            if have == "2":
                out.update(_migrate_2_to_3(con, extras_root))
            out["combinations"] = _migrate_3_to_4(con)
        finally:
            con.close()
        if wh.snapshot_path.exists():     # readers' copy: the old one is schema 2
            wh.publish_snapshot()
    return out


def _migrate_2_to_3(con, extras_root: Path) -> dict:
    """Write each result's extras as its file, then swap the column in one transaction."""
    cols = [r[0] for r in con.execute(
        "SELECT column_name FROM information_schema.columns WHERE table_name = 'results' "
        "ORDER BY ordinal_position").fetchall()]
    if cols != _COLUMNS_2:
        raise MigrationError(f"the results table is not schema 2's (columns {cols})")
    ids = [r[0] for r in con.execute("SELECT result_id FROM results ORDER BY result_id").fetchall()]
    shas: dict[str, str | None] = {}
    for k in range(0, len(ids), ROWS_PER_BATCH):
        part = ids[k:k + ROWS_PER_BATCH]
        rows = con.execute("SELECT result_id, extras FROM results WHERE list_contains(?, result_id)",
                           [part]).fetchall()
        texts = [(rid, x) for rid, x in rows if x is not None]
        for (rid, _), sha in zip(texts, write_extras(extras_root, [x for _, x in texts])):
            shas[rid] = sha
        shas.update({rid: None for rid, x in rows if x is None})
    sha_table = _arrow({"result_id": list(shas), "sha": list(shas.values())})
    with _transaction(con), _registered(con, "_extras_sha", sha_table):
        con.execute(results_ddl("results_schema3"))
        keep = ", ".join(f"r.{c}" if c != "extras" else "x.sha" for c in _COLUMNS_2)
        con.execute(f"INSERT INTO results_schema3 SELECT {keep} FROM results r "
                    "LEFT JOIN _extras_sha x USING (result_id) ORDER BY r.rowid")
        n_old = con.execute("SELECT count(*) FROM results").fetchall()[0][0]
        n_new = con.execute("SELECT count(*) FROM results_schema3").fetchall()[0][0]
        if n_old != n_new:
            raise MigrationError(f"results: {n_new} rows copied of {n_old}; nothing changed")
        views = [r[0] for r in con.execute(
            "SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()]
        for v in views:                 # _apply_schema makes them again on the next open
            con.execute(f'DROP VIEW IF EXISTS "{v}"')
        con.execute("DROP TABLE results")
        con.execute("ALTER TABLE results_schema3 RENAME TO results")
        con.execute("UPDATE schema_info SET value = '3' WHERE key = 'schema_version'")
        con.execute("INSERT INTO schema_info VALUES (?, ?) ON CONFLICT DO NOTHING",
                    [EXTRAS_DIR_KEY, extras_root.name])
    con.execute("CHECKPOINT")
    return {"results": len(ids), "extras_files": len({s for s in shas.values() if s})}


#: A schema-3 combination name: the coefficient, then each term as +f*K or -f*K (f left
#: out when 1), a bracketed scope kept with its coefficient.
_NAME_3 = r"[A-Za-z_][A-Za-z0-9_]*(?:\[[^\]]*\])?"
_TERM_3 = re.compile(rf"([+-])(?:([0-9.]+(?:e[+-]?[0-9]+)?)\*)?({_NAME_3})")


def structural_name(name: str) -> tuple[str, dict[str, float]] | None:
    """A schema-3 row name as schema 4 names it: ``"K1+9.55*K3+1.1*Koq"`` ->
    ``("K1(Koq,K3)", {"K3": 9.55, "Koq": 1.1})``; None for a plain name."""
    m = re.fullmatch(rf"({_NAME_3})((?:[+-](?:[0-9.]+(?:e[+-]?[0-9]+)?\*)?{_NAME_3})+)", name)
    if m is None:
        return None
    factors = {k: (-1.0 if s == "-" else 1.0) * (float(f) if f else 1.0)
               for s, f, k in _TERM_3.findall(m.group(2))}
    return combination_name(m.group(1), factors), factors


def _migrate_3_to_4(con) -> int:
    """Add ``coefficient_history.factors`` and rename the combination rows (and their
    budget lines) structurally, in one transaction; returns how many rows were renamed."""
    rows = con.execute("SELECT DISTINCT result_id, name FROM coefficient_history").fetchall()
    renamed = [(rid, old, *new) for rid, old in rows if (new := structural_name(old)) is not None]
    with _transaction(con):
        views = [r[0] for r in con.execute(
            "SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()]
        for v in views:                 # _apply_schema makes them again on the next open
            con.execute(f'DROP VIEW IF EXISTS "{v}"')
        con.execute("ALTER TABLE coefficient_history ADD COLUMN factors VARCHAR")
        for rid, old, new, factors in renamed:
            con.execute("UPDATE coefficient_history SET name = ?, factors = ? "
                        "WHERE result_id = ? AND name = ?",
                        [new, canonical_json(factors), rid, old])
            con.execute("UPDATE budget_history SET coefficient = ? "
                        "WHERE result_id = ? AND coefficient = ?", [new, rid, old])
        con.execute("UPDATE schema_info SET value = ? WHERE key = 'schema_version'",
                    [SCHEMA_VERSION])
    con.execute("CHECKPOINT")
    return len(renamed)

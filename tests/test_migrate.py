"""``accelcal migrate``: a schema-2 or schema-3 warehouse brought to schema 4 keeps every row.

The schema-2 warehouse is made here from a schema-3 one by the reverse of the migration,
written independently of accelcal.warehouse.migrate: schema 2's results table (its DDL as
schema.sql had it before schema 3, copied below) with each extras file's text in the
column ``extras``, schema_version '2', no extras folder; and, as schemas 2 and 3 had them,
no column ``coefficient_history.factors`` and each combination named with its factors to
three significant digits (``K0+96.1*Koo``).  Migrating it must give back the schema-4
warehouse table by table (the factors to the three digits the old names kept) and the
extras files byte for byte.  (A warehouse
written by the schema-2 code itself, c4eab5d, was migrated the same way by hand: every
table equal, each file's sha256 its column; see the closing note of issue 13.)
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import duckdb
import pytest

from accelcal.flows.pipeline import run_pipeline
from accelcal.warehouse import migrate as mig
from accelcal.warehouse.db import Warehouse
from accelcal.warehouse.errors import WarehouseError

from test_faults import warehouse_contents

DEMO = Path(__file__).resolve().parents[1] / "accelcal" / "demo_data" / "drop-demo"

RESULTS_SCHEMA_2 = """
CREATE TABLE results_v2 (
    result_id      VARCHAR PRIMARY KEY,
    campaign       VARCHAR NOT NULL,
    unit_serial    VARCHAR NOT NULL,
    unit_model     VARCHAR,
    tests          VARCHAR,
    rig_ids        VARCHAR,
    computed_at    TIMESTAMPTZ NOT NULL,
    flow_run_id    VARCHAR,
    code_version   VARCHAR NOT NULL,
    parameters     VARCHAR NOT NULL,
    science_parameters VARCHAR,
    input_sha256   VARCHAR NOT NULL,
    extras         VARCHAR,
    simulated      BOOLEAN NOT NULL DEFAULT false,
    completeness   VARCHAR NOT NULL DEFAULT 'complete'
                   CHECK (completeness IN ('complete', 'incomplete')),
    completeness_reasons VARCHAR
)"""


def old_name(name: str, factors: dict) -> str:
    """A combination as schemas 2 and 3 named it: each term +f*K / -f*K, f to three
    significant digits, left out when 1."""
    out = name.split("(", 1)[0]
    for k, f in factors.items():
        out += ("-" if f < 0 else "+") + ("" if abs(abs(f) - 1) < 5e-3 else f"{abs(f):.3g}*") + k
    return out


def as_schema_3_names(con) -> None:
    """coefficient_history and budget_history as schema 3 had them, on an open connection."""
    for (v,) in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall():
        con.execute(f'DROP VIEW "{v}"')
    for rid, name, factors in con.execute("SELECT result_id, name, factors FROM coefficient_history "
                                          "WHERE factors IS NOT NULL").fetchall():
        old = old_name(name, json.loads(factors))
        con.execute("UPDATE coefficient_history SET name = ? WHERE result_id = ? AND name = ?",
                    [old, rid, name])
        con.execute("UPDATE budget_history SET coefficient = ? WHERE result_id = ? AND coefficient = ?",
                    [old, rid, name])
    con.execute("ALTER TABLE coefficient_history DROP COLUMN factors")


def contents(path: Path) -> dict:
    """warehouse_contents with each stored factor to the three digits an old name kept."""
    out = warehouse_contents(path)
    out["coefficient_history"] = [
        r[:-1] + (None if r[-1] is None else {k: float(f"{v:.3g}") for k, v in json.loads(r[-1]).items()},)
        for r in out["coefficient_history"]]
    return out


@pytest.fixture(scope="module")
def schema3(tmp_path_factory) -> Path:
    wh = tmp_path_factory.mktemp("v3") / "lab.duckdb"
    run_pipeline([str(DEMO)], wh, engine="local", allow_simulated=True, workers=1)
    return wh


def as_schema_2(schema3: Path, where: Path) -> Path:
    """A copy of the schema-3 warehouse as the schema-2 code wrote it."""
    where.mkdir()
    wh = where / schema3.name
    shutil.copyfile(schema3, wh)
    extras = schema3.parent / f"{schema3.stem}-extras"
    shutil.copytree(schema3.parent / f"{schema3.stem}-parquet", where / f"{schema3.stem}-parquet")
    con = duckdb.connect(str(wh))
    try:
        rows = con.execute("SELECT * FROM results").fetchall()
        cols = [d[0] for d in con.execute("SELECT * FROM results").description]
        i = cols.index("extras_sha256")
        con.execute(RESULTS_SCHEMA_2)
        for r in rows:
            sha = r[i]
            text = (extras / sha[:2] / f"{sha}.json").read_text("utf-8") if sha else None
            con.execute(f"INSERT INTO results_v2 VALUES ({', '.join('?' * len(r))})",
                        list(r[:i]) + [text] + list(r[i + 1:]))
        as_schema_3_names(con)
        con.execute("DROP TABLE results")
        con.execute("ALTER TABLE results_v2 RENAME TO results")
        con.execute("UPDATE schema_info SET value = '2' WHERE key = 'schema_version'")
        con.execute("DELETE FROM schema_info WHERE key = 'extras_dir'")
    finally:
        con.close()
    return wh


def test_schema_2_is_refused_with_the_way_out(schema3, tmp_path):
    wh = as_schema_2(schema3, tmp_path / "w")
    with pytest.raises(WarehouseError, match="schema version 2, this accelcal uses 4: "
                                             "upgrade it with `accelcal migrate"):
        Warehouse(wh).init()


def test_migration_gives_back_every_table_and_extras_file(schema3, tmp_path):
    wh = as_schema_2(schema3, tmp_path / "w")
    before = wh.read_bytes()
    out = mig.migrate(wh)
    assert (out["from"], out["to"]) == ("2", "4") and out["combinations"] > 0
    n = len(duckdb.connect(str(schema3), read_only=True).execute("SELECT * FROM results").fetchall())
    assert out["results"] == n > 0
    assert Path(out["backup"]).read_bytes() == before          # the old file, untouched
    assert contents(wh) == contents(schema3)
    # the views and macros are there again, and read the extras through the files
    Warehouse(wh).init()
    again = mig.migrate(wh)
    assert again["from"] == again["to"] == "4" and again["backup"] is None


def test_an_interrupted_migration_changes_nothing_and_can_be_run_again(schema3, tmp_path,
                                                                       monkeypatch):
    wh = as_schema_2(schema3, tmp_path / "w")
    old = duckdb.connect(str(wh), read_only=True)
    tables_before = {t: old.execute(f"SELECT count(*) FROM {t}").fetchall()
                     for (t,) in old.execute("SELECT table_name FROM information_schema.tables "
                                             "WHERE table_type = 'BASE TABLE'").fetchall()}
    old.close()

    real = mig.results_ddl      # a failure inside the transaction, after the files
    monkeypatch.setattr(mig, "results_ddl",
                        lambda name: real(name) + "; SELECT error('killed mid-migration')")
    with pytest.raises(duckdb.Error, match="killed mid-migration"):
        mig.migrate(wh)
    assert mig.schema_version_of(wh) == "2"
    con = duckdb.connect(str(wh), read_only=True)
    assert {t: con.execute(f"SELECT count(*) FROM {t}").fetchall() for t in tables_before} \
        == tables_before
    con.close()
    monkeypatch.setattr(mig, "results_ddl", real)
    mig.migrate(wh)
    assert contents(wh) == contents(schema3)


def test_other_versions_are_refused_in_one_line(tmp_path):
    wh = tmp_path / "lab.duckdb"
    con = duckdb.connect(str(wh))
    con.execute("CREATE TABLE schema_info (key VARCHAR PRIMARY KEY, value VARCHAR)")
    con.execute("INSERT INTO schema_info VALUES ('schema_version', '1')")
    con.close()
    with pytest.raises(mig.MigrationError, match="schema version 1; accelcal migrate upgrades "
                                                 "schema 2 or 3 to 4 only"):
        mig.migrate(wh)


def test_the_cli_says_what_it_did(schema3, tmp_path):
    wh = as_schema_2(schema3, tmp_path / "w")
    cmd = [sys.executable, "-m", "accelcal", "migrate", "-w", str(wh)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    n = len(duckdb.connect(str(schema3), read_only=True).execute(
        "SELECT DISTINCT extras_sha256 FROM results").fetchall())
    m = duckdb.connect(str(schema3), read_only=True).execute(
        "SELECT count(*) FROM coefficient_history WHERE factors IS NOT NULL").fetchall()[0][0]
    assert p.stdout.strip() == (f"{wh}: schema 2 -> 4; {n} results, {n} extras files, {m} "
                                "combination rows named structurally; the "
                                f"schema-2 file is kept as {tmp_path / 'w' / 'lab.schema-2.duckdb'}")
    p = subprocess.run(cmd, capture_output=True, text=True)
    assert p.returncode == 0 and "schema 4 already; nothing to do" in p.stdout

"""Every SQL example of the READMEs returns rows on the demo warehouse (issue 28): a reader
who runs `accelcal demo` and pastes an example sees what it is for."""
from __future__ import annotations

import re
from pathlib import Path

import duckdb
import pytest

from accelcal import cli

REPO = Path(__file__).resolve().parents[1]
READMES = [REPO / "README.md", REPO / "accelcal" / "warehouse" / "README.md"]


def _examples() -> list[tuple[str, int, list[str]]]:
    """(readme, block number, statements) of every ```sql block."""
    out = []
    for readme in READMES:
        text = readme.read_text(encoding="utf-8")
        for k, block in enumerate(re.findall(r"```sql\n(.*?)```", text, re.S)):
            body = re.sub(r"--[^\n]*", "", block)
            stmts = [s.strip() for s in body.split(";") if s.strip()]
            out.append((readme.relative_to(REPO).as_posix(), k, stmts))
    return out


@pytest.fixture(scope="module")
def demo_warehouse(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    assert cli.main(["demo", "--dir", str(out), "--engine", "local", "-q"]) == 0
    return out / "lab.duckdb"


def test_the_readmes_have_sql_examples():
    assert sum(len(s) for _, _, s in _examples()) >= 10


@pytest.mark.parametrize("readme, block, stmts", _examples(), ids=lambda v: str(v)[:40])
def test_sql_example_returns_rows_on_the_demo(demo_warehouse, monkeypatch, readme, block, stmts):
    monkeypatch.chdir(demo_warehouse.parent)     # the extras example reads lab-extras/ from there
    con = duckdb.connect(str(demo_warehouse), read_only=True)
    try:
        for q in stmts:
            rows = con.execute(q).fetchall()
            if q.upper().startswith(("SET ", "PRAGMA ")):
                continue
            assert rows, f"{readme} sql block {block}: no rows from: {' '.join(q.split())[:120]}"
    finally:
        con.close()

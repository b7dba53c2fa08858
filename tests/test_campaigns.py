"""Completeness, adoption and quarantine (issue 11): an incomplete campaign (drop-bad's
ok-small.csv, one 4-position tumble) is stored and visible but kept out of history, En,
the fleet views and the rig comparison; `accelcal campaign exclude|include` is an
append-only audit trail; history reads adopted values; an old warehouse gets one line."""
from __future__ import annotations

import duckdb
import pytest

from accelcal import cli
from accelcal.warehouse import Warehouse
from conftest import copy_lab

C20, C21 = "SNJ-1-03/2026-11-20", "SNJ-1-03/2026-11-21-LXJ200"
OPS_VIEWS = ("unit_history", "calibration", "fleet_latest", "rig_comparison")


@pytest.fixture(scope="module")
def lab(tmp_path_factory, sample_lab):
    """The session's warehouse of 2026-11-20, 2026-11-21 and drop-bad, copied (the
    tests exclude and include)."""
    return Warehouse(copy_lab(sample_lab, tmp_path_factory.mktemp("camp") / "lab"))


def _small_campaign(wh):
    (r,) = wh.query("SELECT campaign FROM runs WHERE source_path LIKE '%/ok-small.csv'")
    return r["campaign"]


def test_ok_small_is_incomplete_visible_and_out_of_history(lab):
    camp = _small_campaign(lab)
    (res,) = lab.query("SELECT completeness, completeness_reasons, unit_serial FROM "
                       "results_current WHERE campaign = ?", [camp])
    assert res["completeness"] == "incomplete" and "degrees of freedom" in res["completeness_reasons"]
    assert res["unit_serial"] == "SNJ-1-03"
    # visible: its coefficients are in the current coefficients, marked
    vis = lab.query("SELECT DISTINCT completeness FROM coefficients WHERE campaign = ?", [camp])
    assert vis == [{"completeness": "incomplete"}]
    # never in coefficient_changes, as either side
    ch = lab.query("SELECT campaign, prev_campaign FROM coefficient_changes")
    assert ch and not [c for c in ch if camp in (c["campaign"], c["prev_campaign"])]
    for v in OPS_VIEWS:
        assert not lab.query(f"SELECT * FROM {v} WHERE campaign = ?", [camp]), v
    assert not lab.query("SELECT * FROM rig_comparison WHERE rig_id = 'DH-1' AND name = 'K2'")


def test_history_reads_one_adopted_value_per_campaign_and_coefficient(lab):
    hist = lab.query("SELECT campaign, name, count(*) AS n FROM unit_history GROUP BY ALL")
    assert hist and all(h["n"] == 1 for h in hist)
    adopted = {(r["campaign"], r["name"]): r["method"] for r in lab.query(
        "SELECT campaign, name, method FROM coefficients WHERE adopted")}
    for h in lab.query("SELECT campaign, name, method FROM unit_history"):
        assert adopted[(h["campaign"], h["name"])] == h["method"]
    assert {c["name"] for c in lab.query("SELECT name FROM calibration WHERE campaign = ?",
                                         [C20])} >= {"K0", "K1", "K2", "Kip", "Kio"}


def test_exclude_and_include_are_an_audit_trail(lab, capsys):
    def run(*a):
        return cli.main(["campaign", *a, "--warehouse", str(lab.path)])
    with duckdb.connect(str(lab.path), read_only=True) as con:
        t_before = con.execute("SELECT now()").fetchall()[0][0]
    before = lab.query("SELECT * FROM coefficient_changes ORDER BY ALL")
    assert any(c["campaign"] == C21 for c in before)
    assert run("exclude", C21, "--why", "LXJ-200 arm radius in doubt", "--by", "qa") == 0
    assert "excluded by qa" in capsys.readouterr().out
    for v in OPS_VIEWS + ("coefficient_changes",):
        assert not lab.query(f"SELECT * FROM {v} WHERE campaign = ?", [C21]), v
    # the as-of view still shows what the warehouse said before the exclusion
    assert lab.query("SELECT * FROM unit_history_as_of(?) WHERE campaign = ?", [t_before, C21])
    # a second exclusion records nothing and says so
    assert run("exclude", C21, "--why", "again") == 1
    assert "already excluded" in capsys.readouterr().err
    assert run("include", C21, "--why", "radius re-measured, fine", "--by", "qa") == 0
    assert lab.query("SELECT * FROM coefficient_changes ORDER BY ALL") == before
    log = lab.query("SELECT action, why, acted_by FROM campaign_actions WHERE campaign = ? "
                    "ORDER BY seq", [C21])
    assert [(a["action"], a["acted_by"]) for a in log] == [("exclude", "qa"), ("include", "qa")]
    assert run("show", C21) == 0
    out = capsys.readouterr().out
    assert "LXJ-200 arm radius in doubt" in out and "radius re-measured" in out
    assert run("exclude", "NOPE/1", "--why", "x") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no campaign 'NOPE/1'" in err[0]


def test_old_warehouse_gets_one_line_not_a_traceback(tmp_path, capsys):
    old = tmp_path / "old.duckdb"
    with duckdb.connect(str(old)) as con:
        con.execute("CREATE TABLE schema_info (key VARCHAR PRIMARY KEY, value VARCHAR)")
        con.execute("INSERT INTO schema_info VALUES ('schema_version', '1')")
        con.execute("CREATE TABLE results (result_id VARCHAR, campaign VARCHAR)")
    drop = tmp_path / "drop"
    drop.mkdir()
    for argv in (["run", str(drop), "--warehouse", str(old), "--engine", "local", "-q"],
                 ["report", "C/1", "--out", str(tmp_path / "r"), "--warehouse", str(old)],
                 ["campaign", "list", "--warehouse", str(old)]):
        assert cli.main(argv) == 1, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "schema version 1, this accelcal uses 4" in err[0], (argv, err)


def test_sql_reads_with_the_client_that_wrote_it(lab, capsys):
    assert cli.main(["sql", "SELECT count(*) AS n_cal FROM calibration", "--warehouse",
                     str(lab.path), "--csv"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "n_cal" and int(out[1]) > 0
    assert cli.main(["sql", "SELECT nope", "--warehouse", str(lab.path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]

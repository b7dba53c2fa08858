"""Simulated data is never taken for real (issue 11): `accelcal simulate` marks every file,
`run` refuses marked files unless --allow-simulated, and even then a simulated result never
becomes current for a unit with a complete real calibration."""
from __future__ import annotations

import pytest

from accelcal.flows.pipeline import run_pipeline
from accelcal.provenance import is_simulated, simulated_line
from accelcal.schemas.dropformat import read_run
from accelcal.simulate import simulate_to_drop
from accelcal.warehouse import Warehouse

CAMP = "SNJ-1-03/2026-11-20"
STATE_SQL = {
    "current": "SELECT campaign, result_id FROM results_current ORDER BY 1",
    "coefficients": "SELECT campaign, name, method, value FROM coefficients ORDER BY ALL",
    "history": "SELECT * FROM unit_history ORDER BY ALL",
    "calibration": "SELECT * FROM calibration ORDER BY ALL",
    "inputs of the real campaign": f"SELECT run_id, sha256 FROM current_runs WHERE campaign = '{CAMP}' ORDER BY ALL",
}


def _state(wh: Warehouse) -> dict:
    return {k: wh.query(q) for k, q in STATE_SQL.items()}


@pytest.fixture(scope="module")
def sims(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    simulate_to_drop("snj103-lxj100", d / "sim", seed=3)
    simulate_to_drop("snj103-lxj100", d / "sim-keep", seed=4, keep_ids=True)
    return d / "sim", d / "sim-keep"


@pytest.fixture(scope="module")
def real_wh(tmp_path_factory, examples):
    d = tmp_path_factory.mktemp("real")
    run_pipeline([str(examples / "drop-2026-11-20")], d / "lab.duckdb", engine="local")
    return Warehouse(d / "lab.duckdb")


def test_every_simulated_file_is_marked_and_parses(sims):
    plain, keep = sims
    for p in list(plain.rglob("*.csv")) + list(keep.rglob("*.csv")):
        run = read_run(p)                    # the parser reads the mark as an extra key
        assert is_simulated(run.meta) and simulated_line(p.read_bytes()) == 2
    ids = {read_run(p).run_id for p in plain.rglob("*.csv")}
    assert ids and all(i.startswith("SIM-") for i in ids)
    assert {read_run(p).meta["campaign"] for p in plain.rglob("*.csv")} == {"SIM-" + CAMP}
    assert {read_run(p).meta["campaign"] for p in keep.rglob("*.csv")} == {CAMP}


def test_real_files_are_not_simulated(examples):
    for p in (examples / "drop-2026-11-20").rglob("*.csv"):
        assert simulated_line(p.read_bytes()) is None


def test_simulated_drop_into_a_real_warehouse_changes_no_current_result(real_wh, sims):
    plain, keep = sims
    before = _state(real_wh)
    assert any(r["campaign"] == CAMP for r in before["current"])
    # 1. refused without --allow-simulated: nothing of it is stored
    n_files = real_wh.counts()["run_files"]
    s = run_pipeline([str(plain), str(keep)], real_wh.path, engine="local")
    assert [len(d["simulated_held"]) for d in s["drops"]] == [11, 11]
    assert all(h["line"] == 2 for d in s["drops"] for h in d["simulated_held"])
    assert real_wh.counts()["run_files"] == n_files and s["campaigns"] == []
    assert _state(real_wh) == before
    # 2. allowed: stored and marked, but never current for SNJ-1-03 (it has a real result);
    #    the same run ids (--keep-ids) make revisions that never supersede the real ones
    s = run_pipeline([str(plain), str(keep)], real_wh.path, engine="local",
                     allow_simulated=True)
    st = {c["campaign"]: c for c in s["campaigns"]}
    assert st["SIM-" + CAMP]["status"] == "simulated-not-current"
    assert st["SIM-" + CAMP]["current_result_id"] is None
    assert st[CAMP]["status"] == "unchanged" and st[CAMP]["simulated_left_out"] == 11
    assert _state(real_wh) == before
    # shown apart, under a SIMULATED banner that says why, and listed by `campaign`
    import io

    from rich.console import Console

    from accelcal.cli import print_summary
    from accelcal.ops.campaigns import campaign_rows
    sim = st["SIM-" + CAMP]
    assert sim["shown_result_id"] and sim["coefficients"]
    con = Console(file=io.StringIO(), width=100)
    print_summary(s, con)
    text = con.file.getvalue()
    block = text[text.index("SIM-" + CAMP):]
    assert "(not current)" in block and "SIMULATED" in block
    assert "the unit has a real calibration" in " ".join(block.split())
    (row,) = campaign_rows(real_wh.path, "SIM-" + CAMP)
    assert row["simulated"] and not row["in_history"] and not row["is_current"]
    sim_files = real_wh.query("SELECT count(*) AS n, bool_and(simulated) AS all_sim, "
                              "max(revision) AS top FROM run_files WHERE simulated")[0]
    assert sim_files["n"] == 22 and sim_files["all_sim"] and sim_files["top"] == 2
    res = real_wh.query("SELECT campaign, simulated FROM result_history WHERE simulated")
    assert [r["campaign"] for r in res] == ["SIM-" + CAMP]
    # 3. again: nothing changes
    run_pipeline([str(plain), str(keep)], real_wh.path, engine="local", allow_simulated=True)
    assert _state(real_wh) == before


def test_simulated_result_is_current_only_where_no_real_calibration(tmp_path, sims, examples):
    plain, _ = sims
    wh = Warehouse(tmp_path / "lab.duckdb")
    s = run_pipeline([str(plain)], wh.path, engine="local", allow_simulated=True)
    (c,) = s["campaigns"]
    assert c["status"] == "new" and c["simulated"] and c["current_result_id"]
    assert wh.query("SELECT count(*) AS n FROM unit_history")[0]["n"] == 0   # not history
    # a real calibration of the unit arrives: the simulated result stops being current
    run_pipeline([str(examples / "drop-2026-11-20")], wh.path, engine="local")
    cur = {r["campaign"] for r in wh.query("SELECT campaign FROM results_current")}
    assert cur == {CAMP}
    assert {r["campaign"] for r in wh.query("SELECT campaign FROM unit_history")} == {CAMP}


def test_cli_run_refuses_simulated_files_naming_file_and_line(tmp_path, sims, capsys):
    from accelcal import cli
    plain, _ = sims
    rc = cli.main(["run", str(plain), "--warehouse", str(tmp_path / "w.duckdb"),
                   "--engine", "local", "-q"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "refused sim/SIM-DH1-20261120-0001.csv:2: simulated:" in out
    assert "--allow-simulated" in out

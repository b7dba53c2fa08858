"""Warehouse: schema, idempotency, revisions, transactions (exception and SIGKILL), lock, as-of.

No Prefect, no parser: hand-made records and results.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from accelcal.results import CampaignResult, CoefficientResult, RadiusResult
from accelcal.warehouse import (RunRecord, Warehouse, WarehouseBusy, result_id, trace,
                                verify_lineage, warehouse_lock)
from accelcal.warehouse.db import Refusal

CV = "test+src.0"
PARAMS = {"science": {}}


def rec(sha, path, run_id="R-1", status="accepted", campaign="C/1", **kw) -> RunRecord:
    return RunRecord(sha256=sha, source_path=path, drop_name="d", drop_path="/d", size_bytes=10,
                     status=status, run_id=run_id, test="tumble", unit_serial="SN-1",
                     campaign=campaign, rig_id="DH-1", parquet_path=f"pq/{sha}.parquet",
                     validator_version=kw.pop("vv", "val.1"),
                     refusals=[Refusal(path, 3, "bad-thing", "detail")] if status == "refused" else [],
                     **kw)


def result(campaign="C/1", shas=("a" * 64,), k2=3.9e-7) -> CampaignResult:
    return CampaignResult(
        campaign=campaign, unit_serial="SN-1", unit_model="QA", tests=["tumble"], rig_ids=["DH-1"],
        input_sha256=list(shas),
        coefficients=[CoefficientResult("K0", 4e-4, 1e-6, "m/s2", "tumble_lm", "DH-1"),
                      CoefficientResult("K2", k2, 1e-9, "s2/m", "tumble_lm", "DH-1")],
        radii=[RadiusResult("LXJ", "+", "static", None, 1.0, 0.7147, 3e-7)],
        flags=["a flag"], extras={"x": [1, 2]}, parameters={"orders": [1, 2, 3]})


def inputs_for(wh: Warehouse, campaign="C/1"):
    return wh.campaign_inputs(campaign)


def store(wh, res, checkpoint=None):
    inputs = inputs_for(wh, res.campaign)
    rid = result_id(res.campaign, [i["sha256"] for i in inputs], CV, PARAMS)
    return rid, wh.store_result(res, result_id=rid, inputs=inputs, code_version=CV,
                                parameters=PARAMS, flow_run_id="flow-1", checkpoint=checkpoint)


@pytest.fixture
def wh(tmp_path) -> Warehouse:
    w = Warehouse(tmp_path / "lab.duckdb", lock_timeout=5)
    w.init()
    return w


def test_schema_is_idempotent_and_has_the_issue_tables(wh):
    wh.init()
    Warehouse(wh.path).init()
    with wh.connect() as con:
        names = {r[0] for r in con.execute(
            "SELECT table_name FROM information_schema.tables").fetchall()}
    for t in ("runs", "coefficients", "radii", "lineage", "results", "result_history",
              "coefficient_history", "radius_history", "adequacy", "uncertainty_budget",
              "alignment", "flags", "current_runs"):
        assert t in names, t
    cols = [r["column_name"] for r in wh.query("DESCRIBE runs")]
    assert cols[:10] == ["run_id", "revision", "sha256", "source_path", "test", "unit_serial",
                         "campaign", "status", "reason", "ingested_at"]


def test_record_runs_idempotent_and_revisions(wh):
    a, b, c = "a" * 64, "b" * 64, "c" * 64
    out = wh.record_runs([rec(a, "/d/x.csv"), rec(b, "/d/y.csv", run_id="R-2")])
    assert [r.revision for r in out] == [1, 1] and all(r.new for r in out)
    before = wh.counts()
    again = wh.record_runs([rec(a, "/d/x.csv"), rec(b, "/d/y.csv", run_id="R-2")])
    assert not any(r.new for r in again) and wh.counts() == before
    # same bytes at another path: same revision; other bytes, same run_id: revision 2
    out = wh.record_runs([rec(a, "/e/x.csv"), rec(c, "/e/x2.csv")])
    assert [r.revision for r in out] == [1, 2]
    cur = {r["run_id"]: (r["revision"], r["sha256"]) for r in wh.campaign_inputs("C/1")}
    assert cur == {"R-1": (2, c), "R-2": (1, b)}
    # both revisions kept
    revs = wh.query("SELECT DISTINCT revision, sha256 FROM runs WHERE run_id = 'R-1' ORDER BY 1")
    assert [(r["revision"], r["sha256"]) for r in revs] == [(1, a), (2, c)]


def test_refused_newest_revision_falls_back_to_newest_accepted(wh):
    a, b = "a" * 64, "b" * 64
    wh.record_runs([rec(a, "/d/ok.csv"), rec(b, "/d/trunc.csv", status="refused")])
    runs = wh.query("SELECT revision, status, reason FROM runs ORDER BY revision")
    assert [(r["revision"], r["status"]) for r in runs] == [(1, "accepted"), (2, "refused")]
    assert "/d/trunc.csv:3: bad-thing: detail" == runs[1]["reason"]
    assert [i["sha256"] for i in wh.campaign_inputs("C/1")] == [a]


def test_new_validator_version_adds_a_verdict_not_a_file(wh):
    a = "a" * 64
    wh.record_runs([rec(a, "/d/x.csv", status="refused")])
    assert wh.campaign_inputs("C/1") == []
    out = wh.record_runs([rec(a, "/d/x.csv", vv="val.2")])
    assert out[0].rechecked and not out[0].new
    c = wh.counts()
    assert c["run_files"] == 1 and c["run_verdicts"] == 2
    assert wh.query("SELECT status FROM runs")[0]["status"] == "accepted"
    assert len(wh.campaign_inputs("C/1")) == 1


def _fields(rows):
    """What the flow reads of a stored record (pipeline._record_batch), row by row."""
    return [{k: r[k] for k in ("sha256", "source_path", "status", "reason", "campaign")} for r in rows]


def test_known_files_are_the_runs_views_latest_verdict_and_stand_for_their_records(wh):
    """A file's known verdict is its newest (by seq), as the ``runs`` view has it, whatever
    the validator versions and reasons before; and a batch of known files with nothing to
    record gets, without a query, the records stored_runs gives (re-runs read them so)."""
    from accelcal.tasks.ingest import DropIngest
    from accelcal.tasks.store import record_drop
    a, b, c = "a" * 64, "b" * 64, "c" * 64
    wh.record_runs([rec(a, "/d/x.csv", status="refused"), rec(b, "/d/y.csv", run_id="R-2"),
                    rec(c, "/e/z.csv", run_id="R-3", status="refused")])
    wh.record_runs([rec(a, "/d/x.csv", vv="val.2"),                       # refused, then accepted
                    rec(b, "/d/y.csv", run_id="R-2", vv="val.2", status="refused")])
    known = wh.latest_verdicts("/d/")
    assert set(known) == {(a, "/d/x.csv"), (b, "/d/y.csv")}
    view = {(r["sha256"], r["source_path"]): r for r in wh.query("SELECT * FROM runs")}
    for k, v in known.items():
        assert (v.validator_version, v.status, v.reason, v.campaign) == (
            view[k]["validator_version"], view[k]["status"], view[k]["reason"], view[k]["campaign"])
    assert known[(a, "/d/x.csv")].status == "accepted" and known[(a, "/d/x.csv")].reason is None
    keys = [(b, "/d/y.csv"), (a, "/d/x.csv")]
    ing = DropIngest("d", "/d", keys=keys)
    assert _fields(record_drop(wh, ing, None, known)) == _fields(wh.stored_runs(keys))
    assert wh.counts()["run_verdicts"] == 5                                 # nothing written


def test_known_files_of_the_sample_drops_give_their_stored_records(sample_lab, examples, tmp_path):
    """Every sample drop (accepted, refused, revised files): its known files' records are
    stored_runs' for the same keys."""
    from accelcal.tasks.ingest import DropIngest
    from accelcal.tasks.store import known_keys, record_drop
    from conftest import SAMPLE_LAB_DROPS, copy_lab
    w = Warehouse(copy_lab(sample_lab, tmp_path / "lab"), lock_timeout=5)
    for drop in SAMPLE_LAB_DROPS:
        known = known_keys(w, str(examples / drop))
        assert known, drop
        ing = DropIngest(drop, str(examples / drop), keys=sorted(known))
        got = record_drop(w, ing, None, known)
        assert _fields(got) == _fields(w.stored_runs(ing.keys)), drop
        assert {r["status"] for r in got} <= {"accepted", "refused"}


def test_store_result_idempotent_with_lineage(wh):
    a = "a" * 64
    wh.record_runs([rec(a, "/d/x.csv")])
    rid, status = store(wh, result())
    assert status == "new"
    before = wh.counts()
    assert store(wh, result())[1] == "unchanged"
    assert wh.counts() == before
    coefs = wh.query("SELECT name, result_id FROM coefficients")
    assert {c["name"] for c in coefs} == {"K0", "K2"} and {c["result_id"] for c in coefs} == {rid}
    with wh.connect() as con:
        assert [t["sha256"] for t in trace(con, rid)] == [a]
        assert verify_lineage(con) == []
    lin = wh.query("SELECT * FROM lineage")
    assert lin[0]["flow_run_id"] == "flow-1" and lin[0]["code_version"] == CV
    assert wh.query("SELECT flag FROM flags")[0]["flag"] == "a flag"
    assert wh.query("SELECT radius_m FROM radii")[0]["radius_m"] == pytest.approx(0.7147)


def test_superseded_results_stay_queryable_as_of(wh):
    a, b = "a" * 64, "b" * 64
    wh.record_runs([rec(a, "/d/x.csv")])
    rid1, _ = store(wh, result(k2=1e-7))
    t_between = wh.query("SELECT now() AS t")[0]["t"]
    time.sleep(0.01)
    wh.record_runs([rec(b, "/d/x2.csv")])        # revision 2 of R-1
    rid2, status = store(wh, result(shas=(b,), k2=2e-7))
    assert status == "new" and rid1 != rid2
    assert wh.query("SELECT value FROM coefficients WHERE name = 'K2'")[0]["value"] == 2e-7
    old = wh.query("SELECT value FROM coefficients_as_of(?) WHERE name = 'K2'", [t_between])
    assert [r["value"] for r in old] == [1e-7]
    hist = {r["result_id"]: r for r in wh.query("SELECT * FROM result_history")}
    assert hist[rid1]["superseded_by"] == rid2 and not hist[rid1]["is_current"]
    assert hist[rid2]["is_current"]
    assert wh.query("SELECT count(*) AS n FROM coefficient_history")[0]["n"] == 4


def test_earlier_identical_result_is_reactivated_not_duplicated(wh):
    a = "a" * 64
    wh.record_runs([rec(a, "/d/x.csv")])
    res = result()
    inputs = wh.campaign_inputs("C/1")
    kw = dict(inputs=inputs, parameters=PARAMS, flow_run_id="f")
    wh.store_result(res, result_id="r1", code_version="v1", **kw)
    wh.store_result(res, result_id="r2", code_version="v2", **kw)
    assert wh.store_result(res, result_id="r1", code_version="v1", **kw) == "reactivated"
    assert wh.query("SELECT result_id FROM results_current")[0]["result_id"] == "r1"
    assert wh.counts()["results"] == 2 and wh.counts()["result_activations"] == 3


@pytest.mark.parametrize("step", ["extras", "results", "lineage", "coefficients", "radii", "details",
                                  "activate", "commit"])
def test_exception_between_statements_leaves_warehouse_as_before(wh, step):
    wh.record_runs([rec("a" * 64, "/d/x.csv")])
    before = wh.counts()

    def boom(s):
        if s == step:
            raise RuntimeError("injected")
    with pytest.raises(RuntimeError, match="injected"):
        store(wh, result(), checkpoint=boom)
    assert wh.counts() == before
    assert wh.query("SELECT count(*) AS n FROM coefficients")[0]["n"] == 0
    assert store(wh, result())[1] == "new"


def test_extras_are_a_content_addressed_file_the_row_names(wh):
    """results.extras_sha256 names <stem>-extras/<sha[:2]>/<sha>.json (schema_info.extras_dir),
    whose bytes are the canonical JSON; a missing or altered file is one ExtrasError line."""
    import hashlib
    import json

    from accelcal.warehouse.errors import ExtrasError
    from accelcal.warehouse.extras import extras_file, load_extras, write_extras
    wh.record_runs([rec("a" * 64, "/d/x.csv")])
    store(wh, result())
    sha = wh.query("SELECT extras_sha256 FROM results")[0]["extras_sha256"]
    assert wh.query("SELECT value FROM schema_info WHERE key = 'extras_dir'")[0]["value"] == \
        "lab-extras"
    f = extras_file(wh.root / "lab-extras", sha)
    assert f.read_bytes() == b'{"x":[1,2]}' and hashlib.sha256(f.read_bytes()).hexdigest() == sha
    assert load_extras(wh.extras_root, sha) == {"x": [1, 2]}
    # SQL reads it too (the path from schema_info and the sha)
    got = wh.query("SELECT content FROM read_text(?)", [str(f)])[0]["content"]
    assert json.loads(got) == {"x": [1, 2]}
    os.chmod(f, 0o644)
    f.write_bytes(b'{"x":[1,3]}')
    with pytest.raises(ExtrasError, match="does not hold the bytes"):
        load_extras(wh.extras_root, sha)
    f.unlink()
    with pytest.raises(ExtrasError, match="cannot read the extras") as e:
        load_extras(wh.extras_root, sha)
    assert "\n" not in str(e.value)
    # writing the same extras again (a re-run after a kill) puts the right bytes back
    f.parent.mkdir(exist_ok=True)
    f.write_bytes(b'{"x":')
    assert write_extras(wh.extras_root, ['{"x":[1,2]}']) == [sha]
    assert load_extras(wh.extras_root, sha) == {"x": [1, 2]}


_KILL_SCRIPT = textwrap.dedent("""
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    from test_warehouse import Warehouse, rec, result, store
    wh = Warehouse({db!r})
    step = {step!r}
    def kill(s):
        if s == step:
            os.kill(os.getpid(), signal.SIGKILL)
    if step.startswith("run:"):
        wh.record_runs([rec("c" * 64, "/d/z.csv"), rec("d" * 64, "/d/w.csv")], checkpoint=kill)
    else:
        store(wh, result(), checkpoint=kill)
""")


@pytest.mark.parametrize("step", ["extras", "lineage", "details", "commit", "run:0"])
def test_sigkill_mid_write_leaves_warehouse_as_before(wh, step):
    wh.record_runs([rec("a" * 64, "/d/x.csv")])
    before = wh.counts()
    script = _KILL_SCRIPT.format(tests=str(Path(__file__).parent), db=str(wh.path), step=step)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    after = Warehouse(wh.path)
    assert after.counts() == before
    # ... and running again completes the work exactly once
    if step.startswith("run:"):
        after.record_runs([rec("c" * 64, "/d/z.csv"), rec("d" * 64, "/d/w.csv")])
        assert after.counts()["run_files"] == before["run_files"] + 2
    else:
        assert store(after, result())[1] == "new"
        assert store(after, result())[1] == "unchanged"
        assert after.counts()["results"] == before["results"] + 1


def test_second_writer_waits_then_fails_naming_the_pid(tmp_path):
    db = tmp_path / "lab.duckdb"
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; from accelcal.warehouse import warehouse_lock\n"
         f"with warehouse_lock({str(db)!r}):\n"
         "    print('locked', flush=True); time.sleep(30)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        t0 = time.monotonic()
        with pytest.raises(WarehouseBusy) as e:
            with warehouse_lock(db, timeout=0.5):
                pass
        assert time.monotonic() - t0 >= 0.4
        assert f"warehouse {db} is in use by pid {holder.pid}" in str(e.value)
        with pytest.raises(WarehouseBusy):
            Warehouse(db, lock_timeout=0.2).init()
    finally:
        holder.kill()
        holder.wait()
    with warehouse_lock(db, timeout=5):       # released when the holder dies
        pass


def test_lock_is_reentrant_in_process(tmp_path):
    db = tmp_path / "lab.duckdb"
    with warehouse_lock(db, timeout=0.1):
        with warehouse_lock(db, timeout=0.1):
            Warehouse(db, lock_timeout=0.1).init()


def test_result_id_is_deterministic():
    r1 = result_id("C", ["b", "a"], "v", {"x": 1, "y": [1, 2]})
    assert r1 == result_id("C", ["a", "b", "a"], "v", {"y": [1, 2], "x": 1})
    assert r1 != result_id("C", ["a", "b"], "v2", {"x": 1, "y": [1, 2]})
    assert r1 != result_id("C", ["a"], "v", {"x": 1, "y": [1, 2]})


def test_roomy_raises_the_memory_limit_for_its_statements_then_sets_it_back(monkeypatch):
    """The write connection's cap (64 MB) is too small for the plan query of a large
    warehouse (2,000 campaigns: 'could not allocate block'); roomy lifts it for those
    statements and puts it back."""
    import duckdb
    from accelcal.warehouse.db import roomy
    monkeypatch.setenv("ACCELCAL_DUCKDB_MEMORY", "64MB")
    monkeypatch.setenv("ACCELCAL_DUCKDB_QUERY_MEMORY", "1GB")
    con = duckdb.connect()
    con.execute("SET memory_limit = '64MB'").fetchall()

    def limit():
        return con.execute("SELECT current_setting('memory_limit')").fetchall()[0][0]
    before = limit()
    with roomy(con):
        inside = limit()
    assert (before, inside) == ("61.0 MiB", "953.6 MiB")    # 64 MB, 1 GB in MiB
    assert limit() == before

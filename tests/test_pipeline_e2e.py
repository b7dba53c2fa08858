"""End to end on the shared sample drops: counts, refusals, idempotency, lineage, revisions.

Most runs use the 'local' engine (same steps, no Prefect server); one test runs the
real Prefect flow.
"""
from __future__ import annotations

import hashlib
import shutil
import uuid
from pathlib import Path

import pytest

from accelcal.flows.pipeline import PipelineError, quiet_prefect, run_pipeline
from accelcal.warehouse import Warehouse, verify_lineage

from conftest import EXAMPLES  # noqa: E402  (ACCELCAL_SHARED, else ../shared)
SAMPLE = EXAMPLES / "drop-2026-11-20"
BAD = EXAMPLES / "drop-bad"
CAMPAIGN = "SNJ-1-03/2026-11-20"

quiet_prefect()   # before Prefect is imported: no INFO logs into pytest's closed streams at exit

pytestmark = pytest.mark.skipif(not SAMPLE.is_dir() or not BAD.is_dir(),
                                reason="../shared/examples not available")


def sha256(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def raw_state(*drops: Path) -> dict[str, tuple[str, float]]:
    return {str(p): (sha256(p), p.stat().st_mtime) for d in drops for p in sorted(d.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory):
    before = raw_state(SAMPLE, BAD)
    db = tmp_path_factory.mktemp("wh") / "lab.duckdb"
    summary = run_pipeline([SAMPLE, BAD], db, engine="local")
    return db, summary, before


def test_counts_and_refusals(sample_run):
    db, summary, _ = sample_run
    wh = Warehouse(db)
    st = {r["status"]: r["n"] for r in wh.query("SELECT status, count(*) AS n FROM runs GROUP BY 1")}
    assert st == {"accepted": 12, "refused": 11}
    accepted = {Path(r["source_path"]).name for r in
                wh.query("SELECT source_path FROM runs WHERE status = 'accepted'")}
    assert accepted == {p.name for p in SAMPLE.rglob("*.csv")} | {"ok-small.csv"}
    refused = wh.query("SELECT source_path, reason FROM runs WHERE status = 'refused'")
    assert {Path(r["source_path"]).name for r in refused} == \
        {p.name for p in BAD.glob("*.csv")} - {"ok-small.csv"}
    for r in refused:
        assert r["reason"] and Path(r["source_path"]).name in r["reason"], r
    assert not any(r["source_path"].endswith(".part") for r in wh.query("SELECT source_path FROM runs"))
    by_drop = {d["drop"]: d for d in summary["drops"]}
    assert (by_drop["drop-2026-11-20"]["accepted"], by_drop["drop-2026-11-20"]["refused"]) == (11, 0)
    assert (by_drop["drop-bad"]["accepted"], by_drop["drop-bad"]["refused"]) == (1, 11)
    # refusals are also stored rule by rule
    assert wh.query("SELECT count(DISTINCT source_path) AS n FROM refusals")[0]["n"] == 11
    # Data Docs next to the warehouse, one folder per drop
    for d in ("drop-2026-11-20", "drop-bad"):
        assert list((wh.docs_root / d).rglob("*.html")), d


def test_every_coefficient_traces_to_raw_bytes(sample_run):
    db, summary, _ = sample_run
    wh = Warehouse(db)
    expected = {CAMPAIGN: {sha256(p) for p in SAMPLE.rglob("*.csv")},
                "X/1": {sha256(BAD / "ok-small.csv")}}
    coefs = wh.query("SELECT DISTINCT campaign, result_id FROM coefficients")
    assert {c["campaign"] for c in coefs} == set(expected)
    for c in coefs:
        lin = wh.query("SELECT sha256, flow_run_id, code_version, parameters FROM lineage "
                       "WHERE result_id = ?", [c["result_id"]])
        assert {r["sha256"] for r in lin} == expected[c["campaign"]]
        assert all(r["flow_run_id"] == summary["flow_run_id"] and r["code_version"]
                   and r["parameters"] is not None for r in lin)
    n = wh.query("SELECT count(*) AS n FROM coefficients")[0]["n"]
    assert n > 0
    with wh.connect() as con:
        assert verify_lineage(con) == []
    # the Parquet copies the campaigns were read from carry the raw files' sha256
    from accelcal.schemas.tables import read_run_parquet
    for r in wh.query("SELECT sha256, parquet_path FROM runs WHERE status = 'accepted'"):
        assert read_run_parquet(wh.root / r["parquet_path"]).sha256 == r["sha256"]


def test_rerun_changes_no_row_count_and_raw_files_untouched(sample_run):
    db, _, before = sample_run
    counts = Warehouse(db).counts()
    summary = run_pipeline([SAMPLE, BAD], db, engine="local")
    assert Warehouse(db).counts() == counts
    assert {c["status"] for c in summary["campaigns"]} == {"unchanged"}
    assert raw_state(SAMPLE, BAD) == before


def test_reexport_with_changed_bytes_is_revision_2_and_used(tmp_path):
    drop1 = tmp_path / "drop-a"
    shutil.copytree(SAMPLE, drop1)
    db = tmp_path / "lab.duckdb"
    run_pipeline([drop1], db, engine="local")
    wh = Warehouse(db)
    old_rid = wh.query("SELECT result_id FROM results_current WHERE campaign = ?", [CAMPAIGN])[0]
    # a later drop brings run 0002 again with one reading changed in its last digit
    src = drop1 / "centrifuge" / "LXJ100-20261120-0002.csv"
    lines = src.read_text().splitlines(keepends=True)
    k = len(lines) - 3
    fields = lines[k].rstrip("\n").split(",")
    fields[4] = fields[4][:-1] + ("1" if fields[4][-1] != "1" else "2")
    lines[k] = ",".join(fields) + "\n"
    drop2 = tmp_path / "drop-b"
    (drop2 / "centrifuge").mkdir(parents=True)
    new = drop2 / "centrifuge" / src.name
    new.write_text("".join(lines))
    assert sha256(new) != sha256(src)

    summary = run_pipeline([drop2], db, engine="local")
    rows = wh.query("SELECT revision, sha256, status FROM runs WHERE run_id = "
                    "'LXJ100-20261120-0002' ORDER BY revision")
    assert [(r["revision"], r["sha256"], r["status"]) for r in rows] == [
        (1, sha256(src), "accepted"), (2, sha256(new), "accepted")]
    # the campaign now rests on revision 2 (and still on the other ten runs of drop-a)
    camp = next(c for c in summary["campaigns"] if c["campaign"] == CAMPAIGN)
    assert camp["status"] == "new" and camp["n_runs"] == 11
    rid = camp["current_result_id"]
    lin = {r["sha256"] for r in wh.query("SELECT sha256 FROM lineage WHERE result_id = ?", [rid])}
    assert sha256(new) in lin and sha256(src) not in lin and len(lin) == 11
    hist = {r["result_id"]: r for r in wh.query(
        "SELECT result_id, is_current, superseded_by FROM result_history WHERE campaign = ?",
        [CAMPAIGN])}
    assert hist[old_rid["result_id"]]["superseded_by"] == rid and hist[rid]["is_current"]


def test_missing_drop_is_a_clear_error(tmp_path):
    with pytest.raises(PipelineError, match="does not exist"):
        run_pipeline([tmp_path / "nope"], tmp_path / "lab.duckdb", engine="local")


def test_prefect_flow_end_to_end(tmp_path):
    """The real Prefect flow on the small bad drop (one flow run: a few seconds)."""
    db = tmp_path / "lab.duckdb"
    summary = run_pipeline([BAD], db, engine="prefect")
    uuid.UUID(summary["flow_run_id"])            # a real Prefect flow run id
    wh = Warehouse(db)
    assert wh.query("SELECT count(*) AS n FROM runs WHERE status = 'accepted'")[0]["n"] == 1
    lin = wh.query("SELECT DISTINCT flow_run_id FROM lineage")
    assert [r["flow_run_id"] for r in lin] == [summary["flow_run_id"]]

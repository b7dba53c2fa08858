"""A batch of a drop whose ingest fails (a bug in a step, not a bad file) must not let that
drop's campaigns be computed from the runs of its other batches: a current result from part
of a campaign's runs would stand in the warehouse until someone ran the drop again."""
from __future__ import annotations

import shutil

import pytest

from conftest import EXAMPLES, needs_shared

DROP = "drop-2026-11-21"        # one campaign: a tumble and six centrifuge runs


@needs_shared
def test_a_failed_batch_holds_back_its_drops_campaigns_until_a_rerun(tmp_path, monkeypatch):
    from accelcal.flows.pipeline import run_pipeline
    from accelcal.tasks import validate
    from accelcal.warehouse import Warehouse
    drop = tmp_path / DROP
    shutil.copytree(EXAMPLES / DROP, drop)
    wh = tmp_path / "lab.duckdb"
    monkeypatch.setenv("ACCELCAL_WORKERS", "1")       # the batches run in this process
    monkeypatch.setenv("ACCELCAL_BATCH_FILES", "3")   # three batches of the seven files
    real = validate.intake_batch

    def failing(drop_dir, paths, *a, **kw):
        if any("LXJ200-20261121-0006" in str(getattr(p, "path", p)) for p in paths):
            raise RuntimeError("injected step failure")
        return real(drop_dir, paths, *a, **kw)

    monkeypatch.setattr(validate, "intake_batch", failing)
    summary = run_pipeline([str(drop)], wh, engine="local", settle=0)
    (d,) = summary["drops"]
    assert d["errors"] and "injected step failure" in d["errors"][0]
    assert d["accepted"] >= 4                   # the other batches' files are kept
    assert summary["campaigns"] == []           # ... but their campaign is not computed
    assert any("not computed: a batch of its files failed" in w for w in d["warnings"])
    assert Warehouse(wh).query("SELECT count(*) AS n FROM results")[0]["n"] == 0

    monkeypatch.setattr(validate, "intake_batch", real)
    again = run_pipeline([str(drop)], wh, engine="local", settle=0)
    assert [c["status"] for c in again["campaigns"]] == ["new"]
    (n,) = Warehouse(wh).query("SELECT count(*) AS n FROM run_files")
    assert n["n"] == 7

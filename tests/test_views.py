"""Fleet / recalibration-history views (accelcal/warehouse/views.sql).

Hand-made results with known numbers (paper 000 Table 5 for the rig
comparison), then the example drops end to end.
"""
from __future__ import annotations

import hashlib
import math
import time

import duckdb
import pytest

from accelcal.warehouse import ensure_views
from accelcal.warehouse.views import apply_views, macro_names, view_names
from accelcal.results import CampaignResult, CoefficientResult
from accelcal.warehouse import RunRecord, Warehouse
from conftest import copy_lab

CV = "test+views"


def _sha(*parts) -> str:
    return hashlib.sha256("|".join(map(str, parts)).encode()).hexdigest()


def add_campaign(wh: Warehouse, serial: str, campaign: str, rig: str, started: str,
                 coefs: dict[str, tuple[float, float]], model: str = "QA-2000",
                 method: str = "centrifuge_eq9", salt: str = "") -> str:
    """One run file + one result with the given {name: (value, u)} or {name: (value, u,
    factors)} (a combination), each the adopted value of its coefficient (history reads
    adopted values); returns result_id."""
    with wh.session():          # one open of the file for the three writes
        sha = _sha(serial, campaign, rig, salt)
        wh.record_runs([RunRecord(sha256=sha, source_path=f"/drops/{campaign}/{rig}{salt}.csv",
                                  drop_name="d", drop_path="/drops", size_bytes=1, status="accepted",
                                  run_id=f"{rig}-{campaign}{salt}", test="centrifuge",
                                  unit_serial=serial, unit_model=model, campaign=campaign, rig_id=rig,
                                  started_at=started, n_rows=1, parquet_path=None,
                                  validator_version="v1")])
        res = CampaignResult(campaign=campaign, unit_serial=serial, unit_model=model,
                             tests=["centrifuge"], rig_ids=[rig], input_sha256=[sha],
                             coefficients=[CoefficientResult(n, v, u, "s2/m", method, rig, adopted=True,
                                                             factors=dict(*f))
                                           for n, (v, u, *f) in coefs.items()])
        inputs = wh.campaign_inputs(campaign)
        rid = _sha("result", campaign, salt, *sorted(i["sha256"] for i in inputs))
        wh.store_result(res, result_id=rid, inputs=inputs, code_version=CV, parameters={},
                        flow_run_id="f")
        return rid


def rows(con, sql, params=None):
    cur = con.execute(sql, params or [])
    cols = [d[0] for d in cur.description]
    return [dict(zip(cols, r)) for r in cur.fetchall()]


@pytest.fixture
def wh(tmp_path) -> Warehouse:
    w = Warehouse(tmp_path / "lab.duckdb", lock_timeout=5)
    w.init()
    ensure_views(w.path)
    return w


def test_views_apply_idempotently_and_exist(wh):
    with wh.connect() as con:
        apply_views(con)
        apply_views(con)
        have = {r[0] for r in con.execute("SELECT view_name FROM duckdb_views()").fetchall()}
        macros = {r[0] for r in con.execute("SELECT function_name FROM duckdb_functions() "
                                            "WHERE function_type = 'table_macro'").fetchall()}
    assert set(view_names()) <= have and "fleet_stats" in view_names()
    assert set(macro_names()) <= macros and "unit_history_as_of" in macro_names()


def test_rig_comparison_reproduces_table5_reference_and_en(wh):
    """Paper 000 Table 5: Kip 7.10e-7 (LXJ-100), 6.67e-7 (LXJ-200); u 0.11e-7, 0.10e-7."""
    add_campaign(wh, "SNJ-1-03", "S/100", "LXJ-100", "2026-11-20T10:00:00+08:00",
                 {"Kip": (7.10e-7, 0.11e-7), "K2": (3.94e-7, 0.02e-7)})
    add_campaign(wh, "SNJ-1-03", "S/200", "LXJ-200", "2026-11-21T10:00:00+08:00",
                 {"Kip": (6.67e-7, 0.10e-7), "K2": (4.13e-7, 0.02e-7)})
    with wh.connect() as con:
        rc = {r["rig_id"]: r for r in rows(con, "SELECT * FROM rig_comparison WHERE name = 'Kip'")}
        pair = rows(con, "SELECT * FROM rig_pairs WHERE name = 'Kip'")
    assert set(rc) == {"LXJ-100", "LXJ-200"}
    ref = (7.10e-7 + 6.67e-7) / 2
    U_ref = 2 * math.sqrt(0.11e-7 ** 2 + 0.10e-7 ** 2) / 2
    for rig, x, u in (("LXJ-100", 7.10e-7, 0.11e-7), ("LXJ-200", 6.67e-7, 0.10e-7)):
        r = rc[rig]
        assert r["n_rigs"] == 2
        assert r["reference_value"] == pytest.approx(ref, rel=1e-12)
        assert r["reference_expanded_uncertainty"] == pytest.approx(U_ref, rel=1e-12)
        assert r["en"] == pytest.approx((x - ref) / math.sqrt((2 * u) ** 2 + U_ref ** 2), rel=1e-12)
    # |En| 0.81 and 0.86 (the paper prints 0.84 and 0.85 without stating U_ref)
    assert abs(rc["LXJ-100"]["en"]) == pytest.approx(0.81, abs=0.01)
    assert abs(rc["LXJ-200"]["en"]) == pytest.approx(0.86, abs=0.01)
    assert not any(r["exceeds_uncertainty"] for r in rc.values())
    (p,) = pair
    assert (p["rig_a"], p["rig_b"]) == ("LXJ-100", "LXJ-200")
    assert p["en"] == pytest.approx(0.43e-7 / math.sqrt(0.22e-7 ** 2 + 0.20e-7 ** 2), rel=1e-9)
    assert p["exceeds_uncertainty"]          # 1.45: the rigs disagree pairwise


def test_history_changes_and_superseded_results_as_of(wh):
    s = "SN-9"
    add_campaign(wh, s, "SN-9/2025-01", "LXJ-100", "2025-01-10T09:00:00+00:00",
                 {"K2": (3.90e-7, 0.02e-7)})
    add_campaign(wh, s, "SN-9/2025-07", "LXJ-100", "2025-07-10T09:00:00+00:00",
                 {"K2": (3.93e-7, 0.02e-7)})
    add_campaign(wh, s, "SN-9/2026-01", "LXJ-100", "2026-01-10T09:00:00+00:00",
                 {"K2": (4.10e-7, 0.02e-7)})
    with wh.connect() as con:
        t_before = con.execute("SELECT now()").fetchall()[0][0]
    time.sleep(0.05)
    # the 2025-07 campaign is reprocessed (a re-export): its old result is superseded
    add_campaign(wh, s, "SN-9/2025-07", "LXJ-100", "2025-07-10T09:00:00+00:00",
                 {"K2": (3.95e-7, 0.02e-7)}, salt="rev2")
    with wh.connect() as con:
        hist = rows(con, "SELECT * FROM unit_history WHERE unit_serial = ? AND name = 'K2' "
                         "ORDER BY calibration_no", [s])
        ch = rows(con, "SELECT * FROM coefficient_changes WHERE unit_serial = ? "
                       "ORDER BY calibration_no", [s])
        old = rows(con, "SELECT * FROM unit_history_as_of(?) WHERE unit_serial = ? "
                        "ORDER BY calibration_no", [t_before, s])
        old_ch = rows(con, "SELECT * FROM coefficient_changes_as_of(?) WHERE unit_serial = ? "
                           "ORDER BY calibration_no", [t_before, s])
        versions = rows(con, "SELECT * FROM coefficient_versions WHERE campaign = 'SN-9/2025-07'")
    assert [h["campaign"] for h in hist] == ["SN-9/2025-01", "SN-9/2025-07", "SN-9/2026-01"]
    assert [h["value"] for h in hist] == pytest.approx([3.90e-7, 3.95e-7, 4.10e-7])
    assert hist[0]["expanded_uncertainty"] == pytest.approx(0.04e-7)
    assert [h["value"] for h in old] == pytest.approx([3.90e-7, 3.93e-7, 4.10e-7])
    U = 0.04e-7
    assert [c["en"] for c in ch] == pytest.approx([0.05e-7 / math.hypot(U, U),
                                                   0.15e-7 / math.hypot(U, U)])
    assert [c["exceeds_uncertainty"] for c in ch] == [False, True]
    assert [c["en"] for c in old_ch] == pytest.approx([0.03e-7 / math.hypot(U, U),
                                                       0.17e-7 / math.hypot(U, U)])
    assert all(c["same_rig"] for c in ch)
    # nothing overwritten: both versions of the reprocessed campaign are there
    assert sorted((v["value"], v["is_current"]) for v in versions) == [(3.93e-7, False),
                                                                       (3.95e-7, True)]


def test_fleet_stats_and_robust_outlier(wh):
    vals = [4.00e-7, 4.02e-7, 3.98e-7, 4.01e-7, 3.99e-7, 4.03e-7, 3.97e-7, 5.00e-7]
    for i, v in enumerate(vals):
        add_campaign(wh, f"U-{i}", f"U-{i}/2026", "LXJ-100", "2026-03-01T00:00:00+00:00",
                     {"K2": (v, 0.02e-7)})
    # an older calibration of U-0 must not count: the fleet uses each unit's latest
    add_campaign(wh, "U-0", "U-0/2020", "LXJ-100", "2020-03-01T00:00:00+00:00",
                 {"K2": (9.0e-7, 0.02e-7)})
    add_campaign(wh, "V-1", "V-1/2026", "LXJ-200", "2026-03-01T00:00:00+00:00",
                 {"K2": (4.0e-7, 0.02e-7)})
    with wh.connect() as con:
        st = rows(con, "SELECT * FROM fleet_stats WHERE name = 'K2' ORDER BY rig_id")
        out = rows(con, "SELECT * FROM fleet_outliers")
    s100, s200 = st
    assert (s100["rig_id"], s100["n_units"], s200["n_units"]) == ("LXJ-100", 8, 1)
    assert s100["mean"] == pytest.approx(sum(vals) / len(vals))
    assert s100["median"] == pytest.approx(sorted(vals)[3] / 2 + sorted(vals)[4] / 2)
    assert s100["lcl"] < 3.97e-7 and s100["ucl"] > 4.03e-7
    assert s200["lcl"] is None                      # too few units for limits
    # the outlier is found although it lies within mean +- 3 sd (it inflates the sd)
    assert s100["mean_minus_3sd"] < 5.0e-7 < s100["mean_plus_3sd"]
    assert [(o["unit_serial"], o["value"]) for o in out] == [("U-7", 5.0e-7)]
    assert out[0]["robust_z"] > 3


@pytest.fixture(scope="module")
def examples_wh(sample_lab, tmp_path_factory):
    """A copy of the run's warehouse of the sample drops (2026-11-20, 2026-11-21, drop-bad)."""
    return copy_lab(sample_lab, tmp_path_factory.mktemp("views") / "lab")


def test_example_drops_same_unit_on_two_centrifuges(examples_wh):
    con = duckdb.connect(str(examples_wh), read_only=True)
    try:
        # the adopted values (the joint fit)
        rc = rows(con, "SELECT * FROM rig_comparison WHERE name = 'Kip' AND method = 'joint_ml' ORDER BY rig_id")
        hist = rows(con, "SELECT * FROM unit_history WHERE unit_serial = 'SNJ-1-03'")
        ch = rows(con, "SELECT * FROM coefficient_changes WHERE name = 'Kip' AND method = 'joint_ml'")
    finally:
        con.close()
    assert [r["rig_id"] for r in rc] == ["LXJ-100", "LXJ-200"]
    # truth 7.1e-7 on both rigs: the two centrifuges agree within their uncertainty
    for r in rc:
        assert r["value"] == pytest.approx(7.1e-7, rel=0.03)
        assert abs(r["en"]) < 1
    assert {h["campaign"] for h in hist} == {"SNJ-1-03/2026-11-20", "SNJ-1-03/2026-11-21-LXJ200"}
    (c,) = ch
    assert (c["prev_rig_id"], c["rig_id"], c["same_rig"]) == ("LXJ-100", "LXJ-200", False)
    assert c["prev_calibrated_at"] < c["calibrated_at"]

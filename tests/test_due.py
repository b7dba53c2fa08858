"""``accelcal due``, ``history``, ``campaign adjust`` and the ``recalibration_forecast``
view (issue 29) on hand-made warehouses (tests/test_views.add_campaign)."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from accelcal.cli import main
from accelcal.warehouse import ensure_views
from accelcal.warehouse import Warehouse
from test_views import add_campaign

TOML = ('[tolerance."QA-2000"]\nK1 = { relative = 2.0e-4 }\nK0 = { absolute = 5.0e-4 }\n'
        '[forecast]\nrisk = 0.05\n')
K1_U = 0.1 * 5e-6


@pytest.fixture(scope="session")
def fleet_built(tmp_path_factory):
    """Five QA-2000 units tumbled yearly 2021-2026: QA-0 and QA-1 stable, QA-2 drifting
    1e-4/a in K1, QA-3 calibrated once, QA-4 adjusted in 2024 (K1 reset to 0.1); QA-0
    also has a tumble's combination theta0(Ko); QA-2's last tumble started at 02:00 in
    UTC+08:00 (its certificate's date, 2026-03-01, is the UTC day before).  Built once."""
    tmp_path = tmp_path_factory.mktemp("fleet")
    w = Warehouse(tmp_path / "lab.duckdb", lock_timeout=5)
    w.init()
    ensure_views(w.path)
    rng = np.random.default_rng(7)
    for j in range(5):
        years = range(2021, 2022) if j == 3 else range(2021, 2027)
        for y in years:
            k1 = 0.1 * (1 + (1e-4 * (y - 2021) if j == 2 else 0))
            if j == 4:
                k1 = 0.1 * (1 + 1e-4 * ((y - 2024) if y >= 2024 else (y - 2021)))
            k1 += K1_U * rng.standard_normal()
            coefs = {"K1": (k1, K1_U), "K2": (4e-7, 2e-9)}
            if j == 0:
                coefs["theta0(Ko)"] = (1e-5 + 2e-7 * (y - 2021), 2e-8, {"Ko": -1.0})
            start = ("2026-03-01T02:00:00+08:00" if (j, y) == (2, 2026) else
                     f"{y}-03-01T10:00:00+00:00")
            add_campaign(w, f"QA-{j}", f"QA-{j}/{y}", "DH-1", start, coefs)
    with w.connect() as con:   # as if each result had been stored a week after its tumble
        for table, col in (("result_activations", "activated_at"), ("results", "computed_at")):
            con.execute(f"UPDATE {table} SET {col} = CAST(split_part(campaign, '/', 2) "
                        "|| '-03-08 00:00:00+00' AS TIMESTAMPTZ)")
    (tmp_path / "accelcal.toml").write_text(TOML)
    return tmp_path


@pytest.fixture
def fleet(fleet_built, tmp_path):
    """A copy of the fleet's warehouse and config for one test (some tests write)."""
    shutil.copytree(fleet_built, tmp_path / "fleet")
    return tmp_path / "fleet"


def _due(capsys, *args):
    capsys.readouterr()
    rc = main(["due", *args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_due_json_rows_and_bases(fleet, capsys):
    wh = str(fleet / "lab.duckdb")
    rc, out, _ = _due(capsys, "-w", wh, "--config", str(fleet / "accelcal.toml"), "--json",
                      "--as-of", "2026-06-01")
    assert rc == 0
    rows = {(r["unit_serial"], r["coefficient"]): r for r in json.loads(out)}
    keys = {"unit_serial", "unit_model", "coefficient", "n_campaigns", "last_calibrated",
            "drift_per_year", "u_drift_per_year", "due_date", "p_out_at_due", "basis"}
    assert all(keys <= set(r) for r in rows.values())
    drifting = rows[("QA-2", "K1")]
    assert drifting["drift_per_year"] == pytest.approx(1e-5, rel=0.05)
    # 1e-4/a against 2e-4: the tolerance is used up two years after 2026-03-01
    assert "2027-06-01" < drifting["due_date"] < "2028-03-01"
    assert drifting["p_out_at_due"] == pytest.approx(0.05, abs=0.01)
    assert rows[("QA-0", "K1")]["due_date"] is None
    once = rows[("QA-3", "K1")]
    assert once["n_campaigns"] == 1 and once["basis"].startswith("fleet prior")
    assert rows[("QA-0", "K2")]["due_date"] is None
    assert rows[("QA-0", "K2")]["basis"].startswith("no tolerance")
    # the unmarked reset is a step the line cannot explain: flagged, a new series
    assert [s["campaign"] for s in rows[("QA-4", "K1")]["steps"]] == ["QA-4/2024"]


def test_due_within_and_text_at_80_columns(fleet, capsys):
    wh = str(fleet / "lab.duckdb")
    cfg = str(fleet / "accelcal.toml")
    rc, out, _ = _due(capsys, "-w", wh, "--config", cfg, "--within", "90d",
                      "--as-of", "2026-06-01", "--json")
    assert rc == 0 and all(r["due_date"] <= "2026-08-30" for r in json.loads(out))
    rc, out, _ = _due(capsys, "-w", wh, "--config", cfg, "--as-of", "2026-06-01")
    assert rc == 0 and "QA-2" in out and "ppm/a" in out
    assert max(len(line) for line in out.splitlines()) <= 80, out
    # full names, every rate with its display unit (the catalogue's: theta0 in degrees)
    assert ("QA-0  theta0 (as theta0 - 1·Ko, the combination the design determines)  no due "
            "date") in out.replace("\n    ", " ") and "°/a (u, k = 1)" in out
    drifts = [ln for ln in out.replace("\n    ", " ").splitlines() if "drift " in ln]
    assert drifts and all(re.search(r"drift -?[0-9.]+ ± [0-9.]+ (ppm|µg/g²|°)/a", ln) for ln in drifts), drifts
    # QA-3, calibrated once in 2021, is overdue; QA-2 is not yet
    assert "QA-3  K1  due 2022-02-17 OVERDUE (as of 2026-06-01)" in out
    assert "OVERDUE" not in out[out.index("QA-2  K1"):].split("\n")[0]
    # the certificate's calibration date (the run's own offset), not the UTC date
    qa2 = out[out.index("QA-2  K1"):]
    assert "last 2026-03-01" in qa2.replace("\n    ", " ")[:300]
    rc, out, _ = _due(capsys, "-w", wh, "--config", cfg, "--as-of", "2030-01-01", "--json")
    row = next(r for r in json.loads(out) if (r["unit_serial"], r["coefficient"]) == ("QA-2", "K1"))
    assert row["overdue"] and row["last_calibrated"] == "2026-03-01"
    assert row["drift_display"].endswith(" ppm/a")
    rc, out, _ = _due(capsys, "-w", wh, "--config", cfg, "--as-of", "2030-01-01")
    assert f"QA-2  K1  due {row['due_date']} OVERDUE (as of 2030-01-01)" in out
    rc, _, err = _due(capsys, "-w", wh, "--within", "soon")
    assert rc == 1 and err.startswith("accelcal: error: --within")


def test_as_of_sees_the_history_of_then(fleet, capsys):
    wh = str(fleet / "lab.duckdb")
    rc, out, _ = _due(capsys, "-w", wh, "--json", "--as-of", "2023-06-01",
                      "--config", str(fleet / "accelcal.toml"))
    rows = {(r["unit_serial"], r["coefficient"]): r for r in json.loads(out)}
    assert rows[("QA-2", "K1")]["n_campaigns"] == 3
    assert rows[("QA-2", "K1")]["last_calibrated"] == "2023-03-01"


def test_adjust_is_audited_and_starts_a_new_series(fleet, capsys):
    wh = str(fleet / "lab.duckdb")
    cfg = str(fleet / "accelcal.toml")
    assert main(["campaign", "adjust", "QA-4/2024", "-w", wh, "--why", "K1 trimmed"]) == 0
    assert main(["campaign", "adjust", "QA-4/2024", "-w", wh, "--why", "again"]) == 1
    assert main(["campaign", "adjust", "nope", "-w", wh, "--why", "x"]) == 1
    rc, out, _ = _due(capsys, "-w", wh, "--config", cfg, "--json", "--store")
    row = next(r for r in json.loads(out) if r["unit_serial"] == "QA-4" and r["coefficient"] == "K1")
    assert row["n_campaigns"] == 3 and row["steps"] == [] and "adjustment" in row["basis"]
    assert row["drift_per_year"] == pytest.approx(1e-5, rel=0.1)
    w = Warehouse(wh)
    trail = w.query("SELECT campaign, action, why, acted_by FROM campaign_adjustments")
    assert [(t["campaign"], t["action"], t["why"]) for t in trail] == [("QA-4/2024", "adjust", "K1 trimmed")]
    view = w.query("SELECT * FROM recalibration_forecast WHERE unit_serial = 'QA-4' "
                   "AND coefficient = 'K1'")
    assert view[0]["n_campaigns"] == 3 and str(view[0]["due_date"] or "") == (row["due_date"] or "")
    # before the mark was made, the as-of view sees no adjustment
    assert main(["campaign", "unadjust", "QA-4/2024", "-w", wh, "--why", "wrong unit"]) == 0
    assert len(w.query("SELECT * FROM adjusted_campaigns")) == 0


def test_a_warehouse_without_adjustments_is_left_unchanged_by_due(fleet, capsys):
    wh = str(fleet / "lab.duckdb")
    before = {r["table_name"] for r in Warehouse(wh).query(
        "SELECT table_name FROM information_schema.tables")}
    _due(capsys, "-w", wh, "--json")
    after = {r["table_name"] for r in Warehouse(wh).query(
        "SELECT table_name FROM information_schema.tables")}
    assert before == after and "forecast_history" not in after


def test_history_page_has_one_chart_per_coefficient(fleet, capsys, tmp_path):
    wh = str(fleet / "lab.duckdb")
    out = tmp_path / "html"
    assert main(["history", "QA-2", "--html", str(out), "-w", wh,
                 "--config", str(fleet / "accelcal.toml")]) == 0
    page = (out / "QA-2-history.html").read_text()
    mask = os.umask(0)
    os.umask(mask)
    assert (out / "QA-2-history.html").stat().st_mode & 0o777 == 0o666 & ~mask
    assert page.count("<img") == 2 and "control chart" in page and "due <b>20" in page
    assert "OVERDUE" not in page
    assert main(["history", "QA-2", "--html", str(out / "later"), "-w", wh, "--as-of", "2030-01-01",
                 "--config", str(fleet / "accelcal.toml")]) == 0
    assert "OVERDUE" in (out / "later" / "QA-2-history.html").read_text()
    assert main(["history", "NOPE", "--html", str(out), "-w", wh]) == 1
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium:
        png = tmp_path / "h.png"
        subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu",
                        f"--user-data-dir={tmp_path / 'chr'}", f"--screenshot={png}",
                        "--window-size=1000,1400", (out / "QA-2-history.html").as_uri()],
                       capture_output=True, timeout=120)
        assert png.stat().st_size > 10_000


def test_certificate_states_the_due_date_only_when_agreed(fleet):
    from accelcal.ops.due import certificate_due_statement
    wh = str(fleet / "lab.duckdb")
    cfg = fleet / "accelcal.toml"
    assert certificate_due_statement(wh, "QA-2", "QA-2/2026", cfg) is None
    cfg.write_text(TOML + "[certificate]\nstate_due_date = true\n")
    s = certificate_due_statement(wh, "QA-2", "QA-2/2026", cfg)
    assert s.startswith("Recommended recalibration by 202") and "K1" in s
    # the certificate of an earlier campaign uses the history up to it
    s23 = certificate_due_statement(wh, "QA-2", "QA-2/2023", cfg)
    assert s23 != s and "3 calibrations" in s23
    s0 = certificate_due_statement(wh, "QA-0", "QA-0/2026", cfg)
    assert s0.startswith("No recalibration date is stated")


def test_mixed_code_versions_are_named_in_the_basis(fleet):
    from accelcal.config import forecast_config
    from accelcal.ops.due import due_rows
    wh = str(fleet / "lab.duckdb")
    with Warehouse(wh).connect() as con:
        con.execute("UPDATE results SET code_version = '9.9+src.other' WHERE campaign = 'QA-2/2025'")
    rows = due_rows(wh, forecast_config(fleet / "accelcal.toml"))
    row = next(r for r in rows if r["unit_serial"] == "QA-2" and r["coefficient"] == "K1")
    assert "mixed code versions (9.9+src.other, test+views)" in row["basis"]
    assert row["due_date"] is not None       # still a date, with its qualification stated

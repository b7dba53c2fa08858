"""CLI: demo end to end (local engine), exit codes and one-line reasons, busy warehouse."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from accelcal import cli
from accelcal.warehouse import Warehouse


def test_help_lists_subcommands(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "run" in out and "demo" in out


def test_subcommand_registry_is_open():
    assert {"run", "demo"} <= set(cli.SUBCOMMANDS)

    @cli.subcommand("hello")
    def _reg(sub):
        p = sub.add_parser("hello")
        p.set_defaults(func=lambda args: 7)
    try:
        assert cli.main(["hello"]) == 7
    finally:
        del cli.SUBCOMMANDS["hello"]


def test_demo_runs_on_the_shipped_drops(tmp_path, capsys):
    drops = cli.demo_drops()
    assert {d.name for d in drops} == {"drop-demo", "drop-bad", "drop-2026-11-20", "drop-2026-11-21"}
    rc = cli.main(["demo", "--dir", str(tmp_path / "demo"), "--engine", "local", "-q"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "µg/g²" in out and "U (k=2)" in out and "SNJ-1-03/demo" in out
    assert "refused drop-bad/nan-output.csv" in out
    wh = Warehouse(tmp_path / "demo" / "lab.duckdb")
    st = {r["status"]: r["n"] for r in wh.query("SELECT status, count(*) AS n FROM runs GROUP BY 1")}
    assert st == {"accepted": 30, "refused": 3}
    # again, as JSON: nothing new
    rc = cli.main(["demo", "--dir", str(tmp_path / "demo"), "--engine", "local", "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and {c["status"] for c in summary["campaigns"]} == {"unchanged"}
    assert sum(d["new"] for d in summary["drops"]) == 0


def test_display_units():
    v, U, unit = cli.display_coefficient(
        {"name": "K2", "value": 3.94e-7, "std_uncertainty": 1.5e-9, "unit": "s2/m"})
    assert unit == "µg/g²" and float(v) == pytest.approx(3.94e-7 / (1e-6 / 9.80665), rel=1e-3)
    assert float(U) == pytest.approx(2 * 1.5e-9 / (1e-6 / 9.80665), rel=0.05)
    v, U, unit = cli.display_coefficient(
        {"name": "K1", "value": 0.1325, "std_uncertainty": 1e-8, "unit": "mA/(m/s2)"})
    assert unit == "mA/g" and U.endswith("ppm")
    v, U, unit = cli.display_coefficient(
        {"name": "K0", "value": 4e-4, "std_uncertainty": 1e-6, "unit": "m/s2"})
    assert unit == "µg"


def test_missing_drop_exits_1_with_one_line(tmp_path, capsys):
    rc = cli.main(["run", str(tmp_path / "nope"), "--warehouse", str(tmp_path / "w.duckdb"),
                   "--engine", "local", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1
    assert err[0].startswith("accelcal: error: drop") and "does not exist" in err[0]


def test_busy_warehouse_exits_1_naming_the_pid(tmp_path, capsys):
    db = tmp_path / "lab.duckdb"
    drop = tmp_path / "empty-drop"
    drop.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import time; from accelcal.warehouse import warehouse_lock\n"
         f"with warehouse_lock({str(db)!r}):\n"
         "    print('locked', flush=True); time.sleep(30)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        rc = cli.main(["run", str(drop), "--warehouse", str(db), "--lock-timeout", "0.3",
                       "--engine", "local", "-q"])
    finally:
        holder.kill()
        holder.wait()
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1
    assert f"is in use by pid {holder.pid}" in err[0]


def test_python_m_accelcal_usage_error():
    p = subprocess.run([sys.executable, "-m", "accelcal", "run"], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 2 and "DROP" in p.stderr


@pytest.mark.parametrize("argv, says", [
    (["diagnose", "{tmp}/nothing-here", "--baseline", "none"], "no readable run files"),
    (["diagnose", "{tmp}", "--baseline", "not_an_effect"], "no readable run files"),
])
def test_diagnose_errors_in_the_one_form(tmp_path, capsys, argv, says):
    """Every subcommand fails as 'accelcal: error: ...' with exit 1 (issue 28: diagnose
    printed 'diagnose:' and exited 2)."""
    rc = cli.main([a.replace("{tmp}", str(tmp_path)) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == cli.EXIT_FAIL
    assert err[-1].startswith("accelcal: error: diagnose: ") and says in err[-1]


def test_diagnose_unknown_baseline_effect_is_one_line(capsys, examples):
    rc = cli.main(["diagnose", str(examples / "drop-2026-11-20" / "DH1-20261120-0001.csv"),
                   "--baseline", "not_an_effect"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == cli.EXIT_FAIL and len(err) == 1
    assert err[0].startswith("accelcal: error: diagnose: unknown effect id 'not_an_effect'")

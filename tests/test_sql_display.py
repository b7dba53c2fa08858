"""`accelcal sql` prints what people read (issue 28): display units, GUM rounding, 80 columns;
--raw keeps the stored SI floats."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from accelcal import cli
from accelcal.ops.sql import display_rows

G = 9.80665


def test_a_coefficient_row_in_display_units_rounded_to_its_U():
    cols = ["name", "value", "std_uncertainty", "coverage_factor", "unit", "dof"]
    rows = [("K2", 3.94e-7, 1.5e-9, 2.0, "s2/m", 235.0),
            ("K0", 4.0e-4, 2.0e-7, 2.0, "m/s2", 12.345678)]
    (k2, k0) = display_rows(cols, rows)
    # by hand: 1 ug/g2 = 1e-6/g s2/m; U = 2u
    ug_g2 = 1e-6 / G
    assert k2[4] == "µg/g²"
    assert float(k2[2]) == pytest.approx(1.5e-9 / ug_g2, rel=0.05) and len(k2[2].replace("0.", "").lstrip("0")) <= 2
    U = 2 * 1.5e-9 / ug_g2                      # 0.0294 -> "0.029": the value to 3 decimals
    assert k2[1] == f"{3.94e-7 / ug_g2:.3f}" and U == pytest.approx(0.0294, rel=1e-2)
    ug = 1e-6 * G                               # 1 ug in m/s2; U = 0.0408 ug -> value to 0.001
    assert k0[4] == "µg" and k0[1] == f"{4.0e-4 / ug:.3f}"
    assert k0[5] == "12.35"                     # a number with no U: four significant digits


def test_without_a_unit_column_the_unit_goes_with_the_number():
    (row,) = display_rows(["name", "change", "en"], [("Kip", 5.4e-9, 0.8531234)])
    assert row[1].endswith(" µg/g²") and row[2] == "0.8531"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert cli.main(["demo", "--dir", str(out), "--engine", "local", "-q"]) == 0
    return out / "lab.duckdb"


@pytest.mark.parametrize("query", ["SELECT * FROM coefficients",
                                   "SELECT name, method, rig_id, value, expanded_uncertainty, unit "
                                   "FROM calibration"])
def test_fits_80_columns_and_raw_keeps_the_floats(demo, query):
    env = {**os.environ, "COLUMNS": "80"}
    p = subprocess.run([sys.executable, "-m", "accelcal", "sql", query, "-w", str(demo)],
                       capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    assert max(len(line) for line in p.stdout.splitlines()) <= 80
    assert "e-07" not in p.stdout and "µg/g²" in p.stdout
    raw = subprocess.run([sys.executable, "-m", "accelcal", "sql", query, "-w", str(demo), "--raw"],
                         capture_output=True, text=True, env=env, timeout=120)
    assert raw.returncode == 0 and "s2/m" in raw.stdout

"""Every number the terminal prints has its unit; an undetermined value says so.  Closed
forms from the catalogue's display units (accelcal/effects.py)."""
from __future__ import annotations

from accelcal.ops.design_cli import _u
from accelcal.ops.due import display_rate

G = 9.80665


def test_design_u_in_display_units_with_the_runs_output_unit():
    assert _u("K1", 4.9e-8 / G, "out/(m/s2)", "mA") == "4.9e-8 mA/g"      # SI per (m/s2) to per g
    assert _u("K2", 2e-9, "s2/m") == "0.020 µg/g²"                 # 2e-9 s2/m = 0.0196 µg/g²
    assert _u("K2", 2e23, "s2/m") == "not determined"
    assert _u("K2", None, "s2/m") == _u("K2", float("nan"), "s2/m") == "not determined"


def test_due_rates_carry_the_catalogues_display_unit():
    assert display_rate("K1", 2e-6, 1e-7, 0.1) == "20.0 ± 1.0 ppm/a"       # ppm of K1 in use
    assert display_rate("K0", 1e-6 * G, 1e-7 * G, 0.0) == "1.00 ± 0.10 µg/a"
    assert display_rate("Kp(Kpo)", 2e-6, 2e-7, 0.0) == "2.00 ± 0.20 µrad/a"
    assert display_rate("theta0(Ko)", 1e-5, None, 0.0).endswith(" °/a")

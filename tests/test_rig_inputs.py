"""Rig inputs with a lab-stated uncertainty enter every budget (issue 27): local gravity,
the thermal table's tilt, the temperature reading.

The sensitivities are checked against truths derived here, not printed by the code:

* dimensional analysis: where local gravity is the campaign's only acceleration reference
  (the centrifuge radius is fitted), a coefficient whose SI unit holds (m/s2)^p scales as
  g^p, so dC/dg = p C / g;
* paper 001's own closed forms for the tilted table: K1 = b / (g sin gamma), K0 = a / K1;
* the straight line through the set points: a reading error dT_k at set point k moves the
  slope by -slope (T_k - Tbar) / Sxx dT_k (equal weights), so the root-sum-square
  sensitivity of K1T = slope / K1 is |K1T| / sqrt(Sxx).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from accelcal.effects import split_combination
from accelcal.config import ConfigError, rig_uncertainties
from accelcal.estimators.campaign import process_campaign
from accelcal.ops.certificate import missing_rig_inputs
from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover

from conftest import EXAMPLES, require_shared

require_shared()

#: power p of m/s2 in each coefficient's SI unit (effects.md): K0 m/s2, K1 out/(m/s2),
#: the second-order terms s2/m = (m/s2)^-1, K3 s4/m2 = (m/s2)^-2
POWER = {"K0": 1, "K1": -1, "K2": -1, "Koq": -1, "Kip": -1, "Kio": -1, "Kpo": -1, "Kpp": -1,
         "Koo": -1, "K3": -2}


def _runs(drop):
    return [read_run(p) for p in discover(EXAMPLES / drop)]


def _g_sensitivity(res, name):
    return sum(b.sensitivity for b in res.budget
               if b.coefficient == name and b.method == "joint_ml" and b.quantity.startswith("local gravity"))


@pytest.mark.parametrize("drop", ["drop-2026-11-20", "drop-2026-11-19-sine"])
def test_gravity_sensitivity_follows_the_coefficients_dimension(drop):
    runs = _runs(drop)
    rigs = {r.meta["rig_id"] for r in runs}
    res = process_campaign(runs, {rig: {"g_local": 1e-5} for rig in rigs})
    g = runs[0].meta["g_local_m_s2"]
    checked = 0
    for c in res.coefficients:
        if c.method != "joint_ml" or c.name not in POWER or abs(c.value) < 10 * c.std_uncertainty:
            continue
        assert _g_sensitivity(res, c.name) * g / c.value == pytest.approx(POWER[c.name], abs=0.01), c.name
        checked += 1
    assert checked >= 8


def _thermal_truth(run):
    """K1, K0T, K1T sensitivities from paper 001's closed forms and the set points."""
    d = run.data
    T = d.groupby("temp_set_c")["temp_c"].mean().to_numpy()       # one reading per set point
    sxx = float(np.sum((T - T.mean()) ** 2))
    return run.meta["g_local_m_s2"], math.radians(run.meta["tilt_deg"]), sxx


def test_thermal_table_sensitivities_match_paper_001():
    runs = _runs("drop-2026-11-18-thermal")
    rig = runs[0].meta["rig_id"]
    g, gamma, sxx = _thermal_truth(runs[0])
    res = process_campaign(runs, {rig: {"g_local": 1e-5, "table_tilt": 0.002, "temperature": 0.05}})
    for method in ("joint_ml", "tilt_rotation_ls"):
        coef = {split_combination(c.name)[0]: c for c in res.coefficients if c.method == method}
        sens = {}
        for b in res.budget:
            if b.method == method and b.type == "B" and not b.quantity.startswith("K"):
                what = next(w for w in ("gravity", "tilt", "temperature") if w in b.quantity)
                sens[(split_combination(b.coefficient)[0], what)] = b.sensitivity
        K1, K0T, K1T = coef["K1"].value, coef["K0T"].value, coef["K1T"].value
        assert sens[("K1", "gravity")] == pytest.approx(-K1 / g, rel=1e-3), method
        assert sens[("K1", "tilt")] == pytest.approx(-K1 / math.tan(gamma), rel=1e-3), method
        assert sens[("K0T", "gravity")] == pytest.approx(K0T / g, rel=1e-3), method
        assert sens[("K0T", "tilt")] == pytest.approx(K0T / math.tan(gamma), rel=1e-3), method
        assert abs(sens.get(("K1T", "gravity"), 0.0)) < 1e-6 * abs(K1T) / g       # a ratio: no g
        assert abs(sens[("K1T", "temperature")]) == pytest.approx(abs(K1T) / math.sqrt(sxx), rel=0.02)
        # the coefficient's u is the budget's: its type A and the stated inputs
        for c in coef.values():
            lines = [b for b in res.budget if b.method == method and b.coefficient == c.name]
            assert c.std_uncertainty == pytest.approx(math.sqrt(sum(b.contribution ** 2 for b in lines)),
                                                      rel=1e-9), c.name
    assert all(v["validated"] for v in res.extras["mc_check"].values())


def test_an_input_without_a_stated_uncertainty_is_flagged_and_keeps_the_certificate_draft():
    runs = _runs("drop-2026-11-18-thermal")
    res = process_campaign(runs)
    flag = next(f for f in res.flags if f.startswith("budgets leave out"))
    for key in ("g_local_u_m_s2", "tilt_u_deg", "temperature_u_c"):
        assert f'[rigs."TT-1"] {key}' in flag
    left = missing_rig_inputs({"extras": res.extras})
    assert [w for w, _ in left] == ["u(g_local) of TT-1", "u(table_tilt) of TT-1", "u(temperature) of TT-1"]
    # a stated input is no longer missing; the others still are
    res = process_campaign(runs, {"TT-1": {"g_local": 1e-5}})
    assert [w for w, _ in missing_rig_inputs({"extras": res.extras})] == [
        "u(table_tilt) of TT-1", "u(temperature) of TT-1"]
    # a result stored before the rig inputs entered the budgets cannot say: DRAFT too
    old = {"extras": {"joint": {k: v for k, v in res.extras["joint"].items() if k != "rig_inputs"}}}
    assert len(missing_rig_inputs(old)) == 1


def test_without_stated_inputs_the_values_and_uncertainties_do_not_move():
    runs = _runs("drop-2026-11-18-thermal")
    a, b = process_campaign(runs), process_campaign(runs, {"OTHER-RIG": {"g_local": 1e-5}})
    assert [(c.name, c.value, c.std_uncertainty) for c in a.coefficients] == \
        [(c.name, c.value, c.std_uncertainty) for c in b.coefficients]


def test_config_states_rig_inputs_and_refuses_a_bad_one_in_one_line(tmp_path):
    p = tmp_path / "accelcal.toml"
    p.write_text('[rigs."TT-1"]\nmax_g = 2\ng_local_u_m_s2 = 1e-5\ntilt_u_deg = 0.002\n'
                 'temperature_u_c = 0.05\n[rigs."DH-1"]\ng_local_u_m_s2 = 2e-5\n')
    assert rig_uncertainties(p) == {"TT-1": {"g_local": 1e-5, "table_tilt": 0.002, "temperature": 0.05},
                                    "DH-1": {"g_local": 2e-5}}
    for bad in ("-1e-5", '"small"', "0"):
        p.write_text(f'[rigs."DH-1"]\ng_local_u_m_s2 = {bad}\n')
        with pytest.raises(ConfigError) as e:
            rig_uncertainties(p)
        msg = str(e.value)
        assert "\n" not in msg and '[rigs."DH-1"] g_local_u_m_s2 must be a positive number' in msg


def test_paper_methods_carry_the_stated_local_gravity_line(tmp_path, examples):
    """Every paper method's budget has the stated g line.  For the tumble (paper 003) the
    gravity field is the only acceleration reference, so a coefficient in (m/s²)^p scales as
    g^p: dK1/dg = -K1/g and dK0/dg = +K0/g, derived here, against the method's own
    derivative (it runs again with g moved)."""
    import duckdb

    from accelcal.flows.pipeline import run_pipeline
    run_pipeline([str(examples / "drop-2026-11-20")], tmp_path / "lab.duckdb", engine="local",
                 parameters={"rig_uncertainty": {"DH-1": {"g_local": 1e-5}, "LXJ-100": {"g_local": 1e-5}}})
    con = duckdb.connect(str(tmp_path / "lab.duckdb"), read_only=True)
    coef = {(m, n): (v, u) for m, n, v, u in con.execute(
        "SELECT method, name, value, std_uncertainty FROM coefficient_history").fetchall()}
    lines = {(m, c): (g, u, s) for m, c, g, u, s in con.execute(
        "SELECT method, coefficient, value, std_uncertainty, sensitivity FROM budget_history "
        "WHERE starts_with(quantity, 'local gravity g_local')").fetchall()}
    for (m, n) in coef:
        if m in ("tumble_lm", "centrifuge_eq9"):
            assert (m, n) in lines, (m, n)
    g, u, s = lines[("tumble_lm", "K1")]
    assert u == 1e-5 and s == pytest.approx(-coef[("tumble_lm", "K1")][0] / g, rel=1e-4)
    k0 = next(n for (m, n) in coef if m == "tumble_lm" and n.startswith("K0"))
    assert lines[("tumble_lm", k0)][2] == pytest.approx(coef[("tumble_lm", k0)][0] / g, rel=1e-3)
    # the K1 budget: its u_c now holds the g line, |dK1/dg| u_g = K1 u_g / g (1.02 ppm here)
    assert coef[("tumble_lm", "K1")][1] >= abs(s) * u

"""The estimator recipe of docs/design.md ("Add an estimator"), followed with a toy method:
one registry entry, and the method is in the campaign result, the Monte Carlo study and the
certificate, with no other edit.  And the registry holds the paper methods as the papers
order them."""
from __future__ import annotations

import math

from accelcal.estimators import registry
from accelcal.estimators.records import Records
from accelcal.results import CoefficientResult

TOY = "toy_two_point_bias"


def _toy_records(runs, steps):
    """The toy method: the bias as the mean output of each tumble run over its head
    positions (a full turn of equally spaced positions averages g cos out), in the run's
    output unit divided by the nominal K1 of 1 -- a method a lab could add in an afternoon."""
    vals = []
    for r in runs:
        y = r.data["output"].to_numpy(float)
        vals.append(float(y.mean()))
    m = sum(vals) / len(vals)
    u = (max(vals) - min(vals)) / 2 / math.sqrt(3) if len(vals) > 1 else abs(m)
    return [Records(coefficients=[CoefficientResult("K0", m, u, "m/s2", TOY, str(runs[0].meta["rig_id"]))])]


def _toy_truth(c, eff, test, g, notes):
    return {("K0", str(test["rig_id"])): (c["K0"], "instrument value (toy)")}


TOY_ESTIMATOR = registry.Estimator(
    method=TOY, tests=("tumble",), certificate="toy: mean output over the head positions",
    records=_toy_records, truth=_toy_truth, main=("K0",), crb=False, order=90)


def test_paper_methods_in_run_and_adoption_order():
    """Tumble first (its reference scales the centrifuge radius), then paper 000, 001, 002;
    a value is adopted from the joint fit, else paper 000, 002, 001, 003."""
    assert [e.method for e in registry.estimators()] == ["tumble_lm", "centrifuge_eq9", "tilt_rotation_ls",
                                                         "sine_ls"]
    assert registry.adoption_order() == ("joint_ml", "centrifuge_eq9", "sine_ls", "tilt_rotation_ls",
                                         "tilt_rotation_two_position", "tumble_lm")
    assert [e.method for e in registry.for_test("tilt_rotation")] == ["tilt_rotation_ls"]


def test_toy_estimator_reaches_result_study_and_certificate():
    from accelcal.validation.montecarlo import run_study
    from accelcal.ops.certificate import method_text
    from accelcal.simulate.scenario import load_scenario

    sc = load_scenario("demo")
    with registry.registered(TOY_ESTIMATOR):
        study = run_study(sc, n=2, seed=0, workers=1, crb=False)
        how = method_text("tumble")[1]
    toy = [c for c in study.coefficients if c.method == TOY]
    assert [c.name for c in toy] == ["K0"] and toy[0].n == 2
    assert toy[0].truth == sc.coefficients["K0"] and toy[0].main
    assert "toy: mean output over the head positions" in how and how.startswith("paper 003")
    # and gone again: the paper methods alone
    assert TOY not in registry.ESTIMATORS
    assert "toy" not in method_text("tumble")[1]


def test_toy_estimator_in_campaign_result():
    from accelcal.validation.montecarlo import _campaign
    from accelcal.simulate.scenario import load_scenario

    with registry.registered(TOY_ESTIMATOR):
        res = _campaign(load_scenario("demo"), 1)
    toy = [c for c in res.coefficients if c.method == TOY]
    assert len(toy) == 1 and not toy[0].adopted          # the joint fit's values are adopted
    assert any(c.method == "joint_ml" and c.name == "K0" and c.adopted for c in res.coefficients)

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


def _toy_figures(extras):
    """The toy method's residual figure, read from what it stored (its own key)."""
    from accelcal.results import ResidualFigure, ResidualPanel, ResidualSeries
    pts = (extras.get("toy") or {}).get("residuals") or []
    if not pts:
        return []
    return [ResidualFigure("series", "toy: each run's mean minus the toy K0, in u.", (
        ResidualPanel("toy residuals", "run", (ResidualSeries("", tuple(range(len(pts))), tuple(pts)),)),))]


def test_toy_estimator_figure_reaches_the_certificate():
    """A method states its residual figures from its own stored extras (issue 23: the typed
    science-to-report contract); the certificate's adequacy section draws them, in the
    registry's order, with the method's caption, and reads no method's keys itself."""
    import base64

    from accelcal.ops.report_sections import _sec_adequacy

    toy = registry.Estimator(method=TOY, tests=("tumble",), certificate="toy", records=_toy_records,
                             order=90, figures=_toy_figures)
    d = {"extras": {"toy": {"residuals": [0.5, -1.2, 0.3]}}, "tests": ["tumble"], "adequacy": [],
         "coefficients": [], "science_parameters": {}}
    assert "toy: each run" not in _sec_adequacy(d, True)
    with registry.registered(toy):
        (fig,) = registry.residual_figures(d["extras"])
        html = _sec_adequacy(d, True)
    assert fig.style == "series" and fig.panels[0].series[0].y == (0.5, -1.2, 0.3)
    assert "toy: each run&#x27;s mean minus the toy K0, in u." in html or "toy: each run's mean" in html
    png = html.split("data:image/png;base64,", 1)[1].split("'", 1)[0]
    assert base64.b64decode(png).startswith(b"\x89PNG")


def test_paper_methods_state_their_figures_from_their_own_extras():
    """Each paper method that stores residuals turns them into its figure: the eq 9 dwell
    residuals (a panel per pair, series by polarity and sweep), the thermal points (a K0
    and a K1 panel, a series per run) and the sine runs (a bar per run); the values are
    the stored ones, recomputed here from the stored numbers."""
    from accelcal.constants import G_STANDARD
    ex = {"pairs": {"C1": [{"pair": "IA-PA 0/180", "order": 2, "dwells": {
              "a": [0.0, 9.80665, -19.6133], "std_resid": [0.1, None, -0.4], "pol": [1, 1, -1],
              "sweep": ["rest", "up", "down"]}}]},
          "thermal": {"T1": {"temperature_model": {"K0": 1e-3, "K0T": 1e-5, "K1": 1.0, "K1T": 2e-6},
                             "points": [{"temp_c": 30.0, "K0": 1.1e-3 + 1e-5 * 10, "u_K0": 5e-5,
                                         "K1": 1.0 + 2e-5, "u_K1": 1e-5}]}},
          "sine": {"S1": {"residual_rms": {"r2": 3.0, "r1": 1.5}, "sigma": 1.5}}}
    figs = {f.style: f for f in registry.residual_figures(ex)}
    assert list(figs) == ["dwells", "points", "bars"]
    (p,) = figs["dwells"].panels
    assert p.title == "C1 IA-PA 0/180 (order 2)"
    assert {s.label: (s.x, s.y) for s in p.series} == {"+ rest": ((0.0,), (0.1,)),
                                                        "− down": ((-19.6133 / G_STANDARD,), (-0.4,))}
    assert {(s.polarity, s.sweep) for s in p.series} == {(1, "rest"), (-1, "down")}
    k0, k1 = figs["points"].panels
    assert k0.series[0].y[0] == (1.1e-3 + 1e-4 - (1e-3 + 1e-5 * 10)) / 5e-5
    assert k1.series[0].y[0] == (1.0 + 2e-5 - 1.0 * (1 + 2e-6 * 10)) / 1e-5
    (b,) = figs["bars"].panels
    assert b.ticks == ("S1 r1", "S1 r2") and b.series[0].y == (1.0, 2.0)


def test_toy_estimator_fit_check_reaches_the_certificate():
    """A method states its fit statistics from its own stored extras (issue 23): the
    certificate's adequacy table lists the toy's FitCheck with the verdict at the lab's
    adequacy alpha, and the paper methods' checks hold the stored numbers."""
    from accelcal.ops.report_sections import _sec_adequacy
    from accelcal.results import FitCheck

    def checks(extras):
        p = (extras.get("toy") or {}).get("p")
        return [FitCheck("tumble", "toy run", "toy spread test", "Q = 2.5", "3", p)] if p is not None else []

    toy = registry.Estimator(method=TOY, tests=("tumble",), certificate="toy", records=_toy_records,
                             order=90, checks=checks)
    d = {"extras": {"toy": {"p": 0.004}}, "tests": ["tumble"], "adequacy": [], "coefficients": [],
         "science_parameters": {"adequacy_alpha": 0.01}}
    assert "toy spread test" not in _sec_adequacy(d, False)
    with registry.registered(toy):
        html = _sec_adequacy(d, False)
        d["science_parameters"]["adequacy_alpha"] = 0.001
        html2 = _sec_adequacy(d, False)
    row = html.split("toy spread test", 1)[1].split("</tr>", 1)[0]
    assert "Q = 2.5" in row and "0.004" in row and "NOT adequate" in row
    assert "NOT adequate" not in html2.split("toy spread test", 1)[1].split("</tr>", 1)[0]
    ex = {"tumble": [{"run_id": "t1", "lack_of_fit": {"F": 1.234, "dof_lof": 3, "dof_pe": 40, "p": 0.31}},
                     {"run_id": "t2", "dof": 0}],
          "thermal": {"T1": {"temperature_model": {"chi2_K0": 12.0, "nu": 3, "birge_ratio_K0": 2.0},
                             "scale_factor_time_trend": {"slope_ppm_per_h": 0.5, "u_slope_ppm_per_h": 0.1,
                                                         "significant": True}}},
          "sine": {"S1": {"per_run_bias": {"F": 0.5, "df1": 2, "df2": 30, "p_value": 0.61}}}}
    got = [(c.test, c.fit, c.statistic, c.dof, c.p, c.verdict(0.01)[0]) for c in registry.fit_checks(ex)]
    from scipy import stats
    assert got == [
        ("tumble", "t1", "F = 1.23", "3 / 40", 0.31, "adequate"),
        ("tumble", "t2", "not testable", "0", None, "no replicated positions beyond the parameters"),
        ("thermal", "T1", "χ² = 12, Birge 2", "3", float(stats.chi2.sf(12.0, 3)), "NOT adequate"),
        ("thermal", "T1", "χ² = —, Birge —", "3", None, "—"),
        ("thermal", "T1", "0.50 ± 0.10 ppm/h", "—", None, "significant"),
        ("sine", "S1", "F = 0.5", "2 / 30", 0.61, "not needed (model adequate without)")]

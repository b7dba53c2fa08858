"""Priors for what a design cannot see: a tumble-only campaign with the lab's priors for
the terms its combinations take up reports K1 and K0 themselves.

Independent truth: the simulated unit's own coefficients (the scenario's), and the GUM
measurement model Q = C - sum f_k T_k written out here (JCGM 100 §5.1.2: sensitivities
-f_k, u_c^2 = u(C)^2 + sum (f_k u(T_k))^2).
"""
from __future__ import annotations

import copy
import math

import pytest

from accelcal.config import priors, run_parameters


def _tumble(seed: int, prior=None):
    from accelcal.estimators.campaign import process_campaign
    from accelcal.simulate import load_scenario, simulate_campaign
    from accelcal.validation.montecarlo import SimRunFile
    sc = copy.deepcopy(load_scenario("snj103-lxj100"))
    sc.tests = [t for t in sc.tests if t["kind"] == "tumble"]
    runs = [SimRunFile.from_simrun(r) for r in simulate_campaign(sc, seed)]
    model = str(runs[0].meta.get("unit_model", ""))
    res = process_campaign(runs, priors={model: prior} if prior else None)
    return sc, model, {c.name: c for c in res.coefficients if c.adopted}, res


def test_a_tumble_with_priors_for_the_odd_and_square_terms_reports_k1_and_k0():
    sc, model, bare, _ = _tumble(7)
    truth = sc.coefficients
    # priors at the unit's own values, 10 % standard uncertainty (the lab's last full calibration)
    prior = {k: {"value": truth[k], "u": 0.1 * abs(truth[k])} for k in ("Koq", "K3", "Koo")}
    _, _, got, res = _tumble(7, prior)
    comb, k1 = bare["K1(Koq,K3)"], got["K1"]
    assert not k1.factors and "K1(Koq,K3)" not in got
    # the measurement model, written out: value and combined u
    want = comb.value - sum(f * prior[t]["value"] for t, f in comb.factors.items())
    assert k1.value == pytest.approx(want, rel=1e-12)
    u_c = math.sqrt(comb.std_uncertainty ** 2 + sum((f * prior[t]["u"]) ** 2 for t, f in comb.factors.items()))
    assert k1.std_uncertainty == pytest.approx(u_c, rel=1e-12)
    # the quantity is the unit's K1 (the combination was not: its terms are many u away)
    assert abs(k1.value - truth["K1"]) < 3 * k1.std_uncertainty
    assert abs(comb.value - truth["K1"]) > 10 * comb.std_uncertainty
    k0 = got["K0"]
    assert abs(k0.value - truth["K0"]) < 3 * k0.std_uncertainty
    # the budget says what was assumed, with the sensitivity -f
    lines = [b for b in res.budget if b.coefficient == "K1" and "prior" in b.quantity]
    assert {b.quantity.split()[0] for b in lines} == {"Koq", "K3"}
    for b in lines:
        t = b.quantity.split()[0]
        assert b.sensitivity == pytest.approx(-comb.factors[t]) and b.type == "B"
        assert b.std_uncertainty == prior[t]["u"]
    assert "assumed" in k1.note and f'[prior."{model}"]' in k1.note
    assert res.parameters["priors"] == {k: prior[k] for k in sorted(prior)}


def test_a_combination_with_a_term_without_prior_stays_the_combination():
    sc, _, _, _ = _tumble(8)
    _, _, got, _ = _tumble(8, {"K3": {"value": sc.coefficients["K3"], "u": 1e-10}})
    assert "K1(Koq,K3)" in got and "K1" not in got


def test_the_config_file_states_priors_per_unit_model(tmp_path):
    cfg = tmp_path / "accelcal.toml"
    cfg.write_text('[prior."QA-2000"]\nK3 = { value = 1.5e-9, u = 5e-10 }\nKoq = { value = 2e-8, u = 1e-8 }\n')
    assert priors(cfg) == {"QA-2000": {"K3": {"value": 1.5e-9, "u": 5e-10}, "Koq": {"value": 2e-8, "u": 1e-8}}}
    assert run_parameters(cfg) == {"priors": priors(cfg)}
    cfg.write_text('[prior."QA-2000"]\nK3 = { value = 1.5e-9, u = 0 }\n')
    from accelcal.config import ConfigError
    with pytest.raises(ConfigError, match=r'\[prior."QA-2000"\] K3: u must be a positive number'):
        priors(cfg)

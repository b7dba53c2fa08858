"""The campaign model (accelcal.fitting.model) on data of an independent reference simulator
(../shared/diagnosis-dev, truth from its maker)."""
from __future__ import annotations

import json

import pytest

from accelcal.estimators.joint import fit_campaign_model, prepare
from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover

from conftest import SHARED

DEV = SHARED / "diagnosis-dev"


def _case(name):
    if not (DEV / "cases" / name).is_dir():
        pytest.skip(f"{DEV} not found")
    truth = json.loads((DEV / "truth.json").read_text())[name]
    cells, _ = prepare([read_run(p) for p in discover(DEV / "cases" / name)])
    return cells, truth


def test_instrument_effect_adds_its_coefficient_where_it_applies():
    """bias_temperature in a centrifuge campaign's model adds K0T (effects.md: it applies to
    every test), although no centrifuge test is designed to measure it."""
    cells, truth = _case("cent-k0t-d0")
    jf = fit_campaign_model(cells, truth["baseline"] + ["bias_temperature"])
    assert "K0T" in jf.model.params.index
    assert jf.fit.value("K0T") == pytest.approx(truth["param"], rel=0.1)
    assert jf.fit.lof.status == "adequate"


def test_sampled_sensor_lag_recovered():
    """The sine-centrifuge lag of the reference simulator is recovered by the joint fit (the
    sampled first-order lag, physics.instrument.first_order_lag; the start is profiled since
    its derivative vanishes at 0)."""
    cells, truth = _case("sine-lag-d0")
    jf = fit_campaign_model(cells, truth["baseline"] + ["sensor_lag"])
    assert jf.fit.value("sensor_lag") == pytest.approx(truth["param"], rel=0.01)
    assert jf.fit.lof.status == "adequate"


def test_a_fit_changes_neither_the_model_nor_the_runs_it_is_given():
    """The model is a value: the start, the selection and the fit leave the caller's model
    (its parameters) and runs (their noise models) as they were; the refitted noise and the
    holds are the result's."""
    from accelcal.fitting.model import CampaignModel
    from accelcal.fitting.procedure import fit_selected

    cells, truth = _case("cent-k0t-d0")
    noise = [(c.noise, c.var_mean.copy()) for c in cells]
    model = CampaignModel(cells, truth["baseline"])
    params = list(model.params)
    held = model.select(model.start())
    assert held and list(model.params) == params
    mf = fit_selected(model)
    assert list(model.params) == params and all(a is b for a, b in zip(model.runs, cells))
    assert all(c.noise is n and (c.var_mean == v).all() for c, (n, v) in zip(cells, noise))
    assert all(m.source in ("residuals", "pooled") for m in mf.noise) and mf.model is not model
    assert {p.name for p in mf.model.params if not p.vary} == set(mf.held)

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


@pytest.mark.parametrize("drop", ["drop-2026-11-20", "drop-2026-11-18-thermal"])
def test_a_big_runs_model_taken_a_slice_at_a_time_fits_as_whole(drop, monkeypatch):
    """A run of more readings than fitting.data.ROW_SLICE is evaluated a slice of readings
    at a time (issue 28); the forward model is reading by reading, so the outputs are the
    same to the bit, and the cell means, Jacobian and fit differ only by the order of the
    sums (here every sample run is cut into slices of 97 readings)."""
    import numpy as np

    from accelcal.fitting import data as fdata
    from conftest import EXAMPLES

    if not (EXAMPLES / drop).is_dir():
        pytest.skip(f"{EXAMPLES / drop} not found")
    runs = [read_run(p) for p in discover(EXAMPLES / drop)]
    whole = fdata.ROW_SLICE

    def at_point(m, p):
        for k in ("_predictions", "_jacobians", "_cell_predictions"):
            m.__dict__.pop(k, None)
        return ([np.array(m.predict_rows(p, j)) for j in range(len(m.runs))], m.jacobian(p), m.predict(p))

    cells, _ = prepare(runs)
    a = fit_campaign_model(cells, [])
    m, p = a.model, a.fit.values
    rows_a, J_a, y_a = at_point(m, p)
    monkeypatch.setattr(fdata, "ROW_SLICE", 97)
    assert any(len(r.row_slices()) > 1 for r in m.runs)
    rows_b, J_b, y_b = at_point(m, p)
    assert all(np.array_equal(u, v) for u, v in zip(rows_a, rows_b))
    np.testing.assert_allclose(y_b, y_a, rtol=1e-13, atol=0)
    np.testing.assert_allclose(J_b, J_a, rtol=1e-7, atol=1e-9 * np.abs(J_a).max())
    cells, _ = prepare(runs)
    b = fit_campaign_model(cells, [])
    assert list(b.fit.names) == list(a.fit.names) if hasattr(a.fit, "names") else True
    np.testing.assert_allclose(b.fit.values, a.fit.values, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.sqrt(np.diag(b.fit.cov)), np.sqrt(np.diag(a.fit.cov)), rtol=1e-6)
    assert whole > 97


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

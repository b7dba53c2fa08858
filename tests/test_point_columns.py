"""Parameter points as columns (physics.rigs.POINT_COLUMNS): the forward model evaluated at
m points at once gives, bit for bit, what it gives at each point alone; the campaign
model's finite differences taken that way equal the ones taken point by point.

The reference in every test is the scalar path itself, called once per point: the
batched path must change no floating-point operation (results stay identical table by
table), not merely agree to a tolerance."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from accelcal.estimators.joint import prepare
from accelcal.fitting.model import CampaignModel
from accelcal.physics.rigs import POINT_COLUMNS, rig_output
from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover

from conftest import EXAMPLES, needs_shared

pytestmark = needs_shared

#: the sample drops with centrifuge (and tumble), sine-centrifuge runs
DROPS = ("drop-2026-11-20", "drop-2026-11-19-sine")


def _runs(drop):
    return [read_run(p) for p in discover(EXAMPLES / drop)]


@pytest.mark.parametrize("drop", DROPS)
def test_m_points_at_once_are_each_point_alone(drop):
    """rig_output with (m, 1) columns of the point parameters: row k equals rig_output at
    the k-th values, for every run of the drop, with temperature, bias drift and a sensor
    lag acting (the lag filters each row on its own)."""
    rng = np.random.default_rng(7)
    coeffs = {"K0": 2e-4, "K1": 0.13, "K2": 1e-5, "Kip": 3e-6, "K0T": 1e-6, "K1T": 2e-5}
    for run in _runs(drop):
        test = str(run.meta["test"])
        keys = sorted(POINT_COLUMNS.get(test, ()))
        if not keys:
            continue
        cols = {c: run.data[c].to_numpy() for c in run.data.columns}
        size = {"radius": 1e-3, "mount_angle_error": 1e-3, "mass_centre_offset": 1e-3,
                "initial_misalignment": 1e-3}
        # a lag of three sample periods: it changes every reading
        base = {"bias_drift": 1e-9, "sensor_lag": 3 * float(np.median(np.diff(cols["time_s"])))}
        points = [{k: (float(run.meta["arm_radius_m"]) if k == "radius" else 0.0)
                   + size[k] * rng.normal() for k in keys} for _ in range(5)]
        alone = []
        for pt in points:
            eff = {**base, **{k: v for k, v in pt.items() if k != "radius"}}
            kw = {"radius_m": pt["radius"]} if "radius" in pt else {}
            alone.append(rig_output(test, run.meta, cols, coeffs, eff, **kw))
        eff = {**base, **{k: np.array([pt[k] for pt in points])[:, None] for k in keys if k != "radius"}}
        kw = {"radius_m": np.array([pt["radius"] for pt in points])[:, None]} if "radius" in keys else {}
        together = rig_output(test, run.meta, cols, coeffs, eff, **kw)
        assert together.shape == (len(points), len(cols["output"]))
        assert np.array_equal(together, np.vstack(alone)), run.meta["run_id"]


@pytest.mark.parametrize("drop", DROPS)
def test_jacobian_differences_taken_together_equal_point_by_point(drop):
    """CampaignModel.jacobian_run: every column of a point parameter equals the central
    difference of the cell means of ``_rows`` at p + h and p - h, worked out here one
    point at a time (h = 1e-3 of the parameter's scale)."""
    cells, _ = prepare(_runs(drop))
    model = CampaignModel(cells, ["mount_angle_error", "mass_centre_offset", "initial_misalignment",
                                  "sensor_lag", "bias_temperature"])
    rng = np.random.default_rng(3)
    p = model.start() + np.array([q.scale for q in model.params]) * rng.normal(0, 0.1, len(model.params))
    p = np.maximum(p, model.lower_bounds())
    checked = 0
    for j, run in enumerate(model.runs):
        J = model.jacobian_run(p, j)
        for i, role in enumerate(model.roles):
            if not model._point_column(i, j) or i not in model._acting[j]:
                continue
            h = 1e-3 * model.params[i].scale
            pp, pm = p.copy(), p.copy()
            pp[i] += h
            pm[i] -= h
            ref = (run.cell_mean(model._rows(pp, j)) - run.cell_mean(model._rows(pm, j))) / (2 * h)
            assert np.array_equal(J[:, i], ref), (run.meta["run_id"], role.key)
            checked += 1
    assert checked >= 2


def test_cell_means_of_a_block_are_each_columns_cell_mean():
    """RunCells.cell_means: column q equals cell_mean of column q bit for bit, with some
    readings left out of every cell (cid -1)."""
    cells, _ = prepare(_runs("drop-2026-11-20"))
    rng = np.random.default_rng(11)
    for run in cells[:3]:
        X = rng.normal(size=(run.cid.size, 4)) * 10.0 ** rng.integers(-8, 8, size=4)
        block = run.cell_means(X)
        assert np.array_equal(block, np.column_stack([run.cell_mean(X[:, q]) for q in range(4)]))
        dropped = run.cid.copy()
        dropped[::7] = -1
        cut = replace(run, cid=dropped)
        assert np.array_equal(cut.cell_means(X), np.column_stack([cut.cell_mean(X[:, q]) for q in range(4)]))

"""Smoke tests of the Monte Carlo study (accelcal.validation.montecarlo, issue 3): the machinery, the
truth mapping, and the Cramér–Rao bound on a case checkable in closed form."""
from __future__ import annotations

import argparse
import copy
import json
import math
import tomllib

import numpy as np
import pytest

from accelcal.validation import montecarlo as mc
from accelcal.simulate import SCENARIO_DIR, load_scenario, simulate_campaign


def _thermal_linear() -> dict:
    """hust-m07-thermal reduced: one sweep over three set-points, 8 positions x 5 readings,
    no temperature noise (the recorded temp_c is constant within a point), white noise only.
    The estimator (per-point LS on {1, sin, cos}, then WLS lines across points) is then
    the efficient linear LS of the model, so var/CRB should be 1."""
    with open(SCENARIO_DIR / "hust-m07-thermal.toml", "rb") as fh:
        raw = tomllib.load(fh)
    raw = copy.deepcopy(raw)
    raw["noise"] = {"white_m_s2": 3.0e-8}
    t = raw["test"][0]
    t.update(sweeps=1, temp_set_c=[20, 30, 40], positions=8, readings=5)
    return raw


@pytest.fixture(scope="module")
def thermal_study():
    return mc.run_study(_thermal_linear(), n=100, seed=7, workers=1)


def test_crb_closed_form():
    """CRB(K0T) = sigma / sqrt(sum (T - mean T)^2) for white noise sigma (input units): the
    K0T column of the Jacobian is K1 (T - 20) and is orthogonal to the others to < 1e-2."""
    sc = load_scenario(_thermal_linear())
    crb = mc.cramer_rao(sc, seed=7)
    run = simulate_campaign(sc, 7)[0]
    T = run.data["temp_c"].to_numpy(float)
    closed = 3.0e-8 / math.sqrt(np.sum((T - T.mean()) ** 2))
    got = math.sqrt(crb[("K0T", "tilt_rotation_ls", "TT-1")])
    assert got == pytest.approx(closed, rel=0.02)
    assert crb[("K1T", "tilt_rotation_ls", "TT-1")] > 0


def test_study_linear_case(thermal_study):
    r = thermal_study
    assert r.n == 100 and not r.failures
    names = {(c.name, c.method) for c in r.coefficients}
    assert {("K0", "tilt_rotation_ls"), ("K1", "tilt_rotation_ls"), ("K0T", "tilt_rotation_ls"),
            ("K1T", "tilt_rotation_ls")} <= names
    for c in r.coefficients:
        assert c.truth is not None and 0.0 <= c.coverage <= 1.0
        assert c.n == 100
    k0t = r.get("K0T", "tilt_rotation_ls")
    # truth includes the fixture thermal tilt: K0T + g c cos(gamma)
    g, gam = 9.7936, math.radians(0.45)
    assert k0t.truth == pytest.approx(2.0e-6 + g * 2.00133e-7 * math.cos(gam), rel=1e-9)
    assert abs(k0t.bias_z) < 4
    # efficient linear estimator: var/CRB ~ 1 (n = 100: sampling sd of the ratio ~0.14)
    for name in ("K0T", "K1T"):
        for method in ("tilt_rotation_ls", "joint_ml"):
            c = r.get(name, method)
            assert c.main and c.var_over_crb is not None
            assert 0.7 < c.var_over_crb < 1.5, (name, method, c.var_over_crb)
            assert 0.85 <= c.coverage <= 1.0
            lo, hi = c.var_over_crb_interval
            assert lo < c.var_over_crb < hi


def test_markdown_and_json(thermal_study):
    md = thermal_study.to_markdown()
    assert "| **K0T** | joint_ml | 100 |" in md and "| K0T | tilt_rotation_ls | 100 |" in md
    assert "var/CRB" in md and "n = 100" in md
    d = json.loads(json.dumps(thermal_study.to_dict(), default=str))
    assert d["coefficients"][0]["coverage"] is not None


def test_truth_mapping_centrifuge_and_tumble():
    from accelcal.estimators.records import TumbleCoefficient
    corrected = TumbleCoefficient("K2", 3.9e-7, 1e-9, "s2/m", "tumble_lm", "DH-1", less=())
    t = mc.truth_table("snj103-lxj100", {("K2", "tumble_lm", "DH-1"): corrected})
    g = 9.80122
    assert t[("K2", "centrifuge_eq9", "LXJ-100")][0] == 3.94e-7
    assert t[("K0", "tumble_lm", "DH-1")][0] == pytest.approx(4.0e-4 + 3.0e-8 * g * g)
    assert t[("K2", "tumble_lm", "DH-1")][0] == 3.94e-7
    assert t[("theta0", "tumble_lm", "DH-1")][0] == pytest.approx(1.5e-5)   # -Ko, Ko = -1.5e-5
    t2 = mc.truth_table("snj103-lxj100")
    assert t2[("K2", "tumble_lm", "DH-1")][0] == pytest.approx(3.94e-7 - 3.0e-8)


def test_smoke_demo_and_cli(tmp_path):
    """The demo campaign (tumble + 10 centrifuge mounts), n = 3, through the CLI."""
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers()
    from accelcal.ops.validate_cli import register_cli
    register_cli(sub)
    out = tmp_path / "mc.json"
    args = ap.parse_args(["montecarlo", "demo", "--n", "3", "--seed", "5", "--json", "--out", str(out)])
    assert args.func(args) == 0
    d = json.loads(out.read_text())
    assert d["n"] == 3 and not d["failures"]
    got = {(c["name"], c["method"]): c for c in d["coefficients"]}
    for key in [("K2", "centrifuge_eq9"), ("Kip", "centrifuge_eq9"), ("Kpp", "centrifuge_eq9"),
                ("K2", "tumble_lm")]:
        c = got[key]
        assert c["truth"] is not None and 0.0 <= c["coverage"] <= 1.0
    for k in ("K2", "Kip", "Kpp"):
        assert got[(k, "centrifuge_eq9")]["crb_sd"] > 0

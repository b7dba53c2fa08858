"""Identifiability at the fitted geometry: an instrument coefficient seen only through a
nuisance (Kip through a mass-centre offset on 90/270 deg mounts) and a candidate nearly
aliased with a coefficient of the bare model (Kip and Kpp on 0/180/45/225).

Truth: designs built by hand in the test from paper 000 eq 2 (a_I = omega^2 (R cos phi + r),
a_P = omega^2 R sin phi for a mass centre r along IA, effects.md ``mass_centre_offset``), the
correlation of two least-squares estimates from the test's own inverse of J^T J, and
simulated campaigns whose coefficients the test sets.
"""
from __future__ import annotations

import numpy as np
import pytest

from accelcal.fitting.identify import (PRIORITY, Column, added_correlations, holds, near_aliases,
                                       seen_through_nuisances)

R_ARM = 0.71                                 # [m]
G_LEVELS = np.array([1, 2, 3, 5, 7, 10, 14, 18, 21, 25]) * 9.80665   # centripetal input [m/s^2]
SIGMA = 2e-6                                 # noise of a cell mean [m/s^2]


def inputs(phis_deg, r):
    """a_I, a_P and the mount index of every cell, for a mass centre r [m] along IA."""
    aI, aP, mount = [], [], []
    for k, phi in enumerate(phis_deg):
        w2 = G_LEVELS / R_ARM
        c, s = round(np.cos(np.radians(phi)), 15), round(np.sin(np.radians(phi)), 15)   # cos 90 deg is 0
        aI.append(w2 * (R_ARM * c + r))
        aP.append(w2 * R_ARM * s)
        mount.append(np.full(G_LEVELS.size, k))
    return np.concatenate(aI), np.concatenate(aP), np.concatenate(mount)


def design(phis_deg, r):
    """Whitened columns K1, K2, Kp, Kip, Kpp and a bias per mount (eq 2, K1 = 1)."""
    aI, aP, mount = inputs(phis_deg, r)
    cols = {"K1": aI, "K2": aI ** 2, "Kp": aP, "Kip": aI * aP, "Kpp": aP ** 2}
    for k in range(len(phis_deg)):
        cols[f"K0[{k}]"] = (mount == k).astype(float)
    J = np.column_stack(list(cols.values())) / SIGMA
    columns = [Column(n, "bias" if n.startswith("K0[") else "coef", "K0" if n.startswith("K0[") else n,
                      "", PRIORITY.index("bias" if n.startswith("K0[") else n)) for n in cols]
    return J, columns


def test_kip_determined_at_the_fitted_offset_not_at_nominal():
    J0, columns = design((0, 90, 180, 270), 0.0)
    J, _ = design((0, 90, 180, 270), 0.003)
    kip = [c.name for c in columns].index("Kip")
    # nominal: a_I a_P = 0 in every mount (a_P = 0 at 0/180, a_I = 0 at 90/270)
    assert not np.any(J0[:, kip])
    assert "Kip" in holds(J0, columns)
    # a 3 mm offset: a_I = omega^2 r on 90/270, opposite a_P: Kip a column of its own
    assert "Kip" not in holds(J, columns)
    assert seen_through_nuisances(J, J0, columns, [kip]) == [kip]
    # a coefficient determined at nominal too is not "seen through a nuisance"
    kpp = [c.name for c in columns].index("Kpp")
    assert seen_through_nuisances(J, J0, columns, [kpp]) == []


def correlation_by_hand(J, a, b):
    C = np.linalg.inv(J.T @ J)
    return C[a, b] / np.sqrt(C[a, a] * C[b, b])


@pytest.mark.parametrize("r", [0.0005, 0.003, 0.005])
def test_kip_kpp_near_alias_on_45_225(r):
    J, columns = design((0, 180, 45, 225), r)
    names = [c.name for c in columns]
    kip, kpp = names.index("Kip"), names.index("Kpp")
    # at 45/225 a_I a_P = a_P^2 (1 + r / (R cos phi)): one column but for the offset's share
    aI, aP, _ = inputs((0, 180, 45, 225), r)
    on45 = aP != 0
    cos_phi = np.sign(aP[on45]) / np.sqrt(2)
    np.testing.assert_allclose((aI * aP)[on45] / aP[on45] ** 2, 1 + r / (R_ARM * cos_phi), rtol=1e-12)
    free = [k for k in range(len(names)) if k != kip]
    R, u = added_correlations(J[:, free], J[:, kip])
    order = free + [kip]
    r_hand = correlation_by_hand(J[:, order], order.index(kpp), len(order) - 1)
    assert abs(r_hand) > 0.999
    assert R[order.index(kpp), -1] == pytest.approx(r_hand, abs=1e-6 * (1 - abs(r_hand)) + 1e-12)
    pairs = [a for a in near_aliases([names[k] for k in free] + ["Kip"], R, u) if a.b == "Kip"]
    assert [a.a for a in pairs] == ["Kpp"]


def test_kip_kpp_separate_on_45_135():
    J, columns = design((0, 180, 45, 135), 0.003)
    names = [c.name for c in columns]
    kip, kpp = names.index("Kip"), names.index("Kpp")
    # at 135 a_I a_P = -a_P^2: the two columns differ in sign there
    assert abs(correlation_by_hand(J, kip, kpp)) < 0.9
    free = [k for k in range(len(names)) if k != kip]
    R, u = added_correlations(J[:, free], J[:, kip])
    assert not [a for a in near_aliases([names[k] for k in free] + ["Kip"], R, u) if a.b == "Kip"]


# ----------------------------------------------------------------------------- end to end
def campaign(mounts, kip, seed, offset=-0.004):
    from accelcal.validation.diagnosis_benchmark import EVERYDAY_UNIT, runs_of, scenario
    sc = scenario("centrifuge", {"mass_centre_offset": offset})
    sc["unit"]["coefficients"] = dict(EVERYDAY_UNIT, Kip=kip)
    sc["test"][0]["mounts"] = [{"plane": "IA-PA", "angle_deg": a, "vertical": "+OA"} for a in mounts]
    return runs_of(sc, seed)


def diagnose_dev_baseline(runs):
    from accelcal.diagnosis.core import diagnose
    return diagnose(runs, ["earth_rate", "mass_centre_offset"])


def test_unit_kip_on_90_270_is_the_bare_model_coefficient():
    res = diagnose_dev_baseline(campaign((0, 180, 90, 270), 7.1e-7, 11))
    assert res["verdict"] is None and res["explained"] is True
    (d,) = res["determined"]
    assert d["effect"] == "cross_coupling" and d["coefficient"] == "Kip"
    assert abs(d["value"] - 7.1e-7) < 4 * d["std_uncertainty"]
    assert d["note"].startswith("Kip determined after all: ")
    row = next(r for r in res["ranking"] if r["effect"] == "cross_coupling")
    assert not row["selected"] and "Kip" in res["baseline"]["bare_model"].split("; held")[0]


def test_withheld_kip_on_45_225_is_aliased_with_kpp():
    res = diagnose_dev_baseline(campaign((0, 180, 45, 225), 5e-7, 12))
    assert res["verdict"] is None
    row = next(r for r in res["ranking"] if r["effect"] == "cross_coupling")
    assert row["observable"] is False and "Kpp" in row["aliases"]
    assert abs(row["near_alias"]["Kpp"]) > 0.999
    assert "aliased with Kpp (nearly, r = " in row["note"]
    # were the whole of the bare model's Kpp the effect: the unit's Kip + Kpp
    assert row["alias_estimates"]["Kpp"] == pytest.approx(5e-7 + 4.7e-8, rel=0.05)


def test_withheld_kip_on_45_135_is_named():
    res = diagnose_dev_baseline(campaign((0, 180, 45, 135), 5e-7, 13))
    assert res["verdict"] == "cross_coupling"
    top = next(r for r in res["ranking"] if r["effect"] == "cross_coupling")
    assert top["estimate"] == pytest.approx(5e-7, rel=0.05)

"""Issue 30: on a partial design every row is what the runs determine, or says it is aliased.

Independent truth: the sample drops of ../shared/examples (a reference simulator we did not
write, with the instrument values the issues quote), closed forms of the papers' equations
(paper 000 eq 2/3, IEEE 1293's tumble combinations) and plain linear algebra.
"""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from accelcal.effects import coefficient_spec, combination_name, split_combination
from accelcal.fitting.core import lstsq_svd

from conftest import EXAMPLES  # noqa: E402  (ACCELCAL_SHARED, else ../shared)
#: SNJ-1-03 as the reference simulator made it (issues 1-30; sample drops 11-20, 11-21)
UNIT = {"K0": 4.0e-4, "K1": 0.1325631, "Kp": 2.0e-5, "Ko": -1.5e-5, "K2": 3.94e-7, "Kpp": 4.7e-8,
        "Kip": 7.1e-7, "Kio": 2.0e-7, "Koo": 3.0e-8, "Koq": 3.0e-8, "K3": 2.0e-10, "Kpo": 0.0, "theta0": 0.0}
SINE = {**UNIT, "K3": 1.5e-9, "Koq": 2.0e-8}
needs_samples = pytest.mark.skipif(not EXAMPLES.is_dir(), reason="../shared/examples not present")


def truth_of(name: str, truth: dict) -> float | None:
    base, terms = split_combination(name)
    if base not in truth or any(k not in truth for k in terms):
        return None
    return truth[base] + sum(f * truth[k] for k, f in terms.items())


def _runs(drop: str):
    from accelcal.schemas.dropformat import read_run
    from accelcal.schemas.dropscan import discover
    return [read_run(p) for p in discover(EXAMPLES / drop)]


def _centrifuge_subset(runs, angles, tumble):
    return [r for r in runs if (r.meta["test"] == "tumble" and tumble) or (
        r.meta["test"] == "centrifuge" and r.meta.get("mount_plane") == "IA-PA"
        and float(r.meta["mount_angle_deg"]) in angles)]


def _check(res, truth):
    """Every coefficient row within 4 u of the truth of what it names; joint fit adequate."""
    assert not any("model inadequate" in f for f in res.flags), res.flags
    checked = 0
    for c in res.coefficients:
        t = truth_of(c.name, truth)
        if t is None or not c.std_uncertainty > 0:
            continue
        z = (c.value - t) / c.std_uncertainty
        assert abs(z) < 4, f"{c.method} {c.name}: {c.value:.6g} vs {t:.6g}, {z:+.1f} u ({c.note})"
        checked += 1
    return checked


# ------------------------------------------------------------------- names of combinations

def test_combination_names_round_trip_and_display_as_their_coefficient():
    for name, terms in [("K0", {"Koo": 96.064}), ("K2[PA]", {"Koo": -1.0}), ("Kip", {"Kpp": 1.0}),
                        ("K3", {"Ko": 0.002582, "Kio": -1.2e-05})]:
        text = combination_name(name, terms)
        base, back = split_combination(text)
        assert base == name
        assert back.keys() == terms.keys()
        for k in terms:
            assert back[k] == pytest.approx(terms[k], rel=5e-3)
        assert coefficient_spec(text) is coefficient_spec(name)
    assert combination_name("K2", {"Koo": -1.0}) == "K2-Koo"
    assert combination_name("K0", {"Koo": 96.064}) == "K0+96.1*Koo"


# ------------------------------------------------------------------- linear algebra

def test_fewer_rows_than_columns_leave_the_tied_columns_not_estimable():
    # K2 from the IA pair; the 45 deg pair sees (K2 + Kpp + Kip) / 2: Kpp and Kip only as a sum
    A = np.array([[1.0, 0.0, 0.0], [0.5, 0.5, 0.5]])
    sol = lstsq_svd(A, np.array([1.0, 1.0]))
    assert list(sol.estimable) == [True, False, False]
    n = sol.null_space[:, 0] / sol.column_norm
    assert abs(n[0]) < 1e-12 and n[1] == pytest.approx(-n[2])


def test_eq3_without_the_90_degree_pair_gives_kip_plus_kpp():
    """Paper 000 eq 2 at 0 and 45 deg: c2(0) = K2, c2(45) = (K2 + Kpp + Kip) / 2, so the pairs
    determine Kip + Kpp = 2 c2(45) - c2(0) and neither alone."""
    from types import SimpleNamespace

    from accelcal.estimators.crosscoupling import combine_second_order
    K2, Kpp, Kip = 3.94e-7, 4.7e-8, 7.1e-7
    pairs = [SimpleNamespace(plane="IA-PA", phi0_deg=phi, c2=c2, u_c2=1e-9)
             for phi, c2 in ((0.0, K2), (45.0, (K2 + Kpp + Kip) / 2))]
    comb = combine_second_order(pairs)
    assert "Kip" not in comb.values and "Kpp" not in comb.values
    assert comb.values["Kip+Kpp"] == pytest.approx(Kip + Kpp, rel=1e-9)
    assert comb.std["Kip+Kpp"] == pytest.approx(math.hypot(2e-9, 1e-9), rel=1e-6)
    assert comb.values["K2"] == pytest.approx(K2, rel=1e-12)


# ------------------------------------------------------------------- the sample drops

@needs_samples
@pytest.mark.parametrize("drop", ["drop-2026-11-20", "drop-2026-11-21"])
@pytest.mark.parametrize("angles, tumble", [({0, 180}, True), ({0, 180, 45, 225}, True),
                                            ({0, 180}, False), ({0, 180, 45, 225}, False)],
                         ids=["T+pair", "T+pair+45", "pair", "pair+45"])
def test_partial_centrifuge_designs_report_what_they_determine(drop, angles, tumble):
    from accelcal.estimators.campaign import process_campaign
    res = process_campaign(_centrifuge_subset(_runs(drop), angles, tumble))
    assert _check(res, UNIT) >= 5
    names = {(c.method, c.name) for c in res.coefficients}
    if 90 not in angles and 45 in angles:
        # eq 9/eq 2 cannot split Kip and Kpp without a PA-radial mount (paper 000 eq 3)
        assert ("centrifuge_eq9", "Kip+Kpp") in names
        assert ("centrifuge_eq9", "Kip") not in names
        # the joint fit: Kip and Kpp with honest (large) u, and the sum they determine
        (kk,) = [c for c in res.coefficients if c.method == "joint_ml" and c.name.startswith("Kip+")]
        kip = next(c for c in res.coefficients if c.method == "joint_ml" and c.name == "Kip")
        assert kk.std_uncertainty < kip.std_uncertainty / 50 and "nearly aliased" in kip.note
        # and the run that separates them turns PA through a known input: a PA-radial mount
        # (paper 000 eq 3), a mount where a_I a_P changes sign against 45/225 deg while a_P^2
        # does not (at phi: Kip cos(phi) sin(phi) + Kpp sin(phi)^2, so 135/315 deg give
        # Kpp/2 - Kip/2), or a tumble about OA, which turns IA through PA (IEEE 1293)
        from accelcal.diagnosis.core import prepare_cells
        from accelcal.testdesign import separating_run_flag
        from accelcal.estimators.joint import ALIASED_PAIR_FLAG
        assert ALIASED_PAIR_FLAG.format(a="Kip", b="Kpp") in res.flags
        sep = separating_run_flag(prepare_cells(_centrifuge_subset(_runs(drop), angles, tumble))[0], ("Kip", "Kpp"))
        assert sep.startswith("Kip, Kpp: one more run would separate them")
        assert re.search(r"centrifuge \S+ IA-PA (90|135|270|315)°|tumble \S+ head OA", sep), sep
    if tumble:
        # IEEE 1293: one tumble about PA measures K0 + Koo g^2, K2 - Koo, theta0 - Ko
        g = float(next(r for r in _runs(drop) if r.meta["test"] == "tumble").meta["g_local_m_s2"])
        k0 = next(c for c in res.coefficients if c.method == "tumble_lm" and c.name.startswith("K0"))
        base, terms = split_combination(k0.name)
        assert base == "K0" and set(terms) == {"Koo"}
        assert terms["Koo"] == pytest.approx(g * g, rel=1e-3)
        assert ("tumble_lm", "theta0-Ko") in names and ("joint_ml", "theta0-Ko") in names
    else:
        # no gravity reference: K1 is K1 at the nominal radius, said so
        assert any("R[" in c.note and c.name.startswith("K1") for c in res.coefficients
                   if c.method == "joint_ml")


@needs_samples
@pytest.mark.parametrize("drop", ["drop-2026-11-20", "drop-2026-11-21"])
def test_a_tumble_alone_names_its_k1_with_the_odd_terms_it_takes_up(drop):
    """The fundamental of a tumble's IA input takes Koq a|a| and K3 a^3: cos|cos| has
    fundamental 8/(3 pi), cos^3 has 3/4, so K1 (1 + Koq g 8/(3 pi) + K3 g^2 3/4)."""
    from accelcal.estimators.campaign import process_campaign
    runs = _runs(drop)
    res = process_campaign(_centrifuge_subset(runs, set(), True))
    assert _check(res, UNIT) >= 4
    g = float(runs[0].meta["g_local_m_s2"])
    k1 = next(c for c in res.coefficients if c.method == "joint_ml" and c.name.startswith("K1"))
    base, terms = split_combination(k1.name)
    assert base == "K1"
    assert terms["Koq"] == pytest.approx(UNIT["K1"] * g * 8 / (3 * math.pi), rel=5e-3)
    assert terms["K3"] == pytest.approx(UNIT["K1"] * 0.75 * g * g, rel=5e-3)


@needs_samples
@pytest.mark.parametrize("keep", [(1,), (2,), (1, 2), (2, 3)], ids=["a", "b", "a+b", "b+c"])
def test_sine_with_fewer_attitudes_reports_combinations_not_paper_002_values(keep):
    from accelcal.estimators.campaign import process_campaign
    runs = _runs("drop-2026-11-19-sine")
    res = process_campaign([runs[i - 1] for i in keep])
    assert not any(c.method == "sine_ls" for c in res.coefficients)
    assert any("sine_ls: no values" in f for f in res.flags)
    assert _check(res, SINE) >= 5
    if keep == (1,):
        # methods.md: in attitude (a) a_I >= 0, so K2 and Koq alias
        assert any(c.name == "K2+Koq" for c in res.coefficients)


# ------------------------------------------------------------------- designs the samples cannot make
# Our simulator: regression checks that these designs fit (issue 30's list), not evidence
# of the model (the sample-drop tests above are).

def _simulated(sc, seed=1):
    from accelcal.estimators.campaign import process_campaign
    from accelcal.simulate import simulate_campaign
    from accelcal.validation.montecarlo import SimRunFile
    return process_campaign([SimRunFile.from_simrun(r) for r in simulate_campaign(sc, seed)])


def _adequate(res):
    return res.extras["joint"]["lack_of_fit"]["status"] == "adequate"


def test_a_second_centrifuge_with_only_a_pa_radial_pair_holds_its_radius():
    import copy

    from accelcal.simulate import load_scenario
    sc = load_scenario("snj103-lxj200")
    second = copy.deepcopy(load_scenario("snj103-lxj100").tests[1])
    second["mounts"] = [m for m in second["mounts"] if m["plane"] == "IA-PA" and float(m["angle_deg"]) in (90, 270)]
    second["run_id_prefix"] = "LXJ100-X"
    sc.tests.append(second)
    res = _simulated(sc)
    assert _adequate(res)
    held = {p["name"]: p["held"] for p in res.extras["joint"]["parameters"] if p["held"]}
    assert held.get("R[LXJ-100]", "").startswith("weakly determined")


def test_a_tilted_table_lets_in_the_square_terms_it_shows():
    import copy

    from accelcal.simulate import load_scenario
    sc = copy.deepcopy(load_scenario("hust-m07-thermal"))
    sc.tests[0]["tilt_deg"] = 30.0
    sc.coefficients.update({"K2": 3.94e-7, "Kpp": 4.7e-8, "Kip": 7.1e-7, "Koo": 3e-8, "Kio": 2e-7})
    res = _simulated(sc)
    assert _adequate(res)
    rows = {c.name: c for c in res.coefficients if c.method == "joint_ml"}
    # a tilted table turns gravity through IA and PA: cos 2psi sees K2 - Kpp, sin 2psi Kip
    assert abs(rows["K2-Kpp"].value - (3.94e-7 - 4.7e-8)) < 4 * rows["K2-Kpp"].std_uncertainty
    assert abs(rows["Kip"].value - 7.1e-7) < 4 * rows["Kip"].std_uncertainty
    # K1 (1 + Kio g cos tilt)
    k1 = next(c for n, c in rows.items() if n.startswith("K1+"))
    assert split_combination(k1.name)[1]["Kio"] == pytest.approx(50.0 * 9.7936 * math.cos(math.radians(30)),
                                                                    rel=5e-3)


@needs_samples
def test_on_many_readings_the_separating_run_is_left_to_accelcal_design(monkeypatch):
    """The run that separates an aliased pair is sought by a test-design advice, which
    refits the runs made reading by reading; above testdesign.SEPARATION_MAX_READINGS the
    certificate keeps the stored flag, which names the command that finds it."""
    from accelcal import testdesign
    from accelcal.diagnosis.core import prepare_cells
    from accelcal.estimators.campaign import process_campaign
    monkeypatch.setattr(testdesign, "SEPARATION_MAX_READINGS", 10)
    runs = _centrifuge_subset(_runs("drop-2026-11-20"), {0, 180, 45, 225}, False)
    res = process_campaign(runs)
    (flag,) = [f for f in res.flags if f.startswith("Kip, Kpp: ")]
    assert flag.endswith("accelcal design --separate Kip,Kpp --max-runs 1")
    assert testdesign.separating_run_flag(prepare_cells(runs)[0], ("Kip", "Kpp")) is None

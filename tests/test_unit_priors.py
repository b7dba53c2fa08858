"""A unit's last calibration is the prior of its next tumble-only recalibration.

One unit, a full calibration (tumble + centrifuge: Koq, K3 and Koo determined alone) in
2024, then a tumble alone in 2025: the tumble's rows are K1 and K0, held at the 2024
values of the terms they take up, each a type-B line of the budget naming that result.

Independent truth: the same tumble stored where the unit has no real earlier
calibration (its 2024 campaign simulated: never a prior) gives the combination C with
its factors; the GUM measurement model Q = C - sum f_k T_k (JCGM 100 §5.1.2,
u_c^2 = u(C)^2 + sum (f_k u(T_k))^2) is written out here with T_k the 2024 result's
stored values.
"""
from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

import pytest

from accelcal.warehouse import Warehouse

SERIAL, MODEL = "PU-1", "QA-2000"
FULL, TUMBLE = f"{SERIAL}/2024-03-01", f"{SERIAL}/2025-03-01"
#: model-wide priors far from the unit's own values: the unit's own take precedence
TOML = (f'[prior."{MODEL}"]\nKoq = {{ value = 3e-5, u = 1e-5 }}\nK3 = {{ value = 3e-6, u = 1e-6 }}\n'
        'Koo = { value = 3e-5, u = 1e-5 }\n')


def _drop(out: Path, campaign: str, date: str, tumble_only: bool, seed: int, real: bool = True) -> Path:
    """One campaign of scenario snj103-lxj100 (our simulator) as a drop of unit PU-1;
    ``real``: without the simulator's mark (as the lab's DAQ writes it)."""
    from accelcal.simulate import load_scenario, simulate_campaign, write_drop
    sc = copy.deepcopy(load_scenario("snj103-lxj100"))
    if tumble_only:
        sc.tests = [t for t in sc.tests if t["kind"] == "tumble"]
    runs = simulate_campaign(sc, seed)
    for k, r in enumerate(runs):
        r.meta.update(unit_serial=SERIAL, unit_model=MODEL, campaign=campaign,
                      run_id=f"{campaign}-{r.meta['run_id']}",
                      started_at=f"{date}T{9 + k // 60:02d}:{k % 60:02d}:00+00:00")
    for p in write_drop(runs, out):
        if real:
            p.write_text("".join(x for x in p.read_text().splitlines(keepends=True)
                                 if x.strip() != "# simulated: true"))
    return out


@pytest.fixture(scope="module")
def drops(tmp_path_factory):
    d = tmp_path_factory.mktemp("unit-priors")
    return {"full": _drop(d / "full", FULL, "2024-03-01", False, 11),
            "full-sim": _drop(d / "full-sim", FULL.replace("/", "/sim-"), "2024-03-01", False, 11, real=False),
            "tumble": _drop(d / "tumble", TUMBLE, "2025-03-01", True, 12)}


def _run(folder: Path, drops: list[Path], toml: str | None = None, simulated: bool = False) -> Warehouse:
    from accelcal.config import run_parameters
    from accelcal.flows.pipeline import run_pipeline
    folder.mkdir(parents=True, exist_ok=True)
    if toml:
        (folder / "accelcal.toml").write_text(toml)
    summary = run_pipeline([str(p) for p in drops], folder / "lab.duckdb", engine="local", settle=0,
                           allow_simulated=simulated, parameters=run_parameters(None, folder / "lab.duckdb"))
    assert all(c["status"] in ("new", "simulated-not-current") for c in summary["campaigns"]), summary
    return Warehouse(folder / "lab.duckdb")


def _adopted(w: Warehouse, campaign: str) -> dict:
    return {r["name"]: r for r in w.query(
        "SELECT * FROM coefficient_history JOIN results_current USING (result_id) "
        "WHERE results_current.campaign = ? AND adopted", [campaign])}


@pytest.fixture(scope="module")
def held(drops, tmp_path_factory):
    """The full calibration and the tumble in one run, the tumble's drop listed first; the
    config file states model-wide priors too."""
    return _run(tmp_path_factory.mktemp("held"), [drops["tumble"], drops["full"]], TOML)


@pytest.fixture(scope="module")
def bare(drops, tmp_path_factory):
    """The tumble where the unit's only earlier calibration is simulated."""
    return _run(tmp_path_factory.mktemp("bare"), [drops["full-sim"], drops["tumble"]], simulated=True)


def test_without_a_real_earlier_calibration_the_tumble_keeps_its_combinations(bare):
    rows = _adopted(bare, TUMBLE)
    assert {"K1(Koq,K3)", "K0(Koo)"} <= set(rows) and "K1" not in rows and "K0" not in rows
    (params,) = bare.query("SELECT parameters FROM results_current WHERE campaign = ?", [TUMBLE])
    assert "prior_results" not in json.loads(params["parameters"])


def test_the_tumble_is_held_at_the_units_last_calibration(held, bare):
    full = _adopted(held, FULL)
    assert {"Koq", "K3", "Koo"} <= set(full) and not any(full[t]["factors"] for t in ("Koq", "K3", "Koo"))
    got, comb = _adopted(held, TUMBLE), _adopted(bare, TUMBLE)
    assert "K1(Koq,K3)" not in got and "K0(Koo)" not in got
    held_rows = [n for n, c in comb.items() if c["factors"] and set(json.loads(c["factors"])) <= set(full)]
    assert {"K1(Koq,K3)", "K0(Koo)"} <= set(held_rows)
    for name in held_rows:
        c, q = comb[name], got[name.split("(")[0]]
        f = json.loads(c["factors"])
        # the measurement model, by hand: the 2024 result's values and u, the stored factors
        want = c["value"] - sum(f[t] * full[t]["value"] for t in f)
        u_c = math.sqrt(c["std_uncertainty"] ** 2 + sum((f[t] * full[t]["std_uncertainty"]) ** 2 for t in f))
        assert q["value"] == pytest.approx(want, rel=1e-12, abs=1e-18)
        assert q["std_uncertainty"] == pytest.approx(u_c, rel=1e-12)
        assert q["factors"] is None and full[next(iter(f))]["result_id"][:12] in q["note"]
        assert "accelcal.toml" not in q["note"]        # the unit's own before the model's
    # each held term a type-B line of the quantity's budget, naming the result it is from
    src = full["Koq"]["result_id"]
    lines = held.query("SELECT quantity, sensitivity, std_uncertainty, type FROM budget_history "
                       "JOIN results_current USING (result_id) WHERE results_current.campaign = ? "
                       "AND coefficient = 'K1' AND quantity LIKE '%held at its prior%'", [TUMBLE])
    assert {x["quantity"].split()[0] for x in lines} == {"Koq", "K3"}
    for x in lines:
        t = x["quantity"].split()[0]
        assert x["type"] == "B" and f"result {src[:12]} of {FULL}, 2024-03-01" in x["quantity"]
        assert x["sensitivity"] == pytest.approx(-json.loads(comb["K1(Koq,K3)"]["factors"])[t], rel=1e-12)
        assert x["std_uncertainty"] == full[t]["std_uncertainty"]
    # the stored parameters name the source result (it enters the result_id); the science
    # records what it assumed
    (r,) = held.query("SELECT parameters, science_parameters FROM results_current WHERE campaign = ?", [TUMBLE])
    assert json.loads(r["parameters"])["prior_results"] == [src]
    assumed = json.loads(r["science_parameters"])["assumed"]
    assert set(assumed) == {n.split("(")[0] for n in held_rows}
    assert assumed["K1"]["Koq"]["value"] == full["Koq"]["value"]


def test_the_units_k1_series_continues_through_the_tumble(held):
    hist = held.query("SELECT campaign, name, calibration_no FROM unit_history "
                      "WHERE unit_serial = ? AND quantity = 'K1' ORDER BY calibration_no", [SERIAL])
    assert [(h["campaign"], h["name"]) for h in hist] == [(FULL, "K1"), (TUMBLE, "K1")]


def test_a_rerun_of_the_same_history_changes_nothing(held, drops):
    from accelcal.config import run_parameters
    from accelcal.flows.pipeline import run_pipeline
    summary = run_pipeline([str(drops["full"]), str(drops["tumble"])], held.path, engine="local",
                           settle=0, parameters=run_parameters(None, held.path))
    assert {c["campaign"]: c["status"] for c in summary["campaigns"]} == {FULL: "unchanged", TUMBLE: "unchanged"}


def test_the_certificate_says_what_was_assumed_and_from_which_result(held, tmp_path):
    from accelcal.ops.dcc import dcc_path
    from accelcal.ops.report import build_report
    page = build_report(held.path, TUMBLE, tmp_path, dcc=True)
    html = page.read_text()
    src = _adopted(held, FULL)["Koq"]["result_id"][:12]
    assumed = html.split("Assumed values")[1].split("</table>")[0]
    for q, term in (("K1", "Koq"), ("K1", "K3"), ("K0", "Koo")):
        assert re.search(rf"<td>{q}</td><td>{term}</td>.*?result {src} of {FULL}, 2024-03-01", assumed), term
    assert "accelcal.toml" not in assumed
    # the quantity's own budget, prior lines included, has its JCGM 101 check; the fit's
    # remark that the terms were held at 0 belongs to the combination, not to the quantity
    for q in ("K0", "K1", "K2"):
        assert re.search(rf"<tr><td>{q}</td>(?:<td[^>]*>[^<]*</td>){{8}}<td class=\"ok\">PASS</td>", html), q
    assert not re.search(r"class='flag'>K[012]\([^)]*\): aliased in this design", html)
    # the DCC's description of each such result says the same
    dcc = dcc_path(page).read_text()
    assert re.search(rf"K1 with K3 = [^;]*, Koq = [^;]* \(result {src} of {FULL}, 2024-03-01\) assumed", dcc)


def test_ten_units_by_one_tumble_a_year_held_at_their_full_calibration_get_due_dates(tmp_path):
    """Ten units, a full calibration in 2020 (Koq, K3, Koo, K1 determined alone), then one
    tumble a year 2021-2025 held at the 2020 values (the warehouse's look-up, the
    science's measurement model); units 0-4 drift in K1 (5e-5 to 1.3e-4 a year,
    relative), 5-9 are stable; tolerance K1 = { relative = 2.0e-4 }."""
    import datetime as dt

    import numpy as np

    from accelcal.estimators.priors import apply_priors
    from accelcal.ops import due
    from test_structural_names import _adopted, _stored_a_week_after, _tumble, _warehouse
    from test_views import add_campaign
    sc, raw = _tumble(1)
    w, cfg = _warehouse(tmp_path)
    truth = sc.coefficients
    comb = _adopted(raw)["K1(Koq,K3)"]
    u = 5e-6 * comb.value                   # a lab's u of the combination, type B included
    rate = {j: (5e-5 + 2e-5 * j if j < 5 else 0.0) for j in range(10)}
    rng = np.random.default_rng(3)
    with w.session():                       # one open of the file for the fleet
        for j in range(10):
            serial = f"TU-{j}"
            full = {k: (truth[k], 0.05 * abs(truth[k]) or 1e-9) for k in ("K0", "K2", "Koq", "K3", "Koo")}
            full["K1"] = (truth["K1"], u)
            add_campaign(w, serial, f"{serial}/2020", "DH-1", "2020-03-01T10:00:00+00:00", full, method="joint_ml")
            for y in range(2021, 2026):
                res = copy.deepcopy(raw)
                row = next(c for c in res.coefficients if c.adopted and c.name == "K1(Koq,K3)")
                row.value = comb.value * (1 + rate[j] * (y - 2021)) + u * rng.standard_normal()
                row.std_uncertainty = u
                camp, at = f"{serial}/{y}", dt.datetime(y, 3, 1, 10, tzinfo=dt.timezone.utc)
                known = w.unit_priors({camp: (serial, at, False)})[camp]
                assert {t: known[t]["value"] for t in ("Koq", "K3", "Koo")} == {t: full[t][0] for t in ("Koq", "K3", "Koo")}
                assert apply_priors(res, known)
                add_campaign(w, serial, camp, "DH-1", at.isoformat(),
                             {n: (c.value, c.std_uncertainty, c.factors) for n, c in _adopted(res).items()},
                             method="joint_ml")
    _stored_a_week_after(w)
    as_of = dt.datetime(2025, 6, 1, 23, 59, 59, tzinfo=dt.timezone.utc)
    rows = {(r["unit_serial"], r["coefficient"]): r for r in due.due_rows(w.path, cfg, as_of)}
    for j in range(10):
        r = rows[(f"TU-{j}", "K1")]
        assert r["name"] == "K1" and r["n_campaigns"] >= 5     # the tumbles, 2020 too unless adjusted
        assert r["tolerance"] == pytest.approx(2e-4 * abs(r["value_in_use"]))
        if rate[j]:
            assert r["due_date"] is not None, r
        else:
            assert r["due_date"] is None or r["due_date"] > "2028-03-01", r

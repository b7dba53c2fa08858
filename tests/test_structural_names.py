"""A row's name is the quantity, never a number from the data.

A tumble alone determines K1 only with the odd terms its input takes up (the fundamental of
cos|cos| is 8/(3 pi), of cos^3 3/4: K1 (1 + Koq g 8/(3 pi) + K3 g^2 3/4)), so its factors
are proportional to K1 and move with every draw and every year of a drifting unit.  The
name must not: it is the coefficient kept and the names of the terms it takes up
(``K1(Koq,K3)``), the factors beside it.  Tolerances, drift series and due dates key on the
quantity (``K1``), so the lab's yearly recalibration by tumble alone gets a due date.

Independent truth: the closed form above for the factors; the fleets are hand-made
(tests/test_views.add_campaign) from the rows our simulator's tumbles are adopted as.
"""
from __future__ import annotations

import copy
import datetime as dt
import json
import math

import numpy as np
import pytest

from accelcal.effects import split_combination
from accelcal.ops import due
from accelcal.config import forecast_config
from accelcal.warehouse import Warehouse, ensure_views
from test_views import add_campaign

TOML = ('[tolerance."QA-2000"]\nK1 = { relative = 2.0e-4 }\nK0 = { absolute = 5.0e-4 }\n'
        '[forecast]\nrisk = 0.05\n')


def _tumble(seed: int, k1: float | None = None):
    """One tumble-only campaign of scenario snj103-lxj100 (our simulator), processed; K1 as
    given."""
    from accelcal.estimators.campaign import process_campaign
    from accelcal.simulate import load_scenario, simulate_campaign
    from accelcal.validation.montecarlo import SimRunFile
    sc = copy.deepcopy(load_scenario("snj103-lxj100"))
    sc.tests = [t for t in sc.tests if t["kind"] == "tumble"]
    if k1 is not None:
        sc.coefficients["K1"] = k1
    res = process_campaign([SimRunFile.from_simrun(r) for r in simulate_campaign(sc, seed)])
    return sc, res


def _adopted(res) -> dict:
    return {c.name: c for c in res.coefficients if c.adopted}


def test_every_draw_of_one_tumble_design_adopts_the_same_names():
    draws = [_tumble(seed) for seed in (1, 2, 3, 4)]
    names = [sorted(_adopted(res)) for _, res in draws]
    assert all(n == names[0] for n in names), names
    assert {"K1(Koq,K3)", "K0(Koo)", "K2(Koo)", "theta0(Ko)"} <= set(names[0])
    g = float(draws[0][0].site["g_local_m_s2"])
    for sc, res in draws:
        for name, c in _adopted(res).items():
            # the name says which terms; the factors say how much of each
            assert set(split_combination(name)[1]) == set(c.factors), name
        k1 = _adopted(res)["K1(Koq,K3)"]
        K1 = sc.coefficients["K1"]
        assert k1.factors["Koq"] == pytest.approx(K1 * g * 8 / (3 * math.pi), rel=5e-3)
        assert k1.factors["K3"] == pytest.approx(K1 * 0.75 * g * g, rel=5e-3)
        assert _adopted(res)["K0(Koo)"].factors["Koo"] == pytest.approx(g * g, rel=1e-6)
    # the factors do move with the data (the fitted K1), the names do not
    assert len({_adopted(res)["K1(Koq,K3)"].factors["K3"] for _, res in draws}) > 1


def _warehouse(tmp_path):
    w = Warehouse(tmp_path / "lab.duckdb", lock_timeout=5)
    w.init()
    ensure_views(w.path)
    (tmp_path / "accelcal.toml").write_text(TOML)
    return w, forecast_config(tmp_path / "accelcal.toml")


def _stored_a_week_after(w) -> None:
    """As if each result had been stored a week after its tumble (as-of queries)."""
    with w.connect() as con:
        for table, col in (("result_activations", "activated_at"), ("results", "computed_at")):
            con.execute(f"UPDATE {table} SET {col} = CAST(split_part(campaign, '/', 2) "
                        "|| '-03-08 00:00:00+00' AS TIMESTAMPTZ)")


def _rows(res, k1: tuple[float, float] | None = None) -> dict:
    """{name: (value, u, factors)} of a tumble's adopted rows, K1's (value, u) as given."""
    out = {n: (c.value, c.std_uncertainty, c.factors) for n, c in _adopted(res).items()}
    if k1 is not None:
        out["K1(Koq,K3)"] = (*k1, out["K1(Koq,K3)"][2])
    return out


def test_ten_units_recalibrated_by_tumble_alone_get_due_dates_where_they_drift(tmp_path):
    """Ten units, one tumble a year 2021-2025; units 0-4 drift in K1 (5e-5 to 1.3e-4 a
    year, relative), units 5-9 are stable; tolerance K1 = { relative = 2.0e-4 }."""
    _, res = _tumble(1)
    w, cfg = _warehouse(tmp_path)
    k1 = _adopted(res)["K1(Koq,K3)"].value
    u = 5e-6 * k1           # a lab's u of K1, type B included (the simulated tumble's is 2e-8)
    rate = {j: (5e-5 + 2e-5 * j if j < 5 else 0.0) for j in range(10)}
    rng = np.random.default_rng(3)
    with w.session():                       # one open of the file for the fleet
        for j in range(10):
            for y in range(2021, 2026):
                value = k1 * (1 + rate[j] * (y - 2021)) + u * rng.standard_normal()
                add_campaign(w, f"TU-{j}", f"TU-{j}/{y}", "DH-1", f"{y}-03-01T10:00:00+00:00",
                             _rows(res, (value, u)), method="joint_ml")
    _stored_a_week_after(w)
    as_of = dt.datetime(2025, 6, 1, 23, 59, 59, tzinfo=dt.timezone.utc)
    rows = {(r["unit_serial"], r["coefficient"]): r for r in due.due_rows(w.path, cfg, as_of)}
    for j in range(10):
        r, r0 = rows[(f"TU-{j}", "K1")], rows[(f"TU-{j}", "K0")]
        # the tolerance of the quantity applies to the combination that measures it
        assert r["tolerance"] == pytest.approx(2e-4 * abs(r["value_in_use"]))
        assert r0["tolerance"] == pytest.approx(5e-4)
        assert r["name"] == "K1(Koq,K3)" and set(r["factors"]) == {"Koq", "K3"}
        assert r["measured"].startswith("K1 + ") and r["n_campaigns"] == 5
        if rate[j]:
            assert r["due_date"] is not None, r
        else:
            assert r["due_date"] is None or r["due_date"] > "2028-03-01", r
    text = "\n".join(due.text_lines(list(rows.values()), as_of.date(), width=200))
    assert "TU-0  K1 (as K1 + 9.55·K3 + 1.1·Koq, the combination the design determines)  due" in text


def test_one_units_history_over_five_tumbles_is_one_series_per_coefficient(tmp_path):
    """Five tumbles of one unit whose K1 drifts 1e-4 a year: every year's factors differ
    (they are proportional to K1), one series per coefficient all the same."""
    w, cfg = _warehouse(tmp_path)
    k1 = 0.1325631
    factors = []
    for k, y in enumerate(range(2021, 2026)):
        _, res = _tumble(10 + k, k1 * (1 + 1e-3 * k))
        factors.append(_adopted(res)["K1(Koq,K3)"].factors["K3"])
        add_campaign(w, "TU-1", f"TU-1/{y}", "DH-1", f"{y}-03-01T10:00:00+00:00", _rows(res),
                     method="joint_ml")
    assert len({f"{f:.3g}" for f in factors}) > 1     # the old names would have split
    rows, adjusted = due.load_history(w.path)
    series = {q: lst for (unit, q), lst in due._series(rows).items()}
    assert set(series) == {"K0", "K1", "K2", "Kio", "theta0"}
    assert all(len(lst) == 5 for lst in series.values())
    assert {r["name"] for r in series["K1"]} == {"K1(Koq,K3)"}
    assert all(json.loads(r["factors"]).keys() == {"K3", "Koq"} for r in series["K1"])
    with w.connect(read_only=True) as con:
        n = con.execute("SELECT quantity, count(*), max(calibration_no) FROM unit_history "
                        "WHERE unit_serial = 'TU-1' GROUP BY quantity ORDER BY quantity").fetchall()
    assert n == [(q, 5, 5) for q in sorted(series)]
    page = due.history_html(w.path, "TU-1", tmp_path / "html", cfg)
    html = page.read_text()
    assert html.count("<h2>") == 5 and "<h2>K1</h2>" in html and "K1(Koq,K3)" in html


def test_a_result_adopting_a_coefficient_and_a_combination_of_it_keeps_the_coefficient(tmp_path):
    """IA-PA 0/180 + 45/225: the joint fit adopts Kip (large u) and Kip(Kpp) (the nearly
    aliased pair's combination); the Kip series takes Kip, the view still lists both."""
    w, _ = _warehouse(tmp_path)
    for y in (2024, 2025):
        add_campaign(w, "TU-2", f"TU-2/{y}", "LXJ-100", f"{y}-03-01T10:00:00+00:00",
                     {"Kip": (7.1e-7, 1e-6), "Kip(Kpp)": (7.6e-7, 4e-9, {"Kpp": 1.0})},
                     method="joint_ml")
    with w.connect(read_only=True) as con:
        hist = con.execute("SELECT quantity, name, factors, calibration_no FROM unit_history "
                           "ORDER BY calibration_no").fetchall()
        n_cal = con.execute("SELECT count(*) FROM calibration").fetchall()[0][0]
    assert hist == [("Kip", "Kip", None, 1), ("Kip", "Kip", None, 2)] and n_cal == 4

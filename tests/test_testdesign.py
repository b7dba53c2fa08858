"""Test-design advice (issue 25), against facts that do not come from the code:

* the square root of the information reproduces J^T J, and stacking it over more rows is
  the least squares of all rows (linear algebra, checked with numpy's own lstsq);
* at 45 deg and 225 deg a_I a_P = +a^2/2, at 135 deg and 315 deg -a^2/2 (drop-format.md's
  mount angle), so with every instrument coefficient unknown one 45 deg run gives only
  Kip + Kpp, and 45 deg with 135 deg separates them (issue 25);
* a tumble at 1 g senses sum K_ii a_i^2 with sum a_i^2 = g^2: no tumble determines K2
  itself, only its differences with Kpp and Koo (IEEE Std 1293 annex on the multi-position
  test);
* bad input is one line naming what is wrong.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from accelcal import testdesign as td
from accelcal.fitting.core import information_root, lstsq_svd

BASE = ["earth_rate", "odd_quadratic", "cubic", "mass_centre_offset", "mount_angle_error"]


def _cells(keep_mounts=((0, "IA-PA"), (180, "IA-PA")), tumble=True, centrifuge=True):
    from accelcal.diagnosis.core import prepare_cells
    from accelcal.simulate import load_scenario, simulate_campaign
    from accelcal.validation.simruns import SimRunFile
    sc = load_scenario("demo")
    cen = next(t for t in sc.tests if t["kind"] == "centrifuge")
    cen["mounts"] = [m for m in cen["mounts"] if (m["angle_deg"], m["plane"]) in keep_mounts]
    sc.tests = [t for t in sc.tests if (t["kind"] == "tumble" and tumble) or (t["kind"] == "centrifuge" and centrifuge)]
    cells, _ = prepare_cells([SimRunFile.from_simrun(r) for r in simulate_campaign(sc, 3)])
    return cells


def test_information_root_is_the_information_and_stacks_as_more_rows():
    rng = np.random.default_rng(7)
    J1 = rng.normal(size=(40, 5)) * [1, 1e4, 1e-4, 1, 3]
    J2 = rng.normal(size=(6, 5)) * [1, 1e4, 1e-4, 1, 3]
    R = information_root(J1)
    assert np.allclose(R.T @ R, J1.T @ J1, rtol=1e-9, atol=0)
    both = np.vstack([J1, J2])
    direct = np.linalg.inv(both.T @ both)
    via_root = lstsq_svd(np.vstack([R, J2]), np.zeros(R.shape[0] + 6)).cov
    assert np.allclose(via_root, direct, rtol=1e-7)


@pytest.fixture(scope="module")
def ia_pair():
    return _cells()


def test_one_45_deg_run_leaves_kip_and_kpp_aliased_45_and_135_separate_them(ia_pair):
    cands = [c for c in td.candidate_runs(ia_pair)
             if c.test == "centrifuge" and c.spec["mount_plane"] == "IA-PA" and c.spec["vertical_axis"] == "+OA"
             and c.spec["mount_angle_deg"] in (45.0, 135.0)]
    assert len(cands) == 2
    one = td.advise(ia_pair, BASE, ["Kip"], [("Kip", "Kpp")], max_runs=1, candidates=cands[:1])
    assert one.current.std_uncertainty == {"Kip": None, "Kpp": None}
    assert not one.proposals or one.proposals[0].predicted.std_uncertainty["Kip"] is None
    two = td.advise(ia_pair, BASE, ["Kip"], [("Kip", "Kpp")], max_runs=2, candidates=cands)
    best = two.proposals[0]
    assert sorted(c.spec["mount_angle_deg"] for c in best.runs) == [45.0, 135.0]
    u = best.predicted.std_uncertainty
    assert u["Kip"] is not None and u["Kpp"] is not None
    assert abs(best.predicted.corr["Kip|Kpp"]) < td.SEPARATED
    assert best.minutes == pytest.approx(sum(c.minutes + td.SETUP_MIN_DEFAULT for c in cands))


def test_no_tumble_determines_k2_itself():
    cells = _cells(centrifuge=False)
    adv = td.advise(cells, ["initial_misalignment"], ["K2"], max_runs=2)
    assert adv.current.std_uncertainty["K2"] is None
    assert all(p.predicted.std_uncertainty["K2"] is None for p in adv.proposals)
    assert any("no run these rigs can make determines it" in n for n in adv.notes)
    assert {c.test for c in td.candidate_runs(cells)} == {"tumble"}


def test_json_keeps_drop_format_keys(ia_pair):
    adv = td.advise(ia_pair, BASE, ["Kip"], max_runs=1, top=3)
    d = json.loads(json.dumps(adv.to_dict()))
    assert set(d) >= {"current", "proposals"} and "std_uncertainty" in d["current"]
    run = d["proposals"][0]["runs"][0]
    keys = {"test", "rig_id"} | ({"mount_plane", "mount_angle_deg", "vertical_axis", "g_levels", "reads_per_level"}
                                 if run["test"] == "centrifuge" else {"head_axis", "cos_axis", "sin_axis",
                                                                      "positions_deg"})
    assert keys <= set(run)
    assert d["proposals"][0]["minutes"] > 0


def test_bad_input_is_one_line(ia_pair, tmp_path):
    with pytest.raises(td.DesignError, match="target 'Kxx': neither a coefficient nor an effects.md id"):
        td.advise(ia_pair, BASE, ["Kxx"])
    with pytest.raises(td.DesignError, match="baseline effect 'warp'"):
        td.advise(ia_pair, ["warp"], ["Kip"])
    f = tmp_path / "c.toml"
    f.write_text('[[run]]\ntest = "centrifuge"\nrig_id = "LXJ-100"\nmount_plane = "IA-PA"\n'
                 'mount_angle_deg = 45\nvertical_axis = "+OA"\ng_levels = [1, 30]\n')
    with pytest.raises(td.DesignError, match=r"c.toml: \[\[run\]\] 1: g level 30 beyond rig LXJ-100's limit 20 g"):
        td.load_candidates(f, ia_pair, {"LXJ-100": 20.0})
    f.write_text('[[run]]\ntest = "centrifuge"\nrig_id = "LXJ-999"\nmount_plane = "IA-PA"\n'
                 'mount_angle_deg = 45\nvertical_axis = "+OA"\n')
    with pytest.raises(td.DesignError, match="no centrifuge run of rig LXJ-999"):
        td.load_candidates(f, ia_pair)
    for e in (td.DesignError,):
        try:
            td.advise(ia_pair, BASE, ["Kxx"])
        except e as exc:
            assert "\n" not in str(exc)


def test_cli_prints_a_short_table_and_json(ia_pair, tmp_path, capsys):
    from accelcal.cli import main
    from accelcal.simulate.io import write_run_file
    drop = tmp_path / "drop"
    drop.mkdir()
    from accelcal.simulate import load_scenario, simulate_campaign
    sc = load_scenario("demo")
    cen = next(t for t in sc.tests if t["kind"] == "centrifuge")
    cen["mounts"] = [m for m in cen["mounts"] if m["plane"] == "IA-PA" and m["angle_deg"] in (0, 180)]
    for r in simulate_campaign(sc, 3):
        write_run_file(r.meta, r.data, drop / f"{r.meta['run_id']}.csv")
    assert main(["design", str(drop), "--target", "Kip", "--top", "3"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Now: u(Kip) not determined")
    assert all(len(line) <= 80 for line in out.splitlines())
    assert main(["design", str(drop), "--target", "Kip", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["current"]["std_uncertainty"]["Kip"] is None and d["proposals"]
    assert main(["design", str(drop), "--target", "Kxx"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Kxx" in err[0]


def test_diagnose_says_which_run_would_fix_what_it_cannot_see(ia_pair):
    """An effect the runs cannot see gets the best single run to see it, or says that no
    run of these rigs does (the rate scale error is one with the radius on a centrifuge)."""
    from accelcal.testdesign import next_runs
    res = {"unobservable": [{"effect": "cross_coupling"}, {"effect": "rate_scale_error"}], "ranking": [],
           "baseline": {"effects": [e for e in BASE]}}
    out = {f["to"]: f for f in next_runs_from_cells(ia_pair, res, next_runs)}
    assert out["see cross_coupling"]["run"] and out["see cross_coupling"]["minutes"] > 0
    assert out["see cross_coupling"]["predicted"]["cross_coupling"] is not None
    assert "no run or pair of runs" in out["see rate_scale_error"]["note"]


def next_runs_from_cells(cells, res, fn):
    """next_runs reads RunFile-like runs; RunCells carry the same meta and columns."""
    import pandas as pd

    class Run:
        def __init__(self, c):
            self.meta, self.data, self.sha256 = c.meta, pd.DataFrame(c.cols), c.sha256
    return fn([Run(c) for c in cells], res)


def test_rig_limits_come_from_the_config_file(tmp_path):
    """``[rigs."ID"] max_g`` of accelcal.toml bounds a candidate's g levels; a bad value is
    one line naming the file and the key."""
    from accelcal.config import ConfigError, rig_limits
    f = tmp_path / "accelcal.toml"
    f.write_text('[rigs."LXJ-100"]\nmax_g = 20\n[rigs."DH-1"]\nnote = "no g limit"\n')
    assert rig_limits(f) == {"LXJ-100": 20.0}
    f.write_text('[rigs."LXJ-100"]\nmax_g = "fast"\n')
    with pytest.raises(ConfigError, match=r'accelcal.toml: \[rigs."LXJ-100"\] max_g must be a number'):
        rig_limits(f)


def test_a_session_gives_the_answers_of_separate_calls_fitting_the_runs_made_once(ia_pair, monkeypatch):
    """Questions that share a model (the same baseline and candidates) asked in one session
    get exactly the answers they get alone; the runs made are fitted once per model."""
    asks = [(["K2"], [], 1), (None, [("Kip", "Kpp")], 1), (["Kip"], [("Kip", "Kpp")], 2), (["K2"], [], 2)]
    alone = [td.advise(ia_pair, BASE, t, s, max_runs=m) for t, s, m in asks]
    fits = []
    real = td.fit_selected
    monkeypatch.setattr(td, "fit_selected", lambda model, **kw: fits.append(1) or real(model, **kw))
    session: dict = {}
    together = [td.advise(ia_pair, BASE, t, s, max_runs=m, session=session) for t, s, m in asks]
    assert len(fits) == 1 and len(session) == 1
    for a, b in zip(alone, together):
        assert repr(a) == repr(b)

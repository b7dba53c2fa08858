"""GE validation tests (drop-format.md, "What the pipeline must refuse" and the per-test claims)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover
from accelcal.schemas.dropspec import DropFormatError
from accelcal.schemas.suites import Refusal, validate_report, validate_runs

from conftest import EXAMPLES, require_shared  # ../shared/examples relative to the repository root

require_shared()
BAD = EXAMPLES / "drop-bad"
GOOD_DROPS = ["drop-2026-11-18-thermal", "drop-2026-11-19-sine", "drop-2026-11-20", "drop-2026-11-21"]


def _lines(p: Path) -> list[str]:
    return p.read_text().split("\n")


def _data_start(lines: list[str]) -> int:
    """0-based index of the first data row."""
    return next(i for i, s in enumerate(lines) if s.strip() and not s.startswith("#")) + 1


@pytest.fixture(scope="module")
def good_runs():
    return {d: [read_run(p) for p in discover(EXAMPLES / d)] for d in GOOD_DROPS}


def test_good_drops_fully_accepted(good_runs, tmp_path):
    for drop, runs in good_runs.items():
        rep = validate_report(runs, tmp_path if drop == "drop-2026-11-20" else None, drop)
        assert set(rep.refusals) == {r.path for r in runs}
        bad = [str(x) for v in rep.refusals.values() for x in v]
        assert bad == [], bad
    index = tmp_path / "drop-2026-11-20" / "index.html"
    assert index.exists() and rep.seconds > 0
    assert list((tmp_path / "drop-2026-11-20").rglob("validations/**/*.html"))


def test_drop_bad_validation_refusals():
    runs = []
    for p in discover(BAD):
        try:
            runs.append(read_run(p))
        except DropFormatError:
            pass
    assert sorted(Path(r.path).name for r in runs) == ["nan-output.csv", "ok-small.csv", "time-backwards.csv"]
    res = validate_runs(runs, None, "drop-bad")
    by_name = {Path(p).name: v for p, v in res.items()}
    assert by_name["ok-small.csv"] == []
    # independent: the line whose output field is not a number
    ls = _lines(BAD / "nan-output.csv")
    nan_line = next(i + 1 for i, s in enumerate(ls) if s and not s.startswith("#")
                    and s.split(",")[3].strip().lower() in ("nan", "inf", "-inf"))
    assert [(r.rule, r.line) for r in by_name["nan-output.csv"]] == [("output-not-finite", nan_line)]
    # independent: the first line whose time is less than the previous row's
    ls = _lines(BAD / "time-backwards.csv")
    start = _data_start(ls)
    t = [(i + 1, float(s.split(",")[0])) for i, s in enumerate(ls) if i >= start and s.strip()]
    back = next(ln for (ln, x), (_, prev) in zip(t[1:], t[:-1]) if x <= prev)
    assert [(r.rule, r.line) for r in by_name["time-backwards.csv"]] == [("time-not-increasing", back)]
    for v in by_name.values():
        for r in v:
            assert isinstance(r, Refusal) and r.rule and r.detail
            assert str(r) == f"{r.path}:{r.line}: {r.rule}: {r.detail}"


# ---- synthetic variants, all validated in one batch (tests mapping back to file + line) ----

def _edit_cell(text: str, row: int, col: int, value: str) -> tuple[str, int]:
    """Set data row ``row`` (0-based), column ``col``; return the text and that line number."""
    ls = text.split("\n")
    i = _data_start(ls) + row
    f = ls[i].split(",")
    f[col] = value
    ls[i] = ",".join(f)
    return "\n".join(ls), i + 1


def _variants():
    cen = (EXAMPLES / "drop-2026-11-20/centrifuge/LXJ100-20261120-0004.csv").read_text()
    tum = (EXAMPLES / "drop-2026-11-20/DH1-20261120-0001.csv").read_text()
    tilt = (EXAMPLES / "drop-2026-11-18-thermal/TT1-20261118-0001.csv").read_text()
    sine = (EXAMPLES / "drop-2026-11-19-sine/DC1-20261119-0001.csv").read_text()
    v = {}  # name -> (text, expected [(rule, line or None)])
    t, ln = _edit_cell(cen, 100, 2, "-0.5")
    v["negative-rate"] = (t, [("negative-rate", ln)])
    t, ln = _edit_cell(cen, 50, 4, "inf")
    v["inf-output"] = (t, [("output-not-finite", ln)])
    t, ln = _edit_cell(cen, 60, 5, "260.0")
    v["hot"] = (t, [("temp-out-of-range", ln)])
    t, ln = _edit_cell(cen, 9, 3, "")
    v["no-azimuth-at-rest"] = (t, [("angle-missing-at-rest", ln)])
    rest = _data_start(cen.split("\n")) + 1
    t = cen
    for row in range(8, 16):  # second rest dwell at 100 deg instead of 90
        t, _ = _edit_cell(t, row, 3, "100")
    v["rest-uneven"] = (t, [("rest-dwells", rest)])
    t = cen.replace("# arm_radius_m: 0.7102845", "# arm_radius_m: 0.3")
    v["no-1g"] = (t, [("no-1g-step", None)])
    t, ln = _edit_cell(tum, 25, 2, "30.9")
    v["tumble-angle"] = (t, [("angle-inconsistent", ln)])
    t = tum.replace("# sample_period_s: 1.0", "# sample_period_s: 0.5")
    v["tumble-period"] = (t, [("sample-period", _data_start(t.split("\n")) + 1)])
    t = tilt.replace("# positions: 12", "# positions: 10")
    v["tilt-positions"] = (t, [("positions-mismatch", None)])
    t = sine.replace("# rate_amplitude_rad_s: 12.566370614359172", "# rate_amplitude_rad_s: 15.0")
    v["sine-amp"] = (t, [("sine-amplitude", _data_start(t.split("\n")) + 1)])
    t = sine.replace("# rate_frequency_hz: 1.0", "# rate_frequency_hz: 1.5")
    v["sine-freq"] = (t, [("sine-frequency", _data_start(t.split("\n")) + 1)])
    t = tum.replace("# g_local_m_s2: 9.80122", "# g_local_m_s2: 98.0122")
    gl = next(i + 1 for i, s in enumerate(t.split("\n")) if s.startswith("# g_local"))
    v["tumble-g"] = (t, [("metadata-range", gl)])
    v["clean-centrifuge"] = (cen, [])
    return v


@pytest.fixture(scope="module")
def variant_results(tmp_path_factory):
    d = tmp_path_factory.mktemp("variants")
    runs, expect = [], {}
    for name, (text, exp) in _variants().items():
        p = d / f"{name}.csv"
        p.write_text(text)
        runs.append(read_run(p))
        expect[str(p)] = exp
    return validate_runs(runs, None, "variants"), expect


@pytest.mark.parametrize("name", sorted(_variants()))
def test_variant_refused_with_rule_and_line(variant_results, name):
    res, expect = variant_results
    path = next(p for p in res if Path(p).stem == name)
    got = [(r.rule, r.line) for r in res[path]]
    for rule, line in expect[path]:
        hits = [g for g in got if g[0] == rule]
        assert hits, (name, [str(r) for r in res[path]])
        if line is not None:
            assert (rule, line) in hits, (name, [str(r) for r in res[path]])
    if not expect[path]:
        assert got == []
    else:  # nothing unrelated refused
        assert {g[0] for g in got} == {rule for rule, _ in expect[path]}, [str(r) for r in res[path]]
    for r in res[path]:
        assert r.rule and r.detail and r.path == path


def test_configuration_memo_changes_no_verdict(variant_results, monkeypatch, tmp_path):
    """suites._configurations_memo (each expectation's GE configuration computed once per
    validation, a CPU saving) must leave every verdict as great-expectations' own code
    gives it: the same variants validated without the memo give the same refusals."""
    import contextlib

    from accelcal.schemas import suites
    res, _ = variant_results
    monkeypatch.setattr(suites, "_configurations_memo", contextlib.nullcontext)
    runs = [read_run(p) for p in sorted(res)]
    plain = validate_runs(runs, None, "variants")
    key = lambda d: {p: [(r.rule, r.line, r.detail) for r in v] for p, v in d.items()}  # noqa: E731
    assert key(plain) == key(res)


def test_sliced_validation_changes_no_verdict(variant_results, monkeypatch, tmp_path):
    """A batch of more rows than suites.VALIDATE_ROWS is validated a slice of rows at a time
    (issue 28: a big run file in bounded memory); the refusals -- rule, first line, detail
    with its row count -- must be those of the whole table, whatever the slice size (here
    slices that cut runs anywhere), Data Docs written."""
    from accelcal.schemas import suites
    res, _ = variant_results
    runs = [read_run(p) for p in sorted(res)]
    key = lambda d: {p: [(r.rule, r.line, r.detail) for r in v] for p, v in d.items()}  # noqa: E731
    for rows in (1000, 2501):
        monkeypatch.setattr(suites, "VALIDATE_ROWS", rows)
        sliced = validate_report(runs, tmp_path / str(rows), "variants")
        assert key(sliced.refusals) == key(res)
        assert (tmp_path / str(rows) / "variants" / "index.html").exists()


def test_configuration_memo_is_off_outside_a_validation():
    """Outside accelcal's own validation GE's property runs as shipped: a new
    configuration object on every access; inside, one per expectation."""
    import great_expectations as gx

    from accelcal.schemas import suites
    suites._memoize_configurations()
    e = gx.expectations.ExpectColumnValuesToNotBeNull(column="output")
    assert e.configuration is not e.configuration
    with suites._configurations_memo():
        assert e.configuration is e.configuration
    assert e.configuration is not e.configuration


def test_each_metadata_rule_checked_in_one_place():
    """The parser owns a key's presence, type, set, time form and axes; the suites own
    plausible ranges.  No rule id is used by both for the metadata, and the meta suites
    hold nothing but range checks."""
    import inspect

    from accelcal.effects import TESTS
    from accelcal.schemas import dropformat, dropspec
    from accelcal.schemas.rules import METADATA_RANGES, _suite_specs

    parser_src = inspect.getsource(dropformat) + inspect.getsource(dropspec)
    parser_rules = set(re.findall(r'"([a-z]+(?:-[a-z0-9]+)+)"', parser_src))
    assert {"missing-key", "bad-value", "bad-axis", "unknown-format", "unknown-test"} <= parser_rules
    for test in TESTS:
        meta = _suite_specs(test)["meta"]
        assert {rule for _, rule, _, _ in meta} == {"metadata-range"}
        assert {kw["column"] for _, _, _, kw in meta} <= set(METADATA_RANGES) | {"ambient_temp_c"}
    assert "metadata-range" not in parser_rules


def test_a_run_made_without_the_parser_is_refused_by_the_parsers_rule(good_runs):
    """A RunFile whose test is not a kind is refused with the parser's own words."""
    import dataclasses

    r = next(iter(good_runs.values()))[0]
    bad = dataclasses.replace(r, meta={**r.meta, "test": "spin"}, data=r.data)
    rep = validate_report([bad])
    (ref,) = rep.refusals[bad.path]
    assert (ref.rule, ref.detail) == (
        "unknown-test", "test 'spin' is not one of tumble, centrifuge, tilt_rotation, sine_centrifuge")


def test_derived_columns_made_a_slice_at_a_time_hold_the_whole_columns(good_runs):
    """The derived columns a big run is checked on are made a slice of rows at a time
    (issue 28); every slice must hold the numbers of the column made whole, computed here
    from the run's own arrays by the rules' definitions (rules.py): the time step, the step
    over the sample period, the non-finite cells, the distance of a rotation from its grid,
    and the distinct positions of each temperature point (a pandas ``nunique``)."""
    import numpy as np
    import pandas as pd

    from accelcal.schemas.derived import RowColumn, _derive
    from accelcal.schemas.dropspec import COLUMNS, INT_COLUMNS, NULLABLE_COLUMNS
    from accelcal.schemas.rules import ANGLE_TOL_DEG

    seen = set()
    for r in (r for runs in good_runs.values() for r in runs):
        d, a, n = _derive(r.test, r), r.arrays, r.n_rows
        t = a["time_s"].astype(float)
        dt = np.r_[np.nan, np.diff(t)]
        period = float(r.meta["sample_period_s"])
        bad = sum((np.isinf(a[c]) if c in NULLABLE_COLUMNS[r.test] else ~np.isfinite(a[c])).astype(int)
                  for c in COLUMNS[r.test] if c != "output" and c not in INT_COLUMNS)
        want = {"d_time_s": dt, "dt_over_period": np.where(dt > 0, dt / period, np.nan),
                "nonfinite_cells": bad}
        if r.test == "tilt_rotation":
            npos, rot = int(r.meta["positions"]), a["rotation_deg"]
            step = 360.0 / npos
            want["rotation_grid_dev_deg"] = np.minimum(np.mod(rot, step), step - np.mod(rot, step))
            sp = a["temp_set_c"]
            seg = np.cumsum(np.r_[False, sp[1:] != sp[:-1]])
            rk = np.round(np.mod(rot, 360.0) / ANGLE_TOL_DEG)
            distinct = pd.Series(rk).groupby(seg).transform("nunique").to_numpy(float)
            want["positions_error"] = np.where(np.r_[True, seg[1:] != seg[:-1]], distinct - npos, np.nan)
        for c, w in want.items():
            col = d[c]
            assert isinstance(col, RowColumn) and len(col) == n, c
            cuts = [0, 1, n // 3, n // 3 + 1, n - 1, n]
            got = np.concatenate([col[lo:hi] for lo, hi in zip(cuts[:-1], cuts[1:])])
            assert np.array_equal(got, w, equal_nan=True), (r.path, c)
            assert np.array_equal(col[:], w, equal_nan=True)
            assert np.array_equal(col[n - 1:n], w[-1:], equal_nan=True) and (col[0] == w[0] or np.isnan(w[0]))
        seen.add(r.test)
    assert "tilt_rotation" in seen and "centrifuge" in seen


def test_one_g_check_takes_pandas_groupby_means(good_runs):
    """The 1 g check's mean turning rate per step (numpy, accelcal.fitting.data.Groups) is
    pandas' groupby mean of each run, bit for bit, so its figure is |omega^2 R / g - 1| of
    those means."""
    import numpy as np
    import pandas as pd

    from accelcal.schemas.derived import _one_g
    from accelcal.schemas.rules import REST_RATE

    runs = [r for rs in good_runs.values() for r in rs if r.test == "centrifuge"]
    assert runs
    for r in runs:
        rate, step = r.arrays["table_rate_rad_s"], r.arrays["step"]
        turning = rate >= REST_RATE
        means = pd.Series(rate[turning]).groupby(step[turning]).mean().to_numpy()
        want = np.min(np.abs(means ** 2 * float(r.meta["arm_radius_m"]) / float(r.meta["g_local_m_s2"]) - 1.0))
        rows, values = _one_g(r.arrays, r.meta, r.n_rows)
        assert rows.tolist() == [int(np.argmax(turning))] and values.tolist() == [want], r.path
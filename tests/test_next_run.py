"""The run that would separate an aliased pair is advice read on demand: the science stores
the pair and the command that answers it; the certificate's "one more run" line is
``accelcal design --separate A,B --max-runs 1``'s first proposal for the same campaign."""
from __future__ import annotations

import html
import re
from importlib import resources
from pathlib import Path

import pytest

DEMO = Path(str(resources.files("accelcal") / "demo_data" / "drop-2026-11-20"))
CAMPAIGN = "SNJ-1-03/2026-11-20"


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    from accelcal.flows.pipeline import run_pipeline
    d = tmp_path_factory.mktemp("nextrun")
    run_pipeline([str(DEMO)], d / "lab.duckdb", engine="local", allow_simulated=True)
    return d / "lab.duckdb"


def _design_first_proposal(capsys, a: str, b: str) -> str:
    from accelcal.cli import main
    assert main(["design", str(DEMO), "--separate", f"{a},{b}", "--max-runs", "1"]) == 0
    out = capsys.readouterr().out.replace("\n       ", " ")
    m = re.search(r"^ 1\. \d+ min: (.+)$", out, re.M)
    assert m, out
    return m.group(1)


def test_the_certificate_names_the_run_accelcal_design_proposes_first(lab, tmp_path, capsys):
    import duckdb

    from accelcal.estimators.joint import ALIASED_PAIR_FLAG, stored_aliased_pairs
    from accelcal.ops.certificate import load_report_data
    from accelcal.ops.report import build_report
    con = duckdb.connect(str(lab), read_only=True)
    stored = [f for (f,) in con.execute(
        "SELECT flag FROM flag_history WHERE result_id IN "
        "(SELECT result_id FROM results_current WHERE campaign = ?) ORDER BY seq",
        [CAMPAIGN]).fetchall()]
    con.close()
    data = load_report_data(lab, CAMPAIGN)
    pairs = stored_aliased_pairs(data["extras"])
    assert ("Kp", "Kpo") in pairs
    assert all(ALIASED_PAIR_FLAG.format(a=a, b=b) in stored for a, b in pairs)
    # the nightly science names the pair and the command, not the run
    assert not [f for f in stored if "one more run would separate them" in f]
    flags = data["flags"]
    page = html.unescape(build_report(lab, CAMPAIGN, tmp_path).read_text())
    for a, b in pairs:
        (line,) = [f for f in flags if f.startswith(f"{a}, {b}: ")]
        run = _design_first_proposal(capsys, a, b)
        assert line == (f"{a}, {b}: one more run would separate them: {run} "
                        f"(accelcal design --separate {a},{b} --max-runs 1)")
        assert line in page


def test_other_flags_pass_through_unchanged(lab):
    """Only the stored pairs' flags gain a run; every other flag reads as stored."""
    from accelcal.ops.certificate import separating_run_flags
    flags = ["K1: no tolerance", "Kp, Kpo: aliased"]
    extras = {"joint": {"aliased_pairs": []}}
    assert separating_run_flags(lab.parent, [], flags, extras) == flags

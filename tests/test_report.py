"""`accelcal report`: self-contained HTML certificate per campaign, rendered by a real
headless chromium (skipped cleanly when chromium is not installed)."""
from __future__ import annotations

import base64
import io
import os
import re
import shutil
import subprocess
import sys

import pytest

from accelcal.ops.report import build_report, report_filename
from accelcal.ops.report_display import display_value

CAMP = "SNJ-1-03/2026-11-20"


@pytest.fixture(scope="module")
def lab(tmp_path_factory, examples):
    from accelcal.flows.pipeline import run_pipeline
    d = tmp_path_factory.mktemp("rep")
    s = run_pipeline([str(examples / "drop-2026-11-20")], d / "lab.duckdb", engine="local")
    return d / "lab.duckdb", s


def test_display_units():
    assert display_value("K2", 3.94e-7, 1.6e-9, "s2/m")[2] == "µg/g²"
    v, U, unit = display_value("K0", 4.029391e-4, 2.3e-7, "m/s2")
    assert unit == "µg" and float(v) == pytest.approx(41.09, abs=0.01) and U == "0.047"
    v, U, unit = display_value("K1", 0.1325631, 2.55e-9, "mA/(m/s2)")
    assert unit == "mA/g" and U.endswith("ppm")
    assert display_value("K1T", 2e-6, 1e-7, "1/degC")[2] == "ppm/°C"


def test_report_contents(lab, tmp_path):
    wh, summary = lab
    path = build_report(wh, CAMP, tmp_path / "out")
    assert path.name == report_filename(CAMP) == "SNJ-1-03_2026-11-20.html"
    html = path.read_text()
    # self-contained: no external resources
    assert not re.search(r"(src|href)\s*=\s*['\"]?(https?:)?//", html)
    assert "<script" not in html
    pngs = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", html)
    assert len(pngs) == 2                                  # radius + residual plots
    for b in pngs:
        assert base64.b64decode(b)[:8] == b"\x89PNG\r\n\x1a\n"
    for text in ("SNJ-1-03", "QA-2000", "LXJ-100", "DH-1", "U (k=2)", "µg/g²", "µg",
                 "Model adequacy", "Alignment analysis", "Lineage", "NOT adequate", "adequate",
                 "residuals of the eq 9 fits (▲ up-sweep, ▼ down-sweep, ● rest; blue + polarity"):
        assert text in html, text
    # every input run with its sha256, and the result id
    def grouped(token):              # long ids are printed in groups of 16, to break between
        return " ".join(token[i:i + 16] for i in range(0, len(token), 16))
    camp = next(c for c in summary["campaigns"] if c["campaign"] == CAMP)
    assert grouped(camp["current_result_id"]) in html
    for d in summary["drops"]:
        assert d["files"] == 11
    import duckdb
    con = duckdb.connect(str(wh), read_only=True)
    shas = [r[0] for r in con.execute("SELECT sha256 FROM lineage").fetchall()]
    con.close()
    assert len(shas) == 11 and all(grouped(s) in html for s in shas)
    # K2 of the centrifuge shown in µg/g² with its U: 3.84 +- 0.031
    assert re.search(r"<td>K2</td><td class=\"num\">3\.84\d*</td><td class=\"num\">0\.03\d*</td>",
                     html)


def test_report_of_superseded_result_says_so(lab, tmp_path):
    wh, summary = lab
    from accelcal.results import CampaignResult, CoefficientResult
    from accelcal.warehouse import Warehouse
    w = Warehouse(wh)
    old = next(c for c in summary["campaigns"] if c["campaign"] == CAMP)["current_result_id"]
    res = CampaignResult(campaign=CAMP, unit_serial="SNJ-1-03", unit_model="QA-2000",
                         tests=["centrifuge"], rig_ids=["LXJ-100"], input_sha256=[],
                         coefficients=[CoefficientResult("K2", 4e-7, 2e-9, "s2/m", "x", "LXJ-100")])
    w.store_result(res, result_id="f" * 64, inputs=w.campaign_inputs(CAMP), code_version="t",
                   parameters={"changed": True}, flow_run_id="test")
    try:
        html = build_report(wh, CAMP, tmp_path, result_id=old).read_text()
        assert "SUPERSEDED" in html and "f" * 64 in html
        assert "SUPERSEDED" not in build_report(wh, CAMP, tmp_path / "cur").read_text()
    finally:   # make the original current again (append-only: a new activation)
        w.store_result(res, result_id=old, inputs=w.campaign_inputs(CAMP), code_version="t",
                       parameters={}, flow_run_id="test")


def test_cli_report_unknown_campaign_is_a_clear_error(lab, tmp_path):
    wh, _ = lab
    p = subprocess.run([sys.executable, "-c",
                        "import sys; from accelcal.cli import main; sys.exit(main(sys.argv[1:]))",
                        "report", "NOPE/1", "--out", str(tmp_path), "--warehouse", str(wh)],
                       capture_output=True, text=True, timeout=60)
    if "invalid choice: 'report'" in p.stderr:
        pytest.skip("accelcal.ops.cli not registered in accelcal/cli.py yet (lead applies hook)")
    assert p.returncode == 1
    assert "no result for campaign 'NOPE/1'" in p.stderr and CAMP in p.stderr


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        p = shutil.which(name)
        if p:
            return p
    return None


@pytest.mark.skipif(_chromium() is None, reason="chromium not installed "
                    "(apt-get install -y chromium)")
def test_report_renders_in_headless_chromium(lab, tmp_path):
    wh, _ = lab
    path = build_report(wh, CAMP, tmp_path / "out")
    shot = tmp_path / "report.png"
    cmd = [_chromium(), "--headless", "--no-sandbox", "--disable-gpu",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--no-first-run", "--hide-scrollbars", f"--user-data-dir={tmp_path / 'chrome'}",
           "--window-size=1200,2600", f"--screenshot={shot}", path.as_uri()]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=90,
                       env={**os.environ, "HOME": str(tmp_path)})
    assert p.returncode == 0, p.stderr[-2000:]
    assert shot.exists() and shot.stat().st_size > 20_000
    from PIL import Image
    im = Image.open(io.BytesIO(shot.read_bytes())).convert("RGB")
    assert im.size == (1200, 2600)
    # not blank: text and tables give many colours; the header band is dark blue text on white
    colours = im.getcolors(maxcolors=1 << 20)
    assert colours is not None and len(colours) > 200
    keep = os.environ.get("ACCELCAL_KEEP_SCREENSHOT")
    if keep:
        shutil.copy(shot, keep)


def _cells(html: str) -> list[list[str]]:
    """Table rows of an HTML page as lists of cell texts."""
    import html as h
    rows = []
    for tr in re.findall(r"<tr[^>]*>(.*?)</tr>", html, re.S):
        cells = re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", tr, re.S)
        rows.append([h.unescape(re.sub(r"<[^>]+>", "", c)).strip() for c in cells])
    return rows


def _decimals(s: str) -> int:
    m = re.fullmatch(r"-?\d+(?:\.(\d+))?(?:e-?\d+)?", s)
    assert m, s
    return len(m.group(1) or "")


def _sig(s: str) -> int:
    digits = re.sub(r"e-?\d+$", "", s).replace("-", "").replace(".", "").lstrip("0")
    return len(digits)


def test_certificate_numbers_are_rounded_as_it_promises(lab, tmp_path):
    """GUM 7.2.6 as the certificate states it (issue 27): U to at most two significant
    digits, the value to U's last digit; budgets' uc and U likewise, in the results' unit;
    no number anywhere with float noise (12 or more significant digits)."""
    wh, _ = lab
    html = build_report(wh, CAMP, tmp_path / "out").read_text()
    text = re.sub(r"<[^>]+>", " ", re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", html))
    for num in re.findall(r"(?<![\w.])-?\d+\.\d+(?:e-?\d+)?", text):
        assert _sig(num) < 12, num
    head = None
    checked = 0
    for row in _cells(html):
        if row[:3] == ["coefficient", "value", "U (k=2)"]:
            head = row
            continue
        if head and len(row) == len(head) and row[1] not in ("—", "") and row[2] not in ("—", ""):
            U = row[2]
            assert _sig(U.replace(" ppm", "")) <= 2, row
            if not U.endswith("ppm"):               # K1: U relative, value to its absolute digit
                assert _decimals(row[1]) == _decimals(U), row
            checked += 1
        if row and row[0].startswith(("combined standard uncertainty", "expanded uncertainty U")):
            assert _sig(row[4]) <= 2, row
    assert checked >= 10
    assert "0.0002908882086657216" not in html and "budgets in SI units" not in html


def test_a_monte_carlo_fail_says_what_it_means_for_U():
    """JCGM 101 §8 (issue 27): a FAIL is said in words. A budget dominated by one uniform
    term: its 95 % interval is +-0.95*sqrt(3) u = +-1.645 u, narrower than the normal +-1.96 u,
    so U is conservative; a heavier-tailed output would make U too small."""
    from accelcal.results import monte_carlo_checks

    def mc_meaning(m):          # the stored record as the report reads it
        return monte_carlo_checks({"mc_check": {"K0": m}})[0].meaning()

    flat = {"validated": False, "gum_u": 1.0, "mc_low": -0.95 * 3 ** 0.5, "mc_high": 0.95 * 3 ** 0.5}
    assert mc_meaning(flat).startswith("U is conservative")
    heavy = {"validated": False, "gum_u": 1.0, "mc_low": -2.3, "mc_high": 2.3}
    assert mc_meaning(heavy).startswith("U covers less than 95 %")
    assert mc_meaning({**flat, "validated": True}) == ""


def test_a_stored_monte_carlo_fail_reaches_the_flags_and_the_table():
    """The report reads the JCGM 101 checks as typed records (issue 23): an adopted
    coefficient whose stored check fails is flagged with what it means, and its table row
    says FAIL; a check of a paper method's value is listed but not flagged."""
    from accelcal.ops.report_sections import _sec_flags, _sec_mc
    from accelcal.results import monte_carlo_checks
    fail = {"method": "joint_ml", "rig_id": "", "coefficient": "K0", "validated": False, "gum_u": 1e-5,
            "mc_u": 1e-5, "mc_low": -2.3e-5, "mc_high": 2.3e-5, "delta": 1e-7}
    ok = {**fail, "method": "tumble_lm", "rig_id": "DH-1", "validated": True}
    d = {"extras": {"mc_check": {"joint_ml::K0": fail, "tumble_lm:DH-1:K0": ok, "note": "not a check"}},
         "coefficients": [{"name": "K0", "unit": "m/s2", "method": "joint_ml", "rig_id": "", "adopted": True},
                          {"name": "K0", "unit": "m/s2", "method": "tumble_lm", "rig_id": "DH-1"}],
         "flags": [], "radii": [], "result": {"completeness": "complete"}}
    assert [m.key for m in monte_carlo_checks(d["extras"])] == ["joint_ml::K0", "tumble_lm:DH-1:K0"]
    flags = _sec_flags(d)
    assert flags.count("Monte Carlo check FAIL") == 1 and "U covers less than 95 %" in flags
    table = _sec_mc(d)
    assert "1 of 2 budgets pass" in table and table.count(">FAIL<") == 1


def test_cross_checks_beyond_their_combined_U_are_flagged(lab, tmp_path):
    """Issue 27: a cross-check more than its combined U from the adopted value (|En| > 1,
    ISO 13528 9.7) is flagged; En computed here from the stored values."""
    import duckdb
    wh, _ = lab
    con = duckdb.connect(str(wh), read_only=True)
    rows = con.execute("SELECT name, method, rig_id, value, std_uncertainty, coverage_factor, adopted "
                       "FROM coefficients WHERE campaign = ? AND name = 'K0'", [CAMP]).fetchall()
    con.close()
    adopted = next(r for r in rows if r[6])
    html = build_report(wh, CAMP, tmp_path / "out").read_text()
    flags = re.findall(r"<div class='flag'>([^<]*)</div>", html)
    for name, method, rig, v, u, k, ad in rows:
        if ad:
            continue
        en = (v - adopted[3]) / ((k * u) ** 2 + (adopted[5] * adopted[4]) ** 2) ** 0.5
        said = [f for f in flags if f.startswith(f"cross-check K0 by {method} ({rig})")]
        assert bool(said) == (abs(en) > 1), (method, en, said)
        if said:
            assert f"En = {en:.2f}" in said[0]

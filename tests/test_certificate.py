"""The certificate holds what ISO/IEC 17025 7.8.2-7.8.4 asks (issue 11), for the three sample
campaigns (centrifuge + tumble, thermal, sine), in the HTML and in the PDF the same headless
chromium prints (skipped without chromium; the PDF text check also needs pdftotext)."""
from __future__ import annotations

import math
import re
import shutil
import subprocess
from decimal import Decimal

import pytest

from accelcal import cli
from accelcal.ops.report import build_report, report_filename

from conftest import RIG_INPUTS_TOML, copy_lab

CAMPS = {"centrifuge": "SNJ-1-03/2026-11-20", "thermal": "HUST-M-07/2026-11-18",
         "sine": "QA-5512/2026-11-19"}
LAB = {"name": "Inertial Metrology Lab of Example", "address": "12 Example Road, Wuhan",
       "approver": "Dr A. Approver"}
CONFIG = f"""
[lab]
name = "{LAB['name']}"
address = "{LAB['address']}"
location = "Centrifuge hall 3"
[certificate]
number_prefix = "IML"
approver = "{LAB['approver']}"
approver_role = "Head of laboratory"
customer = "Example Customer Ltd"
[traceability]
statement = "Traceable to the SI through the national standards of length, time and angle."
[traceability.rigs]
"LXJ-100" = "arm radius cert. R-1"
"DH-1" = "dividing head angle cert. A-7"
"TT-1" = "tilt table angle cert. T-2; chamber thermometer cert. C-9"
"DC-1" = "disc centrifuge radius cert. R-4"
""" + RIG_INPUTS_TOML
#: 7.8.2.1 / 7.8.4 elements, as the certificate words them (in every certificate).
ELEMENTS = ["Calibration Certificate", "Certificate No. IML-", LAB["name"], LAB["address"],
            "Centrifuge hall 3", "Example Customer Ltd", LAB["approver"], "Head of laboratory",
            "Item calibrated", "Serial number", "Method", "Calibration performed", "Date of issue",
            "Environmental conditions", "instrument temperature", "Traceability",
            "Traceable to the SI", "U (k=2)", "coverage probability", "approximately 95 %",
            "relate only to the item", "Uncertainty budgets", "combined standard uncertainty",
            "expanded uncertainty U, k = 2", "Monte Carlo", "Model adequacy",
            "Other methods", "Lineage", "End of certificate"]


@pytest.fixture(scope="module")
def lab(tmp_path_factory, certified_lab):
    wh = copy_lab(certified_lab, tmp_path_factory.mktemp("cert") / "lab")
    (wh.parent / "accelcal.toml").write_text(CONFIG)          # found beside the warehouse
    return wh


@pytest.fixture(scope="module")
def htmls(lab, tmp_path_factory):
    out = tmp_path_factory.mktemp("html")
    return {k: build_report(lab, c, out).read_text() for k, c in CAMPS.items()}


def _sections(html: str) -> tuple[list[int], list[str]]:
    heads = re.findall(r"<h2>([^<]*)</h2>", html)
    nums = [int(m.group(1)) for h in heads if (m := re.match(r"(\d+) ", h))]
    annex = [m.group(1) for h in heads if (m := re.match(r"Annex ([A-Z]) ", h))]
    return nums, annex


@pytest.mark.parametrize("kind", sorted(CAMPS))
def test_html_has_every_element_and_no_section_gap(htmls, kind):
    html = htmls[kind]
    for e in ELEMENTS:
        assert e in html, (kind, e)
    assert "DRAFT" not in html and "placeholder'>[laboratory" not in html
    nums, annex = _sections(html)
    assert nums == list(range(1, len(nums) + 1)) and len(nums) >= 9, nums
    assert annex == [chr(ord("A") + k) for k in range(len(annex))] and annex
    assert len(re.findall(r"data:image/png;base64,", html)) >= 1, kind   # residual plot(s)
    assert not re.search(r"(src|href)\s*=\s*['\"]?(https?:)?//", html) and "<script" not in html


def test_thermal_certificate_dates_numbers_and_no_centrifuge_parameters(htmls):
    html = htmls["thermal"]
    # the data's dates: started_at to the last reading (17.5 h later), not start -> start
    assert "2026-11-20 00:00 (UTC+08:00) to 2026-11-20 17:29 (UTC+08:00)" in html
    assert "The campaign label names 2026-11-18" in html
    # the adopted value (joint fit, reading by reading) and the paper method in the annex;
    # U now holds the stated temperature reading (0.05 degC at each of the set points 20,
    # 25, ..., 40 degC): u = |K1T| u_T / sqrt(sum (T - Tbar)^2) = 120 ppm * 0.05 / sqrt(250)
    # beside the readings' 0.0013 (joint) and 0.015 (paper) ppm/degC, derived here
    for u_a in (0.0013, 0.015):
        U = 2 * math.hypot(120 * 0.05 / math.sqrt(250), u_a)
        assert f"{U:.2f}" == "0.76"
    assert re.search(r"<td>K1T</td><td class=\"num\">-120\.00</td><td class=\"num\">0\.76</td>", html)
    assert re.search(r"<td>K1T</td><td class=\"num\">-119\.99</td><td class=\"num\">0\.76</td>", html)
    for word in ("radius", "mount_angle_tolerance", "Alignment", "centrifuge runs"):
        assert word not in html, word
    assert "20.15 / 30.30 / 40.46" in html                  # instrument temperature from temp_c
    assert "readings: joint fit through the forward model" in html     # itemised budget


def test_sine_certificate_has_its_own_adequacy(htmls):
    html = htmls["sine"]
    assert "no centrifuge runs" not in html
    assert "tool-error terms (joint F test)" in html
    assert "Residual rms of the joint sine fit per run" in html


def test_centrifuge_budget_and_monte_carlo(htmls):
    html = htmls["centrifuge"]
    assert html.count("combined standard uncertainty u<sub>c</sub>") == html.count(
        "expanded uncertainty U, k = 2") >= 10
    assert "readings: joint fit through the forward model" in html      # itemised budget rows
    assert "mount angle of LXJ-100 IA-PA 0/180 (type B" in html
    # every budget's JCGM 101 check is an exact convolution of its linear budget (no sampling
    # noise): on this campaign each one passes, the paper method's eq 9 Kip included (its
    # 50 000-draw check used to FAIL on sampling noise alone)
    m = re.search(r"<b>(\d+) of (\d+) budgets pass</b>", html)
    assert m and int(m.group(2)) >= 10 and m.group(1) == m.group(2)
    assert "PASS" in html and "centrifuge_eq9:LXJ-100:Kip" in html


def test_missing_config_gives_marked_placeholders(tmp_path, lab, monkeypatch, examples):
    import shutil as sh
    wh = tmp_path / "lab.duckdb"
    sh.copy(lab, wh)
    sh.copytree(lab.parent / "lab-extras", tmp_path / "lab-extras")   # the results' extras
    monkeypatch.chdir(tmp_path)
    html = build_report(wh, CAMPS["thermal"], tmp_path / "out").read_text()
    assert "DRAFT — not valid as a certificate" in html
    assert "[laboratory name: set [lab] name in accelcal.toml]" in html
    assert LAB["name"] not in html
    # ./accelcal.toml is found before the one beside the warehouse; --config before both
    (tmp_path / "accelcal.toml").write_text('[lab]\nname = "Here Lab"\n')
    assert "Here Lab" in build_report(wh, CAMPS["thermal"], tmp_path / "o2").read_text()
    other = tmp_path / "other.toml"
    other.write_text('[lab]\nname = "Given Lab"\n')
    assert "Given Lab" in build_report(wh, CAMPS["thermal"], tmp_path / "o3",
                                       config=other).read_text()


def test_report_by_short_result_id_and_safe_names(lab, tmp_path, capsys):
    import duckdb
    with duckdb.connect(str(lab), read_only=True) as con:
        rid = con.execute("SELECT result_id FROM results_current WHERE campaign = ?",
                          [CAMPS["sine"]]).fetchall()[0][0]
    assert cli.main(["report", "--result", rid[:12], "--out", str(tmp_path),
                     "--warehouse", str(lab)]) == 0
    assert capsys.readouterr().out.strip().endswith("QA-5512_2026-11-19.html")
    assert cli.main(["report", CAMPS["thermal"], "--result", rid[:12], "--out", str(tmp_path),
                     "--warehouse", str(lab)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a result of campaign 'QA-5512/2026-11-19'" in err[0]
    names = {report_filename(c) for c in ("../../x", "..\\..\\x", "x", "_x", "a/b", "a_b")}
    assert len(names) == 6
    for n in names:
        assert "/" not in n and "\\" not in n and not n.startswith(".")


def _chromium():
    from accelcal.ops.report import find_chromium
    return find_chromium()


@pytest.mark.skipif(_chromium() is None, reason="chromium not installed (apt-get install chromium)")
@pytest.mark.parametrize("kind", sorted(CAMPS))
def test_pdf_has_every_element_page_numbers_and_no_gap(lab, tmp_path, kind):
    html_path = build_report(lab, CAMPS[kind], tmp_path, pdf=True)
    pdf = html_path.with_suffix(".pdf")
    raw = pdf.read_bytes()
    assert raw.startswith(b"%PDF")
    n_pages = len(re.findall(rb"/Type\s*/Page[^s]", raw))
    assert n_pages >= 2
    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext not installed (poppler-utils): PDF text not checked")
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True).stdout
    pages = text.split("\f")
    pages = [p for p in pages if p.strip()]
    assert len(pages) == n_pages
    number = re.search(r"Certificate No\. (IML-[0-9A-F]{12})", text).group(1)
    for i, page in enumerate(pages, start=1):
        assert f"Page {i} of {n_pages}" in page, (kind, i)
        assert number in page and LAB["name"] in page, (kind, i)
    raw_text = subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True,
                              check=True).stdout            # reading order: table cells flow
    flat = re.sub(r"\s+", " ", raw_text)
    for e in ELEMENTS:
        assert re.sub(r"\s+", " ", e) in flat, (kind, e)
    nums = [int(n) for n in re.findall(r"(?m)^\s*(\d{1,2}) [A-Z][a-z]", text)]
    heads = sorted(set(nums))
    assert heads == list(range(1, len(heads) + 1)) and len(heads) >= 9, heads


@pytest.mark.skipif(_chromium() is None or shutil.which("pdftotext") is None,
                    reason="chromium and pdftotext (poppler-utils) needed")
def test_a_draft_says_draft_on_every_page_and_shows_no_certificate_number(lab, tmp_path):
    """With only the customer missing: every printed page says DRAFT in its header and its
    footer, and the final number (prefix + the 12 hex of the result id) is on none."""
    from accelcal.ops.certificate import certificate_number, load_report_data
    cfg = tmp_path / "no-customer.toml"
    cfg.write_text(CONFIG.replace('customer = "Example Customer Ltd"\n', ""))
    pdf = build_report(lab, CAMPS["centrifuge"], tmp_path, pdf=True, config=cfg).with_suffix(".pdf")
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True).stdout
    pages = [p for p in text.split("\f") if p.strip()]
    final = certificate_number(load_report_data(lab, CAMPS["centrifuge"])["result_id"], "IML")
    assert len(pages) >= 2
    for i, page in enumerate(pages, start=1):
        lines = [x for x in page.splitlines() if x.strip()]
        assert "DRAFT" in lines[0] and "DRAFT" in lines[-1], (i, lines[0], lines[-1])
        assert final not in page and "Certificate No." not in page, i


def test_a_rig_without_traceability_keeps_the_certificate_draft(lab, tmp_path):
    """Issue 27: with the README's one-rig accelcal.toml the certificate was final while
    DH-1 showed the traceability placeholder; any placeholder left means DRAFT."""
    cfg = tmp_path / "one-rig.toml"
    cfg.write_text(CONFIG.split('"DH-1"')[0])
    html = build_report(lab, CAMPS["centrifuge"], tmp_path / "out", config=cfg).read_text()
    draft = re.search(r"DRAFT — not valid as a certificate: ([^<]*)", html)
    assert draft and "reference standards of this rig" in draft.group(1)


# ---------------------------------------------------------------- every number as rounded as it says

TUMBLE = "IMUCAL-EXAMPLE-X/2021-01-03"      # a real hand-held tumble (../shared/real)


def _place(tok: str) -> Decimal:
    """Decimal place of the last digit of a printed number ('0.059e-4' -> 1e-7); trailing
    zeros of an integer are not significant ('24000' -> 1000)."""
    m = re.fullmatch(r"(-?)(\d+)(?:\.(\d+))?(?:e(-?\d+))?", tok)
    assert m, tok
    intp, frac, exp = m.group(2), m.group(3) or "", int(m.group(4) or 0)
    if frac:
        return Decimal(1).scaleb(-len(frac) + exp)
    stripped = intp.rstrip("0") or "0"
    return Decimal(1).scaleb(len(intp) - len(stripped) + exp)


def _sig(tok: str) -> int:
    digits = re.sub(r"e-?\d+$", "", tok).lstrip("-").replace(".", "").lstrip("0")
    if "." not in tok:
        digits = digits.rstrip("0")
    return len(digits)


def _value(tok: str) -> Decimal:
    return Decimal(tok)


def _check_pair(value: str, U: str, where: str) -> None:
    """GUM 7.2.6: U with at most two significant digits, the value to U's last digit."""
    assert _sig(U) <= 2, (where, value, U)
    if _value(value) != 0:
        assert _place(value) == _place(U), (where, value, U)


@pytest.fixture(scope="module")
def pdf_texts(lab, tmp_path_factory, examples):
    from accelcal.flows.pipeline import run_pipeline
    if _chromium() is None or shutil.which("pdftotext") is None:
        pytest.skip("chromium and pdftotext (poppler-utils) are needed to read the PDFs")
    run_pipeline([str(examples.parent / "real" / "imucal-ferraris")], lab, engine="local")
    out = tmp_path_factory.mktemp("pdfnum")
    texts = {}
    for kind, camp in {**CAMPS, "tumble": TUMBLE}.items():
        pdf = build_report(lab, camp, out / kind, pdf=True).with_suffix(".pdf")
        texts[kind] = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                                     text=True, check=True).stdout
    return texts


NUM = r"-?\d+(?:\.\d+)?(?:e-?\d+)?"


@pytest.mark.parametrize("kind", sorted({*CAMPS, "tumble"}))
def test_every_printed_value_is_rounded_to_its_uncertainty(pdf_texts, kind):
    """Issue 27: every value in the results, cross-check and budget tables of the PDF
    paired with its U (or u) and checked by the rule the certificate states; a K1 with a
    relative U in ppm against its absolute U. No number carries float noise."""
    text = pdf_texts[kind]
    pairs = 0
    # results table and Annex A: name, value, U [ppm], k, coverage
    for m in re.finditer(rf"(?m)^\s*((?:K\w*|theta0)\S*)\s+({NUM})\s+({NUM})( ppm)?\s+({NUM})\s+≈ 95 %", text):
        name, value, U, ppm = m.group(1), m.group(2), m.group(3), m.group(4)
        assert _sig(U) <= 2, (kind, m.group(0))
        if ppm:
            absU = abs(_value(value)) * _value(U) * Decimal("1e-6")
            lead = Decimal(1).scaleb(absU.adjusted() - 1)      # two significant digits of U
            assert _place(value) <= lead * 10 and _place(value) >= lead / 10, (kind, m.group(0))
        else:
            _check_pair(value, U, f"{kind} {name}")
        pairs += 1
    # budget lines: quantity ... value u sensitivity contribution A|B
    for m in re.finditer(rf"(?m)\s({NUM})\s+({NUM})\s+{NUM}\s+{NUM}\s+[AB]\s+(?:normal|uniform|triangular|U-shaped|rectangular)",
                         text):
        _check_pair(m.group(1), m.group(2), f"{kind} budget")
        pairs += 1
    # Monte Carlo intervals: [lo, hi] to the digit of delta
    for m in re.finditer(rf"\[({NUM}), ({NUM})\]\s+({NUM})\s", text):
        lo, hi, delta = m.groups()
        assert _place(lo) == _place(hi) <= _place(delta), (kind, m.group(0))
        pairs += 1
    assert pairs >= 8, (kind, pairs)
    for tok in re.findall(r"(?<![\w.])-?\d+\.\d+(?:e-?\d+)?(?![\w.])", text):
        assert _sig(tok) < 12, (kind, tok)

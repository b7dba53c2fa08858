"""Calibration certificate: one self-contained HTML page (and, with ``pdf=True``, the PDF
the same headless chromium prints) per campaign result.

What ISO/IEC 17025:2017 7.8.2 and 7.8.4 ask of a calibration certificate, and where it is:

===================================================  ===========================================
title, unique certificate number on every page,      header; ``@page`` margin boxes (PDF)
page x of y
lab name and address, location of the activities    section "Certificate", from accelcal.toml
customer                                             accelcal.toml or ``--customer``
method used, deviations                              "Method", "Flags and deviations"
item: description, identification                    "Item calibrated"
dates of the calibration, date of issue              "Dates and conditions" (run started_at and
                                                     their last reading), issue date
environmental conditions                             "Dates and conditions" (temperatures read
                                                     from the data)
results with units, U, k, coverage probability       "Results" (adopted values; GUM 7.2.6)
traceability statement                               "Traceability"
person authorising                                   "Certificate" (approver from accelcal.toml)
results relate only to the item                      statement under the results
===================================================  ===========================================

plus, per adopted coefficient, its uncertainty budget with the combined standard and the
expanded uncertainty, the Monte Carlo check (JCGM 101) as pass/fail, the adequacy of
every fit and the residual plots, and annexes with the other methods' values and the
lineage (every input run's sha256).  Missing lab facts are printed as marked
placeholders with a DRAFT banner; nothing is invented.  Sections are numbered in the
order they appear, so there are no gaps.

The certificate is three modules: :mod:`.certificate` reads a result from the warehouse
(and holds what the DCC shares), :mod:`.report_sections` writes each section
(:mod:`.report_display` prints the numbers), and this one orders them, renders the page
and prints the PDF.

Nothing is fetched from the network: no scripts, no external CSS or fonts, plots are
inline PNGs.  The warehouse is only read (under its writer lock, so a running pipeline
is waited for, never observed half-way).
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import html
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from .certificate import (ReportError, _read, document_number, load_report_data, missing_facts,
                          rig_input_sources)
from .report_display import PLACEHOLDER_CLASS, _e, _ph
from .report_sections import (_CSS, _Doc, _annex_lineage, _annex_other, _grouped, _lineage_close, _page_css,
                              _sec_adequacy, _sec_alignment, _sec_budgets, _sec_certificate, _sec_dates,
                              _sec_flags, _sec_item, _sec_mc, _sec_method, _sec_radius, _sec_results,
                              _sec_traceability)


def render_html(d: dict[str, Any], plots: bool = True, config=None,
                customer: str | None = None, issued: str | None = None,
                draft: list[str] | None = None) -> str:
    """The certificate page.  A DRAFT (any fact of :func:`.certificate.missing_facts`
    missing, or ``draft`` naming more) says DRAFT in every page's header and footer and
    carries no certificate number (:func:`.certificate.document_number`)."""
    from ..config import LabConfig
    cfg = config or LabConfig()
    r = d["result"]
    camp = d["campaign"]
    missing = list(dict.fromkeys(missing_facts(d, cfg, customer) + list(draft or [])))
    d = {**d, "rig_sources": rig_input_sources(d, cfg)}
    number = document_number(d["result_id"], cfg.number_prefix, bool(missing))
    issued = issued or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d")
    tests = set(d.get("tests") or [])
    doc = _Doc()
    doc.section("Certificate", _sec_certificate(d, cfg, number, issued, customer))
    doc.section("Item calibrated", _sec_item(d))
    doc.section("Method", _sec_method(d))
    doc.section("Dates and environmental conditions", _sec_dates(d, issued))
    doc.section("Traceability", _sec_traceability(d, cfg))
    doc.section("Results: calibrated coefficients", _sec_results(d, plots))
    doc.section("Uncertainty budgets", _sec_budgets(d))
    doc.section("Monte Carlo check of the uncertainty (JCGM 101)", _sec_mc(d))
    doc.section("Model adequacy and residuals", _sec_adequacy(d, plots))
    if tests & {"centrifuge", "sine_centrifuge"} and d["radii"]:
        doc.section("Test radius", _sec_radius(d, plots))
    if tests & {"centrifuge"} and d["alignment"]:
        doc.section("Alignment analysis", _sec_alignment(d))
    doc.section("Flags and deviations from the method", _sec_flags(d))
    if d.get("due_statement"):  # accelcal.ops.due.certificate_due_statement
        doc.section("Recalibration", f"<p>{_e(d['due_statement'])}</p>")
    doc.annex("Other methods (cross-checks)", _annex_other(d))
    doc.annex("Lineage", _annex_lineage(d))

    banners = []
    if not d["is_current"]:
        cur = d["current_result_id"]
        was = any(a["result_id"] == d["result_id"] for a in d["activations"])
        banners.append("<div class='banner'>This result is "
                       + ("SUPERSEDED" if was else "NOT CURRENT (it was never made current)")
                       + (f"; the current result of the campaign is <span class='mono'>{_e(cur)}"
                          f"</span>" if cur else "; the campaign has no current result") + ".</div>")
    if r.get("simulated"):
        banners.append("<div class='banner'>SIMULATED DATA — NOT A CALIBRATION. This result was "
                       "computed from files made by accelcal simulate.</div>")
    if r.get("completeness") == "incomplete":
        banners.append("<div class='banner'>INCOMPLETE CAMPAIGN — not a calibration: "
                       + _e("; ".join(d.get("completeness_reasons") or [])) + "</div>")
    if d.get("excluded"):
        x = d["excluded"]
        banners.append(f"<div class='banner'>EXCLUDED by {_e(x.get('acted_by'))} on "
                       f"{_e(x.get('acted_at'))}: {_e(x.get('why'))}</div>")
    body = doc.html()
    # DRAFT whenever any placeholder remains for anything the certificate uses (a rig's
    # traceability, the customer, ...), not only the [lab] keys config.missing knows
    placeholders = [html.unescape(x) for x in
                    re.findall(rf"<span class='{PLACEHOLDER_CLASS}'>\[(.*?)\]</span>", body)]
    more = [x.split(":", 1)[0] for x in placeholders
            if x.split(":", 1)[0] not in " ".join(missing)]
    if more and not missing:    # a placeholder the facts above do not name: DRAFT all the same
        return render_html(d, plots, cfg, customer, issued, more)
    missing += more
    if missing:
        banners.append("<div class='draft'>DRAFT — not valid as a certificate: "
                       + _e(", ".join(dict.fromkeys(missing))) + " not configured "
                       "(accelcal.toml); the marked placeholders show where. A draft carries no "
                       "certificate number and is never signed.</div>")
    page = _page_css(cfg.name or "[laboratory not configured]", number, bool(missing))
    head = (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{'DRAFT c' if missing else 'C'}alibration certificate {_e(number)} — {_e(camp)}</title>"
            f"<style>{page}{_CSS}</style></head><body>")
    title = (f"<h1>{'DRAFT — ' if missing else ''}Calibration Certificate</h1>"
             + (f"<div class='certno'>DRAFT (no certificate number; reference {_e(number)})</div>"
                if missing else f"<div class='certno'>No. {_e(number)}</div>")
             + f"<div class='sub'>{_e(r.get('unit_model'))} serial {_e(r.get('unit_serial'))} · "
             f"campaign {_e(camp)} · result <span class='mono'>{_e(_grouped(d['result_id']))}</span></div>")
    sign = ("<div class='keep'>" + _lineage_close(d) + "<div class='sign'>"
            + (_e(cfg.approver) if cfg.approver else _ph("approver not configured")) + "</div>"
            "<p class='note'>Signature of the person authorising this certificate.</p>")
    foot = (f"<footer>{'DRAFT, not a certificate: ' + _e(number) if missing else 'Certificate No. ' + _e(number)}"
            f" · issued {_e(issued)} by accelcal "
            f"{_e(r.get('code_version'))} from the warehouse; self-contained (no external "
            f"resources). End of certificate.</footer></div></body></html>")
    return head + title + "".join(banners) + body + sign + foot


# ------------------------------------------------------------------- output --

def report_filename(campaign: str) -> str:
    """A file name for a campaign's report that is safe and one-to-one: labels made of
    letters, digits, '.', '-' and '/' keep their spelling with '/' as '_'; any other
    label (with '_', '\\\\', '..', spaces, ...) gets a sanitised name plus '~' and a hash of
    the exact label, so '../../x' and '..\\\\..\\\\x' never overwrite each other."""
    plain = (re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9.\-/]*", campaign or "") is not None
             and ".." not in campaign and "//" not in campaign and not campaign.endswith("/")
             and len(campaign) <= 150)
    if plain:
        return campaign.replace("/", "_") + ".html"
    safe = re.sub(r"[^A-Za-z0-9.-]+", "_", campaign or "").strip("._")[:80] or "campaign"
    return f"{safe}~{hashlib.sha256((campaign or '').encode('utf-8')).hexdigest()[:16]}.html"


def find_chromium() -> str | None:
    env = os.environ.get("ACCELCAL_CHROMIUM")
    if env:
        return env
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        p = shutil.which(name)
        if p:
            return p
    return None


def render_pdf(html_path: Path, pdf_path: Path, timeout: float = 180.0) -> Path:
    """Print the HTML to PDF with headless chromium (page size and page numbers from the
    page's @page rules; chromium's own header and footer off)."""
    exe = find_chromium()
    if exe is None:
        raise ReportError("--pdf needs chromium (Debian: apt-get install chromium; or set "
                          "ACCELCAL_CHROMIUM to a Chrome/Chromium executable)")
    with tempfile.TemporaryDirectory(prefix="accelcal-chromium-") as prof:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={prof}", "--no-pdf-header-footer",
               f"--print-to-pdf={pdf_path}", Path(html_path).resolve().as_uri()]
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                               env={**os.environ, "HOME": prof})
        except subprocess.TimeoutExpired:
            raise ReportError(f"chromium did not print {html_path} within {timeout:g} s") from None
    if p.returncode != 0 or not Path(pdf_path).is_file():
        last = (p.stderr.strip().splitlines() or ["no output"])[-1]
        raise ReportError(f"chromium could not print {html_path}: {last}")
    return Path(pdf_path)


def build_report(warehouse: str | Path, campaign: str | None, out_dir: str | Path,
                 result_id: str | None = None, lock_timeout: float = 60.0,
                 config: str | Path | None = None, pdf: bool = False,
                 customer: str | None = None, dcc: bool = False, sign: bool | None = None) -> Path:
    """Write the certificate of a campaign's current result (or of ``result_id``, a unique
    prefix); returns the HTML path (the PDF, with ``pdf``, and the DCC XML, with ``dcc``
    (:func:`accelcal.ops.dcc.write_dcc`), are beside it)."""
    from ..config import ConfigError, lab_config
    try:
        cfg = lab_config(config, warehouse)
    except ConfigError as e:
        raise ReportError(str(e)) from None
    d = load_report_data(warehouse, campaign, result_id=result_id, lock_timeout=lock_timeout)
    from .due import DueError, certificate_due_statement
    try:  # the due-date sentence, only with [certificate] state_due_date = true
        d["due_statement"] = certificate_due_statement(warehouse, d["result"]["unit_serial"],
                                                       d["campaign"], config)
    except (ConfigError, DueError) as e:
        raise ReportError(str(e)) from None
    text = render_html(d, config=cfg, customer=customer)
    out = Path(out_dir).expanduser()
    name = report_filename(d["campaign"])
    if not d["is_current"]:
        name = name[:-5] + f"@{d['result_id'][:12]}.html"
    try:
        out.mkdir(parents=True, exist_ok=True)
        path = out / name
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise ReportError(f"cannot write report to {out}: {e.strerror}") from None
    if pdf:
        render_pdf(path, path.with_suffix(".pdf"))
    if sign and not dcc:
        raise ReportError("--sign signs the DCC: give --dcc too")
    if dcc:
        from .dcc import write_dcc
        write_dcc(d, cfg, path, pdf=pdf, customer=customer, sign=sign)
    return path


def list_campaigns(warehouse: str | Path) -> list[str]:
    return _read(warehouse, lambda con, path: [r[0] for r in con.execute(
        "SELECT DISTINCT campaign FROM results_current ORDER BY campaign").fetchall()])

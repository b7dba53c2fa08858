"""The sections of the calibration certificate (:mod:`accelcal.ops.report` puts them in
order and renders the page): certificate, item, method, dates and conditions,
traceability, results, budgets, Monte Carlo check, adequacy, alignment, flags, annexes."""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from ..estimators.joint import stored_adequacy
from ..estimators.registry import fit_checks, residual_figures
from ..results import MonteCarloCheck, monte_carlo_checks
from .certificate import COVERAGE_PROBABILITY, _adopted, _k, _u_unknown, method_text, missing_rig_inputs
from .plots import K_COVERAGE, figure_caption, radius_plot, residual_figure
from .report_display import (_at_digit, _coefficient_scale, _e, _fmt, _img, _keep, _kv, _ph, _same_minute,
                             _table, _to_second, _when, display_value)

#: Science parameters that belong to one test kind (others apply to every certificate).
PARAMETER_TESTS = {"radius_orders": "centrifuge", "radius_ranges_g": "centrifuge",
                   "mount_angle_tolerance_rad": "centrifuge"}


# ---------------------------------------------------------------- sections --

def _css_string(s: str) -> str:
    """A CSS string literal that cannot end the string or the <style> element."""
    out = s.replace("\\", "\\5C ").replace('"', "\\22 ").replace("<", "\\3C ")
    return '"' + re.sub(r"[\x00-\x1f]", " ", out) + '"'


def _page_css(lab: str, number: str, draft: bool = False) -> str:
    """Every printed page carries the lab, the certificate number and 'Page x of y'; a
    DRAFT's pages say DRAFT in the header and the footer instead of a number."""
    right = f"DRAFT — not a certificate ({number})" if draft else f"Certificate No. {number}"
    style = "font-size:8pt;color:#444" if not draft else "font-size:10pt;font-weight:700;color:#a61b1b"
    foot = ('@bottom-left{content:"DRAFT — not valid as a certificate";' + style + "}"
            if draft else "")
    return ("@page{size:A4;margin:20mm 14mm 18mm 14mm;"
            f"@top-left{{content:{_css_string(lab)};font-size:8pt;color:#444}}"
            f"@top-right{{content:{_css_string(right)};{style}}}"
            "@bottom-center{content:\"Page \" counter(page) \" of \" counter(pages);"
            f"font-size:8pt;color:#444}}{foot}}}")


_CSS = """
body{font-family:"DejaVu Sans",Arial,Helvetica,sans-serif;color:#111;margin:24px auto;
     max-width:1100px;font-size:12px;line-height:1.35}
@media print{body{margin:0;max-width:none;font-size:10px} h2,h3,.note{break-after:avoid}
     table,img,.keep{break-inside:avoid}}
h1{font-size:21px;margin:0 0 2px 0} h2{font-size:15px;border-bottom:2px solid #1f3f6e;
     color:#1f3f6e;margin-top:22px;padding-bottom:2px} h3{font-size:13px;margin:12px 0 4px 0}
.sub{color:#444;margin-bottom:10px} .certno{font-size:14px;font-weight:700}
table{border-collapse:collapse;margin:6px 0 10px 0;width:100%}
th,td{border:1px solid #bbb;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#e9eef5;font-weight:600}
td.nw{white-space:nowrap} td.brk{overflow-wrap:anywhere} td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
td.ok{color:#176b2c;font-weight:600} td.bad{color:#a61b1b;font-weight:600}
td.mono,.mono{font-family:"DejaVu Sans Mono",monospace;font-size:10px;word-break:normal}
tr.total td{font-weight:700;background:#f3f5f8}
table.kv{width:auto;min-width:60%} table.kv th{width:210px}
.flag{background:#fff4d6;border-left:4px solid #e0a800;padding:4px 8px;margin:4px 0}
.banner{background:#fde2e2;border:2px solid #a61b1b;padding:6px 10px;font-weight:600;margin:6px 0}
.draft{background:#fff4d6;border:2px solid #e0a800;padding:6px 10px;font-weight:600;margin:6px 0}
.placeholder{color:#a61b1b;font-style:italic}
img{max-width:100%;border:1px solid #ddd}
.note{color:#444;font-size:11px}
.sign{margin-top:26px;border-top:1px solid #111;width:280px;padding-top:2px}
footer{margin-top:24px;color:#555;font-size:10px;border-top:1px solid #ccc;padding-top:6px}
"""


class _Doc:
    """Numbered sections in order of appearance (no gaps) and lettered annexes."""

    def __init__(self):
        self.sections: list[tuple[str, str]] = []
        self.annexes: list[tuple[str, str]] = []

    def section(self, title: str, body: str) -> None:
        self.sections.append((title, body))

    def annex(self, title: str, body: str) -> None:
        self.annexes.append((title, body))

    def html(self) -> str:
        # a short section is kept on one page (its heading never parted from its table)
        out = [f"<section{_keep(b)}><h2>{k} {_e(t)}</h2>{b}</section>"
               for k, (t, b) in enumerate(self.sections, start=1)]
        out += [f"<section><h2>Annex {chr(ord('A') + k)} {_e(t)}</h2>{b}</section>"
                for k, (t, b) in enumerate(self.annexes)]
        return "".join(out)


def _sec_certificate(d, cfg, number, issued, customer) -> str:
    lab = cfg.name and _e(cfg.name) or _ph("laboratory name: set [lab] name in accelcal.toml")
    addr = cfg.address and _e(cfg.address) or _ph("address: set [lab] address in accelcal.toml")
    loc = cfg.location and _e(cfg.location) or _ph("location of the calibration: set [lab] "
                                                   "location in accelcal.toml")
    rigs = ", ".join(d.get("rig_ids") or []) or "—"
    cust = customer or cfg.customer
    appr = (_e(cfg.approver) + (f", {_e(cfg.approver_role)}" if cfg.approver_role else "")
            if cfg.approver else _ph("approver: set [certificate] approver in accelcal.toml"))
    pairs = [("Certificate number", f"none: DRAFT (reference {_e(number)})" if number.startswith("DRAFT-")
              else f"<b>{_e(number)}</b>"),
             ("Date of issue", _e(issued)),
             ("Laboratory", lab), ("Address", addr),
             ("Location of the calibration", f"{loc} (rigs {_e(rigs)})")]
    if cfg.accreditation:
        pairs.append(("Accreditation", _e(cfg.accreditation)))
    pairs += [("Customer", _e(cust) if cust else _ph("customer: not stated (accelcal.toml "
                                                     "[certificate] customer or --customer)")),
              ("Authorised by", appr),
              ("Configuration", _e(cfg.path) if cfg.path else _ph("no accelcal.toml found"))]
    return (_kv(pairs) + "<p class='note'>The results relate only to the item calibrated. This "
            "certificate shall not be reproduced except in full without the written approval "
            "of the laboratory.</p>")


def _sec_item(d) -> str:
    r = d["result"]
    return _kv([("Item", f"accelerometer, model {_e(r.get('unit_model'))}"),
                ("Serial number", f"<b>{_e(r.get('unit_serial'))}</b>"),
                ("Campaign", _e(d["campaign"])),
                ("Condition on receipt", "<i>not recorded in the data drop</i>"),
                ("Runs", f"{len(d['lineage'])} ({', '.join(sorted({str(x.get('test')) for x in d['lineage']}))})")])


def _sec_method(d) -> str:
    rows = []
    for test in d.get("tests") or []:
        name, how = method_text(test)
        rigs = sorted({str(x.get("rig_id")) for x in d["lineage"] if x.get("test") == test})
        n = sum(1 for x in d["lineage"] if x.get("test") == test)
        rows.append([name, ", ".join(rigs), (str(n), "num"), how])
    methods = sorted({c.get("method") for c in d["coefficients"] if c.get("method")})
    adopted = sorted({c.get("method") for c in _adopted(d) if c.get("method")})
    if "joint_ml" in adopted:
        rows.insert(0, [("Adopted values: joint fit", "nw"), ", ".join(sorted({str(x.get("rig_id")) for x in d["lineage"]})),
                        (str(len(d["lineage"])), "num"),
                        "one maximum-likelihood fit of every reading of every run through the instrument "
                        "model and rig kinematics (IEEE Std 1293 form, effects.md): instrument coefficients "
                        "shared by all runs" + (", radius, mass-centre offset, mount angles and per-run biases"
                                                if {"centrifuge", "sine_centrifuge"} & set(d.get("tests") or [])
                                                else "") +
                        ", temperature reading by reading, nuisance parameters where the design determines "
                        "them; weights from a noise model fitted to "
                        "the data of each run; model adequacy by a lack-of-fit test against the replicated "
                        f"readings (status: {stored_adequacy(d.get('extras')) or '—'}). The paper methods below are computed "
                        "beside it as cross-checks (Annex A)."])
    out = _table(["test", "rig", "runs", "procedure"], rows)
    out += (f"<p class='note'>Methods computed: {_e(', '.join(methods))}; adopted values from: "
            f"{_e(', '.join(adopted) or 'none')} (the other methods' values are cross-checks, "
            f"Annex A). Instrument model and coefficient names: IEEE Std 1293 form "
            f"(effects.md). Data processed by accelcal {_e(d['result'].get('code_version'))}.</p>")
    params = {k: v for k, v in (d.get("science_parameters") or {}).items()
              if k != "assumed" and PARAMETER_TESTS.get(k, None) in (None, *(d.get("tests") or []))}
    if params:
        out += ("<p class='note'>Processing parameters: "
                + _e(", ".join(f"{k} = {_setting(v)}" for k, v in sorted(params.items())))
                + "</p>")
    return out


def _setting(v: Any) -> str:
    """A processing setting as written: floats to six significant digits (a setting has
    no uncertainty; its stored float's last digits are noise of a conversion)."""
    if isinstance(v, float):
        return format(v, ".6g")
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_setting(x) for x in v) + "]"
    return json.dumps(v)


def _label_date(campaign: str) -> str | None:
    m = re.search(r"(\d{4}-\d{2}-\d{2})", campaign)
    return m.group(1) if m else None


def _sec_dates(d, issued) -> str:
    runs = d["runs"]
    starts = [x["start"] for x in runs if x.get("start")]
    ends = [x["end"] or x["start"] for x in runs if x.get("start")]
    first, last = (min(starts), max(ends)) if starts else (None, None)
    pairs = [("Calibration performed", f"{_e(_when(first))} to {_e(_when(last))}"),
             ("Date of issue", _e(issued))]
    out = _kv(pairs)
    lab_date = _label_date(d["campaign"])
    if first is not None and lab_date and lab_date != f"{first:%Y-%m-%d}":
        out += (f"<div class='flag'>The campaign label names {_e(lab_date)}, but the data were "
                f"taken from {_e(_when(first))} (the runs' started_at); the dates above are the "
                f"data's.</div>")
    rows = []
    for x in runs:
        tc, ts = x.get("temp_c"), x.get("temp_set_c")
        sec = _same_minute(x.get("start"), x.get("end"))     # a short run: to the second
        rows.append([(x.get("run_id"), "nw"), x.get("test"), (x.get("rig_id"), "nw"),
                     (_when(x.get("start"), sec), "nw"), (_when(x.get("end"), sec), "nw"),
                     ("—" if not tc else f"{tc[0]:.2f} / {tc[1]:.2f} / {tc[2]:.2f}", "num"),
                     ("—" if not ts else f"{ts[0]:.1f} to {ts[2]:.1f}", "num"),
                     ("not recorded" if x.get("ambient") is None else f"{x['ambient']:.1f}", "num"),
                     ("—" if x.get("g_local") is None else f"{x['g_local']:.6g}", "num"),
                     ("—" if x.get("latitude") is None else f"{x['latitude']:.4g}", "num")])
    out += "<h3>Environmental conditions, from the data</h3>"
    out += _table(["run", "test", "rig", "first reading", "last reading",
                   "instrument temperature min / mean / max / °C", "chamber set-points / °C",
                   "ambient / °C", "g local / m s⁻²", "latitude / °"], rows)
    missing = [x["run_id"] for x in runs if not x.get("data")]
    if missing:
        out += (f"<p class='note'>No Parquet copy of {_e(', '.join(map(str, missing)))}: only "
                f"its start time is known here.</p>")
    out += ("<p class='note'>Instrument temperature is the run's <span class='mono'>temp_c</span> "
            "column (the unit's case sensor); ambient is the optional "
            "<span class='mono'>ambient_temp_c</span> the DAQ records.</p>")
    return out


def _sec_traceability(d, cfg) -> str:
    r0 = next((x for x in d["runs"] if x.get("g_local") is not None), None)
    g = f"{r0['g_local']:.6g} m/s²" if r0 else "the value in the run files"
    parts = [f"<p>{_e(cfg.traceability)}</p>" if cfg.traceability else
             f"<p>{_ph('traceability statement: set [traceability] statement in accelcal.toml')}</p>"]
    rows = []
    for rig in d.get("rig_ids") or []:
        t = cfg.rig_traceability.get(rig)
        rows.append(f"<tr><th>{_e(rig)}</th><td>{_e(t) if t else _ph('reference standards of this rig: set [traceability.rigs] in accelcal.toml')}</td></tr>")
    parts.append("<table class='kv'>" + "".join(rows) + "</table>")
    srcs = [(rig, src) for rig, t in (d.get("rig_sources") or {}).items() for src in t.values()]
    if srcs:
        from ..rounding import round_gum_sci
        parts.append(_table(["rig", "reference standard", "from DCC", "issued by", "value",
                             "u", "file sha256"],
                            [[(rig, "nw"), src.what, (src.unique_identifier, "nw"), src.issuer,
                              *[(f"{t} {src.unit}", "num") for t in round_gum_sci(src.value, src.u)],
                              (src.sha256[:16] + "…", "mono")] for rig, src in srcs]))
    parts.append(f"<p class='note'>Local gravity used by the calculation: g = {_e(g)} (run "
                 "metadata). The results trace to the bytes of every input run (sha256, Annex B) "
                 "and to the code version that computed them.</p>")
    return "".join(parts)


def _mc_entry(d, c) -> MonteCarloCheck | None:
    """The JCGM 101 check stored for this coefficient by the method that computed it."""
    return next((m for m in monte_carlo_checks(d.get("extras")) if m.method == c.get("method")
                 and m.coefficient == c["name"] and m.rig_id == (c.get("rig_id") or "")), None)


def _mc_verdict(d, c) -> tuple[str, str]:
    """The JCGM 101 check of this coefficient's budget, as a table cell."""
    m = _mc_entry(d, c)
    if m is None:
        return ("not checked", "nw")
    return ("PASS", "ok") if m.validated else ("FAIL", "bad")


def name_with_factors(c) -> str:
    """A coefficient row's name as the certificate prints it: for a combination the design
    determines, with what it measures (``K1(Koq,K3) = K1 + 9.55·K3 + 1.1·Koq``, factors
    to three significant digits, from the row's ``factors``)."""
    from ..effects import combination_formula
    f = c.get("factors")
    factors = json.loads(f) if isinstance(f, str) else dict(f or {})
    return f"{c['name']} = {combination_formula(c['name'], factors)}" if factors else c["name"]


def _coef_rows(d, coefs) -> list[list[Any]]:
    rows = []
    for c in coefs:
        k = _k(c)
        v, U, unit = display_value(c["name"], c.get("value"), c.get("std_uncertainty"),
                                   c.get("unit"), k)
        if _u_unknown(c):
            U = "not assessable"
        rows.append([name_with_factors(c), (v, "num"), (U, "num"), (f"{k:.3g}", "num"),
                     (COVERAGE_PROBABILITY, "nw"), (unit, "nw"), c.get("method") or "",
                     (c.get("rig_id") or "", "nw"), (_fmt(c.get("dof"), ".0f"), "num"),
                     _mc_verdict(d, c), c.get("note") or ""])
    return rows


_COEF_HEAD = ["coefficient", "value", "U (k=2)", "k", "coverage probability", "unit", "method",
              "rig", "dof", "Monte Carlo check", "note"]


def _sec_results(d, plots) -> str:
    adopted = _adopted(d)
    head = list(_COEF_HEAD)
    if any(_k(c) != K_COVERAGE for c in adopted):
        head[2] = "U (k as given)"
    out = (_table(head, _coef_rows(d, adopted)) if adopted else
           "<p><b>No adopted value in this result</b>: the values computed are listed in "
           "Annex A as cross-checks only.</p>")
    out += ("<p class='note'>The expanded uncertainty U is the combined standard uncertainty "
            "multiplied by the coverage factor k = 2, which for a normal distribution "
            "corresponds to a coverage probability of approximately 95 %; where the "
            "uncertainty rests on few degrees of freedom (a model that failed its adequacy "
            "test, u scaled by its lack of fit) k is Student's t for 95 % on those degrees of "
            "freedom (JCGM 100 G.3), as given. 'Not assessable': the runs leave no degrees of "
            "freedom to test the model, and reading noise alone would understate u. Values and U are "
            "rounded per GUM 7.2.6 (U to two significant digits, the value to the same "
            "decimal). K1 is given in output unit per g with its relative U in ppm; "
            "1 µg/g² = 10⁻⁶/g₀, g₀ = 9.80665 m/s².</p>")
    return out + _assumed(d)


def _assumed(d) -> str:
    """What a row made a quantity from priors assumed: each held term with value ± u and
    the result (or config table) it is from (:func:`accelcal.estimators.priors.apply_priors`)."""
    from ..effects import display_coefficient, si_unit
    assumed = (d.get("science_parameters") or {}).get("assumed") or {}
    rows = []
    for quantity, terms in sorted(assumed.items()):
        for term, h in terms.items():
            v, u, unit = display_coefficient(term, h["value"], h["u"], si_unit(term), k=1.0)
            rows.append([quantity, term, (v, "num"), (u, "num"), (unit, "nw"), h["source"]])
    if not rows:
        return ""
    return ("<p><b>Assumed values.</b> The runs determine these coefficients only together "
            "with the terms below, which the design cannot see; each is reported with the "
            "terms held at what the laboratory knows of them (the unit's last calibration "
            "that determined them, or the laboratory's stated prior), each held term's "
            "standard uncertainty a type-B line of the coefficient's uncertainty budget "
            "(JCGM 100 §4.3).</p>"
            + _table(["coefficient", "term held", "value", "standard uncertainty u", "unit", "from"], rows))


def _sec_radius(d, plots) -> str:
    from ..rounding import format_sig, round_gum
    rows = []
    for x in d["radii"]:
        u = x.get("std_uncertainty_m")
        U = None if u is None else K_COVERAGE * u
        en = radius_en(d, x)
        rows.append([(x.get("rig_id"), "nw"), x.get("polarity"), x.get("method"),
                     _fmt(x.get("model_order")), (_fmt(x.get("g_max"), ".1f"), "num"),
                     (round_gum(x.get("radius_m"), U).value, "num"),
                     (format_sig(None if U is None else 1e6 * U), "num"),
                     ("—" if en is None else f"{en:.2f}", "bad" if en is not None and abs(en) > 1 else "num"),
                     x.get("note") or ""])
    out = ("<p class='note'>The centrifuge's test radius, measured with the item (a rig "
           "parameter, not a result for the item).</p>")
    out += _table(["rig", "polarity", "method", "order", "g max / g", "radius / m",
                   "U (k=2) / µm", "En vs joint fit", "note"], rows)
    if plots:
        out += _img(radius_plot(d["radii"]), "radius plot")
    return out


def _input_unit(b, coefficient_unit: str) -> str:
    """The SI unit of a budget line's input value: a rig input's own unit; the coefficient's
    unit when the line's sensitivity is one (the input is the coefficient as fitted)."""
    from ..effects import RIG_INPUTS
    q = b.get("quantity") or ""
    for r in RIG_INPUTS.values():
        if q.startswith(r.what):
            return r.unit.replace("m/s2", "m/s²").replace("degC", "°C")
    m = re.search(r"±\s*[0-9.eE+-]+\s*([^\s:;,)]+)", q)     # "uniform ±0.000291 rad: ..."
    if m:
        return m.group(1)
    sens = b.get("sensitivity")
    if sens is not None and abs(abs(sens) - 1.0) < 1e-12:
        return coefficient_unit.replace("m/s2", "m/s²").replace("s2/m", "s²/m").replace("s4/m2", "s⁴/m²")
    return ""


def _budget_quantity(d, c, b) -> str:
    """A budget line's name; a rig input read from a standard's DCC names that DCC's
    uniqueIdentifier and issuer."""
    from ..effects import RIG_INPUTS
    q = b.get("quantity") or ""
    if not q.startswith(RIG_INPUTS["g_local"].what):
        return q
    for rig, srcs in (d.get("rig_sources") or {}).items():
        src = srcs.get("g_local_dcc")
        if src is not None and (f"of {rig}" in q or c.get("rig_id") == rig):
            return f"{q}; u from {src.source()}"
    return q


def _sec_budgets(d) -> str:
    from ..rounding import format_sig_sci, round_gum_sci
    budget = d["budget"]
    out = []
    for c in _adopted(d):
        name, u = c["name"], c.get("std_uncertainty")
        meth = c.get("method") or ""
        rows = [b for b in budget if b.get("coefficient") == name
                and ((b.get("method") or "") == meth or (not b.get("method") and meth != "joint_ml"))]
        k = _k(c)
        unit = c.get("unit") or ""
        f, dunit = _coefficient_scale(name, unit)
        body = []
        n_zero = 0
        for b in rows:
            bu, contrib = b.get("std_uncertainty"), b.get("contribution")
            if not bu and not contrib:              # a term of zero size is no term
                n_zero += 1
                continue
            v_text, u_text = round_gum_sci(b.get("value"), bu)
            sens = b.get("sensitivity")
            iu = _input_unit(b, unit)
            v_text, u_text = (f"{v_text} {iu}", f"{u_text} {iu}") if iu else (v_text, u_text)
            body.append("<tr>" + "".join(f"<td{cls}>{_e(v)}</td>" for cls, v in (
                ("", _budget_quantity(d, c, b)), (" class='num'", v_text), (" class='num'", u_text),
                (" class='num'", "—" if sens is None else format_sig_sci(sens / f, 3)),
                (" class='num'", "—" if contrib is None else format_sig_sci(contrib / f)),
                ("", b.get("type")), ("", b.get("distribution")))) + "</tr>")
        if not rows:
            body.append("<tr><td colspan='7' class='note'>budget not itemised: no "
                        "input-quantity breakdown is stored for this coefficient</td></tr>")
        if n_zero:
            body.append(f"<tr><td colspan='7' class='note'>{n_zero} term(s) of zero size not "
                        "listed</td></tr>")
        uc = None if u is None else u / f
        body.append(f"<tr class='total'><td>combined standard uncertainty u<sub>c</sub></td>"
                    f"<td></td><td></td><td></td><td class='num'>{_e(format_sig_sci(uc))}</td>"
                    f"<td colspan='2'>{_e(dunit)}</td></tr>")
        _, U_disp, _ = display_value(name, c.get("value"), u, unit, k)
        ppm = f" (= {U_disp})" if U_disp.endswith("ppm") else ""
        body.append(f"<tr class='total'><td>expanded uncertainty U, k = {k:.3g}, p {COVERAGE_PROBABILITY}"
                    f"</td><td></td><td></td><td></td>"
                    f"<td class='num'>{_e(format_sig_sci(None if uc is None else k * uc))}</td>"
                    f"<td colspan='2'>{_e(dunit)}{_e(ppm)}</td></tr>")
        out.append(f"<div class='keep'><h3>{_e(name)} ({_e(c.get('method'))}, "
                   f"{_e(c.get('rig_id'))})</h3><table><thead><tr><th>quantity</th><th>value</th>"
                   f"<th>u</th><th>sensitivity c / ({_e(dunit)} per unit)</th>"
                   f"<th>|c|·u / {_e(dunit)}</th><th>type</th>"
                   f"<th>distribution</th></tr></thead><tbody>{''.join(body)}</tbody></table></div>")
    if not out:
        return "<p>No adopted value, no budget.</p>"
    left = missing_rig_inputs(d)
    gap = ("<p>Left out of every budget, for want of a stated uncertainty: "
           + "; ".join(_ph(f"{what}: {how}") for what, how in left) + ".</p>") if left else ""
    return ("<p class='note'>GUM (JCGM 100) budgets. Each input quantity in its own SI unit, "
            "its value to the last digit of its u; sensitivities, contributions, u<sub>c</sub> and "
            "U in the unit of the results table (section 4). u<sub>c</sub> is the stored standard "
            "uncertainty of the adopted value.</p>" + gap + "".join(out))


def _sec_mc(d) -> str:
    adopted = {(c.get("method"), c.get("rig_id") or "", c["name"]) for c in _adopted(d)}
    from ..rounding import format_sig, round_sig
    units = {c["name"]: c.get("unit") for c in d["coefficients"]}
    rows = []
    for m in monte_carlo_checks(d.get("extras")):
        mine = (m.method, m.rig_id, m.coefficient) in adopted
        f, dunit = _coefficient_scale(m.coefficient, units.get(m.coefficient))
        # the interval's end points to the digit of the numerical tolerance (JCGM 101 7.9.2),
        # else to the last digit of u(MC) at two significant digits
        exp = (round_sig(m.delta / f, 1)[1] if m.delta else
               round_sig(m.mc_u / f)[1] if m.mc_u else None)
        lo, hi = (None if x is None else x / f for x in (m.mc_low, m.mc_high))
        # a long combination's key may break anywhere (it would push the table past the page)
        rows.append([(m.key, "brk"), ("yes" if mine else "", "nw"),
                     (_u_text(m.gum_u, f), "num"), (_u_text(m.mc_u, f), "num"),
                     (f"[{_at_digit(lo, exp)}, {_at_digit(hi, exp)}]", "nw"),
                     ("—" if not m.delta else format_sig(m.delta / f, 1), "num"), (dunit, "nw"),
                     ("PASS" if m.validated else "FAIL", "ok" if m.validated else "bad"), m.meaning()])
    methods = sorted({c.get("method") for c in _adopted(d)})
    if not rows:
        return (f"<p>No Monte Carlo check is stored for this result (methods "
                f"{_e(', '.join(methods) or '—')}): the GUM uncertainty is not validated by "
                f"JCGM 101 here.</p>")
    n_fail = sum(1 for r in rows if r[-2][0] == "FAIL")
    head = (f"<p><b>{len(rows) - n_fail} of {len(rows)} budgets pass</b> the JCGM 101 check "
            "(GUM interval end points within the numerical tolerance δ of the Monte Carlo "
            "ones).</p>")
    if n_fail:
        head += ("<div class='flag'>A FAIL means the GUM interval y ± U (normal, k for 95 %) and "
                 "the 95 % interval of the propagated distributions differ by more than δ at the "
                 "digits stated. The value is unaffected; what changes is what U covers: the "
                 "last column says which way. Where U covers less than 95 %, quote the Monte "
                 "Carlo interval.</div>")
    return head + _table(["budget", "adopted", "u (GUM)", "u (Monte Carlo)",
                          "95 % interval (Monte Carlo)", "δ", "unit", "result", "what it means"], rows)


def _u_text(u: float | None, f: float) -> str:
    from ..rounding import format_sig
    return format_sig(None if u is None else u / f)


def _fit_statistics(d) -> list[list[Any]]:
    """Adequacy and term tests stored by each method, one row each (the methods' own
    :class:`~accelcal.results.FitCheck` records, :func:`fit_checks`)."""
    alpha = float((d.get("science_parameters") or {}).get("adequacy_alpha", 0.01))
    return [[c.test, c.fit, c.check, (c.statistic, "nw"), (c.dof, "num"), (_fmt(c.p, ".3g"), "num"),
             c.verdict(alpha)] for c in fit_checks(d.get("extras"))]


def _sec_adequacy(d, plots) -> str:
    out = []
    if d["adequacy"]:
        rows = []
        for a in d["adequacy"]:
            ok = a.get("adequate")
            rows.append([(a.get("rig_id"), "nw"), a.get("fit"), _fmt(a.get("model_order")),
                         (_fmt(a.get("g_max"), ".1f"), "num"),
                         (_fmt(a.get("f_statistic"), ".3g"), "num"),
                         (_fmt(a.get("p_value"), ".3g"), "num"),
                         (f"{_fmt(a.get('dof_lack_of_fit'))}/{_fmt(a.get('dof_pure_error'))}", "num"),
                         (_fmt(a.get("trend_p"), ".3g"), "num"), (_fmt(a.get("sweep_p"), ".3g"), "num"),
                         (_fmt(a.get("runs_p"), ".3g"), "num"),
                         (("not testable (no degrees of freedom)", "") if not ok and (not a.get("dof_lack_of_fit") or a.get("f_statistic") is None)
                          else ("adequate", "ok") if ok else ("NOT adequate", "bad")),
                         ("✔" if ok else "used: no order tested is adequate") if a.get("chosen") else ""])
        out.append("<h3>Regressions: lack-of-fit F test and residual checks</h3>")
        out.append(_table(["rig", "fit", "order", "g max", "F", "p (lack of fit)", "dof lof/pe",
                           "trend p", "sweep p", "runs p", "verdict", "chosen"], rows))
    stats_rows = _fit_statistics(d)
    if stats_rows:
        out.append("<h3>Fit statistics stored by the methods</h3>")
        out.append(_table(["test", "fit", "check", "statistic", "dof", "p", "verdict"], stats_rows))
    if not out:
        out.append("<p>No adequacy test is stored for this result.</p>")
    if plots:
        for fig in residual_figures(d.get("extras")):
            img = residual_figure(fig)
            if img:
                out.append(f"<div class='keep'><p class='note'>{_e(figure_caption(fig))}</p>"
                           f"{_img(img, 'residual plot')}</div>")
        tests = set(d.get("tests") or [])
        if "tumble" in tests:
            out.append("<p class='note'>Tumble: no residual series is stored; its lack-of-fit "
                       "test and residual rms are in the table above.</p>")
    return "".join(out)


def _sec_alignment(d) -> str:
    from ..rounding import round_gum_sci
    lam = [a for a in d["alignment"] if a.get("kind") == "lambda_c"]
    mounts = [a for a in d["alignment"] if a.get("kind") == "mount"]
    other = [a for a in d["alignment"] if a.get("kind") not in ("lambda_c", "mount")]
    out = []
    if lam:
        rows = [[a.get("rig_id"), *[(t, "num") for sign in "+-" for t in round_gum_sci(
                    _mul(a.get(f"lambda_c{sign}"), 1e6), _mul(a.get(f"u_lambda_c{sign}"), 2e6))]]
                for a in lam]
        out.append(_table(["rig", "λc+ / µrad", "U / µrad", "λc− / µrad", "U / µrad"], rows))
    if mounts:
        rows = [[a.get("rig_id"), a.get("pair"), (_fmt(a.get("phi0_deg"), ".0f"), "num"),
                 (_fmt(_mul(a.get("dphi1"), 1e3), ".3f"), "num"),
                 (_fmt(_mul(a.get("dphi2"), 1e3), ".3f"), "num"),
                 (_fmt(_mul(a.get("r"), 1e3), ".3f"), "num"),
                 (_ug_g2(a.get("c2")), "num"),
                 *[(t, "num") for t in _ug_g2_pair(a.get("dc2_1"), a.get("u_dc2_typeB"))[:1]],
                 *[(t, "num") for t in _ug_g2_pair(a.get("dc2_2"), a.get("u_dc2_typeB"))]]
                for a in mounts]
        out.append(_table(["rig", "mount pair", "φ0 / °", "Δφ1 / mrad", "Δφ2 / mrad",
                           "mass-centre offset r / mm", "c2 / µg/g²", "Δc2(1) / µg/g²",
                           "Δc2(2) / µg/g²", "U type B (Δc2) / µg/g²"], rows))
        out.append("<p class='note'>Δc2 from the mount angle error (paper 000 eq 8), treated as "
                   "a uniform type-B term in the budget.</p>")
    for a in other:
        if a.get("kind") == "joint":
            out.append(_joint_geometry(a))
        else:
            out.append(f"<p class='mono'>{_e(json.dumps(a, default=str))}</p>")
    return "".join(out)


#: display of the joint fit's geometry parameters by SI unit: (value unit, factor, U unit, factor)
_GEOMETRY_DISPLAY = {"m": ("mm", 1e3, "µm", 1e6), "rad": ("mrad", 1e3, "µrad", 1e6)}


def _joint_geometry(a: dict) -> str:
    """The joint fit's rig-geometry and effect parameters (radii, mass-centre offset, mount
    angle errors) as a table: value, U (k = 2), and what was held and why."""
    from ..rounding import format_sig, round_gum
    rows = []
    for name, prm in (a.get("parameters") or {}).items():
        vu, vf, uu, uf = _GEOMETRY_DISPLAY.get(prm.get("unit"), (prm.get("unit") or "", 1.0, prm.get("unit") or "", 1.0))
        u = prm.get("u")
        held = prm.get("held")
        v, U = _mul(prm.get("value"), vf), None if u is None else 2 * u * vf
        # the value to the last digit of U (both in the value's unit), U shown in its own
        rows.append([name, (f"{round_gum(v, U).value} {vu}", "num"),
                     (f"{format_sig(2 * u * uf)} {uu}" if u is not None else "—", "num"),
                     "" if not held else f"held: {held}"])
    return (_table(["joint-fit parameter", "value", "U (k=2)", "note"], rows)
            + "<p class='note'>Rig geometry fitted with the coefficients in the joint maximum-likelihood "
              "fit (section 6); these are its estimates, not separate measurements.</p>")


def _mul(x, f):
    return None if x is None else x * f


def _ug_g2_pair(x, u) -> tuple[str, str]:
    """(value, U = 2u) in µg/g², the value to U's last digit (GUM 7.2.6)."""
    from ..effects import COEFFICIENTS
    from ..rounding import round_gum_sci
    f = COEFFICIENTS["K2"].display_factor
    if u is None:
        return _ug_g2(x), "—"
    return round_gum_sci(None if x is None else x / f, 2 * u / f)


def _ug_g2(x) -> str:
    from ..effects import COEFFICIENTS
    if x is None:
        return "—"
    return f"{x / COEFFICIENTS['K2'].display_factor:.4g}"


def _sec_flags(d) -> str:
    items = [f"<div class='flag'>{_e(f)}</div>" for f in d["flags"] + _cross_check_flags(d)]
    mc = {m.key: m for m in monte_carlo_checks(d.get("extras"))}
    for c in _adopted(d):
        m = mc.get(f"{c.get('method')}:{c.get('rig_id') or ''}:{c['name']}")
        if m is not None and not m.validated:
            items.append(f"<div class='flag'>Monte Carlo check FAIL for the adopted {_e(c['name'])}: "
                         f"{_e(m.meaning())} (see Monte Carlo check of the uncertainty).</div>")
    if d["result"].get("completeness") == "incomplete":
        items.append("<div class='flag'>Incomplete campaign: "
                     + _e("; ".join(d.get("completeness_reasons") or [])) + "</div>")
    return "".join(items) or "<p>None: the method was applied without deviation.</p>"


def en_against_adopted(d, c) -> float | None:
    """En = (x - x_adopted) / sqrt(U^2 + U_adopted^2) of a cross-check ``c`` against the
    adopted value of the same coefficient (same rig if there is one), U = k u (ISO 13528
    §9.7); None without an adopted value or an uncertainty."""
    same = [a for a in _adopted(d) if a["name"] == c["name"]]
    a = next((a for a in same if a.get("rig_id") == c.get("rig_id")), same[0] if same else None)
    if a is None or _u_unknown(a) or _u_unknown(c) or c.get("value") is None:
        return None
    U1, U2 = _k(c) * c["std_uncertainty"], _k(a) * a["std_uncertainty"]
    den = math.hypot(U1, U2)
    return (c["value"] - a["value"]) / den if den > 0 else None


def _cross_check_flags(d) -> list[str]:
    """Cross-checks more than their combined U from the adopted value (|En| > 1)."""
    out = []
    for c in d["coefficients"]:
        if c.get("adopted"):
            continue
        en = en_against_adopted(d, c)
        if en is not None and abs(en) > 1:
            out.append(f"cross-check {c['name']} by {c.get('method')} ({c.get('rig_id') or ''}) "
                       f"differs from the adopted value by En = {en:.2f} (|En| > 1; Annex A)")
    # radii: the row of each method and order over the widest g range (its final value;
    # narrower ranges are the iterative method's steps, shown in the table)
    widest: dict[tuple, float] = {}
    for x in d["radii"]:
        key = (x.get("rig_id"), x.get("polarity"), x.get("method"), x.get("model_order"))
        widest[key] = max(widest.get(key, -math.inf), x.get("g_max") or 0.0)
    for x in d["radii"]:
        key = (x.get("rig_id"), x.get("polarity"), x.get("method"), x.get("model_order"))
        if (x.get("g_max") or 0.0) < widest[key]:
            continue
        en = radius_en(d, x)
        if en is not None and abs(en) > 1:
            out.append(f"test radius of {x.get('rig_id')} {x.get('polarity')} by {x.get('method')} "
                       f"differs from the joint fit's by En = {en:.2f} (|En| > 1; section Test radius)")
    return out


def radius_en(d, x) -> float | None:
    """En of a paper-method test radius against the joint fit's for the same rig and
    polarity (None for the joint fit's own row or without uncertainties)."""
    if x.get("method") == "joint_ml":
        return None
    j = next((y for y in d["radii"] if y.get("method") == "joint_ml"
              and y.get("rig_id") == x.get("rig_id") and y.get("polarity") == x.get("polarity")), None)
    if j is None or not x.get("std_uncertainty_m") or not j.get("std_uncertainty_m"):
        return None
    den = K_COVERAGE * math.hypot(x["std_uncertainty_m"], j["std_uncertainty_m"])
    return (x["radius_m"] - j["radius_m"]) / den if den > 0 else None


def _annex_other(d) -> str:
    others = [c for c in d["coefficients"] if not c.get("adopted")]
    if not others:
        return "<p>None: every value computed is adopted.</p>"
    rows = _coef_rows(d, others)
    for r, c in zip(rows, others):
        en = en_against_adopted(d, c)
        r.insert(-1, ("—" if en is None else f"{en:.2f}", "bad" if en is not None and abs(en) > 1 else "num"))
    head = _COEF_HEAD[:-1] + ["En vs adopted", _COEF_HEAD[-1]]
    return ("<p class='note'>Values of the same coefficients by the other methods, kept as "
            "cross-checks; they are not the certified values. En = (x − x<sub>adopted</sub>) / "
            "√(U² + U<sub>adopted</sub>²); both come from the same readings, so they are "
            "correlated and |En| > 1 is a disagreement worth a look (flagged in section "
            "Flags).</p>" + _table(head, rows))


def _grouped(token: str | None, n: int = 16) -> str:
    """A long id in groups of n characters, so a line breaks between groups, never inside."""
    if not token:
        return ""
    return " ".join(token[i:i + n] for i in range(0, len(token), n))


def _in_drop(x: dict) -> str:
    """The raw file as the lab names it: drop name / path inside the drop (not a path of
    the processing machine), with break opportunities after each '/'."""
    src, root = x.get("source_path") or "", x.get("drop_path") or ""
    try:
        rel = Path(src).relative_to(root).as_posix() if root else Path(src).name
    except ValueError:
        rel = Path(src).name
    name = f"{x['drop_name']}/{rel}" if x.get("drop_name") else rel
    return name.replace("/", "/\u200b")


def _annex_lineage(d) -> str:
    rows = [[(x.get("run_id"), "nw"), _fmt(x.get("revision")), x.get("test"),
             (x.get("rig_id"), "nw"), (x.get("started_at"), "nw"), (_grouped(x.get("sha256")), "mono"),
             (_in_drop(x), "mono"), (x.get("flow_run_id"), "mono")]
            for x in d["lineage"]]
    return _table(["run id", "rev", "test", "rig", "started", "sha256", "raw file (drop / path)",
                   "ingest flow run"], rows)


def _lineage_close(d) -> str:
    """The end of the lineage annex: the result history, quarantine decisions and the
    result's identity.  The certificate prints it in one block with the signature, so that
    the signature never stands alone on the last page."""
    acts = [[a["seq"], (_grouped(a["result_id"]), "mono"), _to_second(a["activated_at"]),
             (a.get("flow_run_id"), "mono")]
            for a in d["activations"]]
    out = ("<p class='note'>Result history of this campaign (append-only; the last activation "
           "is current):</p>")
    out += _table(["#", "result id", "activated", "flow run"], acts)
    if d.get("audit"):
        out += "<p class='note'>Quarantine decisions (accelcal campaign exclude|include):</p>"
        out += _table(["#", "action", "why", "when", "by"],
                      [[a["seq"], a["action"], a["why"], a["acted_at"], a["acted_by"]]
                       for a in d["audit"]])
    out += (f"<p class='note'>Result id <span class='mono'>{_e(_grouped(d['result_id']))}</span>; code "
            f"version {_e(d['result'].get('code_version'))}; pipeline parameters "
            f"<span class='mono'>{_e(json.dumps(d.get('parameters'), sort_keys=True))}</span>.</p>")
    return out

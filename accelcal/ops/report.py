"""Calibration report: one self-contained HTML certificate-style page per campaign.

``build_report(warehouse, campaign, out_dir)`` reads the campaign's current
result (or a given, possibly superseded, result_id) from the warehouse and
writes ``<out_dir>/<campaign with / -> _>.html``: unit, rigs, dates, the
coefficients with expanded uncertainties (k = 2) in display units
(accelcal.effects.COEFFICIENTS), the adequacy tests, the alignment analysis,
the uncertainty budget, flags, residual and radius plots (matplotlib PNG,
base64-embedded) and the lineage (run ids, revisions, sha256, flow run ids).

Nothing is fetched from the network: no scripts, no external CSS or fonts.
The warehouse is only read (under its writer lock so a running pipeline is
waited for, never observed half-way).
"""
from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import json
import math
import re
from pathlib import Path
from typing import Any

K_COVERAGE = 2.0



class ReportError(RuntimeError):
    """The report cannot be made (one-line reason)."""


# ------------------------------------------------------------------ reading --

def _rows(con, sql: str, params: list | None = None) -> list[dict[str, Any]]:
    cur = con.execute(sql, params or [])
    cols = [d[0] for d in cur.description]
    return [dict(zip(cols, r)) for r in cur.fetchall()]


def load_report_data(warehouse: str | Path, campaign: str, result_id: str | None = None,
                     lock_timeout: float = 60.0) -> dict[str, Any]:
    """Everything the report shows, as plain Python objects."""
    import duckdb

    from ..warehouse.db import WarehouseError, check_schema_version, warehouse_lock
    path = Path(warehouse).expanduser().resolve()
    if not path.exists():
        raise ReportError(f"warehouse {path} does not exist")
    try:
        with warehouse_lock(path, timeout=lock_timeout):
            con = duckdb.connect(str(path), read_only=True)
            try:
                check_schema_version(con, path)
                return _load(con, campaign, result_id)
            finally:
                con.close()
    except WarehouseError as e:
        raise ReportError(str(e)) from None
    except duckdb.Error as e:
        raise ReportError(f"cannot read warehouse {path}: {str(e).splitlines()[0]}") from None


def _load(con, campaign: str, result_id: str | None) -> dict[str, Any]:
    acts = _rows(con, "SELECT seq, result_id, activated_at, flow_run_id FROM result_activations "
                      "WHERE campaign = ? ORDER BY seq", [campaign])
    if not acts:
        known = [r["campaign"] for r in _rows(
            con, "SELECT DISTINCT campaign FROM results ORDER BY campaign LIMIT 20")]
        hint = f" (known: {', '.join(known)})" if known else " (the warehouse holds no results)"
        raise ReportError(f"no result for campaign {campaign!r}{hint}")
    current = acts[-1]["result_id"]
    rid = result_id or current
    res = _rows(con, "SELECT * FROM results WHERE result_id = ? AND campaign = ?", [rid, campaign])
    if not res:
        raise ReportError(f"result {rid!r} is not a result of campaign {campaign!r}")
    r = res[0]
    d: dict[str, Any] = {"campaign": campaign, "result": r, "result_id": rid,
                         "is_current": rid == current, "current_result_id": current,
                         "activations": acts}
    for key in ("tests", "rig_ids", "science_parameters", "parameters", "extras", "input_sha256"):
        try:
            d[key] = json.loads(r.get(key) or "null")
        except (TypeError, ValueError):
            d[key] = None
    d["coefficients"] = _rows(con, "SELECT * FROM coefficient_history WHERE result_id = ? "
                                   "ORDER BY seq", [rid])
    d["radii"] = _rows(con, "SELECT * FROM radius_history WHERE result_id = ? ORDER BY seq", [rid])
    d["adequacy"] = _rows(con, "SELECT * FROM adequacy_history WHERE result_id = ? ORDER BY seq",
                          [rid])
    d["budget"] = _rows(con, "SELECT * FROM budget_history WHERE result_id = ? ORDER BY seq", [rid])
    d["alignment"] = [json.loads(a["record"]) for a in _rows(
        con, "SELECT record FROM alignment_history WHERE result_id = ? ORDER BY seq", [rid])]
    d["flags"] = [f["flag"] for f in _rows(
        con, "SELECT flag FROM flag_history WHERE result_id = ? ORDER BY seq", [rid])]
    d["lineage"] = _rows(con, """
        SELECT l.run_id, l.revision, l.sha256, l.source_path, l.parquet_path, l.flow_run_id,
               l.code_version, f.test, f.rig_id, f.started_at, f.size_bytes
        FROM lineage l
        LEFT JOIN (SELECT sha256, any_value(test) AS test, any_value(rig_id) AS rig_id,
                          any_value(started_at) AS started_at, any_value(size_bytes) AS size_bytes
                   FROM run_files GROUP BY sha256) f USING (sha256)
        WHERE l.result_id = ? ORDER BY f.started_at, l.run_id""", [rid])
    starts = [x["started_at"] for x in d["lineage"] if x.get("started_at")]
    d["first_run"], d["last_run"] = (min(starts), max(starts)) if starts else (None, None)
    return d


# ------------------------------------------------------------------ display --

def display_value(name: str, value: float | None, std_u: float | None,
                  unit: str | None) -> tuple[str, str, str]:
    """(value, U (k = 2), display unit) for one coefficient, rounded per GUM 7.2.6."""
    from ..effects import display_coefficient
    return display_coefficient(name, value, std_u, unit, K_COVERAGE)


def _fmt(x: Any, spec: str = ".4g") -> str:
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        if math.isnan(x):
            return "—"
        return format(x, spec)
    return str(x)


def _e(x: Any) -> str:
    return html.escape("" if x is None else str(x))


def _table(headers: list[str], rows: list[list[Any]], cls: str = "") -> str:
    th = "".join(f"<th>{_e(h)}</th>" for h in headers)
    body = []
    for row in rows:
        tds = []
        for c in row:
            if isinstance(c, tuple):        # (text, css class)
                tds.append(f'<td class="{c[1]}">{_e(c[0])}</td>')
            else:
                tds.append(f"<td>{_e(c)}</td>")
        body.append("<tr>" + "".join(tds) + "</tr>")
    return (f'<table class="{cls}"><thead><tr>{th}</tr></thead>'
            f"<tbody>{''.join(body)}</tbody></table>")


# ------------------------------------------------------------------- plots --

def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def residual_plot(extras: dict[str, Any] | None) -> str | None:
    """Standardised dwell residuals of the eq 9 fits against centripetal g, one panel per pair."""
    pairs = [(rig, p) for rig, ps in ((extras or {}).get("pairs") or {}).items() for p in ps
             if isinstance(p, dict) and isinstance(p.get("dwells"), dict)]
    if not pairs:
        return None
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from ..constants import G_STANDARD
    n = len(pairs)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 2.9 * nrow), squeeze=False,
                             sharey=True)
    for k, (rig, p) in enumerate(pairs):
        ax = axes[k // ncol][k % ncol]
        dw = p["dwells"]
        a = [(x or 0.0) / G_STANDARD for x in dw.get("a", [])]
        r = dw.get("std_resid", [])
        pol = dw.get("pol", [1] * len(a))
        sweep = dw.get("sweep", ["up"] * len(a))
        for sgn, colour in ((1, "#1f5fa8"), (-1, "#c0392b")):
            for sw, marker in (("up", "^"), ("down", "v"), ("rest", "o")):
                xs = [x for x, s, w, y in zip(a, pol, sweep, r) if s == sgn and w == sw and y is not None]
                ys = [y for x, s, w, y in zip(a, pol, sweep, r) if s == sgn and w == sw and y is not None]
                if xs:
                    ax.scatter(xs, ys, s=14, marker=marker, color=colour, alpha=0.8,
                               label=f"{'+' if sgn > 0 else '−'} {sw}")
        for lim in (-3, 3):
            ax.axhline(lim, color="#888", lw=0.6, ls="--")
        ax.axhline(0, color="#444", lw=0.6)
        ax.set_title(f"{rig} {p.get('pair', '')} (order {p.get('order', '?')})", fontsize=9)
        ax.set_xlabel("input acceleration along IA (signed) / g", fontsize=8)
        if k % ncol == 0:
            ax.set_ylabel("standardised residual", fontsize=8)
        ax.tick_params(labelsize=7)
    for k in range(n, nrow * ncol):
        axes[k // ncol][k % ncol].axis("off")
    h, lab = axes[0][0].get_legend_handles_labels()
    if h:
        fig.legend(h, lab, loc="upper center", ncol=6, fontsize=7, frameon=False,
                   bbox_to_anchor=(0.5, 1.04))
    fig.tight_layout()
    return _png(fig)


def radius_plot(radii: list[dict[str, Any]]) -> str | None:
    """Test radius per polarity against the g range of the fit, per method/order, with U (k=2)."""
    rows = [r for r in radii if r.get("radius_m") is not None]
    if not rows:
        return None
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r.get("rig_id"), r.get("polarity")), []).append(r)
    keys = sorted(groups, key=lambda k: (str(k[0]), str(k[1])))
    fig, axes = plt.subplots(1, len(keys), figsize=(4.4 * len(keys), 3.2), squeeze=False)
    for ax, key in zip(axes[0], keys):
        rs = groups[key]
        ref = sorted(r["radius_m"] for r in rs)[len(rs) // 2]
        series: dict[str, list[dict[str, Any]]] = {}
        for r in rs:
            lab = f"{r.get('method')}" + (f" o{r['model_order']}" if r.get("model_order") else "")
            series.setdefault(lab, []).append(r)
        for i, (lab, ss) in enumerate(sorted(series.items())):
            ss = sorted(ss, key=lambda r: r.get("g_max") or 0)
            xs = [(r.get("g_max") or 1.0) + 0.3 * (i - len(series) / 2) for r in ss]   # dodge
            ys = [1e6 * (r["radius_m"] - ref) for r in ss]
            es = [K_COVERAGE * 1e6 * (r.get("std_uncertainty_m") or 0.0) for r in ss]
            ax.errorbar(xs, ys, yerr=es, fmt="o-" if len(ss) > 1 else "s", ms=4, lw=1,
                        capsize=2, label=lab)
        ax.set_title(f"{key[0]}  polarity {key[1]}:  R = {ref:.6f} m + Δ", fontsize=9)
        ax.set_xlabel("upper end of the fit's g range / g  (static: 1 g)", fontsize=8)
        ax.set_ylabel("Δ test radius / µm  (bars: U, k=2)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6, frameon=False)
    fig.tight_layout()
    return _png(fig)


# -------------------------------------------------------------------- html --

_CSS = """
body{font-family:"DejaVu Sans",Arial,Helvetica,sans-serif;color:#111;margin:28px auto;
     max-width:1100px;font-size:13px;line-height:1.35}
h1{font-size:22px;margin:0 0 4px 0} h2{font-size:16px;border-bottom:2px solid #1f3f6e;
     color:#1f3f6e;margin-top:26px;padding-bottom:2px}
.sub{color:#555;margin-bottom:14px}
table{border-collapse:collapse;margin:6px 0 10px 0;width:100%}
th,td{border:1px solid #bbb;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#e9eef5;font-weight:600}
td.nw{white-space:nowrap} td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
td.ok{color:#176b2c;font-weight:600} td.bad{color:#a61b1b;font-weight:600}
td.mono,.mono{font-family:"DejaVu Sans Mono",monospace;font-size:11px;word-break:break-all}
table.kv{width:auto} table.kv th{width:180px}
.flag{background:#fff4d6;border-left:4px solid #e0a800;padding:4px 8px;margin:4px 0}
.superseded{background:#fde2e2;border:2px solid #a61b1b;padding:6px 10px;font-weight:600}
img{max-width:100%;border:1px solid #ddd}
.note{color:#555;font-size:12px}
footer{margin-top:30px;color:#666;font-size:11px;border-top:1px solid #ccc;padding-top:6px}
"""


def render_html(d: dict[str, Any], plots: bool = True) -> str:
    r = d["result"]
    camp = d["campaign"]
    gen = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    parts: list[str] = []
    add = parts.append
    add(f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>Calibration report {_e(camp)}</title><style>{_CSS}</style></head><body>")
    add(f"<h1>Calibration report — {_e(r.get('unit_serial'))}</h1>")
    add(f"<div class='sub'>Campaign <b>{_e(camp)}</b> · result "
        f"<span class='mono'>{_e(d['result_id'])}</span></div>")
    if not d["is_current"]:
        add(f"<div class='superseded'>This result is SUPERSEDED; the current result of the "
            f"campaign is <span class='mono'>{_e(d['current_result_id'])}</span>.</div>")

    rigs = ", ".join(d.get("rig_ids") or []) or "—"
    tests = ", ".join(d.get("tests") or []) or "—"
    kv = [("Unit serial", r.get("unit_serial")), ("Unit model", r.get("unit_model")),
          ("Rigs", rigs), ("Tests", tests),
          ("Data taken", f"{d.get('first_run') or '—'}  →  {d.get('last_run') or '—'}"),
          ("Computed", r.get("computed_at")), ("Status", "current" if d["is_current"] else
                                                  "superseded"),
          ("Code version", r.get("code_version")), ("Flow run", r.get("flow_run_id")),
          ("Coverage factor", "k = 2 (expanded uncertainty U = 2u, ≈ 95 %)")]
    add("<h2>1 Identification</h2><table class='kv'>" + "".join(
        f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in kv) + "</table>")

    # coefficients
    rows = []
    for c in d["coefficients"]:
        v, U, unit = display_value(c["name"], c.get("value"), c.get("std_uncertainty"),
                                   c.get("unit"))
        rows.append([c["name"], (v, "num"), (U, "num"), (unit, "nw"), c.get("method") or "",
                     (c.get("rig_id") or "", "nw"), (_fmt(c.get("dof"), ".0f"), "num"),
                     (_fmt(c.get("value"), ".6e"), "num"), c.get("unit") or "",
                     c.get("note") or ""])
    add("<h2>2 Calibrated coefficients</h2>")
    add(_table(["coefficient", "value", "U (k=2)", "display unit", "method", "rig", "dof",
                "value (SI)", "SI unit", "note"], rows) if rows else
        "<p>No coefficients.</p>")
    add("<p class='note'>K1 is shown in output unit per g with its relative expanded "
        "uncertainty; the other coefficients in the display units of the effects catalogue.</p>")

    # radius
    if d["radii"]:
        rows = [[(x.get("rig_id"), "nw"), x.get("polarity"), x.get("method"), _fmt(x.get("model_order")),
                 (_fmt(x.get("g_max"), ".1f"), "num"), (_fmt(x.get("radius_m"), ".6f"), "num"),
                 (_fmt(None if x.get("std_uncertainty_m") is None
                       else K_COVERAGE * 1e6 * x["std_uncertainty_m"], ".2f"), "num"),
                 x.get("note") or ""] for x in d["radii"]]
        add("<h2>3 Test radius</h2>")
        add(_table(["rig", "polarity", "method", "order", "g max / g", "radius / m",
                    "U (k=2) / µm", "note"], rows))
        if plots:
            img = radius_plot(d["radii"])
            if img:
                add(f"<img alt='radius plot' src='data:image/png;base64,{img}'>")

    # adequacy
    add("<h2>4 Model adequacy</h2>")
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
                         ("adequate" if ok else "NOT adequate", "ok" if ok else "bad"),
                         "✔" if a.get("chosen") else ""])
        add(_table(["rig", "fit", "order", "g max", "F", "p (lack of fit)", "dof lof/pe",
                    "trend p", "sweep p", "runs p", "verdict", "chosen"], rows))
    tum = (d.get("extras") or {}).get("tumble") or []
    if tum:
        rows = [[t.get("run_id"), (_fmt((t.get("lack_of_fit") or {}).get("F"), ".3g"), "num"),
                 (_fmt((t.get("lack_of_fit") or {}).get("p"), ".3g"), "num"),
                 (_fmt(t.get("dof")), "num"), (_fmt(t.get("residual_rms"), ".3g"), "num"),
                 t.get("note") or ""] for t in tum if isinstance(t, dict)]
        add("<p class='note'>Tumble fits (paper 003):</p>")
        add(_table(["run", "F (lack of fit)", "p", "dof", "residual rms / output unit", "note"],
                   rows))
    if not d["adequacy"] and not tum:
        add("<p>No adequacy tests in this result.</p>")
    if plots:
        img = residual_plot(d.get("extras"))
        if img:
            add("<p class='note'>Standardised dwell-mean residuals of the eq 9 fits "
                "(▲ up-sweep, ▼ down-sweep, ● rest; blue + polarity, red − polarity; "
                "dashed: ±3).</p>")
            add(f"<img alt='residual plot' src='data:image/png;base64,{img}'>")

    # alignment
    add("<h2>5 Alignment analysis</h2>")
    lam = [a for a in d["alignment"] if a.get("kind") == "lambda_c"]
    mounts = [a for a in d["alignment"] if a.get("kind") == "mount"]
    other = [a for a in d["alignment"] if a.get("kind") not in ("lambda_c", "mount")]
    if lam:
        rows = [[a.get("rig_id"), (_fmt(_mul(a.get("lambda_c+"), 1e6), ".2f"), "num"),
                 (_fmt(_mul(a.get("u_lambda_c+"), 2e6), ".2g"), "num"),
                 (_fmt(_mul(a.get("lambda_c-"), 1e6), ".2f"), "num"),
                 (_fmt(_mul(a.get("u_lambda_c-"), 2e6), ".2g"), "num")] for a in lam]
        add(_table(["rig", "λc+ / µrad", "U / µrad", "λc− / µrad", "U / µrad"], rows))
    if mounts:
        rows = [[a.get("rig_id"), a.get("pair"), (_fmt(a.get("phi0_deg"), ".0f"), "num"),
                 (_fmt(_mul(a.get("dphi1"), 1e3), ".3f"), "num"),
                 (_fmt(_mul(a.get("dphi2"), 1e3), ".3f"), "num"),
                 (_fmt(_mul(a.get("r"), 1e3), ".3f"), "num"),
                 (_ug_g2(a.get("c2")), "num"), (_ug_g2(a.get("dc2_1")), "num"),
                 (_ug_g2(a.get("dc2_2")), "num"),
                 (_ug_g2(None if a.get("u_dc2_typeB") is None else 2 * a["u_dc2_typeB"]), "num")]
                for a in mounts]
        add(_table(["rig", "mount pair", "φ0 / °", "Δφ1 / mrad", "Δφ2 / mrad",
                    "mass-centre offset r / mm", "c2 / µg/g²", "Δc2(1) / µg/g²",
                    "Δc2(2) / µg/g²", "U type B (Δc2) / µg/g²"], rows))
        add("<p class='note'>Δc2 from the mount angle error (paper 000 eq 8), treated as a "
            "uniform type-B term in the budget.</p>")
    for a in other:
        add(f"<p class='mono'>{_e(json.dumps(a, default=str))}</p>")
    if not d["alignment"]:
        add("<p>No alignment analysis in this result (no centrifuge runs).</p>")

    # budget
    if d["budget"]:
        rows = [[b.get("coefficient"), b.get("quantity"), (_fmt(b.get("value"), ".4g"), "num"),
                 (_fmt(b.get("std_uncertainty"), ".3g"), "num"),
                 (_fmt(b.get("sensitivity"), ".3g"), "num"),
                 (_fmt(b.get("contribution"), ".3g"), "num"), b.get("type"),
                 b.get("distribution")] for b in d["budget"]]
        add("<h2>6 Uncertainty budgets (GUM, SI units)</h2>")
        add(_table(["coefficient", "quantity", "value", "u", "sensitivity", "|c|·u", "type",
                    "distribution"], rows))

    # flags
    add("<h2>7 Flags</h2>")
    if d["flags"]:
        for f in d["flags"]:
            add(f"<div class='flag'>{_e(f)}</div>")
    else:
        add("<p>None.</p>")

    # lineage
    add("<h2>8 Lineage</h2>")
    rows = [[(x.get("run_id"), "nw"), _fmt(x.get("revision")), x.get("test"), (x.get("rig_id"), "nw"),
             (x.get("started_at"), "nw"), (x.get("sha256"), "mono"), (x.get("source_path"), "mono"),
             (x.get("flow_run_id"), "mono")] for x in d["lineage"]]
    add(_table(["run id", "rev", "test", "rig", "started", "sha256", "raw file",
                "ingest flow run"], rows))
    acts = [[a["seq"], (a["result_id"], "mono"), a["activated_at"], (a.get("flow_run_id"), "mono")]
            for a in d["activations"]]
    add("<p class='note'>Result history of this campaign (append-only; the last activation "
        "is current):</p>")
    add(_table(["#", "result id", "activated", "flow run"], acts))
    add(f"<footer>Generated {gen} by accelcal {_e(r.get('code_version'))} from the warehouse; "
        f"self-contained (no external resources). Parameters: "
        f"<span class='mono'>{_e(json.dumps(d.get('science_parameters'), sort_keys=True))}</span>"
        f"</footer></body></html>")
    return "".join(parts)


def _mul(x, f):
    return None if x is None else x * f


def _ug_g2(x) -> str:
    from ..effects import COEFFICIENTS
    if x is None:
        return "—"
    return f"{x / COEFFICIENTS['K2'].display_factor:.4g}"


def report_filename(campaign: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", campaign).strip("_") + ".html"


def build_report(warehouse: str | Path, campaign: str, out_dir: str | Path,
                 result_id: str | None = None, lock_timeout: float = 60.0) -> Path:
    """Write the campaign's report; returns the HTML path."""
    d = load_report_data(warehouse, campaign, result_id=result_id, lock_timeout=lock_timeout)
    text = render_html(d)
    out = Path(out_dir).expanduser()
    try:
        out.mkdir(parents=True, exist_ok=True)
        path = out / report_filename(campaign)
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise ReportError(f"cannot write report to {out}: {e.strerror}") from None
    return path


def list_campaigns(warehouse: str | Path) -> list[str]:
    import duckdb
    con = duckdb.connect(str(Path(warehouse).expanduser().resolve()), read_only=True)
    try:
        return [r[0] for r in con.execute(
            "SELECT DISTINCT campaign FROM result_activations ORDER BY campaign").fetchall()]
    finally:
        con.close()

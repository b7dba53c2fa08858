"""Terminal and HTML reports of a diagnosis (HTML: self-contained, PNGs embedded base64)."""
from __future__ import annotations

import base64
import html
import io
import json
import textwrap
from pathlib import Path

import numpy as np

from ..rounding import format_sig, format_sig_sci, round_gum_sci


def _f(v, fmt="{:.4g}"):
    return "-" if v is None else fmt.format(v)


def text_report(res: dict, width: int = 80) -> str:
    """The diagnosis as plain text for a terminal of ``width`` columns.

    Baseline, gap before and after (whitened rms [1] and in SI [m/s^2]), shrink in sample
    and held out, status, verdict and whether the gap is explained; the ranked effects
    (estimate ± u rounded as people read them, in the effect's effects.md unit, z, held-out
    shrink, observable fraction, significance, aliases on a line of their own); the
    unobservable effects, coefficient aliases, the Holm-significant segments (first 15) and
    the shape of the gap.  Every line fits ``width`` (long ones wrap, indented); the
    figures the text leaves out (delta chi2, in-sample shrinks per effect) are in --json.

    Parameters
    ----------
    res : dict
        Result of :func:`accelcal.diagnosis.core.diagnose`.
    width : int
        Columns of the terminal [1].

    Returns
    -------
    str
        Lines joined by newlines, no trailing newline.
    """
    L: list[str] = []

    def say(text: str, indent: str = "  ") -> None:
        L.extend(textwrap.wrap(text, width, subsequent_indent=indent, break_on_hyphens=False) or [""])

    g = res["gap"]
    lab, effs = res["baseline"]["label"], ", ".join(res["baseline"]["effects"]) or "bare model"
    say(f"baseline: {effs}" if lab.replace(" ", "") == effs.replace(" ", "") else f"baseline: {lab} ({effs})")
    sb, sa = g["significant_before"], g["significant_after"]
    say(f"gap before: {sb['status']}" + (f" (F = {format_sig(sb['F'], 3)}, p = {format_sig_sci(sb['p_value'])})"
                                         if sb["p_value"] is not None else ""))
    si = g["si"]
    say(f"gap, whitened rms: before {format_sig(g['rms_before'], 3)}, after {format_sig(g['rms_after'], 3)} "
        f"(noise {format_sig(g['noise_rms'], 2)}); in SI {format_sig_sci(si['rms_before_m_s2'])} -> "
        f"{format_sig_sci(si['rms_after_m_s2'])} m/s2 (noise {format_sig_sci(si['noise_rms_m_s2'])})")
    say(f"shrink: in sample {_f(g['shrink_in_sample'], '{:.2f}')}, held out {_f(g['shrink_heldout'], '{:.2f}')}")
    say(f"STATUS: {res['status']}")
    say(f"VERDICT: {res['verdict'] or 'none'}"
        + (f" (aliases: {', '.join(res['verdict_aliases'])})" if res.get("verdict_aliases") else "")
        + f"; explained: {'-' if res['explained'] is None else str(res['explained']).lower()}")
    if res["selected"]:
        say(f"effects found (forward selection, alpha {res['alpha']}): {', '.join(res['selected'])}; "
            f"gap after: {sa['status']}" + (f" (p = {format_sig_sci(sa['p_value'])})"
                                            if sa["p_value"] is not None else ""))
    if res.get("unexplained"):
        say("UNEXPLAINED: " + res["unexplained"]["text"])
    L.append("")
    L.append(f"{'effect':20s} {'estimate ± u':>27s} {'z':>6s} {'held-out':>8s} {'obs.':>6s} sig")
    for e in res["ranking"]:
        if e["estimate"] is None:
            est = "-"
        else:
            v, u = round_gum_sci(e["estimate"], e["std_uncertainty"])
            est = f"{v} ± {u} {e['unit']}"
        L.append(f"{e['effect'][:20]:20s} {est:>27s} {_f(e['z'], '{:.1f}'):>6s} "
                 f"{_f(e['shrink_heldout'], '{:.2f}'):>8s} {format_sig_sci(e['observable_fraction'], 2):>6s} "
                 f"{'*' if e['significant'] else ' ':>3s}")
        if e["aliases"]:
            say(f"    aliases: {', '.join(e['aliases'])}", "      ")
    if res["unobservable"]:
        L.append("")
        L.append("not observable in these runs:")
        for u in res["unobservable"]:
            say(f"  {u['effect']}: {u['note']}", "    ")
    for e in res["ranking"]:
        for ca in e.get("coefficient_aliases", []):
            if "value" in ca:                # the bare model keeps the unit's coefficient
                k = ca["coefficient"]
                v, u = round_gum_sci(ca["value"], ca["std_uncertainty"])
                alt = (e.get("alias_estimates") or {}).get(k)
                say(f"note: these runs cannot tell {e['effect']} from the unit's {k}; the calibration keeps "
                    f"{k} = {v} ± {u} {ca.get('unit', '')}".rstrip() + (f" (were it all {e['effect']}: {format_sig_sci(alt)} {e['unit']})"
                                         if alt is not None else ""))
                continue
            say(f"note: {e['effect']} is indistinguishable here from the coefficient {ca['coefficient']} "
                f"({ca['note']})")
    for d in res.get("determined") or []:       # the unit's coefficient, seen through the geometry
        say(f"note: {d['effect']}: {d['note']}")
    L.append("")
    say("where the gap lies before (Holm-significant segments, share of the dimension's excess chi2):")
    for w in res["where"][:15]:
        say(f"  {w['dimension']} {w['segment']}: share {w['share']:.2f}, chi2 {format_sig(w['chi2'], 3)} "
            f"(expected {format_sig(w['expected'], 3)}), mean residual "
            f"{format_sig_sci(w['mean_residual_m_s2'])} m/s2", "    ")
    if res.get("shape_before"):
        say("shape before: " + "; ".join(f"{s['form']} ({100 * s['explained_fraction']:.0f} %)"
                                         for s in res["shape_before"]))
    L.append(f"\n({len(res['runs'])} runs, {res['elapsed_s']:.2f} s)")
    return "\n".join(L)


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


#: The run's own axis of a residual plot, first found: (attribute, axis label).
_X_AXES = (("g_level", "centripetal input [g]"), ("position", "head / table position [°]"),
           ("temperature", "temperature [°C]"), ("time", "time from run start [s]"))
#: 1 µg in m/s² (the residual plots' unit, effects.md display of K0)
_UG = 1e-6 * 9.80665

_CSS = """body{font-family:'DejaVu Sans',Arial,sans-serif;max-width:1100px;margin:16px auto;
padding:0 12px;color:#1b1b1b;font-size:14px;line-height:1.4}
h1{font-size:22px;margin-bottom:4px} h2{font-size:17px;border-bottom:2px solid #2b4c7e;
padding-bottom:2px;margin-top:26px} .sub{color:#555}
.box{border:2px solid #2b4c7e;background:#f3f6fb;padding:8px 12px;margin:12px 0}
.box.bad{border-color:#a61b1b;background:#fdeeee} .big{font-size:18px;font-weight:700}
table{border-collapse:collapse;margin:6px 0;font-size:13px} th,td{border:1px solid #c9d1dc;
padding:3px 6px;vertical-align:top} th{background:#e9eef5;text-align:left}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
tr.sel td{background:#fff7e0} img{max-width:100%} .note{color:#555;font-size:12px}"""


def _esc(x) -> str:
    return html.escape("" if x is None else str(x))


def _unit_of(effect: str) -> str:
    from ..effects import EFFECTS
    e = EFFECTS.get(effect)
    return "" if e is None else e.unit


def _why_verdict(res: dict) -> str:
    """In words, why the verdict is the one named (the rule of
    :meth:`accelcal.diagnosis.core.Diagnosis.run`)."""
    from ..diagnosis.core import HELDOUT_GATE, HELDOUT_Z, VERDICT_STATISTIC
    v = res.get("verdict")
    rk = {e["effect"]: e for e in res["ranking"]}
    if not v:
        if res["gap"]["significant_before"]["status"] in ("adequate", "no gap"):
            return "No verdict: the bare model fits these runs within their noise."
        return ("No verdict: no catalogue effect was significant, passed the held-out test "
                "and carried the gap; see 'Unexplained' and where the gap lies.")
    e = rk[v]
    strong = [x["effect"] for x in res["ranking"] if x.get("selected") and x.get("significant")
              and (x.get("statistic") or 0) >= VERDICT_STATISTIC]
    parts = [f"{v} was selected by forward selection and is significant "
             f"(z = {_f(e.get('z'), '{:.1f}')}, Δχ² = {_f(e.get('delta_chi2'), '{:.3g}')}); "
             f"on the cells it was not fitted to it removes {_f(e.get('shrink_heldout'), '{:.2f}')} of "
             f"the gap (the gate is {HELDOUT_GATE:g}) and improves the prediction at held-out "
             f"z = {_f(e.get('heldout_z'), '{:.1f}')} (z >= {HELDOUT_Z:g} names an effect whatever "
             f"share of the gap it removes)."]
    others = [x for x in strong if x != v]
    if others:
        parts.append(f"Other effects also carry a five-sigma part of the misfit on their own "
                     f"({', '.join(others)}); of these, the one named first is the term the "
                     f"lab's processing model would add first for these tests, then the "
                     f"catalogue's order (effects.md). All are listed as significant below.")
    if res.get("verdict_aliases"):
        parts.append(f"The data cannot tell it from: {', '.join(res['verdict_aliases'])} "
                     f"(same signature in these runs).")
    return " ".join(parts)


def _residual_figure(res: dict):
    """Residuals per run, in µg of input, against the run's own axis, before and after."""
    import matplotlib.pyplot as plt

    from ..diagnosis.localise import residual_si
    fb, fa = res["_fits"]["before"], res["_fits"]["after"]
    rb, ra = residual_si(fb) / _UG, residual_si(fa) / _UG
    runs = fb.model.runs
    ncol = min(3, len(runs))
    nrow = (len(runs) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 2.9 * nrow), squeeze=False)
    for j, r in enumerate(runs):
        ax = axes[j // ncol, j % ncol]
        key, label = next(((k, lab) for k, lab in _X_AXES if k in r.attrs), ("time", "cell"))
        x = np.asarray(r.attrs.get(key, np.arange(r.ncell)), float)
        sl = fb.model.rows(j)
        ax.axhline(0, color="0.6", lw=0.8)
        ax.plot(x, rb[sl], "o", ms=3, color="C3", alpha=0.7, label="bare model (before)")
        ax.plot(x, ra[sl], "o", ms=3, color="C0", alpha=0.8, label="with the effects found (after)")
        ax.set_title(f"{r.run_id} ({r.test})", fontsize=9)
        ax.set_xlabel(label, fontsize=8)
        ax.set_ylabel("residual [µg]", fontsize=8)
        ax.tick_params(labelsize=7)
    for k in range(len(runs), nrow * ncol):
        axes[k // ncol, k % ncol].axis("off")
    h, lab = axes[0, 0].get_legend_handles_labels()
    fig.legend(h, lab, loc="upper center", ncol=2, fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return fig


def _shrink_figure(res: dict):
    """The gap's shrink, in sample and held out, overall and per effect found (bars)."""
    import matplotlib.pyplot as plt
    g = res["gap"]
    rows = [("all effects found", g.get("shrink_in_sample"), g.get("shrink_heldout"))]
    rows += [(e["effect"], e.get("shrink_in_sample"), e.get("shrink_heldout"))
             for e in res["ranking"] if e.get("selected")][:8]
    fig, ax = plt.subplots(figsize=(7.5, 0.55 * len(rows) + 1.2))
    yy = np.arange(len(rows))[::-1]
    ax.barh(yy + 0.18, [r[1] or 0 for r in rows], 0.36, color="C0", label="in sample")
    ax.barh(yy - 0.18, [r[2] or 0 for r in rows], 0.36, color="C2", label="held out")
    ax.set_yticks(yy)
    ax.set_yticklabels([r[0] for r in rows], fontsize=9)
    ax.set_xlim(0, 1.05)
    ax.set_xlabel("shrink of the gap (1 = the whole excess misfit explained)")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


def html_report(res: dict, out_dir, terminal: str | None = None,
                next_runs: list | None = None) -> Path:
    """A page an engineer reads: the verdict and why, where the gap lies (residual
    plots per run in µg against each run's own axis), the ranked effects with aliases, how
    far the gap shrinks in sample and held out, what cannot be seen; the full result as
    ``diagnosis.json`` beside it.  Self-contained (PNGs embedded), no scripts.

    Parameters
    ----------
    res : dict
        Result of :func:`accelcal.diagnosis.core.diagnose`.
    out_dir : str or Path
        Folder to write into (created if missing); ``diagnosis.html`` and
        ``diagnosis.json`` there are replaced atomically.
    terminal : str, optional
        The text the terminal prints (the report and the advice after it), shown whole in
        its order; default :func:`text_report`.
    next_runs : list of dict, optional
        The advice (:func:`accelcal.testdesign.next_runs`), kept in ``diagnosis.json``.

    Returns
    -------
    Path
        Path of ``diagnosis.html``.
    """
    import matplotlib
    matplotlib.use("Agg")

    from ..diagnosis.core import public
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pub = public(res)
    pub.pop("where_all", None)
    if next_runs is not None:
        pub["next_runs"] = next_runs
    from ..fileio import atomic_write
    atomic_write(out / "diagnosis.json",
                 lambda fh: fh.write(json.dumps(clean_json(pub), indent=1, default=_jd)), "w",
                 encoding="utf-8")
    g = res["gap"]
    sb, sa = g["significant_before"], g["significant_after"]
    bad = bool(res.get("unexplained")) or res.get("explained") is False
    B = [f"<h1>Sim-to-real diagnosis</h1><div class='sub'>{len(res['runs'])} runs · baseline "
         f"{_esc(res['baseline']['label'])} ({_esc(', '.join(res['baseline']['effects']) or 'bare model')})"
         f" · {res['elapsed_s']:.1f} s</div>"]
    B.append(f"<div class='box{' bad' if bad else ''}'><div class='big'>Verdict: "
             f"{_esc(res['verdict'] or 'none')}</div>"
             f"<div>status {_esc(res['status'])}; explained: "
             f"{'—' if res['explained'] is None else str(res['explained']).lower()}</div>"
             f"<div>gap before: {_esc(sb['status'])}"
             + (f" (F = {sb['F']:.3g}, p = {sb['p_value']:.2g})" if sb.get("p_value") is not None else "")
             + f"; after: {_esc(sa['status'])}"
             + (f" (p = {sa['p_value']:.2g})" if sa.get("p_value") is not None else "")
             + f"</div><div>residual rms {g['si']['rms_before_m_s2'] / _UG:.3g} µg before, "
             f"{g['si']['rms_after_m_s2'] / _UG:.3g} µg after (noise {g['si']['noise_rms_m_s2'] / _UG:.3g} µg)</div>"
             f"<p>{_esc(_why_verdict(res))}</p>"
             + (f"<p><b>Unexplained:</b> {_esc(res['unexplained']['text'])}</p>" if res.get("unexplained") else "")
             + "</div>")
    B.append("<h2>Where: residuals per run</h2><p class='note'>Cell-mean residuals in µg of "
             "input (whitened residual × noise ÷ K1) against each run's own axis; red: the "
             "baseline model, blue: with the effects found.</p>")
    B.append(f"<img alt='residuals per run' src='data:image/png;base64,{_png(_residual_figure(res))}'/>")
    if res["where"]:
        B.append("<table><tr><th>dimension</th><th>segment</th><th>share of the excess</th>"
                 "<th>χ² (expected)</th><th>mean residual / µg</th></tr>"
                 + "".join(f"<tr><td>{_esc(w['dimension'])}</td><td>{_esc(w['segment'])}</td>"
                           f"<td class='num'>{w['share']:.2f}</td><td class='num'>{w['chi2']:.3g} "
                           f"({w['expected']:.3g})</td><td class='num'>"
                           f"{w['mean_residual_m_s2'] / _UG:.3g}</td></tr>" for w in res["where"][:15])
                 + "</table>")
    if res.get("shape_before"):
        B.append("<p>Shape of the gap before: " + _esc("; ".join(
            f"{x['form']} ({100 * x['explained_fraction']:.0f} %)" for x in res["shape_before"])) + "</p>")
    B.append("<h2>Which: the effects, ranked</h2><p class='note'>Estimate ± standard "
             "uncertainty in the effect's unit (effects.md); z = estimate / u; shrink of the gap "
             "in sample and on held-out data; observable fraction: the part of the effect's "
             "signature the baseline cannot absorb. Highlighted: selected.</p>")
    rows = []
    for e in res["ranking"]:
        est, u = round_gum_sci(e.get("estimate"), e.get("std_uncertainty"))
        rows.append(f"<tr class='{'sel' if e.get('selected') else ''}'><td>{_esc(e['effect'])}</td>"
                    f"<td class='num'>{_esc(est)} ± {_esc(u)}</td>"
                    f"<td>{_esc(_unit_of(e['effect']))}</td>"
                    f"<td class='num'>{_f(e.get('z'), '{:.1f}')}</td>"
                    f"<td class='num'>{_f(e.get('delta_chi2'), '{:.3g}')}</td>"
                    f"<td class='num'>{_f(e.get('shrink_in_sample'), '{:.2f}')}</td>"
                    f"<td class='num'>{_f(e.get('shrink_heldout'), '{:.2f}')}</td>"
                    f"<td class='num'>{_f(e.get('observable_fraction'), '{:.2g}')}</td>"
                    f"<td>{'yes' if e.get('significant') else ''}</td>"
                    f"<td>{_esc(', '.join(e.get('aliases') or []))}</td></tr>")
    B.append("<table><tr><th>effect</th><th>estimate ± u</th><th>unit</th><th>z</th><th>Δχ²</th>"
             "<th>shrink in sample</th><th>shrink held out</th><th>observable fraction</th>"
             "<th>significant</th><th>aliases</th></tr>" + "".join(rows) + "</table>")
    notes = [f"{e['effect']} cannot be told here from the instrument coefficient "
             f"{ca['coefficient']} ({ca['note']})" for e in res["ranking"]
             for ca in e.get("coefficient_aliases", [])]
    if res["unobservable"] or notes:
        B.append("<h2>What these runs cannot see</h2><ul>"
                 + "".join(f"<li><b>{_esc(u['effect'])}</b>: {_esc(u['note'])}</li>" for u in res["unobservable"])
                 + "".join(f"<li>{_esc(n)}</li>" for n in notes) + "</ul>")
    B.append("<h2>How far: the gap's shrink</h2>")
    B.append(f"<img alt='shrink' src='data:image/png;base64,{_png(_shrink_figure(res))}'/>")
    B.append("<h2>The whole result</h2><p><a href='diagnosis.json'>diagnosis.json</a> (every "
             "number above, and more, as JSON). The same text as the terminal prints:</p>"
             f"<pre style='white-space:pre-wrap;font-size:12px'>{_esc(terminal or text_report(res))}</pre>")
    p = out / "diagnosis.html"
    page = ("<!doctype html><html lang='en'><head><meta charset='utf-8'><title>accelcal "
            f"diagnosis</title><style>{_CSS}</style></head><body>" + "\n".join(B) + "</body></html>")
    atomic_write(p, lambda fh: fh.write(page), "w", encoding="utf-8")
    return p


def clean_json(o):
    """The same structure with non-finite floats as None (strict JSON).

    Parameters
    ----------
    o : object
        Nested dicts, lists, tuples, numpy arrays and scalars.

    Returns
    -------
    object
        The same values with tuples and arrays as lists, numpy floats and integers as Python
        ones and nan/inf as None; other objects unchanged.
    """
    if isinstance(o, dict):
        return {k: clean_json(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [clean_json(v) for v in o]
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.ndarray):
        return clean_json(o.tolist())
    return o


def _jd(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, float) and not np.isfinite(o):
        return None
    return str(o)

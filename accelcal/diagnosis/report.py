"""Terminal and HTML reports of a diagnosis (HTML: self-contained, PNGs embedded base64)."""
from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

import numpy as np


def _f(v, fmt="{:.4g}"):
    return "-" if v is None else fmt.format(v)


def text_report(res: dict) -> str:
    L = []
    g = res["gap"]
    L.append(f"baseline: {res['baseline']['label']} ({', '.join(res['baseline']['effects']) or 'bare model'})")
    sb, sa = g["significant_before"], g["significant_after"]
    L.append(f"gap before: {sb['status']}"
             + (f" (F = {sb['F']:.4g}, p = {sb['p_value']:.3g})" if sb["p_value"] is not None else ""))
    L.append(f"gap (whitened rms, noise = {_f(g['noise_rms'], '{:.3f}')}): before {g['rms_before']:.4g}, after "
             f"{g['rms_after']:.4g}; in SI {g['si']['rms_before_m_s2']:.3g} -> {g['si']['rms_after_m_s2']:.3g} m/s2"
             f" (noise {g['si']['noise_rms_m_s2']:.3g})")
    L.append(f"shrink: in sample {_f(g['shrink_in_sample'], '{:.3f}')}, held out {_f(g['shrink_heldout'], '{:.3f}')}")
    L.append(f"STATUS: {res['status']}")
    L.append(f"VERDICT: {res['verdict'] or 'none'}"
             + (f" (aliases: {', '.join(res['verdict_aliases'])})" if res.get("verdict_aliases") else "")
             + f"; explained: {'-' if res['explained'] is None else str(res['explained']).lower()}")
    if res["selected"]:
        L.append(f"effects found (forward selection, alpha {res['alpha']}): {', '.join(res['selected'])}; "
                 f"gap after: {sa['status']}" + (f" (p = {sa['p_value']:.3g})" if sa["p_value"] is not None else ""))
    if res.get("unexplained"):
        L.append("UNEXPLAINED: " + res["unexplained"]["text"])
    L.append("")
    L.append(f"{'effect':22s} {'estimate':>12s} {'u':>10s} {'z':>8s} {'dchi2':>10s} {'shrink':>7s} {'heldout':>7s} "
             f"{'obs.frac':>9s} sig aliases")
    for e in res["ranking"]:
        L.append(f"{e['effect']:22s} {_f(e['estimate']):>12s} {_f(e['std_uncertainty'], '{:.2g}'):>10s} "
                 f"{_f(e['z'], '{:.1f}'):>8s} {_f(e['delta_chi2'], '{:.3g}'):>10s} "
                 f"{_f(e['shrink_in_sample'], '{:.2f}'):>7s} {_f(e['shrink_heldout'], '{:.2f}'):>7s} "
                 f"{_f(e['observable_fraction'], '{:.3g}'):>9s} {'*' if e['significant'] else ' ':>3s} "
                 f"{','.join(e['aliases'])}")
    if res["unobservable"]:
        L.append("")
        L.append("not observable in these runs:")
        for u in res["unobservable"]:
            L.append(f"  {u['effect']}: {u['note']}")
    for e in res["ranking"]:
        for ca in e.get("coefficient_aliases", []):
            L.append(f"note: {e['effect']} is indistinguishable here from the coefficient {ca['coefficient']} "
                     f"({ca['note']})")
    L.append("")
    L.append("where the gap lies before (Holm-significant segments, share of the dimension's excess chi2):")
    for w in res["where"][:15]:
        L.append(f"  {w['dimension']:12s} {w['segment']:28s} share {w['share']:.2f}  chi2 {w['chi2']:.4g} "
                 f"(expected {w['expected']:.3g}), mean residual {w['mean_residual_m_s2']:.3g} m/s2")
    if res.get("shape_before"):
        L.append("shape before: " + "; ".join(f"{s['form']} ({100 * s['explained_fraction']:.0f} %)"
                                              for s in res["shape_before"]))
    L.append(f"\n({len(res['runs'])} runs, {res['elapsed_s']:.2f} s)")
    return "\n".join(L)


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def html_report(res: dict, out_dir) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fb, fa = res["_fits"]["before"], res["_fits"]["after"]
    runs = fb.model.runs
    imgs = []
    dims = ["g_level", "time_frac", "position", "temperature"]
    fig, axes = plt.subplots(2, len(dims) + 1, figsize=(4 * (len(dims) + 1), 6.5), squeeze=False)
    for row, (f, lab) in enumerate(((fb, "before"), (fa, "after"))):
        ax = axes[row, 0]
        for j, r in enumerate(runs):
            zz = f.z[f.model.rows(j)]
            ax.plot(np.full(zz.size, j) + np.linspace(-0.3, 0.3, zz.size), zz, ".", ms=3)
        ax.set_xticks(range(len(runs)))
        ax.set_xticklabels([r.run_id[-4:] for r in runs], rotation=90, fontsize=7)
        ax.set_ylabel(f"z ({lab})")
        ax.set_title("residual by run")
        for k, d in enumerate(dims):
            ax = axes[row, k + 1]
            for j, r in enumerate(runs):
                if d in r.attrs:
                    ax.plot(r.attrs[d], f.z[f.model.rows(j)], ".", ms=3)
            ax.set_title(f"residual vs {d}")
    imgs.append(("Whitened residuals before (top) and after (bottom) adding the effects found", _png(fig)))
    rk = [e for e in res["ranking"] if e["delta_chi2"] is not None and e["delta_chi2"] > 0][:10]
    if rk:
        fig, ax = plt.subplots(figsize=(7, 3.5))
        ax.barh([e["effect"] for e in rk][::-1], [max(e["delta_chi2"], 1e-3) for e in rk][::-1],
                color=["C3" if e["significant"] else "C0" for e in rk][::-1])
        ax.set_xscale("log")
        ax.set_xlabel("delta chi2 (red: selected)")
        imgs.append(("Ranking", _png(fig)))
    obs = [e for e in res["ranking"] if e["observable_fraction"] is not None]
    if obs:
        fig, ax = plt.subplots(figsize=(7, 3.5))
        ax.barh([e["effect"] for e in obs][::-1], [max(e["observable_fraction"], 1e-6) for e in obs][::-1])
        ax.set_xscale("log")
        ax.axvline(1e-3, color="k", ls="--")
        ax.set_xlabel("observable fraction |P_perp j| / |j| (left of the line: absorbed by the baseline)")
        imgs.append(("Aliasing / observability picture", _png(fig)))
    body = [f"<h1>accelcal diagnosis</h1><pre>{html.escape(text_report(res))}</pre>"]
    for title, b64 in imgs:
        body.append(f"<h2>{html.escape(title)}</h2><img src='data:image/png;base64,{b64}'/>")
    from .core import public
    pub = public(res)
    pub.pop("where_all", None)
    body.append(f"<h2>JSON</h2><pre>{html.escape(json.dumps(clean_json(pub), indent=1, default=_jd))}</pre>")
    p = out / "diagnosis.html"
    p.write_text("<!doctype html><html><head><meta charset='utf-8'><title>accelcal diagnosis</title></head><body>"
                 + "\n".join(body) + "</body></html>", encoding="utf-8")
    return p


def clean_json(o):
    """The same structure with non-finite floats as None (strict JSON)."""
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

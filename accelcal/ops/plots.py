"""Plots of the calibration certificate (matplotlib, PNG, base64 for inline embedding).

Each function takes what the warehouse stores and returns a base64 PNG, or None when
there is nothing to plot.  Residual plots exist for every test kind whose result stores
something to plot: the eq 9 dwell residuals (centrifuge), the per-temperature-point
residuals from the temperature model (thermal), the per-run residual rms of the joint
fit (sine), and any ``extras["residual_series"]`` a method provides.
"""
from __future__ import annotations

import base64
import io
import math
from typing import Any

K_COVERAGE = 2.0


def _plt():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def _panels(n: int, sharey: bool = False):
    """A figure with n panels, three per row; returns (figure, the n axes in order)."""
    plt = _plt()
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 2.9 * nrow), squeeze=False,
                             sharey=sharey)
    flat = [ax for row in axes for ax in row]
    for ax in flat[n:]:
        ax.axis("off")
    return fig, flat[:n]


def _residual_axes(ax, x_label: str, y_label: bool = True) -> None:
    """Dashed ±3 limits, the zero line and the labels of a standardised-residual panel."""
    for lim in (-3, 3):
        ax.axhline(lim, color="#888", lw=0.6, ls="--")
    ax.axhline(0, color="#444", lw=0.6)
    ax.set_xlabel(x_label, fontsize=8)
    if y_label:
        ax.set_ylabel("standardised residual", fontsize=8)
    ax.tick_params(labelsize=7)


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    _plt().close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def residual_plot(extras: dict[str, Any] | None) -> str | None:
    """Standardised dwell residuals of the eq 9 fits against centripetal g, one panel per pair."""
    pairs = [(rig, p) for rig, ps in ((extras or {}).get("pairs") or {}).items() for p in ps
             if isinstance(p, dict) and isinstance(p.get("dwells"), dict)]
    if not pairs:
        return None
    from ..constants import G_STANDARD
    fig, axes = _panels(len(pairs), sharey=True)
    for k, (rig, p) in enumerate(pairs):
        ax = axes[k]
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
        ax.set_title(f"{rig} {p.get('pair', '')} (order {p.get('order', '?')})", fontsize=9)
        _residual_axes(ax, "input acceleration along IA (signed) / g", y_label=k % 3 == 0)
    h, lab = axes[0].get_legend_handles_labels()
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
    plt = _plt()
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


def thermal_residual_plot(extras: dict[str, Any] | None) -> str | None:
    """Per temperature point: the point's K0 and K1 minus the temperature model's value at
    its temperature, in units of the point's standard uncertainty (paper 001)."""
    runs = [(rid, t) for rid, t in ((extras or {}).get("thermal") or {}).items()
            if isinstance(t, dict) and t.get("points") and t.get("temperature_model")]
    if not runs:
        return None
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(9.0, 3.0), squeeze=False)
    for rid, t in runs:
        m = t["temperature_model"]
        tref = float(m.get("t_ref_c", 20.0))
        pts = [p for p in t["points"] if p.get("temp_c") is not None]
        T = [p["temp_c"] for p in pts]
        r0 = [(p["K0"] - (m["K0"] + m["K0T"] * (p["temp_c"] - tref))) / p["u_K0"]
              if p.get("u_K0") else None for p in pts]
        r1 = [(p["K1"] - m["K1"] * (1 + m["K1T"] * (p["temp_c"] - tref))) / p["u_K1"]
              if p.get("u_K1") else None for p in pts]
        for ax, r, name in ((axes[0][0], r0, "K0"), (axes[0][1], r1, "K1")):
            xs = [x for x, y in zip(T, r) if y is not None]
            ys = [y for y in r if y is not None]
            ax.scatter(xs, ys, s=16, label=rid)
            ax.set_title(f"{name} per point − temperature model", fontsize=9)
    for ax in axes[0]:
        _residual_axes(ax, "instrument temperature / °C")
    fig.tight_layout()
    return _png(fig)


def sine_residual_plot(extras: dict[str, Any] | None) -> str | None:
    """Per run: the rms residual of the joint fit relative to the fit's pooled sigma (a run
    whose model misses shows as a bar well above 1)."""
    rigs = [(rig, s) for rig, s in ((extras or {}).get("sine") or {}).items()
            if isinstance(s, dict) and isinstance(s.get("residual_rms"), dict) and s.get("sigma")]
    if not rigs:
        return None
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.0, 2.8))
    labels, vals = [], []
    for rig, s in rigs:
        for run, rms in sorted(s["residual_rms"].items()):
            labels.append(f"{rig} {run}")
            vals.append(rms / s["sigma"])
    ax.bar(range(len(vals)), vals, color="#1f5fa8")
    ax.axhline(1.0, color="#444", lw=0.8, ls="--")
    ax.set_xticks(range(len(vals)), labels, fontsize=7, rotation=15)
    ax.set_ylabel("rms residual / pooled σ", fontsize=8)
    ax.set_title("sine fit: residual rms per run", fontsize=9)
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    return _png(fig)


def series_residual_plot(extras: dict[str, Any] | None) -> str | None:
    """Any residual series a method stores as ``extras["residual_series"]``: a list of
    {"title", "x_label", "x": [...], "std_resid": [...]} (one panel each)."""
    series = [s for s in ((extras or {}).get("residual_series") or [])
              if isinstance(s, dict) and s.get("x") and s.get("std_resid")]
    if not series:
        return None
    fig, axes = _panels(len(series))
    for ax, s in zip(axes, series):
        ax.scatter(s["x"], s["std_resid"], s=10)
        ax.set_title(str(s.get("title", "")), fontsize=9)
        _residual_axes(ax, str(s.get("x_label", "")))
    fig.tight_layout()
    return _png(fig)

"""Plots of the calibration certificate (matplotlib, PNG, base64 for inline embedding).

Each function takes what the warehouse stores, or a typed figure a method made of it, and
returns a base64 PNG, or None when there is nothing to plot.  The residual figures are the
methods' own (:class:`accelcal.results.ResidualFigure`, from
:func:`accelcal.estimators.registry.residual_figures`): a method states the data, this module
chooses how they look (layout, colours, markers, the key in the caption) by what the figure
shows, and never reads a method's extras.
"""
from __future__ import annotations

import base64
import io
import math
from typing import Any

from ..results import ResidualFigure

K_COVERAGE = 2.0

#: Colour of a dwell series by its IA polarity, and marker by its sweep (``'dwells'``)
POLARITY_COLOUR = {1: "#1f5fa8", -1: "#c0392b"}
SWEEP_MARKER = {"up": "^", "down": "v", "rest": "o"}
#: The key a figure's caption gives for how it is drawn, by what it shows
CAPTION_KEY = {"dwells": "▲ up-sweep, ▼ down-sweep, ● rest; blue + polarity, red − polarity; dashed: ±3"}


def figure_caption(fig: ResidualFigure) -> str:
    """A residual figure's caption with the key to how :func:`residual_figure` draws it.

    Parameters
    ----------
    fig : ResidualFigure

    Returns
    -------
    str
        The method's caption, its key in brackets before the full stop where the figure's
        style has one (:data:`CAPTION_KEY`).
    """
    key = CAPTION_KEY.get(fig.style)
    return f"{fig.caption.rstrip('.')} ({key})." if key else fig.caption


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


def residual_figure(fig: ResidualFigure) -> str | None:
    """Draw a method's residual figure by its style (``accelcal.results.FIGURE_STYLES``).

    Parameters
    ----------
    fig : ResidualFigure

    Returns
    -------
    str or None
        Base64 PNG; None for a figure without panels.
    """
    panels = list(fig.panels)
    if not panels:
        return None
    if fig.style == "bars":
        return _bars(fig, panels[0])
    if fig.style == "points":
        figure, axes = _plt().subplots(1, len(panels), figsize=(4.5 * len(panels), 3.0), squeeze=False)
        axes = list(axes[0])
    else:
        figure, axes = _panels(len(panels), sharey=fig.style == "dwells")
    size = {"dwells": 14, "points": 16, "series": 10}[fig.style]
    for k, (ax, p) in enumerate(zip(axes, panels)):
        for sr in p.series:
            kw = {"s": size}
            if fig.style == "dwells":
                kw.update(marker=SWEEP_MARKER.get(sr.sweep, "o"), color=POLARITY_COLOUR.get(sr.polarity),
                          alpha=0.8)
            elif sr.colour is not None:
                kw["color"] = sr.colour
            if sr.label:
                kw["label"] = sr.label
            ax.scatter(list(sr.x), list(sr.y), **kw)
        ax.set_title(p.title, fontsize=9)
        _residual_axes(ax, p.x_label, y_label=k % 3 == 0 or fig.style != "dwells")
    if fig.style == "dwells":
        h, lab = axes[0].get_legend_handles_labels()
        if h:
            figure.legend(h, lab, loc="upper center", ncol=6, fontsize=7, frameon=False,
                          bbox_to_anchor=(0.5, 1.04))
    figure.tight_layout()
    return _png(figure)


def _bars(fig: ResidualFigure, p) -> str:
    """A ``'bars'`` figure: one bar per tick, the line at 1."""
    figure, ax = _plt().subplots(figsize=(6.0, 2.8))
    vals = list(p.series[0].y)
    ax.bar(range(len(vals)), vals, color=p.series[0].colour or "#1f5fa8")
    ax.axhline(1.0, color="#444", lw=0.8, ls="--")
    ax.set_xticks(range(len(vals)), list(p.ticks), fontsize=7, rotation=15)
    ax.set_ylabel(fig.y_label, fontsize=8)
    ax.set_title(p.title, fontsize=9)
    ax.tick_params(labelsize=7)
    figure.tight_layout()
    return _png(figure)

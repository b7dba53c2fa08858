"""Result records that the science returns and the warehouse stores.

The science (estimators) fills a :class:`CampaignResult` per campaign; the
warehouse writes it in one transaction with its lineage.  Values are SI
(effects.md units); display conversion happens only at the edges (CLI, report).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class CoefficientResult:
    """One calibrated coefficient. name: an effects.md id (K0, K1, K2, ..., theta0, K0T, K1T)."""
    name: str
    value: float
    std_uncertainty: float
    unit: str
    method: str                 # e.g. 'tumble_lm', 'centrifuge_eq9', 'tilt_rotation_ls', 'sine_ls'
    rig_id: str = ""
    dof: float | None = None
    note: str = ""
    #: True for the value the lab adopts (the joint fit through the forward model, one per
    #: campaign and coefficient); the paper methods are stored beside it as cross-checks.
    adopted: bool = False
    #: k of U = k u for a coverage probability of about 95 %: 2, or Student's t(dof) when the
    #: uncertainty rests on few degrees of freedom (a lack-of-fit-scaled u, JCGM 100 G.3)
    coverage_factor: float = 2.0
    #: for a combination the design determines (name ``"K1(Koq,K3)"``,
    #: :func:`accelcal.effects.combination_name`): each term it takes up -> its factor
    #: [unit of the quantity / unit of the term]; empty for a coefficient determined alone
    factors: dict[str, float] = field(default_factory=dict)


@dataclass
class RadiusResult:
    """Test radius of one polarity (paper 000, 2.1). method: 'static' or 'iterative'."""
    rig_id: str
    polarity: str               # '+' (phi = 0) or '-' (phi = 180 deg)
    method: str
    model_order: int | None     # None for the static back-calculation
    g_max: float | None         # upper end of the g range used, in g; None for static
    radius_m: float
    std_uncertainty_m: float
    note: str = ""


@dataclass
class AdequacyResult:
    """Model adequacy of one regression (lack-of-fit F test + residual checks)."""
    rig_id: str
    fit: str                    # which regression, e.g. 'radius IA-PA 0/180' or 'eq9 IA-PA 45/225'
    model_order: int
    g_max: float | None
    f_statistic: float
    p_value: float
    dof_lack_of_fit: int
    dof_pure_error: int
    trend_p: float              # residual trend in time
    sweep_p: float              # up-versus-down sweep difference
    runs_p: float               # Wald-Wolfowitz run of signs
    adequate: bool
    chosen: bool = False
    note: str = ""


@dataclass
class BudgetTerm:
    """One line of a GUM uncertainty budget (JCGM 100)."""
    coefficient: str
    quantity: str
    value: float
    std_uncertainty: float
    sensitivity: float
    contribution: float         # |sensitivity| * std_uncertainty
    type: str                   # 'A' or 'B'
    distribution: str           # 'normal', 'uniform', ...
    #: the method whose coefficient this line belongs to ('' for a line written without one)
    #: and its rig: several methods give the same coefficient
    method: str = ""
    rig_id: str = ""


@dataclass
class CampaignResult:
    campaign: str
    unit_serial: str
    unit_model: str
    tests: list[str]
    rig_ids: list[str]
    input_sha256: list[str]                       # every run the result rests on
    coefficients: list[CoefficientResult] = field(default_factory=list)
    radii: list[RadiusResult] = field(default_factory=list)
    adequacy: list[AdequacyResult] = field(default_factory=list)
    budget: list[BudgetTerm] = field(default_factory=list)
    alignment: list[dict[str, Any]] = field(default_factory=list)
    extras: dict[str, Any] = field(default_factory=dict)   # JSON-able: per-pair fits, two-position values...
    flags: list[str] = field(default_factory=list)         # human-readable warnings (inadequate fit, ...)
    parameters: dict[str, Any] = field(default_factory=dict)
    #: 'complete' when the runs determine the coefficients of their tests with degrees of
    #: freedom to spare for an adequacy test; 'incomplete' otherwise (stored, visible, but
    #: kept out of history, En and the fleet views).  The reasons say what is missing.
    completeness: str = "complete"
    completeness_reasons: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# ------------------------------------------------------------------ what the report draws
#
# The science-to-report contract of the residual figures: each paper method
# turns what it stored (its own ``extras``) into ResidualFigure records
# (:attr:`accelcal.estimators.registry.Estimator.figures`); the certificate draws those
# (:func:`accelcal.ops.plots.residual_figure`) and never reads a method's extras itself.

#: What a figure shows, which decides how accelcal.ops.plots draws it: ``'dwells'`` residuals
#: of dwell means by polarity and sweep, a panel per mount pair (the eq 9 fits); ``'points'``
#: per-point residuals, a panel per quantity; ``'bars'`` one ratio to sigma per tick;
#: ``'series'`` plain residual series, a panel each.
FIGURE_STYLES = ("dwells", "points", "bars", "series")


@dataclass(frozen=True)
class ResidualSeries:
    """One set of points of a residual panel.

    Attributes
    ----------
    label : str
        Legend text ('' for none).
    x : tuple of float
        Abscissae [the panel's ``x_label`` unit]; bar positions for ``'bars'``.
    y : tuple of float
        Standardised residuals [1] (``'bars'``: a ratio to sigma [1]).
    polarity : int or None
        +1 or -1: the IA polarity of the dwells (``'dwells'``); None otherwise.
    sweep : str or None
        'up', 'down' or 'rest': the sweep of the dwells (``'dwells'``); None otherwise.
    colour : str or None
        matplotlib colour; None: the drawing's own.
    """
    label: str
    x: tuple[float, ...]
    y: tuple[float, ...]
    polarity: int | None = None
    sweep: str | None = None
    colour: str | None = None


@dataclass(frozen=True)
class ResidualPanel:
    """One panel of a residual figure: its title, x label, series and (``'bars'``) the
    text under each bar."""
    title: str
    x_label: str
    series: tuple[ResidualSeries, ...]
    ticks: tuple[str, ...] = ()


@dataclass(frozen=True)
class ResidualFigure:
    """A residual figure of the certificate, as a method states it.

    Attributes
    ----------
    style : str
        One of :data:`FIGURE_STYLES`.
    caption : str
        What the figure shows, in the certificate's words.
    panels : tuple of ResidualPanel
    y_label : str
        The y axis [1].
    """
    style: str
    caption: str
    panels: tuple[ResidualPanel, ...]
    y_label: str = "standardised residual"

    def __post_init__(self):
        if self.style not in FIGURE_STYLES:
            raise ValueError(f"figure style {self.style!r}: one of {', '.join(FIGURE_STYLES)}")


def stored_series_figures(extras: dict[str, Any] | None) -> list[ResidualFigure]:
    """Residual series any method stored as ``extras["residual_series"]`` (a list of
    ``{"title", "x_label", "x": [...], "std_resid": [...]}``), as one ``'series'`` figure.

    Parameters
    ----------
    extras : dict or None
        A stored result's extras.

    Returns
    -------
    list of ResidualFigure
        Empty when no series has points.
    """
    series = [s for s in ((extras or {}).get("residual_series") or [])
              if isinstance(s, dict) and s.get("x") and s.get("std_resid")]
    if not series:
        return []
    return [ResidualFigure("series", "Residual series stored by the method.", tuple(
        ResidualPanel(str(s.get("title", "")), str(s.get("x_label", "")),
                      (ResidualSeries("", tuple(s["x"]), tuple(s["std_resid"])),))
        for s in series))]


# ------------------------------------------------------------------ what the report lists
#
# The fit statistics a method stores (its lack-of-fit test, term F tests, residual trends)
# reach the certificate's adequacy section as FitCheck records
# (:attr:`accelcal.estimators.registry.Estimator.checks`), the way the residual figures do.

def display_number(x: Any, spec: str = ".4g") -> str:
    """A number as a table cell shows it: ``format(x, spec)``; '—' for None or nan,
    'yes'/'no' for a bool, ``str`` for anything else."""
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        if math.isnan(x):
            return "—"
        return format(x, spec)
    return str(x)


@dataclass(frozen=True)
class FitCheck:
    """One adequacy or term test a method stored, as the certificate lists it.

    Attributes
    ----------
    test : str
        Test kind ('tumble', 'thermal', 'sine').
    fit : str or None
        The run or rig it belongs to.
    check : str
        What is tested, in the certificate's words.
    statistic : str
        The statistic as shown (e.g. 'F = 1.23') [display units].
    dof : str
        Its degrees of freedom as shown ('3 / 40', or '—').
    p : float or None
        p-value [1]; the check passes when p >= the adequacy alpha.
    passes : bool or None
        The method's own verdict where there is no p-value (None: none).
    yes, no : str
        The verdict's words when it passes, when it does not.
    """
    test: str
    fit: Any
    check: str
    statistic: str
    dof: str
    p: float | None = None
    passes: bool | None = None
    yes: str = "adequate"
    no: str = "NOT adequate"

    def verdict(self, alpha: float) -> tuple[str, str]:
        """(words, 'ok' | 'bad' | '') at the adequacy level ``alpha`` [1]."""
        good = (self.p >= alpha) if self.p is not None else self.passes
        if good is None:
            return ("—", "")
        return (self.yes if good else self.no, "ok" if good else "bad")


@dataclass(frozen=True)
class MonteCarloCheck:
    """The JCGM 101 §8 check of one coefficient's GUM budget, as stored in
    ``extras['mc_check']`` under ``'<method>:<rig_id>:<coefficient>'``
    (:func:`accelcal.estimators.uncertainty.budget_check` writes one).

    Attributes
    ----------
    key : str
        Its key in the stored extras.
    method, rig_id, coefficient : str
        The coefficient checked.
    validated : bool
        The GUM interval's end points are within ``delta`` of the Monte Carlo ones (PASS).
    gum_u, mc_u : float or None
        Standard uncertainty by the GUM and by the propagated distribution [coefficient unit].
    mc_low, mc_high : float or None
        The 95 % coverage interval of the propagated distribution [coefficient unit].
    delta : float or None
        Numerical tolerance of the comparison (JCGM 101 7.9.2) [coefficient unit].
    """
    key: str
    method: str = ""
    rig_id: str = ""
    coefficient: str = ""
    validated: bool = False
    gum_u: float | None = None
    mc_u: float | None = None
    mc_low: float | None = None
    mc_high: float | None = None
    delta: float | None = None

    def meaning(self) -> str:
        """In words, what a FAIL says of the stated U (empty for a PASS or when the
        interval is not stored)."""
        if self.validated or None in (self.gum_u, self.mc_low, self.mc_high):
            return ""
        from scipy.stats import norm
        half_gum = float(norm.ppf(0.975)) * self.gum_u
        if (self.mc_high - self.mc_low) / 2 < half_gum:
            return ("U is conservative: the output is flatter than normal (uniform type-B terms "
                    "dominate), so y ± U covers more than 95 %")
        return "U covers less than 95 %: the Monte Carlo interval is the 95 % coverage interval"


def monte_carlo_checks(extras: dict[str, Any] | None) -> list[MonteCarloCheck]:
    """The JCGM 101 checks of a stored result, in key order (entries that are not a
    check's record are passed over)."""
    out = []
    for key, m in sorted(((extras or {}).get("mc_check") or {}).items()):
        if isinstance(m, dict):
            out.append(MonteCarloCheck(
                key, str(m.get("method") or ""), str(m.get("rig_id") or ""), str(m.get("coefficient") or ""),
                bool(m.get("validated")), *(m.get(k) for k in ("gum_u", "mc_u", "mc_low", "mc_high", "delta"))))
    return out

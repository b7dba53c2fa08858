"""Result records that the science returns and the warehouse stores.

The science (estimators) fills a :class:`CampaignResult` per campaign; the
warehouse writes it in one transaction with its lineage.  Values are SI
(effects.md units); display conversion happens only at the edges (CLI, report).
"""
from __future__ import annotations

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

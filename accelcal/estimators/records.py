"""The records one paper method adds to a :class:`~accelcal.results.CampaignResult`."""
from __future__ import annotations

import json
from dataclasses import dataclass, field

from ..results import AdequacyResult, BudgetTerm, CoefficientResult, RadiusResult


def run_columns(run):
    """The columns of a RunFile-like run for a method that reads them as arrays: the
    parser's own numpy arrays (``RunFile.arrays``) where the run has them in memory, else
    its ``data`` (a DataFrame's column lookup costs more than the arithmetic of a small
    run, and the methods look up each column many times)."""
    a = getattr(run, "arrays", None)
    return a if isinstance(a, dict) else run.data


def jsonable(obj):
    """A JSON-able copy of a method's extras: numpy values as Python ones, non-finite
    floats as None (what the warehouse stores)."""
    return json.loads(json.dumps(obj, default=lambda v: v.tolist()), parse_constant=lambda _: None)


@dataclass
class TumbleCoefficient(CoefficientResult):
    """A coefficient of a single-tumble method (paper 003) with what it estimates.

    Attributes
    ----------
    less : tuple of str
        The square terms K_ss of the heads' other turning axes (Kpp, Koo) that a K2 no
        centrifuge corrected is less by: it estimates K2 − K_ss.
    key : str
        The fitted parameter of the row (``'K2'`` of ``'K2[PA]'``, ``'theta0'``).
    head : str
        The head axis of a row pooled per head (``'PA'``), '' for one pooled over the heads.
    """
    less: tuple[str, ...] = ()
    key: str = ""
    head: str = ""


@dataclass
class Records:
    """Records for a :class:`~accelcal.results.CampaignResult`, built once."""
    coefficients: list[CoefficientResult] = field(default_factory=list)
    radii: list[RadiusResult] = field(default_factory=list)
    adequacy: list[AdequacyResult] = field(default_factory=list)
    budget: list[BudgetTerm] = field(default_factory=list)
    alignment: list[dict] = field(default_factory=list)
    extras: dict[str, dict] = field(default_factory=dict)
    flags: list[str] = field(default_factory=list)
    #: why the campaign cannot be complete, as this method finds (``completeness_reasons``)
    incomplete: list[str] = field(default_factory=list)

    def checked(self) -> "Records":
        """The records with the JCGM 101 check of every coefficient's budget in
        ``extras['mc_check']`` (:func:`.uncertainty.budget_check`), where not there yet."""
        from .uncertainty import budget_check
        checks = self.extras.setdefault("mc_check", {})
        for c in self.coefficients:
            key = f"{c.method}:{c.rig_id}:{c.name}"
            if key in checks:
                continue
            terms = [b for b in self.budget if b.coefficient == c.name and b.method == c.method
                     and b.rig_id == c.rig_id]
            chk = budget_check(c.method, c.rig_id, c.name, c.value, terms)
            if chk is not None:
                checks[key] = chk
        if not checks:
            del self.extras["mc_check"]
        return self

    def add_to(self, res) -> None:
        """Append to a CampaignResult: lists appended, extras merged per key (dicts by key,
        lists extended), as the paper methods write them."""
        res.coefficients += self.coefficients
        res.radii += self.radii
        res.adequacy += self.adequacy
        res.budget += self.budget
        res.alignment += self.alignment
        res.flags += self.flags
        res.completeness_reasons += [r for r in self.incomplete if r not in res.completeness_reasons]
        for key, value in self.extras.items():
            if isinstance(value, dict) and isinstance(res.extras.get(key), dict):
                res.extras[key] = {**res.extras[key], **value}
            elif isinstance(value, list) and isinstance(res.extras.get(key), list):
                res.extras[key] = res.extras[key] + value
            else:
                res.extras[key] = value

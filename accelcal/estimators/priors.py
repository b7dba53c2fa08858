"""Priors for what a design cannot see: an adopted combination made the quantity it names.

A design that determines a coefficient only together with others (one tumble: K1 with
the odd terms its input takes up, K1 + f_Koq Koq + f_K3 K3) is adopted as that
combination, named by its structure (``K1(Koq,K3)``, :func:`accelcal.effects.combination_name`)
with its factors beside it.  Where the lab knows the terms it takes up (the unit's last
calibration that determined them alone, :mod:`accelcal.warehouse.priors`, or else
``[prior."MODEL"]`` of accelcal.toml: a value and a standard uncertainty for each), the
quantity itself follows from the measurement model

    Q = C - sum_k f_k T_k,

C the combination the runs determine, T_k the terms at their prior values: sensitivity
-f_k to each, each prior a type-B input with a normal distribution (JCGM 100 §4.3, §5.1).
The combined standard uncertainty is u_c^2 = u(C)^2 + sum_k (f_k u(T_k))^2; its effective
degrees of freedom follow Welch-Satterthwaite (JCGM 100 G.4.1), a prior's being infinite.
A combination with a term that has no prior stays as it is.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from ..effects import combination_formula, display_coefficient, si_unit, split_combination
from ..results import BudgetTerm, CampaignResult


def apply_priors(res: CampaignResult, priors: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Make each adopted combination whose every term has a prior the quantity it names.

    Parameters
    ----------
    res : CampaignResult
        The campaign's result; its adopted rows and their budget lines are changed in place,
        and ``res.parameters["assumed"]`` records quantity -> term -> ``{"value", "u",
        "source"}`` for each row made a quantity.
    priors : mapping
        Coefficient name -> ``{"value": [SI], "u": [SI], "source": text}``, the source
        saying where the prior comes from (``'accelcal.toml [prior."QA-2000"]'``, or the
        unit's earlier result).

    Returns
    -------
    list of str
        The names of the rows made quantities (their old, structural names).
    """
    from .joint import coverage_factor
    from .uncertainty import budget_check
    done = []
    for c in res.coefficients:
        if not (c.adopted and c.factors) or not all(t in priors for t in c.factors):
            continue
        old, quantity = c.name, split_combination(c.name)[0]
        held = {t: {k: priors[t][k] for k in ("value", "u", "source")} for t in c.factors}
        value = c.value - sum(f * held[t]["value"] for t, f in c.factors.items())
        u_c = math.sqrt(c.std_uncertainty ** 2 + sum((f * held[t]["u"]) ** 2 for t, f in c.factors.items()))
        res.budget += [BudgetTerm(quantity, f"{t} held at its prior (type B, normal; {held[t]['source']})",
                                  held[t]["value"], held[t]["u"], -f, abs(f) * held[t]["u"], "B", "normal",
                                  c.method, c.rig_id) for t, f in c.factors.items()]
        if c.dof is not None and math.isfinite(c.dof) and c.dof > 0 and c.std_uncertainty > 0:
            c.dof = u_c ** 4 / (c.std_uncertainty ** 4 / c.dof)
            if c.coverage_factor != 2.0:
                c.coverage_factor = coverage_factor(c.dof)
        by_source: dict[str, list[str]] = {}     # value ± u rounded (GUM 7.2.6), display unit
        for t, h in held.items():
            v, u, unit = display_coefficient(t, h["value"], h["u"], si_unit(t), k=1.0)
            by_source.setdefault(h["source"], []).append(f"{t} = {v} ± {u} {unit}".rstrip())
        assumed = "; ".join(f"{', '.join(ts)} ({src})" for src, ts in by_source.items())
        # the fit's own aliasing remark (the terms held at 0) no longer holds
        rest = [p for p in (c.note or "").split("; ") if p and not p.startswith("aliased in this design")]
        c.note = "; ".join([f"the runs determine {combination_formula(old, c.factors)}; {quantity} with "
                            f"{assumed} assumed", *rest])
        c.name, c.value, c.std_uncertainty, c.factors = quantity, value, u_c, {}
        for b in res.budget:
            if b.coefficient == old and b.method == c.method:
                b.coefficient = quantity
        # the fit's flag that the terms were held at 0 is the combination's, not the quantity's
        res.flags = [f for f in res.flags if not f.startswith(f"{old}: aliased in this design")]
        checks = res.extras.get("mc_check") or {}
        if checks.pop(f"{c.method}:{c.rig_id}:{old}", None) is not None:
            chk = budget_check(c.method, c.rig_id, quantity, value,
                               [b for b in res.budget if b.coefficient == quantity and b.method == c.method])
            if chk is not None:
                checks[f"{c.method}:{c.rig_id}:{quantity}"] = chk
        res.parameters.setdefault("assumed", {})[quantity] = held
        done.append(old)
    return done

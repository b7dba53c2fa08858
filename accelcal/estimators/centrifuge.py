"""The centrifuge paper method of one rig (He & Yin 2017, paper 000), as pure steps.

Each step takes what the steps before it returned and returns a typed, frozen result;
nothing is edited after it is built.  :func:`process_rig` runs them in the paper's order and
:func:`rig_records` turns the outcome into the records a
:class:`~accelcal.results.CampaignResult` holds:

1. :func:`group_mounts` — runs by mount (plane, phi mod 180) and polarity; the IA pair.
2. :func:`reference_scale` — K0, K1 from the tumble (or, without one, from the IA pair at
   the nominal arm radius).
3. :func:`static_step` — eqs 4–6 per IA polarity (:func:`.radius.test_radius_static`).
4. :func:`iterative_step` — eq 7 for orders 1–3 over the 7/14/25 g ranges and the full
   range, each with its adequacy, and the order choice.
5. :func:`pair_step` — eq 9 per mount pair (:func:`.crosscoupling.fit_mount_pair`).
6. :func:`combination_step` — eq 2/3 by weighted least squares with the eq 8 type-B terms
   of the alignment analysis (§2.2).
7. :func:`budget_step` — GUM budgets with a JCGM 101 Monte Carlo check, eq 10 as printed
   against the GUM, and the budgets of Koq and K3 of the IA pair.
8. :func:`radius_corrections` — the type-B terms the paper's effective radii carry and the
   radii corrected for the instrument's own terms.

Units: SI (effects.md); radii in m, angles in rad, second-order terms in s2/m.
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

from ..constants import G_STANDARD, MOUNT_ANGLE_TOLERANCE_RAD
from ..effects import CROSS_TERM
from ..physics.axes import parse_plane
from ..physics.geometry import geometry_of
from ..results import (AdequacyResult, CoefficientResult, RadiusResult, ResidualFigure, ResidualPanel,
                       ResidualSeries)
from . import uncertainty as unc
from .adequacy import choose_order
from .crosscoupling import Combination, PairFit, combine_second_order, delta_c2, fit_mount_pair, pair_label
from .radius import (IterativeRadius, PairData, StaticRadius, g_levels, geometric_static_radius,
                     test_radius_iterative, test_radius_static)
from .records import Records, run_columns
from .registry import Estimator, register
from .tumble import Reference, TumbleStep, campaign_k1_correction

METHOD = "centrifuge_eq9"
#: g ranges of the radius table, in g (paper 000 Table 2), plus the full range.
RADIUS_RANGES = (7.0, 14.0, 25.0)
RADIUS_ORDERS = (1, 2, 3)
SECOND_ORDER_UNIT = "s2/m"


# ------------------------------------------------------------------ typed results

@dataclass(frozen=True)
class Mounts:
    """The runs of one centrifuge rig grouped by mount.

    Attributes
    ----------
    rig : str
    by_key : dict
        (plane, phi mod 180 [deg]) -> {+1: run at phi, -1: run at phi + 180 deg}.
    ia_key : tuple or None
        The key of the IA pair (IA radial, both polarities), None when there is none.
    run_plus, run_minus
        The IA pair's runs with IA towards and away from the spindle.
    """
    rig: str
    by_key: dict
    ia_key: tuple | None
    run_plus: Any = None
    run_minus: Any = None


@dataclass(frozen=True)
class StaticStep:
    """Eqs 4–6 per IA polarity ('+', '-') and the failures, as flags."""
    radii: dict[str, StaticRadius]
    flags: tuple[str, ...] = ()


@dataclass(frozen=True)
class IterativeStep:
    """Eq 7 for every (order, g range) with the chosen order of the full range."""
    fits: dict[tuple[int, float | None], IterativeRadius]
    label: str
    top: float | None
    ranges: tuple[float | None, ...]
    chosen: int
    adequate: bool

    @property
    def best(self) -> IterativeRadius:
        return self.fits[(self.chosen, None)]


@dataclass(frozen=True)
class PairStep:
    """Eq 9 fits of the mount pairs with both polarities; single-polarity mounts as flags."""
    pairs: tuple[PairFit, ...]
    flags: tuple[str, ...] = ()


@dataclass(frozen=True)
class CombinationStep:
    """Eq 2/3 over the pairs: a first pass without type-B terms (for eq 8's K's), the eq 8
    type-B standard uncertainty of each pair's c2, the alignment rows and the combination."""
    first: Combination
    u_dc2: dict[str, float]
    alignment: tuple[dict, ...]
    combination: Combination


@dataclass(frozen=True)
class CoefficientBudget:
    """One coefficient of the rig with its GUM budget and its JCGM 101 check."""
    name: str
    value: float
    unit: str
    budget: unc.GumBudget
    note: str
    mc: dict | None = None


@dataclass(frozen=True)
class BudgetStep:
    """Budgets of the combined coefficients, of Koq and K3 of the IA pair, eq 10 as printed."""
    coefficients: tuple[CoefficientBudget, ...]
    eq10: dict | None
    flags: tuple[str, ...] = ()


@dataclass(frozen=True)
class RadiusCorrections:
    """What the paper's effective radii leave in them, and the radii without it.

    Attributes
    ----------
    cross : str or None
        The cross term of IA with the vertical axis (Kio or Kip).
    type_b : dict
        (method, polarity, order, g_max) -> standard uncertainty [m] of the type-B term of the
        static and iterative radii (uniform; instrument terms the method leaves in the radius).
        None where K_iv is undetermined (no term can be evaluated).
    iterative, static : dict
        Polarity -> (radius [m], standard uncertainty [m]) of the corrected radii.
    kiv_source : str
        Where K_iv comes from: ``'pairs'`` (the mount pairs, eq 2/3), ``'tumble'`` (the
        campaign's tumble, where the pairs leave it undetermined), ``'undetermined'`` (by
        neither: its leak into the radius is not in u, and a flag says so), ``'none'``.
    """
    cross: str | None
    type_b: dict
    iterative: dict[str, tuple[float, float]]
    static: dict[str, tuple[float, float]]
    kiv_source: str = "pairs"


@dataclass(frozen=True)
class RigOutcome:
    """Everything the paper method computed for one centrifuge rig."""
    rig: str
    mounts: Mounts
    reference: Reference
    static: StaticStep
    iterative: IterativeStep
    pairs: PairStep
    combination: CombinationStep
    budgets: BudgetStep
    ia: PairFit
    corrections: RadiusCorrections
    flags: tuple[str, ...] = ()

    def coefficient(self, name: str) -> CoefficientBudget | None:
        return next((c for c in self.budgets.coefficients if c.name == name), None)


# ------------------------------------------------------------------ steps

def group_mounts(runs: Sequence) -> Mounts:
    """Runs of one rig by mount and polarity.

    Parameters
    ----------
    runs : sequence
        RunFile-like objects of one centrifuge rig (the newest revision of each run).

    Returns
    -------
    Mounts
        By (plane, phi mod 180 [deg]) and polarity (typed geometry), with the IA pair.
    """
    rig = str(runs[0].meta.get("rig_id", ""))
    by_key: dict = defaultdict(dict)
    for run in runs:
        g = geometry_of(run.meta)
        by_key[g.mount_key][g.polarity] = run
    ia_key = next((k for k, v in by_key.items() if 1 in v and -1 in v
                   and geometry_of(v[1].meta).ia_polarity is not None), None)
    if ia_key is None:
        return Mounts(rig, dict(by_key), None)
    run_p, run_m = by_key[ia_key][1], by_key[ia_key][-1]
    if geometry_of(run_p.meta).ia_polarity < 0:
        run_p, run_m = run_m, run_p
    return Mounts(rig, dict(by_key), ia_key, run_p, run_m)


def ia_pair_data(mounts: Mounts, K1: float) -> PairData:
    """The IA pair's dwell data (:class:`.radius.PairData`), outputs divided by K1
    [output_unit/(m/s2)]."""
    p, m = mounts.run_plus, mounts.run_minus
    return PairData.from_runs([(p.meta, run_columns(p), 1), (m.meta, run_columns(m), -1)], K1)


def reference_scale(mounts: Mounts, tumble: Reference | None) -> tuple[Reference, tuple[str, ...]]:
    """K0 [m/s2] and K1 [output_unit/(m/s2)] for the test radius.

    Parameters
    ----------
    mounts : Mounts
    tumble : Reference or None
        The tumble's values (paper 000 §2.1.1: "K1, K0 from a gravity calibration").

    Returns
    -------
    (Reference, flags)
        The tumble's, or (flagged) the IA pair's at the nominal arm radius, whose radius is
        then not independent.
    """
    if tumble is not None:
        return tumble, ()
    flag = (f"{mounts.rig}: no tumble run in the campaign: K1, K0 taken from the centrifuge at the "
            "nominal arm radius; the radius is then not independent")
    pair0 = ia_pair_data(mounts, 1.0)
    R0 = float(mounts.run_plus.meta["arm_radius_m"])
    f = pair0.fit(pair0.inputs(R0), 3, subtract_a=False)
    K1 = 0.5 * (f.value("b+") + f.value("b-"))
    K0 = 0.5 * (f.value("K0+") + f.value("K0-")) / K1
    return Reference(K0, K1, 0.0, 0.0, 0.0, from_tumble=False), (flag,)


def static_step(mounts: Mounts, ref: Reference) -> StaticStep:
    """Eqs 4–6 on each run of the IA pair (He & Yin 2017, paper 000 §2.1.1).

    Parameters
    ----------
    mounts : Mounts
    ref : Reference

    Returns
    -------
    StaticStep
        Polarity -> :class:`.radius.StaticRadius` [m]; a run that fails is a flag.
    """
    radii, flags = {}, []
    for run in (mounts.run_plus, mounts.run_minus):
        try:
            s = test_radius_static(run.meta, run_columns(run), ref.K0, ref.K1, ref.u_K0, ref.u_K1)
            radii[s.polarity] = s
        except Exception as exc:
            flags.append(f"{mounts.rig}: static radius of {run.meta.get('run_id')} failed: {exc}")
    return StaticStep(radii, tuple(flags))


def iterative_step(mounts: Mounts, ref: Reference, static: StaticStep, pair: PairData) -> IterativeStep:
    """Eq 7 (He & Yin 2017, paper 000 §2.1.2) for every order and g range.

    Parameters
    ----------
    mounts : Mounts
    ref : Reference
        u(K1)/K1 enters u(R).
    static : StaticStep
        Start radii (the nominal arm radius when eq 6 failed).
    pair : PairData
        The IA pair's dwells.

    Returns
    -------
    IterativeStep
        Radii [m] for orders 1–3 over the 7/14/25 g ranges (those the data reach with at
        least four levels) and the full range, and the order chosen on the full range by
        :func:`.adequacy.choose_order`.
    """
    arm = float(mounts.run_plus.meta["arm_radius_m"])
    R0p, R0m = (static.radii[pol].radius_m if pol in static.radii else arm for pol in "+-")
    levels = g_levels(pair, R0p, R0m)
    top = max(levels) if levels else None
    ranges = [r for r in RADIUS_RANGES if levels and r < top * 0.98 and sum(lv <= r * 1.02 for lv in levels) >= 4]
    ranges.append(None)
    fits = {(order, gr): test_radius_iterative(pair, R0p, R0m, order, gr, ref.u_K1 / abs(ref.K1))
            for order in RADIUS_ORDERS for gr in ranges}
    chosen, ok = choose_order({o: fits[(o, None)].fit for o in RADIUS_ORDERS}, {2: ["c2", "d"], 3: ["c3"]})
    label = f"radius {mounts.ia_key[0]} {mounts.ia_key[1]:g}/{mounts.ia_key[1] + 180:g}"
    return IterativeStep(fits, label, top, tuple(ranges), chosen, ok)


def pair_step(mounts: Mounts, ref: Reference, iterative: IterativeStep, ia_pair: PairData) -> PairStep:
    """Eq 9 on every mount with both polarities (He & Yin 2017, paper 000 §3.1).

    Parameters
    ----------
    mounts : Mounts
    ref : Reference
    iterative : IterativeStep
        Radii of the chosen eq 7 order (turning centre and mass-centre offset).
    ia_pair : PairData
        The IA pair's dwells, reused.

    Returns
    -------
    PairStep
        :class:`.crosscoupling.PairFit` per mount pair; single-polarity mounts and
        inadequate fits as flags.
    """
    best = iterative.best
    pairs, flags = [], []
    for key, runs_k in sorted(mounts.by_key.items()):
        if 1 not in runs_k or -1 not in runs_k:
            flags.append(f"{mounts.rig}: mount {key[0]} {key[1]:g} has one polarity only; not used")
            continue
        a, b = runs_k[1], runs_k[-1]
        pre = ia_pair if key == mounts.ia_key and a is mounts.run_plus else None
        pf = fit_mount_pair((a.meta, run_columns(a)), (b.meta, run_columns(b)), ref.K1, best.R_plus, best.R_minus, pair=pre)
        pairs.append(pf)
        if not pf.adequate:
            flags.append(f"{mounts.rig}: eq 9 fit of {pair_label(pf)} is not adequate at any order; used and flagged")
    return PairStep(tuple(pairs), tuple(flags))


def combination_step(mounts: Mounts, pairs: PairStep) -> CombinationStep:
    """Eq 2/3 over the pairs and the eq 8 type-B terms (He & Yin 2017, paper 000 §2.2, §3.2).

    Parameters
    ----------
    mounts : Mounts
    pairs : PairStep

    Returns
    -------
    CombinationStep
        Second-order coefficients [s2/m] with their covariance and sensitivities.

    Notes
    -----

    A first pass without type-B terms gives the K's for eq 8.  The two polarities' angle
    errors from the mass-centre offset are opposite, so their eq 8 errors cancel in the
    pair's common c2 to first order; what is left is (d1 + d2)/2, plus eq 8 for an unknown
    mount-angle error common to both polarities (the fixture tolerance,
    constants.MOUNT_ANGLE_TOLERANCE_RAD).  Type B, uniform.  The paper's bound max|d| is kept
    for reference."""
    first = combine_second_order(list(pairs.pairs))
    u_dc2, rows = {}, []
    for pf in pairs.pairs:
        g = pf.geometry
        d1 = delta_c2(first.values, pf.plane, math.radians(pf.phi0_deg), g.dphi1)
        d2 = delta_c2(first.values, pf.plane, math.radians(pf.phi0_deg + 180), g.dphi2)
        tol = delta_c2(first.values, pf.plane, math.radians(pf.phi0_deg), MOUNT_ANGLE_TOLERANCE_RAD)
        lab = pair_label(pf)
        u_dc2[lab] = unc.uniform_u(abs(d1 + d2) / 2 + abs(tol))
        rows.append({"kind": "mount", "rig_id": mounts.rig, "pair": lab, **asdict(g),
                     "dc2_1": d1, "dc2_2": d2, "u_dc2_typeB": u_dc2[lab],
                     "dc2_paper_bound": max(abs(d1), abs(d2)), "dc2_tolerance": tol,
                     "c2": pf.c2, "u_c2": pf.u_c2, "order": pf.order})
    return CombinationStep(first, u_dc2, tuple(rows), combine_second_order(list(pairs.pairs), u_dc2))


def _is_plane(p: PairFit, axes: set[int], phi: float) -> bool:
    """The pair lies in the plane of ``axes`` at nominal angle ``phi`` [deg]."""
    return set(parse_plane(p.plane)) == axes and abs(p.phi0_deg - phi) < 1e-6


def budget_step(mounts: Mounts, pairs: PairStep, comb: CombinationStep, ia: PairFit) -> BudgetStep:
    """GUM budgets (He & Yin 2017, paper 000 §3.2; JCGM 100 §5, JCGM 101).

    Parameters
    ----------
    mounts : Mounts
    pairs : PairStep
    comb : CombinationStep
    ia : PairFit
        The IA pair's eq 9 fit.

    Returns
    -------
    BudgetStep
        Per combined coefficient: type A each pair's c2, type B its eq 8 term (uniform),
        sensitivities of eq 2/3, with a JCGM 101 check (:func:`.uncertainty.budget_check`:
        the propagated distribution by exact convolution, no sampling); u(Kip) by eq 10 as printed against the GUM (factor 4, not 2); Koq and K3
        of the IA pair with their type-A term.
    """
    out, flags = [], []
    c = comb.combination
    for name, value in c.values.items():
        terms = []
        for lab, s in c.sensitivities[name].items():
            p = next(p for p in pairs.pairs if pair_label(p) == lab)
            if p.u_c2 > 0:
                terms.append((f"c2({lab})", p.c2, p.u_c2, s, "A", "normal"))
            if comb.u_dc2.get(lab, 0.0) > 0:
                terms.append((f"dc2({lab})", 0.0, comb.u_dc2[lab], s, "B", "uniform"))
        gb = unc.linear_budget(name, terms, method=METHOD, rig_id=mounts.rig, value=value)
        mc = unc.budget_check(METHOD, mounts.rig, name, float(value), gb.terms)
        note = (f"eq 2/3 over {len(c.sensitivities[name])} mount pair(s); GUM u with type-B eq 8 terms; "
                f"JCGM 101 check (exact convolution of the linear budget): validated={mc['validated']}")
        out.append(CoefficientBudget(name, float(value), SECOND_ORDER_UNIT, gb, note, mc))
    # eq 10 as printed vs GUM, for Kip from the 45 deg pair
    kip_pair = next((p for p in pairs.pairs if _is_plane(p, {0, 1}, 45.0)), None)
    kpp_pair = next((p for p in pairs.pairs if _is_plane(p, {0, 1}, 90.0)), None)
    eq10 = None
    if kip_pair is not None and "Kip" in c.values:
        ku = unc.kip_uncertainty(kip_pair.u_c2, comb.u_dc2.get(pair_label(kip_pair), 0.0), c.std.get("K2", 0.0),
                                 kpp_pair.u_c2 if kpp_pair else 0.0,
                                 comb.u_dc2.get(pair_label(kpp_pair), 0.0) if kpp_pair else 0.0)
        eq10 = {"printed": ku["printed"], "gum": ku["gum"], "differ": ku["differ"], "ratio": ku["ratio"]}
        if ku["differ"]:
            flags.append(f"{mounts.rig}: u(Kip) by eq 10 as printed is {ku['printed']:.3e}, by the GUM "
                         f"{ku['gum']:.3e} s2/m (the printed factor 2 on u(c2) should be 4); GUM stored")
    # odd quadratic and cubic of the IA pair (eq 9), per-polarity bias and scale
    lab = pair_label(ia)
    gb = unc.linear_budget("Koq", [(f"d({lab}): eq 9 fit of the IA pair", ia.d, ia.u_d, 1.0, "A", "normal")],
                           method=METHOD, rig_id=mounts.rig)
    out.append(CoefficientBudget("Koq", ia.d, SECOND_ORDER_UNIT, gb, "odd quadratic of the IA pair (eq 9)"))
    if ia.c3 is not None:
        gb = unc.linear_budget("K3", [(f"c3({lab}): eq 9 fit of the IA pair", ia.c3, ia.u_c3, 1.0, "A", "normal")],
                               method=METHOD, rig_id=mounts.rig)
        out.append(CoefficientBudget("K3", ia.c3, "s4/m2", gb, "cubic of the IA pair (eq 9), order-3 model chosen"))
    return BudgetStep(tuple(out), eq10, tuple(flags))


def radius_corrections(mounts: Mounts, ref: Reference, static: StaticStep, iterative: IterativeStep,
                       comb: CombinationStep, ia: PairFit) -> RadiusCorrections:
    """Type-B terms of the paper's effective radii and the radii corrected for the instrument.

    Parameters
    ----------
    mounts, ref, static, iterative, comb, ia
        The steps before.

    Returns
    -------
    RadiusCorrections
        [m].

    Notes
    -----

    The paper's radii (eq 6 and eq 7) are effective radii: the instrument's own terms at the
    reference acceleration leak into them.  Paper 000 §2.1.1 bounds that by the nonlinearity
    envelope; here it is a type-B (uniform) term: half-width R |K_iv| g for eq 7 (the cross
    coupling with gravity, which no order of eq 7 can absorb) and R (|K2| + |Koq|) |a_g| +
    R |K_iv| g for eq 6 (which models no nonlinearity at all).  The corrected radii:
    eq 7's divided by (1 + K_iv a_vertical); eq 6's from the forward model with K2, Koq, K3
    and K_iv (:func:`.radius.geometric_static_radius`).
    """
    meta = mounts.run_plus.meta
    g = float(meta["g_local_m_s2"])
    vert = geometry_of(meta)
    cross = CROSS_TERM.get(frozenset((0, vert.vertical)))
    c = comb.combination
    # K_iv from the mount pairs; where they leave it undetermined, from the tumble; where
    # neither determines it, its leak into the radius is not evaluated (None: no term)
    tumble_cross = {k: (v, u) for k, v, u in ref.cross}
    if not cross:
        Kiv, uKiv, source = 0.0, 0.0, "none"
    elif cross in c.values:
        Kiv, uKiv, source = c.values[cross], c.std.get(cross, 0.0), "pairs"
    elif cross in tumble_cross:
        (Kiv, uKiv), source = tumble_cross[cross], "tumble"
    else:
        Kiv, uKiv, source = 0.0, 0.0, "undetermined"
    scale = 1.0 + Kiv * vert.vertical_sign * g
    K2c = c.values.get("K2", ref.K2)
    type_b = {}
    for pol, s in static.radii.items():
        half = s.radius_m * abs(Kiv) * g + s.radius_m * (abs(K2c) + abs(ia.d)) * g
        type_b[("static", pol, None, 1.0)] = unc.uniform_u(half)
    for (order, gr), it in iterative.fits.items():
        gmax = iterative.top if gr is None else gr
        for pol, R in (("+", it.R_plus), ("-", it.R_minus)):
            type_b[("iterative", pol, order, gmax)] = (None if source == "undetermined"
                                                       else unc.uniform_u(R * abs(Kiv) * g))
    best = iterative.best
    it_corr = {pol: (R / scale, math.hypot(u, R * g * uKiv))
               for pol, R, u in (("+", best.R_plus, best.u_plus), ("-", best.R_minus, best.u_minus))}
    coeffs = {"K2": K2c, "Koq": ia.d, "K3": ia.c3 or 0.0, **({cross: Kiv} if cross else {})}
    runs = {"+": mounts.run_plus, "-": mounts.run_minus}
    st_corr = {pol: (geometric_static_radius(runs[pol].meta, s, coeffs),
                     math.hypot(s.std_uncertainty_m, s.radius_m * g * uKiv)) for pol, s in static.radii.items()}
    return RadiusCorrections(cross, type_b, it_corr, st_corr, source)


def process_rig(runs: Sequence, tumble: Reference | None) -> RigOutcome | tuple[str, ...]:
    """All of paper 000 on the runs of one centrifuge rig.

    Parameters
    ----------
    runs : sequence
        RunFile-like objects (``.meta``, ``.data``) of one rig.
    tumble : Reference or None
        K0, K1 (and K2) from the campaign's tumble.

    Returns
    -------
    RigOutcome, or a tuple of flags when there is no IA pair (no test radius, no K2).
    """
    mounts = group_mounts(runs)
    if mounts.ia_key is None:
        return (f"{mounts.rig}: no IA mount pair (phi = 0/180 deg): test radius and K2 cannot be determined",)
    ref, ref_flags = reference_scale(mounts, tumble)
    static = static_step(mounts, ref)
    ia_pair = ia_pair_data(mounts, ref.K1)
    iterative = iterative_step(mounts, ref, static, ia_pair)
    pairs = pair_step(mounts, ref, iterative, ia_pair)
    comb = combination_step(mounts, pairs)
    ia = next(p for p in pairs.pairs if (p.plane, p.phi0_deg) == mounts.ia_key)
    budgets = budget_step(mounts, pairs, comb, ia)
    corr = radius_corrections(mounts, ref, static, iterative, comb, ia)
    flags = ref_flags + static.flags
    if not iterative.adequate:
        flags += (f"{mounts.rig}: no radius model order is adequate over the full range (lack-of-fit or "
                  f"residual checks fail); order {iterative.chosen} used and flagged",)
    return RigOutcome(mounts.rig, mounts, ref, static, iterative, pairs, comb, budgets, ia, corr,
                      flags + pairs.flags + budgets.flags)


# ------------------------------------------------------------------ records

def rig_records(out: RigOutcome, k1_correction: tuple[float, float] | None = None) -> Records:
    """The records of one rig, built once.

    Parameters
    ----------
    out : RigOutcome
    k1_correction : (delta, u_delta), optional
        The tumble K1 is K1 (1 + delta) with Koq and K3 in it (:func:`.tumble.k1_correction`);
        the geometric (*_corrected) radii, which scale as 1/K1, follow.
    """
    rig, rec = out.rig, Records()
    st, it, corr = out.static, out.iterative, out.corrections
    neither = f"{corr.cross} (IA with the vertical) is determined by neither the mount pairs nor a tumble"
    src = {"tumble": f"; {corr.cross} from the tumble (the mount pairs leave it undetermined)",
           "undetermined": f"; {neither}: its leak R·{corr.cross}·g is not in u"}.get(corr.kiv_source, "")
    if corr.kiv_source == "undetermined":
        rec.flags.append(f"{rig}: test radii: {neither}; their u leaves out R·{corr.cross}·g (add a tumble "
                         "or a mount pair that determines it)")

    def typeb_note(b):
        if b is None:
            return f"no type-B term: {neither}"
        return (f"includes type-B {b:.2e} m (uniform) for instrument terms the method leaves in the radius"
                + src)

    def with_b(u, key):
        return u if corr.type_b[key] is None else math.hypot(u, corr.type_b[key])

    # static radius (eq 4-6)
    for pol, s in st.radii.items():
        key = ("static", pol, None, 1.0)
        rec.radii.append(RadiusResult(rig, pol, "static", None, 1.0, s.radius_m, with_b(s.std_uncertainty_m, key),
                                      note=f"eq 6; printed-form u = {s.std_uncertainty_printed_m:.3e} m; "
                                           + typeb_note(corr.type_b[key])))
    rec.alignment.append({"kind": "lambda_c", "rig_id": rig,
                          **{f"lambda_c{p}": s.lambda_c_rad for p, s in st.radii.items()},
                          **{f"u_lambda_c{p}": s.u_lambda_c_rad for p, s in st.radii.items()}})
    rec.extras["static_radius"] = {rig: {
        p: {"radius_m": s.radius_m, "u_gum_m": s.std_uncertainty_m, "u_printed_m": s.std_uncertainty_printed_m,
            "lambda_c_rad": s.lambda_c_rad, "omega_g": s.omega_g, "a_g": s.a_g, "budget": s.budget}
        for p, s in st.radii.items()}}
    # iterative radius (eq 7) with adequacy
    for order in RADIUS_ORDERS:
        for gr in it.ranges:
            f = it.fits[(order, gr)]
            gmax = it.top if gr is None else gr
            for pol, R, u in (("+", f.R_plus, f.u_plus), ("-", f.R_minus, f.u_minus)):
                key = ("iterative", pol, order, gmax)
                rec.radii.append(RadiusResult(rig, pol, "iterative", order, gmax, R, with_b(u, key),
                                              note=typeb_note(corr.type_b[key])))
            d = f.fit
            rec.adequacy.append(AdequacyResult(rig, it.label, order, gmax, d.f_statistic, d.p_value, d.dof_lof,
                                               d.dof_pe, d.trend_p, d.sweep_p, d.runs_p, d.adequate,
                                               chosen=(order == it.chosen and gr is None)))
    # mount pairs (eq 9)
    for pf in out.pairs.pairs:
        for order, fo in pf.fits.items():
            rec.adequacy.append(AdequacyResult(rig, f"eq9 {pair_label(pf)}", order, it.top, fo.f_statistic,
                                               fo.p_value, fo.dof_lof, fo.dof_pe, fo.trend_p, fo.sweep_p,
                                               fo.runs_p, fo.adequate, chosen=(order == pf.order)))
    rec.alignment += list(out.combination.alignment)
    rec.extras["pairs"] = {rig: [
        {"pair": pair_label(p), "runs": list(p.run_ids), "order": p.order, "adequate": p.adequate,
         "c2": p.c2, "u_c2": p.u_c2, "d": p.d, "u_d": p.u_d, "c3": p.c3, "u_c3": p.u_c3,
         "noise_s0": p.fit.extra.get("noise_s0"), "noise_k": p.fit.extra.get("noise_k"),
         "dwells": {c: p.dwells[c].tolist() for c in ("run_id", "pol", "a", "mean_output", "n", "time_mid",
                                                         "sweep", "std_resid")}} for p in out.pairs.pairs]}
    rec.extras["combination"] = {rig: out.combination.combination.design}
    # coefficients and their budgets
    for cb in out.budgets.coefficients:
        rec.budget += cb.budget.terms
        rec.coefficients.append(CoefficientResult(cb.name, cb.value, float(cb.budget.u_c), cb.unit, METHOD, rig,
                                                  note=cb.note,
                                                  factors=out.combination.combination.factors.get(cb.name, {})))
        if cb.mc is not None:
            rec.extras.setdefault("mc_check", {})[f"{METHOD}:{rig}:{cb.name}"] = cb.mc
    if out.budgets.eq10 is not None:
        rec.extras["eq10"] = {rig: out.budgets.eq10}
    f = out.ia.fit
    rec.extras["polarity_terms"] = {rig: {k: {"value": f.value(k), "u": f.std_error(k)}
                                          for k in ("K0+", "K0-", "b+", "b-")}}
    # radii corrected for the instrument terms (and for Koq, K3 in the tumble's K1)
    delta, u_delta = k1_correction if k1_correction is not None else (0.0, 0.0)
    for kind, order, gmax, radii, note in (
            ("iterative_corrected", it.chosen, it.top, corr.iterative,
             f"eq 7 radius / (1 + {corr.cross}·a_vertical): cross-coupling with gravity removed"),
            ("static_corrected", None, 1.0, corr.static,
             "eq 6 radius with K2, Koq, K3 and the cross-coupling with gravity removed")):
        for pol, (R, u) in radii.items():
            Rn = R * (1.0 + delta)
            rec.radii.append(RadiusResult(rig, pol, kind, order, gmax, Rn,
                                          math.hypot(u, Rn * u_delta) if k1_correction is not None else u, note=note))
    rec.flags += list(out.flags)
    return rec


# ------------------------------------------------------------------ the campaign's centrifuge step

#: why a campaign whose centrifuge rig has no IA mount pair is incomplete
NO_IA_PAIR = "no IA mount pair: test radius and K2 cannot be determined"


class CentrifugeStep(NamedTuple):
    """The campaign's centrifuge rigs processed by paper 000 (:func:`campaign_rigs`).

    Attributes
    ----------
    rigs : tuple of RigOutcome
        The rigs processed.
    flags : tuple of str
        One per rig that could not be (no IA pair, a failure).
    without_ia_pair : tuple of str
        Ids of the rigs without an IA mount pair (no test radius, no K2).
    """
    rigs: tuple[RigOutcome, ...] = ()
    flags: tuple[str, ...] = ()
    without_ia_pair: tuple[str, ...] = ()


def campaign_rigs(runs: Sequence, steps) -> CentrifugeStep:
    """Paper 000 on every centrifuge rig of a campaign (:func:`process_rig`), with the
    campaign's tumble (its :class:`~.tumble.TumbleStep`) as the reference scale where it has
    one; a rig never costs the rest of the campaign."""
    tumble = next((s for s in steps.values() if isinstance(s, TumbleStep)), None)
    rigs, flags, no_pair = [], [], []
    by_rig = defaultdict(list)
    for r in runs:
        by_rig[str(r.meta["rig_id"])].append(r)
    for rig, rig_runs in by_rig.items():
        try:
            out = process_rig(rig_runs, tumble.reference if tumble is not None else None)
        except Exception as exc:  # never lose the rest of the campaign
            flags.append(f"centrifuge {rig_runs[0].meta.get('rig_id')}: processing failed: "
                         f"{type(exc).__name__}: {exc}")
            continue
        if isinstance(out, RigOutcome):
            rigs.append(out)
        else:
            flags += list(out)
            no_pair.append(rig)
    return CentrifugeStep(tuple(rigs), tuple(flags), tuple(no_pair))


def campaign_records(runs: Sequence, steps) -> list[Records]:
    """The records of every rig (:func:`rig_records`, geometric radii with the tumble K1
    correction), then the rigs' flags (and :data:`NO_IA_PAIR` as the campaign's
    incompleteness where a rig has no IA pair)."""
    step = steps.get(METHOD, CentrifugeStep())
    k1 = campaign_k1_correction(steps)
    return [rig_records(out, k1).checked() for out in step.rigs] + [
        Records(flags=list(step.flags), incomplete=[NO_IA_PAIR] if step.without_ia_pair else [])]


def mc_truth(c, eff, test, g, records) -> dict[tuple[str, str], tuple[float, str]]:
    """What each paper-000 coefficient estimates in a simulated test: the instrument values
    of K2, Kpp, Koo, Kip, Kio, Kpo, Koq, K3 (signature of
    :data:`accelcal.estimators.registry.TruthMapping`)."""
    rig = str(test["rig_id"])
    return {(k, rig): (c[k], "instrument value") for k in ("K2", "Kpp", "Koo", "Kip", "Kio", "Kpo", "Koq", "K3")}


def residual_figures(extras: Mapping[str, Any]) -> list[ResidualFigure]:
    """The eq 9 fits' standardised dwell-mean residuals against the signed centripetal
    input, one panel per mount pair, from what :func:`campaign_records` stored
    (``extras['pairs']``), for the certificate.

    Parameters
    ----------
    extras : mapping
        A stored result's extras.

    Returns
    -------
    list of ResidualFigure
        One ``'dwells'`` figure (a series per polarity and sweep), or none without pairs.
    """
    pairs = [(rig, p) for rig, ps in (extras.get("pairs") or {}).items() for p in ps
             if isinstance(p, dict) and isinstance(p.get("dwells"), dict)]
    panels = []
    for rig, p in pairs:
        dw = p["dwells"]
        a = [(x or 0.0) / G_STANDARD for x in dw.get("a", [])]
        r = dw.get("std_resid", [])
        pol = dw.get("pol", [1] * len(a))
        sweep = dw.get("sweep", ["up"] * len(a))
        series = []
        for sgn in (1, -1):
            for sw in ("up", "down", "rest"):
                xy = [(x, y) for x, s, w, y in zip(a, pol, sweep, r) if s == sgn and w == sw and y is not None]
                if xy:
                    series.append(ResidualSeries(f"{'+' if sgn > 0 else '−'} {sw}", tuple(x for x, _ in xy),
                                                 tuple(y for _, y in xy), polarity=sgn, sweep=sw))
        panels.append(ResidualPanel(f"{rig} {p.get('pair', '')} (order {p.get('order', '?')})",
                                    "input acceleration along IA (signed) / g", tuple(series)))
    if not panels:
        return []
    return [ResidualFigure("dwells", "Standardised dwell-mean residuals of the eq 9 fits.", tuple(panels))]


ESTIMATOR = register(Estimator(
    method=METHOD, tests=("centrifuge",),
    certificate=("paper 000 (He & Yin, 2017): test radius by static back-calculation "
                 "(eqs 4–6) and iterative regression (eq 7); second-order and cross-coupling "
                 "coefficients from the mount pairs (eq 9) combined by weighted least squares "
                 "(eqs 2–3); alignment analysis (eq 8); GUM budgets with a JCGM 101 Monte Carlo "
                 "check"),
    prepare=campaign_rigs, records=campaign_records, truth=mc_truth, adoption=1,
    main=("K2", "Kip", "Kpp", "Koq", "K3"), order=1, figures=residual_figures))

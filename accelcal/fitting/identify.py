"""What a design determines: the one rank decision of a campaign model, the aliases as
determined combinations, and the holds, with one set of thresholds for every consumer (the
adopted fit, the test-design advice, the diagnosis; the Monte Carlo bound reads its
thresholds).

A design is a whitened Jacobian J (rows: cells, columns: candidate parameters
[1 / parameter unit]); any matrix with the same J^T J judges the same.  The decision is

1. in :data:`PRIORITY` order, a column that adds less than :data:`ALIAS_TOL` of new
   direction (unit-scaled, relative norm outside the span of those kept before it) is held
   as aliased with the kept columns that make it up, or as not excited when it is zero
   (:func:`accelcal.fitting.core.separable_columns`, with the radius rule of
   :func:`scale_referenced_columns`), those the design cannot determine at the
   structural point judged last (:func:`structural_order`);
2. then, one at a time, the kept parameter outside :data:`BASE` whose design uncertainty
   most exceeds its plausible size (:func:`accelcal.effects.plausible_size`) is held as
   weakly determined, and an effect whose direction it had claimed is judged again
   without it.

What a free parameter then measures is itself plus the held parameters it absorbs, through
the alias matrix A = (J_f^T J_f)^+ J_f^T J_h (Draper & Smith, *Applied Regression
Analysis*, 3rd ed., §10.2): a :class:`Combination` with structured coefficients.

Every decision is a typed record (:class:`Hold`, :class:`Combination`); the words a reader
sees are rendered from the record (:attr:`Hold.reason`, :func:`display_name`), never read
back.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

import numpy as np

from ..effects import combination_name, plausible_size
from .core import correlation_matrix, lstsq_min_norm, lstsq_svd, lstsq_svd_x, separable_columns

#: A parameter whose Jacobian column (unit-scaled) has less than this relative norm outside
#: the span of the parameters before it is aliased: its variance would be inflated 1e6-fold.
ALIAS_TOL = 1e-3
#: Smallest share of a held column a kept column must carry to be named among what it is
#: aliased with, or to count as mixed with it [1].
ALIAS_SHARE = 0.05
#: At most this many parameters are named as what a held one is aliased with.
ALIASES_NAMED = 4
#: A held parameter is part of what a free one measures when a typical size of it would
#: move the free one's estimate by more than this many of its standard uncertainties.
ABSORBED_SHARE = 1.0
#: |correlation| of two estimates from which each is said to be determined only through
#: their combination (:func:`near_aliases`).
NEAR_ALIAS_R = 0.999
#: |cos| of two directions, each projected off a fitted model, above which the runs do not
#: tell them apart (two candidate effects; an effect and a held coefficient).
ALIAS_COS = 0.95
#: Share of a direction a fitted parameter must take up to be named as what absorbs it
#: (:func:`taken_up`) [1].
TAKEN_SHARE = 0.25
#: Observable fraction |P s| / |s| (what is left of a direction off a fitted model) below
#: which the model absorbs it: what is left is rounding.
UNOBSERVABLE_FRACTION = 1e-3
#: Order in which parameters claim directions of the design (earlier first).  The
#: instrument's own terms come before the rig's effects: in one mount plane Kp a_P is exactly
#: a rotation of the mount (Kp = -dphi), Ko a_O a tilt of IA towards OA, and Kp is what the
#: calibration exists to measure; a mount angle error or an IA tilt then claims only what
#: the instrument's terms leave (a difference between mounts).  Kp comes before Kpo: with
#: one vertical axis Kpo a_O a_P is Kp times g.
PRIORITY = ("K1", "K0", "theta0", "K2", "bias", "radius", "K3", "Koq", "Kip", "Kio", "Kpp", "Koo",
            "K0T", "K1T", "Kp", "Ko", "Kpo", "mass_centre_offset", "mount_angle_error", "effect")
#: Coefficients never held for being weakly determined (the base of every design).
BASE = ("K0", "K1", "K2", "theta0", "bias")
#: Coefficients that scale a centrifuge's output as its radius does: K1, and IA's cross
#: terms with an axis along gravity (K1 (1 + Kio g) a_I with OA up).
SCALE_TERMS = ("K1", "Kio", "Kip")


def structural_point(p: np.ndarray, columns: Sequence[Column]) -> np.ndarray:
    """The point at which the design's structure is judged: the instrument's terms of A
    (effects.md, every coefficient but the scale factor K1) at their held values (0), the
    scale factor and the rig's quantities (radius, offset, mount angles, per-run biases,
    effects) where p has them.

    The output is K1 A(a; K0, K2, Kp, ...) with A linear in the coefficients, so scaling K1
    by (1 + e) and every coefficient of A by 1 / (1 + e) leaves it unchanged but for the
    term a_I, which Kio g takes up on a mount with OA up and a per-run bias with IA
    vertical; scaling the radius does the same with K1, K2, K3, Koq, Kpp.  At a point p
    where Kp is 2e-5 rad the columns of Kio and R leave the span of the others by Kp a_P
    and Kpp a_P^2 (1e-3 to 4e-3 of their norm at 25 g against :data:`ALIAS_TOL` = 1e-3);
    judged there, they look separable and the member of the symmetry judged last (Kp) is
    held, though no finite move along it brings Kp to 0 (it scales Kp, it does not shift
    it).

    Parameters
    ----------
    p : (k,) ndarray
        Parameter vector [parameter units].
    columns : sequence of Column
        All k parameters (:attr:`Column.value`: the value a coefficient is held at).

    Returns
    -------
    (k,) ndarray
    """
    return np.array([c.value if c.kind == "coef" and c.key != "K1" else v for v, c in zip(p, columns)])


def nominal_point(p: np.ndarray, columns: Sequence[Column]) -> np.ndarray:
    """The design as the test plan states it: :func:`structural_point` with the rig's
    nuisances too (mass-centre offset, mount angles, tilts: every effect) at their held
    values (0), the scale factor, the radius and the per-run biases where p has them.

    Parameters
    ----------
    p : (k,) ndarray
        Parameter vector [parameter units].
    columns : sequence of Column
        All k parameters (:attr:`Column.value`: the value each is held at).

    Returns
    -------
    (k,) ndarray
    """
    return np.array([c.value if c.kind == "effect" else v for v, c in zip(structural_point(p, columns), columns)])


def seen_through_nuisances(J: np.ndarray, Jn: np.ndarray, columns: Sequence[Column], which: Sequence[int],
                           tol: float = ALIAS_TOL) -> list[int]:
    """The columns of ``which`` that the design determines at the fitted nuisances and not
    at the nominal geometry (:func:`holds` at both points, instrument coefficients at 0 in
    both, so that only the nuisances differ).

    A mass-centre offset r along IA turns a 90 deg mount's input r / R towards IA:
    a_I = omega^2 r, and Kip a_I a_P, nothing at the nominal geometry (a_I = 0 or a_P = 0
    in every mount of 0/90/180/270), is then a column of its own (paper 000 eq 2 with the
    offset of effects.md ``mass_centre_offset``).

    Parameters
    ----------
    J, Jn : (m, k) ndarray
        Whitened design at :func:`structural_point` and at :func:`nominal_point` of the
        fitted values [1 / parameter unit].
    columns : sequence of Column
        The k parameters.
    which : sequence of int
        Positions of the columns asked about.
    tol : float
        :data:`ALIAS_TOL` [1].

    Returns
    -------
    list of int
        Positions (of ``which``) kept at J and held at Jn.
    """
    at = holds(J, columns, tol, name_aliases=False)
    nominal = holds(Jn, columns, tol, name_aliases=False)
    return [c for c in which if columns[c].name not in at and columns[c].name in nominal]


def structural_order(J: np.ndarray, J0: np.ndarray | None, order: Sequence[int], tol: float = ALIAS_TOL
                     ) -> list[int]:
    """The order in which the columns claim directions: ``order``, with every parameter the
    design cannot determine at the structural point (:func:`structural_point`) judged after
    those it can.

    Such a parameter (Kio and the radius with IA vertical and no gravity reference) adds a
    direction at the estimate only through the products of the instrument's terms with it;
    judged in priority order there, it takes that direction from the coefficient that makes
    it (Kp a_P) and leaves the coefficient held.  Judged last, it is held where the design
    leaves it in the span of the others, as at the structural point.  A parameter whose
    column at the structural point is below ``tol`` of its column at the estimate acts only
    through the instrument's terms (a mount angle error with IA tangential: Kp a_I) and
    keeps its place.

    Parameters
    ----------
    J, J0 : (m, k) ndarray
        Whitened design at the estimate and at the structural point (None: ``order``
        unchanged) [1 / parameter unit].
    order : sequence of int
        Column positions in :data:`PRIORITY` order.
    tol : float
        :data:`ALIAS_TOL` [1].

    Returns
    -------
    list of int
    """
    order = list(order)
    if J0 is None:
        return order
    first = np.linalg.norm(J0, axis=0) > tol * np.linalg.norm(J, axis=0)
    kept = set(separable_columns(J0, [c for c in order if first[c]], tol))
    late = [c for c in order if first[c] and c not in kept]
    return [c for c in order if c not in late] + late


class Why(Enum):
    """Why a parameter is held."""
    ALIASED = "aliased"              #: its column lies in the span of those kept
    NOT_EXCITED = "not excited"      #: its column is zero in these runs
    WEAK = "weakly determined"       #: design uncertainty above its plausible size
    CLAIMED = "claimed by an effect"  #: a candidate effect of the diagnosis takes its direction
    GIVEN = "given"                  #: held by the caller, whatever the design


@dataclass(frozen=True)
class Hold:
    """One held parameter: why, at what value, with what prior uncertainty.

    Attributes
    ----------
    why : Why
    value : float
        Held value [parameter unit].
    u : float or None
        Prior standard uncertainty of the held value [parameter unit]; None: none stated.
    aliased_with : tuple of str
        The kept parameters (or, for :attr:`Why.CLAIMED`, the candidate effects) that make
        up its column, largest share first.
    design_u : float or None
        Design uncertainty of a weakly determined parameter [parameter unit].
    unit : str
        Its unit (effects.md notation).
    note : str
        The caller's words for a :attr:`Why.GIVEN` hold.
    """
    why: Why
    value: float = 0.0
    u: float | None = None
    aliased_with: tuple[str, ...] = ()
    design_u: float | None = None
    unit: str = ""
    note: str = ""

    @property
    def reason(self) -> str:
        """The hold said in words (shown in flags, extras and reports)."""
        if self.why is Why.ALIASED:
            return "aliased with " + ", ".join(self.aliased_with) if self.aliased_with else "aliased"
        if self.why is Why.NOT_EXCITED:
            return "not excited by these runs"
        if self.why is Why.WEAK:
            return f"weakly determined: design uncertainty {self.design_u:.2g} {self.unit} exceeds its plausible size"
        if self.why is Why.CLAIMED:
            return ("aliased with candidate effect " + ", ".join(self.aliased_with)
                    + " (the effect claims the direction)")
        return self.note

    def __str__(self) -> str:
        return self.reason


@dataclass(frozen=True)
class Column:
    """A candidate parameter as the rank decision sees it.

    Attributes
    ----------
    name : str
        Parameter name.
    kind : str
        ``'coef'``, ``'bias'``, ``'radius'``, ``'scale'`` or ``'effect'``.
    key : str
        Instrument coefficient or effects.md id.
    unit : str
        Its unit.
    priority : int
        Position of its claim in :data:`PRIORITY`.
    value : float
        Value it is held at [unit].
    """
    name: str
    kind: str
    key: str
    unit: str
    priority: int
    value: float = 0.0


@dataclass(frozen=True)
class Combination:
    """What a free parameter's estimate measures: itself plus factors times the instrument
    coefficients held at 0 that it takes up, and the other held parameters it depends on.

    Attributes
    ----------
    kept : str
        The free parameter's name.
    terms : tuple of (str, float)
        (held instrument coefficient, factor [kept unit / its unit]), in parameter order.
    depends : tuple of (str, float, str, float)
        (held parameter, held value [its unit], its unit, factor [kept unit / its unit]) of
        every other held parameter it takes up (a rig quantity at its nominal value, an
        effect).
    """
    kept: str
    terms: tuple[tuple[str, float], ...] = ()
    depends: tuple[tuple[str, float, str, float], ...] = ()

    @property
    def factors(self) -> dict[str, float]:
        """:attr:`terms` as a mapping coefficient -> factor."""
        return dict(self.terms)


def design_rank(X: np.ndarray) -> int:
    """Numerical rank of a design as its columns stand [1]: singular values above
    max(shape) eps s_max (numpy's rule), so a column at rounding level counts as none,
    where the column-scaled rank of :func:`~accelcal.fitting.core.lstsq_svd` would count
    it full (a per-run offset that the runs' biases already take)."""
    return int(np.linalg.matrix_rank(X))


def display_name(label: str, comb: Combination | None) -> str:
    """The row name of what a parameter measures: ``label`` with the names of the terms the
    combination takes up (:func:`accelcal.effects.combination_name`, ``'K2(Koo)'``; their
    factors are :attr:`Combination.factors`); ``label`` itself when it takes up nothing."""
    return combination_name(label, comb.factors if comb is not None else {})


def aliased_with(J: np.ndarray, i: int, kept: Sequence[int], share: float = ALIAS_SHARE) -> list[int]:
    """Positions of the kept columns that make up column i (at most :data:`ALIASES_NAMED`,
    by their share of it).

    Parameters
    ----------
    J : (m, k) ndarray
        Whitened design [1 / parameter unit].
    i : int
        Position of the column held.
    kept : sequence of int
        Positions of the columns kept.
    share : float
        Smallest share of column i a kept column must carry [1].

    Returns
    -------
    list of int
    """
    if not kept or not np.any(J[:, i]):
        return []
    sol = lstsq_svd(J[:, list(kept)], J[:, i])
    contrib = np.abs(sol.x) * np.linalg.norm(J[:, list(kept)], axis=0)
    tot = contrib.sum()
    if tot == 0:
        return []
    return [kept[c] for c in np.argsort(-contrib) if contrib[c] > share * tot][:ALIASES_NAMED]


def mixed_with(Jf: np.ndarray, Jh: np.ndarray, cov: np.ndarray, share: float = ALIAS_SHARE) -> np.ndarray:
    """Which free parameters make up a held column: their estimates are that combination,
    not themselves (one 45 deg mount: Kpp held, the Kip fitted is Kip + Kpp).

    The alias matrix X = (J_f^T J_f)^+ J_f^T J_h (Draper & Smith §10.2) in shares of each
    held column: |X_kh| |J_f,k| / |J_h,h|.

    Parameters
    ----------
    Jf, Jh : (m, f), (m, h) ndarray
        Whitened columns of the free and of the held parameters [1 / parameter unit].
    cov : (f, f) ndarray
        (J_f^T J_f)^+ [free units squared].
    share : float
        Smallest share that makes a free parameter part of a held column [1].

    Returns
    -------
    (f,) ndarray of bool
    """
    X = cov @ (Jf.T @ Jh)
    nh = np.linalg.norm(Jh, axis=0)
    frac = np.abs(X) * np.linalg.norm(Jf, axis=0)[:, None] / np.where(nh > 0, nh, 1.0)[None, :]
    return (frac > share).any(axis=1)


def scale_referenced_columns(J: np.ndarray, order: Sequence[int], tol: float, *, radius: Sequence[bool],
                             scale: Sequence[bool]) -> list[int]:
    """:func:`~accelcal.fitting.core.separable_columns` in ``order``, with one rule of physics
    on top: a rig's radius that only the scale factor K1 (with the terms that scale with it)
    can stand in for is held at its nominal value, not the others.

    Without a gravity reference (no tumble, no axis along gravity) the readings fix K1 R,
    not K1 and R: scaling R by s and K1, K2, Koq, K3 and the mass-centre offset by the
    matching powers of 1/s leaves every output unchanged.  Judged in priority order at a
    point where K2 is not 0, the radius would be kept and the last term of that scale
    direction held (the offset: an inadequate fit).  So each kept radius is judged again
    last, and held when K1 or a cross term of IA with the vertical axis
    (:data:`SCALE_TERMS`) is among what it is aliased with.

    Parameters
    ----------
    J : (m, k) ndarray
        Whitened design [1 / parameter unit].
    order : sequence of int
        Column positions in priority order.
    tol : float
        :data:`ALIAS_TOL` [1].
    radius, scale : sequence of bool
        Per column: a rig radius; a term of :data:`SCALE_TERMS`.

    Returns
    -------
    list of int
        Positions of the columns kept.
    """
    order = list(order)
    kept = separable_columns(J, order, tol)
    for c in [k for k in kept if radius[k]]:
        others = [k for k in order if k != c and np.any(J[:, k])]
        if others:
            # a radius that adds a direction to every other column is kept however late it
            # is judged (every design with a gravity reference): one solve, not a second pass
            col = J[:, c] / np.linalg.norm(J[:, c])
            Jo = J[:, others] / np.linalg.norm(J[:, others], axis=0)
            if np.linalg.norm(col - Jo @ lstsq_svd_x(Jo, col)) > tol:
                continue
        last = separable_columns(J, [k for k in order if k != c] + [c], tol)
        if c not in last:
            sol = lstsq_svd_x(J[:, last], J[:, c])
            share = np.abs(sol) * np.linalg.norm(J[:, last], axis=0)
            if any(scale[k] and share[i] > ALIAS_SHARE * share.sum() for i, k in enumerate(last)):
                kept = last
    return kept


def holds(J: np.ndarray, columns: Sequence[Column], tol: float = ALIAS_TOL, keep: Sequence[str] = (),
          name_aliases: bool = True, scale_rule: bool = True, structural: np.ndarray | None = None
          ) -> dict[str, Hold]:
    """The parameters a design cannot determine (module docstring): aliased or not excited
    in priority order, then weakly determined one at a time.

    Parameters
    ----------
    J : (m, k) ndarray
        Whitened design whose columns are ``columns`` [1 / parameter unit].
    columns : sequence of Column
        The candidate parameters, one per column of J.
    tol : float
        :data:`ALIAS_TOL` [1].
    keep : sequence of str
        Names never held for being weakly determined.
    name_aliases : bool
        Name what an aliased parameter is aliased with (one more solve per parameter
        held); False leaves :attr:`Hold.aliased_with` empty.
    scale_rule : bool
        Apply :func:`scale_referenced_columns` (False: where the caller knows the runs fix
        the radius).
    structural : (m, k) ndarray, optional
        The same design at :func:`structural_point` [1 / parameter unit]: the order of
        :func:`structural_order` (None: :data:`PRIORITY` order).

    Returns
    -------
    dict of str to Hold
        Name -> hold of each parameter held, in the order decided.
    """
    order = structural_order(J, structural, sorted(range(len(columns)), key=lambda c: (columns[c].priority, c)),
                             tol)
    radius = [col.kind == "radius" for col in columns]
    scale = [col.key in SCALE_TERMS for col in columns]

    def separable(out):
        o = [c for c in order if c not in out]
        return (scale_referenced_columns(J, o, tol, radius=radius, scale=scale) if scale_rule
                else separable_columns(J, o, tol))

    def hold(c, why, **kw):
        return Hold(why, columns[c].value, unit=columns[c].unit, **kw)

    def aliased(kept):
        out: dict[str, Hold] = {}
        kept_set = set(kept)
        for c in range(len(columns)):
            if c in kept_set or c in weak:
                continue
            ali = tuple(columns[k].name for k in aliased_with(J, c, kept)) if name_aliases else ()
            excited = bool(ali) or (not name_aliases and np.any(J[:, c]))
            out[columns[c].name] = hold(c, Why.ALIASED, aliased_with=ali) if excited else hold(c, Why.NOT_EXCITED)
        return out

    weak: set[int] = set()
    kept = separable(weak)
    held = aliased(kept)
    # weakly determined extension terms; a direction one of them had claimed (a
    # rounding-level column: Kp in an IA pair, Kpo with IA vertical, judged before the
    # mass-centre offset) goes back to an effect of the model it had displaced, whatever
    # the held effect is said to be aliased with (a rounding-level column is below the
    # solver's cut-off there); coefficients it displaced stay held: the runs did not
    # determine them before it either
    while True:
        sol = lstsq_svd(J[:, kept], np.zeros(J.shape[0]))
        u = np.sqrt(np.clip(np.diag(sol.cov), 0, None))
        worst, ratio = None, 1.0
        for c, k in enumerate(kept):
            ck = columns[k]
            lim = plausible_size(ck.key)
            base = ("theta0" if ck.key == "initial_misalignment"
                    else ck.key if ck.kind in ("coef", "bias", "radius") else "")
            if base in BASE or ck.name in keep or lim is None:
                continue
            if u[c] / lim > ratio:
                worst, ratio = c, u[c] / lim
        if worst is None:
            break
        k = kept.pop(worst)
        weak.add(k)
        kept_set = set(kept)
        stay = weak | {c for c in range(len(columns)) if c not in kept_set and columns[c].kind != "effect"}
        back = [c for c in separable(stay) if c not in kept_set]
        if back:
            kept = kept + back
            for c in back:
                held.pop(columns[c].name, None)
        held[columns[k].name] = hold(k, Why.WEAK, design_u=float(u[worst]))
    return held


def absorbed(Jf: np.ndarray, Jh: np.ndarray, u_f: np.ndarray | None, typical: np.ndarray,
             share: float = ABSORBED_SHARE) -> np.ndarray:
    """The alias matrix of the held parameters in the free ones, where it matters.

    Linearised, the estimate of free parameter k is ``x_k + sum_h A_kh (x_h - p_h)`` with
    ``A = (J_f^T J_f)^+ J_f^T J_h`` (Draper & Smith §10.2).  A held parameter counts when a
    size of it typical of an ordinary unit would move the estimate by more than ``share``
    of its uncertainty.

    Parameters
    ----------
    Jf, Jh : (m, f), (m, h) ndarray
        Whitened columns of the free and the held parameters [1 / parameter unit].
    u_f : (f,) ndarray or None
        Standard uncertainty of each free parameter [its unit] (None: the design's, from
        J_f).
    typical : (h,) ndarray
        Typical size of each held parameter [its unit].
    share : float
        Smallest shift, in units of u, that counts [1].

    Returns
    -------
    (f, h) ndarray
        A [free unit / held unit], 0 where the shift does not count.
    """
    A = np.column_stack([lstsq_svd_x(Jf, Jh[:, c]) for c in range(Jh.shape[1])])
    if u_f is None:
        sol = lstsq_svd(Jf, np.zeros(Jf.shape[0]))
        u_f = np.sqrt(np.clip(np.diag(sol.cov), 0, None))
    return np.where(np.abs(A) * typical[None, :] > share * u_f[:, None], A, 0.0)


def combinations(free: Sequence[Column], held: Sequence[Column], A: np.ndarray,
                 coefficient: Sequence[bool]) -> dict[str, Combination]:
    """What each free parameter measures (:class:`Combination`), from :func:`absorbed`.

    Parameters
    ----------
    free, held : sequence of Column
        The free and the held parameters (held ones at their held values).
    A : (f, h) ndarray
        :func:`absorbed`.
    coefficient : sequence of bool
        Per held parameter: an instrument coefficient (it becomes a term of the combination
        when held at 0; any other held parameter is a dependence).

    Returns
    -------
    dict of str to Combination
        Free parameter name -> what it measures, only for those that take something up.
    """
    out = {}
    for a, f in enumerate(free):
        terms: dict[str, float] = {}
        depends = []
        for b, h in enumerate(held):
            x = float(A[a, b])
            if x == 0.0:
                continue
            if coefficient[b] and h.value == 0.0:
                terms[h.key] = x
            else:
                depends.append((h.name, float(h.value), h.unit, x))
        if terms or depends:
            out[f.name] = Combination(f.name, tuple(terms.items()), tuple(depends))
    return out


def dependence_text(comb: Combination) -> list[str]:
    """Each held parameter a combination depends on, said as its held value and the factor
    on its departure."""
    return [f"{h} held at {v:.6g} {unit} (the value includes {f:+.3g}·({h} − {v:.6g}))"
            for h, v, unit, f in comb.depends]


def as_holds(held: Mapping[str, Hold | str] | None) -> dict[str, Hold]:
    """A mapping of holds with the caller's words made :attr:`Why.GIVEN` holds."""
    return {k: v if isinstance(v, Hold) else Hold(Why.GIVEN, note=v) for k, v in (held or {}).items()}


def alias_cos(a: np.ndarray, b: np.ndarray) -> float:
    """cos of the angle between two directions, each projected off a fitted model [1]; the
    runs do not tell them apart when its size exceeds :data:`ALIAS_COS` (0 for a zero
    direction).

    Parameters
    ----------
    a, b : (m,) ndarray
        Whitened directions (signatures, Jacobian columns) [1 per their units].

    Returns
    -------
    float
    """
    return float(float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b) or 1.0))


class NearAlias(NamedTuple):
    """Two free parameters the runs determine far better together than alone: the
    combination ``a + t b`` of least variance, ``t = -r u_a / u_b``."""
    a: str
    b: str
    t: float
    r: float


def near_aliases(names: Sequence[str], R: np.ndarray, u: np.ndarray, r_min: float = NEAR_ALIAS_R
                 ) -> list[NearAlias]:
    """The pairs of estimates that correlate with |r| >= ``r_min`` (Kip and Kpp from IA-PA
    0/180 and 45/225 without 90/270).

    Parameters
    ----------
    names : sequence of str
        Free parameters.
    R : (k, k) ndarray
        Correlation matrix of their estimates [1].
    u : (k,) ndarray
        Their standard uncertainties [their units].
    r_min : float
        Smallest |correlation| named [1].

    Returns
    -------
    list of NearAlias
        t [unit a / unit b], r [1].
    """
    return [NearAlias(names[a], names[b], float(-R[a, b] * u[a] / u[b]), float(R[a, b]))
            for a in range(len(names)) for b in range(a + 1, len(names))
            if np.isfinite(R[a, b]) and abs(R[a, b]) >= r_min]


def added_correlations(Jf: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correlation matrix and standard uncertainties of the estimates of a fitted design's
    free parameters with one direction s added as a last column (an effect's signature):
    what :func:`near_aliases` reads.

    Parameters
    ----------
    Jf : (m, k) ndarray
        Whitened design of the free parameters [1 / parameter unit].
    s : (m,) ndarray
        Whitened direction [1 per its unit].

    Returns
    -------
    R : (k + 1, k + 1) ndarray
        Correlation matrix [1] (:func:`~accelcal.fitting.core.correlation_matrix`: not
        finite where a variance is 0).
    u : (k + 1,) ndarray
        Design standard uncertainties [parameter units].
    """
    return correlation_matrix(lstsq_svd(np.column_stack([Jf, s]), np.zeros(Jf.shape[0])).cov)


def taken_up(J: np.ndarray, s: np.ndarray, top: int = 6) -> list[tuple[int, float, float]]:
    """How the columns of a fitted design take up a direction s: the minimum-norm least
    squares of s on the unit-scaled columns.

    Parameters
    ----------
    J : (m, k) ndarray
        Whitened design of the free parameters [1 / parameter unit].
    s : (m,) ndarray
        Whitened direction (an effect's signature) [1 per its unit].
    top : int
        Most columns returned.

    Returns
    -------
    list of (int, float, float)
        (column, share of |s|^2 [1], how far one unit of s moves that parameter [parameter
        unit / its unit]), largest share first, shares above 1e-3 only.
    """
    nrm = np.linalg.norm(J, axis=0)
    x = lstsq_min_norm(J / nrm, s, rcond=1e-10) / nrm
    n2 = float(s @ s)
    out = sorted(((k, float((J[:, k] * x[k]) @ s / n2), float(x[k])) for k in range(J.shape[1])),
                 key=lambda a: -abs(a[1]))
    return [a for a in out if abs(a[1]) > 1e-3][:top]

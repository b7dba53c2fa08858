"""The one fitting core of accelcal: parameters, weighted least squares through a scaled
SVD, Gauss–Newton with Levenberg–Marquardt damping, lack of fit and the fit result.

Every estimator (the joint campaign fit, the paper methods that keep their own design)
and the sim-to-real diagnosis solve their least-squares problems here, so that there is
one definition of a covariance, one rank rule and one lack-of-fit test.

Conventions
-----------
A problem is posed *whitened*: the residual vector is ``z = (y - f(p)) / sigma`` and the
Jacobian is ``J = (df/dp) / sigma`` (rows = observations, columns = parameters), so that
the weighted sum of squares is ``z @ z`` and the covariance of the estimate under the
noise model is ``(J^T J)^+`` (JCGM 102 §7 / the usual Gauss–Markov result).

The SVD works on the column-scaled matrix ``J / |J_k|``: scaling makes the rank decision
independent of the parameters' units (a K3 in s⁴/m² of 1e-10 sits beside a radius in m),
and it is what makes the solver pass the NIST StRD higher-difficulty problems (Longley,
Wampler) without the normal equations.

References
----------
NIST/SEMATECH, Statistical Reference Datasets (StRD), linear least squares, 1999.
Draper & Smith, *Applied Regression Analysis*, 3rd ed., §2.1 (lack of fit with pure error).
Birge, R. T., Phys. Rev. 40, 207 (1932) (the ratio of external to internal consistency).
JCGM 100:2008 (GUM) §4.2, G.4; JCGM 102:2011 §7 (multivariate measurement models).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from .distributions import chi2_sf, f_sf

#: Relative singular value below which a direction of the column-scaled design counts as
#: not determined by the data (the rank rule of every fit in accelcal).
RCOND = 1e-10
#: Significance level of lack-of-fit tests (model adequacy, IEEE 836 practice).
ALPHA = 0.01


# --------------------------------------------------------------------------- parameters

@dataclass(frozen=True)
class Parameter:
    """One fitted (or held) quantity of a model.

    Parameters
    ----------
    name : str
        Unique name in its set, e.g. ``'K2'``, ``'K0[LXJ100-20261120-0002]'``,
        ``'theta0[DH-1 head PA]'``.
    key : str
        What it is in the physics: an instrument coefficient of effects.md (``'K2'``), an
        effect id (``'mass_centre_offset'``) or a nuisance kind (``'bias'``, ``'radius'``).
    unit : str
        SI unit of the value, effects.md notation (``'s2/m'``; ``'out/(m/s2)'`` for K1).
    scale : float
        Typical magnitude [unit]: sets difference steps and the "weakly determined" rule.
    runs : tuple of int or None
        Indices of the runs (blocks of observations) it acts on; None = every run.
    group : str
        Human-readable family for reports: ``'instrument'``, ``'per-run bias'``, ...
    vary : bool
        False holds it at ``value``.
    value : float
        Start value (or the held value) [unit].
    """
    name: str
    key: str
    unit: str = ""
    scale: float = 1.0
    runs: tuple[int, ...] | None = None
    group: str = ""
    vary: bool = True
    value: float = 0.0

    def acts_on(self, run: int) -> bool:
        """Whether the parameter enters the model of run ``run``.

        Parameters
        ----------
        run : int
            Run index (block of observations) [1].

        Returns
        -------
        bool
            True when ``runs`` is None (every run) or contains ``run``.
        """
        return self.runs is None or run in self.runs


class ParameterSet:
    """An ordered set of :class:`Parameter` with name lookup."""

    def __init__(self, params: Iterable[Parameter] = ()):
        self._p: list[Parameter] = []
        self.index: dict[str, int] = {}
        for p in params:
            self.add(p)

    def add(self, p: Parameter) -> int:
        """Append a parameter at the end of the set.

        Parameters
        ----------
        p : Parameter
            The parameter; its name must be new to the set.

        Returns
        -------
        int
            Its index (column of the Jacobian) [1].

        Raises
        ------
        ValueError
            When a parameter of that name is already in the set.
        """
        if p.name in self.index:
            raise ValueError(f"parameter {p.name!r} defined twice")
        self.index[p.name] = len(self._p)
        self._p.append(p)
        return self.index[p.name]

    def __len__(self) -> int:
        return len(self._p)

    def __iter__(self):
        return iter(self._p)

    def __getitem__(self, key: int | str) -> Parameter:
        return self._p[self.index[key]] if isinstance(key, str) else self._p[key]

    def __contains__(self, name: str) -> bool:
        return name in self.index

    @property
    def names(self) -> list[str]:
        """Parameter names, in set order."""
        return [p.name for p in self._p]

    def values(self) -> np.ndarray:
        """Start/held values of the parameters.

        Returns
        -------
        (p,) ndarray
            ``Parameter.value`` of each, in set order [parameter units, SI].
        """
        return np.array([p.value for p in self._p], float)

    def free(self) -> np.ndarray:
        """Mask of the parameters that vary.

        Returns
        -------
        (p,) ndarray of bool
            ``Parameter.vary`` of each, in set order.
        """
        return np.array([p.vary for p in self._p], bool)

    def held(self, names: Iterable[str], values: Sequence[float] | None = None) -> "ParameterSet":
        """A copy of the set with some parameters held.

        Parameters
        ----------
        names : iterable of str
            Parameters to hold (``vary=False``); names not in the set are ignored.
        values : sequence of float, optional
            Held values, paired with ``names`` [parameter units]; None keeps each
            parameter's current ``value``.

        Returns
        -------
        ParameterSet
            New set in the same order; the original is unchanged.
        """
        names = list(names)
        vals = dict(zip(names, values)) if values is not None else {}
        return ParameterSet(replace(p, vary=False, value=vals.get(p.name, p.value)) if p.name in names else p
                            for p in self._p)

    def subset(self, names: Iterable[str]) -> "ParameterSet":
        """The parameters named, as a new set.

        Parameters
        ----------
        names : iterable of str
            Names to keep; names not in the set are ignored.

        Returns
        -------
        ParameterSet
            The kept parameters in this set's order (not the order of ``names``).
        """
        keep = set(names)
        return ParameterSet(p for p in self._p if p.name in keep)


# --------------------------------------------------------------------------- linear algebra

@dataclass
class LinearSolution:
    """Least-squares solution of ``J x ~ z`` (whitened) by the column-scaled SVD.

    Attributes
    ----------
    x : ndarray
        Minimum-norm solution (in the scaled space) mapped back to parameter units.
    cov : ndarray
        ``(J^T J)^+`` in parameter units (the covariance when z has unit variance).
    rank : int
        Number of singular values above ``rcond * s_max``.
    singular_values : ndarray
        Of the column-scaled matrix, descending.
    estimable : ndarray of bool
        Per column: the unit vector lies in the row space (its value is determined by the
        data; the others are only determined in combinations).
    column_norm : ndarray
        ``|J_k|``, the scaling used.
    """
    x: np.ndarray
    cov: np.ndarray
    rank: int
    singular_values: np.ndarray
    estimable: np.ndarray
    column_norm: np.ndarray
    null_space: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def lstsq_svd(J: np.ndarray, z: np.ndarray, rcond: float = RCOND) -> LinearSolution:
    """Minimum-norm least squares of ``J x = z`` through the SVD of the column-scaled J.

    Parameters
    ----------
    J : (n, p) ndarray
        Whitened design (Jacobian) [whitened output per parameter unit].
    z : (n,) ndarray
        Whitened right-hand side (residual) [1].
    rcond : float
        Relative singular-value cut [1] (:data:`RCOND`).

    Returns
    -------
    LinearSolution
        x [parameter units], cov [parameter unit_i * parameter unit_j].  Columns that are identically zero get x = 0, zero covariance and
        ``estimable = False``.

    Notes
    -----
    Passes the NIST StRD linear problems (Pontius, Longley, Wampler 1–5) to the certified
    digits; see ``tests/test_fitting_core.py``.
    """
    x, norm, act, svd = _svd_solve(J, z, rcond)
    p = x.size
    cov = np.zeros((p, p))
    est = np.zeros(p, bool)
    if svd is None:
        return LinearSolution(x, cov, 0, np.zeros(0), est, norm)
    S, Vt, keep, V = svd
    C = (V / S[keep] ** 2) @ V.T
    if act.all():                     # every column: the same values without the fancy index
        cov[:, :] = C / np.outer(norm, norm)
    else:
        cov[np.ix_(act, act)] = C / np.outer(norm[act], norm[act])
    Vn = np.vstack([Vt[:S.size][~keep], Vt[S.size:]])
    est[act] = np.linalg.norm(Vn, axis=0) < 1e-6 if Vn.size else True
    null = np.zeros((p, Vn.shape[0]))
    null[act] = Vn.T
    return LinearSolution(x, cov, int(keep.sum()), S, est, norm, null)


def _svd_solve(J: np.ndarray, z: np.ndarray, rcond: float):
    """x of :func:`lstsq_svd` with the column norms, the active columns and (S, Vt, keep, V)
    of the SVD (None when no column is active)."""
    J = np.asarray(J, float)
    z = np.asarray(z, float)
    n, p = J.shape
    norm = np.sqrt(np.einsum("ij,ij->j", J, J))
    act = norm > 0
    if act.any():
        act &= norm > norm[act].max() * 1e-300
    x = np.zeros(p)
    if not act.any():
        return x, norm, act, None
    Js = J[:, act] / norm[act]
    # fewer rows than columns: the full Vt, whose last rows span the null space that a thin
    # SVD leaves out (2 mount pairs for 3 second-order unknowns)
    U, S, Vt = np.linalg.svd(Js, full_matrices=Js.shape[0] < Js.shape[1])
    keep = S > S[0] * rcond
    V = Vt[:S.size][keep].T
    xs = V @ ((U[:, keep].T @ z) / S[keep])
    x[act] = xs / norm[act]
    return x, norm, act, (S, Vt, keep, V)


def lstsq_svd_x(J: np.ndarray, z: np.ndarray, rcond: float = RCOND) -> np.ndarray:
    """The solution x of :func:`lstsq_svd` alone (the same values), without its covariance
    and null space, for the many small solves that use nothing else.

    Parameters
    ----------
    J : (n, p) ndarray
        Whitened design (Jacobian) [1 per parameter unit].
    z : (n,) ndarray
        Whitened right-hand side (residual) [1].
    rcond : float
        Relative singular-value cut [1] (:data:`RCOND`).

    Returns
    -------
    (p,) ndarray
        Minimum-norm solution [parameter units]; 0 for identically zero columns.
    """
    return _svd_solve(J, z, rcond)[0]


def pure_error_lack_of_fit(z: np.ndarray, cell: np.ndarray, n_params: int, alpha: float = ALPHA) -> "LackOfFit":
    """Lack-of-fit test of a fit to every reading against the pure error of its replicate
    cells (Draper & Smith §2.1): readings of one cell share the model's inputs.

    Parameters
    ----------
    z : (n,) ndarray
        Whitened (or equally weighted within each cell) residual of every reading [1].
    cell : (n,) ndarray of int
        Cell of each reading (readings with the same inputs; unique across runs).
    n_params : int
        Fitted parameters [1].
    alpha : float
        Significance level [1].

    Returns
    -------
    LackOfFit
        :func:`lack_of_fit` of the between-cell sum of squares sum n_j zbar_j^2 on
        (cells - n_params) dof against the within-cell sum of squares on (n - cells) dof.
    """
    _, inv, n = np.unique(cell, return_inverse=True, return_counts=True)
    mean = np.bincount(inv, weights=z) / n
    return lack_of_fit(float(n @ mean ** 2), n.size - int(n_params), float(np.sum((z - mean[inv]) ** 2)),
                       z.size - n.size, alpha)


def thin_svd(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thin SVD ``A = U diag(S) Vt`` (LAPACK ``gesdd``), S descending.

    For subspace questions on an already scaled design: column-space bases, null
    directions, bounds (the diagnosis' held-out folds, the Monte Carlo Cramér–Rao bound).

    Parameters
    ----------
    A : (n, p) ndarray
        Matrix [any unit].

    Returns
    -------
    U : (n, k) ndarray, S : (k,) ndarray, Vt : (k, p) ndarray
        k = min(n, p).
    """
    return np.linalg.svd(A, full_matrices=False)


def information_root(J: np.ndarray) -> np.ndarray:
    """A square root R of the Fisher information J^T J of a whitened design, by the thin
    SVD of the column-scaled J (not by forming J^T J, which would square its condition).

    Stacking R over the whitened rows of more data gives the design of all of it
    (R^T R + J2^T J2 = J^T J + J2^T J2): a proposed run is judged by
    :func:`lstsq_svd` of ``vstack([R, J2])`` without the tall design of the runs made.

    Parameters
    ----------
    J : (n, p) ndarray
        Whitened design [1 per parameter unit].

    Returns
    -------
    R : (k, p) ndarray
        k = min(n, p); R^T R = J^T J [1 / (parameter unit_i parameter unit_j)].
    """
    J = np.asarray(J, float)
    c = np.linalg.norm(J, axis=0)
    c = np.where(c > 0, c, 1.0)
    _, S, Vt = thin_svd(J / c)
    return (S[:, None] * Vt) * c[None, :]


def column_space_basis(J: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Orthonormal basis of the column space of J, columns scaled to unit norm first.

    Parameters
    ----------
    J : (n, p) ndarray
        Whitened design [1 per parameter unit].
    rcond : float
        Relative singular-value cut [1].

    Returns
    -------
    (n, r) ndarray
        r = the rank at ``rcond``; zero columns are left out (an empty basis if all are).
    """
    norm = np.linalg.norm(J, axis=0)
    act = norm > 0
    if not act.any():
        return np.zeros((J.shape[0], 0))
    U, S, _ = thin_svd(J[:, act] / norm[act])
    return U[:, S > S[0] * rcond]


def lstsq_min_norm(A: np.ndarray, b: np.ndarray, rcond: float | None = None) -> np.ndarray:
    """Minimum-norm least squares of ``A x = b`` on the unscaled matrix (LAPACK ``gelsd``).

    For small auxiliary fits whose columns are already on one scale: the diagnosis'
    residual shapes and signature shares, the sine check of a logged rate.  Fits of
    parameters with units use :func:`lstsq_svd` (column-scaled, with covariance).

    Parameters
    ----------
    A : (n, p) ndarray
        Design [any unit per parameter unit].
    b : (n,) ndarray
        Right-hand side [same unit as A's rows].
    rcond : float or None
        Relative singular-value cut; None: machine precision times max(n, p).

    Returns
    -------
    ndarray
        The solution x (p,) [parameter units].

    Raises
    ------
    numpy.linalg.LinAlgError
        When the SVD does not converge.
    """
    return np.linalg.lstsq(A, b, rcond=rcond)[0]


def separable_columns(J: np.ndarray, order: Sequence[int], tol: float = 1e-6) -> list[int]:
    """Greedy choice of columns that add a new direction, in priority order.

    Column k is kept when the part of its unit-scaled column outside the span of the
    columns kept before it has relative norm above ``tol``: a parameter aliased with
    higher-priority ones (θ0 and Ko in one tumble, K2 and Koo) is left out instead of
    making the design singular.

    Parameters
    ----------
    J : (n, p) ndarray
        Design [any unit per parameter unit]; zero columns are never kept.
    order : sequence of int
        Column indices, highest priority first.
    tol : float
        Relative norm of the new direction below which a column is aliased [1].

    Returns
    -------
    list of int
        The kept columns, in the order given.
    """
    norm = np.linalg.norm(J, axis=0)
    Q = np.zeros((J.shape[0], 0))
    kept = []
    for k in order:
        if norm[k] == 0:
            continue
        v = J[:, k] / norm[k]
        r = v - Q @ (Q.T @ v)
        r = r - Q @ (Q.T @ r)          # second pass: orthogonality to working precision
        nr = float(np.linalg.norm(r))
        if nr > tol:
            Q = np.column_stack([Q, r / nr])
            kept.append(k)
    return kept


# --------------------------------------------------------------------------- nonlinear

@dataclass
class GaussNewton:
    """Outcome of :func:`gauss_newton`: solution, whitened residual and Jacobian at it."""
    p: np.ndarray
    z: np.ndarray
    J: np.ndarray
    chi2: float
    iterations: int
    converged: bool
    message: str


def gauss_newton(residual: Callable[[np.ndarray], np.ndarray],
                 jacobian: Callable[[np.ndarray], np.ndarray],
                 p0: np.ndarray, free: np.ndarray | None = None, *, max_iter: int = 30,
                 rtol: float = 1e-10, rcond: float = RCOND,
                 lower: np.ndarray | None = None) -> GaussNewton:
    """Minimise ``|residual(p)|^2`` by Gauss–Newton steps, damped (Levenberg–Marquardt)
    when a full step does not lower it.

    Parameters
    ----------
    residual : callable
        p -> whitened residual z = (y - f(p)) / sigma, shape (n,).
    jacobian : callable
        p -> whitened Jacobian df/dp / sigma, shape (n, len(p)). Columns of held
        parameters are ignored.
    p0 : ndarray
        Start [parameter units].
    free : ndarray of bool, optional
        Which parameters vary (default all).
    max_iter : int
        Maximum number of accepted steps [1].
    rtol : float
        Stop when the chi-square decreases by less than ``rtol`` relative [1].
    rcond : float
        Rank rule of each step [1] (:func:`lstsq_svd`).
    lower : ndarray, optional
        Lower bounds [parameter units] (-inf for none): each trial point is projected onto them (a time
        constant cannot be negative).

    Returns
    -------
    GaussNewton
        The solution with z and J evaluated at it (J with all columns).

    Notes
    -----
    All damping levels of one iteration come from one SVD of the column-scaled
    Jacobian; the first that lowers chi-square is taken (Marquardt 1963).
    """
    p = np.array(p0, float)
    free = np.ones(p.size, bool) if free is None else np.asarray(free, bool)
    lo = None if lower is None else np.asarray(lower, float)
    if lo is not None:
        p = np.maximum(p, lo)
    z = residual(p)
    chi2 = float(z @ z)
    J = jacobian(p)
    mus = (0.0, 1e-12, 1e-9, 1e-6, 1e-4, 1e-2, 1.0)
    it, converged, msg = 0, False, "max_iter reached"
    if not np.isfinite(chi2):
        return GaussNewton(p, z, J, chi2, 0, False, "non-finite residual at the start")
    for it in range(1, max_iter + 1):
        Jf = J[:, free]
        norm = np.linalg.norm(Jf, axis=0)
        act = norm > 0
        if not act.any():
            converged, msg = True, "no free parameter acts"
            break
        U, S, Vt = np.linalg.svd(Jf[:, act] / norm[act], full_matrices=False)
        keep = S > S[0] * rcond
        U, S, V = U[:, keep], S[keep], Vt[keep].T
        uz = U.T @ z
        better = False
        for mu in mus:
            d = np.zeros(p.size)
            d[np.flatnonzero(free)[act]] = (V @ (S / (S ** 2 + mu * S[0] ** 2) * uz)) / norm[act]
            pn = p + d if lo is None else np.maximum(p + d, lo)
            zn = residual(pn)
            cn = float(zn @ zn)
            if np.isfinite(cn) and cn <= chi2:
                better = True
                break
        if not better:
            converged, msg = True, "no step lowers chi-square (minimum)"
            break
        dec = chi2 - cn
        p, z, chi2 = pn, zn, cn
        J = jacobian(p)
        if dec <= rtol * max(chi2, 1e-300):
            converged, msg = True, "chi-square converged"
            break
    return GaussNewton(p, z, J, chi2, it, converged, msg)


# --------------------------------------------------------------------------- adequacy

@dataclass(frozen=True)
class LackOfFit:
    """Result of :func:`lack_of_fit`.

    Attributes
    ----------
    status : 'adequate' | 'inadequate' | 'untestable'
        'untestable' when the model has no spare degrees of freedom (as many parameters
        as distinct inputs) or there is no independent estimate of the noise.
    statistic : float or None
        F (pure error from the data) or chi-square/dof (noise known).
    p_value : float or None
    dof_lof, dof_pe : int
        Lack-of-fit and pure-error degrees of freedom (dof_pe 0 when the noise is known).
    factor : float
        Factor to apply to standard uncertainties [1]: sqrt(statistic) when inadequate
        (Birge ratio), else 1.
    note : str
        Why the test is untestable, or how the covariance was scaled; may be empty.
    """
    status: str
    statistic: float | None
    p_value: float | None
    dof_lof: int
    dof_pe: int
    factor: float = 1.0
    note: str = ""

    @property
    def adequate(self) -> bool:
        """True when ``status`` is 'adequate' (False also when untestable)."""
        return self.status == "adequate"


def lack_of_fit(chi2_lof: float, dof_lof: int, chi2_pe: float | None = None, dof_pe: int = 0,
                alpha: float = ALPHA, reference: tuple[float, float, float] | None = None) -> LackOfFit:
    """Lack-of-fit test of a weighted fit to cell means against the pure error.

    Parameters
    ----------
    chi2_lof : float
        Weighted sum of squares of the cell-mean residuals, ``sum n_j (ybar_j - yhat_j)^2 /
        sigma_j^2`` (Draper & Smith §2.1 with weights).
    dof_lof : int
        Cells minus fitted parameters.
    chi2_pe : float, optional
        Weighted pure-error sum of squares, ``sum_j sum_i (y_ij - ybar_j)^2 / sigma_j^2``;
        None when sigma is known a priori (then chi2_lof ~ chi^2(dof_lof)).
    dof_pe : int
        Pure-error degrees of freedom (readings minus cells).
    alpha : float
        Significance level.
    reference : (k1, k2, k3), optional
        Cumulants of F dof_lof under the model when the weights are noise models estimated
        run by run from the pure error
        (:func:`accelcal.fitting.model.lack_of_fit_reference`); the p-value is then that of
        the shifted, scaled chi-square with these three cumulants, a + c chi^2(k) with
        c = k3 / (4 k2), k = 8 k2^3 / k3^2, a = k1 - c k (Pearson's type III; exact,
        chi^2(dof_lof), when the noise is known), instead of F(dof_lof, dof_pe).

    Returns
    -------
    LackOfFit
        F = (chi2_lof / dof_lof) / (chi2_pe / dof_pe) ~ F(dof_lof, dof_pe) under the model
        (or the reference's scaled chi-square).
    """
    if dof_lof <= 0:
        return LackOfFit("untestable", None, None, int(dof_lof), int(dof_pe), 1.0,
                         "no degrees of freedom left to test the model: as many parameters as "
                         "distinct inputs")
    if chi2_pe is None or dof_pe <= 0:
        stat = chi2_lof / dof_lof
        p = float(chi2_sf(chi2_lof, dof_lof))
        dpe = 0
    else:
        if chi2_pe <= 0:
            return LackOfFit("untestable", None, None, int(dof_lof), int(dof_pe), 1.0,
                             "no pure-error scatter")
        stat = (chi2_lof / dof_lof) / (chi2_pe / dof_pe)
        if reference is not None and reference[1] > 0 and reference[2] > 0:
            k1, k2, k3 = reference
            c, k = k3 / (4.0 * k2), 8.0 * k2 ** 3 / k3 ** 2
            p = float(chi2_sf(max(stat * dof_lof - (k1 - c * k), 0.0) / c, k))
        else:
            p = float(f_sf(stat, dof_lof, dof_pe))
        dpe = int(dof_pe)
    bad = p < alpha
    return LackOfFit("inadequate" if bad else "adequate", float(stat), p, int(dof_lof), dpe,
                     math.sqrt(stat) if bad and stat > 1 else 1.0)


@dataclass(frozen=True)
class NestedTest:
    """The nested test of a model against a smaller one it extends (:func:`nested_test`).

    Attributes
    ----------
    delta_chi2 : float
        Drop of the whitened chi-square [1].
    q : int
        Parameters gained [1].
    dof : int
        Residual dof of the larger model [1].
    statistic : float or None
        F = delta_chi2 / q / s2 when scaled by the larger model's s2 = chi2 / dof, else
        delta_chi2 / q; None when untestable.
    p_value : float or None
        F(q, dof) when scaled, chi-square(q) of delta_chi2 otherwise; None when untestable.
    scaled : bool
        Whether the statistic is scaled by s2.
    """
    delta_chi2: float
    q: int
    dof: int
    statistic: float | None
    p_value: float | None
    scaled: bool


def nested_test(chi2_small: float, chi2_big: float, q: int, dof: int, always_scaled: bool = False) -> NestedTest:
    """The nested test (extra sum of squares, Draper & Smith §6.1; the likelihood ratio of
    whitened Gaussian residuals) of a model against a smaller one it extends.

    Parameters
    ----------
    chi2_small, chi2_big : float
        Whitened chi-square of the smaller and of the larger model [1].
    q : int
        Parameters the larger model gains [1].
    dof : int
        Residual dof of the larger model [1].
    always_scaled : bool
        Scale by s2 = chi2_big / dof whatever its size (the F test); False: only when s2
        exceeds 1 (a gap the larger model leaves), else the chi-square test with the noise
        model taken as known.

    Returns
    -------
    NestedTest
        Untestable (statistic and p None) when q or dof is not positive, or chi2_big = 0
        when always scaled.
    """
    dchi = float(chi2_small - chi2_big)
    if q <= 0 or dof <= 0 or (always_scaled and chi2_big <= 0):
        return NestedTest(dchi, q, dof, None, None, False)
    s2 = chi2_big / dof
    scaled = always_scaled or s2 > 1.0
    F = dchi / q / s2 if scaled else dchi / q
    p = (f_sf(F, q, dof) if scaled else chi2_sf(dchi, q)) if dchi > 0 else 1.0
    return NestedTest(dchi, q, dof, F, float(p), scaled)


def birge_ratio(values: Sequence[float], u: Sequence[float]) -> tuple[float, float, float, int]:
    """Weighted mean of independent results and the Birge ratio of their scatter.

    Parameters
    ----------
    values, u : sequence of float
        Results and their standard uncertainties [same unit].

    Returns
    -------
    mean, u_mean, birge, dof : float, float, float, int
        Weighted mean [unit of values]; ``u_mean`` is the internal uncertainty 1/sqrt(sum w); ``birge`` = sqrt(chi2/(N-1))
        (Birge 1932); dof = N - 1.
    """
    x = np.asarray(values, float)
    w = 1.0 / np.asarray(u, float) ** 2
    m = float(np.sum(w * x) / np.sum(w))
    um = float(1.0 / math.sqrt(np.sum(w)))
    dof = x.size - 1
    chi2 = float(np.sum(w * (x - m) ** 2))
    return m, um, (math.sqrt(chi2 / dof) if dof > 0 else float("nan")), dof


def normalised_error(x1: float, U1: float, x2: float, U2: float) -> float:
    """Normalised error En of two results (ISO 13528 §9.7).

    Parameters
    ----------
    x1, x2 : float
        The two results [same unit].
    U1, U2 : float
        Their expanded uncertainties [same unit as x1].

    Returns
    -------
    float
        En = (x1 - x2) / sqrt(U1^2 + U2^2) [1]; |En| <= 1 is agreement.  With
        U1 = U2 = 0: +-inf by the sign of x1 - x2 (nan when x1 == x2).

    References
    ----------
    ISO 13528:2015, Statistical methods for use in proficiency testing by
    interlaboratory comparison, §9.7.
    """
    d = math.sqrt(U1 * U1 + U2 * U2)
    return (x1 - x2) / d if d > 0 else float("inf") * np.sign(x1 - x2)


def correlation_matrix(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correlation matrix and standard uncertainties of estimates from their covariance.

    Parameters
    ----------
    cov : (k, k) ndarray
        Covariance [parameter units squared].

    Returns
    -------
    R : (k, k) ndarray
        cov_ij / (u_i u_j) [1]; nan (or inf) in rows and columns of a zero variance.
    u : (k,) ndarray
        sqrt of the diagonal, negative rounding clipped to 0 [parameter units].
    """
    u = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        return cov / np.outer(u, u), u


# --------------------------------------------------------------------------- result

@dataclass
class FitResult:
    """A weighted least-squares fit.

    Attributes
    ----------
    params : ParameterSet
    values : ndarray
        Estimates [parameter units]; held parameters at their held values.
    cov_noise : ndarray
        Covariance from the noise model, (J^T J)^+ over the free, estimable parameters.
    cov : ndarray
        The covariance reported: cov_noise times ``lof.factor ** 2`` (lack-of-fit scaling).
    estimable : ndarray of bool
        Determined by the data (free and in the row space of the design).
    chi2, dof, n_obs, rank
        Whitened chi-square at the solution, n_obs - rank, observations, rank.
    lof : LackOfFit
    z, J : ndarray
        Whitened residual and Jacobian at the solution.
    converged : bool
    message : str
    """
    params: ParameterSet
    values: np.ndarray
    cov_noise: np.ndarray
    cov: np.ndarray
    estimable: np.ndarray
    chi2: float
    dof: int
    n_obs: int
    rank: int
    lof: LackOfFit
    z: np.ndarray
    J: np.ndarray
    converged: bool = True
    message: str = ""

    @property
    def names(self) -> list[str]:
        """Parameter names, in the order of ``values`` and of the covariance."""
        return self.params.names

    def value(self, name: str) -> float:
        """Estimate of one parameter.

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        float
            Estimate (or held value) [parameter unit].
        """
        return float(self.values[self.params.index[name]])

    def std(self, name: str) -> float:
        """Reported standard uncertainty of one parameter, from ``cov``.

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        float
            sqrt of the diagonal of ``cov`` (lack-of-fit factor included) [parameter
            unit]; nan when the parameter is held or not estimable.
        """
        i = self.params.index[name]
        return float(math.sqrt(max(self.cov[i, i], 0.0))) if self.estimable[i] else float("nan")

    def std_noise(self, name: str) -> float:
        """Standard uncertainty of one parameter from the noise model alone.

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        float
            sqrt of the diagonal of ``cov_noise`` (no lack-of-fit factor) [parameter
            unit]; nan when the parameter is held or not estimable.
        """
        i = self.params.index[name]
        return float(math.sqrt(max(self.cov_noise[i, i], 0.0))) if self.estimable[i] else float("nan")

    def correlation(self, names: Sequence[str]) -> tuple[list[str], np.ndarray]:
        """Correlation matrix of some parameters, from ``cov`` (:func:`correlation_matrix`).

        Parameters
        ----------
        names : sequence of str
            Parameters to include.

        Returns
        -------
        names : list of str
            The parameters, in the order of the matrix rows.
        R : (k, k) ndarray
            Correlation coefficients [1]; nan in rows and columns of parameters with
            zero variance (held or not estimable).
        """
        idx = [self.params.index[n] for n in names]
        return list(names), correlation_matrix(self.cov[np.ix_(idx, idx)])[0]

    @property
    def birge(self) -> float:
        """sqrt(chi2 / dof) of the whitened residuals (nan without dof)."""
        return math.sqrt(self.chi2 / self.dof) if self.dof > 0 else float("nan")


def finish_fit(params: ParameterSet, gn: GaussNewton, lof: LackOfFit | None = None,
               rcond: float = RCOND) -> FitResult:
    """Covariance and result of a converged problem (:func:`gauss_newton` outcome).

    The noise-model covariance is ``(J^T J)^+`` over the free parameters from the
    column-scaled SVD of the whitened Jacobian at the solution; held parameters get zero
    covariance and ``estimable = False``.

    Parameters
    ----------
    params : ParameterSet
        The parameters, in the order of ``gn.p`` and of the Jacobian columns.
    gn : GaussNewton
        Solution with its whitened residual [1] and Jacobian [1 per parameter unit].
    lof : LackOfFit, optional
        Adequacy test to apply; default: the chi-square test of the whitened residuals
        with dof = n - rank (noise known), :func:`lack_of_fit`.
    rcond : float
        Relative singular-value cut [1] (:data:`RCOND`).

    Returns
    -------
    FitResult
        Reported covariance = noise-model covariance times ``lof.factor ** 2``.
    """
    free = params.free()
    J = gn.J
    sol = lstsq_svd(J[:, free], np.zeros(J.shape[0]), rcond)
    p = len(params)
    cov_n = np.zeros((p, p))
    idx = np.flatnonzero(free)
    cov_n[np.ix_(idx, idx)] = sol.cov
    est = np.zeros(p, bool)
    est[idx] = sol.estimable
    n = J.shape[0]
    dof = n - sol.rank
    if lof is None:
        lof = lack_of_fit(gn.chi2, dof)
    cov = cov_n * lof.factor ** 2
    return FitResult(params, gn.p, cov_n, cov, est, gn.chi2, dof, n, sol.rank, lof, gn.z, J,
                     gn.converged, gn.message)


def straight_line_slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of y on x with an intercept, and its standard uncertainty from
    the residuals (s^2 on n - 2 degrees of freedom): b = S_xy / S_xx, u(b) = s / sqrt(S_xx)
    (NIST/SEMATECH e-Handbook §4.1.4.1), in closed form, so a series of millions of
    readings takes no design matrix.

    Parameters
    ----------
    x, y : (n,) ndarray
        Finite values, n >= 3, x not constant [any units].

    Returns
    -------
    (float, float)
        Slope [unit of y / unit of x] and its standard uncertainty.
    """
    xc = x - x.mean()
    sxx = float(xc @ xc)
    slope = float(xc @ (y - y.mean())) / sxx
    resid = y - y.mean() - slope * xc
    return slope, math.sqrt(float(resid @ resid) / (y.size - 2) / sxx)


def linear_fit(X: np.ndarray, y: np.ndarray, sigma: np.ndarray | float = 1.0,
               params: ParameterSet | Sequence[str] | None = None, *,
               residual_scale: bool = True, rcond: float = RCOND) -> FitResult:
    """Weighted linear least squares ``y = X b`` (a model linear in its parameters).

    Parameters
    ----------
    X : (n, p) ndarray
        Design [output unit per parameter unit].
    y : (n,) ndarray
        Observations [output unit].
    sigma : ndarray or float
        Standard deviation of each observation [output unit].
    params : ParameterSet or list of names, optional
        Names of the p columns (default ``b0``, ``b1``, ...).
    residual_scale : bool
        True (the classical regression covariance, NIST StRD): cov = s^2 (X^T W X)^+ with
        s^2 = chi2 / (n - rank). False: cov = (X^T W X)^+ (sigma known), and the lack-of-fit
        factor applies when the chi-square test fails.
    rcond : float
        Relative singular-value cut [1] (:data:`RCOND`).

    Returns
    -------
    FitResult
        Estimates [parameter units] with covariance, chi-square and adequacy.
    """
    X = np.asarray(X, float)
    y = np.asarray(y, float)
    s = np.broadcast_to(np.asarray(sigma, float), y.shape)
    if params is None:
        params = ParameterSet(Parameter(f"b{k}", f"b{k}") for k in range(X.shape[1]))
    elif not isinstance(params, ParameterSet):
        params = ParameterSet(Parameter(n, n) for n in params)
    Jw = X / s[:, None]
    sol = lstsq_svd(Jw, y / s, rcond)
    z = (y - X @ sol.x) / s
    chi2 = float(z @ z)
    dof = y.size - sol.rank
    if residual_scale:
        s2 = chi2 / dof if dof > 0 else float("nan")
        lof = LackOfFit("untestable" if dof <= 0 else "adequate", s2, None, dof, 0,
                        math.sqrt(s2) if dof > 0 else 1.0,
                        "covariance scaled by the residual variance")
    else:
        lof = lack_of_fit(chi2, dof)
    return FitResult(params, sol.x, sol.cov, sol.cov * lof.factor ** 2, sol.estimable, chi2, dof,
                     y.size, sol.rank, lof, z, Jw)

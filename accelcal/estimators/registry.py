"""The estimator registry: every paper method the campaign runs, declared once.

pvlib's ModelChain is the pattern: a method declares what it is and the code that runs a
campaign, the Monte Carlo study and the certificate read the declaration, so a new method
is one entry here (``docs/design.md``, "Add an estimator").  Each :class:`Estimator`
names

* ``method``: the id stored with every record it makes (``results.method``);
* ``tests``: the test kinds (drop-format ``test``) whose runs it takes;
* ``certificate``: how it works, in the certificate's words (section 3);
* ``records(runs, steps)``: the records it adds to the campaign result, in order
  (:class:`~accelcal.estimators.records.Records`; a failure is a flags-only record);
* ``prepare(runs, steps)``: optional first pass whose outcome other methods read
  (``steps[method]``: the tumble's reference for the centrifuge radius, the centrifuge's
  square terms for the tumble's K2); ``steps["rig_uncertainty"]`` holds the lab's stated
  rig inputs (rig id -> :data:`accelcal.effects.RIG_INPUTS` id -> u) for the budgets;
* ``truth(coefficients, effects, test, g, records)``: what each of its coefficients
  estimates in a simulated scenario (the Monte Carlo study's truth mapping), given the
  records of its own the processed campaign holds, by name;
* ``methods``: the method ids of its records, in the order a value is adopted from them
  when the joint fit could not run, and ``adoption`` (lower first) among estimators;
* ``main``: the coefficients the Monte Carlo study reports as its headline;
* ``crb``: whether the whole-campaign Cramér–Rao bound applies to its values (not to a
  tumble's apparent, aliased ones);
* ``order``: where it runs (lower first; the tumble first, its reference scales the
  centrifuge radius);
* ``figures(extras)``: the residual figures of its stored result
  (:class:`~accelcal.results.ResidualFigure`), which the certificate draws: what a method
  stored is read by the method, never by the report (:func:`residual_figures`);
* ``checks(extras)``: the fit statistics of its stored result
  (:class:`~accelcal.results.FitCheck`: lack of fit, term F tests, residual trends), which
  the certificate lists in its adequacy section (:func:`fit_checks`).

The adopted values come from the joint fit (:mod:`accelcal.estimators.joint`, method
:data:`ADOPTED`), which is not a paper method and not in the registry.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

#: Method id of the adopted values (the joint fit through the forward model).
ADOPTED = "joint_ml"

#: truth(coefficients, effects, test, g [m/s2], records) -> {(name, rig_id): (truth, how)}
TruthMapping = Callable[[Mapping[str, float], Mapping[str, float], Mapping[str, Any], float,
                         Mapping[str, Any]], dict[tuple[str, str], tuple[float, str]]]


@dataclass(frozen=True)
class Estimator:
    """A paper method of the campaign (module docstring for each field)."""
    method: str
    tests: tuple[str, ...]
    certificate: str
    records: Callable[[Sequence, Mapping[str, Any]], list]
    prepare: Callable[[Sequence, Mapping[str, Any]], Any] | None = None
    truth: TruthMapping | None = None
    methods: tuple[str, ...] = ()
    adoption: int = 99
    main: tuple[str, ...] = ()
    crb: bool = True
    order: int = 50
    figures: Callable[[Mapping[str, Any]], list] | None = None
    checks: Callable[[Mapping[str, Any]], list] | None = None

    @property
    def record_methods(self) -> tuple[str, ...]:
        """Method ids of its records (``methods``, default its own)."""
        return self.methods or (self.method,)


#: method id -> Estimator, in the order the campaign runs them
ESTIMATORS: dict[str, Estimator] = {}


def register(est: Estimator) -> Estimator:
    """Add (or replace) an estimator; returns it."""
    ESTIMATORS[est.method] = est
    return est


@contextmanager
def registered(est: Estimator) -> Iterator[Estimator]:
    """An estimator registered for the duration of a ``with`` block (a test's toy method)."""
    before = ESTIMATORS.get(est.method)
    register(est)
    try:
        yield est
    finally:
        if before is None:
            ESTIMATORS.pop(est.method, None)
        else:
            ESTIMATORS[est.method] = before


def estimators() -> list[Estimator]:
    """Every registered estimator, in run order (the paper methods registered on import)."""
    _load()
    return sorted(ESTIMATORS.values(), key=lambda e: e.order)


def for_test(test: str) -> list[Estimator]:
    """The estimators that take runs of test kind ``test``."""
    return [e for e in estimators() if test in e.tests]


def prepared(steps: Mapping[str, Any], test: str) -> list:
    """The first-pass outcomes (``prepare``) of the estimators that take runs of test kind
    ``test``, in run order: what one method reads of another, found by the runs it takes,
    never by its method id.

    Parameters
    ----------
    steps : mapping
        Method id -> first-pass outcome, as the campaign builds it.
    test : str
        Drop-format test kind (``'centrifuge'``, ``'tilt_rotation'``, ...).

    Returns
    -------
    list
        The outcomes present in ``steps``.
    """
    return [steps[e.method] for e in for_test(test) if e.method in steps]


def adoption_order() -> tuple[str, ...]:
    """Method ids in the order a value is adopted: the joint fit, then the paper methods."""
    ranked = sorted(estimators(), key=lambda e: e.adoption)
    return (ADOPTED,) + tuple(m for e in ranked for m in e.record_methods)


def display_order() -> dict[str, int]:
    """Method id -> rank for tables (the joint fit first, then the run order)."""
    out = {ADOPTED: -1}
    for k, e in enumerate(estimators()):
        for m in e.record_methods:
            out.setdefault(m, k)
    return out


def main_coefficients() -> dict[str, tuple[str, ...]]:
    """Method id -> the coefficients the Monte Carlo study reports as its headline."""
    return {e.method: e.main for e in estimators() if e.main}


def residual_figures(extras: Mapping[str, Any] | None) -> list:
    """The residual figures of a stored result: each estimator's (``figures``, in run
    order), then any residual series a method stored
    (:func:`accelcal.results.stored_series_figures`).

    Parameters
    ----------
    extras : mapping or None
        The stored result's extras.

    Returns
    -------
    list of ResidualFigure
    """
    from ..results import stored_series_figures
    return ([f for est in estimators() if est.figures is not None for f in est.figures(extras or {})]
            + stored_series_figures(dict(extras or {})))


def fit_checks(extras: Mapping[str, Any] | None) -> list:
    """The fit statistics of a stored result: each estimator's (``checks``, in run order).

    Parameters
    ----------
    extras : mapping or None
        The stored result's extras.

    Returns
    -------
    list of FitCheck
    """
    return [c for est in estimators() if est.checks is not None for c in est.checks(extras or {})]


#: The modules of the paper methods (each registers its estimator on import).
PAPER_METHOD_MODULES = ("tumble", "centrifuge", "thermal", "sinusoidal")
_LOADED = False


def _load() -> None:
    """Import the paper methods' modules, which register themselves (once)."""
    global _LOADED
    if not _LOADED:
        _LOADED = True
        for name in PAPER_METHOD_MODULES:
            importlib.import_module(f"{__package__}.{name}")

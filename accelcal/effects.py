"""The catalogue of instrument coefficients and rig/instrument effects (effects.md).

These ids are the shared vocabulary of the simulator, the estimators, the
diagnosis and the warehouse: never rename them.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

from .constants import G_STANDARD

TESTS = ("tumble", "centrifuge", "tilt_rotation", "sine_centrifuge")


@dataclass(frozen=True)
class Coefficient:
    """One instrument coefficient: every per-parameter fact the code needs.

    Attributes
    ----------
    name : str
        effects.md symbol.
    unit : str
        SI unit; "out" stands for the run's output_unit.
    display_unit, display_factor : str, float
        Display = SI / display_factor, in ``display_unit`` (effects.md "usual display").
    typical : float
        Typical size [SI]: the scale of its parameter (finite-difference steps, solver
        scaling, a paper method's "weakly determined" test).
    plausible : float or None
        Largest plausible size [SI] of an ordinary unit; a term whose design uncertainty
        exceeds it is held as weakly determined.  None for the coefficients every design
        is built to determine (never held on that ground).
    """
    name: str
    unit: str
    display_unit: str
    display_factor: float
    typical: float = 1.0
    plausible: float | None = None


#: Instrument-model coefficients (effects.md, "Instrument model"), plus theta0 of the tumble.
COEFFICIENTS: dict[str, Coefficient] = {c.name: c for c in [
    Coefficient("K0", "m/s2", "ug", 1e-6 * G_STANDARD, typical=0.001, plausible=None),
    Coefficient("K1", "out/(m/s2)", "out/g", 1.0 / G_STANDARD, typical=1, plausible=None),
    Coefficient("Kp", "rad", "urad", 1e-6, typical=0.0001, plausible=0.05),
    Coefficient("Ko", "rad", "urad", 1e-6, typical=0.0001, plausible=0.05),
    Coefficient("K2", "s2/m", "ug/g2", 1e-6 / G_STANDARD, typical=1e-6, plausible=0.0001),
    Coefficient("Koq", "s2/m", "ug/g2", 1e-6 / G_STANDARD, typical=1e-7, plausible=1e-5),
    Coefficient("Kip", "s2/m", "ug/g2", 1e-6 / G_STANDARD, typical=1e-6, plausible=1e-5),
    Coefficient("Kio", "s2/m", "ug/g2", 1e-6 / G_STANDARD, typical=1e-6, plausible=1e-5),
    Coefficient("Kpo", "s2/m", "ug/g2", 1e-6 / G_STANDARD, typical=1e-6, plausible=1e-5),
    Coefficient("Kpp", "s2/m", "ug/g2", 1e-6 / G_STANDARD, typical=1e-6, plausible=1e-5),
    Coefficient("Koo", "s2/m", "ug/g2", 1e-6 / G_STANDARD, typical=1e-6, plausible=1e-5),
    Coefficient("K3", "s4/m2", "ug/g3", 1e-6 / G_STANDARD ** 2, typical=1e-9, plausible=1e-7),
    Coefficient("K0T", "m/s2/degC", "ug/degC", 1e-6 * G_STANDARD, typical=1e-5, plausible=0.001),
    Coefficient("K1T", "1/degC", "ppm/degC", 1e-6, typical=0.0001, plausible=0.01),
    Coefficient("theta0", "rad", "deg", 3.141592653589793 / 180.0, typical=0.001, plausible=None),
]}

#: Paper 002's extra third-order terms KPPP·a_P³, KOOO·a_O³ (methods.md, paper 002 eq 1):
#: not in the effects.md model; the sinusoidal method may add them (its F test).
PAPER_TERMS: dict[str, Coefficient] = {c.name: c for c in [
    Coefficient("Kppp", "s4/m2", "ug/g3", 1e-6 / G_STANDARD ** 2, typical=1e-9, plausible=1e-7),
    Coefficient("Kooo", "s4/m2", "ug/g3", 1e-6 / G_STANDARD ** 2, typical=1e-9, plausible=1e-7),
]}

#: The instrument coefficients by the input axis they belong to (0 IA, 1 PA, 2 OA; effects.md
#: model): the cross-axis sensitivity of an axis (IA has none) and its square term.
CROSS_AXIS_TERM: tuple[str | None, str, str] = (None, "Kp", "Ko")
SQUARE_TERM: tuple[str, str, str] = ("K2", "Kpp", "Koo")
#: The cross-coupling coefficient of each pair of input axes (effects.md model).
CROSS_TERM: dict[frozenset[int], str] = {frozenset((0, 1)): "Kip", frozenset((0, 2)): "Kio",
                                         frozenset((1, 2)): "Kpo"}

#: Rig quantities fitted beside the instrument: name -> (SI unit, typical size [SI], largest
#: plausible departure from the nominal value [SI]).  A radius known to worse than 1 cm from
#: the runs (a rig with no IA-radial mount: IA sees it only through the mount angle) is
#: held at the rig's nominal radius, as weakly determined.
RIG_QUANTITIES: dict[str, tuple[str, float, float]] = {"radius": ("m", 1.0, 0.01)}


@dataclass(frozen=True)
class RigInput:
    """A quantity of the rig the forward model takes as known from the drop (a metadata
    value or a logged column) whose uncertainty the lab states: it enters every budget
    through the model's derivative (JCGM 100 §5.1.3), a type-B term.

    Attributes
    ----------
    id : str
        Its name in budgets and flags (``g_local``).
    config_key : str
        Key of ``[rigs."ID"]`` in accelcal.toml that states its standard uncertainty.
    unit : str
        Unit of that uncertainty and of the value (``m/s2``, ``deg``, ``degC``).
    meta_key : str or None
        Drop-format metadata key the model reads (``g_local_m_s2``), or None.
    column : str or None
        Logged column the model reads (``temp_c``), or None.
    tests : tuple of str
        Test kinds whose output depends on it.
    per_point : bool
        True when its error is shared by every return to one chamber set point and
        independent between set points (a reading), False when it is one value for all
        runs of the rig.
    what : str
        How the budget line names it.
    step : float
        Difference step of the model's derivative with respect to it [its unit].
    read_through : tuple of str
        For a logged column: the coefficients through which the forward model reads it
        (the temperature only through K0T and K1T); it enters a model that has one of them.
    """

    id: str
    config_key: str
    unit: str
    meta_key: str | None
    column: str | None
    tests: tuple[str, ...]
    per_point: bool
    what: str
    step: float
    read_through: tuple[str, ...] = ()


#: Rig inputs with a lab-stated uncertainty: local gravity at every rig, the
#: tilt of the thermal table, the temperature reading of a thermal run.
RIG_INPUTS: dict[str, RigInput] = {r.id: r for r in [
    RigInput("g_local", "g_local_u_m_s2", "m/s2", "g_local_m_s2", None, TESTS, False,
             "local gravity g_local", 1e-5),
    RigInput("table_tilt", "tilt_u_deg", "deg", "tilt_deg", None, ("tilt_rotation",), False,
             "tilt angle of the table", 1e-3),
    RigInput("temperature", "temperature_u_c", "degC", None, "temp_c", ("tilt_rotation",), True,
             "error of the temperature reading at each set point (independent between set points)",
             1e-3, ("K0T", "K1T")),
]}


def coefficient_spec(name: str) -> Coefficient | None:
    """The catalogue row of a coefficient name (``"K2"``, ``"K0[run]"``, ``"Kppp"``), or None.
    A combination (:func:`combination_name`, ``"K2(Koo)"``) has the row of its first term: its
    unit and display unit."""
    base = re.split(r"[\[(]", name, maxsplit=1)[0]
    return COEFFICIENTS.get(base) or PAPER_TERMS.get(base)


def _catalogue_rank(name: str) -> tuple[int, str]:
    """Sort key of a parameter name in catalogue order: the instrument coefficients, the
    paper terms, the effects, then any other name alphabetically."""
    order = [*COEFFICIENTS, *PAPER_TERMS, *EFFECTS]
    base = name.split("[", 1)[0]
    return (order.index(base) if base in order else len(order)), name


def combination_name(name: str, terms: Mapping[str, float]) -> str:
    """The name of what a row measures when the runs determine a coefficient only together
    with others (IEEE 1293's tumble ``K2 - Koo``): structural, never a number from the data.

    Parameters
    ----------
    name : str
        The coefficient kept (``"K2"``, ``"theta0[PA]"``): the quantity the row stands for.
    terms : mapping of str to float
        Other coefficient -> its factor in the combination [unit of name / unit of it]; only
        the names enter the row's name.

    Returns
    -------
    str
        ``name(T1,T2,...)``, the terms in catalogue order without factors or signs
        (``"K1(Koq,K3)"``, ``"K0(Koo)"``, ``"theta0(Ko)"``); ``name`` when ``terms`` is
        empty.  It is the same for every draw and every campaign of a design; the factors
        travel beside it (``CoefficientResult.factors``, the warehouse column ``factors``,
        :func:`combination_formula`).  In SQL the quantity is ``split_part(name, '(', 1)``.
    """
    if not terms:
        return name
    return f"{name}({','.join(sorted(terms, key=_catalogue_rank))})"


def split_combination(name: str) -> tuple[str, tuple[str, ...]]:
    """The inverse of :func:`combination_name`: ``"K1(Koq,K3)"`` -> ``("K1", ("K3", "Koq"))``.

    Parameters
    ----------
    name : str
        A row name; a bracketed scope (``"K2[PA](Koo)"``) stays with its coefficient.

    Returns
    -------
    (str, tuple of str)
        The quantity (the coefficient kept) and the names of the terms it takes up (empty
        for a plain name); their factors are the row's ``factors``.
    """
    kept, _, rest = name.partition("(")
    return kept, tuple(rest.rstrip(")").split(",")) if rest else ()


def combination_formula(name: str, factors: Mapping[str, float], digits: int = 3) -> str:
    """What a combination row measures, as a formula for people:
    ``"K1 + 9.55·K3 + 1.1·Koq"`` (factors to ``digits`` significant digits, in the order
    given); ``name`` alone when ``factors`` is empty.

    Parameters
    ----------
    name : str
        The row name or the quantity (``"K1(Koq,K3)"`` or ``"K1"``).
    factors : mapping of str to float
        Term -> factor [unit of the quantity / unit of the term].
    """
    return split_combination(name)[0] + "".join(
        f" {'-' if f < 0 else '+'} {abs(f):.{digits}g}·{k}" for k, f in factors.items())


def si_unit(name: str, output_unit: str = "out") -> str:
    """SI unit of a coefficient or effect parameter [text], "out" replaced by the run's
    output unit; "s2/m" for a name the catalogue does not know (a second-order term)."""
    spec = coefficient_spec(name)
    if spec is not None:
        unit = spec.unit
    elif name.split("[", 1)[0] in EFFECTS:
        unit = EFFECTS[name.split("[", 1)[0]].unit
    else:
        unit = "s2/m"
    return output_unit + unit[3:] if unit.startswith("out/") else unit

#: How display units are printed (effects.md notation -> symbols).
PRETTY_UNITS = {"ug": "µg", "ug/g2": "µg/g²", "ug/g3": "µg/g³", "urad": "µrad",
                "ug/degC": "µg/°C", "ppm/degC": "ppm/°C", "deg": "°"}


def to_display(name: str, value: float, std_u: float | None, unit: str,
               k: float = 2.0) -> tuple[float, float | None, str, bool]:
    """A coefficient in its display unit: (value, U = k u, unit, U_in_ppm).

    K1 is shown in <output unit>/g with U relative, in ppm (U_in_ppm True); a name
    outside COEFFICIENTS is returned in its own unit.  value and u in SI (effects.md)."""
    U = None if std_u is None else k * std_u
    spec = coefficient_spec(name)
    if spec is None or spec.name not in COEFFICIENTS:
        return value, U, unit, False
    val = value / spec.display_factor
    if spec.name == "K1":
        # the SI unit is "<output unit>/(m/s2)" (si_unit); the output unit may hold a "/"
        out_unit = unit[:-len("/(m/s2)")] if unit.endswith("/(m/s2)") else (unit.split("/")[0] if "/" in unit else "out")
        rel = None if U is None or value == 0 else U / abs(value) * 1e6
        return val, rel, f"{out_unit}/g", True
    return (val, None if U is None else U / spec.display_factor,
            PRETTY_UNITS.get(spec.display_unit, spec.display_unit), False)


def display_coefficient(name: str, value: float | None, std_u: float | None, unit: str | None,
                        k: float = 2.0) -> tuple[str, str, str]:
    """(value, U, display unit) as written for people: GUM 7.2.6 rounding
    (:func:`accelcal.rounding.round_gum`), U = k u.  K1's U is relative, "x ppm", and its
    value is rounded to the last digit of the absolute U."""
    from .rounding import format_sig, round_gum
    unit = unit or ""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—", "—", unit
    if isinstance(std_u, float) and math.isnan(std_u):
        std_u = None
    val, U, dunit, ppm = to_display(name, value, std_u, unit, k)
    if ppm:
        U_abs = None if U is None else U * 1e-6 * abs(val)
        return round_gum(val, U_abs).value, ("—" if U is None else f"{format_sig(U)} ppm"), dunit
    r = round_gum(val, U)
    return r.value, r.uncertainty, dunit


@dataclass(frozen=True)
class Effect:
    """One effects.md effect.

    Attributes
    ----------
    id, tests, parameter, unit, definition : str
        As in effects.md (``unit`` of the parameter, SI).
    typical : float
        Typical size of the parameter [unit]: difference steps (1e-3 of it), parameter
        scaling, the size of an "unobservable" benchmark case.
    plausible : float
        Largest plausible size [unit]: a larger estimate is not a credible finding.
    coefficient : str or None
        The instrument-model coefficient it is, if any.
    """
    id: str
    tests: tuple[str, ...]
    parameter: str
    unit: str
    definition: str
    typical: float
    plausible: float
    coefficient: str | None = None


def _instrument_effect(eid: str, tests: tuple[str, ...], coefficient: str, definition: str) -> Effect:
    """An effect that is an instrument-model coefficient (effects.md: ``cross_coupling`` is
    Kip): its unit, typical and plausible size are the coefficient's, one fact in one place."""
    c = COEFFICIENTS[coefficient]
    return Effect(eid, tests, coefficient, c.unit, definition, typical=c.typical, plausible=c.plausible,
                  coefficient=coefficient)


EFFECTS: dict[str, Effect] = {e.id: e for e in [
    Effect("earth_rate", ("centrifuge", "sine_centrifuge"), "scale", "1",
           "the Omega_e*sin(latitude) part of omega_z; 1 means the physical size", typical=1.0, plausible=3.0),
    Effect("ia_tilt", ("centrifuge", "sine_centrifuge"), "lambda", "rad",
           "first plane axis tilted out of the table plane by lambda, positive towards up", typical=0.0001, plausible=0.01),
    Effect("mass_centre_offset", ("centrifuge", "sine_centrifuge"), "r", "m",
           "effective mass centre r from the turning centre along the first plane axis", typical=0.001, plausible=0.02),
    Effect("mount_angle_error", ("centrifuge",), "dphi", "rad",
           "true mount angle is phi + dphi, same for both polarities", typical=0.001, plausible=0.02),
    Effect("arm_stretch", ("centrifuge", "sine_centrifuge"), "kappa", "s2",
           "turning centre sits at R*(1 + kappa*omega_z^2)", typical=1e-06, plausible=1e-05),
    Effect("rate_scale_error", ("centrifuge", "sine_centrifuge"), "epsilon", "1",
           "true rate is (1 + epsilon) times the logged table_rate_rad_s", typical=1e-05, plausible=0.01),
    Effect("spindle_tilt", ("sine_centrifuge",), "beta", "rad",
           "table plane tilted by beta: gravity adds g*sin(beta)*cos(alpha) along the inward radial "
           "and g*sin(beta)*sin(alpha) along the ccw direction of motion; vertical g*cos(beta)", typical=0.0001, plausible=0.01),
    Effect("sensor_lag", ("sine_centrifuge",), "tau", "s",
           "output follows the input through a first-order lag with time constant tau", typical=0.001, plausible=0.05),
    Effect("initial_misalignment", ("tumble",), "theta0", "rad",
           "true head angle is theta + theta0", typical=0.001, plausible=0.05),
    Effect("fixture_thermal_tilt", ("tilt_rotation",), "c", "rad/degC",
           "IA tilts out of the table plane by c*(T - T_ref), positive towards the normal axis", typical=1e-06, plausible=0.0001),
    Effect("base_tilt_drift", ("tilt_rotation",), "dgamma_dt", "rad/s",
           "the tilt gamma grows linearly in time from the run start", typical=1e-09, plausible=1e-07),
    Effect("tilt_tide", ("tilt_rotation",), "amplitude", "rad",
           "gamma gains A*sin(2*pi*t/44712 s)", typical=1e-06, plausible=0.0001),
    _instrument_effect("bias_temperature", TESTS, "K0T", "as in the instrument model"),
    _instrument_effect("scale_temperature", TESTS, "K1T", "as in the instrument model"),
    Effect("bias_drift", TESTS, "d", "m/s2/s", "K0 grows by d*t, t = time_s", typical=1e-08, plausible=1e-05),
    _instrument_effect("odd_quadratic", ("centrifuge", "sine_centrifuge"), "Koq",
                       "instrument term, when the baseline model omits it"),
    _instrument_effect("cubic", ("centrifuge", "sine_centrifuge"), "K3",
                       "instrument term, when the baseline model omits it"),
    _instrument_effect("cross_coupling", ("centrifuge", "sine_centrifuge"), "Kip",
                       "instrument term, when the baseline model omits it"),
]}


def typical_size(key: str) -> float:
    """Typical size [SI] of a coefficient (``"K2"``, ``"K0[run]"``), an effect's parameter
    (``"sensor_lag"``) or a rig quantity (``"radius"``): the catalogue's one value.

    Raises
    ------
    KeyError
        For a name the catalogue does not know.
    """
    spec = coefficient_spec(key)
    if spec is not None:
        return spec.typical
    base = key.split("[", 1)[0]
    if base in EFFECTS:
        return EFFECTS[base].typical
    return RIG_QUANTITIES[base][1]


def plausible_size(key: str) -> float | None:
    """Largest plausible size [SI] of a coefficient or effect parameter, or of a rig
    quantity's departure from its nominal value; None for the coefficients every design
    determines and names the catalogue lacks."""
    spec = coefficient_spec(key)
    if spec is not None:
        return spec.plausible
    base = key.split("[", 1)[0]
    if base in RIG_QUANTITIES:
        return RIG_QUANTITIES[base][2]
    return EFFECTS[base].plausible if base in EFFECTS else None

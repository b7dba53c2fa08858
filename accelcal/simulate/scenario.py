"""Scenario files: what to simulate (a unit, its truth, the rigs, the test plan, the noise).

A scenario is a TOML file (or the equivalent dict).  Every number is SI unless its
key says otherwise (``*_deg``, ``*_c``).  Layout::

    name = "snj103-lxj100"          # free text
    seed = 20261120                 # default seed; simulate_campaign(seed=...) overrides it

    [unit]
    serial = "SNJ-1-03"             # -> unit_serial
    model = "QA-2000"               # -> unit_model
    campaign = "SNJ-1-03/2026-11-20"
    output_unit = "mA"              # mA, V, count or m/s2
    [unit.coefficients]             # effects.md names; absent = 0 (K1 = 1)
    K0 = 4.0e-4                     # m/s^2
    K1 = 0.1325                     # output_unit per m/s^2
    K2 = 3.94e-7                    # s^2/m    (also Koq Kip Kio Kpo Kpp Koo)
    K3 = 2.0e-10                    # s^4/m^2
    Kp = 0.0                        # rad      (also Ko)
    K0T = 0.0                       # m/s^2/degC
    K1T = 0.0                       # 1/degC

    [site]
    latitude_deg = 39.9
    g_local_m_s2 = 9.80122

    [effects]                       # campaign-wide effects (effects.md ids -> parameter).
    earth_rate = 1.0                # absent = not there; a physical scenario has earth_rate = 1
    ia_tilt = 2.9e-4                # each run keeps only the effects whose effects.md "tests"
                                    # column names its test kind

    [noise]                         # defaults for every test (a test's [test.noise] overrides)
    white_m_s2 = 2.0e-6             # white noise of one reading (one row), in m/s^2 of input;
                                    # the simulator multiplies it by K1 (output_unit)
    white_ar1_rho = 0.0             # lag-1 correlation of that noise between consecutive rows (AR(1))
    rate_jitter_rel = 2.5e-6        # delta ~ N(0, sigma): true omega^2 = logged omega^2 (1 + delta),
                                    # one draw per reading (centrifuge) or per sample (sine)
    rate_log_rel = 1.5e-7           # logged rate = level rate or sine drive times (1 + nu), nu ~ N(0, sigma)
    rate_log_abs = 0.0              # rad/s: plus this absolute logged-rate noise
    centripetal_rel = 0.0           # output noise proportional to the centripetal level omega_z^2 R,
                                    # the same in every mount (what real centrifuge data show)
    bias_walk_m_s2_rt_s = 0.0       # bias random walk, m/s^2/sqrt(s): K0 gains a Wiener process
    temp_noise_c = 0.02             # reading-to-reading noise of temp_c, degC
    angle_log_deg = 0.0             # noise of the logged angle (angle_deg, rotation_deg,
                                    #   table_angle_deg), deg; the physics sees the true angle
    spike_rate = 0.0                # probability per row of a spike in the output ...
    spike_m_s2 = 0.0                # ... of size spike_m_s2 (1 + |N(0,1)|) m/s^2 of input, random sign
    output_quantum = 0.0            # output rounded to counts of this size (output_unit)
                                    # (the optional keys draw nothing when 0)

    [disturbance]                   # effects outside the catalogue (diagnosis tests); defaults 0
    bias_temp_quadratic_m_s2_c2 = 0.0   # bias gains c (T - 20 degC)^2
    bias_periodic_m_s2 = 0.0            # bias gains A sin(2 pi t / P) ...
    bias_periodic_period_s = 0.0        # ... with this period P

    [[test]]                        # one [[test]] per rig session; each makes one or more runs
    kind = "tumble"                 # tumble | centrifuge | tilt_rotation | sine_centrifuge
    rig_id = "DH-1"
    run_id_prefix = "DH1-20261120"  # run_id = prefix-NNNN; NNNN counts per prefix from
    first_number = 1                #   first_number (default 1, or continuing the prefix)
    started_at = "2026-11-20T08:00:00+08:00"
    run_interval_s = 3600           # started_at of the k-th run of this test = start + k*interval
    subdir = ""                     # sub-folder of the drop for write_drop
    notes = ""                      # optional metadata (also: operator, daq_id)
    [test.effects]                  # overrides/additions to the campaign-wide effects
    [test.noise]                    # overrides of the noise defaults
    [test.disturbance]              # overrides of the disturbances

Per kind (defaults in brackets):

``tumble``: ``heads`` = list of {head_axis, cos_axis, sin_axis} (one run each)
[one run from ``head_axis``/``cos_axis``/``sin_axis``, default PA/+IA/+OA];
``positions`` [24] equally spaced head angles; ``readings`` [10] per position;
``sample_period_s`` [1]; ``dwell_period_s`` [40] from one position to the next;
``temp_c`` [23] case temperature (plus temp noise); with ``temp_tau_s`` [0] the temperature
approaches ``temp_c`` exponentially from ``temp_start_c``, with ``temp_cycle_c`` [0] it swings
by that amplitude with ``temp_cycle_period_s`` (also for ``centrifuge``).

``centrifuge``: ``arm_radius_m`` (nominal, written to the file; the true turning centre is
the same unless ``arm_stretch``), ``rotation_sense`` [ccw], ``mounts`` = list of
{plane, angle_deg, vertical, effects = {...}} (per-mount effect overrides, e.g. an
``ia_tilt`` that is new at every mounting); ``replicates`` [1] runs per mount;
``rest_azimuths_deg`` [0, 90, 180, 270]; ``g_levels`` [1, 2, 3, 5, 7, 10, 14, 18, 21, 25];
``sweep`` ["up_down"] or "up"; ``readings`` [8]; ``sample_period_s`` [2];
``reading_window_s`` [2]; ``rest_dwell_period_s`` [36] and ``rate_dwell_period_s`` [76]
from the start of a dwell to the start of the next; ``temp_c`` [23];
``level_radius_m`` [arm_radius_m] and ``level_earth_rate`` [true]: the logged rate of level L is
omega = sqrt(L g / level_radius_m) - s Omega_e sin(latitude) (so that omega_z^2 R = L g, as the
lab does; with level_earth_rate = false, omega = sqrt(L g / R)).

``tilt_rotation``: ``tilt_deg``, ``sin_axis`` [+IA], ``cos_axis`` [+PA], ``normal_axis`` [+OA],
``positions`` [12]; ``temp_set_c`` = list of set-points [20, 25, 30, 35, 40]; ``sweeps`` [1]
repeats of the whole set-point list within one run; ``readings`` [20]; ``sample_period_s`` [1];
``dwell_period_s`` [50]; ``soak_s`` [3600] from reaching a set-point to its first reading
(the first set-point too); ``temp_offset_c`` [0] constant offset of the instrument's sensor
from the set-point; ``temp_tau_s`` [600] time constant of the slow approach of temp_c to a new
set-point (exponential from the previous temperature); ``start_temp_c`` [first set-point];
temperature noise from ``noise.temp_noise_c``.

``sine_centrifuge``: ``arm_radius_m``, ``rotation_sense``, ``attitudes`` = list of
{plane, angle_deg, vertical, notes, effects} (one run each); ``rate_amplitude_rad_s``,
``rate_frequency_hz``, ``sample_rate_hz`` [50], ``samples`` [1000].  The drive is
omega(t) = Omega sin(2 pi f t); ``table_angle_deg`` is its integral (unwrapped, from 0).
No ``temp_c`` column.
"""
from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..effects import COEFFICIENTS, EFFECTS, TESTS
from ..physics.axes import parse_signed_axis, plane_handedness

SCENARIO_DIR = Path(__file__).with_name("scenarios")

#: Noise keys of a scenario (``[noise]``, per test too), all 0 (off) by default.
NOISE_DEFAULTS: dict[str, float] = dict.fromkeys((
    "white_m_s2", "white_ar1_rho", "rate_jitter_rel", "rate_log_rel", "rate_log_abs", "centripetal_rel",
    "bias_walk_m_s2_rt_s", "temp_noise_c", "angle_log_deg", "spike_rate", "spike_m_s2", "output_quantum"), 0.0)
#: Effects outside the catalogue the simulator can add (``[disturbance]``), all off by default.
DISTURBANCE_DEFAULTS: dict[str, float] = dict.fromkeys((
    "sweep_hysteresis_rel", "bias_temp_quadratic_m_s2_c2", "bias_periodic_m_s2", "bias_periodic_period_s"), 0.0)

_COEFF_NAMES = set(COEFFICIENTS) - {"theta0"}

#: The keys a test of each kind must state (the others have defaults).
_REQUIRED = {"centrifuge": ("arm_radius_m",), "tilt_rotation": ("tilt_deg",),
             "sine_centrifuge": ("arm_radius_m", "rate_amplitude_rad_s", "rate_frequency_hz")}


class ScenarioError(ValueError):
    """A scenario that cannot be simulated (unknown key value, axis, effect, ...)."""


@dataclass
class Scenario:
    """A parsed, validated scenario.  ``raw`` keeps the dict it was made from."""
    name: str
    seed: int | None
    unit: dict[str, Any]
    coefficients: dict[str, float]
    site: dict[str, float]
    effects: dict[str, float]
    noise: dict[str, float]
    tests: list[dict[str, Any]]
    raw: dict[str, Any] = field(repr=False, default_factory=dict)
    source: str | None = None
    disturbance: dict[str, float] = field(default_factory=dict)


def _check_effects(eff: Mapping, where: str) -> dict[str, float]:
    out = {}
    for k, v in (eff or {}).items():
        if k not in EFFECTS:
            raise ScenarioError(f"{where}: unknown effect {k!r} (effects.md ids: {sorted(EFFECTS)})")
        try:
            out[k] = float(v)
        except (TypeError, ValueError):
            raise ScenarioError(f"{where}: effect {k} = {v!r} is not a number") from None
    return out


def _check_noise(noise: Mapping, where: str, known: Mapping[str, float] = NOISE_DEFAULTS,
                 what: str = "noise") -> dict[str, float]:
    out = {}
    for k, v in (noise or {}).items():
        if k not in known:
            raise ScenarioError(f"{where}: unknown {what} key {k!r} (known: {sorted(known)})")
        out[k] = float(v)
        if what == "noise" and out[k] < 0:
            raise ScenarioError(f"{where}: noise {k} must be >= 0")
    if what == "noise" and out.get("spike_rate", 0.0) > 1:
        raise ScenarioError(f"{where}: noise spike_rate is a probability (<= 1)")
    return out


def _check_mount(m: Mapping, where: str) -> None:
    try:
        plane_handedness(m["plane"], m["vertical"])       # (parses both)
        float(m.get("angle_deg", 0.0))
    except KeyError as e:
        raise ScenarioError(f"{where}: mount needs {e.args[0]!r}") from None
    except ValueError as e:
        raise ScenarioError(f"{where}: {e}") from None
    _check_effects(m.get("effects", {}), where)


def load_scenario(path_or_dict) -> Scenario:
    """Read a scenario TOML file (path) or take the equivalent dict; validate it."""
    source = None
    if isinstance(path_or_dict, Mapping):
        raw = copy.deepcopy(dict(path_or_dict))
    else:
        p = Path(path_or_dict)
        if not p.exists() and not p.suffix and (SCENARIO_DIR / f"{p}.toml").exists():
            p = SCENARIO_DIR / f"{p}.toml"          # a shipped scenario by name
        with open(p, "rb") as fh:
            raw = tomllib.load(fh)
        source = str(p)

    unit = dict(raw.get("unit", {}))
    for k in ("serial", "model"):
        if k not in unit:
            raise ScenarioError(f"[unit] needs {k!r}")
    unit.setdefault("campaign", f"{unit['serial']}/sim")
    unit.setdefault("output_unit", "m/s2")
    if unit["output_unit"] not in ("mA", "V", "count", "m/s2"):
        raise ScenarioError(f"[unit] output_unit {unit['output_unit']!r} is not mA, V, count or m/s2")
    coeffs = {}
    for k, v in dict(unit.pop("coefficients", {})).items():
        if k not in _COEFF_NAMES:
            raise ScenarioError(f"[unit.coefficients]: unknown coefficient {k!r}")
        coeffs[k] = float(v)
    coeffs.setdefault("K1", 1.0)

    site = dict(raw.get("site", {}))
    if "latitude_deg" not in site or "g_local_m_s2" not in site:
        raise ScenarioError("[site] needs latitude_deg and g_local_m_s2")
    site = {k: float(v) for k, v in site.items()}

    effects = _check_effects(raw.get("effects", {}), "[effects]")
    noise = {**NOISE_DEFAULTS, **_check_noise(raw.get("noise", {}), "[noise]")}
    disturbance = _check_noise(raw.get("disturbance", {}), "[disturbance]", DISTURBANCE_DEFAULTS, "disturbance")

    tests = [dict(t) for t in raw.get("test", [])]
    if not tests:
        raise ScenarioError("a scenario needs at least one [[test]]")
    for i, t in enumerate(tests):
        where = f"[[test]] #{i + 1}"
        kind = t.get("kind")
        if kind not in TESTS:
            raise ScenarioError(f"{where}: kind {kind!r} is not one of {TESTS}")
        t["effects"] = _check_effects(t.get("effects", {}), where)
        t["noise"] = _check_noise(t.get("noise", {}), where)
        t["disturbance"] = _check_noise(t.get("disturbance", {}), where, DISTURBANCE_DEFAULTS, "disturbance")
        t.setdefault("rig_id", {"tumble": "DH-1", "centrifuge": "CF-1", "tilt_rotation": "TT-1",
                                "sine_centrifuge": "DC-1"}[kind])
        for k in _REQUIRED.get(kind, ()):
            if k not in t:
                raise ScenarioError(f"{where}: {kind} needs {k}")
        if kind in ("centrifuge", "sine_centrifuge"):
            if str(t.get("rotation_sense", "ccw")) not in ("ccw", "cw"):
                raise ScenarioError(f"{where}: rotation_sense must be ccw or cw")
            key = "mounts" if kind == "centrifuge" else "attitudes"
            if not t.get(key):
                raise ScenarioError(f"{where}: {kind} needs a non-empty {key} list")
            for m in t[key]:
                _check_mount(m, where)
        if kind == "tilt_rotation":
            try:
                for k in ("sin_axis", "cos_axis", "normal_axis"):
                    parse_signed_axis(t.get(k, "+IA"))
            except ValueError as e:
                raise ScenarioError(f"{where}: {e}") from None
        if kind == "tumble":
            heads = t.get("heads") or [{"head_axis": t.get("head_axis", "PA"),
                                        "cos_axis": t.get("cos_axis", "+IA"),
                                        "sin_axis": t.get("sin_axis", "+OA")}]
            for h in heads:
                try:
                    axes = {parse_signed_axis(h[k])[0] for k in ("head_axis", "cos_axis", "sin_axis")}
                except (KeyError, ValueError) as e:
                    raise ScenarioError(f"{where}: head {h}: {e}") from None
                if len(axes) != 3:
                    raise ScenarioError(f"{where}: head {h} repeats an axis")
            t["heads"] = heads

    seed = raw.get("seed")
    return Scenario(name=str(raw.get("name", Path(source).stem if source else "scenario")),
                    seed=None if seed is None else int(seed), unit=unit, coefficients=coeffs,
                    site=site, effects=effects, noise=noise, tests=tests, raw=raw, source=source,
                    disturbance=disturbance)

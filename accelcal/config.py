"""The lab's own facts for certificates: ``accelcal.toml``.

Looked up in this order (the first that exists wins): the ``--config`` path, then
``./accelcal.toml`` (the working folder), then ``accelcal.toml`` beside the warehouse.
Nothing is invented when it is absent: :func:`lab_config` returns ``None`` for every
missing field and the certificate prints a clearly marked placeholder instead, with a
"DRAFT" banner.  Example (every key optional)::

    [lab]
    name = "Inertial Metrology Laboratory"
    address = "12 Example Road, Wuhan 430074, China"
    location = "Building 3, centrifuge hall"        # where the calibrations are made
    accreditation = "CNAS L0000 (ISO/IEC 17025:2017)"

    [certificate]
    number_prefix = "IML-ACC"         # certificate number = <prefix>-<first 12 of result id>
    approver = "Dr A. N. Other"       # who authorises certificates (ISO/IEC 17025 7.8.2.1 o)
    approver_role = "Head of laboratory"
    customer = "Customer name, address"   # or per certificate: accelcal report --customer

    [traceability]
    statement = "..."                 # how the results are traceable to the SI
    [traceability.rigs]               # per rig: its reference standards and their certificates
    "LXJ-100" = "arm radius by CMM, cert. ...; rate by encoder, cert. ..."
    "DH-1" = "dividing head angle, cert. ..."

Every command reads the file through :func:`_read`, which checks it against the one
schema (:func:`config_schema`: ``[lab]``, ``[certificate]``, ``[traceability]``,
``[rigs."ID"]``, ``[tolerance."MODEL"]``, ``[forecast]``, ``[prior."MODEL"]``, ``[dcc]``):
an unknown key or a value of the wrong type is one :class:`ConfigError` line.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

CONFIG_NAME = "accelcal.toml"
DEFAULT_NUMBER_PREFIX = "ACC"


class ConfigError(RuntimeError):
    """The config file exists but cannot be used (one-line reason)."""


@dataclass
class LabConfig:
    path: Path | None = None            # the file read, None when there is none
    name: str | None = None
    address: str | None = None
    location: str | None = None
    accreditation: str | None = None
    number_prefix: str = DEFAULT_NUMBER_PREFIX
    approver: str | None = None
    approver_role: str | None = None
    customer: str | None = None
    traceability: str | None = None
    rig_traceability: dict[str, str] = field(default_factory=dict)

    @property
    def missing(self) -> list[str]:
        """What a signed certificate needs and the config does not give."""
        need = {"[lab] name": self.name, "[lab] address": self.address,
                "[certificate] approver": self.approver}
        return [k for k, v in need.items() if not v]


def find_config(explicit: str | Path | None = None,
                warehouse: str | Path | None = None) -> Path | None:
    """The config file to use: ``explicit`` (must exist), ./accelcal.toml, beside the
    warehouse; None when there is none."""
    if explicit is not None:
        p = Path(explicit).expanduser()
        if not p.is_file():
            raise ConfigError(f"config file {p} does not exist")
        return p
    candidates = [Path.cwd() / CONFIG_NAME]
    if warehouse is not None:
        candidates.append(Path(warehouse).expanduser().resolve().parent / CONFIG_NAME)
    return next((c for c in candidates if c.is_file()), None)


# ------------------------------------------------------------------ schema ----

#: A key's expected type: (python types accepted, how an error names it).
_TEXT = ((str,), "text")
_NUMBER = ((int, float), "a number")
_BOOL = ((bool,), "true or false")
#: Per-rig keys: the stated uncertainties of :data:`accelcal.effects.RIG_INPUTS` (added by
#: :func:`config_schema`), the design's bounds, a free-text note and the DCCs of the rig's standards
#: (:mod:`accelcal.traceability`), each with an optional sha256 pin.
_RIG_KEYS = {"max_g": _NUMBER, "setup_min": _NUMBER, "note": _TEXT,
             **{k: _TEXT for k in ("g_local_dcc", "radius_dcc", "reference_dcc")},
             **{f"{k}_sha256": _TEXT for k in ("g_local_dcc", "radius_dcc", "reference_dcc")},
             "reference_dcc_label": _TEXT}
#: The one schema of accelcal.toml that ``run``, ``report``, ``due``, ``design`` and
#: ``verify`` read: table -> key -> type; ``"*"`` is any name (a rig id, a unit model, a
#: coefficient).
_SCHEMA: dict[str, Any] = {
    "lab": {"name": _TEXT, "address": _TEXT, "location": _TEXT, "accreditation": _TEXT},
    "certificate": {"number_prefix": _TEXT, "approver": _TEXT, "approver_role": _TEXT,
                    "customer": _TEXT, "state_due_date": _BOOL},
    "traceability": {"statement": _TEXT, "rigs": {"*": _TEXT}},
    "rigs": {"*": _RIG_KEYS},
    "tolerance": {"*": {"*": {"relative": _NUMBER, "absolute": _NUMBER}}},
    "forecast": {"risk": _NUMBER},
    "prior": {"*": {"*": {"value": _NUMBER, "u": _NUMBER}}},
    "dcc": {k: _TEXT for k in ("country_code", "language", "email", "key_file", "cert_file",
                               "key_password_env", "signature")},
}


def config_schema() -> dict[str, Any]:
    """The schema of accelcal.toml, the rig inputs' uncertainty keys included."""
    from .effects import RIG_INPUTS
    rig = {**_RIG_KEYS, **{r.config_key: (_NUMBER[0], f"a positive number (a standard "
                                                     f"uncertainty in {r.unit})")
                           for r in RIG_INPUTS.values()}}
    return {**_SCHEMA, "rigs": {"*": rig}}


def _line_of(text: str, key: str) -> str:
    """' (line N)' of the first line that sets ``key`` (empty when none is found)."""
    import re
    for n, line in enumerate(text.splitlines(), start=1):
        if re.match(rf"\s*\"?{re.escape(key)}\"?\s*=", line) or re.match(
                rf"\s*\[+[^\]]*\b{re.escape(key)}\b", line):
            return f" (line {n})"
    return ""


def check_config(raw: dict[str, Any], path: Path, text: str = "") -> None:
    """Raise a one-line :class:`ConfigError` for the first key the schema does not know
    (naming the nearest known key) or the first value of the wrong type (file, key,
    expected type)."""
    import difflib

    def walk(node: dict[str, Any], spec: dict[str, Any], where: list[str]) -> None:
        for key, val in node.items():
            sub = spec.get(key, spec.get("*"))
            name = (f"[{'.'.join(where)}] " if where else "") + str(key)
            line = _line_of(text, str(key))
            if sub is None:
                known = [k for k in spec if k != "*"]
                near = ([k for k in known if k.startswith(str(key)) or str(key).startswith(k)]
                        or difflib.get_close_matches(str(key), known, n=1, cutoff=0.5))
                hint = f"; did you mean {near[0]!r}?" if near else \
                    f"; known: {', '.join(k for k in spec if k != '*')}"
                raise ConfigError(f"{path}: unknown key {name}{line}{hint}")
            if isinstance(sub, dict):
                if not isinstance(val, dict):
                    raise ConfigError(f"{path}: {name} must be a table{line}")
                walk(val, sub, where + [f'"{key}"' if "*" in spec and key not in spec else str(key)])
                continue
            types, what = sub
            if not isinstance(val, types) or (bool not in types and isinstance(val, bool)):
                raise ConfigError(f"{path}: {name} must be {what}, not {type(val).__name__} "
                                  f"{val!r}{line}")
    walk(raw, config_schema(), [])


def _read(path: Path) -> dict[str, Any]:
    """The config file's TOML, checked against :func:`config_schema`; a file that cannot be
    read, parsed or is off the schema is one ConfigError line."""
    try:
        text = path.read_text(encoding="utf-8")
        raw = tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read config {path}: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"config {path} is not valid TOML: {e}") from None
    check_config(raw, path, text)
    return raw


def _rig_tables(explicit: str | Path | None, warehouse: str | Path | None = None
                ) -> tuple[Path | None, dict[str, Any]]:
    """(the config file, its ``[rigs]`` table: rig id -> its keys); (None, {}) without a file."""
    path = find_config(explicit, warehouse)
    if path is None:
        return None, {}
    rigs = _read(path).get("rigs") or {}
    if not isinstance(rigs, dict):
        raise ConfigError(f"{path}: [rigs] must be a table of rig ids")
    return path, rigs


def rig_limits(explicit: str | Path | None = None) -> dict[str, float]:
    """Rig id -> the highest g level it may run [g], from ``[rigs."ID"] max_g`` of the config
    file (same look-up as :func:`lab_config`; none without a file)."""
    path, rigs = _rig_tables(explicit)
    out = {}
    for rig, v in rigs.items():
        if isinstance(v, dict) and "max_g" in v:
            try:
                out[str(rig)] = float(v["max_g"])
            except (TypeError, ValueError):
                raise ConfigError(f'{path}: [rigs."{rig}"] max_g must be a number') from None
    return out


def advice_inputs(explicit: str | Path | None = None,
                  warehouse: str | Path | None = None) -> dict[str, dict]:
    """The lab's statements the test-design advice reads, as keyword arguments of
    :func:`accelcal.testdesign.advise`: ``stated`` (:func:`rig_uncertainties`, the type-B
    inputs the budget adds) and ``setup_min`` (:func:`rig_setup_minutes`).  ``accelcal
    design``, the certificate's "one more run" and ``accelcal diagnose``'s next runs all
    ask the advice with these, so they give one answer."""
    return {"stated": rig_uncertainties(explicit, warehouse), "setup_min": rig_setup_minutes(explicit, warehouse)}


def rig_setup_minutes(explicit: str | Path | None = None,
                      warehouse: str | Path | None = None) -> dict[str, float]:
    """Rig id -> the set-up time of one run on it [min], from ``[rigs."ID"] setup_min`` of
    the config file (same look-up as :func:`lab_config`; none without a file)."""
    path, rigs = _rig_tables(explicit, warehouse)
    out = {}
    for rig, v in rigs.items():
        if isinstance(v, dict) and "setup_min" in v:      # a number: the schema checked it
            if not v["setup_min"] >= 0:
                raise ConfigError(f'{path}: [rigs."{rig}"] setup_min must be a number of minutes >= 0')
            out[str(rig)] = float(v["setup_min"])
    return out


def rig_uncertainties(explicit: str | Path | None = None,
                      warehouse: str | Path | None = None) -> dict[str, dict[str, float]]:
    """Rig id -> :data:`accelcal.effects.RIG_INPUTS` id -> the lab's stated standard
    uncertainty of that input, from ``[rigs."ID"]`` of the config file::

        [rigs."TT-1"]
        g_local_u_m_s2 = 1e-5      # local gravity at the rig [m/s2]
        tilt_u_deg = 0.002         # tilt of the thermal table [deg]
        temperature_u_c = 0.05     # temperature reading at each set point [degC]
        # or: g_local_dcc = "gravimetry.dcc.xml"  (u read from that DCC, accelcal.traceability)

    Same look-up as :func:`lab_config`; none without a file.  A value that is not a
    positive number is one :class:`ConfigError` line naming it."""
    from .effects import RIG_INPUTS
    path, rigs = _rig_tables(explicit, warehouse)
    out: dict[str, dict[str, float]] = {}
    for rig, v in rigs.items():
        if not isinstance(v, dict):
            continue
        if v.get("g_local_dcc"):        # local gravity from the gravimetry survey's own DCC
            from .traceability import InputDccError, read_input_dcc
            if RIG_INPUTS["g_local"].config_key in v:
                raise ConfigError(f'{path}: [rigs."{rig}"] give g_local_dcc or '
                                  f'{RIG_INPUTS["g_local"].config_key}, not both')
            try:
                src = read_input_dcc(path.parent / v["g_local_dcc"], "g_local_dcc",
                                     v.get("g_local_dcc_sha256"))
            except InputDccError as e:
                raise ConfigError(f'{path}: [rigs."{rig}"] g_local_dcc: {e}') from None
            out.setdefault(str(rig), {})["g_local"] = src.u
        for spec in RIG_INPUTS.values():
            if spec.config_key not in v:
                continue
            x = v[spec.config_key]
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not x > 0:
                raise ConfigError(f'{path}: [rigs."{rig}"] {spec.config_key} must be a positive number '
                                  f"(a standard uncertainty in {spec.unit})")
            out.setdefault(str(rig), {})[spec.id] = float(x)
    return out


def priors(explicit: str | Path | None = None,
           warehouse: str | Path | None = None) -> dict[str, dict[str, dict[str, float]]]:
    """Unit model -> coefficient -> ``{"value", "u"}`` [SI], from ``[prior."MODEL"]`` of the
    config file::

        [prior."QA-2000"]
        K3 = { value = 1.5e-9, u = 5e-10 }     # s4/m3 (SI, as effects.md)
        Koq = { value = 2e-8, u = 1e-8 }       # s2/m

    What the lab knows of terms a design cannot see (the schema checks the keys and types;
    a u that is not positive is one :class:`ConfigError` line).  Same look-up as
    :func:`lab_config`; none without a file."""
    path = find_config(explicit, warehouse)
    if path is None:
        return {}
    out: dict[str, dict[str, dict[str, float]]] = {}
    for model, table in (_read(path).get("prior") or {}).items():
        for name, v in (table or {}).items():
            if not float(v["u"]) > 0:
                raise ConfigError(f'{path}: [prior."{model}"] {name}: u must be a positive number')
            out.setdefault(str(model), {})[str(name)] = {"value": float(v["value"]), "u": float(v["u"])}
    return out


def run_parameters(explicit: str | Path | None = None,
                   warehouse: str | Path | None = None) -> dict[str, Any] | None:
    """The pipeline parameters the lab's config file sets for a run (``run``, ``demo``,
    ``serve``): ``{"rig_uncertainty": ...}`` (:func:`rig_uncertainties`) and ``{"priors":
    ...}`` (:func:`priors`) when it states any, else None, so that a run without them keeps
    the result ids it always had."""
    out: dict[str, Any] = {}
    stated = rig_uncertainties(explicit, warehouse)
    if stated:
        out["rig_uncertainty"] = stated
    known = priors(explicit, warehouse)
    if known:
        out["priors"] = known
    return out or None


def _str(d: dict[str, Any], key: str, where: str, path: Path) -> str | None:
    v = d.get(key)
    if v is None:
        return None
    if not isinstance(v, str):
        raise ConfigError(f"{path}: {where}.{key} must be text")
    return v.strip() or None


def lab_config(explicit: str | Path | None = None,
               warehouse: str | Path | None = None) -> LabConfig:
    path = find_config(explicit, warehouse)
    if path is None:
        return LabConfig()
    raw = _read(path)
    lab, cert, tr = (raw.get(k) or {} for k in ("lab", "certificate", "traceability"))
    for name, sec in (("lab", lab), ("certificate", cert), ("traceability", tr)):
        if not isinstance(sec, dict):
            raise ConfigError(f"{path}: [{name}] must be a table")
    rigs = tr.get("rigs") or {}
    if not isinstance(rigs, dict) or not all(isinstance(v, str) for v in rigs.values()):
        raise ConfigError(f"{path}: [traceability.rigs] must map rig ids to text")
    return LabConfig(
        path=path, name=_str(lab, "name", "lab", path), address=_str(lab, "address", "lab", path),
        location=_str(lab, "location", "lab", path),
        accreditation=_str(lab, "accreditation", "lab", path),
        number_prefix=_str(cert, "number_prefix", "certificate", path) or DEFAULT_NUMBER_PREFIX,
        approver=_str(cert, "approver", "certificate", path),
        approver_role=_str(cert, "approver_role", "certificate", path),
        customer=_str(cert, "customer", "certificate", path),
        traceability=_str(tr, "statement", "traceability", path),
        rig_traceability={str(k): v.strip() for k, v in rigs.items() if v.strip()})


# ------------------------------------------------------------ drift forecast ----

#: The lab's acceptable probability of a unit being out of tolerance at its due date.
DEFAULT_RISK = 0.05


@dataclass
class ForecastConfig:
    """What ``accelcal due`` / ``history`` and the certificate's due-date sentence read
    from ``accelcal.toml``::

        [tolerance."QA-2000"]            # per unit model, SI units (effects.md)
        K1 = { relative = 2.0e-4 }       # |K1 - K1 in use| <= 2e-4 |K1 in use|
        K0 = { absolute = 5.0e-4 }       # m/s2
        [forecast]
        risk = 0.05                      # acceptable probability of out of tolerance
        [certificate]
        state_due_date = false           # ISO/IEC 17025 7.8.6: only when agreed
    """
    path: Path | None = None
    tolerances: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    risk: float = DEFAULT_RISK
    state_due_date: bool = False

    def tolerance(self, unit_model: str | None, name: str) -> dict[str, float] | None:
        return (self.tolerances.get(unit_model or "") or {}).get(name)


def forecast_config(explicit: str | Path | None = None,
                    warehouse: str | Path | None = None) -> ForecastConfig:
    """Tolerances, risk and ``state_due_date`` from the config file (same look-up as
    :func:`lab_config`); a bad entry is one :class:`ConfigError` line naming it."""
    path = find_config(explicit, warehouse)
    if path is None:
        return ForecastConfig()
    raw = _read(path)
    tol = raw.get("tolerance") or {}
    if not isinstance(tol, dict):
        raise ConfigError(f"{path}: [tolerance] must be a table of unit models")
    out: dict[str, dict[str, dict[str, float]]] = {}
    for model, coefs in tol.items():
        if not isinstance(coefs, dict):
            raise ConfigError(f'{path}: [tolerance."{model}"] must be a table of coefficients')
        for name, spec in coefs.items():
            where = f'{path}: [tolerance."{model}"] {name}'
            if not isinstance(spec, dict) or len(spec) != 1 \
                    or next(iter(spec)) not in ("relative", "absolute"):
                raise ConfigError(f"{where} must be {{ relative = r }} or {{ absolute = T }}")
            kind, val = next(iter(spec.items()))
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not val > 0:
                raise ConfigError(f"{where}: {kind} must be a positive number")
            out.setdefault(str(model), {})[str(name)] = {kind: float(val)}
    fc = raw.get("forecast") or {}
    risk = fc.get("risk", DEFAULT_RISK) if isinstance(fc, dict) else None
    if isinstance(risk, bool) or not isinstance(risk, (int, float)) or not 0 < risk < 0.5:
        raise ConfigError(f"{path}: [forecast] risk must be a number between 0 and 0.5")
    cert = raw.get("certificate") or {}
    state = cert.get("state_due_date", False) if isinstance(cert, dict) else False
    if not isinstance(state, bool):
        raise ConfigError(f"{path}: [certificate] state_due_date must be true or false")
    return ForecastConfig(path, out, float(risk), state)


def default_warehouse() -> str:
    """The warehouse a command uses when none is given: $ACCELCAL_WAREHOUSE, else
    ./lab.duckdb."""
    import os
    return os.environ.get("ACCELCAL_WAREHOUSE", "lab.duckdb")

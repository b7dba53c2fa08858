"""Digital Calibration Certificate (PTB DCC 3.3.0, D-SI 2.2.0, XML) beside the HTML/PDF
certificate.

``accelcal report ... --dcc`` writes ``<report>.dcc.xml``; ``accelcal verify FILE`` checks
one.  The DCC is built from the same data the certificate shows
(:func:`accelcal.ops.certificate.load_report_data`) and the same lab facts (accelcal.toml):

- administrativeData: software (accelcal, release ``v<version>``), the refTypes it uses
  (``refTypeDefinitions``), core data (country, language, unique identifier = the
  certificate number, performance and issue dates), the calibration laboratory, the person
  authorising, the customer and the item (model and serial).  A fact the lab has not
  configured is written as a marked ``[not configured: ...]`` text and the DCC is a DRAFT:
  an ``accelcal_draft`` statement, a ``DRAFT-`` identifier instead of the number, never
  signed.
- measurementResults: the methods and software; the measuring equipment (each rig with its
  reference standards, each standard whose own DCC gives a rig input,
  :mod:`accelcal.traceability`); the influence conditions (each run's temperature range,
  each rig's local g with its stated u, each rig); every adopted coefficient as an
  ``si:real`` with its D-SI unit (:data:`DISPLAY_TO_DSI`) and
  ``si:measurementUncertaintyUnivariate/si:expandedMU`` (U, k, coverage probability),
  rounded per GUM 7.2.6 (:mod:`accelcal.rounding`); and the lineage (every input run's id
  and sha256, the result id) as ``dcc:measurementMetaData``.
- document: the human-readable certificate (the PDF when there is one, else the HTML),
  base64.

Every DCC is validated on write against the schema its ``schemaVersion`` names, from the
copies shipped in ``accelcal/schemas/dcc`` (no network; :func:`load_schema`), and against
PTB's own Schematron rules from PTB's ``dcclib`` (:func:`schematron_report`); a final one
with any finding is refused with a one-line :class:`DccError`.  With ``[dcc] key_file`` and
``cert_file`` in accelcal.toml a final DCC carries an enveloped XML signature (XAdES-BES by
default; ``ds:Signature`` as the root's last element, where DCC 3.3.0 admits it), checked
by :func:`verify_dcc` against the lab's certificate.
"""
from __future__ import annotations

import base64
import datetime as _dt
import math
import os
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from .certificate import ReportError

#: The DCC schema version written, and the folder of each version's shipped schemas.
SCHEMA_VERSION = "3.3.0"
SCHEMA_DIRS = {"3.3.0": Path(__file__).resolve().parents[1] / "schemas" / "dcc"}
#: D-SI 2.2.0 imports the QUDT quantity kinds from this address; the shipped stand-in
#: (schemas/dcc/qudt, see its NOTICE.md) is read instead.
QUDT_URL = "https://www.ptb.de/si/v2.2.0/qudt/quantitykind.xsd"

DCC_NS = "https://ptb.de/dcc"
SI_NS = "https://ptb.de/si"
DS_NS = "http://www.w3.org/2000/09/xmldsig#"
XSI_NS = "http://www.w3.org/2001/XMLSchema-instance"
NSMAP = {"dcc": DCC_NS, "si": SI_NS}

#: Display unit of the results table (accelcal.effects) -> (D-SI unit, SI value of one
#: such unit).  The standard acceleration of gravity g is no D-SI unit, so the units made
#: of g (µg, µg/g², ...) are written in SI, with a prefix where one keeps the numbers
#: readable; µrad, ppm/°C and ° are D-SI units as they are.
DISPLAY_TO_DSI: dict[str, tuple[str, float]] = {
    "ug": (r"\micro\metre\second\tothe{-2}", 1e-6),
    "urad": (r"\micro\radian", 1e-6),
    "ug/g2": (r"\second\tothe{2}\metre\tothe{-1}", 1.0),
    "ug/g3": (r"\second\tothe{4}\metre\tothe{-2}", 1.0),
    "ug/degC": (r"\micro\metre\second\tothe{-2}\degreecelsius\tothe{-1}", 1e-6),
    "ppm/degC": (r"\ppm\degreecelsius\tothe{-1}", 1e-6),
    "deg": (r"\degree", math.pi / 180.0),
}
#: A run's output unit (dropspec.OUTPUT_UNITS) in D-SI, for K1 = output per m/s².
OUTPUT_TO_DSI = {"mA": r"\milli\ampere", "V": r"\volt", "count": "", "m/s2": r"\metre\second\tothe{-2}"}
#: Coverage probability written beside U = k u (k from the coefficient; about 95 %).
COVERAGE_PROBABILITY = "0.95"


class DccError(ReportError):
    """The DCC cannot be made, is invalid, or fails its signature check (one line)."""


@dataclass
class DccConfig:
    """``[dcc]`` of accelcal.toml (every key optional)::

        [dcc]
        country_code = "CN"          # ISO 3166-1 alpha-2 of the laboratory
        language = "en"              # ISO 639-1 of the DCC's texts
        email = "lab@example.org"    # the laboratory's contact e-mail
        key_file = "keys/lab.key"    # PEM private key: the DCC is signed (XML-DSig)
        cert_file = "keys/lab.pem"   # PEM X.509 certificate of that key
        key_password_env = "ACCELCAL_DCC_KEY_PASSWORD"   # env var holding the key's password
        signature = "xades"          # XAdES-BES (default) or "xmldsig" (plain XML-DSig)

    Relative paths are relative to the config file.
    """
    country_code: str | None = None
    language: str = "en"
    email: str | None = None
    key_file: Path | None = None
    cert_file: Path | None = None
    key_password_env: str | None = None
    signature: str = "xades"


#: Signature formats: XAdES-BES (ETSI EN 319 132: XML-DSig plus signed signing time and
#: signing-certificate digest) or plain XML-DSig.
SIGNATURE_FORMATS = ("xades", "xmldsig")
XADES_NS = "http://uri.etsi.org/01903/v1.3.2#"


def dcc_config(path: Path | None) -> DccConfig:
    """The ``[dcc]`` table of the config file at ``path`` (None: defaults)."""
    from ..config import ConfigError
    from ..config import _read as read_config
    if path is None:
        return DccConfig()
    try:
        raw = read_config(Path(path)).get("dcc") or {}     # checked against the one schema
    except ConfigError as e:
        raise DccError(str(e)) from None
    cc = (raw.get("country_code") or "").strip().upper() or None
    if cc is not None and not (len(cc) == 2 and cc.isascii() and cc.isalpha()):
        raise DccError(f"{path}: [dcc] country_code must be two letters (ISO 3166-1), not {cc!r}")
    lang = (raw.get("language") or "en").strip().lower()
    if not (len(lang) == 2 and lang.isascii() and lang.isalpha()):
        raise DccError(f"{path}: [dcc] language must be two letters (ISO 639-1), not {lang!r}")
    fmt = (raw.get("signature") or "xades").strip().lower()
    if fmt not in SIGNATURE_FORMATS:
        raise DccError(f"{path}: [dcc] signature must be one of {', '.join(SIGNATURE_FORMATS)}, not {fmt!r}")
    base = Path(path).expanduser().resolve().parent

    def _file(key):
        v = (raw.get(key) or "").strip()
        return (base / Path(v).expanduser()) if v else None
    return DccConfig(country_code=cc, language=lang, email=(raw.get("email") or "").strip() or None,
                     key_file=_file("key_file"), cert_file=_file("cert_file"),
                     key_password_env=(raw.get("key_password_env") or "").strip() or None,
                     signature=fmt)


# ------------------------------------------------------------------- units --

def dsi_unit(name: str, unit: str | None) -> tuple[str, float]:
    """(D-SI unit, SI value of one such unit) of an adopted coefficient.

    Parameters
    ----------
    name : str
        Coefficient name (``"K0"``, ``"K1"``, ``"K2"``, ...; ``"K0[run]"`` forms too).
    unit : str or None
        The coefficient's unit as stored (for K1, ``"<output unit>/(m/s2)"``).

    Returns
    -------
    tuple of (str, float)
        The D-SI string and the factor: value in that unit = SI value / factor.

    Raises
    ------
    DccError
        For a coefficient without a known display unit or output unit.
    """
    from ..effects import coefficient_spec
    spec = coefficient_spec(name)
    if spec is None:
        raise DccError(f"no D-SI unit known for coefficient {name!r}")
    if spec.name == "K1":
        unit = unit or ""
        # "<output unit>/(m/s2)" (effects.si_unit); the output unit may itself hold a '/'
        out = unit[:-len("/(m/s2)")] if unit.endswith("/(m/s2)") else unit.split("/", 1)[0]
        if out not in OUTPUT_TO_DSI:
            raise DccError(f"no D-SI unit known for the output unit {out!r} of {name}")
        if out == "m/s2":
            return r"\one", 1.0
        return OUTPUT_TO_DSI[out] + r"\second\tothe{2}\metre\tothe{-1}", 1.0
    if spec.display_unit not in DISPLAY_TO_DSI:
        raise DccError(f"no D-SI unit known for display unit {spec.display_unit!r} of {name}")
    return DISPLAY_TO_DSI[spec.display_unit]


def check_dsi_unit(s: str) -> None:
    """Raise :class:`DccError` unless ``s`` is a D-SI unit string dsiunits parses cleanly."""
    import warnings

    from dsi_unit import DsiUnit
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        u = DsiUnit(s)
    if not u.valid:
        raise DccError(f"unit {s!r} is not a valid D-SI unit: {'; '.join(map(str, u.warnings))}")


def rounded_pair(value: float, U: float | None) -> tuple[str, str | None]:
    """(value, U) as written in the DCC: GUM 7.2.6 via :func:`accelcal.rounding.round_gum_sci`
    (U to two significant digits, the value to U's last digit; powers of ten outside
    0.001-99999).  Without a usable U the value keeps six significant digits and U is None.
    """
    from ..rounding import round_gum, round_gum_sci
    if U is None or not math.isfinite(U) or U <= 0:
        return round_gum(value, None).value, None
    v, u = round_gum_sci(value, U)
    return v, u


# ------------------------------------------------------------------ schema --

@lru_cache(maxsize=4)
def load_schema(version: str = SCHEMA_VERSION):
    """The shipped XSD of a DCC ``schemaVersion`` (with D-SI and XML-DSig), loaded with no
    network access at all (xmlschema ``allow="local"``: local files only; the D-SI import of
    QUDT mapped to the shipped stand-in)."""
    import xmlschema
    folder = SCHEMA_DIRS.get(version)
    if folder is None:
        raise DccError(f"DCC schemaVersion {version!r} is not one accelcal ships "
                       f"({', '.join(sorted(SCHEMA_DIRS))})")
    return xmlschema.XMLSchema(str(folder / "dcc.xsd"), allow="local",
                               uri_mapper={QUDT_URL: str(folder / "qudt" / "quantitykind.xsd")})


def _parse(data: bytes):
    from lxml import etree
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False,
                             huge_tree=True, remove_blank_text=False)
    try:
        return etree.fromstring(data, parser)
    except etree.XMLSyntaxError as e:
        raise DccError(f"not well-formed XML: {e}") from None


def validate(root) -> str:
    """Validate a DCC (lxml element) against the shipped XSD of its ``schemaVersion``;
    returns that version, raises :class:`DccError` with the first error in one line."""
    if root.tag != f"{{{DCC_NS}}}digitalCalibrationCertificate":
        raise DccError(f"not a DCC: the root element is {root.tag}")
    version = root.get("schemaVersion") or ""
    schema = load_schema(version)
    import xmlschema
    # the instance is read as given: no xsi:schemaLocation hint of it is ever followed
    err = next(iter(schema.iter_errors(xmlschema.XMLResource(root, allow="none"))), None)
    if err is not None:
        reason = " ".join(str(err.reason or err.message).split())
        raise DccError(f"invalid against dcc.xsd {version}: {reason} (at {err.path})")
    return version


# ----------------------------------------------------------------- building --

def _el(parent, ns: str, tag: str, text: str | None = None, **attrib):
    from lxml import etree
    e = etree.SubElement(parent, f"{{{ns}}}{tag}", {k: v for k, v in attrib.items() if v is not None})
    if text is not None:
        e.text = text
    return e


def _text(parent, tag: str, text: str, lang: str):
    """A dcc:textType (or richContentType) element with one content in ``lang``."""
    e = _el(parent, DCC_NS, tag)
    _el(e, DCC_NS, "content", text, lang=lang)
    return e


def _ph(what: str) -> str:
    return f"[not configured: {what}]"


def _contact(parent, tag: str, name: str, email: str | None, where: str | None, cc: str | None,
             lang: str):
    """A dcc:contactType: name, e-mail only when known (PTB's rules refuse an empty element),
    and a location (country and/or address)."""
    c = _el(parent, DCC_NS, tag)
    _text(c, "name", name, lang)
    if email:
        _el(c, DCC_NS, "eMail", email)
    loc = _el(c, DCC_NS, "location")
    if cc:
        _el(loc, DCC_NS, "countryCode", cc)
    if where or not cc:
        _text(loc, "further", where or _ph("address"), lang)
    return c


def _dates(d) -> tuple[_dt.date | None, _dt.date | None]:
    runs = d.get("runs") or []
    starts = [x["start"] for x in runs if x.get("start")]
    ends = [x.get("end") or x["start"] for x in runs if x.get("start")]
    return (min(starts).date(), max(ends).date()) if starts else (None, None)


def _software_version(d) -> tuple[str, str]:
    """(release as PTB's rules want it: a letter, then up to four numbers, e.g. ``v0.1.0``;
    the full code version for the description)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        pkg = version("accelcal")
    except PackageNotFoundError:
        pkg = ""
    cv = d["result"].get("code_version") or pkg or "unknown"
    m = re.match(r"\d{1,3}(\.\d{1,3}){0,3}", pkg or str(cv))
    return "v" + (m.group(0) if m else "0"), f"accelcal {pkg or ''} (code version {cv})".replace("  ", " ")


def _software(parent, d, lang: str) -> None:
    release, about = _software_version(d)
    sw = _el(parent, DCC_NS, "software")
    _text(sw, "name", "accelcal", lang)
    _el(sw, DCC_NS, "release", release)
    _el(sw, DCC_NS, "type", "application")
    _text(sw, "description", about, lang)


#: Every refType the DCC uses, declared in ``refTypeDefinitions``: refType -> (namespace,
#: link, what it marks).  ``basic_*`` is PTB's DKD refType vocabulary; ``accelcal_*`` are
#: accelcal's own, documented in its README ("Certificates").
REFTYPES: dict[str, tuple[str, str, str]] = {
    "basic_measuredValue": ("basic", "https://digilab.ptb.de/dkd/refType/vocab/index.php",
                            "a measured value of the item"),
}
ACCELCAL_LINK = "https://github.com/accelcal/accelcal#certificates"
ACCELCAL_REFTYPES = {
    "accelcal_adopted": "the value adopted for the certificate (joint fit of every reading)",
    "accelcal_draft": "this DCC is a DRAFT, not a certificate",
    "accelcal_incomplete": "the campaign is incomplete: not a calibration",
    "accelcal_simulated": "computed from simulated files: not a calibration",
    "accelcal_excluded": "the campaign was excluded from the unit's history",
    "accelcal_notCurrent": "the result is not the campaign's current result",
    "accelcal_result": "the accelcal result this DCC reports",
    "accelcal_inputRun": "an input run (raw file and its sha256)",
    "accelcal_runTemperature": "the instrument temperature logged during a run",
    "accelcal_localGravity": "local gravity at a rig, with its stated standard uncertainty",
    "accelcal_rig": "a rig and its reference standards",
    "accelcal_referenceStandard": "a reference standard whose own DCC gives a rig input",
}
#: Statement refType -> the status word ``accelcal verify`` prints, most severe first.
STATUS_REFTYPES = {"accelcal_draft": "DRAFT", "accelcal_incomplete": "INCOMPLETE",
                   "accelcal_excluded": "EXCLUDED", "accelcal_simulated": "SIMULATED",
                   "accelcal_notCurrent": "NOT CURRENT"}


def _reftype_definitions(root, adm, lang: str) -> None:
    used = sorted({t for e in root.iter() for t in (e.get("refType") or "").split()})
    if not used:
        return
    defs = _el(adm, DCC_NS, "refTypeDefinitions")
    for t in used:
        if t in REFTYPES:
            ns, link, what = REFTYPES[t]
        elif t.startswith("accelcal_"):
            ns, link = "accelcal", ACCELCAL_LINK
            what = ACCELCAL_REFTYPES.get(t) or (
                f"the test kind {t.removeprefix('accelcal_test_')} (its runs and their evaluation)"
                if t.startswith("accelcal_test_") else
                f"the coefficient {t.removeprefix('accelcal_coefficient_')} of the instrument model")
        else:
            raise DccError(f"refType {t!r} has no definition")
        e = _el(defs, DCC_NS, "refTypeDefinition", refType=t)
        _text(e, "name", t, lang)
        _text(e, "description", what, lang)
        _el(e, DCC_NS, "namespace", ns)
        _el(e, DCC_NS, "link", link)


def _real(parent, label: str | None, value: float, unit: str, u: float | None = None,
          k: float | None = None):
    """An si:real rounded per GUM 7.2.6; with ``u`` a standard uncertainty, with ``k`` too an
    expanded one (U = k u), as D-SI 2.2 ``si:measurementUncertaintyUnivariate``."""
    U = None if u is None else (u * k if k is not None else u)
    v_txt, U_txt = rounded_pair(value, U)
    real = _el(parent, SI_NS, "real")
    if label:
        _el(real, SI_NS, "label", label)
    _el(real, SI_NS, "value", v_txt)
    _el(real, SI_NS, "unit", unit)
    if U_txt is not None:
        mu = _el(real, SI_NS, "measurementUncertaintyUnivariate")
        if k is None:
            _el(_el(mu, SI_NS, "standardMU"), SI_NS, "valueStandardMU", U_txt)
        else:
            e = _el(mu, SI_NS, "expandedMU")
            _el(e, SI_NS, "valueExpandedMU", U_txt)
            _el(e, SI_NS, "coverageFactor", _k_text(k))
            _el(e, SI_NS, "coverageProbability", COVERAGE_PROBABILITY)
            _el(e, SI_NS, "distribution", "normal" if k == 2 else "t")
    return real


def _quantity(parent, name: str, lang: str, *real_args, refType: str | None = None, **kw):
    q = _el(parent, DCC_NS, "quantity", refType=refType)
    _text(q, "name", name, lang)
    _real(q, *real_args, **kw)
    return q


def _certificate_hash(parent, src, lang: str) -> None:
    """dcc:certificate of a reference standard: its DCC's identifier, issuer and sha256."""
    h = _el(parent, DCC_NS, "certificate")
    _text(h, "referral", f"DCC of {src.issuer}", lang)
    _el(h, DCC_NS, "referralID", src.unique_identifier)
    _el(h, DCC_NS, "procedure", "SHA-256 of the DCC file")
    _el(h, DCC_NS, "value", src.sha256)
    _el(h, DCC_NS, "traceable", "true")


def _equipment_and_conditions(mr, d, cfg, lang: str) -> None:
    """``measuringEquipments`` (each rig with its reference standards; each standard whose
    own DCC gives a rig input) and ``influenceConditions`` (each run's temperatures, each
    rig's local gravity with its stated u, each rig), under the measurement result, so that
    every quantity has its conditions (PTB's rules)."""
    from .certificate import rig_input_sources
    rigs = list(d.get("rig_ids") or [])
    sources = rig_input_sources(d, cfg)
    eq = _el(mr, DCC_NS, "measuringEquipments")
    for rig in rigs:
        e = _el(eq, DCC_NS, "measuringEquipment", refType="accelcal_rig")
        _text(e, "name", f"rig {rig}", lang)
        _text(e, "description", cfg.rig_traceability.get(rig)
              or _ph(f'[traceability.rigs] "{rig}": its reference standards'), lang)
        for key, src in sources.get(rig, {}).items():
            s = _el(eq, DCC_NS, "measuringEquipment", refType="accelcal_referenceStandard")
            _text(s, "name", f"{src.what} of rig {rig}", lang)
            _text(s, "description", f"{src.what} from {src.source()}, file sha256 {src.sha256}", lang)
            _certificate_hash(s, src, lang)
            ids = _el(_el(s, DCC_NS, "identifications"), DCC_NS, "identification")
            _el(ids, DCC_NS, "issuer", "calibrationLaboratory")
            _el(ids, DCC_NS, "value", src.unique_identifier)
            _text(ids, "name", f"uniqueIdentifier of the DCC issued by {src.issuer}", lang)
            q = _el(_el(s, DCC_NS, "measuringEquipmentQuantities"), DCC_NS, "measuringEquipmentQuantity")
            _text(q, "name", src.what, lang)
            _real(q, src.label or None, src.value, src.unit, src.u)

    ic = _el(mr, DCC_NS, "influenceConditions")
    for x in d.get("runs") or []:
        c = _el(ic, DCC_NS, "influenceCondition", refType="accelcal_runTemperature")
        _text(c, "name", f"instrument temperature during run {x.get('run_id')} ({x.get('test')}, "
              f"rig {x.get('rig_id')})", lang)
        data = _el(c, DCC_NS, "data")
        tc = x.get("temp_c")
        if not tc:
            _text(data, "text", "not recorded in the run's data", lang)
            continue
        for what, v in (("minimum", tc[0]), ("maximum", tc[2])):
            q = _el(data, DCC_NS, "quantity")
            _text(q, "name", what, lang)
            real = _el(q, SI_NS, "real")     # as logged, to 0.01 °C (the certificate's table)
            _el(real, SI_NS, "value", f"{float(v):.2f}")
            _el(real, SI_NS, "unit", r"\degreecelsius")
    stated = (d.get("parameters") or {}).get("rig_uncertainty") or {}
    for rig in rigs:
        g = next((x["g_local"] for x in d.get("runs") or []
                  if x.get("rig_id") == rig and x.get("g_local") is not None), None)
        u = (stated.get(rig) or {}).get("g_local")
        src = sources.get(rig, {}).get("g_local_dcc")
        c = _el(ic, DCC_NS, "influenceCondition", refType="accelcal_localGravity")
        _text(c, "name", f"local gravity at rig {rig}", lang)
        how = ("value from the runs' metadata; standard uncertainty "
               + (f"from {src.source()}" if src is not None else
                  "stated by the laboratory" if u is not None else "not stated"))
        _text(c, "description", how, lang)
        if src is not None:
            _certificate_hash(c, src, lang)
        data = _el(c, DCC_NS, "data")
        if g is None:
            _text(data, "text", "not recorded in the run files", lang)
        else:
            q = _el(data, DCC_NS, "quantity")
            _text(q, "name", "g_local", lang)
            _real(q, "g_local", float(g), r"\metre\second\tothe{-2}", u)
        c = _el(ic, DCC_NS, "influenceCondition", refType="accelcal_rig")
        _text(c, "name", f"rig {rig} and its reference standards", lang)
        other = [f"{k} = {v:g}" for k, v in sorted((stated.get(rig) or {}).items()) if k != "g_local"]
        _text(_el(c, DCC_NS, "data"), "text", (cfg.rig_traceability.get(rig) or
              _ph(f'[traceability.rigs] "{rig}"')) + (f"; stated standard uncertainties: "
                                                       f"{', '.join(other)}" if other else ""), lang)


def build_dcc(d: dict[str, Any], cfg, dcfg: DccConfig | None = None,
              document: tuple[str, str, bytes] | None = None, customer: str | None = None,
              issued: str | None = None):
    """The DCC of one result, as an lxml element (unsigned, not yet validated).

    Parameters
    ----------
    d : dict
        :func:`accelcal.ops.certificate.load_report_data` of the result.
    cfg : accelcal.config.LabConfig
        The lab's facts (name, address, approver, customer, number prefix, traceability).
    dcfg : DccConfig, optional
        ``[dcc]`` of accelcal.toml (country, language, e-mail).
    document : (file name, MIME type, bytes), optional
        The human-readable certificate to embed as ``dcc:document``.
    customer : str, optional
        Overrides ``[certificate] customer`` (``accelcal report --customer``).
    issued : str, optional
        Date of issue (ISO); today (UTC) by default.

    Returns
    -------
    lxml.etree._Element
        The ``dcc:digitalCalibrationCertificate`` root.  A DRAFT (any fact missing) carries
        no certificate number (:func:`accelcal.ops.certificate.document_number`) and an
        ``accelcal_draft`` statement.
    """
    from lxml import etree

    from .certificate import COVERAGE_PROBABILITY as _CP_TEXT
    from .certificate import _adopted, _k, _u_unknown, document_number, method_text, missing_facts
    dcfg = dcfg or DccConfig()
    lang = dcfg.language
    r = d["result"]
    missing = missing_facts(d, cfg, customer, dcfg)
    number = document_number(d["result_id"], cfg.number_prefix, bool(missing))
    issued = issued or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d")
    cust = customer or cfg.customer

    root = etree.Element(f"{{{DCC_NS}}}digitalCalibrationCertificate", nsmap=NSMAP)
    root.set("schemaVersion", SCHEMA_VERSION)
    adm = _el(root, DCC_NS, "administrativeData")
    _software(_el(adm, DCC_NS, "dccSoftware"), d, lang)

    core = _el(adm, DCC_NS, "coreData")
    _el(core, DCC_NS, "countryCodeISO3166_1", dcfg.country_code or "ZZ")
    _el(core, DCC_NS, "usedLangCodeISO639_1", lang)
    _el(core, DCC_NS, "mandatoryLangCodeISO639_1", lang)
    _el(core, DCC_NS, "uniqueIdentifier", number)
    ids = _el(core, DCC_NS, "identifications")
    for value, what in ((d["result_id"], "accelcal result id"), (d["campaign"], "campaign")):
        i = _el(ids, DCC_NS, "identification")
        _el(i, DCC_NS, "issuer", "calibrationLaboratory")
        _el(i, DCC_NS, "value", value)
        _text(i, "name", what, lang)
    first, last = _dates(d)
    if first is None:
        raise DccError("no run of this result has a start time: no performance dates for the DCC")
    # receiptDate is optional and not recorded in a data drop: left out, not invented
    _el(core, DCC_NS, "beginPerformanceDate", first.isoformat())
    _el(core, DCC_NS, "endPerformanceDate", last.isoformat())
    _el(core, DCC_NS, "performanceLocation", "laboratory")
    _el(core, DCC_NS, "issueDate", issued)

    items = _el(adm, DCC_NS, "items")
    item = _el(items, DCC_NS, "item")
    _text(item, "name", "accelerometer", lang)
    _text(item, "description", f"linear accelerometer, model {r.get('unit_model')}, calibrated "
          f"in campaign {d['campaign']}", lang)
    man = _el(item, DCC_NS, "manufacturer")
    _text(man, "name", "not recorded in the data drop", lang)
    if r.get("unit_model"):
        _el(item, DCC_NS, "model", str(r["unit_model"]))
    iids = _el(item, DCC_NS, "identifications")
    i = _el(iids, DCC_NS, "identification")
    _el(i, DCC_NS, "issuer", "manufacturer")
    _el(i, DCC_NS, "value", str(r.get("unit_serial") or "not recorded"))
    _text(i, "name", "serial number", lang)

    lab = _el(adm, DCC_NS, "calibrationLaboratory")
    if cfg.accreditation:
        _el(lab, DCC_NS, "calibrationLaboratoryCode", cfg.accreditation)
    where = ", ".join(x for x in (cfg.address, cfg.location and f"calibrations at {cfg.location}") if x)
    _contact(lab, "contact", cfg.name or _ph("[lab] name"), dcfg.email,
             where or _ph("[lab] address"), dcfg.country_code, lang)

    rp = _el(_el(adm, DCC_NS, "respPersons"), DCC_NS, "respPerson")
    person = _el(rp, DCC_NS, "person")
    _text(person, "name", cfg.approver or _ph("[certificate] approver"), lang)
    if cfg.approver_role:
        _el(rp, DCC_NS, "role", cfg.approver_role)
    _el(rp, DCC_NS, "mainSigner", "true")

    _contact(adm, "customer", cust or _ph("[certificate] customer (or --customer)"), None,
             cust or None, None, lang)

    st = _el(adm, DCC_NS, "statements")
    statements = [(None, "The results relate only to the item calibrated."),
                  (None, f"The expanded uncertainty U is the combined standard uncertainty "
                         f"multiplied by the coverage factor k given with each value (k = 2 unless "
                         f"the uncertainty rests on few degrees of freedom), for a coverage "
                         f"probability of {_CP_TEXT}. Values and U are rounded per GUM 7.2.6 (U to "
                         f"two significant digits, the value to the same decimal place)."),
                  (None, cfg.traceability or _ph("[traceability] statement")),
                  (None, f"Date of issue: {issued}.")]
    if r.get("simulated"):
        statements.insert(0, ("accelcal_simulated", "SIMULATED DATA - NOT A CALIBRATION: computed "
                              "from files made by accelcal simulate."))
    if r.get("completeness") == "incomplete":
        statements.insert(0, ("accelcal_incomplete", "INCOMPLETE CAMPAIGN - not a calibration: "
                              + "; ".join(d.get("completeness_reasons") or [])))
    if not d["is_current"]:
        statements.insert(0, ("accelcal_notCurrent", "This result is not the campaign's current "
                              "result (superseded or never made current)."))
    if d.get("excluded"):
        x = d["excluded"]
        statements.insert(0, ("accelcal_excluded", f"EXCLUDED by {x.get('acted_by')} on "
                              f"{x.get('acted_at')}: {x.get('why')}"))
    if missing:
        statements.insert(0, ("accelcal_draft", "DRAFT - not valid as a certificate, carries no "
                              "certificate number and is not signed: " + ", ".join(missing)
                              + " not configured (accelcal.toml)."))
    for ref, s in statements:
        _text(_el(st, DCC_NS, "statement", refType=ref), "declaration", s, lang)

    # ---- measurement results
    mrs = _el(root, DCC_NS, "measurementResults")
    mr = _el(mrs, DCC_NS, "measurementResult")
    _text(mr, "name", "Calibrated coefficients of the instrument model (IEEE Std 1293 form)", lang)
    methods = _el(mr, DCC_NS, "usedMethods")
    for test in d.get("tests") or []:
        name, how = method_text(test)
        m = _el(methods, DCC_NS, "usedMethod", refType=f"accelcal_test_{test}")
        _text(m, "name", name, lang)
        if how:
            _text(m, "description", how, lang)
    adopted_methods = sorted({c.get("method") for c in _adopted(d) if c.get("method")})
    m = _el(methods, DCC_NS, "usedMethod", refType="accelcal_adopted")
    _text(m, "name", "adopted values from: " + (", ".join(adopted_methods) or "none"), lang)
    _software(_el(mr, DCC_NS, "usedSoftware"), d, lang)
    _equipment_and_conditions(mr, d, cfg, lang)

    results = _el(mr, DCC_NS, "results")
    n = 0
    for c in _adopted(d):
        if c.get("value") is None or not math.isfinite(float(c["value"])):
            continue
        unit, f = dsi_unit(c["name"], c.get("unit"))
        check_dsi_unit(unit)
        k = _k(c)
        u = None if _u_unknown(c) else float(c["std_uncertainty"]) / f
        res = _el(results, DCC_NS, "result", refType=f"accelcal_coefficient_{c['name']}")
        _text(res, "name", c["name"] + (f" ({c['rig_id']})" if c.get("rig_id") else ""), lang)
        about = [f"method {c.get('method') or '—'}"]
        if c.get("rig_id"):
            about.append(f"rig {c['rig_id']}")
        if c.get("dof") is not None and math.isfinite(float(c["dof"])):
            about.append(f"degrees of freedom {float(c['dof']):.0f}")
        if u is None or not math.isfinite(u) or u <= 0:
            about.append("uncertainty not assessable (the runs leave no degrees of freedom to "
                         "test the model)")
        if c.get("note"):
            about.append(str(c["note"]))
        _text(res, "description", "; ".join(about), lang)
        q = _el(_el(res, DCC_NS, "data"), DCC_NS, "quantity", refType="basic_measuredValue accelcal_adopted")
        _real(q, c["name"], float(c["value"]) / f, unit, u, k)
        n += 1
    if n == 0:
        res = _el(results, DCC_NS, "result")
        _text(res, "name", "no adopted value", lang)
        _text(_el(res, DCC_NS, "data"), "text", "No adopted value in this result: the values "
              "computed are cross-checks only (see the embedded certificate).", lang)

    meta = _el(mr, DCC_NS, "measurementMetaData")
    md = _el(meta, DCC_NS, "metaData", refType="accelcal_result")
    _el(md, DCC_NS, "reference", f"result_id:{d['result_id']}")
    _text(md, "declaration", f"accelcal result {d['result_id']} of campaign {d['campaign']}, "
          f"code version {r.get('code_version')}", lang)
    for x in d.get("lineage") or []:
        md = _el(meta, DCC_NS, "metaData", refType="accelcal_inputRun")
        _el(md, DCC_NS, "reference", f"sha256:{x.get('sha256')}")
        _text(md, "declaration", f"input run {x.get('run_id')} revision {x.get('revision')}: test "
              f"{x.get('test')}, rig {x.get('rig_id')}, started {x.get('started_at')}, raw file "
              f"{x.get('drop_name') or ''} sha256 {x.get('sha256')}", lang)

    if document is not None:
        fname, mime, data = document
        doc = _el(root, DCC_NS, "document")
        _text(doc, "name", ("DRAFT calibration certificate" if missing else
                            f"Calibration certificate {number}") + " (human-readable)", lang)
        _el(doc, DCC_NS, "fileName", fname)
        _el(doc, DCC_NS, "mimeType", mime)
        _el(doc, DCC_NS, "dataBase64", base64.b64encode(data).decode("ascii"))
    _reftype_definitions(root, adm, lang)
    return root


def _k_text(k: float) -> str:
    """A coverage factor as si:kValueType wants it (>= 1, no exponent): 2, 2.37."""
    return format(k, ".3g") if k >= 1 else "1"


# ------------------------------------------------------------ PTB's rules --

@dataclass
class SchematronReport:
    """What PTB's Schematron rules (dcclib) say of a DCC: the failed errors and warnings."""
    errors: list[str]
    warnings: list[str]

    def summary(self) -> str:
        first = (self.errors or self.warnings or [""])[0]
        return (f"{len(self.errors)} errors, {len(self.warnings)} warnings"
                + (f"; first: {' '.join(first.split())}" if first else ""))


@lru_cache(maxsize=1)
def _schematron():
    from dcclib.validation.schematron import SchematronValidator
    return SchematronValidator.for_dcc()


def schematron_report(root) -> SchematronReport:
    """PTB's DCC rules beyond the schema, run from PTB's own ``dcclib`` (its compiled
    Schematron, no network).  The rules are meant for the DCC's content: the XML-DSig
    signature (W3C's elements, which are empty by design, e.g. ``ds:DigestMethod``) is
    checked by :func:`verify_dcc` instead and left out here."""
    import copy
    root = copy.deepcopy(root)
    for sig in root.findall(f"{{{DS_NS}}}Signature"):
        root.remove(sig)
    res = _schematron().validate_tree(root)
    found = list(res.failed_assertions) + list(res.successful_reports)
    pick = lambda role: [f"{r.text} (at {r.location})" for r in found if r.role == role]
    return SchematronReport(pick("error") + pick("fatal"), pick("warning"))


def statuses(root) -> list[str]:
    """The status words of a DCC written by accelcal (DRAFT, INCOMPLETE, EXCLUDED,
    SIMULATED, NOT CURRENT), from its statements' refTypes; empty for a final one."""
    found = {t for st in root.iter(f"{{{DCC_NS}}}statement") for t in (st.get("refType") or "").split()}
    return [word for ref, word in STATUS_REFTYPES.items() if ref in found]


def is_draft(root) -> bool:
    return "DRAFT" in statuses(root)


def draft_reason(root) -> str:
    st = root.find(f".//{{{DCC_NS}}}statement[@refType='accelcal_draft']")
    text = "".join(st.itertext()) if st is not None else ""
    return " ".join(text.split()).split(": ", 1)[-1].rstrip(".")


# ----------------------------------------------------------------- signing --

def sign_dcc(root, key_pem: bytes, cert_pem: bytes, password: bytes | None = None,
             fmt: str = "xades"):
    """Sign a final DCC with an enveloped signature (SHA-256; RSA or ECDSA by the key), the
    ``ds:Signature`` the root's last child (DCC 3.3.0): XAdES-BES
    (``fmt="xades"``: the signing time and the signing certificate's digest are signed
    too) or plain XML-DSig (``fmt="xmldsig"``).

    Parameters
    ----------
    root : lxml.etree._Element
        The unsigned DCC.
    key_pem, cert_pem : bytes
        The lab's PEM private key and its X.509 certificate.
    password : bytes, optional
        The key's password.
    fmt : {"xades", "xmldsig"}
        Signature format.

    Returns
    -------
    lxml.etree._Element
        The signed DCC root.
    """
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.hazmat.primitives.serialization import load_pem_private_key
    from signxml import DigestAlgorithm, SignatureMethod, XMLSigner
    try:
        key = load_pem_private_key(key_pem, password)
    except (ValueError, TypeError) as e:
        raise DccError(f"cannot load the DCC signing key: {e}") from None
    algo = SignatureMethod.ECDSA_SHA256 if isinstance(key, ec.EllipticCurvePrivateKey) else SignatureMethod.RSA_SHA256
    for sig in root.findall(f".//{{{DS_NS}}}Signature"):
        sig.getparent().remove(sig)
    if is_draft(root):
        raise DccError("a DRAFT is never signed: state what its DRAFT statement names in "
                       "accelcal.toml and report again")
    _el(root, DS_NS, "Signature", Id="placeholder")     # DCC 3.3.0: the root's last child
    rp = root.find(f"{{{DCC_NS}}}administrativeData/{{{DCC_NS}}}respPersons/{{{DCC_NS}}}respPerson")
    if rp is not None and rp.find(f"{{{DCC_NS}}}cryptElectronicSignature") is None:
        _el(rp, DCC_NS, "cryptElectronicSignature", "true")
    args = dict(signature_algorithm=algo, digest_algorithm=DigestAlgorithm.SHA256)
    try:
        if fmt == "xades":
            from signxml.xades import XAdESDataObjectFormat, XAdESSigner
            signer = XAdESSigner(claimed_roles=["calibration laboratory"], data_object_format=
                                 XAdESDataObjectFormat(Description="Digital Calibration Certificate",
                                                       MimeType="text/xml"), **args)
        else:
            signer = XMLSigner(**args)
        return signer.sign(root, key=key, cert=cert_pem.decode("ascii"))
    except Exception as e:          # signxml raises several kinds; the CLI shows one line
        raise DccError(f"cannot sign the DCC: {type(e).__name__}: {e}") from None


def _read(path: Path | None, what: str) -> bytes:
    if path is None:
        raise DccError(f"{what} not configured")
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise DccError(f"cannot read {what} {path}: {e.strerror}") from None


# ----------------------------------------------------------------- writing --

def dcc_path(html_path: Path) -> Path:
    """Where the DCC of a certificate goes: beside it, ``<name>.dcc.xml``."""
    return Path(html_path).with_suffix(".dcc.xml")


def write_dcc(d: dict[str, Any], cfg, html_path: Path, pdf: bool = False,
              customer: str | None = None, issued: str | None = None,
              sign: bool | None = None) -> Path:
    """Build, sign, validate and write the DCC of a certificate beside its HTML; the PDF
    (``pdf``: printed beside the HTML just now) or else the HTML is embedded.

    ``sign``: None signs a final DCC when ``[dcc] key_file``/``cert_file`` are set and
    leaves a DRAFT unsigned; True (``--sign``) requires the signature and refuses a DRAFT.
    The XSD and PTB's Schematron (:func:`schematron_report`) must pass, or nothing is
    written.

    Raises
    ------
    DccError
        One line: the DCC is invalid against the shipped schema or PTB's rules (nothing is
        written), a unit is not D-SI, a DRAFT is to be signed, the key cannot be read, or
        the file cannot be written.
    """
    from ..fileio import atomic_write
    dcfg = dcc_config(cfg.path)
    html_path = Path(html_path)
    if pdf:
        p = html_path.with_suffix(".pdf")
        document = (p.name, "application/pdf", p.read_bytes())
    else:
        document = (html_path.name, "text/html", html_path.read_bytes())
    root = build_dcc(d, cfg, dcfg, document=document, customer=customer, issued=issued)
    if sign and is_draft(root):
        raise DccError("--sign refused: the DCC is a DRAFT (" + draft_reason(root) + ")")
    keyed = dcfg.key_file is not None or dcfg.cert_file is not None
    if sign and not keyed:
        raise DccError("--sign needs [dcc] key_file and cert_file in accelcal.toml")
    if keyed and not is_draft(root) and sign is not False:
        pw = os.environ.get(dcfg.key_password_env) if dcfg.key_password_env else None
        root = sign_dcc(root, _read(dcfg.key_file, "[dcc] key_file"),
                        _read(dcfg.cert_file, "[dcc] cert_file"),
                        None if pw is None else pw.encode("utf-8"), dcfg.signature)
    data = serialize(root)
    try:
        parsed = _parse(data)
        validate(parsed)
        rep = schematron_report(parsed)
        if (rep.errors or rep.warnings) and not is_draft(parsed):
            raise DccError(f"PTB's rules (dcclib Schematron): {rep.summary()}")
    except DccError as e:
        raise DccError(f"DCC not written: {e}") from None
    out = dcc_path(html_path)
    try:
        atomic_write(out, lambda fh: fh.write(data))
    except OSError as e:
        raise DccError(f"cannot write DCC {out}: {e.strerror}") from None
    return out


def serialize(root) -> bytes:
    from lxml import etree
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8")


# ---------------------------------------------------------------- verifying --

@dataclass
class Verified:
    """What :func:`verify_dcc` found: the schema version, PTB's rules' findings, the
    certificate's status words (empty: final) and the signer if signed."""
    schema_version: str
    signed: bool
    signer: str | None = None
    signature_format: str | None = None
    rules: SchematronReport | None = None
    status: list[str] | None = None


def verify_dcc(path: str | Path, cert_pem: bytes | None = None) -> Verified:
    """Check a DCC file: valid against the shipped XSD of its ``schemaVersion`` and, if it
    carries a ``ds:Signature``, that the signature verifies with ``cert_pem`` (the lab's
    certificate) and covers the whole document.

    Raises
    ------
    DccError
        One line saying what fails.
    """
    from signxml import XMLVerifier
    from signxml.exceptions import InvalidInput, InvalidSignature
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise DccError(f"cannot read {path}: {e.strerror}") from None
    root = _parse(data)
    version = validate(root)
    rules, status = schematron_report(root), statuses(root)
    sigs = root.findall(f".//{{{DS_NS}}}Signature")
    if not sigs:
        return Verified(version, False, rules=rules, status=status)
    if "DRAFT" in status:
        raise DccError("a DRAFT carries a signature: a draft is never signed")
    if len(sigs) > 1:
        raise DccError(f"{len(sigs)} signatures; accelcal checks a DCC with one")
    if cert_pem is None:
        raise DccError("signed, but no certificate to check it with: give --cert or set "
                       "[dcc] cert_file in accelcal.toml")
    xades = root.find(f".//{{{XADES_NS}}}QualifyingProperties") is not None
    try:
        if xades:   # three references: the document, the signed properties, the key info
            from signxml.xades import XAdESVerifier
            results = XAdESVerifier().verify(data, x509_cert=cert_pem.decode("ascii"),
                                             expect_references=3)
        else:
            results = [XMLVerifier().verify(data, x509_cert=cert_pem.decode("ascii"))]
    except (InvalidSignature, InvalidInput) as e:
        raise DccError(f"signature does not verify: {' '.join(str(e).split())}") from None
    except Exception as e:
        raise DccError(f"signature cannot be checked: {type(e).__name__}: {e}") from None
    if not any(r.signed_xml is not None and r.signed_xml.tag == root.tag
               and r.signed_xml.get("schemaVersion") == version for r in results):
        raise DccError("the signature does not cover the whole DCC")
    from cryptography import x509
    subject = x509.load_pem_x509_certificate(cert_pem).subject.rfc4514_string()
    return Verified(version, True, subject, "XAdES-BES" if xades else "XML-DSig", rules, status)

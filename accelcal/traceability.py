"""A rig input read from its standard's own Digital Calibration Certificate (PTB DCC XML).

``[rigs."ID"] g_local_dcc = "gravimetry.dcc.xml"`` (and ``radius_dcc``, ``reference_dcc``)
names the DCC of the standard behind a rig input: the gravimetry survey of the site, the
arm radius measurement, the reference accelerometer.  :func:`read_input_dcc` takes from it
the value and the standard uncertainty (``si:measurementUncertaintyUnivariate``: standardMU,
or expandedMU / k; the deprecated ``si:expandedUnc`` too), the certificate's
``uniqueIdentifier``, its issuer (the calibration laboratory) and the file's sha256, so the
budget line and our own DCC's ``measuringEquipments`` can name the certificate the number
came from.  A DCC written by ``accelcal report --dcc`` (a reference unit's) reads back the
same way.

A tampered input is refused in one line: a signed DCC whose XML signature fails against
the certificate it embeds, a file whose sha256 differs from the pin
(``g_local_dcc_sha256``), or a DCC that says it is a DRAFT.
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

DCC_NS = "https://ptb.de/dcc"
SI_NS = "https://ptb.de/si"
DS_NS = "http://www.w3.org/2000/09/xmldsig#"

#: Rig inputs that may come from a DCC: config key -> (what it is, its SI unit in D-SI).
#: ``g_local`` enters the budgets (:data:`accelcal.effects.RIG_INPUTS`); the arm radius and
#: the reference accelerometer are named as measuring equipment.
DCC_INPUTS = {"g_local_dcc": ("local gravity g_local", r"\metre\second\tothe{-2}"),
              "radius_dcc": ("arm radius of the centrifuge", r"\metre"),
              "reference_dcc": ("reference accelerometer", None)}
#: The refType of the statement a DRAFT DCC carries (accelcal.ops.dcc writes it).
DRAFT_REFTYPE = "accelcal_draft"

_PREFIX = {"": 1.0, r"\kilo": 1e3, r"\centi": 1e-2, r"\milli": 1e-3, r"\micro": 1e-6,
           r"\nano": 1e-9}


class InputDccError(ValueError):
    """The input DCC cannot be used (one line)."""


@dataclass(frozen=True)
class InputDcc:
    """What a rig input takes from its standard's DCC.

    Attributes
    ----------
    path : str
        The file read.
    sha256 : str
        Of its bytes.
    unique_identifier, issuer : str
        ``coreData/uniqueIdentifier`` and the calibration laboratory's name.
    label : str
        The quantity's ``si:label`` (or its result's name).
    value, u : float
        Value and standard uncertainty, in ``unit`` scaled to SI when the unit is known
        (m/s² for g, m for a radius), else in the DCC's own unit.
    unit : str
        The D-SI unit of ``value`` and ``u``.
    signed : bool
        Whether it carries an XML signature (verified when it does).
    """
    path: str
    sha256: str
    unique_identifier: str
    issuer: str
    label: str
    value: float
    u: float
    unit: str
    signed: bool
    what: str = ""

    def source(self) -> str:
        """How a budget line or a table names it."""
        return f"DCC {self.unique_identifier} of {self.issuer}"


def _text(el, path: str) -> str | None:
    x = el.find(path, {"dcc": DCC_NS, "si": SI_NS})
    return None if x is None or x.text is None else " ".join(x.text.split())


def _u_of(real) -> float | None:
    ns = {"si": SI_NS}
    std = real.find("si:measurementUncertaintyUnivariate/si:standardMU/si:valueStandardMU", ns)
    if std is not None:
        return float(std.text)
    exp = real.find("si:measurementUncertaintyUnivariate/si:expandedMU", ns)
    if exp is None:
        exp = real.find("si:expandedUnc", ns)
    if exp is None:
        return None
    U = exp.find("si:valueExpandedMU", ns)
    U = exp.find("si:uncertainty", ns) if U is None else U
    return float(U.text) / float(exp.find("si:coverageFactor", ns).text)


def _scale(unit: str, si_unit: str | None) -> float | None:
    """SI value of one ``unit`` when it is ``si_unit`` with a prefix, else None."""
    if si_unit is None:
        return None
    m = re.fullmatch(r"(\\[a-z]+)?" + re.escape(si_unit), unit.strip())
    return _PREFIX.get(m.group(1) or "") if m else None


def _check_signature(data: bytes, root, where: str) -> bool:
    sigs = root.findall(f".//{{{DS_NS}}}Signature")
    if not sigs:
        return False
    cert = root.find(f".//{{{DS_NS}}}X509Certificate")
    if cert is None or not (cert.text or "").strip():
        raise InputDccError(f"{where}: signed, but the signature carries no certificate to check it with")
    pem = ("-----BEGIN CERTIFICATE-----\n" + "".join(cert.text.split())
           + "\n-----END CERTIFICATE-----\n")
    try:
        if root.find(".//{http://uri.etsi.org/01903/v1.3.2#}QualifyingProperties") is not None:
            from signxml.xades import XAdESVerifier
            XAdESVerifier().verify(data, x509_cert=pem, expect_references=3)
        else:
            from signxml import XMLVerifier
            XMLVerifier().verify(data, x509_cert=pem)
    except Exception as e:
        raise InputDccError(f"{where}: signature does not verify ({type(e).__name__}); "
                            f"the file was changed after it was signed") from None
    return True


def read_input_dcc(path: str | Path, key: str = "g_local_dcc", sha256: str | None = None,
                   label: str | None = None) -> InputDcc:
    """Value, u, identifier and issuer of the quantity a rig input takes from a DCC.

    Parameters
    ----------
    path : str or Path
        The DCC file.
    key : str
        The config key naming it (:data:`DCC_INPUTS`): which unit the quantity must have.
    sha256 : str, optional
        The file's expected sha256 (a pin in accelcal.toml).
    label : str, optional
        The ``si:label`` to take (default: the first result quantity in the expected unit,
        else the first with an uncertainty).

    Raises
    ------
    InputDccError
        One line: unreadable, not a DCC, a DRAFT, a changed file (sha256 or signature), or
        no quantity with a stated uncertainty.
    """
    from lxml import etree
    where = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise InputDccError(f"{where}: cannot read the DCC: {e.strerror}") from None
    digest = hashlib.sha256(data).hexdigest()
    if sha256 and digest != sha256.strip().lower():
        raise InputDccError(f"{where}: sha256 {digest[:16]}... differs from the pinned "
                            f"{sha256.strip()[:16]}...; the file is not the certificate stated")
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=True)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as e:
        raise InputDccError(f"{where}: not well-formed XML: {e}") from None
    if root.tag != f"{{{DCC_NS}}}digitalCalibrationCertificate":
        raise InputDccError(f"{where}: not a DCC (root element {root.tag})")
    signed = _check_signature(data, root, where)
    ns = {"dcc": DCC_NS, "si": SI_NS}
    if root.find(f".//dcc:statement[@refType='{DRAFT_REFTYPE}']", ns) is not None:
        raise InputDccError(f"{where}: the DCC is a DRAFT, not a certificate")
    uid = _text(root, "dcc:administrativeData/dcc:coreData/dcc:uniqueIdentifier") or ""
    issuer = _text(root, "dcc:administrativeData/dcc:calibrationLaboratory/dcc:contact/dcc:name/dcc:content")
    if not uid or not issuer:
        raise InputDccError(f"{where}: the DCC names no uniqueIdentifier or no calibration laboratory")
    what, si_unit = DCC_INPUTS[key]
    candidates = []
    for real in root.iterfind(".//dcc:measurementResult/dcc:results//si:real", ns):
        u = _u_of(real)
        unit = _text(real, "si:unit") or ""
        lab = _text(real, "si:label") or ""
        if u is None or (label and lab != label):
            continue
        candidates.append((_scale(unit, si_unit) is None, real, u, unit, lab))
    if not candidates:
        raise InputDccError(f"{where}: no result quantity{f' labelled {label!r}' if label else ''} "
                            f"with a stated uncertainty")
    candidates.sort(key=lambda c: c[0])
    _, real, u, unit, lab = candidates[0]
    f = _scale(unit, si_unit)
    if si_unit is not None and f is None:
        raise InputDccError(f"{where}: no quantity in {si_unit} (the {what}); found {unit}")
    f = 1.0 if f is None else f
    value = float(_text(real, "si:value"))
    return InputDcc(where, digest, uid, issuer, lab, value * f, u * f,
                    si_unit if si_unit is not None else unit, signed, what)

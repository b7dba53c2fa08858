"""The Digital Calibration Certificate: ``accelcal report --dcc`` writes a PTB DCC 3.3.0 that
validates offline against the shipped XSD of its schemaVersion and that PTB's own Schematron
rules (dcclib) pass without an error or a warning, whose units are D-SI, whose numbers follow
GUM 7.2.6 (checked here independently of accelcal.rounding), whose XML-DSig signature
``accelcal verify`` checks (a changed byte fails), and whose DRAFT is never signed."""
from __future__ import annotations

import datetime as dt
import math
import re
import socket
import warnings
from decimal import Decimal
from pathlib import Path

import pytest

from accelcal import cli
from accelcal.ops import dcc as dccmod
from accelcal.ops.report import build_report, load_report_data

from conftest import RIG_INPUTS_TOML, copy_lab

#: the sample campaigns: the centrifuge campaign holds the tumble runs too
CAMPS = {"thermal": "HUST-M-07/2026-11-18", "centrifuge": "SNJ-1-03/2026-11-20",
         "sine": "QA-5512/2026-11-19"}
SI = "{https://ptb.de/si}"
DCC = "{https://ptb.de/dcc}"
CONFIG = """
[lab]
name = "Inertial Metrology Lab of Example"
address = "12 Example Road, Wuhan"
[certificate]
number_prefix = "IML"
approver = "Dr A. Approver"
customer = "Example Customer Ltd"
[traceability]
statement = "Traceable to the SI."
[traceability.rigs]
"LXJ-100" = "arm radius: CMM cert. 1; rate: encoder cert. 2"
"DH-1" = "dividing head: angle cert. 3"
"TT-1" = "thermal table: tilt cert. 4"
"DC-1" = "disc centrifuge: cert. 5"
""" + RIG_INPUTS_TOML + """[dcc]
country_code = "CN"
email = "lab@example.org"
"""
#: SI value of one D-SI unit of the DCC, written here from the SI brochure, not from accelcal.
SCALE = {r"\micro\metre\second\tothe{-2}": 1e-6, r"\micro\radian": 1e-6, r"\degree": math.pi / 180,
         r"\micro\metre\second\tothe{-2}\degreecelsius\tothe{-1}": 1e-6,
         r"\ppm\degreecelsius\tothe{-1}": 1e-6}


@pytest.fixture(scope="module")
def lab(tmp_path_factory, certified_lab):
    wh = copy_lab(certified_lab, tmp_path_factory.mktemp("dcc") / "lab")
    (wh.parent / "accelcal.toml").write_text(CONFIG)          # found beside the warehouse
    return wh


@pytest.fixture(scope="module")
def dccs(lab, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    return {k: dccmod.dcc_path(build_report(lab, c, out, dcc=True)) for k, c in CAMPS.items()}


def _root(path: Path):
    from lxml import etree
    return etree.parse(str(path)).getroot()


@pytest.fixture
def no_network(monkeypatch):
    """Any attempt to open a connection fails the test."""
    def refuse(*a, **k):
        raise AssertionError("network access attempted")
    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def _schema(folder: Path):
    """The shipped XSD loaded as the offline copy's README says (one URL mapped to the QUDT
    stand-in), without accelcal's loader."""
    import xmlschema
    return xmlschema.XMLSchema(str(folder / "dcc.xsd"), allow="local", uri_mapper={
        "https://www.ptb.de/si/v2.2.0/qudt/quantitykind.xsd": str(folder / "qudt" / "quantitykind.xsd")})


def test_shipped_schemas_import_only_local_files():
    folder = dccmod.SCHEMA_DIRS[dccmod.SCHEMA_VERSION]
    for xsd in folder.rglob("*.xsd"):
        for loc in re.findall(r'schemaLocation="([^"]*)"', xsd.read_text(encoding="utf-8")):
            if loc == "https://www.ptb.de/si/v2.2.0/qudt/quantitykind.xsd":   # mapped: the stand-in
                loc = str(folder / "qudt" / "quantitykind.xsd")
            assert "://" not in loc and (xsd.parent / loc).is_file(), (xsd.name, loc)
    assert dccmod.SCHEMA_VERSION == "3.3.0" and 'version="2.2.0"' in (folder / "si" / "SI_Format.xsd").read_text()
    assert (folder / "COPYING.LESSER").is_file() and "LESSER" in (folder / "COPYING.LESSER").read_text()


@pytest.mark.parametrize("kind", sorted(CAMPS))
def test_dcc_validates_offline_against_its_declared_schema(dccs, kind, no_network):
    import xmlschema
    root = _root(dccs[kind])
    version = root.get("schemaVersion")
    assert version == "3.3.0"
    schema = _schema(dccmod.SCHEMA_DIRS[version])    # the XSD of the version it declares
    assert schema.version == version
    schema.validate(xmlschema.XMLResource(root, allow="none"))   # no hint of the file followed
    assert root.findtext(f"{DCC}administrativeData/{DCC}coreData/{DCC}uniqueIdentifier").startswith("IML-")
    # the lineage: every input run's sha256
    refs = [e.text for e in root.iter(f"{DCC}reference") if e.text.startswith("sha256:")]
    assert refs and all(re.fullmatch(r"sha256:[0-9a-f]{64}", r) for r in refs)
    doc = root.find(f"{DCC}document")
    assert doc.findtext(f"{DCC}mimeType") == "text/html" and len(doc.findtext(f"{DCC}dataBase64")) > 1000
    assert "DRAFT" not in "".join(root.itertext())
    assert not list(root.iter(f"{SI}expandedUnc")) and list(root.iter(f"{SI}measurementUncertaintyUnivariate"))
    assert cli.main(["verify", str(dccs[kind])]) == 5        # valid, final, not signed


@pytest.mark.parametrize("kind", sorted(CAMPS))
def test_ptb_schematron_reports_no_error_and_no_warning(dccs, kind, no_network):
    """PTB's own rules, run from dcclib directly: influence conditions declared, release
    'v0.1.0', no empty element, a real country, refTypes declared, 3.3.0."""
    from dcclib.validation.schematron import SchematronValidator
    root = _root(dccs[kind])
    res = SchematronValidator.for_dcc().validate_tree(root)
    found = [(r.role, r.text) for r in list(res.failed_assertions) + list(res.successful_reports)
             if r.role in ("error", "fatal", "warning")]
    assert found == []
    mr = root.find(f"{DCC}measurementResults/{DCC}measurementResult")
    conds = [c.get("refType") for c in mr.iterfind(f"{DCC}influenceConditions/{DCC}influenceCondition")]
    assert "accelcal_localGravity" in conds and "accelcal_rig" in conds
    g = next(c for c in mr.iter(f"{DCC}influenceCondition") if c.get("refType") == "accelcal_localGravity")
    assert g.findtext(f".//{SI}valueStandardMU") == "0.000010"     # the stated 1e-5 m/s2, 2 digits
    used = {t for e in root.iter() for t in (e.get("refType") or "").split()}
    defined = {e.get("refType") for e in root.iter(f"{DCC}refTypeDefinition")}
    assert used <= defined
    assert root.findtext(f".//{DCC}countryCodeISO3166_1") == "CN"


def test_every_unit_parses_with_dsiunits(dccs):
    from dsi_unit import DsiUnit
    units = {e.text for p in dccs.values() for e in _root(p).iter(f"{SI}unit")}
    assert len(units) >= 4, units
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bad = {u: DsiUnit(u).warnings for u in units if not DsiUnit(u).valid}
    assert not bad


def test_every_unit_the_catalogue_can_need_is_d_si():
    from accelcal.effects import COEFFICIENTS, PAPER_TERMS
    for name in list(COEFFICIENTS) + list(PAPER_TERMS):
        for out in ("mA", "V", "count", "m/s2"):
            unit, f = dccmod.dsi_unit(name, f"{out}/(m/s2)")
            dccmod.check_dsi_unit(unit)
            assert f > 0


def _ulp(s: str) -> Decimal:
    return Decimal(1).scaleb(Decimal(s).as_tuple().exponent)


@pytest.mark.parametrize("kind", sorted(CAMPS))
def test_values_and_u_follow_gum_rounding(lab, dccs, kind):
    """U has at most two significant digits, the value ends at U's last digit, and both are
    the stored numbers correctly rounded (half a unit of the last place)."""
    d = load_report_data(lab, CAMPS[kind])
    adopted = {c["name"]: c for c in d["coefficients"] if c.get("adopted")}
    n = 0
    for real in _root(dccs[kind]).iter(f"{SI}real"):
        v, unit = real.findtext(f"{SI}value"), real.findtext(f"{SI}unit")
        eu = real.find(f"{SI}measurementUncertaintyUnivariate/{SI}expandedMU")
        if eu is None:
            continue
        U, k = eu.findtext(f"{SI}valueExpandedMU"), float(eu.findtext(f"{SI}coverageFactor"))
        Ud = Decimal(U)
        assert Ud > 0 and len(Ud.as_tuple().digits) <= 2, U           # <= 2 significant digits
        assert Decimal(v).as_tuple().exponent == Ud.as_tuple().exponent, (v, U)
        c = adopted[real.findtext(f"{SI}label")]
        scale = SCALE.get(unit, 1.0)
        true_v, true_U = c["value"] / scale, k * c["std_uncertainty"] / scale
        assert abs(Decimal(v) - Decimal(repr(true_v))) <= _ulp(v) / 2 * Decimal("1.000001"), (v, true_v)
        assert abs(Ud - Decimal(repr(true_U))) <= _ulp(U) / 2 * Decimal("1.000001"), (U, true_U)
        assert eu.findtext(f"{SI}coverageProbability") == "0.95"
        n += 1
    assert n >= 3


def _self_signed(tmp: Path) -> tuple[Path, Path]:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "Example Lab DCC signer")])
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(days=1)).not_valid_after(now + dt.timedelta(days=30))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True,
                                         key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, key_cert_sign=True, crl_sign=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    kp, cp = tmp / "lab.key", tmp / "lab.pem"
    kp.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                     serialization.NoEncryption()))
    cp.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return kp, cp


@pytest.mark.parametrize("fmt", ["xades", "xmldsig"])
def test_signed_dcc_verifies_and_one_changed_byte_fails(lab, tmp_path, capsys, fmt):
    kp, cp = _self_signed(tmp_path)
    cfg = tmp_path / "signing.toml"
    cfg.write_text(CONFIG + f'key_file = "{kp.name}"\ncert_file = "{cp.name}"\nsignature = "{fmt}"\n')
    html = build_report(lab, CAMPS["thermal"], tmp_path / "out", config=cfg, dcc=True)
    path = dccmod.dcc_path(html)
    root = _root(path)
    assert root[-1].tag == "{http://www.w3.org/2000/09/xmldsig#}Signature"   # DCC 3.3.0's place
    assert cli.main(["verify", str(path), "--cert", str(cp)]) == 0
    assert f"{'XAdES-BES' if fmt == 'xades' else 'XML-DSig'} signature verified" in capsys.readouterr().out
    has_xades = b"QualifyingProperties" in path.read_bytes()
    assert has_xades == (fmt == "xades")
    assert cli.main(["verify", str(path), "--config", str(cfg)]) == 0     # [dcc] cert_file
    capsys.readouterr()
    assert cli.main(["verify", str(path)]) == 1          # signed, nothing to check it with

    data = path.read_bytes()
    m = re.search(rb"<si:value>-?(\d)", data)
    i = m.start(1)
    bad = tmp_path / "tampered.dcc.xml"
    bad.write_bytes(data[:i] + (b"1" if data[i:i + 1] != b"1" else b"2") + data[i + 1:])
    capsys.readouterr()
    assert cli.main(["verify", str(bad), "--cert", str(cp)]) == 1
    err = capsys.readouterr().err.strip()
    assert "signature does not verify" in err and len(err.splitlines()) == 1, err

    if fmt == "xades":   # the signing time is signed too
        t = re.sub(rb"(<xades:SigningTime>\d)\d", rb"\g<1>9", data, count=1)
        assert t != data
        bad.write_bytes(t)
        assert cli.main(["verify", str(bad), "--cert", str(cp)]) == 1

    # another key's certificate does not verify it either
    (tmp_path / "other").mkdir()
    _, other = _self_signed(tmp_path / "other")
    assert cli.main(["verify", str(path), "--cert", str(other)]) == 1


def test_an_invalid_dcc_is_refused_in_one_line_and_not_written(lab, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(dccmod, "COVERAGE_PROBABILITY", "95 %")     # not a probability in [0, 1]
    out = tmp_path / "out"
    rc = cli.main(["report", CAMPS["thermal"], "-w", str(lab), "--out", str(out), "--dcc"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "DCC not written" in err and len(err.splitlines()) == 1, err
    assert not list(out.glob("*.dcc.xml"))


def test_verify_refuses_a_file_that_is_not_a_valid_dcc(tmp_path, capsys):
    f = tmp_path / "x.xml"
    f.write_text('<dcc:digitalCalibrationCertificate xmlns:dcc="https://ptb.de/dcc" '
                 'schemaVersion="3.3.0"/>')
    assert cli.main(["verify", str(f)]) == 1
    assert "invalid against dcc.xsd 3.3.0" in capsys.readouterr().err
    f.write_text("<not-closed>")
    assert cli.main(["verify", str(f)]) == 1


def test_with_pdf_the_pdf_is_the_embedded_document(lab, tmp_path):
    """``report --pdf --dcc`` embeds the PDF printed just now (chromium is not needed here:
    a stand-in PDF is put where the print goes)."""
    import base64

    from accelcal.config import lab_config
    html = build_report(lab, CAMPS["thermal"], tmp_path)
    pdf = b"%PDF-1.4 stand-in\n%%EOF\n"
    html.with_suffix(".pdf").write_bytes(pdf)
    d = load_report_data(lab, CAMPS["thermal"])
    path = dccmod.write_dcc(d, lab_config(None, lab), html, pdf=True)
    doc = _root(path).find(f"{DCC}document")
    assert doc.findtext(f"{DCC}mimeType") == "application/pdf"
    assert base64.b64decode(doc.findtext(f"{DCC}dataBase64")) == pdf


# ------------------------------------------------------------------ DRAFT ----

def test_a_draft_dcc_has_no_number_is_never_signed_and_verify_says_draft(lab, tmp_path, capsys):
    kp, cp = _self_signed(tmp_path)
    cfg = tmp_path / "draft.toml"          # the customer missing; a signing key configured
    cfg.write_text(CONFIG.replace('customer = "Example Customer Ltd"\n', "")
                   + f'key_file = "{kp.name}"\ncert_file = "{cp.name}"\n')
    html = build_report(lab, CAMPS["thermal"], tmp_path / "out", config=cfg, dcc=True)
    path = dccmod.dcc_path(html)
    root = _root(path)
    uid = root.findtext(f"{DCC}administrativeData/{DCC}coreData/{DCC}uniqueIdentifier")
    assert uid.startswith("DRAFT-") and "IML-" not in path.read_text()      # no final number
    assert root.find("{http://www.w3.org/2000/09/xmldsig#}Signature") is None
    capsys.readouterr()
    assert cli.main(["verify", str(path), "--cert", str(cp)]) == 4
    out = capsys.readouterr().out
    assert out.split(": ", 1)[1].startswith("DRAFT;") and "not signed" in out
    rc = cli.main(["report", CAMPS["thermal"], "-w", str(lab), "--out", str(tmp_path / "o2"),
                   "--config", str(cfg), "--dcc", "--sign"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and len(err.splitlines()) == 1 and "--sign refused: the DCC is a DRAFT" in err
    assert "[certificate] customer" in err


# ------------------------------------------------------- traceability in XML --

#: A gravimetry survey's DCC, written here by hand (not by accelcal): g = 9 793 620 µm/s² with
#: U = 60 µm/s² at k = 2, so u = 30 µm/s² = 3.0e-5 m/s².
GRAVIMETRY = """<?xml version="1.0" encoding="UTF-8"?>
<dcc:digitalCalibrationCertificate xmlns:dcc="https://ptb.de/dcc" xmlns:si="https://ptb.de/si" schemaVersion="3.3.0">
 <dcc:administrativeData>
  <dcc:coreData><dcc:uniqueIdentifier>GRAV-2026-0042</dcc:uniqueIdentifier></dcc:coreData>
  <dcc:calibrationLaboratory><dcc:contact><dcc:name><dcc:content>National Gravimetry Service</dcc:content></dcc:name></dcc:contact></dcc:calibrationLaboratory>
 </dcc:administrativeData>
 <dcc:measurementResults><dcc:measurementResult><dcc:results><dcc:result><dcc:data><dcc:quantity>
  <si:real><si:label>g</si:label><si:value>9793620</si:value><si:unit>\\micro\\metre\\second\\tothe{-2}</si:unit>
   <si:measurementUncertaintyUnivariate><si:expandedMU><si:valueExpandedMU>60</si:valueExpandedMU>
    <si:coverageFactor>2</si:coverageFactor><si:coverageProbability>0.95</si:coverageProbability>
   </si:expandedMU></si:measurementUncertaintyUnivariate></si:real>
 </dcc:quantity></dcc:data></dcc:result></dcc:results></dcc:measurementResult></dcc:measurementResults>
</dcc:digitalCalibrationCertificate>
"""
U_GRAV = 30e-6          # 60 µm/s² / k = 2, in m/s²


def _budget(wh, campaign):
    d = load_report_data(wh, campaign)
    return d, {c["name"]: c for c in d["coefficients"] if c.get("adopted")}


def test_local_gravity_from_a_gravimetry_dcc_changes_the_budget_by_exactly_its_u(lab, tmp_path, examples):
    """The u the DCC states replaces the 1e-5 m/s² of accelcal.toml: the budget line carries
    30 µm/s², each coefficient's u_c² grows by c²(30e-6² - 1e-5²), and the certificate and
    our DCC name the gravimetry DCC's uniqueIdentifier and issuer."""
    from accelcal.config import rig_uncertainties
    from accelcal.flows.pipeline import run_pipeline
    (tmp_path / "grav.dcc.xml").write_text(GRAVIMETRY)
    cfg = tmp_path / "accelcal.toml"
    cfg.write_text(CONFIG.replace('[rigs."TT-1"]\ng_local_u_m_s2 = 1e-5\n',
                                  '[rigs."TT-1"]\ng_local_dcc = "grav.dcc.xml"\n'))
    stated = rig_uncertainties(cfg)
    assert stated["TT-1"]["g_local"] == pytest.approx(U_GRAV, rel=1e-12)
    run_pipeline([str(examples / "drop-2026-11-18-thermal")], tmp_path / "lab.duckdb",
                 engine="local", parameters={"rig_uncertainty": stated})
    _, old = _budget(lab, CAMPS["thermal"])
    d, new = _budget(tmp_path / "lab.duckdb", CAMPS["thermal"])
    lines = [b for b in d["budget"] if b["quantity"].startswith("local gravity g_local")
             and b.get("method") == "joint_ml"]
    assert lines and all(b["std_uncertainty"] == pytest.approx(U_GRAV, rel=1e-12) for b in lines)
    for b in lines:
        c_old, c_new = old[b["coefficient"]], new[b["coefficient"]]
        grow = b["sensitivity"] ** 2 * (U_GRAV ** 2 - 1e-5 ** 2)
        assert c_new["std_uncertainty"] ** 2 - c_old["std_uncertainty"] ** 2 == pytest.approx(
            grow, rel=1e-6, abs=1e-12 * c_old["std_uncertainty"] ** 2)
    html = build_report(tmp_path / "lab.duckdb", CAMPS["thermal"], tmp_path / "out", config=cfg,
                        dcc=True)
    text = html.read_text()
    assert "u from DCC GRAV-2026-0042 of National Gravimetry Service" in text
    root = _root(dccmod.dcc_path(html))
    eq = [e for e in root.iter(f"{DCC}measuringEquipment") if e.get("refType") == "accelcal_referenceStandard"]
    assert len(eq) == 1 and eq[0].findtext(f"{DCC}certificate/{DCC}referralID") == "GRAV-2026-0042"
    assert eq[0].findtext(f".//{SI}valueStandardMU") == "0.000030"


def test_a_tampered_or_draft_input_dcc_is_refused_in_one_line(lab, tmp_path):
    import hashlib

    from accelcal.config import ConfigError, rig_uncertainties
    kp, cp = _self_signed(tmp_path)
    good = tmp_path / "grav.dcc.xml"
    good.write_text(GRAVIMETRY)
    pin = hashlib.sha256(good.read_bytes()).hexdigest()
    cfg = tmp_path / "accelcal.toml"

    def refused(body: str, text: str) -> str:
        cfg.write_text(f'[rigs."TT-1"]\n{body}\n')
        with pytest.raises(ConfigError) as e:
            rig_uncertainties(cfg)
        msg = str(e.value)
        assert len(msg.splitlines()) == 1 and text in msg, msg
        return msg

    cfg.write_text(f'[rigs."TT-1"]\ng_local_dcc = "grav.dcc.xml"\ng_local_dcc_sha256 = "{pin}"\n')
    assert rig_uncertainties(cfg)["TT-1"]["g_local"] == pytest.approx(U_GRAV)
    good.write_text(GRAVIMETRY.replace("9793620", "9793630"))          # one digit changed
    refused(f'g_local_dcc = "grav.dcc.xml"\ng_local_dcc_sha256 = "{pin}"', "differs from the pinned")
    refused('g_local_dcc = "grav.dcc.xml"\ng_local_u_m_s2 = 1e-5', "not both")

    # a DCC accelcal signed reads back as an input; one changed byte fails its signature
    sign_cfg = tmp_path / "sign.toml"
    sign_cfg.write_text(CONFIG + f'key_file = "{kp.name}"\ncert_file = "{cp.name}"\n')
    path = dccmod.dcc_path(build_report(lab, CAMPS["centrifuge"], tmp_path / "out", config=sign_cfg, dcc=True))
    from accelcal.traceability import read_input_dcc
    src = read_input_dcc(path, "reference_dcc", label="K2")
    k2 = _root(path).find(f".//{SI}real[{SI}label='K2']")
    assert src.signed and src.unique_identifier.startswith("IML-") and src.issuer == "Inertial Metrology Lab of Example"
    eu = k2.find(f"{SI}measurementUncertaintyUnivariate/{SI}expandedMU")
    assert src.u == pytest.approx(float(eu.findtext(f"{SI}valueExpandedMU")) / float(eu.findtext(f"{SI}coverageFactor")))
    data = path.read_bytes()
    i = data.index(b"<si:value>") + len(b"<si:value>") + 1
    (tmp_path / "bad.dcc.xml").write_bytes(data[:i] + (b"7" if data[i:i + 1] != b"7" else b"8") + data[i + 1:])
    refused('reference_dcc = "bad.dcc.xml"\ng_local_dcc = "bad.dcc.xml"', "signature does not verify")

    draft_cfg = tmp_path / "draft.toml"
    draft_cfg.write_text(CONFIG.replace('customer = "Example Customer Ltd"\n', ""))
    draft = dccmod.dcc_path(build_report(lab, CAMPS["thermal"], tmp_path / "o3", config=draft_cfg, dcc=True))
    (tmp_path / "draft.dcc.xml").write_bytes(draft.read_bytes())
    refused('g_local_dcc = "draft.dcc.xml"', "is a DRAFT")

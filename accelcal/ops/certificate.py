"""What a certificate and its machine-readable twin (the DCC) share: the data of a result
read from the warehouse (:func:`load_report_data`), the coverage words, the method texts
from the estimator registry, the certificate number, which values are adopted and how
their coverage factor is read (:mod:`accelcal.ops.report` renders the HTML
and PDF, :mod:`accelcal.ops.dcc` the DCC XML)."""
from __future__ import annotations

import datetime as _dt
import json
import math
import re
from pathlib import Path
from typing import Any

from .plots import K_COVERAGE

#: Coverage probability of U = 2u for a normal distribution (EA-4/02 wording).
COVERAGE_PROBABILITY = "≈ 95 %"

#: What each test kind is, in the certificate's words (../shared/docs/methods.md); how each
#: is evaluated is the method's own text (:mod:`accelcal.estimators.registry`).
TEST_TITLES = {
    "tumble": "Multi-position tumble in the gravity field on a dividing head",
    "centrifuge": "Precision centrifuge at stepped constant rates",
    "tilt_rotation": "Tilted rotary table in a thermal chamber",
    "sine_centrifuge": "Disc centrifuge at a sinusoidal rate",
}


def method_text(test: str) -> tuple[str, str]:
    """(what the test is, how its runs are evaluated) for the certificate's method section:
    the texts of the registered estimators that take the test, joined."""
    from ..estimators import registry
    return TEST_TITLES.get(test, test), "; ".join(e.certificate for e in registry.for_test(test))


class ReportError(RuntimeError):
    """The report cannot be made (one-line reason)."""


def _k(c) -> float:
    k = c.get("coverage_factor")
    return float(k) if k is not None and math.isfinite(float(k)) else K_COVERAGE


def _u_unknown(c) -> bool:
    u = c.get("std_uncertainty")
    return u is None or (isinstance(u, float) and math.isnan(u))


def certificate_number(result_id: str, prefix: str) -> str:
    """Unique per result: the lab's prefix and the first 12 hex of the result id (the id
    the CLI prints).  A re-issue of the same result carries the same number."""
    return f"{prefix}-{result_id[:12].upper()}"


def _adopted(d) -> list[dict[str, Any]]:
    return [c for c in d["coefficients"] if c.get("adopted")]


def missing_rig_inputs(d) -> list[tuple[str, str]]:
    """The rig inputs whose uncertainty the budgets of this result leave out, as
    (what, how to state it): each input the joint fit found entering without a stated u
    (:func:`accelcal.estimators.joint.stored_missing_rig_inputs`); a joint fit stored before the rig
    inputs entered the budgets is one entry of its own.  Any entry keeps a certificate DRAFT."""
    from ..estimators.joint import stored_missing_rig_inputs
    missing = stored_missing_rig_inputs(d.get("extras"))
    if missing is None:
        return [("uncertainties of the rig inputs (g_local, table tilt, temperature)",
                 "this result was computed before they entered the budgets: state them in "
                 "accelcal.toml and process the drops again")]
    return [(f"u({m['input']}) of {m['rig']}",
             f"set [rigs.\"{m['rig']}\"] {m['key']} in accelcal.toml and process the drops again")
            for m in missing]


def missing_facts(d, cfg, customer: str | None = None, dcfg=None) -> list[str]:
    """Everything a final certificate of this result needs and the lab has not given: the
    ``[lab]``/``[certificate]`` keys, the customer, the traceability statement and each
    rig's reference standards, the rig inputs' stated u (:func:`missing_rig_inputs`), and
    with ``dcfg`` (the DCC) the ``[dcc]`` country and e-mail.  Any entry makes the HTML, the
    PDF and the DCC a DRAFT (:func:`document_number`)."""
    missing = list(cfg.missing)
    if not (customer or cfg.customer):
        missing.append("[certificate] customer")
    if not cfg.traceability:
        missing.append("[traceability] statement")
    missing += [f'[traceability.rigs] "{rig}"' for rig in d.get("rig_ids") or []
                if not cfg.rig_traceability.get(rig)]
    if dcfg is not None:
        missing += [k for k, v in (("[dcc] country_code", dcfg.country_code),
                                   ("[dcc] email", dcfg.email)) if not v]
    missing += [what for what, _ in missing_rig_inputs(d)]
    return list(dict.fromkeys(missing))


def document_number(result_id: str, prefix: str, draft: bool) -> str:
    """The certificate number, or for a DRAFT an identifier that is not one (``DRAFT-`` and
    the result id as the CLI prints it, without the lab's prefix): a draft never carries the
    number its final certificate will have."""
    return f"DRAFT-{result_id[:12]}" if draft else certificate_number(result_id, prefix)


def rig_input_sources(d, cfg) -> dict[str, dict[str, Any]]:
    """Rig id -> config key -> :class:`accelcal.traceability.InputDcc`: the rigs of this
    result whose inputs come from a standard's own DCC (``[rigs."ID"] g_local_dcc`` ...).
    A DCC that is tampered with, or whose u differs from the u this result was computed
    with (the file changed since the drops were processed), is one ReportError line."""
    from ..config import ConfigError, _rig_tables
    from ..traceability import DCC_INPUTS, InputDccError, read_input_dcc
    if cfg.path is None:
        return {}
    try:
        path, rigs = _rig_tables(cfg.path)
    except ConfigError as e:
        raise ReportError(str(e)) from None
    stated = (d.get("parameters") or {}).get("rig_uncertainty") or {}
    out: dict[str, dict[str, Any]] = {}
    for rig in d.get("rig_ids") or []:
        t = rigs.get(rig) or {}
        for key in DCC_INPUTS:
            if not t.get(key):
                continue
            try:
                src = read_input_dcc(Path(path).parent / t[key], key, t.get(f"{key}_sha256"),
                                     t.get(f"{key}_label"))
            except InputDccError as e:
                raise ReportError(str(e)) from None
            used = (stated.get(rig) or {}).get("g_local")
            if key == "g_local_dcc" and (used is None or not math.isclose(used, src.u, rel_tol=1e-12)):
                raise ReportError(f"{src.path}: states u = {src.u:g} m/s2 but result "
                                  f"{d['result_id'][:12]} was computed with "
                                  f"{'no u' if used is None else f'{used:g} m/s2'}; process the drops again")
            out.setdefault(rig, {})[key] = src
    return out


# ------------------------------------------------------------------ reading --

def _rows(con, sql: str, params: list | None = None) -> list[dict[str, Any]]:
    cur = con.execute(sql, params or [])
    cols = [d[0] for d in cur.description]
    return [dict(zip(cols, r)) for r in cur.fetchall()]


def _read(warehouse: str | Path, fn, lock_timeout: float = 60.0):
    """Call fn(con, path) on a read-only connection, under the writer lock."""
    import duckdb

    from ..warehouse.db import check_schema_version
    from ..warehouse.errors import WarehouseError
    from ..warehouse.lock import warehouse_lock
    path = Path(warehouse).expanduser().resolve()
    if not path.exists():
        raise ReportError(f"warehouse {path} does not exist")
    try:
        with warehouse_lock(path, timeout=lock_timeout):
            con = duckdb.connect(str(path), read_only=True)
            try:
                check_schema_version(con, path)
                return fn(con, path)
            finally:
                con.close()
    except WarehouseError as e:
        raise ReportError(str(e)) from None
    except duckdb.Error as e:
        raise ReportError(f"cannot read warehouse {path}: {str(e).splitlines()[0]}") from None


def load_report_data(warehouse: str | Path, campaign: str | None, result_id: str | None = None,
                     lock_timeout: float = 60.0) -> dict[str, Any]:
    """Everything the certificate shows, as plain Python objects.  ``result_id`` may be
    the short id the CLI prints (a unique prefix); ``campaign`` may then be omitted."""
    d = _read(warehouse, lambda con, path: _load(con, campaign, result_id, path), lock_timeout)
    root = Path(warehouse).expanduser().resolve().parent
    d["runs"] = run_conditions(root, d["lineage"])
    d["flags"] = separating_run_flags(root, d["lineage"], d["flags"], d.get("extras"))
    return d


def separating_run_flags(root: Path, lineage: list[dict[str, Any]], flags: list[str],
                         extras: dict[str, Any] | None) -> list[str]:
    """The flags with each aliased pair's separating run named, asked of the runs' Parquet
    copies when the certificate is made (:func:`accelcal.testdesign.separating_run_flag`:
    ``accelcal design``'s call on the cells that command reads); the stored flags when the
    runs are gone."""
    from ..estimators.joint import ALIASED_PAIR_FLAG, stored_aliased_pairs
    pairs = stored_aliased_pairs(extras)
    if not pairs:
        return flags
    from ..diagnosis.core import prepare_cells
    from ..tasks.science import load_campaign_runs
    from ..testdesign import separating_run_flag
    try:
        cells, _ = prepare_cells(load_campaign_runs(str(root), lineage))
    except (OSError, ValueError):
        return flags
    from ..config import ConfigError, advice_inputs
    try:
        lab = advice_inputs(None, root / "lab.duckdb")
    except ConfigError:
        lab = {}
    session: dict = {}                    # the pairs of one campaign share the advice's fits
    lines = {ALIASED_PAIR_FLAG.format(a=a, b=b): separating_run_flag(cells, (a, b), session, **lab)
             for a, b in pairs}
    return [lines.get(f) or f for f in flags]


def resolve_result(con, campaign: str | None, result_id: str | None) -> tuple[str, str | None]:
    """(campaign, full result id or None for the current one) from a campaign and/or an id
    prefix; a one-line ReportError says what does not match."""
    if result_id is None:
        if not campaign:
            raise ReportError("give a CAMPAIGN or --result")
        return campaign, None
    rid = result_id.strip().lower()
    if not re.fullmatch(r"[0-9a-f]{4,64}", rid):
        raise ReportError(f"result id {result_id!r} is not a (prefix of a) hexadecimal result id")
    hits = _rows(con, "SELECT result_id, campaign FROM results WHERE starts_with(result_id, ?) "
                      "ORDER BY result_id LIMIT 6", [rid])
    if not hits:
        raise ReportError(f"no result id starts with {rid!r}")
    if len(hits) > 1:
        raise ReportError(f"result id {rid!r} is ambiguous: "
                          + ", ".join(f"{h['result_id'][:16]} ({h['campaign']})" for h in hits[:5]))
    hit = hits[0]
    if campaign and hit["campaign"] != campaign:
        raise ReportError(f"result {hit['result_id'][:12]} is a result of campaign "
                          f"{hit['campaign']!r}, not {campaign!r}")
    return hit["campaign"], hit["result_id"]


def _load(con, campaign: str | None, result_id: str | None, path: Path) -> dict[str, Any]:
    from ..warehouse.extras import extras_root_of, load_extras
    campaign, rid = resolve_result(con, campaign, result_id)
    acts = _rows(con, "SELECT seq, result_id, activated_at, flow_run_id FROM result_activations "
                      "WHERE campaign = ? ORDER BY seq", [campaign])
    cur = _rows(con, "SELECT result_id FROM results_current WHERE campaign = ?", [campaign])
    current = cur[0]["result_id"] if cur else None
    if rid is None:
        if current is None:
            known = [r["campaign"] for r in _rows(
                con, "SELECT DISTINCT campaign FROM results_current ORDER BY campaign LIMIT 20")]
            stored = _rows(con, "SELECT result_id FROM results WHERE campaign = ? "
                                "ORDER BY computed_at DESC LIMIT 1", [campaign])
            if stored:
                raise ReportError(f"campaign {campaign!r} has no current result (simulated data "
                                  f"for a unit with a real calibration); report it with --result "
                                  f"{stored[0]['result_id'][:12]}")
            hint = f" (known: {', '.join(known)})" if known else " (the warehouse holds no results)"
            raise ReportError(f"no result for campaign {campaign!r}{hint}")
        rid = current
    res = _rows(con, "SELECT * FROM results WHERE result_id = ?", [rid])
    r = res[0]
    d: dict[str, Any] = {"campaign": campaign, "result": r, "result_id": rid,
                         "is_current": rid == current, "current_result_id": current,
                         "activations": acts}
    for key in ("tests", "rig_ids", "science_parameters", "parameters", "input_sha256",
                "completeness_reasons"):
        try:
            d[key] = json.loads(r.get(key) or "null")
        except (TypeError, ValueError):
            d[key] = None
    # a file beside the warehouse, its bytes checked against the sha256 (WarehouseError)
    d["extras"] = load_extras(extras_root_of(con, path), r.get("extras_sha256"))
    d["coefficients"] = _rows(con, "SELECT * FROM coefficient_history WHERE result_id = ? "
                                   "ORDER BY seq", [rid])
    d["radii"] = _rows(con, "SELECT * FROM radius_history WHERE result_id = ? ORDER BY seq", [rid])
    d["adequacy"] = _rows(con, "SELECT * FROM adequacy_history WHERE result_id = ? ORDER BY seq",
                          [rid])
    d["budget"] = _rows(con, "SELECT * FROM budget_history WHERE result_id = ? ORDER BY seq", [rid])
    d["alignment"] = [json.loads(a["record"]) for a in _rows(
        con, "SELECT record FROM alignment_history WHERE result_id = ? ORDER BY seq", [rid])]
    d["flags"] = [f["flag"] for f in _rows(
        con, "SELECT flag FROM flag_history WHERE result_id = ? ORDER BY seq", [rid])]
    d["lineage"] = _rows(con, """
        SELECT l.run_id, l.revision, l.sha256, l.source_path, l.parquet_path, l.flow_run_id,
               l.code_version, f.test, f.rig_id, f.started_at, f.size_bytes, f.simulated,
               g.drop_name, g.drop_path
        FROM lineage l
        LEFT JOIN (SELECT source_path, any_value(drop_name) AS drop_name,
                          any_value(drop_path) AS drop_path
                   FROM run_files GROUP BY source_path) g USING (source_path)
        LEFT JOIN (SELECT sha256, any_value(test) AS test, any_value(rig_id) AS rig_id,
                          any_value(started_at) AS started_at, any_value(size_bytes) AS size_bytes,
                          bool_or(simulated) AS simulated
                   FROM run_files GROUP BY sha256) f USING (sha256)
        WHERE l.result_id = ? ORDER BY f.started_at, l.run_id""", [rid])
    ex = _rows(con, "SELECT why, acted_at, acted_by FROM excluded_campaigns WHERE campaign = ?",
               [campaign])
    d["excluded"] = ex[0] if ex else None
    d["audit"] = _rows(con, "SELECT seq, action, why, acted_at, acted_by FROM campaign_actions "
                            "WHERE campaign = ? ORDER BY seq", [campaign])
    return d


def _parse_time(s: str | None) -> _dt.datetime | None:
    try:
        return _dt.datetime.fromisoformat(str(s)) if s else None
    except ValueError:
        return None


def run_conditions(root: Path, lineage: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per input run, from its Parquet copy: when its data were taken (started_at to the
    last reading) and the conditions it logged (temperatures, site).  A run whose copy is
    gone keeps only what the warehouse row says."""
    import numpy as np
    import pyarrow.parquet as pq

    from ..schemas.tables import META_KEY
    out = []
    for x in lineage:
        start = _parse_time(x.get("started_at"))
        row: dict[str, Any] = {"run_id": x.get("run_id"), "test": x.get("test"),
                               "rig_id": x.get("rig_id"), "start": start, "end": None,
                               "data": False}
        pqp = root / x["parquet_path"] if x.get("parquet_path") else None
        if pqp is not None and pqp.is_file():
            try:
                pf = pq.ParquetFile(pqp)
                meta = json.loads((pf.schema_arrow.metadata or {})[META_KEY]).get("meta", {})
                names = set(pf.schema_arrow.names)
                cols = [c for c in ("time_s", "temp_c", "temp_set_c") if c in names]
                # a batch of rows at a time (a long run's columns are never held
                # whole); a run of one batch -- every sample's -- gives np.mean's own mean
                tmax, temps = np.nan, {c: [np.inf, -np.inf, 0.0, 0] for c in cols if c != "time_s"}
                for b in pf.iter_batches(batch_size=1 << 20, columns=cols):
                    tm = b.column(cols.index("time_s")).to_numpy(zero_copy_only=False)
                    tmax = float(np.fmax(tmax, np.nanmax(tm))) if np.isfinite(tm).any() else tmax
                    for c, acc in temps.items():
                        v = b.column(cols.index(c)).to_numpy(zero_copy_only=False).astype(float)
                        v = v[np.isfinite(v)]
                        if v.size:
                            acc[0], acc[1] = min(acc[0], float(v.min())), max(acc[1], float(v.max()))
                            acc[2], acc[3] = acc[2] + float(np.add.reduce(v)), acc[3] + v.size
                row.update(data=True, g_local=meta.get("g_local_m_s2"),
                           latitude=meta.get("site_latitude_deg"),
                           ambient=meta.get("ambient_temp_c"), operator=meta.get("operator"))
                if start is not None and math.isfinite(tmax):
                    row["end"] = start + _dt.timedelta(seconds=tmax)
                for c, (lo, hi, total, n) in temps.items():
                    if n:
                        row[c] = (lo, total / n, hi)
            except Exception as e:      # a damaged copy: say so, keep the certificate
                row["error"] = f"{type(e).__name__}: {e}"[:200]
        out.append(row)
    return out

"""When must each unit come back: ``accelcal due``, ``accelcal history UNIT --html``,
``accelcal campaign adjust``.

Reads a unit's calibrations from the warehouse (``unit_history_as_of``: the adopted values
of complete, real, non-excluded campaigns), the adjustments (``campaign_adjustments``) and
the tolerances of ``accelcal.toml`` (:func:`accelcal.config.forecast_config`), and hands
them to the science, :mod:`accelcal.drift`.  ``due --store`` appends the rows to
``forecast_history``; the view ``recalibration_forecast`` is the latest batch
(``warehouse/drift.sql``).
"""
from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import html
import json
import re
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .. import drift
from ..config import ForecastConfig

SECONDS_PER_YEAR = 86400.0 * drift.YEAR_DAYS

_HISTORY_SQL = """
SELECT h.unit_serial, h.unit_model, h.name, h.quantity, h.factors, h.unit, h.campaign,
       h.calibrated_at, h.value, h.std_uncertainty, h.expanded_uncertainty, h.method,
       h.rig_id, h.result_id, r.code_version, h.calibration_no,
       (SELECT arg_min(f.started_at, TRY_CAST(f.started_at AS TIMESTAMPTZ))
        FROM lineage l JOIN run_files f USING (sha256)
        WHERE l.result_id = h.result_id) AS first_started_at
FROM unit_history_as_of(CAST(? AS TIMESTAMPTZ)) h JOIN results r USING (result_id)
WHERE (CAST(? AS TIMESTAMPTZ) IS NULL OR h.calibrated_at <= CAST(? AS TIMESTAMPTZ))
  AND h.value IS NOT NULL AND h.std_uncertainty > 0
ORDER BY h.unit_serial, h.quantity, h.calibration_no
"""


class DueError(RuntimeError):
    """One line: why the forecast cannot be made (bad option, unknown unit)."""


# ------------------------------------------------------------------ options ----

def parse_as_of(text: str | None) -> dt.datetime | None:
    """``YYYY-MM-DD`` -> the end of that day, UTC (what the warehouse said that day)."""
    if text is None:
        return None
    try:
        d = dt.date.fromisoformat(text)
    except ValueError:
        raise DueError(f"--as-of {text!r}: give a date, YYYY-MM-DD") from None
    return dt.datetime(d.year, d.month, d.day, 23, 59, 59, tzinfo=dt.timezone.utc)


def parse_within(text: str | None) -> int | None:
    """``90d``, ``12w``, ``6m`` (30-day months) or ``1y`` -> days."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*([dwmy]?)\s*", text)
    if not m:
        raise DueError(f"--within {text!r}: give a number of days, weeks, months or years, "
                       "e.g. 90d, 12w, 6m, 1y")
    return int(m.group(1)) * {"": 1, "d": 1, "w": 7, "m": 30, "y": 365}[m.group(2)]


def _years(ts: dt.datetime) -> float:
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=dt.timezone.utc)
    return ts.timestamp() / SECONDS_PER_YEAR


def _date(years: float | None) -> str | None:
    if years is None:
        return None
    return dt.datetime.fromtimestamp(years * SECONDS_PER_YEAR, dt.timezone.utc).date().isoformat()


# ---------------------------------------------------------------- reading ----

def _has_table(con, name: str) -> bool:
    return bool(con.execute("SELECT count(*) FROM information_schema.tables "
                            "WHERE table_name = ?", [name]).fetchall()[0][0])


def load_history(warehouse: str | Path, as_of: dt.datetime | None = None,
                 lock_timeout: float = 60.0) -> tuple[list[dict[str, Any]], set[str]]:
    """The calibrations (unit_history as of ``as_of``, taken up to then) and the
    campaigns marked as adjustments at that time."""
    from ..warehouse import Warehouse, WarehouseError, warehouse_lock
    wh = Warehouse(warehouse, lock_timeout=lock_timeout)
    if not wh.path.exists():
        raise DueError(f"warehouse {wh.path} does not exist")
    try:
        with warehouse_lock(wh.path, timeout=lock_timeout, shared=True), \
                wh.connect(read_only=True) as con:
            cur = con.execute(_HISTORY_SQL, [as_of, as_of, as_of])
            cols = [d[0] for d in cur.description]
            rows = [dict(zip(cols, r)) for r in cur.fetchall()]
            adjusted: set[str] = set()
            if _has_table(con, "campaign_adjustments"):
                adjusted = {r[0] for r in con.execute(
                    "SELECT campaign FROM adjusted_campaigns_as_of(CAST(? AS TIMESTAMPTZ))",
                    [as_of]).fetchall()}
    except WarehouseError as e:
        raise DueError(str(e)) from None
    return rows, adjusted


def _series(rows: list[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """The calibrations of each (unit, quantity): a coefficient's series whether a
    campaign determined it alone or in the combination its design determines."""
    out: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        out.setdefault((r["unit_serial"], r["quantity"]), []).append(r)
    for lst in out.values():
        lst.sort(key=lambda r: (r["calibrated_at"], r["calibration_no"]))
    return out


def _arrays(lst, adjusted):
    t = np.array([_years(r["calibrated_at"]) for r in lst])
    x = np.array([r["value"] for r in lst], float)
    u = np.array([r["std_uncertainty"] for r in lst], float)
    adj = [r["campaign"] in adjusted for r in lst]
    return t, x, u, adj


def compute(rows: list[dict[str, Any]], adjusted: set[str], cfg: ForecastConfig
            ) -> list[tuple[list[dict[str, Any]], drift.Forecast]]:
    """Every series' :class:`accelcal.drift.Forecast`, with the fleet prior of its unit
    model and coefficient (from the other units' current series); series, tolerances and
    the fleet are keyed on the quantity (``K1`` for a row ``K1(Koq,K3)``)."""
    series = _series(rows)
    first = {k: drift.forecast(*_arrays(v, adjusted)[:3], None, cfg.risk,
                               adjusted=_arrays(v, adjusted)[3]) for k, v in series.items()}
    pools: dict[tuple[Any, str], list] = {}
    for (unit, name), lst in series.items():
        t, x, u, _ = _arrays(lst, adjusted)
        s = first[(unit, name)].series_start
        pools.setdefault((lst[-1]["unit_model"], name), []).append((unit, (t[s:], x[s:], u[s:])))
    out = []
    for (unit, name), lst in sorted(series.items()):
        t, x, u, adj = _arrays(lst, adjusted)
        model = lst[-1]["unit_model"]
        # the fleet: the other units of the model (a unit is not its own prior)
        others = [s for uu, s in pools[(model, name)] if uu != unit]
        prior = drift.fleet_prior(others) if others else None
        f = drift.forecast(t, x, u, cfg.tolerance(model, name), cfg.risk, adjusted=adj,
                           prior=prior)
        versions = sorted({r["code_version"] for r in lst[len(lst) - len(f.fit.t):]}
                          if f.fit is not None else {lst[-1]["code_version"]})
        if len(versions) > 1:
            f.basis += ("; mixed code versions (" + ", ".join(versions)
                        + "): reprocess the campaigns with one to be sure a change is the unit's")
        out.append((lst, f))
    return out


def calibration_date(row: dict[str, Any]) -> str:
    """The date the certificate gives the calibration: the day its first run started, in
    the run's own UTC offset (``started_at`` as the DAQ wrote it), not the UTC day."""
    text = row.get("first_started_at")
    if text:
        with contextlib.suppress(ValueError):
            return dt.datetime.fromisoformat(str(text)).date().isoformat()
    return row["calibrated_at"].astimezone(dt.timezone.utc).date().isoformat()


def forecast_row(lst: list[dict[str, Any]], f: drift.Forecast,
                 today: dt.date | None = None) -> dict[str, Any]:
    """The issue's JSON row (plus what the row was computed from); ``overdue``: the due
    date lies before ``today`` (default: today, UTC).  ``coefficient`` is the quantity;
    ``name`` and ``factors`` the row in use (a combination the design determines:
    ``K1(Koq,K3)`` with ``{"Koq": 1.1, "K3": 9.55}``), ``measured`` it as a formula."""
    from ..effects import combination_formula
    last = lst[-1]
    factors = json.loads(last["factors"]) if last.get("factors") else {}
    due = _date(f.due)
    today = today or dt.datetime.now(dt.timezone.utc).date()
    return {
        "unit_serial": last["unit_serial"], "unit_model": last["unit_model"],
        "coefficient": last["quantity"], "n_campaigns": f.n_campaigns,
        "name": last["name"], "factors": factors,
        "measured": combination_formula(last["quantity"], factors),
        "last_calibrated": calibration_date(last),
        "drift_per_year": f.drift_per_year, "u_drift_per_year": f.u_drift_per_year,
        "drift_display": display_rate(last["quantity"], f.drift_per_year, f.u_drift_per_year,
                                      f.value_in_use),
        "due_date": due, "overdue": due is not None and due < today.isoformat(),
        "exit_interval_95": [_date(f.due_interval[0]), _date(f.due_interval[1])],
        "p_out_at_due": f.p_out_at_due, "basis": f.basis,
        "unit": last["unit"], "n_total": f.n_total, "last_campaign": last["campaign"],
        "value_in_use": f.value_in_use, "tolerance": f.tolerance,
        "steps": [{"campaign": lst[s.at]["campaign"], "en": s.en} for s in f.steps],
    }


def due_rows(warehouse: str | Path, cfg: ForecastConfig, as_of: dt.datetime | None = None,
             within_days: int | None = None, lock_timeout: float = 60.0) -> list[dict[str, Any]]:
    """Rows of ``accelcal due``: every unit and coefficient, soonest due first; with
    ``within_days`` only those due by then (overdue included)."""
    rows, adjusted = load_history(warehouse, as_of, lock_timeout)
    ref = (as_of or dt.datetime.now(dt.timezone.utc)).date()
    out = [forecast_row(lst, f, ref) for lst, f in compute(rows, adjusted, cfg)]
    if within_days is not None:
        limit = (ref + dt.timedelta(days=within_days)).isoformat()
        out = [r for r in out if r["due_date"] is not None and r["due_date"] <= limit]
    out.sort(key=lambda r: (r["due_date"] is None, r["due_date"] or "", r["unit_serial"],
                            r["coefficient"]))
    return out


# ---------------------------------------------------------------- writing ----

@contextlib.contextmanager
def _write(warehouse: str | Path, lock_timeout: float):
    """One write transaction (the warehouse lock held) with ``warehouse/drift.sql``
    applied first; a warehouse error is one DueError line."""
    from ..warehouse import Warehouse, WarehouseError
    try:
        with Warehouse(warehouse, lock_timeout=lock_timeout).connect() as con:
            con.execute("BEGIN")
            try:
                con.execute(resources.files("accelcal.warehouse").joinpath("drift.sql").read_text())
                yield con
                con.execute("COMMIT")
            except BaseException:
                con.execute("ROLLBACK")
                raise
    except WarehouseError as e:
        raise DueError(str(e)) from None


def store_forecast(warehouse: str | Path, rows: list[dict[str, Any]], cfg: ForecastConfig,
                   as_of: dt.datetime | None, lock_timeout: float = 60.0) -> int:
    """Append ``rows`` as one batch of ``forecast_history``; returns the batch number."""
    from ..warehouse import code_version
    sha = (hashlib.sha256(cfg.path.read_bytes()).hexdigest()
           if cfg.path is not None and cfg.path.is_file() else None)
    with _write(warehouse, lock_timeout) as con:
        batch = con.execute("SELECT nextval('forecast_batch_seq')").fetchall()[0][0]
        now = dt.datetime.now(dt.timezone.utc)
        cv = code_version()
        for r in rows:
            con.execute(
                "INSERT INTO forecast_history VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                "?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [batch, now, as_of, cv, None if cfg.path is None else str(cfg.path), sha,
                 cfg.risk, r["unit_serial"], r["unit_model"], r["coefficient"],
                 r["unit"], r["n_campaigns"], r["n_total"], r["last_campaign"],
                 r["last_calibrated"], r["value_in_use"], r["tolerance"],
                 r["drift_per_year"], r["u_drift_per_year"], r["due_date"],
                 r["p_out_at_due"], r["basis"], json.dumps(r["steps"])])
    return int(batch)


def set_adjustment(warehouse: str | Path, campaign: str, why: str, by: str | None,
                   undo: bool = False, lock_timeout: float = 60.0) -> dict[str, Any]:
    """Mark a campaign as an adjustment (``undo``: withdraw the mark), appended to
    ``campaign_adjustments`` with who, when and why.  Refused, one line: an unknown
    campaign, no reason, a mark that changes nothing."""
    action = "unadjust" if undo else "adjust"
    if not (why or "").strip():
        raise DueError("give a reason (--why): the audit trail needs one")
    with _write(warehouse, lock_timeout) as con:
        known = con.execute("SELECT count(*) FROM results WHERE campaign = ?",
                            [campaign]).fetchall()[0][0]
        if not known:
            raise DueError(f"no campaign {campaign!r} in warehouse {warehouse}")
        last = con.execute("SELECT action, acted_at, acted_by, why FROM "
                           "campaign_adjustments WHERE campaign = ? ORDER BY seq DESC "
                           "LIMIT 1", [campaign]).fetchall()
        state = last[0][0] if last else "unadjust"
        if state == action:
            since = (f" since {last[0][1]:%Y-%m-%d %H:%M} by {last[0][2] or '?'}: "
                     f"{last[0][3]}" if last else "")
            raise DueError(f"campaign {campaign!r} is "
                           f"{'already' if last else 'not'} marked as an adjustment"
                           f"{since}; nothing recorded")
        row = con.execute(
            "INSERT INTO campaign_adjustments VALUES "
            "(nextval('campaign_adjustment_seq'), ?, ?, ?, now(), ?) "
            "RETURNING seq, acted_at", [campaign, action, why.strip(), by]).fetchall()
    return {"seq": row[0][0], "acted_at": row[0][1], "campaign": campaign, "action": action,
            "why": why.strip(), "by": by}


# ------------------------------------------------------------------- display ----

def display_scale(name: str, value_in_use: float | None) -> tuple[float, str | None]:
    """(SI per display unit, display unit) of a coefficient's changes, from the catalogue
    (:func:`accelcal.effects.coefficient_spec`; a combination takes its first term's): K1
    in ppm of the value in use, the others in their display unit (µg, µrad, °, ...);
    (1, None) for a name the catalogue does not know (its SI unit stays)."""
    from ..effects import PRETTY_UNITS, coefficient_spec
    spec = coefficient_spec(name)
    if spec is not None and spec.name == "K1" and value_in_use:
        return abs(value_in_use) * 1e-6, "ppm"
    if spec is not None:
        return spec.display_factor, PRETTY_UNITS.get(spec.display_unit, spec.display_unit)
    return 1.0, None


def display_rate(name: str, rate: float | None, u_rate: float | None,
                 value_in_use: float, si_unit: str | None = None) -> str:
    """Drift rate ± u per year in display units, GUM-rounded (u to two digits):
    ``20 ± 1.3 ppm/a``, ``0.52 ± 0.10 µg/a``."""
    from ..rounding import round_gum
    if rate is None:
        return "—"
    f, unit = display_scale(name, value_in_use)
    unit = unit or si_unit or "(SI unit)"
    r = round_gum(rate / f, None if u_rate is None else u_rate / f)
    if u_rate is None:
        return f"{r.value} {unit}/a"
    return f"{r.value} ± {r.uncertainty} {unit}/a"


def text_lines(rows: list[dict[str, Any]], today: dt.date | None = None,
               width: int = 80) -> list[str]:
    """``accelcal due`` for people, ``width`` columns: per unit and coefficient a line
    with the full names and the due date (OVERDUE when before ``today``), then the drift
    rate in display units, the last calibration's date and the basis, wrapped (never
    cut)."""
    import textwrap

    from ..rounding import format_sig
    today_s = (today or dt.datetime.now(dt.timezone.utc).date()).isoformat()
    wrap = dict(width=width, break_on_hyphens=False)
    out: list[str] = []
    for r in rows:
        due = r["due_date"]
        when = ("no due date" if due is None else
                f"due {due}" + (f" OVERDUE (as of {today_s})" if due < today_s else ""))
        lo, hi = r.get("exit_interval_95") or (None, None)
        if lo is not None:
            when += (f"; out of tolerance between {lo} and {hi}" if hi else
                     f"; out of tolerance from {lo} on") + " (95\u00a0%)"
        what = r["coefficient"] + (f" (as {r['measured']}, the combination the design "
                                   "determines)" if r.get("factors") else "")
        out += textwrap.wrap(f"{r['unit_serial']}  {what}  {when}",
                             subsequent_indent="    ", **wrap)
        rate = display_rate(r["coefficient"], r["drift_per_year"], r["u_drift_per_year"],
                            r["value_in_use"], r.get("unit"))
        p = "" if r["p_out_at_due"] is None else \
            f"; P(out of tolerance) {format_sig(r['p_out_at_due'])} at due"
        out += textwrap.wrap(f"drift {rate} (u, k = 1); {r['n_campaigns']} calibration(s), "
                             f"last {r['last_calibrated']}{p}; {r['basis']}.",
                             initial_indent="    ", subsequent_indent="    ", **wrap)
    return out


# --------------------------------------------------------------- certificate ----

def certificate_due_statement(warehouse: str | Path, unit_serial: str, campaign: str,
                              config: str | Path | None = None) -> str | None:
    """The certificate's due-date sentence for the unit (``[certificate] state_due_date``;
    None when the lab has not agreed to state one).  The date is the earliest due date
    of the unit's coefficients that have a tolerance, from the history up to and with
    this campaign."""
    from ..config import forecast_config
    cfg = forecast_config(config, warehouse)
    if not cfg.state_due_date:
        return None
    rows, adjusted = load_history(warehouse)
    mine = [r for r in rows if r["unit_serial"] == unit_serial]
    stop = {}
    for r in mine:
        if r["campaign"] == campaign:
            stop[r["quantity"]] = r["calibration_no"]
    mine = [r for r in mine
            if r["quantity"] in stop and r["calibration_no"] <= stop[r["quantity"]]]
    # the fleet prior needs the other units: keep their rows as they are
    fc = compute([r for r in rows if r["unit_serial"] != unit_serial] + mine, adjusted, cfg)
    dated = [(f.due, _measured(lst[-1]), f.basis) for lst, f in fc
             if lst[-1]["unit_serial"] == unit_serial and f.due is not None]
    if not dated:
        bases = sorted({f.basis.split(";")[0] for lst, f in fc
                        if lst[-1]["unit_serial"] == unit_serial})
        return drift.due_date_statement(None, "; ".join(bases) or "no calibration history",
                                        cfg.risk, True)
    due, name, basis = min(dated)
    return drift.due_date_statement(_date(due), f"{name}, {basis}", cfg.risk, True)


def _measured(row: dict[str, Any]) -> str:
    """A history row's quantity, with the combination it was measured as, if one."""
    from ..effects import combination_formula
    if not row.get("factors"):
        return row["quantity"]
    return f"{row['quantity']} (as {combination_formula(row['quantity'], json.loads(row['factors']))})"


# ---------------------------------------------------------------- history ----

def _chart(lst, f: drift.Forecast, en: np.ndarray, today: float) -> str:
    """One control chart (base64 PNG) in the certificate's display units
    (:func:`display_scale`; K1 in ppm from the value in use): value ± U per campaign, the
    drift line with its 95 % prediction band (a new campaign's value), the value in use
    and the tolerance band around it, the due date (marked overdue when before ``today``
    [a]; explained when it is the day of the last calibration), En between consecutive
    campaigns.  Every line is in a legend; the axes carry no offset or power of ten."""
    from .plots import _plt, _png
    plt = _plt()
    name = lst[-1]["quantity"]
    scale, unit = display_scale(name, f.value_in_use)
    unit = unit or lst[-1]["unit"] or "SI unit"
    ppm = unit == "ppm"
    off = f.value_in_use if ppm else 0.0
    ylabel = f"{name} - value in use [ppm]" if ppm else f"{name} [{unit}]"
    tt = np.array([_years(r["calibrated_at"]) for r in lst])
    x = (np.array([r["value"] for r in lst]) - off) / scale
    U = np.array([r["expanded_uncertainty"] for r in lst]) / scale
    def yr(y):       # years since 1970 [a] -> dates on the axis
        return np.array([dt.datetime.fromtimestamp(float(v) * SECONDS_PER_YEAR, dt.timezone.utc)
                         .replace(tzinfo=None) for v in np.atleast_1d(y)], dtype="datetime64[s]")
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8.4, 5.8), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 1]})
    end = max(tt[-1] + 1.0, (f.due + 0.5) if f.due is not None else tt[-1] + 2.0, today + 0.25)
    end = min(end, tt[-1] + 5.0)
    if f.predict is not None:
        start = tt[f.series_start] if f.fit is None else min(tt[f.series_start], tt[-1])
        grid = np.linspace(start, end, 200)
        m, s, nu = f.predict(grid)
        lo, hi = f.interval(grid, u_new=float(np.mean(f.fit.u)) if f.fit is not None else 0.0)
        ax.fill_between(yr(grid), (lo - off) / scale, (hi - off) / scale, color="#cfe3f5",
                        label="95 % prediction band (next campaign)")
        ax.plot(yr(grid), (m - off) / scale, color="#1f5fa0", lw=1.2, label="drift line")
    if f.tolerance is not None:
        for sgn in (-1, 1):
            ax.axhline((f.value_in_use + sgn * f.tolerance - off) / scale, color="#b03030",
                       lw=0.9, ls="--", label="tolerance around the value in use" if sgn > 0 else None)
    ax.axhline((f.value_in_use - off) / scale, color="#b03030", lw=0.6,
               label="value in use (last calibration)")
    old = np.arange(len(lst)) < f.series_start
    ax.errorbar(yr(tt[~old]), x[~old], U[~old], fmt="o", color="#222", ms=4, capsize=3,
                label="calibration ± U (k = 2)")
    if old.any():
        ax.errorbar(yr(tt[old]), x[old], U[old], fmt="o", color="#999", ms=4, capsize=3,
                    mfc="white", label="earlier series")
    for k, st in enumerate(f.steps):
        ax.axvline(yr(tt[st.at])[0], color="#d08000", lw=1, ls=":",
                   label="flagged step" if k == 0 else None)
    if f.series_start and not any(st.at == f.series_start for st in f.steps):
        ax.axvline(yr(tt[f.series_start])[0], color="#666", lw=1, ls="-.", label="adjustment")
    notes = []
    if f.due is not None:
        overdue = f.due < today
        ax.axvline(yr(f.due)[0], color="#b03030", lw=1.4,
                   label=f"due {_date(f.due)}" + (" (OVERDUE)" if overdue else ""))
        if f.due - f.t_last < 1.5 / drift.YEAR_DAYS:
            notes.append("due at calibration: the value in use is already too uncertain for "
                         "its tolerance at the lab's risk")
        if overdue:
            notes.append(f"OVERDUE: the due date is before {_date(today)}")
    elif f.tolerance is not None and f.predict is not None:
        notes.append(f"not due within {drift.HORIZON_YEARS:g} years")
    ax.axvline(yr(today)[0], color="#555", lw=0.8, ls=(0, (1, 3)), label=f"as of {_date(today)}")
    for k, text in enumerate(notes):
        ax.text(0.01, 0.02 + 0.07 * k, text, transform=ax.transAxes, fontsize=8,
                color="#b03030", ha="left", va="bottom",
                bbox={"fc": "white", "ec": "#b03030", "pad": 2})
    ax.set_xlim(yr(min(tt[0], today) - 0.25)[0], yr(end)[0])
    ax.set_ylabel(ylabel, fontsize=8)
    ax.ticklabel_format(axis="y", style="plain", useOffset=False)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    if len(en):
        mid = yr((tt[1:] + tt[:-1]) / 2)
        ax2.bar(mid, en, width=np.timedelta64(int(0.02 * (end - tt[0] + 0.25) * 365.25), "D"),
                color=["#b03030" if abs(e) > 1 else "#1f5fa0" for e in en],
                label="En of consecutive calibrations")
        ax2.axhline(1, color="#888", lw=0.6, ls="--", label="|En| = 1")
        ax2.axhline(-1, color="#888", lw=0.6, ls="--")
        ax2.axhline(0, color="#444", lw=0.6)
        ax2.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    else:
        ax2.text(0.5, 0.5, "one calibration: no En between consecutive calibrations yet",
                 transform=ax2.transAxes, fontsize=8, ha="center", va="center", color="#555")
        ax2.set_yticks([])
    ax2.set_ylabel("En consecutive", fontsize=8)
    ax2.set_xlabel("date", fontsize=8)
    ax2.tick_params(labelsize=7)
    fig.tight_layout()
    return _png(fig)


def history_html(warehouse: str | Path, unit_serial: str, out_dir: str | Path,
                 cfg: ForecastConfig, as_of: dt.datetime | None = None,
                 lock_timeout: float = 60.0) -> Path:
    """``accelcal history UNIT --html DIR``: one control chart per coefficient; returns
    the page's path (``DIR/<unit>-history.html``)."""
    from ..fileio import atomic_write
    from ..rounding import format_sig
    rows, adjusted = load_history(warehouse, as_of, lock_timeout)
    fc = [(lst, f) for lst, f in compute(rows, adjusted, cfg)
          if lst[-1]["unit_serial"] == unit_serial]
    if not fc:
        raise DueError(f"no calibrations of unit {unit_serial!r} in warehouse {warehouse}"
                       + ("" if as_of is None else f" as of {as_of:%Y-%m-%d}"))
    e = html.escape
    parts = [f"<h1>Recalibration history of {e(unit_serial)}</h1>",
             f"<p>Unit model {e(str(fc[0][0][-1]['unit_model']))}; due when the probability of "
             f"being out of tolerance reaches {cfg.risk * 100:g} %; as of "
             f"{e(as_of.date().isoformat() if as_of else 'now')}; tolerances from "
             f"{e(str(cfg.path) if cfg.path else 'no config file')}.</p>"]
    ref = (as_of or dt.datetime.now(dt.timezone.utc))
    for lst, f in fc:
        r = forecast_row(lst, f, ref.date())
        en = drift.en_consecutive([q["value"] for q in lst],
                                  [q["expanded_uncertainty"] for q in lst])
        steps = ", ".join(f"{s['campaign']} (En {format_sig(s['en'])})" for s in r["steps"])
        parts.append(
            f"<h2>{e(r['coefficient'])}</h2>"
            + (f"<p>Measured as {e(r['measured'])} ({e(r['name'])}): the combination its "
               "design determines.</p>" if r["factors"] else "")
            + f"<p>due <b>{e(r['due_date'] or '—')}</b>"
            + (" <b class='overdue'>OVERDUE</b>" if r["overdue"] else "")
            + f"; last calibrated {e(r['last_calibrated'])}; drift {e(r['drift_display'])}"
            + (" (u, k = 1)" if r["drift_per_year"] is not None else "")
            + f"; {r['n_campaigns']} of {r['n_total']} calibrations in the current "
            f"series; {e(r['basis'])}." + (f" Steps flagged: {e(steps)}." if steps else "")
            + f"</p><img alt='{e(r['coefficient'])} control chart' "
            f"src='data:image/png;base64,{_chart(lst, f, en, _years(ref))}'>")
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>"
            f"{e(unit_serial)} history</title><style>body{{font-family:sans-serif;"
            "max-width:960px;margin:2em auto;font-size:14px}}img{{width:100%}}"
            ".overdue{{color:#b03030}}</style></head>"
            "<body>" + "\n".join(parts) + "</body></html>")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", unit_serial)
    path = out / f"{safe}-history.html"
    atomic_write(path, lambda fh: fh.write(page), "w", encoding="utf-8")
    return path

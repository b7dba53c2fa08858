"""``accelcal sql "SELECT ..." --warehouse W``: read the warehouse without getting in a run's way.

The query runs on a read-only connection while holding the warehouse lock *shared*:
readers wait for a run that is writing (up to ``--lock-timeout``, as a second run would),
many readers go together, and a run waits for the readers before it starts -- never
half-way through, so a long query cannot make a run fail.  ``--snapshot`` reads the copy
each run publishes (``<stem>-snapshot.duckdb``) instead: no lock, no waiting, the state
after the last run that changed something.

Output: a table (at most ``--max-rows`` rows shown) or, with ``--csv``, every row as CSV.
Every value is printed as text (accelcal.textout), never as markup.  The table is for
people: a coefficient's value and the columns in its unit are shown in its display unit
(effects.md), rounded to the last digit of its expanded uncertainty (GUM 7.2.6,
:func:`accelcal.rounding.round_gum`), uncertainties to two significant digits, other
numbers to four, times to the minute (UTC), long text cut with "…"; when the columns do
not fit the terminal, each row is printed as ``column: value`` lines.  ``--raw`` prints
the stored SI floats in full (as ``--csv`` always does).
"""
from __future__ import annotations

import os


def register(sub) -> None:
    p = sub.add_parser(
        "sql", help="run a read-only SQL query on the warehouse (waits for a running pipeline)",
        description="Run SQL on the warehouse, read-only.  Waits (up to --lock-timeout) for a "
                    "run that is writing, like a second run would; --snapshot reads the "
                    "read-only copy the last run published instead, without waiting.")
    p.add_argument("query", help='SQL, e.g. "SELECT * FROM unit_history LIMIT 5"')
    p.add_argument("--warehouse", "-w", default=os.environ.get("ACCELCAL_WAREHOUSE", "lab.duckdb"))
    p.add_argument("--csv", action="store_true", help="print every row as CSV (with a header)")
    p.add_argument("--raw", action="store_true",
                   help="the table with the stored values (SI, full precision), not display units")
    p.add_argument("--snapshot", action="store_true",
                   help="read <warehouse>-snapshot.duckdb (no lock; as of the last run)")
    p.add_argument("--max-rows", type=int, default=200, metavar="N",
                   help="rows shown in the table (default 200; --csv prints all)")
    p.add_argument("--lock-timeout", type=float, default=60.0, metavar="S",
                   help="wait this long for a run holding the warehouse (default 60 s)")
    p.set_defaults(func=_cmd_sql)


def _fail(msg: str):
    from ..cli import CliError
    raise CliError(msg)


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _cmd_sql(args) -> int:
    import contextlib

    import duckdb

    from ..warehouse.db import Warehouse
    from ..warehouse.errors import WarehouseBusy, WarehouseError
    from ..warehouse.lock import warehouse_lock
    wh = Warehouse(args.warehouse, lock_timeout=args.lock_timeout)
    path = wh.snapshot_path if args.snapshot else wh.path
    if not path.exists():
        _fail(f"{'snapshot' if args.snapshot else 'warehouse'} {path} does not exist"
              + (" (a run publishes it)" if args.snapshot else ""))
    try:
        lock = contextlib.nullcontext() if args.snapshot else \
            warehouse_lock(wh.path, timeout=args.lock_timeout, shared=True)
        with lock:
            wh.check_duckdb_file(path)
            con = wh._open(read_only=True, path=path)
            try:
                try:
                    cur = con.execute(args.query)
                except duckdb.Error as e:
                    _fail(f"SQL: {' '.join(str(e).split())[:300]}")
                if cur.description is None:
                    return 0
                cols = [d[0] for d in cur.description]
                if args.csv:
                    _print_csv(cur, cols)
                    return 0
                rows = cur.fetchmany(max(args.max_rows, 0) + 1)
            finally:
                con.close()
    except WarehouseBusy as e:
        _fail(f"{e}; --snapshot reads the copy the last run published, without waiting")
    except WarehouseError as e:
        _fail(str(e))
    if args.raw:
        shown = [[_cell(v) for v in r] for r in rows]
    else:
        shown = display_rows(cols, rows)
        cols = [SHORT.get(c, c) for c in cols]
    _print_table(cols, shown, args.max_rows)
    return 0


def _print_csv(cur, cols) -> None:
    import csv
    import sys

    from ..textout import plain
    w = csv.writer(sys.stdout, lineterminator="\n")
    w.writerow([plain(c) for c in cols])
    while True:
        rows = cur.fetchmany(10000)
        if not rows:
            break
        # CSV quotes what needs quoting; plain() keeps each value one line of text
        w.writerows([[plain(_cell(v)) for v in r] for r in rows])


#: Columns in the unit of the row's coefficient (``name``), shown in its display unit and
#: rounded to the last digit of its U.
SAME_UNIT = frozenset({"value", "change", "mean", "sd", "median", "mad", "robust_sd", "lcl", "ucl",
                       "min", "max", "mean_minus_3sd", "mean_plus_3sd", "reference_value",
                       "difference", "prev_value", "value_in_use"})
#: Uncertainties in that unit: two significant digits.
UNCERTAINTY = frozenset({"std_uncertainty", "expanded_uncertainty", "mean_expanded_uncertainty",
                         "u_change", "expanded_uncertainty_change"})
#: Headers people know by their symbol (display mode).
SHORT = {"expanded_uncertainty": "U", "std_uncertainty": "u", "coverage_factor": "k"}
#: Longest text shown in a table cell [characters].
TEXT_MAX = 40


def display_rows(cols: list[str], rows: list[tuple]) -> list[list[str]]:
    """Rows as people read them (module docstring): display units, GUM rounding.

    Parameters
    ----------
    cols : list of str
        Column names of the result.
    rows : list of tuple
        The rows as DuckDB returns them (SI values).

    Returns
    -------
    list of list of str
    """
    import datetime as dt
    import math

    from ..effects import coefficient_spec, to_display
    from ..rounding import format_sig, round_gum
    at = {c: i for i, c in enumerate(cols)}
    out = []
    for r in rows:
        cells = [_plain_cell(v, dt) for v in r]
        name = r[at["name"]] if "name" in at else None
        spec = coefficient_spec(name) if isinstance(name, str) else None
        if spec is not None:
            unit = r[at["unit"]] if "unit" in at and isinstance(r[at["unit"]], str) else spec.unit
            k = r[at["coverage_factor"]] if "coverage_factor" in at else None
            k = float(k) if isinstance(k, (int, float)) and math.isfinite(k) and k > 0 else 2.0
            U = _first_float(r, at, ("expanded_uncertainty", "mean_expanded_uncertainty"))
            if U is None:
                u = _first_float(r, at, ("std_uncertainty",))
                U = None if u is None else k * u
            ref = _first_float(r, at, ("value", "mean", "median")) or 1.0
            _, U_disp, dunit, ppm = to_display(spec.name, ref, None if U is None else U / k, unit, k)
            factor = ref / _display_value(spec.name, ref, unit, k) if ref else 1.0
            U_abs = None if U is None else U / factor       # U in the display unit
            for c, i in at.items():
                v = r[i]
                if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                    continue
                # without a unit column the unit goes with the number
                tail = "" if "unit" in at else f" {dunit}"
                if c in SAME_UNIT:
                    cells[i] = round_gum(v / factor, U_abs, fallback_sig=4).value + tail
                elif c in UNCERTAINTY:
                    if ppm and ref:
                        cells[i] = f"{format_sig(v / abs(ref) * 1e6)} ppm"
                    else:
                        cells[i] = format_sig(v / factor) + tail
            if "unit" in at:
                cells[at["unit"]] = dunit
        out.append(cells)
    return out


def _display_value(name: str, value: float, unit: str, k: float) -> float:
    from ..effects import to_display
    return to_display(name, value, None, unit, k)[0]


def _first_float(r, at, names) -> float | None:
    import math
    for n in names:
        if n in at:
            v = r[at[n]]
            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0:
                return float(v)
    return None


def _plain_cell(v, dt) -> str:
    """A value with no coefficient to follow: 4 significant digits, times to the minute."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return format(v, ".4g")
    if isinstance(v, dt.datetime):
        if v.tzinfo is not None:
            v = v.astimezone(dt.timezone.utc)
        return v.strftime("%Y-%m-%d %H:%M")
    text = str(v)
    return text if len(text) <= TEXT_MAX else text[:TEXT_MAX - 1] + "…"


def _print_table(cols, rows, max_rows: int) -> None:
    """A table, or rows as ``column: value`` lines when it is wider than the terminal."""
    from rich.table import Table

    from ..textout import console, esc
    con = console()
    shown = rows[:max_rows]
    widths = [max([len(c)] + [len(x) for x in (r[i] for r in shown)]) for i, c in enumerate(cols)]
    # rich draws a cell as " x " and a rule between cells
    if shown and sum(widths) + 3 * len(cols) + 1 > con.width:
        pad = max(len(c) for c in cols)
        for n, r in enumerate(shown, 1):
            con.print(esc(f"-- row {n} " + "-" * max(0, min(con.width, 40) - 8 - len(str(n)))))
            for c, x in zip(cols, r):
                con.print(esc(f"{c:>{pad}}  {x}", 400), overflow="fold")
    else:
        t = Table(show_edge=False)
        for c in cols:
            t.add_column(esc(c, 60), overflow="fold")
        for r in shown:
            t.add_row(*(esc(x, 200) for x in r))
        con.print(t)
    more = "" if len(rows) <= max_rows else f" (first {max_rows} shown; --csv prints all)"
    con.print(f"{len(shown)} row(s){more}")

"""``accelcal sql "SELECT ..." --warehouse W``: read the warehouse without getting in a run's way.

The query runs on a read-only connection while holding the warehouse lock *shared*:
readers wait for a run that is writing (up to ``--lock-timeout``, as a second run would),
many readers go together, and a run waits for the readers before it starts -- never
half-way through, so a long query cannot make a run fail.  ``--snapshot`` reads the copy
each run publishes (``<stem>-snapshot.duckdb``) instead: no lock, no waiting, the state
after the last run that changed something.

Output: a table (at most ``--max-rows`` rows shown) or, with ``--csv``, every row as CSV.
Every value is printed as text (accelcal.textout), never as markup.
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

    from ..warehouse.db import Warehouse, WarehouseBusy, WarehouseError, warehouse_lock
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
    _print_table(cols, rows, args.max_rows)
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


def _print_table(cols, rows, max_rows: int) -> None:
    from rich.table import Table

    from ..textout import console, esc
    con = console()
    t = Table(show_edge=False)
    for c in cols:
        t.add_column(esc(c, 60), overflow="fold")
    for r in rows[:max_rows]:
        t.add_row(*(esc(_cell(v), 200) for v in r))
    con.print(t)
    more = "" if len(rows) <= max_rows else f" (first {max_rows} shown; --csv prints all)"
    con.print(f"{min(len(rows), max_rows)} row(s){more}")

"""CLI for operations: ``accelcal serve`` and ``accelcal report``.

``register_cli(subparsers)`` (alias ``register``) adds both sub-commands; heavy
imports happen only when a command runs.
"""
from __future__ import annotations

import os
import sys


def _default_warehouse() -> str:
    return os.environ.get("ACCELCAL_WAREHOUSE", "lab.duckdb")


def register_cli(sub) -> None:
    p = sub.add_parser(
        "serve", help="process new drops of a folder on a schedule and when files appear",
        description="Serve the accelcal-watch Prefect deployment from this process: every pass "
                    "processes the settled new drops of --watch into the warehouse (a drop with "
                    "a *.part or a growing file waits for the next pass).  Schedules need a "
                    "Prefect server: set PREFECT_API_URL (see accelcal/warehouse/README.md).")
    p.add_argument("--watch", required=True, metavar="DIR", help="folder whose sub-folders are drops")
    p.add_argument("--warehouse", "-w", default=_default_warehouse(),
                   help="DuckDB warehouse file (default: $ACCELCAL_WAREHOUSE or ./lab.duckdb)")
    p.add_argument("--cron", default=None, help='cron schedule of passes, e.g. "0 2 * * *"')
    p.add_argument("--poll", type=float, default=None, metavar="SECONDS",
                   help="also watch the folder every SECONDS and trigger a pass when files "
                        "appear or change")
    p.add_argument("--settle", type=float, default=30.0, metavar="SECONDS",
                   help="a file first seen unchanged for this long counts as complete (default 30)")
    p.add_argument("--name", default="accelcal-watch", help="deployment name")
    p.add_argument("--task-runner", choices=("thread", "dask"), default="thread")
    p.add_argument("--lock-timeout", type=float, default=600.0, metavar="S")
    p.add_argument("--once", action="store_true",
                   help="run one pass in this process (no Prefect server, local engine) and exit")
    p.set_defaults(func=_cmd_serve)

    r = sub.add_parser(
        "report", help="write a self-contained HTML calibration report for a campaign",
        description="Certificate-style HTML report of a campaign's current (or given) result: "
                    "coefficients with U (k=2) in display units, adequacy, alignment, plots, "
                    "lineage.")
    r.add_argument("campaign", nargs="?", help="campaign label (omit with --all)")
    r.add_argument("--out", required=True, metavar="DIR", help="output folder")
    r.add_argument("--warehouse", "-w", default=_default_warehouse())
    r.add_argument("--result", default=None, metavar="RESULT_ID",
                   help="report this (possibly superseded) result instead of the current one")
    r.add_argument("--all", action="store_true", help="one report per campaign in the warehouse")
    r.add_argument("--lock-timeout", type=float, default=60.0, metavar="S")
    r.set_defaults(func=_cmd_report)


register = register_cli


def _fail(msg: str):
    try:
        from ..cli import CliError
    except ImportError:  # pragma: no cover
        CliError = RuntimeError
    raise CliError(msg)


def _cmd_report(args) -> int:
    from .report import ReportError, build_report, list_campaigns
    if not args.campaign and not args.all:
        _fail("give a CAMPAIGN or --all")
    try:
        camps = list_campaigns(args.warehouse) if args.all else [args.campaign]
        for c in camps:
            path = build_report(args.warehouse, c, args.out, result_id=args.result,
                                lock_timeout=args.lock_timeout)
            print(path)
    except ReportError as e:
        _fail(str(e))
    except Exception as e:
        if type(e).__module__.startswith("duckdb"):
            _fail(f"cannot read warehouse {args.warehouse}: {str(e).splitlines()[0]}")
        raise
    return 0


def _cmd_serve(args) -> int:
    import logging
    from ..flows.pipeline import quiet_prefect
    quiet_prefect("WARNING")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    for noisy in ("httpx", "httpcore"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    from pathlib import Path
    if not Path(args.watch).expanduser().is_dir():
        _fail(f"watch folder {args.watch} does not exist")
    if args.once:
        import json

        from .serve import watch_pass
        out = watch_pass(args.watch, args.warehouse, settle=args.settle, engine="local",
                         lock_timeout=args.lock_timeout)
        print(json.dumps(out, indent=1, default=str))
        return 1 if out.get("error") else 0
    if not args.cron and not args.poll:
        _fail("give --cron and/or --poll (or --once)")
    from .serve import serve
    try:
        serve(args.watch, args.warehouse, cron=args.cron, poll=args.poll, settle=args.settle,
              name=args.name, lock_timeout=args.lock_timeout, task_runner=args.task_runner)
    except KeyboardInterrupt:
        print("accelcal serve: stopped", file=sys.stderr)
    return 0

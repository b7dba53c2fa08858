"""CLI for operations: ``accelcal serve``, ``report``, ``verify``, ``campaign``, ``status``
and ``migrate``.

``register_cli(subparsers)`` (alias ``register``) adds the sub-commands; heavy
imports happen only when a command runs.  Text that comes from files (campaign labels,
run ids, reasons) is printed through :func:`accelcal.cli.say`, escaped.
"""
from __future__ import annotations

import sys

from ..config import default_warehouse


def register_cli(sub) -> None:
    p = sub.add_parser(
        "serve", help="process new drops of a folder on a schedule and when files appear",
        description="Serve the accelcal-watch Prefect deployment from this process: every pass "
                    "processes the settled new drops of --watch into the warehouse (a drop with "
                    "a *.part or a growing file waits for the next pass).  Schedules need a "
                    "Prefect server: set PREFECT_API_URL (see accelcal/warehouse/README.md).")
    p.add_argument("--watch", required=True, metavar="DIR", help="folder whose sub-folders are drops")
    p.add_argument("--warehouse", "-w", default=default_warehouse(),
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
    p.add_argument("--part-stale", type=float, default=3600.0, metavar="SECONDS",
                   help="a *.part file unchanged this long is a stopped copy: logged once, and "
                        "the rest of its drop goes ahead (default 3600)")
    p.add_argument("--once", action="store_true",
                   help="run one pass in this process (no Prefect server, local engine) and exit")
    p.add_argument("--json", action="store_true", help="with --once: print the pass record as JSON")
    p.set_defaults(func=_cmd_serve)

    r = sub.add_parser(
        "report", help="write the calibration certificate (HTML, and PDF with --pdf) of a campaign",
        description="Calibration certificate of a campaign's current (or given) result, with what "
                    "ISO/IEC 17025 7.8.2-7.8.4 asks: certificate number, lab, item, method, dates "
                    "and conditions from the data, traceability, adopted values with U (k=2), "
                    "budgets, Monte Carlo check, adequacy and residuals, lineage. Lab facts come "
                    "from accelcal.toml (--config, else ./accelcal.toml, else beside the "
                    "warehouse); missing ones are marked placeholders.")
    r.add_argument("campaign", nargs="?", help="campaign label (omit with --all or --result)")
    r.add_argument("--out", required=True, metavar="DIR", help="output folder")
    r.add_argument("--warehouse", "-w", default=default_warehouse())
    r.add_argument("--result", default=None, metavar="RESULT_ID",
                   help="report this (possibly superseded) result; the short id the CLI prints "
                        "is enough")
    r.add_argument("--all", action="store_true", help="one report per campaign in the warehouse")
    r.add_argument("--pdf", action="store_true",
                   help="also print the certificate to PDF with headless chromium")
    r.add_argument("--config", default=None, metavar="TOML",
                   help="the lab's accelcal.toml (default: ./accelcal.toml, then beside the "
                        "warehouse)")
    r.add_argument("--customer", default=None, help="customer name and address for this certificate")
    r.add_argument("--dcc", action="store_true",
                   help="also write the PTB Digital Calibration Certificate (XML, DCC 3.3.0) beside "
                        "it, validated against the shipped schema and PTB's Schematron rules; a "
                        "final one is signed with [dcc] key_file and cert_file of accelcal.toml "
                        "when set, a DRAFT never")
    r.add_argument("--sign", action="store_true",
                   help="with --dcc: the DCC must be signed; refused (one line) for a DRAFT or "
                        "without [dcc] key_file and cert_file")
    r.add_argument("--lock-timeout", type=float, default=60.0, metavar="S")
    r.set_defaults(func=_cmd_report)

    v = sub.add_parser(
        "verify", help="check a DCC file: schema, PTB's rules, status and signature",
        description="Validate a Digital Calibration Certificate (XML) against the schema of its "
                    "schemaVersion shipped with accelcal and PTB's Schematron rules (dcclib; no "
                    "network), print its status (final, DRAFT, INCOMPLETE, SIMULATED, EXCLUDED, "
                    "NOT CURRENT) and, if it carries an XML-DSig signature, verify it with the "
                    "lab's certificate (--cert, else [dcc] cert_file of accelcal.toml). Exit 0: "
                    "valid, final and signed; 1: invalid (XSD, PTB's rules or signature fail; one "
                    "line); 4: valid but not a final certificate (DRAFT, INCOMPLETE, ...); 5: "
                    "valid and final but not signed.")
    v.add_argument("file", metavar="FILE", help="the DCC XML file")
    v.add_argument("--cert", default=None, metavar="PEM",
                   help="the signer's X.509 certificate (PEM) to check the signature with")
    v.add_argument("--config", default=None, metavar="TOML",
                   help="accelcal.toml whose [dcc] cert_file to use (default: ./accelcal.toml)")
    v.set_defaults(func=_cmd_verify)

    st = sub.add_parser(
        "status", help="the last passes of `accelcal serve` and what waits",
        description="What the scheduled processing did and what it waits for: the last passes "
                    "(drops seen, processed, held back and why, refusals, results), the drops "
                    "held back at the last pass and the files seen but not processed. Read from "
                    "<warehouse>-watch.json, so it answers while a pass holds the warehouse.")
    st.add_argument("--warehouse", "-w", default=default_warehouse())
    st.add_argument("--passes", type=int, default=5, metavar="N", help="how many passes (default 5)")
    st.add_argument("--watch", default=None, metavar="DIR",
                    help="also look at the watched folder now (records nothing)")
    st.add_argument("--settle", type=float, default=30.0, metavar="SECONDS")
    st.add_argument("--part-stale", type=float, default=3600.0, metavar="SECONDS")
    st.set_defaults(func=_cmd_status)

    c = sub.add_parser(
        "campaign", help="list campaigns; exclude or include one (audit-trailed quarantine)",
        description="Campaigns and what keeps them out of history, En and the fleet views: "
                    "incomplete (not enough runs), simulated, or excluded by an operator. "
                    "exclude/include append to an audit trail (who, when, why); nothing is "
                    "deleted.")
    csub = c.add_subparsers(dest="action", metavar="ACTION")
    csub.required = True
    for name, hlp in (("list", "every campaign's current result and status"),
                      ("show", "one campaign: status, reasons and its audit trail"),
                      ("exclude", "keep a campaign out of history, En, fleet and calibration"),
                      ("include", "undo an exclusion"),
                      ("adjust", "mark an adjustment: the unit's drift series starts anew there"),
                      ("unadjust", "withdraw an adjustment mark")):
        q = csub.add_parser(name, help=hlp)
        if name != "list":
            q.add_argument("campaign", metavar="CAMPAIGN")
        if name in ("exclude", "include", "adjust", "unadjust"):
            q.add_argument("--why", required=True, metavar="TEXT",
                           help="the reason, kept in the audit trail")
            q.add_argument("--by", default=None, help="who decides (default: the login name)")
            q.add_argument("--lock-timeout", type=float, default=60.0, metavar="S")
        q.add_argument("--warehouse", "-w", default=default_warehouse())
        q.set_defaults(func=_cmd_campaign)

    m = sub.add_parser(
        "migrate", help="upgrade a warehouse written by an older accelcal (schema 2 or 3 -> 4)",
        description="Bring a warehouse to this accelcal's schema in place, keeping every row "
                    "and the activation history. The file is first copied (its write-ahead log "
                    "folded in) to <stem>.schema-<old>.duckdb beside it. Schema 2 -> 3 writes each result's "
                    "extras as the file <stem>-extras/<sha[:2]>/<sha>.json its "
                    "results.extras_sha256 names. Schema 3 -> 4 names each combination row "
                    "structurally (K1(Koq,K3)) with its factors in coefficient_history.factors. "
                    "Safe to run again after an interruption.")
    m.add_argument("--warehouse", "-w", default=default_warehouse())
    m.add_argument("--lock-timeout", type=float, default=60.0, metavar="S")
    m.set_defaults(func=_cmd_migrate)


register = register_cli


#: ``accelcal verify`` exit codes beside 0 (valid, final, signed) and 1 (fails; one line).
EXIT_NOT_FINAL = 4
EXIT_UNSIGNED = 5


def _fail(msg: str):
    try:
        from ..cli import CliError
    except ImportError:  # pragma: no cover
        CliError = RuntimeError
    raise CliError(msg)


def _cmd_report(args) -> int:
    from .report import ReportError, build_report, list_campaigns
    if not args.campaign and not args.all and not args.result:
        _fail("give a CAMPAIGN, --result ID or --all")
    try:
        camps = list_campaigns(args.warehouse) if args.all else [args.campaign]
        for c in camps:
            path = build_report(args.warehouse, c, args.out, result_id=args.result,
                                lock_timeout=args.lock_timeout, config=args.config,
                                pdf=args.pdf, customer=args.customer, dcc=args.dcc,
                                sign=True if args.sign else None)
            print(path)
            if args.pdf:
                print(path.with_suffix(".pdf"))
            if args.dcc:
                print(path.with_suffix(".dcc.xml"))
    except ReportError as e:
        _fail(str(e))
    return 0


def _cmd_verify(args) -> int:
    from pathlib import Path

    from ..config import ConfigError, find_config
    from .dcc import DccError, dcc_config, verify_dcc
    try:
        if args.cert:
            cert_file = Path(args.cert).expanduser()
        else:
            cert_file = dcc_config(find_config(args.config)).cert_file
        cert = None
        if cert_file is not None:
            try:
                cert = cert_file.read_bytes()
            except OSError as e:
                raise DccError(f"cannot read certificate {cert_file}: {e.strerror}") from None
        v = verify_dcc(args.file, cert)
    except (DccError, ConfigError) as e:
        _fail(f"{args.file}: {e}")
    rules = v.rules
    if rules.errors:
        _fail(f"{args.file}: valid against dcc.xsd {v.schema_version} but not PTB's rules "
              f"(dcclib Schematron): {rules.summary()}")
    status = " + ".join(v.status) if v.status else "final"
    print(f"{args.file}: {status}; valid DCC {v.schema_version}; PTB's rules: "
          f"{len(rules.errors)} errors, {len(rules.warnings)} warnings; "
          + (f"{v.signature_format} signature verified ({v.signer})" if v.signed else "not signed"))
    if v.status:
        return EXIT_NOT_FINAL
    return 0 if v.signed else EXIT_UNSIGNED


def _need_warehouse(path: str) -> None:
    """Reading commands never create a warehouse: a missing one is a one-line error."""
    from pathlib import Path
    if not Path(path).expanduser().exists():
        _fail(f"warehouse {path} does not exist")


def _cmd_migrate(args) -> int:
    from ..cli import _console, say
    from ..warehouse.errors import WarehouseError
    from ..warehouse.migrate import migrate
    _need_warehouse(args.warehouse)
    try:
        out = migrate(args.warehouse, lock_timeout=args.lock_timeout)
    except WarehouseError as e:
        _fail(str(e))
    con = _console()
    if out["from"] == out["to"]:
        say(con, f"{out['warehouse']}: schema {out['to']} already; nothing to do")
        return 0
    say(con, f"{out['warehouse']}: schema {out['from']} -> {out['to']}; {out['results']} "
             f"results, {out['extras_files']} extras files, {out['combinations']} combination "
             f"rows named structurally; the schema-{out['from']} file is "
             f"kept as {out['backup']}")
    return 0


def _cmd_status(args) -> int:
    from ..cli import _console, say
    from .serve import status_lines
    _need_warehouse(args.warehouse)
    con = _console()
    for line in status_lines(args.warehouse, n=max(1, args.passes), watch_dir=args.watch,
                             settle=args.settle, part_stale=args.part_stale):
        say(con, line)
    return 0


def _cmd_campaign(args) -> int:
    from ..cli import _console, say
    from ..warehouse.errors import WarehouseError
    from .campaigns import campaign_log, campaign_rows, set_campaign
    _need_warehouse(args.warehouse)
    if args.action in ("adjust", "unadjust"):
        from .due_cli import cmd_adjust
        return cmd_adjust(args)
    con = _console()
    try:
        if args.action in ("exclude", "include"):
            a = set_campaign(args.warehouse, args.campaign, args.action, args.why, args.by,
                             lock_timeout=args.lock_timeout)
            say(con, f"{a['campaign']}: {a['action']}d by {a['by']} at "
                     f"{a['acted_at']:%Y-%m-%d %H:%M:%S %Z} (audit #{a['seq']}): {a['why']}")
            return 0
        rows = campaign_rows(args.warehouse, None if args.action == "list" else args.campaign)
        if args.action == "show" and not rows:
            _fail(f"no current result for campaign {args.campaign!r}")
        for r in rows:
            why = []
            if r["completeness"] != "complete":
                why.append("incomplete: " + "; ".join(r["completeness_reasons"]))
            if r["simulated"]:
                why.append("simulated")
            if r["excluded_why"] is not None:
                why.append(f"excluded by {r['excluded_by']}: {r['excluded_why']}")
            state = "calibration" if r["in_history"] else "kept out of history"
            say(con, f"{r['campaign']}  {r['unit_serial']}  result {r['result_id'][:12]}  "
                     f"{state}" + (f" ({'; '.join(why)})" if why else ""))
        if args.action == "show":
            for a in campaign_log(args.warehouse, args.campaign):
                say(con, f"#{a['seq']} {a['acted_at']:%Y-%m-%d %H:%M:%S %Z} {a['action']} by "
                         f"{a['acted_by']}: {a['why']}", indent="  ")
    except WarehouseError as e:
        _fail(str(e))
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

        from .serve import setup_logging, watch_pass
        setup_logging()
        out = watch_pass(args.watch, args.warehouse, settle=args.settle, engine="local",
                         lock_timeout=args.lock_timeout, part_stale=args.part_stale)
        if args.json:                   # the pass's lines went to the log (stderr) already
            print(json.dumps(out, indent=1, default=str))
        return 1 if out.get("error") else 0
    if not args.cron and not args.poll:
        _fail("give --cron and/or --poll (or --once)")
    from .serve import serve
    try:
        serve(args.watch, args.warehouse, cron=args.cron, poll=args.poll, settle=args.settle,
              name=args.name, lock_timeout=args.lock_timeout, task_runner=args.task_runner,
              part_stale=args.part_stale)
    except KeyboardInterrupt:
        pass
    print("accelcal serve: stopped", file=sys.stderr)
    return 0

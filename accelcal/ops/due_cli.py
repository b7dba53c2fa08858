"""CLI of ``accelcal due`` and ``accelcal history UNIT --html DIR``
(``accelcal campaign adjust`` lives with the other campaign actions in ops/cli.py).
Registration is cheap; the science is imported when a command runs."""
from __future__ import annotations

from ..config import default_warehouse


def register(sub) -> None:
    d = sub.add_parser(
        "due", help="when each unit must come back: drift, due date and its basis",
        description="Per unit and coefficient: the drift line over its calibrations (a "
                    "new level after each adjustment or flagged step), the date on which the probability "
                    "of being out of tolerance around the value in use reaches the lab's risk "
                    "([tolerance.\"MODEL\"] and [forecast] risk in accelcal.toml), and the "
                    "basis of that date. A unit with too little history, no tolerance or "
                    "mixed code versions says so instead of inventing a date.")
    d.add_argument("--warehouse", "-w", default=default_warehouse())
    d.add_argument("--config", default=None, metavar="TOML",
                   help="accelcal.toml (default: ./accelcal.toml, then beside the warehouse)")
    d.add_argument("--within", default=None, metavar="SPAN",
                   help="only units due within SPAN of today (or --as-of): 90d, 12w, 6m, 1y")
    d.add_argument("--as-of", default=None, metavar="DATE",
                   help="what the warehouse said at the end of DATE (YYYY-MM-DD)")
    d.add_argument("--json", action="store_true", help="a JSON list of rows")
    d.add_argument("--store", action="store_true",
                   help="also append the rows to forecast_history (view recalibration_forecast)")
    d.add_argument("--lock-timeout", type=float, default=60.0, metavar="S")
    d.set_defaults(func=_cmd_due)

    h = sub.add_parser(
        "history", help="a unit's control charts: values, drift line, tolerance, due date",
        description="One control chart per coefficient: value ± U per campaign, the drift "
                    "line with its 95 %% prediction band, the tolerance band around the value "
                    "in use, the due date, En between consecutive campaigns.")
    h.add_argument("unit", metavar="UNIT", help="unit serial")
    h.add_argument("--html", required=True, metavar="DIR", help="output folder")
    h.add_argument("--warehouse", "-w", default=default_warehouse())
    h.add_argument("--config", default=None, metavar="TOML")
    h.add_argument("--as-of", default=None, metavar="DATE")
    h.add_argument("--lock-timeout", type=float, default=60.0, metavar="S")
    h.set_defaults(func=_cmd_history)


def _fail(msg: str):
    from ..cli import CliError
    raise CliError(msg)


def _cmd_due(args) -> int:
    import json

    from ..cli import _console, say
    from ..config import ConfigError, forecast_config
    from .due import DueError, due_rows, parse_as_of, parse_within, store_forecast, text_lines
    try:
        cfg = forecast_config(args.config, args.warehouse)
        as_of = parse_as_of(args.as_of)
        rows = due_rows(args.warehouse, cfg, as_of, parse_within(args.within),
                        lock_timeout=args.lock_timeout)
        if args.store:
            store_forecast(args.warehouse, rows, cfg, as_of, lock_timeout=args.lock_timeout)
    except (ConfigError, DueError) as e:
        _fail(str(e))
    if args.json:
        print(json.dumps(rows, indent=1, ensure_ascii=False))
        return 0
    con = _console()
    if not rows:
        say(con, f"nothing due within {args.within}" if args.within else
            "no calibrations (complete, real, not excluded campaigns) in the warehouse")
        return 0
    for line in text_lines(rows, None if as_of is None else as_of.date()):
        say(con, line)
    return 0


def _cmd_history(args) -> int:
    from ..config import ConfigError, forecast_config
    from .due import DueError, history_html, parse_as_of
    try:
        cfg = forecast_config(args.config, args.warehouse)
        path = history_html(args.warehouse, args.unit, args.html, cfg, parse_as_of(args.as_of),
                            lock_timeout=args.lock_timeout)
    except (ConfigError, DueError) as e:
        _fail(str(e))
    print(path)
    return 0


def cmd_adjust(args) -> int:
    """``accelcal campaign adjust|unadjust CAMPAIGN --why TEXT`` (called by ops/cli.py)."""
    from ..cli import _console, say
    from .campaigns import who
    from .due import DueError, set_adjustment
    try:
        a = set_adjustment(args.warehouse, args.campaign, args.why, args.by or who(),
                           undo=args.action == "unadjust", lock_timeout=args.lock_timeout)
    except DueError as e:
        _fail(str(e))
    say(_console(), f"{a['campaign']}: {a['action']}ed by {a['by']} at "
                    f"{a['acted_at']:%Y-%m-%d %H:%M:%S %Z} (adjustment audit #{a['seq']}): "
                    f"{a['why']}; its unit's drift series starts anew there"
        if a["action"] == "adjust" else
        f"{a['campaign']}: adjustment mark withdrawn by {a['by']} (adjustment audit "
        f"#{a['seq']}): {a['why']}")
    return 0

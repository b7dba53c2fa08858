"""Command line: ``accelcal run|demo|...``.

Subcommands register themselves in :data:`SUBCOMMANDS` (name -> registrar).  A
registrar gets argparse's sub-parsers object, adds its parser and sets
``func`` (called with the parsed args; returns the exit code).  Registrars must
be cheap: import heavy things inside ``func``.  Other parts of accelcal may add
a subcommand by providing ``register(subparsers)`` / ``register_cli(subparsers)``
in a module listed in :data:`PLUGIN_MODULES` (skipped if absent).

Exit codes (:data:`EXIT_CODES`): 0 processed what it could (refused and held-back files
are results, listed); 1 could not work, or stopped part-way (one line on stderr naming the
path and what to do; what was committed stays, a re-run completes it exactly once); 2 usage
error; 3 an internal error (a bug: one line, the traceback saved to a file it names; in a
run, the other files are still processed); 130 interrupted (``run``/``demo``: at once, one
line, through :func:`accelcal.procguard.stop_on_interrupt`).  Nothing is printed that has
not passed through :mod:`accelcal.textout` (no markup, emoji or control characters from a
file reach the terminal) and no error is a traceback.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from pathlib import Path
from typing import Any, Callable

Registrar = Callable[[Any], None]
SUBCOMMANDS: dict[str, Registrar] = {}

#: Modules that may provide ``register(subparsers)`` (or ``register_cli``) for their
#: own subcommands (simulate, diagnose, montecarlo, report, serve, ...).  Absent
#: modules are skipped.  They are not imported when a built-in command runs.
PLUGIN_MODULES = ("accelcal.ops.simulate_cli", "accelcal.ops.diagnose_cli", "accelcal.ops.validate_cli",
                  "accelcal.ops.cli", "accelcal.ops.sql", "accelcal.ops.due_cli", "accelcal.ops.design_cli")

EXIT_OK, EXIT_FAIL, EXIT_USAGE, EXIT_BUG, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
EXIT_CODES = {EXIT_OK: "processed what it could (refused / held-back files listed)",
              EXIT_FAIL: "could not work, or stopped part-way: one line says where and what to do",
              EXIT_USAGE: "usage error", EXIT_BUG: "internal error (a bug; traceback saved)",
              EXIT_INTERRUPTED: "interrupted"}


class CliError(RuntimeError):
    """A one-line reason the command could not work."""


def subcommand(name: str) -> Callable[[Registrar], Registrar]:
    def deco(fn: Registrar) -> Registrar:
        SUBCOMMANDS[name] = fn
        return fn
    return deco


# ------------------------------------------------------------------- display --

def display_coefficient(c: dict[str, Any]) -> tuple[str, str, str]:
    """(value, U (k=2), unit) in display units, rounded per GUM 7.2.6."""
    from .effects import display_coefficient as show
    return show(c["name"], c["value"], c["std_uncertainty"], c.get("unit") or "")


class RichReporter:
    """Progress bar for the pipeline's stages (accelcal.tasks.progress)."""

    LABELS = {"prefect": "starting Prefect", "ingest": "ingest files", "validate": "validate drops",
              "record": "record runs", "science": "process campaigns", "store": "store results"}

    def __init__(self, progress):
        self.p = progress
        self.ids: dict[str, Any] = {}

    def stage(self, name, total):
        if "prefect" in self.ids and name != "prefect":
            tid = self.ids["prefect"]
            self.p.update(tid, total=1, completed=1)
        if name in self.ids:
            tid = self.ids[name]
            t = self.p.tasks[tid].total or 0
            self.p.update(tid, total=t + (total or 0))
        else:
            self.ids[name] = self.p.add_task(self.LABELS.get(name, name), total=total)

    def advance(self, name, n=1, note=""):
        if name not in self.ids:
            self.stage(name, None)
        self.p.advance(self.ids[name], n)


def _console(stderr: bool = False):
    from .textout import console
    return console(stderr)


#: Longest line printed for one refusal / error (the warehouse keeps the whole reason).
LINE_MAX = 400


def say(con, text: str, tag: str = "", style: str = "", indent: str = "") -> None:
    """Print one line whose ``text`` may come from a file (a run id, a campaign label, a
    refusal reason): it is escaped, so it is shown as written and never read as markup.
    ``tag`` is ours (e.g. "refused") and shown in ``style``."""
    from .textout import esc
    head = f"[{style}]{esc(tag)}[/{style}] " if tag and style else (f"{esc(tag)} " if tag else "")
    con.print(indent + head + esc(text, LINE_MAX), soft_wrap=True)


def _cell(x) -> Any:
    """A table cell taken literally (file-derived text is not markup)."""
    from rich.text import Text

    from .textout import plain
    return Text("" if x is None else plain(x, 200))


#: What a campaign's store status means, for people.
STATUS_WORDS = {"simulated-not-current": "simulated: stored, NOT current (the unit has a "
                                         "complete real calibration)"}


def print_summary(summary: dict[str, Any], console=None) -> None:
    """The run summary.  Every value that came from a file or a path goes through
    textout.esc: printed as text, never as markup."""
    from rich.table import Table

    from .textout import esc
    con = console or _console()
    wh = summary["warehouse"]
    t = Table(title="Drops", title_justify="left", show_edge=False)
    for col, j in (("drop", "left"), ("files", "right"), ("accepted", "right"),
                   ("refused", "right"), ("new", "right")):
        t.add_column(col, justify=j)
    for d in summary["drops"]:
        t.add_row(_cell(d["drop"]), str(d["files"]), str(d["accepted"]),
                  f"[red]{d['refused']}[/red]" if d["refused"] else "0", str(d["new"]))
    con.print(t)
    for d in summary["drops"]:
        for r in d["refused_files"]:
            rel = f"{d['drop']}/{os.path.relpath(r['path'], d['path'])}"
            reason = (r["reason"] or "refused").replace(r["path"], rel)
            say(con, reason, "refused", "red", "  ")
        held = d.get("simulated_held") or []
        for r in held[:5]:
            rel = f"{d['drop']}/{os.path.relpath(r['path'], d['path'])}"
            say(con, f"{rel}:{r['line']}: simulated: the file carries the simulator's mark; "
                     "not stored (--allow-simulated stores simulated data apart from real "
                     "results)", "refused", "red", "  ")
        if len(held) > 5:
            say(con, f"... and {len(held) - 5} more simulated files of {d['drop']}", indent="  ")
        for e in d.get("held", []):
            say(con, e, "held back", "yellow", "  ")
        for e in d["errors"]:
            say(con, e, "not ingested", "yellow", "  ")
        if d.get("docs"):
            say(con, f"Data Docs: {d['docs']}", indent="  ")
    from .warehouse.summary import SUMMARY_DETAIL_MAX
    for k, c in enumerate(summary["campaigns"]):
        if k == SUMMARY_DETAIL_MAX:
            rest = summary["campaigns"][k:]
            st: dict[str, int] = {}
            for x in rest:
                st[x["status"]] = st.get(x["status"], 0) + 1
            con.print()
            con.print(f"... and {len(rest)} more campaigns ("
                      + ", ".join(f"{n} {s_}" for s_, n in sorted(st.items()))
                      + "): see the unit_history view or `accelcal report CAMPAIGN`")
            for x in rest:
                if x.get("error"):
                    say(con, f"{x['campaign']}: {x['error']}", "failed", "red", "  ")
            break
        con.print()
        status = STATUS_WORDS.get(c["status"], c["status"])
        head = f"{c['campaign']} ({c.get('unit_serial') or '?'}): {c['n_runs']} runs, {status}"
        if c.get("current_result_id"):
            head += f", result {c['current_result_id'][:12]}"
        elif c.get("shown_result_id"):
            head += f", result {c['shown_result_id'][:12]} (not current)"
        say(con, head)
        if c.get("simulated") and not c.get("current_result_id"):
            say(con, "computed from the simulator's files, not from a DAQ. Kept "
                     "out of history, En, the fleet views and the calibration view, and never "
                     "the unit's current result: the unit has a real calibration, and a "
                     "simulated value must never stand in for a measured one",
                "SIMULATED", "bold yellow", "  ")
        elif c.get("simulated"):
            say(con, "computed from simulated data: kept out of history, En and the fleet "
                     "views", "simulated", "yellow", "  ")
        if c.get("simulated_left_out"):
            say(con, f"{c['simulated_left_out']} simulated run(s) with this campaign label "
                     "were left out (real runs are never mixed with simulated ones)",
                "simulated", "yellow", "  ")
        if c.get("completeness") == "incomplete":
            say(con, "; ".join(c.get("completeness_reasons") or []) + " — visible, but kept "
                     "out of history, En and the fleet views", "incomplete", "yellow", "  ")
        if c.get("excluded"):
            say(con, f"excluded by `accelcal campaign exclude`: {c['excluded']}",
                "excluded", "yellow", "  ")
        if c.get("error"):
            say(con, c["error"], "failed", "red", "  ")
        if c.get("coefficients"):
            t = Table(show_edge=False, box=None, padding=(0, 1),
                      caption="* the adopted value" if any(
                          co.get("adopted") for co in c["coefficients"]) else None,
                      caption_justify="left")
            rows = [("*" if co.get("adopted") else "", _cell(co["name"]), *display_coefficient(co),
                     _cell(co.get("method")), _cell(co.get("rig_id"))) for co in c["coefficients"]]
            # the numbers and their unit are never cut: a long name (a combination the runs
            # determine, K0+0.00296*K2+...) folds onto a second line instead
            for k, (col, j) in enumerate((("", "left"), ("coef", "left"), ("value", "right"),
                                          ("U (k=2)", "right"), ("unit", "left"), ("method", "left"),
                                          ("rig", "left"))):
                whole = col in ("value", "U (k=2)", "unit")
                t.add_column(col, justify=j, no_wrap=whole, overflow="fold",
                             min_width=max([len(col)] + [len(str(r[k])) for r in rows]) if whole else None,
                             max_width=24 if col == "coef" else None)
            for r in rows:
                t.add_row(*r)
            con.print(t)
        radii = _radius_rows(c.get("radii") or [])
        if radii:
            t = Table(show_edge=False, box=None, padding=(0, 1))
            t.add_column("radius (widest g)", overflow="fold")
            t.add_column("R+ / m", justify="right", no_wrap=True)
            t.add_column("U / µm", justify="right", no_wrap=True)
            t.add_column("R− / m", justify="right", no_wrap=True)
            t.add_column("U / µm", justify="right", no_wrap=True)
            for label, plus, minus in radii:
                t.add_row(_cell(label), *(_fmt_radius(plus)), *(_fmt_radius(minus)))
            con.print(t)
        for f in c.get("flags") or []:
            say(con, f, "flag", "yellow", "  ")
    con.print()
    tm = summary.get("timings", {})
    n = summary.get("workers") or 1
    procs = f" ({n} worker processes)" if n > 1 else ""
    say(con, f"warehouse {wh}  ·  {summary.get('engine', '')} engine{procs}  ·  "
             f"{tm.get('total', 0):.1f} s  ·  flow run {summary['flow_run_id']}")


def _fmt_radius(r):
    """(R / m, U / µm), GUM 7.2.6: U to 2 digits, R to the same decimal."""
    from .rounding import format_sig, round_gum
    if r is None:
        return "—", "—"
    u = r.get("std_uncertainty_m")
    U = None if u is None else 2 * u
    return round_gum(r["radius_m"], U).value, format_sig(None if U is None else 1e6 * U)


def _radius_rows(radii: list[dict[str, Any]]):
    """One row per (rig, method, order) at its widest g range; order 1 left out (it drifts)."""
    best: dict[tuple, dict[str, Any]] = {}
    for r in radii:
        if r.get("model_order") == 1:
            continue
        key = (r.get("rig_id"), r.get("method"), r.get("model_order"), r.get("polarity"))
        if key not in best or (r.get("g_max") or 0) > (best[key].get("g_max") or 0):
            best[key] = r
    rows = {}
    for (rig, method, order, pol), r in best.items():
        label = f"{rig} {method}" + (f" o{order}" if order is not None else "")
        rows.setdefault(label, {})[pol] = r
    return [(label, v.get("+"), v.get("-")) for label, v in sorted(rows.items())]


# ---------------------------------------------------------------- commands --

def _execute(drops: list[str], warehouse: str, args, console, create: bool = False,
             allow_simulated: bool = False) -> int:
    from .fileio import StoreError
    from .flows.pipeline import PipelineError, quiet_prefect
    from .warehouse.errors import WarehouseError
    # Prefect logs a failed task or flow with its traceback; the CLI reports every failure
    # itself in one line, so Prefect's console says nothing unless asked (--log-level, or
    # PREFECT_LOGGING_LEVEL in the environment).
    level = (args.log_level or os.environ.get("PREFECT_LOGGING_LEVEL") or "CRITICAL").upper()
    for k in ("PREFECT_LOGGING_LEVEL", "PREFECT_SERVER_LOGGING_LEVEL", "PREFECT_LOGGING_ROOT_LEVEL"):
        os.environ[k] = level
    quiet_prefect(level)
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn,
                               TextColumn, TimeElapsedColumn)

    from .flows.pipeline import run_pipeline
    from .tasks import progress as prog
    err = _console(stderr=True)
    show = not args.quiet and not args.json
    bar = Progress(SpinnerColumn(), TextColumn("{task.description:<18}"), BarColumn(),
                   MofNCompleteColumn(), TimeElapsedColumn(), console=err, transient=False,
                   disable=not show)
    rep = RichReporter(bar)
    from .config import ConfigError, run_parameters
    try:
        parameters = run_parameters(args.config, warehouse)
    except ConfigError as e:
        raise CliError(str(e)) from None
    try:
        with bar:
            prog.set_reporter(rep)
            if args.engine == "prefect":
                rep.stage("prefect", None)
            summary = run_pipeline(drops, warehouse, engine=args.engine,
                                   lock_timeout=args.lock_timeout,
                                   task_runner=args.task_runner, settle=args.settle,
                                   create=create, snapshot=not args.no_snapshot,
                                   allow_simulated=allow_simulated,
                                   workers=args.workers,
                                   parameters=parameters)
    except (PipelineError, WarehouseError, StoreError) as e:
        raise CliError(str(e)) from None
    finally:
        prog.set_reporter(None)
    if args.json:
        import json
        print(json.dumps(summary, indent=2, default=str))
    else:
        print_summary(summary, console)
    from .textout import warn
    for w in [w for d in summary["drops"] for w in d.get("warnings", [])] + summary.get("warnings", []):
        warn(w)
    if any(d["errors"] for d in summary["drops"]):
        n = sum(len(d["errors"]) for d in summary["drops"])
        from .textout import error
        error(f"{n} file(s) not ingested because of an internal error (listed above); "
              "the others were processed")
        return EXIT_BUG
    return EXIT_OK


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lock-timeout", type=float, default=60.0, metavar="S",
                   help="wait this long for another run holding the warehouse (default 60 s)")
    p.add_argument("--engine", choices=("prefect", "local"), default="prefect",
                   help="prefect: steps as Prefect tasks (default); local: same steps "
                        "without Prefect (no server start-up)")
    p.add_argument("--task-runner", default="thread",
                   help="Prefect task runner for ingest/validate batches and campaign science: thread, dask (local cluster) or tcp://HOST:PORT (an existing Dask scheduler)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local engine: N processes for the ingest/validate batches and the "
                        "campaign science (default $ACCELCAL_WORKERS or 1; the warehouse "
                        "writes stay in one process)")
    p.add_argument("--settle", type=float, default=None, metavar="S",
                   help="read a file only when its size and mtime have been stable for S "
                        "seconds (default $ACCELCAL_SETTLE_S or 2); one still changing is "
                        "held back for the next run")
    p.add_argument("--no-snapshot", action="store_true",
                   help="do not publish the read-only copy <warehouse>-snapshot.duckdb")
    p.add_argument("--config", default=None, metavar="TOML",
                   help="the lab's accelcal.toml (default ./accelcal.toml, else beside the "
                        "warehouse): the stated uncertainties of rig inputs ([rigs.\"ID\"] "
                        "g_local_u_m_s2, tilt_u_deg, temperature_u_c) enter every budget")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--log-level", default=None,
                   help="Prefect's console log level (default $PREFECT_LOGGING_LEVEL or CRITICAL: "
                        "the CLI reports failures itself, in one line)")


@subcommand("run")
def _register_run(sub) -> None:
    p = sub.add_parser("run", help="process drops end to end into a warehouse",
                       description="Ingest, validate and process lab drops; store results "
                                   "with lineage in a DuckDB warehouse.")
    p.add_argument("drops", nargs="+", metavar="DROP", help="drop folder(s)")
    p.add_argument("--warehouse", "-w", default=os.environ.get("ACCELCAL_WAREHOUSE", "lab.duckdb"),
                   help="DuckDB warehouse file (default: $ACCELCAL_WAREHOUSE or ./lab.duckdb); "
                        "Parquet and Data Docs go next to it")
    p.add_argument("--allow-simulated", action="store_true",
                   help="store files made by `accelcal simulate` (marked '# simulated: true'); "
                        "without it they are refused. A simulated result is never current for "
                        "a unit that has a complete real calibration, and never enters history, "
                        "En or the fleet views")
    p.add_argument("--create", action="store_true",
                   help="create the warehouse's folder if it does not exist (else an error)")
    _add_run_options(p)
    p.set_defaults(func=_cmd_run)


def _cmd_run(args) -> int:
    return _execute(args.drops, args.warehouse, args, _console(), create=args.create,
                    allow_simulated=args.allow_simulated)


def demo_drops() -> list[Path]:
    """The drops shipped inside the package (accelcal/demo_data/*)."""
    from importlib import resources
    root = resources.files("accelcal") / "demo_data"
    drops = sorted(Path(str(p)) for p in root.iterdir() if p.is_dir() and not p.name.startswith(("_", ".")))
    if not drops:
        raise CliError(f"no demo drops found in {root}")
    return drops


@subcommand("demo")
def _register_demo(sub) -> None:
    p = sub.add_parser("demo", help="run the pipeline on the built-in demo drops",
                       description="Process the demo drops shipped with accelcal into "
                                   "DIR/lab.duckdb (default ./accelcal-demo).")
    p.add_argument("--dir", default="accelcal-demo", help="output folder (default ./accelcal-demo)")
    _add_run_options(p)
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args) -> int:
    out = Path(args.dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CliError(f"cannot create {out}: {e.strerror}") from None
    drops = [str(d) for d in demo_drops()]
    console = _console()
    if not args.json:
        say(console, f"demo drops: {', '.join(Path(d).name for d in drops)} -> {out / 'lab.duckdb'}")
    # the demo drop is made by the simulator (accelcal/demo_data/README.md)
    return _execute(drops, str(out / "lab.duckdb"), args, console, create=True, allow_simulated=True)


# -------------------------------------------------------------------- main --

def _load_plugins(sub) -> None:
    for mod in PLUGIN_MODULES:
        try:
            m = importlib.import_module(mod)
        except ModuleNotFoundError as e:
            if e.name and (mod == e.name or mod.startswith(e.name + ".")):
                continue
            raise
        reg = getattr(m, "register", None) or getattr(m, "register_cli", None)
        if reg is not None:
            reg(sub)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="accelcal", description="Accelerometer calibration pipeline.")
    try:
        from importlib.metadata import version
        ver = version("accelcal")
    except Exception:
        ver = "unknown"
    parser.add_argument("--version", action="version", version=f"accelcal {ver}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, reg in SUBCOMMANDS.items():
        reg(sub)
    first = next((a for a in (argv or []) if not a.startswith("-")), None)
    if first not in SUBCOMMANDS:      # a built-in command needs no plugin imports
        _load_plugins(sub)
    return parser


#: Commands that may start processes of their own (Prefect's server, Dask workers): they
#: are watched by accelcal.procguard so nothing outlives the command, even after SIGKILL.
GUARDED = ("run", "demo", "serve")
#: Commands that Ctrl-C ends at once (accelcal.procguard.stop_on_interrupt); ``serve``
#: finishes its pass first.
STOP_AT_ONCE = ("run", "demo")
INTERRUPTED = "interrupted; what was committed stays, a re-run completes the rest"


def main(argv: list[str] | None = None) -> int:
    """The ``accelcal`` command (``argv`` None: ``sys.argv``, the program itself).  As the
    program, ``run`` and ``demo`` stop at once on Ctrl-C and end without the interpreter's
    shutdown (:func:`accelcal.procguard.exit_now`)."""
    program = argv is None
    argv = sys.argv[1:] if argv is None else argv
    command = next((a for a in argv if not a.startswith("-")), None)
    at_once = program and command in STOP_AT_ONCE and not os.environ.get("ACCELCAL_NO_GUARD")
    if command in GUARDED and not os.environ.get("ACCELCAL_NO_GUARD"):
        # first of all: from here on Ctrl-C is one line and exit 130, never a traceback
        from .procguard import guard_descendants, stop_on_interrupt
        at_once = at_once and stop_on_interrupt(INTERRUPTED, EXIT_INTERRUPTED)
        guard_descendants()
    rc = _main(argv)
    if at_once:
        from .procguard import exit_now
        exit_now(rc)
    return rc


def _main(argv: list[str]) -> int:
    from . import textout
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CliError as e:
        textout.error(e)
        return EXIT_FAIL
    except KeyboardInterrupt:
        textout.error(INTERRUPTED)
        return EXIT_INTERRUPTED
    except BrokenPipeError:                 # the reader of our output went away (| head)
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_FAIL
    except OSError as e:
        from .fileio import os_error_text
        textout.error(os_error_text(e))
        return EXIT_FAIL
    except MemoryError:
        textout.error("out of memory; see the README (Faults) for the memory a run needs")
        return EXIT_FAIL
    except Exception as e:
        if os.environ.get("ACCELCAL_DEBUG"):
            raise
        where = _save_traceback()
        textout.error(f"internal error: {type(e).__name__}: {e} -- a bug in accelcal; "
                      f"traceback saved in {where}")
        return EXIT_BUG


def _save_traceback() -> str:
    import tempfile
    import time
    import traceback
    try:
        fd, path = tempfile.mkstemp(prefix=f"accelcal-crash-{time.strftime('%Y%m%dT%H%M%S')}-",
                                    suffix=".txt")
        with os.fdopen(fd, "w") as f:
            f.write(f"accelcal {' '.join(sys.argv[1:])}\n\n")
            traceback.print_exc(file=f)
        return path
    except OSError:
        return "(nowhere: the temporary folder is not writable; set ACCELCAL_DEBUG=1)"


if __name__ == "__main__":
    sys.exit(main())

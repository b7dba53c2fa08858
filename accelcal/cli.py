"""Command line: ``accelcal run|demo|...``.

Subcommands register themselves in :data:`SUBCOMMANDS` (name -> registrar).  A
registrar gets argparse's sub-parsers object, adds its parser and sets
``func`` (called with the parsed args; returns the exit code).  Registrars must
be cheap: import heavy things inside ``func``.  Other parts of accelcal may add
a subcommand by providing ``register(subparsers)`` / ``register_cli(subparsers)``
in a module listed in :data:`PLUGIN_MODULES` (skipped if absent).

Exit codes: 0 processed what it could (refused files are results); 1 could not
work at all (one-line reason on stderr); 2 usage error.
"""
from __future__ import annotations

import argparse
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
PLUGIN_MODULES = ("accelcal.simulate.cli", "accelcal.diagnosis.cli", "accelcal.montecarlo",
                  "accelcal.ops.cli")

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2


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
    from rich.console import Console
    return Console(stderr=stderr, highlight=False)


def print_summary(summary: dict[str, Any], console=None) -> None:
    from rich.table import Table
    con = console or _console()
    wh = summary["warehouse"]
    t = Table(title="Drops", title_justify="left", show_edge=False)
    for col, j in (("drop", "left"), ("files", "right"), ("accepted", "right"),
                   ("refused", "right"), ("new", "right")):
        t.add_column(col, justify=j)
    for d in summary["drops"]:
        t.add_row(d["drop"], str(d["files"]), str(d["accepted"]),
                  f"[red]{d['refused']}[/red]" if d["refused"] else "0", str(d["new"]))
    con.print(t)
    for d in summary["drops"]:
        for r in d["refused_files"]:
            rel = f"{d['drop']}/{os.path.relpath(r['path'], d['path'])}"
            reason = (r["reason"] or "refused").replace(r["path"], rel)
            con.print(f"  [red]refused[/red] {reason}", soft_wrap=True)
        for e in d["errors"]:
            con.print(f"  [yellow]not ingested[/yellow] {e}", soft_wrap=True)
        if d.get("docs"):
            con.print(f"  Data Docs: {d['docs']}", soft_wrap=True)
    from .flows.pipeline import SUMMARY_DETAIL_MAX
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
                    con.print(f"  [red]failed[/red] {x['campaign']}: {x['error']}", soft_wrap=True)
            break
        con.print()
        status = c["status"]
        head = f"[bold]{c['campaign']}[/bold] ({c.get('unit_serial') or '?'}): {c['n_runs']} runs, {status}"
        if c.get("current_result_id"):
            head += f", result {c['current_result_id'][:12]}"
        con.print(head)
        if c.get("error"):
            con.print(f"  [red]failed[/red]: {c['error']}", soft_wrap=True)
        if c.get("coefficients"):
            t = Table(show_edge=False, box=None, padding=(0, 2))
            for col, j in (("coef", "left"), ("value", "right"), ("U (k=2)", "right"),
                           ("unit", "left"), ("method", "left"), ("rig", "left")):
                t.add_column(col, justify=j)
            for co in c["coefficients"]:
                v, U, unit = display_coefficient(co)
                t.add_row(co["name"], v, U, unit, co.get("method") or "", co.get("rig_id") or "")
            con.print(t)
        radii = _radius_rows(c.get("radii") or [])
        if radii:
            t = Table(show_edge=False, box=None, padding=(0, 2))
            t.add_column("radius (widest g)", no_wrap=True)
            t.add_column("R+ / m", justify="right", no_wrap=True)
            t.add_column("U / µm", justify="right", no_wrap=True)
            t.add_column("R− / m", justify="right", no_wrap=True)
            t.add_column("U / µm", justify="right", no_wrap=True)
            for label, plus, minus in radii:
                t.add_row(label, *(_fmt_radius(plus)), *(_fmt_radius(minus)))
            con.print(t)
        for f in c.get("flags") or []:
            con.print(f"  [yellow]flag[/yellow] {f}", soft_wrap=True)
    con.print()
    tm = summary.get("timings", {})
    con.print(f"warehouse {wh}  ·  {summary.get('engine', '')} engine  ·  "
              f"{tm.get('total', 0):.1f} s  ·  flow run {summary['flow_run_id']}", soft_wrap=True)


def _fmt_radius(r):
    if r is None:
        return "—", "—"
    u = r.get("std_uncertainty_m")
    return f"{r['radius_m']:.6f}", ("—" if u is None else f"{2e6 * u:.2f}")


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

def _execute(drops: list[str], warehouse: str, args, console) -> int:
    from .flows.pipeline import PipelineError, quiet_prefect
    from .warehouse.db import WarehouseError
    quiet_prefect(args.log_level)
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
    try:
        with bar:
            prog.set_reporter(rep)
            if args.engine == "prefect":
                rep.stage("prefect", None)
            summary = run_pipeline(drops, warehouse, engine=args.engine,
                                   lock_timeout=args.lock_timeout,
                                   task_runner=args.task_runner)
    except (PipelineError, WarehouseError) as e:
        raise CliError(str(e)) from None
    finally:
        prog.set_reporter(None)
    if args.json:
        import json
        print(json.dumps(summary, indent=2, default=str))
    else:
        print_summary(summary, console)
    return EXIT_OK


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lock-timeout", type=float, default=60.0, metavar="S",
                   help="wait this long for another run holding the warehouse (default 60 s)")
    p.add_argument("--engine", choices=("prefect", "local"), default="prefect",
                   help="prefect: steps as Prefect tasks (default); local: same steps "
                        "without Prefect (no server start-up)")
    p.add_argument("--task-runner", default="thread",
                   help="Prefect task runner for ingest/validate batches and campaign science: thread, dask (local cluster) or tcp://HOST:PORT (an existing Dask scheduler)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--log-level", default="WARNING",
                   help="Prefect log level (default WARNING, keeps the progress bar readable)")


@subcommand("run")
def _register_run(sub) -> None:
    p = sub.add_parser("run", help="process drops end to end into a warehouse",
                       description="Ingest, validate and process lab drops; store results "
                                   "with lineage in a DuckDB warehouse.")
    p.add_argument("drops", nargs="+", metavar="DROP", help="drop folder(s)")
    p.add_argument("--warehouse", "-w", default=os.environ.get("ACCELCAL_WAREHOUSE", "lab.duckdb"),
                   help="DuckDB warehouse file (default: $ACCELCAL_WAREHOUSE or ./lab.duckdb); "
                        "Parquet and Data Docs go next to it")
    _add_run_options(p)
    p.set_defaults(func=_cmd_run)


def _cmd_run(args) -> int:
    return _execute(args.drops, args.warehouse, args, _console())


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
        console.print(f"demo drops: {', '.join(Path(d).name for d in drops)} -> {out / 'lab.duckdb'}")
    return _execute(drops, str(out / "lab.duckdb"), args, console)


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


def main(argv: list[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CliError as e:
        print(f"accelcal: error: {e}", file=sys.stderr)
        return EXIT_FAIL
    except KeyboardInterrupt:
        print("accelcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""CLI: ``accelcal diagnose PATH... [--baseline ID[,ID...]|none] [--json [--all-segments]]
[--report DIR]``.

``accelcal diagnose-benchmark`` is registered by :mod:`accelcal.ops.validate_cli`."""
from __future__ import annotations

import json
import sys
import textwrap


def _diagnose(args) -> int:
    from ..cli import CliError            # the CLI's one error form: "accelcal: error: ..." and exit 1
    from ..diagnosis.core import diagnose, public
    from ..diagnosis.runfiles import read_paths
    from ..config import ConfigError, advice_inputs
    from ..testdesign import next_runs
    from .diagnosis_report import _jd, clean_json, html_report, text_report
    runs = read_paths(args.paths)
    if not runs:
        raise CliError("diagnose: no readable run files in " + ", ".join(map(str, args.paths)))
    try:
        res = diagnose(runs, args.baseline)
    except ValueError as e:
        raise CliError(f"diagnose: {e}") from None
    try:
        lab = advice_inputs(args.config)
    except ConfigError as e:
        raise CliError(str(e)) from None
    fixes = next_runs(runs, res, **lab)
    terminal = "\n".join([text_report(res)] + [
        textwrap.fill(f"to {f['to']}: add {f['run']} ({f['minutes']:.0f} min)" if f.get("run")
                      else f"to {f['to']}: {f['note']}", 80, subsequent_indent="  ") for f in fixes])
    if args.report:
        p = html_report(res, args.report, terminal=terminal, next_runs=fixes)
        print(f"report: {p}", file=sys.stderr)
    if args.json:
        pub = public(res)
        if not args.all_segments:
            pub.pop("where_all", None)
        pub["next_runs"] = fixes
        print(json.dumps(clean_json(pub), default=_jd, allow_nan=False))
    else:
        print(terminal)
    return 0


def register_cli(subparsers) -> None:
    """Add the ``diagnose`` subcommand to the accelcal CLI.

    ``diagnose`` reads run files or folders, runs :func:`accelcal.diagnosis.core.diagnose`
    with ``--baseline`` and prints the text report, or one JSON object with ``--json``
    (the localisation of every segment only with ``--all-segments``); ``--report DIR``
    also writes ``DIR/diagnosis.html``.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``add_subparsers()`` object of the accelcal parser.
    """
    p = subparsers.add_parser("diagnose", help="diagnose the sim-to-real gap of one or more campaigns")
    p.add_argument("paths", nargs="+", metavar="PATH", help="run files or folders")
    p.add_argument("--baseline", default=None,
                   help="effects the model already includes (comma-separated effects.md ids), or 'none' "
                        "for the bare model; default: the pipeline's own processing")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--all-segments", action="store_true", help="with --json: every localisation segment")
    p.add_argument("--report", metavar="DIR", help="write DIR/diagnosis.html (self-contained)")
    p.add_argument("--config", default=None, metavar="TOML",
                   help="accelcal.toml whose [rigs.\"ID\"] setup_min and stated rig-input "
                        "uncertainties the next-run advice reads, as accelcal design does "
                        "(default ./accelcal.toml)")
    p.set_defaults(func=_diagnose)


def main(argv=None) -> int:
    """Standalone use, ``python -m accelcal.ops.diagnose_cli diagnose ...``: the accelcal CLI
    itself, so errors and exit codes are the same.

    Parameters
    ----------
    argv : list of str, optional
        Command line without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code of :func:`accelcal.cli.main` (0 done, 1 failed with a one-line
        reason, 2 usage error, 3 internal error, 130 interrupted).
    """
    from ..cli import main as accelcal_main
    return accelcal_main(argv)


if __name__ == "__main__":
    sys.exit(main())

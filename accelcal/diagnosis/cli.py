"""CLI: ``accelcal diagnose PATH... --baseline ID[,ID...]|none [--json] [--report DIR]`` and
``accelcal diagnose-benchmark [--quick] [--json] [--markdown FILE]``."""
from __future__ import annotations

import json
import sys

from .runfiles import read_paths


def _diagnose(args) -> int:
    from .core import diagnose, public
    from .report import _jd, clean_json, html_report, text_report
    from ..cli import CliError            # the CLI's one error form: "accelcal: error: ..." and exit 1
    runs = read_paths(args.paths)
    if not runs:
        raise CliError("diagnose: no readable run files in " + ", ".join(map(str, args.paths)))
    try:
        res = diagnose(runs, args.baseline)
    except ValueError as e:
        raise CliError(f"diagnose: {e}") from None
    if args.report:
        p = html_report(res, args.report)
        print(f"report: {p}", file=sys.stderr)
    if args.json:
        pub = public(res)
        if not args.all_segments:
            pub.pop("where_all", None)
        print(json.dumps(clean_json(pub), default=_jd, allow_nan=False))
    else:
        print(text_report(res))
    return 0


def _benchmark(args) -> int:
    import subprocess
    from pathlib import Path

    from .benchmark import run_benchmark, write_readme
    from .report import _jd, clean_json
    commit = ""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).resolve().parent, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, cwd=Path(__file__).resolve().parent).stdout.strip()
        commit += "+changes" if dirty else ""
    except Exception:  # noqa: BLE001 - not a git checkout
        pass
    s = run_benchmark(quick=args.quick, seeds=args.seeds, n_clean=args.clean, dev=not args.no_dev,
                      log=(lambda m: print(m, file=sys.stderr, flush=True)), only=args.only, commit=commit)
    if args.markdown:
        Path(args.markdown).write_text(s["markdown"] + "\n", encoding="utf-8")
    if args.results:
        Path(args.results).write_text(json.dumps(clean_json(s), default=_jd, indent=1) + "\n", encoding="utf-8")
    if args.readme:
        write_readme(Path(args.readme), s["markdown"])
    if args.json:
        print(json.dumps(clean_json(s), default=_jd))
    else:
        print(s["markdown"])
        print(f"\n({s['elapsed_s']:.1f} s)")
    return 0


def register_cli(subparsers) -> None:
    p = subparsers.add_parser("diagnose", help="diagnose the sim-to-real gap of one or more campaigns")
    p.add_argument("paths", nargs="+", metavar="PATH", help="run files or folders")
    p.add_argument("--baseline", default=None,
                   help="effects the model already includes (comma-separated effects.md ids), or 'none' "
                        "for the bare model; default: the pipeline's own processing")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--all-segments", action="store_true", help="with --json: every localisation segment")
    p.add_argument("--report", metavar="DIR", help="write DIR/diagnosis.html (self-contained)")
    p.set_defaults(func=_diagnose)
    b = subparsers.add_parser("diagnose-benchmark",
                              help="score the diagnosis on simulated campaigns with realistic DAQ noise, and on the "
                                   "dev set of the independent reference simulator")
    b.add_argument("--quick", action="store_true", help="a few cases of each kind (a smoke test)")
    b.add_argument("--seeds", type=int, default=2, help="cases per (test, effect, baseline) (default 2)")
    b.add_argument("--clean", type=int, default=200, help="clean campaigns for the false-alarm rate (default 200)")
    b.add_argument("--no-dev", action="store_true", help="skip the dev-set section")
    b.add_argument("--only", default="*", help="glob on the simulated case labels (test/effect/baseline)")
    b.add_argument("--json", action="store_true")
    b.add_argument("--markdown", metavar="FILE", help="also write the markdown report to FILE")
    b.add_argument("--results", metavar="FILE", help="also write every case as JSON to FILE")
    b.add_argument("--readme", metavar="FILE", help="replace the README's diagnosis-benchmark section in FILE")
    b.set_defaults(func=_benchmark)


def main(argv=None) -> int:
    """Standalone use, ``python -m accelcal.diagnosis.cli diagnose ...``: the accelcal CLI
    itself, so errors and exit codes are the same."""
    from ..cli import main as accelcal_main
    return accelcal_main(argv)


if __name__ == "__main__":
    sys.exit(main())

"""CLI: ``accelcal diagnose PATH... --baseline ID[,ID...]|none [--json] [--report DIR]`` and
``accelcal diagnose-benchmark [--quick] [--json] [--markdown FILE]``."""
from __future__ import annotations

import argparse
import json
import sys


def _diagnose(args) -> int:
    from .core import public
    from .data import make_cells, read_paths
    from .report import _jd, html_report, text_report
    from .core import diagnose
    loaded = read_paths(args.paths)
    if not loaded:
        print("diagnose: no readable run files", file=sys.stderr)
        return 2
    runs = [make_cells(m, d, p) for m, d, p in loaded]
    base = None
    if args.baseline is not None:
        base = "none" if args.baseline.strip().lower() == "none" else [
            b.strip() for b in args.baseline.split(",") if b.strip()]
    try:
        res = diagnose(runs, base)
    except ValueError as e:
        print(f"diagnose: {e}", file=sys.stderr)
        return 2
    if args.report:
        p = html_report(res, args.report)
        print(f"report: {p}", file=sys.stderr)
    if args.json:
        pub = public(res)
        if not args.all_segments:
            pub.pop("where_all", None)
        print(json.dumps(pub, default=_jd, allow_nan=False if False else True))
    else:
        print(text_report(res))
    return 0


def _benchmark(args) -> int:
    from .benchmark import run_benchmark
    from .report import _jd
    s = run_benchmark(quick=args.quick, log=(lambda m: print(m, file=sys.stderr)))
    if args.markdown:
        with open(args.markdown, "w", encoding="utf-8") as fh:
            fh.write(s["markdown"] + "\n")
    if args.json:
        print(json.dumps(s, default=_jd))
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
    b = subparsers.add_parser("diagnose-benchmark", help="score the diagnosis on simulated campaigns")
    b.add_argument("--quick", action="store_true", help="one size, one noise level, few clean cases (CI)")
    b.add_argument("--json", action="store_true")
    b.add_argument("--markdown", metavar="FILE", help="also write the markdown tables to FILE")
    b.set_defaults(func=_benchmark)


def main(argv=None) -> int:     # standalone use: python -m accelcal.diagnosis.cli ...
    ap = argparse.ArgumentParser(prog="accelcal")
    sp = ap.add_subparsers(dest="cmd", required=True)
    register_cli(sp)
    a = ap.parse_args(argv)
    return a.func(a)


if __name__ == "__main__":
    sys.exit(main())

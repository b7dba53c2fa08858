"""Subcommands of the validation wing: ``accelcal montecarlo`` (the Monte Carlo validity
study of the estimators) and ``accelcal diagnose-benchmark`` (the diagnosis scored on
simulated campaigns and on the dev set)."""
from __future__ import annotations

import argparse
import json
import sys


def _run(args: argparse.Namespace) -> int:
    from ..validation.montecarlo import run_study
    res = run_study(args.scenario, n=args.n, seed=args.seed, workers=args.workers)
    text = json.dumps(res.to_dict(), indent=1, default=str) if args.json else res.to_markdown()
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text)
    else:
        print(text)
    return 0


def _benchmark(args) -> int:
    import subprocess
    from pathlib import Path

    from ..validation.diagnosis_benchmark import run_benchmark, write_readme
    from .diagnosis_report import _jd, clean_json
    commit = ""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).resolve().parent, check=True).stdout.strip()
        # the package's own files: the README and results this command writes do not count
        pkg = Path(__file__).resolve().parents[1]
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", "."],
                               capture_output=True, text=True, cwd=pkg).stdout.strip()
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
    """Add ``montecarlo`` and ``diagnose-benchmark``."""
    p = subparsers.add_parser("montecarlo", help="Monte Carlo validity study of the estimators",
                              description="Simulate N campaigns of a scenario, process each and report "
                              "bias, sd against the stated u, coverage of the 95 % intervals and "
                              "var/CRB per coefficient. A bare name means a shipped scenario.")
    p.add_argument("scenario", help="scenario TOML file (or the name of a shipped scenario)")
    p.add_argument("--n", type=int, default=200, help="number of campaigns (default 200)")
    p.add_argument("--seed", type=int, default=0, help="first seed (campaign i uses seed + i)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    p.add_argument("--json", action="store_true", help="write JSON instead of markdown")
    p.add_argument("--out", default=None, help="write to this file instead of stdout")
    p.set_defaults(func=_run)
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


register = register_cli

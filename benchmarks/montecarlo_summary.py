#!/usr/bin/env python
"""Summarise the Monte Carlo studies (``bench_montecarlo.py --json``) for the README.

    python benchmarks/montecarlo_summary.py [--readme README.md]

Reads ``benchmarks/results/montecarlo-<scenario>.json`` (and the commit from the header of
the ``.md`` beside it) and prints one row per adopted main coefficient (method
``joint_ml``): var/CRB with its chi² 95 % interval, coverage of x ± k·u with its Wilson
interval, bias/sd, and whether the issue-9 bands hold (var/CRB ≤ 1.15, coverage 93–97 %,
|bias| < 0.15 sd).  With ``--readme`` the table is written between the
``<!-- montecarlo:begin -->`` / ``<!-- montecarlo:end -->`` markers.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import write_block  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SCENARIOS = ("snj103-lxj100", "qa5512-sine", "hust-m07-thermal")
#: the issue-9 bands for an adopted main coefficient
VAR_CRB_MAX, COVERAGE, BIAS_SD_MAX = 1.15, (0.93, 0.97), 0.15


def rows(scenario: str) -> tuple[dict, str, list[dict]]:
    data = json.loads((RESULTS / f"montecarlo-{scenario}.json").read_text(encoding="utf-8"))
    head = (RESULTS / f"montecarlo-{scenario}.md").read_text(encoding="utf-8").split("\n", 1)[0]
    m = re.search(r"at commit (\S+):", head)
    main = [c for c in data["coefficients"] if c["main"] and c["method"] == "joint_ml"]
    return data, (m.group(1) if m else "not recorded"), main


def verdict(c: dict) -> str:
    bad = []
    if c["var_over_crb"] is None or c["var_over_crb"] > VAR_CRB_MAX:
        bad.append("var/CRB")
    if c["coverage"] is None or not COVERAGE[0] <= c["coverage"] <= COVERAGE[1]:
        bad.append("coverage")
    if c["bias_over_sd"] is None or abs(c["bias_over_sd"]) >= BIAS_SD_MAX:
        bad.append("bias")
    return "holds" if not bad else "**fails: " + ", ".join(bad) + "**"


def interval(x, ci, scale: float, fmt: str) -> str:
    """``x (lo–hi)`` scaled for display; '—' for what the study did not compute."""
    if x is None:
        return "—"
    text = fmt.format(scale * x)
    return text if not ci else f"{text} ({scale * ci[0]:.{1 if scale == 100 else 2}f}–{scale * ci[1]:.{1 if scale == 100 else 2}f})"


def table() -> str:
    out = ["Adopted main coefficients (`joint_ml`), from `python benchmarks/bench_montecarlo.py "
           "--n 1000 --workers 2 --json` and `python benchmarks/montecarlo_summary.py --readme "
           "README.md`. Bands: var/CRB ≤ 1.15 against the whole-campaign Cramér–Rao bound, "
           "coverage of x ± k·u within 93–97 %, |bias| < 0.15 sd.", "",
           "| scenario (n, commit) | coefficient | var/CRB (95 %) | coverage (Wilson 95 %) | bias/sd | bands |",
           "|---|---|---|---|---|---|"]
    for sc in SCENARIOS:
        data, commit, main = rows(sc)
        for c in main:
            out.append(f"| {sc} ({data['n']}, {commit}) | {c['name']} | "
                       f"{interval(c['var_over_crb'], c['var_over_crb_interval'], 1, '{:.3f}')} | "
                       f"{interval(c['coverage'], c['coverage_wilson'], 100, '{:.1f} %')} | "
                       f"{'—' if c['bias_over_sd'] is None else format(c['bias_over_sd'], '+.3f')} | "
                       f"{verdict(c)} |")
    out += ["", "The papers' methods in the same studies (var/CRB; they are kept as the cross-check):"]
    for sc in SCENARIOS:
        data = json.loads((RESULTS / f"montecarlo-{sc}.json").read_text(encoding="utf-8"))
        names = {c["name"] for c in data["coefficients"] if c["main"] and c["method"] == "joint_ml"}
        paper = [f"{c['name']} ({c['method']}) {c['var_over_crb']:.2g}" for c in data["coefficients"]
                 if c["method"] != "joint_ml" and c["name"] in names and c["var_over_crb"] is not None]
        out.append(f"{sc}: {', '.join(paper) or 'none with a bound'}.")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readme", type=Path)
    args = ap.parse_args()
    md = table()
    print(md)
    if args.readme:
        write_block(args.readme, "montecarlo", md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

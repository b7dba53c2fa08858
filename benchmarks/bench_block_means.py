#!/usr/bin/env python
"""What taking a run as block means of its dwells does to the adopted values (issue 28).

    python benchmarks/bench_block_means.py [--readme README.md]

A run of more than ``fitting.data.BLOCK_READINGS`` readings is taken by the science as
the means of near-equal blocks of consecutive readings of one dwell.  No sample run is
that long, so this script lowers the threshold until the sample runs are taken as blocks
of two or three readings -- far shorter blocks, and far fewer of them per dwell, than a
real long run gets (11 readings, thousands of blocks a dwell, at 1 GB), so the changes
are larger here than there -- and compares every adopted value and its u with the
in-memory result on the same runs (the independent reference simulator's sample drops,
``../shared/examples``).  A block mean weighs a dwell's readings by up to 1/length
unequally: the value moves by a fraction of its u of the order of 1/length, the
uncertainty by what fewer pure-error degrees of freedom allow.

--readme writes the table between ``<!-- bench_block_means:begin -->`` and ``...:end -->``.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = Path(os.environ.get("ACCELCAL_SHARED", ROOT.parent / "shared")) / "examples"
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_block import commit, write_block  # noqa: E402

#: drop -> BLOCK_READINGS that makes its runs blocks of 2-3 readings
CASES = {"drop-2026-11-20": 100, "drop-2026-11-18-thermal": 1200}


def compare(drop: str, threshold: int) -> dict:
    from accelcal.estimators.campaign import process_campaign
    from accelcal.fitting import data as fdata
    from accelcal.schemas import dropformat, tables
    runs = [dropformat.read_run(f) for f in sorted((EXAMPLES / drop).glob("**/*.csv"))]
    whole = process_campaign(runs)
    keep = fdata.BLOCK_READINGS
    fdata.BLOCK_READINGS = threshold
    try:
        with tempfile.TemporaryDirectory() as tmp:
            taken = [tables.read_run_parquet(tables.write_run_parquet(r, tmp),
                                             blocks=fdata.long_run_blocks) for r in runs]
            blocks = process_campaign(taken)
    finally:
        fdata.BLOCK_READINGS = keep
    most = sorted({r.meta[fdata.BLOCK_META_KEY][2] for r in taken if fdata.BLOCK_META_KEY in r.meta})
    a = {c.name: c for c in whole.coefficients if c.adopted}
    b = {c.name: c for c in blocks.coefficients if c.adopted}
    dz = [(b[k].value - a[k].value) / a[k].std_uncertainty for k in a]
    ur = [b[k].std_uncertainty / a[k].std_uncertainty for k in a]
    return {"drop": drop, "runs": len(runs), "blocked": sum(fdata.BLOCK_META_KEY in r.meta for r in taken),
            "most": most, "n": len(a), "max_dz": max(abs(z) for z in dz),
            "ur": (min(ur), max(ur)), "same_names": a.keys() == b.keys()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--readme", type=Path)
    args = ap.parse_args(argv)
    rows = [compare(d, t) for d, t in CASES.items()]
    lines = ["| sample drop | runs taken as blocks | readings a block | adopted values | largest shift of a value | u blocks / u whole |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['drop']} | {r['blocked']} of {r['runs']} | {' or '.join(map(str, r['most']))} "
                     f"(at most) | {r['n']}{'' if r['same_names'] else ' (names differ!)'} | "
                     f"{r['max_dz']:.2f} u | {r['ur'][0]:.2f} to {r['ur'][1]:.2f} |")
    text = "\n".join(lines)
    print(text)
    if args.readme:
        body = (f"`python benchmarks/bench_block_means.py --readme README.md`, commit {commit()}: "
                "the sample campaigns with every run taken as blocks of two or three readings, "
                "against the same runs taken whole:\n\n" + text + "\n")
        write_block(args.readme, "bench_block_means", body)
    return 0 if all(r["same_names"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())

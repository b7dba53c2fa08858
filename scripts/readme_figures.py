#!/usr/bin/env python
"""Regenerate the README figures that come from the lab's example drops, so none is typed.

Runs the pipeline (local engine) on ../shared/examples/drop-2026-11-20, drop-2026-11-21 and
drop-bad into a temporary warehouse, reads the views, and rewrites every block between

    <!-- readme_figures:NAME -->  ...  <!-- /readme_figures -->

in README.md and accelcal/warehouse/README.md, stamped with the commit it ran on (and
"+dirty" when accelcal/ had uncommitted changes).  Blocks: ``rig-comparison`` (the
one-line summary in README.md) and ``example-drops`` (the paragraph in the warehouse
README).  Usage: ``python scripts/readme_figures.py [--check]`` (--check: exit 1 if a
figure in a README differs from a fresh run, the commit stamp aside; write nothing).
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT.parent / "shared" / "examples"
DROPS = ("drop-2026-11-20", "drop-2026-11-21", "drop-bad")
STAMP = re.compile(r"commit [0-9a-z+]+\)")
TARGETS = (ROOT / "README.md", ROOT / "accelcal" / "warehouse" / "README.md")
BLOCK = re.compile(r"(?P<indent>[ \t]*)<!-- readme_figures:(?P<name>[\w-]+) -->\n(?P<body>.*?)"
                   r"[ \t]*<!-- /readme_figures -->", re.S)


def commit() -> str:
    def git(*a):
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    rev = git("rev-parse", "--short", "HEAD") or "unknown"
    return rev + ("+dirty" if git("status", "--porcelain", "--", "accelcal", ":!*.md") else "")


def figures() -> dict[str, str]:
    sys.path.insert(0, str(ROOT))
    from accelcal.flows.pipeline import run_pipeline
    from accelcal.warehouse import Warehouse
    with tempfile.TemporaryDirectory() as tmp:
        wh = Warehouse(Path(tmp) / "lab.duckdb")
        run_pipeline([str(EXAMPLES / d) for d in DROPS], wh.path, engine="local")
        rc = {r["rig_id"]: r for r in wh.query(
            "SELECT rig_id, value, en FROM rig_comparison WHERE unit_serial = 'SNJ-1-03' "
            "AND name = 'Kip' ORDER BY rig_id")}
        (pair,) = wh.query("SELECT en FROM rig_pairs WHERE unit_serial = 'SNJ-1-03' AND name = 'Kip'")
        k2 = {r["rig_id"]: r["value"] for r in wh.query(
            "SELECT rig_id, value FROM rig_comparison WHERE unit_serial = 'SNJ-1-03' AND name = 'K2'")}
        ch = wh.query("SELECT name, method, prev_value, value, en FROM coefficient_changes "
                      "WHERE unit_serial = 'SNJ-1-03' ORDER BY abs(en) DESC")
        small = wh.query("SELECT campaign, completeness FROM results_current "
                         "WHERE completeness = 'incomplete'")
    a, b = rc["LXJ-100"], rc["LXJ-200"]
    stamp = f"(`python scripts/readme_figures.py`, commit {commit()})"
    flagged = [c for c in ch if abs(c["en"]) > 1]
    k2_rel = abs(k2["LXJ-200"] - k2["LXJ-100"]) / k2["LXJ-100"]
    line = (f"On the sample drops, the adopted Kip on LXJ-100 vs LXJ-200 is {a['value']:.5g} / "
            f"{b['value']:.5g} s²/m with En {a['en']:+.3f} / {b['en']:+.3f} against their mean "
            f"(pairwise {pair['en']:+.3f}) {stamp}.")
    changes = "; ".join(f"{c['name']} ({c['method']}, {c['prev_value']:.4g} → {c['value']:.4g}, "
                        f"En = {c['en']:+.2f})" for c in flagged) or "nothing"
    para = (f"On the example drops (drop-2026-11-20 = SNJ-1-03 on LXJ-100, drop-2026-11-21 = the "
            f"same unit on LXJ-200, drop-bad), `rig_comparison` gives the adopted Kip = "
            f"{a['value']:.5g} / {b['value']:.5g} with En = {a['en']:+.3f} / {b['en']:+.3f} "
            f"(`rig_pairs`: {pair['en']:+.3f}). `coefficient_changes` holds {len(ch)} changes "
            f"of adopted values and flags {changes}; the centrifuge K2 agrees to "
            f"{100 * k2_rel:.2f} %. drop-bad's ok-small.csv is stored as "
            f"{', '.join(repr(s['campaign']) for s in small)} (incomplete) and is in none of "
            f"them {stamp}.")
    return {"rig-comparison": line, "example-drops": para}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a README would change")
    args = ap.parse_args()
    figs = figures()
    changed = []
    for path in TARGETS:
        text = path.read_text()

        def sub(m):
            if m.group("name") not in figs:
                raise SystemExit(f"{path}: unknown block {m.group('name')!r}")
            ind, name = m.group("indent"), m.group("name")
            return (f"{ind}<!-- readme_figures:{name} -->\n{ind}{figs[name]}\n"
                    f"{ind}<!-- /readme_figures -->")
        new = BLOCK.sub(sub, text)
        if STAMP.sub("", new) != STAMP.sub("", text) or (new != text and not args.check):
            changed.append(path)
            if not args.check:
                path.write_text(new)
    for p in changed:
        print(f"{'would update' if args.check else 'updated'} {p.relative_to(ROOT)}")
    return 1 if (args.check and changed) else 0


if __name__ == "__main__":
    sys.exit(main())

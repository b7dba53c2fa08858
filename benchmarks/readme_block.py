"""Write a benchmark's figures into the README between its markers, stamped with the commit.

Every figure in the README comes from a script; each script calls :func:`write_block`
with its own block name, so the README section reads

    <!-- NAME:begin -->
    ...text written by the script...
    <!-- NAME:end -->

and nothing between the markers is typed by hand.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def commit() -> str:
    """Short hash of HEAD of the checkout whose ``accelcal`` is imported (PYTHONPATH may name
    another one than this script's), with ``+changes`` when its tracked files differ from it
    (the README and ``benchmarks/results/``, which the scripts write, do not count)."""
    try:
        import accelcal
        where = Path(accelcal.__file__).resolve().parents[1]
    except ImportError:
        where = ROOT

    def git(*a: str) -> str:
        try:
            return subprocess.run(["git", *a], cwd=where, capture_output=True, text=True).stdout.strip()
        except OSError:
            return ""
    sha = git("rev-parse", "--short", "HEAD") or "unknown"
    # the README and the results folder are what the scripts write, not what they run
    changed = [ln for ln in git("status", "--porcelain", "--untracked-files=no").splitlines()
               if ln[2:].strip() != "README.md" and not ln[2:].strip().startswith("benchmarks/results/")]
    return sha + ("+changes" if changed else "")


def write_block(readme: Path, name: str, body: str) -> None:
    """Replace the text between ``<!-- name:begin -->`` and ``<!-- name:end -->`` in *readme*.

    Raises
    ------
    SystemExit
        When the README lacks either marker (the section must be placed by hand once).
    """
    text = readme.read_text(encoding="utf-8")
    a, b = f"<!-- {name}:begin -->\n", f"<!-- {name}:end -->"
    if a not in text or b not in text:
        raise SystemExit(f"{readme}: no '{a.strip()}' ... '{b}' markers to write {name} into")
    i, j = text.index(a) + len(a), text.index(b)
    readme.write_text(text[:i] + body.rstrip("\n") + "\n" + text[j:], encoding="utf-8")

"""The runs a diagnosis reads: run files or folders of them, in the drop format."""
from __future__ import annotations

from ..textout import warn


def read_paths(paths) -> list:
    """Run files or folders -> parsed runs (drop format); a file the parser refuses is
    skipped with its reason on stderr (it is not ours to diagnose).

    Parameters
    ----------
    paths : iterable of str or Path
        Run files (``*.csv``) or folders (every run file in them, as a drop is read).

    Returns
    -------
    list of RunFile
        Parsed runs (typed ``meta`` and ``data`` columns), files in the order given and,
        within a folder, sorted (:func:`accelcal.schemas.dropscan.discover`); empty when
        nothing could be read.
    """
    from pathlib import Path

    from ..schemas.dropformat import read_run
    from ..schemas.dropscan import discover
    files: list[Path] = []
    for p in paths:
        p = Path(p)
        files += discover(p) if p.is_dir() else [p]
    out = []
    for f in files:
        try:
            out.append(read_run(f))
        except Exception as e:  # noqa: BLE001 - a refused file: say so, diagnose the rest
            warn(f"diagnose: skipping {f}: {e}")
    return out

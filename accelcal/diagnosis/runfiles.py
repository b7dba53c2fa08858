"""The runs a diagnosis reads: run files or folders of them, in the drop format."""
from __future__ import annotations

from ..schemas.dropspec import SMALL_FILE
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
            out.append(read_run(f) if f.stat().st_size <= SMALL_FILE else _read_long(f))
        except Exception as e:  # noqa: BLE001 - a refused file: say so, diagnose the rest
            warn(f"diagnose: skipping {f}: {e}")
    return out


def _read_long(path) -> object:
    """A run file over SMALL_FILE as the pipeline's science takes it: parsed into
    a Parquet file in a temporary folder as it is read, then read back a slice at a time
    as the block means of its dwells when it is long
    (:func:`accelcal.fitting.data.long_run_blocks`), whole otherwise; the folder is gone
    when the run is returned.  Raises what the parser raises, and ValueError when the
    file changed while it was read."""
    import tempfile

    from ..fileio import sha256_fd
    from ..fitting.data import long_run_blocks
    from ..schemas import dropformat, tables
    with open(path, "rb", buffering=0) as fh:
        sha, size = sha256_fd(fh.fileno())
    with tempfile.TemporaryDirectory(prefix="accelcal-run-") as tmp:
        stream = tables.RunParquetStream(tmp, sha, size)
        try:
            with open(path, "rb", buffering=0) as fh:
                run = dropformat.parse_run(fh, str(path), stream)
            if run.sha256 != stream.sha256:
                raise ValueError("the file changed while it was read")
            written = stream.commit()
        finally:
            stream.abort()
        return tables.read_run_parquet(written, blocks=long_run_blocks)

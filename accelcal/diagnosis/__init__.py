"""Sim-to-real gap diagnosis: which catalogue effect the forward model
misses, its size, where the gap lies and what shape it has, how far it shrinks in sample
and held out; or that a gap remains that no catalogue effect explains.

    diagnose(runs, baseline=None|'none'|[ids]) -> dict   (runs: RunFile-like or RunCells)
    diagnose_paths(paths, baseline) -> dict              (run files or folders)

The ``diagnose`` command and its text and HTML reports are in :mod:`accelcal.ops`
(:mod:`~accelcal.ops.diagnose_cli`, :mod:`~accelcal.ops.diagnosis_report`).
"""
from .runfiles import read_paths  # noqa: F401
from .core import diagnose, public  # noqa: F401


def diagnose_paths(paths, baseline=None, **kw):
    """Read run files/folders (drop format) and diagnose them together.

    Parameters
    ----------
    paths : iterable of str or Path
        Run files (``*.csv``) or folders (:func:`accelcal.diagnosis.runfiles.read_paths`;
        a file the parser refuses is skipped with its reason on stderr).
    baseline : None, 'none', str or list of str
        Effects the model already includes: None = the pipeline's processing model for the
        tests present, 'none' = the bare model, or effects.md ids.
    **kw
        Further options of :func:`accelcal.diagnosis.core.diagnose` (``alpha``,
        ``max_effects``, ``refit_top``).

    Returns
    -------
    dict
        The diagnosis of all the runs read in one model
        (:func:`~accelcal.diagnosis.core.diagnose`).
    """
    return diagnose(read_paths(paths), baseline, **kw)

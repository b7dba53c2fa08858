"""Sim-to-real gap diagnosis (issues 4 and 10): which catalogue effect the forward model
misses, its size, where the gap lies and what shape it has, how far it shrinks in sample
and held out; or that a gap remains that no catalogue effect explains.

    diagnose(runs, baseline=None|'none'|[ids]) -> dict   (runs: RunFile-like or RunCells)
    diagnose_paths(paths, baseline) -> dict              (run files or folders)
    register_cli(subparsers)                             # `diagnose`, `diagnose-benchmark`
"""
from .cli import register_cli  # noqa: F401
from .runfiles import read_paths  # noqa: F401
from .core import diagnose, public  # noqa: F401


def diagnose_paths(paths, baseline=None, **kw):
    """Read run files/folders (drop format) and diagnose them together."""
    return diagnose(read_paths(paths), baseline, **kw)

"""Sim-to-real gap diagnosis (issue 4): which catalogue effect the forward model misses,
its size, where the gap lies, how far it shrinks in sample and held out.

    diagnose(runs, baseline=None|'none'|[ids]) -> dict     (runs: data.make_cells(meta, data))
    register_cli(subparsers)                                # `diagnose`, `diagnose-benchmark`
"""
from .cli import register_cli  # noqa: F401
from .core import DEFAULT_BASELINE, diagnose, public  # noqa: F401
from .data import make_cells, read_paths  # noqa: F401


def diagnose_paths(paths, baseline=None, **kw):
    """Read run files/folders and diagnose them."""
    return diagnose([make_cells(m, d, p) for m, d, p in read_paths(paths)], baseline, **kw)

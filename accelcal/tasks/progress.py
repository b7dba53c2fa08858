"""Progress reporting from pipeline steps to whoever shows it (the CLI's rich bar).

A process-wide reporter (not a flow parameter: Prefect would try to serialise it).
"""
from __future__ import annotations

import threading
from typing import Protocol


class Reporter(Protocol):
    def stage(self, name: str, total: int | None) -> None: ...
    def advance(self, name: str, n: int = 1, note: str = "") -> None: ...


class _Null:
    def stage(self, name, total):
        pass

    def advance(self, name, n=1, note=""):
        pass


_lock = threading.Lock()
_reporter: Reporter = _Null()


def set_reporter(r: Reporter | None) -> None:
    global _reporter
    with _lock:
        _reporter = r if r is not None else _Null()


def stage(name: str, total: int | None = None) -> None:
    try:
        _reporter.stage(name, total)
    except Exception:  # a display problem must never break the pipeline
        pass


def advance(name: str, n: int = 1, note: str = "") -> None:
    try:
        _reporter.advance(name, n, note)
    except Exception:
        pass

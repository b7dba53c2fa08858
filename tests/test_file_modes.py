"""What accelcal writes follows the umask, so the lab's colleagues can read it (issue 28);
the raw drop is left as it came."""
from __future__ import annotations

import os
import stat

import pytest

from accelcal.fileio import atomic_write, current_umask
from accelcal.flows.pipeline import quiet_prefect, run_pipeline

from conftest import EXAMPLES  # noqa: E402  (ACCELCAL_SHARED, else ../shared)
SAMPLE = EXAMPLES / "drop-2026-11-20"

quiet_prefect()


@pytest.fixture
def umask():
    def set_(mask):
        old = os.umask(mask)
        restore.append(old)
    restore: list[int] = []
    yield set_
    if restore:
        os.umask(restore[0])


@pytest.mark.parametrize("mask, want", [(0o022, 0o644), (0o027, 0o640), (0o077, 0o600)])
def test_atomic_write_gives_the_mode_of_an_ordinary_open(tmp_path, umask, mask, want):
    umask(mask)
    assert current_umask() == mask
    p = atomic_write(tmp_path / "x.txt", lambda fh: fh.write(b"x"))
    assert stat.S_IMODE(p.stat().st_mode) == want


@pytest.mark.skipif(not SAMPLE.is_dir(), reason="needs the lab's sample drops at ../shared (see README)")
def test_every_file_a_run_writes_is_readable_by_the_lab(tmp_path, umask):
    umask(0o022)
    modes_before = {p: p.stat().st_mode for p in SAMPLE.rglob("*")}
    place = tmp_path / "wh"
    place.mkdir()
    run_pipeline([SAMPLE], place / "lab.duckdb", engine="local")
    unreadable = []
    n = 0
    for p in place.rglob("*"):
        n += 1
        m = stat.S_IMODE(p.stat().st_mode)
        need = 0o055 if p.is_dir() else 0o044
        if m & need != need:
            unreadable.append(f"{p.relative_to(place)} {m:o}")
    assert n > 10, "the run wrote nothing to look at"
    assert not unreadable, unreadable
    assert {p: p.stat().st_mode for p in SAMPLE.rglob("*")} == modes_before

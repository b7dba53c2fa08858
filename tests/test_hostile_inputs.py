"""Hostile inputs (issue 12): what a file can hold must never crash the parser, flood a
message, or cost memory beyond a chunk.  The heavy versions of these probes (200 MB files,
10 MB lines through the whole pipeline) are in benchmarks/bench_faults.py."""
from __future__ import annotations

import io
from pathlib import Path

import pytest

from accelcal.schemas import dropformat
from accelcal.schemas.dropformat import DETAIL_MAX, LINE_MAX, DropFormatError, parse_run, read_run

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "examples"
OK = (REPO / "accelcal" / "demo_data" / "drop-bad" / "ok-small.csv").read_bytes()
_LINES = OK.split(b"\n")
HEADER = next(i for i, s in enumerate(_LINES) if s and not s.startswith(b"#"))


def _refusal(raw: bytes) -> DropFormatError:
    with pytest.raises(DropFormatError) as ei:
        parse_run(io.BytesIO(raw), "x.csv")
    return ei.value


def test_ten_megabyte_header_line_is_refused_in_one_short_message():
    raw = b"\n".join(_LINES[:HEADER]) + b"\n" + b"time_s," * ((10 << 20) // 7) + b"\n1,2\n"
    e = _refusal(raw)
    assert (e.rule, e.line) == ("line-too-long", HEADER + 1)
    assert len(str(e)) < DETAIL_MAX + 20


def test_ten_megabyte_number_is_not_reported_as_infinite():
    row = _LINES[HEADER + 1].split(b",")
    row[0] = b"9" * (10 << 20)
    raw = b"\n".join(_LINES[:HEADER + 1] + [b",".join(row)] + _LINES[HEADER + 2:])
    e = _refusal(raw)
    assert (e.rule, e.line) == ("line-too-long", HEADER + 2) and "inf" not in e.detail
    row[0] = b"9" * 400                                 # short enough for a line, too big for a float
    e = _refusal(b"\n".join(_LINES[:HEADER + 1] + [b",".join(row)] + _LINES[HEADER + 2:]))
    assert (e.rule, e.line) == ("out-of-range", HEADER + 2)
    assert "time_s" in e.detail and "400 characters" in e.detail and len(e.detail) <= DETAIL_MAX


def test_long_metadata_value_is_refused_and_capped():
    value = "[/x] :x: \u202e".encode() * (LINE_MAX // 10)
    raw = OK.replace(b"\n", b"\n# notes: " + value + b"\n", 1)
    e = _refusal(raw)
    assert e.rule == "line-too-long" and len(e.detail) <= DETAIL_MAX


def test_chunk_size_does_not_change_the_result(monkeypatch):
    """The stream is cut into chunks; where the cuts fall must not matter (values, line
    numbers, the first refusal)."""
    files = [SHARED / "drop-2026-11-20" / "centrifuge" / "LXJ100-20261120-0002.csv",
             SHARED / "drop-2026-11-18-thermal" / "TT1-20261118-0001.csv"]
    want = [read_run(p) for p in files]
    ls = OK.split(b"\n")
    bad = b"\n".join(ls[:HEADER + 3] + [b"", b"  "] + ls[HEADER + 3:HEADER + 9]
                     + [ls[HEADER + 9].replace(b",", b",,", 1)] + ls[HEADER + 10:])
    want_bad = _refusal(bad)
    monkeypatch.setattr(dropformat, "CHUNK_BYTES", 257)
    monkeypatch.setattr(dropformat, "BLOCK_BYTES", 61)
    for p, w in zip(files, want):
        assert read_run(p) == w
    e = _refusal(bad)
    assert (e.rule, e.line, e.detail) == (want_bad.rule, want_bad.line, want_bad.detail)

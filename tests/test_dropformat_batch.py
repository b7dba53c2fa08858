"""parse_runs (the batch parse of small files) gives exactly what parse_run gives, file
by file: the same RunFile (arrays, dtypes, meta, meta_raw, lines, sha256) or the same
refusal (path:line: rule: detail), on every sample file and on crafted edge cases."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from accelcal.schemas.dropformat import parse_run, parse_runs
from accelcal.schemas.dropspec import DropFormatError

DEMO = Path(__file__).resolve().parents[1] / "accelcal" / "demo_data"


def _one(raw: bytes, path: str):
    try:
        return parse_run(io.BytesIO(raw), path)
    except DropFormatError as e:
        return e


def _same(a, b) -> None:
    assert type(a) is type(b), (a, b)
    if isinstance(a, DropFormatError):
        assert (str(a), a.path, a.line, a.rule, a.detail) == (str(b), b.path, b.line, b.rule, b.detail)
        return
    assert a == b
    assert (a.sha256, a.size_bytes, a.meta, a.meta_raw, a.meta_lines, a.header_line, a.n_rows) == \
        (b.sha256, b.size_bytes, b.meta, b.meta_raw, b.meta_lines, b.header_line, b.n_rows)
    assert list(a.arrays) == list(b.arrays)
    for c in a.arrays:
        x, y = a.arrays[c], b.arrays[c]
        assert x.dtype == y.dtype and x.shape == y.shape, c
        assert np.array_equal(x, y, equal_nan=True), c
        assert np.array_equal(np.signbit(x), np.signbit(y)), c     # -0.0 stays -0.0


def _check(items) -> int:
    got = parse_runs(items)
    assert len(got) == len(items)
    for (raw, path), g in zip(items, got):
        _same(_one(raw, path), g)
    return sum(not isinstance(g, DropFormatError) for g in got)


def _files(root: Path):
    return [(p.read_bytes(), str(p)) for p in sorted(root.rglob("*.csv")) if p.is_file()]


def test_every_sample_and_demo_file(examples):
    items = _files(examples.parent) + _files(DEMO)
    assert len(items) >= 40
    assert _check(items) > 0
    # one at a time too (a group of one), and in reverse order (other groups)
    for it in items:
        _check([it])
    _check(items[::-1])


def _base(examples) -> tuple[bytes, bytes]:
    """A good tumble file of the samples, split into (metadata + header, rows)."""
    for p in sorted((examples / "drop-2026-11-20").rglob("*.csv")):
        raw = p.read_bytes()
        if b"# test: tumble" in raw:
            lines = raw.split(b"\n")
            k = next(i for i, ln in enumerate(lines) if ln and not ln.startswith(b"#"))
            return b"\n".join(lines[:k + 1]) + b"\n", b"\n".join(lines[k + 1:])
    pytest.skip("no tumble sample")


def test_crafted_edge_cases(examples):
    head, rows = _base(examples)
    lines = rows.rstrip(b"\n").split(b"\n")
    row = lines[0]
    ncol = row.count(b",") + 1

    def with_row(i: int, new: bytes) -> bytes:
        ls = list(lines)
        ls[i] = new
        return head + b"\n".join(ls) + b"\n"

    cells = row.split(b",")
    variants = {
        "good": head + rows,
        "no-final-newline": head + rows.rstrip(b"\n"),
        "crlf": (head + rows).replace(b"\n", b"\r\n"),
        "lone-cr": with_row(3, row.replace(b",", b"\r", 1)),
        "blank-line": with_row(2, b""),
        "spaces-line": with_row(2, b"   "),
        "space-in-cell": with_row(2, b" " + row),
        "too-few-fields": with_row(4, b",".join(cells[:-1])),
        "too-many-fields": with_row(4, row + b",1"),
        "empty-cell": with_row(5, b",".join([b""] + cells[1:])),
        "empty-last": with_row(5, b",".join(cells[:-1] + [b""])),
        "non-numeric": with_row(6, b",".join([b"abc"] + cells[1:])),
        "two-points": with_row(6, b",".join([b"1.2.3"] + cells[1:])),
        "lone-e": with_row(6, b",".join([b"e"] + cells[1:])),
        "nan": with_row(6, b",".join([b"nan"] + cells[1:])),
        "inf": with_row(6, b",".join([b"-inf"] + cells[1:])),
        "overflow": with_row(6, b",".join([b"1e999"] + cells[1:])),
        "neg-zero": with_row(6, b",".join([b"-0.0"] + cells[1:])),
        "plus-sign": with_row(6, b",".join([b"+1.5E+2"] + cells[1:])),
        "quote": with_row(6, b",".join([b'"1"'] + cells[1:])),
        "non-utf8": with_row(6, b",".join([b"1\xff"] + cells[1:])),
        "non-integer-position": with_row(7, b",".join(c if k != 1 else b"1.5"
                                                      for k, c in enumerate(cells))),
        "huge-position": with_row(7, b",".join(c if k != 1 else b"1e300"
                                               for k, c in enumerate(cells))),
        "long-line": with_row(7, row + b"0" * 70000),
        "header-only": head,
        "no-rows-blank": head + b"\n",
        "bom": b"\xef\xbb\xbf" + head + rows,
        "empty": b"",
        "only-metadata": head.split(b"\n")[0] + b"\n",
    }
    assert ncol >= 4
    items = [(raw, f"case-{name}.csv") for name, raw in variants.items()]
    assert _check(items) >= 3
    # each bad file beside good ones of the same header: the good ones are still parsed
    # together, the bad one alone, and nothing changes
    good = variants["good"]
    for raw, path in items:
        _check([(good, "a.csv"), (raw, path), (good, "b.csv")])


def test_columns_in_another_order(examples):
    head, rows = _base(examples)
    hl = head.rstrip(b"\n").split(b"\n")
    names = hl[-1].split(b",")
    perm = list(range(len(names)))[::-1]
    new_head = b"\n".join(hl[:-1] + [b",".join(names[k] for k in perm)]) + b"\n"
    new_rows = b"\n".join(b",".join(r.split(b",")[k] for k in perm)
                          for r in rows.rstrip(b"\n").split(b"\n")) + b"\n"
    assert _check([(head + rows, "a.csv"), (new_head + new_rows, "b.csv"),
                   (head + rows, "c.csv")]) == 3

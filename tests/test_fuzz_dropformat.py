"""Fuzz: malformed variants of valid run files are refused cleanly (drop-format.md,
"What the pipeline must refuse"): nothing but DropFormatError from the parser, nothing but
Refusals from the validation, and every refusal has a rule and a detail."""
from __future__ import annotations

import random
import re
import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accelcal.schemas.dropformat import RunFile, read_run
from accelcal.schemas.dropspec import COLUMNS, DropFormatError
from accelcal.schemas.suites import Refusal, validate_runs

from conftest import EXAMPLES, require_shared  # ../shared/examples relative to the repository root

require_shared()


def _head(p: Path, rows: int) -> bytes:
    ls = p.read_bytes().split(b"\n")
    h = next(i for i, s in enumerate(ls) if s and not s.startswith(b"#"))
    return b"\n".join(ls[:h + 1 + rows]) + b"\n"


BASES = [
    (EXAMPLES / "drop-bad/ok-small.csv").read_bytes(),
    _head(EXAMPLES / "drop-2026-11-20/centrifuge/LXJ100-20261120-0002.csv", 60),
    _head(EXAMPLES / "drop-2026-11-19-sine/DC1-20261119-0001.csv", 80),
    _head(EXAMPLES / "drop-2026-11-18-thermal/TT1-20261118-0001.csv", 40),
]
RULE = re.compile(r"^[a-z0-9]+(-[a-z0-9]+)*$")
_DIR = Path(tempfile.mkdtemp(prefix="accelcal-fuzz-"))
PARSED: list[RunFile] = []


# ---- mutations: (raw, rnd) -> raw; rnd is a random.Random or a hypothesis-driven one ----

def _truncate(raw, rnd):
    return raw[:rnd.randrange(len(raw) + 1)]


def _flip(raw, rnd):
    k = rnd.randrange(len(raw))
    return raw[:k] + bytes([rnd.randrange(256)]) + raw[k + 1:]


def _lines_op(raw, rnd, op):
    ls = raw.split(b"\n")
    i = rnd.randrange(len(ls))
    if op == "drop":
        del ls[i]
    elif op == "dup":
        ls.insert(i, ls[i])
    elif op == "swap":
        j = rnd.randrange(len(ls))
        ls[i], ls[j] = ls[j], ls[i]
    elif op == "field":
        f = ls[i].split(b",")
        f.insert(rnd.randrange(len(f) + 1), rnd.choice([b"", b"x", b"1.5", b"nan", b"-inf", b" "]))
        ls[i] = b",".join(f)
    elif op == "cell":
        f = ls[i].split(b",")
        f[rnd.randrange(len(f))] = rnd.choice([b"", b"abc", b"1e999", b"-0", b"1_0", b"0x1F", b"inf",
                                                b"NaN", b"\xc3\xa9", b"1.2.3", b"99999999999999999999"])
        ls[i] = b",".join(f)
    return b"\n".join(ls)


def _non_utf8(raw, rnd):
    k = rnd.randrange(len(raw) + 1)
    return raw[:k] + rnd.choice([b"\xff", b"\xc3", b"\xe9t\xe9", b"\xed\xa0\x80", b"\x80"]) + raw[k:]


def _swap_keys(raw, rnd):
    ls = raw.split(b"\n")
    meta = [i for i, s in enumerate(ls) if s.startswith(b"# ") and b":" in s]
    i, j = rnd.choice(meta), rnd.choice(meta)
    ki, vi = ls[i].split(b":", 1)
    kj, vj = ls[j].split(b":", 1)
    ls[i], ls[j] = ki + b":" + vj, kj + b":" + vi
    return b"\n".join(ls)


def _crlf(raw, rnd):
    return raw.replace(b"\n", b"\r\n")


MUTATIONS = [_truncate, _flip, lambda r, n: _lines_op(r, n, "drop"), lambda r, n: _lines_op(r, n, "dup"),
             lambda r, n: _lines_op(r, n, "swap"), lambda r, n: _lines_op(r, n, "field"),
             lambda r, n: _lines_op(r, n, "cell"), _non_utf8, _swap_keys, _crlf]


def _check_parse(raw: bytes, name: str) -> RunFile | None:
    p = _DIR / name
    p.write_bytes(raw)
    try:
        r = read_run(p)
    except DropFormatError as e:
        assert RULE.match(e.rule), e.rule
        assert e.detail and e.path == str(p)
        assert e.line is None or 1 <= e.line <= raw.count(b"\n") + 1, str(e)
        where = str(p) if e.line is None else f"{p}:{e.line}"
        assert str(e) == f"{where}: {e.rule}: {e.detail}"
        return None
    assert list(r.data.columns) == list(COLUMNS[r.test]) + ["line"]
    assert r.data["line"].is_monotonic_increasing and r.data["line"].iloc[0] > r.header_line
    assert len(r.data) > 0 and r.sha256 and r.size_bytes == len(raw)
    return r


class _HypRandom:
    """random.Random-like face on hypothesis' data draws (so failures shrink)."""

    def __init__(self, data):
        self.data = data

    def randrange(self, n):
        return self.data.draw(st.integers(0, max(n - 1, 0))) if n > 0 else 0

    def choice(self, seq):
        return seq[self.randrange(len(seq))]


@settings(max_examples=100, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(base=st.sampled_from(range(len(BASES))), n=st.integers(1, 3), data=st.data())
def test_parser_refuses_cleanly(base, n, data):
    rnd = _HypRandom(data)
    raw = BASES[base]
    for _ in range(n):
        raw = rnd.choice(MUTATIONS)(raw, rnd)
    r = _check_parse(raw, f"h{len(PARSED)}.csv")
    if r is not None and len(PARSED) < 100:
        PARSED.append(r)


def _check_refusals(res, runs):
    assert set(res) == {r.path for r in runs}
    for path, refs in res.items():
        for x in refs:
            assert isinstance(x, Refusal) and x.path == path
            assert RULE.match(x.rule) and x.rule != "validation-error", str(x)
            assert x.detail, str(x)


def test_validation_of_mutants_refuses_cleanly():
    """Seeded mutants that still parse (plus those of the hypothesis test), validated in one batch."""
    rnd = random.Random(20261121)
    runs = list(PARSED)
    for k in range(160):
        raw = BASES[k % len(BASES)]
        for _ in range(rnd.randint(1, 2)):
            raw = rnd.choice(MUTATIONS[2:7] + [_crlf])(raw, rnd)  # mostly-parseable mutations
        r = _check_parse(raw, f"s{k}.csv")
        if r is not None:
            runs.append(r)
    assert len(runs) >= 20  # the mutants must reach the validation
    res = validate_runs(runs, None, "fuzz")
    _check_refusals(res, runs)
    assert any(res.values())  # some mutants are semantically wrong

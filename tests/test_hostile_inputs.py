"""Hostile inputs (issue 12): what a file can hold must never crash the parser, flood a
message, or cost memory beyond a chunk.  The heavy versions of these probes (200 MB files,
10 MB lines through the whole pipeline) are in benchmarks/bench_faults.py."""
from __future__ import annotations

import io
from pathlib import Path

import pytest

from accelcal.schemas import dropformat, runbody
from accelcal.schemas.dropformat import parse_run, read_run
from accelcal.schemas.dropspec import DETAIL_MAX, LINE_MAX, DropFormatError

REPO = Path(__file__).resolve().parents[1]
from conftest import EXAMPLES as SHARED  # noqa: E402  (ACCELCAL_SHARED, else ../shared)
from conftest import needs_shared  # noqa: E402
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


@needs_shared
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
    monkeypatch.setattr(dropformat, "CHUNK_BYTES", 257)     # the stream's chunks
    monkeypatch.setattr(runbody, "CHUNK_BYTES", 257)        # the row parser's read block
    monkeypatch.setattr(dropformat, "BLOCK_BYTES", 61)
    for p, w in zip(files, want):
        assert read_run(p) == w
    e = _refusal(bad)
    assert (e.rule, e.line, e.detail) == (want_bad.rule, want_bad.line, want_bad.detail)


def test_big_run_columns_are_views_of_the_same_values(monkeypatch):
    """A big run's parsed columns are handed out as views of the parser's buffers, not
    copied to their exact length (issue 28: that copy doubled a 5 M-row run's columns for
    a moment): the run is the same."""
    p = SHARED / "drop-2026-11-18-thermal" / "TT1-20261118-0001.csv"
    want = read_run(p)
    monkeypatch.setattr(runbody, "VIEW_BYTES", 0)
    got = read_run(p)
    assert got == want
    assert all(a.base is not None for a in got.arrays.values())


# ------------------------------------------------------------ the file rules --

import json
import os
import shutil
import subprocess
import sys

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accelcal.schemas.dropscan import Entry, scan_drop, settle_wait
from accelcal.textout import esc, plain


def _tumble(run_id: str, **meta) -> str:
    import re
    text = OK.decode()
    for k, v in dict(meta, run_id=run_id).items():
        text = re.sub(rf"^# {k}:.*$", lambda m: f"# {k}: {v}", text, count=1, flags=re.M)
    return text


def _entries(drop: Path) -> dict[str, tuple | None]:
    return {os.path.relpath(e.path, drop): (e.refusal[0] if e.refusal else None)
            for e in scan_drop(drop)}


def test_scan_refuses_links_fifos_and_bad_names_without_opening_them(tmp_path):
    drop = tmp_path / "drop"
    (drop / "sub").mkdir(parents=True)
    (drop / "sub" / "ok.csv").write_bytes(OK)
    (tmp_path / "outside").mkdir()
    os.symlink("/etc/passwd", drop / "passwd.csv")
    os.symlink("sub/ok.csv", drop / "inside.csv")
    os.symlink(drop / "nowhere.csv", drop / "dangling.csv")
    os.symlink(tmp_path / "outside", drop / "linked-folder")
    os.symlink("sub/ok.csv", drop / "notes.txt")                 # not a run file: ignored
    os.mkfifo(drop / "fifo.csv")
    for name in (b"bad\xffname.csv", b"new\nline.csv"):
        with open(os.path.join(os.fsencode(drop), name), "wb") as f:
            f.write(OK)
    os.mkdir(os.path.join(os.fsencode(drop), b"folder\xfe"))
    got = _entries(drop)
    assert got == {"sub/ok.csv": None, "passwd.csv": "link", "inside.csv": "link",
                   "dangling.csv": "link", "linked-folder": "link", "fifo.csv": "not-a-file",
                   "bad\udcffname.csv": "bad-file-name", "new\nline.csv": "bad-file-name",
                   "folder\udcfe": "bad-file-name"}
    why = {os.path.basename(e.path): e.refusal[1] for e in scan_drop(drop) if e.refusal}
    assert "out of the drop" in why["passwd.csv"] and "inside the drop" in why["inside.csv"]
    assert "dangling" in why["dangling.csv"] and "folder" in why["linked-folder"]
    assert "byte 0xff" in why["bad\udcffname.csv"]


def test_settle_wait_holds_back_a_file_that_keeps_changing(tmp_path):
    f = tmp_path / "a.csv"
    f.write_bytes(OK)
    st0 = f.stat()
    t = [st0.st_mtime_ns / 1e9]                 # a clock that starts at the file's mtime

    def sleep(s):
        t[0] += s
        with open(f, "ab") as fh:               # the DAQ writes on while we wait
            fh.write(b"\n")
        os.utime(f, ns=(int(t[0] * 1e9), int(t[0] * 1e9)))
    ready, held = settle_wait([Entry(str(f), st0.st_size, st0.st_mtime_ns)], 2.0, 5.0,
                              sleep=sleep, clock=lambda: t[0])
    assert ready == [] and "still being written" in held[0][1]
    st1 = f.stat()
    t = [st1.st_mtime_ns / 1e9 + 0.5]
    ready, held = settle_wait([Entry(str(f), st1.st_size, st1.st_mtime_ns)], 2.0, 5.0,
                              sleep=lambda s: t.__setitem__(0, t[0] + s), clock=lambda: t[0])
    assert [e.path for e in ready] == [str(f)] and held == []      # waited 1.5 s, then read


def test_hostile_drop_costs_no_good_file_and_prints_as_text(tmp_path, examples, capsys):
    """One run over the sample drop plus every kind of hostile entry: each refused with its
    rule, recorded, printed on one line as text; the good files and their campaign are
    untouched; a second run adds nothing.  (The full-size probes: bench_faults.py.)"""
    from accelcal import cli
    from accelcal.warehouse import Warehouse
    drop = tmp_path / "drop"
    shutil.copytree(examples / "drop-2026-11-20", drop)
    os.chmod(drop, 0o755)
    good = {p.name for p in drop.rglob("*.csv")}
    os.symlink("/etc/passwd", drop / "passwd.csv")
    os.mkfifo(drop / "fifo.csv")
    with open(os.path.join(os.fsencode(drop), b"bad\xffname.csv"), "w") as f:
        f.write(_tumble("NAME-1"))
    (drop / "markup.csv").write_text(_tumble("MK-1", campaign="C[/x]:x:[bold]", rig_id=":x:"))
    (drop / "markup-test.csv").write_text(_tumble("MK-2", test="[/x] :x:"))
    (drop / "long-ids.csv").write_text(_tumble("R" * 300, unit_serial="S" * 300))
    lines = OK.split(b"\n")
    (drop / "long-line.csv").write_bytes(b"\n".join(lines[:HEADER + 1] + [b"9" * (LINE_MAX + 1)]))
    (drop / "ctl.csv").write_text(_tumble("CTL-1", campaign="a\x1b[2Jb\u202ec"))
    wh = tmp_path / "wh" / "lab.duckdb"
    rc = cli.main(["run", str(drop), "-w", str(wh), "--create", "--engine", "local", "-q",
                   "--settle", "0"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    rows = {os.path.basename(r["source_path"]): r for r in Warehouse(wh).query(
        "SELECT r.source_path, r.status, f.rule, r.reason FROM runs r LEFT JOIN refusals f "
        "USING (sha256, source_path)")}
    want = {"passwd.csv": "link", "fifo.csv": "not-a-file", "bad\\xffname.csv": "bad-file-name",
            "markup-test.csv": "unknown-test", "long-line.csv": "line-too-long"}
    assert {n: rows[n]["rule"] for n in want} == want
    assert all(rows[n]["status"] == "accepted" for n in good | {"markup.csv", "long-ids.csv", "ctl.csv"})
    assert "root:" not in out and "\u274c" not in out                 # nothing read, no emoji
    assert "C[/x]:x:[bold]" in out and "'[/x] :x:'" in out             # printed as text
    assert "\x1b" not in out and "\u202e" not in out and "a\\x1b[2Jb\\u202ec" in out
    refused = [ln for ln in out.splitlines() if ln.lstrip().startswith("refused")]
    assert len(refused) == len(want) and all(len(ln) < 420 for ln in refused)
    # again: nothing new, nothing crashes
    rc = cli.main(["run", str(drop), "-w", str(wh), "--engine", "local", "--json", "--settle", "0"])
    s = json.loads(capsys.readouterr().out)
    assert rc == 0 and sum(d["new"] for d in s["drops"]) == 0


@pytest.mark.skipif(os.geteuid() == 0 and not shutil.which("setpriv"),
                    reason="as root, needs setpriv to make permission bits bind")
def test_unreadable_file_and_folder_are_refused_with_the_os_reason(tmp_path):
    """As root, permission bits only bind without CAP_DAC_OVERRIDE: the scan and ingest run
    in a child under ``setpriv --bounding-set=-dac_override,-dac_read_search``."""
    drop = tmp_path / "drop"
    (drop / "closed").mkdir(parents=True)
    (drop / "ok.csv").write_bytes(OK)
    (drop / "secret.csv").write_bytes(OK.replace(b"BAD-0001", b"SECRET-1"))
    (drop / "closed" / "x.csv").write_bytes(OK)
    os.chmod(drop / "secret.csv", 0)
    os.chmod(drop / "closed", 0)
    code = ("import json, sys; from accelcal.tasks.ingest import ingest_drop\n"
            "ing = ingest_drop(sys.argv[1], sys.argv[2], sys.argv[3], {})\n"
            "print(json.dumps({__import__('os').path.basename(r.source_path): "
            "[r.status, r.refusals[0].rule if r.refusals else None, r.reason] for r in ing.records}))")
    pre = ["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--"] if os.geteuid() == 0 else []
    try:
        p = subprocess.run(pre + [sys.executable, "-c", code, str(drop), str(tmp_path / "pq"),
                                  str(tmp_path)], capture_output=True, text=True, timeout=120)
    finally:
        os.chmod(drop / "closed", 0o755)
    assert p.returncode == 0, p.stderr[-2000:]
    got = json.loads(p.stdout.strip().splitlines()[-1])
    assert got["ok.csv"][0] == "accepted"
    assert got["secret.csv"][:2] == ["refused", "unreadable"] and "Permission denied" in got["secret.csv"][2]
    assert got["closed"][:2] == ["refused", "unreadable"]


# --------------------------------------------------- never a crash (hypothesis) --

_NAME = st.binary(min_size=1, max_size=40).filter(
    lambda b: b"/" not in b and b"\0" not in b and b not in (b".", b".."))
_VALUE = st.one_of(st.text(max_size=40),
                   st.builds(lambda c, n: c * n, st.characters(), st.integers(0, 3 * LINE_MAX)))
_KEYS = ("run_id", "campaign", "unit_serial", "rig_id", "unit_model", "test", "started_at",
         "g_local_m_s2", "notes")


@settings(max_examples=6, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                 HealthCheck.data_too_large])
@given(files=st.lists(st.tuples(_NAME, st.sampled_from(_KEYS), _VALUE, st.booleans()),
                      min_size=1, max_size=6))
def test_any_file_name_and_metadata_value_never_crash_a_run(tmp_path_factory, files):
    """Names of any bytes (*.csv or not) and metadata values of any unicode and length:
    each file is accepted, refused with a rule or ignored; the good file is always
    accepted; nothing crashes; the CLI prints the summary."""
    from accelcal.cli import print_summary
    from accelcal.flows.pipeline import run_pipeline
    from accelcal.textout import console
    d = tmp_path_factory.mktemp("names")
    drop = d / "drop"
    drop.mkdir()
    (drop / "good.csv").write_bytes(OK)
    names = set()
    for k, (name, key, value, csv) in enumerate(files):
        name = name + (b".csv" if csv else b"")
        if name in names or name == b"good.csv":
            continue
        names.add(name)
        if key == "notes":
            text = _tumble(f"H-{k}").replace("# test:", f"# notes: {value}\n# test:", 1)
        else:
            text = _tumble(**{"run_id": f"H-{k}", key: value})
        with open(os.path.join(os.fsencode(drop), name), "wb") as f:
            f.write(text.encode("utf-8", "surrogatepass"))
    s = run_pipeline([str(drop)], d / "lab.duckdb", engine="local", settle=0)
    (dr,) = s["drops"]
    assert dr["errors"] == [] and dr["held"] == []
    recorded = {os.path.basename(r["path"]) for r in dr["refused_files"]}
    assert "good.csv" not in recorded and dr["accepted"] >= 1
    csvs = {n for n in names if n.lower().endswith(b".csv")}
    assert dr["files"] == len(csvs) + 1
    for r in dr["refused_files"]:
        assert r["reason"] and len(r["reason"]) < 2 * DETAIL_MAX + len(r["path"]) + 50
    con = console()
    with con.capture() as cap:
        print_summary(s, con)
    assert "Traceback" not in cap.get()


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet=st.characters(codec=None, exclude_categories=())))
def test_text_out_is_one_printable_line_never_markup(s):
    from rich.text import Text
    p = plain(s)
    assert p.isprintable() and "\n" not in p
    p.encode("utf-8")                                     # never an encoding error
    assert Text.from_markup(esc(s), emoji=False).plain in (p, p.rstrip("\\") + "\\" * (p.endswith("\\")))


def test_an_os_error_or_a_change_while_reading_costs_only_that_file(tmp_path, monkeypatch):
    """Per-file isolation in ingest: EIO while reading one file is that file's refusal
    ('unreadable', with the OS's words), a file that grows while it is read is held back
    (not judged, not recorded), and the rest of the batch is ingested."""
    from accelcal.tasks import ingest
    drop = tmp_path / "drop"
    drop.mkdir()
    for name in ("a.csv", "eio.csv", "grows.csv", "z.csv"):
        (drop / name).write_bytes(OK.replace(b"BAD-0001", name.encode()))
    real = ingest._read_all

    def read_all(fd, size):
        name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
        if name == "eio.csv":
            raise OSError(5, "Input/output error")
        raw = real(fd, size)
        if name == "grows.csv":
            with open(drop / name, "ab") as f:
                f.write(b"0,0,0,0,0\n")
        return raw
    monkeypatch.setattr(ingest, "_read_all", read_all)
    ing = ingest.ingest_drop(str(drop), str(tmp_path / "pq"), str(tmp_path), {})
    got = {os.path.basename(r.source_path): (r.status, r.refusals[0].rule if r.refusals else None)
           for r in ing.records}
    assert got == {"a.csv": ("accepted", None), "z.csv": ("accepted", None),
                   "eio.csv": ("refused", "unreadable")}
    assert "Input/output error" in next(r.reason for r in ing.records if r.status == "refused")
    assert len(ing.held) == 1 and "grows.csv" in ing.held[0] and ing.errors == []

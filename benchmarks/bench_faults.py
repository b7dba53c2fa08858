#!/usr/bin/env python
"""Hostile inputs and faults (issue 12): every probe of the issue's table, SIGKILLs under the
Prefect engine and concurrency trials.  A script, not a test (tests/test_hostile_inputs.py
and tests/test_faults.py keep a fast subset).

    python benchmarks/bench_faults.py [--kills 30] [--only NAME[,NAME]] [--out FILE]

Prints a markdown table: probe -> outcome, N tried, N refused clearly, N crashed, N lost.

* tried: hostile files, or runs under the fault;
* refused clearly: a hostile file refused with its rule and a one-line reason in the
  warehouse, or a run under a fault that stopped with exactly one line ``accelcal: error:``
  naming the place and the documented exit code (1);
* crashed: a traceback, an undocumented exit code, a hang, an orphaned process, a
  leftover temporary file, or a file modified that must not be;
* lost: a good file of the drop not in the warehouse as accepted afterwards, a hostile
  file neither refused nor held back, or a warehouse that differs from a clean run's
  after the fault is removed and the run repeated.

Everything runs in fresh ``python -m accelcal`` processes on copies of ../shared/examples.
Faults of the file system are real, which needs root: a read-only bind mount, a tmpfs of
a few MB (disk full), and ``setpriv --bounding-set=-dac_override,-dac_read_search`` so
that a chmod-000 file is unreadable for a process running as root.  Without root those
probes are reported as skipped.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT.parent / "shared" / "examples"
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

EXIT_DOCUMENTED = {0, 1, 2, 130}
NOPRIV = ["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--"]
RESULTS: list[dict] = []


# ----------------------------------------------------------------- helpers --

def _short_paths(s: str) -> str:
    """Absolute paths of the bench's own folders shown by their last part."""
    return re.sub(r"(?<![\w.])/(?:[^\s:;,()'\"/]+/)+([^\s:;,()'\"/]*)", r"…/\1", s)


class Res:
    """One probe's counts."""

    def __init__(self, probe: str):
        self.probe, self.tried, self.clear, self.crashed, self.lost = probe, 0, 0, 0, 0
        self.notes: list[str] = []
        self.skipped = None

    def note(self, s: str) -> None:
        s = _short_paths(s)
        if s not in self.notes:
            self.notes.append(s)

    def row(self) -> dict:
        if self.skipped:
            outcome = f"skipped: {self.skipped}"
        elif self.crashed or self.lost:
            outcome = "FAIL: " + "; ".join(self.notes[:3])
        else:
            outcome = "; ".join(self.notes[:2]) or "ok"
        return {"probe": self.probe, "outcome": outcome, "tried": self.tried,
                "refused_clearly": self.clear, "crashed": self.crashed, "lost": self.lost,
                "notes": self.notes}


def accelcal(*args, cwd=None, env=None, timeout=600, priv=False, marker=None) -> tuple:
    """(exit code, stdout, stderr, seconds) of ``python -m accelcal ARGS``."""
    e = {**os.environ, **(env or {})}
    if marker:
        e["BENCH_FAULTS_MARK"] = marker
    cmd = (NOPRIV if priv else []) + [sys.executable, "-m", "accelcal", *map(str, args)]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=cwd, env=e, capture_output=True, timeout=timeout)
        out, err, rc = p.stdout.decode("utf-8", "replace"), p.stderr.decode("utf-8", "replace"), p.returncode
    except subprocess.TimeoutExpired as x:
        out = (x.stdout or b"").decode("utf-8", "replace")
        err = (x.stderr or b"").decode("utf-8", "replace") + "\n[timeout]"
        rc = "timeout"
    return rc, out, err, time.perf_counter() - t0


def traceback_in(*texts) -> bool:
    return any("Traceback (most recent call last)" in t for t in texts)


def one_line_error(rc, err) -> bool:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errs = [ln for ln in lines if ln.startswith("accelcal: error:")]
    return rc == 1 and len(errs) == 1 and not traceback_in(err)


def runs(wh: Path, snapshot=False) -> dict[str, dict]:
    """source file name -> {status, rule, reason, sha256} of the latest verdicts."""
    import duckdb
    if not wh.exists():
        return {}
    con = duckdb.connect(str(wh), read_only=True)
    try:
        rows = con.execute("SELECT r.source_path, r.status, r.reason, r.sha256, "
                           "(SELECT min(rule) FROM refusals f WHERE f.sha256 = r.sha256 AND "
                           " f.source_path = r.source_path) FROM runs r").fetchall()
    finally:
        con.close()
    return {Path(p).name: {"status": s, "reason": why, "sha256": sha, "rule": rule, "path": p}
            for p, s, why, sha, rule in rows}


def contents(wh: Path) -> dict:
    from test_faults import warehouse_contents
    return warehouse_contents(wh)


def copy_drop(name: str, dst: Path) -> Path:
    shutil.copytree(EXAMPLES / name, dst)
    for p in dst.rglob("*"):
        os.chmod(p, 0o755 if p.is_dir() else 0o644)
    os.chmod(dst, 0o755)
    return dst


def good_names(drop: Path) -> set[str]:
    return {p.name for p in drop.rglob("*.csv") if p.is_file() and not p.is_symlink()}


def check_good(res: Res, wh: Path, names: set[str]) -> None:
    r = runs(wh)
    lost = [n for n in names if r.get(n, {}).get("status") != "accepted"]
    if lost:
        res.lost += len(lost)
        res.note(f"good files not accepted: {sorted(lost)[:3]}")


def check_refused(res: Res, wh: Path, name: str, rule: str | None = None) -> bool:
    r = runs(wh).get(name)
    res.tried += 1
    if r and r["status"] == "refused" and r["reason"] and (rule is None or r["rule"] == rule):
        if len(r["reason"]) > 800:
            res.crashed += 1
            res.note(f"{name}: reason of {len(r['reason'])} characters")
            return False
        res.clear += 1
        return True
    res.lost += 1
    res.note(f"{name}: {r['rule'] if r else 'not recorded'} (wanted {rule})")
    return False


def check_run(res: Res, rc, out, err, want=0) -> bool:
    if traceback_in(out, err) or rc not in EXIT_DOCUMENTED:
        res.crashed += 1
        res.note(f"exit {rc}: {(err.strip().splitlines() or ['?'])[-1][:160]}")
        return False
    if rc != want:
        res.crashed += 1
        res.note(f"exit {rc}, wanted {want}: {(err.strip().splitlines() or ['?'])[-1][:160]}")
        return False
    return True


LOCAL = ("--engine", "local", "--settle", "0")


def run_checked(res: Res, drops, wh: Path, *extra, want=0, **kw) -> tuple:
    """``accelcal run DROPS -w WH --create`` (local engine, no settle wait), checked."""
    drops = drops if isinstance(drops, (list, tuple)) else [drops]
    rc, out, err, dt = accelcal("run", *drops, "-w", wh, "--create", *LOCAL, *extra, **kw)
    check_run(res, rc, out, err, want)
    return rc, out, err, dt


def marked_pids(marker: str) -> list[int]:
    """Processes whose environment carries BENCH_FAULTS_MARK=marker (ours, any depth)."""
    needle = f"\0BENCH_FAULTS_MARK={marker}\0".encode()
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/environ", "rb") as f:
                if needle in b"\0" + f.read() + b"\0":
                    out.append(int(d))
        except OSError:
            pass
    return out


def temp_files(wh: Path) -> list[str]:
    from accelcal.fileio import is_temp_name
    found = [p for p in wh.parent.rglob("*") if is_temp_name(p.name) or p.name.endswith(".tmp")]
    return [str(p) for p in found]


def can_mount() -> bool:
    if os.geteuid() != 0 or not shutil.which("mount"):
        return False
    d = tempfile.mkdtemp()
    try:
        ok = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", d],
                            capture_output=True).returncode == 0
        if ok:
            subprocess.run(["umount", d])
        return ok
    finally:
        os.rmdir(d)


def can_nopriv() -> bool:
    if os.geteuid() != 0 or not shutil.which("setpriv"):
        return False
    with tempfile.NamedTemporaryFile() as f:
        os.chmod(f.name, 0)
        return subprocess.run(NOPRIV + ["cat", f.name], capture_output=True).returncode != 0


class ReadOnly:
    """A read-only bind mount of a folder over itself (root), undone on exit."""

    def __init__(self, path: Path):
        self.path = str(path)

    def __enter__(self):
        subprocess.run(["mount", "--bind", self.path, self.path], check=True)
        subprocess.run(["mount", "-o", "remount,bind,ro", self.path], check=True)
        return self

    def __exit__(self, *exc):
        subprocess.run(["umount", self.path], check=True)


def tumble_text(run_id=None, **meta) -> str:
    """The lab's sample tumble, with metadata values replaced."""
    text = (EXAMPLES / "drop-bad" / "ok-small.csv").read_text()
    if run_id is not None:
        meta["run_id"] = run_id
    for k, v in meta.items():
        text = re.sub(rf"^# {k}:.*$", lambda m: f"# {k}: {v}", text, count=1, flags=re.M)
    return text


# ----------------------------------------------------------------- probes --

PROBES: dict[str, callable] = {}


def probe(name):
    def deco(fn):
        PROBES[name] = fn
        return fn
    return deco


def _hostile_drop(tmp: Path) -> tuple[Path, set[str]]:
    drop = copy_drop("drop-2026-11-20", tmp / "drop")
    return drop, good_names(drop)


def hostile(name: str, title: str):
    """A probe of hostile files put into a copy of the sample drop 2026-11-20:
    ``fn(res, tmp, drop, wh, args)`` adds them and runs; afterwards every good file of
    the drop must be accepted."""
    def deco(fn):
        def run(tmp, args):
            res = Res(title)
            drop, good = _hostile_drop(tmp)
            wh = tmp / "wh" / "lab.duckdb"
            fn(res, tmp, drop, wh, args)
            if not res.skipped:
                check_good(res, wh, good)
            return res
        PROBES[name] = run
        return fn
    return deco


@hostile("file name not UTF-8 / with a control character", "file name not UTF-8 (`bad\\xffname.csv`), or holding a newline")
def p_names(res, tmp, drop, wh, args):
    ok = tumble_text("NAMES-1")
    hostile = [b"bad\xffname.csv", b"new\nline.csv", b"tab\there.csv"]
    for n in hostile:
        with open(os.path.join(os.fsencode(drop), n), "w") as f:
            f.write(ok)
    os.mkdir(os.path.join(os.fsencode(drop), b"dir\xfe"))
    shutil.copy(EXAMPLES / "drop-bad" / "ok-small.csv", os.path.join(os.fsencode(drop), b"dir\xfe", b"x.csv"))
    run_checked(res, drop, wh, cwd=tmp)
    rc, out, err, _ = run_checked(res, drop, wh, "--json", cwd=tmp)    # again: nothing new
    if check_run(res, rc, out, err) and sum(d["new"] for d in json.loads(out)["drops"]):
        res.crashed += 1
        res.note("the second run added records")
    r = runs(wh)
    for n in hostile + [b"dir\xfe"]:
        shown = n.decode("utf-8", "backslashreplace")
        res.tried += 1
        rec = r.get(shown)
        if rec and rec["status"] == "refused" and rec["rule"] == "bad-file-name":
            res.clear += 1
        else:
            res.lost += 1
            res.note(f"{shown!r}: {rec}")
    res.note("refused `bad-file-name`, path stored as UTF-8 text (\\xff); a second run adds nothing")


@hostile("markup and emoji codes in metadata", "`[/x]` and `:x:` in campaign, test, rig_id values")
def p_markup(res, tmp, drop, wh, args):
    (drop / "markup-ok.csv").write_text(tumble_text("MK-[/x]-1", campaign="C[/x]:x:[bold]", rig_id=":x:[/x]"))
    (drop / "markup-bad.csv").write_text(tumble_text("MK-2", test="[/x]:x:"))
    rc, out, err, _ = run_checked(res, drop, wh, cwd=tmp)
    res.tried += 2
    r = runs(wh)
    if r.get("markup-ok.csv", {}).get("status") == "accepted" and "C[/x]:x:[bold]" in out:
        res.clear += 1
    else:
        res.lost += 1
        res.note(f"markup-ok: {r.get('markup-ok.csv')}; printed: {'C[/x]:x:[bold]' in out}")
    if r.get("markup-bad.csv", {}).get("rule") == "unknown-test" and "'[/x]:x:'" in out:
        res.clear += 1
    else:
        res.lost += 1
        res.note(f"markup-bad: {r.get('markup-bad.csv')}")
    if "\u274c" in out + err:
        res.crashed += 1
        res.note("an emoji was printed")
    res.note("printed as text (no markup, no emoji)")


@hostile("run_id or serial over 255 bytes", "run_id, serial or campaign of 300 bytes")
def p_long_ids(res, tmp, drop, wh, args):
    long_ = {"long-run-id.csv": dict(run_id="R" * 300),
             "long-serial.csv": dict(run_id="LS-1", unit_serial="S" * 300),
             "long-utf8.csv": dict(run_id="é" * 200, campaign="ü" * 300)}
    for n, kw in long_.items():
        (drop / n).write_text(tumble_text(**kw))
    rc, out, err, _ = run_checked(res, drop, wh, cwd=tmp)
    r = runs(wh)
    for n in long_:
        res.tried += 1
        if r.get(n, {}).get("status") == "accepted":
            res.clear += 1
        else:
            res.lost += 1
            res.note(f"{n}: {r.get(n)}")
    longest = max(len(p.name.encode()) for p in (wh.parent / "lab-parquet").rglob("*"))
    if longest > 255:
        res.crashed += 1
    res.note(f"accepted; Parquet names cut with a hash (longest component {longest} bytes)")


@hostile("symbolic links", "links: `x.csv -> /etc/passwd`, inside the drop, dangling, a linked sub-folder")
def p_links(res, tmp, drop, wh, args):
    inside = next((drop / "centrifuge").glob("*.csv"))
    os.symlink("/etc/passwd", drop / "passwd.csv")
    os.symlink(os.path.relpath(inside, drop), drop / "inside.csv")
    os.symlink(drop / "nowhere.csv", drop / "dangling.csv")
    os.symlink(EXAMPLES / "drop-2026-11-21", drop / "linked-folder")
    rc, out, err, _ = run_checked(res, drop, wh, cwd=tmp)
    for n in ("passwd.csv", "inside.csv", "dangling.csv", "linked-folder"):
        check_refused(res, wh, n, "link")
    if "root:" in out + err or any("/etc/passwd" == v["path"] for v in runs(wh).values()):
        res.crashed += 1
        res.note("/etc/passwd was read")
    if any("LXJ200" in n for n in runs(wh)):
        res.lost += 1
        res.note("the linked folder was followed")
    res.note("refused `link`, never followed or read")


@hostile("FIFO named *.csv", "a FIFO `x.csv` (nobody writes to it)")
def p_fifo(res, tmp, drop, wh, args):
    os.mkfifo(drop / "fifo.csv")
    rc, out, err, dt = run_checked(res, drop, wh, cwd=tmp, timeout=180)
    check_refused(res, wh, "fifo.csv", "not-a-file")
    res.note(f"refused `not-a-file`, never opened ({dt:.0f} s run)")


@hostile("unreadable file and sub-folder", "unreadable file, unreadable sub-folder (mode 000)")
def p_unreadable(res, tmp, drop, wh, args):
    if not can_nopriv():
        res.skipped = "needs root and setpriv"
        return
    (drop / "secret.csv").write_text(tumble_text("SECRET-1"))
    os.chmod(drop / "secret.csv", 0)
    (drop / "closed").mkdir()
    (drop / "closed" / "inside.csv").write_text(tumble_text("CLOSED-1"))
    os.chmod(drop / "closed", 0)
    (tmp / "wh").mkdir()
    rc, out, err, _ = accelcal("run", drop, "-w", wh, "--engine", "local", "--settle", "0", cwd=tmp, priv=True)
    check_run(res, rc, out, err)
    check_refused(res, wh, "secret.csv", "unreadable")
    check_refused(res, wh, "closed", "unreadable")
    os.chmod(drop / "closed", 0o755)
    res.note("refused `unreadable` with the OS's reason (run as root without CAP_DAC_OVERRIDE)")


@probe("file still growing while read")
def p_growing(tmp, args):
    res = Res("a file still being written while `run` reads the drop (settle 2 s, the default)")
    src = EXAMPLES / "drop-2026-11-20" / "centrifuge" / "LXJ100-20261120-0002.csv"
    lines = src.read_bytes().splitlines(keepends=True)
    for trial in range(3):
        d = tmp / f"t{trial}"
        drop, good = _hostile_drop(d)
        (drop / "centrifuge" / src.name).unlink()
        good.discard(src.name)
        target = drop / "growing.csv"
        stop = threading.Event()
        period = [0.02, 0.3, 1.0][trial]          # pauses shorter / longer than the settle time? (< 2 s)

        def writer():
            with open(target, "wb") as f:
                for k in range(0, len(lines), 8):
                    f.write(b"".join(lines[k:k + 8]))
                    f.flush()
                    if stop.wait(period * (0.5 + random.random())):
                        return
        th = threading.Thread(target=writer)
        th.start()
        time.sleep(0.5)
        wh = d / "wh" / "lab.duckdb"
        rc, out, err, _ = accelcal("run", drop, "-w", wh, "--create", "--engine", "local", cwd=d)
        th.join()
        check_run(res, rc, out, err)
        res.tried += 1
        r = runs(wh).get("growing.csv")
        final = hashlib.sha256(target.read_bytes()).hexdigest()
        if r is None and "held back" in out:
            res.clear += 1
            res.note("held back while growing, read whole by the next run")
        elif r is not None and r["sha256"] == final and r["status"] == "accepted":
            res.clear += 1
            res.note("waited until it stopped growing, then read whole")
        else:
            res.lost += 1
            res.note(f"trial {trial}: partial file {r}")
        rc, out, err, _ = accelcal("run", drop, "-w", wh, "--engine", "local", cwd=d)
        check_run(res, rc, out, err)
        r = runs(wh).get("growing.csv")
        if not (r and r["sha256"] == final and r["status"] == "accepted"):
            res.lost += 1
            res.note(f"trial {trial}: complete file not accepted on the next run: {r}")
        check_good(res, wh, good)
    return res


def _big_line(drop: Path, where: str) -> None:
    lines = tumble_text("BIG-1").splitlines(keepends=True)
    h = next(i for i, s in enumerate(lines) if s and not s.startswith("#"))
    if where == "header":
        lines[h] = "time_s," * ((10 << 20) // 7) + "\n"
    else:
        cells = lines[h + 1].split(",")
        cells[0] = "9" * (10 << 20)
        lines[h + 1] = ",".join(cells)
    (drop / f"ten-mb-{where}.csv").write_text("".join(lines))


@hostile("10 MB header line", "a 10 MB header line")
def p_big_header(res, tmp, drop, wh, args):
    _big_line(drop, "header")
    rc, out, err, _ = run_checked(res, drop, wh, cwd=tmp)
    check_refused(res, wh, "ten-mb-header.csv", "line-too-long")
    longest = max((len(ln) for ln in out.splitlines()), default=0)
    res.note(f"refused `line-too-long`; reason {len(runs(wh)['ten-mb-header.csv']['reason'])} chars, "
             f"longest printed line {longest}")


@hostile("10 MB data line of digits", "a 10 MB data line of digits")
def p_big_number(res, tmp, drop, wh, args):
    _big_line(drop, "data")
    rc, out, err, _ = run_checked(res, drop, wh, cwd=tmp)
    check_refused(res, wh, "ten-mb-data.csv", "line-too-long")
    if "inf" in (runs(wh)["ten-mb-data.csv"]["reason"] or ""):
        res.crashed += 1
        res.note("reported as infinite")
    res.note("refused `line-too-long` (a shorter over-long number: `out-of-range`), not 'inf'")


def make_big(path: Path, mb: int) -> None:
    """A valid tilt_rotation run of about ``mb`` MB: the thermal sample repeated in time."""
    src = (EXAMPLES / "drop-2026-11-18-thermal" / "TT1-20261118-0001.csv").read_text().splitlines()
    hdr = [ln for ln in src if ln.startswith("#")]
    hdr = [re.sub(r"TT1-20261118-0001", f"TT1-BIG-{mb}", ln) for ln in hdr]
    cols, rows = src[len(hdr)], [ln.split(",", 1) for ln in src[len(hdr) + 1:]]
    t0 = float(rows[0][0])
    span = float(rows[-1][0]) - t0 + 1
    with open(path, "w") as f:
        f.write("\n".join(hdr) + "\n" + cols + "\n")
        k = 0
        while f.tell() < mb * 1e6:
            f.write("".join(f"{float(r[0]) + k * span:.0f},{r[1]}\n" for r in rows))
            k += 1


def peak_rss_of(cmd, env=None, cwd=None, timeout=1800) -> tuple[int, float, str, str]:
    """(exit code, peak RSS in MB of the process tree, stdout, stderr)."""
    import psutil
    p = subprocess.Popen(cmd, env={**os.environ, **(env or {})}, cwd=cwd, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    peak = 0.0
    out_err = {}

    def drain(name, stream):
        out_err[name] = stream.read().decode("utf-8", "replace")
    ts = [threading.Thread(target=drain, args=(n, s)) for n, s in (("out", p.stdout), ("err", p.stderr))]
    for t in ts:
        t.start()
    t_end = time.time() + timeout
    while p.poll() is None and time.time() < t_end:
        try:
            pr = psutil.Process(p.pid)
            rss = pr.memory_info().rss + sum(c.memory_info().rss for c in pr.children(recursive=True))
            peak = max(peak, rss / 2 ** 20)
        except psutil.Error:
            pass
        time.sleep(0.05)
    if p.poll() is None:
        p.kill()
    p.wait()
    for t in ts:
        t.join()
    return p.returncode, peak, out_err.get("out", ""), out_err.get("err", "")


INGEST_ONE = r'''
import json, resource, sys, time
from accelcal.tasks.ingest import ingest_files
from accelcal.schemas.dropscan import scan_drop
t = time.perf_counter()
ing = ingest_files(sys.argv[1], scan_drop(sys.argv[1]), sys.argv[2], sys.argv[3], {})
print(json.dumps({"seconds": time.perf_counter() - t, "status": [r.status for r in ing.records],
                  "errors": ing.errors,
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
'''


@probe("200 MB file")
def p_big_file(tmp, args):
    res = Res("a 200 MB run file (valid: the thermal sample repeated)")
    drop = tmp / "drop"
    drop.mkdir()
    make_big(drop / "big.csv", args.big_mb)
    res.tried = 1
    # the ingest step alone (hash + parse + Parquet), as a batch task does it
    out = subprocess.run([sys.executable, "-c", INGEST_ONE, drop, tmp / "pq", tmp], capture_output=True,
                         text=True, timeout=1800)
    if out.returncode != 0:
        res.crashed += 1
        res.note(out.stderr.strip().splitlines()[-1][:200])
        return res
    ing = json.loads(out.stdout)
    # the whole run, peak RSS of the process tree
    rc, peak, o, e = peak_rss_of([sys.executable, "-m", "accelcal", "run", drop, "-w", tmp / "wh" / "lab.duckdb",
                                  "--create", "--engine", "local", "--settle", "0", "-q"])
    check_run(res, rc, o, e)
    r = runs(tmp / "wh" / "lab.duckdb").get("big.csv", {})
    if r.get("status") == "accepted" and ing["status"] == ["accepted"]:
        res.clear += 1
    else:
        res.lost += 1
        res.note(f"not accepted: {r} {ing}")
    res.note(f"accepted; ingest (hash+parse+Parquet) {ing['peak_mb']:.0f} MB peak RSS in "
             f"{ing['seconds']:.1f} s; whole run {peak:.0f} MB peak RSS")
    res.extra = {"ingest_peak_mb": ing["peak_mb"], "run_peak_mb": peak}
    return res


def _popen_accelcal(*args, marker, env=None, cwd=None, priv=False):
    e = {**os.environ, "BENCH_FAULTS_MARK": marker, **(env or {})}
    return subprocess.Popen((NOPRIV if priv else []) + [sys.executable, "-m", "accelcal", *map(str, args)],
                            env=e, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _orphans_after(marker: str, wait: float = 12.0) -> list[int]:
    t_end = time.time() + wait
    while time.time() < t_end:
        left = marked_pids(marker)
        if not left:
            return []
        time.sleep(0.25)
    return marked_pids(marker)


@probe("SIGKILL of accelcal run (Prefect engine)")
def p_sigkill_prefect(tmp, args):
    res = Res(f"{args.kills} SIGKILLs of `accelcal run` (Prefect engine) at random times, then a re-run")
    drops = [copy_drop("drop-2026-11-20", tmp / "d20"), copy_drop("drop-2026-11-21", tmp / "d21")]
    rng = random.Random(20261122)
    mark = uuid.uuid4().hex
    t0 = time.perf_counter()
    clean = tmp / "clean" / "lab.duckdb"
    rc, out, err, T = accelcal("run", *drops, "-w", clean, "--create", "-q", "--settle", "0", marker=mark)
    if not check_run(res, rc, out, err):
        return res
    orphans = _orphans_after(mark)        # a clean run must leave no process behind either
    if orphans:
        res.crashed += 1
        res.note(f"processes left after the clean run: {len(orphans)}")
        for q in orphans:
            with_kill(q)
    want = contents(clean)
    g, attempts, kills = 0, 0, 0
    stages: dict[str, int] = {}
    while kills < args.kills and attempts < 3 * args.kills:
        attempts += 1
        wh = tmp / f"g{g}" / "lab.duckdb"
        mark = uuid.uuid4().hex
        t_start = time.time()
        p = _popen_accelcal("run", *drops, "-w", wh, "--create", "-q", "--settle", "0", "--lock-timeout", "120",
                            marker=mark)
        delay = rng.uniform(0.5, T)
        try:
            p.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            pass
        if p.poll() is None:
            # where was it?  before Prefect's server was up, after this run published its
            # snapshot (Prefect stopping), or in between (ingest ... store)
            snap = wh.parent / "lab-snapshot.duckdb"
            server = any(b"uvicorn" in _cmdline(q) for q in marked_pids(mark))
            stage = ("Prefect starting" if not server else
                     "Prefect stopping" if snap.exists() and snap.stat().st_mtime > t_start else
                     "server up (ingest to store)")
            stages[stage] = stages.get(stage, 0) + 1
            os.kill(p.pid, signal.SIGKILL)
            p.wait()
            p.stdout.read(), p.stderr.read()
            kills += 1
            res.tried += 1
            left = _orphans_after(mark)
            if left:
                res.crashed += 1
                res.note(f"orphaned processes after SIGKILL: {len(left)}")
                for q in left:
                    with_kill(q)
            else:
                res.clear += 1
        else:
            out, err = p.stdout.read().decode(), p.stderr.read().decode()
            check_run(res, p.returncode, out, err)
            g += 1
    # every group: one more run completes the work; then compare with the clean run
    for k in range(g + 1):
        wh = tmp / f"g{k}" / "lab.duckdb"
        rc, out, err, _ = accelcal("run", *drops, "-w", wh, "--create", "-q", "--settle", "0")
        check_run(res, rc, out, err)
        if contents(wh) != want:
            res.lost += 1
            res.note(f"group {k}: warehouse differs from the clean run")
        left = temp_files(wh)
        if left:
            res.crashed += 1
            res.note(f"temporary files left: {left[:2]}")
    res.note(f"no orphan, warehouse = clean run, no temp file ({g + 1} warehouses; clean run {T:.0f} s; "
             f"killed at: {', '.join(f'{k} {v}' for k, v in sorted(stages.items()))}; "
             f"{time.perf_counter() - t0:.0f} s)")
    return res


def _cmdline(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read()
    except OSError:
        return b""


def with_kill(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:
        pass


@probe("SIGKILL during the Parquet write")
def p_sigkill_parquet(tmp, args):
    res = Res("SIGKILL while a Parquet file is being written (a 60 MB run)")
    drop = copy_drop("drop-2026-11-20", tmp / "drop")
    make_big(drop / "big.csv", 60)
    clean = tmp / "clean" / "lab.duckdb"
    rc, out, err, _ = accelcal("run", drop, "-w", clean, "--create", "--engine", "local", "-q", "--settle", "0")
    check_run(res, rc, out, err)
    want = contents(clean)
    tmp_left = 0
    for trial in range(3):
        wh = tmp / f"w{trial}" / "lab.duckdb"
        wh.parent.mkdir()
        mark = uuid.uuid4().hex
        p = _popen_accelcal("run", drop, "-w", wh, "--engine", "local", "-q", "--settle", "0", marker=mark)
        pq = wh.parent / "lab-parquet"
        t_end = time.time() + 300
        seen = None
        while time.time() < t_end and p.poll() is None and not seen:
            seen = [x for x in pq.rglob("*.tmp")] if pq.exists() else None
            time.sleep(0.005)
        if p.poll() is None:
            os.kill(p.pid, signal.SIGKILL)
        p.wait()
        res.tried += 1
        left_before = temp_files(wh)
        rc, out, err, _ = accelcal("run", drop, "-w", wh, "--engine", "local", "-q", "--settle", "0")
        check_run(res, rc, out, err)
        if temp_files(wh):
            res.crashed += 1
            res.note(f"temporary file left after the next run: {temp_files(wh)[:1]}")
        elif contents(wh) != want:
            res.lost += 1
            res.note("warehouse differs from the clean run")
        else:
            res.clear += 1
        tmp_left += bool(left_before)
    res.note(f"a .tmp was left by {tmp_left} of {res.tried} kills; the next run removed it and "
             "equals the clean run")
    return res


@probe("disk full")
def p_disk_full(tmp, args):
    res = Res("disk full (the warehouse folder on a tmpfs of 0.25 to 40 MB), then space freed and run again")
    if not can_mount():
        res.skipped = "needs root (tmpfs mounts)"
        return res
    drops = [copy_drop("drop-2026-11-20", tmp / "d20"), copy_drop("drop-2026-11-21", tmp / "d21"),
             copy_drop("drop-bad", tmp / "bad")]
    clean = tmp / "clean" / "lab.duckdb"
    rc, out, err, _ = accelcal("run", *drops, "-w", clean, "--create", "--engine", "local", "-q", "--settle", "0")
    check_run(res, rc, out, err)
    want = contents(clean)
    full_seen, kinds, example = 0, {}, ""
    # sizes from well below what a run writes to well above it, so that the disk fills at
    # several different places (a smaller warehouse file moved them once: keep the low end low)
    for kb in (256, 512, 768, 1024, 1536, 2048, 4096, 40960):
        mb = f"{kb / 1024:g}"
        mnt = tmp / f"fs{kb}k"
        mnt.mkdir()
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={kb}k", "tmpfs", mnt], check=True)
        try:
            wh = mnt / "lab.duckdb"
            rc, out, err, _ = accelcal("run", *drops, "-w", wh, "--engine", "local", "-q", "--settle", "0")
            res.tried += 1
            if rc == 0:
                check_run(res, rc, out, err)
                res.clear += 1
            elif one_line_error(rc, err) and ("No space left" in err or "disk is full" in err):
                res.clear += 1
                full_seen += 1
                m = re.search(r"cannot (write|create|publish) ([\w ]+?)(?: under| \S*/|:)", err)
                kinds[m.group(2) if m else "?"] = kinds.get(m.group(2) if m else "?", 0) + 1
                example = err.strip().splitlines()[-1]
            else:
                res.crashed += 1
                res.note(f"{mb} MB: exit {rc}: {err.strip()[-300:]}")
            subprocess.run(["mount", "-o", "remount,size=400m", mnt], check=True)
            rc, out, err, _ = accelcal("run", *drops, "-w", wh, "--engine", "local", "-q", "--settle", "0")
            check_run(res, rc, out, err)
            if contents(wh) != want:
                res.lost += 1
                res.note(f"{mb} MB: after freeing space and a re-run, the warehouse differs from a clean run")
            if temp_files(wh):
                res.crashed += 1
                res.note(f"{mb} MB: temporary files left {temp_files(wh)[:1]}")
        finally:
            subprocess.run(["umount", "-l", mnt])
    if not full_seen:                # the probe did not test what it names: say so, loudly
        res.crashed += 1
        res.note("the disk never filled: no run met a full disk, so this probe tested nothing")
    where = ", ".join(f"{k} {v}" for k, v in sorted(kinds.items()))
    res.notes.insert(0, f"full {full_seen} times ({where}): one line, exit 1; with space again, "
                        "a re-run = a clean run")
    res.note(f"e.g. `{_short_paths(example)[:170]}`")
    return res


def _clean_warehouse(tmp: Path, drops=("drop-2026-11-20",)) -> tuple[Path, list[Path]]:
    ds = [copy_drop(d, tmp / d) for d in drops]
    wh = tmp / "wh" / "lab.duckdb"
    rc, out, err, _ = accelcal("run", *ds, "-w", wh, "--create", "--engine", "local", "-q", "--settle", "0")
    assert rc == 0, err
    return wh, ds


def sha_file(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@probe("half-truncated warehouse")
def p_truncated(tmp, args):
    res = Res("a warehouse cut to half its size (and to 4 KiB, and 0 bytes)")
    wh, ds = _clean_warehouse(tmp)
    new = copy_drop("drop-2026-11-21", tmp / "d21")
    full = wh.read_bytes()
    for size in (len(full) // 2, 4096, 0):
        wh.write_bytes(full[:size])
        for f in wh.parent.glob("lab.duckdb.wal"):
            f.unlink()
        before = sha_file(wh)
        for cmd in (["run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0"],
                    ["sql", "SELECT count(*) FROM runs", "-w", wh]):
            rc, out, err, _ = accelcal(*cmd)
            res.tried += 1
            if one_line_error(rc, err):
                res.clear += 1
            else:
                res.crashed += 1
                res.note(f"{size} B {cmd[0]}: exit {rc}: {err.strip()[-200:]}")
            if sha_file(wh) != before:
                res.crashed += 1
                res.note(f"{size} B: the file was modified")
    res.note("one line, exit 1, the file unmodified, for run and sql alike")
    res.note(f"e.g. `{err.strip().splitlines()[-1][:170]}`")
    return res


@probe("warehouse in a read-only folder")
def p_readonly_dir(tmp, args):
    res = Res("an existing warehouse in a read-only folder")
    if not can_mount():
        res.skipped = "needs root (bind mounts)"
        return res
    wh, ds = _clean_warehouse(tmp)
    new = copy_drop("drop-2026-11-21", tmp / "d21")
    before = sha_file(wh)
    with ReadOnly(wh.parent):
        rc, out, err, _ = accelcal("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0")
        res.tried += 1
        if one_line_error(rc, err) and "read-only" in err:
            res.clear += 1
            res.note("run: one line, exit 1: " + err.strip().splitlines()[-1][:140])
        else:
            res.crashed += 1
            res.note(f"run: exit {rc}: {err.strip()[-300:]}")
        rc, out, err, _ = accelcal("sql", "SELECT count(*) AS n FROM runs", "-w", wh)
        res.tried += 1
        if rc == 0 and "11" in out:
            res.clear += 1
            res.note("`accelcal sql` still reads it")
        else:
            res.crashed += 1
            res.note(f"sql: exit {rc}: {err.strip()[-200:]}")
    if sha_file(wh) != before:
        res.crashed += 1
        res.note("modified")
    rc, out, err, _ = accelcal("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0")
    check_run(res, rc, out, err)
    check_good(res, wh, good_names(new) | good_names(ds[0]))
    return res


@probe("read-only Parquet folder")
def p_readonly_parquet(tmp, args):
    res = Res("a read-only Parquet folder (bind mount; and mode 555 without CAP_DAC_OVERRIDE)")
    if not can_mount() or not can_nopriv():
        res.skipped = "needs root (bind mounts, setpriv)"
        return res
    for mode in ("mount", "chmod"):
        t = tmp / mode
        wh, ds = _clean_warehouse(t)
        new = copy_drop("drop-2026-11-21", t / "d21")
        clean, _ = _clean_warehouse(t / "clean", ("drop-2026-11-20",))
        pq = wh.parent / "lab-parquet"
        if mode == "mount":
            with ReadOnly(pq):
                rc, out, err, _ = accelcal("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0")
        else:
            for p in [pq, *pq.rglob("*")]:
                if p.is_dir():
                    os.chmod(p, 0o555)
            rc, out, err, _ = accelcal("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0", priv=True)
            for p in [pq, *pq.rglob("*")]:
                if p.is_dir():
                    os.chmod(p, 0o755)
        res.tried += 1
        if one_line_error(rc, err) and "Parquet" in err:
            res.clear += 1
            res.note("one line, exit 1: " + err.strip().splitlines()[-1][:150])
        else:
            res.crashed += 1
            res.note(f"{mode}: exit {rc}: {err.strip()[-300:]}")
        rc, out, err, _ = accelcal("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0")
        check_run(res, rc, out, err)
        check_good(res, wh, good_names(new) | good_names(ds[0]))
    res.note("after the folder is writable again, a re-run records every file")
    return res


@probe("--warehouse some.csv")
def p_wrong_type(tmp, args):
    res = Res("`--warehouse` naming a csv of the drop, or a new file inside the drop")
    drop, good = _hostile_drop(tmp)
    listing = sorted(str(p) for p in drop.rglob("*"))
    target = drop / "DH1-20261120-0001.csv"
    before = sha_file(target)
    for w in (target, drop / "lab.duckdb", drop / "centrifuge"):
        rc, out, err, _ = accelcal("run", drop, "-w", w, "--engine", "local", "-q", "--settle", "0", cwd=tmp)
        res.tried += 1
        if one_line_error(rc, err):
            res.clear += 1
            res.note(re.sub(r"/tmp/\S+/", ".../", err.strip().splitlines()[-1])[:110])
        else:
            res.crashed += 1
            res.note(f"{w.name}: exit {rc}: {err.strip()[-200:]}")
    if sorted(str(p) for p in drop.rglob("*")) != listing or sha_file(target) != before:
        res.crashed += 1
        res.note("the drop was modified (a stray file?)")
    res.notes = res.notes[:3] + ["nothing written into the drop"]
    return res


HOLD_OPEN = r'''
import duckdb, sys, time
con = duckdb.connect(sys.argv[1], read_only=True)
con.execute("SELECT count(*) FROM runs").fetchall()
print("open", flush=True)
time.sleep(float(sys.argv[2]))
'''
SLOW_QUERY = "SELECT count(*) AS n, sum(hash(i)) % 7 AS h FROM runs, range({n}) t(i)"


@probe("reader while a run writes")
def p_readers(tmp, args):
    res = Res("readers during runs: `accelcal sql` mid-run; a long `accelcal sql` before a run; "
              "a reader outside accelcal holding the file; the snapshot held open")
    drops = [copy_drop("drop-2026-11-20", tmp / "d20"), copy_drop("drop-2026-11-21", tmp / "d21"),
             copy_drop("drop-bad", tmp / "bad")]
    clean = tmp / "clean" / "lab.duckdb"
    rc, out, err, T = accelcal("run", *drops, "-w", clean, "--create", "--engine", "local", "-q", "--settle", "0")
    check_run(res, rc, out, err)
    want = contents(clean)
    rng = random.Random(7)
    run_args = ("--engine", "local", "-q", "--settle", "0")
    # 1. accelcal sql while a run writes: it waits, then prints the table
    for trial in range(args.pairs):
        wh = tmp / f"r{trial}" / "lab.duckdb"
        wh.parent.mkdir()
        accelcal("run", drops[0], "-w", wh, *run_args)               # the warehouse exists
        p = _popen_accelcal("run", *drops, "-w", wh, *run_args, marker="r")
        time.sleep(rng.uniform(0.5, max(T - 1, 1)))
        rc, out, err, dt = accelcal("sql", "SELECT count(*) AS n FROM runs", "-w", wh, "--lock-timeout", "300")
        res.tried += 1
        if rc == 0 and re.search(r"\b\d+\b", out) and not traceback_in(out, err):
            res.clear += 1
        else:
            res.crashed += 1
            res.note(f"sql mid-run: exit {rc}: {err.strip()[-200:]}")
        p.wait()
        if p.returncode != 0 or contents(wh) != want:
            res.lost += 1
            res.note(f"run with a reader: exit {p.returncode}, equal to clean: {contents(wh) == want}")
    res.note("`accelcal sql` mid-run waits for the run, then prints; the run is never disturbed")
    # 2. a long accelcal sql, then a run: the run waits for the reader (never fails half-way)
    wh = tmp / "long" / "lab.duckdb"
    wh.parent.mkdir()
    accelcal("run", drops[0], "-w", wh, *run_args)
    t0 = time.perf_counter()
    rd = _popen_accelcal("sql", SLOW_QUERY.format(n=args.slow_rows), "-w", wh, marker="q")
    time.sleep(3.0)
    rc, out, err, dt = accelcal("run", *drops, "-w", wh, *run_args, "--lock-timeout", "300")
    rd.wait()
    read_s = time.perf_counter() - t0
    res.tried += 1
    if rc == 0 and rd.returncode == 0 and contents(wh) == want:
        res.clear += 1
        res.note(f"a {read_s:.0f} s reader: the run waited for it, then ran whole")
    else:
        res.crashed += 1
        res.note(f"long reader: run exit {rc}, reader {rd.returncode}: {err.strip()[-200:]}")
    rd = _popen_accelcal("sql", SLOW_QUERY.format(n=args.slow_rows), "-w", wh, marker="q")
    from accelcal.warehouse.lock import lock_holders
    t_end = time.time() + 60
    while time.time() < t_end and not any(m == "READ" for _, m in lock_holders(str(wh) + ".lock")):
        time.sleep(0.05)
    rc, out, err, dt = accelcal("run", *drops, "-w", wh, *run_args, "--lock-timeout", "1")
    rd.wait()
    res.tried += 1
    if one_line_error(rc, err) and "reading" in err:
        res.clear += 1
        res.note("with --lock-timeout 1: " + err.strip().splitlines()[-1][:140])
    elif rc == 0:
        res.clear += 1
    else:
        res.crashed += 1
        res.note(f"impatient run: exit {rc}: {err.strip()[-200:]}")
    # 3. a reader outside accelcal holding the live file when a run starts
    wh = tmp / "foreign" / "lab.duckdb"
    wh.parent.mkdir()
    accelcal("run", drops[0], "-w", wh, *run_args)
    before = contents(wh)
    hold = subprocess.Popen([sys.executable, "-c", HOLD_OPEN, wh, "8"], stdout=subprocess.PIPE)
    hold.stdout.readline()
    rc, out, err, dt = accelcal("run", *drops, "-w", wh, *run_args, "--lock-timeout", "3")
    res.tried += 1
    if one_line_error(rc, err) and contents(wh) == before:
        res.clear += 1
        res.note("a program holding lab.duckdb when a run starts: " + err.strip().splitlines()[-1][:150])
    else:
        res.crashed += 1
        res.note(f"foreign reader: exit {rc}: {err.strip()[-250:]}")
    hold.wait()
    rc, out, err, _ = accelcal("run", *drops, "-w", wh, *run_args)
    check_run(res, rc, out, err)
    if contents(wh) != want:
        res.lost += 1
        res.note("after the foreign reader, the re-run differs from clean")
    # 4. a dashboard holding the snapshot open while runs publish new ones
    wh = tmp / "snap" / "lab.duckdb"
    wh.parent.mkdir()
    accelcal("run", drops[0], "-w", wh, *run_args)
    hold = subprocess.Popen([sys.executable, "-c", HOLD_OPEN, wh.parent / "lab-snapshot.duckdb", "20"],
                            stdout=subprocess.PIPE)
    hold.stdout.readline()
    rc, out, err, _ = accelcal("run", *drops, "-w", wh, *run_args, "--lock-timeout", "3")
    res.tried += 1
    snap = wh.parent / "lab-snapshot.duckdb"
    if rc == 0 and contents(wh) == want and contents(snap)["run_files"] == want["run_files"]:
        res.clear += 1
        res.note("the snapshot held open by a reader never blocks a run, and is replaced whole")
    else:
        res.crashed += 1
        res.note(f"snapshot reader: exit {rc}: {err.strip()[-200:]}")
    hold.kill()
    return res


@probe("two runs at once")
def p_two_runs(tmp, args):
    res = Res(f"{args.pairs} pairs of `accelcal run` on one warehouse at once")
    drops = [copy_drop("drop-2026-11-20", tmp / "d20"), copy_drop("drop-bad", tmp / "bad")]
    clean = tmp / "clean" / "lab.duckdb"
    rc, out, err, _ = accelcal("run", *drops, "-w", clean, "--create", "--engine", "local", "-q", "--settle", "0")
    want = contents(clean)
    for k in range(args.pairs):
        wh = tmp / f"p{k}" / "lab.duckdb"
        ps = [_popen_accelcal("run", *drops, "-w", wh, "--create", "--engine", "local", "-q", "--settle", "0",
                              "--lock-timeout", "300", marker="two") for _ in range(2)]
        for p in ps:
            p.wait()
            res.tried += 1
            out, err = p.stdout.read().decode(), p.stderr.read().decode()
            if check_run(res, p.returncode, out, err):
                res.clear += 1
        if contents(wh) != want:
            res.lost += 1
            res.note(f"pair {k}: warehouse differs from a clean run")
    res.note("the second waits for the first; warehouse = one clean run")
    return res


# ------------------------------------------------------------------- main --

def table(rows: list[dict]) -> str:
    out = ["| probe | outcome | N tried | N refused clearly | N crashed | N lost |",
           "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['probe']} | {r['outcome']} | {r['tried']} | {r['refused_clearly']} | "
                   f"{r['crashed']} | {r['lost']} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kills", type=int, default=30, help="SIGKILLs under the Prefect engine (default 30)")
    ap.add_argument("--pairs", type=int, default=5, help="concurrency trials (default 5)")
    ap.add_argument("--big-mb", type=int, default=200, help="size of the big file (default 200)")
    ap.add_argument("--slow-rows", type=int, default=2_000_000, help="rows the slow reader's query scans per run")
    ap.add_argument("--only", default=None, help="comma-separated probe name fragments")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "faults.md"))
    ap.add_argument("--keep", action="store_true", help="keep the temporary folders")
    ap.add_argument("--readme", action="store_true",
                    help="put the table into README.md between the bench_faults markers")
    args = ap.parse_args(argv)
    own_home = None
    if "PREFECT_HOME" not in os.environ:             # a Prefect home of its own, removed at the end
        own_home = os.environ["PREFECT_HOME"] = tempfile.mkdtemp(prefix="bench-faults-prefect-")
    os.environ.setdefault("PYTHONPATH", str(ROOT))
    names = [n for n in PROBES if not args.only or any(f.lower() in n.lower() for f in args.only.split(","))]
    commit_id = commit()
    t_all = time.perf_counter()
    rows = []
    base = Path(tempfile.mkdtemp(prefix="bench-faults-"))
    for k, name in enumerate(names):
        tmp = base / f"p{k:02d}"
        tmp.mkdir()
        t0 = time.perf_counter()
        print(f"[{k + 1}/{len(names)}] {name} ...", file=sys.stderr, flush=True)
        try:
            res = PROBES[name](tmp, args)
        except Exception as e:                      # the bench itself must report, not die
            res = Res(name)
            res.crashed += 1
            res.note(f"probe error: {type(e).__name__}: {e}")
        row = res.row()
        row["seconds"] = round(time.perf_counter() - t0, 1)
        row.update(getattr(res, "extra", {}))
        rows.append(row)
        print(f"    {row['outcome'][:200]} ({row['seconds']} s)", file=sys.stderr, flush=True)
    if not args.keep:
        shutil.rmtree(base, ignore_errors=True)
        if own_home:
            shutil.rmtree(own_home, ignore_errors=True)
    md = (f"Faults and hostile inputs (`python benchmarks/bench_faults.py`), commit {commit_id}, "
          f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, "
          f"{time.perf_counter() - t_all:.0f} s in all.\n\n" + table(rows) + "\n")
    md = md.replace(str(base), "…")
    print(md)
    if args.readme:
        write_block(ROOT / "README.md", "bench_faults", md)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(md)
        Path(args.out).with_suffix(".json").write_text(json.dumps(rows, indent=1).replace(str(base), "…"))
    return 1 if any(r["crashed"] or r["lost"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())

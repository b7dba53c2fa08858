"""Ctrl-C during `accelcal run` (Prefect engine): the run stops within 10 s with exit 130 and
one line, leaves no process behind, and a re-run leaves the warehouse a clean run leaves.

Every run is the command a lab types (``python -m accelcal run``, Prefect engine).  The
interrupt is sent as a terminal sends it: SIGINT to the whole foreground process group,
so Prefect's server gets it too.  The moments are drawn at random over a clean run's
duration, Prefect's start and stop included.
"""
from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from conftest import marked_pids
from test_faults import warehouse_contents

pytestmark = pytest.mark.slow

#: Interrupts tried: 3 moments in the everyday suite (each costs a Prefect server's start),
#: the issue's 10 in CI (.ci/run sets ACCELCAL_TEST_INTERRUPTS=10).
N_INTERRUPTS = int(os.environ.get("ACCELCAL_TEST_INTERRUPTS", "3"))
#: The run must be gone this long after the interrupt [s].
STOP_WITHIN_S = 10.0


def _marked(mark: str) -> list[int]:
    return marked_pids("ACCELCAL_TEST_MARK", mark)


def _guarded(pid: int) -> bool:
    """Whether the run has reached accelcal's code: its process guard's watchdog is up.
    Before that the Python interpreter itself is starting, and dies by the signal (a
    shell shows 130 too); the moments are drawn from then on."""
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        return any(b"-I\0-S\0-c" in Path(f"/proc/{k}/cmdline").read_bytes() for k in kids)
    except OSError:
        return False


def _start(drop: Path, wh: Path, mark: str) -> subprocess.Popen:
    env = {**os.environ, "ACCELCAL_TEST_MARK": mark}
    env.pop("ACCELCAL_NO_GUARD", None)
    return subprocess.Popen([sys.executable, "-m", "accelcal", "run", str(drop), "-w", str(wh),
                             "--create", "-q", "--settle", "0", "--lock-timeout", "120"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)     # its own group: killpg = Ctrl-C


def test_ctrl_c_at_random_moments_exits_130_within_10_s_and_a_rerun_equals_a_clean_run(
        tmp_path, examples):
    """Interrupted runs follow each other on one warehouse (each a re-run of the one
    before) until a run ends before its moment; that warehouse, completed by a re-run,
    must equal the clean run's, and the next run starts a new warehouse."""
    drop = tmp_path / "drop"
    shutil.copytree(examples / "drop-2026-11-20", drop)
    clean = tmp_path / "clean" / "lab.duckdb"
    t0 = time.monotonic()
    p = _start(drop, clean, uuid.uuid4().hex)
    out, err = p.communicate(timeout=900)
    length = time.monotonic() - t0
    assert p.returncode == 0, err.decode()
    want = warehouse_contents(clean)
    rng = random.Random(20261128)
    problems, stopped, tried, group = [], 0, 0, 0

    def compare(wh: Path) -> None:
        if not wh.exists():
            return
        p = _start(drop, wh, uuid.uuid4().hex)
        p.communicate(timeout=900)
        got = warehouse_contents(wh) if p.returncode == 0 else {}
        if got != want:
            problems.append(f"{wh.parent.name}: after a re-run (exit {p.returncode}) the warehouse "
                            f"differs from a clean run's in {sorted(k for k in want if got.get(k) != want[k])}")

    while stopped < N_INTERRUPTS and tried < 3 * N_INTERRUPTS:
        tried += 1
        wh = tmp_path / f"g{group}" / "lab.duckdb"
        mark = uuid.uuid4().hex
        p = _start(drop, wh, mark)
        t_end = time.monotonic() + 120
        while not _guarded(p.pid) and p.poll() is None and time.monotonic() < t_end:
            time.sleep(0.02)
        try:
            p.wait(timeout=rng.uniform(0.0, length))
        except subprocess.TimeoutExpired:
            pass
        if p.poll() is not None:           # it finished first: the group is complete
            p.communicate()
            if p.returncode != 0 or warehouse_contents(wh) != want:
                problems.append(f"g{group}: the run that completed it (exit {p.returncode}) "
                                "left a warehouse other than the clean run's")
            group += 1
            continue
        t_sig = time.monotonic()
        os.killpg(p.pid, signal.SIGINT)
        try:
            out, err = p.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            out, err = p.communicate()
        took = time.monotonic() - t_sig
        text = err.decode("utf-8", "replace")
        lines = [ln for ln in text.splitlines() if ln.strip()]
        left = _marked(mark)
        for q in left:
            os.kill(q, signal.SIGKILL)
        if p.returncode == 0 and not lines and not left:
            # The interrupt came while the finished run was exiting (its work committed,
            # `procguard.exit_now` under way): it completed the group, as above.
            if warehouse_contents(wh) != want:
                problems.append(f"g{group}: a run that exited 0 as it was interrupted "
                                "left a warehouse other than the clean run's")
            group += 1
            continue
        stopped += 1
        if p.returncode != 130 or took > STOP_WITHIN_S or len(lines) != 1 or "bug" in text \
                or "interrupted" not in text or left:
            problems.append(f"#{tried}: exit {p.returncode} after {took:.1f} s, "
                            f"{len(left)} process(es) left, stderr {lines[-3:]}")
    compare(tmp_path / f"g{group}" / "lab.duckdb")
    assert stopped == N_INTERRUPTS, f"only {stopped} runs were still running at their moment"
    assert not problems, "\n".join(problems)


def test_a_prefect_server_that_does_not_start_in_time_is_one_operational_line(tmp_path, examples):
    """Prefect's start failing (here: given 1 s) is exit 1 with one line saying what to do,
    never "a bug"; nothing is left running."""
    mark = uuid.uuid4().hex
    env = {**os.environ, "ACCELCAL_TEST_MARK": mark, "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "1"}
    env.pop("PREFECT_API_URL", None)
    p = subprocess.run([sys.executable, "-m", "accelcal", "run", str(examples / "drop-2026-11-20"),
                        "-w", str(tmp_path / "lab.duckdb"), "-q", "--settle", "0"],
                       env=env, capture_output=True, text=True, timeout=600)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 1 and len(lines) == 1, p.stderr
    assert "Prefect's temporary API server did not start" in lines[0] and "bug" not in lines[0]
    t_end = time.monotonic() + 10
    while _marked(mark) and time.monotonic() < t_end:
        time.sleep(0.2)
    assert _marked(mark) == []


_HUSHED = r'''
import subprocess, sys, time
from accelcal import procguard
procguard.stop_on_interrupt("interrupted")
procguard.guard_descendants()
child = r"""
import signal, sys, time
def dying(*_):
    sys.stderr.write("Traceback: dying words\n"); sys.stderr.flush(); time.sleep(1.0); sys.exit(1)
signal.signal(signal.SIGINT, dying); signal.signal(signal.SIGTERM, dying)
sys.stderr.write("said while running\n"); sys.stderr.flush()
time.sleep(60)
"""
with procguard.hushed_when_stopping():
    server = subprocess.Popen([sys.executable, "-c", child])


def client():                    # as Prefect's event worker does once its server is gone
    server.wait()
    while True:
        sys.stderr.write("EventsWorker: ConnectError\n")
        sys.stderr.flush()
        time.sleep(0.002)


import threading
threading.Thread(target=client, daemon=True).start()
time.sleep(1.5)
print("ready", flush=True)
time.sleep(60)
'''


def test_what_a_descendant_prints_as_ctrl_c_stops_it_never_follows_the_one_line(tmp_path):
    """A descendant that takes the terminal's Ctrl-C itself (uvicorn does, once Prefect's
    server serves) and prints a traceback as it stops, and a thread of the command that
    complains once that server is gone: stderr holds what the descendant said while it
    ran, then the command's one line, and nothing after."""
    p = subprocess.Popen([sys.executable, "-c", _HUSHED], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, start_new_session=True)
    assert p.stdout.readline() == b"ready\n"
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 130
    assert err.decode().split("\n") == ["said while running", "accelcal: error: interrupted", ""]

"""Nothing a command starts outlives it, even when the command is killed with SIGKILL.

``accelcal run`` with the Prefect engine starts Prefect's ephemeral API server (a uvicorn
subprocess, about 200 MB); ``--task-runner dask`` starts Dask workers; ``serve`` starts
flow-run subprocesses.  Killed with SIGKILL, the command cannot stop them, and they would
run on as orphans.

:func:`guard_descendants` (called by ``main`` for ``run``, ``demo`` and ``serve``) puts a
token in this process's environment, which every process it starts inherits, and starts a
small watchdog process holding the read end of a pipe whose write end only this process
holds.  However this process ends -- a normal exit, an exception, SIGKILL -- the kernel
closes the write end; the watchdog wakes, finds every process whose environment carries
the token (``/proc/<pid>/environ``), sends SIGTERM, and SIGKILL to those still there after
a grace period.

Why not the other two usual ways: a process group of our own would take the command out
of its terminal's foreground group (Ctrl-C would no longer reach it) and a group kill hits
whatever else shares the group; ``PR_SET_PDEATHSIG`` must be set inside each child (that
is, in Prefect's and Dask's code) and fires when the *thread* that started the child ends,
not the process, and it does not reach grandchildren.  The token reaches every
descendant however it was started.  Linux only (``/proc``); elsewhere this does nothing.

:func:`stop_on_interrupt` (``run`` and ``demo``) makes Ctrl-C end the command within
seconds whatever it is doing: one line on stderr, the descendants stopped through the
watchdog, exit 130.  Unwinding the stack instead hands the interrupt to Prefect's crash
handling, which keeps calling its API server -- a server that the terminal's Ctrl-C has
stopped too (it reaches the whole foreground group) -- for over a minute.  Stopping at
once is what a SIGKILL does, which the warehouse and the Parquet store survive by design
(one transaction per stored campaign, files put in place by rename, a stale ``.tmp``
removed by the next run): what was committed stays and a re-run completes the rest.
"""
from __future__ import annotations

import atexit
import contextlib
import os
import signal
import subprocess
import sys
import threading
import uuid

ENV = "ACCELCAL_GUARD"
#: Seconds between SIGTERM and SIGKILL.
GRACE_S = 5.0

# Runs as ``python -I -S -c``: no site-packages, no PYTHONPATH, nothing of accelcal.
_WATCHDOG = r'''
import os, signal, sys, time
token, grace, parent = sys.argv[1], float(sys.argv[2]), int(sys.argv[4])
for s in (signal.SIGINT, signal.SIGHUP, signal.SIGTERM, signal.SIGQUIT):
    signal.signal(s, signal.SIG_IGN)
try:
    while True:
        got = os.read(0, 4096)
        if not got:
            break
        if b"now" in got:              # an interrupt: the user waits
            grace = min(grace, 1.5)
except OSError:
    pass
me = os.getpid()
needle = ("\0%s=%s\0" % (sys.argv[3], token)).encode()

def marked():
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit() or int(d) in (me, parent):
            continue
        try:
            with open("/proc/%s/environ" % d, "rb") as f:
                env = b"\0" + f.read() + b"\0"
        except OSError:
            continue
        if needle in env:
            out.append(int(d))
    return out

def send(pids, sig):
    for p in pids:
        try:
            os.kill(p, sig)
        except OSError:
            pass

pids = marked()
if pids:
    send(pids, signal.SIGTERM)
    t_end = time.time() + grace
    while time.time() < t_end and marked():
        time.sleep(0.1)
    for _ in range(3):
        left = marked()
        if not left:
            break
        send(left, signal.SIGKILL)
        time.sleep(0.2)
'''

_guard: dict[str, object] = {}


def guard_descendants(grace: float = GRACE_S) -> str | None:
    """Start the watchdog for this process (once); returns the token, or None where there
    is no /proc.  Call it before starting any process that must not outlive this one."""
    if "token" in _guard:
        return _guard["token"]      # type: ignore[return-value]
    if not os.path.isdir("/proc/self"):
        return None
    token = uuid.uuid4().hex
    r, w = os.pipe()                 # both non-inheritable: children never hold w
    try:
        proc = subprocess.Popen([sys.executable, "-I", "-S", "-c", _WATCHDOG, token, str(grace), ENV,
                                 str(os.getpid())],
                                stdin=r, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                env={}, start_new_session=True, close_fds=True)
    except OSError:
        os.close(r)
        os.close(w)
        return None
    os.close(r)
    os.environ[ENV] = token          # after the watchdog started: it does not carry it
    _guard.update(token=token, write_fd=w, watchdog=proc)
    return token


#: Longest wait for the watchdog to stop the descendants after an interrupt [s].
STOP_WAIT_S = GRACE_S + 2.0
_stopping = threading.Lock()
#: Set once the command stops (:func:`stop_now`, :func:`exit_now`).
_stopped = threading.Event()
#: How long a hushed descendant's output waits before it is passed on [s]: a Ctrl-C reaches
#: the descendants as it reaches the command, and they may print before the command stops.
HUSH_DELAY_S = 0.5


def guarded() -> bool:
    """Whether this process runs under its watchdog (a command of :data:`accelcal.cli.GUARDED`)."""
    return "token" in _guard


def stop_now(line: str, code: int) -> None:
    """End this process now from any thread: ``line`` on stderr (``accelcal: error: ...``),
    every descendant stopped (SIGTERM, SIGKILL after the grace period), exit ``code``.
    A second caller (a second Ctrl-C, the server watch) waits for the first.  The line is
    the last this process writes to stderr: its other threads (Prefect's event and log
    workers, calling a server the Ctrl-C stopped) write to /dev/null from then on."""
    if not _stopping.acquire(blocking=False):
        threading.Event().wait()
    _stopped.set()
    try:
        tty = os.isatty(2)
        os.write(2, ("\n\x1b[?25h" if tty else "").encode() + f"accelcal: error: {line}\n".encode())
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
    except OSError:
        pass
    _stop_descendants_and_exit(code)


def exit_now(code: int) -> None:
    """End the command with ``code`` once its work is done: output flushed, descendants
    stopped, no interpreter shutdown -- during which Python puts SIGINT back to its
    default, so a Ctrl-C would kill the process by the signal, and Prefect's exit hook
    waits seconds for its server."""
    import logging
    if not _stopping.acquire(blocking=False):
        threading.Event().wait()
    _stopped.set()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    logging.shutdown()
    _stop_descendants_and_exit(code)


@contextlib.contextmanager
def hushed_when_stopping():
    """Processes started in this block write their stderr through a thread that passes it
    on to the command's stderr until the command stops; what they print while they are
    being stopped is dropped.  Prefect's server, stopped mid-start or by the terminal's
    Ctrl-C, prints a traceback; the command's one line must stay the last.  Output written
    by this process inside the block goes through the same thread, so nothing else is
    lost.  Outside a guarded command this does nothing."""
    if not guarded():
        yield
        return
    r, w = os.pipe()
    threading.Thread(target=_pass_on, args=(r,), name="accelcal-hushed-stderr", daemon=True).start()
    saved = os.dup(2)
    os.dup2(w, 2)                                      # inheritable: the children write to w
    os.close(w)
    try:
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _pass_on(r: int) -> None:
    while True:
        try:
            chunk = os.read(r, 65536)
        except OSError:
            return
        if not chunk:
            return
        if not _stopped.wait(HUSH_DELAY_S):
            try:
                os.write(2, chunk)
            except OSError:
                pass


def _stop_descendants_and_exit(code: int) -> None:
    w, proc = _guard.get("write_fd"), _guard.get("watchdog")
    if w is not None:
        try:
            os.write(w, b"now")                           # type: ignore[arg-type]
            os.close(w)                                   # type: ignore[arg-type]
            proc.wait(timeout=STOP_WAIT_S)                # type: ignore[union-attr]
        except (OSError, subprocess.TimeoutExpired):
            pass
    os._exit(code)


def _finish_stopping() -> None:
    """At exit: a stop under way ends the process with its own code (the main thread may
    return while the interrupt is handled)."""
    if _stopping.locked():
        threading.Event().wait()


def stop_on_interrupt(line: str, code: int = 130) -> bool:
    """Make SIGINT call :func:`stop_now` (from the main thread; install it before
    :func:`guard_descendants`, so no moment is left between them, and start the guard
    before any process: only the guard's descendants are stopped).  The signal is taken
    from a wakeup pipe by a thread of its own, so it acts even while the main thread
    waits inside a C call.  Returns whether it is installed."""
    if threading.current_thread() is not threading.main_thread() or not os.path.isdir("/proc/self"):
        return False
    r, w = os.pipe()
    os.set_blocking(w, False)
    signal.signal(signal.SIGINT, lambda *_: None)     # a Python handler: the pipe is written
    signal.set_wakeup_fd(w, warn_on_full_buffer=False)

    def wait_for_signal() -> None:
        while True:
            got = os.read(r, 64)
            if not got:
                return
            if signal.SIGINT in got:
                break
        stop_now(line, code)

    threading.Thread(target=wait_for_signal, name="accelcal-interrupt", daemon=True).start()
    atexit.register(_finish_stopping)
    return True

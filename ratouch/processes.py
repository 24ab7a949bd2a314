"""Worker processes that end with their parent, however it ends.

A process pool's workers are children of the process that made them; when that parent is
killed (SIGKILL gives it no chance to shut the pool down), Linux hands them to PID 1 and they
wait for work for good, each holding its copy of the world's texture tiles. Every pool of the
project is made here, with an initializer that binds each worker to its parent twice over: the
kernel's parent-death signal (`prctl(PR_SET_PDEATHSIG)`, Linux only), and a watchdog thread
that ends the worker once its parent process id changes (any POSIX system).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor

PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
WATCH_SECONDS = 0.5  # how often the watchdog looks at the parent


def fork_context():
    """Fork where the platform has it (workers inherit warmed tiles), else the default."""
    return mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None


def worker_pool(workers: int) -> ProcessPoolExecutor:
    """A process pool of `workers` (forked where possible) that end with this process."""
    return ProcessPoolExecutor(workers, mp_context=fork_context(),
                               initializer=bind_to_parent, initargs=(os.getpid(),))


def bind_to_parent(parent: int, death_signal: bool = True) -> None:
    """Make this (worker) process end when process `parent` ends; a pool's initializer.

    `death_signal=False` leaves the kernel's signal out and relies on the watchdog alone: the
    signal fires when the *thread* that started this process ends, not the process, which is
    wrong for a child started from a short-lived thread (`ratouch.serve.pool`'s model
    processes are started by whichever thread answers)."""
    if death_signal and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # no libc to call: the watchdog alone
            pass
    if os.getppid() != parent:  # the parent ended before the signal was asked for
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True,
                     name="parent-watchdog").start()


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_SECONDS)
    os._exit(1)  # the parent is gone: nothing will ever read this worker's results


# --------------------------------------------------------------------------- tagged processes
# Processes this one starts through another program (a local Ray: its GCS, raylet, agents and
# workers, which rename themselves "ray::DashboardAgent" and the like) cannot be bound to it
# with an initializer. They inherit its environment, though: a tag set there before they start
# finds every one of them, and a reaper process, started in a session of its own, ends them
# when this process ends, however it ends (its stdin, a pipe from this process, closes).

#: The environment variable whose value tags the processes of one owner: "<owner pid>-<random>".
TAG_VAR = "RATOUCH_PROCESS_TAG"
TERM_WAIT_S = 5.0  # how long tagged processes get to end after SIGTERM before SIGKILL


def tagged(tag: str | None = None) -> dict[int, str]:
    """{pid: tag} of the running processes (this user's, readable) whose environment carries a
    `TAG_VAR`, or this value of it; this process is left out."""
    found: dict[int, str] = {}
    prefix = f"{TAG_VAR}=".encode()
    for entry in os.listdir("/proc") if os.path.isdir("/proc") else []:
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                env = f.read().split(b"\0")
        except OSError:  # ended meanwhile, or another user's
            continue
        for item in env:
            if item.startswith(prefix):
                value = item[len(prefix):].decode(errors="replace")
                if tag is None or value == tag:
                    found[int(entry)] = value
                break
    return found


def end_tagged(tag: str) -> list[int]:
    """End every process tagged `tag` (SIGTERM, then SIGKILL after `TERM_WAIT_S`); returns
    their ids."""
    pids = list(tagged(tag))
    _signal_all(pids, signal.SIGTERM)
    deadline = time.monotonic() + TERM_WAIT_S
    while time.monotonic() < deadline and any(_running(p) for p in pids):
        time.sleep(0.1)
    _signal_all([p for p in pids if _running(p)], signal.SIGKILL)
    return pids


def end_orphans() -> list[int]:
    """End the tagged processes whose owner no longer runs (what a killed owner whose reaper
    was killed too left behind); returns their ids."""
    ended: list[int] = []
    for tag in set(tagged().values()):
        owner = tag.split("-", 1)[0]
        if owner.isdigit() and not _running(int(owner)):
            ended += end_tagged(tag)
    return ended


def start_reaper(tag: str, code_path: str) -> subprocess.Popen:
    """A process, in a session of its own (so a signal to this process's group spares it),
    that waits for this process to end, or to close the reaper's stdin, and then ends every
    process tagged `tag`. `code_path`: where this package is imported from."""

    env = {k: v for k, v in os.environ.items() if k != TAG_VAR}  # the reaper is not tagged
    env["PYTHONPATH"] = os.pathsep.join(p for p in (code_path, env.get("PYTHONPATH")) if p)
    return subprocess.Popen(
        [sys.executable, "-c", "import sys; from ratouch.processes import _reap; "
                               "_reap(sys.argv[1])", tag],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
        start_new_session=True, close_fds=True)


def _reap(tag: str) -> None:
    sys.stdin.buffer.read()  # returns when the owner closes the pipe or dies
    end_tagged(tag)


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _signal_all(pids: list[int], sig: int) -> None:
    for pid in pids:
        try:
            os.kill(pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

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


def bind_to_parent(parent: int) -> None:
    """Make this (worker) process end when process `parent` ends; a pool's initializer."""
    if sys.platform.startswith("linux"):
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

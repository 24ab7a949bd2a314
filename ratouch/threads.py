"""How many intra-op threads torch uses for a stretch of work, in the calling thread only.

`torch.set_num_threads` sets the OpenMP/MKL thread count of the calling thread (and the default
of threads started later); other running threads keep theirs. Small ops split over two OpenMP
threads on shared cores wait at a barrier for a descheduled thread, and waiting threads spin,
burning CPU. On this 2-core machine under load, a query's two generations took 480 ms (p50)
with two threads against 68 ms with one, and a batch of queries 90 instead of 12.5 CPU-ms
per query. The encoders of one query took 5.0-5.5 ms steadily with one thread, and
between 4.5 and 256 ms with two, in the same conditions (load 3-4). Switching a thread back
and forth between one and two is no cure: set the count once per serving thread.

Work someone waits for (a batch of queries) and work that can wait (a model prepared in the
background, its corpus embedded on first use) share the cores: `foreground` marks the first,
and the second calls `yield_to_foreground` between its steps, so that a query answered while
the app prepares its other models is not slowed by them (`waiting_for_background` marks the
stretch where a query waits for such work, which must then not wait for the query).

Where work can run on an accelerator instead (the TVL encoders, the encoders' training step),
`parse_device` checks the device asked for.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from typing import Iterator

import torch

from ratouch.errors import ConfigError


def parse_device(device: str | torch.device) -> torch.device:
    """A device name checked: one torch knows, and a GPU only where torch sees one.

    Raises:
        ConfigError: an unknown name, or "cuda" on a machine without a usable GPU.
    """
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as e:
        raise ConfigError(f"invalid device {device!r}: {e}") from e
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {device!r} requested but CUDA is not available")
    return dev


@contextlib.contextmanager
def intra_op_threads(n: int) -> Iterator[None]:
    """Run the enclosed torch ops of this thread on `n` intra-op threads, then restore.
    Meant for long stretches (a serving thread's life, a command), not around each call."""
    before = torch.get_num_threads()
    if before == n:
        yield
        return
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def blas_threads(n: int) -> None:
    """Run numpy's and scipy's BLAS (OpenBLAS: every matrix product, the blurs, the height
    map's perceptron) on `n` threads from now on, in the whole process. Unlike torch's
    count this is not per thread, so it is set once, by what serves (the batch worker,
    `ratouch query`, `ratouch bench query`), and not restored (threadpoolctl lets one live
    thread at a time change OpenBLAS's count: the first to set it). Its threads spin like
    torch's: under load on 2 cores (`scripts/load_test.py --clients 16 --queries 10`) the
    server took 0.276 CPU-s per query with OpenBLAS's default two and 0.172 with one, for
    the same throughput (6.6 and 6.5 queries/s)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(n, user_api="blas")


_cv = threading.Condition()
_busy = 0  # foreground stretches running now, in every thread
_local = threading.local()  # this thread's foreground depth


def _depth() -> int:
    return getattr(_local, "depth", 0)


@contextlib.contextmanager
def foreground() -> Iterator[None]:
    """Mark the enclosed work as work someone is waiting for (a batch of queries): background
    work calling `yield_to_foreground` waits while any runs."""
    global _busy
    with _cv:
        _busy += 1
    _local.depth = _depth() + 1
    try:
        yield
    finally:
        _local.depth = _depth() - 1
        with _cv:
            _busy -= 1
            _cv.notify_all()


@contextlib.contextmanager
def waiting_for_background() -> Iterator[None]:
    """Within foreground work, a stretch spent waiting for background work (a query waiting
    for a model another thread is loading): that work must not wait for this one meanwhile."""
    global _busy
    if _depth() == 0:
        yield
        return
    with _cv:
        _busy -= 1
        _cv.notify_all()
    try:
        yield
    finally:
        with _cv:
            _busy += 1


def yield_to_foreground(most_s: float = 2.0) -> float:
    """Called by background work between its steps: wait while foreground work runs, but at
    most `most_s` seconds (background work still advances under constant load); never in a
    thread that is itself doing foreground work. Returns the seconds waited."""
    if _depth() > 0:
        return 0.0
    t0 = time.monotonic()
    with _cv:
        _cv.wait_for(lambda: _busy <= 0, timeout=most_s)
    return time.monotonic() - t0


#: The nice value of background work (`background_priority`): the lowest priority.
BACKGROUND_NICE = 19


def background_priority() -> bool:
    """Run the calling thread, and the processes it forks from now on, at the lowest
    scheduling priority (:data:`BACKGROUND_NICE`), so that the cores go to foreground work
    whenever it wants them and to this work otherwise. Linux only (where a thread has a
    priority of its own); elsewhere nothing changes. Returns whether it changed. A thread
    cannot take its priority back: call it only from a thread that does background work to
    the end (`ModelChoice.prepare`'s)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, max(os.getpriority(os.PRIO_PROCESS, tid),
                                                 BACKGROUND_NICE))
        return True
    except OSError:
        return False

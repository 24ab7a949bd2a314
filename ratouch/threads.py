"""How many intra-op threads torch uses for a stretch of work, in the calling thread only.

`torch.set_num_threads` sets the OpenMP/MKL thread count of the calling thread (and the default
of threads started later); other running threads keep theirs. Small ops split over two OpenMP
threads on shared cores wait at a barrier for a descheduled thread, and waiting threads spin,
burning CPU. On this 2-core machine under load, a query's two generations took 480 ms (p50)
with two threads against 68 ms with one, and a batch of queries 90 instead of 12.5 CPU-ms
per query. The encoders of one query took 5.0-5.5 ms steadily with one thread, and
between 4.5 and 256 ms with two, in the same conditions (load 3-4). Switching a thread back
and forth between one and two is no cure: set the count once per serving thread.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch


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

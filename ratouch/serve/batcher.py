"""Serving many users from one model: concurrent requests gathered into batches.

On a CPU, one query's cost is mostly the two generators' greedy decoding, whose per-step
overhead hardly grows with the batch; concurrent queries answered one by one queue behind
each other. An `Answerer` answers several requests at once; `QueryBatcher` only gathers the
concurrent `answer` calls of server threads into such batches, so that latency under load
stays close to a single user's.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from typing import Any, Generic, TypeVar

from ratouch.errors import ConfigError
from ratouch.serve.request import ModelAnswerer, QueryRequest, QueryResult
from ratouch.threads import blas_threads, foreground, intra_op_threads

log = logging.getLogger(__name__)

M = TypeVar("M")


class _Pending:
    __slots__ = ("request", "result", "done")

    def __init__(self, request: QueryRequest):
        self.request = request
        self.result: Any = None
        self.done = threading.Event()


class QueryBatcher(Generic[M]):
    """An `Answerer` that answers concurrent calls together, by the `Answerer` it wraps.

    A worker thread takes what is waiting (up to `max_batch` requests, after waiting at most
    `max_wait_s` for more to arrive once the first has) and has the wrapped answerer answer
    it; each caller gets its own results. At most `workers` batches run at a time, so the
    model work of a server is bounded however many threads call `answer`. The requests come decoded
    (`QueryRequest.decode`, in the caller's thread), so that a slow upload (or a bad one)
    delays only its own caller, never the shared batch.

    Args:
        answerer: what answers the batches (a `RATouchPipeline`, a `ModelChoice`, ...).
        max_batch: most requests in one batch.
        max_wait_s: how long a batch waits for company; 0 answers what is there at once
            (requests that arrive while a batch runs form the next one anyway).
        threads: intra-op threads of the batch worker, and numpy's BLAS threads of the
            whole process (`ratouch.threads.blas_threads`), set when the worker starts. 1
            (the default) leaves the other cores to the server's HTTP work, and on shared
            cores it costs far less CPU per query (measured: 12.5 vs 90 CPU-ms per query in
            batches of 10, see `ratouch.threads`); None keeps torch's and numpy's settings.
        workers: batch workers, each answering its own batch (a share of what waits) at
            the same time as the others. One batch on one thread leaves the second of 2
            cores idle for 45 % of the time; 2 workers used it, but they contend for the
            GIL: on 2 cores (`scripts/load_test.py --clients 16 --queries 10`, 8 runs
            against 6) 7.7 against 7.0 queries/s on average, the p50 under load halved,
            the p95 up from 2.6-3.0 to 3.3-4.3 s and the server's CPU per query up from
            0.157 to 0.18-0.21 s (docs/performance.md), so 1 is the default for an
            answerer in this process. Over a `ratouch.serve.pool.ProcessPool`, whose model
            processes answer the batches, use one worker per model process (the app does).
            The answerer must answer concurrent batches as it answers them one at a time
            (the pipeline does: `tests/test_batcher.py`).
    """

    def __init__(self, answerer: ModelAnswerer[M], max_batch: int = 16, max_wait_s: float = 0.0,
                 threads: int | None = 1, workers: int = 1):
        if max_batch < 1:
            raise ConfigError(f"max_batch must be >= 1, got {max_batch}")
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ConfigError(f"workers must be an integer >= 1, got {workers!r}")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                    or threads < 1):
            raise ConfigError(f"threads must be None or an integer >= 1, got {threads!r}")
        self.answerer = answerer
        self.max_batch = max_batch
        self.max_wait_s = max_wait_s
        self.threads = threads
        self.batches: list[int] = []  # sizes of the recent batches (the last 1000)
        self._queue: list[_Pending] = []
        self._cv = threading.Condition()
        self.workers = workers
        self._pool: list[threading.Thread] = []

    def answer(self, requests: Sequence[QueryRequest]) -> list[QueryResult | Exception]:
        """The wrapped answerer's `answer`, in batches with concurrent calls' requests."""
        items = [_Pending(r) for r in requests]
        with self._cv:
            self._queue.extend(items)
            self._pool = [w for w in self._pool if w.is_alive()]
            while len(self._pool) < self.workers:
                self._pool.append(threading.Thread(target=self._run, daemon=True,
                                                   name=f"query-batcher-{len(self._pool)}"))
                self._pool[-1].start()
            self._cv.notify()
        for item in items:
            item.done.wait()
        return [item.result for item in items]

    def model(self, name: str | None = None) -> M:
        """The loaded model behind the wrapped answerer that answers requests naming `name`
        (its `model`)."""
        return self.answerer.model(name)

    def _take(self) -> list[_Pending]:
        """The next batch: a `workers`-th of what waits (rounded up), at most `max_batch`;
        the next idle worker is woken for the rest. A burst is split between the workers
        rather than taken whole by the first free one, which left the others' callers
        waiting behind one long batch: with two model processes (16 x 30, after a warm-up
        load) taking all that waited gave a p95 of 2.36-2.49 s, a share 1.54-2.02 s, for
        the same throughput (docs/performance.md)."""
        with self._cv:
            while not self._queue:
                self._cv.wait()
            if self.max_wait_s > 0 and len(self._queue) < self.max_batch:
                end = time.monotonic() + self.max_wait_s
                while len(self._queue) < self.max_batch and (left := end - time.monotonic()) > 0:
                    self._cv.wait(left)
            n = min(self.max_batch, -(-len(self._queue) // self.workers))
            batch, self._queue = self._queue[:n], self._queue[n:]
            if self._queue:
                self._cv.notify()
            return batch

    def _run(self) -> None:
        if self.threads is None:
            return self._loop()
        blas_threads(self.threads)  # process-wide: the batch worker is what a server runs
        with intra_op_threads(self.threads):
            self._loop()

    def _loop(self) -> None:
        while True:
            batch = self._take()
            results: Sequence[QueryResult | BaseException]
            try:
                with foreground():  # background work (models being prepared) waits meanwhile
                    results = self.answerer.answer([p.request for p in batch])
            except BaseException as e:  # noqa: BLE001 - every caller of the batch gets it
                log.error("a query batch of %d failed", len(batch), exc_info=e)
                results = [e] * len(batch)
            self.batches = (self.batches + [len(batch)])[-1000:]
            for p, r in zip(batch, results):
                p.result = r
                p.done.set()

"""Serving many users from one `RATouchPipeline`: concurrent queries gathered into batches.

On a CPU, one query's cost is mostly the two generators' greedy decoding, whose per-step
overhead hardly grows with the batch; concurrent queries answered one by one queue behind
each other. The pipeline's `query_many` answers several queries at once; `QueryBatcher` only
gathers concurrent `query` calls from server threads into such batches, so that latency under
load stays close to a single user's.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from ratouch.errors import ConfigError
from ratouch.threads import intra_op_threads

log = logging.getLogger(__name__)

class _Pending:
    __slots__ = ("request", "result", "done")

    def __init__(self, request: dict):
        self.request = request
        self.result: Any = None
        self.done = threading.Event()


class QueryBatcher:
    """`query` like the pipeline's, but concurrent calls are answered together.

    A worker thread takes what is waiting (up to `max_batch` requests, after waiting at most
    `max_wait_s` for more to arrive once the first has) and runs `query_many` on it; each
    caller gets its own result or exception. One batch runs at a time, so the model work of
    a server is bounded however many threads call `query`.

    Args:
        pipeline: the loaded pipeline (or anything whose attribute access yields one, like
            the app's `BackgroundPipeline`).
        max_batch: most requests in one batch.
        max_wait_s: how long a batch waits for company; 0 answers what is there at once
            (requests that arrive while a batch runs form the next one anyway).
        threads: intra-op threads of the batch worker. 1 (the default) leaves the other
            cores to the server's HTTP work, and on shared cores it costs far less CPU per
            query (measured: 12.5 vs 90 CPU-ms per query in batches of 10, see
            `ratouch.threads`); None keeps torch's setting.
    """

    def __init__(self, pipeline, max_batch: int = 16, max_wait_s: float = 0.0,
                 threads: int | None = 1):
        if max_batch < 1:
            raise ConfigError(f"max_batch must be >= 1, got {max_batch}")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                    or threads < 1):
            raise ConfigError(f"threads must be None or an integer >= 1, got {threads!r}")
        self.pipeline = pipeline
        self.max_batch = max_batch
        self.max_wait_s = max_wait_s
        self.threads = threads
        self.batches: list[int] = []  # sizes of the recent batches (the last 1000)
        self._queue: list[_Pending] = []
        self._cv = threading.Condition()
        self._worker: threading.Thread | None = None

    def query(self, visual: Any, tactile: Any = None, box=None, k: int = 5,
              label: str | None = None, background: Any = None,
              encoder: str | None = None) -> dict:
        """`RATouchPipeline.query`, answered in a batch with concurrent calls (`encoder`:
        the model, for a pipeline that offers a choice, `ratouch.serve.models.ModelChoice`).

        The images are decoded and checked here, in the caller's thread, so that a slow
        upload (or a bad one) delays only its own caller, never the shared batch."""
        req = {"visual": visual, "tactile": tactile, "box": box, "k": k, "label": label,
               "background": background}
        if encoder is not None:
            req["encoder"] = encoder
        item = _Pending(self.pipeline.prepare_request(req))
        with self._cv:
            self._queue.append(item)
            if self._worker is None or not self._worker.is_alive():
                self._worker = threading.Thread(target=self._run, daemon=True,
                                                name="query-batcher")
                self._worker.start()
            self._cv.notify()
        item.done.wait()
        if isinstance(item.result, BaseException):
            raise item.result
        return item.result

    def _take(self) -> list[_Pending]:
        with self._cv:
            while not self._queue:
                self._cv.wait()
            if self.max_wait_s > 0 and len(self._queue) < self.max_batch:
                end = time.monotonic() + self.max_wait_s
                while len(self._queue) < self.max_batch and (left := end - time.monotonic()) > 0:
                    self._cv.wait(left)
            batch, self._queue = self._queue[:self.max_batch], self._queue[self.max_batch:]
            return batch

    def _run(self) -> None:
        if self.threads is None:
            return self._loop()
        with intra_op_threads(self.threads):
            self._loop()

    def _loop(self) -> None:
        while True:
            batch = self._take()
            try:
                results = self.pipeline.query_many([p.request for p in batch])
            except BaseException as e:  # noqa: BLE001 - every caller of the batch gets it
                log.error("a query batch of %d failed", len(batch), exc_info=e)
                results = [e] * len(batch)
            self.batches = (self.batches + [len(batch)])[-1000:]
            for p, r in zip(batch, results):
                p.result = r
                p.done.set()

    def __getattr__(self, name: str) -> Any:
        """Everything but `query` is the pipeline's (corpus, encoders, ...)."""
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.pipeline, name)

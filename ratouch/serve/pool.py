"""Model work in child processes: batches answered at once without sharing one interpreter.

Two batches answered by threads of one process contend for its GIL (the pipeline's Python
between numpy and torch calls): on 2 cores two batch threads gave 10 % more queries/s for
15-35 % more CPU per query (docs/performance.md). `ProcessPool` answers each batch in one
of `n` child processes instead, each holding its own `ModelChoice` over the same models and
corpus, so each answers a request exactly as the parent would. The parent keeps its own
`ModelChoice` for everything else a server asks of a model (`model(name)`: thumbnails,
regeneration, the failure cases) and answers in-process until the first child is ready.

A child is started with the `spawn` method (a fresh interpreter: no threads or locks forked
from a server), runs its model work on one intra-op and one BLAS thread, warms its default
model (`ModelChoice.warm`: what a process's first query builds once) before it says it is
ready, and loads a model other than the default on its first request for it. A child that
dies (killed, out of memory) fails the batch it held with `ModelProcessError` and is replaced
(one found dead while idle is replaced and fails nothing: the batch goes to the next free
one), until `GIVE_UP_AFTER` have ended in a row with no batch answered between (a child that
dies on every batch): then the dead ones are no longer replaced and the parent's own models
answer. A child whose parent dies ends within a second, even while it loads
(`ratouch.processes.bind_to_parent`'s watchdog, started before torch is imported). As with
any `spawn`, a script that starts a pool must guard its own work with
``if __name__ == "__main__":`` (the child imports the script's module); `python -m app` does.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import queue
import threading
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from ratouch.errors import ConfigError, RATouchError
from ratouch.processes import bind_to_parent

if TYPE_CHECKING:  # not imported at run time: a model process starts its watch first
    from ratouch.serve.models import Model, ModelChoice
    from ratouch.serve.request import QueryRequest, QueryResult

log = logging.getLogger(__name__)


#: Model processes ended in a row (while answering a batch or idle; no batch answered
#: between) after which dead ones are no longer replaced: the parent answers by itself.
GIVE_UP_AFTER = 3


class ModelProcessError(RATouchError):
    """A model process ended while it answered a batch (the batch's requests get this)."""


def _child(conn, parent: int, default: str, names: list[str], corpus: str | None,
           make: Callable[..., Any] | None) -> None:
    """A model process: load the default model, say "ready", then answer the batches sent
    until None (or until the parent's end of the pipe closes)."""
    bind_to_parent(parent, death_signal=False)  # started from a batch worker's thread
    from ratouch.threads import blas_threads, intra_op_threads  # torch: after the watch

    if make is None:
        from ratouch.serve.models import ModelChoice
        make = ModelChoice
    blas_threads(1)
    with intra_op_threads(1):
        try:
            choice = make(default, names, corpus=corpus)
            warm = getattr(choice, "warm", None)
            if warm is not None:  # before "ready": the server answers meanwhile
                warm()
        except BaseException as e:  # noqa: BLE001 - reported to the parent, then exit
            try:
                conn.send(("failed", f"{type(e).__name__}: {e}"))
            except OSError:  # the parent is gone
                pass
            return
        try:
            conn.send(("ready", os.getpid()))
        except OSError:  # the parent went while this one loaded
            return
        while True:
            try:
                requests = conn.recv()
            except (EOFError, OSError):  # the parent is gone
                return
            if requests is None:
                return
            try:
                out: Any = choice.answer(requests)
            except BaseException as e:  # noqa: BLE001 - every request of the batch gets it
                out = e
            try:
                conn.send(out)
            except Exception as e:  # noqa: BLE001 - an answer that cannot be pickled
                conn.send(ModelProcessError(f"the answer could not be sent back: {e}"))


class _Worker:
    __slots__ = ("process", "conn", "pid")

    def __init__(self, process: Any, conn: Any) -> None:
        self.process = process
        self.conn = conn
        self.pid: int | None = None


class ProcessPool:
    """An `Answerer` whose batches are answered by `n` model processes, one batch each at a
    time (wrap it in `QueryBatcher(pool, workers=n)` to keep all of them busy).

    Args:
        local: the parent's own models: `model(name)` is `local.model(name)`, and `answer`
            uses it until a child is ready.
        n: model processes (>= 1).
        corpus: the corpus folder the children's models search (as `local`'s).
        on_demand: start the model processes only when concurrent requests first arrive
            (a batch of two or more, or two batches at once); until then, and while they
            load, `local` answers. One user asking one query at a time never starts them (no
            start-up work, no memory).
        make: what a model process answers with, called there as `make(default, names,
            corpus=corpus)` (default `ModelChoice`), whose `warm()`, where it has one, runs
            before the child says it is ready; it must be picklable by reference (a
            module-level function or class).
    """

    def __init__(self, local: ModelChoice, n: int, corpus: str | os.PathLike | None = None,
                 on_demand: bool = False, make: Callable[..., Any] | None = None):
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ConfigError(f"model processes must be an integer >= 1, got {n!r}")
        self.local = local
        self.n = n
        self._args = (os.getpid(), local.default, list(local.names),
                      None if corpus is None else str(corpus), make)
        self._ctx = mp.get_context("spawn")
        self._idle: queue.Queue[_Worker] = queue.Queue()
        self._lock = threading.Lock()
        self._workers: list[_Worker] = []
        self._ready = threading.Event()  # set once a child has answered "ready"
        self._closed = False
        self._in_flight = 0  # batches being answered now
        self.started = 0  # model processes started, replacements included
        self.ended_in_a_row = 0  # model processes that ended, no batch answered since
        self.gave_up = False  # True once GIVE_UP_AFTER ended in a row stopped replacements
        self._started_all = not on_demand
        if not on_demand:
            for _ in range(n):
                self._start()

    # ------------------------------------------------------------------ the processes

    def _start(self) -> None:
        parent, child = self._ctx.Pipe()
        process = self._ctx.Process(target=_child, args=(child, *self._args), daemon=True,
                                    name="ratouch-model")
        process.start()
        child.close()
        worker = _Worker(process, parent)
        with self._lock:
            self._workers.append(worker)
            self.started += 1
        threading.Thread(target=self._await_ready, args=(worker,), daemon=True,
                         name="ratouch-model-ready").start()

    def _await_ready(self, worker: _Worker) -> None:
        try:
            kind, what = worker.conn.recv()
        except (EOFError, OSError):
            kind, what = "failed", f"exit code {worker.process.exitcode}"
        if kind != "ready":
            log.error("a model process could not load its model: %s", what)
            self._drop(worker)
            return
        worker.pid = what
        log.info("model process %d ready", what)
        self._ready.set()
        self._idle.put(worker)

    def _ended(self, worker: _Worker) -> None:
        """A model process that ended: let go, and replaced unless the pool is closed or
        GIVE_UP_AFTER have ended in a row (none answered between)."""
        self._drop(worker)
        with self._lock:
            self.ended_in_a_row += 1
            if self.ended_in_a_row >= GIVE_UP_AFTER and not self.gave_up:
                self.gave_up = True
                log.error("model processes ended %d times in a row: they are no longer "
                          "replaced, and the server's own models answer once none is left",
                          self.ended_in_a_row)
            replace = not (self._closed or self.gave_up)
        if replace:
            self._start()  # a replacement; answers once it has loaded

    def _drop(self, worker: _Worker) -> None:
        with self._lock:
            if worker in self._workers:
                self._workers.remove(worker)
        worker.conn.close()
        if worker.process.is_alive():
            worker.process.kill()
        worker.process.join(5)

    def pids(self) -> list[int]:
        """The process ids of the ready model processes."""
        with self._lock:
            return [w.pid for w in self._workers if w.pid is not None]

    def ready(self) -> bool:
        """Whether a model process has loaded its model."""
        return self._ready.is_set()

    def close(self) -> None:
        """End the model processes (each finishes the batch it holds)."""
        self._closed = True
        with self._lock:
            workers = list(self._workers)
        for w in workers:
            try:
                w.conn.send(None)
            except (OSError, ValueError):
                pass
        for w in workers:
            w.process.join(10)
            self._drop(w)

    # ------------------------------------------------------------------ the Answerer

    def answer(self, requests: Sequence[QueryRequest]) -> list[QueryResult | Exception]:
        """The requests answered by the next free model process (by the parent's own models
        while none is ready yet)."""
        if self._closed:
            raise ModelProcessError("the model processes were closed")
        with self._lock:
            self._in_flight += 1
            start = not self._started_all and (self._in_flight >= 2 or len(requests) >= 2)
            self._started_all = self._started_all or start
        if start:
            log.info("concurrent queries: starting %d model process(es)", self.n)
            for _ in range(self.n):
                self._start()
        try:
            return self._answer(requests)
        finally:
            with self._lock:
                self._in_flight -= 1

    def _answer(self, requests: Sequence[QueryRequest]) -> list[QueryResult | Exception]:
        while True:
            worker = self._next() if self._ready.is_set() else None
            if worker is None:
                return self.local.answer(requests)
            if worker.process.is_alive():
                break
            # it ended while idle (killed, out of memory): not this batch's fault, which
            # goes to the next free one
            log.error("model process %s ended while idle (exit code %s)", worker.pid,
                      worker.process.exitcode)
            self._ended(worker)
        try:
            worker.conn.send(list(requests))
            out = worker.conn.recv()
        except (EOFError, OSError) as e:
            log.error("model process %s ended while answering a batch of %d: %s",
                      worker.pid, len(requests), e)
            self._ended(worker)
            err = ModelProcessError(f"the model process answering this query ended (exit code "
                                    f"{worker.process.exitcode}); ask again")
            return [err] * len(requests)
        with self._lock:
            self.ended_in_a_row = 0
        self._idle.put(worker)
        if isinstance(out, BaseException):
            raise out
        return out

    def _next(self) -> _Worker | None:
        """The next free model process, waiting for one; None when none is left (every one
        failed to load, or ended and was not replaced)."""
        while True:
            with self._lock:
                if not self._workers:
                    return None
            try:
                return self._idle.get(timeout=1.0)
            except queue.Empty:
                continue

    def model(self, name: str | None = None) -> Model:
        """The parent's own loaded model called `name` (`ModelChoice.model`)."""
        return self.local.model(name)

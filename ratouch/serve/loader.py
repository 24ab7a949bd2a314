"""Serving while the models load: `BackgroundPipeline` loads an answerer in a thread, so a
server (the app) answers within seconds of launch and queries wait for the models instead of
the page. It is an `Answerer` (`ratouch.serve.request`) wrapping the one it loads."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from typing import Any, Callable

from ratouch.errors import RATouchError

log = logging.getLogger(__name__)


class PipelineNotReady(RATouchError):
    """The pipeline failed to load, or did not load within the wait."""


class BackgroundPipeline:
    """An `Answerer` (`ratouch.serve.request`) being loaded by `load()` in a daemon thread.

    `answer` and `model` wait for it, so the app's handlers use it like the loaded answerer
    itself; `ready()` and `status()` never wait.

    Args:
        load: returns the loaded answerer (a `RATouchPipeline`, a `QueryBatcher`, ...).
        name: the encoder set, for the status line while loading.
        wait_s: longest wait of one attribute access.
        start: start loading now; False waits for `start()` (e.g. until the server is up,
            so that the loader does not compete with the server's start-up).
    """

    def __init__(self, load: Callable[[], Any], name: str, wait_s: float = 600.0,
                 start: bool = True):
        self.name = name
        self.wait_s = wait_s
        self.started = time.perf_counter()
        self.seconds: float | None = None
        self._pipeline: Any = None
        self._error: BaseException | None = None
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(load,), daemon=True,
                                        name="pipeline-loader")
        if start:
            self.start()

    def start(self) -> None:
        """Start loading (once)."""
        if not self._thread.is_alive() and not self._done.is_set():
            self._thread.start()

    def _run(self, load: Callable[[], Any]) -> None:
        t0 = time.perf_counter()
        try:
            self._pipeline = load()
            self.seconds = time.perf_counter() - t0
            log.info("pipeline loaded in %.1f s", self.seconds)
        except BaseException as e:  # noqa: BLE001 - handed to every waiting caller
            self._error = e
            log.error("the pipeline failed to load: %s", e)
        finally:
            self._done.set()

    def ready(self) -> bool:
        return self._done.is_set() and self._error is None

    def status(self) -> str:
        """'loading' / 'ready' / 'failed: <reason>'."""
        if not self._done.is_set():
            return "loading"
        return "ready" if self._error is None else f"failed: {self._error}"

    def get(self, timeout: float | None = None) -> Any:
        """The loaded pipeline, waiting up to `timeout` (default `wait_s`) seconds.

        Raises:
            PipelineNotReady: it failed to load, or is still loading after the wait.
        """
        if not self._done.wait(self.wait_s if timeout is None else timeout):
            raise PipelineNotReady(f"the models are still loading (started "
                                   f"{time.perf_counter() - self.started:.0f} s ago); "
                                   "try again in a moment")
        if self._error is not None:
            raise PipelineNotReady(f"the pipeline failed to load: {self._error}")
        return self._pipeline

    def answer(self, requests: Sequence) -> list:
        """The loaded answerer's `answer`, once it is loaded; every request's answer is
        `PipelineNotReady` when it failed to load, or is still loading after `wait_s`."""
        try:
            answerer = self.get()
        except PipelineNotReady as e:
            return [e] * len(requests)
        return answerer.answer(requests)

    def model(self, name: str | None = None) -> Any:
        """The loaded model answering requests that name `name` (the loaded answerer's
        `model`), once it is loaded."""
        return self.get().model(name)

"""Timing and progress: the library's one convention for each.

**Timing.** `Laps` is a stopwatch of named laps: ``clock = Laps()``, then ``clock.lap("encode")``
after each stage records the seconds since the previous lap (or the start); ``clock.ms()`` and
``clock.seconds(1)`` give them rounded, ``clock.elapsed()`` the time since the start.

**Progress.** A long-running function takes ``progress: Progress``, one of:

* ``False`` / ``None``: quiet (its lines go to the debug log);
* ``True``: progress bars on the terminal (tqdm) and its lines in the info log;
* a callable taking one line of text (``print``, ``list.append``): its lines go there, no bars.

Inside, ``say = say_to(progress, log)`` gives the function that takes each line, and
``progress_bar(iterable, progress, desc=...)`` the bar (drawn only for ``progress=True``);
`bars(progress)` passes the bar choice on to a callee that takes a plain bool.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from typing import Any, Union

#: What a function's ``progress`` argument may be (see the module docstring).
Progress = Union[bool, None, Callable[[str], Any]]

_log = logging.getLogger("ratouch")


class Laps:
    """A stopwatch of named laps (seconds, `time.perf_counter`)."""

    def __init__(self) -> None:
        self.start = self._t = time.perf_counter()
        self.laps: dict[str, float] = {}

    def lap(self, name: str) -> float:
        """Record the seconds since the previous lap (or the start) under `name` (added to
        what `name` already holds) and start the next lap; returns this lap's seconds."""
        now = time.perf_counter()
        took = now - self._t
        self.laps[name] = self.laps.get(name, 0.0) + took
        self._t = now
        return took

    def elapsed(self) -> float:
        """Seconds since the stopwatch started."""
        return time.perf_counter() - self.start

    def seconds(self, digits: int = 1) -> dict[str, float]:
        """The laps in seconds, rounded to `digits`."""
        return {k: round(v, digits) for k, v in self.laps.items()}

    def ms(self, digits: int = 2) -> dict[str, float]:
        """The laps in milliseconds, rounded to `digits`."""
        return {k: round(v * 1000, digits) for k, v in self.laps.items()}


def say_to(progress: Progress, log: logging.Logger | None = None) -> Callable[..., None]:
    """Where a function's progress lines go: the callable itself, else `log` (default the
    ``ratouch`` logger) at info level when `progress` is true and at debug level otherwise.
    The returned function takes a line, or a %-format and its arguments (as logging does)."""
    if callable(progress):
        return lambda msg, *args: progress(msg % args if args else msg)
    log = log or _log
    return log.info if progress else log.debug


def bars(progress: Progress) -> bool:
    """Whether progress bars are drawn: for a true `progress` that is not a callable."""
    return bool(progress) and not callable(progress)


def progress_bar(iterable: Iterable | None = None, progress: Progress = False, **kwargs):
    """A tqdm bar over `iterable` (or with ``total=``), drawn when `bars` (`progress`)."""
    from tqdm import tqdm

    return tqdm(iterable, disable=not bars(progress), **kwargs)


def peak_rss_mb() -> float:
    """This process's peak resident memory so far, in MB (Linux reports kilobytes)."""
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)

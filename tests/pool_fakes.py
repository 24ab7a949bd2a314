"""Stand-ins for a model process's models (`ProcessPool(make=...)`), kept in a module of their
own so that a spawned model process imports nothing else of the tests."""

from __future__ import annotations

import os

#: A request asking for this many neighbours ends the model process that answers it.
FATAL_K = 13


class EndsOnFatalRequests:
    """Answers each request with its `k` and this process's id; a batch holding a request of
    k == FATAL_K ends the process at once, as running out of memory would."""

    def __init__(self, default, names, corpus=None):
        self.default = default

    def answer(self, requests):
        if any(r.k == FATAL_K for r in requests):
            os._exit(3)
        return [{"k": r.k, "pid": os.getpid()} for r in requests]


class Warms(EndsOnFatalRequests):
    """Warms before it is ready (`ModelChoice.warm`'s place) and says so in each answer; a
    default named "cannot-warm" fails its warm-up."""

    def __init__(self, default, names, corpus=None):
        super().__init__(default, names, corpus)
        self.warmed = 0

    def warm(self):
        if self.default == "cannot-warm":
            raise RuntimeError("the warm-up failed")
        self.warmed += 1

    def answer(self, requests):
        return [{**a, "warmed": self.warmed} for a in super().answer(requests)]

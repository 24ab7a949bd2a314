"""`ratouch.threads`: how foreground work (batches of queries) and background work (models
prepared while the app serves) share the cores."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from ratouch.threads import (
    BACKGROUND_NICE,
    background_priority,
    foreground,
    waiting_for_background,
    yield_to_foreground,
)


def test_background_work_waits_while_queries_are_answered_but_not_for_ever():
    """`yield_to_foreground` waits while a batch of queries runs (`foreground`), returns at
    once when none does or when called from the foreground itself, and gives up after its
    limit, so a model being prepared still advances under constant load."""
    assert yield_to_foreground(1.0) < 0.05            # nothing in the foreground
    started, done = threading.Event(), threading.Event()

    def batch():
        with foreground():
            started.set()
            assert yield_to_foreground(1.0) == 0.0  # the foreground never waits for itself
            done.wait(5)

    t = threading.Thread(target=batch)
    t.start()
    started.wait(5)
    threading.Timer(0.3, done.set).start()
    waited = yield_to_foreground(5.0)
    assert 0.2 < waited < 3.0                          # until the batch ended
    t.join(5)
    with foreground():
        pass
    assert yield_to_foreground(1.0) < 0.05            # the count is back to zero
    hold, held = threading.Event(), threading.Event()

    def long_batch():
        with foreground():
            held.set()
            hold.wait(5)

    t = threading.Thread(target=long_batch)
    t.start()
    held.wait(5)
    assert 0.15 < yield_to_foreground(0.2) < 1.0      # gives up after its limit
    hold.set()
    t.join(5)


def test_a_stretch_waiting_for_background_work_does_not_hold_it_back():
    """Inside a batch, `waiting_for_background` lets background work run on while the batch
    waits for it; outside any batch it changes nothing."""
    with waiting_for_background():
        assert yield_to_foreground(1.0) < 0.05
    got = {}
    inside, release = threading.Event(), threading.Event()

    def batch():
        with foreground():
            with waiting_for_background():
                inside.set()
                release.wait(5)

    t = threading.Thread(target=batch)
    t.start()
    inside.wait(5)
    got["waited"] = yield_to_foreground(2.0)
    release.set()
    t.join(5)
    assert got["waited"] < 0.5
    assert yield_to_foreground(1.0) < 0.05


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a thread's own priority")
def test_background_priority_lowers_the_calling_thread_and_what_it_forks_only():
    here = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    seen = {}

    def run():
        seen["changed"] = background_priority()
        seen["nice"] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        pid = os.fork()
        if pid == 0:  # the child reports its priority by its exit status
            os._exit(os.getpriority(os.PRIO_PROCESS, 0))
        seen["child"] = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])

    t = threading.Thread(target=run)
    t.start()
    t.join(10)
    assert seen == {"changed": True, "nice": BACKGROUND_NICE, "child": BACKGROUND_NICE}
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == here

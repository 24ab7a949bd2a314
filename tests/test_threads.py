"""`ratouch.threads`: how foreground work (batches of queries) and background work (models
prepared while the app serves) share the cores."""

from __future__ import annotations

import contextlib
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


def _batch(waiting: bool = False) -> tuple[threading.Thread, threading.Event, dict]:
    """A thread answering a batch of queries (`foreground`; inside it, waiting for background
    work when `waiting`) until the event returned is set; the dict gets what
    `yield_to_foreground` gave inside it ("own")."""
    entered, release, seen = threading.Event(), threading.Event(), {}

    def run():
        with foreground():
            with waiting_for_background() if waiting else contextlib.nullcontext():
                seen["own"] = yield_to_foreground(1.0)
                entered.set()
                release.wait(5)

    t = threading.Thread(target=run)
    t.start()
    entered.wait(5)
    return t, release, seen


def test_background_work_waits_while_queries_are_answered_but_not_for_ever():
    """`yield_to_foreground` waits while a batch of queries runs (`foreground`), returns at
    once when none does or when called from the foreground itself, and gives up after its
    limit, so a model being prepared still advances under constant load."""
    assert yield_to_foreground(1.0) < 0.05            # nothing in the foreground
    t, release, seen = _batch()
    threading.Timer(0.3, release.set).start()
    waited = yield_to_foreground(5.0)
    t.join(5)
    assert seen["own"] == 0.0                          # the foreground never waits for itself
    assert 0.2 < waited < 3.0                          # until the batch ended
    with foreground():
        pass
    assert yield_to_foreground(1.0) < 0.05            # the count is back to zero
    t, release, _ = _batch()
    assert 0.15 < yield_to_foreground(0.2) < 1.0      # gives up after its limit
    release.set()
    t.join(5)


def test_a_stretch_waiting_for_background_work_does_not_hold_it_back():
    """Inside a batch, `waiting_for_background` lets background work run on while the batch
    waits for it; outside any batch it changes nothing."""
    with waiting_for_background():
        assert yield_to_foreground(1.0) < 0.05
    t, release, _ = _batch(waiting=True)
    waited = yield_to_foreground(2.0)
    release.set()
    t.join(5)
    assert waited < 0.5
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
    # a child at the lowest priority waits for every busier process: on a loaded machine it
    # may take many seconds to run at all (it failed at 10 s with a dozen processes on 2 cores)
    t.join(180)
    assert not t.is_alive(), "the lowered thread's child did not finish in 180 s"
    assert seen == {"changed": True, "nice": BACKGROUND_NICE, "child": BACKGROUND_NICE}
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == here


def test_an_xdist_worker_and_what_it_starts_run_on_its_share_of_the_cores():
    """`make test` runs two pytest-xdist workers; each, and each process its tests start,
    takes `cores // workers` intra-op threads (tests/conftest.py), so that the workers'
    OpenMP threads do not spin against each other."""
    import subprocess

    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if not workers:
        pytest.skip("not under pytest-xdist (`make test` runs it there)")
    share = max(1, (os.cpu_count() or 1) // int(workers))
    want = int(os.environ.get("OMP_NUM_THREADS", share))  # a user's own setting is kept
    out = subprocess.run([sys.executable, "-c", "import torch; print(torch.get_num_threads())"],
                         capture_output=True, text=True, check=True, timeout=120)
    assert int(out.stdout.strip()) == want

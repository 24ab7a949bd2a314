"""Model work in child processes (`ratouch.serve.pool.ProcessPool`): the same answers as in
the server's process, a dead model process fails only its batch and is replaced, a model
process that cannot load leaves the server answering by itself, one found dead while idle
fails nothing, model processes that end batch after batch are given up."""

from __future__ import annotations

import dataclasses
import os
import signal
import time
from types import SimpleNamespace

import numpy as np
import pytest

from ratouch.errors import ConfigError
from ratouch.serve.pool import GIVE_UP_AFTER, ModelProcessError, ProcessPool
from ratouch.serve.request import QueryRequest, answer_one


def _answers(results) -> list[tuple]:
    return [(r.description, {m: [n["id"] for n in ns] for m, ns in r.neighbours.items()},
             r.attention, r.warnings, r.trust) for r in results]


def _tiny(k: int) -> QueryRequest:
    """A request asking for `k` neighbours (the stand-in models answer with its `k`)."""
    return QueryRequest(np.zeros((4, 4, 3), np.uint8), None, None, (0, 0, 4, 4), k)


def _here() -> SimpleNamespace:
    """The server's own models, stood in for: each request answered with its `k`, marked."""
    return SimpleNamespace(default="fake", names=["fake"], model=lambda name=None: "local",
                           answer=lambda requests: [{"k": r.k, "here": True}
                                                    for r in requests])


def _wait(cond, seconds: float = 120.0) -> None:
    end = time.monotonic() + seconds
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.1)


@pytest.mark.slow
def test_model_processes_answer_as_the_server_would_and_replace_a_dead_one(
        pipeline, shipped_corpus, world):
    from concurrent.futures import ThreadPoolExecutor

    from ratouch.serve.batcher import QueryBatcher
    from ratouch.serve.models import ModelChoice

    local = ModelChoice("default-s", ["default-s"], load=lambda name: pipeline)
    samples = [world.sample("test", i) for i in range(0, 240, 20)]
    requests = [QueryRequest.decode(s.visual, s.tactile, box=s.box, k=5,
                                    background=world.background_image(s.sensor) if i % 2 else None,
                                    retrieval=("paper", "gated", "fallback")[i % 3])
                for i, s in enumerate(samples)]
    here = [answer_one(pipeline, r) for r in requests]
    pool = ProcessPool(local, 2, corpus=shipped_corpus)
    try:
        assert pool.model() is pipeline  # the server's own model, for everything else
        _wait(lambda: len(pool.pids()) == 2)
        pids = pool.pids()
        assert os.getpid() not in pids
        batcher = QueryBatcher(pool, workers=2)
        with ThreadPoolExecutor(8) as ex:
            there = list(ex.map(lambda r: answer_one(batcher, r), requests * 2))
        assert _answers(there) == _answers(here) * 2
        # a request's own error comes back as its error
        too_many = dataclasses.replace(requests[0], k=10_000)  # more than the corpus holds
        out = pool.answer([requests[0], too_many])
        assert _answers(out[:1]) == _answers(here[:1]) and isinstance(out[1], Exception)

        os.kill(pids[0], signal.SIGKILL)  # a model process dies while idle
        dead = next(w for w in pool._workers if w.pid == pids[0])
        _wait(lambda: not dead.process.is_alive(), 30)
        after = [pool.answer([requests[1]])[0] for _ in range(2)]  # the other answers them
        assert _answers(after) == _answers(here[1:2]) * 2
        _wait(lambda: len(pool.pids()) == 2 and pids[0] not in pool.pids())  # replaced
        assert _answers(pool.answer(requests[:3])) == _answers(here[:3])
    finally:
        pool.close()
    assert pool.pids() == []
    with pytest.raises(ModelProcessError, match="closed"):
        pool.answer(requests[:1])


def test_model_processes_that_end_batch_after_batch_are_given_up():
    """A model process that ends while answering fails that batch and is replaced, but after
    GIVE_UP_AFTER have ended in a row (no batch answered between) no more are started and the
    server's own models answer; an answered batch starts the count again."""
    from pool_fakes import FATAL_K, EndsOnFatalRequests

    pool = ProcessPool(_here(), 1, make=EndsOnFatalRequests)
    try:
        _wait(pool.ready)
        for _ in range(GIVE_UP_AFTER - 1):  # ends, replaced, ends, replaced ...
            assert isinstance(pool.answer([_tiny(FATAL_K)])[0], ModelProcessError)
        answered = pool.answer([_tiny(4)])[0]  # ... answered: the count starts again
        assert answered["k"] == 4 and answered["pid"] in pool.pids()
        assert not pool.gave_up and pool.started == GIVE_UP_AFTER
        for _ in range(GIVE_UP_AFTER):
            assert not pool.gave_up
            out = pool.answer([_tiny(FATAL_K), _tiny(5)])
            assert all(isinstance(e, ModelProcessError) and "ended" in str(e) for e in out)
        assert pool.gave_up and pool.started == 2 * GIVE_UP_AFTER - 1  # the last not replaced
        t0 = time.monotonic()
        assert pool.answer([_tiny(6)]) == [{"k": 6, "here": True}]  # the server's models
        assert time.monotonic() - t0 < 0.5  # nothing waited for
        assert pool.started == 2 * GIVE_UP_AFTER - 1 and pool.pids() == []
    finally:
        pool.close()


def test_a_model_process_found_dead_while_idle_fails_no_query():
    """A model process that ended between batches is found so before a batch is sent to it:
    it is replaced, and the batch goes to the next free one (here, its replacement)."""
    from pool_fakes import EndsOnFatalRequests

    pool = ProcessPool(_here(), 1, make=EndsOnFatalRequests)
    try:
        _wait(pool.ready)
        (pid,) = pool.pids()
        os.kill(pid, signal.SIGKILL)
        _wait(lambda: not pool._workers[0].process.is_alive(), 30)
        answered = pool.answer([_tiny(4)])[0]
        assert answered["k"] == 4 and answered["pid"] not in (pid, os.getpid())
        assert pool.started == 2 and pool.ended_in_a_row == 0 and not pool.gave_up
    finally:
        pool.close()


def test_a_model_process_that_cannot_load_leaves_the_server_answering():
    seen = []

    def local_answer(requests):
        seen.append(len(requests))
        return [{"k": r.k} for r in requests]

    local = SimpleNamespace(default="no-such-model", names=["no-such-model"],
                            answer=local_answer, model=lambda name=None: "local")
    pool = ProcessPool(local, 1)
    try:
        _wait(lambda: not pool._workers, 120)  # it reported its error and was let go
        request = _tiny(3)
        assert pool.answer([request]) == [{"k": 3}] and seen == [1]
        assert not pool.ready() and pool.model() == "local"
    finally:
        pool.close()
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match="model processes"):
            ProcessPool(local, bad)


def test_a_model_process_warms_before_it_says_it_is_ready_and_one_that_cannot_is_let_go():
    """A model process warms its models once (`ModelChoice.warm`) before it says "ready": its
    first answer comes after the warm-up. One whose warm-up fails is let go as one that
    cannot load, and the server answers."""
    from pool_fakes import Warms

    pool = ProcessPool(_here(), 1, make=Warms)
    try:
        _wait(pool.ready)
        assert [a["warmed"] for a in pool.answer([_tiny(2), _tiny(3)])] == [1, 1]
        assert pool.answer([_tiny(4)])[0]["warmed"] == 1  # once, not per batch
    finally:
        pool.close()
    cold = SimpleNamespace(**{**vars(_here()), "default": "cannot-warm", "names": ["cannot-warm"]})
    pool = ProcessPool(cold, 1, make=Warms)
    try:
        _wait(lambda: not pool._workers, 120)
        assert pool.answer([_tiny(5)]) == [{"k": 5, "here": True}] and not pool.ready()
    finally:
        pool.close()


def test_warming_a_model_choice_answers_two_made_up_queries_with_the_default_model(pipeline):
    """`ModelChoice.warm`: a grey image and frame, alone and against itself as background,
    answered by the default model only (the others stay unloaded); an error is raised. On the
    real pipeline both answer."""
    from ratouch.serve.models import ModelChoice

    seen = []

    class Recording:
        def __init__(self, fail=False):
            self.fail = fail

        def answer(self, requests):
            seen.append(requests)
            return [RuntimeError("no") if self.fail else {"k": r.k} for r in requests]

    loads = []
    choice = ModelChoice("a", ["a", "b"], load=lambda n: (loads.append(n), Recording())[1])
    choice.warm()
    (batch,) = seen
    assert [r.background is None for r in batch] == [True, False] and loads == ["a"]
    assert all(r.frame is not None and r.k == 1 and r.model is None for r in batch)
    with pytest.raises(RuntimeError, match="no"):
        ModelChoice("a", ["a"], load=lambda n: Recording(fail=True)).warm()
    # the photo route, which no grey crop takes, is warmed on its own: of a pipeline and of
    # each stage of a cascade
    warmed = []
    route = SimpleNamespace(warm=lambda: warmed.append("route"))
    with_route = Recording()
    with_route.photos = route
    ModelChoice("a", ["a"], load=lambda n: with_route).warm()
    cascade = Recording()
    cascade.stages = [SimpleNamespace(photos=None), SimpleNamespace(photos=route)]
    ModelChoice("a", ["a"], load=lambda n: cascade).warm()
    assert warmed == ["route", "route"]
    ModelChoice("default-s", ["default-s"], load=lambda name: pipeline).warm()


@pytest.mark.slow
def test_the_app_answers_through_a_model_process(shipped_corpus, world, tmp_path):
    """`python -m app --model-processes 1`, as a user starts it: one user's query is
    answered in the server's process and starts nothing; concurrent queries start the model
    process (spawned: the app's module is not run again in it), which then answers the
    queries sent through the API, and ends with the server."""
    import subprocess
    import sys
    from concurrent.futures import ThreadPoolExecutor
    from pathlib import Path

    import psutil
    from gradio_client import Client, handle_file
    from PIL import Image

    from conftest import free_port

    s = world.sample("test", 3)
    Image.fromarray(s.visual).save(tmp_path / "v.png")
    Image.fromarray(s.tactile).save(tmp_path / "t.png")
    port = free_port()
    log = open(tmp_path / "app.log", "w")
    app = subprocess.Popen([sys.executable, "-m", "app", "--host", "127.0.0.1", "--port",
                            str(port), "--corpus", str(shipped_corpus),
                            "--model-processes", "1"],
                           cwd=Path(__file__).resolve().parents[1], stdout=log,
                           stderr=subprocess.STDOUT)
    text = lambda: (tmp_path / "app.log").read_text()  # noqa: E731
    children: list = []
    try:
        _wait(lambda: "serving on http://" in text() or app.poll() is not None, 300)
        assert app.poll() is None, text()[-3000:]

        def ask(_=None) -> dict:
            c = Client(f"http://127.0.0.1:{port}/", verbose=False)
            return c.predict(handle_file(str(tmp_path / "v.png")),
                             handle_file(str(tmp_path / "t.png")), None, None, None, None, 5,
                             api_name="/query")

        first = ask()  # one user: answered here, nothing started
        assert first["description"]["ra_touch"]
        assert "starting 1 model process" not in text()
        assert not psutil.Process(app.pid).children()
        for _ in range(5):  # concurrent users: the model process is started
            with ThreadPoolExecutor(4) as ex:
                assert all(a["description"] == first["description"]
                           for a in ex.map(ask, range(4)))
            if "starting 1 model process" in text():
                break
        assert "starting 1 model process" in text(), text()[-3000:]
        _wait(lambda: "model process" in text() and " ready" in text()
              or app.poll() is not None, 300)
        assert app.poll() is None, text()[-3000:]
        children = [c for c in psutil.Process(app.pid).children()  # (not the resource
                    if "spawn_main" in " ".join(c.cmdline())]       # tracker)
        assert len(children) == 1
        busy = sum(children[0].cpu_times()[:2])
        answer = ask()
        assert answer["description"] == first["description"]
        assert len(answer["neighbours"]["joint"]) == 5
        assert sum(children[0].cpu_times()[:2]) - busy > 0.02  # it did the model work
        assert text().count("serving on http://") == 1  # the app ran once, not in the child
    finally:
        app.terminate()
        app.wait(30)
        log.close()
    _wait(lambda: not any(c.is_running() and c.status() != psutil.STATUS_ZOMBIE
                          for c in children), 30)  # its pipe closed: it ended too


def test_on_demand_model_processes_start_with_the_first_concurrent_requests():
    import threading

    both = threading.Barrier(2, timeout=30)
    pairs = []

    def local_answer(requests):
        pairs.append(len(requests))
        if pairs.count(2) <= 2 and len(requests) == 2:  # the concurrent pair: at once
            both.wait()
        return [{"k": r.k} for r in requests]

    local = SimpleNamespace(default="no-such-model", names=["no-such-model"],
                            answer=local_answer, model=lambda name=None: "local")
    pool = ProcessPool(local, 2, on_demand=True)
    try:
        request = _tiny(3)
        for _ in range(3):  # one at a time: nothing started
            assert pool.answer([request]) == [{"k": 3}]
        assert pool.started == 0
        threads = [threading.Thread(target=pool.answer, args=([request, request],))
                   for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30)
        assert pool.started == 2  # both, once
        pool.answer([request, request])
        assert pool.started == 2
        late = ProcessPool(local, 1, on_demand=True)  # a batch of two is concurrent too
        try:
            late.answer([request])
            assert late.started == 0
            late.answer([request, request, request])
            assert late.started == 1
        finally:
            late.close()
        _wait(lambda: not pool._workers, 120)  # they could not load: let go, answered here
        assert pool.answer([request]) == [{"k": 3}]
    finally:
        pool.close()


def test_a_model_process_ends_with_its_server_even_while_it_loads(shipped_corpus):
    """A server killed outright (no exit handlers run) leaves no model process behind, even
    one still loading its model (it notices its parent's end within a second)."""
    import subprocess
    import sys

    import psutil

    code = f"""if True:
        import os, signal, sys, time
        from types import SimpleNamespace
        from ratouch.serve.pool import ProcessPool
        local = SimpleNamespace(default="default-s", names=["default-s"])
        pool = ProcessPool(local, 1, corpus={str(shipped_corpus)!r})
        print(pool._workers[0].process.pid, flush=True)
        time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGKILL)
    """
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout is not None
        child = int(p.stdout.readline().split()[0])
        p.wait(120)  # the server's end (the child holds its stdout: not read to the end)
    finally:
        p.kill()
    t0 = time.monotonic()
    assert psutil.pid_exists(child)  # still loading when its server went
    _wait(lambda: not psutil.pid_exists(child)
          or psutil.Process(child).status() == psutil.STATUS_ZOMBIE, 30)
    assert time.monotonic() - t0 < 4.0  # well before its model would have loaded

"""Model work in child processes (`ratouch.serve.pool.ProcessPool`): the same answers as in
the server's process, a dead model process fails only its batch and is replaced, a model
process that cannot load leaves the server answering by itself."""

from __future__ import annotations

import dataclasses
import os
import signal
import time
from types import SimpleNamespace

import numpy as np
import pytest

from ratouch.errors import ConfigError
from ratouch.serve.pool import ModelProcessError, ProcessPool
from ratouch.serve.request import QueryRequest, answer_one


def _answers(results) -> list[tuple]:
    return [(r.description, {m: [n["id"] for n in ns] for m, ns in r.neighbours.items()},
             r.attention, r.warnings, r.trust) for r in results]


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

        os.kill(pids[0], signal.SIGKILL)  # a model process dies
        failed = [pool.answer([requests[1]])[0] for _ in range(2)]
        errors = [e for e in failed if isinstance(e, ModelProcessError)]
        assert len(errors) == 1 and "ended" in str(errors[0])
        assert _answers([r for r in failed if r is not errors[0]]) == _answers(here[1:2])
        _wait(lambda: len(pool.pids()) == 2 and pids[0] not in pool.pids())  # replaced
        assert _answers(pool.answer(requests[:3])) == _answers(here[:3])
    finally:
        pool.close()
    assert pool.pids() == []
    with pytest.raises(ModelProcessError, match="closed"):
        pool.answer(requests[:1])


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
        request = QueryRequest(np.zeros((4, 4, 3), np.uint8), None, None, (0, 0, 4, 4), 3)
        assert pool.answer([request]) == [{"k": 3}] and seen == [1]
        assert not pool.ready() and pool.model() == "local"
    finally:
        pool.close()
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match="model processes"):
            ProcessPool(local, bad)


@pytest.mark.slow
def test_the_app_answers_through_a_model_process(shipped_corpus, world, tmp_path):
    """`python -m app --model-processes 1`, as a user starts it: the model process is
    spawned (the app's module is not run again in it), becomes ready, answers a query sent
    through the API, and ends with the server."""
    import subprocess
    import sys
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
    try:
        text = lambda: (tmp_path / "app.log").read_text()  # noqa: E731
        _wait(lambda: "model process" in text() and " ready" in text()
              or app.poll() is not None, 300)
        assert app.poll() is None, text()[-3000:]
        children = psutil.Process(app.pid).children()
        assert len([c for c in children if c.is_running()]) >= 1
        assert text().count("serving on http://") == 1  # the app ran once, not in the child
        c = Client(f"http://127.0.0.1:{port}/", verbose=False)
        out = c.predict(handle_file(str(tmp_path / "v.png")), handle_file(str(tmp_path / "t.png")),
                        None, None, None, None, 5, api_name="/query")
        assert out["description"]["ra_touch"] and len(out["neighbours"]["joint"]) == 5
    finally:
        app.terminate()
        app.wait(30)
        log.close()
    _wait(lambda: not any(c.is_running() and c.status() != psutil.STATUS_ZOMBIE
                          for c in children), 30)  # its pipe closed: it ended too

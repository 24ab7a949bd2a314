"""The batching server: an `Answerer` wrapping an `Answerer`; its workers run on their own
intra-op thread count, the callers' left alone, and answer up to `workers` batches at once."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from ratouch.errors import ConfigError, DataError
from ratouch.serve.batcher import QueryBatcher
from ratouch.serve.request import QueryRequest, answer_one


def _request(k: int = 5) -> QueryRequest:
    return QueryRequest(np.zeros((4, 4, 3), np.uint8), None, None, (0, 0, 4, 4), k)


def test_worker_runs_batches_on_its_own_thread_count():
    seen = []

    def fake_answer(requests):
        seen.append(torch.get_num_threads())
        return [{"k": r.k} for r in requests]

    inner = SimpleNamespace(answer=fake_answer)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert answer_one(QueryBatcher(inner), _request(3)) == {"k": 3}
        assert answer_one(QueryBatcher(inner, threads=None), _request())
        assert torch.get_num_threads() == 2  # the caller's setting is untouched
    finally:
        torch.set_num_threads(before)
    assert seen[0] == 1
    for bad in (0, 1.5, True):
        with pytest.raises(ConfigError, match="threads"):
            QueryBatcher(inner, threads=bad)


def test_worker_puts_numpys_blas_on_one_thread_for_the_process():
    """OpenBLAS's count is process-wide: the worker sets it when it starts (its threads spin
    like torch's, `ratouch.threads.blas_threads`), and numpy's products run on one thread.
    In a fresh process: in this one an earlier test's worker already holds the setting."""
    code = """if True:
        import json
        from types import SimpleNamespace
        import numpy as np
        from threadpoolctl import threadpool_info
        from ratouch.serve.batcher import QueryBatcher
        from ratouch.serve.request import QueryRequest, answer_one

        def blas():
            return sorted({d["num_threads"] for d in threadpool_info()
                           if d["user_api"] == "blas"})

        seen = [blas()]
        def fake_answer(requests):
            seen.append(blas())
            return [{"k": r.k} for r in requests]
        request = QueryRequest(np.zeros((4, 4, 3), np.uint8), None, None, (0, 0, 4, 4), 3)
        answer_one(QueryBatcher(SimpleNamespace(answer=fake_answer)), request)
        print(json.dumps(seen + [blas()]))
    """
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    # before the worker, inside it, after it
    assert json.loads(p.stdout.strip().splitlines()[-1]) == [[2], [1], [1]]


def test_a_call_of_several_requests_gets_each_its_own_answer():
    def fake_answer(requests):
        return [DataError("bad") if r.k == 2 else {"k": r.k} for r in requests]

    b = QueryBatcher(SimpleNamespace(answer=fake_answer), max_batch=2)
    out = b.answer([_request(k) for k in (1, 2, 3)])
    assert out[0] == {"k": 1} and isinstance(out[1], DataError) and out[2] == {"k": 3}
    assert sorted(b.batches) == [1, 2]  # at most two requests a batch
    with pytest.raises(DataError):
        answer_one(b, _request(2))


def _busy_answerer(seconds: float):
    """A fake answerer that takes `seconds` a batch and records how many batches ran at
    once at most."""
    import threading
    import time

    state = {"now": 0, "most": 0}
    lock = threading.Lock()

    def fake_answer(requests):
        with lock:
            state["now"] += 1
            state["most"] = max(state["most"], state["now"])
        time.sleep(seconds)
        with lock:
            state["now"] -= 1
        return [{"k": r.k} for r in requests]

    return SimpleNamespace(answer=fake_answer), state


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_workers_answer_that_many_batches_at_once_and_share_a_burst(workers):
    inner, state = _busy_answerer(0.2)
    b = QueryBatcher(inner, max_batch=16, workers=workers)
    assert answer_one(b, _request(1)) == {"k": 1}  # starts the workers
    out = b.answer([_request(k) for k in range(1, 13)])
    assert out == [{"k": k} for k in range(1, 13)]  # each caller its own answer, in order
    assert state["most"] == workers
    # the burst of 12 split between the workers, not taken whole by the first: each take
    # is a `workers`-th of what waits then (12, then what the others left), whichever
    # worker is free first
    taken = sorted(b.batches[1:], reverse=True)  # the order they were taken in
    expected, left = [], 12
    while left:
        expected.append(-(-left // workers))
        left -= expected[-1]
    assert taken == expected


def test_a_burst_larger_than_the_workers_batches_waits_for_the_next_free_one():
    inner, state = _busy_answerer(0.05)
    b = QueryBatcher(inner, max_batch=2, workers=2)
    answer_one(b, _request(1))
    assert b.answer([_request(k) for k in range(1, 8)]) == [{"k": k} for k in range(1, 8)]
    assert sum(b.batches[1:]) == 7 and max(b.batches) <= 2 and state["most"] == 2
    for bad in (0, -1, 1.5, True, None):
        with pytest.raises(ConfigError, match="workers"):
            QueryBatcher(inner, workers=bad)


def test_a_failing_batch_answers_every_caller_with_its_error():
    def broken(requests):
        raise RuntimeError("the model broke")

    out = QueryBatcher(SimpleNamespace(answer=broken)).answer([_request(), _request()])
    assert all(isinstance(e, RuntimeError) for e in out)


def _answers(results) -> list[tuple]:
    """What a user compares: both descriptions and every mode's neighbours, in order."""
    return [(r.description, {m: [n["id"] for n in ns] for m, ns in r.neighbours.items()},
             r.attention) for r in results]


def test_an_answer_does_not_depend_on_who_else_is_asking(pipeline, world):
    """The same 32 world pairs through the serving stack one at a time and 16 at a time:
    identical descriptions and neighbour lists (encoding, search and prompts are per request;
    entries tied in score, e.g. identical captions, are ranked by corpus id)."""
    from concurrent.futures import ThreadPoolExecutor

    requests = [QueryRequest.decode(s.visual, s.tactile, box=s.box, k=5)
                for s in (world.sample("test", i) for i in range(0, 384, 12))]
    batcher = QueryBatcher(pipeline, max_batch=16, max_wait_s=0.05)
    alone = [answer_one(batcher, r) for r in requests]
    with ThreadPoolExecutor(16) as pool:
        together = list(pool.map(lambda r: answer_one(batcher, r), requests))
    assert max(batcher.batches) > 4  # they were answered together
    differ = [i for i, (a, b) in enumerate(zip(_answers(alone), _answers(together))) if a != b]
    assert not differ, f"{len(differ)} of {len(requests)} answers changed under load"
    # two batches answered at the same time by one pipeline (`--batch-workers 2`): the same
    two = QueryBatcher(pipeline, max_batch=16, workers=2)
    with ThreadPoolExecutor(16) as pool:
        parallel = list(pool.map(lambda r: answer_one(two, r), requests * 2))
    differ = [i for i, (a, b) in enumerate(zip(_answers(alone) * 2, _answers(parallel)))
              if a != b]
    assert not differ, f"{len(differ)} of {2 * len(requests)} answers changed in two workers"
    ranked = [[(-n["score"], n["id"]) for n in ns] for r in together
              for ns in r.neighbours.values()]
    assert all(keys == sorted(keys) for keys in ranked)  # equal shown scores: by corpus id
    assert any(len({s for s, _ in keys}) < len(keys) for keys in ranked)  # (there are ties)

"""The batching server's worker: its own intra-op thread count, the callers' left alone."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from ratouch.errors import ConfigError
from ratouch.serve.batcher import QueryBatcher


def test_worker_runs_batches_on_its_own_thread_count():
    seen = []

    def fake_many(requests):
        seen.append(torch.get_num_threads())
        return [{"k": r["k"]} for r in requests]

    pipe = SimpleNamespace(query_many=fake_many, prepare_request=dict)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert QueryBatcher(pipe).query("v", k=3) == {"k": 3}
        assert QueryBatcher(pipe, threads=None).query("v")
        assert torch.get_num_threads() == 2  # the caller's setting is untouched
    finally:
        torch.set_num_threads(before)
    assert seen[0] == 1
    for bad in (0, 1.5, True):
        with pytest.raises(ConfigError, match="threads"):
            QueryBatcher(pipe, threads=bad)

"""The retrieval benchmark: shape of the result and agreement of the methods (not speed)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ratouch.bench.index import (
    SCALE_EF_SWEEP,
    bench_corpus_index,
    bench_retrieval,
    bench_scale,
    clustered_vectors,
    format_bench,
    format_real,
    recall_by_score,
    upstream_retrieve,
)
from ratouch.corpus.embed import load_embeddings
from ratouch.errors import ConfigError
from ratouch.search.index import IndexConfig, VectorIndex, exact_topk


@pytest.fixture(scope="module")
def result() -> dict:
    return bench_retrieval(n=3000, dim=32, n_queries=20, batch=8, seed=1)


def test_result_has_every_key(result):
    for key in ("n", "dim", "k", "bandwidth_gb_s", "bound_ms", "methods",
                "speedup_vs_upstream", "peak_rss_mb", "flat_vs_bound"):
        assert key in result, key
    assert set(result["methods"]) == {"upstream", "flat", "hnsw", "ivfpq"}
    for name, row in result["methods"].items():
        for key in ("p50_ms", "p95_ms", "recall_at_5", "build_s"):
            assert key in row, (name, key)
        assert 0 < row["p50_ms"] <= row["p95_ms"]
        assert 0.0 <= row["recall_at_5"] <= 1.0
    assert set(result["speedup_vs_upstream"]) == {"flat", "hnsw", "ivfpq"}
    assert result["bandwidth_gb_s"] > 0 and result["bound_ms"] > 0
    assert result["methods"]["flat"]["batch_ms_per_query"] > 0
    assert set(result["methods"]["hnsw"]["ef_search_sweep"]) == {"32", "48", "64", "128"}
    assert set(result["methods"]["ivfpq"]["refine_sweep"]) == {"1", "5", "20"}
    json.dumps(result)  # a CLI prints it as JSON


def test_exact_methods_have_full_recall(result):
    assert result["methods"]["flat"]["recall_at_5"] == 1.0
    assert result["methods"]["upstream"]["recall_at_5"] == 1.0


def test_upstream_and_flat_agree_on_top1():
    x = clustered_vectors(3020, 32, seed=2)
    corpus, queries = x[:3000], x[3000:]
    index = VectorIndex.build(corpus, IndexConfig())
    _, ids = index.search(queries, 5)
    up = torch.stack([upstream_retrieve(torch.from_numpy(corpus), torch.from_numpy(q), 5)
                      for q in queries]).numpy()
    np.testing.assert_array_equal(up[:, 0], ids[:, 0])
    np.testing.assert_array_equal(exact_topk(queries, corpus, 5)[:, 0], ids[:, 0])


def test_clustered_vectors_are_unit_and_reproducible():
    a = clustered_vectors(100, 16, seed=5)
    assert a.dtype == np.float32 and a.shape == (100, 16)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(a, clustered_vectors(100, 16, seed=5))


def test_format_bench_names_every_method(result):
    text = format_bench(result)
    for name in result["methods"]:
        assert name in text
    assert "bandwidth" in text


def test_bad_arguments_raise_config_error():
    with pytest.raises(ConfigError, match="methods="):
        bench_retrieval(n=500, dim=8, methods=("flat", "annoy"))
    with pytest.raises(ConfigError, match="K="):
        bench_retrieval(n=500, dim=8, k=0)
    with pytest.raises(ConfigError, match="kind='upstream'"):
        bench_scale(n=500, dim=8, kind="upstream")


def test_bench_scale_small(tmp_path):
    out = bench_scale(n=2000, dim=16, kind="hnsw", folder=tmp_path, n_queries=10)
    for key in ("build_s", "save_s", "load_s", "p50_ms", "recall_at_5", "peak_rss_mb"):
        assert key in out
    assert out["recall_at_5"] >= 0.9
    assert out["config"]["ef_construction"] == 80
    assert set(out["ef_search_sweep"]) == {"128", "256", "512"}
    assert (tmp_path / "manifest.json").is_file()
    assert "load_s" in format_bench(out)


def test_bench_scale_default_kind_uses_a_temporary_folder():
    out = bench_scale(n=2000, dim=16, n_queries=10)
    assert out["kind"] == "ivfpq" and out["config"]["refine_factor"] == 20
    assert out["index_file_mb"] > 0 and "ef_search_sweep" not in out
    assert 0.0 <= out["recall_at_5"] <= 1.0


def test_recall_by_score_counts_an_equal_row_as_found_and_a_worse_one_not():
    keys = np.eye(4, dtype=np.float32)[[0, 0, 1, 2, 3]]  # rows 0 and 1 are the same vector
    q = np.array([[1.0, 0.2, 0.1, 0.0]], np.float32)
    truth = -np.sort(-(keys @ q[0]))[None, :]
    # the exact top-2 is {0, 1}; returning {1, 0} or {0, 1} is perfect, {0, 3} half wrong
    assert recall_by_score(np.array([[1, 0]]), q, keys, truth, k=2) == 1.0
    assert recall_by_score(np.array([[0, 3]]), q, keys, truth, k=2) == 0.5
    assert recall_by_score(np.array([[2, -1]]), q, keys, truth, k=2) == 0.0


def test_the_benchmark_on_a_built_corpus_holds_its_queries_out(small_corpus):
    r = bench_corpus_index(small_corpus, "debug", key="image", kinds=("flat", "hnsw"),
                           n_queries=20)
    _, _, manifest = load_embeddings(small_corpus, "debug", verify=False)
    assert r["n"] == manifest["count"] - 20 and r["key"] == "image"
    assert r["kinds"]["flat"]["recall_at_5"] == 1.0  # exact search finds the exact top 5
    assert set(r["kinds"]["hnsw"]["sweep"]) == {f"ef_search={e}" for e in SCALE_EF_SWEEP}
    assert "recall@5" in format_real(r)
    with pytest.raises(ConfigError, match="n_queries"):
        bench_corpus_index(small_corpus, "debug", n_queries=10**7)


def test_cli_bench_retrieval_on_a_corpus(small_corpus, capsys):
    from ratouch.cli import main

    assert main(["bench", "retrieval", "--corpus", str(small_corpus), "--encoder", "debug",
                 "--kinds", "flat", "--queries", "20", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert set(r) == {"image", "text"} and r["text"]["kinds"]["flat"]["recall_at_5"] == 1.0
    assert main(["bench", "retrieval", "--corpus", str(small_corpus), "--encoder", "debug",
                 "--kinds", "annoy"]) == 2

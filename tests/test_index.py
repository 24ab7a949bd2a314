"""The retrieval index: correctness of each kind, input checks, and safe persistence."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from ratouch.bench.index import clustered_vectors
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.search.index import IndexConfig, VectorIndex

N, DIM = 2000, 64


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray]:
    x = clustered_vectors(N + 50, DIM, seed=3, n_centres=40)
    return x[:N], x[N:]


@pytest.fixture(scope="module")
def flat(data) -> VectorIndex:
    return VectorIndex.build(data[0], IndexConfig(kind="flat"))


@pytest.fixture(scope="module")
def hnsw(data) -> VectorIndex:
    return VectorIndex.build(data[0], IndexConfig(kind="hnsw", hnsw_m=16, ef_construction=40,
                                                  ef_search=64))


def brute_force(corpus: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    return np.argsort(-(queries @ corpus.T), axis=1, kind="stable")[:, :k]


def recall(ids: np.ndarray, truth: np.ndarray) -> float:
    k = truth.shape[1]
    return float(np.mean([len(set(a) & set(b)) / k for a, b in zip(ids, truth)]))


@pytest.mark.parametrize("n_queries", [1, 5, 40])  # the BLAS scan and faiss's batched path
def test_flat_equals_numpy_brute_force(data, flat, n_queries):
    corpus, queries = data
    scores, ids = flat.search(queries[:n_queries], 5)
    assert scores.shape == ids.shape == (n_queries, 5)
    assert scores.dtype == np.float32 and ids.dtype == np.int64
    np.testing.assert_array_equal(ids, brute_force(corpus, queries[:n_queries], 5))
    np.testing.assert_allclose(scores, np.take_along_axis(queries[:n_queries] @ corpus.T,
                                                          ids, axis=1), atol=1e-5)
    assert np.all(np.diff(scores, axis=1) <= 0)


def test_hnsw_recall_on_clustered_data(data, hnsw):
    corpus, queries = data
    _, ids = hnsw.search(queries, 5)
    assert recall(ids, brute_force(corpus, queries, 5)) >= 0.9


def test_ivfpq_builds_and_finds_neighbours(data):
    corpus, queries = data
    index = VectorIndex.build(corpus, IndexConfig(kind="ivfpq", nlist=16, nprobe=16))
    assert index.kind == "ivfpq" and index.count == N and index.dim == DIM
    _, ids = index.search(queries, 5)
    assert ids.shape == (len(queries), 5) and ids.min() >= 0
    # product quantisation is lossy, but the right neighbourhood must be found
    assert recall(ids, brute_force(corpus, queries, 5)) >= 0.3
    _, top1 = index.search(corpus[:50], 1)
    assert np.mean(top1[:, 0] == np.arange(50)) >= 0.8


def test_one_dimensional_query_and_properties(data, flat):
    corpus, queries = data
    scores, ids = flat.search(queries[0], 3)
    assert scores.shape == ids.shape == (1, 3)
    assert (flat.dim, flat.count, flat.kind) == (DIM, N, "flat")
    assert flat.config == IndexConfig(kind="flat")


def test_queries_and_vectors_are_normalised(data, caplog):
    corpus, queries = data
    with caplog.at_level(logging.WARNING, logger="ratouch.search.index"):
        scaled = VectorIndex.build(corpus * 7.0, IndexConfig())
    assert "not unit norm" in caplog.text
    s1, i1 = scaled.search(queries[:3] * 0.01, 4)
    s2, i2 = scaled.search(queries[:3].astype(np.float64), 4)
    np.testing.assert_array_equal(i1, i2)
    np.testing.assert_allclose(s1, s2, atol=1e-5)
    assert s1.max() <= 1.0 + 1e-5


@pytest.mark.parametrize("k", [0, -1, N + 1])
def test_bad_k_raises_config_error(flat, data, k):
    with pytest.raises(ConfigError, match="K="):
        flat.search(data[1][0], k)


def test_k_larger_than_corpus_message(flat, data):
    with pytest.raises(ConfigError, match=f"larger than the corpus of {N} entries"):
        flat.search(data[1][0], N + 1)


def test_dimension_mismatch_raises_data_error(flat):
    with pytest.raises(DataError, match=f"query dimension 32 does not match the index "
                                        f"dimension {DIM}"):
        flat.search(np.ones(32, dtype=np.float32), 1)
    with pytest.raises(DataError, match="query dimension"):
        flat.search(np.ones((2, DIM + 1)), 1)


@pytest.mark.parametrize("bad", [np.zeros((0, 8)), np.zeros(8), np.zeros((2, 3, 4)),
                                 np.array([[1.0, np.nan]]), np.array([[np.inf, 1.0]]),
                                 np.zeros((3, 4)), [["a", "b"]], np.array([[1e300, 1.0]])])
def test_bad_vectors_raise_data_error(bad):
    with pytest.raises(DataError):
        VectorIndex.build(bad, IndexConfig())


@pytest.mark.parametrize("bad", [np.full(DIM, np.nan), np.zeros(DIM), np.zeros((0, DIM))])
def test_bad_queries_raise_data_error(flat, bad):
    with pytest.raises(DataError):
        flat.search(bad, 1)


def test_non_finite_row_is_named():
    x = np.ones((5, 4), dtype=np.float32)
    x[3, 1] = np.nan
    with pytest.raises(DataError, match="row 3"):
        VectorIndex.build(x, IndexConfig())


@pytest.mark.parametrize("kind, refine", [("flat", 0), ("hnsw", 0), ("ivfpq", 0),
                                          ("ivfpq", 4)])
def test_save_load_round_trip(tmp_path, data, kind, refine):
    corpus, queries = data
    cfg = IndexConfig(kind=kind, hnsw_m=8, ef_construction=20, nlist=8, refine_factor=refine)
    index = VectorIndex.build(corpus, cfg)
    index.save(tmp_path, {"encoder": "enc-a"})
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["kind"] == kind and manifest["dim"] == DIM and manifest["count"] == N
    assert manifest["meta"] == {"encoder": "enc-a"} and len(manifest["index_sha256"]) == 64
    loaded, meta = VectorIndex.load(tmp_path, expected_dim=DIM, expected_encoder="enc-a")
    assert meta == {"encoder": "enc-a"} and loaded.config == cfg
    for a, b in zip(index.search(queries, 5), loaded.search(queries, 5)):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(index.search(queries[0], 5), loaded.search(queries[0], 5)):
        np.testing.assert_array_equal(a, b)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.fixture
def saved(tmp_path, data):
    VectorIndex.build(data[0][:300], IndexConfig()).save(tmp_path, {"encoder": "enc-a"})
    return tmp_path


def snapshot(folder) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_corrupt_index_refuses_and_leaves_files(saved):
    path = saved / "index.faiss"
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    before = snapshot(saved)
    with pytest.raises(DataError, match="is corrupt: checksum mismatch"):
        VectorIndex.load(saved)
    assert snapshot(saved) == before


def test_missing_manifest_refuses(saved):
    (saved / "manifest.json").unlink()
    before = snapshot(saved)
    with pytest.raises(DataError, match="manifest.json"):
        VectorIndex.load(saved)
    assert snapshot(saved) == before


def test_unreadable_manifest_refuses(saved):
    (saved / "manifest.json").write_text("{not json")
    before = snapshot(saved)
    with pytest.raises(DataError, match="unreadable"):
        VectorIndex.load(saved)
    assert snapshot(saved) == before


def test_wrong_expected_dim_refuses(saved):
    before = snapshot(saved)
    with pytest.raises(DataError, match=f"was built for dimension {DIM}, the encoder gives 768"):
        VectorIndex.load(saved, expected_dim=768)
    assert snapshot(saved) == before


def test_wrong_expected_encoder_refuses(saved):
    before = snapshot(saved)
    with pytest.raises(DataError, match="'enc-a', expected 'enc-b'"):
        VectorIndex.load(saved, expected_encoder="enc-b")
    assert snapshot(saved) == before


def test_manifest_disagreeing_with_index_refuses(saved):
    manifest = json.loads((saved / "manifest.json").read_text())
    manifest["count"] = 999
    (saved / "manifest.json").write_text(json.dumps(manifest))
    before = snapshot(saved)
    with pytest.raises(DataError, match="manifest says"):
        VectorIndex.load(saved)
    assert snapshot(saved) == before


def test_index_of_another_kind_refuses(saved, data):
    VectorIndex.build(data[0][:300], IndexConfig(kind="hnsw", hnsw_m=8)).save(saved / "h")
    manifest = json.loads((saved / "manifest.json").read_text())
    manifest["index_sha256"] = json.loads((saved / "h" / "manifest.json").read_text())[
        "index_sha256"]
    (saved / "index.faiss").write_bytes((saved / "h" / "index.faiss").read_bytes())
    (saved / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DataError, match="manifest says flat 300 x 64, index.faiss holds "
                                        "IndexHNSWFlat"):
        VectorIndex.load(saved)


def test_missing_folder_raises_not_found(tmp_path):
    with pytest.raises(DataNotFoundError, match="does not exist"):
        VectorIndex.load(tmp_path / "nope")


@pytest.mark.parametrize("field, value", [
    ("kind", "annoy"), ("hnsw_m", 0), ("ef_construction", -1), ("ef_search", 0),
    ("nlist", 0), ("pq_m", -2), ("nprobe", 0), ("threads", 0), ("blas_threshold", 0),
    ("threads", 1.5), ("nprobe", True), ("refine_factor", -1)])
def test_index_config_validation(field, value):
    with pytest.raises(ConfigError, match=f"{field}={value!r}"):
        IndexConfig(**{field: value})


def test_refine_factor_only_for_ivfpq():
    with pytest.raises(ConfigError, match="refine_factor=4 applies to kind='ivfpq' only"):
        IndexConfig(kind="hnsw", refine_factor=4)


def test_ivfpq_refinement_reranks_exactly(data):
    corpus, queries = data
    index = VectorIndex.build(corpus, IndexConfig(kind="ivfpq", nlist=16, refine_factor=20))
    truth = brute_force(corpus, queries, 5)
    scores, ids = index.search(queries, 5)
    np.testing.assert_allclose(scores, np.take_along_axis(queries @ corpus.T, ids, axis=1),
                               atol=1e-5)  # exact scores of the re-ranked candidates
    assert recall(ids, truth) >= recall(index.with_search(refine_factor=1).search(
        queries, 5)[1], truth)
    assert recall(ids, truth) >= 0.8
    with pytest.raises(ConfigError, match="refine_factor=0"):
        index.with_search(refine_factor=0)


def test_ivfpq_config_must_fit_the_data(data):
    with pytest.raises(ConfigError, match="pq_m=7"):
        VectorIndex.build(data[0], IndexConfig(kind="ivfpq", pq_m=7))
    with pytest.raises(ConfigError, match="at least 256"):
        VectorIndex.build(data[0][:100], IndexConfig(kind="ivfpq"))


def test_with_search_changes_search_settings_only(data, hnsw):
    wider = hnsw.with_search(ef_search=128, threads=2)
    assert wider.config.ef_search == 128 and hnsw.config.ef_search == 64
    _, ids = wider.search(data[1], 5)
    assert recall(ids, brute_force(data[0], data[1], 5)) >= 0.9
    with pytest.raises(ConfigError, match="hnsw_m=8 cannot change"):
        hnsw.with_search(hnsw_m=8)


@pytest.mark.parametrize("cfg", [IndexConfig(kind="flat"),
                                 IndexConfig(kind="hnsw", hnsw_m=16, ef_construction=40,
                                             ef_search=64),
                                 IndexConfig(kind="ivfpq", nlist=16, nprobe=16, refine_factor=8)],
                         ids=["flat", "hnsw", "ivfpq+refine"])
def test_planted_neighbours_are_found_in_order(cfg):
    """Each query has five planted copies at increasing distances among 2000 random vectors:
    the top-5 must be exactly those, nearest first."""
    rng = np.random.default_rng(7)
    background = rng.normal(size=(2000, DIM)).astype(np.float32)
    queries = rng.normal(size=(20, DIM)).astype(np.float32)
    queries /= np.linalg.norm(queries, axis=1, keepdims=True)
    planted, truth = [], []
    for j, q in enumerate(queries):
        noise = rng.normal(size=(5, DIM)).astype(np.float32)
        noise /= np.linalg.norm(noise, axis=1, keepdims=True)
        planted.append(q + np.array([0.02, 0.05, 0.1, 0.15, 0.2], np.float32)[:, None] * noise)
        truth.append(len(background) + 5 * j + np.arange(5))
    corpus = np.concatenate([background, *planted])
    index = VectorIndex.build(corpus, cfg)
    _, ids = index.search(queries, 5)
    np.testing.assert_array_equal(ids, np.array(truth))


def test_one_top_k_decides_equal_scores_by_id():
    """`top_k` is the project's one top-k (exact reference, the flat index's few-query scan,
    the sharded merge): the k best by (higher score, lower id), in the order and at the k-th
    place alike, as a full lexicographic sort would give."""
    from ratouch.search.index import exact_topk, top_k

    rng = np.random.default_rng(0)
    for _ in range(200):
        q, n = rng.integers(1, 5), rng.integers(1, 40)
        sims = rng.integers(0, 4, (q, n)).astype(np.float32)  # many equal scores
        k = int(rng.integers(1, n + 1))
        scores, ids = top_k(sims, k)
        ref = np.array([np.lexsort((np.arange(n), -row))[:k] for row in sims])
        assert ids.dtype == np.int64 and (ids == ref).all()
        assert (scores == np.take_along_axis(sims, ref, 1)).all()
        assert (top_k(np.ascontiguousarray(sims.T).T, k)[1] == ref).all()  # a transposed view
    # duplicate keys (captions repeat): the exact reference and the flat index's scan agree
    keys = rng.standard_normal((300, 8)).astype(np.float32)
    keys[[40, 7, 250, 90]] = keys[3]
    keys /= np.linalg.norm(keys, axis=1, keepdims=True)
    index = VectorIndex.build(keys, IndexConfig(kind="flat"))
    assert exact_topk(keys[[3]], keys, 3).tolist() == [[3, 7, 40]]
    assert index.search(keys[3], 3)[1].tolist() == [[3, 7, 40]]

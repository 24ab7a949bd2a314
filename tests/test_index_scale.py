"""Index at scale: an IVF index built from shards into one on-disk index (lists memory-mapped
from `lists.ivfdata`), loaded through the usual `VectorIndex.load`, and a sharded index that
searches several indexes as one."""

from __future__ import annotations

import numpy as np
import pytest

from ratouch.errors import ConfigError, DataError
from ratouch.search.index import (
    IndexConfig,
    ShardedVectorIndex,
    VectorIndex,
    exact_topk,
)


def _vectors(n: int, dim: int = 32, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(40, dim))
    x = centres[rng.integers(0, 40, n)] + 0.3 * rng.normal(size=(n, dim))
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def _recall(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.mean([len(set(g) & set(w)) / len(w) for g, w in zip(got, want)]))


def test_ondisk_ivf_from_shards_matches_exact_search(tmp_path, capfd):
    x = _vectors(6000)
    shards = [x[:2500], x[2500:4000], x[4000:]]
    folder = tmp_path / "idx"
    cfg = IndexConfig(kind="ivfflat", nlist=32, nprobe=32)  # every list: exact
    capfd.readouterr()
    index = VectorIndex.build_ondisk(shards, folder, cfg, meta={"encoder": "e"})
    assert sorted(p.name for p in folder.iterdir()) == ["index.faiss", "lists.ivfdata",
                                                        "manifest.json"]
    assert capfd.readouterr().out == ""  # building and loading print nothing to stdout
    loaded, meta = VectorIndex.load(folder, expected_dim=32, expected_encoder="e")
    assert loaded.count == 6000 and meta == {"encoder": "e"}
    assert capfd.readouterr().out == ""  # faiss's notes go to stderr: stdout stays parseable
    q = x[[5, 3000, 5999]]
    want = exact_topk(q, x, 5)
    for ix in (index, loaded):
        assert np.array_equal(ix.search(q, 5)[1], want)  # global ids across shards
    approx = loaded.with_search(nprobe=4).search(_vectors(200, seed=1), 5)[1]
    assert _recall(approx, exact_topk(_vectors(200, seed=1), x, 5)) > 0.8


def test_ondisk_index_refuses_a_truncated_list_file(tmp_path):
    x = _vectors(3000)
    folder = tmp_path / "idx"
    VectorIndex.build_ondisk([x[:1500], x[1500:]], folder, IndexConfig(kind="ivfflat", nlist=16))
    lists = folder / "lists.ivfdata"
    lists.write_bytes(lists.read_bytes()[:-100])
    with pytest.raises(DataError, match="lists.ivfdata"):
        VectorIndex.load(folder)
    with pytest.raises(ConfigError, match="kind='flat'"):
        VectorIndex.build_ondisk([x], tmp_path / "f", IndexConfig(kind="flat"))


def test_sharded_index_searches_like_one_index(tmp_path):
    x = _vectors(3000)
    whole = VectorIndex.build(x)
    parts = [VectorIndex.build(x[:1000]), VectorIndex.build(x[1000:2200]),
             VectorIndex.build(x[2200:])]
    sharded = ShardedVectorIndex(parts)
    q = _vectors(50, seed=2)
    s1, i1 = whole.search(q, 7)
    s2, i2 = sharded.search(q, 7)
    assert sharded.count == 3000 and np.array_equal(i1, i2)
    np.testing.assert_allclose(s1, s2, atol=1e-6)
    with pytest.raises(ConfigError, match="K=3001"):
        sharded.search(q, 3001)
    with pytest.raises(ConfigError, match="saved where it is built"):
        sharded.save(tmp_path / "s")

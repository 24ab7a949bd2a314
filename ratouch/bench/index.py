"""Retrieval benchmark: the upstream RA-Touch ``retrieve()`` recipe against the index.

Every figure comes from one run on the same data: clustered unit vectors that stand in for
encoder embeddings (uniform random vectors are the worst case for approximate search and
say little about real embeddings; recall figures depend on the data, and are reported as
measured). The machine's memory read bandwidth is measured in the same run, which gives
the bound that an exact scan of the corpus cannot beat on this machine.
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ratouch.corpus.embed import load_embeddings
from ratouch.errors import ConfigError
from ratouch.search.index import (
    APPROXIMATE_KINDS,
    BENCH_KINDS,
    KINDS,
    IndexConfig,
    VectorIndex,
    exact_topk,
)
from ratouch.timing import Laps, peak_rss_mb, say_to

logger = logging.getLogger(__name__)

METHODS = ("upstream", *BENCH_KINDS)
HNSW_EF_SWEEP = (32, 48, 64, 128)
SCALE_EF_SWEEP = (128, 256, 512)
IVFPQ_REFINE_SWEEP = (1, 5, 20)  # 1: the PQ ranking alone (then exact scores of its top k)
_CHUNK = 65_536


def _method_config(name: str) -> IndexConfig:
    """The configuration each benchmarked index kind runs with, tuned on 150k x 768 on a
    shared 2-core machine. HNSW: efSearch=32 already gave recall@5 0.993 on the clustered
    data and 64 gave 1.000, at 0.34 and 0.47 ms; 48 keeps a margin on both targets (the
    sweep in the result shows the trade-off). IVF-PQ: PQ codes alone gave recall@5 ~0.4
    (near-duplicate neighbours differ by less than the quantisation error), so the
    benchmark re-ranks 20*k candidates exactly (10*k gave recall@5 0.93)."""
    if name == "hnsw":
        return IndexConfig(kind="hnsw", hnsw_m=32, ef_construction=80, ef_search=48)
    if name == "ivfpq":
        return IndexConfig(kind="ivfpq", nprobe=16, refine_factor=20)
    if name == "ivfflat":
        return IndexConfig(kind="ivfflat", nprobe=16)
    return IndexConfig(kind="flat")


def clustered_vectors(n: int, dim: int, seed: int = 0, n_centres: int = 1000,
                      noise: float = 1.0) -> np.ndarray:
    """(n, dim) float32 unit vectors around ``n_centres`` random centres on the sphere.

    A point is its centre plus Gaussian noise of expected norm ``noise`` (the centre has
    norm 1), then normalised. Rows are made in chunks, so 1M x 768 needs only the 3 GB of
    the result; the same (seed, chunk) always gives the same rows.
    """
    if n < 1 or dim < 1 or n_centres < 1:
        raise ConfigError(f"n={n!r}, dim={dim!r}, n_centres={n_centres!r} must be positive")
    rng = np.random.default_rng([seed, 0])
    centres = rng.standard_normal((n_centres, dim), dtype=np.float32)
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    out = np.empty((n, dim), dtype=np.float32)
    scale = np.float32(noise / math.sqrt(dim))
    for c, start in enumerate(range(0, n, _CHUNK)):
        crng = np.random.default_rng([seed, 1, c])
        rows = out[start:start + _CHUNK]
        crng.standard_normal(rows.shape, dtype=np.float32, out=rows)
        rows *= scale
        rows += centres[crng.integers(0, n_centres, len(rows))]
        rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    return out


def recall_at(ids: np.ndarray, truth: np.ndarray, k: int) -> float:
    """Mean share of the true top-k found in the returned top-k."""
    return float(np.mean([len(set(a[:k]) & set(b[:k])) / k for a, b in zip(ids, truth)]))


def upstream_retrieve(corpus: torch.Tensor, query: torch.Tensor, k: int) -> torch.Tensor:
    """The upstream RA-Touch ``retrieve()`` recipe: re-normalise the whole corpus on every
    call, one matrix product, a full descending argsort, keep the first k."""
    corpus = F.normalize(corpus, dim=-1)
    query = F.normalize(query, dim=-1)
    sims = query @ corpus.T
    return torch.argsort(sims, dim=-1, descending=True)[..., :k]


def measure_bandwidth(gib: float = 1.0, repeats: int = 3) -> float:
    """Memory read bandwidth in GB/s: best of ``repeats`` full reads of a ``gib`` GiB
    float32 array, by a sum (numpy, one thread) and by a BLAS matrix-vector product."""
    a = np.ones((int(gib * 2**30) // 4 // 1024, 1024), dtype=np.float32)
    v = np.ones(1024, dtype=np.float32)
    best = math.inf
    for read in (lambda: np.add.reduce(a, axis=0), lambda: a @ v):
        for _ in range(repeats):
            t0 = time.perf_counter()
            read()
            best = min(best, time.perf_counter() - t0)
    return a.nbytes / best / 1e9


def _latencies(search, queries: np.ndarray) -> tuple[np.ndarray, list[float]]:
    """Time each query alone (after one warm-up); return the ids and the times in ms."""
    search(queries[0])
    ids, times = [], []
    for q in queries:
        t0 = time.perf_counter()
        out = search(q)
        times.append((time.perf_counter() - t0) * 1e3)
        ids.append(np.asarray(out).reshape(-1))
    return np.stack(ids), times


def _summary(times: list[float]) -> dict:
    return {"p50_ms": round(float(np.percentile(times, 50)), 4),
            "p95_ms": round(float(np.percentile(times, 95)), 4), "queries": len(times)}



def _sweep(index, setting: str, values, queries, k: int, recall) -> dict:
    """Latency and recall@5 (``recall(ids)``) of the same index searched with each value of
    one setting, keyed by the value."""
    out = {}
    for value in values:
        tuned = index.with_search(**{setting: value})
        ids, times = _latencies(lambda q, tuned=tuned: tuned.search(q, max(k, 5))[1], queries)
        out[str(value)] = {**_summary(times), "recall_at_5": recall(ids)}
    return out


def bench_retrieval(n: int = 150_000, dim: int = 768, k: int = 5, n_queries: int = 200,
                    batch: int = 64, seed: int = 0, methods: Sequence[str] = METHODS,
                    progress: bool = False) -> dict:
    """Measure top-k retrieval over one clustered corpus, every method in one run.

    ``upstream`` runs the upstream recipe (torch) on at most 20 queries (it takes
    hundreds of ms each at full size); the index kinds run ``n_queries`` single queries,
    each timed alone. Recall@5 is against a numpy brute-force ground truth. ``flat`` also
    reports batched throughput and its ratio to the memory-bandwidth bound of one scan.

    Returns:
        ``{"n", "dim", "k", "bandwidth_gb_s", "scan_bytes", "bound_ms", "methods":
        {name: {"p50_ms", "p95_ms", "recall_at_5", "build_s", ...}},
        "speedup_vs_upstream": {name: upstream p50 / p50}, "peak_rss_mb"}``.
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise ConfigError(f"methods={tuple(methods)!r} must be a non-empty subset of {METHODS}")
    if not 1 <= k <= n:
        raise ConfigError(f"K={k!r} must lie in [1, n={n}]")
    if n_queries < 1 or batch < 1:
        raise ConfigError(f"n_queries={n_queries!r} and batch={batch!r} must be positive")
    say = say_to(progress, logger)
    data = clustered_vectors(n + n_queries, dim, seed=seed)
    corpus, queries = data[:n], data[n:]
    say("data: %d x %d corpus, %d queries", n, dim, n_queries)
    truth = exact_topk(queries, corpus, max(k, 5))
    results: dict[str, dict] = {}
    if "upstream" in methods:
        corpus_t = torch.from_numpy(corpus)
        few = queries[:min(n_queries, 20)]
        with torch.inference_mode():
            ids, times = _latencies(
                lambda q: upstream_retrieve(corpus_t, torch.from_numpy(q), max(k, 5)), few)
        results["upstream"] = {**_summary(times), "recall_at_5": recall_at(ids, truth, 5),
                               "build_s": 0.0}
        say("upstream: p50 %.2f ms", results["upstream"]["p50_ms"])
    # measured just before the exact scan, so both see the same load on the machine
    bandwidth = measure_bandwidth()
    scan_bytes = n * dim * 4
    bound_ms = scan_bytes / (bandwidth * 1e9) * 1e3
    say("read bandwidth %.1f GB/s, exact-scan bound %.2f ms", bandwidth, bound_ms)
    for name in (m for m in methods if m != "upstream"):
        cfg = _method_config(name)
        t0 = time.perf_counter()
        index = VectorIndex.build(corpus, cfg, seed=seed)
        build_s = time.perf_counter() - t0
        ids, times = _latencies(lambda q, index=index: index.search(q, max(k, 5))[1], queries)
        row = {**_summary(times), "recall_at_5": recall_at(ids, truth, 5),
               "build_s": round(build_s, 2), "config": asdict(cfg)}
        if name == "flat":
            t0 = time.perf_counter()
            for start in range(0, n_queries, batch):
                index.search(queries[start:start + batch], k)
            row["batch"] = batch
            row["batch_ms_per_query"] = round((time.perf_counter() - t0) * 1e3 / n_queries, 4)
            row["vs_bound"] = round(row["p50_ms"] / bound_ms, 3)
        if name == "hnsw":
            row["ef_search_sweep"] = _sweep(index, "ef_search", HNSW_EF_SWEEP, queries, k,
                                            lambda ids: recall_at(ids, truth, 5))
        if name == "ivfpq":
            row["refine_sweep"] = _sweep(index, "refine_factor", IVFPQ_REFINE_SWEEP, queries, k,
                                         lambda ids: recall_at(ids, truth, 5))
        results[name] = row
        say("%s: p50 %.3f ms, recall@5 %.3f, build %.1f s", name, row["p50_ms"],
            row["recall_at_5"], build_s)
        del index
    out = {"n": n, "dim": dim, "k": k, "bandwidth_gb_s": round(bandwidth, 2),
           "scan_bytes": scan_bytes, "bound_ms": round(bound_ms, 3), "methods": results}
    if "flat" in results:
        out["flat_vs_bound"] = results["flat"]["vs_bound"]
    if "upstream" in results:
        up = results["upstream"]["p50_ms"]
        out["speedup_vs_upstream"] = {m: round(up / r["p50_ms"], 1)
                                      for m, r in results.items() if m != "upstream"}
    out["peak_rss_mb"] = peak_rss_mb()
    return out


def bench_scale(n: int = 1_000_000, dim: int = 768, kind: str = "ivfpq",
                folder: str | Path | None = None, n_queries: int = 100, seed: int = 0,
                ef_construction: int = 80, progress: bool = False) -> dict:
    """Build an index over n clustered vectors, save it, load it back and query it.

    The index runs with the :func:`bench_retrieval` settings of its kind. The default is
    IVF-PQ (re-ranking 20*k candidates) because HNSW is too slow to build at this scale on
    a shared 2-core machine (load average 2-5). Measured over 1M x 768, one run each:
    HNSW M=32 efConstruction=80 built in 876 s, recall@5 0.83 at efSearch=48;
    efConstruction=40 built in 643 s, recall@5 0.64 (0.89 at efSearch=512, 1.9 ms);
    IVF-PQ built in 209 s, recall@5 0.86 at 1.25 ms. At 1M the ~1000 clusters hold ~1000
    near-equidistant points each, so recall is lower than at 150k; for HNSW the result
    adds a sweep of larger efSearch values on the loaded index.

    Args:
        kind: "hnsw", "ivfpq" or "flat".
        folder: where the index is saved (kept); None uses a temporary folder, removed.
        ef_construction: HNSW candidate list size while building.

    Returns:
        Build, save and load seconds, p50 query ms, recall@5 on ``n_queries`` queries
        against brute force, the index file size and the peak RSS.
    """
    if kind not in KINDS:
        raise ConfigError(f"kind={kind!r} must be one of {KINDS}")
    cfg = _method_config(kind)
    if kind == "hnsw":
        cfg = replace(cfg, ef_construction=ef_construction)
    say = say_to(progress, logger)
    data = clustered_vectors(n + n_queries, dim, seed=seed)
    corpus, queries = data[:n], data[n:]
    truth = exact_topk(queries, corpus, 5)
    own = folder is None
    target = Path(tempfile.mkdtemp(prefix="ratouch-index-")) if folder is None else Path(folder)
    try:
        clock = Laps()
        index = VectorIndex.build(corpus, cfg, seed=seed)
        say("built %s over %d x %d in %.1f s", kind, n, dim, clock.lap("build"))
        index.save(target, {"encoder": "synthetic-clustered", "seed": seed})
        clock.lap("save")
        del index
        loaded, _ = VectorIndex.load(target, expected_dim=dim,
                                     expected_encoder="synthetic-clustered")
        clock.lap("load")
        ids, times = _latencies(lambda q: loaded.search(q, 5)[1], queries)
        sweep = _sweep(loaded, "ef_search", SCALE_EF_SWEEP if kind == "hnsw" else (), queries, 5,
                       lambda ids: recall_at(ids, truth, 5))
        file_mb = (target / "index.faiss").stat().st_size / 2**20
    finally:
        if own:
            shutil.rmtree(target, ignore_errors=True)
    out = {"n": n, "dim": dim, "kind": kind, "config": asdict(cfg),
           **{f"{k}_s": v for k, v in clock.seconds(2).items()}, **_summary(times),
           "recall_at_5": recall_at(ids, truth, 5), "index_file_mb": round(file_mb, 1),
           "peak_rss_mb": peak_rss_mb()}
    if sweep:
        out["ef_search_sweep"] = sweep
    return out


REAL_KINDS = APPROXIMATE_KINDS
NPROBE_SWEEP = (8, 16, 32, 64)
_TIE = 1e-5  # scores this close to the k-th true score count as found (captions repeat)


def recall_by_score(ids: np.ndarray, queries: np.ndarray, keys: np.ndarray,
                    truth_scores: np.ndarray, k: int = 5) -> float:
    """Recall@k that counts a returned row as found when its exact score reaches the k-th
    true score: real corpora hold identical vectors (a caption shared by many entries), and
    which of several equal rows an index returns is arbitrary, not an error."""
    found = 0
    for q, row, best in zip(queries, ids, truth_scores):
        row = row[:k][row[:k] >= 0]
        found += int(np.sum(keys[row] @ q >= best[k - 1] - _TIE))
    return round(found / (k * len(queries)), 4)


def distinct_rows(keys: np.ndarray) -> int:
    """How many different rows keys holds (two seeded random projections as the rows' hash)."""
    proj = np.random.default_rng(0).standard_normal((keys.shape[1], 2)).astype(np.float32)
    return int(len(np.unique(np.round(keys @ proj, 4), axis=0)))


def bench_corpus_index(corpus: str | Path, encoder: str = "default-s", key: str = "image",
                       kinds: Sequence[str] = REAL_KINDS, n_queries: int = 200, seed: int = 0,
                       progress: bool = False) -> dict:
    """Index a built corpus's real embeddings of one key and measure each index kind.

    ``n_queries`` entries, a seeded choice, are held out of the index and query it with their
    own embedding of the same key (an image finds images, a caption captions), each query timed
    alone. Recall@5 is against an exact scan of the same rows, counting ties as found (see
    :func:`recall_by_score`); HNSW adds an efSearch sweep, IVF an nprobe sweep.

    Returns:
        ``{"corpus", "encoder", "key", "n", "dim", "distinct_rows", "kinds": {kind: {"p50_ms",
        "p95_ms", "recall_at_5", "build_s", "sweep", "config"}}, "peak_rss_mb"}``.
    """
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise ConfigError(f"kinds={tuple(kinds)!r} must be a non-empty subset of {KINDS}")
    if key not in ("image", "text"):
        raise ConfigError(f"key={key!r} must be 'image' or 'text'")
    say = say_to(progress, logger)
    image, text, manifest = load_embeddings(corpus, encoder, verify=False)
    rows = image if key == "image" else text
    n_all = len(rows)
    if not 0 < n_queries < n_all // 2:
        raise ConfigError(f"n_queries={n_queries!r} must lie in [1, {n_all // 2})")
    held = np.sort(np.random.default_rng([seed, 5]).choice(n_all, n_queries, replace=False))
    keep = np.ones(n_all, bool)
    keep[held] = False
    queries = np.ascontiguousarray(rows[held], np.float32)
    keys = np.ascontiguousarray(rows[keep], np.float32)
    say("%s key: %d x %d indexed, %d held-out queries", key, len(keys), keys.shape[1], n_queries)
    truth_ids = exact_topk(queries, keys, 5)
    scores = np.einsum("qd,qkd->qk", queries, keys[truth_ids])
    truth_scores = -np.sort(-scores, axis=1)

    def recall(ids: np.ndarray) -> float:
        return recall_by_score(ids, queries, keys, truth_scores)

    results = {}
    for kind in kinds:
        cfg = _method_config(kind)
        t0 = time.perf_counter()
        index = VectorIndex.build(keys, cfg, seed=seed)
        build_s = time.perf_counter() - t0
        ids, times = _latencies(lambda q, index=index: index.search(q, 5)[1], queries)
        row = {**_summary(times), "recall_at_5": recall(ids), "build_s": round(build_s, 1),
               "config": asdict(cfg)}
        setting, values = {"hnsw": ("ef_search", SCALE_EF_SWEEP),
                           "ivfflat": ("nprobe", NPROBE_SWEEP),
                           "ivfpq": ("refine_factor", IVFPQ_REFINE_SWEEP)}.get(kind, ("", ()))
        row["sweep"] = {f"{setting}={value}": r for value, r in
                        _sweep(index, setting, values, queries, 5, recall).items()}
        results[kind] = row
        say("%s: p50 %.3f ms, p95 %.3f ms, recall@5 %.3f, build %.1f s", kind, row["p50_ms"],
            row["p95_ms"], row["recall_at_5"], build_s)
        del index
    return {"corpus": str(corpus), "encoder": manifest["encoder"], "key": key,
            "n": int(len(keys)), "dim": int(keys.shape[1]),
            "distinct_rows": distinct_rows(keys), "kinds": results,
            "peak_rss_mb": peak_rss_mb()}


def format_real(result: dict) -> str:
    """A human-readable table of a :func:`bench_corpus_index` result."""
    lines = [f"{result['key']} key of {result['corpus']} ({result['encoder']}): "
             f"{result['n']} x {result['dim']}, {result['distinct_rows']} distinct rows",
             f"{'index':<10}{'setting':<18}{'p50 ms':>9}{'p95 ms':>9}{'recall@5':>10}{'build s':>9}"]
    for kind, row in result["kinds"].items():
        lines.append(f"{kind:<10}{'default':<18}{row['p50_ms']:>9.3f}{row['p95_ms']:>9.3f}"
                     f"{row['recall_at_5']:>10.3f}{row['build_s']:>9.1f}")
        for setting, s in row["sweep"].items():
            lines.append(f"{'':<10}{setting:<18}{s['p50_ms']:>9.3f}{s['p95_ms']:>9.3f}"
                         f"{s['recall_at_5']:>10.3f}")
    lines.append(f"peak RSS {result['peak_rss_mb']} MB")
    return "\n".join(lines)


def format_bench(result: dict) -> str:
    """A human-readable table of a :func:`bench_retrieval` or :func:`bench_scale` result."""
    if "methods" not in result:
        lines = [f"{key:>14}: {value}" for key, value in result.items()
                 if key not in ("config", "ef_search_sweep")]
        for ef, row in result.get("ef_search_sweep", {}).items():
            lines.append(f"hnsw efSearch={ef:<4} p50 {row['p50_ms']:.3f} ms  "
                         f"recall@5 {row['recall_at_5']:.3f}")
        return "\n".join(lines)
    lines = [f"top-{result['k']} over {result['n']} x {result['dim']} | read bandwidth "
             f"{result['bandwidth_gb_s']} GB/s, exact-scan bound {result['bound_ms']} ms",
             f"{'method':<10}{'p50 ms':>10}{'p95 ms':>10}{'recall@5':>10}{'build s':>10}"
             f"{'speedup':>10}"]
    speedup = result.get("speedup_vs_upstream", {})
    for name, row in result["methods"].items():
        lines.append(f"{name:<10}{row['p50_ms']:>10.3f}{row['p95_ms']:>10.3f}"
                     f"{row['recall_at_5']:>10.3f}{row['build_s']:>10.1f}"
                     f"{speedup.get(name, 1.0 if name == 'upstream' else float('nan')):>9.1f}x")
    flat = result["methods"].get("flat")
    if flat:
        lines.append(f"flat: {flat['p50_ms'] / result['bound_ms']:.2f}x the bandwidth bound "
                     f"single-query; batched ({flat['batch']}) "
                     f"{flat['batch_ms_per_query']} ms/query")
    for ef, row in result["methods"].get("hnsw", {}).get("ef_search_sweep", {}).items():
        lines.append(f"hnsw  efSearch={ef:<4} p50 {row['p50_ms']:.3f} ms  "
                     f"recall@5 {row['recall_at_5']:.3f}")
    for r, row in result["methods"].get("ivfpq", {}).get("refine_sweep", {}).items():
        lines.append(f"ivfpq refine={r:<6} p50 {row['p50_ms']:.3f} ms  "
                     f"recall@5 {row['recall_at_5']:.3f}")
    lines.append(f"peak RSS {result['peak_rss_mb']} MB")
    return "\n".join(lines)

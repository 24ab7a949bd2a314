"""The retrieval index: exact or approximate cosine search behind one class.

Vectors are L2-normalised on the way in, so cosine similarity is the inner product.
Three kinds share one interface: ``flat`` (exact inner product), ``hnsw`` (a graph,
approximate) and ``ivfpq`` (inverted lists over product-quantised codes, approximate and
compact). An index is saved with a manifest that records its shape, configuration, a
checksum of the faiss file and caller metadata (e.g. the encoder id); loading checks all
of it and refuses a mismatch rather than silently rebuilding.

This is the only module in the project that imports faiss.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Sequence, cast

import faiss
import numpy as np

from ratouch.checkpoint import sha256_file
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import replace_folder, staged, write_json_atomic
from ratouch.search.kinds import (  # noqa: F401 - the registry, re-exported
    APPROXIMATE_KINDS,
    BENCH_KINDS,
    KINDS,
    ONDISK_KINDS,
)

logger = logging.getLogger(__name__)

ONDISK_FILE = "lists.ivfdata"
INDEX_FILE = "index.faiss"
MANIFEST_FILE = "manifest.json"
MAX_TRAIN = 100_000
_CHUNK = 65_536
_FAISS_TYPES = {"flat": ("IndexFlatIP",), "hnsw": ("IndexHNSWFlat",),
                "ivfpq": ("IndexIVFPQ", "IndexRefineFlat"), "ivfflat": ("IndexIVFFlat",)}
SEARCH_FIELDS = frozenset({"ef_search", "nprobe", "refine_factor", "threads",
                           "blas_threshold"})


@contextmanager
def _stdout_to_stderr():
    """Send what C code writes to file descriptor 1 to descriptor 2 for a while, so that a
    command's standard output holds only what it means to print."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


@dataclass(frozen=True)
class IndexConfig:
    """How the index is built and searched.

    Attributes:
        kind: "flat" (exact inner product), "hnsw", "ivfpq" or "ivfflat" (inverted lists
            of full vectors; with `VectorIndex.build_ondisk` the lists live on disk).
        hnsw_m: HNSW neighbours per node (M).
        ef_construction: HNSW candidate list size while building.
        ef_search: HNSW candidate list size while searching (recall vs latency).
        nlist: IVF inverted lists; None picks about 4*sqrt(n), clipped to
            [1, n_train // 39] so every centroid gets 39 training points.
        pq_m: PQ sub-quantisers (must divide the dimension); None picks a divisor
            giving about 8-16 dimensions per sub-vector.
        nprobe: IVF lists visited per query.
        refine_factor: IVF-PQ only. 0 keeps only the PQ codes (compact, lossy: on
            near-duplicate clustered data recall@5 was measured at ~0.4). A value r > 0
            also stores the full vectors (n*dim*4 more bytes) and re-ranks the r*k best
            PQ candidates by exact inner product (recall@5 ~1.0 at r=10). Set at build
            time; when > 0 it can be changed per search with :meth:`VectorIndex.with_search`.
        threads: faiss OpenMP threads used for search. Single-query search was
            measured faster on 1 thread than on 2 on a 2-core machine, and degraded when
            another process held a core.
        blas_threshold: value for ``faiss.cvar.distance_compute_blas_threshold``, so
            that batched exact search of at least this many queries takes the BLAS path;
            None leaves faiss's default.
    """

    kind: str = "flat"
    hnsw_m: int = 32
    ef_construction: int = 80
    ef_search: int = 128
    nlist: int | None = None
    pq_m: int | None = None
    nprobe: int = 16
    refine_factor: int = 0
    threads: int = 1
    blas_threshold: int | None = 16

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(f"kind={self.kind!r} must be one of {KINDS}")
        for name in ("hnsw_m", "ef_construction", "ef_search", "nprobe", "threads"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"{name}={value!r} must be a positive integer")
        for name in ("nlist", "pq_m", "blas_threshold"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or isinstance(value, bool)
                                      or value < 1):
                raise ConfigError(f"{name}={value!r} must be a positive integer or None")
        r = self.refine_factor
        if not isinstance(r, int) or isinstance(r, bool) or r < 0:
            raise ConfigError(f"refine_factor={r!r} must be a non-negative integer")
        if r and self.kind != "ivfpq":
            raise ConfigError(f"refine_factor={r!r} applies to kind='ivfpq' only, not "
                              f"kind={self.kind!r}")


def _as_matrix(vectors: np.ndarray, what: str) -> np.ndarray:
    """Check a (N, D) array of finite real numbers; return it as C-contiguous float32."""
    try:
        x = np.asarray(vectors)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{what} cannot be read as an array: {exc}") from exc
    if x.ndim != 2:
        raise DataError(f"{what} must be 2-D (N, D), got shape {x.shape}")
    if x.shape[0] < 1 or x.shape[1] < 1:
        raise DataError(f"{what} is empty: shape {x.shape}")
    if not np.issubdtype(x.dtype, np.number) or np.iscomplexobj(x):
        raise DataError(f"{what} must be real numbers, got dtype {x.dtype}")
    for start in range(0, len(x), _CHUNK):
        finite = np.isfinite(x[start:start + _CHUNK])
        if not finite.all():
            bad = start + int(np.flatnonzero(~finite.all(axis=1))[0])
            raise DataError(f"{what} has a non-finite value in row {bad}")
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(x, dtype=np.float32)
    if x.dtype.itemsize > 4 and not np.isfinite(out).all():
        raise DataError(f"{what} has values too large for float32 (max |x| "
                        f"{float(np.abs(x).max()):.3g})")
    return out


def _normalised(x: np.ndarray, what: str, warn: bool) -> np.ndarray:
    """Rows of a finite (N, D) float32 array scaled to unit L2 norm (x itself when they
    already are). Norms that overflow float32 are redone in float64."""
    norms = np.empty(len(x), dtype=np.float64)
    for start in range(0, len(x), _CHUNK):
        block = x[start:start + _CHUNK]
        norms[start:start + len(block)] = np.sqrt(np.einsum("ij,ij->i", block, block))
    big = ~np.isfinite(norms)
    if big.any():
        norms[big] = np.linalg.norm(x[big].astype(np.float64), axis=1)
    if (norms == 0).any():
        raise DataError(f"{what} has a zero vector in row {int(np.flatnonzero(norms == 0)[0])}")
    if np.abs(norms - 1.0).max() <= 1e-3:
        return x
    if warn:
        logger.warning("%s were not unit norm (norms %.3g .. %.3g); normalising them",
                       what, float(norms.min()), float(norms.max()))
    out = np.empty(x.shape, dtype=np.float32)
    for start in range(0, len(x), _CHUNK):
        stop = start + _CHUNK
        out[start:stop] = x[start:stop] / norms[start:stop, None]
    return out


def _default_nlist(n: int) -> int:
    n_train = min(n, MAX_TRAIN)
    return max(1, min(round(4 * math.sqrt(n)), n_train // 39))


def _default_pq_m(dim: int) -> int:
    """A divisor of dim giving 8-16 dimensions per sub-vector (else the closest to 8)."""
    divisors = [m for m in range(1, dim + 1) if dim % m == 0]
    fitting = [m for m in divisors if 8 <= dim // m <= 16]
    if fitting:
        return max(fitting)
    return min(divisors, key=lambda m: abs(dim / m - 8))


class VectorIndex:
    """A cosine-similarity index over L2-normalised float32 vectors.

    Build one with :meth:`build` or :meth:`load`, never with the constructor.
    """

    def __init__(self, index: faiss.Index, cfg: IndexConfig) -> None:
        self._index = index
        self._cfg = cfg
        self._kind, self._dim, self._count = cfg.kind, int(index.d), int(index.ntotal)
        self._xb: np.ndarray | None = None  # in-place view of a flat index's vectors
        self._ondisk = False
        self._params: faiss.SearchParameters | None = None
        self._ivf_params: faiss.SearchParameters | None = None
        if cfg.kind == "hnsw":
            # faiss's stubs lack SearchParametersHNSW (faiss 1.15.1 defines it)
            self._params = faiss.SearchParametersHNSW(  # type: ignore[attr-defined]
                efSearch=cfg.ef_search)
        elif cfg.kind in ONDISK_KINDS:
            # set field by field: faiss's stubs do not know its keyword constructors (which
            # set the same attributes)
            ivf = faiss.SearchParametersIVF()
            ivf.nprobe = min(cfg.nprobe, faiss.extract_index_ivf(index).nlist)
            self._params = ivf
            if cfg.refine_factor:
                self._ivf_params = ivf  # the refine parameters only point at it
                refine = faiss.IndexRefineSearchParameters()
                refine.k_factor = float(cfg.refine_factor)
                refine.base_index_params = ivf
                self._params = refine

    @property
    def dim(self) -> int:
        """Vector dimension."""
        return self._dim

    @property
    def count(self) -> int:
        """Number of indexed vectors."""
        return self._count

    @property
    def kind(self) -> str:
        """"flat", "hnsw" or "ivfpq"."""
        return self._cfg.kind

    @property
    def config(self) -> IndexConfig:
        """The configuration the index was built with."""
        return self._cfg

    def with_search(self, **changes: int | None) -> VectorIndex:
        """A view of the same index searched with other search-time settings.

        Args:
            changes: any of ``ef_search``, ``nprobe``, ``threads``, ``blas_threshold`` and
                (on an index built with it) ``refine_factor``.

        Raises:
            ConfigError: a field that is fixed at build time, or an invalid value.
        """
        fixed = sorted(set(changes) - SEARCH_FIELDS)
        if fixed:
            raise ConfigError(f"{fixed[0]}={changes[fixed[0]]!r} cannot change after "
                              f"building; only {sorted(SEARCH_FIELDS)} can")
        refine = changes.get("refine_factor", self._cfg.refine_factor)
        if (refine == 0) != (self._cfg.refine_factor == 0):
            raise ConfigError(f"refine_factor={refine!r}: refinement is switched on or off "
                              "only when building")
        fields: dict[str, Any] = dict(changes)  # IndexConfig checks their values
        view = VectorIndex(self._index, replace(self._cfg, **fields))
        view._xb = self._xb
        return view

    @classmethod
    def build(cls, vectors: np.ndarray, cfg: IndexConfig | None = None,
              seed: int = 0) -> VectorIndex:
        """Index (N, D) vectors; rows are normalised (with a log warning if they were not).

        Args:
            vectors: (N, D) finite numbers, N >= 1.
            cfg: the index configuration (default: exact flat search).
            seed: seeds the IVF-PQ training subset and k-means.

        Raises:
            DataError: vectors are not 2-D, empty, non-finite or contain a zero row.
            ConfigError: the configuration does not fit the data (e.g. pq_m does not
                divide the dimension, or IVF-PQ over fewer vectors than it needs to train).
        """
        cfg = cfg or IndexConfig()
        x = _normalised(_as_matrix(vectors, "index vectors"), "index vectors", warn=True)
        n, dim = x.shape
        index: faiss.Index
        if cfg.kind == "flat":
            index = faiss.IndexFlatIP(dim)
        elif cfg.kind == "hnsw":
            hnsw = faiss.IndexHNSWFlat(dim, cfg.hnsw_m, faiss.METRIC_INNER_PRODUCT)
            hnsw.hnsw.efConstruction = cfg.ef_construction
            hnsw.hnsw.efSearch = cfg.ef_search
            index = hnsw
        else:
            index = cls._trained_ivfpq(x, cfg, seed, n)
        t0 = time.perf_counter()
        for start in range(0, n, _CHUNK * 4):
            index.add(x[start:start + _CHUNK * 4])
            logger.debug("added %d / %d vectors (%.0f s)", min(start + _CHUNK * 4, n), n,
                         time.perf_counter() - t0)
        logger.info("built a %s index of %d x %d", cfg.kind, n, dim)
        return cls(index, cfg)

    @staticmethod
    def _trained_ivfpq(x: np.ndarray, cfg: IndexConfig, seed: int, n: int) -> faiss.Index:
        """An empty IVF-PQ or IVF-flat index for `n` vectors, trained on (a sample of) x."""
        dim = x.shape[1]
        pq_m = cfg.pq_m or _default_pq_m(dim)
        if cfg.kind == "ivfpq" and dim % pq_m:
            raise ConfigError(f"pq_m={pq_m!r} must divide the dimension {dim}")
        if len(x) < 256:
            raise ConfigError(f"kind={cfg.kind!r} needs at least 256 vectors to train, "
                              f"got {len(x)}")
        nlist = cfg.nlist or _default_nlist(n)
        if nlist > len(x):
            raise ConfigError(f"nlist={nlist!r} is larger than the corpus of {len(x)} entries "
                              "(training vectors)")
        quantizer = faiss.IndexFlatIP(dim)
        ivf: faiss.IndexIVF
        if cfg.kind == "ivfflat":
            ivf = faiss.IndexIVFFlat(quantizer, dim, nlist, faiss.METRIC_INNER_PRODUCT)
        else:
            ivfpq = faiss.IndexIVFPQ(quantizer, dim, nlist, pq_m, 8, faiss.METRIC_INNER_PRODUCT)
            ivfpq.pq.cp.seed = seed
            ivf = ivfpq
        ivf.cp.seed = seed
        ivf.cp.niter = 10  # a good-enough partition; training dominates build time
        n = len(x)
        rng = np.random.default_rng(seed)
        train = x if n <= MAX_TRAIN else x[np.sort(rng.choice(n, MAX_TRAIN, replace=False))]
        ivf.train(train)
        if cfg.refine_factor:
            return faiss.IndexRefineFlat(ivf)
        return ivf

    @classmethod
    def build_ondisk(cls, shards: Sequence[np.ndarray], folder: str | os.PathLike,
                     cfg: IndexConfig, meta: dict | None = None, seed: int = 0,
                     workers: int = 2) -> VectorIndex:
        """An IVF index over shards too big for memory together, its lists on disk.

        The coarse quantiser is trained on a sample drawn from every shard (at most
        MAX_TRAIN vectors); each shard is added (in parallel threads) to its own copy of the
        trained index with global ids (shard offsets), and the copies are merged into one
        index whose inverted lists live in `lists.ivfdata`, memory-mapped when loaded. Built
        in a temporary folder that replaces `folder` at the end.

        Args:
            shards: (N_i, D) arrays (memory-mapped ones are read shard by shard).
            folder: output folder (`index.faiss`, `lists.ivfdata`, `manifest.json`).
            cfg: kind "ivfflat" or "ivfpq" (without refine_factor).
            meta: caller metadata for the manifest.
            seed: sampling and k-means seed.
            workers: threads adding shards.
        """
        from faiss.contrib.ondisk import merge_ondisk  # faiss's own on-disk merge helper

        if cfg.kind not in ONDISK_KINDS or cfg.refine_factor:
            raise ConfigError(f"kind={cfg.kind!r} (refine_factor={cfg.refine_factor}) cannot "
                              "be built on disk; use 'ivfflat' or 'ivfpq' without refinement")
        sizes = [len(x) for x in shards]
        n = sum(sizes)
        rng = np.random.default_rng(seed)
        take = [min(m, max(1, round(MAX_TRAIN * m / n))) for m in sizes]
        sample = np.concatenate([np.asarray(x)[np.sort(rng.choice(m, t, replace=False))]
                                 for x, m, t in zip(shards, sizes, take)])
        sample = _normalised(_as_matrix(sample, "index vectors"), "index vectors", warn=True)
        trained = cls._trained_ivfpq(sample, cfg, seed, n)
        folder = Path(folder)
        with staged(folder.parent, prefix=f".{folder.name}-") as tmp:
            offsets = np.concatenate([[0], np.cumsum(sizes)])

            def add(k: int) -> str:
                part = faiss.clone_index(trained)
                x = _normalised(_as_matrix(shards[k], "index vectors"), "index vectors", True)
                part.add_with_ids(x, np.arange(offsets[k], offsets[k + 1], dtype=np.int64))
                path = str(tmp / f"part-{k:05d}.faiss")
                faiss.write_index(part, path)
                return path

            with ThreadPoolExecutor(max(1, workers)) as pool:
                parts = list(pool.map(add, range(len(shards))))
            merged = faiss.clone_index(trained)
            with _stdout_to_stderr():  # faiss prints the list file's resizing to stdout
                merge_ondisk(merged, parts, str(tmp / ONDISK_FILE))
            faiss.write_index(merged, str(tmp / INDEX_FILE))
            for part in parts:
                os.unlink(part)
            ondisk = {"file": ONDISK_FILE, "bytes": (tmp / ONDISK_FILE).stat().st_size}
            _write_manifest(tmp, cfg.kind, dim=int(merged.d), count=n, cfg=cfg,
                            meta=meta, ondisk=ondisk)
            del merged
            replace_folder(tmp, folder)
        logger.info("built an on-disk %s index of %d vectors in %d shards at %s", cfg.kind, n,
                    len(shards), folder)
        return cls.load(folder)[0]

    def search(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The k most similar indexed vectors for each query.

        Args:
            queries: (Q, D) or (D,) vectors (normalised here).
            k: neighbours per query, 1 <= k <= count.

        Returns:
            (scores, ids): (Q, k) float32 cosine similarities, best first, and (Q, k) int64
            row numbers of the indexed vectors.

        Raises:
            ConfigError: k < 1 or k larger than the corpus.
            DataError: queries are malformed or of the wrong dimension.
        """
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ConfigError(f"K={k!r} must be a positive integer")
        if k > self.count:
            raise ConfigError(f"K={k} larger than the corpus of {self.count} entries")
        q = self._prepare_queries(queries)
        if self._kind == "flat":
            threshold = self._cfg.blas_threshold
            if threshold is None:
                threshold = faiss.cvar.distance_compute_blas_threshold
            else:
                faiss.cvar.distance_compute_blas_threshold = threshold
            if len(q) < threshold:
                return self._flat_scan(q, int(k))
        threads = self._cfg.threads
        before = faiss.omp_get_max_threads()
        if before != threads:
            faiss.omp_set_num_threads(threads)
        try:
            scores, ids = self._index.search(q, int(k), params=self._params)
        finally:
            if before != threads:
                faiss.omp_set_num_threads(before)
        return scores, ids.astype(np.int64, copy=False)

    def _prepare_queries(self, queries: np.ndarray) -> np.ndarray:
        """Queries as a (Q, D) C-contiguous float32 array of unit rows. The common case (a
        few finite float32 rows) takes a short path: single-query latency is a target."""
        q = np.asarray(queries)
        if q.ndim == 1:
            q = q[None, :]
        if q.ndim == 2 and q.shape[1] != self.dim:
            raise DataError(f"query dimension {q.shape[1]} does not match the index "
                            f"dimension {self.dim}")
        if q.dtype != np.float32 or not q.flags.c_contiguous or q.ndim != 2 or not len(q):
            q = _as_matrix(q, "queries")
        sq = np.einsum("ij,ij->i", q, q)
        if not np.isfinite(sq).all() or not sq.all():
            # non-finite values, zero rows or float32 overflow: the careful path decides
            return _normalised(_as_matrix(q, "queries"), "queries", warn=False)
        if np.abs(sq - 1.0).max() > 2e-3:
            q = q / np.sqrt(sq)[:, None]
        return q

    def _flat_scan(self, q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Exact search of a few queries: one BLAS matrix product over the stored vectors
        (read in place, no copy) and a partial sort. faiss's per-row scan for small batches
        was measured about 2x slower than the memory-bandwidth bound; this runs near it."""
        if self._xb is None:
            n, d = self.count, self.dim
            flat = cast(faiss.IndexFlat, self._index)  # only a flat index is scanned here
            self._xb = faiss.rev_swig_ptr(flat.get_xb(), n * d).reshape(n, d)
        sims = self._xb @ q.T if len(q) > 1 else (self._xb @ q[0])[:, None]
        scores, ids = top_k(sims.T, k)
        return scores.astype(np.float32), ids

    def save(self, folder: str | os.PathLike, meta: dict | None = None) -> Path:
        """Write ``index.faiss`` and then, atomically, ``manifest.json`` into folder.

        Args:
            folder: created if missing.
            meta: JSON-serialisable caller metadata, e.g. ``{"encoder": "minilm-l6"}``.

        Returns:
            The folder.
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        if self._ondisk:
            raise ConfigError("an on-disk or sharded index is saved where it is built "
                              "(VectorIndex.build_ondisk)")
        faiss.write_index(self._index, str(folder / INDEX_FILE))
        _write_manifest(folder, self.kind, self.dim, self.count, self._cfg, meta)
        logger.info("saved a %s index of %d x %d to %s", self.kind, self.count, self.dim,
                    folder)
        return folder

    @classmethod
    def load(cls, folder: str | os.PathLike, expected_dim: int | None = None,
             expected_encoder: str | None = None) -> tuple[VectorIndex, dict]:
        """Load an index written by :meth:`save`, checking it before use; never rebuilds.

        Args:
            folder: the folder holding ``index.faiss`` and ``manifest.json``.
            expected_dim: refuse an index built for another dimension.
            expected_encoder: refuse an index whose ``meta["encoder"]`` differs.

        Returns:
            (index, meta) with meta as saved.

        Raises:
            DataNotFoundError: the folder does not exist.
            DataError: the manifest is missing or unreadable, the checksum does not match,
                the manifest disagrees with the faiss file, or an expectation fails.
        """
        folder = Path(folder)
        if not folder.is_dir():
            raise DataNotFoundError(f"index folder {str(folder)!r} does not exist")
        manifest_path, index_path = folder / MANIFEST_FILE, folder / INDEX_FILE
        if not manifest_path.is_file():
            raise DataError(f"index {str(folder)!r} has no {MANIFEST_FILE}; it is incomplete "
                            "or not an index folder (delete it and build it again)")
        try:
            manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
            kind, dim, count = manifest["kind"], int(manifest["dim"]), int(manifest["count"])
            cfg = IndexConfig(**manifest["config"])
            checksum, meta = str(manifest["index_sha256"]), dict(manifest.get("meta") or {})
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise DataError(f"index {str(folder)!r} has an unreadable {MANIFEST_FILE}: "
                            f"{exc}") from exc
        if not index_path.is_file():
            raise DataError(f"index {str(folder)!r} has no {INDEX_FILE}")
        if sha256_file(index_path) != checksum:
            raise DataError(f"index {str(folder)!r} is corrupt: checksum mismatch of "
                            f"{INDEX_FILE} (delete it and build it again)")
        if expected_dim is not None and dim != expected_dim:
            raise DataError(f"index {str(folder)!r} was built for dimension {dim}, the "
                            f"encoder gives {expected_dim}")
        if expected_encoder is not None and meta.get("encoder") != expected_encoder:
            raise DataError(f"index {str(folder)!r} was built with encoder "
                            f"{meta.get('encoder')!r}, expected {expected_encoder!r}")
        ondisk = manifest.get("ondisk")
        if ondisk:  # inverted lists memory-mapped from the file beside index.faiss
            lists = folder / ondisk["file"]
            if not lists.is_file() or lists.stat().st_size != ondisk["bytes"]:
                raise DataError(f"index {str(folder)!r}: {ondisk['file']} is missing or has "
                                f"the wrong size (expected {ondisk['bytes']} bytes)")
        try:
            with _stdout_to_stderr():  # faiss prints on-disk renames to stdout
                index = faiss.read_index(str(index_path),
                                         faiss.IO_FLAG_ONDISK_SAME_DIR if ondisk else 0)
        except RuntimeError as exc:
            raise DataError(f"index {str(folder)!r}: faiss cannot read {INDEX_FILE}: "
                            f"{exc}") from exc
        held = type(index).__name__
        if (int(index.d), int(index.ntotal)) != (dim, count) or cfg.kind != kind \
                or held not in _FAISS_TYPES[kind]:
            raise DataError(f"index {str(folder)!r}: manifest says {kind} {count} x {dim}, "
                            f"{INDEX_FILE} holds {held} {index.ntotal} x {index.d}")
        logger.info("loaded a %s index of %d x %d from %s", kind, count, dim, folder)
        out = cls(index, cfg)
        out._ondisk = bool(ondisk)
        return out, meta


def _write_manifest(folder: Path, kind: str, dim: int, count: int, cfg: IndexConfig,
                    meta: dict | None, ondisk: dict | None = None) -> None:
    """manifest.json (shape, config, checksum of index.faiss, caller metadata), atomically."""
    manifest = {"kind": kind, "dim": dim, "count": count, "config": asdict(cfg),
                "index_sha256": sha256_file(folder / INDEX_FILE), "meta": dict(meta or {})}
    if ondisk:
        manifest["ondisk"] = ondisk
    write_json_atomic(folder / MANIFEST_FILE, manifest, indent=2, sort_keys=True, newline=False)


class ShardedVectorIndex(VectorIndex):
    """Several indexes searched as one (e.g. one per machine): each shard's top-k, merged
    by score; shard i's row r is global id offsets[i] + r (default: successive ranges).
    Same search API as `VectorIndex`."""

    def __init__(self, shards: Sequence[VectorIndex], offsets: Sequence[int] | None = None):
        if not shards:
            raise ConfigError("a sharded index needs at least one shard")
        dims = sorted({s.dim for s in shards})
        if len(dims) != 1:
            raise DataError(f"index shards have different dimensions {dims}")
        self._shards = list(shards)
        self._offsets = (list(offsets) if offsets is not None else
                         [int(x) for x in np.cumsum([0] + [s.count for s in shards[:-1]])])
        if len(self._offsets) != len(shards):
            raise ConfigError(f"{len(self._offsets)} offsets for {len(shards)} shards")
        self._cfg = shards[0].config
        self._kind, self._dim = self._cfg.kind, dims[0]
        self._count = sum(s.count for s in shards)
        self._ondisk, self._xb = True, None

    def with_search(self, **changes: int | None) -> VectorIndex:
        return ShardedVectorIndex([s.with_search(**changes) for s in self._shards],
                                  self._offsets)

    def search(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ConfigError(f"K={k!r} must be a positive integer")
        if k > self.count:
            raise ConfigError(f"K={k} larger than the corpus of {self.count} entries")
        q = self._prepare_queries(queries)
        parts = [s.search(q, min(int(k), s.count)) for s in self._shards]
        scores = np.concatenate([p[0] for p in parts], axis=1)
        ids = np.concatenate([np.where(p[1] >= 0, p[1] + off, -1)
                              for p, off in zip(parts, self._offsets)], axis=1)
        best, pos = top_k(scores, k)  # ties: the earlier shard, then the shard's own order
        return best.astype(np.float32), np.take_along_axis(ids, pos, 1).astype(np.int64)


def exact_topk(queries: np.ndarray, keys: np.ndarray, k: int, max_bytes: int = 1 << 28
               ) -> np.ndarray:
    """Exact top-k: (Q, k) row ids of `keys` with the largest inner product with each query,
    best first (ties by lower id). Queries go in chunks so that one chunk's similarity matrix
    stays under `max_bytes`; the reference that approximate indexes are measured against."""
    queries = np.asarray(queries, np.float32)
    keys = np.asarray(keys, np.float32)
    k = min(k, len(keys))
    out = np.empty((len(queries), k), np.int64)
    step = max(1, max_bytes // (4 * max(1, len(keys))))
    for s in range(0, len(queries), step):
        out[s:s + step] = top_k(queries[s:s + step] @ keys.T, k)[1]
    return out


def top_k(sims: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The one top-k of the project: the `k` best entries of each row of a (Q, N) score
    matrix by (higher score, lower column id), as ((Q, k) scores, (Q, k) int64 column ids),
    best first. Equal scores (duplicate captions embed identically) are thus decided by id,
    in the order and at the k-th place alike. A partial sort (`argpartition`) picks the k, so
    the cost grows with N, not N log N; `sims` may be a transposed view (it is not copied)."""
    n = sims.shape[1]
    k = min(int(k), n)
    if k < n:
        part = np.argpartition(sims, n - k, axis=1)[:, n - k:]
        kth = np.take_along_axis(sims, part, 1).min(axis=1)
        for r in np.flatnonzero((sims >= kth[:, None]).sum(axis=1) > k):
            # the k-th score is shared beyond the k: the lower ids among it get the places
            above = np.flatnonzero(sims[r] > kth[r])
            part[r] = np.concatenate([above, np.flatnonzero(sims[r] == kth[r])[:k - len(above)]])
        part.sort(axis=1)  # lower ids first, so that the stable sort breaks ties by id
    else:
        part = np.broadcast_to(np.arange(n), sims.shape)
    scores = np.take_along_axis(sims, part, 1)
    order = np.argsort(-scores, axis=1, kind="stable")
    return (np.take_along_axis(scores, order, 1),
            np.take_along_axis(part, order, 1).astype(np.int64, copy=False))

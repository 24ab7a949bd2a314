"""ImageNet-T on Ray Data: the corpus build of `imagenet_t` + `embed` as a distributed pipeline.

plan -> recaption -> render or load images -> embed images and captions -> write shards ->
assemble -> index. The plan (stratified ids, or a user's CSV/Parquet list) is made on the driver,
exactly as `build_corpus` makes it; the stages run as Ray Data `map_batches` operators: the plan
and the offline recaptioner as light tasks, the LLM recaptioner as a small actor pool with
bounded concurrency, retries and a rate limit (falling back per entry to the offline
recaptioner, as `LLMRecaptioner` does), and rendering + embedding as an actor pool that loads
the encoders once per actor. The driver streams the results into shards of `shard_size` entries
under `<out>/shards/` (Parquet metadata + `.npy` embeddings, a manifest of counts and
checksums); a re-run skips finished shards. When every shard is there they are assembled into
the standard corpus layout (`metadata.jsonl`, `manifest.json`, `embeddings/<encoder>/`), so
`load_corpus`, `load_embeddings`, `CorpusIndex` and `RATouchPipeline.load` read the result
unchanged, and the indexes are built.

Local Ray by default (this machine's cores); a cluster when an address is given or
`RAY_ADDRESS` is set (its nodes need this package and the encoder weights at the same path).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import secrets
import shutil
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import ray
import torch

from ratouch import processes
from ratouch.checkpoint import sha256_file
from ratouch.corpus.embed import (
    EMBED_MANIFEST,
    CaptionEmbeddings,
    embeddings_dir,
    read_corpus_image,
    write_embeddings_manifest,
)
from ratouch.corpus.imagenet_t import (
    MANIFEST,
    CorpusEntry,
    parse_size,
    parse_world_source,
    read_image_list,
    stratified_rows,
    stratified_world_ids,
    world_lexicon,
    write_corpus_metadata,
)
from ratouch.corpus.recaption import LLMRecaptioner, OfflineRecaptioner, RecaptionConfig
from ratouch.encoders.factory import create_model
from ratouch.errors import ConfigError, DataError, ServiceError
from ratouch.files import publish, write_json_atomic
from ratouch.search.index import ONDISK_KINDS, IndexConfig, VectorIndex
from ratouch.search.retrieval import CorpusIndex, index_folder
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import check_writable
from ratouch.world.sampler import World

log = logging.getLogger(__name__)

SHARD_DIR = "shards"
PARTIAL_DIR = ".partial"
META_COLUMNS = ("id", "class_name", "description", "caption", "source", "material")
#: CPUs asked by each light task (plan, offline recaption) and each LLM actor.
LIGHT_CPUS = 0.25
STAGES = ("plan", "recaption", "render", "embed", "write", "assemble", "index")


@dataclass(frozen=True)
class RayOptions:
    """How the Ray build runs.

    Attributes:
        address: Ray cluster address; None uses $RAY_ADDRESS, else starts a local Ray.
        num_cpus: CPUs of the local Ray (default: this machine's cores).
        workers: embedding actors (each loads the encoders once).
        batch_size: entries per `map_batches` batch.
        shard_size: entries per output shard (the unit of resumption).
        llm_concurrency: LLM requests in flight at once, all actors together.
        llm_rate: LLM requests per second, all actors together (0: unlimited).
    """

    address: str | None = None
    num_cpus: int | None = None
    workers: int = 2
    batch_size: int = 250
    shard_size: int = 1000
    llm_concurrency: int = 8
    llm_rate: float = 50.0

    def __post_init__(self) -> None:
        for name in ("workers", "batch_size", "shard_size", "llm_concurrency"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ConfigError(f"{name}={v!r} must be a positive integer")
        if self.num_cpus is not None and (not isinstance(self.num_cpus, int) or self.num_cpus < 1):
            raise ConfigError(f"num_cpus={self.num_cpus!r} must be a positive integer")
        if not isinstance(self.llm_rate, (int, float)) or self.llm_rate < 0:
            raise ConfigError(f"llm_rate={self.llm_rate!r} must be >= 0")


def plan_cpus(total_cpus: float, workers: int, llm_actors: int = 0) -> float:
    """CPUs per embedding actor so that the actors never take the cores the light tasks
    (plan, recaption) and LLM actors need: with every actor alive there is still room for
    two light tasks. On 2 CPUs with 2 workers that is 0.75 each (1 each would starve the
    plan stage and hang the pipeline)."""
    reserved = LIGHT_CPUS * (2 + llm_actors)
    per_actor = min(1.0, (total_cpus - reserved) / workers)
    per_actor = math.floor(per_actor * 100) / 100
    if per_actor < 0.05:
        raise ConfigError(f"workers={workers} is too many for {total_cpus:g} CPUs "
                          f"(each embedding actor would get {per_actor:g})")
    return per_actor


# ---------------------------------------------------------------------------------------------
# stage functions (run in Ray workers)

_WORLDS: dict[int, World] = {}
_OFFLINE: list[OfflineRecaptioner] = []


def _world(seed: int) -> World:
    """One World per seed and worker process (its texture tiles are built once)."""
    if seed not in _WORLDS:
        _WORLDS[seed] = World(WorldConfig(seed=seed))
    return _WORLDS[seed]


def _offline() -> OfflineRecaptioner:
    if not _OFFLINE:
        _OFFLINE.append(OfflineRecaptioner(world_lexicon()))
    return _OFFLINE[0]


def _strings(values) -> np.ndarray:
    return np.asarray(list(values), dtype=object)


def _per_row(seconds: float, n: int) -> np.ndarray:
    return np.full(n, seconds / max(n, 1))


def plan_world_batch(batch: dict, seed: int) -> dict:
    """Plan stage for the world: (id, class index, instance) -> class, description, source."""
    t0 = time.perf_counter()
    world = _world(seed)
    recs = [world.corpus_record(int(c), int(i)) for c, i in zip(batch["c"], batch["inst"])]
    n = len(recs)
    return {"id": batch["id"], "class_name": _strings(r.class_name for r in recs),
            "description": _strings(r.description for r in recs),
            "source": _strings(f"world:{seed}:{int(c)}:{int(i)}"
                               for c, i in zip(batch["c"], batch["inst"])),
            "material": _strings(r.material for r in recs),
            "t_plan": _per_row(time.perf_counter() - t0, n)}


def recaption_offline_batch(batch: dict) -> dict:
    """Recaption stage, offline lexicon recaptioner."""
    t0 = time.perf_counter()
    rc = _offline()
    caps = [", ".join(rc.recaption(str(c), str(d)))
            for c, d in zip(batch["class_name"], batch["description"])]
    n = len(caps)
    return {**batch, "caption": _strings(caps), "llm_requests": np.zeros(n, np.int32),
            "llm_fallback": np.zeros(n, bool), "t_recaption": _per_row(time.perf_counter() - t0, n)}


class RateLimiter:
    """At most `rate` calls per second (evenly spaced) across threads; 0 means unlimited."""

    def __init__(self, rate: float) -> None:
        self.interval = 1.0 / rate if rate > 0 else 0.0
        self._next = 0.0
        self._lock = threading.Lock()

    def wait(self) -> None:
        if not self.interval:
            return
        with self._lock:
            now = time.monotonic()
            slot = max(now, self._next)
            self._next = slot + self.interval
        if slot > now:
            time.sleep(slot - now)


class _FlaggedFallback:
    """The offline recaptioner, noting (per thread) that the LLM recaptioner fell back to it."""

    def __init__(self, offline: OfflineRecaptioner, local: threading.local) -> None:
        self.offline, self.local = offline, local

    def recaption(self, class_name: str, description: str) -> list[str]:
        self.local.fell_back = True
        return self.offline.recaption(class_name, description)


class LimitedLLMRecaptioner(LLMRecaptioner):
    """`LLMRecaptioner` (same retries and fallback) with a rate limit, counting per entry the
    requests made and whether the offline fallback answered."""

    def __init__(self, config: RecaptionConfig, limiter: RateLimiter) -> None:
        self._local = threading.local()
        super().__init__(config, _FlaggedFallback(_offline(), self._local))
        self.limiter = limiter

    def _request(self, prompt: str) -> str:
        self.limiter.wait()
        self._local.requests += 1
        return super()._request(prompt)

    def recaption_counted(self, class_name: str, description: str) -> tuple[str, int, bool]:
        """(caption, requests made, fell back) for one entry."""
        self._local.requests, self._local.fell_back = 0, False
        cap = self.recaption(class_name, description)
        return ", ".join(cap), self._local.requests, self._local.fell_back


class LLMRecaptionStage:
    """Recaption stage against an LLM endpoint: one actor holds `threads` requests in flight
    and its share of the rate limit."""

    def __init__(self, config: RecaptionConfig, threads: int, rate: float) -> None:
        self.rc = LimitedLLMRecaptioner(config, RateLimiter(rate))
        self.threads = threads

    def __call__(self, batch: dict) -> dict:
        from concurrent.futures import ThreadPoolExecutor

        t0 = time.perf_counter()
        pairs = list(zip(batch["class_name"], batch["description"]))
        with ThreadPoolExecutor(max(1, min(self.threads, len(pairs)))) as pool:
            out = list(pool.map(lambda p: self.rc.recaption_counted(str(p[0]), str(p[1])), pairs))
        n = len(out)
        return {**batch, "caption": _strings(c for c, _, _ in out),
                "llm_requests": np.asarray([r for _, r, _ in out], np.int32),
                "llm_fallback": np.asarray([f for _, _, f in out], bool),
                "t_recaption": _per_row(time.perf_counter() - t0, n)}


def entry_image(source: str) -> np.ndarray:
    """A corpus entry's image: re-rendered from a world source, else read from its path."""
    if source.startswith("world:"):
        seed, c, i = parse_world_source(source)
        return _world(seed).corpus_image(c, i)
    return read_corpus_image(source)


class EmbedStage:
    """Render/load + embed stage: the encoders are loaded once per actor."""

    def __init__(self, encoder: str, threads: int) -> None:
        torch.set_num_threads(threads)
        self.model = create_model(encoder)
        self.captions = CaptionEmbeddings(self.model)

    def __call__(self, batch: dict) -> dict:
        t0 = time.perf_counter()
        images = [entry_image(str(s)) for s in batch["source"]]
        t1 = time.perf_counter()
        img = self.model.encode_image(images)
        txt = self.captions(batch["caption"])
        n = len(images)
        return {**batch, "image_emb": img, "text_emb": txt,
                "t_render": _per_row(t1 - t0, n), "t_embed": _per_row(time.perf_counter() - t1, n)}


# ---------------------------------------------------------------------------------------------
# driver: plan, shards, assembly

def plan_table(n: int, seed: int, image_list: str | None) -> pa.Table:
    """The build's plan, made exactly as `build_corpus` makes it: (id, c, inst) for the world,
    (id, class_name, description, source, material) for a list."""
    if image_list is None:
        ids = stratified_world_ids(n, seed)
        return pa.table({"id": np.arange(len(ids), dtype=np.int64),
                         "c": np.asarray([c for c, _ in ids], np.int64),
                         "inst": np.asarray([i for _, i in ids], np.int64)})
    rows = stratified_rows(read_image_list(image_list), n, seed)
    return pa.table({"id": np.arange(len(rows), dtype=np.int64),
                     "class_name": [cls for _, cls, _ in rows],
                     "description": [cap for _, _, cap in rows],
                     "source": [img for img, _, _ in rows], "material": [""] * len(rows)})


class ShardStore:
    """`<out>/shards/`: shard files and their manifest (build parameters, per-shard counts
    and checksums). A shard is finished once the manifest lists it; files are written in
    `<out>/.partial/` and renamed into place first, so no reader ever sees half a file."""

    def __init__(self, out: Path, build: dict, n: int, shard_size: int) -> None:
        self.dir, self.partial = out / SHARD_DIR, out / PARTIAL_DIR
        self.path = self.dir / "manifest.json"
        self.n, self.shard_size = n, shard_size
        self.n_shards = math.ceil(n / shard_size)
        if self.path.is_file():
            self.manifest = json.loads(self.path.read_text())
            if self.manifest["build"] != build:
                raise ConfigError(f"{self.dir} holds shards of another build "
                                  f"({self.manifest['build']}); choose another folder")
        else:
            self.manifest = {"build": build, "count": n, "shard_size": shard_size,
                             "n_shards": self.n_shards, "shards": {}}
        shutil.rmtree(self.partial, ignore_errors=True)  # leftovers of a killed run
        self.dir.mkdir(parents=True, exist_ok=True)
        self.partial.mkdir(parents=True, exist_ok=True)

    def done(self) -> set[int]:
        return {int(k) for k in self.manifest["shards"]}

    def expected(self, shard: int) -> int:
        return min(self.shard_size, self.n - shard * self.shard_size)

    def files(self, shard: int) -> dict[str, Path]:
        stem = f"shard-{shard:05d}"
        return {k: self.dir / f"{stem}.{k}" for k in ("parquet", "image.npy", "text.npy")}

    def write(self, shard: int, cols: dict[str, np.ndarray]) -> None:
        """Write one complete shard (rows sorted by id) and record it in the manifest."""
        order = np.argsort(cols["id"], kind="stable")
        cols = {k: v[order] for k, v in cols.items()}
        expected_ids = np.arange(shard * self.shard_size, shard * self.shard_size
                                 + self.expected(shard))
        if not np.array_equal(cols["id"], expected_ids):
            raise DataError(f"shard {shard} got ids {cols['id'][:5]}..., expected "
                            f"{expected_ids[:5]}...")
        table = pa.table({k: (cols[k] if k == "id" else [str(x) for x in cols[k]])
                          for k in META_COLUMNS})
        final = self.files(shard)
        tmp = {k: self.partial / p.name for k, p in final.items()}
        pq.write_table(table, tmp["parquet"])
        np.save(tmp["image.npy"], np.ascontiguousarray(cols["image_emb"], np.float32))
        np.save(tmp["text.npy"], np.ascontiguousarray(cols["text_emb"], np.float32))
        sums = {k: sha256_file(p) for k, p in tmp.items()}
        publish(self.partial, self.dir, [p.name for p in final.values()])
        self.manifest["shards"][str(shard)] = {"count": len(table), "sha256": sums}
        write_json_atomic(self.path, self.manifest)

    def add_llm_stats(self, requests: int, fallbacks: int) -> None:
        """Add one run's LLM request and fallback counts to the manifest's totals."""
        stats = self.manifest.setdefault("captioner_stats", {"n_requests": 0, "n_fallbacks": 0})
        stats["n_requests"] += requests
        stats["n_fallbacks"] += fallbacks
        write_json_atomic(self.path, self.manifest)

    def read(self, shard: int) -> tuple[list[CorpusEntry], np.ndarray, np.ndarray]:
        """One finished shard, checked against its checksums."""
        rec = self.manifest["shards"][str(shard)]
        files = self.files(shard)
        for k, p in files.items():
            if not p.is_file() or sha256_file(p) != rec["sha256"][k]:
                raise DataError(f"shard file {p} is missing or corrupt (checksum mismatch); "
                                f"delete its entry from {self.path} and re-run to rebuild it")
        t = pq.read_table(files["parquet"]).to_pydict()
        entries = [CorpusEntry(int(i), *(t[k][j] for k in META_COLUMNS[1:]))
                   for j, i in enumerate(t["id"])]
        return entries, np.load(files["image.npy"]), np.load(files["text.npy"])


@contextmanager
def connect(opts: RayOptions) -> Iterator[None]:
    """Join the cluster at opts.address / $RAY_ADDRESS, else start a local Ray, for the
    block; a connection this opened is shut down at its end. Workers find this package
    through PYTHONPATH (the same path on every node).

    A local Ray's processes (GCS, raylet, its agents, workers) are tagged
    (`ratouch.processes.TAG_VAR`) and a reaper ends them when this process ends, however it
    ends: a killed build leaves no ``ray::DashboardAgent`` behind. Those a build killed
    together with its reaper left are ended before a local Ray starts."""
    if ray.is_initialized():
        yield
        return
    code = str(Path(__file__).resolve().parents[2])
    path = os.pathsep.join(p for p in (code, os.environ.get("PYTHONPATH", "")) if p)
    runtime_env = {"env_vars": {"PYTHONPATH": path}}
    address = opts.address or os.environ.get("RAY_ADDRESS") or None
    with contextlib.ExitStack() as stack:
        try:
            if address:
                ray.init(address=address, runtime_env=runtime_env, log_to_driver=False,
                         logging_level=logging.WARNING)
            else:
                stack.enter_context(_tagged_local_processes(code))
                ray.init(address="local", num_cpus=opts.num_cpus or os.cpu_count(),
                         include_dashboard=False, runtime_env=runtime_env,
                         log_to_driver=False, logging_level=logging.WARNING)
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise ServiceError(f"cannot connect to Ray at address={address!r}: {e}") from e
        try:
            yield
        finally:
            ray.shutdown()


@contextmanager
def _tagged_local_processes(code: str) -> Iterator[None]:
    """Tag the processes started in the block (through the environment they inherit) and
    have a reaper end them when the block ends or this process dies."""
    orphans = processes.end_orphans()
    if orphans:
        log.warning("ended %d processes a killed Ray build left behind", len(orphans))
    tag = f"{os.getpid()}-{secrets.token_hex(6)}"
    reaper = processes.start_reaper(tag, code)
    before = os.environ.get(processes.TAG_VAR)
    os.environ[processes.TAG_VAR] = tag
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(processes.TAG_VAR, None)
        else:
            os.environ[processes.TAG_VAR] = before
        assert reaper.stdin is not None
        reaper.stdin.close()  # the reaper ends what is left of this Ray, then itself
        reaper.wait()


def _dataset(table: pa.Table, todo: list[int], seed: int, recaption: RecaptionConfig,
             encoder: str, opts: RayOptions, is_world: bool) -> ray.data.Dataset:
    """The Ray Data pipeline over the entries of unfinished shards."""
    ids = table.column("id").to_numpy()
    keep = np.isin(ids // opts.shard_size, todo)
    rows = table.filter(pa.array(keep))
    blocks = [rows.slice(k, opts.batch_size) for k in range(0, len(rows), opts.batch_size)]
    total = float(ray.cluster_resources().get("CPU", 1))
    llm = recaption.backend == "llm"
    llm_actors = max(1, min(opts.workers, opts.llm_concurrency)) if llm else 0
    actor_cpus = plan_cpus(total, opts.workers, llm_actors)
    log.info("Ray: %g CPUs, %d embedding actors at %g CPU each, light tasks at %g CPU%s",
             total, opts.workers, actor_cpus, LIGHT_CPUS,
             f", {llm_actors} LLM actors" if llm else "")
    ds: ray.data.Dataset = ray.data.from_arrow(blocks)
    light: dict[str, Any] = dict(batch_size=opts.batch_size, batch_format="numpy",
                                 num_cpus=LIGHT_CPUS)
    if is_world:
        # ray's annotation of `fn` has no room for the arguments that fn_kwargs supplies
        ds = ds.map_batches(plan_world_batch, fn_kwargs={"seed": seed},  # type: ignore[arg-type]
                            **light)
    if llm:
        ds = ds.map_batches(LLMRecaptionStage, fn_constructor_kwargs={
            "config": recaption, "threads": math.ceil(opts.llm_concurrency / llm_actors),
            "rate": opts.llm_rate / llm_actors}, concurrency=llm_actors, **light)
    else:
        ds = ds.map_batches(recaption_offline_batch, **light)
    return ds.map_batches(EmbedStage, fn_constructor_kwargs={
        "encoder": encoder, "threads": max(1, round(actor_cpus))},
        batch_size=opts.batch_size, batch_format="numpy", num_cpus=actor_cpus,
        concurrency=opts.workers)


class StageClock:
    """Per-stage busy seconds and entries, logged as entries/s while the build runs."""

    def __init__(self) -> None:
        self.busy = {s: 0.0 for s in STAGES}
        self.entries = {s: 0 for s in STAGES}
        self.llm_requests = self.llm_fallbacks = 0
        self.t0 = time.perf_counter()

    def add_batch(self, batch: dict) -> None:
        n = len(batch["id"])
        for s in ("plan", "recaption", "render", "embed"):
            if f"t_{s}" in batch:
                self.busy[s] += float(np.sum(batch[f"t_{s}"]))
                self.entries[s] += n
        self.llm_requests += int(np.sum(batch["llm_requests"]))
        self.llm_fallbacks += int(np.sum(batch["llm_fallback"]))

    def add(self, stage: str, seconds: float, n: int) -> None:
        self.busy[stage] += seconds
        self.entries[stage] += n

    def rates(self) -> dict[str, dict]:
        """{stage: {entries, busy_s, entries_per_s}}: entries per busy second of one worker."""
        return {s: {"entries": self.entries[s], "busy_s": round(self.busy[s], 3),
                    "entries_per_s": round(self.entries[s] / self.busy[s], 1)}
                for s in STAGES if self.entries[s] and self.busy[s] > 0}

    def log_progress(self, done: int, total: int) -> None:
        wall = time.perf_counter() - self.t0
        per = ", ".join(f"{s} {r['entries_per_s']:.0f}/s" for s, r in self.rates().items())
        log.info("%d / %d entries in shards, %.1f entries/s end to end (%s)", done, total,
                 done / max(wall, 1e-9), per)


def _stream_shards(ds, store: ShardStore, todo: list[int], clock: StageClock) -> None:
    """Consume the pipeline, writing each shard as soon as all its entries have arrived."""
    buffers: dict[int, list[dict]] = {}
    counts: dict[int, int] = {}
    written = sum(store.expected(s) for s in store.done())
    for batch in ds.iter_batches(batch_size=None, batch_format="numpy"):
        clock.add_batch(batch)
        shard_of = batch["id"] // store.shard_size
        for s in np.unique(shard_of):
            sel = shard_of == s
            buffers.setdefault(int(s), []).append({k: v[sel] for k, v in batch.items()})
            counts[int(s)] = counts.get(int(s), 0) + int(sel.sum())
            if counts[int(s)] == store.expected(int(s)):
                parts = buffers.pop(int(s))
                t0 = time.perf_counter()
                store.write(int(s), {k: np.concatenate([p[k] for p in parts]) for k in parts[0]})
                clock.add("write", time.perf_counter() - t0, counts[int(s)])
                written += counts[int(s)]
                clock.log_progress(written, store.n)
    missing = sorted(set(todo) - store.done())
    if missing:
        raise DataError(f"the Ray pipeline ended with shards {missing[:5]} incomplete")


def assemble(out: Path, store: ShardStore, manifest: dict, encoder: str, dim: int,
             weights: str | None) -> dict:
    """Concatenate finished shards into the standard corpus and embeddings layout (each part
    written atomically, the manifests last; parts already there are kept). `weights` is the
    encoder's `weights_fingerprint`, recorded in the embeddings manifest. Returns the corpus
    manifest."""
    if not (out / MANIFEST).is_file():
        entries = []
        for s in range(store.n_shards):
            entries.extend(store.read(s)[0])
        manifest = {**manifest, "n_classes": len({e.class_name for e in entries})}
        write_corpus_metadata(out, entries, manifest)
    corpus_manifest = json.loads((out / MANIFEST).read_text())
    emb = embeddings_dir(out, encoder)
    if (emb / EMBED_MANIFEST).is_file():
        return corpus_manifest
    emb.mkdir(parents=True, exist_ok=True)
    tmp = {k: store.partial / f"{k}.npy" for k in ("image", "text")}
    mm = {k: np.lib.format.open_memmap(p, mode="w+", dtype=np.float32, shape=(store.n, dim))
          for k, p in tmp.items()}
    for s in range(store.n_shards):
        _, img, txt = store.read(s)
        lo = s * store.shard_size
        mm["image"][lo:lo + len(img)] = img
        mm["text"][lo:lo + len(txt)] = txt
    for m in mm.values():
        m.flush()
    del mm
    publish(store.partial, emb, [p.name for p in tmp.values()])
    write_embeddings_manifest(emb, encoder, weights, dim, store.n,
                              corpus_manifest["metadata_sha256"])
    return corpus_manifest


def build_ondisk_indexes(out: Path, store: ShardStore, encoder: str, kind: str,
                         corpus_sha256: str, workers: int) -> None:
    """IVF indexes of the image and text embeddings built from the shards (memory-mapped,
    one at a time) into one on-disk index each, where `CorpusIndex` finds them."""
    emb_manifest = json.loads((embeddings_dir(out, encoder) / EMBED_MANIFEST).read_text())
    for key in ("image", "text"):
        folder = index_folder(out, encoder, key, kind)
        if (folder / "manifest.json").is_file():
            continue
        folder.parent.mkdir(parents=True, exist_ok=True)
        shards = [np.load(store.files(s)[f"{key}.npy"], mmap_mode="r")
                  for s in range(store.n_shards)]
        VectorIndex.build_ondisk(shards, folder, IndexConfig(kind=kind),
                                 meta={"encoder": encoder, "key": key,
                                       "corpus_sha256": corpus_sha256,
                                       "embeddings_sha256": emb_manifest[f"{key}_sha256"]},
                                 workers=workers)


def build_corpus_ray(out: str | os.PathLike, size: int | str = "10k", seed: int = 0,
                     recaption: RecaptionConfig | None = None, image_list: str | None = None,
                     encoder: str = "default-s", index: str = "flat",
                     options: RayOptions | None = None) -> dict:
    """Build, embed and index an ImageNet-T corpus on Ray Data; resumes an interrupted build.

    Gives the same entries (ids, captions, sources) and, within float tolerance, the same
    embeddings as `build_corpus` + `embed_and_index`.

    Args:
        out: corpus folder.
        size: number of entries (10k, 1m or any count).
        seed: sampling seed (and the world's seed).
        recaption: recaptioner config (offline by default).
        image_list: CSV or Parquet of (path, class, caption) for a real corpus; None: the world.
        encoder: encoder to embed with.
        index: index kind built at the end: "flat" or "hnsw" in memory, "ivfflat" or
            "ivfpq" from the shards as one on-disk index.
        options: Ray options (address, workers, batch and shard sizes, LLM limits).

    Returns:
        The corpus manifest, plus the embedding/index summary and per-stage throughput.
    """
    n, opts = parse_size(size), options or RayOptions()
    recaption = recaption or RecaptionConfig()
    if recaption.backend not in ("offline", "llm"):
        # the pipeline runs the offline recaptioner as light tasks and the LLM one as actors;
        # a local model is not wired in, and must not silently become the offline one
        raise ConfigError(f"--captioner {recaption.backend} runs with --engine local only")
    IndexConfig(kind=index)  # fail on a bad kind before any work
    out = Path(out)
    check_writable(out)
    if (out / MANIFEST).is_file() and not (out / SHARD_DIR).is_dir():
        raise ConfigError(f"{out} already holds a finished corpus; run `ratouch corpus build` "
                          f"with --overwrite to replace it, or choose another --out")
    t0 = time.perf_counter()
    table = plan_table(n, seed, image_list)
    model = create_model(encoder)
    dim, weights = model.dim, model.weights_fingerprint
    del model
    # the weights too: shards embedded before the encoder was retrained must not be mixed in
    build = {"size": len(table), "seed": seed, "encoder": encoder, "encoder_weights": weights,
             "source": "world" if image_list is None else str(image_list),
             "captioner": recaption.backend, "endpoint": recaption.endpoint,
             "model": recaption.model if recaption.backend == "llm" else None}
    store = ShardStore(out, build, len(table), opts.shard_size)
    todo = sorted(set(range(store.n_shards)) - store.done())
    if store.done():
        log.info("resuming: %d of %d shards already finished", len(store.done()), store.n_shards)
    clock = StageClock()
    if todo:
        try:
            with connect(opts):
                ds = _dataset(table, todo, seed, recaption, encoder, opts, image_list is None)
                _stream_shards(ds, store, todo, clock)
        except ray.exceptions.RayError as e:  # finished shards stay; a re-run resumes
            raise ServiceError(f"the Ray pipeline failed ({len(store.done())} of "
                               f"{store.n_shards} shards finished, kept for a re-run): "
                               f"{str(e).splitlines()[0] if str(e) else type(e).__name__}"
                               ) from e
    if recaption.backend == "llm":
        store.add_llm_stats(clock.llm_requests, clock.llm_fallbacks)
    ta = time.perf_counter()
    entries_meta = {"kind": "imagenet-t", "size": store.n, "seed": seed,
                    "source": build["source"], "captioner": recaption.backend,
                    "captioner_stats": store.manifest.get("captioner_stats", {}),
                    "engine": "ray", "build_seconds": round(time.perf_counter() - t0, 2)}
    manifest = assemble(out, store, entries_meta, encoder, dim, weights)
    clock.add("assemble", time.perf_counter() - ta, store.n)
    ti = time.perf_counter()
    if index in ONDISK_KINDS:
        build_ondisk_indexes(out, store, encoder, index, manifest["metadata_sha256"],
                             opts.workers)
    CorpusIndex(out, encoder, dim, IndexConfig(kind=index), weights=weights)
    clock.add("index", time.perf_counter() - ti, store.n)
    shutil.rmtree(store.partial, ignore_errors=True)
    wall = time.perf_counter() - t0
    log.info("Ray build of %s: %d entries in %.1f s (%.1f entries/s end to end)", out, store.n,
             wall, store.n / wall)
    return {**manifest, "encoder": encoder, "dim": dim, "index": index, "embedded": store.n,
            "shards": store.n_shards, "shards_built": len(todo), "stages": clock.rates(),
            "wall_s": round(wall, 2)}

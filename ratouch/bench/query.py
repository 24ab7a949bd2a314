"""Benchmark commands: figures measured in one run, printed (tests check behaviour, not time)."""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time

import numpy as np
import torch

from ratouch.corpus.imagenet_t import (
    build_corpus,
    load_corpus,
    parse_world_source,
    render_world_images,
)
from ratouch.model.decoder import generate_together
from ratouch.model.fastpath import GreedyStack, StackCache
from ratouch.search.modes import RA_TOUCH_MODE, RETRIEVAL_SYSTEMS
from ratouch.search.retrieval_side import default_corpus
from ratouch.serve.cascade import CASCADE, Cascade
from ratouch.serve.models import Model, load_model
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.serve.request import QueryRequest, answer_one, split_model_name
from ratouch.threads import intra_op_threads
from ratouch.timing import peak_rss_mb
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import write_split
from ratouch.world.sampler import World


def bench_world(corpus_size: int = 10_000, workers: int = 2, seed: int = 0,
                progress: bool = False) -> dict:
    """Time generating the ImageNet-T corpus (plan + recaption, then rendering every image)
    and writing the 402-sample test split in the TVL layout, in one run.

    Returns:
        Seconds and throughput per stage, the total, and a digest of the rendered corpus
        images (the same seed must always give the same digest).
    """
    cfg = WorldConfig(seed=seed)
    tmp = tempfile.mkdtemp(prefix="ratouch-bench-")
    try:
        t0 = time.perf_counter()
        build_corpus(os.path.join(tmp, "corpus"), corpus_size, seed=seed, world_cfg=cfg,
                     progress=progress)
        t1 = time.perf_counter()
        _, entries = load_corpus(os.path.join(tmp, "corpus"))
        ids = [parse_world_source(e.source)[1:] for e in entries]
        digest = hashlib.sha256()
        n_img = 0
        for batch in render_world_images(ids, cfg, workers=workers, progress=progress):
            digest.update(batch.tobytes())
            n_img += len(batch)
        t2 = time.perf_counter()
        write_split(cfg, os.path.join(tmp, "tvl"), "test", workers=workers, progress=progress)
        t3 = time.perf_counter()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    total = t3 - t0
    return {
        "corpus_size": corpus_size, "workers": workers, "cpu_count": os.cpu_count(),
        "corpus_metadata_s": round(t1 - t0, 2),
        "corpus_render_s": round(t2 - t1, 2),
        "corpus_images_per_s": round(n_img / (t2 - t1), 1),
        "test_split_s": round(t3 - t2, 2),
        "test_pairs_per_s": round(402 / (t3 - t2), 1),
        "total_s": round(total, 2),
        "target_s": 60.0,
        "meets_target": total < 60.0,
        "corpus_images_sha256": digest.hexdigest()[:16],
    }


def bench_query(encoder: str = "default-s", corpus: str | None = None, n: int = 60,
                k: int = 5, seed: int = 0) -> dict:
    """Cold start and warm latency of the whole RA-Touch query (both encoders, three
    retrievals, retriever, integrator, both generations, PCA) on world test pairs; of the
    cascade, the generation figures are its first stage's. The same queries are timed again
    with each pair's sensor background given ("with_background": the contact check against
    it, the structured change and the height map are then computed too)."""
    if encoder != CASCADE:  # the cascade's stages each use their default corpus
        # built before timing (the corpus is the encoder set's, whichever generators answer)
        corpus = corpus or str(default_corpus(split_model_name(encoder)[0], progress=False))
    t0 = time.perf_counter()
    model = load_model(encoder, corpus=corpus)
    cold = time.perf_counter() - t0
    world = World(WorldConfig(seed=seed))
    samples = [world.sample("test", 46 + (7 * i) % 356) for i in range(n)]
    _ask(model, samples[0], k)  # warm-up
    totals: list[float] = []
    stages: dict[str, list[float]] = {}
    escalated: list[bool] = []
    for s in samples:
        r = _ask(model, s, k)
        totals.append(r.timings_ms["total"])
        if r.cascade is not None:
            escalated.append(r.cascade["escalated"])
        for name, ms in r.timings_ms.items():
            stages.setdefault(name, []).append(ms)
    with_bg = [_ask(model, s, k, world.background_image(s.sensor)).timings_ms["total"]
               for s in samples]
    systems: dict[str, list[float]] = {name: [] for name in RETRIEVAL_SYSTEMS}
    for s in samples:  # interleaved, so both systems meet the same machine load
        for name in systems:
            systems[name].append(_ask(model, s, k, retrieval=name).timings_ms["total"])
    return {"encoder": encoder, "corpus_size": len(model.corpus), "n_queries": n, "k": k,
            "cold_start_s": round(cold, 2),
            "p50_ms": round(float(np.percentile(totals, 50)), 1),
            "p95_ms": round(float(np.percentile(totals, 95)), 1),
            "with_background": {"p50_ms": round(float(np.percentile(with_bg, 50)), 1),
                                "p95_ms": round(float(np.percentile(with_bg, 95)), 1)},
            "by_retrieval": {name: {"p50_ms": round(float(np.percentile(t, 50)), 1),
                                    "p95_ms": round(float(np.percentile(t, 95)), 1)}
                             for name, t in systems.items()},
            "stages_p50_ms": {k_: round(float(np.median(v)), 2) for k_, v in stages.items()},
            **({"escalated": round(float(np.mean(escalated)), 4)} if escalated else {}),
            "generation": bench_generation(
                model.stages[0] if isinstance(model, Cascade) else model, samples[:20], k),
            "regenerate_after_drop_ms": bench_regenerate(model, samples[:20], k),
            "loadavg": [round(x, 2) for x in os.getloadavg()],
            "peak_rss_mb": peak_rss_mb(),
            "target": {"p50_ms": 40, "p95_ms": 80, "generation_each_ms": 10,
                       "cold_start_s": 10}}


def _ask(model: Model, s, k: int, background: np.ndarray | None = None,
         retrieval: str | None = None):
    """A world sample's query (with its sensor's background when given; with the retrieval
    system `retrieval`, default the model's), answered by `model` (a `QueryResult`)."""
    return answer_one(model, QueryRequest.decode(s.visual, s.tactile, box=s.box, k=k,
                                                 background=background, retrieval=retrieval))


def _bench_transformers_generation(ra, base, rows: list) -> dict:
    """Each generation alone through transformers (decoders without the fast path: a
    pretrained language model), its median time and time per written token."""
    out: dict[str, float] = {}
    for name, dec, col in (("ra_touch", ra, 0), ("baseline", base, 1)):
        dec.generate(rows[0][col])  # warm-up
        times, tokens = [], []
        for row in rows:
            t0 = time.perf_counter()
            text = dec.generate(row[col])[0]
            times.append((time.perf_counter() - t0) * 1000)
            # the tokens written: the text's and its end token, at most the limit
            tokens.append(min(len(dec.tokenizer.encode(text)) + 1, dec.cfg.max_new_tokens))
        out[f"{name}_alone_ms"] = round(float(np.median(times)), 2)
        out[f"{name}_ms_per_token"] = round(float(np.sum(times) / np.sum(tokens)), 2)
        out[f"{name}_tokens_mean"] = round(float(np.mean(tokens)), 2)
    return out


def bench_regenerate(model: Model, samples: list, k: int = 5) -> dict:
    """`regenerate` with the first joint neighbour dropped (the neighbour-shuffle control)."""
    times = []
    for s in samples:
        request = QueryRequest.decode(s.visual, s.tactile, box=s.box, k=k)
        ids = [n["id"] for n in answer_one(model, request).neighbours[RA_TOUCH_MODE]]
        times.append(model.regenerate(request, ids[1:])["timings_ms"]["total"])
    return {"p50": round(float(np.median(times)), 1),
            "p95": round(float(np.percentile(times, 95)), 1), "target": 50}


def bench_generation(pipe: RATouchPipeline, samples: list, k: int = 5) -> dict:
    """The two generations of single queries, together and each alone (fast path) and through
    transformers (the reference), against a floor for this model on this CPU: every decoding
    pass (the prefill and each new token) must read the decoders' weights once, at the speed
    this process reads a buffer of that size.
    """
    ra, base = pipe.generator_ra.decoder, pipe.generator_base.decoder
    rows = []
    for s in samples:
        V = pipe.encoders.encode_image([s.crop])
        T = pipe.encoders.encode_tactile([s.tactile])
        p_ra, _ = pipe.ra_prefix(V, T, pipe.joint_neighbours(V, T, k))
        with torch.inference_mode():
            rows.append((p_ra, pipe.generator_base.prefix(torch.from_numpy(V),
                                                          torch.from_numpy(T))))
    if not (ra.fast and base.fast):  # a pretrained LM: transformers with its key/value cache
        return _bench_transformers_generation(ra, base, rows)
    cache = StackCache()  # as the pipeline keeps it: the stack is built once
    runs = {"together_ms": lambda a, b: generate_together([ra, base], [a, b], cache=cache),
            "ra_touch_alone_ms": lambda a, b: ra.generate(a),
            "baseline_alone_ms": lambda a, b: base.generate(b),
            "ra_touch_transformers_ms": lambda a, b: ra.generate(a, fast=False),
            "baseline_transformers_ms": lambda a, b: base.generate(b, fast=False)}
    out = {}
    for name, fn in runs.items():
        fn(*rows[0])
        times = []
        for a, b in rows:
            t0 = time.perf_counter()
            fn(a, b)
            times.append((time.perf_counter() - t0) * 1000)
        out[name] = round(float(np.median(times)), 2)
    stack = GreedyStack([ra.model, base.model])
    with torch.inference_mode():
        ctx = torch.stack([ra._context(rows[0][0]), base._context(rows[0][1])])
        passes = 1 + stack.greedy(ctx, ra.cfg.max_new_tokens, ra.tokenizer.eos_id).shape[2]
    nbytes = stack.step_bytes()
    buf = torch.ones(nbytes // 4)
    with torch.inference_mode(), intra_op_threads(1):  # as the decoding runs
        buf.sum()
        t0 = time.perf_counter()
        for _ in range(20):
            buf.sum()
        read_gb_s = nbytes * 20 / (time.perf_counter() - t0) / 1e9
    out.update({
        "passes_per_query": passes,
        "weight_mb_per_pass": round(nbytes / 1e6, 2),
        "mflop_per_token_per_model": round(stack.step_flops(1) / stack.G / 1e6, 2),
        "read_gb_s": round(read_gb_s, 1),
        "floor_together_ms": round(passes * nbytes / (read_gb_s * 1e9) * 1000, 2)})
    return out

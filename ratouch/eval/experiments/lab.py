"""The lab: what every experiment shares (the pipeline, the training pairs, the test split, the
stage-1 generator), training and judging variants, and the disk cache of their results, keyed
by everything they depend on (settings, weights, corpus and the source of the training code).
"""

from __future__ import annotations

import hashlib
import importlib
import json
import logging
import multiprocessing as mp
import os
import time
from dataclasses import asdict
from functools import cached_property
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ratouch.checkpoint import sha256_file
from ratouch.errors import ConfigError
from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split, judge_answers
from ratouch.eval.experiments.variants import INTEGRATIONS, ExperimentConfig, Variant
from ratouch.eval.judge import OfflineJudge
from ratouch.files import write_json_atomic
from ratouch.model.generator import load_generator, save_generator
from ratouch.model.integrator import (
    IntegratorConfig,
    SumIntegrator,
    TextureAwareIntegrator,
)
from ratouch.paths import cache_dir, generator_weights, retriever_weights
from ratouch.processes import bind_to_parent
from ratouch.search.index import exact_topk
from ratouch.search.retrieval import mode_query
from ratouch.seeds import seeded_build
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.generator import GeneratorTrainConfig, train_stage1, train_stage2
from ratouch.train.recipes import language_prior, training_pairs
from ratouch.world.splits import encode_test_split

log = logging.getLogger(__name__)

#: The code that trains a variant (a package stands for all its modules): its source is part of
#: the cache keys, so that a change to it trains again instead of reusing stale results.
TRAINING_CODE = ("ratouch.train", "ratouch.model", "ratouch.world.scarcity", "ratouch.seeds",
                 "ratouch.eval.experiments.lab")


def source_sha256(modules: Sequence[str] = TRAINING_CODE) -> str:
    """sha256 over the source files of modules, found through their `__file__` (a package:
    every `.py` file beside its `__init__.py`), each with its module-relative name."""
    h = hashlib.sha256()
    for name in modules:
        source = importlib.import_module(name).__file__
        assert source is not None, f"{name} has no source file"  # the project's own modules
        path = Path(source)
        files = sorted(path.parent.glob("*.py")) if path.name == "__init__.py" else [path]
        for f in files:
            h.update(f"{name}:{f.name}\n".encode())
            h.update(f.read_bytes())
    return h.hexdigest()


class Lab:
    """Everything the experiments share: the pipeline, the training pairs, the test split, the
    stage-1 generator, the corpus key embeddings and a cache of evaluated variants."""

    def __init__(self, cfg: ExperimentConfig | None = None):
        self.cfg = cfg or ExperimentConfig()
        self._results: dict[Variant, dict] = {}
        self.counts = {"trained": 0, "from_cache": 0}  # variants, for the report's provenance

    @cached_property
    def pipeline(self):

        return RATouchPipeline.load(self.cfg.encoder)

    @cached_property
    def train(self) -> dict:

        return training_pairs(self.pipeline.encoders, self.cfg.seed)

    @cached_property
    def test(self):

        return encode_test_split(self.pipeline.encoders)

    @cached_property
    def stage1(self):

        return load_generator(generator_weights(self.cfg.encoder, "ra"), stage1=True)

    @cached_property
    def judge(self):

        return OfflineJudge()

    @cached_property
    def code_sha256(self) -> str:
        """The training code's `source_sha256`, read once per lab."""
        return source_sha256()

    def subset_ids(self, size: int) -> np.ndarray:
        """A class-stratified subset of the corpus: each class's first entries, round robin."""
        entries = self.pipeline.corpus.entries
        if size <= 0 or size >= len(entries):
            return np.arange(len(entries))
        rank: dict[str, int] = {}
        order = []
        for i, e in enumerate(entries):
            r = rank.get(e.class_name, 0)
            rank[e.class_name] = r + 1
            order.append((r, i))
        order.sort()
        return np.sort(np.array([i for _, i in order[:size]]))

    def withheld_materials(self, n: int) -> list[str]:
        """`n` materials drawn (seeded) from those of the training pairs."""
        mats = sorted(set(self.train["materials"]))
        if not 0 <= n < len(mats):
            raise ConfigError(f"can withhold 0..{len(mats) - 1} of {len(mats)} materials, not {n}")
        rng = np.random.default_rng(self.cfg.seed)
        return sorted(str(m) for m in rng.choice(mats, size=n, replace=False))

    def train_for(self, n: int) -> dict:
        """The paired training data without the `n` withheld materials."""
        if n == 0:
            return self.train
        held = set(self.withheld_materials(n))
        keep = np.array([m not in held for m in self.train["materials"]])
        return {"V": self.train["V"][keep], "T": self.train["T"][keep],
                "labels": [x for x, k in zip(self.train["labels"], keep) if k],
                "materials": [x for x, k in zip(self.train["materials"], keep) if k]}

    def stage1_for(self, n: int):
        """The stage-1 generator trained without the `n` withheld materials (trained once with
        the shipped stage-1 recipe, from the shipped language prior, then cached on disk)."""
        if n == 0:
            return self.stage1

        tc = GeneratorTrainConfig(seed=self.cfg.seed, threads=2,
                                  stage1_steps=self.cfg.stage1_steps)
        key = hashlib.sha256(json.dumps([self.cfg.encoder, n, asdict(tc),
                                         self.withheld_materials(n), self.code_sha256,
                                         self.pipeline.encoders.weights_fingerprint]
                                        ).encode()).hexdigest()[:16]
        folder = cache_dir() / "experiments" / f"stage1-withheld{n}-{key}"
        if not (folder / "manifest.json").is_file():
            data = self.train_for(n)
            log.info("training a stage-1 generator without %d materials (%d pairs, %d steps)",
                     n, len(data["labels"]), tc.stage1_steps)
            prior, _ = language_prior(self.cfg.encoder, progress=False)  # as the shipped pair
            gen, _ = train_stage1(torch.from_numpy(np.asarray(data["V"], np.float32)),
                                  torch.from_numpy(np.asarray(data["T"], np.float32)),
                                  data["labels"], data["V"].shape[1], tc, prior)
            save_generator(folder, gen, {"withheld": self.withheld_materials(n)})
        return load_generator(folder, stage1=True)

    def neighbours(self, v: Variant, V: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, ...]:
        """(ids, Rv, Rl) of a variant's retrieval for queries (V, T), by exact search."""
        q = mode_query(v.mode, V, T, self.pipeline.joint_query)
        keys = self.pipeline.corpus_embeddings("image" if v.key == "image" else v.caption)
        ids_all = self.subset_ids(v.corpus_size)
        ids = ids_all[exact_topk(q, keys[ids_all], v.k)]
        return ids, self.pipeline.corpus_embeddings("image")[ids], self.pipeline.corpus_embeddings(v.caption)[ids]

    def evaluate(self, variants: Sequence[Variant]) -> dict[Variant, dict]:
        """Train (or load from the disk cache) and judge variants; returns their results."""
        todo = [v for v in dict.fromkeys(variants) if v not in self._results]
        missing = []
        for v in todo:
            cached = self._load(v)
            if cached is not None:  # re-judged: the cache keeps answers, the judge may change
                self._results[v] = self._judge(v, cached["responses"], cached["train_seconds"])
                self.counts["from_cache"] += 1
            else:
                missing.append(v)
        if missing:
            log.info("training %d variant(s): %s", len(missing), [v.label() for v in missing])
            for v, responses, secs in self._train_many(missing):
                self._results[v] = self._judge(v, responses, secs)
                self._save(v, self._results[v])
                self.counts["trained"] += 1
        return {v: self._results[v] for v in variants}

    # -- training ------------------------------------------------------------------------

    def _train_many(self, variants: list[Variant]):
        jobs = [(self.stage1_for(v.withheld), self.train_for(v.withheld), self.test, self.cfg,
                 v, self._inputs(v)) for v in variants]
        if self.cfg.workers > 1 and len(jobs) > 1:
            with mp.get_context("fork").Pool(min(self.cfg.workers, len(jobs)),
                                             initializer=bind_to_parent,
                                             initargs=(os.getpid(),)) as pool:
                return pool.map(_run_variant, jobs)
        return [_run_variant(job) for job in jobs]

    def _inputs(self, v: Variant):
        if not v.retrieval:
            return None
        train = self.train_for(v.withheld)
        _, rv, rl = self.neighbours(v, train["V"], train["T"])
        _, trv, trl = self.neighbours(v, self.test.V, self.test.T)
        return rv, rl, trv, trl

    def _judge(self, v: Variant, responses: list[str], seconds: float) -> dict:

        scores, _, summary = judge_answers(self.judge, self.test, responses, v.label())
        return {"variant": asdict(v), "responses": responses,
                "scores": scores.tolist(),
                "means": {k: round(s["mean"], 4) for k, s in summary["subsets"].items()},
                "stats": {k: {f: round(s[f], 4) for f in ("ci_low", "ci_high", "f1", "mean_length")}
                          for k, s in summary["subsets"].items()},
                "train_seconds": round(seconds, 1)}

    # -- disk cache ----------------------------------------------------------------------

    def _key(self, v: Variant) -> str:

        # fields added after results were cached keep the old keys while at their defaults
        vd = {k: x for k, x in asdict(v).items() if not (k in _LATER_FIELDS and x == 0)}
        if v.withheld:
            vd["stage1_steps"] = self.cfg.stage1_steps
        parts = {"v": vd, "cfg": [self.cfg.encoder, self.cfg.steps, self.cfg.batch,
                                         self.cfg.seed],
                 "assets": [sha256_file(generator_weights(self.cfg.encoder, "ra")
                                        / "manifest.json"),
                            sha256_file(retriever_weights(self.cfg.encoder) / "manifest.json")],
                 "encoder_weights": self.pipeline.encoders.weights_fingerprint,
                 "code": self.code_sha256,
                 "corpus": self.pipeline.corpus.manifest.get("metadata_sha256"), "version": 1}
        return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:20]

    def _path(self, v: Variant) -> Path:

        return cache_dir() / "experiments" / f"{self._key(v)}.json"

    def _load(self, v: Variant) -> dict | None:
        path = self._path(v)
        if not path.is_file():
            return None
        try:
            return json.loads(path.read_text())
        except ValueError:
            return None

    def _save(self, v: Variant, result: dict) -> None:

        write_json_atomic(self._path(v), result)


_LATER_FIELDS = {"withheld"}


def _run_variant(job):
    """Train one variant's stage 2 and describe the test split (runs in a worker)."""
    stage1, train, test, cfg, v, inputs = job
    torch.set_num_threads(1 if cfg.workers > 1 else 2)
    t0 = time.perf_counter()
    tc = GeneratorTrainConfig(stage2_steps=cfg.steps, batch=cfg.batch, seed=cfg.seed,
                              k=v.k, threads=torch.get_num_threads())
    V, T = (torch.from_numpy(np.asarray(train[x], np.float32)) for x in ("V", "T"))
    if inputs is None:
        gen, _ = train_stage2(stage1, None, V, T, train["labels"], None, None, tc, "baseline")
        ans = answer_split(None, test, BASELINE, generator=gen)
        return v, ans.responses, time.perf_counter() - t0
    rv, rl, trv, trl = inputs
    integrator = seeded_build(cfg.seed, lambda: make_integrator(v, V.shape[1],
                                                                 stage1.decoder.hidden))
    gen, _ = train_stage2(stage1, integrator, V, T, train["labels"], torch.from_numpy(rv),
                          torch.from_numpy(rl), tc, v.label())
    ans = answer_split(None, test, RA_TOUCH, neighbours=(trv, trl), generator=gen)
    return v, ans.responses, time.perf_counter() - t0


def make_integrator(v: Variant, dim: int, out_dim: int):

    if v.integration == "sum":
        return SumIntegrator(dim, out_dim)
    if v.integration not in INTEGRATIONS:
        raise ConfigError(f"integration must be one of {INTEGRATIONS + ('sum',)}, "
                          f"got {v.integration!r}")
    return TextureAwareIntegrator(IntegratorConfig(
        dim=dim, out_dim=out_dim, use_image=v.integration in ("image", "both"),
        use_text=v.integration in ("text", "both")))

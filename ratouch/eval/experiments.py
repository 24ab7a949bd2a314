"""The paper's experiments on the world: Tables 1-5 and Figures 3, 5 and 6, each one function
that trains what it needs, evaluates on the world's TVL-style test split with the offline judge,
and returns a `Report` (markdown table + plotly figure + data); `run_all` writes them all into
one markdown report (`docs/results.md`).

Every generator variant starts from the same stage-1 generator (the shipped RA-Touch
checkpoint's prompt projection and decoder base, i.e. the TVL-LLaMA stage) and gets the same
stage-2 budget (`ExperimentConfig.steps` LoRA steps, the same batches): the baseline trains LoRA
alone, the RA-Touch variants train LoRA plus an integrator over the neighbours their retrieval
setting finds. So rows differ only by what the experiment varies. Variant results are cached on
disk (`cache_dir()/experiments/`), keyed by everything they depend on (settings, weights, corpus
and the source of the code that trains them), so that `run_all` reuses what a single experiment
command computed.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import logging
import multiprocessing as mp
import os
import time
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ratouch.checkpoint import sha256_file
from ratouch.errors import ConfigError
from ratouch.eval.catalog import EXPERIMENT_HELP
from ratouch.eval.judge import OfflineJudge, judge_results
from ratouch.eval.report import git_commit, save_png
from ratouch.eval.retrieval import entry_materials, material_precision
from ratouch.eval.tvl import describe, records_for
from ratouch.files import write_json_atomic
from ratouch.model.generator import load_generator, save_generator
from ratouch.model.integrator import (
    IntegratorConfig,
    SumIntegrator,
    TextureAwareIntegrator,
)
from ratouch.model.retriever import collapse_stats
from ratouch.paths import cache_dir, generator_weights, retriever_weights
from ratouch.search.index import exact_topk
from ratouch.search.pca import PCA2D
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.generator import GeneratorTrainConfig, train_stage1, train_stage2
from ratouch.train.recipes import align_only_tgr, training_pairs
from ratouch.world.splits import encode_test_split

log = logging.getLogger(__name__)

SUBSET_NAMES = {"SSVTP": "structured", "HCT": "wild"}
CAPTION_TYPES = ("class_name", "visual_description", "tactile_caption")
QUERY_KEY = (("image", "image"), ("image", "text"), ("tactile", "image"), ("tactile", "text"),
             ("joint", "text"))
INTEGRATIONS = ("image", "text", "both")

#: The code that trains a variant (a package stands for all its modules): its source is part of
#: the cache keys, so that a change to it trains again instead of reusing stale results.
TRAINING_CODE = ("ratouch.train", "ratouch.model", "ratouch.world.scarcity")


def source_sha256(modules: Sequence[str] = TRAINING_CODE) -> str:
    """sha256 over the source files of modules, found through their `__file__` (a package:
    every `.py` file beside its `__init__.py`), each with its module-relative name."""
    h = hashlib.sha256()
    for name in modules:
        path = Path(importlib.import_module(name).__file__)
        files = sorted(path.parent.glob("*.py")) if path.name == "__init__.py" else [path]
        for f in files:
            h.update(f"{name}:{f.name}\n".encode())
            h.update(f.read_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class Variant:
    """One generator variant: what it retrieves and how it integrates it.

    ``retrieval=False`` is the no-retrieval baseline (LoRA only); ``integration="sum"`` is Table
    2's "retriever without integrator" row (neighbours summed, one Linear to D').
    """

    retrieval: bool = True
    mode: str = "joint"            # query: image / tactile / joint (Tactile-Guided Retriever)
    key: str = "text"              # key: image / text embeddings of the corpus
    caption: str = "tactile_caption"  # what the corpus text embeddings encode (Table 3)
    integration: str = "both"      # image / text / both (Table 5) / sum (Table 2)
    k: int = 5
    corpus_size: int = 0           # 0 = the whole corpus; else a stratified subset
    withheld: int = 0              # materials left out of the generator's paired training data

    def label(self) -> str:
        held = f", {self.withheld} materials withheld" if self.withheld else ""
        if not self.retrieval:
            return "baseline (no retrieval)" + held
        return (f"{self.mode}->{self.key}, {self.caption}, {self.integration}, K={self.k}"
                + (f", corpus {self.corpus_size}" if self.corpus_size else "") + held)


BASELINE = Variant(retrieval=False)
RA_TOUCH = Variant()


@dataclass(frozen=True)
class ExperimentConfig:
    """Settings shared by every experiment.

    Attributes:
        encoder: the default encoder whose retriever and generators are used.
        steps: stage-2 steps of every variant (the shipped generators had 800).
        batch: stage-2 batch size.
        seed: training seed.
        workers: variants trained in parallel processes (one thread each).
        corpus_sizes: Figure 3's stratified subset sizes of the corpus.
        ks: Figure 6's K values.
        stage1_steps: stage-1 steps of a generator retrained without withheld materials (the
            shipped stage 1 had 1500).
        withheld: Table 6's number of materials left out of the paired training data.
    """

    encoder: str = "default-s"
    steps: int = 300
    batch: int = 64
    seed: int = 0
    workers: int = 2
    corpus_sizes: tuple[int, ...] = (1000, 2500, 5000, 10000)
    ks: tuple[int, ...] = (1, 3, 5, 7, 10)
    stage1_steps: int = 1500
    withheld: int = 12

    def __post_init__(self) -> None:
        for name in ("steps", "batch", "workers"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 1")
        if not self.ks or min(self.ks) < 1:
            raise ConfigError(f"ks={self.ks} must be positive")
        if not self.corpus_sizes or min(self.corpus_sizes) < 1:
            raise ConfigError(f"corpus_sizes={self.corpus_sizes} must be positive")


@dataclass
class Report:
    """One experiment's output."""

    name: str
    title: str
    markdown: str
    figure: object = None  # a plotly Figure
    data: dict = field(default_factory=dict)
    seconds: float = 0.0


# --------------------------------------------------------------------------------------------
# the lab: shared state, built lazily


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
            import torch

            data = self.train_for(n)
            log.info("training a stage-1 generator without %d materials (%d pairs, %d steps)",
                     n, len(data["labels"]), tc.stage1_steps)
            from ratouch.train.recipes import language_prior

            prior, _ = language_prior(self.cfg.encoder, progress=False)  # as the shipped pair
            gen, _ = train_stage1(torch.from_numpy(np.asarray(data["V"], np.float32)),
                                  torch.from_numpy(np.asarray(data["T"], np.float32)),
                                  data["labels"], data["V"].shape[1], tc, prior)
            save_generator(folder, gen, {"withheld": self.withheld_materials(n)})
        return load_generator(folder, stage1=True)

    def neighbours(self, v: Variant, V: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, ...]:
        """(ids, Rv, Rl) of a variant's retrieval for queries (V, T), by exact search."""
        q = {"image": V, "tactile": T}.get(v.mode)
        if q is None:
            q = self.pipeline.joint_query(V, T)
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
            with mp.get_context("fork").Pool(min(self.cfg.workers, len(jobs))) as pool:
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

        records, summary = judge_results(records_for(self.test, responses, v.label()),
                                         self.judge)
        return {"variant": asdict(v), "responses": responses,
                "scores": [r["offline_score"] for r in records],
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
    import torch


    stage1, train, test, cfg, v, inputs = job
    torch.set_num_threads(1 if cfg.workers > 1 else 2)
    t0 = time.perf_counter()
    tc = GeneratorTrainConfig(stage2_steps=cfg.steps, batch=cfg.batch, seed=cfg.seed,
                              k=v.k, threads=torch.get_num_threads())
    V, T = (torch.from_numpy(np.asarray(train[x], np.float32)) for x in ("V", "T"))
    if inputs is None:
        gen, _ = train_stage2(stage1, None, V, T, train["labels"], None, None, tc, "baseline")
        return v, describe(gen, test.V, test.T), time.perf_counter() - t0
    rv, rl, trv, trl = inputs
    gen, _ = train_stage2(stage1, make_integrator(v, V.shape[1], stage1.decoder.hidden),
                          V, T, train["labels"], torch.from_numpy(rv), torch.from_numpy(rl), tc,
                          v.label())
    return v, describe(gen, test.V, test.T, trv, trl), time.perf_counter() - t0


def make_integrator(v: Variant, dim: int, out_dim: int):

    if v.integration == "sum":
        return SumIntegrator(dim, out_dim)
    if v.integration not in INTEGRATIONS:
        raise ConfigError(f"integration must be one of {INTEGRATIONS + ('sum',)}, "
                          f"got {v.integration!r}")
    return TextureAwareIntegrator(IntegratorConfig(
        dim=dim, out_dim=out_dim, use_image=v.integration in ("image", "both"),
        use_text=v.integration in ("text", "both")))


# --------------------------------------------------------------------------------------------
# the experiments


def _row(lab: Lab, name: str, r: dict, base: dict | None) -> list[str]:
    """A table row: SSVTP / HCT / TVL means with their 95 % bootstrap CI, the gain over the
    baseline and its p-value; then adjective F1 and mean answer length (overall)."""
    from scipy.stats import ttest_rel

    cells = [name]
    subs = np.array(lab.test.subsets)
    for key, sel in (("SSVTP", subs == "structured"), ("HCT", subs == "wild"),
                     ("overall", np.ones(len(subs), bool))):
        s = r["stats"][key]
        cell = f"{r['means'][key]:.3f} [{s['ci_low']:.2f}, {s['ci_high']:.2f}]"
        if base is not None and base is not r:
            a, b = np.array(base["scores"])[sel], np.array(r["scores"])[sel]
            d = float((b - a).mean())
            p = float(ttest_rel(b, a).pvalue) if np.any(b - a) else 1.0
            cell += f" ({d:+.3f}, p={p:.2g})"
        cells.append(cell)
    s = r["stats"]["overall"]
    return cells + [f"{s['f1']:.3f}", f"{s['mean_length']:.1f}"]


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


JUDGE_COLS = ["SSVTP (structured) [95% CI]", "HCT (wild) [95% CI]", "TVL (overall) [95% CI]",
              "adjective F1", "adjectives / answer"]


def paired_difference(a: np.ndarray, b: np.ndarray, level: float = 0.95
                      ) -> tuple[float, float, float]:
    """Mean of the paired differences b - a and its `level` t-interval (lo, hi)."""
    from scipy.stats import t as student_t

    d = np.asarray(b, np.float64) - np.asarray(a, np.float64)
    mean = float(d.mean())
    if len(d) < 2 or not np.any(d - mean):
        return mean, mean, mean
    half = float(student_t.ppf(0.5 + level / 2, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)))
    return mean, mean - half, mean + half


def _diff_chart(title: str, names: Sequence[str], results: Sequence[dict], base: dict,
                subsets: Sequence[str]):
    """Each setting's judge-score difference from the baseline with its paired 95 % CI, per
    subset: the differences are a few hundredths, invisible on bars drawn from zero."""
    import plotly.graph_objects as go

    subs = np.array(subsets)
    fig = go.Figure()
    for key, label, sel in (("SSVTP", "SSVTP (structured)", subs == "structured"),
                            ("HCT", "HCT (wild)", subs == "wild"),
                            ("overall", "TVL (overall)", np.ones(len(subs), bool))):
        stats = [paired_difference(np.array(base["scores"])[sel], np.array(r["scores"])[sel])
                 for r in results]
        fig.add_scatter(name=label, x=list(names), y=[m for m, _, _ in stats], mode="markers",
                        marker={"size": 9}, error_y={"type": "data", "symmetric": False,
                                                     "array": [hi - m for m, _, hi in stats],
                                                     "arrayminus": [m - lo for m, lo, _ in stats]})
    fig.add_hline(y=0, line_dash="dot", annotation_text="baseline (no retrieval)")
    fig.update_layout(title=title, template="plotly_white", height=440, autosize=True,
                      yaxis_title="judge score − baseline (paired 95 % CI)",
                      scattermode="group", legend={"orientation": "h", "y": -0.35},
                      margin={"b": 160})
    return fig


def _simple(lab: Lab, name: str, title: str, rows: Sequence[tuple[str, Variant]],
            note: str = "") -> Report:
    t0 = time.perf_counter()
    res = lab.evaluate([BASELINE] + [v for _, v in rows])
    base = res[BASELINE]
    named = [("baseline (no retrieval)", BASELINE)] + list(rows)
    table = _table(["setting"] + JUDGE_COLS, [_row(lab, n, res[v], base) for n, v in named])
    md = table + ("\n\n" + note if note else "")
    fig = _diff_chart(title, [n for n, _ in rows], [res[v] for _, v in rows], base,
                      lab.test.subsets)
    data = {n: res[v]["means"] for n, v in named}
    return Report(name, title, md, fig, data, time.perf_counter() - t0)


def table2_ablation(lab: Lab) -> Report:
    """Table 2: retriever and integrator ablation."""
    return _simple(lab, "table2", "Table 2 - ablation: retriever, integrator", [
        ("+ Tactile-Guided Retriever (sum + Linear, no integrator)",
         replace(RA_TOUCH, integration="sum")),
        ("+ Tactile-Guided Retriever + Texture-Aware Integrator (RA-Touch)", RA_TOUCH)],
        "Gains in brackets are over the baseline row, with a paired t-test over the 402 test "
        "pairs (46 / 356 per subset).")


def table3_caption_type(lab: Lab) -> Report:
    """Table 3: what the corpus's text side holds."""
    return _simple(lab, "table3", "Table 3 - caption type of the retrieval corpus", [
        ("+ RA-Touch, class name", replace(RA_TOUCH, caption="class_name")),
        ("+ RA-Touch, visual description", replace(RA_TOUCH, caption="visual_description")),
        ("+ RA-Touch, tactile caption (ImageNet-T)", RA_TOUCH)],
        "The caption type sets both the retrieval key (the joint query searches that text's "
        "embeddings) and the text the integrator reads.")


def table4_query_key(lab: Lab) -> Report:
    """Table 4: retrieval query x key."""

    rows = [(f"{m} -> {k}", replace(RA_TOUCH, mode=m, key=k)) for m, k in QUERY_KEY]
    rep = _simple(lab, "table4", "Table 4 - retrieval query x key", rows)
    prec = []
    for name, v in rows:
        ids, _, _ = lab.neighbours(v, lab.test.V, lab.test.T)
        prec.append([name, f"{material_precision(ids, lab.test.materials, entry_materials(lab.pipeline.corpus)).mean():.3f}"])
    rep.markdown += ("\n\nMaterial precision@5 of the neighbours each setting feeds the "
                     "integrator (test split):\n\n" + _table(["setting", "P@5"], prec))
    rep.data["material_precision@5"] = dict(prec)
    return rep


def table5_integration(lab: Lab) -> Report:
    """Table 5: integrate retrieved images, texts or both."""
    return _simple(lab, "table5", "Table 5 - integration modality", [
        ("image only", replace(RA_TOUCH, integration="image")),
        ("text only", replace(RA_TOUCH, integration="text")),
        ("image + text (RA-Touch)", RA_TOUCH)])


def _curve(lab: Lab, name: str, title: str, xs: Sequence[int], variants: Sequence[Variant],
           xlabel: str, log_x: bool = False) -> Report:
    import plotly.graph_objects as go

    t0 = time.perf_counter()
    res = lab.evaluate([BASELINE] + list(variants))
    base = res[BASELINE]
    rows = [_row(lab, str(x), res[v], base) for x, v in zip(xs, variants)]
    md = _table([xlabel] + JUDGE_COLS, [_row(lab, "baseline", base, None)] + rows)
    fig = go.Figure()
    for key, label in (("SSVTP", "SSVTP (structured)"), ("HCT", "HCT (wild)"),
                       ("overall", "TVL (overall)")):
        color = {"SSVTP": "#1f77b4", "HCT": "#ff7f0e", "overall": "#2ca02c"}[key]
        fig.add_scatter(x=list(xs), y=[res[v]["means"][key] for v in variants],
                        mode="lines+markers", name=f"RA-Touch, {label}", line={"color": color})
        fig.add_scatter(x=[min(xs), max(xs)], y=[base["means"][key]] * 2, mode="lines",
                        name=f"baseline, {label}", line={"color": color, "dash": "dot"})
    fig.update_layout(title=title, xaxis_title=xlabel, yaxis_title="offline judge score (1-10)",
                      template="plotly_white", height=420, width=760)
    if log_x:
        fig.update_xaxes(type="log")
    data = {str(x): res[v]["means"] for x, v in zip(xs, variants)}
    data["baseline"] = base["means"]
    return Report(name, title, md, fig, data, time.perf_counter() - t0)


def fig3_corpus_size(lab: Lab) -> Report:
    """Figure 3: corpus scale (stratified subsets of the corpus)."""
    sizes = [s for s in lab.cfg.corpus_sizes if s <= len(lab.pipeline.corpus)]
    rep = _curve(lab, "fig3", "Figure 3 - corpus size", sizes,
                 [replace(RA_TOUCH, corpus_size=s if s < len(lab.pipeline.corpus) else 0)
                  for s in sizes], "corpus entries", log_x=True)
    rep.markdown += (f"\n\nSubsets are class-stratified and nested inside the "
                     f"{len(lab.pipeline.corpus)}-entry default corpus; each point trains its "
                     "own integrator.")
    return rep


def fig6_top_k(lab: Lab) -> Report:
    """Figure 6: number of retrieved neighbours K."""
    return _curve(lab, "fig6", "Figure 6 - number of retrieved samples K", list(lab.cfg.ks),
                  [replace(RA_TOUCH, k=k) for k in lab.cfg.ks], "K")


def table1_main(lab: Lab) -> Report:
    """Table 1 (the world's version): the encoder's baseline vs RA-Touch over corpus sizes."""
    sizes = [s for s in lab.cfg.corpus_sizes if s <= len(lab.pipeline.corpus)]
    rows = [(f"{lab.cfg.encoder} + RA-Touch, corpus {s}",
             replace(RA_TOUCH, corpus_size=s if s < len(lab.pipeline.corpus) else 0))
            for s in sizes]
    rep = _simple(lab, "table1", f"Table 1 - {lab.cfg.encoder}: baseline vs RA-Touch", rows,
                  "Other encoder sizes: `ratouch eval table1 --encoder default-tiny` (needs that "
                  "encoder's retriever and generators; see the note in the report header).")
    return rep


def fig5_loss_pca(lab: Lab) -> Report:
    """Figure 5: PCA of the joint queries, alignment loss only vs alignment + stability."""
    import torch
    from plotly.subplots import make_subplots


    t0 = time.perf_counter()
    tgrs = {"alignment only": align_only_tgr(lab.cfg.encoder, seed=lab.cfg.seed)[0],
            "alignment + stability (shipped)": lab.pipeline.tgr}
    V, T = (torch.from_numpy(np.asarray(x, np.float32)) for x in (lab.test.V, lab.test.T))
    fig = make_subplots(rows=1, cols=2, subplot_titles=list(tgrs))
    mats = np.array(lab.test.materials)
    uniq = sorted(set(mats))
    from plotly.colors import sample_colorscale

    colours = sample_colorscale("Turbo", [j / max(1, len(uniq) - 1) for j in range(len(uniq))])
    rows, data = [], {}
    for col, (name, tgr) in enumerate(tgrs.items(), start=1):
        with torch.no_grad():
            q = tgr(V, T).query
        stats = collapse_stats(q)
        qn = q.numpy()
        ids = exact_topk(qn, lab.pipeline.corpus_embeddings("tactile_caption"), 5)
        prec = float(material_precision(ids, lab.test.materials, entry_materials(lab.pipeline.corpus)).mean())
        xy = PCA2D.fit(qn).project(qn)
        for j, m in enumerate(uniq):
            sel = mats == m
            fig.add_scatter(x=xy[sel, 0], y=xy[sel, 1], mode="markers", name=m,
                            legendgroup=m, showlegend=col == 1,
                            marker={"size": 5, "color": colours[j]}, row=1, col=col)
        rows.append([name, f"{stats['mean_cosine']:.3f}", f"{stats['effective_rank']:.1f}",
                     f"{prec:.3f}"])
        data[name] = {**{k: round(float(v), 4) for k, v in stats.items()},
                      "material_precision@5": round(prec, 4)}
    fig.update_layout(title="Figure 5 - PCA of the joint queries on the test split (colour = "
                            "material)", template="plotly_white", height=480, width=980)
    md = _table(["retriever loss", "mean pairwise cosine", "effective rank",
                 "joint->text material P@5"], rows)
    return Report("fig5", "Figure 5 - loss strategies: PCA of the queries", md, fig, data,
                  time.perf_counter() - t0)


def table6_withheld(lab: Lab) -> Report:
    """Table 6 (not in the paper): materials missing from the paired training data."""
    from scipy.stats import ttest_rel

    t0 = time.perf_counter()
    n = lab.cfg.withheld
    base, ra = replace(BASELINE, withheld=n), replace(RA_TOUCH, withheld=n)
    res = lab.evaluate([BASELINE, RA_TOUCH, base, ra])
    held = set(lab.withheld_materials(n))
    unseen = np.array([m in held for m in lab.test.materials])
    groups = (("all test pairs", np.ones(len(unseen), bool)), ("seen materials", ~unseen),
              ("withheld materials", unseen))
    rows, data = [], {}
    for name, (b, r) in ((f"all {len(set(lab.train['materials']))} materials in training",
                          (BASELINE, RA_TOUCH)), (f"{n} materials withheld", (base, ra))):
        cells = [name]
        for gname, sel in groups:
            x, y = np.array(res[b]["scores"])[sel], np.array(res[r]["scores"])[sel]
            p = float(ttest_rel(y, x).pvalue) if len(x) > 1 and np.any(y - x) else 1.0
            cells.append(f"{x.mean():.3f} -> {y.mean():.3f} ({y.mean() - x.mean():+.3f}, "
                         f"p={p:.2g}, n={int(sel.sum())})")
            _, lo, hi = paired_difference(x, y)
            data.setdefault(name, {})[gname] = {"baseline": round(float(x.mean()), 4),
                                                "ra_touch": round(float(y.mean()), 4),
                                                "ci95": [round(lo, 4), round(hi, 4)],
                                                "p": p, "n": int(sel.sum())}
        rows.append(cells)
    md = (_table(["paired training data", *(f"{g}: baseline -> RA-Touch" for g, _ in groups)],
                 rows)
          + f"\n\nWithheld (never in the generator's training pairs; the encoders, the "
            f"retriever and the corpus still cover them): {', '.join(sorted(held))}. Each row's "
            "baseline and RA-Touch share that row's stage-1 generator.")
    import plotly.graph_objects as go

    fig = go.Figure()
    for r in data:  # RA-Touch - baseline per subset, with its paired 95 % CI
        diffs = [v["ra_touch"] - v["baseline"] for v in data[r].values()]
        fig.add_scatter(name=r, x=list(data[r]), y=diffs, mode="markers", marker={"size": 9},
                        error_y={"type": "data", "symmetric": False,
                                 "array": [v["ci95"][1] - d for v, d in zip(data[r].values(),
                                                                            diffs)],
                                 "arrayminus": [d - v["ci95"][0] for v, d in
                                                zip(data[r].values(), diffs)]})
    fig.add_hline(y=0, line_dash="dot", annotation_text="baseline (no retrieval)")
    fig.update_layout(title="Table 6 - materials withheld from the paired training data",
                      template="plotly_white", height=440, autosize=True, scattermode="group",
                      yaxis_title="RA-Touch − baseline judge score (paired 95 % CI)",
                      legend={"orientation": "h", "y": -0.25})
    return Report("table6", "Table 6 - low resource: materials withheld from training (not in "
                  "the paper)", md, fig, data, time.perf_counter() - t0)


EXPERIMENTS: dict[str, Callable[[Lab], Report]] = {
    "table1": table1_main, "table2": table2_ablation, "table3": table3_caption_type,
    "table4": table4_query_key, "table5": table5_integration, "fig3": fig3_corpus_size,
    "fig6": fig6_top_k, "fig5": fig5_loss_pca, "table6": table6_withheld,
}
assert list(EXPERIMENTS) == list(EXPERIMENT_HELP), "ratouch.eval.catalog lists the experiments"


# --------------------------------------------------------------------------------------------
# writing reports


def write_report(rep: Report, folder: str | os.PathLike, png: bool = True) -> dict[str, Path]:
    """``<name>.md``, ``<name>.html`` (self-contained), ``<name>.json`` (plotly figure JSON, for
    the app) and ``<name>.png`` when a static exporter works offline."""

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = {"md": folder / f"{rep.name}.md"}
    out["md"].write_text(f"## {rep.title}\n\n{rep.markdown}\n", encoding="utf-8")
    write_json_atomic(folder / f"{rep.name}.data.json", rep.data)
    if rep.figure is not None:
        out["html"] = folder / f"{rep.name}.html"
        rep.figure.write_html(out["html"], include_plotlyjs="directory", full_html=True)
        out["json"] = folder / f"{rep.name}.json"
        out["json"].write_text(rep.figure.to_json(), encoding="utf-8")
        path = save_png(rep.figure, folder / f"{rep.name}.png") if png else None
        if path is not None:
            out["png"] = path
    return out


def run_experiments(names: Sequence[str], cfg: ExperimentConfig, out: str | os.PathLike,
                    lab: Lab | None = None, png: bool = True) -> list[Report]:
    unknown = [n for n in names if n not in EXPERIMENTS]
    if unknown:
        raise ConfigError(f"unknown experiment(s) {unknown}; choose from {list(EXPERIMENTS)}")
    lab = lab or Lab(cfg)
    reports = []
    for n in names:
        t0 = time.perf_counter()
        rep = EXPERIMENTS[n](lab)
        rep.seconds = time.perf_counter() - t0
        write_report(rep, Path(out) / "figures", png)
        reports.append(rep)
        log.info("%s done in %.0f s", n, rep.seconds)
    return reports


def companion_sections(out: str | os.PathLike) -> str:
    """The speed-against-accuracy and stress reports that live beside the results, when their
    commands (`ratouch bench tradeoff`, `ratouch eval stress --out <out>/stress`) made them."""
    out, parts = Path(out), []
    trade = out / "figures" / "tradeoff.md"
    if trade.is_file():
        stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(trade.stat().st_mtime))
        parts += [trade.read_text(encoding="utf-8").strip(), "",
                  f"Made by `ratouch bench tradeoff` ({stamp}).", ""]
        if (out / "figures" / "tradeoff.png").is_file():
            parts += ["![Speed against accuracy](figures/tradeoff.png) "
                      "([interactive](figures/tradeoff.html))", ""]
    stress = out / "stress" / "stress.md"
    if stress.is_file():
        text = stress.read_text(encoding="utf-8")
        start = text.find("## Break points")
        end = text.find("\n## ", start + 1)
        parts += ["## Stability where methods fail (`ratouch eval stress`)", "",
                  "The whole sweep, per knob, with the collapse check: "
                  "[stress/stress.md](stress/stress.md).", ""]
        if start >= 0:
            parts += ["#" + text[start:end if end > 0 else None].strip(), ""]
        for png in ("stress.png", "stress_overlap.png"):
            if (out / "stress" / png).is_file():
                parts += [f"![{png}](stress/{png})", ""]
    return "\n".join(parts)


def results_markdown(reports: Sequence[Report], cfg: ExperimentConfig, seconds: float,
                     header: str = "", out: str | os.PathLike | None = None,
                     counts: dict | None = None) -> str:
    """The whole report: provenance, then every experiment with its figure."""
    lines = ["# RA-Touch on the world: the paper's experiments",
             "",
             "Generated by `ratouch eval all` - do not edit by hand.",
             "",
             f"* commit `{git_commit()}`, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
             f"wall time {seconds / 60:.1f} min on this machine"
             + (f" ({counts['trained']} generator variants trained in this run, "
                f"{counts['from_cache']} read from the cache of earlier runs: the wall time "
                "covers only what was trained here)" if counts else ""),
             f"* settings: `{json.dumps(asdict(cfg))}`",
             "* test split: the world's 402 pairs (46 structured = SSVTP-like, 356 wild = "
             "HCT-like); scores: the offline judge (1-10, see README 'Judges'); gains are paired "
             "differences to the no-retrieval baseline with two-sided paired t-tests",
             ""]
    if header:
        lines += [header, ""]
    for rep in reports:
        lines += [f"## {rep.title}", "", rep.markdown, ""]
        if rep.figure is not None:
            png = f"figures/{rep.name}.png"
            lines += [f"![{rep.title}]({png}) ([interactive](figures/{rep.name}.html))", ""]
    if out is not None:
        lines.append(companion_sections(out))
    return "\n".join(lines) + "\n"

"""Training of the generators: the TVL-LLaMA-style baseline and RA-Touch, compared like with like.

Stage 0, the language prior, plays the part of LLaMA-2 and its adapter pre-training in the
paper: the prompt projection and the decoder learn to verbalise text embeddings of the corpus
(class names, appearance descriptions and their tactile captions, each to its tactile caption),
with no paired touch data. Both systems start from it.

Stage 1 trains the visual prompt p = Linear(V + T) and the small decoder from scratch on the
paired train split (the real path starts from a pre-trained LLaMA instead). Stage 2 starts both
systems from stage 1 and trains LoRA on the decoder for the same number of steps: RA-Touch also
trains the Texture-Aware Integrator over the neighbours that the frozen Tactile-Guided Retriever
finds in ImageNet-T (p' = p + integrator), the baseline has no integrator. So the two differ only
by retrieval.
"""

from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch

from ratouch.errors import ConfigError
from ratouch.model.decoder import DecoderConfig, build_small_decoder
from ratouch.model.generator import (
    BaselinePrompt,
    PromptConfig,
    RATouchGenerator,
    trainable_parameters,
)
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.vocabulary import EXTRA_TACTILE, TVL_ADJECTIVES, adjective_f1

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class GeneratorTrainConfig:
    stage0_steps: int = 600
    stage1_steps: int = 1600  # 800 until 2026-12-03: docs/premise.md, "A longer stage 1"
    stage2_steps: int = 600
    batch: int = 64
    lr: float = 1e-3
    lora_lr: float = 1e-3
    k: int = 5
    seed: int = 0
    hidden: int = 256
    layers: int = 4
    threads: int = 2

    def __post_init__(self) -> None:
        for name in ("stage0_steps", "stage1_steps", "stage2_steps", "batch", "k", "hidden", "layers"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 1")


def _steps(gen, params, V, T, labels, rv, rl, steps: int, batch: int, lr: float, seed: int,
           desc: str) -> list[dict]:
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=0.0)
    warm = max(1, steps // 10)
    sched = torch.optim.lr_scheduler.LambdaLR(  # linear warm-up, then cosine decay
        opt, lambda i: (i + 1) / warm if i < warm
        else 0.5 * (1 + math.cos(math.pi * (i - warm) / max(1, steps - warm))))
    g = torch.Generator().manual_seed(seed)
    gen.train()
    history, running = [], 0.0
    for step in range(steps):
        idx = torch.randint(len(V), (batch,), generator=g)
        targets = [labels[i] for i in idx.tolist()]
        kwargs = {}
        if rv is not None:
            kwargs = {"Rv": rv[idx], "Rl": rl[idx]}
        loss = gen.loss(V[idx], T[idx], targets, **kwargs)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        sched.step()
        running += loss.item()
        if (step + 1) % 100 == 0 or step == steps - 1:
            n = (step % 100) + 1
            history.append({"stage": desc, "step": step + 1, "loss": round(running / n, 4)})
            log.info("%s step %d loss %.4f", desc, step + 1, running / n)
            running = 0.0
    gen.eval()
    return history


def _lora_only(gen) -> list:
    """Stage 2 of the baseline: the same LoRA budget as RA-Touch, without an integrator."""
    for p in gen.parameters():
        p.requires_grad_(False)
    for name, p in gen.decoder.named_parameters():
        if "lora_" in name:
            p.requires_grad_(True)
    return [p for p in gen.parameters() if p.requires_grad]


def train_stage2(stage1, integrator, V, T, labels: list[str], rv, rl,
                 tc: GeneratorTrainConfig, desc: str = "stage2"):
    """Stage 2 from a stage-1 generator: fresh LoRA on the decoder, plus `integrator` if given.

    With ``integrator=None`` only LoRA trains and the neighbours are ignored (the baseline's
    stage 2); otherwise the integrator and LoRA train on p' = p + integrator(T, Rv, Rl), with
    the prompt projection frozen (RA-Touch, and its ablations). Both get the same budget
    (`tc.stage2_steps`, `tc.lora_lr`, the same batches), so variants differ only by retrieval.

    Args:
        stage1: a generator without LoRA (see `load_generator(..., stage1=True)`); not changed.
        integrator: a new integrator module, or None.
        V, T: (N, D) float tensors of the training pairs; labels: their captions.
        rv, rl: (N, K, D) float tensors of each pair's neighbours (unused without integrator).

    Returns:
        (the trained generator in eval mode, loss history)
    """

    torch.manual_seed(tc.seed)
    gen = copy.deepcopy(stage1)
    gen.integrator = integrator
    gen.decoder.add_lora(gen.decoder.cfg, seed=tc.seed)
    if integrator is None:
        params, rv, rl = _lora_only(gen), None, None
    else:
        params = trainable_parameters(gen, "ra")
    history = _steps(gen, params, V, T, labels, rv, rl, tc.stage2_steps, tc.batch, tc.lora_lr,
                     tc.seed + 1, desc)
    return gen, history


def train_stage0(L, texts: list[str], dim: int, tc: GeneratorTrainConfig):
    """Stage 0, the language prior: the prompt projection and a fresh small decoder learn to
    verbalise text embeddings. Each input L_i (a text embedding of a corpus caption, class name
    or description) stands in for both V and T, so p = Linear(2 L_i); the target is the tactile
    caption it belongs to. No paired touch data.

    Args:
        L: (N, D) float tensor of text embeddings.
        texts: the N target captions.

    Returns:
        (generator without LoRA, loss history)
    """
    torch.manual_seed(tc.seed)
    decoder = build_small_decoder(DecoderConfig(hidden=tc.hidden, layers=tc.layers),
                                  list(TVL_ADJECTIVES) + list(EXTRA_TACTILE), seed=tc.seed)
    prior = RATouchGenerator(BaselinePrompt(PromptConfig(dim=dim, out_dim=decoder.hidden)),
                             decoder)
    history = _steps(prior, trainable_parameters(prior, "baseline"), L, L, texts, None, None,
                     tc.stage0_steps, tc.batch, tc.lr, tc.seed + 7, "stage0")
    return prior, history


def train_stage1(V, T, labels: list[str], dim: int, tc: GeneratorTrainConfig, prior=None):
    """Stage 1 (TVL-LLaMA): the prompt projection p = Linear(V + T) and the small decoder,
    from the stage-0 language prior when given (it is not changed), else from scratch.
    Returns (generator without LoRA, loss history)."""

    torch.manual_seed(tc.seed)
    if prior is not None:
        stage1 = copy.deepcopy(prior)
    else:
        decoder = build_small_decoder(DecoderConfig(hidden=tc.hidden, layers=tc.layers),
                                      list(TVL_ADJECTIVES) + list(EXTRA_TACTILE), seed=tc.seed)
        stage1 = RATouchGenerator(BaselinePrompt(PromptConfig(dim=dim, out_dim=decoder.hidden)),
                                  decoder)
    history = _steps(stage1, trainable_parameters(stage1, "baseline"), V, T, labels, None, None,
                     tc.stage1_steps, tc.batch, tc.lr, tc.seed, "stage1")
    return stage1, history


def train_generators(emb: dict[str, np.ndarray], labels: list[str], Rv: np.ndarray,
                     Rl: np.ndarray, dim: int, tc: GeneratorTrainConfig, integrator_cfg=None,
                     prior=None):
    """Train the baseline and RA-Touch generators.

    Args:
        emb: {"V": (N, D), "T": (N, D)} frozen encoder embeddings of the training pairs.
        labels: their ground-truth captions.
        Rv, Rl: (N, K, D) image / text embeddings of each pair's retrieved neighbours.
        dim: D.
        tc: training config.
        integrator_cfg: `IntegratorConfig` (default: both modalities, out_dim = hidden).
        prior: the stage-0 generator both systems start from (`train_stage0`), or None
            (stage 1 from scratch).

    Returns:
        (baseline generator, RA-Touch generator, report)
    """

    torch.set_num_threads(tc.threads)
    t0 = time.perf_counter()
    V = torch.from_numpy(np.asarray(emb["V"], np.float32))
    T = torch.from_numpy(np.asarray(emb["T"], np.float32))
    rv = torch.from_numpy(np.asarray(Rv, np.float32))
    rl = torch.from_numpy(np.asarray(Rl, np.float32))
    stage1, history = train_stage1(V, T, labels, dim, tc, prior)
    t1 = time.perf_counter()
    base, h = train_stage2(stage1, None, V, T, labels, None, None, tc, "baseline-lora")
    history += h
    icfg = integrator_cfg or IntegratorConfig(dim=dim, out_dim=stage1.decoder.hidden)
    ra, h = train_stage2(stage1, TextureAwareIntegrator(icfg), V, T, labels, rv, rl, tc,
                         "ra-touch-lora")
    history += h
    report = {"train": asdict(tc), "n_pairs": len(V), "integrator": asdict(icfg),
              "language_prior": prior is not None,
              "stage1_seconds": round(t1 - t0, 1),
              "stage2_seconds": round(time.perf_counter() - t1, 1), "history": history}
    return base, ra, report


def evaluate_generators(base, ra, V: np.ndarray, T: np.ndarray, Rv: np.ndarray,
                        Rl: np.ndarray, labels: list[str], batch: int = 128) -> dict:
    """Label-adjective F1 of both systems on held-out pairs, with a paired comparison."""
    from scipy.stats import ttest_rel

    outs: dict[str, list[str]] = {"baseline": [], "ra_touch": []}
    with torch.no_grad():
        for s in range(0, len(V), batch):
            v, t = torch.from_numpy(V[s:s + batch]), torch.from_numpy(T[s:s + batch])
            outs["baseline"] += base.describe(v, t)
            outs["ra_touch"] += ra.describe(v, t, torch.from_numpy(Rv[s:s + batch]),
                                            torch.from_numpy(Rl[s:s + batch]))
    f1 = {k: np.array([adjective_f1(g, p) for p, g in zip(v, labels)]) for k, v in outs.items()}
    test = ttest_rel(f1["ra_touch"], f1["baseline"])
    return {"n": len(labels), "f1_baseline": round(float(f1["baseline"].mean()), 4),
            "f1_ra_touch": round(float(f1["ra_touch"].mean()), 4),
            "paired_t": round(float(test.statistic), 3), "p_value": float(test.pvalue),
            "examples": [{"label": g, "baseline": b, "ra_touch": r}
                         for g, b, r in list(zip(labels, outs["baseline"], outs["ra_touch"]))[:8]]}

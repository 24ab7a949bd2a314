"""The reproducible training recipes behind `ratouch train retriever|generator` (and the
steps of `ratouch train all`, `ratouch.ship.retrain`): they wire cached data, frozen encoders,
the retrieval side and the trainers together, and save the weights shipped in `assets/`."""

from __future__ import annotations

import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ratouch.checkpoint import MANIFEST, checkpoint_fingerprint
from ratouch.encoders.factory import create_model
from ratouch.errors import ConfigError
from ratouch.model.decoder import DecoderConfig, load_hf_decoder
from ratouch.model.generator import (
    BaselinePrompt,
    PromptConfig,
    RATouchGenerator,
    load_generator,
    save_generator,
)
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.model.loss import RetrieverLossConfig
from ratouch.model.neighbour_text import NeighbourText
from ratouch.model.neighbour_tokens import NeighbourTokens, NeighbourTokensConfig
from ratouch.model.pretrained_lm import PRETRAINED_LMS
from ratouch.model.retriever import RetrieverConfig
from ratouch.model.trust import TrustCalibration
from ratouch.paths import (
    cache_dir,
    encoder_weights,
    generator_weights,
    retriever_weights,
    trust_calibration,
)
from ratouch.search.retrieval_side import RetrievalSide, load_gate, load_tgr
from ratouch.seeds import seeded_build
from ratouch.train.encoders import TrainConfig, tactile_batch, training_data
from ratouch.train.generator import (
    GeneratorTrainConfig,
    evaluate_generators,
    train_generators,
    train_stage0,
    train_stage2,
)
from ratouch.train.retriever import (
    RetrieverTrainConfig,
    paired_embeddings,
    train_retriever,
)
from ratouch.world.splits import encode_test_split

log = logging.getLogger(__name__)


def training_pairs(encoders, seed: int = 0, progress: bool = False,
                   n_pairs: int | None = None) -> dict:
    """V, T and captions of the world's cached paired training split, for frozen encoders:
    all the pairs the encoders trained on, or only the first `n_pairs` of them (rendered
    with a small corpus beside them, which is not returned)."""
    tc = (TrainConfig(model=encoders.name, seed=seed) if n_pairs is None else
          TrainConfig(model=encoders.name, seed=seed, n_pairs=n_pairs, n_corpus=250))
    data = training_data(tc, encoders.cfg.vision_size, encoders.cfg.tactile_size, progress,
                         encoders.cfg.prior, encoders.cfg.prior_size)
    emb = paired_embeddings(encoders, data)
    return {"V": emb["V"], "T": emb["T"], "labels": list(data["labels"]),
            "materials": list(data["materials"])}


def _pairs(encoder: str, seed: int, progress: bool, draw: int = 0):
    model = create_model(encoder)
    tc = TrainConfig(model=encoder, seed=seed, draw=draw)
    data = training_data(tc, model.cfg.vision_size, model.cfg.tactile_size, progress,
                         model.cfg.prior, model.cfg.prior_size)
    return model, data, paired_embeddings(model, data)


def _pairs_with_neighbours(encoder: str, world_seed: int, draw: int, k: int, progress: bool):
    """The paired training data of a draw, its frozen embeddings, the retrieval side and each
    pair's top-k joint-query neighbours: (model, data, emb, retrieval, Rv, Rl)."""
    model, data, emb = _pairs(encoder, world_seed, progress, draw)
    retrieval = RetrievalSide.load(encoder, progress=progress)
    rv, rl = retrieval.neighbour_embeddings(retrieval.joint_neighbours(emb["V"], emb["T"], k))
    return model, data, emb, retrieval, rv, rl


def prior_data(retrieval: RetrievalSide) -> tuple[np.ndarray, list[str]]:
    """Stage 0's data, from the retrieval corpus alone: text embeddings of each entry's tactile
    caption, its class name and its appearance description, each paired with the caption."""
    captions = [e.caption for e in retrieval.corpus.entries]
    L = np.concatenate([retrieval.corpus_embeddings(kind) for kind in
                        ("tactile_caption", "class_name", "visual_description")])
    return L.astype(np.float32), captions * 3


def language_prior(encoder: str = "default-s", seed: int = 0, progress: bool = True,
                   retrieval: RetrievalSide | None = None, **train_overrides):
    """The stage-0 generator shipped beside the two systems (`assets/generator/ENC/prior`),
    trained and saved there when missing. Returns (generator, report)."""
    folder = generator_weights(encoder, "prior")
    if (folder / "manifest.json").is_file():
        return load_generator(folder), {"prior": str(folder), "trained": False}
    t0 = time.perf_counter()
    retrieval = retrieval or RetrievalSide.load(encoder, progress=progress)
    L, texts = prior_data(retrieval)
    tc = GeneratorTrainConfig(seed=seed, **train_overrides)
    torch.set_num_threads(tc.threads)
    prior, history = train_stage0(torch.from_numpy(L), texts, retrieval.encoders.dim, tc)
    report = {"n_texts": len(texts), "stage0_steps": tc.stage0_steps,
              "seconds": round(time.perf_counter() - t0, 1), "history": history}
    save_generator(folder, prior, {"encoder": encoder, **report}, half=True)
    return load_generator(folder), {"prior": str(folder), "trained": True, **report}


def retriever_recipe(encoder: str = "default-s", seed: int = 0, strategy: str = "full",
                     cross_residual: bool = True, epochs: int | None = None, out=None,
                     progress: bool = True) -> dict:
    """Train the Tactile-Guided Retriever for an encoder and save it (default: assets/)."""
    model, _, emb = _pairs(encoder, seed, progress)
    tc = RetrieverTrainConfig(seed=seed, **({"epochs": epochs} if epochs else {}))
    _, report = train_retriever(emb, RetrieverConfig(dim=model.dim, cross_residual=cross_residual),
                                RetrieverLossConfig(strategy=strategy), tc,
                                out=str(out or retriever_weights(encoder)),
                                meta={"encoder": encoder})
    return report


def generator_recipe(encoder: str = "default-s", seed: int = 0, progress: bool = True,
                     draw: int = 0, world_seed: int | None = None, out=None,
                     **train_overrides) -> dict:
    """Train the baseline and RA-Touch generators from the language prior, save both (default:
    assets/, else `out`/baseline and `out`/ra), evaluate on the test split.

    Args:
        seed: the training seed (and the world's, unless `world_seed` is given).
        draw: which few pairs of the scarce materials the paired split keeps
            (`ratouch.world.scarcity`); the encoders and the retriever are not retrained.
    """

    t0 = time.perf_counter()
    world_seed = seed if world_seed is None else world_seed
    tc = GeneratorTrainConfig(seed=seed, **train_overrides)
    model, data, emb, retrieval, rv, rl = _pairs_with_neighbours(encoder, world_seed, draw, tc.k,
                                                                 progress)
    prior, prior_report = language_prior(encoder, world_seed, progress, retrieval)
    base, ra, report = train_generators(emb, list(data["labels"]), rv, rl, model.dim, tc,
                                        prior=prior)
    report.update(draw=draw, world_seed=world_seed, prior=prior_report)
    test = encode_test_split(model)
    trv, trl = retrieval.neighbour_embeddings(retrieval.joint_neighbours(test.V, test.T, tc.k))
    report["test"] = evaluate_generators(base, ra, test.V, test.T, trv, trl, test.labels)
    report["seconds"] = round(time.perf_counter() - t0, 1)
    # shipped weights are stored as float16 (identical test F1 measured; assets stay < 40 MB)
    for kind, gen in (("baseline", base), ("ra", ra)):
        folder = Path(out) / kind if out is not None else generator_weights(encoder, kind)
        save_generator(folder, gen, {"encoder": encoder, **report}, half=True)
    return report


#: The training budget of generators adapted from a pretrained language model (`--lm`): a
#: 135 M-parameter decoder costs 4-8 s a step of 16 captions on the 2 busy CPU cores this was
#: built on, so the budget is what one training (280 steps) fits in about half an hour
#: there, fixed before the first run (not chosen by a test score); `ratouch train generator
#: --stage1-steps ...` overrides it.
PRETRAINED_BUDGET = {"stage1_steps": 120, "stage2_steps": 80, "batch": 16}
#: Tokens a pretrained decoder may write (its sub-word tokenizer spends 2-3 on a word).
PRETRAINED_MAX_NEW_TOKENS = 24


def lm_label(lm: str) -> str:
    """The name generators adapted from `lm` are shipped and served under: a
    `PRETRAINED_LMS` key as it is, a local model folder by its folder name."""
    return lm if lm in PRETRAINED_LMS else Path(lm).resolve().name


def pretrained_generator_recipe(encoder: str = "default-s", lm: str = "smollm2-135m",
                                seed: int = 0, progress: bool = True, out=None,
                                **train_overrides) -> dict:
    """The TVL-LLaMA recipe on a real pretrained LLaMA-architecture model, for the baseline
    and RA-Touch alike. `lm`: a key of `ratouch.model.pretrained_lm.PRETRAINED_LMS`
    ("smollm2-135m", loaded from its wheel) or a local HF-format LLaMA folder (LLaMA-2-7B).

    The model is the language prior (no stage 0) and stays frozen. Stage 1 trains the visual
    prompt p = Linear(V + T), projected into the model's hidden size, on the paired split;
    stage 2 starts both systems from it with fresh LoRA on the attention projections (q, v)
    for the same budget, RA-Touch also training the Texture-Aware Integrator over the joint
    query's neighbours, as for the small decoder (`train_generators`). The checkpoints hold
    the prompt, the integrator and the adapter and name the model, which is never copied.
    Saved to `generator_weights(encoder, kind, lm_label(lm))` (or `out`/baseline,
    `out`/ra); judged on the world's test split by `ratouch eval tvl --lm`."""
    t0 = time.perf_counter()
    budget = {**PRETRAINED_BUDGET, **train_overrides}
    tc = GeneratorTrainConfig(seed=seed, **budget)
    model, data, emb, retrieval, rv, rl = _pairs_with_neighbours(encoder, seed, 0, tc.k,
                                                                 progress)
    torch.set_num_threads(tc.threads)
    path = lm if lm in PRETRAINED_LMS else str(Path(lm).resolve())
    decoder = load_hf_decoder(DecoderConfig(kind="hf", path=path,
                                            max_new_tokens=PRETRAINED_MAX_NEW_TOKENS))
    start = RATouchGenerator(BaselinePrompt(PromptConfig(dim=model.dim,
                                                         out_dim=decoder.hidden)), decoder)
    base, ra, report = train_generators(emb, list(data["labels"]), rv, rl, model.dim, tc,
                                        prior=start)
    # judged on the test split by `ratouch eval tvl --lm` (generation is the slow part here:
    # it is not done twice)
    label = lm_label(lm)
    report.update(lm=path, world_seed=seed, draw=0, test=f"ratouch eval tvl --lm {label}",
                  seconds=round(time.perf_counter() - t0, 1))
    for kind, gen in (("baseline", base), ("ra", ra)):
        folder = (Path(out) / kind if out is not None
                  else generator_weights(encoder, kind, label))
        save_generator(folder, gen, {"encoder": encoder, **report}, half=True)
    return report


def arm_budget(stage1, **train_overrides) -> dict:
    """A second-stage arm's training budget: the stage-2 budget its stage-1 model was trained
    with (`PRETRAINED_BUDGET` on a pretrained language model, the defaults on the small
    decoder), so that an arm and the RA-Touch it is compared with train alike."""
    base = PRETRAINED_BUDGET if stage1.decoder.cfg.kind == "hf" else {}
    return {**base, **train_overrides}


def token_arm_recipe(encoder: str, stage1_from, seed: int = 0, draw: int = 0,
                     world_seed: int = 0, out=None, progress: bool = False, **train_overrides):
    """The neighbour-token arm (`ratouch.model.neighbour_tokens`), trained with RA-Touch's
    stage-2 budget (`arm_budget`) from the stage-1 model inside `stage1_from` (a RA-Touch
    checkpoint folder) on the same paired data; saved to `out`. Returns (generator, report)."""
    t0 = time.perf_counter()
    stage1 = load_generator(stage1_from, stage1=True)
    tc = GeneratorTrainConfig(seed=seed, **arm_budget(stage1, **train_overrides))
    torch.set_num_threads(tc.threads)
    model, data, emb, _, rv, rl = _pairs_with_neighbours(encoder, world_seed, draw, tc.k, progress)
    tokens = seeded_build(tc.seed, lambda: NeighbourTokens(NeighbourTokensConfig(
        dim=model.dim, out_dim=stage1.decoder.hidden)))
    gen, history = train_stage2(
        stage1, tokens,
        torch.from_numpy(emb["V"]), torch.from_numpy(emb["T"]), list(data["labels"]),
        torch.from_numpy(rv), torch.from_numpy(rl), tc, "neighbour-tokens-lora")
    report = {"arm": "neighbour_tokens", "seed": seed, "draw": draw, "stage1_from": str(stage1_from),
              "seconds": round(time.perf_counter() - t0, 1), "history": history}
    if out is not None:
        save_generator(out, gen, {"encoder": encoder, **report}, half=True)
    return gen, report


def text_arm_recipe(encoder: str, stage1_from, seed: int = 0, draw: int = 0,
                    world_seed: int = 0, out=None, progress: bool = False, **train_overrides):
    """The text arm (`ratouch.model.neighbour_text`: the neighbours' captions written into the
    prompt), trained with RA-Touch's stage-2 budget (`arm_budget`) from the stage-1 model
    inside `stage1_from` (a RA-Touch checkpoint folder) on the same paired data and
    joint-query neighbours; saved to `out`. Returns (generator, report)."""
    t0 = time.perf_counter()
    stage1 = load_generator(stage1_from, stage1=True)
    tc = GeneratorTrainConfig(seed=seed, **arm_budget(stage1, **train_overrides))
    torch.set_num_threads(tc.threads)
    _, data, emb, retrieval, rv, rl = _pairs_with_neighbours(encoder, world_seed, draw, tc.k,
                                                             progress)
    arm = seeded_build(tc.seed, lambda: NeighbourText.build(
        [e.caption for e in retrieval.corpus.entries],
        retrieval.corpus_embeddings("tactile_caption"), stage1.decoder))
    gen, history = train_stage2(
        stage1, arm, torch.from_numpy(emb["V"]), torch.from_numpy(emb["T"]),
        list(data["labels"]), torch.from_numpy(rv), torch.from_numpy(rl), tc, "text-arm-lora")
    report = {"arm": "neighbour_text", "seed": seed, "draw": draw,
              "stage1_from": str(stage1_from), "train": asdict(tc),
              "seconds": round(time.perf_counter() - t0, 1), "history": history}
    if out is not None:
        save_generator(out, gen, {"encoder": encoder, **report}, half=True)
    return gen, report


#: The reader's episodes (docs/premise.md, "Reading episodes"; fixed before its first run):
#: the share of training samples whose touch is degraded, and how heavy the noise of the
#: noisy half of those is, in the tactile input's own units (its difference channels have
#: unit RMS per frame): noise of 3x the signal's RMS, a signal-to-noise ratio of 1/9.
READER_DEGRADED_SHARE = 0.5
READER_NOISE_RMS = 3.0


def noisy_inputs(x: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Tactile inputs (N, 4, H, W) under heavy noise: the three difference channels mixed
    with white noise of `READER_NOISE_RMS` times their RMS and rescaled to unit RMS again, as
    `tactile_input` divides a frame by its own contrast; the contrast channel is kept."""
    d = x[:, :3].float()
    noise = torch.randn(d.shape, generator=gen)
    d = (d + READER_NOISE_RMS * noise * d.pow(2).mean((1, 2, 3), keepdim=True).sqrt())
    d = d / d.pow(2).mean((1, 2, 3), keepdim=True).sqrt().clamp_min(1e-6)
    return torch.cat([d, x[:, 3:].float()], 1)


def degraded_touch(encoders, data: dict, T: np.ndarray, seed: int = 0) -> np.ndarray:
    """(N, D) tactile embeddings of the paired split with touch withheld or degraded: half
    the pairs (a seeded draw) get another pair's touch (a derangement), the other half their
    own input under heavy noise (`noisy_inputs`), encoded with or without the pair's
    background as its query was (the seeded draw of `paired_embeddings`)."""
    rng = np.random.default_rng(seed)
    n = len(T)
    perm = rng.permutation(n)
    out = np.empty_like(T)
    out[perm] = T[np.roll(perm, 1)]  # each pair gets another's touch
    noisy = rng.random(n) < 0.5
    draw, noise = torch.Generator().manual_seed(0), torch.Generator().manual_seed(seed)
    batch = 512  # paired_embeddings' batches: the same with/without-background draw
    with torch.no_grad():
        for s in range(0, n, batch):
            idx = torch.arange(s, min(s + batch, n))
            frames = tactile_batch(data, idx, draw)  # the draw paired_embeddings made
            pick = np.flatnonzero(noisy[s:s + batch])
            if len(pick):
                x = noisy_inputs(frames[torch.from_numpy(pick)], noise)
                out[s + pick] = encoders.embed_tactile(x).numpy()
    return out


def reader_episodes(side: RetrievalSide, encoders, data: dict, V: np.ndarray, T: np.ndarray,
                    k: int, seed: int = 0) -> dict:
    """The reader's training samples: each pair keeps its touch or (with probability
    `READER_DEGRADED_SHARE`, a seeded draw) gets it degraded (`degraded_touch`), and reads the
    gated query's top-`k` neighbours of what it then carries.

    Returns:
        {"T": (N, D) the tactile embeddings read, "degraded": (N,) bool, "ids": (N, k)}
    """
    if side.gate is None:
        raise ConfigError("the reader trains on the gated query, and this retrieval side has "
                          f"no touch gate: `ratouch train gate --encoder {encoders.name}`")
    T_bad = degraded_touch(encoders, data, T, seed)
    bad = np.random.default_rng(seed + 11).random(len(V)) < READER_DEGRADED_SHARE
    T_ep = np.where(bad[:, None], T_bad, T).astype(np.float32)
    return {"T": T_ep, "degraded": bad, "ids": side.joint_neighbours(V, T_ep, k, gated=True)}


#: How a reader hands its neighbours to the decoder: "integrator" (a fresh Texture-Aware
#: Integrator, the paper's form) or "text" (their captions in the prompt, `NeighbourText`).
READER_ARMS = ("integrator", "text")
#: The shipped reader's form (docs/premise.md, "The reader in words": which reader ships).
READER_ARM = "integrator"  # the reader in words lost to it (docs/premise.md)


def train_reader(side: RetrievalSide, encoders, stage1, data: dict, V: np.ndarray,
                 T: np.ndarray, labels: list[str], tc: GeneratorTrainConfig,
                 arm: str = "integrator"):
    """Stage 2 of the reader from `stage1` (a generator without LoRA; not changed): a fresh
    Texture-Aware Integrator (`arm` "integrator") or the neighbours as text (`arm` "text",
    docs/premise.md "The reader in words") and LoRA, RA-Touch's budget, on `reader_episodes`.
    Returns (generator, {"arm", "integrator", "episodes"})."""
    if arm not in READER_ARMS:
        raise ConfigError(f"reader arm {arm!r}: known arms are {', '.join(READER_ARMS)}")
    ep = reader_episodes(side, encoders, data, V, T, tc.k, tc.seed)
    rv, rl = side.neighbour_embeddings(ep["ids"])
    module: nn.Module
    if arm == "text":
        module = seeded_build(tc.seed, lambda: NeighbourText.build(
            [e.caption for e in side.corpus.entries], side.corpus_embeddings("tactile_caption"),
            stage1.decoder))
        spec: dict = asdict(module.cfg)
    else:
        icfg = IntegratorConfig(dim=encoders.dim, out_dim=stage1.decoder.hidden)
        module, spec = seeded_build(tc.seed, lambda: TextureAwareIntegrator(icfg)), asdict(icfg)
    gen, history = train_stage2(
        stage1, module, torch.from_numpy(np.asarray(V, np.float32)),
        torch.from_numpy(ep["T"]), list(labels), torch.from_numpy(rv), torch.from_numpy(rl),
        tc, "reader-lora")
    return gen, {"arm": arm, "integrator": spec, "history": history,
                 "episodes": {"degraded_share": READER_DEGRADED_SHARE,
                              "noise_rms": READER_NOISE_RMS,
                              "degraded": int(ep["degraded"].sum()), "n_pairs": len(V)}}


def reader_recipe(encoder: str, stage1_from, seed: int = 0, draw: int = 0,
                  world_seed: int = 0, out=None, progress: bool = False,
                  arm: str = READER_ARM, **train_overrides):
    """The `gated` system's generator, the reader (`train_reader`, in the form `arm`), from
    the stage-1 model inside `stage1_from` (a RA-Touch checkpoint folder) on a draw's paired
    split, with the shipped retrieval side and touch gate; saved to `out`.
    Returns (generator, report)."""
    if arm not in READER_ARMS:
        raise ConfigError(f"reader arm {arm!r}: known arms are {', '.join(READER_ARMS)}")
    t0 = time.perf_counter()
    tc = GeneratorTrainConfig(seed=seed, **train_overrides)
    torch.set_num_threads(tc.threads)
    side = RetrievalSide.load(encoder, progress=progress)
    trust = trust_calibration(encoder)
    if trust.is_file():
        side.gate = load_gate(encoder, TrustCalibration.load(trust))
    if side.gate is None:
        raise ConfigError(f"the reader trains on the gated query: `ratouch train trust "
                          f"--encoder {encoder}` and `ratouch train gate --encoder {encoder}` "
                          "first")
    model, data, emb = _pairs(encoder, world_seed, progress, draw)
    stage1 = load_generator(stage1_from, stage1=True)
    gen, info = train_reader(side, model, stage1, data, emb["V"], emb["T"],
                             list(data["labels"]), tc, arm)
    report = {"system": "gated", "generator": "reader", "seed": seed, "draw": draw,
              "stage1_from": str(stage1_from), "train": asdict(tc), **info,
              "seconds": round(time.perf_counter() - t0, 1)}
    if out is not None:
        save_generator(out, gen, {"encoder": encoder, **report}, half=True)
    return gen, report


def align_retriever_folder(encoder: str, epochs: int, seed: int = 0) -> Path:
    """Where the align-only retriever of an encoder set's shipped weights is cached: keyed by
    those weights, so that one trained before a retrain is not read after it."""
    weights = encoder_weights(encoder)
    tag = (checkpoint_fingerprint(weights)[:12] if (weights / MANIFEST).is_file() else "none")
    return cache_dir() / f"retriever-align-{encoder}-{tag}-e{epochs}-s{seed}"


def align_only_tgr(encoder: str, epochs: int = 12, seed: int = 0, progress: bool = False):
    """The Tactile-Guided Retriever trained with the alignment loss only (Fig. 5's ablation),
    trained into the cache on first use. Returns (retriever, {"align_folder", "trained_s"?})."""
    info: dict[str, Any] = {}
    folder = align_retriever_folder(encoder, epochs, seed)
    if not (folder / "manifest.json").is_file():
        t0 = time.perf_counter()
        log.info("training the align-only retriever (%d epochs) into %s", epochs, folder)
        retriever_recipe(encoder, seed, strategy="align", epochs=epochs, out=folder,
                         progress=progress)
        info["trained_s"] = round(time.perf_counter() - t0, 1)
    info["align_folder"] = str(folder)
    return load_tgr(encoder, folder=folder), info

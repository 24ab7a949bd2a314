"""Training of the default encoders with the TVL recipe, seeded and CPU-sized.

Tactile and vision are aligned contrastively (InfoNCE) to the text space, and to each other, on
the world's paired train split; vision is also aligned to the recaptioned ImageNet-T corpus.
The text side is the frozen MiniLM plus a trained residual projection. Texts that are equal
count as positives of each other (labels repeat), so the targets are soft.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import cast, overload

import numpy as np
import torch
import torch.nn.functional as F

from ratouch.checkpoint import save_checkpoint
from ratouch.corpus.imagenet_t import stratified_world_ids, world_lexicon
from ratouch.corpus.recaption import OfflineRecaptioner
from ratouch.encoders.default import DefaultEncoders, tactile_input
from ratouch.encoders.factory import create_model, model_config
from ratouch.encoders.prior import load_prior
from ratouch.errors import ConfigError
from ratouch.files import write_npz_atomic
from ratouch.images import resize_array
from ratouch.paths import cache_dir
from ratouch.processes import worker_pool
from ratouch.threads import parse_device
from ratouch.timing import progress_bar
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for
from ratouch.world.scarcity import ScarceRegime
from ratouch.world.tactile import touch_version

log = logging.getLogger(__name__)

ANTONYM_PROBE = ("soft, fuzzy, deformable", "hard, rigid, smooth", "squishy, plush")

# Steps per shipped size, chosen so that the three train in under 15 minutes on 2 cores.
STEPS = {"default-tiny": 700, "default-s": 900, "default-b": 700, "debug": 20}


@dataclass(frozen=True)
class TrainConfig:
    model: str = "default-s"
    n_pairs: int = 12_000
    n_corpus: int = 8_000
    steps: int = 900
    batch: int = 128
    lr: float = 2e-3
    weight_decay: float = 0.02
    seed: int = 0
    workers: int = 2
    threads: int = 2
    regime: str = "scarce"  # which train pairs: see ratouch.world.scarcity
    draw: int = 0
    device: str = "cpu"  # where the step loop runs (checked by `parse_device`)

    @property
    def scarcity(self) -> ScarceRegime:
        """The paired split's regime (the world seed fixes its scarce materials)."""
        return ScarceRegime(regime=self.regime, seed=self.seed, draw=self.draw)

    def __post_init__(self) -> None:
        for name in ("n_pairs", "n_corpus", "steps", "batch", "workers", "threads"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 1")
        if not self.lr > 0:
            raise ConfigError(f"lr={self.lr} must be > 0")
        self.scarcity  # noqa: B018 (checks regime and draw)
        parse_device(self.device)


# ---------------------------------------------------------------------------------------------
# data: rendered once, in parallel, kept in memory

def _pair_chunk(args):

    wcfg, indices, vsize, tsize, psize = args
    world = world_for(wcfg)
    crops, pcrops, tacs, tacs_bg, labels, mats = [], [], [], [], [], []
    for i in indices:
        s = world.sample("train", i)
        x0, y0, x1, y1 = s.box
        crop = s.visual[y0:y1, x0:x1]
        crops.append(resize_array(crop, tuple(vsize[::-1])))
        if psize:
            pcrops.append(resize_array(crop, psize))
        bg = world.background_image(s.sensor)
        tacs.append(tactile_input(s.tactile, tsize, None, s.family).astype(np.float16))
        tacs_bg.append(tactile_input(s.tactile, tsize, bg, s.family).astype(np.float16))
        labels.append(s.caption)
        mats.append(s.material)
    return crops, pcrops, tacs, tacs_bg, labels, mats


def _corpus_chunk(args):

    wcfg, ids, vsize, psize = args
    world = world_for(wcfg)
    out = []
    for c, i in ids:
        img = world.corpus_image(c, i)
        small = resize_array(img, tuple(vsize[::-1]))
        big = resize_array(img, psize) if psize else None
        out.append((small, big, world.corpus_record(c, i)))
    return out


def training_data(tc: TrainConfig, vsize, tsize, progress: bool = True,
                  prior: str | None = None, prior_size: int = 128) -> dict:
    """The rendered training data, cached on disk (`$RATOUCH_CACHE/train-data-*.npz`) so that
    later stages (retriever, generator) and re-runs reuse it instead of re-rendering.

    With a visual `prior`, the crops' and corpus images' pooled prior features (at
    `prior_size`) are kept instead of their pixels at that size ("prior_crops",
    "prior_corpus"): the prior is frozen, so they are computed once."""

    tag = (f"s{tc.seed}-p{tc.n_pairs}-c{tc.n_corpus}-v{vsize[0]}x{vsize[1]}-t{tsize[0]}x{tsize[1]}"
           f"-{tc.scarcity.tag}-{touch_version()}" + (f"-{prior}{prior_size}" if prior else ""))
    path = cache_dir() / f"train-data-{tag}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        for k in ("labels", "materials", "corpus_captions"):
            data[k] = [str(x) for x in data[k]]
        return data
    data = render_training_data(tc, vsize, tsize, progress, prior, prior_size)
    write_npz_atomic(path, **{k: np.asarray(v) for k, v in data.items()})
    return data


def render_training_data(tc: TrainConfig, vsize, tsize, progress: bool = True,
                         prior: str | None = None, prior_size: int = 128) -> dict:
    """Render the paired crops / tactile inputs (without and with the sensor's background)
    and the corpus images used for training; with a prior, its features of both."""

    wcfg = WorldConfig(seed=tc.seed)
    world_for(wcfg).warm()
    psize = prior_size if prior else 0
    pairs = tc.scarcity.train_indices(tc.n_pairs)
    pair_jobs = [(wcfg, pairs[k:k + 250], vsize, tsize, psize) for k in range(0, len(pairs), 250)]
    ids = stratified_world_ids(tc.n_corpus, tc.seed)
    corpus_jobs = [(wcfg, ids[k:k + 250], vsize, psize) for k in range(0, len(ids), 250)]
    crops, pcrops, tacs, tacs_bg, labels, mats, cimgs, pcimgs, crecs = ([] for _ in range(9))
    with worker_pool(tc.workers) as pool:
        bar = progress_bar(total=tc.n_pairs + len(ids), desc="render training data",
                           progress=progress)
        for c, pc, t, tb, lab, m in pool.map(_pair_chunk, pair_jobs):
            crops += c
            pcrops += pc
            tacs += t
            tacs_bg += tb
            labels += lab
            mats += m
            bar.update(len(c))
        for part in pool.map(_corpus_chunk, corpus_jobs):
            cimgs += [p[0] for p in part]
            pcimgs += [p[1] for p in part]
            crecs += [p[2] for p in part]
            bar.update(len(part))
        bar.close()
    recap = OfflineRecaptioner(world_lexicon())
    captions = [", ".join(recap.recaption(r.class_name, r.description)) for r in crecs]
    data = {"crops": np.stack(crops), "tactile": np.stack(tacs), "tactile_bg": np.stack(tacs_bg),
            "labels": labels, "materials": mats, "corpus_images": np.stack(cimgs),
            "corpus_captions": captions}
    if prior:
        model = load_prior(prior)
        data["prior_crops"] = model.features(pcrops, prior_size).astype(np.float16)
        data["prior_corpus"] = model.features(pcimgs, prior_size).astype(np.float16)
    return data


# ---------------------------------------------------------------------------------------------
# losses and the loop

def soft_info_nce(a: torch.Tensor, b: torch.Tensor, same: torch.Tensor,
                  scale: torch.Tensor) -> torch.Tensor:
    """Symmetric InfoNCE where `same[i, j]` marks b_j as a positive of a_i (equal texts)."""
    logits = scale * a @ b.T  # (B, B)
    target = same / same.sum(1, keepdim=True)
    loss_ab = -(target * F.log_softmax(logits, 1)).sum(1).mean()
    target_t = same.T / same.T.sum(1, keepdim=True)
    loss_ba = -(target_t * F.log_softmax(logits.T, 1)).sum(1).mean()
    return 0.5 * (loss_ab + loss_ba)


def _norm_images(u8: np.ndarray) -> torch.Tensor:
    x = torch.from_numpy(u8).float().div_(255).sub_(0.5).div_(0.25)
    return x.permute(0, 3, 1, 2)


def _augment(x: torch.Tensor, gen: torch.Generator, vertical: bool) -> torch.Tensor:
    if torch.rand(1, generator=gen).item() < 0.5:
        x = x.flip(3)
    if vertical and torch.rand(1, generator=gen).item() < 0.5:
        x = x.flip(2)
    return x


def _prior(data: dict, key: str, idx: torch.Tensor) -> torch.Tensor | None:
    """The rows `idx` of the cached prior features (None: no prior)."""
    if key not in data:
        return None
    return torch.from_numpy(data[key][idx.numpy()].astype(np.float32))


def tactile_batch(data: dict, idx: torch.Tensor, gen: torch.Generator | None = None,
                  background_share: float = 0.5) -> torch.Tensor:
    """Tactile inputs of the cached pairs `idx`: each drawn with its sensor's background
    (difference from the no-contact frame) with probability `background_share`, else without
    it, so the encoder reads both kinds of query (`gen` None: without background)."""
    plain = torch.from_numpy(data["tactile"][idx.numpy()].astype(np.float32))
    if gen is None or "tactile_bg" not in data:
        return plain
    with_bg = torch.from_numpy(data["tactile_bg"][idx.numpy()].astype(np.float32))
    pick = torch.rand(len(idx), generator=gen) < background_share
    return torch.where(pick[:, None, None, None], with_bg, plain)


def antonym_report(model: DefaultEncoders) -> dict:
    """Cosines of the antonym probe in MiniLM's raw space and in the trained space."""
    raw = torch.from_numpy(model.minilm_features(list(ANTONYM_PROBE)))
    with torch.no_grad():
        proj = model.embed_text_features(raw)
    r = raw @ raw.T
    p = proj @ proj.T
    return {"minilm": {"soft_vs_hard": round(float(r[0, 1]), 3),
                       "soft_vs_squishy": round(float(r[0, 2]), 3)},
            "projected": {"soft_vs_hard": round(float(p[0, 1]), 3),
                          "soft_vs_squishy": round(float(p[0, 2]), 3)}}


def step_losses(model: DefaultEncoders, data: dict, minilm: torch.Tensor, lab: torch.Tensor,
                cap: torch.Tensor, batch: int, gen: torch.Generator) -> dict[str, torch.Tensor]:
    """One training step's four losses: a batch of pairs and one of corpus entries, drawn
    with `gen` from the cached `data` (rows of the text table `minilm`, on the model's device,
    by label `lab` and caption `cap` index), moved to the model's device."""
    dev = minilm.device

    @overload
    def on(x: torch.Tensor) -> torch.Tensor: ...
    @overload
    def on(x: None) -> None: ...
    def on(x: torch.Tensor | None) -> torch.Tensor | None:
        return None if x is None else x.to(dev, non_blocking=True)

    ip = torch.randint(len(lab), (batch,), generator=gen)
    ic = torch.randint(len(cap), (batch,), generator=gen)
    v = model.embed_vision(on(_augment(_norm_images(data["crops"][ip.numpy()]), gen, False)),
                           on(_prior(data, "prior_crops", ip)))
    t = model.embed_tactile(on(_augment(tactile_batch(data, ip, gen), gen, True)))
    lp = model.embed_text_features(minilm[lab[ip].to(dev)])
    vc = model.embed_vision(on(_augment(_norm_images(data["corpus_images"][ic.numpy()]), gen,
                                        False)), on(_prior(data, "prior_corpus", ic)))
    lc = model.embed_text_features(minilm[cap[ic].to(dev)])
    same_p = on((lab[ip][:, None] == lab[ip][None, :]).float())
    same_c = on((cap[ic][:, None] == cap[ic][None, :]).float())
    eye = on(torch.eye(batch))
    scale = model.logit_scale.exp().clamp(max=100)
    return {
        "tactile_text": soft_info_nce(t, lp, same_p, scale),
        "vision_text": soft_info_nce(v, lp, same_p, scale),
        "tactile_vision": soft_info_nce(t, v, eye, scale),
        "corpus_vision_text": soft_info_nce(vc, lc, same_c, scale),
    }


def train_encoders(tc: TrainConfig, out: str | None = None, cache: dict | None = None,
                   progress: bool = True) -> tuple[DefaultEncoders, dict]:
    """Train one default encoder set; save it to `out` (safetensors + config + manifest).

    Args:
        tc: training config.
        out: checkpoint folder (None: do not save).
        cache: a dict in which rendered training data is kept, keyed by input sizes and data
            config, so that several sizes trained in one run render it once.
        progress: show progress bars.

    Returns:
        The trained model and a report (timings, final losses, antonym probe).

    Long on purpose: one training run read top to bottom (data, model, optimiser, the step loop,
    the report), as nanoGPT's train.py is.
    """
    cfg = model_config(tc.model)
    if cfg["backend"] != "default":
        raise ConfigError(f"only default-backend encoders are trained here, not {tc.model!r}")
    torch.manual_seed(tc.seed)
    torch.set_num_threads(tc.threads)
    t0 = time.perf_counter()
    model = create_model(tc.model, pretrained=None)
    key = (model.cfg.vision_size, model.cfg.tactile_size, tc.n_pairs, tc.n_corpus, tc.seed,
           tc.scarcity.tag, model.cfg.prior, model.cfg.prior_size)
    cache = {} if cache is None else cache
    if key not in cache:
        cache[key] = training_data(tc, model.cfg.vision_size, model.cfg.tactile_size, progress,
                                   model.cfg.prior, model.cfg.prior_size)
    data = cache[key]
    t_data = time.perf_counter() - t0
    texts = sorted(set(data["labels"]) | set(data["corpus_captions"]))
    text_id = {t: i for i, t in enumerate(texts)}
    before = antonym_report(model)
    dev = torch.device(tc.device)
    minilm = torch.from_numpy(model.minilm_features(texts)).to(dev)  # (T, 384), frozen
    model.to(dev)
    lab = torch.tensor([text_id[t] for t in data["labels"]])
    cap = torch.tensor([text_id[t] for t in data["corpus_captions"]])
    gen = torch.Generator().manual_seed(tc.seed)
    opt = torch.optim.AdamW(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=tc.lr, total_steps=tc.steps,
                                                pct_start=0.1)
    model.train()
    history = []
    for step in progress_bar(range(tc.steps), desc=f"train {tc.model}", progress=progress):
        losses = step_losses(model, data, minilm, lab, cap, tc.batch, gen)
        loss = cast(torch.Tensor, sum(losses.values()))  # a sum of (four) tensors
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if step % 50 == 0 or step == tc.steps - 1:
            history.append({"step": step, **{k: round(x.item(), 4) for k, x in losses.items()}})
    model.to("cpu").eval()
    report = {
        "model": tc.model, "steps": tc.steps, "batch": tc.batch, "seed": tc.seed,
        "n_pairs": len(lab), "n_corpus": len(cap), "device": str(dev), "threads": tc.threads,
        "regime": tc.scarcity.tag,
        "scarce_materials": list(tc.scarcity.scarce_materials()), "data_seconds": round(t_data, 1),
        "train_seconds": round(time.perf_counter() - t0 - t_data, 1),
        "final": history[-1], "antonyms_before": before, "antonyms_after": antonym_report(model),
    }
    if out is not None:
        save_checkpoint(out, model.state_dict(), cfg, meta={"train": report, "history": history},
                        half=True)
    return model, report

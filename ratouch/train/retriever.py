"""Offline training of the Tactile-Guided Retriever on the paired train split, then frozen.

The frozen encoders give V (visual crop), T (tactile frame) and L (the label's text embedding)
for every training pair; the retriever learns Q(V, T) close to L with the paper's losses
(eqs. 6-9, weights from `RetrieverLossConfig`). The paper trains 60 epochs at batch 256, lr 3e-4,
weight decay 0.02 with 10 warm-up epochs; on embeddings this small model converges in far fewer
epochs, so `epochs` is scaled down (the report says how many were run). A collapse diagnostic
(mean pairwise cosine and effective rank of a fixed batch of queries) is logged every epoch.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch

from ratouch.checkpoint import save_checkpoint
from ratouch.errors import ConfigError
from ratouch.model.loss import RetrieverLossConfig, retriever_loss
from ratouch.model.retriever import (
    RetrieverConfig,
    TactileGuidedRetriever,
    collapse_stats,
)
from ratouch.train.encoders import tactile_batch

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RetrieverTrainConfig:
    epochs: int = 12
    warmup_epochs: int = 2
    batch: int = 256
    lr: float = 3e-4
    weight_decay: float = 0.02
    seed: int = 0
    val_fraction: float = 0.1

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch < 2:
            raise ConfigError(f"epochs={self.epochs} and batch={self.batch} must be >= 1 / >= 2")
        if not 0 <= self.warmup_epochs < self.epochs:
            raise ConfigError(f"warmup_epochs={self.warmup_epochs} must lie in [0, epochs)")
        if not 0 < self.val_fraction < 0.5:
            raise ConfigError(f"val_fraction={self.val_fraction} must lie in (0, 0.5)")


def paired_embeddings(encoders, data: dict, batch: int = 512) -> dict[str, np.ndarray]:
    """V, T, L of the cached training pairs (see `ratouch.train.encoders.training_data`).

    Half of the tactile inputs (a seeded draw) are the difference from the sensor's
    background and half are not, as queries come with and without one."""
    encoders.eval()
    vs, ts = [], []
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for k in range(0, len(data["labels"]), batch):
            idx = torch.arange(k, min(k + batch, len(data["labels"])))
            crops = torch.from_numpy(data["crops"][k:k + batch]).float().div(255).sub(0.5).div(0.25)
            prior = (torch.from_numpy(data["prior_crops"][k:k + batch].astype(np.float32))
                     if "prior_crops" in data else None)
            vs.append(encoders.embed_vision(crops.permute(0, 3, 1, 2), prior).numpy())
            ts.append(encoders.embed_tactile(tactile_batch(data, idx, gen)).numpy())
    return {"V": np.concatenate(vs), "T": np.concatenate(ts),
            "L": encoders.encode_text(list(data["labels"]))}


def _evaluate(model: TactileGuidedRetriever, V, T, L) -> dict[str, float]:
    model.eval()
    with torch.no_grad():
        q = model(V, T).query
    return {"cos_q_l": float((q * L).sum(1).mean()), "cos_v_l": float((V * L).sum(1).mean()),
            "cos_t_l": float((T * L).sum(1).mean()), **collapse_stats(q[:512])}


def train_retriever(emb: dict[str, np.ndarray], cfg: RetrieverConfig,
                    loss_cfg: RetrieverLossConfig, tc: RetrieverTrainConfig,
                    out: str | None = None, meta: dict | None = None
                    ) -> tuple[TactileGuidedRetriever, dict]:
    """Train, evaluate on a held-out part of the pairs, save (optional), return frozen."""
    torch.manual_seed(tc.seed)
    t0 = time.perf_counter()
    V, T, L = (torch.from_numpy(np.asarray(emb[k], np.float32)) for k in ("V", "T", "L"))
    n = len(V)
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(tc.seed))
    n_val = max(1, int(n * tc.val_fraction))
    val, tr = perm[:n_val], perm[n_val:]
    model = TactileGuidedRetriever(cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    steps_per_epoch = math.ceil(len(tr) / tc.batch)
    total, warm = tc.epochs * steps_per_epoch, tc.warmup_epochs * steps_per_epoch

    def lr_at(step: int) -> float:  # linear warm-up, then cosine decay, as the paper's schedule
        if step < warm:
            return (step + 1) / warm
        return 0.5 * (1 + math.cos(math.pi * (step - warm) / max(1, total - warm)))

    sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_at)
    history = []
    gen = torch.Generator().manual_seed(tc.seed + 1)
    for epoch in range(tc.epochs):
        model.train()
        order = tr[torch.randperm(len(tr), generator=gen)]
        terms: dict[str, float] = {}
        for k in range(0, len(order), tc.batch):
            idx = order[k:k + tc.batch]
            if len(idx) < 2:
                continue
            loss, parts = retriever_loss(model(V[idx], T[idx]), L[idx], T[idx], V[idx], loss_cfg)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            for name, value in parts.items():
                terms[name] = terms.get(name, 0.0) + value / steps_per_epoch
        diag = _evaluate(model, V[val], T[val], L[val])
        history.append({"epoch": epoch, **{k: round(v, 4) for k, v in terms.items()},
                        **{f"val_{k}": round(v, 4) for k, v in diag.items()}})
        log.info("retriever epoch %d: %s", epoch, history[-1])
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    report = {"epochs": tc.epochs, "paper_epochs": 60, "n_train": len(tr), "n_val": n_val,
              "seconds": round(time.perf_counter() - t0, 1), "final": history[-1],
              "config": asdict(cfg), "loss": asdict(loss_cfg), "train": asdict(tc)}
    if out is not None:
        save_checkpoint(out, model.state_dict(), {"kind": "tactile_guided_retriever",
                                                  **asdict(cfg)},
                        meta={**(meta or {}), "report": report, "history": history})
    return model, report

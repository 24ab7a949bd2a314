"""Training objectives of the Tactile-Guided Retriever (paper §3.4, eqs. 6-9).

    L_align     = (1 - sim(Q, L)) + λ1 (1 - sim(Q, T))                         (eq. 6)
    L_stability = λ2 L_mse + λ3 (L_div + L_nce)                                (eq. 7)
    L_mse       = ||Q_i - L_i||^2,   L_div = Σ_{j≠i} C_ij,   C = Q Qᵀ          (eq. 7)
    L_nce       = -log( exp(sim(Q_i, T_i)/τ) / Σ_j exp(sim(Q_i, T_j)/τ) )      (eq. 8)
    L           = L_align + L_stability                                        (eq. 9)

Q is the retriever's unit-norm query, L the ground-truth (TVL) text embedding of the sample's
tactile description, T its tactile embedding, sim the cosine similarity. Reductions over the
batch: the paper writes sums; this module takes means (over the batch for the cosine and InfoNCE
terms, over all B·D elements for L_mse, over the B(B-1) off-diagonal pairs for L_div), matching
the words "mean squared error" and the released code, so that λ1-λ3 keep their meaning at any
batch size.

The paper's Fig. 5 compares two strategies, `align` (L_align alone) and `full` (eq. 9). Two
ablations that are not in the paper split the stability loss into its parts: `align_mse`
(L_align + λ2 L_mse) and `align_div_nce` (L_align + λ3 (L_div + L_nce)).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from ratouch.errors import ConfigError, DataError
from ratouch.model.retriever import RetrieverOutput

STRATEGIES: tuple[str, ...] = ("align", "align_mse", "align_div_nce", "full")


@dataclass
class RetrieverLossConfig:
    """Weights and strategy of the retriever loss.

    Attributes:
        lambda1: weight of the tactile alignment term (1 - sim(Q, T)) in eq. 6 (paper: 0.2).
        lambda2: weight of L_mse in eq. 7 (paper: 10).
        lambda3: weight of (L_div + L_nce) in eq. 7 (paper: 0.1).
        temperature: τ of the InfoNCE term, eq. 8.
        strategy: which terms enter the total: `align` (Fig. 5a), `full` (eq. 9, Fig. 5b), or
            the ablations `align_mse` and `align_div_nce`.
    """

    lambda1: float = 0.2
    lambda2: float = 10.0
    lambda3: float = 0.1
    temperature: float = 0.07
    strategy: str = "full"

    def __post_init__(self) -> None:
        for name in ("lambda1", "lambda2", "lambda3"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                raise ConfigError(f"RetrieverLossConfig.{name} must be a number >= 0, "
                                  f"got {value!r}")
        t = self.temperature
        if not isinstance(t, (int, float)) or isinstance(t, bool) or not t > 0:
            raise ConfigError(f"RetrieverLossConfig.temperature must be > 0, got {t!r}")
        if self.strategy not in STRATEGIES:
            raise ConfigError(f"RetrieverLossConfig.strategy must be one of {STRATEGIES}, "
                              f"got {self.strategy!r}")


def alignment_terms(Q: Tensor, L: Tensor, T: Tensor) -> tuple[Tensor, Tensor]:
    """The two parts of eq. 6, batch means: (1 - sim(Q, L)) and (1 - sim(Q, T))."""
    text = (1 - F.cosine_similarity(Q, L, dim=-1)).mean()
    tactile = (1 - F.cosine_similarity(Q, T, dim=-1)).mean()
    return text, tactile


def mse_term(Q: Tensor, L: Tensor) -> Tensor:
    """L_mse of eq. 7: squared error between query and ground-truth text embedding.

    Mean over the B·D elements (the paper's "mean squared error"; the released code's
    `F.mse_loss`). Q is unit-norm, so L should be too for the minimum to be reachable.
    """
    return F.mse_loss(Q, L)


def diversity_term(Q: Tensor) -> Tensor:
    """L_div of eq. 7: mean off-diagonal entry of the query Gram matrix C = Q Qᵀ.

    Signed, as printed (C_ij, not C_ij²): Σ_{i≠j} C_ij = ||Σ_i Q_i||² - B for unit queries, so
    minimising it pushes the batch's mean query towards zero, away from a shared mean embedding.
    Zero for a batch of one.
    """
    b = Q.shape[0]
    if b < 2:
        return Q.sum() * 0.0
    C = Q @ Q.T  # (B, B)
    return (C.sum() - C.diagonal().sum()) / (b * (b - 1))


def infonce_term(Q: Tensor, T: Tensor, temperature: float) -> Tensor:
    """L_nce of eq. 8: InfoNCE of each query against the batch's tactile embeddings.

    One direction (query i must pick its own T_i among the batch's), cosine over τ, batch mean.
    """
    logits = F.normalize(Q, dim=-1) @ F.normalize(T, dim=-1).T / temperature  # (B, B)
    labels = torch.arange(Q.shape[0], device=Q.device)
    return F.cross_entropy(logits, labels)


def retriever_loss(out: RetrieverOutput | Tensor, L: Tensor, T: Tensor, V: Tensor,
                   cfg: RetrieverLossConfig | None = None) -> tuple[Tensor, dict[str, float]]:
    """The retriever's training loss (eq. 9, or the strategy `cfg.strategy` selects).

    Args:
        out: the retriever's output, or its (B, D) query tensor.
        L: (B, D) ground-truth text embeddings.
        T: (B, D) tactile embeddings.
        V: (B, D) visual embeddings; not in the loss, only logged (cos_q_v) to show how far the
            query moved from the image.
        cfg: weights and strategy; the paper's values when omitted.

    Returns:
        The scalar total to backpropagate, and a dict of floats for logging: every raw term
        (`align_text`, `align_tactile`, `mse`, `div`, `nce`, whatever the strategy), the weighted
        `align` and `stability` parts as they enter the total (stability 0 under `align`),
        `total`, and the mean cosines `cos_q_l`, `cos_q_t`, `cos_q_v`.
    """
    cfg = cfg or RetrieverLossConfig()
    Q = out.query if isinstance(out, RetrieverOutput) else out  # (B, D)
    if Q.dim() != 2 or Q.shape[0] == 0:
        raise DataError(f"query must have shape (B, D) with B >= 1, got {tuple(Q.shape)}")
    for name, x in (("L", L), ("T", T), ("V", V)):
        if x.shape != Q.shape:
            raise DataError(f"{name} must have the query's shape {tuple(Q.shape)}, "
                            f"got {tuple(x.shape)}")

    text, tactile = alignment_terms(Q, L, T)
    align = text + cfg.lambda1 * tactile  # eq. 6
    mse, div, nce = mse_term(Q, L), diversity_term(Q), infonce_term(Q, T, cfg.temperature)
    stability = {
        "align": Q.sum() * 0.0,
        "align_mse": cfg.lambda2 * mse,
        "align_div_nce": cfg.lambda3 * (div + nce),
        "full": cfg.lambda2 * mse + cfg.lambda3 * (div + nce),  # eq. 7
    }[cfg.strategy]
    total = align + stability  # eq. 9

    with torch.no_grad():
        cos_v = F.cosine_similarity(Q, V, dim=-1).mean()
    logs = {
        "total": total.item(), "align": align.item(), "stability": stability.item(),
        "align_text": text.item(), "align_tactile": tactile.item(),
        "mse": mse.item(), "div": div.item(), "nce": nce.item(),
        "cos_q_l": 1.0 - text.item(), "cos_q_t": 1.0 - tactile.item(), "cos_q_v": cos_v.item(),
    }
    return total, logs

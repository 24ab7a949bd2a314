"""Tactile-Guided Retriever: the joint visuo-tactile retrieval query (paper §3.2, eqs. 1-3).

The module turns a visual embedding V and a tactile embedding T (frozen TVL encoder outputs) into
a unit-norm query Q that is matched by cosine against the text embeddings of the external corpus:

    V' = V + SA(V, V, V)                                   (eq. 1)
    T' = T + SA(T, T, T)                                   (eq. 1)
    q  = CA(T', V', V')                                    (eq. 2, no residual in the paper)
    Q  = q + Linear(q),  then L2-normalised                (eq. 3; cosine retrieval)

A caveat the paper does not mention: V and T are single vectors (R^D), i.e. one-token sequences.
Softmax attention over a single key gives that key weight 1 whatever the query is, so with
one-token V the cross-attention output is out_proj(v_proj(V')) and Q does not depend on T at
all. The authors' released code (AIM-SKKU/RA-Touch, `tg_retriever.py`) has the same property.
`RetrieverConfig.cross_residual` (default False, the paper as printed) adds the usual
decoder-style residual, q = T' + CA(T', V', V'), which lets the tactile path reach Q; with V given
as a multi-token sequence (B, N, D), N > 1, T steers the attention weights in either mode.

The module only maps embeddings to queries: searching the corpus is the index's job and the
training losses live in `ratouch.model.loss`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ratouch.errors import ConfigError, DataError


@dataclass
class RetrieverConfig:
    """Architecture of the Tactile-Guided Retriever.

    Attributes:
        dim: embedding width D of V, T and the query (768 in the paper for TVL ViT encoders).
        heads: attention heads of every SA/CA block (8 in the paper); must divide `dim`.
        dropout: attention-weight dropout inside the attention blocks.
        cross_residual: False follows eq. 2 as printed (q = CA(T', V', V')); True uses
            q = T' + CA(T', V', V'). With one-token V, only True lets T influence the query
            (see the module docstring).
    """

    dim: int = 384
    heads: int = 8
    dropout: float = 0.0
    cross_residual: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.dim, int) or self.dim <= 0:
            raise ConfigError(f"RetrieverConfig.dim must be a positive int, got {self.dim!r}")
        if not isinstance(self.heads, int) or self.heads <= 0:
            raise ConfigError(f"RetrieverConfig.heads must be a positive int, got {self.heads!r}")
        if self.dim % self.heads != 0:
            raise ConfigError(f"RetrieverConfig.dim={self.dim} must be divisible by "
                              f"heads={self.heads}")
        if not 0.0 <= float(self.dropout) < 1.0:
            raise ConfigError(f"RetrieverConfig.dropout must be in [0, 1), got {self.dropout!r}")
        if not isinstance(self.cross_residual, bool):
            raise ConfigError("RetrieverConfig.cross_residual must be a bool, got "
                              f"{self.cross_residual!r}")


class RetrieverOutput(NamedTuple):
    """What the retriever returns.

    Attributes:
        query: (B, D) final query Q, L2-normalised; use it for cosine retrieval.
        q: (B, D) cross-attention output q of eq. 2 (pooled over tactile tokens), before eq. 3.
        v_prime: V' of eq. 1, same shape as the V given ((B, D) or (B, N, D)).
        t_prime: T' of eq. 1, same shape as the T given ((B, D) or (B, N, D)).
    """

    query: Tensor
    q: Tensor
    v_prime: Tensor
    t_prime: Tensor


def _as_tokens(x: Tensor, name: str, dim: int) -> Tensor:
    """(B, D) -> (B, 1, D); (B, N, D) unchanged; anything else raises DataError."""
    if x.dim() == 2:
        x = x.unsqueeze(1)  # (B, 1, D)
    if x.dim() != 3 or x.shape[-1] != dim or x.shape[1] == 0:
        raise DataError(f"{name} must have shape (B, {dim}) or (B, N, {dim}) with N >= 1, "
                        f"got {tuple(x.shape)}")
    return x


class TactileGuidedRetriever(nn.Module):
    """Joint visuo-tactile query for query-to-text retrieval (eqs. 1-3).

    Args:
        cfg: architecture; the defaults of `RetrieverConfig` when omitted.
    """

    def __init__(self, cfg: RetrieverConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg or RetrieverConfig()
        d, h, p = self.cfg.dim, self.cfg.heads, self.cfg.dropout
        self.vis_sa = nn.MultiheadAttention(d, h, dropout=p, batch_first=True)
        self.tac_sa = nn.MultiheadAttention(d, h, dropout=p, batch_first=True)
        self.cross = nn.MultiheadAttention(d, h, dropout=p, batch_first=True)
        self.proj = nn.Linear(d, d)

    def forward(self, V: Tensor, T: Tensor) -> RetrieverOutput:
        """Builds the retrieval query.

        Args:
            V: visual embedding, (B, D), or a visual token sequence (B, Nv, D).
            T: tactile embedding, (B, D), or a tactile token sequence (B, Nt, D).

        Returns:
            A `RetrieverOutput`; `query` is (B, D) and unit-norm. With several tactile tokens
            the per-token outputs of eq. 2 are mean-pooled into one query.
        """
        d = self.cfg.dim
        v, t = _as_tokens(V, "V", d), _as_tokens(T, "T", d)  # (B, Nv, D), (B, Nt, D)
        if v.shape[0] != t.shape[0]:
            raise DataError(f"V and T must have the same batch size, got {v.shape[0]} and "
                            f"{t.shape[0]}")
        v_p = v + self.vis_sa(v, v, v, need_weights=False)[0]  # (B, Nv, D)  eq. 1
        t_p = t + self.tac_sa(t, t, t, need_weights=False)[0]  # (B, Nt, D)  eq. 1
        q = self.cross(t_p, v_p, v_p, need_weights=False)[0]  # (B, Nt, D)  eq. 2
        if self.cfg.cross_residual:
            q = t_p + q  # (B, Nt, D)
        q = q.mean(dim=1)  # (B, D)  one query per sample
        query = F.normalize(q + self.proj(q), dim=-1)  # (B, D)  eq. 3, unit norm for cosine
        v_out = v_p.squeeze(1) if V.dim() == 2 else v_p
        t_out = t_p.squeeze(1) if T.dim() == 2 else t_p
        return RetrieverOutput(query=query, q=q, v_prime=v_out, t_prime=t_out)


@torch.no_grad()
def collapse_stats(queries: Tensor) -> dict[str, float]:
    """Collapse diagnostics of a set of queries, to log during retriever training.

    All three are computed on the L2-normalised rows. A collapsed retriever (every query near one
    mean embedding) shows mean cosine near 1, effective rank near 1 and per-dimension std near 0;
    well-spread unit vectors show mean cosine near 0, a large effective rank and a std near
    1/sqrt(D).

    Args:
        queries: (N, D) queries, N >= 2.

    Returns:
        `mean_cosine`: mean pairwise cosine over the N(N-1) off-diagonal pairs;
        `effective_rank`: exp of the Shannon entropy of the singular values normalised to sum 1
        (Roy & Vetterli, 2007), between 1 and min(N, D);
        `mean_dim_std`: std over the N queries of each dimension, averaged over dimensions.
    """
    if queries.dim() != 2 or queries.shape[0] < 2:
        raise DataError(f"queries must have shape (N, D) with N >= 2, got {tuple(queries.shape)}")
    x = F.normalize(queries.detach().double(), dim=-1)  # (N, D)
    n = x.shape[0]
    sim = x @ x.T  # (N, N)
    mean_cos = (sim.sum() - sim.diagonal().sum()) / (n * (n - 1))
    s = torch.linalg.svdvals(x)  # (min(N, D),)
    p = s / s.sum()
    entropy = -(p * torch.log(p.clamp_min(1e-300))).sum()
    return {
        "mean_cosine": float(mean_cos),
        "effective_rank": float(torch.exp(entropy)),
        "mean_dim_std": float(x.std(dim=0).mean()),
    }

"""Neighbour tokens: the second, clearly labelled retrieval arm (not the paper's method).

Where the Texture-Aware Integrator folds the K retrieved neighbours into one additive change
of the prompt (p' = p + δ), this arm hands the decoder each retrieved caption embedding as a
prefix token of its own:

    prefix = [p, W r_l^1, ..., W r_l^K]                          (1 + K tokens of width D')

so the decoder can attend to (and copy from) any neighbour. In training each neighbour token
is zeroed with probability `dropout` (neighbour dropout), so the decoder learns to answer with
fewer neighbours and not to lean on one. It bounds what retrieval can deliver on the world
beside the paper's integrator; it never replaces it (`ratouch eval premise` reports both).

W starts at zero, so training starts from the baseline's answer, as the integrator does.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ratouch.errors import ConfigError

KIND = "neighbour_tokens"


@dataclass
class NeighbourTokensConfig:
    """Attributes:
        dim: width D of the retrieved text embeddings.
        out_dim: width D' of the decoder's input.
        dropout: share of neighbour tokens zeroed in training.
        kind: the saved config's tag (`ratouch.serve.pipeline.integrator_factory` reads it).
    """

    dim: int = 384
    out_dim: int = 256
    dropout: float = 0.3
    kind: str = KIND

    def __post_init__(self) -> None:
        if self.dim < 1 or self.out_dim < 1:
            raise ConfigError(f"dim={self.dim} and out_dim={self.out_dim} must be >= 1")
        if not 0.0 <= self.dropout < 1.0:
            raise ConfigError(f"dropout={self.dropout} must lie in [0, 1)")
        if self.kind != KIND:
            raise ConfigError(f"kind={self.kind!r} must be {KIND!r}")


class NeighbourTokens(nn.Module):
    """(T, Rv, Rl) -> (B, K, D') prefix tokens, one per retrieved caption; see the module
    docstring. `as_tokens` tells the generator to append them to p instead of adding."""

    as_tokens = True

    def __init__(self, cfg: NeighbourTokensConfig):
        super().__init__()
        self.cfg = cfg
        self.proj = nn.Linear(cfg.dim, cfg.out_dim)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)

    def forward(self, T: Tensor, Rv: Tensor, Rl: Tensor) -> Tensor:
        """Args: T (B, D) (unused), Rv (B, K, D) (unused), Rl (B, K, D). Returns (B, K, D')."""
        x = self.proj(Rl)                                             # (B, K, D')
        if self.training and self.cfg.dropout > 0:
            keep = torch.rand(x.shape[0], x.shape[1], 1, device=x.device) >= self.cfg.dropout
            x = x * keep
        return x

"""Texture-Aware Integrator: retrieved context into the visual prompt (paper §3.3, eqs. 4-5).

Given the tactile embedding T and the top-K retrieved image and text embeddings Rv, Rl:

    a^V = CA(T, Rv, Rv),   a^L = CA(T, Rl, Rl)                   (eq. 4, T is the query)
    h   = Linear(a^V + a^L)                                      (D -> D')
    δ   = FFN(h) = h + MLP(h)                                    ("a feedforward network, which
                                                                    has residual connection")
    p'  = p + δ                                                  (eq. 5, done by the caller)

The module returns δ; the caller owns the TVL-LLaMA prompt p and adds it. The paper's Table 5
ablation (image-only, text-only, both) is `IntegratorConfig.use_image` / `use_text`: a disabled
path has no parameters and its input is ignored.

Initialisation: the D->D' Linear and the MLP's output layer start at zero, so δ = 0 exactly and
p' = p at step 0. Training therefore starts from the TVL-LLaMA baseline prompt the (LoRA-tuned)
LLM already understands, instead of adding a random D'-dimensional perturbation to its input
that it must first learn to undo. Gradients still flow at step 0: the FFN's identity path
gives the Linear a non-zero gradient, and the MLP's output layer sees non-zero hidden
activations from its bias.

Differences from the released code (AIM-SKKU/RA-Touch `ta_integrator.py`), where the paper is
silent: no LayerNorm before the MLP (LayerNorm of the zero-initialised h has a 1/sqrt(eps)
gradient), and the MLP widens by `ffn_mult` instead of narrowing to D'/4.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ratouch.errors import ConfigError, DataError


@dataclass
class IntegratorConfig:
    """Architecture of the Texture-Aware Integrator.

    Attributes:
        dim: width D of T and the retrieved embeddings.
        out_dim: width D' of the visual prompt p (4096 for LLaMA-2-7B in the paper).
        heads: heads of each cross-attention; must divide `dim`.
        ffn_mult: hidden width of the FFN's MLP as a multiple of `out_dim`.
        dropout: dropout on attention weights and inside the MLP.
        use_image: attend over the retrieved image embeddings Rv (a^V).
        use_text: attend over the retrieved text embeddings Rl (a^L). At least one must be on.
    """

    dim: int = 384
    out_dim: int = 256
    heads: int = 8
    ffn_mult: int = 4
    dropout: float = 0.0
    use_image: bool = True
    use_text: bool = True

    def __post_init__(self) -> None:
        for name in ("dim", "out_dim", "heads", "ffn_mult"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ConfigError(f"IntegratorConfig.{name} must be a positive int, "
                                  f"got {value!r}")
        if self.dim % self.heads != 0:
            raise ConfigError(f"IntegratorConfig.dim={self.dim} must be divisible by "
                              f"heads={self.heads}")
        if not 0.0 <= float(self.dropout) < 1.0:
            raise ConfigError(f"IntegratorConfig.dropout must be in [0, 1), got {self.dropout!r}")
        for name in ("use_image", "use_text"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"IntegratorConfig.{name} must be a bool, "
                                  f"got {getattr(self, name)!r}")
        if not (self.use_image or self.use_text):
            raise ConfigError("IntegratorConfig: use_image=False and use_text=False leave "
                              "nothing to integrate; enable at least one")


class TextureAwareIntegrator(nn.Module):
    """Cross-attends from T to the retrieved neighbours and returns the prompt delta δ (eq. 5).

    Args:
        cfg: architecture; the defaults of `IntegratorConfig` when omitted.
    """

    def __init__(self, cfg: IntegratorConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg or IntegratorConfig()
        c = self.cfg
        self.image_ca = (nn.MultiheadAttention(c.dim, c.heads, dropout=c.dropout,
                                               batch_first=True) if c.use_image else None)
        self.text_ca = (nn.MultiheadAttention(c.dim, c.heads, dropout=c.dropout,
                                              batch_first=True) if c.use_text else None)
        self.fuse = nn.Linear(c.dim, c.out_dim)
        mlp_in = nn.Linear(c.out_dim, c.ffn_mult * c.out_dim)
        mlp_out = nn.Linear(c.ffn_mult * c.out_dim, c.out_dim)  # made in this order: seeded inits
        self.mlp = nn.Sequential(mlp_in, nn.ReLU(), nn.Dropout(c.dropout), mlp_out)
        # Zero-init: δ = 0 at step 0, so p' = p (see the module docstring).
        for layer in (self.fuse, mlp_out):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)

    def _check(self, t: Tensor, r: Tensor | None, name: str, padding: Tensor | None) -> Tensor:
        """`r`, one path's (B, K, D) neighbours for the (B, 1, D) query `t`, checked.

        Raises:
            DataError: a shape does not match."""
        b, d = t.shape[0], self.cfg.dim
        if r is None or r.dim() != 3 or r.shape[0] != b or r.shape[2] != d or r.shape[1] == 0:
            shape = None if r is None else tuple(r.shape)
            raise DataError(f"{name} must have shape ({b}, K, {d}) with K >= 1, got {shape}")
        if padding is not None and padding.shape != r.shape[:2]:
            raise DataError(f"mask must have shape {tuple(r.shape[:2])} to match {name}, "
                            f"got {tuple(padding.shape)}")
        return r

    def _attend(self, ca: nn.MultiheadAttention, t: Tensor, r: Tensor | None, name: str,
                padding: Tensor | None) -> Tensor:
        """CA(T, R, R) for one path: (B, 1, D) query over (B, K, D) neighbours -> (B, D)."""
        r = self._check(t, r, name, padding)
        return ca(t, r, r, key_padding_mask=padding, need_weights=False)[0].squeeze(1)  # (B, D)

    def _query(self, T: Tensor, mask: Tensor | None
               ) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """T as the attention query (B, 1, D), the key padding (B, K) and the rows without
        any real neighbour (B,), the last two None without a mask."""
        if T.dim() != 2 or T.shape[1] != self.cfg.dim:
            raise DataError(f"T must have shape (B, {self.cfg.dim}), got {tuple(T.shape)}")
        if mask is None:
            return T.unsqueeze(1), None, None
        if mask.dtype != torch.bool or mask.dim() != 2 or mask.shape[0] != T.shape[0]:
            raise DataError(f"mask must be a bool tensor of shape ({T.shape[0]}, K), "
                            f"got {mask.dtype} {tuple(mask.shape)}")
        empty = ~mask.any(dim=1)  # (B,)
        # Rows with no real neighbour would softmax over nothing (NaN); let them attend to
        # everything here and zero their delta (and weights) afterwards.
        padding = ~(mask | empty.unsqueeze(1))  # (B, K)  True = ignore (torch convention)
        return T.unsqueeze(1), padding, empty

    def forward(self, T: Tensor, Rv: Tensor | None, Rl: Tensor | None,
                mask: Tensor | None = None) -> Tensor:
        """Computes the prompt delta δ; the caller forms p' = p + δ.

        Args:
            T: (B, D) tactile embeddings (the attention query).
            Rv: (B, K, D) retrieved image embeddings; may be None when `use_image` is False.
            Rl: (B, K, D) retrieved text embeddings; may be None when `use_text` is False.
            mask: optional (B, K) bool, True where a neighbour is real and False where it is
                padding or missing; False neighbours get no attention. A sample with no real
                neighbour gets δ = 0 (its prompt stays the baseline).

        Returns:
            (B, out_dim) delta δ.
        """
        t, padding, empty = self._query(T, mask)
        attended = []  # a^V and a^L, (B, D) each, whichever paths are on (at least one)
        if self.image_ca is not None:
            attended.append(self._attend(self.image_ca, t, Rv, "Rv", padding))
        if self.text_ca is not None:
            attended.append(self._attend(self.text_ca, t, Rl, "Rl", padding))
        h = self.fuse(sum(attended[1:], attended[0]))  # (B, D')
        delta = h + self.mlp(h)  # (B, D')  FFN with its residual, eq. 5
        if empty is not None:
            delta = delta.masked_fill(empty.unsqueeze(1), 0.0)  # (B, D')
        return delta

    def attention(self, T: Tensor, Rv: Tensor | None, Rl: Tensor | None,
                  mask: Tensor | None = None) -> dict[str, Tensor]:
        """How much each retrieved neighbour weighs in eq. 4: the cross-attention weights of T
        over the K images ("image") and the K texts ("text"), averaged over heads.

        Args: as in `forward`.

        Returns:
            {"image": (B, K), "text": (B, K)} (a disabled path is absent); each row sums to 1
            over its real neighbours, 0 on masked ones (all 0 for a row without any).
        """
        t, padding, empty = self._query(T, mask)
        out = {}
        for name, ca, r in (("image", self.image_ca, Rv), ("text", self.text_ca, Rl)):
            if ca is None:
                continue
            r = self._check(t, r, "Rv" if name == "image" else "Rl", padding)
            w = ca(t, r, r, key_padding_mask=padding, need_weights=True,
                   average_attn_weights=True)[1].squeeze(1)  # (B, K)
            out[name] = w if empty is None else w.masked_fill(empty.unsqueeze(1), 0.0)
        return out


class SumIntegrator(nn.Module):
    """Table 2's "retriever without integrator" row: the neighbours are summed and one Linear
    matches the width (the paper: "we apply a simple summation to integrate retrieval
    information and linear operation to match the feature dimensions").

        δ = Linear(mean_k Rv_k + mean_k Rl_k)      (D -> D'), zero-initialised like the
                                                      integrator, so p' = p at step 0.
    """

    def __init__(self, dim: int, out_dim: int) -> None:
        super().__init__()
        self.cfg = IntegratorConfig(dim=dim, out_dim=out_dim)
        self.proj = nn.Linear(dim, out_dim)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)

    def forward(self, T: Tensor, Rv: Tensor, Rl: Tensor, mask: Tensor | None = None) -> Tensor:
        """Args as `TextureAwareIntegrator.forward` (T is unused); returns (B, D') δ."""
        if Rv is None or Rl is None or Rv.dim() != 3 or Rv.shape != Rl.shape:
            raise DataError("SumIntegrator needs Rv and Rl of the same shape (B, K, D)")
        return self.proj(Rv.mean(1) + Rl.mean(1))  # (B, D')

"""Neighbours as text: the third retrieval arm, plain retrieval-augmented generation (not the
paper's method).

Where the Texture-Aware Integrator folds the K retrieved neighbours into one additive change
of the prompt (p' = p + δ) and the neighbour-token arm projects each retrieved caption
*embedding* into a token, this arm writes the retrieved captions themselves into the prompt:
each neighbour's caption, word by word, followed by a full stop, embedded with the decoder's
own (frozen) word embeddings and placed after p:

    prefix = [p, "smooth", ",", "hard", ".", "soft", ",", ... "."]

It has no trainable part: trained like RA-Touch's stage 2 (fresh LoRA on the same stage-1
model, the same budget and neighbours), the decoder learns to read the words, so it answers
the first question a researcher asks of the paper (is the integrator better than putting the
neighbours' text in the prompt?) with everything else equal.

The generator's interface hands an arm the neighbours' *embeddings* (Rv, Rl); the arm turns
each Rl row back into its corpus entry by exact match against the corpus's own text embeddings
(a frozen copy, `keys`), then into that entry's word ids (`ids`). A zero row (the zeroed-
retrieval control) carries no words. Slots left empty are zero vectors, which a LLaMA-style
decoder (RMSNorm, no biases) carries through every layer as zeros; they come first, so that
the words of every sample end right before the text prompt.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from torch import Tensor, nn

from ratouch.errors import ConfigError

KIND = "neighbour_text"
#: Tokens kept of one neighbour's caption (five adjectives, four commas, the full stop).
WORDS = 10


@dataclass
class NeighbourTextConfig:
    """Attributes:
        dim: width D of the retrieved text embeddings (the keys).
        out_dim: width D' of the decoder's input (its word embeddings).
        entries: how many corpus entries the keys hold.
        vocab: rows kept of the decoder's word-embedding table (those the captions use).
        words: tokens kept of one neighbour's caption.
        kind: the saved config's tag (`ratouch.serve.pipeline.integrator_factory` reads it).
    """

    dim: int = 384
    out_dim: int = 256
    entries: int = 1
    vocab: int = 1
    words: int = WORDS
    kind: str = KIND

    def __post_init__(self) -> None:
        for name in ("dim", "out_dim", "entries", "vocab", "words"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"NeighbourTextConfig.{name} must be a positive integer, "
                                  f"got {v!r}")
        if self.kind != KIND:
            raise ConfigError(f"kind={self.kind!r} must be {KIND!r}")


class NeighbourText(nn.Module):
    """(T, Rv, Rl) -> (B, K * words, D') the neighbours' captions as word embeddings; see the
    module docstring. `as_tokens` tells the generator to append them to p."""

    as_tokens = True
    keys: Tensor
    ids: Tensor
    table: Tensor

    def __init__(self, cfg: NeighbourTextConfig):
        super().__init__()
        self.cfg = cfg
        # all frozen and saved with the checkpoint, so that a trained arm reads alone
        self.register_buffer("keys", torch.zeros(cfg.entries, cfg.dim))
        self.register_buffer("ids", torch.full((cfg.entries, cfg.words), -1, dtype=torch.long))
        self.register_buffer("table", torch.zeros(cfg.vocab, cfg.out_dim))

    @classmethod
    def build(cls, captions: Sequence[str], keys: np.ndarray, decoder,
              words: int | None = None) -> NeighbourText:
        """The arm for a corpus: its captions (entry order), their text embeddings `keys`
        (N, D) as the retrieval side returns them, and the decoder whose tokenizer and word
        embeddings write them. `words`: tokens kept of one caption, its full stop included
        (default: the longest caption's, so that none is cut: 10 for the small decoder's
        word-level tokenizer, more for a sub-word one).

        Only the rows of the decoder's embedding table that the captions use are kept (a
        pretrained model's table has ~50k rows; the corpus's captions use about a hundred)."""
        keys = np.array(keys, np.float32)  # a copy: the corpus's arrays are memory-mapped
        if keys.ndim != 2 or len(keys) != len(captions):
            raise ConfigError(f"keys must be (N={len(captions)}, D), got {keys.shape}")
        stop = decoder.tokenizer.encode(".")
        encoded = [decoder.tokenizer.encode(c) for c in captions]
        if words is None:
            words = max((len(e) for e in encoded), default=0) + len(stop)
        if words <= len(stop):
            raise ConfigError(f"words={words} leaves no room for a caption before its "
                              f"{len(stop)} full-stop token(s)")
        encoded = [e[:words - len(stop)] + stop for e in encoded]
        used = sorted({t for e in encoded for t in e})
        row = {t: i for i, t in enumerate(used)}
        table = decoder.embedding.weight.detach().float()[torch.tensor(used, dtype=torch.long)]
        arm = cls(NeighbourTextConfig(dim=keys.shape[1], out_dim=table.shape[1],
                                      entries=len(captions), vocab=len(used), words=words))
        ids = arm.ids.clone()
        for i, e in enumerate(encoded):
            ids[i, :len(e)] = torch.tensor([row[t] for t in e], dtype=torch.long)
        arm.ids.copy_(ids)
        arm.keys.copy_(torch.from_numpy(keys))
        arm.table.copy_(table)
        return arm

    def entries(self, Rl: Tensor) -> Tensor:
        """(B, K) corpus entry of each row of Rl (B, K, D) by nearest key; -1 for a zero row."""
        flat = Rl.reshape(-1, Rl.shape[-1]).float()
        keys = self.keys.float()
        d2 = (keys * keys).sum(1)[None, :] - 2 * flat @ keys.T        # (B*K, N) + const
        out = d2.argmin(1)
        out[flat.abs().sum(1) == 0] = -1
        return out.view(Rl.shape[:-1])

    def forward(self, T: Tensor, Rv: Tensor, Rl: Tensor) -> Tensor:
        """Args: T (B, D) (unused), Rv (B, K, D) (unused), Rl (B, K, D).
        Returns (B, K * words, D'): empty slots (zeros) first, then the captions in rank order."""
        entry = self.entries(Rl)                                      # (B, K)
        ids = torch.where(entry[..., None] >= 0, self.ids[entry.clamp_min(0)],
                          torch.full_like(self.ids[:1], -1))          # (B, K, words)
        ids = ids.reshape(ids.shape[0], -1)                           # (B, K * words)
        order = torch.argsort((ids >= 0).to(torch.int8), dim=1, stable=True)
        ids = torch.gather(ids, 1, order)                             # empty slots first
        x = self.table[ids.clamp_min(0)]                              # (B, K * words, D')
        return x * (ids >= 0).unsqueeze(-1).to(x.dtype)

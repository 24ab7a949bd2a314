# TVL encoders: a frozen OpenCLIP model for RGB images and text plus a timm ViT tactile
# encoder whose classification head maps straight into the CLIP embedding space.
#
# The model layout and the checkpoint layout follow Max-Fu/tvl (tvl_enc/tvl.py and
# tvl_enc/util/misc.py), the public code of "A Touch, Vision, and Language Dataset for
# Multimodal Alignment" (Fu et al., 2024), released under the Apache License 2.0 (the
# repository README says so). In that code:
#   * the CLIP model is OpenCLIP "ViT-L-14" (pretrained "datacomp_xl_s13b_b90k"); images and
#     texts are embedded with `encode_image(..., normalize=True)` / `encode_text(...)`;
#   * the tactile encoder is `timm.create_model(<vit_{tiny,small,base}_patch16_224>,
#     pretrained=False, num_classes=clip.transformer.width, global_pool="avg")`, i.e. a ViT
#     with mean pooling, `fc_norm` and a linear `head` of width 768 for ViT-L-14 (equal to the
#     CLIP embedding dimension); its output is divided by its L2 norm;
#   * the saved checkpoint is `{"model": state_dict, "optimizer": ..., "epoch": ...,
#     "scaler": ..., "args": argparse.Namespace}` where `TVL.state_dict()` drops every key
#     containing "clip", so "model" holds "tactile_encoder.<timm ViT keys>", "logit_scale"
#     (and "modality_heads.*" only for the non-default common-latent-dim variant).
# The code below is an independent implementation of that layout.
"""Load and run the TVL encoders (OpenCLIP ViT-L-14 + TVL tactile ViT) from local files.

Nothing is downloaded: the OpenCLIP model is built from its architecture config with random
weights and then filled from a local checkpoint file; the tactile ViT is built with
``pretrained=False`` and filled from a local ``tvl_enc_vit*.pth``. Checkpoints are read with
``torch.load(..., weights_only=True)`` (or safetensors), so no pickled code is executed.

Example:
    >>> cfg = TVLConfig(clip_arch="ViT-L-14", tactile_arch="tiny")
    >>> enc = load_tvl("open_clip_model.safetensors", "tvl_enc_vittiny.pth", cfg)
    >>> enc.encode_tactile([frame]).shape
    (1, 768)
"""

from __future__ import annotations

import contextlib
import difflib
import logging
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ratouch.checkpoint import (
    KEYS_SHOWN,
    check_state,
    describe_keys,
    load_into,
    read_foreign_weights,
)
from ratouch.encoders.tvl_input import CLIP_MEAN, CLIP_STD, clip_rgb_tensor, tvl_tactile_tensor
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.images import as_image_list
from ratouch.threads import parse_device

log = logging.getLogger(__name__)

#: The tactile ViTs TVL trains, with their token width (embed dim).
TACTILE_ARCHS: dict[str, int] = {
    "vit_tiny_patch16_224": 192,
    "vit_small_patch16_224": 384,
    "vit_base_patch16_224": 768,
}
_EMBED_TO_ARCH = {width: arch for arch, width in TACTILE_ARCHS.items()}
#: Short names, as in TVL's checkpoint file names (tvl_enc_vittiny.pth, ...).
_SHORT = {"vit_tiny_patch16_224": "vittiny", "vit_small_patch16_224": "vits",
          "vit_base_patch16_224": "vitb"}
_ALIASES: dict[str, str] = {}
for _arch, _names in {
    "vit_tiny_patch16_224": ("tiny", "ti", "t", "vittiny", "vit_tiny", "vit-tiny", "vitti"),
    "vit_small_patch16_224": ("s", "small", "vits", "vit_small", "vit-small", "vit_s"),
    "vit_base_patch16_224": ("b", "base", "vitb", "vit_base", "vit-base", "vit_b"),
}.items():
    _ALIASES[_arch] = _arch
    for _name in _names:
        _ALIASES[_name] = _arch

TACTILE_PREFIX = "tactile_encoder."
DEFAULT_BATCH_SIZE = 32
#: The precisions the towers' forward can run in (`TVLConfig.precision`).
PRECISIONS = ("fp32", "bf16")


# --------------------------------------------------------------------------- config


def resolve_tactile_arch(name: str) -> str:
    """Map a tactile architecture name or alias ("tiny"/"s"/"b", "vittiny", ...) to its timm name.

    Args:
        name: A timm name from :data:`TACTILE_ARCHS` or an alias.

    Returns:
        The timm model name.

    Raises:
        ConfigError: If the name is unknown.
    """
    if isinstance(name, str):
        arch = _ALIASES.get(name.strip().lower())
        if arch is not None:
            return arch
    raise ConfigError(
        f"unknown tactile_arch {name!r}; use one of {sorted(TACTILE_ARCHS)} "
        "or the aliases 'tiny', 's', 'b'"
    )


@dataclass(frozen=True)
class TVLConfig:
    """Which TVL encoders to build.

    Attributes:
        clip_arch: An OpenCLIP model config name (``open_clip.list_models()``, including
            configs registered with ``open_clip.add_model_config``). TVL uses "ViT-L-14".
        tactile_arch: "vit_tiny_patch16_224", "vit_small_patch16_224" or
            "vit_base_patch16_224"; the aliases "tiny"/"s"/"b" (and "vittiny"/"vits"/"vitb",
            "small", "base") are normalised to those.
        dim: The shared embedding dimension: CLIP's ``embed_dim`` (768 for ViT-L-14), which
            the tactile head must output.
        subtract_background: Whether the tactile encoder was trained on background-subtracted
            frames (TVL's ``--subtract_background background``). If True, ``encode_tactile``
            needs a background per frame; if False (TVL's released encoders), backgrounds
            passed to ``encode_tactile`` are ignored.
        batch_size: Default batch size of the ``encode_*`` methods.
        precision: "fp32" (default: the towers as trained) or "bf16": their forward under
            bfloat16 autocast, for a GPU. On an H200 ViT-L-14's forward ran 6.7x faster and
            whole image calls 2.3-2.4x (their preprocessing stays on the CPU); the rows, still
            float32, were within cosine 0.99997 of fp32's on random weights
            (docs/performance.md, "On a GPU"; `scripts/device_check.py --precision bf16`).
    """

    clip_arch: str = "ViT-L-14"
    tactile_arch: str = "vit_tiny_patch16_224"
    dim: int = 768
    subtract_background: bool = False
    batch_size: int = DEFAULT_BATCH_SIZE
    precision: str = "fp32"

    def __post_init__(self) -> None:
        if not isinstance(self.clip_arch, str) or not self.clip_arch.strip():
            raise ConfigError(f"clip_arch must be a non-empty OpenCLIP model name, "
                              f"got {self.clip_arch!r}")
        if self.clip_arch.startswith(("hf-hub:", "local-dir:")):
            raise ConfigError(
                f"clip_arch {self.clip_arch!r}: only OpenCLIP config names are supported "
                "(hf-hub:/local-dir: names would fetch remote configs); register a local config "
                "with open_clip.add_model_config instead"
            )
        object.__setattr__(self, "tactile_arch", resolve_tactile_arch(self.tactile_arch))
        if isinstance(self.dim, bool) or not isinstance(self.dim, int) or self.dim < 1:
            raise ConfigError(f"dim must be a positive integer, got {self.dim!r}")
        if not isinstance(self.subtract_background, bool):
            raise ConfigError(f"subtract_background must be True or False, "
                              f"got {self.subtract_background!r}")
        if (isinstance(self.batch_size, bool) or not isinstance(self.batch_size, int)
                or self.batch_size < 1):
            raise ConfigError(f"batch_size must be a positive integer, got {self.batch_size!r}")
        if self.precision not in PRECISIONS:
            raise ConfigError(f"precision must be one of {', '.join(PRECISIONS)}, "
                              f"got {self.precision!r}")

    @property
    def name(self) -> str:
        """Encoder-set name: "tvl-vittiny" etc. for ViT-L-14, else "tvl-<short>-<clip_arch>"."""
        short = _SHORT[self.tactile_arch]
        return f"tvl-{short}" if self.clip_arch == "ViT-L-14" else f"tvl-{short}-{self.clip_arch}"


# --------------------------------------------------------------------------- encoders


class OpenCLIPModel(Protocol):
    """What `TVLEncoders` uses of an OpenCLIP model."""

    visual: nn.Module

    def encode_image(self, image: torch.Tensor) -> torch.Tensor: ...

    def encode_text(self, text: torch.Tensor) -> torch.Tensor: ...


class TVLEncoders(nn.Module):
    """The TVL encoder set: OpenCLIP for images and text, a timm ViT for touch.

    All ``encode_*`` methods run in eval mode under ``torch.no_grad``, in batches, and return
    ``float32`` numpy arrays of shape ``(N, dim)`` whose rows have unit L2 norm.

    Attributes:
        backend: Always "tvl".
        name: The encoder-set name (see :attr:`TVLConfig.name`).
        dim: The embedding dimension.
        cfg: The :class:`TVLConfig`.
        clip: The OpenCLIP model.
        tactile: The timm tactile ViT.
        image_size: Side length of the CLIP input images.
        tactile_size: Side length of the tactile input images.
        weights_fingerprint: What identifies the loaded checkpoint files (set by
            ``create_model``; None where unknown).
    """

    backend = "tvl"
    weights_fingerprint: str | None = None

    def __init__(self, clip_model: OpenCLIPModel, tactile_model: nn.Module,
                 tokenizer: Callable[[list[str]], torch.Tensor], cfg: TVLConfig) -> None:
        """Wrap already-loaded models; use :func:`load_tvl` to build one from files.

        Args:
            clip_model: An OpenCLIP model (``encode_image`` / ``encode_text``).
            tactile_model: A timm ViT whose head outputs ``cfg.dim`` features.
            tokenizer: The OpenCLIP tokenizer of ``cfg.clip_arch``.
            cfg: The configuration.
        """
        super().__init__()
        self.cfg = cfg
        self.name = cfg.name
        self.dim = cfg.dim
        self.clip = clip_model
        self.tactile = tactile_model
        self.tokenizer = tokenizer
        self.image_size = _first_int(getattr(clip_model.visual, "image_size", 224))
        self.tactile_size = _first_int(getattr(getattr(tactile_model, "patch_embed", None),
                                               "img_size", 224))
        pcfg = getattr(clip_model.visual, "preprocess_cfg", None) or {}
        self.image_mean = tuple(pcfg.get("mean", CLIP_MEAN))
        self.image_std = tuple(pcfg.get("std", CLIP_STD))
        for p in self.parameters():
            p.requires_grad_(False)
        self.eval()

    @property
    def device(self) -> torch.device:
        """The device the weights live on."""
        return next(self.tactile.parameters()).device

    @torch.no_grad()
    def encode_image(self, images: Sequence[Any], batch_size: int | None = None) -> np.ndarray:
        """Embed RGB images (crop them to the contact region first, see ``tvl_contact_box``).

        Args:
            images: A list of images (anything ``to_rgb_array`` accepts, typically
                ``(H, W, 3)`` ``uint8`` arrays).
            batch_size: Images per forward pass (default ``cfg.batch_size``).

        Returns:
            ``(N, dim)`` float32, unit-norm rows.

        Raises:
            DataError: If an image is invalid (the message names its index).
        """
        items = as_image_list(images, "images")

        def prep(chunk: list[Any], start: int) -> torch.Tensor:
            return clip_rgb_tensor(chunk, self.image_size, mean=self.image_mean,
                                   std=self.image_std, index_offset=start)

        return self._batched(items, batch_size, prep, self.clip.encode_image)

    @torch.no_grad()
    def encode_tactile(self, frames: Sequence[Any], backgrounds: Any = None,
                       batch_size: int | None = None) -> np.ndarray:
        """Embed tactile sensor frames with TVL's preprocessing.

        Args:
            frames: A list of tactile frames (typically ``(H, W, 3)`` ``uint8`` arrays).
            backgrounds: No-contact frames of the same sensor: one image for all frames, or a
                list with one per frame. Used only when ``cfg.subtract_background`` is True
                (where they are required); otherwise ignored, as TVL's released encoders were
                trained on raw frames.
            batch_size: Frames per forward pass (default ``cfg.batch_size``).

        Returns:
            ``(N, dim)`` float32, unit-norm rows.

        Raises:
            DataError: If a frame or background is invalid, or backgrounds are missing while
                ``cfg.subtract_background`` is True.
        """
        items = as_image_list(frames, "frames")
        bgs: list[Any] | None = None
        if self.cfg.subtract_background:
            bgs = _expand_backgrounds(backgrounds, len(items))
        elif backgrounds is not None:
            log.debug("%s: ignoring tactile backgrounds (subtract_background=False)", self.name)

        def prep(chunk: list[Any], start: int) -> torch.Tensor:
            chunk_bgs = None if bgs is None else bgs[start:start + len(chunk)]
            return tvl_tactile_tensor(chunk, self.tactile_size, chunk_bgs, index_offset=start)

        return self._batched(items, batch_size, prep, self.tactile)

    @torch.no_grad()
    def encode_text(self, texts: Sequence[str], batch_size: int | None = None) -> np.ndarray:
        """Embed texts with the OpenCLIP text tower (its own BPE tokenizer, 77 tokens).

        Args:
            texts: A list of strings (longer texts are truncated by the tokenizer).
            batch_size: Texts per forward pass (default ``cfg.batch_size``).

        Returns:
            ``(N, dim)`` float32, unit-norm rows.

        Raises:
            DataError: If ``texts`` is a lone string or holds a non-string.
        """
        if isinstance(texts, (str, bytes)):
            raise DataError(f"texts must be a list of strings, got a single string {texts!r}; "
                            "wrap it in a list")
        items = list(texts)
        for i, text in enumerate(items):
            if not isinstance(text, str):
                raise DataError(f"text {i} is {type(text).__name__} {text!r}, expected a string")

        def prep(chunk: list[str], start: int) -> torch.Tensor:
            return self.tokenizer(chunk)

        return self._batched(items, batch_size, prep, self.clip.encode_text)

    def _batched(self, items: list[Any], batch_size: int | None,
                 prep: Callable[[list[Any], int], torch.Tensor],
                 forward: Callable[[torch.Tensor], torch.Tensor]) -> np.ndarray:
        """``forward(prep(chunk, start))`` over batches (``prep`` builds a batch's input on
        the CPU; the forward runs in ``cfg.precision``), as L2-normalised float32 rows."""
        bs = self.cfg.batch_size if batch_size is None else batch_size
        if isinstance(bs, bool) or not isinstance(bs, int) or bs < 1:
            raise ConfigError(f"batch_size must be a positive integer, got {batch_size!r}")
        self.eval()
        if not items:
            return np.zeros((0, self.dim), dtype=np.float32)
        out = np.empty((len(items), self.dim), dtype=np.float32)
        dev = self.device
        for start in range(0, len(items), bs):
            chunk = items[start:start + bs]
            x = prep(chunk, start).to(dev)
            with (torch.autocast(dev.type, dtype=torch.bfloat16)
                  if self.cfg.precision == "bf16" else contextlib.nullcontext()):
                feats = forward(x).float()
            out[start:start + len(chunk)] = F.normalize(feats, dim=-1).cpu().numpy()
        return out


def _first_int(value: Any) -> int:
    """The first element of a size tuple, or the int itself."""
    if isinstance(value, (tuple, list)):
        return int(value[0])
    return int(value)


def _expand_backgrounds(backgrounds: Any, n: int) -> list[Any]:
    """One background per frame, required (for ``subtract_background=True``)."""
    if backgrounds is None:
        raise DataError("this TVL encoder subtracts the sensor background "
                        "(subtract_background=True); pass backgrounds=")
    if isinstance(backgrounds, np.ndarray) and backgrounds.ndim in (2, 3):
        return [backgrounds] * n
    if not isinstance(backgrounds, (list, tuple, np.ndarray)):
        return [backgrounds] * n  # a single PIL image or path
    items = list(backgrounds)
    if len(items) != n:
        raise DataError(f"got {len(items)} backgrounds for {n} tactile frames; pass one "
                        "background for all frames or exactly one per frame")
    missing = [i for i, bg in enumerate(items) if bg is None]
    if missing:
        raise DataError(f"background missing for tactile frames {missing[:KEYS_SHOWN]}; this "
                        "TVL encoder subtracts the sensor background (subtract_background=True)")
    return items


# --------------------------------------------------------------------------- checkpoints


def _check_file(path: str | os.PathLike[str], what: str) -> Path:
    """Return ``path`` as a Path if it is an existing file."""
    if not isinstance(path, (str, os.PathLike)):
        raise ConfigError(f"{what} must be a file path, got {type(path).__name__} {path!r}")
    p = Path(path).expanduser()
    if not p.exists():
        raise DataNotFoundError(f"{what} not found: {p}")
    if not p.is_file():
        raise DataError(f"{what} must be a file, got a directory: {p}")
    return p


def _tensor_dict(obj: Any, path: Path, what: str) -> dict[str, torch.Tensor]:
    """Check that ``obj`` is a ``str -> Tensor`` mapping and return it as a dict."""
    if not isinstance(obj, Mapping):
        raise DataError(f"{what} {path} holds a {type(obj).__name__}, not a state dict")
    out: dict[str, torch.Tensor] = {}
    for key, value in obj.items():
        if not isinstance(value, torch.Tensor):
            raise DataError(f"{what} {path}: entry {key!r} is a {type(value).__name__}, "
                            "not a tensor; expected a state dict")
        out[str(key)] = value
    return out


def read_clip_state(path: Path) -> dict[str, torch.Tensor]:
    """Read an OpenCLIP checkpoint: a state dict, or ``{"state_dict": ...}`` from training.

    A ``module.`` prefix (DistributedDataParallel) is stripped.

    Raises:
        DataError: If the file is not a checkpoint or not a state dict.
    """
    what = "OpenCLIP checkpoint"
    obj = read_foreign_weights(path, what)
    if isinstance(obj, Mapping) and isinstance(obj.get("state_dict"), Mapping):
        obj = obj["state_dict"]
    elif isinstance(obj, Mapping) and isinstance(obj.get("model"), Mapping):
        inner = [str(k) for k in obj["model"]]
        swapped = any(k.startswith(TACTILE_PREFIX) for k in inner)
        raise DataError(
            f"{what} {path} is a {{'model': ...}} training checkpoint (keys "
            f"{describe_keys(obj.keys())}), not an OpenCLIP state dict"
            + ("; it looks like a TVL tactile checkpoint - were clip_weights and "
               "tactile_weights swapped?" if swapped else "")
        )
    state = _tensor_dict(obj, path, what)
    if not state:
        raise DataError(f"{what} {path} is an empty state dict")
    if all(k.startswith("module.") for k in state):
        state = {k[len("module."):]: v for k, v in state.items()}
    return state


def read_tvl_tactile_state(path: Path) -> dict[str, torch.Tensor]:
    """Read the tactile encoder out of a TVL checkpoint (``tvl_enc_vit*.pth``).

    The file is TVL's training checkpoint, ``{"model": {"tactile_encoder.<timm key>": ...,
    "logit_scale": ...}, "epoch": ..., ...}``; a ``.safetensors`` file holding the "model"
    state dict itself is accepted too. The ``tactile_encoder.`` prefix is stripped; other
    keys (``logit_scale``, ``logit_bias``) are not needed here.

    Raises:
        DataError: If there is no "model" state dict, no ``tactile_encoder.*`` key, or the
            checkpoint is TVL's common-latent-dim variant (``modality_heads.*``).
    """
    what = "TVL tactile checkpoint"
    obj = read_foreign_weights(path, what)
    if path.suffix == ".safetensors":
        model_state = obj
    else:
        if not isinstance(obj, Mapping):
            raise DataError(f"{what} {path} holds a {type(obj).__name__}; expected TVL's "
                            "{'model': state_dict, ...} dict")
        if "model" not in obj:
            raise DataError(f"{what} {path} has no 'model' entry (TVL layout: "
                            f"{{'model': state_dict, 'epoch': ...}}); found keys "
                            f"{describe_keys(obj.keys())}")
        model_state = obj["model"]
        if not isinstance(model_state, Mapping):
            raise DataError(f"{what} {path}: 'model' is a {type(model_state).__name__}, "
                            "not a state dict")
    keys = [str(k) for k in model_state]
    if any(k.startswith("modality_heads.") for k in keys):
        raise DataError(
            f"{what} {path} has 'modality_heads.*' keys: it was trained with TVL's "
            "common_latent_dim option, whose projection heads are not supported; use a checkpoint "
            "whose tactile head outputs the CLIP dimension (TVL's default, as released)"
        )
    tactile = {k[len(TACTILE_PREFIX):]: v for k, v in model_state.items()
               if str(k).startswith(TACTILE_PREFIX)}
    if not tactile:
        raise DataError(f"{what} {path} has no '{TACTILE_PREFIX}*' keys in its 'model' state "
                        f"dict; found keys {describe_keys(keys)}")
    ignored = [k for k in keys if not k.startswith(TACTILE_PREFIX)]
    if ignored:
        log.debug("%s: ignoring non-tactile keys %s", path, ignored[:KEYS_SHOWN])
    return _tensor_dict(tactile, path, what)


def _tactile_embed_width(state: Mapping[str, torch.Tensor]) -> int | None:
    """The ViT token width of a tactile state dict, if it can be told."""
    cls = state.get("cls_token")
    if isinstance(cls, torch.Tensor) and cls.ndim >= 1:
        return int(cls.shape[-1])
    proj = state.get("patch_embed.proj.weight")
    if isinstance(proj, torch.Tensor) and proj.ndim >= 1:
        return int(proj.shape[0])
    return None


def _arch_hint(state: Mapping[str, torch.Tensor], arch: str) -> str:
    """A sentence suggesting the tactile_arch a checkpoint was trained with, if it differs."""
    width = _tactile_embed_width(state)
    guess = _EMBED_TO_ARCH.get(width) if width is not None else None
    if guess is None or guess == arch:
        return ""
    alias = {"vit_tiny_patch16_224": "tiny", "vit_small_patch16_224": "s",
             "vit_base_patch16_224": "b"}[guess]
    return (f"; the checkpoint looks like {guess} (embed dim {width}): "
            f"use tactile_arch={alias!r}")


def _check_tactile_head(state: Mapping[str, torch.Tensor], cfg: TVLConfig, path: Path) -> None:
    """The tactile head must output exactly the CLIP embedding dimension."""
    head = state.get("head.weight")
    if isinstance(head, torch.Tensor) and head.ndim == 2 and int(head.shape[0]) != cfg.dim:
        raise DataError(
            f"TVL tactile checkpoint {path}: the tactile head outputs {int(head.shape[0])} "
            f"dimensions ('{TACTILE_PREFIX}head.weight' has shape {tuple(head.shape)}) but the "
            f"CLIP model {cfg.clip_arch} embeds into {cfg.dim}; the tactile encoder must have "
            "been trained against this CLIP model"
        )


# --------------------------------------------------------------------------- loading


def _clip_model_config(cfg: TVLConfig) -> dict[str, Any]:
    """The OpenCLIP architecture config of ``cfg.clip_arch``, checked for offline use."""
    import open_clip

    model_cfg = open_clip.get_model_config(cfg.clip_arch)
    if model_cfg is None:
        close = difflib.get_close_matches(cfg.clip_arch, open_clip.list_models(), n=5)
        raise ConfigError(f"unknown OpenCLIP architecture {cfg.clip_arch!r}"
                          + (f"; did you mean one of {close}?" if close else ""))
    text_cfg = model_cfg.get("text_cfg", {}) or {}
    remote = [k for k in ("hf_model_name", "hf_tokenizer_name") if text_cfg.get(k)]
    if remote:
        raise ConfigError(f"OpenCLIP architecture {cfg.clip_arch!r} uses a Hugging Face text "
                          f"tower/tokenizer ({', '.join(remote)}), which would be fetched online; "
                          "only self-contained OpenCLIP configs are supported")
    embed_dim = model_cfg.get("embed_dim")
    if embed_dim != cfg.dim:
        raise ConfigError(f"dim={cfg.dim} but OpenCLIP {cfg.clip_arch} embeds into {embed_dim}")
    return model_cfg


def _clip_skeleton(arch: str) -> nn.Module | None:
    """The OpenCLIP model on the meta device (no memory, no init), to check shapes cheaply."""
    import open_clip

    try:
        with torch.device("meta"):
            return open_clip.create_model(arch, pretrained=None, device="meta")
    except Exception as e:  # some towers may not build on meta; the real model checks later
        log.debug("cannot build %s on the meta device (%s); checking shapes later", arch, e)
        return None


def _create_tactile(cfg: TVLConfig) -> nn.Module:
    """The timm tactile ViT as TVL builds it (mean pooling, head of width ``cfg.dim``).

    Random initialisation is skipped where timm supports it: the strict load that follows
    overwrites every parameter and buffer.
    """
    import timm

    kwargs: dict[str, Any] = {"pretrained": False, "num_classes": cfg.dim, "global_pool": "avg"}
    try:
        return timm.create_model(cfg.tactile_arch, weight_init="skip", **kwargs)
    except (TypeError, ValueError, AssertionError):  # older timm without weight_init="skip"
        return timm.create_model(cfg.tactile_arch, **kwargs)


def load_tvl(clip_weights: str | os.PathLike[str], tactile_weights: str | os.PathLike[str],
             cfg: TVLConfig, device: str | torch.device = "cpu") -> TVLEncoders:
    """Build the TVL encoders from local checkpoint files (nothing is downloaded).

    Args:
        clip_weights: An OpenCLIP checkpoint for ``cfg.clip_arch``: a state dict saved with
            ``torch.save`` (``.pt``/``.bin``/``.pth``, e.g. ``open_clip_pytorch_model.bin``)
            or a ``.safetensors`` file (e.g. ``open_clip_model.safetensors``).
        tactile_weights: A TVL tactile-encoder checkpoint (``tvl_enc_vit{tiny,s,b}.pth``):
            ``{"model": {"tactile_encoder.<timm keys>": ..., ...}, ...}``.
        cfg: Which architectures to build.
        device: Where to put the models ("cpu", "cuda", "cuda:1", ...).

    Returns:
        The encoders, in eval mode with gradients off.

    Raises:
        ConfigError: If ``cfg`` or ``device`` is invalid, the CLIP architecture is unknown or
            its embedding dimension differs from ``cfg.dim``.
        DataNotFoundError: If a checkpoint file does not exist.
        DataError: If a file is not a checkpoint, holds non-data pickles, lacks the expected
            keys, or does not fit the architecture (the message names the first mismatched
            key and both shapes, and the matching tactile_arch where it can tell).
    """
    import open_clip

    if not isinstance(cfg, TVLConfig):
        raise ConfigError(f"cfg must be a TVLConfig, got {type(cfg).__name__}")
    dev = parse_device(device)
    clip_path = _check_file(clip_weights, "OpenCLIP checkpoint")
    tactile_path = _check_file(tactile_weights, "TVL tactile checkpoint")
    _clip_model_config(cfg)

    # Read and check both files before building anything (building ViT-L-14 takes seconds).
    tactile_state = read_tvl_tactile_state(tactile_path)
    _check_tactile_head(tactile_state, cfg, tactile_path)
    clip_state = read_clip_state(clip_path)
    clip_what = f"OpenCLIP checkpoint (arch {cfg.clip_arch})"
    skeleton = _clip_skeleton(cfg.clip_arch)
    if skeleton is not None:
        check_state(skeleton.state_dict(), clip_state, f"{clip_what} {clip_path}")
        del skeleton

    tactile = _create_tactile(cfg)
    load_into(tactile, tactile_state, f"TVL tactile checkpoint {tactile_path}",
              key_prefix=TACTILE_PREFIX, hint=_arch_hint(tactile_state, cfg.tactile_arch))
    del tactile_state
    clip_model = open_clip.create_model(cfg.clip_arch, pretrained=None, device="cpu")
    load_into(clip_model, clip_state, f"{clip_what} {clip_path}")
    del clip_state
    tokenizer = open_clip.get_tokenizer(cfg.clip_arch)

    encoders = TVLEncoders(clip_model, tactile, tokenizer, cfg).to(dev)
    log.info("loaded %s (CLIP %s from %s, tactile %s from %s) on %s", encoders.name,
             cfg.clip_arch, clip_path, cfg.tactile_arch, tactile_path, dev)
    return encoders.eval()

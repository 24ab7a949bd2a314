"""One factory turns encoder names into models: `create_model(name, pretrained=...)`.

Named architectures are JSON files in `ratouch/configs/` (a read-only registry, with a tiny
`debug` one for tests). Default-backend weights that ship with the project live in
`assets/encoders/<name>/`; the TVL backend loads local OpenCLIP and TVL checkpoints.

The registry of encoder sets by role (`DEFAULT_SETS`, `CHAIN_SETS`, `DEFAULT_ENCODER`) is read
from here by every caller, the command line's choices included; importing this module loads
no model code (the backends are imported when a model is created), so the command line stays
fast.
"""

from __future__ import annotations

import json
import os
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Mapping

from ratouch.errors import ConfigError, DataNotFoundError
from ratouch.paths import encoder_weights

if TYPE_CHECKING:
    from ratouch.encoders.default import DefaultConfig


def _scan() -> Mapping[str, dict]:
    out = {}
    for f in resources.files("ratouch.configs").iterdir():
        if f.name.endswith(".json"):
            cfg = json.loads(f.read_text())
            out[cfg["name"]] = cfg
    return MappingProxyType(out)


MODEL_CONFIGS: Mapping[str, dict] = _scan()

#: The encoder set served and evaluated when none is named.
DEFAULT_ENCODER = "default-s"
#: The default-backend encoder sets that ship (trained by `ratouch train all`), smallest first.
DEFAULT_SETS = ("default-tiny", "default-s", "default-b")
#: Those that also ship a retriever and both generators, smallest first: the cascade's chain.
CHAIN_SETS = ("default-tiny", "default-s")
#: Those trained as encoders only (no retriever, no generators).
ENCODER_ONLY_SETS = tuple(n for n in DEFAULT_SETS if n not in CHAIN_SETS)
#: The shipped sets other than the default one (the speed/accuracy trade-off's other points).
OTHER_SETS = tuple(n for n in DEFAULT_SETS if n != DEFAULT_ENCODER)

for _name in DEFAULT_SETS:  # the registry names only what the configs define
    if MODEL_CONFIGS.get(_name, {}).get("backend") != "default":
        raise ConfigError(f"DEFAULT_SETS names {_name!r}, which is not a default-backend config")


def list_models() -> list[str]:
    return sorted(MODEL_CONFIGS)


def model_config(name: str) -> dict:
    if name not in MODEL_CONFIGS:
        raise ConfigError(f"unknown encoder {name!r}; known: {list_models()}")
    return dict(MODEL_CONFIGS[name])


def shipped_weights(name: str) -> Path:
    """Folder of the shipped weights of a default-backend encoder."""
    return encoder_weights(name)


def default_config(cfg: dict) -> DefaultConfig:
    from ratouch.encoders.default import DefaultConfig

    # the prior's settings are optional in a config: absent ones take DefaultConfig's defaults
    prior = {k: cfg[k] for k in ("prior", "prior_size", "prior_hidden", "prior_dropout") if k in cfg}
    return DefaultConfig(name=cfg["name"], dim=cfg["dim"], width=cfg["width"],
                         vision_size=tuple(cfg["vision_size"]),
                         tactile_size=tuple(cfg["tactile_size"]), text_hidden=cfg["text_hidden"],
                         **prior)


def create_model(name: str = DEFAULT_ENCODER, pretrained: str | os.PathLike | dict | None = "shipped",
                 device: str = "cpu", precision: str = "fp32"):
    """Create an encoder set by name.

    Args:
        name: a registered config name (`list_models()`).
        pretrained: for the default backend: "shipped" (the weights in assets/), None (random
            init, for training), or a checkpoint folder. For the TVL backend: a dict
            {"clip": path, "tactile": path} of local checkpoint files, or a folder holding
            `open_clip_model.safetensors`/`.bin`/`.pt` and `tvl_enc_vit*.pth`.
        device: where the TVL backend's models run ("cpu", "cuda", "cuda:1"; checked by
            `load_tvl`). The default backend runs on the CPU only: it is small, and its
            encode methods hand numpy arrays in and out.
        precision: the TVL backend's forward, "fp32" or "bf16" (`TVLConfig.precision`);
            the default backend runs in fp32 only.

    Returns:
        An object with encode_image / encode_tactile / encode_text, `name`, `dim` and
        `weights_fingerprint` (what identifies the loaded weights; None for random init).
    """
    from ratouch.checkpoint import checkpoint_fingerprint, files_fingerprint, load_checkpoint

    cfg = model_config(name)
    if cfg["backend"] == "default":
        from ratouch.encoders.default import DefaultEncoders

        if device != "cpu" or precision != "fp32":
            raise ConfigError(f"encoder {name!r} runs on the CPU in fp32 only (device="
                              f"{device!r}, precision={precision!r}); the TVL backend takes "
                              "a device and a precision")
        model = DefaultEncoders(default_config(cfg))
        if pretrained is None:
            return model
        if isinstance(pretrained, dict):  # what Path(pretrained) would raise
            raise TypeError(f"encoder {name!r} takes \"shipped\", None or a checkpoint folder, "
                            "not a dict of files (that is the TVL backend's)")
        folder = shipped_weights(name) if pretrained == "shipped" else Path(pretrained)
        if not folder.exists():
            raise DataNotFoundError(f"no weights for encoder {name!r} at {folder}; train them "
                                    f"with `ratouch train encoders --model {name}`")
        load_checkpoint(folder, model, name=name)
        model.weights_fingerprint = checkpoint_fingerprint(folder)
        return model.eval()
    from ratouch.encoders.tvl import TVLConfig, load_tvl

    clip, tactile = _tvl_files(cfg, pretrained)
    tvl = load_tvl(str(clip), str(tactile),
                   TVLConfig(clip_arch=cfg["clip_arch"], tactile_arch=cfg["tactile_arch"],
                             dim=cfg["dim"], precision=precision), device=device)
    tvl.weights_fingerprint = files_fingerprint([clip, tactile])
    return tvl


def shipped_fingerprint(name: str) -> str:
    """What identifies the shipped weights of a default-backend encoder (as
    `create_model(name).weights_fingerprint`, without loading them)."""
    if model_config(name)["backend"] != "default":
        raise ConfigError(f"encoder {name!r} has no shipped weights (it needs local TVL weights)")
    from ratouch.checkpoint import checkpoint_fingerprint

    folder = shipped_weights(name)
    if not folder.exists():
        raise DataNotFoundError(f"no weights for encoder {name!r} at {folder}; train them "
                                f"with `ratouch train encoders --model {name}`")
    return checkpoint_fingerprint(folder)


def _tvl_files(cfg: dict, pretrained) -> tuple:
    """The (clip, tactile) checkpoint paths a TVL `pretrained` argument names."""
    if pretrained in (None, "shipped"):
        raise ConfigError(f"encoder {cfg['name']!r} needs local TVL weights: pass "
                          f"pretrained={{'clip': PATH, 'tactile': PATH}} or a folder")
    if isinstance(pretrained, dict):
        clip, tactile = pretrained.get("clip"), pretrained.get("tactile")
    else:
        folder = Path(pretrained)
        if not folder.is_dir():
            raise DataNotFoundError(f"TVL weights folder {folder} does not exist")
        clips = sorted(p for p in folder.iterdir() if p.name.startswith("open_clip"))
        tactiles = sorted(folder.glob("tvl_enc_vit*.pth"))
        if not clips or not tactiles:
            raise DataNotFoundError(f"{folder} must hold an open_clip_* checkpoint and a "
                                    f"tvl_enc_vit*.pth file")
        clip, tactile = clips[0], tactiles[0]
    if not clip or not tactile:
        raise ConfigError("TVL weights need both 'clip' and 'tactile' paths")
    return clip, tactile

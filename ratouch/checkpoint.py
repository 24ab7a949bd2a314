"""The one module that reads and writes weight files.

The project's own checkpoints describe themselves: safetensors weights, the config JSON beside
them, and a sha256 manifest; loading verifies the checksums and loads strictly, reporting
missing and unexpected keys. Checkpoints made elsewhere (TVL's `.pth`, OpenCLIP's) are read by
`read_foreign_weights`. Nothing pickled is ever executed."""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import json_text, publish, staged

WEIGHTS = "model.safetensors"
CONFIG = "config.json"
MANIFEST = "manifest.json"


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def save_checkpoint(folder: str | os.PathLike, state: dict[str, torch.Tensor], config: dict,
                    meta: dict | None = None, half: bool = False) -> Path:
    """Write weights, config and manifest into `folder` atomically (manifest last).

    Args:
        folder: destination folder (created).
        state: tensors to save (contiguous copies are made).
        config: the architecture config; travels beside the weights.
        meta: anything else worth keeping (training figures, seed, ...).
        half: store floating tensors as float16 (halves the size; loading casts back).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tensors = {}
    for k, v in state.items():
        v = v.detach().cpu()
        if half and v.is_floating_point():
            v = v.half()
        tensors[k] = v.contiguous()
    with staged(folder) as tmp:
        save_file(tensors, tmp / WEIGHTS)
        (tmp / CONFIG).write_text(json_text(config, indent=2, newline=False))
        manifest = {"files": {WEIGHTS: sha256_file(tmp / WEIGHTS), CONFIG: sha256_file(tmp / CONFIG)},
                    "dtype": "float16" if half else "float32", "meta": meta or {}}
        (tmp / MANIFEST).write_text(json_text(manifest, indent=2, newline=False))
        publish(tmp, folder, (WEIGHTS, CONFIG, MANIFEST))  # the manifest last
    return folder


def read_manifest(folder: str | os.PathLike) -> dict:
    """A checkpoint folder's manifest (checksums and metadata), without reading the weights."""
    folder = Path(folder)
    if not (folder / MANIFEST).is_file():
        raise DataNotFoundError(f"no checkpoint in {folder} ({MANIFEST} missing)")
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        if not isinstance(manifest["files"], dict):
            raise TypeError(f"'files' is a {type(manifest['files']).__name__}, not a mapping")
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise DataError(f"checkpoint {folder}: {MANIFEST} is unreadable: {e}") from e
    return manifest


def checkpoint_fingerprint(folder: str | os.PathLike) -> str:
    """What identifies a checkpoint's weights: the sha256 of its weights file as its manifest
    records it (read, not recomputed, so this is cheap; `read_checkpoint` verifies it)."""
    digest = read_manifest(folder)["files"].get(WEIGHTS)
    if not isinstance(digest, str):
        raise DataError(f"checkpoint {folder}: {MANIFEST} records no sha256 of {WEIGHTS}")
    return digest


def files_fingerprint(paths: Sequence[str | os.PathLike]) -> str:
    """What identifies weights made elsewhere (TVL, OpenCLIP): a sha256 over each file's
    name, size and sha256, in order (the folder they sit in does not count)."""
    files = [Path(p).expanduser() for p in paths]
    parts = [[f.name, f.stat().st_size, sha256_file(f)] for f in files]
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()


def read_checkpoint(folder: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict, dict]:
    """Verify and read a checkpoint folder: (state, config, manifest)."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    for name, digest in manifest["files"].items():
        path = folder / name
        if not path.is_file():
            raise DataNotFoundError(f"checkpoint {folder}: {name} is missing")
        if sha256_file(path) != digest:
            raise DataError(f"checkpoint {folder}: {name} is corrupt (sha256 mismatch)")
    try:
        state = load_file(folder / WEIGHTS)
        config = json.loads((folder / CONFIG).read_text())
    except (SafetensorError, OSError, json.JSONDecodeError) as e:
        raise DataError(f"checkpoint {folder} is unreadable: {e}") from e
    return state, config, manifest


#: How many keys an error message lists before "... (N in all)".
KEYS_SHOWN = 8


def describe_keys(keys: Iterable[Any]) -> str:
    """The first few of `keys`, for error messages: ``['a', 'b', ... (12 in all)]``."""
    keys = [str(k) for k in keys]
    shown = ", ".join(repr(k) for k in keys[:KEYS_SHOWN])
    more = f", ... ({len(keys)} in all)" if len(keys) > KEYS_SHOWN else ""
    return f"[{shown}{more}]"


def check_state(expected: Mapping[str, torch.Tensor], state: dict[str, torch.Tensor],
                source: str, key_prefix: str = "", hint: str = "") -> None:
    """Check a state dict against a model's, with errors that name the offending keys.

    A scalar ``logit_scale`` / ``logit_bias`` saved with shape ``[]`` or ``[1]`` is reshaped
    in place to the model's shape (as OpenCLIP does).

    Args:
        expected: the model's state dict (its tensors may be on the meta device).
        state: the checkpoint's state dict.
        source: how messages name the checkpoint (its kind and path).
        key_prefix: the prefix the keys had in the file (for messages).
        hint: a sentence appended to a shape-mismatch message.

    Raises:
        DataError: on the first shape mismatch (naming the key and both shapes), or on
            missing / unexpected keys (listing the first few of each).
    """
    for key in ("logit_scale", "logit_bias"):
        if key in state and key in expected and state[key].numel() == expected[key].numel():
            state[key] = state[key].reshape(expected[key].shape)
    for key, ref in expected.items():
        got = state.get(key)
        if got is not None and tuple(got.shape) != tuple(ref.shape):
            raise DataError(f"{source} does not fit the model: key '{key_prefix}{key}' has shape "
                            f"{tuple(got.shape)} in the checkpoint but {tuple(ref.shape)} in the "
                            f"model{hint}")
    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    if missing or unexpected:
        parts = []
        if missing:
            parts.append(f"missing keys {describe_keys(key_prefix + k for k in missing)}")
        if unexpected:
            parts.append(f"unexpected keys {describe_keys(key_prefix + k for k in unexpected)}")
        raise DataError(f"{source} does not fit the model: " + "; ".join(parts))


def load_into(module: torch.nn.Module, state: Mapping[str, torch.Tensor], source: str,
              key_prefix: str = "", hint: str = "") -> None:
    """The one strict load of weights into a built model: `check_state`, then every tensor
    cast to the model's dtype and loaded with ``strict=True``.

    Raises:
        DataError: if the state does not fit `module` exactly (named by `source`).
    """
    state = dict(state)
    own = module.state_dict()
    check_state(own, state, source, key_prefix, hint)
    try:
        module.load_state_dict({k: v.to(own[k].dtype) for k, v in state.items()}, strict=True)
    except RuntimeError as e:  # incompatibilities not caught above
        raise DataError(f"{source} could not be loaded: {first_line(e)}") from e


def load_checkpoint(folder: str | os.PathLike, module: torch.nn.Module, name: str | None = None,
                    prefix: str = "") -> tuple[dict, dict]:
    """Verify a checkpoint folder and load its weights strictly into `module`: the one loader
    of the project's own weights into a model that is already built.

    Args:
        folder: the checkpoint (`save_checkpoint`).
        module: the model whose state the weights must fit exactly (`load_into`).
        name: the config's "name" the checkpoint must carry (an encoder set's), if given.
        prefix: load only the tensors under this prefix (e.g. "vision."), stripped of it.

    Returns:
        (config, manifest) of the checkpoint.

    Raises:
        ConfigError: If the checkpoint is another model's (`name`).
        DataError: If it is corrupt or does not fit `module`.
    """
    folder = Path(folder)
    state, config, manifest = read_checkpoint(folder)
    if name is not None and config.get("name") != name:
        raise ConfigError(f"checkpoint {folder} is for encoder {config.get('name')!r}, "
                          f"not {name!r}")
    if prefix:
        state = {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
    load_into(module, state, f"{folder} ({prefix}*)" if prefix else str(folder))
    return config, manifest


# --------------------------------------------------------------------- foreign checkpoints

def read_foreign_weights(path: Path, what: str) -> Any:
    """Read a checkpoint made elsewhere (TVL, OpenCLIP) without executing pickled code.

    ``.safetensors`` files are read with safetensors; anything else with
    ``torch.load(weights_only=True)``, allowing only tensors, plain containers, numbers,
    strings and ``argparse.Namespace`` (TVL stores its training arguments in one).

    Args:
        path: The checkpoint file.
        what: How to name it in error messages.

    Returns:
        The loaded object (a dict of tensors for safetensors).

    Raises:
        DataError: If the file is not a checkpoint, or holds pickled objects that are not
            plain data (refused, never executed).
    """
    if path.suffix == ".safetensors":
        try:
            return load_file(str(path), device="cpu")
        except (SafetensorError, OSError, ValueError, RuntimeError) as e:
            raise DataError(f"{what} {path} is not a valid safetensors file: {e}") from e
    try:
        with torch.serialization.safe_globals([argparse.Namespace]):
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        found = re.search(r"GLOBAL ([\w.]+)", str(e))
        if found:
            raise DataError(
                f"refusing to load {what} {path}: it contains a pickled {found.group(1)} object, "
                "and only tensors and plain data are unpickled (weights_only=True); re-save the "
                "checkpoint as a plain state dict or safetensors"
            ) from e
        raise DataError(f"{what} {path} is not a PyTorch checkpoint "
                        f"({first_line(e)})") from e
    except Exception as e:  # torch raises RuntimeError/EOFError/KeyError/... on junk files
        raise DataError(f"{what} {path} is not a PyTorch checkpoint "
                        f"({type(e).__name__}: {first_line(e)})") from e


def first_line(e: BaseException) -> str:
    """The first non-empty line of an exception message, shortened."""
    for line in str(e).splitlines():
        if line.strip():
            return line.strip()[:200]
    return type(e).__name__

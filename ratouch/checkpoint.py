"""The one module that reads and writes weight files.

The project's own checkpoints describe themselves: safetensors weights, the config JSON beside
them, and a sha256 manifest of every file the checkpoint holds (a generator's LoRA adapter and
tokenizer too); loading verifies the checksums and loads strictly, reporting missing and
unexpected keys. A checkpoint is published as a whole: written complete beside the current one
and swapped in with one atomic rename (`ratouch.files.replace_folder`), so a killed training
run leaves the old checkpoint or the new one, never a mixture. Checkpoints made elsewhere (TVL's `.pth`, OpenCLIP's) are read by
`read_foreign_weights`. Nothing pickled is ever executed."""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path, PurePosixPath
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import json_text, replace_folder, staged_beside, write_atomic

WEIGHTS = "model.safetensors"
CONFIG = "config.json"
MANIFEST = "manifest.json"


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def rebuild_command(folder: str | os.PathLike) -> str:
    """The command that writes a checkpoint folder again, told by where it sits (the shipped
    layout: ``encoders/<set>``, ``retriever/<set>``, ``generator/<set>/<kind>``)."""
    folder = Path(folder)
    if folder.parent.name == "encoders":
        return f"ratouch train encoders --model {folder.name}"
    if folder.parent.name == "retriever":
        return f"ratouch train retriever --encoder {folder.name}"
    if folder.parent.parent.name == "generator":
        return f"ratouch train generator --encoder {folder.parent.name}"
    return "the command that trained it (`ratouch train all` for the shipped assets)"


def _bad(folder: Path, what: str) -> DataError:
    return DataError(f"checkpoint {folder}: {what}; rebuild it with `{rebuild_command(folder)}`")


def save_checkpoint(folder: str | os.PathLike, state: dict[str, torch.Tensor], config: dict,
                    meta: dict | None = None, half: bool = False,
                    extra: Callable[[Path], None] | None = None) -> Path:
    """Publish a checkpoint as a whole: weights, config, `extra` files and a manifest of
    every file's sha256 are written into a staging folder beside `folder`, which then takes
    `folder`'s place in one atomic step (`ratouch.files.replace_folder`); staging that a
    killed run left behind is removed first.

    Args:
        folder: destination folder (replaced as a whole; its parent is created).
        state: tensors to save (contiguous copies are made).
        config: the architecture config; travels beside the weights.
        meta: anything else worth keeping (training figures, seed, ...).
        half: store floating tensors as float16 (halves the size; loading casts back).
        extra: writes further files (an adapter, a tokenizer) into the folder it is given;
            they are checked on load like the weights.
    """
    folder = Path(folder)
    tensors = {}
    for k, v in state.items():
        v = v.detach().cpu()
        if half and v.is_floating_point():
            v = v.half()
        tensors[k] = v.contiguous()
    with staged_beside(folder) as tmp:
        if extra is not None:
            extra(tmp)
        save_file(tensors, tmp / WEIGHTS)
        (tmp / CONFIG).write_text(json_text(config, indent=2, newline=False))
        manifest = {"files": _hashes(tmp), "dtype": "float16" if half else "float32",
                    "meta": meta or {}}
        (tmp / MANIFEST).write_text(json_text(manifest, indent=2, newline=False))
        replace_folder(tmp, folder)
    return folder


def _hashes(folder: Path) -> dict[str, str]:
    """{relative POSIX path: sha256} of every file under `folder` but the manifest and hidden
    ones (staging), the weights and config first."""
    names = sorted(rel.as_posix() for rel in (p.relative_to(folder) for p in folder.rglob("*")
                                              if p.is_file())
                   if rel.as_posix() != MANIFEST and not any(x.startswith(".") for x in rel.parts))
    names.sort(key=lambda n: (n != WEIGHTS, n != CONFIG, n))
    return {n: sha256_file(folder / n) for n in names}


def rehash_manifest(folder: str | os.PathLike) -> dict[str, str]:
    """Record every file of an existing checkpoint in its manifest (the weights' and config's
    recorded checksums must still hold; dtype and meta are kept), for checkpoints written
    before the manifest covered adapters and tokenizers. The manifest is replaced atomically.

    Returns:
        The files newly recorded, with their sha256.

    Raises:
        DataError: the manifest is unreadable, or a file it already records has changed.
    """
    folder = Path(folder)
    manifest = read_manifest(folder)
    _verify(folder, manifest["files"])
    files = _hashes(folder)
    added = {n: d for n, d in files.items() if n not in manifest["files"]}
    manifest["files"] = files
    write_atomic(folder / MANIFEST, json_text(manifest, indent=2, newline=False))
    return added


def read_manifest(folder: str | os.PathLike) -> dict:
    """A checkpoint folder's manifest (checksums and metadata), without reading the weights.

    Raises:
        DataNotFoundError: the folder holds no manifest.
        DataError: the manifest cannot be read or is not a checkpoint manifest (the message
            names the file and the command that writes the checkpoint again).
    """
    folder = Path(folder)
    path = folder / MANIFEST
    if not path.exists():
        raise DataNotFoundError(f"no checkpoint in {folder} ({MANIFEST} missing); build it "
                                f"with `{rebuild_command(folder)}`")
    try:
        manifest = json.loads(path.read_bytes().decode("utf-8"))
        if not isinstance(manifest, dict):
            raise TypeError(f"it holds a {type(manifest).__name__}, not an object")
        if not isinstance(manifest.get("files"), dict):
            raise TypeError("its 'files' is not a mapping of file names to sha256")
        for name, digest in manifest["files"].items():
            parts = PurePosixPath(name).parts
            if not isinstance(digest, str) or not parts or name.startswith("/") or ".." in parts:
                raise TypeError(f"its entry {name!r}: {digest!r} is not a file and a sha256")
    except (OSError, UnicodeDecodeError, ValueError, TypeError) as e:
        raise _bad(folder, f"{MANIFEST} is unreadable ({type(e).__name__}: {first_line(e)})"
                   ) from e
    return manifest


def _verify(folder: Path, files: Mapping[str, str]) -> None:
    for name, digest in files.items():
        path = folder / name
        if not path.is_file():
            raise DataNotFoundError(f"checkpoint {folder}: {name} is missing; rebuild it with "
                                    f"`{rebuild_command(folder)}`")
        try:
            ok = sha256_file(path) == digest
        except OSError as e:
            raise _bad(folder, f"{name} is unreadable ({first_line(e)})") from e
        if not ok:
            raise _bad(folder, f"{name} is corrupt (sha256 mismatch)")


def require_files(folder: str | os.PathLike, manifest: dict, names: Iterable[str]) -> None:
    """Refuse a checkpoint whose manifest does not record files the loader is about to read
    (a checkpoint written before the manifest covered them: they could not be checked).

    Raises:
        DataError: naming the first such file and the command that rebuilds the checkpoint.
    """
    for name in names:
        if name not in manifest["files"]:
            raise _bad(Path(folder), f"{name} is not recorded in {MANIFEST}, so it cannot be "
                       "checked (the checkpoint was written by an older version)")


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


def read_checkpoint(folder: str | os.PathLike, require: Iterable[str] = ()
                    ) -> tuple[dict[str, torch.Tensor], dict, dict]:
    """Verify and read a checkpoint folder: (state, config, manifest). Every file the manifest
    records is checked against its sha256; `require` names further files the caller will
    read, which the manifest must record (`require_files`)."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    require_files(folder, manifest, (WEIGHTS, CONFIG, *require))
    _verify(folder, manifest["files"])
    try:
        state = load_file(folder / WEIGHTS)
        config = json.loads((folder / CONFIG).read_bytes().decode("utf-8"))
    except (SafetensorError, OSError, ValueError) as e:
        raise _bad(folder, f"it is unreadable ({type(e).__name__}: {first_line(e)})") from e
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

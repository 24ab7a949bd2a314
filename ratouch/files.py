"""Atomic file writes: the content goes to a hidden temporary file beside the target, which is
then renamed over it, so a reader never sees half a file and an interrupted write leaves the
old file (or nothing) behind."""

from __future__ import annotations

import json
import os
from pathlib import Path


def write_atomic(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write bytes, or text as UTF-8, to `path` atomically (parent folders are created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.partial")
    try:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_json_atomic(path: str | os.PathLike, obj) -> Path:
    """`obj` as indented JSON, written atomically."""
    return write_atomic(path, json.dumps(obj, indent=1) + "\n")

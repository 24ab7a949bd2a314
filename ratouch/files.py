"""Atomic file writes, the one implementation the project has: content goes to a hidden
temporary file (or folder) beside its target and is then renamed over it, so a reader never
sees half a file and an interrupted write leaves the old file (or nothing) behind.

* `atomic_path`: the temporary path to write one file to, renamed into place at the end;
  `write_atomic` (bytes or text), `write_json_atomic`, `write_npz_atomic` and `write_npy_atomic`
  are built on it.
* `staged` and `publish`: several files (a checkpoint, a corpus, a data set, a shard) written
  into a hidden folder first and moved into place in a given order, the last one (a manifest)
  marking completion; `replace_folder` swaps a whole folder in.
* `staged_beside` and `replace_folder`: a whole folder (a checkpoint) written complete beside
  the live one and swapped in with one atomic rename (Linux's ``RENAME_EXCHANGE``), so a reader
  sees the old folder or the new one, never a mixture, whenever the writer is killed.

A staging folder's name carries the writing process's id, so `clean_stale_staging` can remove
the ones a killed job left behind without touching a running job's.
"""

from __future__ import annotations

import ctypes
import errno
import glob
import json
import os
import secrets
import shutil
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """The hidden temporary path (``.<name>.partial-<pid>-<random>`` beside `path`, parent
    folders created) to write `path`'s content to; renamed over `path` when the block ends
    without an error, removed otherwise. Temporary files of `path` that a killed process left
    behind are removed first; a running writer's are not (each writer has its own)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    prefix = f".{path.name}.partial"
    for stale in path.parent.glob(f"{glob.escape(prefix)}*"):
        owner = staging_owner(stale, prefix + "-")
        if stale.is_file() and (owner is None or not pid_alive(owner)):
            stale.unlink(missing_ok=True)
    tmp = path.with_name(f"{prefix}-{os.getpid()}-{secrets.token_hex(4)}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_atomic(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write bytes, or text as UTF-8, to `path` atomically (parent folders are created)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return Path(path)


def json_text(obj, indent: int | None = 1, sort_keys: bool = False, newline: bool = True
              ) -> str:
    """`obj` as JSON text: indented by `indent` (None: one line), keys sorted when asked, and
    ending in a new line unless `newline` is False."""
    return json.dumps(obj, indent=indent, sort_keys=sort_keys) + ("\n" if newline else "")


def write_json_atomic(path: str | os.PathLike, obj, indent: int | None = 1,
                      sort_keys: bool = False, newline: bool = True) -> Path:
    """`obj` as JSON (`json_text`: indented by 1 and ending in a new line by default),
    written atomically."""
    return write_atomic(path, json_text(obj, indent, sort_keys, newline))


def write_npz_atomic(path: str | os.PathLike, **arrays) -> Path:
    """Arrays into an uncompressed ``.npz`` file (`numpy.savez`), written atomically."""
    import numpy as np

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
    return Path(path)


def write_npy_atomic(path: str | os.PathLike, array) -> Path:
    """One array into a ``.npy`` file (`numpy.save`), written atomically."""
    import numpy as np

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.save(f, array)
    return Path(path)


@contextmanager
def staged(folder: str | os.PathLike, prefix: str = ".partial-") -> Iterator[Path]:
    """A hidden temporary folder inside `folder` (created) to write several files into before
    `publish` moves them into place; removed, with anything left in it, when the block ends.
    Its name is ``<prefix><pid>-<random>``; a process killed before the block ends leaves it
    behind, for `clean_stale_staging` to find."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-", dir=folder))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def publish(staging: str | os.PathLike, folder: str | os.PathLike,
            names: Iterable[str] | None = None) -> None:
    """Move files from a `staged` folder into `folder` by rename, in the order of `names`
    (relative paths; the last one, e.g. a manifest, marks completion), or every file under
    `staging` in sorted order when None. Sub-folders are created."""
    staging, folder = Path(staging), Path(folder)
    if names is None:
        names = [str(p.relative_to(staging)) for p in sorted(staging.rglob("*"))
                 if not p.is_dir()]
    for name in names:
        dst = folder / name
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staging / name, dst)


def replace_folder(staging: str | os.PathLike, folder: str | os.PathLike) -> None:
    """Put a complete folder (`staging`, made beside `folder` on the same file system) in the
    place of `folder` in one atomic step: a reader of `folder` sees the old folder or the new
    one, never a mixture and never nothing. Where `folder` exists the two are exchanged
    (``renameat2(RENAME_EXCHANGE)``) and the old one, now at `staging`, is removed; a process
    killed before that removal leaves it there for `clean_stale_staging`. Where the system
    cannot exchange, the old folder is first renamed to a ``.<name>.old-<pid>-`` backup, which
    `restore_backup` puts back if the process dies before the new one is in place."""
    staging, folder = Path(staging), Path(folder)
    if not folder.exists():
        os.rename(staging, folder)  # nothing to keep: one rename is atomic
        return
    if _exchange(staging, folder):
        shutil.rmtree(staging, ignore_errors=True)
        return
    backup = Path(tempfile.mkdtemp(prefix=f".{folder.name}.old-{os.getpid()}-",
                                   dir=folder.parent))
    os.replace(folder, backup)  # an empty folder is replaced
    os.rename(staging, folder)
    shutil.rmtree(backup, ignore_errors=True)


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2`` with ``RENAME_EXCHANGE``); False where
    the system or file system cannot, so the caller falls back to two renames."""
    if not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    renameat2 = getattr(libc, "renameat2", None)
    if renameat2 is None:  # a C library older than glibc 2.28
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(a), None, str(b))


def restore_backup(folder: str | os.PathLike) -> Path | None:
    """Where a process was killed between `replace_folder`'s two fallback renames (`folder`
    missing, its ``.<name>.old-`` backup beside it), put the backup back; returns it."""
    folder = Path(folder)
    if folder.exists() or not folder.parent.is_dir():
        return None
    for backup in sorted(folder.parent.glob(f".{folder.name}.old-*")):
        if backup.is_dir() and any(backup.iterdir()):
            os.rename(backup, folder)
            return backup
    return None


@contextmanager
def staged_beside(folder: str | os.PathLike) -> Iterator[Path]:
    """A hidden folder beside `folder` (``.<name>.partial-<pid>-<random>``) to write a whole new
    version of it into, before `replace_folder` swaps it in; removed, with whatever it holds
    then (the old version, after a swap), when the block ends. Staging a killed process left
    beside `folder` (or, from older versions, inside it) is removed first, and a backup the
    fallback swap left is put back."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    restore_backup(folder)
    for kind in ("partial", "old"):
        clean_stale_staging(folder.parent, prefix=f".{folder.name}.{kind}-")
    clean_stale_staging(folder)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.partial-{os.getpid()}-",
                                dir=folder.parent))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def pid_alive(pid: int) -> bool:
    """Whether a process with this id runs now (on this machine)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it runs, as another user
        return True
    return True


def staging_owner(path: Path, prefix: str) -> int | None:
    """The process id in a `staged` folder's name (None: not a name `staged` gives)."""
    head = path.name[len(prefix):].split("-", 1)[0]
    return int(head) if path.name.startswith(prefix) and head.isdigit() else None


def clean_stale_staging(folder: str | os.PathLike, prefix: str = ".partial-") -> list[Path]:
    """Remove the `staged` folders (names starting with `prefix`) in `folder` whose writer no
    longer runs: what a killed job left behind. A folder whose name carries no process id (an
    older version's) counts as stale too. Returns the folders removed."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    for p in sorted(folder.glob(f"{prefix}*")):
        if not p.is_dir():
            continue
        owner = staging_owner(p, prefix)
        if owner is not None and (owner == os.getpid() or pid_alive(owner)):
            continue  # a job running now: its staging is not stale
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed

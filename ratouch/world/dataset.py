"""Paired visuo-tactile data sets on disk in the TVL data set's own layout.

TVL (public repository Max-Fu/tvl, `tvl_enc/tacvis.py`) keeps one folder per subset
(`ssvtp/`, `hct/data1/`, ...), each with a `train.csv` and a `test.csv`: a header row, then
rows of (vision path, tactile path, background path, caption), paths relative to that folder.
`write_split` writes the world in that layout (plus a `meta_<split>.jsonl` sidecar with the
world's ground truth, row for row); `read_tvl` reads both it and the real TVL data set.

A split is written atomically as far as a reader can tell: everything is rendered into a
staging folder (``.partial-<split>-<pid>-*``, never listed by the reader), then a journal
(``.publishing-<split>.json``) is written at the root, the files are moved into place, and the
journal is removed last. A reader refuses a split whose journal is present (a build was killed
while publishing) and names the command that finishes it; the same command, run again,
removes the staging a killed build left, publishes the split again and says so.
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import shutil
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import (
    clean_stale_staging,
    pid_alive,
    publish,
    staged,
    write_json_atomic,
)
from ratouch.processes import worker_pool
from ratouch.timing import progress_bar
from ratouch.world.config import WorldConfig
from ratouch.world.sampler import TEST_SIZE, World

log = logging.getLogger(__name__)

CSV_HEADER = ("url", "tactile", "background", "caption")
SUBSET_DIRS = {"structured": "ssvtp", "wild": os.path.join("hct", "data1")}
WRITABLE_SPLITS = ("train", "test")


@dataclass(frozen=True)
class PairRecord:
    """One row of a TVL-layout CSV, paths made absolute."""

    vision: Path
    tactile: Path
    background: Path
    caption: str
    subset: str  # the subset folder, relative to the data set root
    meta: dict | None = None  # world ground truth, when the sidecar exists


# ---------------------------------------------------------------------------------------------
# writing

def _save_png(path: Path, array: np.ndarray) -> None:
    Image.fromarray(array).save(path, compress_level=1)


@lru_cache(maxsize=2)
def world_for(cfg: WorldConfig) -> World:
    """One World per config and process, so worker processes build texture tiles once."""
    return World(cfg)


def _write_chunk(args: tuple[WorldConfig, str, Sequence[int], str]) -> list[tuple[str, dict]]:
    """Render and save a chunk of samples (runs in a worker process). Returns CSV rows."""
    cfg, split, indices, root = args
    world = world_for(cfg)
    rows = []
    for i in indices:
        s = world.sample(split, i)
        sub = SUBSET_DIRS[s.subset]
        base = Path(root) / sub
        name = f"{split}_{i:06d}.png"
        _save_png(base / "vision" / name, s.visual)
        _save_png(base / "tactile" / name, s.tactile)
        meta = {
            "index": i, "class_name": s.class_name, "material": s.material,
            "label": s.label, "description": s.description, "box": list(s.box),
            "box_true": list(s.box_true), "sensor": s.sensor, "contact": s.contact,
            "object_scale": round(s.object_scale, 4),
        }
        row = (f"vision/{name}", f"tactile/{name}", f"backgrounds/sensor_{s.sensor}.png",
               s.caption)
        rows.append((s.subset, {"row": row, "meta": meta}))
    return rows


def check_writable(out: Path) -> None:
    """Fail early, with the folder named, if `out` cannot be created or written."""
    probe_dir = out
    while not probe_dir.exists():
        probe_dir = probe_dir.parent
    if not probe_dir.is_dir():
        raise ConfigError(f"output path {out} is inside {probe_dir}, which is not a folder")
    if not os.access(probe_dir, os.W_OK | os.X_OK):
        raise ConfigError(f"output folder {probe_dir} is not writable")


def write_split(cfg: WorldConfig, out: str | os.PathLike, split: str, n: int | None = None,
                workers: int = 2, progress: bool = True, regime=None) -> dict[str, int]:
    """Generate a split of the world and write it in the TVL layout under `out`.

    Everything is first written to a temporary folder inside `out` and moved into place only
    when the whole split succeeded, under a journal that readers respect, so a failure or a
    kill at any moment leaves nothing a reader trusts; run again, it cleans up after the
    killed run and writes the split (see the module's docstring).

    Args:
        cfg: world config.
        out: data set root; `ssvtp/` and `hct/data1/` are created under it.
        split: "train" or "test".
        n: number of samples; the test split always has 402 (46 structured + 356 wild).
        workers: processes rendering in parallel.
        progress: show a progress bar.
        regime: for the train split, the `ratouch.world.scarcity.ScarceRegime` whose pairs
            are written (file names keep the world's sample index); None writes samples 0..n-1.

    Returns:
        Number of samples written per subset. What was cleaned up after a killed earlier
        build (staging folders removed, an interrupted publish redone) is logged as warnings.
    """
    if split not in WRITABLE_SPLITS:
        raise ConfigError(f"split={split!r} must be one of {WRITABLE_SPLITS}")
    if split == "test":
        if n not in (None, TEST_SIZE):
            raise ConfigError(f"the test split has exactly {TEST_SIZE} samples; got n={n}")
        n = TEST_SIZE
    if n is None:
        n = 20000
    if n <= 0:
        raise ConfigError(f"n={n} must be a positive number of samples")
    if workers < 1:
        raise ConfigError(f"workers={workers} must be >= 1")
    out = Path(out)
    check_writable(out)
    created_out = not out.exists()
    recover(out, split)
    with contextlib.ExitStack() as stack:
        try:
            tmp = stack.enter_context(staged(out, prefix=f".partial-{split}-"))
        except OSError as e:
            raise ConfigError(f"cannot write to output folder {out}: {e.strerror}") from e
        try:
            indices = regime.train_indices(n) if regime is not None and split == "train" \
                else list(range(n))
            counts = _write_into(cfg, tmp, split, indices, workers, progress)
            _publish_split(tmp, out, split, finish_command(out, split, n, cfg.seed, regime))
        except BaseException:
            stack.close()  # the staging folder goes first
            if created_out and not any(out.iterdir()):
                out.rmdir()
            raise
    return counts


def journal_path(root: Path, split: str) -> Path:
    """The journal that marks a split of `root` as being published (present: not readable)."""
    return root / f".publishing-{split}.json"


def recover(out: Path, split: str) -> list[str]:
    """Clean up after a killed build of `split` into `out`: remove its stale staging folders
    and note an interrupted publish (the journal stays until this build publishes again).
    Returns one line per thing done, for the caller to show."""
    journal = journal_path(out, split)
    if journal.is_file():
        owner = _journal_owner(journal)
        if owner is not None and owner != os.getpid() and pid_alive(owner):
            raise ConfigError(f"another world build (pid {owner}) is publishing the {split} "
                              f"split into {out} now; wait for it to end")
    done = [f"removed the staging folder {p} of a killed build"
            for p in clean_stale_staging(out, f".partial-{split}-")]
    if journal.is_file():
        done.append(f"the publish of the {split} split into {out} was interrupted; this "
                    f"build publishes it again")
    for line in done:
        log.warning("%s", line)
    return done


def _journal_owner(journal: Path) -> int | None:
    try:
        return int(json.loads(journal.read_text())["pid"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def finish_command(out: Path, split: str, n: int, seed: int, regime=None) -> str:
    """The `ratouch world build` command that builds this split again (and so finishes an
    interrupted publish of it): its folder, split, size, seed and regime."""
    cmd = f"ratouch world build --out {out} --split {split}"
    if split != "test":
        cmd += f" --n {n}"
    if seed:
        cmd += f" --seed {seed}"
    if regime is not None and split == "train":
        if getattr(regime, "regime", "scarce") != "scarce":
            cmd += f" --regime {regime.regime}"
        if getattr(regime, "draw", 0):
            cmd += f" --draw {regime.draw}"
    return cmd


def _publish_split(staging: Path, out: Path, split: str, finish: str) -> None:
    """Move a staged split into `out`: the journal first (with `finish`, the command that
    builds it again), the images, then the sidecars and the CSVs (what a reader opens first)
    last, then the journal removed."""
    names = [str(p.relative_to(staging)) for p in sorted(staging.rglob("*")) if p.is_file()]
    names.sort(key=lambda n: (n.endswith(".csv"), n.endswith(".jsonl"), n))
    journal = journal_path(out, split)
    write_json_atomic(journal, {"pid": os.getpid(), "split": split, "finish": finish,
                                "files": names})
    publish(staging, out, names)
    journal.unlink()


def _write_into(cfg: WorldConfig, root: Path, split: str, indices: list[int], workers: int,
                progress: bool) -> dict[str, int]:
    world = world_for(cfg).warm()  # forked workers inherit the texture tiles
    for sub in SUBSET_DIRS.values():
        for folder in ("vision", "tactile", "backgrounds"):
            (root / sub / folder).mkdir(parents=True, exist_ok=True)
    n = len(indices)
    chunk = max(16, min(256, n // (4 * workers) + 1))
    jobs = [(cfg, split, indices[k:k + chunk], str(root)) for k in range(0, n, chunk)]
    results: list[tuple[str, dict]] = []
    bar = progress_bar(total=n, desc=f"world {split}", unit="pair", progress=progress)
    if workers == 1:
        for job in jobs:
            results.extend(_write_chunk(job))
            bar.update(len(job[2]))
    else:
        with worker_pool(workers) as pool:
            for rows in pool.map(_write_chunk, jobs):
                results.extend(rows)
                bar.update(len(rows))
    bar.close()
    counts = {}
    for subset, sub in SUBSET_DIRS.items():
        subset_rows = [r for s, r in results if s == subset]
        counts[subset] = len(subset_rows)
        if not subset_rows:
            shutil.rmtree(root / sub)
            continue
        used = sorted({r["meta"]["sensor"] for r in subset_rows})
        for k in used:
            _save_png(root / sub / "backgrounds" / f"sensor_{k}.png", world.background_image(k))
        with open(root / sub / f"{split}.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(CSV_HEADER)
            w.writerows(r["row"] for r in subset_rows)
        with open(root / sub / f"meta_{split}.jsonl", "w") as f:
            for r in subset_rows:
                f.write(json.dumps(r["meta"]) + "\n")
    return counts


# ---------------------------------------------------------------------------------------------
# reading

def subset_dirs(root: Path, split: str) -> list[Path]:
    """Folders under `root` (root included) that hold the split's CSV, sorted; nothing inside
    a staging folder (a ``.partial*`` folder at any depth) is listed."""
    name = "test.csv" if split == "test" else "train.csv"
    return sorted(p.parent for p in root.rglob(name)
                  if not any(part.startswith(".partial")
                             for part in p.parent.relative_to(root).parts))


def check_published(root: Path, split: str) -> None:
    """Refuse a split whose build was killed while publishing it (its journal is present in
    `root` or a folder above), naming the command that finishes it."""
    for folder in (root, *root.parents):
        journal = journal_path(folder, split)
        if journal.is_file():
            try:
                finish = json.loads(journal.read_bytes().decode("utf-8"))["finish"]
            except (OSError, ValueError, KeyError, TypeError):  # an older version's journal
                finish = f"ratouch world build --out {folder} --split {split}"
            raise DataError(f"the {split} split in {folder} is incomplete: a world build was "
                            f"killed while publishing it ({journal.name} is present); run "
                            f"`{finish}` (with the same stress options, if any) again to "
                            f"finish it")


def read_tvl(root: str | os.PathLike, split: str = "test") -> list[PairRecord]:
    """Read a TVL-layout data set: the world's output or the real TVL data set.

    Args:
        root: the data set root (e.g. `tvl_dataset/`), or one subset folder.
        split: "train" (reads train.csv) or "test" (reads test.csv).

    Returns:
        One record per CSV row, subsets in sorted folder order.
    """
    if split not in WRITABLE_SPLITS:
        raise ConfigError(f"split={split!r} must be one of {WRITABLE_SPLITS}")
    root = Path(root)
    if not root.is_dir():
        raise DataNotFoundError(f"data set folder {root} does not exist")
    check_published(root.resolve(), split)
    dirs = subset_dirs(root, split)
    if not dirs:
        raise DataNotFoundError(f"no {split}.csv under {root}: not a TVL-layout data set")
    records = []
    for d in dirs:
        records.extend(_read_subset(root, d, split))
    return records


def _read_subset(root: Path, d: Path, split: str) -> list[PairRecord]:
    csv_path = d / ("test.csv" if split == "test" else "train.csv")
    with open(csv_path, newline="") as f:
        rows = list(csv.reader(f))[1:]  # TVL's reader skips the header row too
    meta_path = d / f"meta_{split}.jsonl"
    metas: list[dict | None] = [None] * len(rows)
    if meta_path.exists():
        with open(meta_path) as f:
            metas = [json.loads(line) for line in f if line.strip()]
        if len(metas) != len(rows):
            raise DataError(f"{meta_path} has {len(metas)} rows but {csv_path} has {len(rows)}")
    out = []
    for n, (row, meta) in enumerate(zip(rows, metas), start=2):
        if len(row) != 4:
            raise DataError(f"{csv_path}:{n}: expected 4 columns (vision, tactile, background, "
                            f"caption), got {len(row)}")
        vision, tactile, background, caption = row
        out.append(PairRecord(d / vision, d / tactile, d / background, caption,
                              str(d.relative_to(root)), meta))
    return out

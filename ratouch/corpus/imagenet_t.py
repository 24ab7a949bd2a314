"""ImageNet-T: the tactile-recaptioned retrieval corpus, built by the paper's recipe.

Recaption every entry (class name + appearance-only description -> exactly five tactile
adjectives), then draw stratified subsets across classes (10k, 50k, 100k, 150k). The default
source is the procedural world (a pool of 1300 entries per class, like ImageNet's ~1300 images
per class, images rendered on demand from their ids); a real list of (image path, class,
caption) rows, or a folder of images in ImageNet's layout (one subfolder per class,
`read_image_folder`), goes through the same builder.
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
import os
import re
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image, UnidentifiedImageError

from ratouch.corpus.recaption import RecaptionConfig, create_recaptioner
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import clean_stale_staging, json_text, publish, staged
from ratouch.images import resize_array
from ratouch.processes import worker_pool
from ratouch.timing import progress_bar
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import check_writable, world_for
from ratouch.world.material import MATERIALS
from ratouch.world.objects import OBJECT_CLASSES
from ratouch.world.sampler import CORPUS_MAX_PER_CLASS, CORPUS_POOL_PER_CLASS, World

log = logging.getLogger(__name__)

#: The image files `read_image_folder` takes.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
#: The appearance description of an image of a folder, which has none: the project has no
#: image captioner, so the description is the class name in a plain sentence.
FOLDER_DESCRIPTION = "a photo of a {class_name}"
SUBSET_SIZES = {"10k": 10_000, "50k": 50_000, "100k": 100_000, "150k": 150_000}
METADATA = "metadata.jsonl"
MANIFEST = "manifest.json"


@dataclass(frozen=True)
class CorpusEntry:
    """One ImageNet-T row. `source` says how to get the image back: `world:<seed>:<class
    index>:<instance>` for the procedural world, or an image path for a real corpus."""

    id: int
    class_name: str
    description: str
    caption: str  # exactly five tactile adjectives, comma separated
    source: str
    material: str = ""  # world ground truth (never shown to the recaptioner); "" if unknown


def parse_size(text: str | int) -> int:
    """Parse a corpus size such as 10k, 150k, 1m or 2500."""
    if isinstance(text, int):
        n = text
    else:
        m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kKmM]?)\s*", str(text))
        if not m:
            raise ConfigError(f"size={text!r} is not a size like 10k, 150k or 2500")
        n = int(float(m.group(1)) * {"": 1, "k": 1_000, "m": 1_000_000}[m.group(2).lower()])
    if n <= 0:
        raise ConfigError(f"size={text!r} must be positive")
    return n


def world_lexicon() -> dict[str, dict[str, float]]:
    """Lexicon of the world's appearance words and class names for the offline recaptioner.

    A look word ("glossy", "wooden", ...) maps to the mean profile of the materials that look
    that way (so look-alikes stay ambiguous, as they are to a captioner that only sees them);
    a class name maps to the profile expected from its material distribution.
    """
    def norm(p: dict[str, float]) -> dict[str, float]:
        total = sum(p.values())
        return {k: 3.0 * v / total for k, v in p.items()}

    lex: dict[str, dict[str, float]] = {}
    by_look: dict[str, list] = {}
    for m in MATERIALS:
        by_look.setdefault(m.look.word, []).append(m)
    for word, mats in by_look.items():
        acc: dict[str, float] = {}
        for m in mats:
            for adj, w in m.profile:
                acc[adj] = acc.get(adj, 0.0) + w / len(mats)
        lex[word.lower()] = norm(acc)
    profiles = {m.name: dict(m.profile) for m in MATERIALS}
    for c in OBJECT_CLASSES:
        total = sum(w for _, w in c.materials)
        acc = {}
        for name, w in c.materials:
            for adj, pw in profiles[name].items():
                acc[adj] = acc.get(adj, 0.0) + pw * w / total
        lex[c.name.lower()] = norm(acc)
    return lex


def stratified_world_ids(size: int, seed: int, n_classes: int = len(OBJECT_CLASSES)
                         ) -> list[tuple[int, int]]:
    """(class index, instance) pairs of a stratified sample of the world's pool.

    Each class gets size // n_classes entries (the remainder goes to a seeded choice of
    classes), taken as a prefix of a seeded permutation of the class's pool, so smaller
    subsets are contained in larger ones. Past the pool (ImageNet's size: 1300 per class), a
    class's order goes on with the instances after its pool, in order, up to
    `CORPUS_MAX_PER_CLASS`, so a 1M corpus holds every entry of the full pool.
    """
    pool, most = n_classes * CORPUS_POOL_PER_CLASS, n_classes * CORPUS_MAX_PER_CLASS
    if not 0 < size <= most:
        raise ConfigError(f"size={size} must lie in [1, {most}] (the world renders at most "
                          f"{CORPUS_MAX_PER_CLASS} entries for each of its {n_classes} classes; "
                          f"its ImageNet-sized pool holds {pool})")
    rng = np.random.default_rng([seed, 31337])
    quota = np.full(n_classes, size // n_classes)
    quota[rng.permutation(n_classes)[: size % n_classes]] += 1
    beyond = np.arange(CORPUS_POOL_PER_CLASS, max(CORPUS_POOL_PER_CLASS, int(quota.max())))
    ids: list[tuple[int, int]] = []
    for c in range(n_classes):
        order = np.random.default_rng([seed, 4242, c]).permutation(CORPUS_POOL_PER_CLASS)
        ids.extend((c, int(i)) for i in np.concatenate([order, beyond])[: quota[c]])
    return ids


def read_image_folder(folder: str | os.PathLike) -> list[tuple[str, str, str]]:
    """(image path, class, description) rows of a folder in ImageNet's layout: one subfolder
    per class (its name, "_" read as a space, is the class name), image files inside it
    (`IMAGE_SUFFIXES`), sorted. Every image is opened and checked, so an unreadable one is
    refused before anything is written. The description is `FOLDER_DESCRIPTION`.

    Raises:
        DataNotFoundError: the folder does not exist.
        DataError: it is not a folder, holds no image in a class subfolder, or an image
            cannot be read.
    """
    folder = Path(folder)
    if not folder.exists():
        raise DataNotFoundError(f"image folder {folder} does not exist")
    if not folder.is_dir():
        raise DataError(f"{folder} is not a folder of images")
    rows = []
    for sub in sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")):
        class_name = " ".join(sub.name.replace("_", " ").split())
        for img in sorted(sub.iterdir()):
            if img.suffix.lower() not in IMAGE_SUFFIXES or img.name.startswith("."):
                continue
            _check_image(img)
            rows.append((str(img.resolve()), class_name,
                         FOLDER_DESCRIPTION.format(class_name=class_name)))
    if not rows:
        loose = [p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
        hint = (f" ({len(loose)} image(s) lie in the folder itself: put each in a subfolder "
                f"named after its class)") if loose else ""
        raise DataError(f"{folder} holds no image in a class subfolder "
                        f"(FOLDER/<class>/<image>, {', '.join(IMAGE_SUFFIXES)}){hint}")
    return rows


def _check_image(path: Path) -> None:
    """Refuse an image file PIL cannot read (its header and data checked, not decoded)."""
    try:
        with Image.open(path) as im:
            im.verify()
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as e:
        raise DataError(f"image {path} is unreadable: {e}") from e


def read_image_list(path: str | os.PathLike) -> list[tuple[str, str, str]]:
    """Read a real corpus list: a CSV with columns path, class, caption (header optional), a
    Parquet file with columns path, class and optionally caption, or a folder of images in
    ImageNet's layout (`read_image_folder`). Relative image paths are resolved against the
    list's folder."""
    path = Path(path)
    if path.is_dir():
        return read_image_folder(path)
    if not path.is_file():
        raise DataNotFoundError(f"image list {path} does not exist")
    if path.suffix.lower() == ".parquet":
        return _read_parquet_list(path)
    rows = []
    with open(path, newline="") as f:
        for n, row in enumerate(csv.reader(f), 1):
            if n == 1 and [c.strip().lower() for c in row[:3]] == ["path", "class", "caption"]:
                continue
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != 3:
                raise DataError(f"{path}:{n}: expected 3 columns (path, class, caption), "
                                f"got {len(row)}")
            img, cls, cap = (c.strip() for c in row)
            img_path = Path(img) if os.path.isabs(img) else path.parent / img
            if not img_path.is_file():
                raise DataNotFoundError(f"{path}:{n}: image {img_path} does not exist")
            rows.append((str(img_path), cls, cap))
    if not rows:
        raise DataError(f"image list {path} has no rows")
    return rows


def _read_parquet_list(path: Path) -> list[tuple[str, str, str]]:
    """A Parquet image list: columns path, class, optional caption."""
    import pyarrow.parquet as pq  # heavy; only Parquet lists need it

    try:
        table = pq.read_table(path).to_pydict()
    except (OSError, ValueError) as e:
        raise DataError(f"image list {path} is not readable Parquet: {e}") from e
    missing = {"path", "class"} - set(table)
    if missing:
        raise DataError(f"image list {path} lacks columns {sorted(missing)} "
                        f"(has {sorted(table)})")
    caps = table.get("caption") or [""] * len(table["path"])
    rows = []
    for n, (img, cls, cap) in enumerate(zip(table["path"], table["class"], caps), 1):
        img_path = Path(img) if os.path.isabs(img) else path.parent / img
        if not img_path.is_file():
            raise DataNotFoundError(f"{path}: row {n}: image {img_path} does not exist")
        rows.append((str(img_path), str(cls).strip(), str(cap or "").strip()))
    if not rows:
        raise DataError(f"image list {path} has no rows")
    return rows


def stratified_rows(rows: Sequence[tuple[str, str, str]], size: int, seed: int
                    ) -> list[tuple[str, str, str]]:
    """A class-stratified sample of a real list (all rows if size >= len(rows))."""
    if size >= len(rows):
        return list(rows)
    by_class: dict[str, list[int]] = {}
    for i, (_, cls, _) in enumerate(rows):
        by_class.setdefault(cls, []).append(i)
    rng = np.random.default_rng([seed, 777])
    classes = sorted(by_class)
    picked: list[int] = []
    # round-robin over shuffled classes keeps the class balance of a stratified sample
    queues = {c: list(rng.permutation(by_class[c])) for c in classes}
    while len(picked) < size:
        for c in classes:
            if queues[c] and len(picked) < size:
                picked.append(int(queues[c].pop()))
    return [rows[i] for i in sorted(picked)]


def build_corpus(out: str | os.PathLike, size: int | str = "10k", seed: int = 0,
                 recaption: RecaptionConfig | None = None, image_list: str | None = None,
                 world_cfg: WorldConfig | None = None, progress: bool = True,
                 resume: bool = False) -> dict:
    """Build an ImageNet-T corpus folder: `metadata.jsonl` and `manifest.json`.

    Written to a temporary folder first and moved into place at the end (the manifest last),
    so a failure or a kill leaves nothing a reader trusts; the staging a killed build left is
    removed by the next build into the folder. Refuses to overwrite an existing corpus; with
    `resume`, an existing corpus that is the one asked for (same size, seed, source and
    captioner) is kept and its manifest returned, and a different one is refused.

    Args:
        out: corpus folder.
        size: number of entries (10k, 50k, 100k, 150k or any count).
        seed: sampling seed (the world's seed too, unless world_cfg is given).
        recaption: recaptioner config (offline by default).
        image_list: CSV of (path, class, caption) for a real corpus; None for the world.
        world_cfg: world config for the default source.
        progress: show progress bars.
        resume: keep an existing corpus that is the one asked for (see above).

    Returns:
        The manifest.
    """
    n = parse_size(size)
    recaption = recaption or RecaptionConfig()
    out = Path(out)
    check_writable(out)
    if (out / MANIFEST).exists():
        asked = {"seed": seed, "source": source_name(image_list),
                 "captioner": recaption.backend}
        existing = existing_corpus(out, asked, n)
        if resume:
            return existing
        raise ConfigError(f"{out} already holds a corpus; choose another folder")
    for p in clean_stale_staging(out, ".partial-corpus-"):
        log.warning("removed the staging folder %s of a killed corpus build", p)
    t0 = time.perf_counter()
    if image_list is None:
        world = World(world_cfg or WorldConfig(seed=seed))
        ids = stratified_world_ids(n, seed)
        items = []
        for c, i in progress_bar(ids, desc="corpus plan", progress=progress):
            r = world.corpus_record(c, i)
            items.append((r.class_name, r.description, f"world:{world.cfg.seed}:{c}:{i}",
                          r.material))
    else:
        rows = stratified_rows(read_image_list(image_list), n, seed)
        items = [(cls, cap, img, "") for img, cls, cap in rows]
    recaptioner = create_recaptioner(recaption, world_lexicon(), progress=progress)
    pairs = [(cls, desc) for cls, desc, _, _ in items]
    captions = []
    for k in progress_bar(range(0, len(pairs), 512), desc="recaption", progress=progress):
        captions.extend(recaptioner.recaption_many(pairs[k:k + 512]))
    entries = [CorpusEntry(i, cls, desc, ", ".join(cap), src, mat)
               for i, ((cls, desc, src, mat), cap) in enumerate(zip(items, captions))]
    stats = recaptioner.stats() if hasattr(recaptioner, "stats") else {}
    manifest = {
        "kind": "imagenet-t", "size": len(entries), "seed": seed,
        "source": source_name(image_list),
        "n_classes": len({e.class_name for e in entries}),
        "captioner": recaption.backend, "captioner_stats": stats,
        "build_seconds": round(time.perf_counter() - t0, 2),
    }
    return write_corpus_metadata(out, entries, manifest)


def source_name(image_list: str | os.PathLike | None) -> str:
    """What a manifest calls a corpus's source: "world", a list's path as given, or an image
    folder's absolute path (so `corpus build --from-list` finds the corpus `corpus recaption`
    wrote from the same folder, however the folder is spelt)."""
    if image_list is None:
        return "world"
    return str(Path(image_list).resolve()) if Path(image_list).is_dir() else str(image_list)


def existing_corpus(out: Path, asked: dict, n: int) -> dict:
    """The manifest of the corpus in `out` when it is the one `asked` for (its seed, source
    and captioner, and `n` entries, or all of a shorter real list); a ConfigError naming the
    difference, and the way to replace it, when it is another."""
    manifest = json.loads((out / MANIFEST).read_text())
    diff = {k: (manifest.get(k), v) for k, v in asked.items() if manifest.get(k) != v}
    if manifest.get("size") != n and not (asked["source"] != "world"
                                          and manifest.get("size", n + 1) < n):
        diff["size"] = (manifest.get("size"), n)
    if diff:
        said = ", ".join(f"{k} {have!r} (asked {want!r})" for k, (have, want) in diff.items())
        raise ConfigError(f"{out} already holds another corpus: {said}; run `ratouch corpus "
                          f"build` with --overwrite to replace it, or choose another --out")
    return manifest


def write_corpus_metadata(out: Path, entries: list[CorpusEntry], manifest: dict) -> dict:
    """Write metadata and manifest (with the metadata checksum) atomically, the manifest last
    (it marks completion); returns the manifest. A corpus folder this call created is removed
    again when the write fails."""
    created = not out.exists()
    try:
        with staged(out, ".partial-corpus-") as tmp:
            h = hashlib.sha256()
            with open(tmp / METADATA, "w") as f:
                for e in entries:
                    line = json.dumps(asdict(e)) + "\n"
                    h.update(line.encode())
                    f.write(line)
            manifest = dict(manifest, metadata_sha256=h.hexdigest())
            (tmp / MANIFEST).write_text(json_text(manifest, indent=2, newline=False))
            publish(tmp, out, (METADATA, MANIFEST))
        return manifest
    except BaseException:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise


def load_corpus(folder: str | os.PathLike) -> tuple[dict, list[CorpusEntry]]:
    """Load and verify a corpus folder (manifest present, checksum and count match)."""
    folder = Path(folder)
    mpath = folder / MANIFEST
    if not mpath.is_file():
        raise DataNotFoundError(f"{folder} holds no corpus ({MANIFEST} missing)")
    try:
        manifest = json.loads(mpath.read_text())
        data = (folder / METADATA).read_bytes()
    except (OSError, json.JSONDecodeError) as e:
        raise DataError(f"corpus {folder} is unreadable: {e}") from e
    if hashlib.sha256(data).hexdigest() != manifest.get("metadata_sha256"):
        raise DataError(f"corpus {folder}: {METADATA} does not match its manifest checksum")
    entries = [CorpusEntry(**json.loads(line)) for line in data.decode().splitlines() if line]
    if len(entries) != manifest.get("size"):
        raise DataError(f"corpus {folder}: manifest says {manifest.get('size')} entries, "
                        f"found {len(entries)}")
    return manifest, entries


def parse_world_source(source: str) -> tuple[int, int, int]:
    """(seed, class index, instance) of a `world:<seed>:<class>:<instance>` source."""
    parts = source.split(":")
    if len(parts) != 4 or parts[0] != "world":
        raise DataError(f"source {source!r} is not a world source")
    return int(parts[1]), int(parts[2]), int(parts[3])


def _render_chunk(args: tuple[WorldConfig, list[tuple[int, int]], int]) -> list[np.ndarray]:

    cfg, ids, thumb = args
    world = world_for(cfg)
    out = []
    for c, i in ids:
        img = world.corpus_image(c, i)
        if thumb:
            img = resize_array(img, thumb)
        out.append(img)
    return out


def render_world_images(ids: Sequence[tuple[int, int]], cfg: WorldConfig, workers: int = 2,
                        chunk: int = 200, thumb: int = 0, progress: bool = True):
    """Render world corpus images (class index, instance) in parallel, yielding them in order
    in chunks of `chunk` images as (n, S, S, 3) uint8 arrays."""


    jobs = [(cfg, list(ids[k:k + chunk]), thumb) for k in range(0, len(ids), chunk)]
    bar = progress_bar(total=len(ids), desc="render corpus", unit="img", progress=progress)
    if workers == 1:
        results = map(_render_chunk, jobs)
        for imgs in results:
            bar.update(len(imgs))
            yield np.stack(imgs)
    else:
        world_for(cfg).warm()
        with worker_pool(workers) as pool:
            for imgs in pool.map(_render_chunk, jobs):
                bar.update(len(imgs))
                yield np.stack(imgs)
    bar.close()

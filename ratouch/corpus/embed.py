"""Embedding a corpus: image and text embeddings per entry, batched, resumable, memory-mapped.

Outputs live in `<corpus>/embeddings/<encoder>/`: `image.npy` and `text.npy` (float32, (N, D),
memory-mapped while written), `progress.json` (entries done; an interrupted run resumes there)
and, when complete, `manifest.json` (encoder id, the encoder's `weights_fingerprint` as
`encoder_weights`, dimension, count, checksums). Embeddings made with other weights of an
encoder (it was retrained) are refused, not used: their neighbours would be silently wrong.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np
from PIL import Image

from ratouch.checkpoint import sha256_file
from ratouch.corpus.imagenet_t import (
    CorpusEntry,
    load_corpus,
    parse_world_source,
    render_world_images,
)
from ratouch.errors import DataError, DataNotFoundError
from ratouch.files import write_json_atomic
from ratouch.images import to_rgb_array
from ratouch.threads import yield_to_foreground
from ratouch.timing import progress_bar
from ratouch.world.config import WorldConfig

log = logging.getLogger(__name__)

EMBED_MANIFEST = "manifest.json"


def embeddings_dir(corpus: str | os.PathLike, encoder_name: str) -> Path:
    return Path(corpus) / "embeddings" / encoder_name


def corpus_images(entries: Sequence[CorpusEntry], start: int, batch: int, workers: int,
                  progress: bool) -> Iterator[np.ndarray | list[np.ndarray]]:
    """Yield the images of entries[start:] in batches: world entries are re-rendered from
    their ids (in parallel), real entries read from their paths."""
    rest = entries[start:]
    if rest and rest[0].source.startswith("world:"):

        seeds = {parse_world_source(e.source)[0] for e in rest}
        if len(seeds) != 1:
            raise DataError(f"corpus mixes world seeds {sorted(seeds)}")
        ids = [parse_world_source(e.source)[1:] for e in rest]
        yield from render_world_images(ids, WorldConfig(seed=seeds.pop()), workers=workers,
                                       chunk=batch, progress=progress)
        return

    for k in progress_bar(range(0, len(rest), batch), progress, desc="read corpus images"):
        yield [read_corpus_image(e.source) for e in rest[k:k + batch]]


def read_corpus_image(path: str) -> np.ndarray:
    """A real corpus entry's image as an (H, W, 3) uint8 array."""
    try:
        with Image.open(path) as im:
            return to_rgb_array(im)
    except OSError as err:
        raise DataError(f"corpus image {path} is unreadable: {err}") from err


class CaptionEmbeddings:
    """Text embeddings of corpus captions, each distinct caption encoded once.

    Corpus captions repeat (the default 10k world corpus holds 2,043 distinct ones, and the
    number grows far slower than the corpus), and the text encoder is the slowest stage of a
    build, so a caption seen before is looked up instead of encoded again. The rows of new
    captions are encoded together, in one call per batch. Past ``limit`` distinct captions (a
    real corpus's LLM captions rarely repeat) the memory is cleared and starts again.
    """

    def __init__(self, encoders, limit: int = 200_000) -> None:
        self.encoders = encoders
        self.limit = limit
        self.rows: dict[str, np.ndarray] = {}

    def __call__(self, captions: Sequence[str]) -> np.ndarray:
        captions = [str(c) for c in captions]
        if not captions:
            return np.zeros((0, self.encoders.dim), np.float32)
        new = list(dict.fromkeys(c for c in captions if c not in self.rows))
        if len(self.rows) + len(new) > self.limit:
            self.rows = {}
            new = list(dict.fromkeys(captions))
        if new:
            self.rows.update(zip(new, np.asarray(self.encoders.encode_text(new), np.float32)))
        return np.stack([self.rows[c] for c in captions])


def embed_corpus(corpus: str | os.PathLike, encoders, batch: int = 500, workers: int = 2,
                 progress: bool = True) -> dict:
    """Embed every entry's image and tactile caption; resume an interrupted run.

    Args:
        corpus: corpus folder (see `ratouch.corpus.imagenet_t`).
        encoders: an encoder set (`create_model(...)`) with `name`, `dim`, encode_image/text.
        batch: entries per batch (one checkpoint of progress per batch).
        workers: processes rendering world images.
        progress: show progress bars.

    Returns:
        The embeddings manifest.
    """
    manifest, entries = load_corpus(corpus)
    out = embeddings_dir(corpus, encoders.name)
    done_manifest = out / EMBED_MANIFEST
    weights = encoders.weights_fingerprint
    if done_manifest.is_file():
        return load_embeddings(corpus, encoders.name, encoders.dim, weights=weights)[2]
    out.mkdir(parents=True, exist_ok=True)
    n, d = len(entries), encoders.dim
    state_path = out / "progress.json"
    state = json.loads(state_path.read_text()) if state_path.is_file() else {}
    if state and (state.get("count") != n or state.get("dim") != d
                  or state.get("corpus_sha256") != manifest["metadata_sha256"]):
        raise DataError(f"{out} holds a partial run for another corpus or encoder; delete it")
    if state and state.get("encoder_weights") != weights:
        # the same corpus and encoder, other weights: what was done is of no use
        log.info("%s holds a partial run made with other %s weights: starting again", out,
                 encoders.name)
        state = {}
    start = int(state.get("done", 0))
    mode = "r+" if start > 0 else "w+"
    img = np.lib.format.open_memmap(out / "image.npy", mode=mode, dtype=np.float32, shape=(n, d))
    txt = np.lib.format.open_memmap(out / "text.npy", mode=mode, dtype=np.float32, shape=(n, d))
    if start:
        log.info("resuming embedding of %s at %d / %d", corpus, start, n)
    pos = start
    captions = CaptionEmbeddings(encoders)
    for images in corpus_images(entries, start, batch, workers, progress):
        yield_to_foreground()  # a model prepared while queries are answered lets them go first
        m = len(images)
        img[pos:pos + m] = encoders.encode_image(list(images))
        txt[pos:pos + m] = captions([e.caption for e in entries[pos:pos + m]])
        pos += m
        img.flush()
        txt.flush()
        state = {"done": pos, "count": n, "dim": d, "corpus_sha256": manifest["metadata_sha256"],
                 "encoder_weights": weights}
        write_json_atomic(state_path, state, indent=None, newline=False)
    del img, txt
    emb_manifest = write_embeddings_manifest(out, encoders.name, weights, d, n,
                                             manifest["metadata_sha256"])
    state_path.unlink(missing_ok=True)
    return emb_manifest


def embedding_progress(corpus: str | os.PathLike, encoder_name: str) -> tuple[int, int] | None:
    """(entries done, entries) of an interrupted embedding of `corpus`, None when none is."""
    state_path = embeddings_dir(corpus, encoder_name) / "progress.json"
    try:
        state = json.loads(state_path.read_text())
        return int(state["done"]), int(state["count"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_embeddings_manifest(folder: Path, encoder: str, weights: str | None, dim: int,
                              count: int, corpus_sha256: str) -> dict:
    """Finish a corpus's embeddings in `folder` (``image.npy`` and ``text.npy`` in place): the
    manifest with their checksums, written atomically and last, since it marks them complete.
    The one writer of it (a local build's `embed_corpus`, a Ray build's assembly)."""
    emb_manifest = {"encoder": encoder, "encoder_weights": weights, "dim": dim, "count": count,
                    "corpus_sha256": corpus_sha256,
                    "image_sha256": sha256_file(folder / "image.npy"),
                    "text_sha256": sha256_file(folder / "text.npy")}
    write_json_atomic(folder / EMBED_MANIFEST, emb_manifest, indent=2, newline=False)
    return emb_manifest


def load_embeddings(corpus: str | os.PathLike, encoder_name: str, dim: int | None = None,
                    verify: bool = True, weights: str | None = None
                    ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Memory-map a corpus's finished embeddings, refusing mismatched or corrupt ones.

    Args:
        corpus: corpus folder.
        encoder_name: the encoder set's name.
        dim: the encoder's dimension, checked when given.
        verify: check the arrays' checksums (reads them whole).
        weights: the encoder's `weights_fingerprint`, checked when given (see
            `check_encoder_weights`).

    Returns:
        (image, text, manifest): the (N, D) arrays, memory-mapped, and the manifest.
    """
    out = embeddings_dir(corpus, encoder_name)
    mpath = out / EMBED_MANIFEST
    if not mpath.is_file():
        raise DataNotFoundError(f"no finished embeddings of {corpus} for encoder "
                                f"{encoder_name!r}: run `ratouch corpus build --out {corpus} "
                                f"--encoder {encoder_name}` (with the options that built it; "
                                f"it keeps the corpus and finishes the embeddings)")
    try:
        manifest = json.loads(mpath.read_bytes().decode("utf-8"))
    except (OSError, ValueError) as e:  # ValueError: bad JSON or UTF-8
        raise DataError(f"{mpath} is unreadable ({type(e).__name__}: {e}); build it again "
                        f"with `ratouch corpus build --out {corpus} --encoder {encoder_name}`"
                        ) from e
    if dim is not None and manifest["dim"] != dim:
        raise DataError(f"embeddings in {out} have dimension {manifest['dim']}, the encoder "
                        f"gives {dim}")
    check_encoder_weights(manifest, weights, corpus)
    if verify:
        for key in ("image", "text"):
            if sha256_file(out / f"{key}.npy") != manifest[f"{key}_sha256"]:
                raise DataError(f"{out / (key + '.npy')} is corrupt: checksum mismatch")
    img = np.load(out / "image.npy", mmap_mode="r")
    txt = np.load(out / "text.npy", mmap_mode="r")
    if img.shape != (manifest["count"], manifest["dim"]) or txt.shape != img.shape:
        raise DataError(f"embeddings in {out} have shapes {img.shape} / {txt.shape}, the "
                        f"manifest says ({manifest['count']}, {manifest['dim']})")
    return img, txt, manifest


def check_encoder_weights(manifest: dict, weights: str | None,
                          corpus: str | os.PathLike) -> None:
    """Refuse embeddings made with other weights of their encoder than `weights`.

    Embeddings that do not say which weights made them (written before ratouch recorded it,
    or by randomly initialised encoders) are used with a logged warning; `weights=None`
    (the caller's encoder has unidentified weights) checks nothing.

    Raises:
        DataError: the embeddings record other weights (the encoder was retrained or
            replaced since the corpus was embedded).
    """
    recorded = manifest.get("encoder_weights")
    if weights is None or recorded == weights:
        return
    name = manifest["encoder"]
    redo = (f"delete {embeddings_dir(corpus, name)} and {Path(corpus) / 'index' / name} and "
            f"embed the corpus again (ratouch.serve.pipeline.embed_and_index)")
    if recorded is None:
        log.warning("the %s embeddings of %s do not record which encoder weights made them; "
                    "if %s was retrained since, they are stale: %s", name, corpus, name, redo)
        return
    raise DataError(f"the {name} embeddings of {corpus} were made with other {name} weights "
                    f"(sha256 {recorded[:12]}...; the encoder's are {weights[:12]}...): the "
                    f"encoder was retrained or replaced since, and its neighbours would be "
                    f"wrong; {redo}")

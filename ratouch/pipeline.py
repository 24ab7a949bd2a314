"""The library's high-level entry points shared by the CLI and the app: build, embed and index
a corpus; open a retriever on it; the cached default corpus."""

from __future__ import annotations

import logging
import os
from pathlib import Path

from ratouch.corpus.imagenet_t import MANIFEST, build_corpus
from ratouch.embed import embed_corpus
from ratouch.encoders.factory import create_model
from ratouch.index import IndexConfig
from ratouch.retrieval import CorpusIndex, Retriever

log = logging.getLogger(__name__)


def cache_dir() -> Path:
    """Where cached corpora live: $RATOUCH_CACHE, else ~/.cache/ratouch."""
    return Path(os.environ.get("RATOUCH_CACHE", Path.home() / ".cache" / "ratouch"))


def embed_and_index(corpus: str | os.PathLike, encoder: str = "default-s",
                    index: str = "flat", workers: int = 2, progress: bool = True) -> dict:
    """Embed a built corpus with an encoder and build (or check) its indexes."""
    model = create_model(encoder)
    emb = embed_corpus(corpus, model, workers=workers, progress=progress)
    CorpusIndex(corpus, model.name, model.dim, IndexConfig(kind=index))
    return {"encoder": model.name, "dim": model.dim, "index": index,
            "embedded": emb["count"]}


def default_corpus(encoder: str = "default-s", size: str = "10k", seed: int = 0,
                   progress: bool = True) -> Path:
    """The world's ImageNet-T corpus of `size`, built, embedded and indexed on first use and
    cached (a later call finds it ready)."""
    folder = cache_dir() / f"imagenet-t-{size}-seed{seed}"
    if not (folder / MANIFEST).is_file():
        log.info("building the default corpus in %s (first use)", folder)
        build_corpus(folder, size, seed=seed, progress=progress)
    embed_and_index(folder, encoder, progress=progress)
    return folder


def open_retriever(corpus: str | os.PathLike, encoder: str = "default-s",
                   index: str = "flat", pretrained="shipped") -> Retriever:
    """Encoders + the corpus's index, checked against each other."""
    model = create_model(encoder, pretrained=pretrained)
    return Retriever(model, CorpusIndex(corpus, model.name, model.dim, IndexConfig(kind=index)))

"""Retrieval from ImageNet-T in the paper's five settings (Table 4).

Query modality -> key modality: image->image, image->text, tactile->image, tactile->text, and
joint->text (the Tactile-Guided Retriever's query, supplied by the caller once it exists).
Cosine top-K through the index; results carry ids, scores, class names, captions and sources
(from which thumbnails are made).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image

from ratouch.corpus.embed import check_encoder_weights, load_embeddings
from ratouch.corpus.imagenet_t import CorpusEntry, load_corpus, parse_world_source
from ratouch.errors import ConfigError, DataError
from ratouch.search.index import IndexConfig, VectorIndex
from ratouch.search.modes import QUERY_MODES, JointQuery
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for


def mode_query(mode: str, V: np.ndarray, T: np.ndarray, joint_query: JointQuery) -> np.ndarray:
    """A query mode's (N, D) C-contiguous float32 query vectors from the visual embeddings `V`,
    the tactile ones `T` and the Tactile-Guided Retriever's `joint_query` (e.g.
    `RATouchPipeline.joint_query`), as its row in `QUERY_MODES` makes them."""
    return QUERY_MODES[mode].vectors(V, T, joint_query)


def retrieval_settings() -> dict[str, tuple[str, str]]:
    """The retrieval settings, "<mode>_<key>" -> (query mode, key modality): every mode against
    each key its row names (the paper's five of Table 4 for the built-in modes)."""
    return {f"{m}_{key}": (m, key) for m, row in QUERY_MODES.items() for key in row.keys}


@dataclass(frozen=True)
class Neighbour:
    id: int
    score: float
    class_name: str
    caption: str
    description: str
    source: str
    material: str


def index_folder(corpus: str | os.PathLike, encoder_name: str, key: str, kind: str) -> Path:
    """Where a corpus's index of one key modality and kind lives."""
    return Path(corpus) / "index" / encoder_name / f"{key}-{kind}"


class CorpusIndex:
    """A corpus with its embeddings and one index per key modality (image, text).

    Indexes are built on first use and saved under `<corpus>/index/<encoder>/`; later loads
    check them against the embeddings' encoder, dimension and checksum and refuse a mismatch.
    `weights` (the encoder's `weights_fingerprint`) refuses embeddings made with other weights
    of the encoder (see `check_encoder_weights`); `CorpusSearch` checks its encoders' too.
    """

    def __init__(self, corpus: str | os.PathLike, encoder_name: str, dim: int,
                 index_cfg: IndexConfig | None = None, weights: str | None = None):
        self.folder = Path(corpus)
        self.manifest, self.entries = load_corpus(self.folder)
        img, txt, emb_manifest = load_embeddings(self.folder, encoder_name, dim, weights=weights)
        if emb_manifest["corpus_sha256"] != self.manifest["metadata_sha256"]:
            raise DataError(f"embeddings of {corpus} were made for another version of it")
        self.embeddings_manifest = emb_manifest
        self.encoder_name, self.dim = encoder_name, dim
        self.cfg = index_cfg or IndexConfig()
        self.indexes = {key: self._index(key, emb) for key, emb in (("image", img), ("text", txt))}

    def _index(self, key: str, emb: np.ndarray) -> VectorIndex:
        folder = index_folder(self.folder, self.encoder_name, key, self.cfg.kind)
        if (folder / "manifest.json").is_file():
            try:
                index, meta = VectorIndex.load(folder, expected_dim=self.dim,
                                               expected_encoder=self.encoder_name)
            except DataError as e:
                raise DataError(f"{e}; `ratouch corpus build --out {self.folder} --encoder "
                                f"{self.encoder_name} --index {self.cfg.kind} --reindex` "
                                f"builds it again") from e
            if meta.get("corpus_sha256") != self.manifest["metadata_sha256"]:
                raise DataError(f"index {folder} was built for another version of the corpus")
            built_from = meta.get("embeddings_sha256")  # absent in indexes of older versions
            if built_from is not None and built_from != self.embeddings_manifest[f"{key}_sha256"]:
                raise DataError(f"index {folder} was built from other {self.encoder_name} "
                                f"embeddings of the corpus (it was embedded again since); "
                                f"delete {folder} and it is built again")
            return index
        index = VectorIndex.build(np.asarray(emb), self.cfg)
        index.save(folder, {"encoder": self.encoder_name, "key": key,
                            "corpus_sha256": self.manifest["metadata_sha256"],
                            "embeddings_sha256": self.embeddings_manifest[f"{key}_sha256"]})
        return index

    def __len__(self) -> int:
        return len(self.entries)

    def search(self, key: str, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        if key not in self.indexes:
            raise ConfigError(f"key modality {key!r} must be 'image' or 'text'")
        return self.indexes[key].search(queries, k)

    def search_each(self, key: str, blocks: Sequence[np.ndarray], ks: Sequence[int]
                    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Each block of queries (one request's) searched on its own at its K, ties broken by
        corpus id (`stable_top`): what a request gets never depends on the requests searched
        with it (faiss takes another code path, with other float rounding, for a larger
        batch of queries, and returns equal scores in no set order).

        Returns:
            Per block, its ((n, k) scores, (n, k) ids).
        """
        n = len(self.entries)
        out = []
        for q, k in zip(blocks, ks):
            scores, ids = self.search(key, q, min(n, k + TIE_MARGIN))
            out.append(stable_top(scores, ids, k))
        return out

    def entry(self, i: int) -> CorpusEntry:
        return self.entries[i]

    def thumbnail(self, i: int, size: int = 96) -> np.ndarray:
        """The entry's image, re-rendered (world) or read (real corpus), as a thumbnail."""
        e = self.entries[i]
        if e.source.startswith("world:"):

            seed, c, inst = parse_world_source(e.source)
            img = Image.fromarray(world_for(WorldConfig(seed=seed)).corpus_image(c, inst))
        else:
            with Image.open(e.source) as im:
                img = im.convert("RGB")
        img.thumbnail((size, size))
        return np.asarray(img)


#: Candidates fetched beyond K, so that entries tied with the K-th are chosen by corpus id.
TIE_MARGIN = 8
#: Decimals a neighbour's score is ranked by (those a result shows); equal ones go by id.
SCORE_DECIMALS = 4


def stable_top(scores: np.ndarray, ids: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The first `k` of each row of search results, ranked by score at the decimals a result
    shows, then by corpus id: entries tied at those decimals (e.g. identical captions) are
    always ranked, and chosen at the K-th place, the same way."""
    order = np.lexsort((ids, -np.round(scores, SCORE_DECIMALS)), axis=-1)[:, :k]  # (n, k)
    return np.take_along_axis(scores, order, -1), np.take_along_axis(ids, order, -1)


class CorpusSearch:
    """Encoders + a corpus index: queries in, neighbours per setting out."""

    def __init__(self, encoders, corpus_index: CorpusIndex):
        if encoders.dim != corpus_index.dim or encoders.name != corpus_index.encoder_name:
            raise DataError(f"corpus was embedded with {corpus_index.encoder_name!r} "
                            f"(dimension {corpus_index.dim}); the encoder is {encoders.name!r} "
                            f"(dimension {encoders.dim})")
        check_encoder_weights(corpus_index.embeddings_manifest,
                              getattr(encoders, "weights_fingerprint", None), corpus_index.folder)
        self.encoders = encoders
        self.corpus = corpus_index

    def embed_queries(self, images: Sequence[np.ndarray] | None = None,
                      tactiles: Sequence[np.ndarray] | None = None,
                      backgrounds: Sequence[np.ndarray | None] | None = None,
                      joint_query: JointQuery | None = None) -> dict[str, np.ndarray]:
        """Query vectors of every mode (`QUERY_MODES`) whose inputs are given: images are
        visual crops (the contact box), tactiles frames, `joint_query` the Tactile-Guided
        Retriever (modes that need it are left out without it)."""
        V = None if images is None else self.encoders.encode_image(list(images))
        T = None if tactiles is None else self.encoders.encode_tactile(list(tactiles),
                                                                      backgrounds)
        have = {name for name, x in (("image", V), ("tactile", T), ("retriever", joint_query))
                if x is not None}
        return {m: row.vectors(V, T, joint_query) for m, row in QUERY_MODES.items()
                if row.available(have)}

    def retrieve(self, queries: dict[str, np.ndarray], k: int = 5,
                 settings: Sequence[str] | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Top-k (scores, ids) per setting, batched over queries.

        Args:
            queries: {mode: (Q, D)} for any of `QUERY_MODES`.
            k: neighbours per query.
            settings: names from `retrieval_settings()`; default every setting whose query is given.
        """
        if k < 1 or k > len(self.corpus):
            raise ConfigError(f"K={k} must lie in [1, {len(self.corpus)}] (the corpus size)")
        known = retrieval_settings()
        names = list(settings) if settings else [s for s, (q, _) in known.items()
                                                if q in queries]
        out = {}
        for name in names:
            if name not in known:
                raise ConfigError(f"unknown retrieval setting {name!r}; known: {list(known)}")
            q, key = known[name]
            if q not in queries:
                raise ConfigError(f"setting {name!r} needs a {q} query")
            out[name] = self.corpus.search(key, queries[q], k)
        return out

    def neighbours(self, scores: np.ndarray, ids: np.ndarray) -> list[Neighbour]:
        """Describe one query's top-k (1-D scores and ids)."""
        out = []
        for s, i in zip(scores, ids):
            e = self.corpus.entry(int(i))
            out.append(Neighbour(int(i), float(s), e.class_name, e.caption, e.description,
                                 e.source, e.material))
        return out

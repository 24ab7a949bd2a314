"""The retrieval side of RA-Touch: a corpus embedded and indexed, the encoders and the index
opened together, and the Tactile-Guided Retriever's joint query with its neighbours.

Training (the generators read each pair's joint-query neighbours), evaluation and serving all
use it; `ratouch.serve.pipeline.RATouchPipeline` is this side plus the generators, the trust
signals and the PCA frame.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import threading
from pathlib import Path

import numpy as np
import torch

from ratouch.checkpoint import load_into, read_checkpoint
from ratouch.corpus.embed import EMBED_MANIFEST, embed_corpus, embeddings_dir, load_embeddings
from ratouch.corpus.imagenet_t import MANIFEST, build_corpus
from ratouch.encoders.factory import create_model, shipped_fingerprint
from ratouch.errors import ConfigError
from ratouch.model.gate import TouchGate
from ratouch.model.press_map import PressMap
from ratouch.model.retriever import RetrieverConfig, TactileGuidedRetriever
from ratouch.paths import cache_dir, retriever_weights, touch_gate
from ratouch.paths import press_map as press_map_path
from ratouch.search.index import IndexConfig
from ratouch.search.retrieval import CorpusIndex, CorpusSearch

#: What `RetrievalSide.corpus_embeddings` serves.
CORPUS_EMBEDDING_KINDS = ("image", "tactile_caption", "class_name", "visual_description")

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------
# the corpus: built, embedded, indexed

def embed_and_index(corpus: str | os.PathLike, encoder: str = "default-s",
                    index: str = "flat", workers: int = 2, progress: bool = True) -> dict:
    """Embed a built corpus with an encoder and build (or check) its indexes."""
    model = create_model(encoder)
    emb = embed_corpus(corpus, model, workers=workers, progress=progress)  # checks the weights
    CorpusIndex(corpus, model.name, model.dim, IndexConfig(kind=index))
    return {"encoder": model.name, "dim": model.dim, "index": index, "embedded": emb["count"]}


def default_corpus(encoder: str = "default-s", size: str = "10k", seed: int = 0,
                   progress: bool = True) -> Path:
    """The world's ImageNet-T corpus of `size`, built, embedded and indexed on first use and
    cached (a later call finds it ready). Embeddings made with other weights of the encoder
    than the shipped ones (it was retrained since), or that do not say which, are made again."""
    folder = cache_dir() / f"imagenet-t-{size}-seed{seed}"
    if not (folder / MANIFEST).is_file():
        log.info("building the default corpus in %s (first use)", folder)
        build_corpus(folder, size, seed=seed, progress=progress)
    done = embeddings_dir(folder, encoder) / EMBED_MANIFEST
    if done.is_file():
        made_with = _embedded_with(done)
        if made_with != shipped_fingerprint(encoder):
            log.info("re-embedding the default corpus %s with %s: its embeddings were made "
                     "with other weights (%s), not the shipped ones", folder, encoder,
                     "not recorded" if made_with is None else f"sha256 {made_with[:12]}...")
            drop_embeddings(encoder, size, seed)
    if not done.is_file():
        embed_and_index(folder, encoder, progress=progress)  # the index is checked on open
    return folder


def _embedded_with(manifest: Path) -> str | None:
    """The encoder weights an embeddings manifest records (None: not recorded, or unreadable;
    the default corpus is a cache, made again either way)."""
    try:
        return json.loads(manifest.read_text()).get("encoder_weights")
    except (OSError, ValueError, AttributeError):
        return None


def drop_embeddings(encoder: str, size: str = "10k", seed: int = 0) -> None:
    """Delete the default corpus's embeddings and indexes of an encoder (after retraining it),
    so that `default_corpus` embeds it again; the corpus itself is kept."""
    folder = cache_dir() / f"imagenet-t-{size}-seed{seed}"
    for part in (embeddings_dir(folder, encoder), folder / "index" / encoder):
        if part.is_dir():
            shutil.rmtree(part)


def open_retriever(corpus: str | os.PathLike, encoder: str = "default-s",
                   index: str = "flat", pretrained="shipped") -> CorpusSearch:
    """Encoders + the corpus's index, checked against each other (name, dimension, and the
    weights that embedded the corpus: see `ratouch.corpus.embed.check_encoder_weights`)."""
    model = create_model(encoder, pretrained=pretrained)
    return CorpusSearch(model, CorpusIndex(corpus, model.name, model.dim, IndexConfig(kind=index)))


def load_tgr(encoder: str, folder: str | os.PathLike | None = None):
    """The frozen Tactile-Guided Retriever trained for an encoder (the shipped one in assets/,
    or the one saved in `folder`, e.g. an ablation trained into the cache)."""
    folder = Path(folder) if folder is not None else retriever_weights(encoder)
    state, cfg, _ = read_checkpoint(folder)
    cfg = {k: v for k, v in cfg.items() if k != "kind"}
    model = TactileGuidedRetriever(RetrieverConfig(**cfg))
    load_into(model, state, str(folder))
    return model.eval()


def load_press_map(encoder: str) -> PressMap | None:
    """The shipped press map of an encoder set, or None (logged) when there is none."""
    path = press_map_path(encoder)
    if not path.is_file():
        log.warning("no press map for %s (%s): `ratouch train press-map --encoder %s`",
                    encoder, path, encoder)
        return None
    return PressMap.load(path)


def load_gate(encoder: str, trust) -> TouchGate | None:
    """The shipped touch gate of an encoder set, reading novelty with `trust` (the encoder
    set's trust calibration); None (logged) when either is missing."""
    path = touch_gate(encoder)
    if trust is None or not path.is_file():
        log.warning("no touch gate for %s (%s%s): `ratouch train gate --encoder %s`", encoder,
                    path, "" if trust is not None else "; no trust calibration either", encoder)
        return None
    return TouchGate.load(path).with_novelty(trust.tactile, trust.visual)


# ---------------------------------------------------------------------------------------------
# the joint query and its neighbours

class RetrievalSide:
    """Encoders, the corpus index and the Tactile-Guided Retriever, read-only once loaded (the
    corpus embeddings of other caption kinds are computed once, on first use, thread-safely).

    Args:
        retriever: the encoders and the corpus's index (`open_retriever`).
        tgr: the trained Tactile-Guided Retriever (`load_tgr`).
    """

    def __init__(self, retriever: CorpusSearch, tgr):
        self.retriever = retriever
        self.encoders = retriever.encoders
        self.corpus = retriever.corpus
        self.tgr = tgr
        image_emb, text_emb, _ = load_embeddings(
            self.corpus.folder, self.encoders.name, self.encoders.dim, verify=False)
        self._corpus_emb: dict[str, np.ndarray] = {"image": image_emb,
                                                   "tactile_caption": text_emb}
        self._emb_lock = threading.Lock()
        #: the touch gate of the gated query (`ratouch.model.gate`), with the trust
        #: calibration's novelty models; None: the gated query is the paper's (warned once)
        self.gate: TouchGate | None = None
        self._gate_warned = False
        #: the press map of the adapted tactile query (`ratouch.model.press_map`); None: the
        #: adapted query is the tactile embedding itself (warned once)
        self.press_map: PressMap | None = None
        self._map_warned = False

    @classmethod
    def load(cls, encoder: str = "default-s", corpus: str | os.PathLike | None = None,
             index: str = "flat", progress: bool = False) -> "RetrievalSide":
        """The shipped retrieval side of an encoder set; the default corpus is built on first
        use."""
        corpus = corpus or default_corpus(encoder, progress=progress)
        return cls(open_retriever(corpus, encoder, index), load_tgr(encoder))

    def joint_query(self, V: np.ndarray, T: np.ndarray, tgr=None, gated: bool = False,
                    adapted: bool = False) -> np.ndarray:
        """The Tactile-Guided Retriever's joint query Q for (N, D) visual and tactile
        embeddings (`tgr`: another trained retriever, e.g. an ablation's; default this
        side's own); `gated`: the trust-gated query instead (`gated_query`); `adapted`: the
        tactile query through the press map instead (`adapted_query`; V is not read)."""
        if adapted:
            return self.adapted_query(T)
        with torch.no_grad():
            J = (tgr or self.tgr)(torch.from_numpy(np.ascontiguousarray(V, np.float32)),
                                  torch.from_numpy(np.ascontiguousarray(T, np.float32))
                                  ).query.numpy()
        return self._gated(V, T, J)[0] if gated else J

    def adapted_query(self, T: np.ndarray) -> np.ndarray:
        """(N, D) tactile queries through the press map (`ratouch.model.press_map`): brought
        back towards their material's captions for the presses people make; without a map,
        the tactile embeddings themselves (warned once)."""
        if self.press_map is None:
            if not self._map_warned:
                log.warning("no press map for %s: the adapted tactile query is the tactile "
                            "embedding (`ratouch train press-map --encoder %s`)",
                            self.encoders.name, self.encoders.name)
                self._map_warned = True
            return np.ascontiguousarray(T, np.float32)
        return self.press_map.apply(T)

    def gated_query(self, V: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((N, D) trust-gated queries, (N,) touch weights): the joint query moved towards
        the image query as far as touch cannot be trusted (`ratouch.model.gate`)."""
        return self._gated(V, T, self.joint_query(V, T))

    def _gated(self, V: np.ndarray, T: np.ndarray, J: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        if self.gate is None:
            if not self._gate_warned:
                log.warning("no touch gate for %s: the gated query is the paper's joint query "
                            "(`ratouch train gate --encoder %s`)", self.encoders.name,
                            self.encoders.name)
                self._gate_warned = True
            return J, np.ones(len(J))
        return self.gate.query(V, T, J)

    def joint_neighbours(self, V: np.ndarray, T: np.ndarray, k: int, batch: int = 1024,
                         gated: bool = False) -> np.ndarray:
        """(N, k) corpus ids of the joint query's top-k against the text index, in batches
        (`gated`: the trust-gated query's)."""
        return np.concatenate([
            self.corpus.search("text", self.joint_query(V[s:s + batch], T[s:s + batch],
                                                        gated=gated), k)[1]
            for s in range(0, len(V), batch)])

    def corpus_embeddings(self, kind: str) -> np.ndarray:
        """Corpus embeddings of one kind, (N, D): "image", "tactile_caption" (the indexed
        text; memory-mapped), or the text embeddings of the entries' "class_name" or
        "visual_description" (Table 3; encoded on first use, then kept)."""
        if kind in self._corpus_emb:
            return self._corpus_emb[kind]
        entries = self.corpus.entries
        with self._emb_lock:
            if kind == "class_name":
                names = sorted({e.class_name for e in entries})
                row = {n: i for i, n in enumerate(names)}
                emb = self.encoders.encode_text(names)[[row[e.class_name] for e in entries]]
            elif kind == "visual_description":
                emb = self.encoders.encode_text([e.description for e in entries])
            else:
                raise ConfigError(f"corpus embeddings: unknown kind {kind!r}; one of "
                                  f"{', '.join(CORPUS_EMBEDDING_KINDS)}")
            self._corpus_emb[kind] = emb
        return emb

    def neighbour_embeddings(self, ids: np.ndarray, image_kind: str = "image",
                             text_kind: str = "tactile_caption"
                             ) -> tuple[np.ndarray, np.ndarray]:
        """(Rv, Rl): image and text embeddings of retrieved entries `ids` (B, K), each
        (B, K, D); the kinds are those of `corpus_embeddings`."""
        flat = ids.reshape(-1)
        order = np.argsort(flat)  # memory-mapped arrays read fastest in index order
        rv = np.empty((len(flat), self.encoders.dim), np.float32)
        rl = np.empty_like(rv)
        rv[order] = self.corpus_embeddings(image_kind)[flat[order]]
        rl[order] = self.corpus_embeddings(text_kind)[flat[order]]
        return rv.reshape(*ids.shape, -1), rl.reshape(*ids.shape, -1)

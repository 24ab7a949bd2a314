"""The library's high-level entry points shared by the CLI and the app: build, embed and index a
corpus; open a retriever on it; the cached default corpus; and the RA-Touch query pipeline
(`RATouchPipeline.query`), whose JSON-ready output `ratouch query` prints and the app shows."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ratouch.corpus.imagenet_t import MANIFEST, build_corpus
from ratouch.embed import EMBED_MANIFEST, embed_corpus, embeddings_dir, load_embeddings
from ratouch.encoders.factory import ASSETS, create_model
from ratouch.index import IndexConfig
from ratouch.pca import PCA2D
from ratouch.retrieval import CorpusIndex, Retriever

log = logging.getLogger(__name__)

# The three galleries: each query modality against the corpus's text embeddings (Table 4).
MODES = {"image": ("image", "text"), "tactile": ("tactile", "text"), "joint": ("joint", "text")}


def cache_dir() -> Path:
    """Where cached corpora and training data live: $RATOUCH_CACHE, else ~/.cache/ratouch."""
    return Path(os.environ.get("RATOUCH_CACHE", Path.home() / ".cache" / "ratouch"))


def embed_and_index(corpus: str | os.PathLike, encoder: str = "default-s",
                    index: str = "flat", workers: int = 2, progress: bool = True) -> dict:
    """Embed a built corpus with an encoder and build (or check) its indexes."""
    model = create_model(encoder)
    emb = embed_corpus(corpus, model, workers=workers, progress=progress)
    CorpusIndex(corpus, model.name, model.dim, IndexConfig(kind=index))
    return {"encoder": model.name, "dim": model.dim, "index": index, "embedded": emb["count"]}


def default_corpus(encoder: str = "default-s", size: str = "10k", seed: int = 0,
                   progress: bool = True) -> Path:
    """The world's ImageNet-T corpus of `size`, built, embedded and indexed on first use and
    cached (a later call finds it ready)."""
    folder = cache_dir() / f"imagenet-t-{size}-seed{seed}"
    if not (folder / MANIFEST).is_file():
        log.info("building the default corpus in %s (first use)", folder)
        build_corpus(folder, size, seed=seed, progress=progress)
    if not (embeddings_dir(folder, encoder) / EMBED_MANIFEST).is_file():
        embed_and_index(folder, encoder, progress=progress)  # the index is checked on open
    return folder


def open_retriever(corpus: str | os.PathLike, encoder: str = "default-s",
                   index: str = "flat", pretrained="shipped") -> Retriever:
    """Encoders + the corpus's index, checked against each other."""
    model = create_model(encoder, pretrained=pretrained)
    return Retriever(model, CorpusIndex(corpus, model.name, model.dim, IndexConfig(kind=index)))


# ---------------------------------------------------------------------------------------------
# the query pipeline

def retriever_weights(encoder: str) -> Path:
    return ASSETS / "retriever" / encoder


def generator_weights(encoder: str, kind: str) -> Path:
    return ASSETS / "generator" / encoder / kind


def integrator_factory(cfg: dict):
    """Rebuild a saved Texture-Aware Integrator from its config."""
    from ratouch.integrator import IntegratorConfig, TextureAwareIntegrator

    return TextureAwareIntegrator(IntegratorConfig(**cfg))


def load_tgr(encoder: str, folder: str | os.PathLike | None = None):
    """The frozen Tactile-Guided Retriever trained for an encoder (the shipped one in assets/,
    or the one saved in `folder`, e.g. an ablation trained into the cache)."""
    from ratouch.checkpoint import load_into, read_checkpoint
    from ratouch.retriever import RetrieverConfig, TactileGuidedRetriever

    folder = Path(folder) if folder is not None else retriever_weights(encoder)
    state, cfg, _ = read_checkpoint(folder)
    cfg = {k: v for k, v in cfg.items() if k != "kind"}
    model = TactileGuidedRetriever(RetrieverConfig(**cfg))
    load_into(model, state, str(folder))
    return model.eval()


class RATouchPipeline:
    """Encoders, corpus index, Tactile-Guided Retriever, the two generators and the PCA frame.

    Read-only once loaded; `query` may be called from several threads.
    """

    def __init__(self, retriever: Retriever, tgr, generator_ra, generator_base,
                 pca: PCA2D | None = None):
        self.retriever = retriever
        self.encoders = retriever.encoders
        self.corpus = retriever.corpus
        self.tgr = tgr
        self.generator_ra = generator_ra
        self.generator_base = generator_base
        self._image_emb, self._text_emb, _ = load_embeddings(
            self.corpus.folder, self.encoders.name, self.encoders.dim, verify=False)
        # the fixed reference frame: the first 2000 entries' image and text embeddings
        self.pca = pca or PCA2D.fit(np.concatenate([np.asarray(self._image_emb[:2000]),
                                                    np.asarray(self._text_emb[:2000])]))

    @classmethod
    def load(cls, encoder: str = "default-s", corpus: str | os.PathLike | None = None,
             index: str = "flat", progress: bool = False) -> "RATouchPipeline":
        """Load everything for an encoder; the default corpus is built on first use."""
        from ratouch.generator import load_generator

        corpus = corpus or default_corpus(encoder, progress=progress)
        retriever = open_retriever(corpus, encoder, index)
        tgr = load_tgr(encoder)
        gen_ra = load_generator(generator_weights(encoder, "ra"), integrator_factory)
        gen_base = load_generator(generator_weights(encoder, "baseline"))
        for gen in (gen_ra, gen_base):  # inference only: fold LoRA into the weights
            gen.decoder.merge_lora()
        return cls(retriever, tgr, gen_ra, gen_base)

    def joint_query(self, V: np.ndarray, T: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.tgr(torch.from_numpy(V), torch.from_numpy(T)).query.numpy()

    def neighbour_embeddings(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Rv, Rl): image and text embeddings of retrieved entries, (B, K, D) each."""
        flat = ids.reshape(-1)
        order = np.argsort(flat)  # memory-mapped arrays read fastest in index order
        rv = np.empty((len(flat), self.encoders.dim), np.float32)
        rl = np.empty_like(rv)
        rv[order] = self._image_emb[flat[order]]
        rl[order] = self._text_emb[flat[order]]
        return rv.reshape(*ids.shape, -1), rl.reshape(*ids.shape, -1)

    def describe(self, V: np.ndarray, T: np.ndarray, ids: np.ndarray | None) -> list[str]:
        """RA-Touch descriptions (with the neighbours `ids`) or baseline ones (ids None)."""
        v, t = torch.from_numpy(V), torch.from_numpy(T)
        with torch.no_grad():
            if ids is None:
                return self.generator_base.describe(v, t)
            rv, rl = self.neighbour_embeddings(ids)
            return self.generator_ra.describe(v, t, torch.from_numpy(rv), torch.from_numpy(rl))

    def query(self, visual: Any, tactile: Any = None, box=None, k: int = 5,
              label: str | None = None) -> dict:
        """Run the whole RA-Touch query for one visuo-tactile pair.

        Args:
            visual: the visual image (array, PIL image or path).
            tactile: the tactile image, or None (image-only retrieval, said in `warnings`).
            box: contact box (x0, y0, x1, y1) in pixels of the visual image; None uses TVL's
                centred crop and says so in `warnings`.
            k: neighbours per mode.
            label: the ground-truth tactile caption, when known (plotted in the PCA).

        Returns:
            {"neighbours": {"image"|"tactile"|"joint": [{"id", "score", "class_name",
            "caption", "description", "source"}]}, "description": {"ra_touch", "baseline"},
            "pca": {"points": [{"role", "x", "y", "id"?}], "explained": [..]},
            "timings_ms": {stage: ms, ..., "total": ms}, "warnings": [...], "box": [...]}
        """
        from ratouch.serving import query_many  # the one implementation, batched or not

        out = query_many(self, [{"visual": visual, "tactile": tactile, "box": box, "k": k,
                                 "label": label}])[0]
        if isinstance(out, Exception):
            raise out
        return out

    def _neighbour(self, i: int, score: float) -> dict:
        e = self.corpus.entry(int(i))
        return {"id": int(i), "score": round(float(score), 4), "class_name": e.class_name,
                "caption": e.caption, "description": e.description, "source": e.source}

    def _pca_points(self, queries: dict, results: dict, label: str | None) -> list[dict]:
        pts = []
        for mode, q in queries.items():
            x, y = self.pca.project(q)[0]
            pts.append({"role": f"query_{mode}", "x": float(x), "y": float(y)})
        for mode, (_, ids) in results.items():
            xy = self.pca.project(self._text_emb[np.sort(ids[0])])
            for i, (x, y) in zip(np.sort(ids[0]), xy):
                pts.append({"role": f"neighbour_{mode}", "x": float(x), "y": float(y),
                            "id": int(i)})
        if label:
            x, y = self.pca.project(self.encoders.encode_text([label]))[0]
            pts.append({"role": "ground_truth", "x": float(x), "y": float(y)})
        return pts

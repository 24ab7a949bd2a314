"""The RA-Touch query pipeline, the one place a query is answered, and how it is assembled.

`RATouchPipeline.query_many` answers requests (one or several at once: batched encoders, one
index search, batched generation); `query` is `query_many` of one request. Its JSON-ready
output is what `ratouch query` prints and the app shows. Around it: build, embed and index a
corpus, open a search on it, the cached default corpus, and load the trained models.

The three galleries are the three query modes (`QUERY_MODES`), each against the corpus's
text embeddings (Table 4's x->text settings).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import threading
import time
from pathlib import Path
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from PIL import Image

from ratouch.checkpoint import load_into, read_checkpoint
from ratouch.corpus.embed import (
    EMBED_MANIFEST,
    embed_corpus,
    embeddings_dir,
    load_embeddings,
)
from ratouch.corpus.imagenet_t import MANIFEST, build_corpus
from ratouch.encoders.factory import create_model, shipped_fingerprint
from ratouch.encoders.preprocess import (
    QUERY_MAX_SIDE,
    crop_box,
    oriented_size,
    to_rgb_array,
    tvl_contact_box,
)
from ratouch.errors import ConfigError, DataError, RATouchError
from ratouch.model.fastpath import StackCache
from ratouch.model.generator import describe_together, load_generator
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.model.neighbour_tokens import KIND as NEIGHBOUR_TOKENS
from ratouch.model.neighbour_tokens import NeighbourTokens, NeighbourTokensConfig
from ratouch.model.retriever import RetrieverConfig, TactileGuidedRetriever
from ratouch.paths import (
    cache_dir,
    generator_weights,
    retriever_weights,
    trust_calibration,
)
from ratouch.search.index import IndexConfig
from ratouch.search.pca import PCA2D
from ratouch.search.retrieval import QUERY_MODES, CorpusIndex, CorpusSearch
from ratouch.serve.trust import TrustCalibration

#: What `RATouchPipeline.corpus_embeddings` serves.
CORPUS_EMBEDDING_KINDS = ("image", "tactile_caption", "class_name", "visual_description")

log = logging.getLogger(__name__)


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


# ---------------------------------------------------------------------------------------------
# the query pipeline

def integrator_factory(cfg: dict):
    """Rebuild a saved Texture-Aware Integrator (or the neighbour-token arm) from its config."""
    if cfg.get("kind") == NEIGHBOUR_TOKENS:
        return NeighbourTokens(NeighbourTokensConfig(**cfg))
    return TextureAwareIntegrator(IntegratorConfig(**cfg))


def load_for_serving(folder: str | os.PathLike, integrator: bool = True):
    """A saved generator for inference only: its LoRA folded into the weights (the fast path).
    `integrator`: whether the checkpoint holds one (RA-Touch or the neighbour-token arm)."""
    gen = load_generator(folder, integrator_factory if integrator else None)
    gen.decoder.merge_lora()
    return gen


def load_tgr(encoder: str, folder: str | os.PathLike | None = None):
    """The frozen Tactile-Guided Retriever trained for an encoder (the shipped one in assets/,
    or the one saved in `folder`, e.g. an ablation trained into the cache)."""
    folder = Path(folder) if folder is not None else retriever_weights(encoder)
    state, cfg, _ = read_checkpoint(folder)
    cfg = {k: v for k, v in cfg.items() if k != "kind"}
    model = TactileGuidedRetriever(RetrieverConfig(**cfg))
    load_into(model, state, str(folder))
    return model.eval()


def load_trust(encoder: str) -> TrustCalibration | None:
    """The shipped trust calibration of an encoder, or None (logged) when it has none."""
    path = trust_calibration(encoder)
    if not path.is_file():
        log.warning("no trust calibration for %s (%s): `ratouch train trust --encoder %s`",
                    encoder, path, encoder)
        return None
    return TrustCalibration.load(path)


class RATouchPipeline:
    """Encoders, corpus index, Tactile-Guided Retriever, the two generators and the PCA frame.

    Read-only once loaded (the corpus embeddings of other caption kinds are computed once, on
    first use); `query` and `query_many` may be called from several threads. Serve it with
    one intra-op thread per calling thread (`ratouch.threads`), as the app's batcher and
    `ratouch query` do.
    """

    def __init__(self, retriever: CorpusSearch, tgr, generator_ra, generator_base,
                 pca: PCA2D | None = None, trust: TrustCalibration | None = None):
        self.retriever = retriever
        self.trust = trust  # None: queries say that nothing flags unfamiliar inputs
        self.encoders = retriever.encoders
        self.corpus = retriever.corpus
        self.tgr = tgr
        self.generator_ra = generator_ra
        self.generator_base = generator_base
        image_emb, text_emb, _ = load_embeddings(
            self.corpus.folder, self.encoders.name, self.encoders.dim, verify=False)
        self._corpus_emb: dict[str, np.ndarray] = {"image": image_emb,
                                                   "tactile_caption": text_emb}
        self._emb_lock = threading.Lock()
        self._stack = StackCache()  # the two decoders' weights, stacked to decode together
        # the fixed reference frame: the first 2000 entries' image and text embeddings
        self.pca = pca or PCA2D.fit(np.concatenate([np.asarray(image_emb[:2000]),
                                                    np.asarray(text_emb[:2000])]))

    @classmethod
    def load(cls, encoder: str = "default-s", corpus: str | os.PathLike | None = None,
             index: str = "flat", progress: bool = False,
             generators: bool = True) -> "RATouchPipeline":
        """Load everything for an encoder; the default corpus is built on first use.
        `generators=False` loads the retrieval side only (for training the generators, or
        evaluating retrieval): `describe` and `query` then need generators set first."""
        corpus = corpus or default_corpus(encoder, progress=progress)
        retriever = open_retriever(corpus, encoder, index)
        tgr = load_tgr(encoder)
        gen_ra = gen_base = None
        if generators:
            gen_ra = load_for_serving(generator_weights(encoder, "ra"))
            gen_base = load_for_serving(generator_weights(encoder, "baseline"), integrator=False)
        return cls(retriever, tgr, gen_ra, gen_base, trust=load_trust(encoder))

    # ----------------------------------------------------------------- building blocks

    def joint_query(self, V: np.ndarray, T: np.ndarray, tgr=None) -> np.ndarray:
        """The Tactile-Guided Retriever's joint query Q for (N, D) visual and tactile
        embeddings (`tgr`: another trained retriever, e.g. an ablation's; default the
        pipeline's own)."""
        with torch.no_grad():
            return (tgr or self.tgr)(torch.from_numpy(np.ascontiguousarray(V, np.float32)),
                                     torch.from_numpy(np.ascontiguousarray(T, np.float32))
                                     ).query.numpy()

    def joint_neighbours(self, V: np.ndarray, T: np.ndarray, k: int, batch: int = 1024
                         ) -> np.ndarray:
        """(N, k) corpus ids of the joint query's top-k against the text index, in batches."""
        return np.concatenate([
            self.corpus.search("text", self.joint_query(V[s:s + batch], T[s:s + batch]), k)[1]
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

    def ra_prefix(self, V: np.ndarray, T: np.ndarray, ids: np.ndarray
                  ) -> tuple[torch.Tensor, dict[str, np.ndarray]]:
        """RA-Touch's prompt p' for (B, D) V and T with neighbours `ids` (B, K), and the
        integrator's attention over them ({"image"|"text": (B, K)}, empty without an
        integrator that reports it). With K = 0 there is nothing to integrate: p' = p."""
        gen = self.generator_ra
        v, t = torch.from_numpy(V), torch.from_numpy(T)
        with torch.inference_mode():
            if ids.shape[1] == 0:
                return gen.prefix(v, t), {}
            rv, rl = (torch.from_numpy(x) for x in self.neighbour_embeddings(ids))
            attend = getattr(gen.integrator, "attention", None)
            weights = {} if attend is None else {
                name: w.numpy() for name, w in attend(t, rv, rl).items()}
            return gen.prefix(v, t, rv, rl), weights

    def regenerate(self, visual: Any, tactile: Any, neighbours: Sequence[int],
                   box=None) -> dict:
        """The RA-Touch description again, read with the neighbours you choose: the original
        ones with some dropped or pinned, or another query's (the interactive form of the
        neighbour-shuffle control).

        Args:
            visual, tactile, box: the pair, as in `query` (a tactile image is required).
            neighbours: corpus ids RA-Touch reads, in any number (none: the integrator adds
                nothing, p' = p).

        Returns:
            {"description": {"ra_touch"}, "neighbours": [entries as in `query`, scored by the
            joint query], "attention": {"image"|"text": [per neighbour]}, "timings_ms"}.
        """
        clock = Laps()
        ids = self._neighbour_ids(neighbours)
        req = self.prepare_request({"visual": visual, "tactile": tactile, "box": box})
        if req["frame"] is None:
            raise ConfigError("regenerating the RA-Touch description needs a tactile image")
        V = self.encoders.encode_image([req["crop"]])
        T = self.encoders.encode_tactile([req["frame"]])
        clock.lap("encode")
        q = self.joint_query(V, T)[0]
        text = self.corpus_embeddings("tactile_caption")[ids]        # (K, D)
        scores = text @ q / np.maximum(np.linalg.norm(text, axis=1) * np.linalg.norm(q), 1e-12)
        p_ra, weights = self.ra_prefix(V, T, ids[None])
        ra = describe_together([self.generator_ra], [p_ra])[0][0]
        clock.lap("generate")
        return {"description": {"ra_touch": ra},
                "neighbours": [self.neighbour_entry(i, s) for i, s in zip(ids, scores)],
                "attention": {k: [round(float(x), 4) for x in w[0]] for k, w in weights.items()},
                "timings_ms": clock.done(1), "warnings": req["warnings"]}

    def _neighbour_ids(self, neighbours: Sequence[int]) -> np.ndarray:
        n = len(self.corpus.entries)
        bad = [i for i in neighbours if isinstance(i, bool)
               or not isinstance(i, (int, np.integer)) or not 0 <= i < n]
        if bad:
            raise ConfigError(f"neighbour ids must be corpus ids in 0..{n - 1}, got {bad[:5]}")
        if len(set(int(i) for i in neighbours)) != len(neighbours):
            raise ConfigError(f"neighbour ids repeat: {list(neighbours)}")
        return np.asarray([int(i) for i in neighbours], dtype=np.int64)

    def neighbour_entry(self, i: int, score: float) -> dict:
        """One neighbour as `query` reports it."""
        e = self.corpus.entry(int(i))
        return {"id": int(i), "score": round(float(score), 4), "class_name": e.class_name,
                "caption": e.caption, "description": e.description, "source": e.source}

    def pca_points(self, queries: dict, results: dict, label: str | None) -> list[dict]:
        """The PCA plot's points: each query, each mode's neighbours, the label if given."""
        pts = []
        text_emb = self.corpus_embeddings("tactile_caption")
        for mode, q in queries.items():
            x, y = self.pca.project(q)[0]
            pts.append({"role": f"query_{mode}", "x": float(x), "y": float(y)})
        for mode, (_, ids) in results.items():
            xy = self.pca.project(text_emb[np.sort(ids[0])])
            for i, (x, y) in zip(np.sort(ids[0]), xy):
                pts.append({"role": f"neighbour_{mode}", "x": float(x), "y": float(y),
                            "id": int(i)})
        if label:
            x, y = self.pca.project(self.encoders.encode_text([label]))[0]
            pts.append({"role": "ground_truth", "x": float(x), "y": float(y)})
        return pts

    # ----------------------------------------------------------------- the query

    def prepare_request(self, req: Mapping[str, Any]) -> dict:
        """Check and decode one request (what `query` does before any model runs).

        The work is bounded whatever the upload's size: the visual crop and the tactile
        frame (and its background) are reduced to `QUERY_MAX_SIDE` pixels inside PIL before
        any per-pixel work. The result can be passed to `query_many` in place of the
        request (a server decodes in the caller's thread, outside the shared batch)."""
        if req.get("prepared"):
            return dict(req)
        t0 = time.perf_counter()
        k = req.get("k", 5)
        n = len(self.corpus.entries)
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n:
            raise ConfigError(f"k must be a whole number from 1 to {n} (K, the neighbours per "
                              f"mode), got k={k!r}")
        visual = req["visual"]
        width, height = oriented_size(visual, "visual image")
        warnings: list[str] = []
        box = req.get("box")
        if box is None:
            box = tvl_contact_box(width, height)
            warnings.append(f"no contact box given: used TVL's centred crop {list(box)}")
        crop = crop_box(visual, box, max_side=QUERY_MAX_SIDE, name="visual image")
        frame, background = self._tactile_inputs(req, warnings)
        return {"prepared": True, "crop": crop, "frame": frame, "background": background,
                "box": box, "k": int(k), "label": req.get("label"), "warnings": warnings,
                "decode_ms": round((time.perf_counter() - t0) * 1000, 2)}

    @staticmethod
    def _tactile_inputs(req: Mapping[str, Any], warnings: list[str]
                        ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The request's tactile frame and sensor background, decoded and reduced."""
        tactile, background = req.get("tactile"), req.get("background")
        if tactile is None:
            warnings.append("no tactile image: image-only retrieval; the tactile and joint "
                            "queries and the RA-Touch description are not available")
            if background is not None:
                warnings.append("a background frame was given without a tactile image: ignored")
            return None, None
        size = _source_size(tactile)
        frame = to_rgb_array(tactile, name="tactile image", max_side=QUERY_MAX_SIDE)
        if background is None:
            return frame, None
        bg_size = _source_size(background)
        bg = to_rgb_array(background, name="background image", max_side=QUERY_MAX_SIDE)
        if (bg_size or bg.shape[1::-1]) != (size or frame.shape[1::-1]):
            w, h = bg_size or bg.shape[1::-1]
            fw, fh = size or frame.shape[1::-1]
            raise DataError(f"the background image is {w}x{h} (WxH) but the tactile image is "
                            f"{fw}x{fh}; the background must be the same sensor's no-contact "
                            "frame at the same size")
        return frame, bg

    def query(self, visual: Any, tactile: Any = None, box=None, k: int = 5,
              label: str | None = None, background: Any = None) -> dict:
        """Run the whole RA-Touch query for one visuo-tactile pair.

        Args:
            visual: the visual image (array, PIL image or path).
            tactile: the tactile image, or None (image-only retrieval, said in `warnings`).
            box: contact box (x0, y0, x1, y1) in pixels of the visual image; None uses TVL's
                centred crop and says so in `warnings`.
            k: neighbours per mode.
            label: the ground-truth tactile caption, when known (plotted in the PCA).
            background: the tactile sensor's no-contact frame (same size as `tactile`), or
                None: used by the no-contact check (and by encoders trained on
                background-subtracted frames).

        Returns:
            {"neighbours": {"image"|"tactile"|"joint": [{"id", "score", "class_name",
            "caption", "description", "source"}]}, "description": {"ra_touch", "baseline"},
            "attention": {"image"|"text": [RA-Touch's integrator weight per joint neighbour]},
            "pca": {"points": [{"role", "x", "y", "id"?}], "explained": [..]},
            "timings_ms": {stage: ms, ..., "total": ms, "decode": this request's decoding
            (part of "preprocess", or done before the batch by a server)}, "warnings": [...], "box": [...],
            "trust": {"visual": {"novelty", "threshold", "novel"}, "tactile": {"novelty",
            "threshold", "novel", "contact", "contact_threshold", "no_contact", "background"}
            or None} or None (no calibration)}. A frame without contact gets empty
            descriptions and a "no contact detected" warning instead of a material guess.
        """
        return answer_one(self.query_many, {"visual": visual, "tactile": tactile, "box": box,
                                            "k": k, "label": label, "background": background})

    def query_many(self, requests: Sequence[Mapping[str, Any]]) -> list[dict | Exception]:
        """Several `query` calls at once (`query` is this with one request).

        Args:
            requests: `query`'s arguments by name (visual required; tactile, box, k, label,
                background), or what `prepare_request` made of them.

        Returns:
            Per request, in order: `query`'s result, or the exception `query` would have
            raised for an unusable image, box or k (the other requests are answered all the
            same). `timings_ms` are the batch's stages, shared by its requests, plus
            "batch_size".
        """
        clock = Laps()
        out, items = self.prepare_many(requests)
        if items:
            clock.lap("preprocess")
            queries, touch = self.encode_queries(items, clock)
            self.answer(out, items, queries, touch, clock)
        return out

    def prepare_many(self, requests: Sequence[Mapping[str, Any]]
                     ) -> tuple[list[Any], list[dict]]:
        """`prepare_request` for each request: (per request, the exception it raised or
        None; the prepared requests, each with its position "pos")."""
        out: list[Any] = [None] * len(requests)
        items: list[dict] = []
        for pos, req in enumerate(requests):
            try:
                items.append({**self.prepare_request(req), "pos": pos})
            except (RATouchError, OSError) as e:
                out[pos] = e
        return out, items

    def answer(self, out: list[Any], items: list[dict], queries: list[dict],
               touch: list[int], clock: "Laps") -> None:
        """The rest of `query_many` once `encode_queries` has run: trust, search, the two
        generations and the PCA points; each item's result goes to `out[item["pos"]]`."""
        trust = [self._assess(it, q) for it, q in zip(items, queries)]
        clock.lap("trust")
        results = self._search(items, queries)
        clock.lap("search")
        # a frame without contact has no material to describe: no generation for it
        touch = [j for j in touch if not (trust[j] and (trust[j]["tactile"] or {})
                                          .get("no_contact"))]
        ra, base, attention = self._generate(items, queries, results, touch, clock)
        points = self._points(items, queries, results)
        clock.lap("pca")
        timings = clock.done(len(items))
        explained = list(self.pca.explained)
        for j, it in enumerate(items):
            out[it["pos"]] = {
                "neighbours": {mode: [self.neighbour_entry(i, s) for s, i in zip(sc[0], ii[0])]
                               for mode, (sc, ii) in results[j].items()},
                "description": {"ra_touch": ra.get(j, ""), "baseline": base.get(j, "")},
                "attention": attention.get(j, {}),
                "pca": {"points": points[j], "explained": explained},
                "timings_ms": {**timings, "decode": it["decode_ms"]},
                "warnings": it["warnings"] + (trust[j] or {}).get("warnings", []),
                "box": [int(v) for v in it["box"]],
                "encoder": self.encoders.name,
                "trust": None if trust[j] is None else
                {m: trust[j][m] for m in ("visual", "tactile")}}

    def _assess(self, item: dict, queries: dict) -> dict | None:
        """The trust block of one prepared request (None, with a warning, uncalibrated)."""
        if self.trust is None:
            item["warnings"].append(f"no trust calibration for encoder {self.encoders.name}: "
                                    "inputs unlike the training data are not flagged")
            return None
        return self.trust.assess(queries["image"], queries.get("tactile"), item["frame"],
                                 item.get("background"))

    def encode_queries(self, items: list[dict], clock: "Laps"
                       ) -> tuple[list[dict], list[int]]:
        """Per prepared item {mode: (1, D) query}; and which items have a tactile frame."""
        V = self.encoders.encode_image([it["crop"] for it in items])
        clock.lap("encode_image")
        queries: list[dict[str, np.ndarray]] = [{"image": V[j:j + 1]} for j in range(len(items))]
        touch = [j for j, it in enumerate(items) if it["frame"] is not None]
        if touch:
            bgs = [items[j].get("background") for j in touch]
            T = self.encoders.encode_tactile([items[j]["frame"] for j in touch],
                                             bgs if any(b is not None for b in bgs) else None)
            clock.lap("encode_tactile")
            J = self.joint_query(V[touch], T)
            for r, j in enumerate(touch):
                queries[j]["tactile"], queries[j]["joint"] = T[r:r + 1], J[r:r + 1]
            clock.lap("retriever")
        return queries, touch

    def _search(self, items: list[dict], queries: list[dict]) -> list[dict]:
        """Every mode of every request against the text index: one search at the largest K."""
        rows = [(j, m) for j, q in enumerate(queries) for m in QUERY_MODES if m in q]
        scores, ids = self.corpus.search(
            "text", np.concatenate([queries[j][m] for j, m in rows]),
            max(it["k"] for it in items))
        results: list[dict] = [{} for _ in items]
        for r, (j, m) in enumerate(rows):
            k = items[j]["k"]
            results[j][m] = (scores[r:r + 1, :k], ids[r:r + 1, :k])
        return results

    def _generate(self, items, queries, results, touch, clock) -> tuple[dict, dict, dict]:
        """RA-Touch and baseline descriptions of the touch items, decoded together (one
        RA-Touch prompt batch per K), and RA-Touch's attention over each item's neighbours."""
        ra: dict[int, str] = {}
        base: dict[int, str] = {}
        attention: dict[int, dict] = {}
        if not touch:
            return ra, base, attention
        V = np.concatenate([queries[j]["image"] for j in touch])
        T = np.concatenate([queries[j]["tactile"] for j in touch])
        by_k: dict[int, list[int]] = {}
        for r, j in enumerate(touch):
            by_k.setdefault(items[j]["k"], []).append(r)
        p_ra: list = [None] * len(touch)
        for rows in by_k.values():
            nb = np.concatenate([results[touch[r]]["joint"][1] for r in rows])
            prefix, weights = self.ra_prefix(V[rows], T[rows], nb)
            for n, r in enumerate(rows):
                p_ra[r] = prefix[n]
                attention[touch[r]] = {name: [round(float(x), 4) for x in w[n]]
                                       for name, w in weights.items()}
        with torch.inference_mode():
            p_base = self.generator_base.prefix(torch.from_numpy(V), torch.from_numpy(T))
        texts_ra, texts_base = describe_together(
            [self.generator_ra, self.generator_base], [torch.stack(p_ra), p_base],
            cache=self._stack)
        ra.update(zip(touch, texts_ra))
        base.update(zip(touch, texts_base))
        clock.lap("generate")
        return ra, base, attention

    def _points(self, items, queries, results) -> list[list[dict]]:
        points = [self.pca_points(queries[j], results[j], None) for j in range(len(items))]
        labelled = [j for j, it in enumerate(items) if it["label"]]
        if labelled:  # the ground-truth captions' embeddings in one encoder call
            xy = self.pca.project(self.encoders.encode_text(
                [items[j]["label"] for j in labelled]))
            for j, (x, y) in zip(labelled, xy):
                points[j].append({"role": "ground_truth", "x": float(x), "y": float(y)})
        return points


def answer_one(query_many: Callable[[list], list], request: dict) -> dict:
    """`query_many` on one request: its result, or the exception it holds raised."""
    out = query_many([request])[0]
    if isinstance(out, Exception):
        raise out
    return out


def _source_size(image: Any) -> tuple[int, int] | None:
    """(W, H) of an image before any reduction: PIL images and arrays directly, files from
    their header (no decoding); None if a file cannot be opened (decoding then says why)."""
    if isinstance(image, Image.Image):
        return image.size
    if isinstance(image, np.ndarray) and image.ndim >= 2:
        return int(image.shape[1]), int(image.shape[0])
    try:
        with Image.open(image) as img:
            return img.size
    except Exception:  # noqa: BLE001 - to_rgb_array reports unreadable files properly
        return None


class Laps:
    """Stage timings of one `query_many` call, in ms."""

    def __init__(self):
        self.start = self.t = time.perf_counter()
        self.timings: dict[str, float] = {}

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.timings[stage] = round((now - self.t) * 1000, 2)
        self.t = now

    def done(self, batch_size: int) -> dict[str, float]:
        self.timings["total"] = round((time.perf_counter() - self.start) * 1000, 2)
        self.timings["batch_size"] = batch_size
        return self.timings

"""The RA-Touch query pipeline, the one place a query is answered, and how it is loaded.

`RATouchPipeline` is the retrieval side (`ratouch.search.retrieval_side.RetrievalSide`: the
encoders, the corpus index, the Tactile-Guided Retriever) plus the two generators, the trust
signals and the PCA frame. It is an `Answerer` (`ratouch.serve.request`): `answer` takes
decoded `QueryRequest`s, one or several at once (batched encoders, one index search, batched
generation), and returns a `QueryResult` each, whose `to_dict()` is what `ratouch query`
prints and the app shows. `query` is the convenience for one call.

A result's neighbours are those of each query mode (`ratouch.search.modes.QUERY_MODES`),
each against the corpus's text embeddings (Table 4's x->text settings).
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ratouch.errors import ConfigError, DataNotFoundError
from ratouch.model.fastpath import StackCache
from ratouch.model.gate import DOUBT_EFFECT, READ_BELOW, WITHHOLD_COST, TouchGate
from ratouch.model.generator import RATouchGenerator, describe_together, load_generator
from ratouch.model.geometry import GeometryCalibration
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.model.neighbour_text import KIND as NEIGHBOUR_TEXT
from ratouch.model.neighbour_text import NeighbourText, NeighbourTextConfig
from ratouch.model.neighbour_tokens import KIND as NEIGHBOUR_TOKENS
from ratouch.model.neighbour_tokens import NeighbourTokens, NeighbourTokensConfig
from ratouch.model.press_map import PressMap
from ratouch.model.trust import TrustCalibration, doubts_touch
from ratouch.paths import generator_weights, geometry_calibration, trust_calibration
from ratouch.search.modes import (
    IMAGE_MODE,
    QUERY_MODES,
    RA_TOUCH_MODE,
    RETRIEVAL_SYSTEMS,
    WITHHOLDING_SYSTEMS,
)
from ratouch.search.pca import PCA2D
from ratouch.search.retrieval import CorpusSearch
from ratouch.search.retrieval_side import (
    RetrievalSide,
    default_corpus,
    load_gate,
    load_press_map,
    load_tgr,
    open_retriever,
)
from ratouch.serve.photo import PhotoQuery, PhotoRoute
from ratouch.serve.request import (
    QueryRequest,
    QueryResult,
    all_answered,
    answer_one,
    model_name,
    slots_for,
)
from ratouch.timing import Laps
from ratouch.world.sensors import WITHHOLD_LIMIT, guess_family, unfamiliar_look

log = logging.getLogger(__name__)

#: The retrieval system a request that names none is answered with (a key of
#: `RETRIEVAL_SYSTEMS`), chosen by the measurements in docs/premise.md.
DEFAULT_RETRIEVAL = "fallback"


def integrator_factory(cfg: dict):
    """Rebuild a saved Texture-Aware Integrator (or the neighbour-token or text arm) from its
    config."""
    if cfg.get("kind") == NEIGHBOUR_TOKENS:
        return NeighbourTokens(NeighbourTokensConfig(**cfg))
    if cfg.get("kind") == NEIGHBOUR_TEXT:
        return NeighbourText(NeighbourTextConfig(**cfg))
    return TextureAwareIntegrator(IntegratorConfig(**cfg))


def load_for_serving(folder: str | os.PathLike, integrator: bool = True):
    """A saved generator for inference only: its LoRA folded into the weights (the fast path).
    `integrator`: whether the checkpoint holds one (RA-Touch or the neighbour-token arm)."""
    gen = load_generator(folder, integrator_factory if integrator else None)
    gen.decoder.merge_lora()
    return gen


def _optional_generator(encoder: str, kind: str, system: str):
    """The shipped generator `kind` of an encoder set that answers one retrieval `system`, or
    None (logged: that system then reads with the paper's RA-Touch generator)."""
    folder = generator_weights(encoder, kind)
    if not (folder / "manifest.json").is_file():
        log.warning("no %s generator for %s (%s): the %s system reads with the paper's "
                    "RA-Touch generator (`ratouch train %s --encoder %s`)", kind, encoder,
                    folder, system, kind, encoder)
        return None
    return load_for_serving(folder)


def load_reader(encoder: str):
    """The shipped reader of an encoder set (the `gated` system's generator), or None (logged)
    when it has none."""
    return _optional_generator(encoder, "reader", "gated")


def load_text_arm(encoder: str):
    """The shipped generator of the `text` system (the paper's stage 1 with the neighbours'
    captions in the prompt, `ratouch.model.neighbour_text`), or None (logged) when it has
    none. `RATouchPipeline` rebuilds it on the corpus it serves where it was built on
    another (`text_arm_fits`)."""
    return _optional_generator(encoder, "text", "text")


#: Corpus rows compared when checking that a text arm was built on the corpus served.
_FIT_ROWS = 64


def text_arm_fits(arm: NeighbourText, text_embeddings: np.ndarray) -> bool:
    """Whether a text arm's captions are the corpus's: the same number of entries, and its
    keys equal to the corpus's caption embeddings (within half precision) on `_FIT_ROWS`
    rows spread over it. A text arm reads a caption by matching its embedding against its
    keys, so on another corpus it would write the nearest caption of its own: the pipeline
    rebuilds it on the corpus it serves."""
    n = len(text_embeddings)
    if arm.cfg.entries != n or n == 0:
        return False
    rows = np.unique(np.linspace(0, n - 1, min(_FIT_ROWS, n)).astype(int))
    keys = arm.keys[torch.from_numpy(rows)].float().numpy()
    return bool(np.abs(keys - np.asarray(text_embeddings[rows], np.float32)).max() < 1e-2)


def load_trust(encoder: str) -> TrustCalibration | None:
    """The shipped trust calibration of an encoder, or None (logged) when it has none."""
    path = trust_calibration(encoder)
    if not path.is_file():
        log.warning("no trust calibration for %s (%s): `ratouch train trust --encoder %s`",
                    encoder, path, encoder)
        return None
    trust = TrustCalibration.load(path)
    geo = geometry_calibration()
    if not geo.is_file():
        log.warning("no geometry calibration (%s): `ratouch train geometry`; contact against a "
                    "background is read without the structured-change check", geo)
        return trust
    return dataclasses.replace(trust, geometry=GeometryCalibration.load(geo))


def stage_ms(clock: Laps, batch_size: int) -> dict[str, float]:
    """A result's "timings_ms": each stage's ms, the "total" since the clock started and the
    batch's size."""
    return {**clock.ms(), "total": round(clock.elapsed() * 1000, 2), "batch_size": batch_size}


@dataclass
class Encoded:
    """One request as `RATouchPipeline.encode` leaves it for `respond`.

    Attributes:
        V: (1, D) the crop's image embedding.
        T: (1, D) the frame's tactile embedding, or None (no frame).
        queries: {mode: (1, D) query}: every mode of `QUERY_MODES` in its order, those that
            need a tactile frame only with one.
        prior: (1, F) the visual prior's features of the crop, or None (no prior).
        photo: the photo route's query where it answered the crop (its image neighbours
            are then the route's ranking, not a search), else None.
        warnings: what encoding adds to the request's warnings (the photo route's note).
        look: the sensor family the frame looks like and how far from its units
            (`guess_family`), or None (no frame, or a request the rule cannot answer).
        doubt: where a withholding system doubts the touch itself (`doubts_touch`: its
            contact against the background uncertain, the frame alone showing none), the
            trust block's alone reading ({"state", "contact"}); else None. Set by `respond`
            once the trust block is read.
    """

    V: np.ndarray
    T: np.ndarray | None = None
    queries: dict[str, np.ndarray] = field(default_factory=dict)
    prior: np.ndarray | None = None
    photo: PhotoQuery | None = None
    warnings: list[str] = field(default_factory=list)
    look: tuple[str, float] | None = None
    doubt: dict | None = None

    @property
    def unfamiliar(self) -> bool:
        """The frame lies beyond every validation render of the sensor families
        (`unfamiliar_look` at `WITHHOLD_LIMIT`): the withholding rule's test."""
        return self.look is not None and unfamiliar_look(self.look, WITHHOLD_LIMIT)

    @property
    def route(self) -> dict:
        """The result's `visual_route`: {"route": "render"}, or the photo route's account."""
        return {"route": "render"} if self.photo is None else self.photo.route()


class RATouchPipeline(RetrievalSide):
    """The retrieval side, the two generators, the trust signals and the PCA frame.

    Read-only once loaded; `answer` may be called from several threads. Serve it with one
    intra-op thread per calling thread (`ratouch.threads`), as the app's batcher and
    `ratouch query` do.
    """

    def __init__(self, retriever: CorpusSearch, tgr, generator_ra, generator_base,
                 pca: PCA2D | None = None, trust: TrustCalibration | None = None,
                 gate: TouchGate | None = None, retrieval: str = DEFAULT_RETRIEVAL,
                 generator_reader=None, lm: str | None = None, generator_text=None,
                 press_map: PressMap | None = None):
        super().__init__(retriever, tgr)
        self.press_map = press_map
        #: the pretrained language model the generators were adapted from (None: the small
        #: decoder)
        self.lm = lm
        self.trust = trust  # None: queries say that nothing flags unfamiliar inputs
        self.gate = gate
        #: whether the withholding systems (`WITHHOLDING_SYSTEMS`: `gated`, `fallback`)
        #: withhold the touch of a frame beyond every validation render of the sensor families
        #: (`withholds`, `WITHHOLD_LIMIT`). On (docs/premise.md, "Touch withheld only beyond
        #: every validation render": no world test frame is withheld, +0.42 over the baseline
        #: where touch tells nothing). Off: `gated`'s gate alone weighs touch, and `fallback`
        #: answers as `paper`.
        self.withhold_unfamiliar = True
        if retrieval not in RETRIEVAL_SYSTEMS:
            raise ConfigError(f"unknown retrieval system {retrieval!r}; one of "
                              f"{', '.join(RETRIEVAL_SYSTEMS)}")
        #: the retrieval system a request that names none is answered with
        self.retrieval = retrieval
        self.generator_ra = generator_ra
        self.generator_base = generator_base
        #: the `gated` system's generator, trained in reading episodes on the gated query's
        #: neighbours (None: the gated system reads them with the paper's RA-Touch generator)
        self.generator_reader = generator_reader
        image_emb = self.corpus_embeddings("image")
        text_emb = self.corpus_embeddings("tactile_caption")
        #: the `text` system's generator (None: the text system reads with the paper's
        #: RA-Touch generator, and says why: `text_missing`)
        if generator_text is not None and not text_arm_fits(generator_text.integrator, text_emb):
            # built on another corpus (the default one; this is a user's or a test's): the
            # arm has nothing trained of its own, so it is rebuilt on this corpus's captions
            # with the decoder's own (frozen) word embeddings and the words it was trained
            # with, in a generator of this pipeline's own (the one given is left as it is:
            # another pipeline may serve it on its corpus)
            generator_text = RATouchGenerator(
                generator_text.prompt, generator_text.decoder, NeighbourText.build(
                    [e.caption for e in self.corpus.entries], text_emb, generator_text.decoder,
                    words=generator_text.integrator.cfg.words)).train(generator_text.training)
            generator_text.requires_grad_(False)
        self.generator_text = generator_text
        self.text_missing: str | None = (None if generator_text is not None
                                         else "no text-arm generator is loaded")
        prior = getattr(self.encoders, "visual_prior", None)
        #: answers crops that look like real photos (None: the encoders have no prior)
        self.photos = None if prior is None else PhotoRoute(
            prior, [e.class_name for e in self.corpus.entries], image_emb)
        # the decoders' weights stacked to decode together, per set of decoders
        self._stacks: dict[tuple[int, ...], StackCache] = {}
        # the fixed reference frame: the first 2000 entries' image and text embeddings
        self.pca = pca or PCA2D.fit(np.concatenate([np.asarray(image_emb[:2000]),
                                                    np.asarray(text_emb[:2000])]))

    @classmethod
    def load(cls, encoder: str = "default-s", corpus: str | os.PathLike | None = None,
             index: str = "flat", progress: bool = False,
             generators: bool = True, retrieval: str = DEFAULT_RETRIEVAL,
             lm: str | None = None) -> "RATouchPipeline":
        """Load everything for an encoder; the default corpus is built on first use.
        `generators=False` loads no generators (for evaluating retrieval): `answer` then
        needs them set first. `retrieval`: the retrieval system of requests that name none
        (a key of `RETRIEVAL_SYSTEMS`). `lm`: the generators adapted from that pretrained
        language model ("smollm2-135m"; `generator_weights(encoder, kind, lm)`) instead of
        the small decoder's; they have no reader of their own (the gated system reads with
        RA-Touch)."""
        corpus = corpus or default_corpus(encoder, progress=progress)
        retriever = open_retriever(corpus, encoder, index)
        gen_ra = gen_base = gen_reader = gen_text = None
        if generators:
            for kind in ("ra", "baseline") if lm else ():
                if not (generator_weights(encoder, kind, lm) / "manifest.json").is_file():
                    raise DataNotFoundError(
                        f"no {kind} generator for {model_name(encoder, lm)} in "
                        f"{generator_weights(encoder, kind, lm)}: `ratouch train generator "
                        f"--encoder {encoder}{f' --lm {lm}' if lm else ''}`")
            gen_ra = load_for_serving(generator_weights(encoder, "ra", lm))
            gen_base = load_for_serving(generator_weights(encoder, "baseline", lm),
                                        integrator=False)
            gen_reader = load_reader(encoder) if lm is None else None
            gen_text = load_text_arm(encoder) if lm is None else None
        trust = load_trust(encoder)
        return cls(retriever, load_tgr(encoder), gen_ra, gen_base, trust=trust,
                   gate=load_gate(encoder, trust), retrieval=retrieval,
                   generator_reader=gen_reader, lm=lm,
                   generator_text=gen_text, press_map=load_press_map(encoder))

    @property
    def name(self) -> str:
        """The model's name: its encoder set's, with the pretrained language model its
        generators were adapted from (`model_name`)."""
        return model_name(self.encoders.name, self.lm)

    def model(self, name: str | None = None) -> "RATouchPipeline":
        """The loaded model answering requests that name `name`: this one (None or its own
        name; a server offering several models is a `ModelChoice`)."""
        if name not in (None, self.name):
            raise ConfigError(f"unknown model {name!r}: this server answers with {self.name}")
        return self

    # ----------------------------------------------------------------- the query

    def query(self, visual: Any, tactile: Any = None, box=None, k: int = 5,
              label: str | None = None, background: Any = None) -> dict:
        """One query, decoded (`QueryRequest.decode`, which says what each input may be),
        answered, as its JSON-ready dict (`QueryResult.to_dict`).

        Raises:
            the exception the request caused: an unusable image, box or k.
        """
        return answer_one(self, QueryRequest.decode(visual, tactile, box, k, label,
                                                    background)).to_dict()

    def answer(self, requests: Sequence[QueryRequest]) -> list[QueryResult | Exception]:
        """Answer decoded requests together: per request, its `QueryResult` or the exception
        it raised (a K larger than the corpus); `timings_ms` are the batch's stages, shared
        by its requests, plus "batch_size" and the request's own "decode"."""
        clock = Laps()
        out, todo = slots_for(requests, len(self.corpus.entries))
        if todo:
            clock.lap("preprocess")
            batch = [requests[pos] for pos in todo]
            for pos, result in zip(todo, self.respond(batch, self.encode(batch, clock), clock)):
                out[pos] = result
        return all_answered(out)

    def encode(self, requests: Sequence[QueryRequest], clock: Laps) -> list[Encoded]:
        """Step 1: the crops' image embeddings, the frames' tactile ones, and from them each
        query mode's vectors (`QUERY_MODES`; a mode that needs a frame only where there is
        one). Each request is encoded on its own: a batched convolution rounds differently
        from a single one, and a request's answer must not depend on who else is asking."""
        return [self._encode_batch([r], clock)[0] for r in requests]

    def _encode_batch(self, requests: Sequence[QueryRequest], clock: Laps) -> list[Encoded]:
        V, P, photos = self.encode_images([r.crop for r in requests])
        encoded = [Encoded(V[j:j + 1], None, {}, None if P is None else P[j:j + 1], photo,
                           [] if photo is None else [photo.note])
                   for j, photo in enumerate(photos)]
        for mode in QUERY_MODES.values():
            if not mode.needs_touch:
                q = mode.vectors(V, None, self.joint_query)
                for j, e in enumerate(encoded):
                    e.queries[mode.name] = q[j:j + 1]
        clock.lap("encode_image")
        touch = [j for j, r in enumerate(requests) if r.frame is not None]
        if touch:
            bgs = [requests[j].background for j in touch]
            T = self.encoders.encode_tactile([requests[j].frame for j in touch],
                                             bgs if any(b is not None for b in bgs) else None)
            clock.lap("encode_tactile")
            for r, j in enumerate(touch):
                encoded[j].T = T[r:r + 1]
                if self._may_withhold(requests[j]):  # read only where the rule may use it
                    frame = requests[j].frame
                    assert frame is not None  # `touch` holds the requests with a frame
                    encoded[j].look = guess_family(frame)
            for mode in QUERY_MODES.values():
                if mode.needs_touch:
                    q = mode.vectors(V[touch], T, self.joint_query)
                    for r, j in enumerate(touch):
                        encoded[j].queries[mode.name] = q[r:r + 1]
            gated = RETRIEVAL_SYSTEMS["gated"]
            for j in touch:
                # touch withheld: the gated query gives it no say (weight 0), which is the
                # image query, so its neighbours are the ones the answer reads
                if gated in encoded[j].queries and self.withholds(requests[j], encoded[j]):
                    encoded[j].queries[gated] = encoded[j].queries[IMAGE_MODE]
            clock.lap("retriever")
        for e in encoded:  # the modes' order, whichever were made first
            e.queries = {m: e.queries[m] for m in QUERY_MODES if m in e.queries}
        return encoded

    def respond(self, requests: Sequence[QueryRequest], encoded: Sequence[Encoded],
                clock: Laps) -> list[QueryResult]:
        """The rest, once `encode` has run: assess, search, generate, project."""
        trust = [self._assess(r, e) for r, e in zip(requests, encoded)]
        for r, e, t in zip(requests, encoded, trust):
            self._doubt(r, e, None if t is None else t["tactile"])
        clock.lap("trust")
        found = self._search(requests, encoded)
        clock.lap("search")
        # a frame without contact has no material to describe: no generation for it
        touch = [j for j, (e, t) in enumerate(zip(encoded, trust)) if e.T is not None
                 and not (t and (t["tactile"] or {}).get("no_contact"))]
        # who answers each request (the gated system routes by the gate's weight): decided once
        gens = [self.generator_for(r, e) for r, e in zip(requests, encoded)]
        ra, base, attention = self._generate(requests, encoded, found, touch, gens, clock)
        points = self._project(requests, encoded, found)
        clock.lap("pca")
        timings = stage_ms(clock, len(requests))
        explained = list(self.pca.explained)
        return [QueryResult(
            neighbours={mode: [self.neighbour_entry(i, s) for s, i in zip(sc[0], ii[0])]
                        for mode, (sc, ii) in found[j].items()},
            description={"ra_touch": ra.get(j, ""), "baseline": base.get(j, "")},
            attention=attention.get(j, {}),
            pca={"points": points[j], "explained": explained},
            timings_ms={**timings, "decode": req.decode_ms},
            warnings=[*req.warnings, *encoded[j].warnings, *self._trust_warnings(t)],
            box=[int(v) for v in req.box],
            encoder=self.name,  # the model that answered (an encoder set, or "ENC+LM")
            visual_route=encoded[j].route,
            trust=None if t is None else {m: t[m] for m in ("visual", "tactile")},
            retrieval=self._retrieval_block(req, encoded[j], gens[j]),
            height_map=None if t is None else t.get("height_map"))
            for j, (req, t) in enumerate(zip(requests, trust))]

    def reads(self, request: QueryRequest, encoded: Encoded | None = None) -> str:
        """The query mode whose neighbours RA-Touch reads for `request`: its retrieval
        system's (`RETRIEVAL_SYSTEMS`), or this pipeline's default; the image query's where
        the request's touch is withheld (`withholds`)."""
        if encoded is not None and self.withholds(request, encoded):
            return IMAGE_MODE
        return RETRIEVAL_SYSTEMS[request.retrieval or self.retrieval]

    def withholds(self, request: QueryRequest, encoded: Encoded) -> bool:
        """Whether `request`'s touch is withheld from its answer (docs/premise.md, "An
        unfamiliar sensor's touch withheld" and "Touch withheld where contact against the
        background is uncertain and the frame alone shows none"): a withholding system
        (`WITHHOLDING_SYSTEMS`: `gated` or `fallback`), `withhold_unfamiliar` on, a neutral
        touch to read instead (a trust calibration), and a frame beyond every validation
        render of the sensor families (`Encoded.unfamiliar`) or touch in doubt
        (`Encoded.doubt`, set once the trust block is read)."""
        return self._may_withhold(request) and (encoded.unfamiliar or encoded.doubt is not None)

    def _doubt(self, request: QueryRequest, encoded: Encoded, tactile: dict | None) -> None:
        """Set `encoded.doubt` from the request's trust block (its tactile part) where a
        withholding system may withhold and the block doubts the touch (`doubts_touch`); the
        gated query then gives touch no say, as for an unfamiliar look."""
        if not (encoded.T is not None and self._may_withhold(request) and doubts_touch(tactile)):
            return
        assert tactile is not None  # doubts_touch read it
        encoded.doubt = dict(tactile["alone"])
        gated = RETRIEVAL_SYSTEMS["gated"]
        if gated in encoded.queries:
            encoded.queries[gated] = encoded.queries[IMAGE_MODE]

    def _may_withhold(self, request: QueryRequest) -> bool:
        """Whether `withholds` may hold for `request` once its frame's look is read (the
        look is read only then)."""
        return ((request.retrieval or self.retrieval) in WITHHOLDING_SYSTEMS
                and self.withhold_unfamiliar and self.trust is not None)

    def neutral_touch(self) -> np.ndarray:
        """(1, D) the touch read where touch is withheld: the trust calibration's mean
        training tactile embedding, unit length (the regime the reader's episodes trained
        it for: touch that tells nothing)."""
        if self.trust is None:
            raise ConfigError("a neutral touch needs a trust calibration")
        m = np.asarray(self.trust.tactile.mean, np.float32)
        return (m / max(float(np.linalg.norm(m)), 1e-12))[None]

    def generator_for(self, request: QueryRequest, encoded: Encoded):
        """The RA-Touch generator that answers `request`: for `text`, the text arm (where one
        fits the corpus); where touch is withheld (`withholds`), the reader (where one is
        loaded); for `gated`, the reader where the gate gives touch less than `READ_BELOW` of
        the say (and a reader is loaded); else the paper's."""
        system = request.retrieval or self.retrieval
        if system == "text":
            return self.generator_text or self.generator_ra
        if encoded.T is not None and self.withholds(request, encoded):
            return self.generator_reader or self.generator_ra
        if (system != "gated" or self.generator_reader is None or self.gate is None
                or encoded.T is None):
            return self.generator_ra
        w = self.gate.weights(encoded.V, encoded.T, encoded.queries[RA_TOUCH_MODE])[0]
        return self.generator_reader if w < READ_BELOW else self.generator_ra

    def system_generator(self, system: str):
        """A generator-like object (``describe(V, T, Rv, Rl)``) answering as a retrieval
        system (`RETRIEVAL_SYSTEMS`) does, row by row: the paper's RA-Touch generator, or for
        `gated` the trust-routed pair (`TrustRouted`) where a reader and a gate are loaded,
        for `text` the text arm where one fits the corpus. Rows are embeddings, not frames:
        the withholding rule, which reads a frame's look, is not applied here (`fallback` is
        the paper's generator; `scripts/why_withhold.py` applies the rule per row)."""
        if system == "text":
            return self.generator_text or self.generator_ra
        if system == "gated" and self.generator_reader is not None and self.gate is not None:
            return TrustRouted(self, self.generator_ra, self.generator_reader)
        return self.generator_ra

    def _describe(self, generators: Sequence, prefixes: Sequence[torch.Tensor]
                  ) -> list[list[str]]:
        """`describe_together`, with the stacked weights of each set of decoders kept."""
        key = tuple(id(g) for g in generators)
        cache = self._stacks.get(key)
        if cache is None:
            cache = self._stacks[key] = StackCache()
        return describe_together(generators, prefixes, cache=cache)

    def _retrieval_block(self, request: QueryRequest, encoded: Encoded, generator
                         ) -> dict | None:
        """The result's "retrieval": which neighbours RA-Touch read, which `generator` read
        them (`generator_for`) and how far touch was trusted to steer them (None without a
        frame)."""
        if encoded.T is None:
            return None
        system = request.retrieval or self.retrieval
        held = self.withholds(request, encoded)
        out: dict = {"system": system, "reads": self.reads(request, encoded),
                     "generator": ("reader" if self.generator_reader is not None
                                   and generator is self.generator_reader else
                                   "text" if self.generator_text is not None
                                   and generator is self.generator_text else "paper")}
        if self.gate is None:
            out.update(kind=None, touch_weight=1.0, features={},
                       why=["no touch gate for this model: the gated query is the paper's"])
        else:
            out.update(self.gate.explain(encoded.V, encoded.T, encoded.queries[RA_TOUCH_MODE]))
        if system == "paper" or (system == "fallback" and not held):
            out["why"] = ["the paper's joint query: touch steers the search fully"] + (
                [f"the tactile frame looks like the sensors the models learnt (distance "
                 f"{encoded.look[1]:.2f}, within every rendered unit's {WITHHOLD_LIMIT:.2f}): "
                 "touch is not withheld"] if system == "fallback" and encoded.look else []) + \
                [f"(the gate would have weighed touch {out['touch_weight']:.2f})"]
        elif system == "text":
            out["why"] = ["the paper's joint query: touch steers the search fully"] + (
                ["its neighbours' captions are written into the prompt, word by word (no "
                 "Texture-Aware Integrator)"] if out["generator"] == "text" else
                [f"{self.text_missing}: the paper's generator answers"])
        elif held and not encoded.unfamiliar:
            assert encoded.doubt is not None  # withheld, not for its look: for doubt
            effect = DOUBT_EFFECT[system]
            out.update(kind="withheld", touch_weight=0.0,
                       why=[f"contact against the background is uncertain, and the frame read "
                            f"alone shows {encoded.doubt['state']}"
                            + ("" if encoded.doubt["contact"] is None else
                               f" (contact {encoded.doubt['contact']:.2f})")
                            + ": the touch may be a blank's read "
                            "against another unit's background, so it is withheld and the "
                            "answer reads the image query's neighbours (measured on renders "
                            f"read so: {effect['blanks']:+.2f} where the frame was a blank, "
                            f"{effect['presses']:+.2f} where it was a press)",
                            f"the {out['generator']}'s generator answers with a neutral touch"
                            + (", as in its reading episodes" if out["generator"] == "reader"
                               else ""),
                            "to have this touch read anyway, choose the `paper` system (the "
                            "retrieval menu, `--retrieval paper`), or give this unit's "
                            "background taken now"])
        elif held:
            assert encoded.look is not None  # withheld: the frame was read
            out.update(kind="withheld", touch_weight=0.0,
                       why=[f"the tactile frame looks like none of the sensors the models "
                            f"learnt (distance {encoded.look[1]:.2f}, beyond every rendered "
                            f"unit's {WITHHOLD_LIMIT:.2f}): touch is withheld, and the answer "
                            "reads the image query's neighbours (its known cost: where such a "
                            "sensor's touch is still readable, "
                            f"{WITHHOLD_COST[system]:.2f} below the paper's system on "
                            "recoloured renders)",
                            f"the {out['generator']}'s generator answers with a neutral touch"
                            + (", as in its reading episodes" if out["generator"] == "reader"
                               else ""),
                            "to have this sensor's touch read anyway, choose the `paper` "
                            "system (the retrieval menu, `--retrieval paper`)"])
        elif out["generator"] == "reader":
            out["why"] = list(out["why"]) + [
                f"touch has less than {READ_BELOW:.0%} of the say: the reader, trained to "
                "answer from its neighbours where touch is unreliable, answers"]
        elif self.generator_reader is not None and self.gate is not None:
            out["why"] = list(out["why"]) + [
                f"touch has at least {READ_BELOW:.0%} of the say: the paper's generator answers"]
        return out

    def _assess(self, request: QueryRequest, encoded: Encoded) -> dict | None:
        """Step 2: the trust block of one request (None: no calibration). A frame read
        without a background also gets the press map's reading of which regime it is a press
        of (`tactile.press_regime`: `RegimeRouter.read`; the touch-only reading follows it,
        `ratouch.serve.trace.touch_reading`), where the map has a router."""
        if self.trust is None:
            return None
        out = self.trust.assess(encoded.V, encoded.T, request.frame, request.background,
                                encoded.prior, crop=request.crop)
        router = None if self.press_map is None else self.press_map.router
        if (router is not None and out.get("tactile") is not None and encoded.T is not None
                and request.background is None):
            out["tactile"]["press_regime"] = router.read(encoded.T)[0]
        return out

    def _trust_warnings(self, trust: dict | None) -> list[str]:
        if trust is None:
            return [f"no trust calibration for encoder {self.encoders.name}: inputs unlike "
                    "the training data are not flagged"]
        return trust.get("warnings", [])

    def _search(self, requests: Sequence[QueryRequest], encoded: Sequence[Encoded]
                ) -> list[dict]:
        """Step 3: every mode of a request against the text index, in one search per request
        (`CorpusIndex.search_each`: ties broken by corpus id; nothing depends on the other
        requests): per request {mode: ((1, k) scores, (1, k) ids)}. The image neighbours of a
        crop the photo route answered are the route's ranking instead
        (`PhotoRoute.neighbours`: by the classifier's probability of the entry's class)."""
        found: list[dict] = [{} for _ in requests]
        for j, e in enumerate(encoded):
            if e.photo is not None:
                assert self.photos is not None   # only the route makes a PhotoQuery
                sc, ii = self.photos.neighbours(e.photo, requests[j].k)
                found[j][IMAGE_MODE] = (sc[None], ii[None])
        modes = [[m for m in QUERY_MODES if m in e.queries and m not in found[j]]
                 for j, e in enumerate(encoded)]
        todo = [j for j, ms in enumerate(modes) if ms]
        blocks = self.corpus.search_each(
            "text", [np.concatenate([encoded[j].queries[m] for m in modes[j]]) for j in todo],
            [requests[j].k for j in todo])
        for j, (scores, ids) in zip(todo, blocks):
            for r, m in enumerate(modes[j]):
                found[j][m] = (scores[r:r + 1], ids[r:r + 1])
        return found

    def _generate(self, requests, encoded, found, touch, gens, clock
                  ) -> tuple[dict, dict, dict]:
        """Step 4: RA-Touch and baseline descriptions of the `touch` requests (each request's
        prompts made on its own, then decoded together), and RA-Touch's attention over each
        request's neighbours."""
        ra: dict[int, str] = {}
        base: dict[int, str] = {}
        attention: dict[int, dict] = {}
        if not touch:
            return ra, base, attention
        groups: dict[int, tuple[Any, list[int], list[torch.Tensor]]] = {}
        p_base = []
        for j in touch:  # each prompt on its own (a batched one rounds differently)
            e = encoded[j]
            gen = gens[j]
            held = self.withholds(requests[j], e)
            prefix, weights = self.ra_prefix(e.V, self.neutral_touch() if held else e.T,
                                             found[j][self.reads(requests[j], e)][1],
                                             generator=gen)
            groups.setdefault(id(gen), (gen, [], []))
            groups[id(gen)][1].append(j)
            groups[id(gen)][2].append(prefix[0])
            attention[j] = {name: [round(float(x), 4) for x in w[0]]
                            for name, w in weights.items()}
            with torch.inference_mode():
                p_base.append(self.generator_base.prefix(torch.from_numpy(e.V),
                                                         torch.from_numpy(e.T))[0])
        gens = list(groups.values())
        *texts_ra, texts_base = self._describe(
            [g for g, _, _ in gens] + [self.generator_base],
            [torch.stack(ps) for _, _, ps in gens] + [torch.stack(p_base)])
        for (_, js, _), texts in zip(gens, texts_ra):
            ra.update(zip(js, texts))
        base.update(zip(touch, texts_base))
        clock.lap("generate")
        return ra, base, attention

    def _project(self, requests, encoded, found) -> list[list[dict]]:
        """Step 5: the PCA plot's points of each request."""
        points = [self.pca_points(encoded[j].queries, found[j], None)
                  for j in range(len(requests))]
        for j, r in enumerate(requests):  # the ground-truth caption's embedding, each alone
            if r.label:
                x, y = self.pca.project(self.encoders.encode_text([r.label]))[0]
                points[j].append({"role": "ground_truth", "x": float(x), "y": float(y)})
        return points

    # ----------------------------------------------------------------- building blocks

    def encode_images(self, crops: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray | None,
                                                                 list[PhotoQuery | None]]:
        """Image queries of visual crops: (N, D) V, the prior's (N, F) features (None
        without a prior) and, per crop, the photo route's query where it answered it.

        A crop the trust calibration finds novel in the prior's feature space (a real
        photo, not a render) gets its image query from the photo route
        (`ratouch.serve.photo`: its row of V is the route's query vector, and its image
        neighbours the route's ranking); every other crop from the encoders' vision
        tower."""
        if hasattr(self.encoders, "encode_image_features"):
            V, P = self.encoders.encode_image_features(crops)
        else:
            V, P = self.encoders.encode_image(crops), None
        photos: list[PhotoQuery | None] = [None] * len(crops)
        if P is None or self.photos is None or self.trust is None or self.trust.visual_prior is None:
            return V, P, photos
        novel = self.trust.visual_prior.score(P) > self.trust.visual_prior.threshold
        for j in np.flatnonzero(novel):
            photos[j] = photo = self.photos.query(crops[j])
            V[j] = photo.query
        return V, P, photos

    def ra_prefix(self, V: np.ndarray, T: np.ndarray, ids: np.ndarray, generator=None
                  ) -> tuple[torch.Tensor, dict[str, np.ndarray]]:
        """RA-Touch's prompt p' for (B, D) V and T with neighbours `ids` (B, K), and the
        integrator's attention over them ({"image"|"text": (B, K)}, empty without an
        integrator that reports it). With K = 0 there is nothing to integrate: p' = p.
        `generator`: another RA-Touch generator's prompt (default the paper's)."""
        gen = generator or self.generator_ra
        v, t = torch.from_numpy(V), torch.from_numpy(T)
        with torch.inference_mode():
            if ids.shape[1] == 0:
                return gen.prefix(v, t), {}
            rv, rl = (torch.from_numpy(x) for x in self.neighbour_embeddings(ids))
            attend = getattr(gen.integrator, "attention", None)
            weights = {} if attend is None else {
                name: w.numpy() for name, w in attend(t, rv, rl).items()}
            return gen.prefix(v, t, rv, rl), weights

    def regenerate(self, request: QueryRequest, neighbours: Sequence[int]) -> dict:
        """The RA-Touch description again, read with the neighbours you choose: the original
        ones with some dropped or pinned, or another query's (the interactive form of the
        neighbour-shuffle control).

        Args:
            request: the pair, decoded (a tactile image is required; its K is not used).
            neighbours: corpus ids RA-Touch reads, in any number (none: the integrator adds
                nothing, p' = p).

        Returns:
            {"description": {"ra_touch"}, "neighbours": [entries as in a query's, scored by
            the query RA-Touch reads], "attention": {"image"|"text": [per neighbour]}, "timings_ms",
            "warnings"}.
        """
        clock = Laps()
        ids = self._neighbour_ids(neighbours)
        if request.frame is None:
            raise ConfigError("regenerating the RA-Touch description needs a tactile image")
        V = self.encode_images([request.crop])[0]
        bg = request.background
        T = self.encoders.encode_tactile([request.frame], None if bg is None else [bg])
        clock.lap("encode")
        J = self.joint_query(V, T)
        e = Encoded(V, T, {RA_TOUCH_MODE: J},
                    look=guess_family(request.frame) if self._may_withhold(request) else None)
        if self._may_withhold(request) and bg is not None and not e.unfamiliar:
            assert self.trust is not None  # _may_withhold checked it
            state = self.trust.contact_state(request.frame, bg, look=e.look)[0]
            alone = self.trust.second_opinion(request.frame, bg, state)
            self._doubt(request, e, None if alone is None else {"state": state, "alone": alone})
        reads = self.reads(request, e)
        q = (J if reads == RA_TOUCH_MODE else V if reads == IMAGE_MODE
             else self._gated(V, T, J)[0])[0]
        text = self.corpus_embeddings("tactile_caption")[ids]        # (K, D)
        scores = text @ q / np.maximum(np.linalg.norm(text, axis=1) * np.linalg.norm(q), 1e-12)
        gen = self.generator_for(request, e)
        p_ra, weights = self.ra_prefix(V, self.neutral_touch() if self.withholds(request, e)
                                       else T, ids[None], generator=gen)
        ra = self._describe([gen], [p_ra])[0][0]
        clock.lap("generate")
        return {"description": {"ra_touch": ra},
                "neighbours": [self.neighbour_entry(i, s) for i, s in zip(ids, scores)],
                "attention": {k: [round(float(x), 4) for x in w[0]] for k, w in weights.items()},
                "timings_ms": stage_ms(clock, 1), "warnings": list(request.warnings)}

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
        """One neighbour as a query reports it."""
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


class TrustRouted:
    """The `gated` system's answer, row by row, for evaluation (``describe`` like a generator):
    the reader where the gate gives touch less than `READ_BELOW` of the say, the paper's
    RA-Touch generator elsewhere; both read the neighbours they are given."""

    def __init__(self, side: RetrievalSide, paper, reader):
        self.side, self.paper, self.reader = side, paper, reader

    def describe(self, V: torch.Tensor, T: torch.Tensor, Rv: torch.Tensor | None = None,
                 Rl: torch.Tensor | None = None) -> list[str]:
        v, t = V.numpy(), T.numpy()
        gate = self.side.gate
        assert gate is not None  # system_generator makes one only with a gate
        low = gate.weights(v, t, self.side.joint_query(v, t)) < READ_BELOW
        out: list[str] = [""] * len(v)
        for mask, gen in ((low, self.reader), (~low, self.paper)):
            idx = np.flatnonzero(mask)
            if len(idx) == 0:
                continue
            i = torch.from_numpy(idx)
            args = [V[i], T[i]] + ([Rv[i], Rl[i]] if Rv is not None and Rl is not None else [])
            for j, text in zip(idx, gen.describe(*args)):
                out[j] = text
        return out

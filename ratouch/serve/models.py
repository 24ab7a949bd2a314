"""Choosing the model per query: the encoder sets that can answer here, and the cascade.

`available_models` lists what is shipped (an encoder set needs its retriever and both
generators; the cascade its calibration). `load_model` loads one by name. `ModelChoice` serves
several of them as one pipeline: each request names its model ("encoder"), a model is loaded
on its first request, and a batch of mixed requests is answered model by model.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Mapping, Sequence
from typing import Any, Callable

from ratouch.errors import ConfigError
from ratouch.serve.cascade import CASCADE, Cascade
from ratouch.serve.pipeline import RATouchPipeline

log = logging.getLogger(__name__)

#: The default encoder sets, smallest first.
SIZES = ("default-tiny", "default-s", "default-b")


def available_models() -> list[str]:
    """What can answer queries here, smallest first: the default encoder sets with a shipped
    retriever and generators, then the cascade when its calibration is shipped."""
    from ratouch.paths import cascade_calibration, generator_weights, retriever_weights

    names = [n for n in SIZES if retriever_weights(n).is_dir()
             and all(generator_weights(n, kind).is_dir() for kind in ("ra", "baseline"))]
    return names + ([CASCADE] if cascade_calibration().is_file() else [])


def load_model(name: str = "default-s", corpus: str | os.PathLike | None = None,
               index: str = "flat", progress: bool = False) -> RATouchPipeline | Cascade:
    """The pipeline of an encoder set, or the shipped cascade for "cascade"."""
    if name == CASCADE:
        return Cascade.load(corpus=corpus, index=index)
    return RATouchPipeline.load(name, corpus=corpus, index=index, progress=progress)


class ModelChoice:
    """Several models behind one pipeline's interface; requests choose by "encoder".

    Args:
        default: the model of requests that name none (loaded now).
        names: the models requests may name (default: `available_models()`, plus `default`).
        load: loads a model by name (default `load_model` on `corpus`).
        corpus: the corpus folder every model searches (default: the world's 10k).
    """

    def __init__(self, default: str = "default-s", names: Sequence[str] | None = None,
                 load: Callable[[str], Any] | None = None,
                 corpus: str | os.PathLike | None = None):
        self.names = list(dict.fromkeys([*(names if names is not None
                                           else available_models()), default]))
        self.default = default
        self._corpus = corpus
        self._load = load or self._load_shared
        self._lock = threading.RLock()  # re-entered when the cascade loads its stages
        self._models: dict[str, Any] = {}
        self.model(default)  # loaded now (the cascade loads its stages as models too)

    def model(self, name: str | None = None) -> Any:
        """The model called `name` (default: the default one), loaded on first use."""
        name = name or self.default
        if name not in self.names:
            raise ConfigError(f"unknown model {name!r}: one of {', '.join(self.names)}")
        with self._lock:  # one load at a time; concurrent first requests wait for it
            if name not in self._models:
                log.info("loading model %s on its first request ...", name)
                self._models[name] = self._load(name)
            return self._models[name]

    def _load_shared(self, name: str) -> Any:
        """`load_model`, but the cascade's stages are the models of the same names."""
        if name != CASCADE:
            return load_model(name, corpus=self._corpus, progress=True)
        from ratouch.paths import cascade_calibration
        from ratouch.serve.cascade import CascadeCalibration

        cal = CascadeCalibration.load(cascade_calibration())
        return Cascade([self.model(n) if n in self.names else
                        load_model(n, corpus=self._corpus) for n in cal.encoders], cal)

    def __getattr__(self, name: str) -> Any:
        # the default model stands for the choice where one pipeline's parts are asked for
        if name.startswith("__") or name in ("_models", "_load", "_lock", "_corpus", "names",
                                                "default"):
            raise AttributeError(name)
        return getattr(self._models[self.default], name)

    def prepare_request(self, req: Mapping[str, Any]) -> dict:
        """The chosen model's `prepare_request`, keeping the choice in the request."""
        name = req.get("encoder") or self.default
        return {**self.model(name).prepare_request(req), "encoder": name}

    def query(self, visual: Any, tactile: Any = None, box=None, k: int = 5,
              label: str | None = None, background: Any = None,
              encoder: str | None = None) -> dict:
        """`RATouchPipeline.query` by the model named `encoder` (default: the default)."""
        extra = {} if background is None else {"background": background}
        return self.model(encoder).query(visual, tactile, box=box, k=k, label=label, **extra)

    def query_many(self, requests: Sequence[Mapping[str, Any]]) -> list[Any]:
        """`RATouchPipeline.query_many`, each request by its own model (one batch each)."""
        out: list[Any] = [None] * len(requests)
        groups: dict[str, list[int]] = {}
        for pos, req in enumerate(requests):
            name = req.get("encoder") or self.default
            if name not in self.names:
                out[pos] = ConfigError(f"unknown model {name!r}: one of {', '.join(self.names)}")
            else:
                groups.setdefault(name, []).append(pos)
        for name, rows in groups.items():
            for pos, res in zip(rows, self.model(name).query_many([requests[r] for r in rows])):
                out[pos] = res
        return out

    def regenerate(self, visual: Any, tactile: Any, neighbours: Sequence[int], box=None,
                   encoder: str | None = None) -> dict:
        """`RATouchPipeline.regenerate` by the model named `encoder`."""
        return self.model(encoder).regenerate(visual, tactile, neighbours, box=box)

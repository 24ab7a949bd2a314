"""No more model than a scene needs: a cascade of encoder sets, smallest first.

The cascade answers a query with the smallest encoder set whose joint query is confident and
escalates it to the next size otherwise. Its confidence is measured on what the joint query
retrieves, without labels:

* ``agreement``: the share of the top-K joint neighbours that belong to the most common
  corpus class among them (K neighbours that agree on what the object is);
* ``top1``: the cosine of the joint query to its nearest tactile caption;
* ``margin``: that cosine minus the mean cosine of the top K.

Which measure and which threshold are set on the world's validation renders (training-split
renders beyond any training run's pairs, as the trust calibration's), never on the test split:
`ratouch train cascade` (`ratouch.train.cascade`) writes the calibration, a small JSON file
shipped beside the weights (`ratouch.paths.cascade_calibration`).

`Cascade` serves like one `RATouchPipeline` (`query`, `query_many`, `regenerate`); every
result says which encoder answered, with what confidence, and whether it was escalated.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import write_atomic
from ratouch.serve.pipeline import Laps, RATouchPipeline, answer_one

log = logging.getLogger(__name__)

MEASURES = ("agreement", "top1", "margin")
FORMAT = "ratouch-cascade-1"
#: The name that selects the shipped cascade wherever an encoder set is chosen.
CASCADE = "cascade"


def joint_confidence(scores: np.ndarray, ids: np.ndarray, classes: np.ndarray,
                     measure: str) -> np.ndarray:
    """Confidence of each joint query from its top-K search result.

    Args:
        scores: (N, K) cosine scores of the joint query's neighbours, best first.
        ids: (N, K) their corpus ids.
        classes: (n_corpus,) each corpus entry's class (any comparable labels).
        measure: one of `MEASURES`.

    Returns:
        (N,) confidence, higher is surer.
    """
    scores, ids = np.atleast_2d(scores), np.atleast_2d(ids)
    if measure == "top1":
        return scores[:, 0].astype(np.float64)
    if measure == "margin":
        return (scores[:, 0] - scores.mean(1)).astype(np.float64)
    if measure == "agreement":
        labels = np.asarray(classes)[ids]
        return np.array([np.unique(row, return_counts=True)[1].max() / len(row)
                         for row in labels], np.float64)
    raise ConfigError(f"unknown confidence measure {measure!r}; one of {', '.join(MEASURES)}")


@dataclass(frozen=True)
class CascadeCalibration:
    """Which encoder sets the cascade runs, smallest first, and when it escalates.

    Attributes:
        encoders: encoder-set names, smallest first (at least two).
        measure: the confidence measure (`MEASURES`).
        k: neighbours the confidence is measured on.
        thresholds: one per stage but the last: a query whose confidence at that stage is
            below it goes on to the next stage.
        meta: how it was calibrated (validation figures, the rule that chose it).
    """

    encoders: tuple[str, ...]
    measure: str
    k: int
    thresholds: tuple[float, ...]
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.encoders) < 2:
            raise ConfigError(f"a cascade needs two or more encoder sets, got {self.encoders}")
        if len(self.thresholds) != len(self.encoders) - 1:
            raise ConfigError(f"{len(self.encoders)} stages need {len(self.encoders) - 1} "
                              f"thresholds, got {len(self.thresholds)}")
        if self.measure not in MEASURES:
            raise ConfigError(f"unknown confidence measure {self.measure!r}")
        if self.k < 1:
            raise ConfigError(f"k={self.k} must be >= 1")

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration as JSON (atomically)."""
        return write_atomic(path, json.dumps(
            {"format": FORMAT, "encoders": list(self.encoders), "measure": self.measure,
             "k": self.k, "thresholds": [None if not np.isfinite(t) else t
                                         for t in self.thresholds],
             "meta": self.meta}, indent=1) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> CascadeCalibration:
        """Read a calibration written by `save`.

        Raises:
            DataNotFoundError: the file does not exist (train it: `ratouch train cascade`).
            DataError: it is not a cascade calibration.
        """
        path = Path(path)
        if not path.is_file():
            raise DataNotFoundError(f"no cascade calibration at {path}: run `ratouch train "
                                    "cascade` (it needs each encoder's retriever and "
                                    "generators)")
        try:
            d = json.loads(path.read_text())
            if d.get("format") != FORMAT:
                raise ValueError(f"format {d.get('format')!r}, expected {FORMAT!r}")
            return cls(tuple(d["encoders"]), d["measure"], int(d["k"]),
                       tuple(np.inf if t is None else float(t) for t in d["thresholds"]),
                       d.get("meta", {}))
        except (ValueError, KeyError, TypeError) as e:
            raise DataError(f"{path} is not a cascade calibration: {e}") from e


class Cascade:
    """Encoder sets, smallest first, serving as one pipeline.

    Each query is decoded once, encoded by the first stage and searched at the calibration's
    K; when its confidence reaches the stage's threshold the stage answers it from those
    embeddings, otherwise the next stage encodes and answers it (the last stage always
    answers). Requests without a tactile image have no joint query: the first stage answers
    them (image-only retrieval needs no larger model).

    Args:
        pipelines: one loaded pipeline per stage, in the calibration's order, over the same
            corpus entries.
        calibration: the stages' names, confidence measure and thresholds.
    """

    def __init__(self, pipelines: Sequence[RATouchPipeline], calibration: CascadeCalibration):
        names = tuple(p.encoders.name for p in pipelines)
        if names != calibration.encoders:
            raise ConfigError(f"the calibration is for {calibration.encoders}, the pipelines "
                              f"are {names}")
        sizes = {len(p.corpus.entries) for p in pipelines}
        if len(sizes) != 1:
            raise ConfigError(f"the cascade's stages search different corpora (sizes {sizes})")
        self.stages = list(pipelines)
        self.calibration = calibration
        self.name = f"{CASCADE} ({' > '.join(names)})"
        self._classes = np.array([e.class_name for e in pipelines[0].corpus.entries])

    @classmethod
    def load(cls, path: str | os.PathLike | None = None,
             corpus: str | os.PathLike | None = None, index: str = "flat") -> "Cascade":
        """The calibrated cascade (default: the shipped one) with its stages' pipelines."""
        from ratouch.paths import cascade_calibration

        cal = CascadeCalibration.load(path or cascade_calibration())
        return cls([RATouchPipeline.load(name, corpus=corpus, index=index)
                    for name in cal.encoders], cal)

    # the first stage stands for the cascade where one pipeline's parts are asked for
    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("stages", "calibration"):
            raise AttributeError(name)
        return getattr(self.stages[0], name)

    def confidence(self, stage: int, queries: Sequence[Mapping[str, np.ndarray]]) -> np.ndarray:
        """Stage `stage`'s confidence in each item's joint query (NaN without one)."""
        conf = np.full(len(queries), np.nan)
        rows = [j for j, q in enumerate(queries) if "joint" in q]
        if rows:
            p = self.stages[stage]
            scores, ids = p.corpus.search(
                "text", np.concatenate([queries[j]["joint"] for j in rows]), self.calibration.k)
            conf[rows] = joint_confidence(scores, ids, self._classes, self.calibration.measure)
        return conf

    def query(self, visual: Any, tactile: Any = None, box=None, k: int = 5,
              label: str | None = None, background: Any = None) -> dict:
        """`RATouchPipeline.query`, answered by the smallest confident stage; the result
        adds "cascade": {"answered_by", "stage", "escalated", "confidence": [per stage
        tried], "thresholds", "measure"}."""
        return answer_one(self.query_many, {"visual": visual, "tactile": tactile, "box": box,
                                            "k": k, "label": label, "background": background})

    def query_many(self, requests: Sequence[Mapping[str, Any]]) -> list[dict | Exception]:
        """`RATouchPipeline.query_many` through the cascade."""
        clock = Laps()
        out, items = self.stages[0].prepare_many(requests)
        confs: dict[int, list[float]] = {it["pos"]: [] for it in items}
        answered_by: dict[int, int] = {}
        earlier_ms = 0.0  # the stages an escalated query went through before its answer
        for s, stage in enumerate(self.stages):
            if not items:
                break
            if s:
                earlier_ms += (time.perf_counter() - clock.start) * 1000
                clock = Laps()
            clock.lap("preprocess")
            queries, touch = stage.encode_queries(items, clock)
            last = s == len(self.stages) - 1
            conf = self.confidence(s, queries) if not last else np.full(len(items), np.nan)
            clock.lap("confidence")
            keep = [j for j in range(len(items))
                    if last or np.isnan(conf[j]) or conf[j] >= self.calibration.thresholds[s]]
            for j, it in enumerate(items):
                if not np.isnan(conf[j]):
                    confs[it["pos"]].append(round(float(conf[j]), 4))
            if keep:
                stage.answer(out, [items[j] for j in keep], [queries[j] for j in keep],
                             [r for r, j in enumerate(keep) if j in set(touch)], clock)
                for j in keep:
                    answered_by[items[j]["pos"]] = s
                    if s and isinstance(out[items[j]["pos"]], dict):
                        t = out[items[j]["pos"]]["timings_ms"]
                        t["earlier_stages"] = round(earlier_ms, 2)
                        t["total"] = round(t["total"] + earlier_ms, 2)
            kept = set(keep)
            items = [it for j, it in enumerate(items) if j not in kept]
        for pos, s in answered_by.items():
            if isinstance(out[pos], dict):
                out[pos]["cascade"] = {
                    "answered_by": self.calibration.encoders[s], "stage": s,
                    "escalated": s > 0, "confidence": confs[pos],
                    "thresholds": [None if not np.isfinite(t) else round(float(t), 4)
                                   for t in self.calibration.thresholds],
                    "measure": self.calibration.measure}
        return out

    def regenerate(self, visual: Any, tactile: Any, neighbours: Sequence[int], box=None,
                   encoder: str | None = None) -> dict:
        """`RATouchPipeline.regenerate` by the stage named `encoder`, by default the stage
        the cascade answers this pair with (its confidence is measured again)."""
        names = self.calibration.encoders
        if encoder is not None and encoder not in names:
            raise ConfigError(f"encoder {encoder!r} is not a stage of the cascade {names}")
        s = names.index(encoder) if encoder else self.stage_for(visual, tactile, box)
        out = self.stages[s].regenerate(visual, tactile, neighbours, box=box)
        out["encoder"] = names[s]
        return out

    def stage_for(self, visual: Any, tactile: Any, box=None) -> int:
        """The stage that answers one pair: the first whose confidence reaches its threshold."""
        item = {**self.stages[0].prepare_request({"visual": visual, "tactile": tactile,
                                                  "box": box}), "pos": 0}
        for s in range(len(self.stages) - 1):
            queries, _ = self.stages[s].encode_queries([item], Laps())
            conf = self.confidence(s, queries)[0]
            if np.isnan(conf) or conf >= self.calibration.thresholds[s]:
                return s
        return len(self.stages) - 1

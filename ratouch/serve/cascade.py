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
`ratouch train cascade` (`ratouch.ship.cascade`) writes the calibration, a small JSON file
shipped beside the weights (`ratouch.paths.cascade_calibration`).

`Cascade` is an `Answerer` (`ratouch.serve.request`) over its stages' pipelines, and a model
like one `RATouchPipeline` (`answer`, `regenerate`); every result says which encoder answered,
with what confidence, and whether it was escalated.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ratouch import paths
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import write_atomic
from ratouch.search.modes import RA_TOUCH_MODE
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.serve.request import QueryRequest, QueryResult, all_answered, slots_for
from ratouch.timing import Laps

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
    """Encoder sets, smallest first, answering as one model.

    Each request is encoded by the first stage and searched at the calibration's K; when its
    confidence reaches the stage's threshold the stage answers it from those embeddings,
    otherwise the next stage encodes and answers it (the last stage always answers).
    Requests without a tactile image have no joint query: the first stage answers them
    (image-only retrieval needs no larger model).

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
        #: the corpus entries every stage searches (the first stage's index of them)
        self.corpus = pipelines[0].corpus
        self._classes = np.array([e.class_name for e in self.corpus.entries])

    @classmethod
    def load(cls, path: str | os.PathLike | None = None,
             corpus: str | os.PathLike | None = None, index: str = "flat") -> "Cascade":
        """The calibrated cascade (default: the shipped one) with its stages' pipelines."""
        cal = CascadeCalibration.load(path or paths.cascade_calibration())
        return cls([RATouchPipeline.load(name, corpus=corpus, index=index)
                    for name in cal.encoders], cal)

    def model(self, name: str | None = None) -> "Cascade":
        """The loaded model answering requests that name `name`: this one (None or
        "cascade")."""
        if name not in (None, CASCADE):
            raise ConfigError(f"unknown model {name!r}: this server answers with {self.name}")
        return self

    def confidence(self, stage: int, encoded: Sequence) -> np.ndarray:
        """Stage `stage`'s confidence in each encoded request's joint query (NaN without
        one); `encoded` is what that stage's `RATouchPipeline.encode` made."""
        conf = np.full(len(encoded), np.nan)
        rows = [j for j, e in enumerate(encoded) if RA_TOUCH_MODE in e.queries]
        if rows:  # each request searched on its own: its confidence is its own
            found = self.stages[stage].corpus.search_each(
                "text", [encoded[j].queries[RA_TOUCH_MODE] for j in rows],
                [self.calibration.k] * len(rows))
            conf[rows] = joint_confidence(np.concatenate([sc for sc, _ in found]),
                                          np.concatenate([ii for _, ii in found]),
                                          self._classes, self.calibration.measure)
        return conf

    def answer(self, requests: Sequence[QueryRequest]) -> list[QueryResult | Exception]:
        """`RATouchPipeline.answer` through the cascade: each result adds "cascade":
        {"answered_by", "stage", "escalated", "confidence": [per stage tried], "thresholds",
        "measure"}, and an escalated one's timings the "earlier_stages" it went through."""
        clock = Laps()
        # pending: the positions of the requests no stage has answered yet
        out, pending = slots_for(requests, len(self.corpus.entries))
        confs: dict[int, list[float]] = {pos: [] for pos in pending}
        earlier_ms = 0.0  # the stages an escalated query went through before its answer
        for s, stage in enumerate(self.stages):
            if not pending:
                break
            if s:
                earlier_ms += (time.perf_counter() - clock.start) * 1000
                clock = Laps()
            clock.lap("preprocess")
            batch = [requests[pos] for pos in pending]
            encoded = stage.encode(batch, clock)
            last = s == len(self.stages) - 1
            conf = self.confidence(s, encoded) if not last else np.full(len(batch), np.nan)
            clock.lap("confidence")
            for j, pos in enumerate(pending):
                if not np.isnan(conf[j]):
                    confs[pos].append(round(float(conf[j]), 4))
            keep = [j for j in range(len(batch))
                    if last or np.isnan(conf[j]) or conf[j] >= self.calibration.thresholds[s]]
            if keep:
                results = stage.respond([batch[j] for j in keep], [encoded[j] for j in keep],
                                        clock)
                for j, result in zip(keep, results):
                    if s:
                        t = result.timings_ms
                        t["earlier_stages"] = round(earlier_ms, 2)
                        t["total"] = round(t["total"] + earlier_ms, 2)
                    result.cascade = self._account(s, confs[pending[j]])
                    out[pending[j]] = result
            kept = set(keep)
            pending = [pos for j, pos in enumerate(pending) if j not in kept]
        return all_answered(out)

    def _account(self, stage: int, confidence: list[float]) -> dict:
        """The "cascade" block of a result that stage `stage` answered."""
        return {"answered_by": self.calibration.encoders[stage], "stage": stage,
                "escalated": stage > 0, "confidence": confidence,
                "thresholds": [None if not np.isfinite(t) else round(float(t), 4)
                               for t in self.calibration.thresholds],
                "measure": self.calibration.measure}

    def regenerate(self, request: QueryRequest, neighbours: Sequence[int],
                   encoder: str | None = None) -> dict:
        """`RATouchPipeline.regenerate` by the stage named `encoder`, by default the stage
        the cascade answers this request with (its confidence is measured again)."""
        names = self.calibration.encoders
        if encoder is not None and encoder not in names:
            raise ConfigError(f"encoder {encoder!r} is not a stage of the cascade {names}")
        s = names.index(encoder) if encoder else self.stage_for(request)
        out = self.stages[s].regenerate(request, neighbours)
        out["encoder"] = names[s]
        return out

    def stage_for(self, request: QueryRequest) -> int:
        """The stage that answers a request: the first whose confidence reaches its
        threshold."""
        for s in range(len(self.stages) - 1):
            conf = self.confidence(s, self.stages[s].encode([request], Laps()))[0]
            if np.isnan(conf) or conf >= self.calibration.thresholds[s]:
                return s
        return len(self.stages) - 1

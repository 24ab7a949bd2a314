"""Calibrating the encoder cascade on the world alone (`ratouch train cascade`).

The validation pairs are training-split renders far beyond any training run's indices (the
same distribution as the pairs the models were trained on, but unseen, as for the trust
calibration), with their ground-truth captions and materials. Each stage's encoder set
answers every pair as it would alone: the joint query's top-K neighbours (their material
precision@K) and the RA-Touch description read from them (its adjective F1 against the
caption). The rule, fixed before any measurement:

* a stage's threshold is the lowest at which the cascade, answering with that stage where its
  confidence reaches the threshold and with the following stages otherwise, is no worse on
  these pairs than the largest stage alone in *both* material P@K and adjective F1
  (thresholds are set from the last stage backwards; "never answer here" is always allowed);
* of the confidence measures (`ratouch.serve.cascade.MEASURES`) the one with the fewest
  stages run per query wins (ties: the order of `MEASURES`).

The test split is never used here; `ratouch bench tradeoff` measures the cascade on it.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ratouch.errors import ConfigError
from ratouch.eval.answer import RA_TOUCH, answer_split
from ratouch.eval.retrieval import entry_materials, material_precision
from ratouch.serve.cascade import MEASURES, CascadeCalibration, joint_confidence
from ratouch.train.trust import VALIDATION_START
from ratouch.vocabulary import adjective_f1
from ratouch.world.config import WorldConfig
from ratouch.world.splits import encode_test_split

log = logging.getLogger(__name__)

#: First training-split index of the cascade's validation renders (beyond the trust
#: calibration's, which start at VALIDATION_START).
CASCADE_START = VALIDATION_START + 100_000


@dataclass(frozen=True)
class CascadeConfig:
    """Validation renders and the K the confidence and P@K are measured at."""

    seed: int = 0
    n_validation: int = 1000
    k: int = 5

    def __post_init__(self) -> None:
        if self.n_validation < 50:
            raise ConfigError(f"n_validation={self.n_validation} must be >= 50")
        if self.k < 1:
            raise ConfigError(f"k={self.k} must be >= 1")


def stage_outcomes(pipeline, split, k: int) -> dict:
    """What one stage does alone on an encoded split (encoded with its own encoders): the
    joint query's top-k search, its material P@k and the RA-Touch answers' adjective F1."""
    scores, ids = pipeline.corpus.search("text", pipeline.joint_query(split.V, split.T), k)
    answers = answer_split(pipeline, split, RA_TOUCH, ids=ids).responses
    return {"scores": scores, "ids": ids,
            "precision": material_precision(ids, split.materials,
                                            entry_materials(pipeline.corpus)),
            "f1": np.array([adjective_f1(lab, a) for lab, a in zip(split.labels, answers)]),
            "answers": answers}


def choose_thresholds(conf: Sequence[np.ndarray], metrics: Sequence[dict[str, np.ndarray]]
                      ) -> tuple[list[float], dict]:
    """The rule of this module for one confidence measure.

    Args:
        conf: per stage but the last, (N,) confidence of each pair.
        metrics: per stage, {"precision": (N,), "f1": (N,)} of that stage alone.

    Returns:
        (thresholds, {"stages_run": mean stages per query, "answered_by": share per stage,
        "precision", "f1": the cascade's means}).
    """
    target = {m: float(v.mean()) for m, v in metrics[-1].items()}
    rest = {m: v.copy() for m, v in metrics[-1].items()}
    answer_stage = np.full(len(rest["f1"]), len(metrics) - 1)
    thresholds: list[float] = [np.inf] * len(conf)
    for s in range(len(conf) - 1, -1, -1):
        c = conf[s]
        for t in np.unique(np.concatenate([c, [np.inf]])):  # lowest first
            here = c >= t
            if all(np.where(here, metrics[s][m], rest[m]).mean() >= target[m] - 1e-12
                   for m in rest):
                thresholds[s] = float(t)
                break
        here = c >= thresholds[s]
        rest = {m: np.where(here, metrics[s][m], rest[m]) for m in rest}
        answer_stage = np.where(here, s, answer_stage)
    share = [float(np.mean(answer_stage == s)) for s in range(len(metrics))]
    return thresholds, {"stages_run": float(np.mean(answer_stage + 1)),
                        "answered_by": [round(x, 4) for x in share],
                        **{m: round(float(v.mean()), 4) for m, v in rest.items()}}


def calibrate_cascade(pipelines: Sequence, cfg: CascadeConfig = CascadeConfig()
                      ) -> CascadeCalibration:
    """Set the cascade's confidence measure and thresholds for `pipelines` (smallest first)
    on the world's validation renders."""
    if len(pipelines) < 2:
        raise ConfigError("a cascade needs two or more pipelines")
    t0 = time.perf_counter()
    world = WorldConfig(seed=cfg.seed)
    idx = range(CASCADE_START, CASCADE_START + cfg.n_validation)
    classes = np.array([e.class_name for e in pipelines[0].corpus.entries])
    outcomes = []
    for p in pipelines:
        split = encode_test_split(p.encoders, world, indices=idx, split="train")
        outcomes.append(stage_outcomes(p, split, cfg.k))
        log.info("cascade: %s on %d validation pairs: P@%d %.3f, F1 %.3f", p.encoders.name,
                 cfg.n_validation, cfg.k, outcomes[-1]["precision"].mean(),
                 outcomes[-1]["f1"].mean())
    metrics = [{"precision": o["precision"], "f1": o["f1"]} for o in outcomes]
    per_measure = {}
    for measure in MEASURES:
        conf = [joint_confidence(o["scores"], o["ids"], classes, measure) for o in outcomes[:-1]]
        th, summary = choose_thresholds(conf, metrics)
        per_measure[measure] = {"thresholds": [None if not np.isfinite(t) else round(t, 6)
                                               for t in th], **summary}
    best = min(MEASURES, key=lambda m: (per_measure[m]["stages_run"], MEASURES.index(m)))
    thresholds = tuple(np.inf if t is None else t for t in per_measure[best]["thresholds"])
    meta = {"seed": cfg.seed, "n_validation": cfg.n_validation,
            "validation_indices": [CASCADE_START, CASCADE_START + cfg.n_validation],
            "rule": "per stage the lowest threshold at which the cascade is no worse than the "
                    "largest stage alone in both material P@K and adjective F1 on the "
                    "validation renders; the measure with the fewest stages run per query",
            "stages": {p.encoders.name: {"precision": round(float(o["precision"].mean()), 4),
                                         "f1": round(float(o["f1"].mean()), 4)}
                       for p, o in zip(pipelines, outcomes)},
            "measures": per_measure, "seconds": round(time.perf_counter() - t0, 1)}
    return CascadeCalibration(tuple(p.encoders.name for p in pipelines), best, cfg.k,
                              thresholds, meta)

"""Answering a split offline: the one place an evaluation has a system describe encoded pairs
and has the judge score what it said.

`answer_split` gives one system's descriptions of a split's pairs -- the baseline's (no
retrieval) or RA-Touch's (reading the neighbours of a query mode, or the ids, or the neighbour
embeddings it is given), with the pipeline's generator or another one (a retrained variant, the
token arm) -- and, with a judge, the per-sample scores (`judge_answers`). Every evaluation that
answers a split goes through it: the TVL protocol (`ratouch.eval.tvl`), the controls, the
premise, the stress sweeps, the failure table, the experiments' lab, the speed/accuracy
trade-off and the cascade's calibration.

Judging follows `judge_results` (the TVL protocol): the answers of one system are judged
together (the offline judge measures the system's word rates on them); an empty answer scores 1
and counts as failed, so it does not enter those rates.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from ratouch.errors import ConfigError, DataError
from ratouch.eval.catalog import BASELINE, RA_TOUCH, SYSTEMS
from ratouch.eval.judge import RESPONSE_KEY, judge_results
from ratouch.search.modes import RA_TOUCH_MODE
from ratouch.search.retrieval import mode_query
from ratouch.vocabulary import TVL_QUESTION

__all__ = ["BASELINE", "RA_TOUCH", "SYSTEMS", "Answers", "answer_split",
           "describe", "judge_answers", "records_for", "retrieve"]


def retrieve(pipeline, V: np.ndarray, T: np.ndarray, k: int, mode: str = RA_TOUCH_MODE,
             key: str = "text") -> np.ndarray:
    """(N, k) corpus ids for a query mode (a name of `QUERY_MODES`) against a key index."""
    return pipeline.corpus.search(key, mode_query(mode, V, T, pipeline.joint_query), k)[1]


def describe(gen, V: np.ndarray, T: np.ndarray, rv: np.ndarray | None = None,
             rl: np.ndarray | None = None, batch: int = 128) -> list[str]:
    """Greedy descriptions of a generator over arrays, in batches (neighbours optional)."""
    arrays = [V, T]
    if rv is not None:
        assert rl is not None, "neighbour image embeddings without their text embeddings"
        arrays += [rv, rl]
    out: list[str] = []
    for s in range(0, len(V), batch):
        out += gen.describe(*(torch.from_numpy(np.ascontiguousarray(a[s:s + batch], np.float32))
                              for a in arrays))
    return out


def records_for(split, responses: Sequence[str | None], system: str,
                ids: np.ndarray | None = None) -> list[dict]:
    """TVL-format result records (plus the world's ground truth and sensor family, for
    failure analysis, and the corpus ids of the neighbours read, "neighbours", when `ids` are
    given)."""
    if len(responses) != len(split.labels):
        raise DataError(f"{len(responses)} responses for {len(split.labels)} test samples")
    out = [{"image_fp": split.image_fp(i), "tactile_fp": split.tactile_fp(i),
            "label": split.labels[i], RESPONSE_KEY: responses[i], "prompt": TVL_QUESTION,
            "system": system, "index": split.indices[i], "subset": split.subsets[i],
            "material": split.materials[i], "object_scale": round(split.object_scale[i], 4)}
           for i in range(len(responses))]
    for rec, family in zip(out, getattr(split, "families", None) or ()):
        rec["sensor_family"] = family
    if ids is not None:
        for rec, row in zip(out, ids):
            rec["neighbours"] = [int(i) for i in row]
    return out


def judge_answers(judge, split, responses: Sequence[str | None], name: str,
                  ids: np.ndarray | None = None) -> tuple[np.ndarray, list[dict], dict]:
    """Judge one system's answers to a split as `judge_results` does (TVL records, the
    system's word rates, failed answers scoring 1): ((N,) scores, scored records, summary)."""
    rows, summary = judge_results(records_for(split, responses, name, ids), judge)
    return np.array([r[judge.key] for r in rows], float), rows, summary


@dataclass
class Answers:
    """One system's answers to a split.

    Attributes:
        name: the system or answer set ("baseline", "ra-touch", "shuffled_0", ...), the
            records' "system".
        responses: one description per pair.
        ids: (N, K) corpus ids RA-Touch read (None for the baseline, or when neighbour
            embeddings were given instead).
        scores: (N,) judge scores (empty when not judged).
        records: the judged TVL records (empty when not judged).
        summary: `judge_results`' summary (empty when not judged).
    """

    name: str
    responses: list[str]
    ids: np.ndarray | None = None
    scores: np.ndarray = field(default_factory=lambda: np.zeros(0))
    records: list[dict] = field(default_factory=list)
    summary: dict = field(default_factory=dict)


def answer_split(pipeline, split, system: str = RA_TOUCH, *, k: int = 5,
                 mode: str = RA_TOUCH_MODE,
                 ids: np.ndarray | None = None,
                 neighbours: tuple[np.ndarray, np.ndarray] | None = None, generator=None,
                 name: str | None = None, judge=None, batch: int = 128) -> Answers:
    """One system's descriptions of a split's encoded pairs, judged when `judge` is given.

    Args:
        pipeline: a `RATouchPipeline` (its generators, retriever and corpus); may be None
            when `generator` and, for RA-Touch, `neighbours` are given.
        split: a `TestSplit` (anything with ``V`` and ``T`` when not judged).
        system: "baseline" (no retrieval) or "ra-touch".
        k, mode: RA-Touch reads the top-`k` neighbours of the `mode` query (image / tactile /
            joint) against the text index, unless `ids` or `neighbours` are given.
        ids: (N, K) corpus ids RA-Touch reads (their embeddings: `neighbour_embeddings`).
        neighbours: (Rv, Rl) neighbour embeddings RA-Touch reads, (N, K, D) each.
        generator: describes instead of the pipeline's generator of `system`.
        name: the answer set's name in the records (default: `system`).
        judge: scores the answers (`judge_answers`).
    """
    if system not in SYSTEMS:
        raise ConfigError(f"system must be one of {SYSTEMS}, got {system!r}")
    name = name or system
    if system == BASELINE:
        gen = generator or pipeline.generator_base
        responses, ids = describe(gen, split.V, split.T, batch=batch), None
    else:
        gen = generator or pipeline.generator_ra
        if neighbours is None:
            if ids is None:
                ids = retrieve(pipeline, split.V, split.T, k, mode)
            neighbours = pipeline.neighbour_embeddings(ids)
        rv, rl = neighbours
        responses = describe(gen, split.V, split.T, rv, rl, batch=batch)
    out = Answers(name, responses, ids)
    if judge is not None:
        out.scores, out.records, out.summary = judge_answers(judge, split, responses, name, ids)
    return out


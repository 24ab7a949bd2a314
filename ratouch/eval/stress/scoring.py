"""Answering and scoring one sweep point: neighbours per query mode and both generators'
descriptions; retrieval quality, judge scores and stability against the point's reference; the
natural split per object-scale bin; break points along a knob's sweep.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ratouch.eval.answer import SYSTEMS, answer_split, judge_answers, retrieve
from ratouch.eval.retrieval import entry_materials, retrieval_metrics
from ratouch.search.modes import IMAGE_MODE, QUERY_MODES, RA_TOUCH_MODE
from ratouch.vocabulary import parse_adjectives
from ratouch.world.splits import TestSplit

SCALE_BINS = ((0.0, 0.2, "<0.2"), (0.2, 0.4, "0.2-0.4"), (0.4, 0.7, "0.4-0.7"),
              (0.7, 1.01, ">=0.7"))


class Context:
    """What scoring needs once: corpus materials and caption adjectives, the judge."""

    def __init__(self, pipeline, k: int, judge):
        entries = pipeline.corpus.entries
        self.entry_mats = entry_materials(pipeline.corpus)
        self.entry_words = [set(parse_adjectives(e.caption)) for e in entries]
        self.k = k
        self.judge = judge


def answers(pipeline, split: TestSplit, k: int, fallback_image: bool) -> dict:
    """Neighbour ids per mode and both systems' descriptions."""
    ids = {m: retrieve(pipeline, split.V, split.T, k, m) for m in QUERY_MODES}
    raw = None
    if fallback_image:  # missing tactile: the modes that need a frame fall back to the image
        raw = {m: ids[m] for m in QUERY_MODES.needing_touch()}
        ids.update({m: ids[IMAGE_MODE] for m in raw})
    desc = {s: answer_split(pipeline, split, s, ids=ids[RA_TOUCH_MODE]).responses
            for s in SYSTEMS}
    return {"ids": ids, "raw_ids": raw, "desc": desc}


def split_retrieval_metrics(ids: np.ndarray, split: TestSplit, ctx: Context,
                            sel: np.ndarray | None = None) -> dict:

    labels = [set(parse_adjectives(lbl)) for lbl in split.labels]
    sel = np.ones(len(labels), bool) if sel is None else sel
    return retrieval_metrics(ids, split.materials, labels, ctx.entry_mats, ctx.entry_words, ctx.k, sel)


def _judge_scores(split: TestSplit, desc: dict, ctx: Context) -> dict[str, np.ndarray]:
    return {s: judge_answers(ctx.judge, split, desc[s], s)[0] for s in SYSTEMS}


def _jaccard(a: str, b: str) -> float:
    x, y = set(parse_adjectives(a)), set(parse_adjectives(b))
    return 1.0 if not x and not y else len(x & y) / len(x | y)


def score_point(split: TestSplit, ans: dict, ref_split: TestSplit, ref: dict,
                ctx: Context) -> dict:
    k = ctx.k
    retrieval = {}
    for m in QUERY_MODES:
        ids, rid = ans["ids"][m], ref["ids"][m]
        overlap = np.mean([len(set(a) & set(b)) / k for a, b in zip(ids, rid)])
        retrieval[m] = {**split_retrieval_metrics(ids, split, ctx),
                        "topk_overlap": round(float(overlap), 4)}
    scores = _judge_scores(split, ans["desc"], ctx)
    gens = {}
    for s in SYSTEMS:
        d, rd = ans["desc"][s], ref["desc"][s]
        gens[s] = {"judge": round(float(scores[s].mean()), 4),
                   "identical": round(float(np.mean([a == b for a, b in zip(d, rd)])), 4),
                   "adj_jaccard": round(float(np.mean([_jaccard(a, b) for a, b in zip(d, rd)])), 4)}
    out = {"retrieval": retrieval, "generators": gens,
           "paired_labels": round(float(np.mean([a == b for a, b in
                                                  zip(split.labels, ref_split.labels)])), 4)}
    if ans.get("raw_ids"):
        out["retrieval_no_fallback"] = {
            m: {**split_retrieval_metrics(ids, split, ctx),
                "topk_overlap": round(float(np.mean([len(set(a) & set(b)) / k for a, b in
                                                     zip(ids, ref["ids"][m])])), 4)}
            for m, ids in ans["raw_ids"].items()}
    return out


def scale_bins(split: TestSplit, ans: dict, ctx: Context) -> list[dict]:
    """Quality per object-scale bin of the natural split (structured close-ups apart)."""
    scale = np.asarray(split.object_scale)
    wild = np.array([s == "wild" for s in split.subsets])
    groups = [("structured", ~wild)] + [(name, wild & (scale >= lo) & (scale < hi))
                                        for lo, hi, name in SCALE_BINS]
    scores = _judge_scores(split, ans["desc"], ctx)
    rows = []
    for name, sel in groups:
        row: dict[str, Any] = {"bin": name, "n": int(sel.sum())}
        if sel.any():
            row["retrieval"] = {m: split_retrieval_metrics(ans["ids"][m], split, ctx, sel)
                                for m in QUERY_MODES}
            row["judge"] = {s: round(float(scores[s][sel].mean()), 4) for s in SYSTEMS}
        rows.append(row)
    return rows


def _series(point: dict, k: int) -> dict[str, float]:
    out = {f"P@{k} {m}": point["retrieval"][m]["material_precision"] for m in QUERY_MODES}
    out.update({f"judge {s}": point["generators"][s]["judge"] for s in SYSTEMS})
    out.update({f"overlap {m}": point["retrieval"][m]["topk_overlap"] for m in QUERY_MODES})
    return out


def break_points(points: list[dict], k: int, drop: float) -> dict[str, dict]:
    """Per series: the first sweep value whose quality is below `drop` x the reference's
    (points[0]); "holds" when none is."""
    ref = _series(points[0], k)
    out = {}
    for name, v0 in ref.items():
        threshold = drop * v0
        at = None
        for p in points[1:]:
            if _series(p, k)[name] < threshold:
                at = p
                break
        worst = min(points[1:], key=lambda p: _series(p, k)[name]) if len(points) > 1 else None
        out[name] = {"reference": v0, "threshold": round(threshold, 4),
                     "breaks_at": at["label"] if at else None,
                     "value_at_break": _series(at, k)[name] if at else None,
                     "worst": ({"label": worst["label"], "value": _series(worst, k)[name]}
                               if worst else None)}
    return out

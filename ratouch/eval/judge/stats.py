"""What every system comparison prints: the judge mean with its 95 % bootstrap CI, adjective F1
and mean length (`score_stats`), and the judging of a whole TVL-format result file
(`judge_results`); plus the rank statistics the validation uses."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ratouch.errors import ConfigError, DataError
from ratouch.eval.judge.features import is_failed
from ratouch.eval.judge.llm import LLMJudge
from ratouch.eval.judge.offline import OfflineJudge
from ratouch.eval.judge.records import (
    EVAL_KEY,
    LABEL_KEY,
    MIN_SCORE,
    RESPONSE_KEY,
    SUBSETS,
    check_records,
    parse_gpt_score,
    subset_of,
)
from ratouch.vocabulary import adjective_f1, parse_adjectives

BOOTSTRAP_SAMPLES = 2000


def mean_ci(values: Sequence[float] | np.ndarray, level: float = 0.95, n_boot: int = BOOTSTRAP_SAMPLES,
            seed: int = 0) -> tuple[float, float, float]:
    """(mean, low, high): the mean and its percentile bootstrap CI (seeded, so reproducible).

    Raises:
        DataError: If `values` is empty.
    """
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        raise DataError("a confidence interval needs at least one value")
    if not 0 < level < 1:
        raise ConfigError(f"level {level} must lie in (0, 1)")
    means = x[np.random.default_rng(seed).integers(0, x.size, (n_boot, x.size))].mean(1)
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(x.mean()), float(lo), float(hi)


def score_stats(labels: Sequence[str], responses: Sequence[str | None],
                scores: Sequence[float] | np.ndarray, seed: int = 0) -> dict:
    """What every system comparison prints: the judge mean with its 95 % bootstrap CI, label
    adjective F1 and the mean number of adjectives per answer (failed answers count 0).

    Returns:
        ``{"n", "mean", "ci_low", "ci_high", "f1", "mean_length"}``.
    """
    if not len(labels) == len(responses) == len(scores):
        raise DataError(f"{len(labels)} labels, {len(responses)} responses, {len(scores)} scores")
    mean, lo, hi = mean_ci(scores, seed=seed)
    return {"n": len(scores), "mean": mean, "ci_low": lo, "ci_high": hi,
            "f1": float(np.mean([adjective_f1(lab, r) for lab, r in zip(labels, responses)])),
            "mean_length": float(np.mean([len(parse_adjectives(r)) for r in responses]))}


def format_stats(s: Mapping) -> str:
    """``7.945 [7.901, 7.988]  F1 0.606  3.4 adj`` from `score_stats`."""
    return (f"{s['mean']:.3f} [{s['ci_low']:.3f}, {s['ci_high']:.3f}]  F1 {s['f1']:.3f}  "
            f"{s['mean_length']:.1f} adj")


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def judge_results(records: list[dict], judge: OfflineJudge | LLMJudge) -> tuple[list[dict], dict]:
    """Score every record of a TVL-format list (as one system: the offline judge measures the
    system's word rates on these answers).

    Returns:
        (copies of the records with ``judge.key`` -- ``offline_score`` or ``llm_score`` -- added,
        summary). A null or empty response scores 1 and counts as failed. The summary holds,
        per subset (SSVTP, HCT, overall), n, n_failed, the judge's mean with its 95 % bootstrap
        CI, adjective F1 and mean length (`score_stats`) and, where the ``evaluation`` field
        parses, the GPT-4 mean and how many parsed.
    """
    check_records(records)
    failed = [is_failed(r[RESPONSE_KEY]) for r in records]
    todo = [i for i, f in enumerate(failed) if not f]
    got = judge.score_many([(records[i][LABEL_KEY], records[i][RESPONSE_KEY]) for i in todo])
    scores = [MIN_SCORE] * len(records)
    for i, s in zip(todo, got):
        scores[i] = float(s)
    out = [{**rec, judge.key: s} for rec, s in zip(records, scores)]
    groups: dict[str, list[int]] = {name: [] for name in SUBSETS}
    for i, rec in enumerate(records):
        sub = subset_of(rec.get("image_fp"))
        if sub is not None:
            groups[sub].append(i)
    groups["overall"] = list(range(len(records)))
    subsets = {}
    for name, idx in groups.items():
        gpt = [g for g in (parse_gpt_score(records[i].get(EVAL_KEY)) for i in idx) if g is not None]
        stats = (score_stats([records[i][LABEL_KEY] for i in idx],
                             [records[i][RESPONSE_KEY] for i in idx], [scores[i] for i in idx])
                 if idx else {"mean": None})
        subsets[name] = {**stats, "n": len(idx), "n_failed": sum(failed[i] for i in idx),
                         "gpt4_mean": _mean(gpt), "n_gpt4": len(gpt)}
    summary = {"judge": judge.name, "score_key": judge.key, "n": len(records),
               "n_failed": sum(failed), "subsets": subsets, **judge.stats()}
    return out, summary


def format_summary(summary: dict) -> str:
    """Per-subset means (95 % bootstrap CI, adjective F1, mean length) as a small table."""
    judge = summary["judge"]
    lines = [f"{'subset':<9}{'n':>5}{'failed':>8}  {judge + ' [95% CI]':<26}{'F1':>6}{'adj':>6}"
             f"{'GPT-4':>8}"]
    for name, s in summary["subsets"].items():
        if s["mean"] is None:
            lines.append(f"{name:<9}{s['n']:>5}{s['n_failed']:>8}  -")
            continue
        gpt = f"{s['gpt4_mean']:.3f}" if s["gpt4_mean"] is not None else "-"
        ci = f"{s['mean']:.3f} [{s['ci_low']:.3f}, {s['ci_high']:.3f}]"
        lines.append(f"{name:<9}{s['n']:>5}{s['n_failed']:>8}  {ci:<26}{s['f1']:>6.3f}"
                     f"{s['mean_length']:>6.1f}{gpt:>8}")
    if judge == "llm":
        lines.append(f"LLM requests {summary['n_requests']}, errors {summary['n_errors']}, "
                     f"unparseable {summary['n_unparseable']}, "
                     f"fallbacks to the offline judge {summary['n_fallbacks']}")
    return "\n".join(lines)



def ranking(means: Mapping[str, float]) -> list[str]:
    return sorted(means, key=lambda m: (-means[m], m))


def spearman(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(a, b)[0])

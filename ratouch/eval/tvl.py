"""The TVL benchmark protocol on the world's test split (46 structured + 356 wild pairs).

Describe each test pair with a system (the no-retrieval baseline or RA-Touch), write the
answers in the TVL results format (a list of objects with ``image_fp``, ``tactile_fp``,
``label``, ``generated response``, ``prompt``), score them with a judge (`ratouch.eval.judge`), and
compare two systems with a paired t-test over the same samples. Image paths follow the world's
TVL layout (``ssvtp/...`` for the structured subset, ``hct/data1/...`` for the wild one), so the
judge's per-subset means are SSVTP / HCT / overall as in the paper's Table 1.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ratouch.errors import ConfigError, DataError
from ratouch.eval.answer import (  # noqa: F401 - describe, records_for, retrieve: re-exported
    BASELINE,
    SYSTEMS,
    answer_split,
    describe,
    records_for,
    retrieve,
)
from ratouch.eval.judge import (
    LABEL_KEY,
    RESPONSE_KEY,
    OfflineJudge,
    format_stats,
    score_stats,
    subset_of,
)
from ratouch.search.modes import RETRIEVAL_SYSTEMS
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for
from ratouch.world.material import material
from ratouch.world.sampler import TEST_SIZE
from ratouch.world.splits import TestSplit, encode_test_split


def run_tvl(pipeline, system: str, k: int = 5, judge=None, world: WorldConfig | None = None,
            split: TestSplit | None = None, retrieval: str = "paper"
            ) -> tuple[list[dict], dict]:
    """Generate, judge and summarise one system on the world's test split (the summary also
    holds the judge's mean per sensor family, "families"); `retrieval`: the retrieval system
    RA-Touch reads with (`RETRIEVAL_SYSTEMS`, each with its own generator,
    `RATouchPipeline.system_generator`; the test split's frames all look like rendered units,
    so `fallback` answers there as `paper` does)."""
    if retrieval not in RETRIEVAL_SYSTEMS:
        raise ConfigError(f"unknown retrieval system {retrieval!r}; one of "
                          f"{', '.join(RETRIEVAL_SYSTEMS)}")
    split = split or encode_test_split(pipeline.encoders, world)
    gen = getattr(pipeline, "system_generator", None)
    ans = answer_split(pipeline, split, system, k=k, judge=judge or OfflineJudge(),
                       mode=RETRIEVAL_SYSTEMS[retrieval],
                       generator=gen(retrieval) if gen is not None and system != BASELINE
                       else None)
    ans.summary.update({"system": system, "k": k, "world_seed": split.world.seed,
                        "retrieval": retrieval, "families": family_stats(ans.records)})
    return ans.records, ans.summary


def family_stats(records: Sequence[dict]) -> dict[str, dict]:
    """`score_stats` of judged world records per sensor family (their "sensor_family"), in
    the order the families first appear; {} when the records name none."""
    if not records:
        return {}
    key = score_key(records)
    groups: dict[str, list[dict]] = {}
    for rec in records:
        if rec.get("sensor_family"):
            groups.setdefault(rec["sensor_family"], []).append(rec)
    return {name: score_stats([r[LABEL_KEY] for r in recs], [r[RESPONSE_KEY] for r in recs],
                              [float(r[key]) for r in recs])
            for name, recs in groups.items()}


def score_key(records: Sequence[dict]) -> str:
    for key in ("offline_score", "llm_score"):
        if records and all(key in r for r in records):
            return key
    raise DataError("the results carry no judge score on every record: run `ratouch judge` "
                    "on them first")


def paired_ttest(a: Sequence[dict], b: Sequence[dict], key: str | None = None) -> dict:
    """Paired t-test of two scored result lists over the samples they share.

    Samples are matched by (image_fp, tactile_fp); the difference is b - a, per subset and
    overall. A sample present in only one file is left out and counted.
    """
    from scipy.stats import ttest_rel

    key = key or score_key(a)
    if key not in b[0]:
        raise DataError(f"the second results file has no {key!r} scores")

    def by_pair(recs):
        out = {}
        for r in recs:
            out[(r.get("image_fp"), r.get("tactile_fp"))] = r
        return out

    ra, rb = by_pair(a), by_pair(b)
    common = [p for p in ra if p in rb]
    if len(common) < 2:
        raise DataError(f"only {len(common)} samples are shared by the two results files; "
                        "a paired test needs the same samples in both")
    groups: dict[str, list] = {"SSVTP": [], "HCT": [], "overall": common}
    for p in common:
        sub = subset_of(p[0])
        if sub:
            groups[sub].append(p)
    subsets: dict[str, dict] = {}
    out = {"key": key, "n_shared": len(common), "only_first": len(ra) - len(common),
           "only_second": len(rb) - len(common), "subsets": subsets}
    for name, pairs in groups.items():
        if not pairs:
            continue
        x = np.array([float(ra[p][key]) for p in pairs])
        y = np.array([float(rb[p][key]) for p in pairs])
        row = {"n": len(pairs), "mean_a": round(float(x.mean()), 4),
               "mean_b": round(float(y.mean()), 4), "diff": round(float((y - x).mean()), 4),
               "stats_a": _stats(ra, pairs, key), "stats_b": _stats(rb, pairs, key)}
        if len(pairs) >= 2 and np.any(y - x):
            t = ttest_rel(y, x)
            row.update({"t": round(float(t.statistic), 3), "p": float(t.pvalue)})
        else:
            row.update({"t": 0.0, "p": 1.0})
        subsets[name] = row
    return out


def _stats(by_pair: dict, pairs: list, key: str) -> dict:
    """`score_stats` (mean, 95 % bootstrap CI, F1, mean length) of one file on `pairs`."""
    recs = [by_pair[p] for p in pairs]
    s = score_stats([r[LABEL_KEY] for r in recs], [r.get(RESPONSE_KEY) for r in recs],
                    [float(r[key]) for r in recs])
    return s


def format_ttest(result: dict, name_a: str = "A", name_b: str = "B") -> str:
    """The t-test table, then each file's means with 95 % bootstrap CI, F1 and length."""
    lines = [f"paired t-test on {result['key']} ({result['n_shared']} shared samples; "
             f"B - A, A = {name_a}, B = {name_b})",
             f"{'subset':<9}{'n':>5}{'A':>8}{'B':>8}{'B-A':>8}{'t':>8}{'p':>11}"]
    for name, r in result["subsets"].items():
        lines.append(f"{name:<9}{r['n']:>5}{r['mean_a']:>8.3f}{r['mean_b']:>8.3f}"
                     f"{r['diff']:>+8.3f}{r['t']:>8.2f}{r['p']:>11.2e}")
    lines.append("mean [95% bootstrap CI], adjective F1, adjectives per answer:")
    for name, r in result["subsets"].items():
        lines.append(f"  {name:<8} A {format_stats(r['stats_a'])}   B {format_stats(r['stats_b'])}")
    return "\n".join(lines)



def oracle_answer(material_name: str, n: int) -> str:
    """The material's `n` most typical adjectives (highest profile weight first)."""
    profile = sorted(material(material_name).profile, key=lambda wv: -wv[1])
    return ", ".join(w for w, _ in profile[:max(1, n)])


def oracle_length_effect(judge=None, world: WorldConfig | None = None,
                         lengths: Sequence[int] = (2, 3, 4, 5)) -> dict:
    """The judge's length effect: a material oracle's mean score with n adjectives.

    The oracle knows each test pair's material and answers the n heaviest words of its tactile
    profile (labels are random draws from that profile); no pixel is rendered. Each length is
    judged as its own system (its own word rates).

    Returns:
        ``{"lengths": [...], "means": {n: mean}, "stats": {n: score_stats}, "spread"}``, spread
        being the largest minus the smallest mean.
    """
    gen = world_for(world or WorldConfig())
    plans = [gen.plan("test", i) for i in range(TEST_SIZE)]
    labels = [", ".join(p[5]) if not isinstance(p[5], str) else p[5] for p in plans]
    judge = judge or OfflineJudge()
    stats = {}
    for n in lengths:
        answers = [oracle_answer(p[2].name, n) for p in plans]
        stats[n] = score_stats(labels, answers, judge.score_many(zip(labels, answers)))
    means = {n: s["mean"] for n, s in stats.items()}
    return {"lengths": list(lengths), "means": means, "stats": stats,
            "spread": max(means.values()) - min(means.values())}

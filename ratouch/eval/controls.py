"""Controls for RA-Touch: does the generator read its neighbours, and what could they give it?

`run_controls` describes the world's test split with the shipped generators and compares, with
the same judge, answers that differ in one thing only:

* **baseline**: no retrieval;
* **RA-Touch**: the joint query's own top-K neighbours;
* **neighbours shuffled**: each query reads another query's neighbours (a derangement, several
  seeds): if this scores like RA-Touch, the generator does not read its neighbours;
* **integrator zeroed**: RA-Touch's own weights with the integrator's output set to zero (the
  prompt p instead of p + delta): what the integrator adds at all;
* **copy the captions**: no generator, the adjectives most often named by the K retrieved
  captions (a vote), as many as the baseline says for that sample: what retrieval alone knows;
* **copy, perfect retrieval**: the same vote over K corpus entries of the true material: the
  ceiling of what the corpus's captions can give;
* **material oracle**: the true material's most typical adjectives (its tactile profile), as
  many as the baseline says: the ceiling of any answer that knows the material.

Every system is judged as a whole (the offline judge weighs words by how often the system says
them), reported with its 95 % bootstrap CI, adjective F1 and mean length; paired differences
carry their own CI. Copies and oracles are length-matched to the baseline, since the judge
rewards length.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Callable, Sequence

import numpy as np
import torch

from ratouch.errors import ConfigError
from ratouch.eval.answer import BASELINE, RA_TOUCH, Answers, answer_split, judge_answers
from ratouch.eval.judge import OfflineJudge, format_stats, mean_ci, score_stats
from ratouch.eval.tvl import oracle_answer
from ratouch.vocabulary import parse_adjectives
from ratouch.world.splits import TestSplit, encode_test_split

log = logging.getLogger(__name__)


def derangement(n: int, seed: int) -> np.ndarray:
    """A random permutation of range(n) with no fixed point (each query gets another's)."""
    if n < 2:
        raise ConfigError(f"shuffling neighbours needs at least 2 queries, got {n}")
    order = np.random.default_rng(seed).permutation(n)
    out = np.empty(n, np.int64)
    out[order] = np.roll(order, -1)  # each element maps to the next one in a random cycle
    return out


def vote(captions: Sequence[str], n: int) -> str:
    """The `n` adjectives named most often by `captions` (ties: first named first)."""
    counts = Counter(w for c in captions for w in parse_adjectives(c))
    return ", ".join(w for w, _ in counts.most_common(max(1, n)))


class _ZeroIntegrator:
    """Context: the generator's integrator returns a zero delta (p' = p)."""

    def __init__(self, gen):
        self.module = gen.integrator

    def __enter__(self):
        self.handle = self.module.register_forward_hook(lambda m, args, out: torch.zeros_like(out))
        return self

    def __exit__(self, *exc):
        self.handle.remove()


def _answers(pipeline, split: TestSplit, k: int, shuffles: int, seed: int, judge
             ) -> tuple[dict[str, Answers], np.ndarray]:
    """Every control's answers on the split, judged, and the joint query's neighbour ids."""
    p = pipeline
    ids = p.joint_neighbours(split.V, split.T, k)

    def ra(name: str, nb: np.ndarray) -> Answers:
        return answer_split(p, split, RA_TOUCH, ids=nb, name=name, judge=judge)

    out = {"baseline": answer_split(p, split, BASELINE, judge=judge),
           "ra_touch": ra("ra_touch", ids)}
    for s in range(shuffles):
        name = f"shuffled_{s}"
        out[name] = ra(name, ids[derangement(len(ids), seed + s)])
    with _ZeroIntegrator(p.generator_ra):
        out["integrator_zeroed"] = ra("integrator_zeroed", ids)
    lengths = [len(parse_adjectives(a)) for a in out["baseline"].responses]
    entries = p.corpus.entries
    by_material: dict[str, list[int]] = {}
    for i, e in enumerate(entries):
        by_material.setdefault(e.material, []).append(i)
    made = {  # answers without a generator: length-matched copies and the oracle
        "copy_captions": [vote([entries[i].caption for i in row], n)
                          for row, n in zip(ids, lengths)],
        "copy_perfect_retrieval": [
            vote([entries[i].caption for i in by_material.get(m, [])[:k]], n)
            for m, n in zip(split.materials, lengths)],
        "material_oracle": [oracle_answer(m, n) for m, n in zip(split.materials, lengths)]}
    for name, responses in made.items():
        out[name] = Answers(name, responses, scores=judge_answers(judge, split, responses, name)[0])
    return out, ids


def run_controls(pipeline, k: int = 5, shuffles: int = 3, judge=None, seed: int = 0,
                 split: TestSplit | None = None, keep_scores: bool = False) -> dict:
    """Judge every control on the test split, or on `split` (see the module docstring).

    Returns:
        {"k", "n", "systems": {name: score_stats}, "paired_vs_baseline": {name: {"diff",
        "ci_low", "ci_high"}}, "shuffle": {"changed_share", "diff", "ci_low", "ci_high"},
        "zeroed", "reading"}, and with `keep_scores` "scores": {answer set: (N,) judge scores}
        (the shuffles as "shuffled_0", ...)
    """
    if shuffles < 1:
        raise ConfigError(f"shuffles={shuffles} must be >= 1")
    judge = judge or OfflineJudge()
    split = split or encode_test_split(pipeline.encoders)
    answered, ids = _answers(pipeline, split, k, shuffles, seed, judge)
    answers = {name: a.responses for name, a in answered.items()}
    scores = {name: a.scores for name, a in answered.items()}
    systems = {name: score_stats(split.labels, answers[name], scores[name], seed=seed)
               for name in answers if not name.startswith("shuffled_")}
    shuffled = np.mean([scores[f"shuffled_{s}"] for s in range(shuffles)], axis=0)
    systems["neighbours_shuffled"] = score_stats(
        split.labels, answers["shuffled_0"], shuffled, seed=seed)
    base, ra = scores["baseline"], scores["ra_touch"]
    paired = {name: _diff(s - base, seed) for name, s in
              (("ra_touch", ra), ("integrator_zeroed", scores["integrator_zeroed"]),
               ("neighbours_shuffled", shuffled), ("copy_captions", scores["copy_captions"]),
               ("copy_perfect_retrieval", scores["copy_perfect_retrieval"]),
               ("material_oracle", scores["material_oracle"]))}
    changed = np.mean([[a != b for a, b in zip(answers["ra_touch"], answers[f"shuffled_{s}"])]
                       for s in range(shuffles)])
    out = {"k": k, "n": len(split.labels), "shuffles": shuffles, "judge": judge.name,
           "systems": systems, "paired_vs_baseline": paired,
           "shuffle": {"changed_share": round(float(changed), 4), **_diff(ra - shuffled, seed)},
           "zeroed": _diff(ra - scores["integrator_zeroed"], seed),
           "reading": reading_diagnostics(pipeline, split, ids)}
    if keep_scores:
        out["scores"] = scores
    return out


def reading_diagnostics(pipeline, split: TestSplit, ids: np.ndarray) -> dict:
    """Why a generator might ignore its neighbours: how alike they are (distinct captions of
    the K, mean pairwise cosine of their text embeddings) and how the integrator attends
    over them, its weights averaged over heads (mean largest weight against the uniform
    1/K, mean entropy / log K)."""
    entries = pipeline.corpus.entries
    distinct = np.mean([len({entries[i].caption for i in row}) for row in ids])
    _, rl = pipeline.neighbour_embeddings(ids)                              # (N, K, D)
    rl = rl / np.maximum(np.linalg.norm(rl, axis=2, keepdims=True), 1e-12)
    k = ids.shape[1]
    sims = np.einsum("nkd,njd->nkj", rl, rl)
    pairwise = (sims.sum((1, 2)) - k) / max(1, k * (k - 1))
    out = {"k": k, "distinct_captions": round(float(distinct), 3),
           "key_cosine": round(float(pairwise.mean()), 4), "attention": {}}
    _, weights = pipeline.ra_prefix(split.V, split.T, ids)
    for name, w in weights.items():                                          # (N, K)
        w = np.clip(w, 1e-12, 1.0)
        out["attention"][name] = {
            "max": round(float(w.max(1).mean()), 4), "uniform": round(1 / k, 4),
            "entropy_over_log_k": round(float((-(w * np.log(w)).sum(1) / np.log(k)).mean()), 4)}
    return out


def _diff(d: np.ndarray, seed: int) -> dict[str, float]:
    mean, lo, hi = mean_ci(d, seed=seed)
    return {"diff": round(mean, 4), "ci_low": round(lo, 4), "ci_high": round(hi, 4)}


SYSTEM_NAMES = {
    "baseline": "baseline (no retrieval)", "ra_touch": "RA-Touch (own neighbours)",
    "neighbours_shuffled": "RA-Touch, neighbours shuffled", "integrator_zeroed":
    "RA-Touch, integrator zeroed", "copy_captions": "copy the K captions (vote)",
    "copy_perfect_retrieval": "copy, perfect retrieval", "material_oracle": "material oracle",
}


def format_controls(r: dict, fmt: Callable[[dict], str] = format_stats) -> str:
    """The controls as a table: judge mean [95 % CI], F1, length; the difference to the
    baseline [CI]; then the shuffle and zeroing effects on RA-Touch."""
    lines = [f"controls on the world's test split ({r['n']} pairs, K={r['k']}, judge "
             f"{r['judge']}; copies and oracles length-matched to the baseline)",
             f"{'system':<32}{'judge [95% CI]  F1  length':<44}vs baseline [95% CI]"]
    for name, label in SYSTEM_NAMES.items():
        d = r["paired_vs_baseline"].get(name)
        diff = f"{d['diff']:+.3f} [{d['ci_low']:+.3f}, {d['ci_high']:+.3f}]" if d else ""
        lines.append(f"{label:<32}{fmt(r['systems'][name]):<44}{diff}")
    s, z = r["shuffle"], r["zeroed"]
    d = r.get("reading")
    if d:
        att = "; ".join(f"{name}: largest weight {a['max']:.3f} (uniform {a['uniform']:.3f}), "
                        f"entropy {a['entropy_over_log_k']:.3f} of the maximum"
                        for name, a in d["attention"].items())
        lines.append(f"what RA-Touch reads: {d['distinct_captions']:.2f} distinct captions among "
                     f"its {d['k']} neighbours, their text embeddings' mean pairwise cosine "
                     f"{d['key_cosine']:.3f}; integrator attention {att or 'not reported'}")
    lines += [f"shuffling the neighbours changes {s['changed_share']:.1%} of RA-Touch's answers; "
              f"RA-Touch minus shuffled: {s['diff']:+.3f} [{s['ci_low']:+.3f}, "
              f"{s['ci_high']:+.3f}] (mean of {r['shuffles']} shuffles)",
              f"RA-Touch minus integrator zeroed: {z['diff']:+.3f} [{z['ci_low']:+.3f}, "
              f"{z['ci_high']:+.3f}]"]
    return "\n".join(lines)

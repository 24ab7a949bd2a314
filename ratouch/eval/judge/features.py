"""The offline judge's word features: word rates, informativeness and the per-answer features.

Every answer word is weighed by its informativeness: words that fit nearly every label (label
base rates, from the fit data) or that the judged system says for nearly every sample (its own
word rates, measured at judge time on the answers being judged) earn little; antonym clashes
cost. `judge_features` turns one answer into the `FEATURES` the calibration maps to 1-10.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ratouch.errors import DataError
from ratouch.eval.judge.lexicon import MATCHED, MEMBERS, NON_TACTILE, antonymy, similarity
from ratouch.vocabulary import EXTRA_TACTILE, TVL_ADJECTIVES, parse_adjectives

FEATURES = ("precision", "exact_precision", "recall", "antonym_clash", "non_tactile_share")
PSEUDO_ANSWERS = 10.0  # a system's word rates are count / (n + 10): one answer ignores nothing
IGNORE_BELOW = 0.1     # informativeness under this counts as 0 (the word is ignored)


@dataclass(frozen=True)
class WordRates:
    """How often one system says each word: the share of its answers that contain it.

    Computed at judge time from the answers being judged (`answer_rates`); shrunk towards 0 by
    `PSEUDO_ANSWERS`, so a file of a few answers ignores little and a word said in every one of
    400 answers is worth almost nothing.
    """

    counts: Mapping[str, int]
    n: int

    def rate(self, word: str) -> float:
        return self.counts.get(word, 0) / (self.n + PSEUDO_ANSWERS)


NO_RATES = WordRates({}, 0)


def answer_rates(responses: Iterable[str | None]) -> WordRates:
    """The word rates of one system's answers (failed answers count as answers saying nothing)."""
    counts: dict[str, int] = {}
    n = 0
    for r in responses:
        n += 1
        for w in parse_adjectives(r):
            counts[w] = counts.get(w, 0) + 1
    return WordRates(counts, n)


def label_fit_rates(labels: Iterable[str], extra_words: Iterable[str] = ()) -> dict[str, float]:
    """Label-side base rate of every word: its mean best similarity to a label, over labels.

    A word that fits nearly every label ("textured", "uneven") has a rate near 1 and earns little
    when it matches. Computed for the words of the labels, of `extra_words` and of the lexicon.
    """
    labs = [parse_adjectives(x) for x in labels]
    labs = [x for x in labs if x]
    if not labs:
        raise DataError("label base rates need at least one non-empty label")
    vocab = ({w for x in labs for w in x} | set(extra_words) | set(MEMBERS)
             | set(TVL_ADJECTIVES) | set(EXTRA_TACTILE))
    return {w: round(sum(max(similarity(w, lw) for lw in x) for x in labs) / len(labs), 4)
            for w in sorted(vocab)}


def informativeness(word: str, label_rates: Mapping[str, float], rates: WordRates) -> float:
    """(1 - b^2) * (1 - f^2), b the word's label base rate and f the system's rate of it; 0
    below `IGNORE_BELOW`. (Squares: chosen over the linear and square-root forms by
    leave-one-system-out agreement, see docs/judge.md.)"""
    u = (1.0 - label_rates.get(word, 0.0) ** 2) * (1.0 - rates.rate(word) ** 2)
    return u if u >= IGNORE_BELOW else 0.0


def word_table(label: Sequence[str], predicted: Sequence[str], label_rates: Mapping[str, float],
               rates: WordRates = NO_RATES) -> list[dict]:
    """Per predicted word: best label match, similarity, clash strength, rates and weight."""
    rows = []
    for p in predicted:
        sims = [similarity(p, lw) for lw in label]
        best = max(sims)
        clash = max(antonymy(p, lw) for lw in label) if best < MATCHED else 0.0
        u = informativeness(p, label_rates, rates)
        if p in NON_TACTILE:
            status = "non-tactile"
        elif best >= MATCHED:
            status = "matched" if u > 0 else "ignored"
        elif clash > 0:
            status = "clash"
        else:
            status = "unmatched" if u > 0 else "ignored"
        rows.append({"word": p, "status": status, "label_word": label[sims.index(best)] if best
                     else None, "similarity": round(best, 3), "clash": round(clash, 3),
                     "label_rate": label_rates.get(p, 0.0), "system_rate": round(rates.rate(p), 3),
                     "weight": round(u, 3)})
    return rows


def judge_features(label: Sequence[str], predicted: Sequence[str],
                   label_rates: Mapping[str, float], rates: WordRates = NO_RATES) -> list[float]:
    """The `FEATURES` of a predicted adjective list against the label's (both non-empty).

    Credit is weighted by informativeness: precision and recall count a predicted word by its
    weight, so an ignored word (weight 0) neither helps nor hurts; antonym clashes always cost.
    """
    table = word_table(label, predicted, label_rates, rates)
    u = np.array([t["weight"] for t in table])
    best = np.array([t["similarity"] for t in table])
    exact = np.array([float(p in set(label)) for p in predicted])
    mass = float(u.sum())
    precision = float(u @ best) / mass if mass > 0 else 0.0
    exact_precision = float(u @ exact) / mass if mass > 0 else 0.0
    recall = sum(max(similarity(lw, p) * w for p, w in zip(predicted, u)) for lw in label) / len(label)
    clash = float(sum(t["clash"] for t in table))
    non_tactile = sum(p in NON_TACTILE for p in predicted) / len(predicted)
    return [precision, exact_precision, float(recall), clash, non_tactile]


def is_failed(response: object) -> bool:
    return not parse_adjectives(response if isinstance(response, str) else None)

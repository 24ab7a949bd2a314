"""Style shifts of the validation: the judge's answers rewritten (padded, truncated, shuffled,
contradicted), what GPT-4 would be expected to do, its chance level, and the length effect."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ratouch.errors import ConfigError
from ratouch.eval.judge.calibration import MODELS, gpt4_rows
from ratouch.eval.judge.features import word_table
from ratouch.eval.judge.lexicon import MATCHED, MEMBERS, OPPOSITE
from ratouch.eval.judge.offline import OfflineJudge
from ratouch.eval.judge.records import LABEL_KEY, RESPONSE_KEY
from ratouch.vocabulary import EXTRA_TACTILE, TVL_ADJECTIVES, parse_adjectives


def generic_words(label_rates: Mapping[str, float], n: int = 3) -> list[str]:
    """The `n` tactile words that fit the most labels (the padding of the style-shift test)."""
    tactile = set(TVL_ADJECTIVES) | set(EXTRA_TACTILE)
    return sorted((w for w in label_rates if w in tactile), key=lambda w: (-label_rates[w], w))[:n]


def antonym_answer(label: str) -> str | None:
    """An answer that contradicts the label: the head word of each group opposite to a label
    word's groups ("soft, fuzzy" -> "hard"); None when no label word has an antonym."""
    out: list[str] = []
    for w in parse_adjectives(label):
        for g in MEMBERS.get(w, {}):
            out += [b for a, b in sorted(OPPOSITE) if a == g and b not in out]
    return ", ".join(out) if out else None


def style_shift(kind: str, labels: Sequence[str], responses: Sequence[str | None], seed: int = 0,
                pad: Sequence[str] = ()) -> list[str | None]:
    """One system's answers rewritten in another style: "pad" (append the `pad` words),
    "truncate" (first word only), "shuffle" (answers permuted across samples, seeded) or
    "antonyms" (contradict the label; None where it has no antonym)."""
    if kind == "pad":
        return [", ".join(parse_adjectives(r) + [w for w in pad if w not in parse_adjectives(r)])
                for r in responses]
    if kind == "truncate":
        return [next(iter(parse_adjectives(r)), None) for r in responses]
    if kind == "shuffle":
        perm = np.random.default_rng(seed).permutation(len(responses))
        return [responses[i] for i in perm]
    if kind == "antonyms":
        return [antonym_answer(lab) for lab in labels]
    raise ConfigError(f"unknown style shift {kind!r}")


SHIFTS = {  # kind: what GPT-4 would be expected to do
    "pad": "must not rise (generic words carry no information)",
    "truncate": "must fall (fewer correct adjectives)",
    "shuffle": "must fall to near the chance level",
    "antonyms": "must fall below the chance level",
}
CHANCE_TOLERANCE = 0.5


def _cell(label: str, response: str | None, label_rates: Mapping[str, float]) -> tuple[int, int]:
    table = word_table(parse_adjectives(label), parse_adjectives(response), label_rates)
    return (min(sum(t["similarity"] >= MATCHED for t in table), 3),
            min(sum(t["clash"] > 0 for t in table), 2))


def chance_level(data: Mapping[str, list[dict]], idx: Sequence[int], judge: OfflineJudge,
                 seed: int = 0) -> dict:
    """What GPT-4 would give answers shuffled across samples, estimated from its real scores.

    Each real answer falls in a cell (matched words 0/1/2/3+, contradicted words 0/1/2+); the
    chance level is the mean, over shuffled pairs, of GPT-4's mean score of the real answers in
    the shuffled pair's cell. ``floor``: GPT-4's mean over real answers matching nothing.
    """
    rows = [r for r in gpt4_rows(data, idx) if parse_adjectives(r[1])]
    cells: dict[tuple[int, int], list[float]] = {}
    for r in rows:
        cells.setdefault(_cell(r[0], r[1], judge.label_rates), []).append(r[2])
    means = {c: float(np.mean(v)) for c, v in cells.items()}
    est = []
    for model in MODELS:
        labels = [data[model][i][LABEL_KEY] for i in idx]
        shuffled = style_shift("shuffle", labels, [data[model][i][RESPONSE_KEY] for i in idx], seed)
        for lab, resp in zip(labels, shuffled):
            c = _cell(lab, resp, judge.label_rates) if parse_adjectives(resp) else None
            if c in means:
                est.append(means[c])
    return {"chance": float(np.mean(est)), "floor": means.get((0, 0), float("nan"))}


def style_shifts(data: Mapping[str, list[dict]], idx: Sequence[int], judge: OfflineJudge,
                 seed: int = 0) -> dict:
    """The judge's mean over the three systems' answers to `idx`, as written and under each
    style shift, with the expected direction checked (each system is judged as its own file)."""
    pad = generic_words(judge.label_rates)
    levels = chance_level(data, idx, judge, seed)
    chance = levels["chance"]
    base: list[float] = []
    shifted: dict[str, list[float]] = {k: [] for k in SHIFTS}
    for model in MODELS:
        labels = [data[model][i][LABEL_KEY] for i in idx]
        responses = [data[model][i][RESPONSE_KEY] for i in idx]
        base += judge.score_many(zip(labels, responses))
        for kind in SHIFTS:
            new = style_shift(kind, labels, responses, seed, pad)
            keep = [i for i, r in enumerate(new) if r is not None]
            shifted[kind] += judge.score_many([(labels[i], new[i]) for i in keep])
    original = float(np.mean(base))
    out = {"original": original, "chance_level_gpt4": chance, "no_match_gpt4": levels["floor"],
           "pad_words": pad, "shifts": {}}
    for kind, scores in shifted.items():
        m = float(np.mean(scores))
        ok = {"pad": m <= original + 0.05, "truncate": m < original,
              "shuffle": m < original and abs(m - chance) <= CHANCE_TOLERANCE,
              "antonyms": m < min(original, chance)}[kind]
        out["shifts"][kind] = {"n_answers": len(scores), "mean": m, "change": m - original,
                               "expected": SHIFTS[kind], "as_expected": bool(ok)}
    return out


def length_effect(data: Mapping[str, list[dict]], idx: Sequence[int], judge: OfflineJudge) -> dict:
    """What one more adjective does to the score at fixed content, for GPT-4 and for the judge.

    Least squares of the score on (matched words, contradicted words, predicted words, label
    words) over the three systems' answers to `idx`; the ``per_adjective`` coefficients are the
    change per extra adjective that neither matches nor contradicts the label.
    """
    features: list[list[float]] = []
    gpt: list[float] = []
    off: list[float] = []
    for model in MODELS:
        rows = [r for r in gpt4_rows(data, idx, [model]) if parse_adjectives(r[1])]
        off += judge.score_many([(r[0], r[1]) for r in rows])
        for r in rows:
            lab, pred = parse_adjectives(r[0]), parse_adjectives(r[1])
            table = word_table(lab, pred, judge.label_rates)
            features.append([1.0, sum(t["similarity"] >= MATCHED for t in table),
                             sum(t["clash"] > 0 for t in table), len(pred), len(lab)])
            gpt.append(r[2])
    X = np.asarray(features)
    coef = {name: np.linalg.lstsq(X, np.asarray(y), rcond=None)[0]
            for name, y in (("gpt4", gpt), ("offline", off))}
    fits = {name: {"per_matched": float(c[1]), "per_contradicted": float(c[2]),
                   "per_adjective": float(c[3])} for name, c in coef.items()}
    return {**fits, "difference_per_adjective": (fits["offline"]["per_adjective"]
                                                 - fits["gpt4"]["per_adjective"])}

"""How well a recaptioner agrees with the world's own adjectives (`ratouch eval recaption`).

The world knows how each of its corpus entries feels: the entry's material has a tactile
profile (weights over tactile adjectives, `world/material.py`), and its five heaviest words are
the entry's own adjectives. A recaptioner sees what ImageNet-T's recaptioner sees (the class
name and the appearance-only description) and its five adjectives are compared with those:
adjective-set F1 (exact words) and the offline judge's 1-10 score, each with its bootstrap
95 % CI, on a class-stratified sample of the corpus, and milliseconds per caption.

The offline recaptioner's lexicon is built from the same material profiles (`world_lexicon`),
so it has seen the answer key's vocabulary; SmolLM2 knows only what it learnt in pretraining
and may say only TVL adjectives, while the profiles also use words beyond them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType

from ratouch.corpus.imagenet_t import stratified_world_ids, world_lexicon
from ratouch.corpus.recaption import N_ADJECTIVES, OfflineRecaptioner
from ratouch.corpus.smollm import LM_NAME, SmolLM2Recaptioner
from ratouch.errors import ConfigError
from ratouch.eval.judge import OfflineJudge, mean_ci
from ratouch.model.pretrained_lm import PretrainedLM, load_pretrained_lm
from ratouch.vocabulary import TVL_ADJECTIVES, adjective_f1
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.sampler import World

LMGetter = Callable[[], PretrainedLM]

#: The recaptioners measured, by name: each row builds one (the model loaded once, shared).
RECAPTIONERS: Mapping[str, Callable[[LMGetter], OfflineRecaptioner | SmolLM2Recaptioner]] = MappingProxyType({
    "offline": lambda lm: OfflineRecaptioner(world_lexicon()),
    "smollm2": lambda lm: SmolLM2Recaptioner(lm()),
    "smollm2-greedy": lambda lm: SmolLM2Recaptioner(lm(), greedy=True),
})


def world_adjectives(material_name: str, k: int = N_ADJECTIVES) -> list[str]:
    """The k heaviest words of a material's tactile profile (ties in profile order)."""
    profile = material(material_name).profile
    order = sorted(range(len(profile)), key=lambda i: (-profile[i][1], i))
    return [profile[i][0] for i in order[:k]]


def recaption_agreement(names: Sequence[str], n: int = 100, seed: int = 0) -> dict:
    """Each named recaptioner against the world's own adjectives on n corpus entries.

    Returns:
        ``{"n", "seed", "reference_in_tvl", "systems": {name: {"f1", "judge" (each
        [mean, low, high]), "ms_per_caption", "load_seconds", "examples"}}}``;
        ``reference_in_tvl`` is the share of reference words that are TVL adjectives (the
        most F1 a recaptioner held to them can reach, per word).
    """
    unknown = [x for x in names if x not in RECAPTIONERS]
    if unknown or not names:
        raise ConfigError(f"recaptioners {list(names)!r}: each must be one of "
                          f"{sorted(RECAPTIONERS)}")
    world = World(WorldConfig(seed=seed))
    records = [world.corpus_record(c, i) for c, i in stratified_world_ids(n, seed)]
    labels = [", ".join(world_adjectives(r.material)) for r in records]
    pairs = [(r.class_name, r.description) for r in records]
    ref_words = [w for lab in labels for w in lab.split(", ")]
    loaded: list[PretrainedLM] = []

    def lm() -> PretrainedLM:
        if not loaded:
            loaded.append(load_pretrained_lm(LM_NAME))
        return loaded[0]

    judge = OfflineJudge()
    systems = {}
    for name in names:
        recaptioner = RECAPTIONERS[name](lm)
        t0 = time.perf_counter()
        captions = [", ".join(c) for c in recaptioner.recaption_many(pairs)]
        ms = 1000 * (time.perf_counter() - t0) / len(pairs)
        f1 = [adjective_f1(lab, cap) for lab, cap in zip(labels, captions)]
        scores = judge.score_many(zip(labels, captions))
        systems[name] = {
            "f1": list(mean_ci(f1, seed=seed)), "judge": list(mean_ci(scores, seed=seed)),
            "ms_per_caption": round(ms, 1),
            "load_seconds": round(loaded[0].load_seconds, 2) if name.startswith("smollm2")
            else 0.0,
            "examples": [{"class": p[0], "description": p[1], "world": lab, "caption": cap}
                         for p, lab, cap in list(zip(pairs, labels, captions))[:5]],
        }
    return {"n": n, "seed": seed,
            "reference_in_tvl": sum(w in TVL_ADJECTIVES for w in ref_words) / len(ref_words),
            "systems": systems}


def format_recaption_agreement(r: Mapping) -> str:
    """A table of `recaption_agreement`: F1 and judge with CIs, ms per caption."""
    lines = [f"recaptioners against the world's own adjectives, n = {r['n']} corpus entries "
             f"(seed {r['seed']}); {r['reference_in_tvl']:.0%} of the reference words are "
             f"TVL adjectives",
             f"{'recaptioner':16s} {'adjective F1 [95% CI]':24s} {'judge 1-10 [95% CI]':24s} "
             f"{'ms/caption':>10s}"]
    for name, s in r["systems"].items():
        f, j = s["f1"], s["judge"]
        lines.append(f"{name:16s} {f[0]:.3f} [{f[1]:.3f}, {f[2]:.3f}]{'':6s} "
                     f"{j[0]:.2f} [{j[1]:.2f}, {j[2]:.2f}]{'':8s} {s['ms_per_caption']:>10.1f}")
    for name, s in r["systems"].items():
        for e in s["examples"][:3]:
            lines.append(f"  {name}: {e['class']!r} world [{e['world']}] -> [{e['caption']}]")
    return "\n".join(lines)

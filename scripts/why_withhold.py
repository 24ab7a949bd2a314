"""Withholding an unfamiliar sensor's touch: does the world keep its score, and does the answer
come from vision where touch is withheld?

The measures of docs/premise.md, "Touch withheld only beyond every validation render" (the
three of "An unfamiliar sensor's touch withheld" and a fourth), on the world test split (its
first N pairs), offline judge, the shipped weights. The rule is the one the serving path
answers with when `RATouchPipeline.withhold_unfamiliar` is on: in the `gated` system, a frame
beyond every validation render of the sensor families (`unfamiliar_look` at
`WITHHOLD_LIMIT`) is answered from the image query's neighbours by the reader (the paper's
generator without one) with the pipeline's neutral touch (`RATouchPipeline.neutral_touch`);
every other frame as `gated` answers.

1. the natural split: the flagged rows, and `gated` with the rule against without it;
2. every pair read with the neutral touch: the rule's answer against the baseline's;
3. every frame recoloured (channels turned, 10 % brighter), read without its background:
   the rule against the paper's system (its cost where such touch is still readable);
4. fresh renders (2 x `--fresh`, with and without contact): how many lie beyond the limit.

95 % CIs: bootstrap over pairs (the project's `mean_ci`).

    python scripts/why_withhold.py [--n N] [--k K] [--encoder E] [--seed S] [--fresh N]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np

from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split, retrieve
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.judge.stats import mean_ci
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.world.config import WorldConfig
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.sensors import LOOK_LIMIT, WITHHOLD_LIMIT, beyond_every_unit
from ratouch.world.splits import encode_test_split, world_for


def recoloured(frame: np.ndarray) -> np.ndarray:
    """A frame as a sensor the models have not learnt might show it: channels turned (RGB ->
    BRG) and 10 % brighter."""
    return np.clip(frame.astype(np.float32)[..., [2, 0, 1]] * 1.1, 0, 255).astype(np.uint8)


def _diff(a: np.ndarray, b: np.ndarray, seed: int) -> dict:
    m, lo, hi = mean_ci(a - b, seed=seed)
    return {"diff": round(m, 4), "ci95": [round(lo, 4), round(hi, 4)]}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_withhold")
    ap.add_argument("--n", type=int, default=TEST_SIZE, help="test pairs (default all 402)")
    ap.add_argument("--k", type=int, default=5)
    ap.add_argument("--encoder", default="default-s")
    ap.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    ap.add_argument("--fresh", type=int, default=1000,
                    help="fresh renders for criterion 4, each with and without contact")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)

    p = RATouchPipeline.load(args.encoder)
    test = encode_test_split(p.encoders, indices=range(min(args.n, TEST_SIZE)))
    world = world_for(WorldConfig())
    frames = [world.sample("test", i).tactile for i in test.indices]
    judge = OfflineJudge()
    neutral = np.repeat(p.neutral_touch(), len(test.T), 0)
    reader = p.generator_reader or p.generator_ra

    def score(split, kind, **kw) -> np.ndarray:
        return answer_split(p, split, kind, judge=judge, **kw).scores

    def gated(split) -> np.ndarray:
        return score(split, RA_TOUCH, ids=retrieve(p, split.V, split.T, args.k, "gated"),
                     generator=p.system_generator("gated"), name="gated")

    # the rule's answer for every row: the image query's neighbours (they do not depend on
    # touch), the reader with the neutral touch
    withheld = score(dataclasses.replace(test, T=neutral), RA_TOUCH,
                     ids=retrieve(p, test.V, test.T, args.k, "image"), generator=reader,
                     name="withheld")

    def flags(fs) -> np.ndarray:
        return np.array([beyond_every_unit(f) for f in fs])

    out: dict = {"config": {**vars(args), "n": len(test.T), "look_limit": LOOK_LIMIT,
                            "withhold_limit": WITHHOLD_LIMIT,
                            "reader": p.generator_reader is not None}}
    flagged = flags(frames)
    g = gated(test)
    rule = np.where(flagged, withheld, g)
    out["natural"] = {"flagged": int(flagged.sum()),
                      "flagged_indices": [int(i) for i in np.asarray(test.indices)[flagged]],
                      "gated": round(float(g.mean()), 4), "gated_rule": round(float(rule.mean()), 4),
                      "rule_vs_gated": _diff(rule, g, args.seed)}
    base_neutral = score(dataclasses.replace(test, T=neutral), BASELINE, name="baseline")
    out["neutral_touch"] = {"baseline": round(float(base_neutral.mean()), 4),
                            "rule": round(float(withheld.mean()), 4),
                            "rule_vs_baseline": _diff(withheld, base_neutral, args.seed + 1)}
    odd = [recoloured(f) for f in frames]
    s_odd = dataclasses.replace(test, T=p.encoders.encode_tactile(odd, None))
    f_odd = flags(odd)
    rule_odd = np.where(f_odd, withheld, gated(s_odd))
    paper_odd = score(s_odd, RA_TOUCH, k=args.k, name="paper")
    out["recoloured"] = {"flagged": int(f_odd.sum()),
                         "baseline": round(float(score(s_odd, BASELINE, name="baseline").mean()), 4),
                         "paper": round(float(paper_odd.mean()), 4),
                         "gated_rule": round(float(rule_odd.mean()), 4),
                         "rule_vs_paper": _diff(rule_odd, paper_odd, args.seed + 2)}
    out["fresh_renders"] = fresh_renders(args.fresh)
    print(json.dumps(out, indent=1))


def fresh_renders(n: int, start: int = 3_000_000) -> dict:
    """Criterion 4: of `n` fresh renders of world seed 0 (train[start:start + n]), each with
    and without contact, how many lie beyond `WITHHOLD_LIMIT` (by family)."""
    worlds = (World(WorldConfig(seed=0)), World(WorldConfig(seed=0).with_stress(no_contact=1.0)))
    beyond: dict[str, int] = {}
    total = 0
    for i in range(start, start + n):
        for w in worlds:
            s = w.sample("train", i)
            total += 1
            if beyond_every_unit(s.tactile):
                beyond[s.family] = beyond.get(s.family, 0) + 1
    return {"renders": total, "beyond": sum(beyond.values()), "by_family": beyond,
            "share": round(sum(beyond.values()) / max(total, 1), 4)}


if __name__ == "__main__":
    main()

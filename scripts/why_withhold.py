"""Withholding an unfamiliar sensor's touch: does the world keep its score, and does the answer
come from vision where touch is withheld?

The measures of docs/premise.md, "Touch withheld only beyond every validation render" (the
three of "An unfamiliar sensor's touch withheld" and a fourth), on the world test split (its
first N pairs), offline judge, the shipped weights. The rule is the one the serving path
answers with when `RATouchPipeline.withhold_unfamiliar` is on: in the `gated` system, a frame
beyond every validation render of the sensor families (`unfamiliar_look` at
`WITHHOLD_LIMIT`) is answered from the image query's neighbours by the reader (the paper's
generator without one) with the pipeline's neutral touch (`RATouchPipeline.neutral_touch`);
every other frame as `gated` answers. With `--system fallback` (docs/premise.md, "The paper's
system, falling back to vision"), every other frame as `paper` answers instead, and a fifth
measure is reported.

1. the natural split: the flagged rows, and `gated` with the rule against without it;
2. every pair read with the neutral touch: the rule's answer against the baseline's;
3. every frame recoloured (channels turned, 10 % brighter), read without its background:
   the rule against the paper's system (its cost where such touch is still readable);
4. fresh renders (2 x `--fresh`, with and without contact): how many lie beyond the limit;
5. (`--system fallback`) every frame recoloured and taken from another pair (the degraded-
   touch probe's derangement): an unfamiliar sensor whose touch also tells nothing of the
   photo, the regime of the issue's real pairs: the system, `paper`, `gated` and the baseline;
   and the premise groups' frames (`--premise` of each group) beyond the limit: where none
   is, the system's premise figures are the paper's.

95 % CIs: bootstrap over pairs (the project's `mean_ci`).

    python scripts/why_withhold.py [--system gated|fallback] [--n N] [--k K] [--encoder E]
        [--seed S] [--fresh N] [--premise N]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np

from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split, retrieve
from ratouch.eval.controls import derangement
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.judge.stats import mean_ci
from ratouch.eval.report import measured_stamp
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
    ap.add_argument("--system", choices=("gated", "fallback"), default="gated",
                    help="the system the rule answers in (every other frame answers as it does)")
    ap.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    ap.add_argument("--fresh", type=int, default=1000,
                    help="fresh renders for criterion 4, each with and without contact")
    ap.add_argument("--premise", type=int, default=500,
                    help="(fallback) frames of each premise group checked against the limit")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)

    # when and on what code it was measured: the app's Benchmarks tab dates the result by it
    made = measured_stamp()
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

    def paper(split) -> np.ndarray:
        return score(split, RA_TOUCH, k=args.k, name="paper")

    # where the frame looks familiar, the system answers as it does without the rule
    system = gated if args.system == "gated" else paper

    # the rule's answer for every row: the image query's neighbours (they do not depend on
    # touch), the reader with the neutral touch
    withheld = score(dataclasses.replace(test, T=neutral), RA_TOUCH,
                     ids=retrieve(p, test.V, test.T, args.k, "image"), generator=reader,
                     name="withheld")

    def flags(fs) -> np.ndarray:
        return np.array([beyond_every_unit(f) for f in fs])

    out: dict = {**made, "config": {**vars(args), "n": len(test.T), "look_limit": LOOK_LIMIT,
                            "withhold_limit": WITHHOLD_LIMIT,
                            "reader": p.generator_reader is not None}}
    flagged = flags(frames)
    g = system(test)
    rule = np.where(flagged, withheld, g)
    name = args.system
    out["natural"] = {"flagged": int(flagged.sum()),
                      "flagged_indices": [int(i) for i in np.asarray(test.indices)[flagged]],
                      name: round(float(g.mean()), 4), f"{name}_rule": round(float(rule.mean()), 4),
                      f"rule_vs_{name}": _diff(rule, g, args.seed)}
    base_neutral = score(dataclasses.replace(test, T=neutral), BASELINE, name="baseline")
    out["neutral_touch"] = {"baseline": round(float(base_neutral.mean()), 4),
                            "rule": round(float(withheld.mean()), 4),
                            "rule_vs_baseline": _diff(withheld, base_neutral, args.seed + 1)}
    odd = [recoloured(f) for f in frames]
    s_odd = dataclasses.replace(test, T=p.encoders.encode_tactile(odd, None))
    f_odd = flags(odd)
    paper_odd = paper(s_odd)
    rule_odd = np.where(f_odd, withheld, gated(s_odd) if name == "gated" else paper_odd)
    out["recoloured"] = {"flagged": int(f_odd.sum()),
                         "baseline": round(float(score(s_odd, BASELINE, name="baseline").mean()), 4),
                         "paper": round(float(paper_odd.mean()), 4),
                         f"{name}_rule": round(float(rule_odd.mean()), 4),
                         "rule_vs_paper": _diff(rule_odd, paper_odd, args.seed + 2)}
    if name == "fallback":
        out["serving"] = serving_identity(p, args.k, args.n)
        out["recoloured_other"] = unfamiliar_and_wrong(
            p, test, odd, f_odd, withheld, score, paper, gated, args.seed)
        out["premise_groups"] = premise_frames(args.premise)
    out["fresh_renders"] = fresh_renders(args.fresh)
    print(json.dumps(out, indent=1))


def unfamiliar_and_wrong(p, test, odd, f_odd, withheld, score, paper, gated, seed: int
                         ) -> dict:
    """Measure 5: each pair read with another pair's recoloured frame (the degraded-touch
    probe's derangement): where that frame lies beyond the limit, the rule's answer (the
    image query's neighbours do not depend on touch, so `withheld` holds for it); elsewhere the
    paper's (for `gated`, its own). The fallback system, the paper's, the gated one (with the
    rule) and the baseline."""
    order = derangement(len(test.T), seed + 101)
    s_bad = dataclasses.replace(test, T=p.encoders.encode_tactile([odd[i] for i in order],
                                                                  None))
    flagged = f_odd[order]
    paper_bad = paper(s_bad)
    fallback = np.where(flagged, withheld, paper_bad)
    base = score(s_bad, BASELINE, name="baseline")
    return {"flagged": int(flagged.sum()), "baseline": round(float(base.mean()), 4),
            "paper": round(float(paper_bad.mean()), 4),
            "gated_rule": round(float(np.where(flagged, withheld, gated(s_bad)).mean()), 4),
            "fallback": round(float(fallback.mean()), 4),
            "fallback_vs_baseline": _diff(fallback, base, seed + 3),
            "fallback_vs_paper": _diff(fallback, paper_bad, seed + 4)}


def serving_identity(p: RATouchPipeline, k: int, n: int) -> dict:
    """Criterion 1 through the serving path (`answer_one`): the world's first `n` test pairs,
    each with and without its sensor's background, answered by `paper` and by `fallback`;
    the pairs whose descriptions or neighbours differ, and the frames the rule withholds."""
    from ratouch.serve.request import QueryRequest, answer_one

    world = World(WorldConfig())
    out = {"queries": 0, "withheld": 0, "differ": [], "differ_where_not_withheld": 0}
    for i in range(min(n, TEST_SIZE)):
        s = world.sample("test", i)
        for bg in (None, world.background_image(s.sensor)):
            got = {}
            for system in ("paper", "fallback"):
                r = answer_one(p, QueryRequest.decode(s.visual, s.tactile, box=s.box, k=k,
                                                      background=bg, retrieval=system))
                got[system] = (r.description, {m: [e["id"] for e in v]
                                               for m, v in r.neighbours.items()},
                               (r.retrieval or {}).get("kind") == "withheld")
            out["queries"] += 1
            held = got["fallback"][2]
            out["withheld"] += int(held)
            if got["paper"][:2] != got["fallback"][:2]:
                out["differ"].append([i, bg is not None])
                out["differ_where_not_withheld"] += int(not held)
    return out


def premise_frames(n: int) -> dict:
    """Of the premise groups' first `n` frames each (the groups `ratouch eval premise`
    reads, the same in every draw), those beyond `WITHHOLD_LIMIT`: the rows on which a
    withholding system's premise answers could differ from its touch-reading system's."""
    from ratouch.world.scarcity import ScarceRegime, premise_indices

    regime = ScarceRegime()
    world = world_for(WorldConfig(seed=regime.seed))
    out: dict = {}
    for group in ("seen", "scarce"):
        indices = premise_indices(group, n, regime)
        out[group] = {"frames": len(indices), "beyond": [
            i for i in indices if beyond_every_unit(world.sample("probe", i).tactile)]}
    return out


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

"""Can the paper's integrator read neighbours at all, when they carry the answer?

A diagnostic for docs/premise.md: RA-Touch's stage 2 is retrained (same budget, same stage-1
model as the shipped pair) with *perfect retrieval*: each training pair reads 5 corpus entries of
its true material instead of the joint query's neighbours. It is then judged on the premise's
seen and scarce groups with perfect neighbours and with shuffled ones. A large gain with a
significant shuffle drop means the integrator can read, and the shipped one's failure lies in
retrieval; no gain means the integrator (or its training) cannot use even perfect neighbours.

    python scripts/why_oracle_neighbours.py [--n 500] [--steps 600] [--pairs N]

(`--pairs N`: train on the first N paired training renders instead of all of them: a smoke run.)
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch
from scipy import stats

from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split
from ratouch.eval.controls import derangement
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.premise import GROUPS, group_split
from ratouch.model.generator import load_generator
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.paths import generator_weights
from ratouch.seeds import seeded_build
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.generator import GeneratorTrainConfig, train_stage2
from ratouch.train.recipes import training_pairs
from ratouch.world.scarcity import ScarceRegime


def perfect_ids(materials, by_material, fallback, k, rng):
    return np.array([rng.choice(by_material[m], k, replace=False) if len(by_material.get(m, [])) >= k
                     else fallback[i] for i, m in enumerate(materials)])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--pairs", type=int, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(2)
    pipe = RATouchPipeline.load("default-s")
    by_material: dict[str, list[int]] = {}
    for i, e in enumerate(pipe.corpus.entries):
        by_material.setdefault(e.material, []).append(i)
    rng = np.random.default_rng(0)
    data = training_pairs(pipe.encoders, n_pairs=args.pairs)
    fallback = pipe.joint_neighbours(data["V"], data["T"], 5)
    ids = perfect_ids(data["materials"], by_material, fallback, 5, rng)
    rv, rl = pipe.neighbour_embeddings(ids)
    stage1 = load_generator(generator_weights("default-s", "ra"), stage1=True)
    tc = GeneratorTrainConfig(seed=0, stage2_steps=args.steps)
    gen, _ = train_stage2(stage1, seeded_build(tc.seed, lambda: TextureAwareIntegrator(
        IntegratorConfig(dim=pipe.encoders.dim, out_dim=stage1.decoder.hidden))),
        torch.from_numpy(data["V"]), torch.from_numpy(data["T"]), data["labels"],
        torch.from_numpy(rv), torch.from_numpy(rl), tc, "ra-touch-perfect-retrieval")
    judge, out = OfflineJudge(), {}
    for g in GROUPS:
        split = group_split(pipe.encoders, g, args.n, ScarceRegime())
        nb = perfect_ids(split.materials, by_material,
                         pipe.joint_neighbours(split.V, split.T, 5), 5, rng)
        scores = {"baseline": answer_split(pipe, split, BASELINE, judge=judge).scores}
        for name, ids in (("perfect", nb), ("perfect_shuffled", nb[derangement(len(nb), 0)])):
            scores[name] = answer_split(pipe, split, RA_TOUCH, ids=ids, generator=gen, name=name,
                                        judge=judge).scores
        d, drop = scores["perfect"] - scores["baseline"], scores["perfect"] - scores["perfect_shuffled"]
        out[g] = {k: round(float(v.mean()), 4) for k, v in scores.items()}
        out[g].update(gain=round(float(d.mean()), 4), gain_p=float(stats.ttest_1samp(d, 0).pvalue),
                      shuffle_drop=round(float(drop.mean()), 4),
                      shuffle_p=float(stats.ttest_1samp(drop, 0).pvalue))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

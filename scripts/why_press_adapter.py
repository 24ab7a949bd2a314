"""Does a small learnt map bring everyday presses' tactile embeddings to their material?

A feasibility check for docs/geometry.md ("Everyday presses land away from their material").
On renders of the presses people make (`ratouch.world.presses`), the shipped tactile encoder's
embedding holds the material (a linear probe: 2.3-3 times chance, `ratouch eval presses
--probe`), but the tactile query's top-5 captions are of the right material far less often
than for the world's own disc presses. This fits a residual map on tactile embeddings
(`ratouch.train.press_map`, what `ratouch train press-map` ships) with a softmax over the
corpus materials' mean caption embeddings, on everyday presses (fit stream) and the world's
training-split disc presses, with a term that keeps world presses where they are; then reads
material precision@5 of the tactile query against the default corpus's captions on fresh
renders (a stream the fit never draws from; the world's validation renders), with and without
the background, per family. Arms: the shipped embedding (identity), the map, the map fitted on
shuffled materials (control), the map fitted on everyday presses only (no world term).
95 % CIs of the map's gain over the identity: bootstrap over queries.

    python scripts/why_press_adapter.py [--fit N] [--world N] [--eval N] [--world-eval N]
                                        [--steps S] [--seed S]
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from ratouch.eval.judge.stats import mean_ci
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.press_map import (
    KEEP,
    TAU,
    everyday_presses,
    fit_map,
    material_index,
    precision_at5,
    world_presses,
)
from ratouch.train.trust import VALIDATION_START
from ratouch.world.sensors import family_names


def _ci(hits_a: np.ndarray, hits_b: np.ndarray, seed: int) -> list[float]:
    """95 % bootstrap CI of the paired difference (the project's `mean_ci`)."""
    _, lo, hi = mean_ci(hits_a - hits_b, seed=seed)
    return [round(lo, 4), round(hi, 4)]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_press_adapter")
    ap.add_argument("--fit", type=int, default=40, help="fit presses per family and kind")
    ap.add_argument("--world", type=int, default=600, help="world renders the map is fitted on")
    ap.add_argument("--eval", type=int, default=12, help="fresh presses per family and kind")
    ap.add_argument("--world-eval", type=int, default=300, help="world validation renders")
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)

    p = RATouchPipeline.load("default-s", generators=False)
    enc = p.encoders
    mats, names, protos = material_index(p)
    index = {m: i for i, m in enumerate(names)}

    fit_e = everyday_presses(enc, index, args.seed, args.fit)
    fit_w = world_presses(enc, index, 0, args.world)
    ev_e = everyday_presses(enc, index, args.seed + 1, args.eval)
    ev_w = world_presses(enc, index, VALIDATION_START, args.world_eval)

    def hits(T, y):
        return precision_at5(p, mats, names, T, y)

    shuffled_y = np.random.default_rng(args.seed).permutation(fit_e[1])
    shuffled_w = np.random.default_rng(args.seed + 1).permutation(fit_w[1])
    arms = {
        "identity": lambda T: T,
        "map": fit_map(fit_e[0], fit_e[1], fit_w[0], fit_w[1], protos, args.steps,
                       args.seed).apply,
        "shuffled": fit_map(fit_e[0], shuffled_y, fit_w[0], shuffled_w, protos, args.steps,
                            args.seed).apply,
        "everyday_only": fit_map(fit_e[0], fit_e[1], fit_w[0][:0], fit_w[1][:0], protos,
                                 args.steps, args.seed, keep=0.0).apply,
    }
    out: dict = {"config": {**vars(args), "tau": TAU, "keep": KEEP,
                            "materials": len(names)}}
    per_arm = {}
    for arm, f in arms.items():
        he, hw = hits(f(ev_e[0]), ev_e[1]), hits(f(ev_w[0]), ev_w[1])
        per_arm[arm] = (he, hw)
        row = {}
        for fam in family_names():
            e, w = ev_e[2] == fam, ev_w[2] == fam
            row[fam] = {"everyday_bg": round(float(he[e & ev_e[3]].mean()), 4),
                        "everyday_alone": round(float(he[e & ~ev_e[3]].mean()), 4),
                        "world": round(float(hw[w].mean()), 4)}
        row["all"] = {"everyday": round(float(he.mean()), 4), "world": round(float(hw.mean()), 4)}
        out[arm] = row
        print(arm, json.dumps(row["all"]), flush=True)
    (ie, iw), (me, mw) = per_arm["identity"], per_arm["map"]
    out["map_gain"] = {"everyday": round(float((me - ie).mean()), 4),
                       "everyday_ci95": _ci(me, ie, args.seed),
                       "world": round(float((mw - iw).mean()), 4),
                       "world_ci95": _ci(mw, iw, args.seed + 1)}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

"""Does a small learnt map bring everyday presses' tactile embeddings to their material?

A feasibility check for docs/geometry.md ("Everyday presses land away from their material").
On renders of the presses people make (`ratouch.world.presses`), the shipped tactile encoder's
embedding holds the material (a linear probe: 2.3-3 times chance, `ratouch eval presses
--probe`), but the tactile query's top-5 captions are of the right material far less often
than for the world's own disc presses. This fits a residual map on tactile embeddings (384 ->
256 -> 384, its output layer starting at zero: the identity) with a softmax over the corpus
materials' mean caption embeddings, on everyday presses (fit stream) and the world's
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
import torch
import torch.nn.functional as F

from ratouch.eval.retrieval import entry_materials
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.trust import VALIDATION_START, render_samples
from ratouch.world.config import WorldConfig
from ratouch.world.presses import PRESS_KINDS, render_press
from ratouch.world.sampler import World
from ratouch.world.sensors import family_names

#: Temperature of the softmax over material prototypes, and the weight of the term that keeps
#: world presses where the shipped encoder puts them (fixed before the first run).
TAU = 0.05
KEEP = 10.0


def everyday(enc, index: dict, seed: int, n: int):
    """`n` presses a kind a family, each encoded with and without its background: (T, material
    index (-1: not in the corpus), family, with-background flag)."""
    rng = np.random.default_rng([seed, 61])
    T, y, fam, bg = [], [], [], []
    for f in family_names():
        ps = [render_press(f, rng, k) for k in PRESS_KINDS for _ in range(n)]
        for with_bg in (True, False):
            T.append(enc.encode_tactile([p.frame for p in ps],
                                        [p.background for p in ps] if with_bg else None,
                                        sensors=[f] * len(ps)))
            y += [index.get(p.material, -1) for p in ps]
            fam += [f] * len(ps)
            bg += [with_bg] * len(ps)
    return np.concatenate(T), np.array(y), np.array(fam), np.array(bg)


def world_presses(enc, index: dict, start: int, n: int):
    """The world's renders `start`.. of the train split, with and without the background."""
    d = render_samples(World(WorldConfig(seed=0)).warm(), "train", range(start, start + n))
    T = np.concatenate([enc.encode_tactile(d["frames"], d["backgrounds"]),
                        enc.encode_tactile(d["frames"], None)])
    y = np.array([index.get(m, -1) for m in d["materials"]] * 2)
    return T, y, np.array(list(d["families"]) * 2), np.array([True] * n + [False] * n)


def fit_map(Te, ye, Tw, yw, protos, steps: int, seed: int, keep: float = KEEP):
    """The residual map (a function of (N, D) float32 arrays)."""
    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    Xe, Ye, Xw, Yw = (torch.from_numpy(np.ascontiguousarray(a)) for a in (Te, ye, Tw, yw))
    d = Xe.shape[1]
    l1, l2 = torch.nn.Linear(d, 256), torch.nn.Linear(256, d)
    torch.nn.init.zeros_(l2.weight)
    torch.nn.init.zeros_(l2.bias)
    opt = torch.optim.AdamW([*l1.parameters(), *l2.parameters()], 1e-3, weight_decay=1e-3)
    P = torch.from_numpy(protos)

    def f(x):
        return F.normalize(x + l2(F.gelu(l1(x))), dim=1)

    def named(z, y):  # the softmax over materials, on the presses whose material is known
        known = y >= 0
        return F.cross_entropy(z[known] @ P.T / TAU, y[known]) if known.any() else z.sum() * 0

    for _ in range(steps):
        i = torch.randint(0, len(Xe), (min(256, len(Xe)),), generator=g)
        loss = named(f(Xe[i]), Ye[i])
        if keep and len(Xw):
            j = torch.randint(0, len(Xw), (min(256, len(Xw)),), generator=g)
            zw = f(Xw[j])
            loss = loss + keep * (1 - (zw * Xw[j]).sum(1)).mean() + named(zw, Yw[j])
        opt.zero_grad()
        loss.backward()
        opt.step()

    def apply(T: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return f(torch.from_numpy(np.ascontiguousarray(T, np.float32))).numpy()
    return apply


def _ci(hits_a: np.ndarray, hits_b: np.ndarray, seed: int, draws: int = 2000) -> list[float]:
    rng = np.random.default_rng(seed)
    d = hits_a - hits_b
    means = [d[rng.integers(0, len(d), len(d))].mean() for _ in range(draws)]
    return [round(float(np.percentile(means, 2.5)), 4), round(float(np.percentile(means, 97.5)),
                                                               4)]


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
    enc, mats = p.encoders, entry_materials(p.corpus)
    names = sorted({str(m) for m in mats if m is not None})
    index = {m: i for i, m in enumerate(names)}
    C = np.asarray(p.corpus_embeddings("tactile_caption"), np.float32)
    protos = np.stack([C[mats == m].mean(0) for m in names])
    protos /= np.linalg.norm(protos, axis=1, keepdims=True)

    fit_e = everyday(enc, index, args.seed, args.fit)
    fit_w = world_presses(enc, index, 0, args.world)
    ev_e = everyday(enc, index, args.seed + 1, args.eval)
    ev_w = world_presses(enc, index, VALIDATION_START, args.world_eval)

    def hits(T, y):
        _, ids = p.corpus.search("text", np.ascontiguousarray(T, np.float32), 5)
        truth = np.array([names[i] if i >= 0 else "" for i in y])
        return (mats[ids] == truth[:, None]).mean(1)

    shuffled_y = np.random.default_rng(args.seed).permutation(fit_e[1])
    shuffled_w = np.random.default_rng(args.seed + 1).permutation(fit_w[1])
    arms = {
        "identity": lambda T: T,
        "map": fit_map(fit_e[0], fit_e[1], fit_w[0], fit_w[1], protos, args.steps, args.seed),
        "shuffled": fit_map(fit_e[0], shuffled_y, fit_w[0], shuffled_w, protos, args.steps,
                            args.seed),
        "everyday_only": fit_map(fit_e[0], fit_e[1], fit_w[0][:0], fit_w[1][:0], protos,
                                 args.steps, args.seed, keep=0.0),
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

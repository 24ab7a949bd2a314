"""Does a tactile encoder that reads the press's height map beside the normalised difference
read materials better than one that reads the difference alone?

The controlled training behind docs/geometry.md ("A tactile encoder that reads the height
map"): two tactile towers of the shipped default-s shape (`ConvEncoder`), from scratch, with
the same seeds, data, steps and loss, that differ only in their input:

* ``difference``: the shipped input (`tactile_input`: the normalised difference and its
  contrast level, four channels);
* ``geometry``: those four channels and three more: the press's height map against its
  background (`read_height`, the family's lookup) over its own depth, turned to the world's
  portrait orientation at the tower's input size; its log depth over the family's median on
  the fit renders (constant); and a flag, 1 where a background gave a height map (else the two
  geometry channels are 0).

Loss: a softmax over the corpus materials' prototypes in the shipped text space (each
material's mean caption embedding, temperature `TAU`, as the press map's), so both towers are
searched against the shipped corpus's captions. Fit data: the world's training renders 0..N
and everyday presses of a fit stream, each drawn with or without its background (p = 0.5).
Read on streams no fit draws from: fresh everyday presses, the world's validation renders,
each with and without the background, and Taxim's 72 real ball presses against their
backgrounds. Measures: material precision@5 of the tactile query (everyday and world, per
family), the paired gain's 95 % bootstrap CI over presses (seeds pooled), soft against hard
(a 5-fold logistic probe of the embeddings, per family), the real ball presses read hard (the
top-1 caption's firmness) and the distinct top-1 captions per family.

    python scripts/why_geometry_encoder.py [--world N] [--fit N] [--eval N] [--world-eval N]
                                           [--steps S] [--seeds 0,1] [--json F]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

from ratouch.encoders.default import TACTILE_CHANNELS, ConvEncoder, tactile_input
from ratouch.eval.frames import firmness, taxim_frames
from ratouch.eval.judge.stats import mean_ci
from ratouch.eval.presses import balanced_accuracy
from ratouch.images import resize_array
from ratouch.model.geometry import read_height
from ratouch.processes import worker_pool
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.press_map import TAU, _mean, material_index, precision_at5
from ratouch.train.trust import VALIDATION_START
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for
from ratouch.world.presses import render_press, render_presses
from ratouch.world.sensors import family_names, guess_family, sensor_family
from ratouch.world.taxim_optics import CALIBRATIONS

#: Channels the geometry arm adds: the height map over its depth, the log depth level, the flag.
GEOMETRY_CHANNELS = 3
ARMS = ("difference", "geometry")
_LOOKUPS: dict = {}  # family -> GradientLookup, set before the worker pool forks


def _item(frame: np.ndarray, background: np.ndarray | None, fam: str, size) -> tuple:
    """One frame's inputs: (plain (4, H, W), with background (4, H, W), the height map over
    its depth (H, W) in portrait, its log depth); the last two None without a background or
    lookup."""
    plain = tactile_input(frame, size, None, fam)
    if background is None:
        return plain, None, None, None
    with_bg = tactile_input(frame, size, background, fam)
    lookup = _LOOKUPS.get(fam)
    if lookup is None:
        return plain, with_bg, None, None
    hm = read_height(lookup, frame, background)
    z = hm.height if hm.height.shape[0] >= hm.height.shape[1] else hm.height.T
    shape = np.clip(z / max(hm.depth, 1e-6), -1.0, 2.0).astype(np.float32)
    h, w = size
    return plain, with_bg, resize_array(np.ascontiguousarray(shape), (w, h)), float(
        np.log(max(hm.depth, 1e-6)))


def _world_chunk(args) -> list:
    start, stop, size = args
    world = world_for(WorldConfig(seed=0))
    out = []
    for i in range(start, stop):
        s = world.sample("train", i)
        fam = sensor_family(s.sensor)
        out.append((*_item(s.tactile, world.background_image(s.sensor), fam, size), fam,
                    s.material))
    return out


def _press_chunk(args) -> list:
    fam, seed, n, size = args
    rng = np.random.default_rng([seed, 71, family_names().index(fam)])
    return [(*_item(p.frame, p.background, fam, size), fam, p.material, p.soft)
            for p in render_presses(fam, rng, n)]


def _stack(rows: list, index: dict) -> dict:
    """Rows of `_item` (+ family, material[, soft]) -> arrays; the material's index among the
    corpus materials (-1: not in the corpus)."""
    h, w = rows[0][0].shape[1:]
    zero = np.zeros((h, w), np.float32)
    return {"plain": np.stack([r[0] for r in rows]),
            "with_bg": np.stack([r[1] if r[1] is not None else r[0] for r in rows]),
            "has_bg": np.array([r[1] is not None for r in rows]),
            "shape": np.stack([r[2] if r[2] is not None else zero for r in rows])[:, None],
            "has_height": np.array([r[2] is not None for r in rows]),
            "log_depth": np.array([r[3] if r[3] is not None else 0.0 for r in rows], np.float32),
            "family": np.array([r[4] for r in rows]),
            "material": np.array([r[5] for r in rows]),
            "y": np.array([index.get(r[5], -1) for r in rows], np.int64),
            "soft": np.array([bool(r[6]) if len(r) > 6 else False for r in rows])}


def _inputs(d: dict, idx: np.ndarray, use_bg: np.ndarray, arm: str, depth_ref: dict
            ) -> torch.Tensor:
    """The arm's input tensor of rows `idx`, each with its background where `use_bg`."""
    x = np.where(use_bg[:, None, None, None], d["with_bg"][idx], d["plain"][idx])
    if arm == "difference":
        return torch.from_numpy(np.ascontiguousarray(x, np.float32))
    geo = use_bg & d["has_height"][idx]
    ref = np.array([depth_ref.get(f, 0.0) for f in d["family"][idx]], np.float32)
    level = np.clip(d["log_depth"][idx] - ref, -3, 3) * geo
    n, _, h, w = x.shape
    extra = np.concatenate([d["shape"][idx] * geo[:, None, None, None],
                            np.broadcast_to(level[:, None, None, None], (n, 1, h, w)),
                            np.broadcast_to(geo[:, None, None, None], (n, 1, h, w))], 1)
    return torch.from_numpy(np.ascontiguousarray(np.concatenate([x, extra], 1), np.float32))


def train_tower(arm: str, fit: dict, protos: np.ndarray, depth_ref: dict, steps: int,
                batch: int, seed: int, width: int, dim: int) -> ConvEncoder:
    """One tower, from scratch: the softmax over material prototypes, flips as the shipped
    training's, half of each batch with the background."""
    torch.manual_seed(seed)
    gen = np.random.default_rng([seed, 5])
    tower = ConvEncoder(width, dim, in_ch=TACTILE_CHANNELS + (
        GEOMETRY_CHANNELS if arm == "geometry" else 0))
    opt = torch.optim.AdamW(tower.parameters(), lr=2e-3, weight_decay=0.02)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=2e-3, total_steps=steps,
                                                pct_start=0.1)
    known = np.flatnonzero(fit["y"] >= 0)
    P = torch.from_numpy(protos)
    tower.train()
    for _ in range(steps):
        idx = gen.choice(known, min(batch, len(known)), replace=False)
        use_bg = (gen.random(len(idx)) < 0.5) & fit["has_bg"][idx]
        x = _inputs(fit, idx, use_bg, arm, depth_ref)
        if gen.random() < 0.5:
            x = x.flip(3)
        if gen.random() < 0.5:
            x = x.flip(2)
        z = F.normalize(tower(x), dim=1)
        loss = F.cross_entropy(z @ P.T / TAU, torch.from_numpy(fit["y"][idx]))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
    return tower.eval()


@torch.no_grad()
def embed(tower: ConvEncoder, d: dict, arm: str, with_bg: bool, depth_ref: dict
          ) -> np.ndarray:
    out = []
    for k in range(0, len(d["y"]), 256):
        idx = np.arange(k, min(k + 256, len(d["y"])))
        use = np.full(len(idx), with_bg) & d["has_bg"][idx]
        out.append(F.normalize(tower(_inputs(d, idx, use, arm, depth_ref)), dim=1).numpy())
    return np.concatenate(out).astype(np.float32)


def _probe(X: np.ndarray, soft: np.ndarray, seed: int) -> float | None:
    """5-fold balanced accuracy of a standardised logistic probe of soft against hard."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import StratifiedKFold, cross_val_predict
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    folds = min(5, int(soft.sum()), int((~soft).sum()))
    if folds < 2:
        return None
    probe = make_pipeline(StandardScaler(), LogisticRegression(max_iter=3000,
                                                               class_weight="balanced"))
    said = cross_val_predict(probe, X, soft,
                             cv=StratifiedKFold(folds, shuffle=True, random_state=seed))
    return balanced_accuracy(list(said), list(soft))["balanced"]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_geometry_encoder")
    ap.add_argument("--world", type=int, default=2400, help="world training renders fitted on")
    ap.add_argument("--fit", type=int, default=40, help="fit presses per family and kind")
    ap.add_argument("--eval", type=int, default=12, help="fresh presses per family and kind")
    ap.add_argument("--world-eval", type=int, default=300, help="world validation renders")
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default=None, help="also write the report here")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    t0 = time.perf_counter()

    p = RATouchPipeline.load("default-s", generators=False)
    mats, names, protos = material_index(p)
    index = {m: i for i, m in enumerate(names)}
    size = tuple(p.encoders.cfg.tactile_size)
    width, dim = p.encoders.cfg.width, p.encoders.cfg.dim
    if p.trust is None or p.trust.geometry is None:
        raise SystemExit("why_geometry_encoder: no geometry calibration (ratouch train geometry)")
    _LOOKUPS.clear()
    _LOOKUPS.update({f: p.trust.geometry.lookup(f) for f in family_names()})

    # textures and each family's optics built once here, inherited by the forked workers
    world_for(WorldConfig(seed=0)).warm()
    for f in family_names():
        render_press(f, np.random.default_rng(0))
    step = max(1, args.world // (4 * args.workers))
    with worker_pool(args.workers) as pool:  # forked: the lookups are inherited
        def world(start: int, n: int) -> dict:
            jobs = [(k, min(k + step, start + n), size) for k in range(start, start + n, step)]
            return _stack([r for part in pool.map(_world_chunk, jobs) for r in part], index)

        def presses(seed: int, n: int) -> dict:
            jobs = [(f, seed, n, size) for f in family_names()]
            return _stack([r for part in pool.map(_press_chunk, jobs) for r in part], index)

        fit_w, fit_e = world(0, args.world), presses(1000, args.fit)
        ev_w, ev_e = world(VALIDATION_START, args.world_eval), presses(2000, args.eval)
    fit = {k: np.concatenate([fit_w[k], fit_e[k]]) for k in fit_w}
    # the depth level's reference: the family's median log depth on the fit renders
    depth_ref = {f: float(np.median(fit["log_depth"][(fit["family"] == f) & fit["has_height"]]))
                 for f in family_names() if ((fit["family"] == f) & fit["has_height"]).any()}
    real = [f for cal in CALIBRATIONS for f in taxim_frames(cal)
            if f.background is not None and f.centre is not None]
    real_rows = []
    for f in real:
        fam = guess_family(f.frame)[0]
        real_rows.append((*_item(f.frame, f.background, fam, size), fam, "", False))
    ev_r = _stack(real_rows, index)
    t_data = time.perf_counter() - t0
    print(f"data: {len(fit['y'])} fit items, {len(ev_e['y'])} fresh presses, "
          f"{len(ev_w['y'])} world validation renders, {len(ev_r['y'])} real presses "
          f"({t_data:.0f} s)", flush=True)

    def hits(T: np.ndarray, d: dict) -> np.ndarray:
        return precision_at5(p, mats, names, T, d["y"])

    captions = np.array([e.caption for e in p.corpus.entries])
    report: dict = {"config": {**vars(args), "seeds": seeds, "tau": TAU,
                               "materials": len(names), "input_size": list(size),
                               "depth_ref": {k: round(v, 4) for k, v in depth_ref.items()}},
                    "arms": {}}
    pooled: dict = {arm: {} for arm in ARMS}
    for arm in ARMS:
        for seed in seeds:
            t1 = time.perf_counter()
            tower = train_tower(arm, fit, protos, depth_ref, args.steps, args.batch, seed,
                                width, dim)
            row: dict = {"train_seconds": round(time.perf_counter() - t1, 1)}
            for name, d in (("everyday", ev_e), ("world", ev_w)):
                for with_bg in (True, False):
                    T = embed(tower, d, arm, with_bg, depth_ref)
                    h = hits(T, d)
                    key = f"{name}_{'bg' if with_bg else 'alone'}"
                    pooled[arm].setdefault(key, []).append(h)
                    row[key] = {f: _mean(h[d["family"] == f]) for f in family_names()}
                    row[key]["all"] = _mean(h)
                    if name == "everyday" and with_bg:
                        _, top = p.corpus.search("text", T, 1)
                        first = captions[top[:, 0]]
                        row["distinct_top1_bg"] = {
                            f: int(len(set(first[d["family"] == f]))) for f in family_names()}
                        row["soft_probe_bg"] = {f: _probe(T[d["family"] == f],
                                                          d["soft"][d["family"] == f], seed)
                                                for f in family_names()}
            Tr = embed(tower, ev_r, arm, True, depth_ref)
            _, top = p.corpus.search("text", Tr, 1)
            reads = [firmness(c) for c in captions[top[:, 0]]]
            row["real_read_hard"] = int(sum(r == "hard" for r in reads))
            row["real_presses"] = len(reads)
            report["arms"][f"{arm}_seed{seed}"] = row
            print(f"{arm} seed {seed}: everyday bg {row['everyday_bg']['all']}, world bg "
                  f"{row['world_bg']['all']}, real hard {row['real_read_hard']}/{len(reads)} "
                  f"({row['train_seconds']} s)", flush=True)
    gain: dict = {}
    for key in pooled["geometry"]:
        g = np.mean(pooled["geometry"][key], 0)
        c = np.mean(pooled["difference"][key], 0)
        d = ev_e if key.startswith("everyday") else ev_w
        mean, lo, hi = mean_ci(g - c, seed=0)
        gain[key] = {"all": round(mean, 4), "ci95": [round(lo, 4), round(hi, 4)],
                     **{f: _mean((g - c)[d["family"] == f]) for f in family_names()}}
    report["geometry_minus_difference"] = gain
    geo = [report["arms"][f"geometry_seed{s}"] for s in seeds]
    report["criteria"] = {
        "everyday_gain_at_least_0.03_ci_above_0": bool(
            gain["everyday_bg"]["all"] >= 0.03 and gain["everyday_bg"]["ci95"][0] > 0),
        "world_no_family_down_more_than_0.02": bool(all(
            (gain["world_bg"][f] or 0.0) >= -0.02 for f in family_names())),
        "no_collapse": bool(all(r["real_read_hard"] >= 70 * r["real_presses"] / 72
                                and min(r["distinct_top1_bg"].values()) >= 5 for r in geo)),
    }
    report["criteria"]["height_map_helps"] = all(report["criteria"].values())
    report["seconds"] = round(time.perf_counter() - t0, 1)
    text = json.dumps(report, indent=1)
    if args.json:
        with open(args.json, "w") as fh:
            fh.write(text + "\n")
    print(text)


if __name__ == "__main__":
    main()

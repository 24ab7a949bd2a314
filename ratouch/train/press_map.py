"""Fitting the press map (`ratouch train press-map`; `ratouch.model.press_map`).

Per encoder set, on its retrieval side (encoders, the default corpus and its caption
embeddings): everyday presses (`ratouch.world.presses.render_press`, every kind, every
family, each encoded with and without its drifted background) from a fit stream, and the
world's training-split presses (with and without their backgrounds; with
`PressMapConfig.balls` > 0 also renders of a rigid ball, `render_ball`, named
`polished_metal`: tried, not shipped, docs/geometry.md). The map is fitted with a softmax
(temperature :data:`TAU`) of each press against the corpus materials' mean caption embeddings,
plus, on the world's presses (and balls), a term (weight :data:`KEEP`) that keeps them where
the encoder puts them; both fixed before the first run (scripts/why_press_adapter.py, which
also runs the shuffled-material and everyday-only controls). The report reads material
precision@5 of the tactile query against the corpus's captions before and after, on a fresh
stream of everyday presses and on the world's validation renders, per family, and the share
of fresh rigid balls whose top-1 caption is of a rigid material.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ratouch.model.press_map import PressMap, RegimeRouter
from ratouch.train.trust import VALIDATION_START, render_samples
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.presses import BALL_MATERIAL, SOFT_AT, render_ball, render_presses
from ratouch.world.sampler import World
from ratouch.world.sensors import family_names

log = logging.getLogger(__name__)

#: Temperature of the softmax over material prototypes.
TAU = 0.05
#: Weight of the term that keeps the world's presses where the encoder puts them.
KEEP = 10.0
#: Hidden width of the map.
HIDDEN = 256


@dataclass(frozen=True)
class PressMapConfig:
    """fit_per_kind: everyday presses per family and kind fitted on; world: the world's
    training renders fitted on; balls: rigid-ball renders per family fitted on (with the
    world's presses); eval_per_kind / world_eval / balls_eval: the fresh presses, validation
    renders and balls the report reads; steps: AdamW steps (batches of 256); router_balls:
    rigid-ball renders per family the regime router is fitted on (beside the map's own
    everyday and world presses, each read alone)."""

    fit_per_kind: int = 40
    world: int = 600
    balls: int = 0
    eval_per_kind: int = 12
    world_eval: int = 300
    balls_eval: int = 20
    steps: int = 600
    seed: int = 0
    router_balls: int = 40


def material_index(side) -> tuple[np.ndarray, list[str], np.ndarray]:
    """The corpus's entry materials (by id), the sorted material names, and their prototypes:
    each material's mean caption embedding, unit length, (M, D) float32."""
    mats = np.array([e.material for e in side.corpus.entries])
    names = sorted({str(m) for m in mats if m is not None})
    C = np.asarray(side.corpus_embeddings("tactile_caption"), np.float32)
    protos = np.stack([C[mats == m].mean(0) for m in names])
    return mats, names, (protos / np.linalg.norm(protos, axis=1, keepdims=True)).astype(
        np.float32)


def everyday_presses(enc, index: dict, seed: int, n: int):
    """`n` everyday presses a kind a family, each encoded with and without its background:
    (T (2N, D), material index (-1: not in the corpus), family, with-background flag)."""
    rng = np.random.default_rng([seed, 61])
    return _encoded(enc, index, {f: render_presses(f, rng, n) for f in family_names()})


def ball_presses(enc, index: dict, seed: int, n: int):
    """`n` rigid-ball presses a family (`render_ball`, a stream of their own), as
    `everyday_presses`."""
    rng = np.random.default_rng([seed, 67])
    return _encoded(enc, index, {f: [render_ball(f, rng) for _ in range(n)]
                                 for f in family_names()})


def _encoded(enc, index: dict, presses: dict):
    """Each family's presses encoded with and without their backgrounds: (T, material index,
    family, with-background flag)."""
    T, y, fam, bg = [], [], [], []
    for f, ps in presses.items():
        for with_bg in (True, False):
            T.append(enc.encode_tactile([p.frame for p in ps],
                                        [p.background for p in ps] if with_bg else None,
                                        sensors=[f] * len(ps)))
            y += [index.get(p.material, -1) for p in ps]
            fam += [f] * len(ps)
            bg += [with_bg] * len(ps)
    return np.concatenate(T), np.array(y, np.int64), np.array(fam), np.array(bg, bool)


def world_presses(enc, index: dict, start: int, n: int):
    """The world's train-split renders `start`.., with and without their backgrounds (as
    `everyday_presses`)."""
    d = render_samples(World(WorldConfig(seed=0)).warm(), "train", range(start, start + n))
    T = np.concatenate([enc.encode_tactile(d["frames"], d["backgrounds"]),
                        enc.encode_tactile(d["frames"], None)])
    y = np.array([index.get(m, -1) for m in d["materials"]] * 2)
    return T, y, np.array(list(d["families"]) * 2), np.array([True] * n + [False] * n)


def fit_map(Te: np.ndarray, ye: np.ndarray, Tw: np.ndarray, yw: np.ndarray,
            protos: np.ndarray, steps: int, seed: int, keep: float = KEEP,
            meta: dict | None = None) -> PressMap:
    """The map fitted on everyday presses (Te, ye) and world presses (Tw, yw; the keep term
    with weight `keep`, none when 0 or no world presses); labels -1 are left out of the
    softmax."""
    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    Xe, Ye, Xw, Yw = (torch.from_numpy(np.ascontiguousarray(a)) for a in (Te, ye, Tw, yw))
    d = Xe.shape[1]
    l1, l2 = torch.nn.Linear(d, HIDDEN), torch.nn.Linear(HIDDEN, d)
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
    w1, b1, w2, b2 = (t.detach().numpy().astype(np.float32) for t in
                      (l1.weight.T, l1.bias, l2.weight.T, l2.bias))
    return PressMap(w1, b1, w2, b2, meta=dict(meta or {}))


def precision_at5(side, mats: np.ndarray, names: list[str], T: np.ndarray,
                  y: np.ndarray) -> np.ndarray:
    """Per query, the share of the tactile query's top-5 captions made of its material."""
    _, ids = side.corpus.search("text", np.ascontiguousarray(T, np.float32), 5)
    truth = np.array([names[i] if i >= 0 else "" for i in y])
    return (mats[ids] == truth[:, None]).mean(1)


def _mean(x: np.ndarray) -> float | None:
    """The mean, 4 decimals; None for no value (a family without renders in a small run)."""
    return round(float(np.mean(x)), 4) if len(x) else None


def fit_press_map(side, cfg: PressMapConfig = PressMapConfig()) -> tuple[PressMap, dict]:
    """The encoder set's press map on `side` (its encoders and the corpus), and the report:
    per family P@5 of the tactile query before and after, on fresh everyday presses (with and
    without the background) and on the world's validation renders, and the share of fresh
    rigid balls whose top-1 caption is of a rigid material."""
    enc = side.encoders
    mats, names, protos = material_index(side)
    index = {m: i for i, m in enumerate(names)}
    Te, ye, _, te_bg = everyday_presses(enc, index, cfg.seed, cfg.fit_per_kind)
    Tw, yw, _, tw_bg = world_presses(enc, index, 0, cfg.world)
    fit_alone = (Te[~te_bg], Tw[~tw_bg])  # what the router is fitted on, beside its balls
    n_world, n_balls = len(Tw), 0
    if cfg.balls:
        Tb, yb, _, _ = ball_presses(enc, index, cfg.seed, cfg.balls)
        Tw, yw, n_balls = np.concatenate([Tw, Tb]), np.concatenate([yw, yb]), len(Tb)
    pm = fit_map(Te, ye, Tw, yw, protos, cfg.steps, cfg.seed)
    Ee, ey, ef, eb = everyday_presses(enc, index, cfg.seed + 1, cfg.eval_per_kind)
    Ew, wy, wf, wb = world_presses(enc, index, VALIDATION_START, cfg.world_eval)
    Eb, _, bf, bb = ball_presses(enc, index, cfg.seed + 1, cfg.balls_eval)
    router, routed = _router_fit_and_report(enc, index, cfg, fit_alone,
                                            (Ee[~eb], Ew[~wb], Eb[~bb]))
    rigid = np.array([bool(m) and material(str(m)).feel.compliance < SOFT_AT for m in mats])
    report: dict = {}
    for name, f in (("before", lambda T: T), ("after", pm.apply)):
        he, hw = (precision_at5(side, mats, names, f(Ee), ey),
                  precision_at5(side, mats, names, f(Ew), wy))
        _, top = side.corpus.search("text", np.ascontiguousarray(f(Eb), np.float32), 1)
        hb = rigid[top[:, 0]]
        report[name] = {fam: {"everyday_bg": _mean(he[(ef == fam) & eb]),
                              "everyday_alone": _mean(he[(ef == fam) & ~eb]),
                              "world": _mean(hw[wf == fam]),
                              "balls_rigid_top1": _mean(hb[bf == fam])}
                        for fam in family_names()}
        report[name]["all"] = {"everyday": _mean(he), "world": _mean(hw),
                               "balls_rigid_top1": _mean(hb)}
    meta = {"encoder": enc.name, "config": asdict(cfg), "tau": TAU, "keep": KEEP,
            "materials": len(names), "p_at_5": report, "router": routed,
            "fitted_on": f"{len(Te)} everyday-press, {n_world} world-press "
                         f"and {n_balls} rigid-ball ({BALL_MATERIAL}) embeddings (each "
                         "press with and without its background)"}
    log.info("press map %s: everyday P@5 %s -> %s, world %s -> %s", enc.name,
             report["before"]["all"]["everyday"], report["after"]["all"]["everyday"],
             report["before"]["all"]["world"], report["after"]["all"]["world"])
    return PressMap(pm.w1, pm.b1, pm.w2, pm.b2, meta, router), report


def fit_router(everyday: np.ndarray, firm: np.ndarray) -> RegimeRouter:
    """The regime router (`RegimeRouter`): a logistic model (C 0.1, classes balanced, on the
    standardised embeddings) telling the tactile embeddings of everyday presses read alone
    (`everyday`, (N, D)) from those of firm presses read alone (`firm`: the world's presses
    and rigid balls). Fixed before its first run (docs/geometry.md, "The touch-only reading
    of a frame alone, routed too")."""
    from sklearn.linear_model import LogisticRegression

    X = np.concatenate([everyday, firm]).astype(np.float64)
    y = np.r_[np.ones(len(everyday)), np.zeros(len(firm))]
    mean, scale = X.mean(0), X.std(0) + 1e-6
    m = LogisticRegression(C=0.1, class_weight="balanced", max_iter=2000)
    m.fit((X - mean) / scale, y)
    return RegimeRouter(mean, scale, m.coef_[0].astype(np.float64), float(m.intercept_[0]))


def _router_fit_and_report(enc, index: dict, cfg: PressMapConfig,
                           fit_alone: tuple[np.ndarray, np.ndarray],
                           fresh: tuple[np.ndarray, np.ndarray, np.ndarray]
                           ) -> tuple[RegimeRouter, dict]:
    """The router fitted on the map's fit streams read alone (`fit_alone`: its everyday
    presses and its world presses, as `fit_press_map` encodes them) and `cfg.router_balls`
    rigid balls a family, and the share of each fresh group (`fresh`: everyday presses, the
    world's validation renders, balls, each read alone) it sends to the everyday regime."""
    everyday, world = fit_alone
    Tb, _, _, tb_bg = ball_presses(enc, index, cfg.seed, cfg.router_balls)
    router = fit_router(everyday, np.concatenate([world, Tb[~tb_bg]]))
    shares = {name: round(float((router.everyday(T) >= 0.5).mean()), 4)
              for name, T in zip(("everyday", "world", "balls"), fresh)}
    log.info("regime router %s: fresh renders alone read everyday: %s", enc.name, shares)
    return router, {"fitted_on": f"{len(everyday)} everyday presses, {len(world)} world "
                                 f"presses and {int((~tb_bg).sum())} rigid balls, each read "
                                 "alone",
                    "fresh_read_everyday": shares}


def with_router(side, pm: PressMap, cfg: PressMapConfig = PressMapConfig()) -> PressMap:
    """`pm` with its regime router (re)fitted on `side` (`ratouch train press-map
    --router-only`): the map's weights as they are."""
    enc = side.encoders
    _, names, _ = material_index(side)
    index = {m: i for i, m in enumerate(names)}
    Te, _, _, te_bg = everyday_presses(enc, index, cfg.seed, cfg.fit_per_kind)
    Tw, _, _, tw_bg = world_presses(enc, index, 0, cfg.world)
    Ee, _, _, eb = everyday_presses(enc, index, cfg.seed + 1, cfg.eval_per_kind)
    Ew, _, _, wb = world_presses(enc, index, VALIDATION_START, cfg.world_eval)
    Eb, _, _, bb = ball_presses(enc, index, cfg.seed + 1, cfg.balls_eval)
    router, routed = _router_fit_and_report(enc, index, cfg, (Te[~te_bg], Tw[~tw_bg]),
                                            (Ee[~eb], Ew[~wb], Eb[~bb]))
    return PressMap(pm.w1, pm.b1, pm.w2, pm.b2, {**pm.meta, "router": routed}, router)


def press_map_recipe(encoder: str, cfg: PressMapConfig = PressMapConfig(), out=None,
                     router_only: bool = False) -> dict:
    """`ratouch train press-map`: fit an encoder set's press map and its regime router on its
    shipped retrieval side (its encoders and default corpus), save it (default
    `paths.press_map(encoder)`), and return its report; `router_only`: fit only the router
    onto the shipped map (its weights unchanged).

    Raises:
        DataNotFoundError: `router_only` and no shipped map.
    """
    from pathlib import Path

    from ratouch.paths import press_map
    from ratouch.search.retrieval_side import RetrievalSide

    side = RetrievalSide.load(encoder)
    path = Path(out) if out else press_map(encoder)
    if router_only:
        pm = with_router(side, PressMap.load(press_map(encoder)), cfg)
        pm.save(path)
        return {"written": str(path), "router": pm.meta["router"]}
    pm, report = fit_press_map(side, cfg)
    pm.save(path)
    return {"written": str(path), "p_at_5": report, "router": pm.meta["router"]}

"""Fitting the touch gate (`ratouch train gate`; `ratouch.model.gate`).

Data: probe-split renders from index :data:`GATE_START` on (no model trains on the probe split,
and the premise groups stop well below it), materials drawn uniformly, so scarce materials are
among them in their natural share. Each pair is queried four ways: its own touch ("clean"),
another pair's touch ("mismatched"), the sensor's no-contact frame against itself ("blank")
and its frame with heavy noise ("noisy"). For each, the joint query's and the image query's
material hits in the top K of the caption index say which of the two found the true material
more often; the gate learns to predict that from what a query carries (its features,
`ratouch.model.gate.FEATURES`), weighted by how much the two differ. Ties carry no weight.

Half the pairs (by index parity) fit the gate, the other half measure it: material P@K of the
paper's joint query, the image query, the rule control and the learnt gate, per variant.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from ratouch.errors import ConfigError
from ratouch.model.gate import FEATURES, TouchGate, fit_logistic, gate_features, mix
from ratouch.model.trust import TrustCalibration
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for

log = logging.getLogger(__name__)

#: First probe-split index of the gate's renders.
GATE_START = 400_000
VARIANTS = ("clean", "mismatched", "blank", "noisy")
NOISE_SIGMA = 40.0


def _frames(samples, world, variant: str, rng: np.random.Generator):
    frames = [s.tactile for s in samples]
    bgs = [world.background_image(s.sensor) for s in samples]
    if variant == "blank":
        return bgs, bgs
    if variant == "noisy":
        return [np.clip(f + rng.normal(0, NOISE_SIGMA, f.shape), 0, 255).astype(np.uint8)
                for f in frames], bgs
    return frames, bgs


def gate_data(side, trust, n: int = 1200, seed: int = 0, k: int = 5) -> dict[str, Any]:
    """Per variant: V, T, J (the joint query), the features and each query's material hits.

    Args:
        side: the retrieval side (encoders, corpus index, Tactile-Guided Retriever).
        trust: the encoder set's trust calibration (its novelty models).
        n: pairs.
        seed: the variants' randomness (mismatch, noise).
        k: the top K whose material hits are counted.
    """
    if n < 20:
        raise ConfigError(f"--n {n}: the gate needs at least 20 pairs")
    world = world_for(WorldConfig(seed=0))
    samples = [world.sample("probe", GATE_START + i) for i in range(n)]
    mats = np.asarray([s.material for s in samples])
    entry_mats = np.asarray([e.material for e in side.corpus.entries])
    rng = np.random.default_rng([seed, 3_707])
    V = side.encoders.encode_image([s.crop for s in samples])
    hits_image = (entry_mats[side.corpus.search("text", V, k)[1]] == mats[:, None]).mean(1)
    out: dict[str, Any] = {"materials": mats, "V": V, "hits_image": hits_image, "variants": {}}
    clean_T = None
    for variant in VARIANTS:
        if variant == "mismatched":
            assert clean_T is not None
            T = clean_T[(np.arange(n) + 1 + rng.integers(0, n - 1)) % n]
        else:
            frames, bgs = _frames(samples, world, variant, rng)
            T = side.encoders.encode_tactile(frames, bgs)
            if variant == "clean":
                clean_T = T
        J = side.joint_query(V, T)
        hits_joint = (entry_mats[side.corpus.search("text", J, k)[1]] == mats[:, None]).mean(1)
        out["variants"][variant] = {
            "T": T, "J": J, "hits_joint": hits_joint,
            "features": gate_features(V, T, J, trust.tactile, trust.visual)}
    return out


def _precision(side, data, variant: str, w: np.ndarray, sel: np.ndarray, k: int) -> float:
    v = data["variants"][variant]
    Q = mix(data["V"][sel], v["J"][sel], w)
    entry_mats = np.asarray([e.material for e in side.corpus.entries])
    hits = entry_mats[side.corpus.search("text", Q, k)[1]] == data["materials"][sel][:, None]
    return round(float(hits.mean()), 4)


def fit_gate(side, trust, n: int = 1200, seed: int = 0, k: int = 5,
             scarce: tuple[str, ...] = ()) -> TouchGate:
    """The learnt gate, fitted on the even pairs and measured on the odd ones (see the
    module); `scarce`: the materials the shipped weights' regime keeps few pairs of, reported
    apart."""
    t0 = time.perf_counter()
    data = gate_data(side, trust, n, seed, k)
    fit = np.arange(n) % 2 == 0
    X, y, sw = [], [], []
    for v in data["variants"].values():
        d = v["hits_joint"] - data["hits_image"]
        X.append(v["features"][fit])
        y.append((d[fit] > 0).astype(np.float64))
        sw.append(np.abs(d[fit]))
    mean, scale, coef, intercept = fit_logistic(np.concatenate(X), np.concatenate(y),
                                                np.concatenate(sw))
    gate = TouchGate("learnt", mean, scale, coef, intercept, trust.tactile, trust.visual)
    rule = gate.as_rule()
    held = ~fit
    report: dict[str, Any] = {"pairs": n, "held_out": int(held.sum()), "k": k, "seed": seed,
                              "start": GATE_START, "features": list(FEATURES), "by_variant": {}}
    is_scarce = np.isin(data["materials"], list(scarce))
    for variant, v in data["variants"].items():
        row = {}
        for group, sel in (("all", held), ("scarce", held & is_scarce),
                           ("seen", held & ~is_scarce)):
            if not sel.any():
                continue
            V, T, J = data["V"][sel], v["T"][sel], v["J"][sel]
            row[group] = {
                "n": int(sel.sum()),
                "paper": _precision(side, data, variant, np.ones(sel.sum()), sel, k),
                "image": _precision(side, data, variant, np.zeros(sel.sum()), sel, k),
                "rule": _precision(side, data, variant, rule.weights(V, T, J), sel, k),
                "learnt": _precision(side, data, variant, gate.weights(V, T, J), sel, k),
                "mean_weight": round(float(gate.weights(V, T, J).mean()), 3)}
        report["by_variant"][variant] = row
    report["seconds"] = round(time.perf_counter() - t0, 1)
    return TouchGate("learnt", mean, scale, coef, intercept, trust.tactile, trust.visual, report)


def format_gate_report(report: dict) -> str:
    """The held-out material P@K table of a fitted gate's report."""
    lines = [f"touch gate: {report['pairs']} probe pairs from index {report['start']}, "
             f"{report['held_out']} held out, material P@{report['k']} on the held-out half",
             "variant     group   n    paper  image  rule   learnt  mean w"]
    for variant, row in report["by_variant"].items():
        for group, r in row.items():
            lines.append(f"{variant:<11} {group:<7} {r['n']:<4} {r['paper']:.3f}  "
                         f"{r['image']:.3f}  {r['rule']:.3f}  {r['learnt']:.3f}   "
                         f"{r['mean_weight']:.2f}")
    return "\n".join(lines)


def gate_recipe(encoder: str, seed: int = 0, n: int = 1200, out=None) -> dict:
    """`ratouch train gate`: fit an encoder set's gate on its shipped retrieval side and trust
    calibration, save it (default `paths.touch_gate(encoder)`), and return its report."""
    from ratouch.paths import touch_gate, trust_calibration
    from ratouch.search.retrieval_side import RetrievalSide
    from ratouch.world.scarcity import ScarceRegime

    trust = TrustCalibration.load(trust_calibration(encoder))
    gate = fit_gate(RetrievalSide.load(encoder), trust, n=n, seed=seed,
                    scarce=ScarceRegime().scarce_materials())
    path = Path(out) if out else touch_gate(encoder)
    gate.save(path)
    return {"written": str(path), "coef": [round(float(x), 4) for x in gate.coef],
            "intercept": round(gate.intercept, 4), **gate.report}

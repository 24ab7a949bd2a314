"""Per sensor family: how well touch is read on each of the world's tactile sensors
(`ratouch eval families`).

On validation renders (training-split indices far beyond any training run's, the same
distribution but unseen; never the test split), for each family (`ratouch.world.sensors.
SENSOR_FAMILIES`), without and with the sensor's background frame:

* **material probe**: a linear probe's material accuracy on the tactile embeddings (fitted on
  one half of the renders of every family, scored on the other half, and the other way round);
* **joint P@5**: material precision@5 of the joint query against the corpus;
* **hard vs soft**: a 2-fold linear probe's accuracy at telling hard materials (compliance at
  most :data:`HARD`) from soft ones (at least :data:`SOFT`) on the tactile embeddings;
* **contact**: the share of presses not read as "contact" (miss; "uncertain" counts as a miss)
  and of the same renders without contact read as "contact" (false alarm), and the share of
  both left "uncertain", by the shipped trust calibration (`TrustCalibration.contact_state`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sklearn.linear_model import LogisticRegression
from sklearn.preprocessing import StandardScaler

from ratouch.eval.retrieval import entry_materials
from ratouch.train.trust import VALIDATION_START, render_samples
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.sampler import World
from ratouch.world.sensors import family_names

#: First training-split index of these renders (beyond the trust and cascade calibrations').
FAMILIES_START = VALIDATION_START + 300_000
#: Compliance bounds of the hard and soft materials the hard-vs-soft probe tells apart.
HARD, SOFT = 0.15, 0.55


def _probe(T: np.ndarray, materials: np.ndarray, seed: int) -> np.ndarray:
    """Per render, whether a 2-fold linear probe names its material (or its class)."""
    rng = np.random.default_rng(seed)
    fold = rng.permutation(len(T)) % 2
    right = np.zeros(len(T), bool)
    for k in (0, 1):
        fit, score = fold != k, fold == k
        scaler = StandardScaler().fit(T[fit])
        probe = LogisticRegression(max_iter=2000, C=1.0).fit(scaler.transform(T[fit]),
                                                             materials[fit])
        right[score] = probe.predict(scaler.transform(T[score])) == materials[score]
    return right


def evaluate_families(pipeline, n: int = 600, seed: int = 0, k: int = 5) -> dict[str, Any]:
    """The per-family figures of the module docstring for one loaded pipeline."""
    world = World(WorldConfig(seed=seed)).warm()
    empty = World(WorldConfig(seed=seed).with_stress(no_contact=1.0)).warm()
    idx = range(FAMILIES_START, FAMILIES_START + n)
    data, nc = render_samples(world, "train", idx), render_samples(empty, "train", idx)
    enc = pipeline.encoders
    V = pipeline.encode_images(data["crops"])[0]
    materials = np.asarray(data["materials"])
    compliance = np.array([material(m).feel.compliance for m in materials])
    families = np.asarray(data["families"])
    corpus_mats = entry_materials(pipeline.corpus)
    out: dict[str, Any] = {"renders": f"train[{FAMILIES_START}:{FAMILIES_START + n}]",
                           "families": {}}
    rows: dict[str, dict[str, np.ndarray]] = {}
    for kind, bgs in (("plain", None), ("background", data["backgrounds"])):
        T = enc.encode_tactile(data["frames"], bgs)
        _, ids = pipeline.corpus.search("text", pipeline.joint_query(V, T), k)
        firm = np.full(n, np.nan)
        firm[compliance <= HARD], firm[compliance >= SOFT] = 1.0, 0.0
        known = ~np.isnan(firm)
        hard_soft = np.full(n, np.nan)
        hard_soft[known] = _probe(T[known], firm[known], seed)
        rows[kind] = {"probe": _probe(T, materials, seed), "hard_soft": hard_soft,
                      "joint": (corpus_mats[ids] == materials[:, None]).mean(1)}
        if pipeline.trust is not None:
            nc_bgs = nc["backgrounds"] if bgs is not None else [None] * n
            press = [pipeline.trust.contact_state(f, b)[0] for f, b in
                     zip(data["frames"], bgs or [None] * n)]
            blank = [pipeline.trust.contact_state(f, b)[0] for f, b in zip(nc["frames"], nc_bgs)]
            rows[kind]["miss"] = np.array([s != "contact" for s in press])
            rows[kind]["false_alarm"] = np.array([s == "contact" for s in blank])
            rows[kind]["uncertain"] = np.array([s == "uncertain" for s in press + blank])
    for fam in family_names():
        sel = families == fam
        both = np.r_[sel, sel]  # "uncertain" runs over presses, then blanks
        out["families"][fam] = {"n": int(sel.sum()), **{
            kind: {name: round(float(np.nanmean(v[both if len(v) == 2 * n else sel])), 4)
                   for name, v in r.items()}
            for kind, r in rows.items()}}
    out["all"] = {kind: {name: round(float(np.nanmean(v)), 4) for name, v in r.items()}
                  for kind, r in rows.items()}
    return out


def format_families(result: dict[str, Any]) -> str:
    """A markdown table of `evaluate_families`' result."""
    lines = ["| family | n | material probe (plain / bg) | hard vs soft (plain / bg) | "
             "joint P@5 (plain / bg) | contact miss (plain / bg) | contact false alarm "
             "(plain / bg) | uncertain (plain / bg) |",
             "|---|---|---|---|---|---|---|---|"]
    for fam, r in [*result["families"].items(), ("all", {"n": "", **result["all"]})]:
        p, b = r["plain"], r["background"]
        cells = " | ".join(_pair(p, b, key) for key in
                           ("probe", "hard_soft", "joint", "miss", "false_alarm", "uncertain"))
        lines.append(f"| {fam} | {r['n']} | {cells} |")
    return "\n".join(lines)


def _pair(plain: dict[str, float], background: dict[str, float], key: str) -> str:
    """One table cell: the plain and the background-difference value of `key`."""
    return f"{plain[key]:.3f} / {background[key]:.3f}" if key in plain else "–"

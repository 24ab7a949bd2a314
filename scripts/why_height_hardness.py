"""Does a press's height map tell soft from hard? A check of the signal before training a
tactile encoder on it (docs/geometry.md, "Does the height map carry hardness?").

Renders of everyday presses (`ratouch.world.presses`: flat faces, fabrics, foams, small caps,
edges) are read against their drifted backgrounds by the shipped geometry lookups; a logistic
regression on the height map's log depth, spread and log relief-to-depth ratio predicts
whether the pressed material is soft (compliance >= 0.5), scored by 5-fold cross-validation
against always answering the majority class.

    python scripts/why_height_hardness.py [N] [SEED]    # N renders per kind (default 24)
"""

from __future__ import annotations

import json
import sys

import numpy as np
from sklearn.linear_model import LogisticRegression
from sklearn.model_selection import cross_val_score

from ratouch.model.geometry import GeometryCalibration, read_height
from ratouch.paths import geometry_calibration
from ratouch.world.presses import render_press
from ratouch.world.sensors import family_names

KINDS = ("flat_face", "fabric", "foam", "small_curved", "edge")


def measure(n: int = 24, seed: int = 5) -> dict:
    """Per family: renders, soft share, the majority class's accuracy and the cross-validated
    accuracy of the height-map features."""
    cal = GeometryCalibration.load(geometry_calibration())
    rng = np.random.default_rng(seed)
    out = {}
    for fam in family_names():
        lookup = cal.lookup(fam)
        if lookup is None:
            continue
        X, y = [], []
        for kind in KINDS:
            for _ in range(n):
                p = render_press(fam, rng, kind)
                h = read_height(lookup, p.frame, p.background)
                depth = max(h.depth, 1e-6)
                X.append([np.log(depth), h.spread, np.log(max(h.relief, 1e-7) / depth)])
                y.append(p.soft)
        labels = np.array(y)
        folds = int(min(5, labels.sum(), (~labels).sum()))
        acc = (float(cross_val_score(LogisticRegression(max_iter=1000), np.array(X), labels,
                                     cv=folds).mean()) if folds >= 2 else float("nan"))
        out[fam] = {"renders": len(labels), "soft_share": round(float(labels.mean()), 3),
                    "majority_accuracy": round(float(max(labels.mean(), 1 - labels.mean())), 3),
                    "height_map_accuracy": round(acc, 3)}
    return out


def main(argv: list[str]) -> None:
    n = int(argv[0]) if argv else 24
    seed = int(argv[1]) if len(argv) > 1 else 5
    print(json.dumps(measure(n, seed), indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])

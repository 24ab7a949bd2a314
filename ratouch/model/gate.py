"""The touch gate: how far a query's touch can be trusted to steer retrieval.

The paper's joint query J (the Tactile-Guided Retriever's, eqs. 1–3) lets the tactile embedding
steer the search. Where touch is unfamiliar (a sensor the models have not learnt, a frame far
from the training renders), mismatched or empty, that steering pulls the query away from what
vision already found. The gate reads, per query, a weight ``w`` in [0, 1] and the *gated query*
is the unit vector along ``w * J + (1 - w) * V``: ``w = 1`` is the paper's query, ``w = 0`` the
image query (the crop's embedding, searched against the corpus's caption index as the image
mode is).

Two kinds:

* ``"learnt"``: a logistic model on :data:`FEATURES` (the tactile and visual embeddings'
  novelty against the training renders, divided by their thresholds, and the retriever's own
  agreement: the cosines between J, V and T), fitted by `ratouch train gate` on probe renders
  whose touch is clean, mismatched, blank or noisy, to predict whether the joint query finds
  the true material more often than the image query does; ``w`` is that probability.
* ``"rule"``: the control, ``w = 0`` where the trust calibration calls the tactile embedding
  novel, else 1.

The novelty models are the trust calibration's (`ratouch.model.trust.Novelty`); the gate's
file holds only its own coefficients (format ``ratouch-gate-1``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import write_atomic

FORMAT = "ratouch-gate-1"
#: What the learnt gate reads, per query.
FEATURES = ("tactile_novelty", "visual_novelty", "cos_joint_image", "cos_joint_tactile",
            "cos_image_tactile")
KINDS = ("learnt", "rule")


def _unit(X: np.ndarray) -> np.ndarray:
    X = np.asarray(X, np.float64)
    return X / np.maximum(np.linalg.norm(X, axis=1, keepdims=True), 1e-12)


def gate_features(V: np.ndarray, T: np.ndarray, J: np.ndarray, tactile_novelty, visual_novelty
                  ) -> np.ndarray:
    """(N, len(FEATURES)) gate features of (N, D) image, tactile and joint vectors;
    `tactile_novelty`, `visual_novelty`: the trust calibration's `Novelty` models (a score
    divided by its threshold: 1 is the edge of the familiar)."""
    v, t, j = _unit(V), _unit(T), _unit(J)
    tn = tactile_novelty.score(T) / max(tactile_novelty.threshold, 1e-9)
    vn = visual_novelty.score(V) / max(visual_novelty.threshold, 1e-9)
    return np.stack([tn, vn, (j * v).sum(1), (j * t).sum(1), (v * t).sum(1)], 1)


#: Below this touch weight the gated system's reader answers; above it the paper's generator.
#: Chosen on validation renders by a rule fixed before its run (`scripts/why_read_below.py`:
#: the largest threshold of 0.05 ... 0.50 at which `gated` loses at most 0.05 to `paper` with
#: clean touch); it was 0.5, the gate's own decision boundary, at which the reader answered
#: 46 % of clean pairs (docs/premise.md, "The reader only where touch is clearly wrong").
READ_BELOW = 0.25
#: The withholding rule's measured cost per withholding system, in judge points, where a
#: withheld sensor's touch was still readable: the system with the rule against the paper's
#: system on the world's test pairs with every frame recoloured (`python
#: scripts/why_withhold.py [--system fallback]`, the "recoloured" block of
#: docs/premise-result-withhold.json, `gated`: -0.2447 [-0.423, -0.071], and of
#: docs/premise-result-fallback.json, `fallback`: -0.1769 [-0.348, -0.013], both measured
#: again on 2026-12-03 with the retrained reader (they were -0.2195 and -0.1506); `gated`
#: pays for its gate on the frames it does not withhold too). Quoted by "What retrieval did"
#: wherever touch is withheld; a test holds each to its file, so a re-measured cost that moves
#: it cannot go unsaid.
WITHHOLD_COST = {"gated": 0.24, "fallback": 0.18}
#: Where touch is withheld because its contact against the background is uncertain and the
#: frame alone shows none (`ratouch.model.trust.doubts_touch`): the rule's measured effect per
#: withholding system, in judge points, on fresh probe renders whose contact read uncertain
#: (`python scripts/why_withhold_uncertain.py --split probe --start 2500000 --rule
#: second-opinion`, docs/premise-result-withhold-second-opinion.json): on blanks read against
#: another unit's background, and on presses (where it fires on few). Quoted by "What
#: retrieval did"; a test holds each to its file. Measured again on 2026-12-03 on the shipped
#: weights and trust (fallback 1.57 / -0.07 and gated 0.74 / -0.08 on 2026-12-01: the trust
#: changes of 2026-12-02 read more of the rows uncertain, and the reader was retrained).
DOUBT_EFFECT = {"fallback": {"blanks": 1.28, "presses": -0.01},
                "gated": {"blanks": 0.58, "presses": 0.01}}


def mix(V: np.ndarray, J: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, D) float32 unit vectors along ``w * J + (1 - w) * V`` (each side unit first)."""
    w = np.asarray(w, np.float64)[:, None]
    return _unit(w * _unit(J) + (1 - w) * _unit(V)).astype(np.float32)


@dataclass(frozen=True)
class TouchGate:
    """A fitted gate (see the module).

    Attributes:
        kind: "learnt" or "rule".
        mean, scale: the learnt model's feature standardisation ((F,) each).
        coef, intercept: its logistic coefficients on standardised features.
        tactile, visual: the trust calibration's novelty models (set when loaded with it).
        report: how it was fitted and what it measured (free-form, from the trainer).
    """

    kind: str = "rule"
    mean: np.ndarray = field(default_factory=lambda: np.zeros(len(FEATURES)))
    scale: np.ndarray = field(default_factory=lambda: np.ones(len(FEATURES)))
    coef: np.ndarray = field(default_factory=lambda: np.zeros(len(FEATURES)))
    intercept: float = 0.0
    tactile: Any = None
    visual: Any = None
    report: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ConfigError(f"touch gate kind {self.kind!r}: one of {', '.join(KINDS)}")

    def with_novelty(self, tactile, visual) -> TouchGate:
        """This gate reading novelty with the trust calibration's models."""
        return TouchGate(self.kind, self.mean, self.scale, self.coef, self.intercept,
                         tactile, visual, self.report)

    def as_rule(self) -> TouchGate:
        """The rule control with the same novelty models."""
        return TouchGate("rule", tactile=self.tactile, visual=self.visual)

    def weights(self, V: np.ndarray, T: np.ndarray, J: np.ndarray) -> np.ndarray:
        """(N,) how far touch steers each query: 1 the paper's joint query, 0 the image
        query's direction."""
        return self._weights(self._features(V, T, J))

    def _features(self, V: np.ndarray, T: np.ndarray, J: np.ndarray) -> np.ndarray:
        if self.tactile is None or self.visual is None:
            raise ConfigError("the touch gate reads novelty with the trust calibration's "
                              "models: load it with them (`with_novelty`)")
        return gate_features(V, T, J, self.tactile, self.visual)

    def _weights(self, f: np.ndarray) -> np.ndarray:
        """(N,) weights of (N, len(FEATURES)) features."""
        if self.kind == "rule":
            return (f[:, 0] <= 1.0).astype(np.float64)
        z = ((f - self.mean) / self.scale) @ self.coef + self.intercept
        return 1.0 / (1.0 + np.exp(-z))

    def query(self, V: np.ndarray, T: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((N, D) gated queries, (N,) weights)."""
        w = self.weights(V, T, J)
        return mix(V, J, w), w

    def explain(self, V: np.ndarray, T: np.ndarray, J: np.ndarray) -> dict:
        """Why one query's touch was trusted as it was: its weight and features."""
        features = self._features(V, T, J)
        f, w = features[0], float(self._weights(features)[0])
        out = {"kind": self.kind, "touch_weight": round(w, 3),
               "features": {n: round(float(x), 3) for n, x in zip(FEATURES, f)}}
        reasons = []
        if f[0] > 1:
            reasons.append(f"the tactile embedding is unlike the training renders (novelty "
                           f"{f[0]:.2f} of its threshold)")
        if f[1] > 1:
            reasons.append(f"the visual crop is unlike the training renders (novelty "
                           f"{f[1]:.2f} of its threshold)")
        if self.kind == "learnt":
            reasons.append(f"the retriever's agreement: joint·image {f[2]:.2f}, joint·tactile "
                           f"{f[3]:.2f}, image·tactile {f[4]:.2f}")
        out["why"] = reasons
        return out

    # ------------------------------------------------------------------ file

    def to_dict(self) -> dict:
        return {"format": FORMAT, "kind": self.kind, "features": list(FEATURES),
                "mean": [float(x) for x in self.mean], "scale": [float(x) for x in self.scale],
                "coef": [float(x) for x in self.coef], "intercept": float(self.intercept),
                "report": self.report}

    def save(self, path: str | os.PathLike) -> None:
        write_atomic(path, json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> TouchGate:
        """A gate file (without novelty models: `with_novelty`).

        Raises:
            DataNotFoundError: no file. DataError: not a gate file of this format.
        """
        path = Path(path)
        if not path.is_file():
            raise DataNotFoundError(f"no touch gate at {path}: `ratouch train gate`")
        try:
            d = json.loads(path.read_text("utf-8"))
            if d.get("format") != FORMAT or tuple(d["features"]) != FEATURES:
                raise ValueError(f"format {d.get('format')!r}, features {d.get('features')}")
            return cls(d["kind"], np.asarray(d["mean"], np.float64),
                       np.asarray(d["scale"], np.float64), np.asarray(d["coef"], np.float64),
                       float(d["intercept"]), report=d.get("report", {}))
        except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
            raise DataError(f"{path} is not a touch gate ({FORMAT}): {e}; rebuild it with "
                            "`ratouch train gate`") from e


def fit_logistic(X: np.ndarray, y: np.ndarray, sample_weight: np.ndarray | None = None,
                 l2: float = 1e-2, steps: int = 50) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                             float]:
    """A weighted L2-regularised logistic regression by Newton steps: (mean, scale, coef,
    intercept) on standardised features."""
    X = np.asarray(X, np.float64)
    y = np.asarray(y, np.float64)
    sw = np.ones(len(y)) if sample_weight is None else np.asarray(sample_weight, np.float64)
    mean, scale = X.mean(0), X.std(0) + 1e-9
    Z = np.concatenate([(X - mean) / scale, np.ones((len(X), 1))], 1)
    beta = np.zeros(Z.shape[1])
    reg = np.full(Z.shape[1], l2 * sw.sum())
    reg[-1] = 0.0
    for _ in range(steps):
        p = 1 / (1 + np.exp(-(Z @ beta)))
        g = Z.T @ (sw * (p - y)) + reg * beta
        H = (Z * (sw * p * (1 - p))[:, None]).T @ Z + np.diag(reg) + 1e-9 * np.eye(len(beta))
        step = np.linalg.solve(H, g)
        beta -= step
        if np.abs(step).max() < 1e-8:
            break
    return mean, scale, beta[:-1], float(beta[-1])

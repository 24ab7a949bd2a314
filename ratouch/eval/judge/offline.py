"""The offline judge: informativeness-weighted word matching and its fitted 1-10 calibration.

Five weighted features (`ratouch.eval.judge.features`) map to 1-10 with
``1 + 9 * sigmoid(b + w . z)``; the calibration is stored in ``ratouch/configs/judge/offline.json``
(`load_offline_config`, `write_offline_config`; fitted by
`ratouch.eval.judge.calibration.fit_offline_judge`).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ratouch.errors import ConfigError, DataError
from ratouch.eval.judge.features import (
    FEATURES,
    NO_RATES,
    WordRates,
    answer_rates,
    judge_features,
    word_table,
)
from ratouch.eval.judge.records import MAX_SCORE, MIN_SCORE
from ratouch.files import write_json_atomic
from ratouch.paths import CONFIGS
from ratouch.vocabulary import parse_adjectives

CONFIG_PATH = CONFIGS / "judge" / "offline.json"


class OfflineJudge:
    """Informativeness-weighted synonym/antonym matching plus a fitted 1-10 calibration.

    A matched adjective earns credit in proportion to how informative it is: words that fit
    nearly every label (label base rates from the fit data) and words the judged system says in
    nearly every answer (its own rates, `answer_rates`, measured by `score_many` on the answers
    being judged) earn little; contradicted words (antonyms of a label word) cost.

    Args:
        params: Calibration (keys ``features``, ``mean``, ``scale``, ``intercept``, ``weights``,
            ``label_rates``), e.g. from `fit_offline_judge`; default: the shipped
            ``configs/judge/offline.json``.

    Raises:
        ConfigError: If the calibration is missing or malformed.
    """

    name = "offline"
    key = "offline_score"

    def __init__(self, params: Mapping | None = None) -> None:
        if params is None:
            params = load_offline_config()
        self.params = _check_params(params)
        self._mean = np.asarray(self.params["mean"], dtype=np.float64)
        self._scale = np.asarray(self.params["scale"], dtype=np.float64)
        self._w = np.asarray(self.params["weights"], dtype=np.float64)
        self._b = float(self.params["intercept"])
        self.label_rates: dict[str, float] = dict(self.params["label_rates"])

    def _calibrate(self, feats: Sequence[float]) -> float:
        z = (np.asarray(feats) - self._mean) / self._scale
        return MIN_SCORE + (MAX_SCORE - MIN_SCORE) / (1.0 + math.exp(-(self._b + float(z @ self._w))))

    def explain(self, label: str, response: str | None, rates: WordRates = NO_RATES) -> dict:
        """Parsed adjectives, per-word table (matched / clash / ignored ..., weights), features
        and score of one answer, `rates` being the judged system's word rates."""
        lab, pred = parse_adjectives(label), parse_adjectives(response)
        if not lab:
            raise DataError(f"label {label!r} has no adjectives")
        if not pred:
            return {"label": lab, "predicted": [], "words": [], "features": None,
                    "score": MIN_SCORE}
        feats = judge_features(lab, pred, self.label_rates, rates)
        return {"label": lab, "predicted": pred,
                "words": word_table(lab, pred, self.label_rates, rates),
                "features": dict(zip(FEATURES, feats)), "score": self._calibrate(feats)}

    def score(self, label: str, response: str | None, rates: WordRates = NO_RATES) -> float:
        """Score in [1, 10] of a generated response against the ground-truth label; a missing
        or empty response scores 1. Without `rates` only the label base rates weigh words."""
        lab, pred = parse_adjectives(label), parse_adjectives(response)
        if not lab:
            raise DataError(f"label {label!r} has no adjectives")
        if not pred:
            return MIN_SCORE
        return self._calibrate(judge_features(lab, pred, self.label_rates, rates))

    def score_many(self, pairs: Iterable[tuple[str, str | None]]) -> list[float]:
        """Scores of (label, response) pairs of ONE system, in order; the system's word rates
        are measured on these responses."""
        pairs = list(pairs)
        rates = answer_rates(r for _, r in pairs)
        return [self.score(label, response, rates) for label, response in pairs]

    def stats(self) -> dict:
        return {}


def _check_params(params: Mapping) -> dict:
    if not isinstance(params, Mapping):
        raise ConfigError(f"offline judge calibration must be a mapping, got {type(params).__name__}")
    missing = [k for k in ("features", "mean", "scale", "intercept", "weights", "label_rates")
               if k not in params]
    if missing:
        raise ConfigError(f"offline judge calibration lacks {missing}; "
                          "refit with `ratouch judge --fit`")
    if list(params["features"]) != list(FEATURES):
        raise ConfigError(f"offline judge calibration is for features {params['features']}, "
                          f"this code computes {list(FEATURES)}; refit with `ratouch judge --fit`")
    for k in ("mean", "scale", "weights"):
        v = params[k]
        if (not isinstance(v, Sequence) or len(v) != len(FEATURES)
                or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in v)):
            raise ConfigError(f"offline judge calibration {k!r} must be {len(FEATURES)} finite numbers")
    if not all(s > 0 for s in params["scale"]):
        raise ConfigError("offline judge calibration 'scale' must be > 0")
    if not isinstance(params["intercept"], (int, float)) or not math.isfinite(params["intercept"]):
        raise ConfigError("offline judge calibration 'intercept' must be a finite number")
    rates = params["label_rates"]
    if not isinstance(rates, Mapping) or not all(
            isinstance(v, (int, float)) and 0 <= v <= 1 for v in rates.values()):
        raise ConfigError("offline judge calibration 'label_rates' must map words to [0, 1]")
    return dict(params)


def load_offline_config(path: str | os.PathLike | None = None) -> dict:
    """Read the offline judge's calibration (default: the shipped one)."""
    path = Path(path) if path is not None else CONFIG_PATH
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as e:
        raise ConfigError(f"offline judge calibration {path} is missing; "
                          "write it with `ratouch judge --fit`") from e
    except ValueError as e:
        raise ConfigError(f"offline judge calibration {path} is not valid JSON: {e}") from e



def write_offline_config(params: Mapping, path: str | os.PathLike | None = None) -> Path:
    """Write a calibration (atomically) to `path` (default: the shipped config)."""
    return write_json_atomic(path if path is not None else CONFIG_PATH, _check_params(params))

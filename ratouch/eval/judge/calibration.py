"""Fitting the offline judge on the published TVL judge data (GPT-4's scores of three TVL-LLaMA
systems): the data, its seeded held-out split, and the least-squares fit of the calibration."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ratouch.errors import DataError, DataNotFoundError
from ratouch.eval.judge.features import FEATURES, answer_rates, judge_features, label_fit_rates
from ratouch.eval.judge.records import (
    EVAL_KEY,
    LABEL_KEY,
    MAX_SCORE,
    MIN_SCORE,
    RESPONSE_KEY,
    SUBSETS,
    parse_gpt_score,
    read_records,
    subset_of,
)
from ratouch.paths import TVL_JUDGE_ENV, tvl_judge_dir
from ratouch.vocabulary import parse_adjectives

MODELS = ("tvl_llama_vits", "tvl_llama_vits_bgs", "tvl_llama_vittiny")
DATA_DIR_ENV = TVL_JUDGE_ENV


def judge_data_dir() -> Path:
    """``$RATOUCH_TVL_JUDGE_DIR``, else ``../shared/data/tvl_judge`` beside the repository."""
    return tvl_judge_dir()


def load_tvl_results(data_dir: str | os.PathLike | None = None) -> dict[str, list[dict]]:
    """The three published TVL-LLaMA result files, checked to hold the same samples in order."""
    folder = Path(data_dir) if data_dir is not None else judge_data_dir()
    out = {}
    for model in MODELS:
        path = folder / f"{model}.json"
        if not path.is_file():
            raise DataNotFoundError(f"TVL judge data {path} not found (set ${DATA_DIR_ENV})")
        out[model] = read_records(path)
    ref = out[MODELS[0]]
    for model in MODELS[1:]:
        recs = out[model]
        if len(recs) != len(ref) or any(
                a[LABEL_KEY] != b[LABEL_KEY] or Path(str(a.get("image_fp"))).name
                != Path(str(b.get("image_fp"))).name for a, b in zip(ref, recs)):
            raise DataError(f"{model}.json does not list the same samples as {MODELS[0]}.json")
    return out


def heldout_split(records: list[dict], seed: int = 0, fit_fraction: float = 0.5
                  ) -> tuple[list[int], list[int]]:
    """(fit, held-out) sample indices, stratified by subset and seeded. The same indices are
    used for every model, so the answers of the models to one sample share a side."""
    rng = np.random.default_rng(seed)
    by_subset: dict[str | None, list[int]] = {}
    for i, rec in enumerate(records):
        by_subset.setdefault(subset_of(rec.get("image_fp")), []).append(i)
    fit: list[int] = []
    for key in (*SUBSETS, None):  # a fixed order: SSVTP, HCT, then samples of neither
        if key not in by_subset:
            continue
        idx = np.asarray(by_subset[key])[rng.permutation(len(by_subset[key]))]
        fit += idx[: int(len(idx) * fit_fraction)].tolist()
    fit_set = set(fit)
    return sorted(fit_set), [i for i in range(len(records)) if i not in fit_set]


def gpt4_rows(data: Mapping[str, list[dict]], idx: Sequence[int], models: Sequence[str] = MODELS):
    """(label, response, GPT-4 score, model, subset) of the answers of `models` to samples
    `idx`, skipping answers whose GPT-4 evaluation does not parse."""
    rows = []
    for model in models:
        for i in idx:
            rec = data[model][i]
            gpt = parse_gpt_score(rec.get(EVAL_KEY))
            if gpt is not None:
                rows.append((rec[LABEL_KEY], rec[RESPONSE_KEY], gpt, model,
                             subset_of(rec.get("image_fp"))))
    return rows


def fit_calibration(data: Mapping[str, list[dict]], models: Sequence[str], idx: Sequence[int],
                    meta: Mapping | None = None) -> dict:
    """Fit label base rates and the 1-10 calibration on the answers of `models` to samples `idx`.

    Label base rates come from the labels of `idx`; each model's word rates from its own answers
    to `idx` (as `score_many` measures them at judge time); then least squares of
    ``1 + 9 * sigmoid(b + w . z)`` against GPT-4, z the standardised `FEATURES`.
    """
    from scipy.optimize import least_squares

    labels = [data[models[0]][i][LABEL_KEY] for i in idx]
    answer_words = {w for m in models for i in idx for w in parse_adjectives(data[m][i][RESPONSE_KEY])}
    label_rates = label_fit_rates(labels, answer_words)
    feature_rows: list[list[float]] = []
    targets: list[float] = []
    for model in models:
        rates = answer_rates(data[model][i][RESPONSE_KEY] for i in idx)
        for label, response, gpt, _, _ in gpt4_rows(data, idx, [model]):
            pred = parse_adjectives(response)
            if pred:
                feature_rows.append(judge_features(parse_adjectives(label), pred, label_rates,
                                                   rates))
                targets.append(gpt)
    X, y = np.asarray(feature_rows, dtype=np.float64), np.asarray(targets, dtype=np.float64)
    mean, scale = X.mean(0), X.std(0)
    scale[scale == 0] = 1.0
    Z = (X - mean) / scale

    def residual(p):
        return MIN_SCORE + (MAX_SCORE - MIN_SCORE) / (1.0 + np.exp(-(p[0] + Z @ p[1:]))) - y

    p = least_squares(residual, np.zeros(Z.shape[1] + 1), method="trf").x
    return {"features": list(FEATURES), "mean": mean.tolist(), "scale": scale.tolist(),
            "intercept": float(p[0]), "weights": p[1:].tolist(), "label_rates": label_rates,
            "fit": {"models": list(models), **(meta or {}), "n_fit_samples": len(idx),
                    "n_fit_answers": int(len(y))}}


def fit_offline_judge(data_dir: str | os.PathLike | None = None, seed: int = 0,
                      fit_fraction: float = 0.5) -> dict:
    """Fit the offline judge on the FIT part (`heldout_split`) of all three TVL files."""
    data = load_tvl_results(data_dir)
    fit_idx, _ = heldout_split(data[MODELS[0]], seed, fit_fraction)
    return fit_calibration(data, MODELS, fit_idx, {"split_seed": seed, "fit_fraction": fit_fraction})

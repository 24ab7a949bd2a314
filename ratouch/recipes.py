"""The reproducible training recipes behind `ratouch train retriever|generator|all`: they wire
cached data, frozen encoders, the default corpus and the trainers together, and save the
weights shipped in `assets/`."""

from __future__ import annotations

import logging
import time

import numpy as np

from ratouch.embed import load_embeddings
from ratouch.encoders.factory import create_model
from ratouch.loss import RetrieverLossConfig
from ratouch.pipeline import default_corpus, generator_weights, load_tgr, retriever_weights
from ratouch.retrieval import CorpusIndex
from ratouch.retriever import RetrieverConfig
from ratouch.train_encoders import TrainConfig, training_data
from ratouch.train_retriever import RetrieverTrainConfig, paired_embeddings, train_retriever

log = logging.getLogger(__name__)


def training_pairs(encoders, seed: int = 0, progress: bool = False) -> dict:
    """V, T and captions of the world's cached paired training split, for frozen encoders."""
    tc = TrainConfig(model=encoders.name, seed=seed)
    data = training_data(tc, encoders.cfg.vision_size, encoders.cfg.tactile_size, progress)
    emb = paired_embeddings(encoders, data)
    return {"V": emb["V"], "T": emb["T"], "labels": list(data["labels"]),
            "materials": list(data["materials"])}


def _pairs(encoder: str, seed: int, progress: bool):
    model = create_model(encoder)
    tc = TrainConfig(model=encoder, seed=seed)
    data = training_data(tc, model.cfg.vision_size, model.cfg.tactile_size, progress)
    return model, data, paired_embeddings(model, data)


def retriever_recipe(encoder: str = "default-s", seed: int = 0, strategy: str = "full",
                     cross_residual: bool = True, epochs: int | None = None, out=None,
                     progress: bool = True) -> dict:
    """Train the Tactile-Guided Retriever for an encoder and save it (default: assets/)."""
    model, _, emb = _pairs(encoder, seed, progress)
    tc = RetrieverTrainConfig(seed=seed, **({"epochs": epochs} if epochs else {}))
    _, report = train_retriever(emb, RetrieverConfig(dim=model.dim, cross_residual=cross_residual),
                                RetrieverLossConfig(strategy=strategy), tc,
                                out=str(out or retriever_weights(encoder)),
                                meta={"encoder": encoder})
    return report


def _neighbour_embeddings(corpus, encoder, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    img, txt, _ = load_embeddings(corpus, encoder, verify=False)
    flat = ids.reshape(-1)
    return (np.asarray(img)[flat].reshape(*ids.shape, -1),
            np.asarray(txt)[flat].reshape(*ids.shape, -1))


def generator_recipe(encoder: str = "default-s", seed: int = 0, progress: bool = True,
                     **train_overrides) -> dict:
    """Train the baseline and RA-Touch generators, save both, evaluate on the test split."""
    from ratouch.generator import save_generator
    from ratouch.tvl_eval import encode_test_split
    from ratouch.train_generator import (GeneratorTrainConfig, evaluate_generators,
                                         neighbours_for, train_generators)

    t0 = time.perf_counter()
    model, data, emb = _pairs(encoder, seed, progress)
    corpus = default_corpus(encoder, progress=progress)
    index = CorpusIndex(corpus, model.name, model.dim)
    tgr = load_tgr(encoder)
    tc = GeneratorTrainConfig(seed=seed, **train_overrides)
    ids = neighbours_for((tgr, index), emb["V"], emb["T"], tc.k)
    rv, rl = _neighbour_embeddings(corpus, encoder, ids)
    base, ra, report = train_generators(emb, list(data["labels"]), rv, rl, model.dim, tc)
    test = encode_test_split(model)
    tids = neighbours_for((tgr, index), test.V, test.T, tc.k)
    trv, trl = _neighbour_embeddings(corpus, encoder, tids)
    report["test"] = evaluate_generators(base, ra, test.V, test.T, trv, trl, test.labels)
    report["seconds"] = round(time.perf_counter() - t0, 1)
    # shipped weights are stored as float16 (identical test F1 measured; assets stay < 40 MB)
    save_generator(generator_weights(encoder, "baseline"), base, {"encoder": encoder, **report},
                   half=True)
    save_generator(generator_weights(encoder, "ra"), ra, {"encoder": encoder, **report}, half=True)
    return report

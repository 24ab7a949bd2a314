"""The training recipes' caches: keyed by the weights they were made from."""

from __future__ import annotations

import json

import ratouch.train.recipes as recipes


def test_align_only_retriever_cache_follows_the_encoder_weights(tmp_path, monkeypatch):
    weights = tmp_path / "enc"
    weights.mkdir()
    monkeypatch.setattr(recipes, "encoder_weights", lambda name: weights)
    # no shipped weights: one fixed folder
    assert recipes.align_retriever_folder("x", 12, 0).name == "retriever-align-x-none-e12-s0"
    (weights / "manifest.json").write_text(json.dumps({"files": {"model.safetensors": "a" * 64}}))
    first = recipes.align_retriever_folder("x", 12, 0)
    (weights / "manifest.json").write_text(json.dumps({"files": {"model.safetensors": "b" * 64}}))
    retrained = recipes.align_retriever_folder("x", 12, 0)
    # a retrain of the encoders makes a new cache folder: the old retriever is not read
    assert first != retrained and first.name == "retriever-align-x-aaaaaaaaaaaa-e12-s0"

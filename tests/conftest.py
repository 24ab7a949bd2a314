"""Shared fixtures: a default world and a test split written once per session."""

from __future__ import annotations

import pytest

from ratouch.world.config import WorldConfig
from ratouch.world.dataset import write_split
from ratouch.world.generator import World


@pytest.fixture(scope="session")
def world() -> World:
    return World(WorldConfig(seed=0))


@pytest.fixture(scope="session")
def test_split_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("tvl_world")
    counts = write_split(WorldConfig(seed=0), root, "test", workers=2, progress=False)
    return root, counts


@pytest.fixture(scope="session")
def debug_encoders():
    """The tiny `debug` encoder set with fixed random weights (MiniLM is real)."""
    import torch

    from ratouch.encoders.factory import create_model

    torch.manual_seed(0)
    return create_model("debug", pretrained=None).eval()


@pytest.fixture(scope="session")
def small_corpus(tmp_path_factory, debug_encoders):
    """A 240-entry world corpus embedded with the debug encoders."""
    from ratouch.corpus.imagenet_t import build_corpus
    from ratouch.embed import embed_corpus

    folder = tmp_path_factory.mktemp("corpus") / "c"
    build_corpus(folder, 240, seed=0, progress=False)
    embed_corpus(folder, debug_encoders, batch=100, workers=1, progress=False)
    return folder


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Tests never read or write the user's cache of corpora and training data."""
    import os

    old = os.environ.get("RATOUCH_CACHE")
    os.environ["RATOUCH_CACHE"] = str(tmp_path_factory.mktemp("ratouch-cache"))
    yield
    if old is None:
        os.environ.pop("RATOUCH_CACHE", None)
    else:
        os.environ["RATOUCH_CACHE"] = old

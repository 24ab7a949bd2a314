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

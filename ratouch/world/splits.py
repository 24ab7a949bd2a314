"""The world's test split, rendered and encoded once for an evaluation.

`encode_test_split` renders the 402 test pairs (or a subset, or under stress knobs) and
`encode_samples` encodes rendered pairs with any encoder set (anything with `encode_image` and
`encode_tactile`): the contact-box crops, and the tactile frames against their sensor's
background, as every TVL row carries one. `TestSplit` keeps the embeddings beside each pair's
ground truth, its sensor family and its TVL-layout file names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ratouch.errors import ConfigError
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import SUBSET_DIRS, world_for
from ratouch.world.sampler import TEST_SIZE, Sample, World
from ratouch.world.tactile import sensor_family


@dataclass
class TestSplit:
    """The encoded test split of a world.

    Attributes:
        V, T: (N, D) visual (contact-box crop) and tactile embeddings.
        labels: ground-truth captions as written in the data set.
        subsets: "structured" / "wild" per sample.
        materials: the world's ground-truth material per sample.
        indices: sample indices in the test split.
        object_scale: object size / frame side per sample (a failure-mode axis).
        world: the world config (seed and stress knobs) the split was rendered with.
        families: the sensor family (a key of `world.sensors.SENSOR_FAMILIES`) of each tactile frame.
        split: the world split the pairs were drawn from ("test", or "train" for the
            validation pairs); it names their TVL-layout files.
    """

    V: np.ndarray
    T: np.ndarray
    labels: list[str]
    subsets: list[str]
    materials: list[str]
    indices: list[int]
    object_scale: list[float]
    world: WorldConfig
    families: list[str] = field(default_factory=list)
    split: str = "test"

    def image_fp(self, i: int) -> str:

        return f"{SUBSET_DIRS[self.subsets[i]]}/vision/{self.split}_{self.indices[i]:06d}.png"

    def tactile_fp(self, i: int) -> str:
        return self.image_fp(i).replace("/vision/", "/tactile/")


#: The validation pairs: this many train-split pairs from this index on, far beyond every
#: training set (12,000 pairs) and used by nothing else, for choosing a setting without
#: looking at the test split (`ratouch eval tvl --validation`).
VALIDATION_START = 4_000_000
VALIDATION_SIZE = TEST_SIZE


def encode_validation_split(encoders, world: WorldConfig | None = None,
                            n: int = VALIDATION_SIZE) -> TestSplit:
    """Render and encode `n` validation pairs (train[VALIDATION_START:VALIDATION_START + n]),
    as the test split is encoded: crops, and tactile frames against their sensor's
    background."""
    if n < 1:
        raise ConfigError(f"n={n} must be positive")
    return encode_test_split(encoders, world, range(VALIDATION_START, VALIDATION_START + n),
                             split="train")


def encode_test_split(encoders, world: WorldConfig | None = None,
                      indices: Sequence[int] | None = None, split: str = "test") -> TestSplit:
    """Render and encode the test split (all 402 pairs unless `indices` are given), or the
    given `indices` of another held-out split (e.g. "probe"). Tactile frames are encoded with
    their sensor's background, as every TVL row carries one."""

    world = world or WorldConfig()
    gen = world_for(world)
    if indices is None and split != "test":
        raise ConfigError(f"split {split!r} needs explicit indices")
    idx = list(range(TEST_SIZE)) if indices is None else [int(i) for i in indices]
    samples = [gen.sample(split, i) for i in idx]
    return encode_samples(encoders, samples, [gen] * len(samples), idx, world, split)


def encode_samples(encoders, samples: Sequence[Sample], worlds: Sequence[World],
                   indices: Sequence[int], world: WorldConfig, split: str = "test") -> TestSplit:
    """Encode rendered pairs: each contact-box crop, and each tactile frame against the
    background of its sensor in the world that rendered it (`worlds[j]` rendered
    `samples[j]`; `world` is the config the split is reported under)."""
    return TestSplit(
        V=encoders.encode_image([s.crop for s in samples]),
        T=encoders.encode_tactile([s.tactile for s in samples],
                                  [w.background_image(s.sensor) for s, w in zip(samples, worlds,
                                                                                strict=True)]),
        labels=[s.caption for s in samples], subsets=[s.subset for s in samples],
        materials=[s.material for s in samples], indices=[int(i) for i in indices],
        object_scale=[float(s.object_scale) for s in samples], world=world,
        families=[sensor_family(s.sensor) for s in samples], split=split)

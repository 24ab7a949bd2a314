"""The world generator: determinism, catalogue, samples and captions."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import numpy as np
import pytest

from ratouch.errors import ConfigError
from ratouch.vocabulary import TACTILE_WORDS, TVL_ADJECTIVES
from ratouch.world.config import StressConfig, WorldConfig
from ratouch.world.material import MATERIALS, groups
from ratouch.world.objects import OBJECT_CLASSES, classes_with_material
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.silhouette import FAMILIES

_DIGEST = """
import hashlib, sys
from ratouch.world.sampler import World
w = World()
h = hashlib.sha256()
for split, i in [("train", 3), ("test", 7), ("test", 200), ("probe", 11)]:
    s = w.sample(split, i)
    h.update(s.visual.tobytes()); h.update(s.tactile.tobytes()); h.update(s.caption.encode())
h.update(w.corpus_image(5, 17).tobytes())
print(h.hexdigest())
"""


def _digest(world: World) -> str:
    h = hashlib.sha256()
    for split, i in [("train", 3), ("test", 7), ("test", 200), ("probe", 11)]:
        s = world.sample(split, i)
        h.update(s.visual.tobytes())
        h.update(s.tactile.tobytes())
        h.update(s.caption.encode())
    h.update(world.corpus_image(5, 17).tobytes())
    return h.hexdigest()


def test_same_seed_split_index_gives_identical_bytes_in_another_process(world):
    out = subprocess.run([sys.executable, "-c", _DIGEST], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == _digest(world)


def test_different_seed_gives_different_samples(world):
    other = World(WorldConfig(seed=1))
    assert not np.array_equal(world.sample("test", 50).visual, other.sample("test", 50).visual)


def test_catalogue_sizes_and_designed_ambiguity():
    assert len(MATERIALS) >= 32
    assert len(OBJECT_CLASSES) >= 120
    look, feel = groups("look"), groups("feel")
    assert len(look) >= 6 and len(feel) >= 6
    by_name = {m.name: m for m in MATERIALS}
    for members in look.values():  # look alike: one visual generator, different touch
        mats = [by_name[n] for n in members]
        assert len({m.look for m in mats}) == 1
        assert len({m.feel for m in mats}) == len(mats)
    for members in feel.values():  # feel alike: one touch generator, different looks
        mats = [by_name[n] for n in members]
        assert len({m.feel for m in mats}) == 1
        assert len({m.look for m in mats}) == len(mats)
    # materials that appear on visually very different objects (different silhouettes)
    multi = [m.name for m in MATERIALS
             if len({c.family for c in OBJECT_CLASSES if c.name in classes_with_material(m.name)}) >= 3]
    assert len(multi) >= 6, multi
    assert {c.family for c in OBJECT_CLASSES} <= set(FAMILIES)


def test_profiles_speak_the_tvl_vocabulary():
    top = set(TVL_ADJECTIVES[:13])
    used = {w for m in MATERIALS for w, _ in m.profile}
    assert used <= TACTILE_WORDS
    assert top <= used  # every frequent TVL word can be produced


def test_test_split_shape_and_subsets(world):
    s0, s45, s46 = world.sample("test", 0), world.sample("test", 45), world.sample("test", 46)
    assert s0.subset == s45.subset == "structured" and s46.subset == "wild"
    assert s0.class_name == "" and s46.class_name
    assert s46.visual.shape == (128, 128, 3) and s46.visual.dtype == np.uint8
    assert s46.tactile.shape == (128, 96, 3)
    with pytest.raises(ConfigError, match="402"):
        world.sample("test", TEST_SIZE)
    with pytest.raises(ConfigError, match="split"):
        world.sample("validation", 0)


@pytest.mark.parametrize("index", range(46, 402, 37))
def test_contact_box_lies_on_the_object(world, index):
    s = world.sample("test", index)
    x0, y0, x1, y1 = s.box_true
    assert 0 <= x0 < x1 <= 128 and 0 <= y0 < y1 <= 128
    inside = s.object_mask[y0:y1, x0:x1].mean()
    assert s.object_mask[(y0 + y1) // 2, (x0 + x1) // 2]
    assert inside > 0.4


def test_labels_are_two_to_five_tactile_adjectives(world):
    lengths = set()
    for i in range(0, 402, 5):
        s = world.sample("test", i)
        assert 2 <= len(s.label) <= 5
        assert len(set(s.label)) == len(s.label)
        assert set(s.label) <= TACTILE_WORDS
        lengths.add(len(s.label))
    assert {2, 3, 4} <= lengths


def test_descriptions_describe_appearance_only(world):
    soft_words = {"soft", "hard", "rough", "smooth", "squishy", "fuzzy", "pliable"}
    for c in range(0, len(OBJECT_CLASSES), 7):
        r = world.corpus_record(c, 3)
        words = set(r.description.replace(",", " ").split())
        assert r.class_name in r.description
        assert not words & soft_words, r.description


def test_no_contact_frame_is_the_sensor_background(world):
    w = World(WorldConfig(stress=StressConfig(no_contact=1.0, tactile_noise=0.0, tactile_blur=0.0)))
    s = w.sample("train", 5)
    assert not s.contact
    diff = np.abs(s.tactile.astype(int) - w.background_image(s.sensor).astype(int))
    assert diff.max() <= 1
    contact = World(WorldConfig(stress=StressConfig(tactile_noise=0.0, tactile_blur=0.0))).sample("train", 5)
    assert np.abs(contact.tactile.astype(int) - w.background_image(contact.sensor)).max() > 20


def test_config_validation_names_the_field():
    with pytest.raises(ConfigError, match="object_scale"):
        StressConfig(object_scale=0.01)
    with pytest.raises(ConfigError, match="missing"):
        StressConfig(missing="both")
    with pytest.raises(ConfigError, match="seed"):
        WorldConfig(seed=-1)

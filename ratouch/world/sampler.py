"""The world sampler: (seed, split, index) -> a visuo-tactile sample, deterministically.

Every random choice of a sample comes from a generator seeded by (seed, split, index), and
texture tiles depend only on their pattern specs, so any process regenerates byte-identical
images; a corpus of 150k entries needs no stored pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ratouch.errors import ConfigError
from ratouch.world.caption import tactile_label, visual_description
from ratouch.world.config import SPLITS, WorldConfig
from ratouch.world.material import MATERIALS, Material, material
from ratouch.world.objects import (
    CLASS_INDEX,
    OBJECT_CLASSES,
    ObjectClass,
    classes_with_material,
)
from ratouch.world.scene import Box, ScenePlan, plan_scene, render_scene
from ratouch.world.tactile import (
    TactilePlan,
    plan_tactile,
    render_tactile,
    sensor_background,
    sensor_family,
)
from ratouch.world.texture import PatternSpec, make_tile, mip_pyramid

TEST_STRUCTURED = 46  # like SSVTP's share of the TVL test set
TEST_WILD = 356  # like HCT's
TEST_SIZE = TEST_STRUCTURED + TEST_WILD
CORPUS_POOL_PER_CLASS = 1300  # like ImageNet's images per class: the pool subsets sample from
#: instances a class can render beyond its pool, for corpora past ImageNet's size (10M over the
#: 168 classes fits); an instance is a seed, so any of them renders the same on every machine
CORPUS_MAX_PER_CLASS = 60_000

_SPLIT_CODE = {name: i + 1 for i, name in enumerate(SPLITS)}


@dataclass(frozen=True)
class Sample:
    """One visuo-tactile pair with its ground truth."""

    split: str
    index: int
    subset: str  # "structured" or "wild"
    class_name: str
    material: str
    label: list[str]  # TVL-style tactile adjectives
    description: str  # appearance-only caption
    box: Box  # the contact box as given to a user (possibly offset by a stress knob)
    box_true: Box
    visual: np.ndarray  # (S, S, 3) uint8
    tactile: np.ndarray  # (H, W, 3) uint8
    object_mask: np.ndarray  # (S, S) bool
    distractor_mask: np.ndarray  # (S, S) bool
    sensor: int  # global sensor unit id, see ratouch.world.tactile (family: `family`)
    contact: bool
    object_scale: float  # longer side of the object's box / frame side

    @property
    def caption(self) -> str:
        return ", ".join(self.label)

    @property
    def family(self) -> str:
        """The tactile sensor's family (a key of `world.sensors.SENSOR_FAMILIES`)."""
        return sensor_family(self.sensor)

    @property
    def crop(self) -> np.ndarray:
        """The visual image inside the contact box as given (`box`), what encoders see."""
        x0, y0, x1, y1 = self.box
        return self.visual[y0:y1, x0:x1]


@dataclass(frozen=True)
class CorpusRecord:
    """Metadata of one ImageNet-T entry of the world; its image is rendered on demand."""

    class_name: str
    class_index: int
    instance: int  # index within the class pool
    material: str
    colour: str
    description: str


class World:
    """Generates samples and corpus entries of the procedural world.

    Holds read-only catalogue references and a cache of texture pyramids (pure functions of
    their pattern specs), so it can be shared by threads and re-created in any process.
    """

    def __init__(self, cfg: WorldConfig | None = None):
        self.cfg = cfg or WorldConfig()
        self._pyramids: dict[PatternSpec, list] = {}
        self._backgrounds: dict[int, np.ndarray] = {}

    # -- caches --------------------------------------------------------------------------------
    def pyramid(self, spec: PatternSpec) -> list:
        if spec not in self._pyramids:
            self._pyramids[spec] = mip_pyramid(make_tile(spec))
        return self._pyramids[spec]

    def warm(self) -> "World":
        """Build every material's texture pyramids now (about 2 s), e.g. before forking
        worker processes so that they inherit them instead of rebuilding them."""
        for m in MATERIALS:
            self.pyramid(m.look.pattern)
            self.pyramid(m.feel.pattern)
        return self

    def sensor_background(self, sensor: int) -> np.ndarray:
        """The float (H, W, 3) no-contact image of a sensor unit (global id, any family)."""
        if sensor not in self._backgrounds:
            self._backgrounds[sensor] = sensor_background(sensor, self.cfg.tactile_hw)
        return self._backgrounds[sensor]

    def background_image(self, sensor: int) -> np.ndarray:
        """The uint8 background image written beside the data, as TVL ships one."""
        return (self.sensor_background(sensor) * 255 + 0.5).astype(np.uint8)

    # -- samples -------------------------------------------------------------------------------
    def _rng(self, split: str, *index: int) -> np.random.Generator:
        if split not in _SPLIT_CODE:
            raise ConfigError(f"split={split!r} must be one of {SPLITS}")
        if any(i < 0 for i in index):
            raise ConfigError(f"index={index!r} must be non-negative")
        return np.random.default_rng([self.cfg.seed, _SPLIT_CODE[split], *index])

    def _subset(self, split: str, index: int, rng: np.random.Generator) -> str:
        if split == "test":
            if index >= TEST_SIZE:
                raise ConfigError(f"test index {index} out of range: the test split has "
                                  f"{TEST_SIZE} samples")
            return "structured" if index < TEST_STRUCTURED else "wild"
        return "structured" if rng.random() < self.cfg.structured_fraction else "wild"

    def plan(self, split: str, index: int) -> tuple[str, ObjectClass | None, Material,
                                                  ScenePlan, TactilePlan, list[str], str]:
        """Draw all random choices of a sample without rendering any pixel."""
        rng = self._rng(split, index)
        subset = self._subset(split, index, rng)
        if subset == "structured":
            cls = None
            mat = MATERIALS[rng.integers(len(MATERIALS))]
        elif split == "probe":  # balanced over materials, for the material-recognition probe
            mat = MATERIALS[rng.integers(len(MATERIALS))]
            names = classes_with_material(mat.name)
            cls = OBJECT_CLASSES[CLASS_INDEX[names[rng.integers(len(names))]]]
        else:
            cls = OBJECT_CLASSES[rng.integers(len(OBJECT_CLASSES))]
            mat = material(_pick(rng, cls.materials))
        scene = plan_scene(rng, self.cfg, subset, cls, mat)
        touch = plan_tactile(rng, self.cfg, mat)
        label = tactile_label(rng, mat)
        description = visual_description(rng, scene.class_name, mat.name,
                                         scene.obj.surface.colour, scene.background.material)
        return subset, cls, mat, scene, touch, label, description

    def sample(self, split: str, index: int) -> Sample:
        """Generate sample `index` of `split` ("train", "test" or "probe")."""
        subset, cls, mat, scene, touch, label, description = self.plan(split, index)
        size = self.cfg.image_size
        visual, obj_mask, dis_mask = render_scene(scene, self.pyramid, size)
        tactile = render_tactile(touch, self.pyramid, self.cfg.tactile_hw,
                                 self.sensor_background(touch.sensor))
        return Sample(
            split=split, index=index, subset=subset, class_name=scene.class_name,
            material=mat.name, label=label, description=description, box=scene.box,
            box_true=scene.box_true, visual=visual, tactile=tactile, object_mask=obj_mask,
            distractor_mask=dis_mask, sensor=touch.sensor, contact=touch.contact,
            object_scale=scene.object_scale / size)

    # -- ImageNet-T corpus ---------------------------------------------------------------------
    def _corpus_plan(self, class_index: int, instance: int) -> tuple[ScenePlan, CorpusRecord]:
        if not 0 <= class_index < len(OBJECT_CLASSES):
            raise ConfigError(f"class_index={class_index} out of range [0, {len(OBJECT_CLASSES)})")
        if not 0 <= instance < CORPUS_MAX_PER_CLASS:
            raise ConfigError(f"instance={instance} out of range [0, {CORPUS_MAX_PER_CLASS})")
        rng = self._rng("corpus", class_index, instance)
        cls = OBJECT_CLASSES[class_index]
        mat = material(_pick(rng, cls.materials))
        scene = plan_scene(rng, self.cfg, "corpus", cls, mat)
        description = visual_description(rng, cls.name, mat.name, scene.obj.surface.colour,
                                         scene.background.material)
        record = CorpusRecord(cls.name, class_index, instance, mat.name,
                              scene.obj.surface.colour, description)
        return scene, record

    def corpus_record(self, class_index: int, instance: int) -> CorpusRecord:
        return self._corpus_plan(class_index, instance)[1]

    def corpus_image(self, class_index: int, instance: int) -> np.ndarray:
        """Render the image of a corpus entry, (S, S, 3) uint8."""
        scene, _ = self._corpus_plan(class_index, instance)
        return render_scene(scene, self.pyramid, self.cfg.image_size)[0]

    @staticmethod
    def class_index(name: str) -> int:
        try:
            return CLASS_INDEX[name]
        except KeyError as e:
            raise ConfigError(f"unknown class {name!r}") from e


def _pick(rng: np.random.Generator, weighted: tuple[tuple[str, float], ...]) -> str:
    names = [n for n, _ in weighted]
    w = np.array([w for _, w in weighted], float)
    return names[rng.choice(len(names), p=w / w.sum())]

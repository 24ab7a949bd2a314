"""Object classes of the world: a name (ImageNet's where one fits), a silhouette family and a
distribution over materials. The table lives in `objects.txt` beside this module."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

from ratouch.errors import ConfigError
from ratouch.world.material import MATERIAL_INDEX

# Typical width / height of each silhouette family's bounding box.
FAMILY_ASPECT: dict[str, float] = {
    "ball": 1.0, "egg": 1.3, "box": 1.3, "rounded_box": 1.5, "bottle": 0.42, "mug": 1.1,
    "bowl": 1.7, "plate": 2.2, "boot": 0.85, "bag": 1.05, "shirt": 1.15, "trousers": 0.7,
    "chair": 0.7, "table": 1.5, "hat": 1.7, "guitar": 0.45, "pan": 2.0, "blob": 1.35,
    "mitten": 0.75, "cushion": 1.4, "sheet": 1.45, "vase": 0.6, "shoe": 1.9, "lamp": 0.65,
    "teddy": 0.8,
}


@dataclass(frozen=True)
class ObjectClass:
    name: str
    family: str
    materials: tuple[tuple[str, float], ...]  # (material name, weight)

    @property
    def aspect(self) -> float:
        return FAMILY_ASPECT[self.family]


def _load() -> tuple[ObjectClass, ...]:
    text = resources.files("ratouch.world").joinpath("objects.txt").read_text()
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        name, family, mats = (part.strip() for part in line.split("|"))
        if family not in FAMILY_ASPECT:
            raise ConfigError(f"objects.txt line {n}: unknown silhouette family {family!r}")
        weights = []
        for item in mats.split():
            mat, w = item.rsplit(":", 1)
            if mat not in MATERIAL_INDEX:
                raise ConfigError(f"objects.txt line {n}: unknown material {mat!r}")
            weights.append((mat, float(w)))
        out.append(ObjectClass(name, family, tuple(weights)))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise ConfigError("objects.txt: duplicate class names")
    return tuple(out)


OBJECT_CLASSES: tuple[ObjectClass, ...] = _load()
CLASS_INDEX: dict[str, int] = {c.name: i for i, c in enumerate(OBJECT_CLASSES)}


def classes_with_material(material: str) -> list[str]:
    """Names of the classes that can be made of `material`."""
    return [c.name for c in OBJECT_CLASSES if any(m == material for m, _ in c.materials)]

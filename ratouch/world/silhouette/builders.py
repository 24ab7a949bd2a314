"""The silhouette families, by name, in a fixed order: each family's builder.

Each builder takes the four variant numbers (a, b, c, d) in [0, 1] and returns the parts in
drawing order: additive parts are OR-ed in, subtractive ones cut what was drawn before them.
"""

from __future__ import annotations

import types
from collections.abc import Callable

from ratouch.errors import ConfigError
from ratouch.world.silhouette import animals, clothing, furniture, solids, vessels
from ratouch.world.silhouette.parts import Part

_BUILDERS: types.MappingProxyType[str, Callable[[float, float, float, float], list[Part]]] = (
    types.MappingProxyType(
        {
            "ball": solids.ball,
            "egg": solids.egg,
            "box": solids.box,
            "rounded_box": solids.rounded_box,
            "bottle": vessels.bottle,
            "vase": vessels.vase,
            "lamp": furniture.lamp,
            "mug": vessels.mug,
            "bowl": vessels.bowl,
            "plate": vessels.plate,
            "boot": clothing.boot,
            "shoe": clothing.shoe,
            "bag": clothing.bag,
            "shirt": clothing.shirt,
            "trousers": clothing.trousers,
            "chair": furniture.chair,
            "table": furniture.table,
            "hat": clothing.hat,
            "guitar": furniture.guitar,
            "pan": vessels.pan,
            "spoon": vessels.spoon,
            "blob": animals.blob,
            "teddy": animals.teddy,
            "mitten": clothing.mitten,
            "cushion": solids.cushion,
            "sheet": solids.sheet,
            "rock": solids.rock,
        }
    )
)

FAMILIES: tuple[str, ...] = tuple(_BUILDERS)
"""Names of every silhouette family, in a fixed order."""


def builder(family: str) -> Callable[[float, float, float, float], list[Part]]:
    try:
        return _BUILDERS[family]
    except (KeyError, TypeError):
        raise ConfigError(
            f"unknown silhouette family {family!r}; valid families: {', '.join(FAMILIES)}"
        ) from None

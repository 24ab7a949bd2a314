"""Configuration of the procedural world: sizes, seed and the stress knobs."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from ratouch.errors import ConfigError

SPLITS = ("train", "test", "corpus", "probe")
MISSING = ("none", "visual", "tactile")


def _check_range(name: str, value: float, lo: float, hi: float) -> None:
    if not lo <= value <= hi:
        raise ConfigError(f"{name}={value!r} must lie in [{lo}, {hi}]")


@dataclass(frozen=True)
class StressConfig:
    """Stress knobs: each one dials up a failure mode the paper names. `None` keeps the
    split's natural distribution; a value fixes the knob for every sample.

    Attributes:
        object_scale: object's longer side as a fraction of the frame side (0.1 .. 1.0).
        clutter: number of distractor objects in the scene.
        background_dominance: 0 muted background .. 1 loud, high-contrast background texture.
        tactile_noise: std of sensor noise added to the tactile frame (0 .. 0.3).
        tactile_blur: gel blur sigma in tactile pixels (0 .. 6).
        tactile_rotation: rotation of the pressed texture, degrees counter-clockwise as seen
            in the frame.
        box_offset: shift of the reported contact box, as a fraction of its side (0 .. 3).
        missing: "none", "visual" (blank image) or "tactile" (a no-contact frame).
        no_contact: probability of a no-contact tactile frame.
    """

    object_scale: float | None = None
    clutter: int | None = None
    background_dominance: float | None = None
    tactile_noise: float | None = None
    tactile_blur: float | None = None
    tactile_rotation: float | None = None
    box_offset: float = 0.0
    missing: str = "none"
    no_contact: float = 0.0

    def __post_init__(self) -> None:
        if self.object_scale is not None:
            _check_range("object_scale", self.object_scale, 0.1, 1.0)
        if self.clutter is not None and not 0 <= self.clutter <= 12:
            raise ConfigError(f"clutter={self.clutter!r} must lie in [0, 12]")
        if self.background_dominance is not None:
            _check_range("background_dominance", self.background_dominance, 0.0, 1.0)
        if self.tactile_noise is not None:
            _check_range("tactile_noise", self.tactile_noise, 0.0, 0.3)
        if self.tactile_blur is not None:
            _check_range("tactile_blur", self.tactile_blur, 0.0, 6.0)
        if self.tactile_rotation is not None:
            _check_range("tactile_rotation", self.tactile_rotation, -360.0, 360.0)
        _check_range("box_offset", self.box_offset, 0.0, 3.0)
        _check_range("no_contact", self.no_contact, 0.0, 1.0)
        if self.missing not in MISSING:
            raise ConfigError(f"missing={self.missing!r} must be one of {MISSING}")


@dataclass(frozen=True)
class WorldConfig:
    """The world: a seed, image sizes and the stress knobs.

    Attributes:
        seed: the same (seed, split, index) always gives byte-identical samples.
        image_size: side of the square visual image, pixels.
        tactile_hw: (height, width) of the tactile frame (portrait like a DIGIT sensor).
        structured_fraction: share of train samples that are flat close-ups (SSVTP-like).
        stress: the stress knobs.
    """

    seed: int = 0
    image_size: int = 128
    tactile_hw: tuple[int, int] = (128, 96)
    structured_fraction: float = 0.1
    stress: StressConfig = field(default_factory=StressConfig)

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed={self.seed!r} must be a non-negative integer")
        if not 32 <= self.image_size <= 1024:
            raise ConfigError(f"image_size={self.image_size!r} must lie in [32, 1024]")
        h, w = self.tactile_hw
        if not (32 <= h <= 1024 and 32 <= w <= 1024):
            raise ConfigError(f"tactile_hw={self.tactile_hw!r}: both sides must lie in [32, 1024]")
        _check_range("structured_fraction", self.structured_fraction, 0.0, 1.0)

    def with_stress(self, **knobs) -> "WorldConfig":
        """A copy of this config with some stress knobs changed."""
        return replace(self, stress=replace(self.stress, **knobs))

"""Tactile sensor families: one table, a row per family.

A row says everything the rest of the code needs to know about a family: how its frames are
rendered (the world's photometric shader, or Taxim's optics calibrated on real presses), where
its units' no-contact backgrounds come from, how many of its units carry marker dots, the real
sensor's frame size, and its per-frame variation. Adding a family is adding a row to
:data:`SENSOR_FAMILIES`; an unknown family name is an error (:func:`family`), never another
family's gel.

Each family has :data:`UNITS_PER_FAMILY` units; a unit's index is the global sensor id
(`TactilePlan.sensor`, `sensor_{k}.png` of the TVL layout), families in table order.

* ``digit``: a DIGIT, by the shader: red, green and blue LEDs 120 degrees apart light a
  bluish-grey gel; contact shows as strong colour shifts that follow the surface normals.
* ``gelsight``: a GelSight, by Taxim's GelSight calibration (`taxim_optics`) on the real
  sensor's no-contact frame; half of its units carry a grid of dark marker dots (as in Touch
  and Go) that move with the indentation.
* ``mini``: a GelSight Mini, by Taxim's GelSight Mini calibration: a teal-to-violet gel, a
  faint contact (a few of 255 mean change), no markers.

The world's frames are portrait (128 x 96); a landscape sensor (GelSight, Mini: 640 x 480) is
mounted turned by 90 degrees: its optics render the transposed height map, and the result is
turned back, so its lights stay consistent with its calibration.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from ratouch.errors import ConfigError

UNITS_PER_FAMILY = 8
#: Renderers a family row may name.
RENDERERS = ("shader", "taxim")

# Light directions (x right, y down, z out of the gel) and colours: red, green, blue LEDs
# 120 degrees apart around the gel, as on a DIGIT.
DIGIT_LIGHTS = (
    (np.array([-0.85, 0.0, 0.53]), np.array([1.0, 0.25, 0.2])),
    (np.array([0.43, -0.74, 0.53]), np.array([0.2, 1.0, 0.3])),
    (np.array([0.43, 0.74, 0.53]), np.array([0.25, 0.3, 1.0])),
)


@dataclass(frozen=True)
class Variation:
    """What changes from frame to frame on a unit of a family (drawn per frame).

    Attributes:
        blur: gel blur sigma range, pixels at 96 px width.
        noise: sensor noise std range ([0, 1] units).
        gain_jitter: light strength factor 1 +- this.
        turn_jitter: rotation of the lights, degrees (shader only).
        tint_jitter: per-channel tint of the contact shading.
        vignette: vignetting range of the contact shading.
    """

    blur: tuple[float, float]
    noise: tuple[float, float]
    gain_jitter: float
    turn_jitter: float
    tint_jitter: float
    vignette: tuple[float, float]


@dataclass(frozen=True)
class Shader:
    """The world's photometric shader of a family: lights and gains."""

    lights: tuple
    gain: float  # strength of the contact shading
    darken: float  # how much the pressed gel darkens
    texture: float  # gain of the pressed texture against the indentation's dome


@dataclass(frozen=True)
class SensorFamily:
    """One row of the sensor table.

    Attributes:
        name: the family's name ("digit", ...), as frames and the API name it.
        title: a plain name for people.
        renderer: "shader" (the world's photometric shader, `shader` set) or "taxim"
            (Taxim's optics with `calibration`).
        background: how a unit's no-contact field is made (:data:`BACKGROUND_SOURCES`):
            "leds" (the shader's LED field) or "taxim" (the calibration's real no-contact
            frame, varied per unit).
        marker_units: how many of the family's units carry a marker grid.
        native_hw: the real sensor's frame size (h, w).
        variation: per-frame variation.
        shader: the shader's lights and gains (renderer "shader").
        calibration: Taxim's calibration folder (renderer "taxim").
        press_mm: indentation of a full press, mm (renderer "taxim").
        press_contrast: typical RMS change of a press against the background ([0, 1] units,
            the median over 150 of the family's renders, `train[2000000:2000150]`): the tactile encoder reads a frame's contrast
            against it, so that a faint sensor's press is not read as a light touch.
    """

    name: str
    title: str
    renderer: str
    background: str
    marker_units: int
    native_hw: tuple[int, int]
    variation: Variation
    press_contrast: float
    shader: Shader | None = None
    calibration: str | None = None
    press_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.background not in ("leds", "taxim"):
            raise ConfigError(f"sensor family {self.name!r}: background={self.background!r} "
                              "must be 'leds' or 'taxim'")
        if self.renderer not in RENDERERS:
            raise ConfigError(f"sensor family {self.name!r}: renderer={self.renderer!r} must "
                              f"be one of {RENDERERS}")
        if self.renderer == "shader" and self.shader is None:
            raise ConfigError(f"sensor family {self.name!r}: the shader needs `shader`")
        if self.renderer == "taxim" and (self.calibration is None or self.press_mm <= 0):
            raise ConfigError(f"sensor family {self.name!r}: Taxim needs a calibration and "
                              "press_mm > 0")
        if not 0 <= self.marker_units <= UNITS_PER_FAMILY:
            raise ConfigError(f"sensor family {self.name!r}: marker_units="
                              f"{self.marker_units} must lie in [0, {UNITS_PER_FAMILY}]")

    @property
    def landscape(self) -> bool:
        return self.native_hw[1] > self.native_hw[0]


SENSOR_FAMILIES: dict[str, SensorFamily] = {row.name: row for row in (
    SensorFamily(
        name="digit", title="DIGIT", renderer="shader", background="leds", marker_units=0,
        native_hw=(320, 240),
        variation=Variation(blur=(0.5, 1.1), noise=(0.006, 0.015), gain_jitter=0.12,
                            turn_jitter=8.0, tint_jitter=0.06, vignette=(0.1, 0.4)),
        shader=Shader(DIGIT_LIGHTS, gain=0.55, darken=0.12, texture=1.0),
        press_contrast=0.036),
    SensorFamily(
        name="gelsight", title="GelSight (Taxim)", renderer="taxim", background="taxim",
        marker_units=4, native_hw=(480, 640),
        variation=Variation(blur=(0.3, 0.8), noise=(0.003, 0.008), gain_jitter=0.15,
                            turn_jitter=0.0, tint_jitter=0.06, vignette=(0.0, 0.3)),
        calibration="gelsight", press_mm=0.6, press_contrast=0.022),
    SensorFamily(
        name="mini", title="GelSight Mini (Taxim)", renderer="taxim", background="taxim",
        marker_units=0, native_hw=(480, 640),
        variation=Variation(blur=(0.4, 1.0), noise=(0.004, 0.009), gain_jitter=0.2,
                            turn_jitter=0.0, tint_jitter=0.08, vignette=(0.0, 0.4)),
        calibration="gelsight_mini", press_mm=0.6, press_contrast=0.025),
)}
FAMILIES = tuple(SENSOR_FAMILIES)
N_SENSORS = len(FAMILIES) * UNITS_PER_FAMILY  # distinct sensor units, each with its background


def family(name: str) -> SensorFamily:
    """The table's row of family `name`.

    Raises:
        ConfigError: no such family.
    """
    row = SENSOR_FAMILIES.get(str(name))
    if row is None:
        raise ConfigError(f"unknown sensor family {name!r}; known: {', '.join(FAMILIES)}")
    return row


def sensor_family(sensor: int) -> str:
    """The family name of global sensor unit `sensor`."""
    if not 0 <= int(sensor) < N_SENSORS:
        raise ConfigError(f"sensor={sensor!r} out of range [0, {N_SENSORS})")
    return FAMILIES[int(sensor) // UNITS_PER_FAMILY]


def family_sensors(name: str) -> range:
    """The global sensor ids of the units of family `name`."""
    family(name)
    k = FAMILIES.index(name)
    return range(k * UNITS_PER_FAMILY, (k + 1) * UNITS_PER_FAMILY)


def unit_index(sensor: int) -> int:
    """The unit's index within its family, [0, UNITS_PER_FAMILY)."""
    return int(sensor) - FAMILIES.index(sensor_family(sensor)) * UNITS_PER_FAMILY


def has_markers(sensor: int) -> bool:
    """Whether unit `sensor` carries a marker grid (the first `marker_units` of its family)."""
    return unit_index(sensor) < family(sensor_family(sensor)).marker_units


# ------------------------------------------------------------------- backgrounds per unit

def _digit_field(unit: int, hw: tuple[int, int]) -> np.ndarray:
    """A DIGIT's no-contact field: a dark neutral gel lit by its three LEDs from three sides,
    each a broad saturated glow (statistics matched to the real DIGIT frames of
    `shared/data/reference_tactile`: mean about (99, 105, 99) of 255, per-channel spread about
    (43, 18, 22), red strongest)."""
    rng = np.random.default_rng([7919, unit])
    h, w = hw
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xs / w - 0.5, ys / h - 0.5
    img = np.zeros((h, w, 3), np.float32) + np.array([0.16, 0.22, 0.2]) * rng.uniform(0.9, 1.1, 3)
    strength = (0.62, 0.42, 0.36)
    for (d, colour), k, s in zip(DIGIT_LIGHTS, rng.uniform(0.8, 1.2, 3), strength):
        # each LED glows broadly on the side it sits on, fading across the gel
        cx, cy = d[0] * 0.5 + rng.uniform(-0.08, 0.08), d[1] * 0.5 + rng.uniform(-0.08, 0.08)
        fall = np.exp(-(((u - cx) ** 2) / 0.18 + ((v - cy) ** 2) / 0.3))
        img += s * k * fall[..., None] * colour
    vignette = 1 - 0.3 * (u ** 2 + v ** 2)
    img *= vignette[..., None]
    return np.clip(img, 0, 1)


def _taxim_field(row: SensorFamily, rng: np.random.Generator, hw: tuple[int, int]
                 ) -> np.ndarray:
    """The calibration's real no-contact frame, turned to the world's orientation, with this
    unit's own colour gains and a faint illumination gradient (units differ as real ones do:
    another gel, another LED batch)."""
    from ratouch.world.taxim_optics import optics  # the calibration loads on first use

    h, w = hw
    o = optics(str(row.calibration))
    bg = o.background_at((w, h)).transpose(1, 0, 2) if row.landscape else o.background_at(hw)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    a = rng.uniform(0, 2 * np.pi)
    slope = rng.uniform(0.0, 0.06)
    grad = 1 + slope * ((xs / w - 0.5) * np.cos(a) + (ys / h - 0.5) * np.sin(a))
    gains = rng.uniform(0.95, 1.05, 3).astype(np.float32)
    return np.clip(bg * gains * grad[..., None], 0, 1).astype(np.float32)


#: How a unit's field is made, by a row's `background`: (row, unit index, rng, hw) -> field.
BACKGROUND_SOURCES: dict[str, Callable[..., np.ndarray]] = {
    "leds": lambda row, unit, rng, hw: _digit_field(unit, hw),
    "taxim": lambda row, unit, rng, hw: _taxim_field(row, rng, hw),
}


def unit_field(sensor: int, hw: tuple[int, int]) -> np.ndarray:
    """The gel field (no markers) of unit `sensor` at frame size `hw` (h, w), float [0, 1]."""
    name = sensor_family(sensor)
    row = family(name)
    rng = np.random.default_rng([7919, FAMILIES.index(name), unit_index(sensor), 2])
    return BACKGROUND_SOURCES[row.background](row, unit_index(sensor), rng, hw)


# ----------------------------------------------------------------- which family a frame is

def canonical(frame: np.ndarray) -> np.ndarray:
    """A frame turned to the world's portrait orientation (a landscape frame is transposed:
    the sensor read as if mounted turned by 90 degrees, its aspect kept)."""
    return frame.transpose(1, 0, 2) if frame.shape[1] > frame.shape[0] else frame


def _look(frame: np.ndarray) -> np.ndarray:
    """What tells sensor families apart in a frame: the chromaticity of its mean colour, how
    much the chromaticity varies over the gel, and its brightness (6 numbers)."""
    from ratouch.images import resize_array

    f = resize_array(np.ascontiguousarray(canonical(frame)), (18, 24)).astype(np.float64) / 255
    total = f.sum(2, keepdims=True) + 1e-3
    chroma = (f / total)[..., :2]  # (h, w, 2): red and green shares
    return np.r_[chroma.mean((0, 1)), chroma.std((0, 1)), f.mean(), f.mean(2).std()]


@lru_cache(maxsize=1)
def _family_looks() -> tuple[np.ndarray, np.ndarray]:
    """(families, 6) mean looks of each family's unit backgrounds, and the looks' spread."""
    looks: dict[str, list[np.ndarray]] = {n: [] for n in FAMILIES}
    for s in range(N_SENSORS):
        field = (unit_field(s, (128, 96)) * 255 + 0.5).astype(np.uint8)
        looks[sensor_family(s)].append(_look(field))
    centres = np.stack([np.mean(looks[n], 0) for n in FAMILIES])
    spread = np.concatenate([np.asarray(looks[n]) - c for n, c in zip(FAMILIES, centres)])
    scale = np.maximum(spread.std(0), 0.01)
    return centres, scale


#: Beyond this `guess_family` distance a frame looks like none of the families' units: the 99th
#: percentile of the distances of 1,200 validation renders (train[1000000:1000600] of world
#: seed 0, each with and without contact; all 1,200 named their own family).
LOOK_LIMIT = 1.66


def guess_family(frame: np.ndarray) -> tuple[str, float]:
    """The sensor family a frame (uint8 RGB) most looks like, from its colours alone, and how
    far it is from that family's units (in units of their spread; large: a guess at best)."""
    centres, scale = _family_looks()
    d = np.sqrt((((_look(frame) - centres) / scale) ** 2).mean(1))
    k = int(np.argmin(d))
    return FAMILIES[k], float(d[k])

"""Tactile sensor families: one table, a row per family.

A row says everything the rest of the code needs to know about a family: how its frames are
rendered (the world's photometric shader, or Taxim's optics calibrated on real presses), where
its units' no-contact backgrounds come from (a key of :data:`BACKGROUND_SOURCES`, with the
row's own lights and gel), how many of its units carry marker dots, the real sensor's frame
size, its per-frame variation, and the real frames it is compared with. Adding a family is
adding a row to :data:`SENSOR_FAMILIES` (or :func:`register_family` at run time); an unknown
family name is an error (:func:`family`), never another family's gel. Everything derived
from the table is computed from it when asked: the family names and unit count, which family
a frame looks like (:func:`guess_family`), and the table's digest (:func:`table_digest`),
which names cached renders (`world.tactile.touch_version`).

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

import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from ratouch.errors import ConfigError
from ratouch.images import resize_array
from ratouch.world.taxim_optics import optics  # a calibration loads on its first use

UNITS_PER_FAMILY = 8
#: Renderers a family row may name.
RENDERERS = ("shader", "taxim")

#: A light: its direction (x right, y down, z out of the gel) and its colour (RGB).
Light = tuple[tuple[float, float, float], tuple[float, float, float]]

# Red, green and blue LEDs 120 degrees apart around the gel, as on a DIGIT.
DIGIT_LIGHTS: tuple[Light, ...] = (
    ((-0.85, 0.0, 0.53), (1.0, 0.25, 0.2)),
    ((0.43, -0.74, 0.53), (0.2, 1.0, 0.3)),
    ((0.43, 0.74, 0.53), (0.25, 0.3, 1.0)),
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

    lights: tuple[Light, ...]
    gain: float  # strength of the contact shading
    darken: float  # how much the pressed gel darkens
    texture: float  # gain of the pressed texture against the indentation's dome


@dataclass(frozen=True)
class LedGel:
    """A shader family's no-contact gel (background "leds"): a dark base lit by the row's
    shader lights, each a broad glow on the side its LED sits on, fading across the gel.

    Attributes:
        base: the unlit gel's colour ([0, 1] RGB).
        glow: each light's glow strength, in the order of the shader's lights.
        seed: first seed word of the units' jitter (a family takes a seed of its own, so that
            its units are not another family's recoloured).
        vignette: darkening towards the corners.
    """

    base: tuple[float, float, float]
    glow: tuple[float, ...]
    seed: int
    vignette: float = 0.3


@dataclass(frozen=True)
class RealFrames:
    """Real frames of a family's sensor that renders are compared with (`ratouch eval
    sensors`, `eval frames`): files in the reference folder (`eval.photos.reference_dir`).

    Attributes:
        pressed: a frame with something pressed into the gel.
        background: a no-contact frame of the same kind of sensor.
        note: what the pair is, said beside every figure made from it.
    """

    pressed: str
    background: str
    note: str


@dataclass(frozen=True)
class SensorFamily:
    """One row of the sensor table.

    Attributes:
        name: the family's name ("digit", ...), as frames and the API name it.
        title: a plain name for people.
        renderer: "shader" (the world's photometric shader, `shader` set) or "taxim"
            (Taxim's optics with `calibration`).
        background: how a unit's no-contact field is made, a key of
            :data:`BACKGROUND_SOURCES`: "leds" (the row's shader lights glowing on its `gel`)
            or "taxim" (the calibration's real no-contact frame, varied per unit).
        marker_units: how many of the family's units carry a marker grid.
        native_hw: the real sensor's frame size (h, w).
        variation: per-frame variation.
        shader: the shader's lights and gains (renderer "shader").
        calibration: Taxim's calibration folder (renderer "taxim").
        press_mm: indentation of a full press, mm (renderer "taxim").
        gel: the unlit gel and the lights' glow (background "leds").
        reference: real frames of this kind of sensor to compare renders with, beside the
            calibration's own real presses (a Taxim row); None: no real frames.
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
    gel: LedGel | None = None
    reference: RealFrames | None = None

    def __post_init__(self) -> None:
        if self.renderer not in RENDERERS:
            raise ConfigError(f"sensor family {self.name!r}: renderer={self.renderer!r} must "
                              f"be one of {RENDERERS}")
        if self.background not in BACKGROUND_SOURCES:
            raise ConfigError(f"sensor family {self.name!r}: background={self.background!r} "
                              f"must be one of {sorted(BACKGROUND_SOURCES)}")
        if self.background == "leds" and (self.shader is None or self.gel is None
                                          or len(self.gel.glow) != len(self.shader.lights)):
            raise ConfigError(f"sensor family {self.name!r}: an 'leds' background needs a "
                              "shader and a gel with one glow per light")
        if self.background == "taxim" and self.calibration is None:
            raise ConfigError(f"sensor family {self.name!r}: a 'taxim' background needs a "
                              "calibration")
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


# ------------------------------------------------------- where a unit's background comes from

def _led_field(row: SensorFamily, unit: int, hw: tuple[int, int]) -> np.ndarray:
    """A shader family's no-contact field: its gel's dark base lit by the row's lights from
    their sides, each a broad glow in the light's colour (the DIGIT's: three LEDs)."""
    assert row.shader is not None and row.gel is not None  # the row's check
    gel = row.gel
    rng = np.random.default_rng([gel.seed, unit])
    h, w = hw
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xs / w - 0.5, ys / h - 0.5
    img = np.zeros((h, w, 3), np.float32) + np.array(gel.base) * rng.uniform(0.9, 1.1, 3)
    lights = row.shader.lights
    for (d, colour), k, s in zip(lights, rng.uniform(0.8, 1.2, len(lights)), gel.glow):
        # each LED glows broadly on the side it sits on, fading across the gel
        cx, cy = d[0] * 0.5 + rng.uniform(-0.08, 0.08), d[1] * 0.5 + rng.uniform(-0.08, 0.08)
        fall = np.exp(-(((u - cx) ** 2) / 0.18 + ((v - cy) ** 2) / 0.3))
        img += s * k * fall[..., None] * np.asarray(colour)
    vignette = 1 - gel.vignette * (u ** 2 + v ** 2)
    img *= vignette[..., None]
    return np.clip(img, 0, 1)


def _taxim_field(row: SensorFamily, unit: int, hw: tuple[int, int]) -> np.ndarray:
    """The calibration's real no-contact frame, turned to the world's orientation, with this
    unit's own colour gains and a faint illumination gradient (units differ as real ones do:
    another gel, another LED batch)."""
    rng = np.random.default_rng([7919, family_names().index(row.name), unit, 2])
    h, w = hw
    o = optics(str(row.calibration))
    bg = o.background_at((w, h)).transpose(1, 0, 2) if row.landscape else o.background_at(hw)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    a = rng.uniform(0, 2 * np.pi)
    slope = rng.uniform(0.0, 0.06)
    grad = 1 + slope * ((xs / w - 0.5) * np.cos(a) + (ys / h - 0.5) * np.sin(a))
    gains = rng.uniform(0.95, 1.05, 3).astype(np.float32)
    return np.clip(bg * gains * grad[..., None], 0, 1).astype(np.float32)


#: How a unit's field is made, by a row's `background`: (row, unit index within the family,
#: (h, w)) -> float (h, w, 3) field in [0, 1]. Each source seeds its own units from the row, so
#: that a unit's field is fixed. A new kind of gel is a function added here (and the fields
#: its rows need, checked in `SensorFamily.__post_init__`).
BACKGROUND_SOURCES: dict[str, Callable[[SensorFamily, int, tuple[int, int]], np.ndarray]] = {
    "leds": _led_field,
    "taxim": _taxim_field,
}


# ------------------------------------------------------------------------ the table

SENSOR_FAMILIES: dict[str, SensorFamily] = {row.name: row for row in (
    SensorFamily(
        name="digit", title="DIGIT", renderer="shader", background="leds", marker_units=0,
        native_hw=(320, 240),
        variation=Variation(blur=(0.5, 1.1), noise=(0.006, 0.015), gain_jitter=0.12,
                            turn_jitter=8.0, tint_jitter=0.06, vignette=(0.1, 0.4)),
        shader=Shader(DIGIT_LIGHTS, gain=0.55, darken=0.12, texture=1.0),
        # statistics matched to the real DIGIT frames of `shared/data/reference_tactile`:
        # mean about (99, 105, 99) of 255, per-channel spread about (43, 18, 22), red strongest
        gel=LedGel(base=(0.16, 0.22, 0.2), glow=(0.62, 0.42, 0.36), seed=7919),
        reference=RealFrames("digit_aurova_digit_raw.png", "digit_tacto_bg_digit_240_320.png",
                             "the reference DIGIT press against another unit's (tacto) "
                             "background"),
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


def family_names() -> tuple[str, ...]:
    """The families' names, in table order."""
    return tuple(SENSOR_FAMILIES)


def sensor_count() -> int:
    """Distinct sensor units over all families, each with its own background."""
    return len(SENSOR_FAMILIES) * UNITS_PER_FAMILY


def register_family(row: SensorFamily) -> None:
    """Add a family at the end of the table (its units get the next global sensor ids).

    Raises:
        ConfigError: if the name is taken.
    """
    if row.name in SENSOR_FAMILIES:
        raise ConfigError(f"sensor family {row.name!r} is already registered")
    SENSOR_FAMILIES[row.name] = row


def table_digest() -> str:
    """A digest of what the table renders: every row's fields but its title and press
    contrast (which the tactile encoder reads, not the renderer), in table order, and the
    units per family. It changes whenever a row that renders differently is added, removed or
    edited."""
    return _digest(tuple(SENSOR_FAMILIES.values()))


@lru_cache(maxsize=8)
def _digest(rows: tuple[SensorFamily, ...]) -> str:
    rendered = [{k: v for k, v in asdict(row).items() if k not in ("title", "press_contrast")}
                for row in rows]
    blob = json.dumps([UNITS_PER_FAMILY, rendered], sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def family(name: str) -> SensorFamily:
    """The table's row of family `name`.

    Raises:
        ConfigError: no such family.
    """
    row = SENSOR_FAMILIES.get(str(name))
    if row is None:
        raise ConfigError(f"unknown sensor family {name!r}; known: "
                          f"{', '.join(family_names())}")
    return row


def sensor_family(sensor: int) -> str:
    """The family name of global sensor unit `sensor`."""
    if not 0 <= int(sensor) < sensor_count():
        raise ConfigError(f"sensor={sensor!r} out of range [0, {sensor_count()})")
    return family_names()[int(sensor) // UNITS_PER_FAMILY]


def family_sensors(name: str) -> range:
    """The global sensor ids of the units of family `name`."""
    family(name)
    k = family_names().index(name)
    return range(k * UNITS_PER_FAMILY, (k + 1) * UNITS_PER_FAMILY)


def unit_index(sensor: int) -> int:
    """The unit's index within its family, [0, UNITS_PER_FAMILY)."""
    return int(sensor) - family_names().index(sensor_family(sensor)) * UNITS_PER_FAMILY


def has_markers(sensor: int) -> bool:
    """Whether unit `sensor` carries a marker grid (the first `marker_units` of its family)."""
    return unit_index(sensor) < family(sensor_family(sensor)).marker_units


# ------------------------------------------------------------------------ units' backgrounds

def unit_field(sensor: int, hw: tuple[int, int]) -> np.ndarray:
    """The gel field (no markers) of unit `sensor` at frame size `hw` (h, w), float [0, 1]."""
    row = family(sensor_family(sensor))
    return BACKGROUND_SOURCES[row.background](row, unit_index(sensor), hw)


# ----------------------------------------------------------------- which family a frame is

def canonical(frame: np.ndarray) -> np.ndarray:
    """A frame turned to the world's portrait orientation (a landscape frame is transposed:
    the sensor read as if mounted turned by 90 degrees, its aspect kept)."""
    return frame.transpose(1, 0, 2) if frame.shape[1] > frame.shape[0] else frame


def _look(frame: np.ndarray) -> np.ndarray:
    """What tells sensor families apart in a frame: the chromaticity of its mean colour, how
    much the chromaticity varies over the gel, and its brightness (6 numbers)."""
    f = resize_array(np.ascontiguousarray(canonical(frame)), (18, 24)).astype(np.float64) / 255
    total = f.sum(2, keepdims=True) + 1e-3
    chroma = (f / total)[..., :2]  # (h, w, 2): red and green shares
    return np.r_[chroma.mean((0, 1)), chroma.std((0, 1)), f.mean(), f.mean(2).std()]


@lru_cache(maxsize=2)
def _family_looks(digest: str) -> tuple[np.ndarray, np.ndarray]:
    """(families, 6) mean looks of each family's unit backgrounds, and the looks' spread:
    computed from the table whose digest is `digest` (so a changed table is measured anew)."""
    names = family_names()
    looks: dict[str, list[np.ndarray]] = {n: [] for n in names}
    for s in range(sensor_count()):
        field = (unit_field(s, (128, 96)) * 255 + 0.5).astype(np.uint8)
        looks[sensor_family(s)].append(_look(field))
    centres = np.stack([np.mean(looks[n], 0) for n in names])
    spread = np.concatenate([np.asarray(looks[n]) - c for n, c in zip(names, centres)])
    scale = np.maximum(spread.std(0), 0.01)
    return centres, scale


#: Beyond this `guess_family` distance a frame looks like none of the families' units: the 99th
#: percentile of the distances of 1,200 validation renders (train[1000000:1000600] of world
#: seed 0, each with and without contact; all 1,200 named their own family).
LOOK_LIMIT = 1.66


#: Beyond this `guess_family` distance a frame lies beyond *every* one of the validation renders
#: :data:`LOOK_LIMIT` was set on (their largest distance, a DIGIT's: 2.603; the GelSight's
#: largest 1.23, the Mini's 0.90). Where a caution may be wrong on 1 % of the world's frames,
#: withholding touch may not (docs/premise.md, "Touch withheld only beyond every validation
#: render").
WITHHOLD_LIMIT = 2.60


def unfamiliar_look(look: tuple[str, float], limit: float = LOOK_LIMIT) -> bool:
    """Whether a `guess_family` answer (family, distance) lies beyond `limit`: by default
    :data:`LOOK_LIMIT`, the frame looks like none of the families' units (the one check every
    reader of it shares); :data:`WITHHOLD_LIMIT` for the rule that withholds its touch."""
    return look[1] > limit


def unfamiliar_view(frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """`frame` (uint8 RGB) as a sensor with colours none of the rendered units has might show
    it: its channels in a random order, each with a gain in 0.6-1.4 and an offset in -30..30
    levels, after a gamma in 0.7-1.4 (the same for all three). What is pressed, and where,
    is kept; only the sensor's look changes."""
    f = (frame.astype(np.float64)[..., rng.permutation(3)] / 255.0) ** rng.uniform(0.7, 1.4)
    f = f * 255.0 * rng.uniform(0.6, 1.4, 3) + rng.uniform(-30.0, 30.0, 3)
    return np.clip(f + 0.5, 0, 255).astype(np.uint8)


def unfamiliar_pair_view(frame: np.ndarray, background: np.ndarray, rng: np.random.Generator
                         ) -> tuple[np.ndarray, np.ndarray]:
    """A frame and its background under one `unfamiliar_view`, the same for both (one sensor,
    recoloured); the view is drawn from `rng`."""
    view = int(rng.integers(2**31))
    return (unfamiliar_view(frame, np.random.default_rng(view)),
            unfamiliar_view(background, np.random.default_rng(view)))


def beyond_every_unit(frame: np.ndarray) -> bool:
    """Whether a frame (uint8 RGB) lies beyond every rendered unit of the sensor families
    (`guess_family` beyond :data:`WITHHOLD_LIMIT`): the frames whose touch the withholding
    systems (`gated`, `fallback`) withhold, and that a colour-blind contact model reads alone."""
    return unfamiliar_look(guess_family(frame), WITHHOLD_LIMIT)


def unfamiliar_views(frames: Sequence[np.ndarray], rng: np.random.Generator
                     ) -> tuple[list[np.ndarray], list[int]]:
    """Each frame under one `unfamiliar_view` (drawn in order from `rng`); the views that lie
    beyond every rendered unit (`beyond_every_unit`) and the indices of their frames."""
    views = [unfamiliar_view(f, rng) for f in frames]
    kept = [i for i, v in enumerate(views) if beyond_every_unit(v)]
    return [views[i] for i in kept], kept


def guess_family(frame: np.ndarray) -> tuple[str, float]:
    """The sensor family a frame (uint8 RGB) most looks like, from its colours alone, and how
    far it is from that family's units (in units of their spread; large: a guess at best)."""
    centres, scale = _family_looks(table_digest())
    d = np.sqrt((((_look(frame) - centres) / scale) ** 2).mean(1))
    k = int(np.argmin(d))
    return family_names()[k], float(d[k])

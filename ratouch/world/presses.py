"""Renders of the presses people make, and of a sensor's drift between two moments.

The world's training frames (`tactile.py`) press a patch of a material firmly into the gel.
The presses people make with a tactile sensor in their hand are other regimes, and this module
renders them with the same sensor families and renderers (`tactile.contact_change`):

* ``flat_face``: a flat face (a book, a box, a table) covering most of the gel, shallow;
* ``fabric``: a towel, denim, a blanket: a broad, shallow, compliant press whose weave or pile
  is the only structure;
* ``foam``: a sponge: broad, compliant, porous;
* ``tape``: a strip of tape: flat and very shallow;
* ``wire``: steel wool: thin wires crossing the gel;
* ``edge``: the edge of a ruler: a straight ridge across the gel;
* ``small_curved``: an egg, a pebble: a small curved cap.

An everyday press is pressed until it meets the gel over the region it covers: its
indentation is measured from the gel's rest surface (`tactile.contact_change`'s `on_gel`),
which matters for the GelSight's domed gel (its rest surface sags 1.4 mm from apex to corner,
so a press 0.03-0.18 mm deep measured from the apex met only the dome's top). A fabric or a
foam wraps the dome so; a rigid flat face would flatten it, which this renders by its texture
alone.

And a **rigid ball** (:func:`render_ball`), kept apart from the everyday kinds: the press
Taxim's calibrations were made with (a steel ball of radius :data:`BALL_MM`; on the GelSight
and Mini at the calibration's pixel size, on the DIGIT in render units as the shader lookup's
fit draws it), so that a fit can be held to what a rigid press reads.

And a sensor's **drift**: the background is captured at one moment and the press at another;
between them each channel's gain and offset change, the illumination field shifts slowly and
the camera adds noise. :func:`measure_drift` measures these on Taxim's real pairs (away from
the touch), :func:`drifted` applies a drawn drift to a frame. The geometry calibration
(`ratouch.train.geometry`) sets its noise floors on blank pairs drifted this way, and
`ratouch eval presses` measures contact on these renders.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.ndimage import gaussian_filter

from ratouch.files import write_json_atomic
from ratouch.paths import cache_dir
from ratouch.world.material import material
from ratouch.world.sensors import family, family_sensors
from ratouch.world.tactile import contact_change, sensor_background
from ratouch.world.texture import make_tile, mip_pyramid, pixel_grid, sample_tile

log = logging.getLogger(__name__)

#: The press regimes, each with the materials that make it (names of the world's materials).
PRESS_KINDS: dict[str, tuple[str, ...]] = {
    "flat_face": ("oak", "matte_plastic", "paper", "glazed_ceramic", "glossy_plastic"),
    "fabric": ("terry_cloth", "denim", "fleece", "wool_knit", "carpet", "cotton_jersey",
               "velvet", "felt", "linen", "corduroy"),
    "foam": ("sponge", "memory_foam"),
    "tape": ("matte_plastic", "paper"),
    "wire": ("brushed_aluminum",),
    "edge": ("oak", "matte_plastic", "polished_metal"),
    "small_curved": ("glazed_ceramic", "glossy_plastic", "polished_marble"),
}
#: Whether a kind's material is soft (for hard-against-soft measures): compliance >= 0.5.
SOFT_AT = 0.5
#: Radius (mm) of the rigid ball Taxim's calibrations were pressed with (Taxim's procedure
#: presses "a small sphere (about 4 mm)"), and the material a rendered ball is named by.
BALL_MM = 2.0
BALL_MATERIAL = "polished_metal"


@dataclass(frozen=True)
class Drift:
    """How a sensor's frame changes between two moments without contact, [0, 1] units.

    Attributes:
        offset_sd: per-channel offset std.
        gain_sd: per-channel relative gain std.
        field_sd: std of a slowly varying illumination change (sigma: an eighth of the
            frame's width).
        noise_sd: per-pixel camera noise std.
    """

    offset_sd: float
    gain_sd: float
    field_sd: float
    noise_sd: float


#: Version of :func:`measure_drift`'s recipe: a drift kept on disk under another version is
#: measured again.
DRIFT_RECIPE = 1


@lru_cache(maxsize=4)
def measure_drift(calibration: str) -> Drift:
    """The drift between a Taxim calibration's real background and its real presses, away
    from each touch (beyond twice its radius): the spread over presses of the per-channel
    offset and gain, the RMS of the slowly varying remainder and of the fine noise.

    Measuring takes about 4-8 s a calibration (the DIGIT's drift reads both), so the four
    figures are kept in the cache folder (`drift/`), named by the calibration file's sha256
    and :data:`DRIFT_RECIPE`, and read from there by later processes (the same floats: JSON
    writes a float's shortest exact form). A kept file that cannot be read is measured
    again; a cache that cannot be written is not an error."""
    from ratouch.world.taxim_optics import calibration_dir

    pack = calibration_dir(calibration) / "dataPack.npz"
    digest = hashlib.sha256(pack.read_bytes()).hexdigest()[:16]
    kept = cache_dir() / "drift" / f"{calibration}-{digest}-r{DRIFT_RECIPE}.json"
    try:
        values = json.loads(kept.read_text(encoding="utf-8"))
        drift = Drift(**{k: float(v) for k, v in values.items()})
        if all(np.isfinite(v) and v >= 0 for v in dataclasses.astuple(drift)):
            return drift
    except (OSError, ValueError, TypeError, AttributeError):
        pass
    drift = _measured_drift(calibration)
    try:
        write_json_atomic(kept, dataclasses.asdict(drift))
    except OSError as e:
        log.info("drift of %s not kept in the cache (%s): measured again next time",
                 calibration, e)
    return drift


def _measured_drift(calibration: str) -> Drift:
    """:func:`measure_drift`'s figures, measured on the calibration's real pairs."""
    from ratouch.world.taxim_optics import real_presses

    rp = real_presses(calibration)
    bg = rp["background"].astype(np.float64) / 255
    h, w = bg.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    offs, gains, fields, noise = [], [], [], []
    for f, c, r in zip(rp["frames"], rp["centres"], rp["radii"]):
        far = np.hypot(xx - c[0], yy - c[1]) > 2 * r
        f = f.astype(np.float64) / 255
        d = f - bg
        offs.append(d[far].mean(0))
        gains.append([np.median(f[..., k][far] / np.maximum(bg[..., k][far], 1e-3))
                      for k in range(3)])
        low = gaussian_filter(d, (w / 32, w / 32, 0))
        fields.append((low[far] - low[far].mean(0)).std(0))
        fine = d - gaussian_filter(d, (1.5, 1.5, 0))
        noise.append(fine[far].std(0))
    return Drift(offset_sd=float(np.std(offs, 0).mean()), gain_sd=float(np.std(gains, 0).mean()),
                 field_sd=float(np.mean(fields)), noise_sd=float(np.mean(noise)))


@lru_cache(maxsize=4)
def family_drift(name: str) -> Drift:
    """A family's drift: measured on its Taxim calibration's real pairs; a family without
    one (the DIGIT) takes the larger of the two measured (the GelSight's)."""
    row = family(name)
    if row.calibration is not None:
        return measure_drift(str(row.calibration))
    return max((measure_drift(c) for c in ("gelsight", "gelsight_mini")),
               key=lambda d: d.field_sd + d.offset_sd)


def drifted(frame: np.ndarray, drift: Drift, rng: np.random.Generator) -> np.ndarray:
    """`frame` (float [0, 1], (H, W, 3)) as the sensor would show it at another moment."""
    h, w = frame.shape[:2]
    gain = 1 + rng.normal(0, drift.gain_sd, 3)
    offset = rng.normal(0, drift.offset_sd, 3)
    field = gaussian_filter(rng.standard_normal((h, w, 3)), (w / 8, w / 8, 0))
    field = field / (field.std() + 1e-12) * drift.field_sd * rng.uniform(0.3, 1.0)
    out = frame * gain + offset + field + rng.normal(0, drift.noise_sd, frame.shape)
    return out


def to_uint8(frame: np.ndarray) -> np.ndarray:
    return (np.clip(frame, 0, 1) * 255 + 0.5).astype(np.uint8)


@dataclass(frozen=True)
class Press:
    """One rendered everyday press: the frame, its unit's background captured at another
    moment (both uint8), and what was pressed."""

    frame: np.ndarray
    background: np.ndarray
    kind: str
    material: str
    family: str
    soft: bool
    depth: float  # peak indentation, gel-thickness units


@lru_cache(maxsize=64)
def _pyramid(name: str) -> list:
    return mip_pyramid(make_tile(material(name).feel.pattern))


def _surface(kind: str, name: str, rng: np.random.Generator, hw: tuple[int, int]
             ) -> np.ndarray:
    """The indentation (gel-thickness units, (H, W)) of one press of `kind`."""
    h, w = hw
    ys, xs = pixel_grid(h, w)
    mat = material(name)
    k = mat.feel.compliance
    tex = sample_tile(_pyramid(name), hw, float(rng.uniform(0.8, 1.2)) * 96 / w,
                      float(rng.uniform(0, 360)), tuple(rng.uniform(0, 256, 2)))
    relief = mat.feel.relief * (1 - 0.4 * k)
    cx, cy = rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h
    if kind in ("flat_face", "fabric", "foam", "tape"):
        # a broad patch, often running off the gel: radius 0.5 .. 1.2 frame widths
        radius = w * rng.uniform(0.5, 1.2)
        a = float(rng.uniform(0, np.pi))
        u = ((xs - cx) * np.cos(a) + (ys - cy) * np.sin(a)) / radius
        v = (-(xs - cx) * np.sin(a) + (ys - cy) * np.cos(a)) / (radius * rng.uniform(0.6, 1.0))
        rho = np.sqrt(u * u + v * v)
        edge = 0.1 + 0.4 * k
        inside = np.clip((1 - rho) / edge, 0, 1)
        inside = inside * inside * (3 - 2 * inside)
        depth = {"flat_face": rng.uniform(0.05, 0.3), "fabric": rng.uniform(0.05, 0.3),
                 "foam": rng.uniform(0.1, 0.4), "tape": rng.uniform(0.02, 0.08)}[kind]
        texture = {"tape": 0.2, "flat_face": 1.0}.get(kind, 1.6)
        return depth * inside * (1 + texture * 2.2 * relief * (tex - 0.5))
    if kind == "wire":
        z = np.zeros(hw, np.float64)
        depth = rng.uniform(0.1, 0.4)
        for _ in range(int(rng.integers(8, 25))):
            # a wire: a smooth random curve, a tube about a pixel wide
            t = np.linspace(0, 1, 60)
            p0 = rng.uniform(0, 1, 2) * (w, h)
            bend = rng.normal(0, 0.3, (3, 2)) * (w, h)
            pts = p0 + np.outer(t, bend[0]) + np.outer(t * t, bend[1]) + np.outer(t ** 3, bend[2])
            thick = rng.uniform(0.6, 1.5) * w / 96
            for px, py in pts:
                d2 = (xs - px) ** 2 + (ys - py) ** 2
                z = np.maximum(z, np.exp(-d2 / (2 * thick * thick)))
        return depth * z
    if kind == "edge":
        a = float(rng.uniform(0, np.pi))
        d = (xs - cx) * np.cos(a) + (ys - cy) * np.sin(a)
        width = rng.uniform(1.5, 5.0) * w / 96  # a rounded edge a few pixels wide
        depth = rng.uniform(0.2, 0.7)
        ridge = np.sqrt(np.clip(1 - (d / width) ** 2, 0, 1))
        return depth * ridge * (1 + 0.5 * relief * (tex - 0.5))
    if kind == "small_curved":
        r = w * rng.uniform(0.12, 0.3)
        ax = rng.uniform(0.7, 1.0)
        rho2 = ((xs - cx) / r) ** 2 + ((ys - cy) / (r * ax)) ** 2
        depth = rng.uniform(0.3, 0.8)
        return depth * np.sqrt(np.clip(1 - rho2, 0, 1))
    raise ValueError(f"unknown press kind {kind!r}; known: {', '.join(PRESS_KINDS)}")


def render_press(family_name: str, rng: np.random.Generator, kind: str | None = None,
                 hw: tuple[int, int] = (128, 96)) -> Press:
    """One everyday press on a random unit of `family_name` (kind and material drawn when
    not given), with its background captured at another moment (drifted, `family_drift`)."""
    kind = str(rng.choice(list(PRESS_KINDS))) if kind is None else kind
    name = str(rng.choice(list(PRESS_KINDS[kind])))
    return _pressed(family_name, rng, kind, name, lambda: _surface(kind, name, rng, hw), hw,
                    on_gel=True)


def _pressed(family_name: str, rng: np.random.Generator, kind: str, name: str,
             surface: Callable[[], np.ndarray], hw: tuple[int, int], on_gel: bool = False
             ) -> Press:
    """A press of the indentation `surface()` draws, on a random unit of `family_name`, with
    its background captured at another moment. `on_gel`: the indentation is measured from the
    gel's rest surface (an everyday press meets a domed gel wherever it covers it), else from
    its apex (a rigid ball, as Taxim's calibration presses were made)."""
    sensor = int(rng.choice(list(family_sensors(family_name))))
    bg = sensor_background(sensor, hw).astype(np.float64)
    z = surface()
    change = gaussian_filter(contact_change(sensor, z, on_gel=on_gel).astype(np.float64),
                             (0.7, 0.7, 0))
    drift = family_drift(family_name)
    frame = drifted(bg + change, drift, rng)
    later = drifted(bg, drift, rng)
    return Press(to_uint8(frame), to_uint8(later), kind, name, family_name,
                 material(name).feel.compliance >= SOFT_AT, float(z.max()))


def _ball_surface(family_name: str, rng: np.random.Generator, hw: tuple[int, int]
                  ) -> np.ndarray:
    """The indentation (gel-thickness units, (H, W)) of a rigid ball pressed in: a spherical
    cap whose contact radius is 0.5-0.95 of the ball's. GelSight, Mini: a ball of
    :data:`BALL_MM` at the calibration's pixel size (the frame's long side spans the sensor's);
    DIGIT: contact radius 0.12-0.35 of the frame's width in render units (as the shader
    lookup's fit draws its balls)."""
    from ratouch.world.tactile import _SHADER_RELIEF  # the shader's height scale
    from ratouch.world.taxim_optics import optics

    h, w = hw
    ys, xs = pixel_grid(h, w)
    cx, cy = rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h
    share = float(rng.uniform(0.5, 0.95))  # contact radius / ball radius
    row = family(family_name)
    if row.renderer == "taxim":
        o = optics(str(row.calibration))
        mm_per_px = o.pixmm * max(o.hw) / max(hw)
        ball = BALL_MM / mm_per_px
        per_px = mm_per_px / row.press_mm  # gel-thickness units per pixel of height
    else:
        ball = float(rng.uniform(0.12, 0.35)) * w / share
        per_px = 1.0 / _SHADER_RELIEF
    r = share * ball
    d2 = (xs - cx) ** 2 + (ys - cy) ** 2
    cap = np.where(d2 < r * r, np.sqrt(np.maximum(ball * ball - d2, 0.0))
                   - np.sqrt(ball * ball - r * r), 0.0)
    return cap * per_px


def render_ball(family_name: str, rng: np.random.Generator, hw: tuple[int, int] = (128, 96)
                ) -> Press:
    """A rigid ball (:data:`BALL_MM`, named :data:`BALL_MATERIAL`, hard) pressed on a random
    unit of `family_name`, with its background captured at another moment."""
    return _pressed(family_name, rng, "ball", BALL_MATERIAL,
                    lambda: _ball_surface(family_name, rng, hw), hw)


def render_presses(family_name: str, rng: np.random.Generator, per_kind: int,
                   hw: tuple[int, int] = (128, 96)) -> list[Press]:
    """`per_kind` presses of every kind (`PRESS_KINDS`, in its order) on `family_name`."""
    return [render_press(family_name, rng, kind, hw) for kind in PRESS_KINDS
            for _ in range(per_kind)]


def render_blank_pair(family_name: str, rng: np.random.Generator,
                      hw: tuple[int, int] = (128, 96)) -> tuple[np.ndarray, np.ndarray]:
    """A no-contact frame and its unit's background, captured at two moments (uint8)."""
    sensor = int(rng.choice(list(family_sensors(family_name))))
    bg = sensor_background(sensor, hw).astype(np.float64)
    drift = family_drift(family_name)
    return to_uint8(drifted(bg, drift, rng)), to_uint8(drifted(bg, drift, rng))


def render_cross_unit_pair(family_name: str, rng: np.random.Generator,
                           hw: tuple[int, int] = (128, 96)) -> tuple[np.ndarray, np.ndarray]:
    """A no-contact frame of one unit of `family_name` and the background of another unit of
    the same family (uint8), each drifted as `render_blank_pair`'s are: a user who gives the
    wrong unit's no-contact frame."""
    one, other = (int(s) for s in rng.choice(list(family_sensors(family_name)), 2,
                                              replace=False))
    drift = family_drift(family_name)
    return tuple(to_uint8(drifted(sensor_background(s, hw).astype(np.float64), drift, rng))
                 for s in (one, other))  # type: ignore[return-value]

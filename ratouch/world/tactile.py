"""Tactile frames rendered like real vision-based tactile sensors of three families.

The gel is pressed by the contacted material: the indentation (a contact patch whose area and
edge softness come from the material's compliance and the force) plus the material's micro
height-map (attenuated by compliance) give a surface; its normals are shaded by the sensor's
coloured lights (photometric shading) over the sensor unit's own background image, then gel
blur and sensor noise are applied. A no-contact frame is the unit's background plus noise.

Sensor families (:data:`FAMILIES`), each with :data:`UNITS_PER_FAMILY` units; a unit's index
is the global sensor id (`TactilePlan.sensor`, `sensor_{k}.png` of the TVL layout):

* ``digit``: a DIGIT. Red, green and blue LEDs 120 degrees apart light a bluish-grey gel;
  contact shows as strong colour shifts that follow the surface normals (high contrast).
* ``gelsight``: a GelSight as in Touch and Go. A bright grey-white gel lit low from four sides
  with a regular grid of small dark marker dots; in contact the dots move outwards along the
  indentation's slope and with a small shear, and the side lighting shows the texture.
* ``mini``: a GelSight Mini. A vignetted teal-to-violet gel; contact is faint: about 2-5 of
  255 mean absolute change over the frame, 99th percentile of the change about 12-23, as
  measured on real presses. No markers.

Each unit's background (tint, lighting, vignette, marker grid) is fixed; what varies from
frame to frame (light strength and direction, tint and vignetting of the contact shading,
blur, noise, a small global brightness drift, marker shear and jitter) is drawn from the
plan's `render_seed`, never from the shared plan generator, so that adding sensor families
left every other part of a sample byte-identical.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np
from scipy.ndimage import gaussian_filter

from ratouch.errors import ConfigError
from ratouch.world.config import WorldConfig
from ratouch.world.material import Material, material
from ratouch.world.texture import PatternSpec, pixel_grid, sample_tile

FAMILIES = ("digit", "gelsight", "mini")
UNITS_PER_FAMILY = 8
N_SENSORS = len(FAMILIES) * UNITS_PER_FAMILY  # distinct sensor units, each with its background

#: the bound of the shared plan generator's sensor draw before sensor families existed (4
#: units); `plan_tactile` still makes that draw so that the generator's stream is unchanged
_LEGACY_SENSOR_DRAW = 4
#: second seed word of the per-frame generator derived from `render_seed`
_FRAME_STREAM = 17

# Light directions (x right, y down, z out of the gel) and colours: red, green, blue LEDs
# 120 degrees apart around the gel, as on a DIGIT.
_LIGHTS = (
    (np.array([-0.85, 0.0, 0.53]), np.array([1.0, 0.25, 0.2])),
    (np.array([0.43, -0.74, 0.53]), np.array([0.2, 1.0, 0.3])),
    (np.array([0.43, 0.74, 0.53]), np.array([0.25, 0.3, 1.0])),
)
# GelSight (Touch and Go): four LEDs low on the four sides, so slopes show strongly
_GELSIGHT_LIGHTS = (
    (np.array([-0.93, 0.0, 0.37]), np.array([1.0, 0.45, 0.4])),
    (np.array([0.93, 0.0, 0.37]), np.array([0.4, 1.0, 0.5])),
    (np.array([0.0, -0.93, 0.37]), np.array([0.45, 0.5, 1.0])),
    (np.array([0.0, 0.93, 0.37]), np.array([0.8, 0.8, 0.6])),
)
# GelSight Mini: three LEDs, a diffuse gel; shading is faint
_MINI_LIGHTS = (
    (np.array([-0.8, -0.3, 0.52]), np.array([0.9, 0.4, 1.0])),
    (np.array([0.8, -0.3, 0.52]), np.array([0.3, 1.0, 0.9])),
    (np.array([0.0, 0.85, 0.52]), np.array([0.6, 0.5, 1.0])),
)


@dataclass(frozen=True)
class _Family:
    lights: tuple
    gain: float  # strength of the contact shading
    darken: float  # how much the pressed gel darkens
    texture: float  # gain of the pressed texture against the indentation's dome
    blur: tuple[float, float]  # per-frame gel blur sigma range, pixels at 96 px width
    noise: tuple[float, float]  # per-frame noise std range
    gain_jitter: float  # per-frame light strength factor: 1 +- this
    turn_jitter: float  # per-frame rotation of the lights, degrees
    tint_jitter: float  # per-frame per-channel tint of the contact shading
    vignette: tuple[float, float]  # per-frame vignetting of the contact shading


_FAMILY = {
    "digit": _Family(_LIGHTS, gain=0.55, darken=0.12, texture=1.0, blur=(0.5, 1.1),
                     noise=(0.006, 0.015), gain_jitter=0.12, turn_jitter=8.0,
                     tint_jitter=0.06, vignette=(0.1, 0.4)),
    "gelsight": _Family(_GELSIGHT_LIGHTS, gain=0.2, darken=0.05, texture=1.8, blur=(0.4, 0.9),
                        noise=(0.004, 0.010), gain_jitter=0.15, turn_jitter=10.0,
                        tint_jitter=0.08, vignette=(0.1, 0.4)),
    "mini": _Family(_MINI_LIGHTS, gain=0.11, darken=0.025, texture=1.0, blur=(0.7, 1.3),
                    noise=(0.006, 0.011), gain_jitter=0.2, turn_jitter=12.0,
                    tint_jitter=0.1, vignette=(0.5, 0.9)),
}
#: global brightness drift between a frame and its unit's background, relative, per unit of
#: noise std (so that a noise-free frame of no contact is exactly the background)
_DRIFT_PER_NOISE = 0.6


def sensor_family(sensor: int) -> str:
    """The family ("digit", "gelsight" or "mini") of global sensor unit `sensor`."""
    if not 0 <= int(sensor) < N_SENSORS:
        raise ConfigError(f"sensor={sensor!r} out of range [0, {N_SENSORS})")
    return FAMILIES[int(sensor) // UNITS_PER_FAMILY]


def family_sensors(family: str) -> range:
    """The global sensor ids of the units of `family`."""
    if family not in FAMILIES:
        raise ConfigError(f"family={family!r} must be one of {FAMILIES}")
    k = FAMILIES.index(family)
    return range(k * UNITS_PER_FAMILY, (k + 1) * UNITS_PER_FAMILY)


@dataclass(frozen=True)
class TactilePlan:
    material: str
    sensor: int  # global sensor unit id, [0, N_SENSORS)
    contact: bool
    centre: tuple[float, float]  # fraction of (width, height)
    force: float  # 0.4 .. 1
    axes: tuple[float, float]  # contact ellipse aspect factors
    ellipse_angle: float
    texture_angle: float  # includes the stress rotation
    texture_offset: tuple[float, float]
    texture_step: float
    blur: float  # gel blur sigma of the contact shading, pixels
    noise: float
    render_seed: int
    #: blur the whole frame, background and markers too (the `tactile_blur` stress knob: a
    #: degraded sensor), not only the contact shading
    blur_frame: bool = False
    # per-frame sensor randomisation, drawn from `render_seed` (defaults: none)
    light_gain: float = 1.0  # strength of the lights
    light_turn: float = 0.0  # rotation of the lights about the gel normal, degrees
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)  # colour of the contact shading
    vignette: float = 0.0  # fall-off of the contact shading towards the corners
    drift: float = 0.0  # relative global brightness change against the background
    shear: tuple[float, float] = (0.0, 0.0)  # marker shear inside the contact, pixels
    marker_jitter: float = 0.0  # std of irregular marker motion inside the contact, pixels

    @property
    def family(self) -> str:
        return sensor_family(self.sensor)


# ------------------------------------------------------------------------------- sensor units

@dataclass(frozen=True)
class SensorUnit:
    """What is fixed for one sensor unit: its gel field (no markers), marker grid and the
    background image (the field with the markers), float32 in [0, 1]."""

    sensor: int
    family: str
    field: np.ndarray  # (H, W, 3)
    background: np.ndarray  # (H, W, 3)
    markers: np.ndarray  # (N, 2) marker centres (x, y), pixels; (0, 2) without markers
    marker_radius: float
    marker_darkness: float


def _digit_field(unit: int, hw: tuple[int, int]) -> np.ndarray:
    # the renderer's original sensor backgrounds: digit units 0..3 are the former sensors 0..3
    rng = np.random.default_rng([7919, unit])
    h, w = hw
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xs / w - 0.5, ys / h - 0.5
    img = np.zeros((h, w, 3), np.float32) + np.array([0.36, 0.38, 0.50]) * rng.uniform(0.9, 1.1, 3)
    for (d, colour), k in zip(_LIGHTS, rng.uniform(0.8, 1.2, 3)):
        # each LED brightens the side it sits on, fading across the gel
        fall = np.exp(-(((u - d[0] * 0.55) ** 2) / 0.12 + ((v - d[1] * 0.55) ** 2) / 0.2))
        img += 0.32 * k * fall[..., None] * colour
    vignette = 1 - 0.35 * (u ** 2 + v ** 2)
    img *= vignette[..., None]
    return np.clip(img, 0, 1)


def _gelsight_field(rng: np.random.Generator, hw: tuple[int, int]) -> np.ndarray:
    h, w = hw
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xs / w - 0.5, ys / h - 0.5
    base = rng.uniform(0.62, 0.74) * (np.array([1.0, 0.99, 0.97]) * rng.uniform(0.96, 1.04, 3))
    img = np.zeros((h, w, 3), np.float32) + base
    for (d, colour), k in zip(_GELSIGHT_LIGHTS, rng.uniform(0.6, 1.4, 4)):
        # each side LED tints a band along its edge
        side = u * d[0] + v * d[1]  # -0.5 .. 0.5, larger towards the light
        fall = np.exp((side - 0.5) / 0.16)
        img += 0.09 * k * fall[..., None] * (colour - 0.7)
    img *= (1 - rng.uniform(0.12, 0.25) * (u ** 2 + v ** 2) * 2)[..., None]
    return np.clip(img, 0, 1)


def _mini_field(rng: np.random.Generator, hw: tuple[int, int]) -> np.ndarray:
    h, w = hw
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xs / w - 0.5, ys / h - 0.5
    teal = np.array([0.20, 0.60, 0.62]) * rng.uniform(0.92, 1.08, 3)
    violet = np.array([0.50, 0.30, 0.68]) * rng.uniform(0.92, 1.08, 3)
    a = np.deg2rad(rng.uniform(-35, 35) + (180 if rng.random() < 0.5 else 0))  # teal side
    s = np.clip(0.5 + 1.1 * (u * np.cos(a) + v * np.sin(a) * h / w), 0, 1)
    s = s * s * (3 - 2 * s)
    img = teal * s[..., None] + violet * (1 - s[..., None])
    img *= rng.uniform(1.0, 1.15)
    # a soft hot spot from the LEDs and a strong vignette: dark corners
    cx, cy = rng.uniform(-0.1, 0.1, 2)
    img *= (1 + 0.12 * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / 0.05))[..., None]
    r2 = (u / 0.5) ** 2 + (v / 0.5) ** 2  # 1 at the middle of the edges, 2 at the corners
    img *= (1 - rng.uniform(0.22, 0.32) * r2 ** 1.5)[..., None]
    return np.clip(img, 0, 1)


def _marker_grid(rng: np.random.Generator, hw: tuple[int, int]) -> np.ndarray:
    """A regular grid of marker centres (x, y), slightly rotated, clear of the edges."""
    h, w = hw
    cols, rows = int(rng.integers(7, 10)), int(rng.integers(9, 12))
    sx, sy = w / (cols + rng.uniform(0.3, 0.9)), h / (rows + rng.uniform(0.3, 0.9))
    step = min(sx, sy * 1.1)
    gx = (np.arange(cols) - (cols - 1) / 2) * step
    gy = (np.arange(rows) - (rows - 1) / 2) * step * rng.uniform(0.95, 1.05)
    px, py = np.meshgrid(gx, gy)
    a = np.deg2rad(rng.uniform(-2.5, 2.5))
    x = px * np.cos(a) - py * np.sin(a) + w / 2 + rng.uniform(-1.5, 1.5)
    y = px * np.sin(a) + py * np.cos(a) + h / 2 + rng.uniform(-1.5, 1.5)
    pts = np.stack([x.ravel(), y.ravel()], 1)
    pts += rng.normal(0, 0.2, pts.shape)  # hand-made gels are not perfect grids
    keep = (pts[:, 0] > 1.5) & (pts[:, 0] < w - 2.5) & (pts[:, 1] > 1.5) & (pts[:, 1] < h - 2.5)
    return pts[keep].astype(np.float32)


_WIN = np.arange(-3, 4)


def marker_shadow(centres: np.ndarray, radius: float, hw: tuple[int, int]) -> np.ndarray:
    """Coverage (H, W) in [0, 1] of anti-aliased round dots of `radius` at `centres` (x, y)."""
    h, w = hw
    if len(centres) == 0:
        return np.zeros(hw, np.float32)
    ix = np.round(centres[:, 0]).astype(np.int64)[:, None, None] + _WIN[None, None, :]
    iy = np.round(centres[:, 1]).astype(np.int64)[:, None, None] + _WIN[None, :, None]
    d = np.sqrt((ix - centres[:, 0, None, None]) ** 2 + (iy - centres[:, 1, None, None]) ** 2)
    cover = np.clip((radius + 0.6 - d) / 1.2, 0, 1)  # a soft edge: round at 1-2 px radius
    ok = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    ix, iy = np.broadcast_arrays(ix, iy)
    flat = np.bincount((iy[ok] * w + ix[ok]), weights=cover[ok], minlength=h * w)
    return np.minimum(flat, 1.0).reshape(h, w).astype(np.float32)


@lru_cache(maxsize=4 * N_SENSORS)
def sensor_unit(sensor: int, hw: tuple[int, int]) -> SensorUnit:
    """The fixed parts of sensor unit `sensor` at frame size `hw` (cached; read-only)."""
    family = sensor_family(sensor)
    unit = int(sensor) - FAMILIES.index(family) * UNITS_PER_FAMILY
    hw = (int(hw[0]), int(hw[1]))
    rng = np.random.default_rng([7919, FAMILIES.index(family), unit])
    markers, radius, darkness = np.zeros((0, 2), np.float32), 0.0, 0.0
    if family == "digit":
        field = _digit_field(unit, hw)
    elif family == "gelsight":
        field = _gelsight_field(rng, hw)
        markers = _marker_grid(rng, hw)
        scale = hw[1] / 96
        radius, darkness = float(rng.uniform(1.0, 1.5) * scale), float(rng.uniform(0.6, 0.8))
    else:
        field = _mini_field(rng, hw)
    field = field.astype(np.float32)
    background = field
    if len(markers):
        background = field * (1 - darkness * marker_shadow(markers, radius, hw))[..., None]
    for a in (field, background, markers):
        a.setflags(write=False)
    return SensorUnit(int(sensor), family, field, background, markers, radius, darkness)


def sensor_background(sensor: int, hw: tuple[int, int]) -> np.ndarray:
    """The no-contact image of one sensor unit, float32 (H, W, 3) in [0, 1] (read-only)."""
    return sensor_unit(int(sensor), (int(hw[0]), int(hw[1]))).background


# ------------------------------------------------------------------------------------ planning

def plan_tactile(rng: np.random.Generator, cfg: WorldConfig, mat: Material,
                 sensor: int | None = None) -> TactilePlan:
    """Draw a tactile frame's choices. The draws from `rng` (shared with the rest of the
    sample) are exactly those made before sensor families existed; the sensor unit (uniform
    over the units, so the families are equally likely) and all per-frame sensor
    randomisation come from a generator seeded by `render_seed`. `sensor` forces the unit
    (e.g. to render one family); the per-frame draws are then that family's."""
    st = cfg.stress
    contact = st.missing != "tactile" and not (st.no_contact > 0 and rng.random() < st.no_contact)
    base_angle = float(rng.uniform(0, 360))
    rotation = st.tactile_rotation if st.tactile_rotation is not None else 0.0
    rng.integers(_LEGACY_SENSOR_DRAW)  # the former sensor draw, kept for the stream
    cx, cy = rng.uniform(0.4, 0.6, 2)
    centre = (float(cx), float(cy))
    force = float(rng.uniform(0.45, 1.0))
    ax, ay = rng.uniform(0.8, 1.2, 2)
    axes = (float(ax), float(ay))
    ellipse_angle = float(rng.uniform(0, 180))
    ox, oy = rng.uniform(0, 256, 2)
    texture_offset = (float(ox), float(oy))
    texture_step = float(rng.uniform(0.9, 1.1)) * 96 / cfg.tactile_hw[1]
    if st.tactile_blur is None:
        rng.uniform(0.5, 1.1)  # the former blur draw
    if st.tactile_noise is None:
        rng.uniform(0.006, 0.015)  # the former noise draw
    render_seed = int(rng.integers(2**31))

    frame = np.random.default_rng([render_seed, _FRAME_STREAM])
    drawn = int(frame.integers(N_SENSORS))
    sensor = drawn if sensor is None else int(sensor)
    fam = _FAMILY[sensor_family(sensor)]
    scale = cfg.tactile_hw[1] / 96
    blur = float(frame.uniform(*fam.blur)) * scale
    noise = float(frame.uniform(*fam.noise))
    light_gain = float(1 + frame.uniform(-1, 1) * fam.gain_jitter)
    light_turn = float(frame.uniform(-1, 1) * fam.turn_jitter)
    tr, tg, tb = 1 + frame.uniform(-1, 1, 3) * fam.tint_jitter
    tint = (float(tr), float(tg), float(tb))
    vignette = float(frame.uniform(*fam.vignette))
    drift_z = float(np.clip(frame.standard_normal(), -2.5, 2.5))
    sx, sy = frame.normal(0, 0.5, 2) * scale
    shear = (float(sx), float(sy))
    marker_jitter = float(frame.uniform(0.05, 0.25) * scale)
    if st.tactile_blur is not None:
        blur = st.tactile_blur
    if st.tactile_noise is not None:
        noise = st.tactile_noise
    if sensor_family(sensor) != "gelsight":
        shear, marker_jitter = (0.0, 0.0), 0.0
    return TactilePlan(
        material=mat.name, sensor=sensor, contact=contact, centre=centre, force=force,
        axes=axes, ellipse_angle=ellipse_angle, texture_angle=base_angle + rotation,
        texture_offset=texture_offset, texture_step=texture_step, blur=blur, noise=noise,
        render_seed=render_seed, blur_frame=st.tactile_blur is not None,
        light_gain=light_gain, light_turn=light_turn, tint=tint, vignette=vignette,
        drift=_DRIFT_PER_NOISE * noise * drift_z, shear=shear, marker_jitter=marker_jitter)


# ----------------------------------------------------------------------------------- rendering

def gel_surface(plan: TactilePlan, feel_pyramid: list, hw: tuple[int, int],
                dome: bool = False):
    """Indentation depth of the gel, (H, W), in units of gel thickness; with `dome`, also
    the smooth indentation without the texture."""
    mat = material(plan.material)
    k = mat.feel.compliance
    h, w = hw
    ys, xs = pixel_grid(h, w)
    cx, cy = plan.centre[0] * w, plan.centre[1] * h
    # soft materials wrap around the gel: bigger contact patch, softer edge
    radius = w * (0.2 + 0.17 * k) * (0.7 + 0.3 * plan.force)
    a = np.deg2rad(plan.ellipse_angle)
    dx, dy = xs - cx, ys - cy
    u = (dx * np.cos(a) + dy * np.sin(a)) / (radius * plan.axes[0])
    v = (-dx * np.sin(a) + dy * np.cos(a)) / (radius * plan.axes[1])
    rho = np.sqrt(u * u + v * v)
    edge = 0.12 + 0.45 * k
    inside = np.clip((1 - rho) / edge, 0, 1)
    inside = inside * inside * (3 - 2 * inside)  # smoothstep
    depth = 0.5 + 0.5 * plan.force
    tex = sample_tile(feel_pyramid, hw, plan.texture_step, plan.texture_angle, plan.texture_offset)
    relief = mat.feel.relief * (1 - 0.55 * k)
    z = depth * inside + 2.2 * relief * (tex - 0.5) * inside
    return (z, depth * inside) if dome else z


def _light_mix(lights, turn_deg: float) -> np.ndarray:
    """(3, 3) matrix M: the shading change of normal (nx, ny, nz - 1) is n @ M, RGB."""
    t = np.deg2rad(turn_deg)
    c, s = np.cos(t), np.sin(t)
    m = np.zeros((3, 3))
    for d, colour in lights:
        d = d / np.linalg.norm(d)
        d = np.array([d[0] * c - d[1] * s, d[0] * s + d[1] * c, d[2]])
        m += d[:, None] * colour[None, :]
    return m.astype(np.float32)


@lru_cache(maxsize=16)
def _radius2(hw: tuple[int, int]) -> np.ndarray:
    ys, xs = pixel_grid(*hw)
    r2 = ((xs / hw[1] - 0.5) / 0.5) ** 2 + ((ys / hw[0] - 0.5) / 0.5) ** 2
    r2 = (r2 / 2).astype(np.float32)  # 0 centre, 1 corners
    r2.setflags(write=False)
    return r2


def _sample_at(a: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Nearest-pixel values of (H, W) `a` at points (x, y)."""
    h, w = a.shape
    ix = np.clip(np.round(pts[:, 0]).astype(np.int64), 0, w - 1)
    iy = np.clip(np.round(pts[:, 1]).astype(np.int64), 0, h - 1)
    return a[iy, ix]


def render_tactile(plan: TactilePlan, pyramid_fn: Callable[[PatternSpec], list],
                   hw: tuple[int, int], background: np.ndarray) -> np.ndarray:
    """Render a tactile frame, (H, W, 3) uint8: `background` (the unit's no-contact image)
    plus the blurred contact shading, a global brightness drift and sensor noise."""
    hw = (int(hw[0]), int(hw[1]))
    rng = np.random.default_rng(plan.render_seed)
    fam = _FAMILY[plan.family]
    bg = np.asarray(background, np.float32)
    img = bg
    blur = 0.0 if plan.blur_frame else plan.blur
    if plan.contact:
        unit = sensor_unit(plan.sensor, hw)
        mat = material(plan.material)
        z, dome = gel_surface(plan, pyramid_fn(mat.feel.pattern), hw, dome=True)
        if fam.texture != 1.0:
            z = dome + fam.texture * (z - dome)
        z = z * 6.0
        gy, gx = np.gradient(z)
        norm = np.sqrt(gx * gx + gy * gy + 1)
        n = np.stack([-gx / norm, -gy / norm, 1 / norm - 1], -1)  # change against the flat gel
        mix = _light_mix(fam.lights, plan.light_turn)
        mix *= (fam.gain * plan.light_gain) * np.asarray(plan.tint, np.float32)[None, :]
        shade = n @ mix
        if plan.vignette:
            shade *= (1 - plan.vignette * _radius2(hw))[..., None]
        press = (1 - fam.darken * np.clip(z / 6.0, 0, 1))[..., None]  # pressed gel darkens
        if len(unit.markers):
            # markers move outwards along the indentation's slope, with shear and jitter
            dgy, dgx = np.gradient(dome * 6.0)
            at = unit.markers
            inside = np.clip(_sample_at(dome, at) / max(float(dome.max()), 1e-6), 0, 1)
            jit = rng.standard_normal(at.shape).astype(np.float32) * plan.marker_jitter
            move = -2.5 * np.stack([_sample_at(dgx, at), _sample_at(dgy, at)], 1) * (hw[1] / 96)
            move += (np.asarray(plan.shear, np.float32)[None, :] + jit) * inside[:, None]
            cover = marker_shadow((at + move).astype(np.float32), unit.marker_radius, hw)
            dots = (1 - unit.marker_darkness * cover)[..., None]
            # the gel blur softens the shading; the dots are drawn as sharp as the background's
            lit = (unit.field + shade) * press - unit.field
            if blur > 0:
                lit = gaussian_filter(lit, sigma=(blur, blur, 0))
            img = bg + ((unit.field + lit) * dots - unit.background)
        else:
            delta = (bg + shade) * press - bg
            if blur > 0:
                delta = gaussian_filter(delta, sigma=(blur, blur, 0))
            img = bg + delta
    if plan.blur_frame and plan.blur > 0:
        img = gaussian_filter(img, sigma=(plan.blur, plan.blur, 0))
    if plan.drift:
        img = img * np.float32(1 + plan.drift)
    if plan.noise > 0:
        img = img + plan.noise * rng.standard_normal(img.shape, dtype=np.float32)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)

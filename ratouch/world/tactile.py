"""Tactile frames rendered like real vision-based tactile sensors.

The gel is pressed by the contacted material: the indentation (a contact patch whose area and
edge softness come from the material's compliance and the force, shaped by what presses: a
flat face, a sphere or a cylinder, which rigid materials keep and soft ones flatten) plus the
material's micro height-map (attenuated by compliance) give a surface. The sensor family's
row (:mod:`ratouch.world.sensors`) says how it becomes a frame: the world's photometric
shader (normals shaded by coloured lights) or Taxim's optics calibrated on real presses
(:mod:`ratouch.world.taxim_optics`); either way the change is added to the unit's own
background, then gel blur and sensor noise are applied. A no-contact frame is the unit's
background plus noise.

Each unit's background (field, marker grid) is fixed; what varies from frame to frame (light
strength and direction, tint and vignetting of the contact shading, blur, noise, a small
global brightness drift, marker shear and jitter, the pressing shape) is drawn from the plan's
`render_seed`, never from the shared plan generator, so that sensor families left every other
part of a sample byte-identical.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np
from scipy.ndimage import gaussian_filter

from ratouch.world.config import WorldConfig
from ratouch.world.material import Material, material
from ratouch.world.sensors import (
    UNITS_PER_FAMILY,
    family,
    family_names,
    family_sensors,
    has_markers,
    sensor_count,
    sensor_family,
    table_digest,
    unit_field,
    unit_index,
)
from ratouch.world.taxim_optics import optics  # a calibration loads on its first use
from ratouch.world.texture import PatternSpec, pixel_grid, sample_tile

__all__ = ["family_names", "sensor_count", "UNITS_PER_FAMILY", "family_sensors",
           "sensor_family", "TactilePlan", "SensorUnit", "sensor_unit", "sensor_background",
           "plan_tactile", "render_tactile", "gel_surface", "marker_shadow", "touch_version",
           "SHAPES"]

#: Bumped by hand when this module's rendering code changes; what the sensor table renders is
#: in `touch_version` through the table's digest, never bumped by hand.
RENDER_CODE = "touch3"
#: the bound of the shared plan generator's sensor draw before sensor families existed (4
#: units); `plan_tactile` still makes that draw so that the generator's stream is unchanged
_LEGACY_SENSOR_DRAW = 4
#: second seed word of the per-frame generator derived from `render_seed`
_FRAME_STREAM = 17
#: What presses into the gel, with its probability: a flat face (as before shapes existed),
#: a sphere (a ball, a knob, a fingertip-sized bump) or a cylinder (an edge, a rod, a rim).
SHAPES = {"flat": 0.5, "sphere": 0.3, "cylinder": 0.2}
#: Height-map scale of the shader's normals (the gel's thickness in pixel units).
_SHADER_RELIEF = 6.0
#: global brightness drift between a frame and its unit's background, relative, per unit of
#: noise std (so that a noise-free frame of no contact is exactly the background)
_DRIFT_PER_NOISE = 0.6


@dataclass(frozen=True)
class TactilePlan:
    material: str
    sensor: int  # global sensor unit id, [0, sensor_count())
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
    shape: str = "flat"  # what presses: a key of SHAPES

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


def touch_version() -> str:
    """What names cached renders and training data: the rendering code's version and the
    sensor table's digest, so that a family added, removed or changed redoes them."""
    return f"{RENDER_CODE}-{table_digest()}"


def sensor_unit(sensor: int, hw: tuple[int, int]) -> SensorUnit:
    """The fixed parts of sensor unit `sensor` at frame size `hw` (cached per sensor table;
    read-only)."""
    return _sensor_unit(int(sensor), (int(hw[0]), int(hw[1])), table_digest())


@lru_cache(maxsize=128)
def _sensor_unit(sensor: int, hw: tuple[int, int], digest: str) -> SensorUnit:
    name = sensor_family(sensor)
    field = unit_field(sensor, hw).astype(np.float32)
    markers, radius, darkness = np.zeros((0, 2), np.float32), 0.0, 0.0
    if has_markers(sensor):
        rng = np.random.default_rng([7919, family_names().index(name), unit_index(sensor)])
        markers = _marker_grid(rng, hw)
        radius = float(rng.uniform(1.0, 1.5) * hw[1] / 96)
        darkness = float(rng.uniform(0.6, 0.8))
    background = field
    if len(markers):
        shadow = (1 - darkness * marker_shadow(markers, radius, hw))[..., None]
        background = (field * shadow).astype(np.float32)
    for arr in (field, background, markers):
        arr.setflags(write=False)
    return SensorUnit(int(sensor), name, field, background, markers, radius, darkness)


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
    drawn = int(frame.integers(sensor_count()))
    sensor = drawn if sensor is None else int(sensor)
    fam = family(sensor_family(sensor)).variation
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
    names = list(SHAPES)
    shape = names[int(frame.choice(len(names), p=[SHAPES[n] for n in names]))]
    if st.tactile_blur is not None:
        blur = st.tactile_blur
    if st.tactile_noise is not None:
        noise = st.tactile_noise
    if not has_markers(sensor):
        shear, marker_jitter = (0.0, 0.0), 0.0
    return TactilePlan(
        material=mat.name, sensor=sensor, contact=contact, centre=centre, force=force,
        axes=axes, ellipse_angle=ellipse_angle, texture_angle=base_angle + rotation,
        texture_offset=texture_offset, texture_step=texture_step, blur=blur, noise=noise,
        render_seed=render_seed, blur_frame=st.tactile_blur is not None,
        light_gain=light_gain, light_turn=light_turn, tint=tint, vignette=vignette,
        drift=_DRIFT_PER_NOISE * noise * drift_z, shear=shear, marker_jitter=marker_jitter,
        shape=shape)


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
    if plan.shape == "cylinder":
        v = v / 1.8  # a long patch along the cylinder's axis
    rho = np.sqrt(u * u + v * v)
    edge = 0.12 + 0.45 * k
    inside = np.clip((1 - rho) / edge, 0, 1)
    inside = inside * inside * (3 - 2 * inside)  # smoothstep
    if plan.shape != "flat":
        # a rigid material keeps the pressing shape (a spherical or cylindrical cap); a
        # compliant one wraps around it and flattens it towards the plateau
        across = rho if plan.shape == "sphere" else np.abs(u)
        cap = np.sqrt(np.clip(1 - across * across, 0, 1)) * inside
        keep = 1 - 0.8 * k
        inside = keep * cap + (1 - keep) * inside
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
        d, colour = np.asarray(d, np.float64), np.asarray(colour, np.float64)
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


def _shader_change(plan: TactilePlan, z: np.ndarray, dome: np.ndarray, field: np.ndarray
                   ) -> np.ndarray:
    """The world's photometric shader: the field's change (float (H, W, 3)) under a gel
    surface `z` (indentation, gel thickness units)."""
    shader = family(plan.family).shader
    assert shader is not None  # the row's check: a "shader" family has one
    if shader.texture != 1.0:
        z = dome + shader.texture * (z - dome)
    z = z * _SHADER_RELIEF
    gy, gx = np.gradient(z)
    norm = np.sqrt(gx * gx + gy * gy + 1)
    n = np.stack([-gx / norm, -gy / norm, 1 / norm - 1], -1)  # change against the flat gel
    mix = _light_mix(shader.lights, plan.light_turn)
    mix *= (shader.gain * plan.light_gain) * np.asarray(plan.tint, np.float32)[None, :]
    shade = n @ mix
    if plan.vignette:
        shade *= (1 - plan.vignette * _radius2(z.shape))[..., None]
    press = (1 - shader.darken * np.clip(z / _SHADER_RELIEF, 0, 1))[..., None]  # gel darkens
    return (field + shade) * press - field


def _taxim_change(plan: TactilePlan, z: np.ndarray, on_gel: bool = False) -> np.ndarray:
    """Taxim's optics: the colour change (float (H, W, 3)) of the family's calibrated sensor
    pressed `z` deep (indentation, gel thickness units; `press_mm` millimetres per unit),
    measured from the gel's apex or, `on_gel`, from its rest surface (`TaximOptics.change`)."""
    row = family(plan.family)
    height = -row.press_mm * z  # mm; below 0 presses into the gel
    if row.landscape:  # the sensor is mounted turned: render its own orientation, turn back
        change = optics(str(row.calibration)).change(height.T, on_gel).transpose(1, 0, 2)
    else:
        change = optics(str(row.calibration)).change(height, on_gel)
    change = change * (plan.light_gain * np.asarray(plan.tint, np.float32))
    if plan.vignette:
        change *= (1 - plan.vignette * _radius2(z.shape))[..., None]
    return change.astype(np.float32)


def render_tactile(plan: TactilePlan, pyramid_fn: Callable[[PatternSpec], list],
                   hw: tuple[int, int], background: np.ndarray) -> np.ndarray:
    """Render a tactile frame, (H, W, 3) uint8: `background` (the unit's no-contact image)
    plus the blurred contact change (by the family's renderer), moved marker dots, a global
    brightness drift and sensor noise."""
    hw = (int(hw[0]), int(hw[1]))
    rng = np.random.default_rng(plan.render_seed)
    bg = np.asarray(background, np.float32)
    img = bg
    blur = 0.0 if plan.blur_frame else plan.blur
    if plan.contact:
        unit = sensor_unit(plan.sensor, hw)
        mat = material(plan.material)
        z, dome = gel_surface(plan, pyramid_fn(mat.feel.pattern), hw, dome=True)
        if family(plan.family).renderer == "taxim":
            lit = _taxim_change(plan, z)
        else:
            lit = _shader_change(plan, z, dome, unit.field)
        if blur > 0:  # the gel blur softens the change; dots stay as sharp as the background's
            lit = gaussian_filter(lit, sigma=(blur, blur, 0))
        if len(unit.markers):
            # markers move outwards along the indentation's slope, with shear and jitter
            dgy, dgx = np.gradient(dome * _SHADER_RELIEF)
            at = unit.markers
            inside = np.clip(_sample_at(dome, at) / max(float(dome.max()), 1e-6), 0, 1)
            jit = rng.standard_normal(at.shape).astype(np.float32) * plan.marker_jitter
            move = -2.5 * np.stack([_sample_at(dgx, at), _sample_at(dgy, at)], 1) * (hw[1] / 96)
            move += (np.asarray(plan.shear, np.float32)[None, :] + jit) * inside[:, None]
            cover = marker_shadow((at + move).astype(np.float32), unit.marker_radius, hw)
            dots = (1 - unit.marker_darkness * cover)[..., None]
            img = bg + ((unit.field + lit) * dots - unit.background)
        else:
            img = bg + lit
    if plan.blur_frame and plan.blur > 0:
        img = gaussian_filter(img, sigma=(plan.blur, plan.blur, 0))
    if plan.drift:
        img = img * np.float32(1 + plan.drift)
    if plan.noise > 0:
        img = img + plan.noise * rng.standard_normal(img.shape, dtype=np.float32)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def contact_change(sensor: int, z: np.ndarray, dome: np.ndarray | None = None,
                   on_gel: bool = False) -> np.ndarray:
    """The colour change (float (H, W, 3), [0, 1] units) that a gel surface `z` (indentation,
    gel-thickness units, (H, W)) makes on unit `sensor`, by its family's renderer, with
    neutral per-frame settings (no light jitter, tint, vignetting, blur or noise): the
    renderer as a function of geometry, for presses planned outside `plan_tactile`
    (`ratouch.world.presses`) and for fitting the geometry lookups. `on_gel`: `z` is measured
    from the gel's rest surface rather than its apex (matters only for a domed gel: Taxim's
    GelSight; the shader's gels and the Mini's are flat)."""
    z = np.asarray(z, np.float32)
    hw = (int(z.shape[0]), int(z.shape[1]))
    plan = TactilePlan(material="glass", sensor=int(sensor), contact=True, centre=(0.5, 0.5),
                       force=1.0, axes=(1.0, 1.0), ellipse_angle=0.0, texture_angle=0.0,
                       texture_offset=(0.0, 0.0), texture_step=1.0, blur=0.0, noise=0.0,
                       render_seed=0)
    if family(plan.family).renderer == "taxim":
        return _taxim_change(plan, z, on_gel)
    return _shader_change(plan, z, z if dome is None else np.asarray(dome, np.float32),
                          sensor_unit(int(sensor), hw).field)

"""Tactile frames rendered like a vision-based (DIGIT / GelSight style) tactile sensor.

The gel is pressed by the contacted material: the indentation (a contact patch whose area and
edge softness come from the material's compliance and the force) plus the material's micro
height-map (attenuated by compliance) give a surface; its normals are shaded by three coloured
lights (photometric shading) over the sensor's own neutral background image, then gel blur and
sensor noise are applied. A no-contact frame is the background plus noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.ndimage import gaussian_filter

from ratouch.world.config import WorldConfig
from ratouch.world.material import Material, material
from ratouch.world.texture import PatternSpec, pixel_grid, sample_tile

N_SENSORS = 4  # distinct sensor units, each with its own background image

# Light directions (x right, y down, z out of the gel) and colours: red, green, blue LEDs
# 120 degrees apart around the gel, as on a DIGIT.
_LIGHTS = (
    (np.array([-0.85, 0.0, 0.53]), np.array([1.0, 0.25, 0.2])),
    (np.array([0.43, -0.74, 0.53]), np.array([0.2, 1.0, 0.3])),
    (np.array([0.43, 0.74, 0.53]), np.array([0.25, 0.3, 1.0])),
)


@dataclass(frozen=True)
class TactilePlan:
    material: str
    sensor: int
    contact: bool
    centre: tuple[float, float]  # fraction of (width, height)
    force: float  # 0.4 .. 1
    axes: tuple[float, float]  # contact ellipse aspect factors
    ellipse_angle: float
    texture_angle: float  # includes the stress rotation
    texture_offset: tuple[float, float]
    texture_step: float
    blur: float
    noise: float
    render_seed: int


def sensor_background(sensor: int, hw: tuple[int, int]) -> np.ndarray:
    """The no-contact image of one sensor unit: a smooth colour field lit from three sides."""
    rng = np.random.default_rng([7919, sensor])
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


def plan_tactile(rng: np.random.Generator, cfg: WorldConfig, mat: Material) -> TactilePlan:
    st = cfg.stress
    contact = st.missing != "tactile" and not (st.no_contact > 0 and rng.random() < st.no_contact)
    base_angle = float(rng.uniform(0, 360))
    rotation = st.tactile_rotation if st.tactile_rotation is not None else 0.0
    return TactilePlan(
        material=mat.name, sensor=int(rng.integers(N_SENSORS)), contact=contact,
        centre=tuple(float(v) for v in rng.uniform(0.4, 0.6, 2)),
        force=float(rng.uniform(0.45, 1.0)),
        axes=tuple(float(v) for v in rng.uniform(0.8, 1.2, 2)),
        ellipse_angle=float(rng.uniform(0, 180)),
        texture_angle=base_angle + rotation,
        texture_offset=tuple(float(v) for v in rng.uniform(0, 256, 2)),
        texture_step=float(rng.uniform(0.9, 1.1)) * 96 / cfg.tactile_hw[1],
        blur=st.tactile_blur if st.tactile_blur is not None else float(rng.uniform(0.5, 1.1)),
        noise=st.tactile_noise if st.tactile_noise is not None else float(rng.uniform(0.006, 0.015)),
        render_seed=int(rng.integers(2**31)),
    )


def gel_surface(plan: TactilePlan, feel_pyramid: list, hw: tuple[int, int]) -> np.ndarray:
    """Indentation depth of the gel, (H, W), in units of gel thickness."""
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
    return depth * inside + 2.2 * relief * (tex - 0.5) * inside


def render_tactile(plan: TactilePlan, pyramid_fn: Callable[[PatternSpec], list],
                   hw: tuple[int, int], background: np.ndarray) -> np.ndarray:
    """Render a tactile frame, (H, W, 3) uint8."""
    rng = np.random.default_rng(plan.render_seed)
    img = background.astype(np.float32)
    if plan.contact:
        mat = material(plan.material)
        z = gel_surface(plan, pyramid_fn(mat.feel.pattern), hw) * 6.0
        gy, gx = np.gradient(z)
        norm = np.sqrt(gx * gx + gy * gy + 1)
        nx, ny, nz = -gx / norm, -gy / norm, 1 / norm
        for d, colour in _LIGHTS:
            d = d / np.linalg.norm(d)
            shade = nx * d[0] + ny * d[1] + (nz - 1) * d[2]  # change against the flat gel
            img += 0.55 * shade[..., None] * colour
        img *= (1 - 0.12 * np.clip(z / 6.0, 0, 1))[..., None]  # pressed gel darkens slightly
    if plan.blur > 0:
        img = gaussian_filter(img, sigma=(plan.blur, plan.blur, 0))
    img = img + plan.noise * rng.standard_normal(img.shape, dtype=np.float32)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)

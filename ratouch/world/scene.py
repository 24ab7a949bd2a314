"""Visual scenes: an object of one material on a background surface of another, under a light,
among distractors, with the ground-truth contact box on the object.

A scene is drawn in two steps: `plan_scene` draws every random choice into a small `ScenePlan`
(cheap: a corpus of 150k plans needs no pixels), and `render_scene` turns a plan into pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.ndimage import gaussian_filter

from ratouch.errors import ConfigError
from ratouch.world.config import WorldConfig
from ratouch.world.material import COLOURS, MATERIALS, Material, material
from ratouch.world.objects import FAMILY_ASPECT, ObjectClass
from ratouch.world.silhouette import silhouette_mask
from ratouch.world.texture import PatternSpec, pixel_grid, sample_tile

PyramidFn = Callable[[PatternSpec], list]

Box = tuple[int, int, int, int]  # (x0, y0, x1, y1), x1/y1 exclusive


@dataclass(frozen=True)
class Surface:
    """A textured patch: which material, its colour, and how its texture is laid down."""

    material: str
    colour: str
    jitter: tuple[float, float, float]  # per-channel colour multipliers
    step: float  # texels per pixel
    angle: float
    offset: tuple[float, float]


@dataclass(frozen=True)
class Thing:
    """A silhouette of a family drawn over a bounding box with a surface."""

    family: str
    bbox: tuple[float, float, float, float]
    variant: tuple[float, float, float, float]
    flip: bool
    surface: Surface


@dataclass(frozen=True)
class ScenePlan:
    kind: str  # "wild", "structured" or "corpus"
    class_name: str
    obj: Thing
    background: Surface
    dominance: float
    light_angle: float
    ambient: float
    tint: tuple[float, float, float]
    box_true: Box
    box: Box
    render_seed: int
    missing_visual: bool = False
    distractors: tuple[Thing, ...] = field(default_factory=tuple)

    @property
    def object_scale(self) -> float:
        x0, y0, x1, y1 = self.obj.bbox
        return max(x1 - x0, y1 - y0)


def _surface(rng: np.random.Generator, mat: Material, step: float) -> Surface:
    colour = mat.look.palette[rng.integers(len(mat.look.palette))]
    jr, jg, jb = rng.uniform(0.9, 1.1, 3) * rng.uniform(0.85, 1.15)
    step *= float(rng.uniform(0.85, 1.15))
    angle = float(rng.uniform(0, 360))
    ox, oy = rng.uniform(0, 256, 2)
    return Surface(mat.name, colour, (float(jr), float(jg), float(jb)), step, angle,
                   (float(ox), float(oy)))


def _variant(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A silhouette's shape variant: four draws in [0, 1)."""
    a, b, c, d = rng.uniform(0, 1, 4)
    return float(a), float(b), float(c), float(d)


def _tint(rng: np.random.Generator) -> tuple[float, float, float]:
    """The scene light's colour: a factor near 1 per channel."""
    r, g, b = rng.uniform(0.93, 1.07, 3)
    return float(r), float(g), float(b)


def _bbox(rng: np.random.Generator, size: int, extent: float, aspect: float) -> tuple:
    aspect *= float(rng.uniform(0.85, 1.15))
    side = extent * size
    w, h = (side, side / aspect) if aspect >= 1 else (side * aspect, side)
    x0 = float(rng.uniform(0, size - w))
    y0 = float(rng.uniform(0, size - h))
    return (x0, y0, x0 + w, y0 + h)


def _contact_box(rng: np.random.Generator, mask: np.ndarray, bbox: tuple, size: int) -> Box:
    """A box centred on an interior point of the object, sized with the object and shrunk
    until most of it lies on the object (thin objects get small boxes)."""
    extent = max(bbox[2] - bbox[0], bbox[3] - bbox[1])
    soft = gaussian_filter(mask.astype(np.float32), sigma=max(1.0, extent / 16))
    ys, xs = np.nonzero((soft > 0.9 * soft.max()) & mask)
    if len(ys) == 0:
        ys, xs = np.nonzero(mask)
    i = rng.integers(len(ys))
    cx, cy = int(xs[i]), int(ys[i])
    side = int(np.clip(0.45 * extent, 8, 0.6 * size))
    while True:
        x0 = int(np.clip(cx - side // 2, 0, size - side))
        y0 = int(np.clip(cy - side // 2, 0, size - side))
        if side <= 8 or mask[y0:y0 + side, x0:x0 + side].mean() >= 0.6:
            return (x0, y0, x0 + side, y0 + side)
        side = max(8, int(side * 0.85))


def _offset_box(rng: np.random.Generator, box: Box, offset: float, size: int) -> Box:
    if offset <= 0:
        return box
    side = box[2] - box[0]
    a = rng.uniform(0, 2 * np.pi)
    dx, dy = offset * side * np.cos(a), offset * side * np.sin(a)
    x0 = int(np.clip(round(box[0] + dx), 0, size - side))
    y0 = int(np.clip(round(box[1] + dy), 0, size - (box[3] - box[1])))
    return (x0, y0, x0 + side, y0 + box[3] - box[1])


def plan_scene(rng: np.random.Generator, cfg: WorldConfig, kind: str, cls: ObjectClass | None,
               mat: Material) -> ScenePlan:
    """Draw every random choice of one scene.

    Args:
        rng: the sample's generator.
        cfg: world config (sizes and stress knobs).
        kind: "wild" (object in a scene), "structured" (flat close-up) or "corpus"
            (object-centric, ImageNet-like).
        cls: the object class (None for structured close-ups).
        mat: the object's material.
    """
    size, st = cfg.image_size, cfg.stress
    if kind == "structured":
        extent = 1.0
        bbox = (0.0, 0.0, float(size), float(size))
        family, tex_step = "box", float(rng.uniform(0.45, 0.7))
    else:
        if cls is None:
            raise ConfigError(f"a {kind!r} scene needs an object class")
        lo, hi = (0.3, 0.85) if kind == "wild" else (0.5, 0.9)
        extent = st.object_scale if st.object_scale is not None else float(rng.uniform(lo, hi))
        family = cls.family
        bbox = _bbox(rng, size, extent, FAMILY_ASPECT[family])
        tex_step = 0.8 / extent * size / 128
    obj = Thing(family, bbox, _variant(rng), bool(rng.integers(2)), _surface(rng, mat, tex_step))
    others = [m for m in MATERIALS if m.name != mat.name]
    bg_mat = others[rng.integers(len(others))]
    background = _surface(rng, bg_mat, float(rng.uniform(0.9, 1.6)) * size / 128)
    if st.background_dominance is not None:
        dominance = st.background_dominance
    else:
        dominance = float(rng.uniform(0.15, 0.55))
    if st.clutter is not None:
        n_clutter = st.clutter
    else:
        n_clutter = 0 if kind == "structured" else int(rng.integers(0, 3 if kind == "wild" else 2))
    distractors = []
    if kind != "structured":
        families = list(FAMILY_ASPECT)
        for _ in range(n_clutter):
            dm = others[rng.integers(len(others))]
            fam = families[rng.integers(len(families))]
            dbox = _bbox(rng, size, float(rng.uniform(0.1, 0.3)), FAMILY_ASPECT[fam])
            distractors.append(Thing(fam, dbox, _variant(rng), bool(rng.integers(2)),
                                     _surface(rng, dm, 0.8 / 0.2 * size / 128)))
    if kind == "corpus":  # ImageNet-like entries have no contact: the box is the object's
        box_true = _window(bbox, size, 0)
    elif kind == "structured":
        side = int(0.6 * size)
        c = int(rng.integers(size // 2 - size // 10, size // 2 + size // 10))
        x0 = y0 = int(np.clip(c - side // 2, 0, size - side))
        box_true = (x0, y0, x0 + side, y0 + side)
    else:
        mask = silhouette_mask(family, (size, size), bbox, obj.variant, obj.flip)
        box_true = _contact_box(rng, mask, bbox, size)
    box = _offset_box(rng, box_true, st.box_offset, size)
    return ScenePlan(
        kind=kind, class_name=cls.name if cls is not None else "", obj=obj, background=background,
        dominance=dominance, light_angle=float(rng.uniform(0, 360)),
        ambient=float(rng.uniform(0.55, 0.75)),
        tint=_tint(rng),
        box_true=box_true, box=box, render_seed=int(rng.integers(2**31)),
        missing_visual=st.missing == "visual", distractors=tuple(distractors))


# ---------------------------------------------------------------------------------------------
# rendering

def _albedo(pyramid_fn: PyramidFn, s: Surface, hw: tuple[int, int], contrast_gain: float = 1.0
            ) -> np.ndarray:
    """Coloured texture of a surface, (H, W, 3) in [0, 1]."""
    mat = material(s.material)
    look = mat.look
    t = sample_tile(pyramid_fn(look.pattern), hw, s.step, s.angle, s.offset)  # (H, W)
    base = np.asarray(COLOURS[s.colour], np.float32) * np.asarray(s.jitter, np.float32)
    c = min(1.0, look.contrast * contrast_gain)
    if look.two_tone:
        dark = base * 0.45
        rgb = dark[None, None] + (base - dark)[None, None] * t[..., None] * (1 + c) / 2 \
            + (base - dark)[None, None] * (1 - c) / 2
    else:
        rgb = base[None, None] * (1 - c / 2 + c * t)[..., None]
    return np.clip(rgb, 0, 1)


def _shade(mask: np.ndarray, extent: float, light: np.ndarray, gloss: float,
           ambient: float) -> tuple[np.ndarray, np.ndarray]:
    """Lambert shading and a specular highlight over a dome raised inside the silhouette."""
    dome = gaussian_filter(mask.astype(np.float32), sigma=max(1.0, extent / 7))
    gy, gx = np.gradient(dome * extent / 5)
    norm = np.sqrt(gx * gx + gy * gy + 1)
    nx, ny, nz = -gx / norm, -gy / norm, 1 / norm
    lambert = np.clip(nx * light[0] + ny * light[1] + nz * light[2], 0, 1)
    diffuse = ambient + (1 - ambient) * lambert
    half = light + np.array([0, 0, 1.0])
    half /= np.linalg.norm(half)
    spec = np.clip(nx * half[0] + ny * half[1] + nz * half[2], 0, 1) ** 40 * gloss
    return diffuse.astype(np.float32), spec.astype(np.float32)


def _window(bbox: tuple, size: int, margin: int) -> tuple[int, int, int, int]:
    """Integer pixel window around a bbox, clipped to the frame."""
    x0 = max(0, int(np.floor(bbox[0])) - margin)
    y0 = max(0, int(np.floor(bbox[1])) - margin)
    x1 = min(size, int(np.ceil(bbox[2])) + margin)
    y1 = min(size, int(np.ceil(bbox[3])) + margin)
    return x0, y0, x1, y1


def _thing_mask(thing: Thing, size: int, win: tuple[int, int, int, int]) -> np.ndarray:
    x0, y0, x1, y1 = win
    b = thing.bbox
    return silhouette_mask(thing.family, (y1 - y0, x1 - x0),
                           (b[0] - x0, b[1] - y0, b[2] - x0, b[3] - y0), thing.variant, thing.flip)


def _draw(canvas: np.ndarray, thing: Thing, pyramid_fn: PyramidFn, light: np.ndarray,
          ambient: float, size: int) -> np.ndarray:
    """Paint a shaded, textured thing onto the canvas; work only inside its window."""
    win = _window(thing.bbox, size, 2)
    x0, y0, x1, y1 = win
    mask = _thing_mask(thing, size, win)
    extent = max(thing.bbox[2] - thing.bbox[0], thing.bbox[3] - thing.bbox[1])
    rgb = _albedo(pyramid_fn, thing.surface, mask.shape)
    diffuse, spec = _shade(mask, extent, light, material(thing.surface.material).gloss, ambient)
    shaded = rgb * diffuse[..., None] + spec[..., None]
    region = canvas[y0:y1, x0:x1]
    region[mask] = shaded[mask]
    full = np.zeros((size, size), bool)
    full[y0:y1, x0:x1] = mask
    return full


def _drop_shadow(canvas: np.ndarray, thing: Thing, light: np.ndarray, size: int) -> None:
    """Darken the surface under a thing, away from the light."""
    win = _window(thing.bbox, size, 12)
    x0, y0, x1, y1 = win
    mask = _thing_mask(thing, size, win).astype(np.float32)
    shift = (int(round(-light[1] * 4)), int(round(-light[0] * 4)))
    shadow = gaussian_filter(np.roll(mask, shift, axis=(0, 1)), 3)
    canvas[y0:y1, x0:x1] *= (1 - 0.45 * shadow)[..., None]


def _lens_blur(img: np.ndarray) -> np.ndarray:
    """A slight optical blur: separable [0.12, 0.76, 0.12] taps (about sigma 0.5), edges kept."""
    out = img * 0.76
    out[1:] += 0.12 * img[:-1]
    out[:-1] += 0.12 * img[1:]
    out[0] += 0.12 * img[0]
    out[-1] += 0.12 * img[-1]
    res = out * 0.76
    res[:, 1:] += 0.12 * out[:, :-1]
    res[:, :-1] += 0.12 * out[:, 1:]
    res[:, 0] += 0.12 * out[:, 0]
    res[:, -1] += 0.12 * out[:, -1]
    return res


def render_scene(plan: ScenePlan, pyramid_fn: PyramidFn, size: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a plan.

    Returns:
        image (size, size, 3) uint8, object mask (size, size) bool, distractor mask bool.
    """
    rng = np.random.default_rng(plan.render_seed)
    hw = (size, size)
    a = np.deg2rad(plan.light_angle)
    light = np.array([np.cos(a) * 0.6, np.sin(a) * 0.6, 0.8])
    light /= np.linalg.norm(light)
    if plan.kind == "structured":
        rgb = _albedo(pyramid_fn, plan.obj.surface, hw)
        ys, xs = (g / size - 0.5 for g in pixel_grid(size, size))
        falloff = plan.ambient + (1 - plan.ambient) * (0.6 + 0.8 * (xs * light[0] + ys * light[1]))
        gloss = material(plan.obj.surface.material).gloss
        sheen = gloss * 0.35 * np.exp(-((xs - light[0] * 0.3) ** 2 + (ys - light[1] * 0.3) ** 2) / 0.05)
        img = rgb * falloff[..., None] + sheen[..., None]
        obj_mask = np.ones(hw, bool)
        dis_mask = np.zeros(hw, bool)
    else:
        gain = 0.3 + 1.7 * plan.dominance
        bg = _albedo(pyramid_fn, plan.background, hw, contrast_gain=gain)
        bg = bg.mean(axis=2, keepdims=True) + (bg - bg.mean(axis=2, keepdims=True)) * (0.6 + plan.dominance)
        ys, xs = (g / size - 0.5 for g in pixel_grid(size, size))
        falloff = plan.ambient + (1 - plan.ambient) * (0.7 + 0.6 * (xs * light[0] + ys * light[1]))
        img = np.clip(bg, 0, 1) * falloff[..., None]
        dis_mask = np.zeros(hw, bool)
        for d in plan.distractors:
            dis_mask |= _draw(img, d, pyramid_fn, light, plan.ambient, size)
        _drop_shadow(img, plan.obj, light, size)
        obj_mask = _draw(img, plan.obj, pyramid_fn, light, plan.ambient, size)
        dis_mask &= ~obj_mask
    img = img * np.asarray(plan.tint, np.float32)
    img = _lens_blur(img)
    img = img + 0.012 * rng.standard_normal(img.shape, dtype=np.float32)
    if plan.missing_visual:
        img = np.full_like(img, 0.5)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8), obj_mask, dis_mask

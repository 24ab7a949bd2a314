"""Periodic procedural patterns: the visual textures and touch height-maps of materials.

Every pattern is generated once as a seamless (periodic) square tile from a name, a seed and
parameters, so that a scene can sample it at any offset, angle and scale with wrap-around and
any process regenerates the exact same bytes. Patterns return float32 tiles in [0, 1].
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ratouch.errors import ConfigError

TILE = 256  # tile side in texels; must stay a power of two for the mip pyramid


@dataclass(frozen=True)
class PatternSpec:
    """A named pattern and its parameters; equal specs give identical tiles.

    Attributes:
        kind: one of `PATTERNS`.
        period: characteristic feature size in texels (weave thread, cell, rib spacing).
        rough: amount of irregular noise mixed in, 0..1.
        angle: orientation of directional patterns, degrees.
        params: extra kind-specific knobs as (name, value) pairs.
    """

    kind: str
    period: float = 8.0
    rough: float = 0.2
    angle: float = 0.0
    params: tuple[tuple[str, float], ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.kind not in PATTERNS:
            raise ConfigError(f"PatternSpec.kind={self.kind!r} is not one of {sorted(PATTERNS)}")
        if not 1.0 <= self.period <= TILE / 2:
            raise ConfigError(f"PatternSpec.period={self.period} must lie in [1, {TILE // 2}]")
        if not 0.0 <= self.rough <= 1.0:
            raise ConfigError(f"PatternSpec.rough={self.rough} must lie in [0, 1]")

    def param(self, name: str, default: float) -> float:
        return dict(self.params).get(name, default)

    def seed(self) -> int:
        """A seed derived from the spec itself, so identical specs share one tile."""
        digest = hashlib.sha256(repr(self).encode()).digest()
        return int.from_bytes(digest[:8], "little")


# ---------------------------------------------------------------------------------------------
# building blocks (all periodic on the TILE x TILE torus)

def _grid() -> tuple[np.ndarray, np.ndarray]:
    y, x = np.mgrid[0:TILE, 0:TILE].astype(np.float32)
    return x, y


def _normalise(a: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(a, 0.5), np.percentile(a, 99.5)
    return np.clip((a - lo) / max(hi - lo, 1e-6), 0.0, 1.0).astype(np.float32)


def fft_noise(rng: np.random.Generator, beta: float = 2.0, stretch: float = 1.0,
              angle: float = 0.0, f_lo: float = 1.0, f_hi: float = TILE / 2) -> np.ndarray:
    """Periodic 1/f^beta noise, optionally stretched along `angle` (anisotropic), unit std."""
    fy = np.fft.fftfreq(TILE)[:, None] * TILE
    fx = np.fft.fftfreq(TILE)[None, :] * TILE
    a = np.deg2rad(angle)
    fu = fx * np.cos(a) + fy * np.sin(a)  # frequency along the streak direction
    fv = -fx * np.sin(a) + fy * np.cos(a)
    f = np.sqrt((fu * stretch) ** 2 + fv ** 2)
    amp = np.where((f >= f_lo) & (f <= f_hi), 1.0 / np.maximum(f, 1.0) ** (beta / 2), 0.0)
    spec = np.fft.fft2(rng.standard_normal((TILE, TILE))) * amp
    out = np.real(np.fft.ifft2(spec))
    return ((out - out.mean()) / (out.std() + 1e-8)).astype(np.float32)


def voronoi(rng: np.random.Generator, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Worley noise: distances to the nearest and second-nearest jittered site (F1, F2).

    One random site per grid cell of side ~`period`; each pixel only looks at the 3x3
    neighbouring cells, so the cost is 9 passes over the tile whatever the period.
    """
    n = max(2, round(TILE / period))
    cell = TILE / n
    sites = rng.uniform(0.0, 1.0, size=(n, n, 2)).astype(np.float32)  # (cy, cx, xy) in cells
    x, y = _grid()
    cx, cy = np.floor(x / cell).astype(int), np.floor(y / cell).astype(int)
    f1 = np.full((TILE, TILE), np.inf, np.float32)
    f2 = np.full((TILE, TILE), np.inf, np.float32)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            jx, jy = cx + dx, cy + dy
            site = sites[jy % n, jx % n]  # (H, W, 2)
            sx = (jx + site[..., 0]) * cell
            sy = (jy + site[..., 1]) * cell
            d = np.sqrt((x - sx) ** 2 + (y - sy) ** 2)
            f2 = np.where(d < f1, f1, np.minimum(f2, d))
            f1 = np.minimum(f1, d)
    return f1, f2


def _spots(rng: np.random.Generator, period: float, radius: float) -> np.ndarray:
    """Randomly placed round spots of a given radius (periodic), in [0, 1]."""
    f1, _ = voronoi(rng, period)
    return np.clip(1.0 - f1 / max(radius, 0.5), 0.0, 1.0)


def _waves(coord: np.ndarray, period: float) -> np.ndarray:
    """A periodic coordinate with an integer number of waves across the tile."""
    n = max(1, round(TILE / period))
    return coord * (2 * np.pi * n / TILE)


def _rot(x: np.ndarray, y: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    # Only multiples of 45 degrees keep a tile periodic; callers pass 0, 45 or 90.
    a = np.deg2rad(angle)
    return x * np.cos(a) + y * np.sin(a), -x * np.sin(a) + y * np.cos(a)


# ---------------------------------------------------------------------------------------------
# pattern kinds

def _flat(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    return 0.5 + 0.5 * s.rough * fft_noise(rng, beta=3.0) / 3


def _noise(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    return fft_noise(rng, beta=s.param("beta", 2.0), f_lo=TILE / (4 * s.period))


def _grain(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Wood grain: warped growth rings streaked along the board."""
    x, y = _grid()
    warp = fft_noise(rng, beta=3.0, stretch=6.0, angle=s.angle) * s.period * 0.6
    u, v = _rot(x, y, s.angle)
    rings = np.sin(_waves(v + warp, s.period))
    rings = np.sign(rings) * np.abs(rings) ** 0.5
    fibre = fft_noise(rng, beta=1.2, stretch=12.0, angle=s.angle)
    return rings + 0.6 * fibre


def _brushed(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    return fft_noise(rng, beta=1.0, stretch=s.param("stretch", 25.0), angle=s.angle)


def _weave(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Plain (shift=0), twill (shift=1) or basket (group=2) weave of round threads."""
    x, y = _grid()
    p = TILE / max(1, round(TILE / s.period))
    shift = int(s.param("shift", 0))
    group = int(s.param("group", 1))
    ix, iy = np.floor(x / p).astype(int), np.floor(y / p).astype(int)
    over = (((ix // group) + (iy // group) * (1 + shift)) % 2) == 0
    warp = np.abs(np.sin(np.pi * x / p))  # thread cross-section across x
    weft = np.abs(np.sin(np.pi * y / p))
    along_w = 0.75 + 0.25 * np.cos(2 * np.pi * y / (p * 2 * group))
    along_f = 0.75 + 0.25 * np.cos(2 * np.pi * x / (p * 2 * group))
    out = np.where(over, warp * along_w, weft * along_f)
    return out + 0.8 * s.rough * fft_noise(rng, beta=1.0)


def _knit(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Stocking stitch: columns of V-shaped loops."""
    x, y = _grid()
    p = TILE / max(1, round(TILE / s.period))
    fx = (x / p) % 1.0
    v = (y / p + 0.9 * np.abs(fx - 0.5)) % 1.0
    loops = np.sin(np.pi * v) * np.sin(np.pi * fx) ** 0.5
    return loops + 0.6 * s.rough * fft_noise(rng, beta=1.0)


def _ribs(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    x, y = _grid()
    u, _ = _rot(x, y, s.angle)
    sharp = s.param("sharp", 0.5)
    r = np.abs(np.sin(_waves(u, 2 * s.period))) ** sharp
    return r + 0.5 * s.rough * fft_noise(rng, beta=1.5)


def _cells(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Pebbled cells (leather grain, stone crystals): raised plates, sunken borders."""
    f1, f2 = voronoi(rng, s.period)
    edge = np.clip((f2 - f1) / (0.35 * s.period), 0, 1) ** 0.6
    return edge + s.rough * fft_noise(rng, beta=1.5)


def _pores(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Sponge / foam / concrete pores: holes punched in a surface."""
    holes = _spots(rng, s.period, s.period * s.param("hole", 0.35))
    return 1.0 - holes + 0.5 * s.rough * fft_noise(rng, beta=1.5)


def _grit(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Sand, sandpaper, granite speckle: dense small grains."""
    grains = _spots(rng, s.period, s.period * 0.55)
    return grains + s.rough * fft_noise(rng, beta=0.5)


def _fibre(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Fur, fleece, felt, suede nap: fine fibres in a loosely shared direction."""
    a = fft_noise(rng, beta=1.0, stretch=s.param("stretch", 6.0), angle=s.angle,
                  f_lo=TILE / (6 * s.period))
    b = fft_noise(rng, beta=1.0, stretch=s.param("stretch", 6.0), angle=s.angle + 30)
    return a + 0.5 * b + 0.6 * s.rough * fft_noise(rng, beta=2.5)


def _veins(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Marble: thin bright veins over a cloudy ground."""
    x, y = _grid()
    turb = fft_noise(rng, beta=2.6) * s.period * 0.9
    v = np.abs(np.sin(_waves(x + y + turb, 4 * s.period)))
    cloud = fft_noise(rng, beta=2.5)
    return -(v ** 0.15) + 0.25 * cloud


def _mesh(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    x, y = _grid()
    p = TILE / max(1, round(TILE / s.period))
    hole = s.param("hole", 0.6)
    fx, fy = np.abs((x / p) % 1.0 - 0.5) * 2, np.abs((y / p) % 1.0 - 0.5) * 2
    open_ = (fx < hole) & (fy < hole)
    return np.where(open_, 0.0, 1.0) + 0.3 * s.rough * fft_noise(rng, beta=1.5)


def _studs(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Regular raised dots (plastic studs, bubble wrap) on a hex-ish grid."""
    x, y = _grid()
    p = TILE / max(1, round(TILE / s.period))
    stagger = s.param("stagger", 0.0)
    row = np.floor(y / p)
    fx = ((x / p + stagger * 0.5 * row) % 1.0) - 0.5
    fy = ((y / p) % 1.0) - 0.5
    r = np.sqrt(fx * fx + fy * fy)
    rad = s.param("radius", 0.32)
    dome = np.clip(1 - (r / rad) ** 2, 0, 1) ** 0.5
    return dome + 0.3 * s.rough * fft_noise(rng, beta=1.5)


def _bark(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Deep fissures running along one direction."""
    n = fft_noise(rng, beta=2.2, stretch=5.0, angle=s.angle, f_lo=TILE / (8 * s.period))
    return np.tanh(2.0 * n) + 0.4 * s.rough * fft_noise(rng, beta=1.2)


def _loops(s: PatternSpec, rng: np.random.Generator) -> np.ndarray:
    """Terry cloth / looped carpet: a dense carpet of little bumps."""
    bumps = _spots(rng, s.period * 0.8, s.period * 0.5)
    return bumps + 0.7 * s.rough * fft_noise(rng, beta=1.2)


PATTERNS = {
    "flat": _flat, "noise": _noise, "grain": _grain, "brushed": _brushed, "weave": _weave,
    "knit": _knit, "ribs": _ribs, "cells": _cells, "pores": _pores, "grit": _grit,
    "fibre": _fibre, "veins": _veins, "mesh": _mesh, "studs": _studs, "bark": _bark,
    "loops": _loops,
}


def make_tile(spec: PatternSpec) -> np.ndarray:
    """Generate the (TILE, TILE) float32 tile of a pattern, values in [0, 1]."""
    rng = np.random.default_rng(spec.seed())
    tile = PATTERNS[spec.kind](spec, rng)
    if spec.kind == "flat":
        return np.clip(tile, 0, 1).astype(np.float32)
    return _normalise(tile)


@lru_cache(maxsize=64)
def pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Read-only float32 (ys, xs) pixel coordinate grids, cached per size (a pure function)."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    ys.setflags(write=False)
    xs.setflags(write=False)
    return ys, xs


def mip_pyramid(tile: np.ndarray, levels: int = 4) -> list[np.ndarray]:
    """Box-filtered half-resolution copies, so minified sampling does not alias."""
    out = [tile]
    for _ in range(levels - 1):
        t = out[-1]
        out.append(0.25 * (t[0::2, 0::2] + t[1::2, 0::2] + t[0::2, 1::2] + t[1::2, 1::2]))
    return out


def sample_tile(pyramid: list[np.ndarray], shape_hw: tuple[int, int], step: float,
                angle: float, offset: tuple[float, float]) -> np.ndarray:
    """Sample a periodic tile over an image grid with bilinear filtering and wrap-around.

    Args:
        pyramid: output of `mip_pyramid`.
        shape_hw: output (H, W).
        step: texels per output pixel (> 1 minifies: the texture looks finer).
        angle: rotation of the texture in degrees.
        offset: texel offset (x, y) of the output's top-left corner.

    Returns:
        (H, W) float32 array.
    """
    level = int(np.clip(np.floor(np.log2(max(step, 1.0))), 0, len(pyramid) - 1))
    tex = pyramid[level]
    size = tex.shape[0]
    s = step / (2 ** level)
    a = np.deg2rad(angle)
    ys, xs = pixel_grid(*shape_hw)
    u = (xs * np.cos(a) - ys * np.sin(a)) * s + offset[0] / (2 ** level)
    v = (xs * np.sin(a) + ys * np.cos(a)) * s + offset[1] / (2 ** level)
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = u - u0, v - v0
    i0 = u0.astype(np.int64) % size
    j0 = v0.astype(np.int64) % size
    i1, j1 = (i0 + 1) % size, (j0 + 1) % size
    top = tex[j0, i0] * (1 - fu) + tex[j0, i1] * fu
    bot = tex[j1, i0] * (1 - fu) + tex[j1, i1] * fu
    return (top * (1 - fv) + bot * fv).astype(np.float32)

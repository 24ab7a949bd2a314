"""The silhouette API: rasterise a family's silhouette into a pixel bbox (`silhouette_mask`),
and the measures built on it (`mask_bbox`, `fill_fraction`, `natural_aspect`).

The design extent of the additive parts is mapped onto the requested pixel bbox, so the drawn
mask touches all four bbox sides; only the pixels whose centres fall in the bbox's sub-grid are
evaluated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ratouch.errors import ConfigError
from ratouch.world.silhouette.builders import builder
from ratouch.world.silhouette.parts import Part
from ratouch.world.silhouette.primitives import Grid

# Holes (subtractive parts) narrower than this many pixels are skipped rather than drawn:
# at small scales they would only eat away the thin walls around them.
_MIN_HOLE_PX = 2.0


def _variant(variant: Sequence[float] | np.ndarray) -> tuple[float, float, float, float]:
    try:
        vals = [float(t) for t in np.asarray(variant, dtype=float).reshape(-1)]
    except (TypeError, ValueError):
        vals = []
    if len(vals) != 4 or not all(math.isfinite(t) for t in vals):
        raise ConfigError(f"variant must be 4 finite numbers in [0, 1], got {variant!r}")
    a, b, c, d = (min(1.0, max(0.0, t)) for t in vals)
    return a, b, c, d


def _parts_and_extent(
    family: str, variant: Sequence[float] | np.ndarray
) -> tuple[list[Part], tuple[float, float, float, float]]:
    parts = builder(family)(*_variant(variant))
    exts = [p.ext for add, p in parts if add]
    x0 = min(e[0] for e in exts)
    y0 = min(e[1] for e in exts)
    x1 = max(e[2] for e in exts)
    y1 = max(e[3] for e in exts)
    return parts, (x0, y0, x1, y1)


def silhouette_mask(
    family: str,
    shape_hw: tuple[int, int],
    bbox: tuple[float, float, float, float],
    variant: Sequence[float] | np.ndarray = (0.5, 0.5, 0.5, 0.5),
    flip: bool = False,
) -> np.ndarray:
    """Rasterise one object silhouette so that it spans a pixel bbox.

    Args:
        family: one of `FAMILIES`.
        shape_hw: (H, W) of the returned mask.
        bbox: (x0, y0, x1, y1) in pixel coordinates (x right, y down, floats). The shape's
            outline touches all four sides; the parts of the bbox outside the image are
            clipped. Pixels are sampled at their centres (x + 0.5, y + 0.5).
        variant: 4 numbers in [0, 1] (values outside are clipped) that change proportions
            within the family: neck length, handle size, sleeve length, leg gap, brim width...
        flip: mirror the shape horizontally inside its bbox.

    Returns:
        Bool array of shape (H, W). For a bbox inside the image, `mask_bbox` of it matches
        the requested bbox within about one pixel on every side.

    Raises:
        ValueError: unknown family, bad shape, non-finite or degenerate bbox
            (x1 <= x0 or y1 <= y0), or a variant that is not 4 finite numbers.
    """
    builder(family)
    try:
        h, w = (int(s) for s in shape_hw)
    except (TypeError, ValueError):
        raise ConfigError(f"shape_hw must be (H, W), got {shape_hw!r}") from None
    if h < 0 or w < 0:
        raise ConfigError(f"shape_hw must be non-negative, got {shape_hw!r}")
    try:
        bx0, by0, bx1, by1 = (float(t) for t in bbox)
    except (TypeError, ValueError):
        raise ConfigError(f"bbox must be (x0, y0, x1, y1), got {bbox!r}") from None
    if not all(math.isfinite(t) for t in (bx0, by0, bx1, by1)):
        raise ConfigError(f"bbox must be finite, got {bbox!r}")
    if bx1 <= bx0 or by1 <= by0:
        raise ConfigError(f"degenerate bbox {bbox!r}: need x1 > x0 and y1 > y0")
    vals = _variant(variant)

    out = np.zeros((h, w), dtype=bool)
    c0, c1 = max(0, math.floor(bx0)), min(w, math.ceil(bx1))
    r0, r1 = max(0, math.floor(by0)), min(h, math.ceil(by1))
    if c0 >= c1 or r0 >= r1:
        return out

    parts, (ex0, ey0, ex1, ey1) = _parts_and_extent(family, vals)
    bw, bh = bx1 - bx0, by1 - by0
    dx, dy = (ex1 - ex0) / bw, (ey1 - ey0) / bh  # one pixel in design units
    # Design coordinates of the first sampled pixel centre. With `flip` the columns are
    # sampled at their mirrored positions, in increasing design x, and written back reversed.
    u0 = (bx1 - (c1 - 0.5)) / bw if flip else (c0 + 0.5 - bx0) / bw
    gx0 = ex0 + u0 * (ex1 - ex0)
    gy0 = ey0 + (r0 + 0.5 - by0) / bh * (ey1 - ey0)
    grid = Grid(gx0, gy0, dx, dy, c1 - c0, r1 - r0)

    sub = out[r0:r1, c0:c1]
    if flip:
        sub = sub[:, ::-1]  # a view: writing into it writes the mirrored columns of `out`
    for additive, prim in parts:
        if additive:
            res = prim.render(grid, True)
        else:
            hx0, hy0, hx1, hy1 = prim.ext
            if hx1 - hx0 < _MIN_HOLE_PX * dx or hy1 - hy0 < _MIN_HOLE_PX * dy:
                continue  # holes this small would only eat the thin walls around them
            res = prim.render(grid, False)
        if res is None:
            continue
        i0, i1, j0, j1, local = res
        view = sub[j0:j1, i0:i1]
        if local is True:
            view[...] = additive
        elif additive:
            view |= local
        else:
            view &= ~local
    return out


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """Tight bounding box of a 2-D mask.

    Args:
        mask: 2-D array; non-zero entries count as inside.

    Returns:
        (x0, y0, x1, y1) with x1 and y1 exclusive, or None for an empty mask.

    Raises:
        ValueError: the mask is not 2-D.
    """
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ConfigError(f"mask must be 2-D, got shape {m.shape}")
    cols = np.flatnonzero(m.any(axis=0))
    if cols.size == 0:
        return None
    rows = np.flatnonzero(m.any(axis=1))
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


def fill_fraction(
    family: str, variant: Sequence[float] | np.ndarray = (0.5, 0.5, 0.5, 0.5)
) -> float:
    """Fraction of its bbox that a family's silhouette covers (on a 64×64 raster).

    Args:
        family: one of `FAMILIES`.
        variant: 4 numbers in [0, 1], as for `silhouette_mask`.

    Returns:
        Covered fraction in (0, 1].

    Raises:
        ValueError: unknown family or bad variant.
    """
    return float(silhouette_mask(family, (64, 64), (0.0, 0.0, 64.0, 64.0), variant).mean())


def natural_aspect(
    family: str, variant: Sequence[float] | np.ndarray = (0.5, 0.5, 0.5, 0.5)
) -> float:
    """Width / height of a family's design extent, for choosing an undistorted bbox.

    Args:
        family: one of `FAMILIES`.
        variant: 4 numbers in [0, 1], as for `silhouette_mask`.

    Returns:
        The natural width-to-height ratio (> 0).

    Raises:
        ValueError: unknown family or bad variant.
    """
    _, (x0, y0, x1, y1) = _parts_and_extent(family, variant)
    return (x1 - x0) / (y1 - y0)

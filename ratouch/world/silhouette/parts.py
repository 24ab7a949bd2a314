"""Building blocks of the family builders: parts (a primitive that adds to or cuts from the
shape), polygons from their vertices, symmetric profiles from (y, half-width) knots, eased
knots and mirrored points.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ratouch.world.silhouette.primitives import Prim, YPoly

_INF = math.inf


def poly(points: Sequence[tuple[float, float]]) -> YPoly:
    """Convex polygon (vertex list, either orientation) as a row-interval region.

    Exact for polygons that every horizontal line meets in one interval (convex ones, and
    e.g. trapezoids with a notch-free outline); otherwise it fills the row hull.
    """
    n = len(points)
    xs = [float(p[0]) for p in points]
    ys = [float(p[1]) for p in points]
    uniq = sorted(set(ys))
    xl: list[float] = []
    xr: list[float] = []
    for yy in uniq:
        lo, hi = _INF, -_INF
        for k in range(n):
            ya, yb = ys[k], ys[k - 1]
            if (ya <= yy <= yb) or (yb <= yy <= ya):
                xa, xb = xs[k], xs[k - 1]
                if ya == yb:
                    lo, hi = min(lo, xa, xb), max(hi, xa, xb)
                else:
                    xi = xa + (yy - ya) / (yb - ya) * (xb - xa)
                    lo, hi = min(lo, xi), max(hi, xi)
        xl.append(lo)
        xr.append(hi)
    return YPoly(np.array(uniq), np.array(xl), np.array(xr))


def profile(knots: Sequence[tuple[float, float]], cx: float = 0.0) -> YPoly:
    """Left-right symmetric row-interval region from (y, half_width) knots."""
    k = np.asarray(knots, dtype=float)
    return YPoly(k[:, 0], cx - k[:, 1], cx + k[:, 1])


def eased(knots: Sequence[tuple[float, float]], n: int = 12) -> list[tuple[float, float]]:
    """Densify (y, w) knots with cosine easing between them (zero slope at every knot)."""
    out = [knots[0]]
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, math.pi, n + 1)[1:])
    for (ya, wa), (yb, wb) in zip(knots[:-1], knots[1:]):
        out.extend(zip(ya + (yb - ya) * np.linspace(0.0, 1.0, n + 1)[1:], wa + (wb - wa) * s))
    return out


Part = tuple[bool, Prim]  # (additive?, primitive)


def add(p: Prim) -> Part:
    return True, p


def sub(p: Prim) -> Part:
    return False, p


def mirror(points: Sequence[tuple[float, float]], axis: float) -> list[tuple[float, float]]:
    """Mirror points about the vertical line x = axis."""
    return [(2.0 * axis - px, py) for px, py in points]

"""Fast pure-numpy silhouette rasteriser for the world's object families.

Every family (ball, bottle, chair, teddy, ...) is a small union/difference of primitives
(ellipses and rings, rounded rectangles, y- or x-monotone polygons) described in the family's
own *design* coordinates (x right, y down, roughly in its natural proportions). The design
extent of the additive primitives is mapped onto the requested pixel bbox, so the drawn mask
touches all four bbox sides: a caller controls an object's size exactly.

Only the pixels whose centres (x + 0.5, y + 0.5) fall in the bbox's sub-grid are evaluated,
each primitive only inside its own window, with 1-D coordinate vectors broadcast to 2-D, so a
call costs a few hundred microseconds. Parts that would be thinner than a pixel are widened to
about one pixel, so small objects (a dozen pixels) keep their limbs, legs and handles and still
span their bbox.

Example:
    >>> mask = silhouette_mask("mug", (128, 128), (20.0, 30.0, 100.0, 110.0))
    >>> mask_bbox(mask)
    (20, 30, 100, 110)
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["FAMILIES", "fill_fraction", "mask_bbox", "natural_aspect", "silhouette_mask"]

_INF = math.inf

# Minimum sizes, in pixels, that thin parts are widened to so that pixel-centre sampling
# never loses them: a 1-px-wide strip always contains a pixel centre, a disc of radius
# sqrt(2)/2 px always contains one.
_MIN_HALF_PX = 0.55
_MIN_RADIUS_PX = 0.75
_MIN_RING_PX = 1.1
# Polygon rows (columns) whose centre is within this many pixels beyond the polygon's ends are
# still drawn, with the end interval: with footprint sampling, no end vertex gets lost.
_END_PX = 0.45
# Holes (subtractive parts) narrower than this many pixels are skipped rather than drawn:
# at small scales they would only eat away the thin walls around them.
_MIN_HOLE_PX = 2.0


# --------------------------------------------------------------------------- primitives


def _window(
    X: np.ndarray, Y: np.ndarray, x0: float, x1: float, y0: float, y1: float
) -> tuple[int, int, int, int] | None:
    """Index window of the sorted sample vectors X, Y covered by the box [x0, x1] × [y0, y1]."""
    i0 = int(np.searchsorted(X, x0, "left"))
    i1 = int(np.searchsorted(X, x1, "right"))
    if i0 >= i1:
        return None
    j0 = int(np.searchsorted(Y, y0, "left"))
    j1 = int(np.searchsorted(Y, y1, "right"))
    if j0 >= j1:
        return None
    return i0, i1, j0, j1


_Render = tuple[tuple[int, int, int, int], "np.ndarray | bool"]


class _Prim:
    """A primitive shape in design coordinates.

    Attributes:
        ext: (x0, y0, x1, y1), the exact extent of the primitive (before any widening).
    """

    __slots__ = ("ext",)

    def render(self, X: np.ndarray, Y: np.ndarray, pdx: float, pdy: float) -> _Render | None:
        """Rasterise on the sample grid X (columns) × Y (rows), both increasing.

        Args:
            X: design x of every sampled column.
            Y: design y of every sampled row.
            pdx: width of one pixel in design units (for the minimum-thickness rule).
            pdy: height of one pixel in design units.

        Returns:
            ((i0, i1, j0, j1), local) with `local` a bool array of shape (j1-j0, i1-i0) or
            True for "the whole window", or None when the primitive covers no sample.
        """
        raise NotImplementedError


class _Rect(_Prim):
    """Axis-aligned rectangle with optional rounded corners (radius in design units)."""

    __slots__ = ("cx", "cy", "hw", "hh", "r")

    def __init__(self, x0: float, y0: float, x1: float, y1: float, r: float = 0.0) -> None:
        self.cx, self.cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
        self.hw, self.hh = abs(x1 - x0) / 2.0, abs(y1 - y0) / 2.0
        self.r = max(0.0, r)
        self.ext = (self.cx - self.hw, self.cy - self.hh, self.cx + self.hw, self.cy + self.hh)

    def render(self, X: np.ndarray, Y: np.ndarray, pdx: float, pdy: float) -> _Render | None:
        hw = max(self.hw, _MIN_HALF_PX * pdx)
        hh = max(self.hh, _MIN_HALF_PX * pdy)
        win = _window(X, Y, self.cx - hw, self.cx + hw, self.cy - hh, self.cy + hh)
        if win is None:
            return None
        r = min(self.r, hw, hh)
        if r <= 0.0:
            return win, True
        i0, i1, j0, j1 = win
        ax = np.maximum(np.abs(X[i0:i1] - self.cx) - (hw - r), 0.0)
        ay = np.maximum(np.abs(Y[j0:j1] - self.cy) - (hh - r), 0.0)
        return win, (ay * ay)[:, None] + (ax * ax)[None, :] <= r * r


class _Ellipse(_Prim):
    """Ellipse, optionally rotated (degrees, clockwise on screen), ring-shaped or box-clipped.

    `hole` > 0 makes a ring of that thickness. The clip box (xlo, xhi, ylo, yhi) only applies
    to unrotated ellipses.
    """

    __slots__ = ("cx", "cy", "rx", "ry", "cos", "sin", "hole", "clip")

    def __init__(
        self,
        cx: float,
        cy: float,
        rx: float,
        ry: float,
        *,
        angle: float = 0.0,
        hole: float = 0.0,
        xlo: float = -_INF,
        xhi: float = _INF,
        ylo: float = -_INF,
        yhi: float = _INF,
    ) -> None:
        self.cx, self.cy, self.rx, self.ry = cx, cy, rx, ry
        self.hole = hole
        self.clip = (xlo, xhi, ylo, yhi)
        if angle:
            if self.clip != (-_INF, _INF, -_INF, _INF):
                raise ValueError("a rotated ellipse cannot be clipped")
            a = math.radians(angle)
            self.cos, self.sin = math.cos(a), math.sin(a)
            hx = math.hypot(rx * self.cos, ry * self.sin)
            hy = math.hypot(rx * self.sin, ry * self.cos)
            self.ext = (cx - hx, cy - hy, cx + hx, cy + hy)
        else:
            self.cos, self.sin = 1.0, 0.0
            self.ext = self._clipped_extent()

    def _clipped_extent(self) -> tuple[float, float, float, float]:
        """Exact extent of the ellipse intersected with its clip box."""
        cx, cy, rx, ry = self.cx, self.cy, self.rx, self.ry
        xlo, xhi, ylo, yhi = self.clip
        ya, yb = max(ylo, cy - ry), min(yhi, cy + ry)
        xa, xb = max(xlo, cx - rx), min(xhi, cx + rx)
        if ya > yb or xa > xb:
            raise ValueError("clip box misses the ellipse")
        yn = min(max(cy, ya), yb)  # row of the clip band nearest the centre: widest there
        xn = min(max(cx, xa), xb)
        hw = rx * math.sqrt(max(0.0, 1.0 - ((yn - cy) / ry) ** 2))
        hh = ry * math.sqrt(max(0.0, 1.0 - ((xn - cx) / rx) ** 2))
        return (max(xlo, cx - hw), max(ylo, cy - hh), min(xhi, cx + hw), min(yhi, cy + hh))

    def render(self, X: np.ndarray, Y: np.ndarray, pdx: float, pdy: float) -> _Render | None:
        cx, cy = self.cx, self.cy
        if self.sin == 0.0:
            rx = max(self.rx, _MIN_RADIUS_PX * pdx)
            ry = max(self.ry, _MIN_RADIUS_PX * pdy)
            xlo, xhi, ylo, yhi = self.clip
            win = _window(
                X, Y, max(xlo, cx - rx), min(xhi, cx + rx), max(ylo, cy - ry), min(yhi, cy + ry)
            )
            if win is None:
                return None
            i0, i1, j0, j1 = win
            dx = X[i0:i1] - cx
            dy = Y[j0:j1] - cy
            qx, qy = (dx / rx) ** 2, (dy / ry) ** 2
            inside = qy[:, None] + qx[None, :] <= 1.0
            if self.hole > 0.0:
                irx = rx - max(self.hole, _MIN_RING_PX * pdx)
                iry = ry - max(self.hole, _MIN_RING_PX * pdy)
                if irx > 0.0 and iry > 0.0:
                    inside &= (dy / iry)[:, None] ** 2 + (dx / irx)[None, :] ** 2 > 1.0
            return win, inside
        m = _MIN_RADIUS_PX * max(pdx, pdy)
        rx, ry = max(self.rx, m), max(self.ry, m)
        c, s = self.cos, self.sin
        hx, hy = math.hypot(rx * c, ry * s), math.hypot(rx * s, ry * c)
        win = _window(X, Y, cx - hx, cx + hx, cy - hy, cy + hy)
        if win is None:
            return None
        i0, i1, j0, j1 = win
        dx = (X[i0:i1] - cx)[None, :]
        dy = (Y[j0:j1] - cy)[:, None]
        t1 = dx * (c / rx) + dy * (s / rx)
        t2 = dy * (c / ry) - dx * (s / ry)
        return win, t1 * t1 + t2 * t2 <= 1.0


def _footprint_extremes(
    t: np.ndarray, step: float, kt: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Min of the piecewise-linear `lo` and max of `hi` over each sample's pixel footprint.

    Sampling a polygon's edge only at pixel centres can miss a sharp vertex by up to half a
    pixel times the edge slope (several pixels for a squashed shape); taking the extremes over
    the footprint [t - step/2, t + step/2] instead never misses a vertex, so polygon extremes
    land on the bbox sides and sub-pixel-thin polygons stay visible.

    Args:
        t: sample positions, uniformly spaced by `step`, increasing.
        step: sample spacing.
        kt: knot positions (non-decreasing).
        lo: knot values whose footprint minimum is wanted.
        hi: knot values whose footprint maximum is wanted.

    Returns:
        (lo_min, hi_max), one value per sample.
    """
    h = 0.5 * step
    a, b = t - h, t + h
    lo_min = np.minimum(np.interp(a, kt, lo), np.interp(b, kt, lo))
    hi_max = np.maximum(np.interp(a, kt, hi), np.interp(b, kt, hi))
    if step > 0.0:
        j = np.rint((kt - t[0]) / step).astype(np.intp)
        ok = (j >= 0) & (j < t.size)
        if ok.any():
            np.minimum.at(lo_min, j[ok], lo[ok])
            np.maximum.at(hi_max, j[ok], hi[ok])
    return lo_min, hi_max


class _YPoly(_Prim):
    """Region whose every row y in [y0, y1] is one interval [xl(y), xr(y)].

    xl and xr are piecewise linear through their own knots (knot ys non-decreasing, both
    chains running from y0 to y1); rows are widened to their pixel footprint (see
    `_footprint_extremes`).
    """

    __slots__ = ("ys", "xl", "xr")

    def __init__(self, ys: np.ndarray, xl: np.ndarray, xr: np.ndarray) -> None:
        self.ys = np.asarray(ys, dtype=float)
        self.xl = np.asarray(xl, dtype=float)
        self.xr = np.asarray(xr, dtype=float)
        self.ext = (float(self.xl.min()), float(self.ys[0]), float(self.xr.max()), float(self.ys[-1]))

    def render(self, X: np.ndarray, Y: np.ndarray, pdx: float, pdy: float) -> _Render | None:
        x0, y0, x1, y1 = self.ext
        hmin = _MIN_HALF_PX * pdy
        if (y1 - y0) / 2.0 < hmin:
            c = (y0 + y1) / 2.0
            y0, y1 = c - hmin, c + hmin
        wmin = _MIN_HALF_PX * pdx
        # Rows whose centre lies just beyond the ends still see the end knots in their footprint.
        win = _window(X, Y, x0 - wmin, x1 + wmin, y0 - _END_PX * pdy, y1 + _END_PX * pdy)
        if win is None:
            return None
        i0, i1, j0, j1 = win
        left, right = _footprint_extremes(Y[j0:j1], pdy, self.ys, self.xl, self.xr)
        if wmin > 0.0:
            mid = (left + right) * 0.5
            half = np.maximum((right - left) * 0.5, wmin)
            left, right = mid - half, mid + half
        xs = X[i0:i1][None, :]
        return win, (xs >= left[:, None]) & (xs <= right[:, None])


class _XPoly(_Prim):
    """Region whose every column x in [xs[0], xs[-1]] is one interval [yt(x), yb(x)]."""

    __slots__ = ("xs", "yt", "yb")

    def __init__(self, xs: np.ndarray, yt: np.ndarray, yb: np.ndarray) -> None:
        self.xs = np.asarray(xs, dtype=float)
        self.yt = np.asarray(yt, dtype=float)
        self.yb = np.asarray(yb, dtype=float)
        self.ext = (float(self.xs[0]), float(self.yt.min()), float(self.xs[-1]), float(self.yb.max()))

    def render(self, X: np.ndarray, Y: np.ndarray, pdx: float, pdy: float) -> _Render | None:
        x0, y0, x1, y1 = self.ext
        wmin = _MIN_HALF_PX * pdx
        if (x1 - x0) / 2.0 < wmin:
            c = (x0 + x1) / 2.0
            x0, x1 = c - wmin, c + wmin
        hmin = _MIN_HALF_PX * pdy
        win = _window(X, Y, x0 - _END_PX * pdx, x1 + _END_PX * pdx, y0 - hmin, y1 + hmin)
        if win is None:
            return None
        i0, i1, j0, j1 = win
        top, bot = _footprint_extremes(X[i0:i1], pdx, self.xs, self.yt, self.yb)
        if hmin > 0.0:
            mid = (top + bot) * 0.5
            half = np.maximum((bot - top) * 0.5, hmin)
            top, bot = mid - half, mid + half
        ys = Y[j0:j1][:, None]
        return win, (ys >= top[None, :]) & (ys <= bot[None, :])


def _poly(points: Sequence[tuple[float, float]]) -> _YPoly:
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
    return _YPoly(np.array(uniq), np.array(xl), np.array(xr))


def _profile(knots: Sequence[tuple[float, float]], cx: float = 0.0) -> _YPoly:
    """Left-right symmetric row-interval region from (y, half_width) knots."""
    k = np.asarray(knots, dtype=float)
    return _YPoly(k[:, 0], cx - k[:, 1], cx + k[:, 1])


def _eased(knots: Sequence[tuple[float, float]], n: int = 12) -> list[tuple[float, float]]:
    """Densify (y, w) knots with cosine easing between them (zero slope at every knot)."""
    out = [knots[0]]
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, math.pi, n + 1)[1:])
    for (ya, wa), (yb, wb) in zip(knots[:-1], knots[1:]):
        out.extend(zip(ya + (yb - ya) * np.linspace(0.0, 1.0, n + 1)[1:], wa + (wb - wa) * s))
    return out


_Part = tuple[bool, _Prim]  # (additive?, primitive)


def _add(p: _Prim) -> _Part:
    return True, p


def _sub(p: _Prim) -> _Part:
    return False, p


def _mirror(points: Sequence[tuple[float, float]], axis: float) -> list[tuple[float, float]]:
    """Mirror points about the vertical line x = axis."""
    return [(2.0 * axis - px, py) for px, py in points]


# --------------------------------------------------------------------------- families
# Each builder takes the four variant numbers (a, b, c, d) in [0, 1] and returns the parts in
# drawing order: additive parts are OR-ed in, subtractive ones cut what was drawn before them.


def _ball(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A ball resting on the ground: a circle with a slightly flattened contact patch.
    return [_add(_Ellipse(0.0, 0.0, 1.0, 1.0, yhi=0.99 - 0.05 * a))]


def _egg(a: float, b: float, c: float, d: float) -> list[_Part]:
    k = 0.3 + 0.15 * a  # pointiness of the top
    t = np.linspace(-1.0, 1.0, 41)
    hw = 0.72 * np.sqrt(np.clip(1.0 - t * t, 0.0, None)) * (1.0 + k * t) / (1.0 + 0.5 * k)
    hw *= 0.9 + 0.2 * b
    return [_add(_YPoly(t, -hw, hw))]


def _box(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A cuboid seen from above-right: front face + top face + side face (a hexagon).
    w, h = 1.1 + 0.4 * c, 1.0
    dx, dy = 0.26 + 0.16 * a, 0.2 + 0.12 * b
    return [_add(_poly([(0, dy), (dx, 0), (w, 0), (w, h - dy), (w - dx, h), (0, h)]))]


def _rounded_box(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A soft-cornered case: a rounded body under a slightly overhanging lid.
    w = 1.2 + 0.3 * c
    lid = 0.14 + 0.08 * b
    ov = 0.03 + 0.03 * d  # lid overhang
    r = 0.2 + 0.1 * a
    return [
        _add(_Rect(0.0, 0.0, w, lid, r=0.05)),
        _add(_Rect(ov, lid * 0.5, w - ov, 1.0, r=r)),
    ]


def _bottle(a: float, b: float, c: float, d: float) -> list[_Part]:
    bw = 0.16 + 0.08 * b  # body half-width
    nw = 0.045 + 0.025 * c  # neck half-width
    cw = nw + 0.012 + 0.01 * d  # cap half-width
    ch = 0.05 + 0.03 * d  # cap height
    nl = 0.1 + 0.2 * a  # neck length
    sl = 0.08 + 0.12 * c  # shoulder length
    ys = ch + nl
    knots = [(0.0, cw), (ch, cw), (ch + 1e-6, nw), (ys, nw)]
    knots += _eased([(ys, nw), (ys + sl, bw)], 10)[1:]
    knots += [(0.96, bw), (0.985, bw - 0.012), (1.0, bw - 0.035)]
    return [_add(_profile(knots))]


def _vase(a: float, b: float, c: float, d: float) -> list[_Part]:
    lip = 0.16 + 0.06 * d
    ny = 0.12 + 0.12 * a  # neck height
    neck = 0.08 + 0.05 * c
    by = 0.5 + 0.15 * a  # belly height
    belly = 0.3 + 0.08 * b
    foot = 0.14 + 0.04 * c
    knots = _eased([(0.0, lip), (ny, neck), (by, belly), (0.94, foot)], 10)
    knots += [(1.0, foot + 0.02)]
    return [_add(_profile(knots))]


def _lamp(a: float, b: float, c: float, d: float) -> list[_Part]:
    sh = 0.3 + 0.14 * a  # shade height
    top = 0.2 + 0.1 * d
    sw = 0.02 + 0.02 * b  # stem half-width
    bw = 0.16 + 0.1 * c  # base half-width
    return [
        _add(_profile([(0.0, top), (sh, 0.42)])),
        _add(_Rect(-0.42, sh - 0.03, 0.42, sh)),  # shade rim
        _add(_Rect(-sw, sh - 0.02, sw, 0.92)),
        _add(_Rect(-0.035, sh + 0.22, 0.035, sh + 0.27, r=0.01)),  # switch knuckle
        _add(_Rect(-bw, 0.9, bw, 1.0, r=0.035)),
    ]


def _mug(a: float, b: float, c: float, d: float) -> list[_Part]:
    w = 0.7 + 0.2 * c  # body width (height 1)
    rx = 0.2 + 0.1 * a
    ry = 0.25 + 0.1 * b
    t = 0.07 + 0.04 * d
    return [
        _add(_Rect(0.0, 0.0, w, 1.0, r=0.08)),
        _add(_Ellipse(w - 0.04, 0.45, rx, ry, hole=t, xlo=w - 0.06)),
    ]


def _bowl(a: float, b: float, c: float, d: float) -> list[_Part]:
    depth = 0.45 + 0.35 * a
    rim = 0.03 + 0.03 * b
    fw = 0.25 + 0.15 * c
    return [
        _add(_Ellipse(0.0, 0.0, 1.0, depth, ylo=0.0)),
        _add(_Rect(-1.05, -rim, 1.05, rim * 0.6, r=rim * 0.5)),
        _add(_Rect(-fw, depth * 0.9, fw, depth + 0.09)),
    ]


def _plate(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A plate seen from a low angle: elliptical face, shallow underside, narrow foot ring.
    e = 0.13 + 0.1 * a
    fw = 0.42 + 0.15 * c
    under = 0.12 + 0.06 * b
    return [
        _add(_Ellipse(0.0, 0.0, 1.0, e)),
        _add(_Ellipse(0.0, 0.0, 0.9, e + under, ylo=0.0)),
        _add(_Rect(-fw, e + under * 0.6, fw, e + under + 0.05, r=0.015)),
    ]


def _boot(a: float, b: float, c: float, d: float) -> list[_Part]:
    sw = 0.36 + 0.1 * b  # shaft width
    fy = 0.56 + 0.12 * a  # where the foot starts (shaft height)
    toe = 0.85 + 0.2 * c  # toe reach
    ty = fy + 0.12 * (1.0 - fy)  # top of the foot at the toe
    ry = (1.0 - ty) / 2.0
    rx = ry * 1.3
    heel = 0.07 + 0.04 * d
    return [
        _add(_Rect(-0.02, 0.0, sw + 0.02, 0.08, r=0.015)),  # cuff
        _add(_Rect(0.0, 0.04, sw, fy + 0.05)),
        _add(_poly([(0.0, fy), (sw, fy), (toe - rx, ty), (toe - rx, 1.0), (0.0, 1.0)])),
        _add(_Ellipse(toe - rx, ty + ry, rx, ry)),
        _add(_Rect(-0.01, 1.0 - heel, 0.24, 1.0)),  # heel
        _add(_Rect(0.0, 1.0 - 0.035, toe - rx * 0.5, 1.0)),  # sole
    ]


def _shoe(a: float, b: float, c: float, d: float) -> list[_Part]:
    h = 0.4  # natural height (length 1)
    dip = 0.2 + 0.14 * a  # depth of the opening behind the tongue
    tongue = 0.36 + 0.1 * d
    toe_top = 0.55 + 0.15 * b
    heel = 0.05 + 0.05 * c
    top = _eased([(0.0, 0.1), (0.04, 0.0), (0.1, 0.0), (0.24, dip), (tongue, dip * 0.45),
                  (tongue + 0.07, dip * 0.5), (0.82, toe_top), (0.96, 0.8), (1.0, 0.9)], 6)
    xs = np.array([p[0] for p in top])
    yt = np.array([p[1] for p in top])
    yb = np.interp(xs, [0.0, 0.03, 0.9, 1.0], [1.0 - heel, 1.0, 1.0, 0.96])
    return [_add(_XPoly(xs, yt * h, yb * h))]


def _bag(a: float, b: float, c: float, d: float) -> list[_Part]:
    rx = 0.18 + 0.14 * a  # handle half-width
    ry = 0.28 + 0.12 * b  # handle height
    t = 0.045 + 0.035 * c  # handle thickness
    top = 0.3 + 0.08 * d  # body half-width at the top (bottom: 0.5)
    y0, y1, ch = ry, ry + 1.0, 0.06
    return [
        _add(_Ellipse(0.0, y0 + 0.02, rx, ry + 0.02, hole=t, yhi=y0 + 0.04)),
        _add(_poly([(-top, y0), (top, y0), (0.5, y1 - ch), (0.5 - ch * 0.7, y1),
                    (-0.5 + ch * 0.7, y1), (-0.5, y1 - ch)])),
    ]


def _shirt(a: float, b: float, c: float, d: float) -> list[_Part]:
    tw = 0.22 + 0.05 * c  # torso half-width (centre x = 0.5)
    theta = math.radians(28.0 + 30.0 * a)  # sleeve droop
    length = 0.28 + 0.36 * a  # sleeve length
    sw = 0.17 + 0.05 * b  # sleeve width
    neck = 0.09 + 0.03 * d
    torso = _poly([(0.5 - tw, 0.1), (0.5 - neck - 0.05, 0.0), (0.5 + neck + 0.05, 0.0), (0.5 + tw, 0.1),
                   (0.5 + tw, 1.0), (0.5 - tw, 1.0)])
    p1 = (0.5 + neck + 0.04, 0.005)
    p2 = (p1[0] + length * math.cos(theta), p1[1] + length * math.sin(theta))
    p3 = (p2[0] - sw * math.sin(theta), p2[1] + sw * math.cos(theta))
    p4 = (0.5 + tw, 0.26 + 0.06 * b)
    sleeve = [p1, p2, p3, p4]
    return [
        _add(torso),
        _add(_poly(sleeve)),
        _add(_poly(_mirror(sleeve, 0.5))),
        _sub(_Ellipse(0.5, -0.01, neck, 0.06 + 0.03 * d)),
    ]


def _trousers(a: float, b: float, c: float, d: float) -> list[_Part]:
    gap = 0.03 + 0.08 * a  # half gap between the hems
    crotch = 0.28 + 0.12 * b
    flare = 0.06 * c
    wb = 0.06 + 0.03 * d  # waistband height
    leg = [(0.07, crotch - 0.01), (0.5, crotch - 0.01), (0.5 - gap, 1.1), (0.05 - flare, 1.1)]
    return [
        _add(_Rect(0.1, 0.0, 0.9, wb)),
        _add(_poly([(0.1, wb * 0.5), (0.9, wb * 0.5), (0.93, crotch), (0.07, crotch)])),
        _add(_poly(leg)),
        _add(_poly(_mirror(leg, 0.5))),
    ]


def _chair(a: float, b: float, c: float, d: float) -> list[_Part]:
    # Side view: slanted back post running into the rear leg, seat, front leg, stretcher.
    sy = 0.48 + 0.1 * a  # seat height (from the top of the back)
    st = 0.08 + 0.03 * b  # seat thickness
    lt = 0.075 + 0.03 * c  # leg thickness
    tilt = 0.03 + 0.06 * d
    bw = lt + 0.03
    depth = 0.85
    return [
        _add(_poly([(0.0, 0.0), (bw, 0.0), (tilt + bw, sy), (tilt, sy)])),
        _add(_Rect(0.0, 0.0, bw, 0.12)),  # backrest top rail
        _add(_Rect(tilt, sy, tilt + lt, 1.0)),
        _add(_Rect(0.0, sy, depth, sy + st, r=0.01)),
        _add(_Rect(depth - lt, sy, depth, 1.0)),
        _add(_Rect(tilt, 0.81, depth, 0.85)),
    ]


def _table(a: float, b: float, c: float, d: float) -> list[_Part]:
    w, h = 1.4, 0.8
    tt = 0.06 + 0.04 * a  # top thickness
    ap = 0.06 + 0.05 * b  # apron depth
    inset = 0.05 + 0.12 * c
    lw = 0.08 + 0.04 * d
    return [
        _add(_Rect(0.0, 0.0, w, tt, r=0.01)),
        _add(_Rect(inset, tt, w - inset, tt + ap)),
        _add(_Rect(inset, tt, inset + lw, h)),
        _add(_Rect(w - inset - lw, tt, w - inset, h)),
    ]


def _hat(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A fedora: tapered crown with a pinched top, on a wide elliptical brim.
    brim = 0.5 + 0.25 * a  # brim half-width
    bh = 0.07 + 0.05 * b  # brim half-height
    ch = 0.45 + 0.3 * c  # crown height
    cw = 0.28 + 0.05 * d  # crown half-width at the band
    return [
        _add(_poly([(-cw * 0.85, 0.0), (cw * 0.85, 0.0), (cw, ch), (-cw, ch)])),
        _sub(_Ellipse(0.0, -0.02, cw * 0.38, 0.07)),
        _add(_Ellipse(0.0, ch, brim, bh)),
    ]


def _guitar(a: float, b: float, c: float, d: float) -> list[_Part]:
    lb = 0.22 + 0.04 * b  # lower bout radius
    ub = lb * (0.72 + 0.1 * b)
    neck = 0.3 + 0.15 * a  # neck length above the body
    hs = 0.1 + 0.04 * d  # headstock length
    hole = 0.045 + 0.03 * c
    y_ub = hs + neck + ub * 0.85
    y_lb = y_ub + ub + lb * 0.55
    return [
        _add(_Rect(-0.055, 0.0, 0.055, hs, r=0.02)),
        _add(_Rect(-0.032, hs - 0.01, 0.032, y_ub)),
        _add(_Ellipse(0.0, y_ub, ub, ub)),
        _add(_Ellipse(0.0, y_lb, lb, lb)),
        _sub(_Ellipse(0.0, y_ub + ub * 0.75, hole, hole)),
    ]


def _pan(a: float, b: float, c: float, d: float) -> list[_Part]:
    ry = 0.55 + 0.35 * b  # perspective squash of the pan disc
    hl = 0.9 + 0.6 * a  # handle length
    ht = 0.07 + 0.05 * c  # handle half-thickness
    s = 0.25 * d  # handle rise per unit length
    x0, x1 = 0.85, 0.85 + hl
    yend = -s * hl
    return [
        _add(_Ellipse(0.0, 0.0, 1.0, ry)),
        _add(_poly([(x0, -ht), (x1, yend - ht * 1.2), (x1, yend + ht * 1.2), (x0, ht)])),
        _add(_Ellipse(x1, yend, ht * 1.4, ht * 1.4)),
        _sub(_Ellipse(x1 - ht * 0.2, yend, ht * 0.55, ht * 0.55)),  # hanging hole
    ]


def _spoon(a: float, b: float, c: float, d: float) -> list[_Part]:
    bl = 0.15 + 0.06 * a  # bowl half-length
    bh = 0.09 + 0.03 * b  # bowl half-height
    hw = 0.025 + 0.015 * c  # handle half-width at the end
    return [
        _add(_Ellipse(bl, 0.0, bl, bh)),
        _add(_poly([(bl * 1.6, -0.014), (0.95, -hw), (0.95, hw), (bl * 1.6, 0.014)])),
        _add(_Ellipse(0.95, 0.0, 0.05, hw * 1.25)),
    ]


def _blob(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A four-legged animal facing right; the variant moves head, legs, ears and tail.
    leg = 0.22 + 0.16 * b  # leg length
    bh = 0.15 + 0.05 * c  # body half-height
    cy = 1.0 - leg - bh * 0.7  # body centre
    hy = cy - bh - 0.02 - 0.12 * a  # head centre
    hr = 0.13
    ear = 0.05 + 0.04 * c
    spread = 0.04 * d
    el = 25.0 + 40.0 * d  # tail elevation, degrees
    tx, ty = 0.2, cy - bh * 0.5
    tl = 0.16
    tip = (tx - tl * math.cos(math.radians(el)), ty - tl * math.sin(math.radians(el)))
    parts = [
        _add(_Ellipse(0.55, cy, 0.37, bh)),
        _add(_Ellipse(0.86, (cy + hy) / 2.0, 0.09, abs(cy - hy) / 2.0 + 0.06, angle=-25.0)),  # neck
        _add(_Ellipse(0.95, hy, hr, hr * 0.92)),
        _add(_Ellipse(1.09, hy + 0.04, 0.07, 0.05)),  # snout
        _add(_Ellipse(0.89, hy - hr * 0.85, ear * 0.5, ear, angle=-20.0)),
        _add(_Ellipse(0.99, hy - hr * 0.85, ear * 0.5, ear, angle=15.0)),
        _add(_Ellipse((tx + tip[0]) / 2, (ty + tip[1]) / 2, tl / 2 + 0.01, 0.028, angle=el)),
        _add(_Ellipse(tip[0], tip[1], 0.035, 0.035)),
    ]
    for x in (0.26 - spread, 0.37 - spread, 0.7 + spread, 0.8 + spread):
        parts.append(_add(_Rect(x, cy, x + 0.075, 1.0, r=0.02)))
    return parts


def _teddy(a: float, b: float, c: float, d: float) -> list[_Part]:
    er = 0.07 + 0.03 * c  # ear radius
    arm = 35.0 + 30.0 * b  # arm angle below the horizontal
    spread = 0.1 + 0.06 * d
    bw = 0.2 + 0.05 * a
    return [
        _add(_Ellipse(-0.16, 0.1, er, er)),
        _add(_Ellipse(0.16, 0.1, er, er)),
        _add(_Ellipse(0.0, 0.26, 0.2, 0.18)),
        _add(_Ellipse(0.0, 0.62, bw, 0.25)),
        _add(_Ellipse(bw + 0.04, 0.55, 0.15, 0.065, angle=arm)),
        _add(_Ellipse(-bw - 0.04, 0.55, 0.15, 0.065, angle=180.0 - arm)),
        _add(_Ellipse(spread + 0.04, 0.88, 0.1, 0.12)),
        _add(_Ellipse(-spread - 0.04, 0.88, 0.1, 0.12)),
    ]


def _mitten(a: float, b: float, c: float, d: float) -> list[_Part]:
    tilt = -30.0 - 20.0 * a  # thumb angle
    tl = 0.17 + 0.05 * b  # thumb half-length
    cuff = 0.16 + 0.06 * c
    pw = 0.5 + 0.08 * d  # palm width
    x0 = 0.22
    return [
        _add(_Rect(x0, 0.0, x0 + pw, 0.62, r=pw * 0.5)),
        _add(_Rect(x0, 0.3, x0 + pw, 1.0 - cuff + 0.02, r=0.02)),
        _add(_Ellipse(x0 + 0.03, 0.55, 0.085, tl, angle=tilt)),
        _add(_Rect(x0 - 0.02, 1.0 - cuff, x0 + pw + 0.02, 1.0, r=0.02)),
    ]


def _cushion(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A pillow: plump square with the sides pulled in towards the (pinched) corners.
    w, h = 1.0, 0.75 + 0.2 * b
    dep = 0.05 + 0.06 * a  # how far the sides are pulled in
    k = 0.03
    r = 0.02 + 0.03 * c
    return [
        _add(_Rect(0.0, 0.0, w, h, r=r)),
        _sub(_Ellipse(w / 2, -k, w * 0.43, k + dep)),
        _sub(_Ellipse(w / 2, h + k, w * 0.43, k + dep)),
        _sub(_Ellipse(-k, h / 2, k + dep, h * 0.43)),
        _sub(_Ellipse(w + k, h / 2, k + dep, h * 0.43)),
    ]


def _sheet(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A flat cloth or sheet lying slightly rumpled: wavy long edges, straight short edges.
    w, h = 1.5, 0.6
    amp = 0.05 + 0.05 * a
    f = 1.5 + 1.5 * b
    ph = 2.0 * math.pi * c
    xs = np.linspace(0.0, w, 61)
    yt = amp * (0.5 + 0.5 * np.sin(2.0 * math.pi * f * xs / w + ph))
    yb = h - amp * (0.5 + 0.5 * np.sin(2.0 * math.pi * (f + 0.5) * xs / w + ph * 1.7 + d))
    return [_add(_XPoly(xs, yt, yb))]


def _rock(a: float, b: float, c: float, d: float) -> list[_Part]:
    # An irregular faceted stone with a flattish base; the variant shuffles its facets.
    n = 11
    k = np.arange(n)
    th = 2.0 * math.pi * (k + 0.25 * np.sin(k * 2.3 + 6.0 * a)) / n
    rad = 1.0 + 0.1 * np.sin(2.0 * th + 6.0 * b) + 0.07 * np.cos(3.0 * th + 6.0 * c)
    px = rad * np.cos(th) * (1.15 + 0.2 * d)
    py = np.minimum(rad * np.sin(th) * 0.75, 0.55)
    return [_add(_poly(list(zip(px, py))))]


_BUILDERS: types.MappingProxyType[str, Callable[[float, float, float, float], list[_Part]]] = (
    types.MappingProxyType(
        {
            "ball": _ball,
            "egg": _egg,
            "box": _box,
            "rounded_box": _rounded_box,
            "bottle": _bottle,
            "vase": _vase,
            "lamp": _lamp,
            "mug": _mug,
            "bowl": _bowl,
            "plate": _plate,
            "boot": _boot,
            "shoe": _shoe,
            "bag": _bag,
            "shirt": _shirt,
            "trousers": _trousers,
            "chair": _chair,
            "table": _table,
            "hat": _hat,
            "guitar": _guitar,
            "pan": _pan,
            "spoon": _spoon,
            "blob": _blob,
            "teddy": _teddy,
            "mitten": _mitten,
            "cushion": _cushion,
            "sheet": _sheet,
            "rock": _rock,
        }
    )
)

FAMILIES: tuple[str, ...] = tuple(_BUILDERS)
"""Names of every silhouette family, in a fixed order."""


# --------------------------------------------------------------------------- API


def _builder(family: str) -> Callable[[float, float, float, float], list[_Part]]:
    try:
        return _BUILDERS[family]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown silhouette family {family!r}; valid families: {', '.join(FAMILIES)}"
        ) from None


def _variant(variant: Sequence[float] | np.ndarray) -> tuple[float, float, float, float]:
    v = np.asarray(variant, dtype=float).reshape(-1)
    if v.shape != (4,) or not np.all(np.isfinite(v)):
        raise ValueError(f"variant must be 4 finite numbers in [0, 1], got {variant!r}")
    v = np.clip(v, 0.0, 1.0)
    return float(v[0]), float(v[1]), float(v[2]), float(v[3])


def _parts_and_extent(
    family: str, variant: Sequence[float] | np.ndarray
) -> tuple[list[_Part], tuple[float, float, float, float]]:
    parts = _builder(family)(*_variant(variant))
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
    _builder(family)
    try:
        h, w = (int(s) for s in shape_hw)
    except (TypeError, ValueError):
        raise ValueError(f"shape_hw must be (H, W), got {shape_hw!r}") from None
    if h < 0 or w < 0:
        raise ValueError(f"shape_hw must be non-negative, got {shape_hw!r}")
    try:
        bx0, by0, bx1, by1 = (float(t) for t in bbox)
    except (TypeError, ValueError):
        raise ValueError(f"bbox must be (x0, y0, x1, y1), got {bbox!r}") from None
    if not all(math.isfinite(t) for t in (bx0, by0, bx1, by1)):
        raise ValueError(f"bbox must be finite, got {bbox!r}")
    if bx1 <= bx0 or by1 <= by0:
        raise ValueError(f"degenerate bbox {bbox!r}: need x1 > x0 and y1 > y0")
    vals = _variant(variant)

    out = np.zeros((h, w), dtype=bool)
    c0, c1 = max(0, math.floor(bx0)), min(w, math.ceil(bx1))
    r0, r1 = max(0, math.floor(by0)), min(h, math.ceil(by1))
    if c0 >= c1 or r0 >= r1:
        return out

    parts, (ex0, ey0, ex1, ey1) = _parts_and_extent(family, vals)
    bw, bh = bx1 - bx0, by1 - by0
    cols = np.arange(c0, c1, dtype=float) + 0.5
    rows = np.arange(r0, r1, dtype=float) + 0.5
    # Flip: sample the mirrored positions in increasing design x, then reverse the columns.
    u = (bx1 - cols[::-1]) / bw if flip else (cols - bx0) / bw
    X = ex0 + u * (ex1 - ex0)
    Y = ey0 + (rows - by0) / bh * (ey1 - ey0)
    pdx, pdy = (ex1 - ex0) / bw, (ey1 - ey0) / bh

    sub = out[r0:r1, c0:c1]
    if flip:
        sub = sub[:, ::-1]  # a view: writing into it writes the mirrored columns of `out`
    for additive, prim in parts:
        if additive:
            res = prim.render(X, Y, pdx, pdy)
        else:
            hx0, hy0, hx1, hy1 = prim.ext
            if hx1 - hx0 < _MIN_HOLE_PX * pdx or hy1 - hy0 < _MIN_HOLE_PX * pdy:
                continue
            res = prim.render(X, Y, 0.0, 0.0)  # holes are never widened
        if res is None:
            continue
        (i0, i1, j0, j1), local = res
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
        raise ValueError(f"mask must be 2-D, got shape {m.shape}")
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

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

from ratouch.errors import ConfigError

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
# Half-height of the row footprint over which thin ellipses are sampled (a little under half a
# pixel, so that an ellipse ending exactly on a pixel edge grows no nub into the next row).
_FOOT_PX = 0.45
# Tilted ellipses with a minor radius under this many pixels are sampled over row footprints.
_THIN_PX = 2.5
# Corner radii under this many pixels are not worth drawing.
_MIN_CORNER_PX = 1.0
# Holes (subtractive parts) narrower than this many pixels are skipped rather than drawn:
# at small scales they would only eat away the thin walls around them.
_MIN_HOLE_PX = 2.0


# --------------------------------------------------------------------------- primitives


class _Grid:
    """The pixel-centre samples of the bbox sub-grid, in design coordinates.

    Column k sits at x0 + k * dx (k < nx), row j at y0 + j * dy (j < ny); dx and dy are
    also the size of one pixel in design units.
    """

    __slots__ = ("X", "Y", "x0", "y0", "dx", "dy", "nx", "ny")

    def __init__(self, x0: float, y0: float, dx: float, dy: float, nx: int, ny: int) -> None:
        self.x0, self.y0, self.dx, self.dy, self.nx, self.ny = x0, y0, dx, dy, nx, ny
        self.X = x0 + np.arange(nx) * dx
        self.Y = y0 + np.arange(ny) * dy

    @staticmethod
    def _span(lo: float, hi: float, start: float, step: float, n: int) -> tuple[int, int]:
        a = (lo - start) / step
        b = (hi - start) / step
        i0 = 0 if a <= 0.0 else (math.ceil(a) if a < n else n)
        i1 = n if b >= n - 1 else (math.floor(b) + 1 if b >= 0.0 else 0)
        return i0, i1

    def cols(self, lo: float, hi: float) -> tuple[int, int]:
        """Index range [i0, i1) of the columns with lo <= x <= hi."""
        return self._span(lo, hi, self.x0, self.dx, self.nx)

    def rows(self, lo: float, hi: float) -> tuple[int, int]:
        """Index range [j0, j1) of the rows with lo <= y <= hi."""
        return self._span(lo, hi, self.y0, self.dy, self.ny)


# (i0, i1, j0, j1, local): local is a bool array of shape (j1 - j0, i1 - i0), or True for
# "the whole window".
_Render = tuple[int, int, int, int, "np.ndarray | bool"]


class _Prim:
    """A primitive shape in design coordinates.

    Attributes:
        ext: (x0, y0, x1, y1), the exact extent of the primitive (before any widening).
    """

    __slots__ = ("ext",)

    def render(self, g: _Grid, grow: bool) -> _Render | None:
        """Rasterise on the grid.

        Args:
            g: the sample grid.
            grow: widen sub-pixel parts to about a pixel and sample sharp ends over the pixel
                footprint (for additive parts; holes are drawn exactly).

        Returns:
            (i0, i1, j0, j1, local), or None when the primitive covers no sample.
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

    def render(self, g: _Grid, grow: bool) -> _Render | None:
        hw, hh = self.hw, self.hh
        if grow:
            hw = max(hw, _MIN_HALF_PX * g.dx)
            hh = max(hh, _MIN_HALF_PX * g.dy)
        i0, i1 = g.cols(self.cx - hw, self.cx + hw)
        j0, j1 = g.rows(self.cy - hh, self.cy + hh)
        if i0 >= i1 or j0 >= j1:
            return None
        r = min(self.r, hw, hh)
        if r < _MIN_CORNER_PX * max(g.dx, g.dy):
            return i0, i1, j0, j1, True
        ax = np.maximum(np.abs(g.X[i0:i1] - self.cx) - (hw - r), 0.0)
        ay = np.maximum(np.abs(g.Y[j0:j1] - self.cy) - (hh - r), 0.0)
        return i0, i1, j0, j1, (ay * ay)[:, None] + (ax * ax)[None, :] <= r * r


def _half_widths(d: np.ndarray, r_along: float, r_across: float) -> np.ndarray:
    """Half-chord of an ellipse at distances d from its centre (-1 where it misses)."""
    q = d / r_across
    q = 1.0 - q * q
    return np.where(q > 0.0, r_along * np.sqrt(np.maximum(q, 0.0)), -1.0)


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
                raise ConfigError("a rotated ellipse cannot be clipped")
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
            raise ConfigError("clip box misses the ellipse")
        yn = min(max(cy, ya), yb)  # row of the clip band nearest the centre: widest there
        xn = min(max(cx, xa), xb)
        hw = rx * math.sqrt(max(0.0, 1.0 - ((yn - cy) / ry) ** 2))
        hh = ry * math.sqrt(max(0.0, 1.0 - ((xn - cx) / rx) ** 2))
        return (max(xlo, cx - hw), max(ylo, cy - hh), min(xhi, cx + hw), min(yhi, cy + hh))

    def render(self, g: _Grid, grow: bool) -> _Render | None:
        if self.sin != 0.0:
            return self._render_rotated(g, grow)
        cx, cy, rx, ry = self.cx, self.cy, self.rx, self.ry
        if grow:
            rx = max(rx, _MIN_RADIUS_PX * g.dx)
            ry = max(ry, _MIN_RADIUS_PX * g.dy)
        xlo, xhi, ylo, yhi = self.clip
        rx_px, ry_px = rx / g.dx, ry / g.dy
        # Evaluate as one interval per row (per column for tall ellipses). A flat ellipse only
        # a few pixels high would lose its pointed ends between two rows of pixel centres, so
        # then each row is tested over its pixel footprint instead of its centre.
        by_rows = rx_px >= ry_px
        if by_rows:
            foot = _FOOT_PX * g.dy if grow and ry_px * ry_px < 2.0 * rx_px else 0.0
            i0, i1 = g.cols(max(xlo, cx - rx), min(xhi, cx + rx))
            j0, j1 = g.rows(max(ylo, cy - ry - foot), min(yhi, cy + ry + foot))
        else:
            foot = _FOOT_PX * g.dx if grow and rx_px * rx_px < 2.0 * ry_px else 0.0
            i0, i1 = g.cols(max(xlo, cx - rx - foot), min(xhi, cx + rx + foot))
            j0, j1 = g.rows(max(ylo, cy - ry), min(yhi, cy + ry))
        if i0 >= i1 or j0 >= j1:
            return None
        ax = np.abs(g.X[i0:i1] - cx)
        ay = np.abs(g.Y[j0:j1] - cy)
        if not by_rows:
            ax, ay, rx, ry = ay, ax, ry, rx  # work on the transpose
        hw = _half_widths(np.maximum(ay - foot, 0.0), rx, ry)
        inside = ax[None, :] <= hw[:, None]
        if self.hole > 0.0:
            t_along = self.hole
            t_across = self.hole
            if grow:
                t_along = max(t_along, _MIN_RING_PX * (g.dx if by_rows else g.dy))
                t_across = max(t_across, _MIN_RING_PX * (g.dy if by_rows else g.dx))
            irx, iry = rx - t_along, ry - t_across
            if irx > 0.0 and iry > 0.0:
                inside &= ax[None, :] > _half_widths(ay + foot, irx, iry)[:, None]
        return i0, i1, j0, j1, inside if by_rows else inside.T

    def _render_rotated(self, g: _Grid, grow: bool) -> _Render | None:
        # One interval per row, from the ellipse's quadratic form A x^2 + B x y + C y^2 <= 1.
        # With `grow`, each row takes the union of the chords over its pixel footprint (the
        # left boundary is convex, so its minimum is at a footprint end or at the leftmost
        # point), so thin tilted parts keep their tips.
        cx, cy, rx, ry = self.cx, self.cy, self.rx, self.ry
        if grow:
            m = _MIN_RADIUS_PX * max(g.dx, g.dy)
            rx, ry = max(rx, m), max(ry, m)
        c, s = self.cos, self.sin
        if not grow or min(rx, ry) >= _THIN_PX * max(g.dx, g.dy):
            # Fat enough for plain pixel-centre sampling of the quadratic form.
            hx, hy = math.hypot(rx * c, ry * s), math.hypot(rx * s, ry * c)
            i0, i1 = g.cols(cx - hx, cx + hx)
            j0, j1 = g.rows(cy - hy, cy + hy)
            if i0 >= i1 or j0 >= j1:
                return None
            ex = (g.X[i0:i1] - cx)[None, :]
            ey = (g.Y[j0:j1] - cy)[:, None]
            t1 = ex * (c / rx) + ey * (s / rx)
            t2 = ey * (c / ry) - ex * (s / ry)
            return i0, i1, j0, j1, t1 * t1 + t2 * t2 <= 1.0
        A = c * c / (rx * rx) + s * s / (ry * ry)
        B = 2.0 * c * s * (1.0 / (rx * rx) - 1.0 / (ry * ry))
        C = s * s / (rx * rx) + c * c / (ry * ry)
        K = 4.0 / (rx * rx * ry * ry)  # 4AC - B^2
        hx, hy = math.hypot(rx * c, ry * s), math.hypot(rx * s, ry * c)
        foot = _FOOT_PX * g.dy if grow else 0.0
        i0, i1 = g.cols(cx - hx, cx + hx)
        j0, j1 = g.rows(cy - hy - foot, cy + hy + foot)
        if i0 >= i1 or j0 >= j1:
            return None
        dy = g.Y[j0:j1] - cy
        lo = np.maximum(dy - foot, -hy)
        hi = np.minimum(dy + foot, hy)

        def bounds(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            root = np.sqrt(np.maximum(4.0 * A - K * t * t, 0.0))
            return (-B * t - root) / (2.0 * A), (-B * t + root) / (2.0 * A)

        l1, r1 = bounds(lo)
        l2, r2 = bounds(hi)
        left, right = np.minimum(l1, l2), np.maximum(r1, r2)
        y_left = B * hx / (2.0 * C)  # row of the leftmost point (the rightmost is mirrored)
        left = np.where((lo <= y_left) & (y_left <= hi), -hx, left)
        right = np.where((lo <= -y_left) & (-y_left <= hi), hx, right)
        if grow:
            mid = (left + right) * 0.5
            half = np.maximum((right - left) * 0.5, _MIN_HALF_PX * g.dx)
            left, right = mid - half, mid + half
        left = np.where(lo <= hi, left, _INF)
        ax = (g.X[i0:i1] - cx)[None, :]
        return i0, i1, j0, j1, (ax >= left[:, None]) & (ax <= right[:, None])


def _local_extremes(v: np.ndarray, lower: bool) -> np.ndarray:
    """Indices of the knots where the piecewise-linear v has a local minimum (or maximum)."""
    w = v if lower else -v
    prev = np.concatenate(([_INF], w[:-1]))
    nxt = np.concatenate((w[1:], [_INF]))
    return np.flatnonzero((w <= prev) & (w <= nxt))


def _footprint_extremes(
    t: np.ndarray, step: float, kt: np.ndarray, lo: np.ndarray, hi: np.ndarray,
    lo_knots: np.ndarray, hi_knots: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Min of the piecewise-linear `lo` and max of `hi` over each sample's pixel footprint.

    Sampling a polygon's edge only at pixel centres can miss a sharp vertex by up to half a
    pixel times the edge slope (several pixels for a squashed shape); taking the extremes over
    the footprint [t - step/2, t + step/2] instead never misses a vertex, so polygon extremes
    land on the bbox sides and sub-pixel-thin polygons stay visible. Over an interval, a
    piecewise-linear function peaks at an end or at a local-extreme knot.

    Args:
        t: sample positions, uniformly spaced by `step`, increasing.
        step: sample spacing (0: plain point sampling).
        kt: knot positions (non-decreasing).
        lo: knot values whose footprint minimum is wanted.
        hi: knot values whose footprint maximum is wanted.
        lo_knots: indices of the local minima of `lo`.
        hi_knots: indices of the local maxima of `hi`.

    Returns:
        (lo_min, hi_max), one value per sample.
    """
    if step <= 0.0:
        return np.interp(t, kt, lo), np.interp(t, kt, hi)
    h = 0.5 * step
    a, b = t - h, t + h
    lo_min = np.minimum(np.interp(a, kt, lo), np.interp(b, kt, lo))
    hi_max = np.maximum(np.interp(a, kt, hi), np.interp(b, kt, hi))
    t0, n = float(t[0]), t.size
    for k in lo_knots.tolist():
        j = round((float(kt[k]) - t0) / step)
        if 0 <= j < n and lo[k] < lo_min[j]:
            lo_min[j] = lo[k]
    for k in hi_knots.tolist():
        j = round((float(kt[k]) - t0) / step)
        if 0 <= j < n and hi[k] > hi_max[j]:
            hi_max[j] = hi[k]
    return lo_min, hi_max


class _YPoly(_Prim):
    """Region whose every row y in [ys[0], ys[-1]] is one interval [xl(y), xr(y)].

    xl and xr are piecewise linear through the knots (ys non-decreasing).
    """

    __slots__ = ("ys", "xl", "xr", "kl", "kr")

    def __init__(self, ys: np.ndarray, xl: np.ndarray, xr: np.ndarray) -> None:
        self.ys = np.asarray(ys, dtype=float)
        self.xl = np.asarray(xl, dtype=float)
        self.xr = np.asarray(xr, dtype=float)
        self.kl = _local_extremes(self.xl, lower=True)
        self.kr = _local_extremes(self.xr, lower=False)
        self.ext = (
            float(self.xl.min()), float(self.ys[0]), float(self.xr.max()), float(self.ys[-1])
        )

    def render(self, g: _Grid, grow: bool) -> _Render | None:
        x0, y0, x1, y1 = self.ext
        wmin = _MIN_HALF_PX * g.dx if grow else 0.0
        if grow:
            hmin = _MIN_HALF_PX * g.dy
            if (y1 - y0) / 2.0 < hmin:
                c = (y0 + y1) / 2.0
                y0, y1 = c - hmin, c + hmin
            # Rows whose centre is just beyond the ends still see the end knots in their
            # footprint (they get the end interval).
            y0, y1 = y0 - _END_PX * g.dy, y1 + _END_PX * g.dy
        i0, i1 = g.cols(x0 - wmin, x1 + wmin)
        j0, j1 = g.rows(y0, y1)
        if i0 >= i1 or j0 >= j1:
            return None
        left, right = _footprint_extremes(
            g.Y[j0:j1], g.dy if grow else 0.0, self.ys, self.xl, self.xr, self.kl, self.kr
        )
        if grow:
            mid = (left + right) * 0.5
            half = np.maximum((right - left) * 0.5, wmin)
            left, right = mid - half, mid + half
        xs = g.X[i0:i1][None, :]
        return i0, i1, j0, j1, (xs >= left[:, None]) & (xs <= right[:, None])


class _XPoly(_Prim):
    """Region whose every column x in [xs[0], xs[-1]] is one interval [yt(x), yb(x)]."""

    __slots__ = ("xs", "yt", "yb", "kt", "kb")

    def __init__(self, xs: np.ndarray, yt: np.ndarray, yb: np.ndarray) -> None:
        self.xs = np.asarray(xs, dtype=float)
        self.yt = np.asarray(yt, dtype=float)
        self.yb = np.asarray(yb, dtype=float)
        self.kt = _local_extremes(self.yt, lower=True)
        self.kb = _local_extremes(self.yb, lower=False)
        self.ext = (
            float(self.xs[0]), float(self.yt.min()), float(self.xs[-1]), float(self.yb.max())
        )

    def render(self, g: _Grid, grow: bool) -> _Render | None:
        x0, y0, x1, y1 = self.ext
        hmin = _MIN_HALF_PX * g.dy if grow else 0.0
        if grow:
            wmin = _MIN_HALF_PX * g.dx
            if (x1 - x0) / 2.0 < wmin:
                c = (x0 + x1) / 2.0
                x0, x1 = c - wmin, c + wmin
            x0, x1 = x0 - _END_PX * g.dx, x1 + _END_PX * g.dx
        i0, i1 = g.cols(x0, x1)
        j0, j1 = g.rows(y0 - hmin, y1 + hmin)
        if i0 >= i1 or j0 >= j1:
            return None
        top, bot = _footprint_extremes(
            g.X[i0:i1], g.dx if grow else 0.0, self.xs, self.yt, self.yb, self.kt, self.kb
        )
        if grow:
            mid = (top + bot) * 0.5
            half = np.maximum((bot - top) * 0.5, hmin)
            top, bot = mid - half, mid + half
        ys = g.Y[j0:j1][:, None]
        return i0, i1, j0, j1, (ys >= top[None, :]) & (ys <= bot[None, :])


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
    dx, dy = 0.28 + 0.16 * a, 0.22 + 0.12 * b
    return [_add(_poly([(0, dy), (dx, 0), (w, 0), (w, h - dy), (w - dx, h), (0, h)]))]


def _rounded_box(a: float, b: float, c: float, d: float) -> list[_Part]:
    # A lidded storage box: an overhanging lid on a body with well-rounded lower corners.
    w = 1.25 + 0.3 * c
    r = 0.2 + 0.1 * a
    lid = 0.2 + 0.08 * b
    ov = 0.06 + 0.03 * d  # lid overhang
    return [
        _add(_Rect(0.0, 0.0, w, lid, r=0.05)),
        _add(_Rect(ov, lid - 0.02, w - ov, 0.6)),
        _add(_Rect(ov, 0.3, w - ov, 1.0, r=r)),
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
    # A low shoe in side view, heel left: collar, opening, tongue, laced slope, rounded toe.
    h = 0.4  # natural height (length 1)
    dip = 0.22 + 0.12 * a  # depth of the opening behind the tongue
    tongue = 0.36 + 0.08 * d
    toe_top = 0.5 + 0.12 * b
    heel = 0.06 + 0.06 * c
    ry = (1.0 - toe_top) / 2.0
    xs = np.array([0.0, 0.03, 0.09, 0.15, 0.26, tongue, tongue + 0.04, 0.88])
    yt = np.array([0.16, 0.02, 0.0, 0.06, dip, dip * 0.5, dip * 0.55, toe_top])
    yb = np.array([1.0 - heel, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    return [
        _add(_XPoly(xs, yt * h, yb * h)),
        _add(_Ellipse(0.88, (toe_top + ry) * h, 0.12, ry * h)),
        _add(_Rect(0.02, (1.0 - 0.06) * h, 0.9, h)),  # sole
    ]


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
    torso = _poly([(0.5 - tw, 0.1), (0.5 - neck - 0.05, 0.0), (0.5 + neck + 0.05, 0.0),
                   (0.5 + tw, 0.1),
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
    gap = 0.05 + 0.09 * a  # half gap between the hems
    crotch = 0.28 + 0.12 * b
    flare = 0.06 * c
    wb = 0.06 + 0.03 * d  # waistband height
    leg = [(0.07, crotch - 0.01), (0.5, crotch - 0.01), (0.5 - gap, 1.45), (0.06 - flare, 1.45)]
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
        _sub(_Ellipse(0.0, -0.045, cw * 0.5, 0.08)),
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
    tx, ty = 0.25, cy - bh * 0.45  # tail root, inside the body
    tl = 0.22
    ex, ey = tx - tl * math.cos(math.radians(el)), ty - tl * math.sin(math.radians(el))
    parts = [
        _add(_Ellipse(0.55, cy, 0.37, bh)),
        _add(_Ellipse(0.87, (cy + hy) / 2.0, 0.1, abs(cy - hy) / 2.0 + 0.07, angle=25.0)),  # neck
        _add(_Ellipse(0.95, hy, hr, hr * 0.92)),
        _add(_Ellipse(1.08, hy + 0.04, 0.075, 0.055)),  # snout
        _add(_Ellipse(0.89, hy - hr * 0.85, ear * 0.5, ear, angle=-20.0)),
        _add(_Ellipse(0.99, hy - hr * 0.85, ear * 0.5, ear, angle=15.0)),
        _add(_Ellipse((tx + ex) / 2, (ty + ey) / 2, tl / 2, 0.03, angle=el)),
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
    # Palm with a rounded top narrowing to the wrist, a thumb sticking out, a cuff.
    tilt = -30.0 - 20.0 * a  # thumb angle
    tl = 0.16 + 0.05 * b  # thumb half-length
    cuff = 0.16 + 0.06 * c
    pw = 0.5 + 0.08 * d  # palm width
    x0, x1 = 0.22, 0.22 + pw
    yw = 1.0 - cuff  # wrist
    return [
        _add(_Ellipse((x0 + x1) / 2.0, pw * 0.5, pw * 0.5, pw * 0.5)),
        _add(_poly([(x0, pw * 0.5), (x1, pw * 0.5), (x1 - 0.02, yw + 0.02),
                    (x0 + 0.05, yw + 0.02)])),
        _add(_Ellipse(x0 + 0.02, 0.55, 0.095, tl, angle=tilt)),
        _add(_poly([(x0, 0.5), (x0 - 0.02, 0.62), (x0 + 0.05, 0.78), (x0 + 0.1, 0.6)])),
        _add(_Rect(x0 + 0.01, yw, x1 + 0.01, 1.0, r=0.02)),
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
        raise ConfigError(
            f"unknown silhouette family {family!r}; valid families: {', '.join(FAMILIES)}"
        ) from None


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
    grid = _Grid(gx0, gy0, dx, dy, c1 - c0, r1 - r0)

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

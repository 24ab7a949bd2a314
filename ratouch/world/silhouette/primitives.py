"""The primitive shapes of the silhouettes and the pixel grid they are rasterised on.

A primitive (ellipse or ring, rounded rectangle, y- or x-monotone polygon) lives in a family's
own design coordinates and renders itself onto the `Grid` of pixel-centre samples, only inside
its own window, with 1-D coordinate vectors broadcast to 2-D. With `grow` (additive parts),
parts thinner than a pixel are widened to about one pixel and sharp ends are sampled over the
pixel footprint, so small objects keep their limbs, legs and handles.
"""

from __future__ import annotations

import math

import numpy as np

from ratouch.errors import ConfigError

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


class Grid:
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

    def transposed(self) -> Grid:
        """The same samples with the axes swapped (x for y)."""
        return Grid(self.y0, self.x0, self.dy, self.dx, self.ny, self.nx)

    def cols(self, lo: float, hi: float) -> tuple[int, int]:
        """Index range [i0, i1) of the columns with lo <= x <= hi."""
        return self._span(lo, hi, self.x0, self.dx, self.nx)

    def rows(self, lo: float, hi: float) -> tuple[int, int]:
        """Index range [j0, j1) of the rows with lo <= y <= hi."""
        return self._span(lo, hi, self.y0, self.dy, self.ny)


# (i0, i1, j0, j1, local): local is a bool array of shape (j1 - j0, i1 - i0), or True for
# "the whole window".
Render = tuple[int, int, int, int, "np.ndarray | bool"]


class Prim:
    """A primitive shape in design coordinates.

    Attributes:
        ext: (x0, y0, x1, y1), the exact extent of the primitive (before any widening).
    """

    __slots__ = ("ext",)
    ext: tuple[float, float, float, float]

    def render(self, g: Grid, grow: bool) -> Render | None:
        """Rasterise on the grid.

        Args:
            g: the sample grid.
            grow: widen sub-pixel parts to about a pixel and sample sharp ends over the pixel
                footprint (for additive parts; holes are drawn exactly).

        Returns:
            (i0, i1, j0, j1, local), or None when the primitive covers no sample.
        """
        raise NotImplementedError


class Rect(Prim):
    """Axis-aligned rectangle with optional rounded corners (radius in design units)."""

    __slots__ = ("cx", "cy", "hw", "hh", "r")

    def __init__(self, x0: float, y0: float, x1: float, y1: float, r: float = 0.0) -> None:
        self.cx, self.cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
        self.hw, self.hh = abs(x1 - x0) / 2.0, abs(y1 - y0) / 2.0
        self.r = max(0.0, r)
        self.ext = (self.cx - self.hw, self.cy - self.hh, self.cx + self.hw, self.cy + self.hh)

    def render(self, g: Grid, grow: bool) -> Render | None:
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


class Ellipse(Prim):
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

    def render(self, g: Grid, grow: bool) -> Render | None:
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

    def _render_rotated(self, g: Grid, grow: bool) -> Render | None:
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


class YPoly(Prim):
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

    def render(self, g: Grid, grow: bool) -> Render | None:
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


class XPoly(Prim):
    """Region whose every column x in [xs[0], xs[-1]] is one interval [yt(x), yb(x)]: a
    `YPoly` with the axes swapped, rendered as one on the transposed grid.
    """

    __slots__ = ("rows",)

    def __init__(self, xs: np.ndarray, yt: np.ndarray, yb: np.ndarray) -> None:
        self.rows = YPoly(xs, yt, yb)  # its "rows" are this region's columns
        x0, y0, x1, y1 = self.rows.ext
        self.ext = (y0, x0, y1, x1)

    def render(self, g: Grid, grow: bool) -> Render | None:
        out = self.rows.render(g.transposed(), grow)
        if out is None:
            return None
        j0, j1, i0, i1, mask = out
        assert isinstance(mask, np.ndarray)  # a YPoly's mask is always an array
        return i0, i1, j0, j1, np.ascontiguousarray(mask.T)

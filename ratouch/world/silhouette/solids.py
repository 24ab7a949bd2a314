"""Plain solids and soft goods: ball, egg, box, rounded box, cushion, sheet, rock.

Each builder takes the four variant numbers (a, b, c, d) in [0, 1] and returns the parts in
drawing order: additive parts are OR-ed in, subtractive ones cut what was drawn before them.
"""

from __future__ import annotations

import math

import numpy as np

from ratouch.world.silhouette.parts import Part, add, poly, sub
from ratouch.world.silhouette.primitives import Ellipse, Rect, XPoly, YPoly


def ball(a: float, b: float, c: float, d: float) -> list[Part]:
    # A ball resting on the ground: a circle with a slightly flattened contact patch.
    return [add(Ellipse(0.0, 0.0, 1.0, 1.0, yhi=0.99 - 0.05 * a))]


def egg(a: float, b: float, c: float, d: float) -> list[Part]:
    k = 0.3 + 0.15 * a  # pointiness of the top
    t = np.linspace(-1.0, 1.0, 41)
    hw = 0.72 * np.sqrt(np.clip(1.0 - t * t, 0.0, None)) * (1.0 + k * t) / (1.0 + 0.5 * k)
    hw *= 0.9 + 0.2 * b
    return [add(YPoly(t, -hw, hw))]


def box(a: float, b: float, c: float, d: float) -> list[Part]:
    # A cuboid seen from above-right: front face + top face + side face (a hexagon).
    w, h = 1.1 + 0.4 * c, 1.0
    dx, dy = 0.28 + 0.16 * a, 0.22 + 0.12 * b
    return [add(poly([(0, dy), (dx, 0), (w, 0), (w, h - dy), (w - dx, h), (0, h)]))]


def rounded_box(a: float, b: float, c: float, d: float) -> list[Part]:
    # A lidded storage box: an overhanging lid on a body with well-rounded lower corners.
    w = 1.25 + 0.3 * c
    r = 0.2 + 0.1 * a
    lid = 0.2 + 0.08 * b
    ov = 0.06 + 0.03 * d  # lid overhang
    return [
        add(Rect(0.0, 0.0, w, lid, r=0.05)),
        add(Rect(ov, lid - 0.02, w - ov, 0.6)),
        add(Rect(ov, 0.3, w - ov, 1.0, r=r)),
    ]


def cushion(a: float, b: float, c: float, d: float) -> list[Part]:
    # A pillow: plump square with the sides pulled in towards the (pinched) corners.
    w, h = 1.0, 0.75 + 0.2 * b
    dep = 0.05 + 0.06 * a  # how far the sides are pulled in
    k = 0.03
    r = 0.02 + 0.03 * c
    return [
        add(Rect(0.0, 0.0, w, h, r=r)),
        sub(Ellipse(w / 2, -k, w * 0.43, k + dep)),
        sub(Ellipse(w / 2, h + k, w * 0.43, k + dep)),
        sub(Ellipse(-k, h / 2, k + dep, h * 0.43)),
        sub(Ellipse(w + k, h / 2, k + dep, h * 0.43)),
    ]


def sheet(a: float, b: float, c: float, d: float) -> list[Part]:
    # A flat cloth or sheet lying slightly rumpled: wavy long edges, straight short edges.
    w, h = 1.5, 0.6
    amp = 0.05 + 0.05 * a
    f = 1.5 + 1.5 * b
    ph = 2.0 * math.pi * c
    xs = np.linspace(0.0, w, 61)
    yt = amp * (0.5 + 0.5 * np.sin(2.0 * math.pi * f * xs / w + ph))
    yb = h - amp * (0.5 + 0.5 * np.sin(2.0 * math.pi * (f + 0.5) * xs / w + ph * 1.7 + d))
    return [add(XPoly(xs, yt, yb))]


def rock(a: float, b: float, c: float, d: float) -> list[Part]:
    # An irregular faceted stone with a flattish base; the variant shuffles its facets.
    n = 11
    k = np.arange(n)
    th = 2.0 * math.pi * (k + 0.25 * np.sin(k * 2.3 + 6.0 * a)) / n
    rad = 1.0 + 0.1 * np.sin(2.0 * th + 6.0 * b) + 0.07 * np.cos(3.0 * th + 6.0 * c)
    px = rad * np.cos(th) * (1.15 + 0.2 * d)
    py = np.minimum(rad * np.sin(th) * 0.75, 0.55)
    return [add(poly(list(zip(px, py))))]

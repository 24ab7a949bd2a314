"""Vessels and kitchenware: bottle, vase, mug, bowl, plate, pan, spoon.

Each builder takes the four variant numbers (a, b, c, d) in [0, 1] and returns the parts in
drawing order: additive parts are OR-ed in, subtractive ones cut what was drawn before them.
"""

from __future__ import annotations

from ratouch.world.silhouette.parts import Part, add, eased, poly, profile, sub
from ratouch.world.silhouette.primitives import Ellipse, Rect


def bottle(a: float, b: float, c: float, d: float) -> list[Part]:
    bw = 0.16 + 0.08 * b  # body half-width
    nw = 0.045 + 0.025 * c  # neck half-width
    cw = nw + 0.012 + 0.01 * d  # cap half-width
    ch = 0.05 + 0.03 * d  # cap height
    nl = 0.1 + 0.2 * a  # neck length
    sl = 0.08 + 0.12 * c  # shoulder length
    ys = ch + nl
    knots = [(0.0, cw), (ch, cw), (ch + 1e-6, nw), (ys, nw)]
    knots += eased([(ys, nw), (ys + sl, bw)], 10)[1:]
    knots += [(0.96, bw), (0.985, bw - 0.012), (1.0, bw - 0.035)]
    return [add(profile(knots))]


def vase(a: float, b: float, c: float, d: float) -> list[Part]:
    lip = 0.16 + 0.06 * d
    ny = 0.12 + 0.12 * a  # neck height
    neck = 0.08 + 0.05 * c
    by = 0.5 + 0.15 * a  # belly height
    belly = 0.3 + 0.08 * b
    foot = 0.14 + 0.04 * c
    knots = eased([(0.0, lip), (ny, neck), (by, belly), (0.94, foot)], 10)
    knots += [(1.0, foot + 0.02)]
    return [add(profile(knots))]


def mug(a: float, b: float, c: float, d: float) -> list[Part]:
    w = 0.7 + 0.2 * c  # body width (height 1)
    rx = 0.2 + 0.1 * a
    ry = 0.25 + 0.1 * b
    t = 0.07 + 0.04 * d
    return [
        add(Rect(0.0, 0.0, w, 1.0, r=0.08)),
        add(Ellipse(w - 0.04, 0.45, rx, ry, hole=t, xlo=w - 0.06)),
    ]


def bowl(a: float, b: float, c: float, d: float) -> list[Part]:
    depth = 0.45 + 0.35 * a
    rim = 0.03 + 0.03 * b
    fw = 0.25 + 0.15 * c
    return [
        add(Ellipse(0.0, 0.0, 1.0, depth, ylo=0.0)),
        add(Rect(-1.05, -rim, 1.05, rim * 0.6, r=rim * 0.5)),
        add(Rect(-fw, depth * 0.9, fw, depth + 0.09)),
    ]


def plate(a: float, b: float, c: float, d: float) -> list[Part]:
    # A plate seen from a low angle: elliptical face, shallow underside, narrow foot ring.
    e = 0.13 + 0.1 * a
    fw = 0.42 + 0.15 * c
    under = 0.12 + 0.06 * b
    return [
        add(Ellipse(0.0, 0.0, 1.0, e)),
        add(Ellipse(0.0, 0.0, 0.9, e + under, ylo=0.0)),
        add(Rect(-fw, e + under * 0.6, fw, e + under + 0.05, r=0.015)),
    ]


def pan(a: float, b: float, c: float, d: float) -> list[Part]:
    ry = 0.55 + 0.35 * b  # perspective squash of the pan disc
    hl = 0.9 + 0.6 * a  # handle length
    ht = 0.07 + 0.05 * c  # handle half-thickness
    s = 0.25 * d  # handle rise per unit length
    x0, x1 = 0.85, 0.85 + hl
    yend = -s * hl
    return [
        add(Ellipse(0.0, 0.0, 1.0, ry)),
        add(poly([(x0, -ht), (x1, yend - ht * 1.2), (x1, yend + ht * 1.2), (x0, ht)])),
        add(Ellipse(x1, yend, ht * 1.4, ht * 1.4)),
        sub(Ellipse(x1 - ht * 0.2, yend, ht * 0.55, ht * 0.55)),  # hanging hole
    ]


def spoon(a: float, b: float, c: float, d: float) -> list[Part]:
    bl = 0.15 + 0.06 * a  # bowl half-length
    bh = 0.09 + 0.03 * b  # bowl half-height
    hw = 0.025 + 0.015 * c  # handle half-width at the end
    return [
        add(Ellipse(bl, 0.0, bl, bh)),
        add(poly([(bl * 1.6, -0.014), (0.95, -hw), (0.95, hw), (bl * 1.6, 0.014)])),
        add(Ellipse(0.95, 0.0, 0.05, hw * 1.25)),
    ]

"""Clothing, footwear and bags: boot, shoe, bag, shirt, trousers, hat, mitten.

Each builder takes the four variant numbers (a, b, c, d) in [0, 1] and returns the parts in
drawing order: additive parts are OR-ed in, subtractive ones cut what was drawn before them.
"""

from __future__ import annotations

import math

import numpy as np

from ratouch.world.silhouette.parts import Part, add, mirror, poly, sub
from ratouch.world.silhouette.primitives import Ellipse, Rect, XPoly


def boot(a: float, b: float, c: float, d: float) -> list[Part]:
    sw = 0.36 + 0.1 * b  # shaft width
    fy = 0.56 + 0.12 * a  # where the foot starts (shaft height)
    toe = 0.85 + 0.2 * c  # toe reach
    ty = fy + 0.12 * (1.0 - fy)  # top of the foot at the toe
    ry = (1.0 - ty) / 2.0
    rx = ry * 1.3
    heel = 0.07 + 0.04 * d
    return [
        add(Rect(-0.02, 0.0, sw + 0.02, 0.08, r=0.015)),  # cuff
        add(Rect(0.0, 0.04, sw, fy + 0.05)),
        add(poly([(0.0, fy), (sw, fy), (toe - rx, ty), (toe - rx, 1.0), (0.0, 1.0)])),
        add(Ellipse(toe - rx, ty + ry, rx, ry)),
        add(Rect(-0.01, 1.0 - heel, 0.24, 1.0)),  # heel
        add(Rect(0.0, 1.0 - 0.035, toe - rx * 0.5, 1.0)),  # sole
    ]


def shoe(a: float, b: float, c: float, d: float) -> list[Part]:
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
        add(XPoly(xs, yt * h, yb * h)),
        add(Ellipse(0.88, (toe_top + ry) * h, 0.12, ry * h)),
        add(Rect(0.02, (1.0 - 0.06) * h, 0.9, h)),  # sole
    ]


def bag(a: float, b: float, c: float, d: float) -> list[Part]:
    rx = 0.18 + 0.14 * a  # handle half-width
    ry = 0.28 + 0.12 * b  # handle height
    t = 0.045 + 0.035 * c  # handle thickness
    top = 0.3 + 0.08 * d  # body half-width at the top (bottom: 0.5)
    y0, y1, ch = ry, ry + 1.0, 0.06
    return [
        add(Ellipse(0.0, y0 + 0.02, rx, ry + 0.02, hole=t, yhi=y0 + 0.04)),
        add(poly([(-top, y0), (top, y0), (0.5, y1 - ch), (0.5 - ch * 0.7, y1),
                  (-0.5 + ch * 0.7, y1), (-0.5, y1 - ch)])),
    ]


def shirt(a: float, b: float, c: float, d: float) -> list[Part]:
    tw = 0.22 + 0.05 * c  # torso half-width (centre x = 0.5)
    theta = math.radians(28.0 + 30.0 * a)  # sleeve droop
    length = 0.28 + 0.36 * a  # sleeve length
    sw = 0.17 + 0.05 * b  # sleeve width
    neck = 0.09 + 0.03 * d
    torso = poly([(0.5 - tw, 0.1), (0.5 - neck - 0.05, 0.0), (0.5 + neck + 0.05, 0.0),
                  (0.5 + tw, 0.1),
                  (0.5 + tw, 1.0), (0.5 - tw, 1.0)])
    p1 = (0.5 + neck + 0.04, 0.005)
    p2 = (p1[0] + length * math.cos(theta), p1[1] + length * math.sin(theta))
    p3 = (p2[0] - sw * math.sin(theta), p2[1] + sw * math.cos(theta))
    p4 = (0.5 + tw, 0.26 + 0.06 * b)
    sleeve = [p1, p2, p3, p4]
    return [
        add(torso),
        add(poly(sleeve)),
        add(poly(mirror(sleeve, 0.5))),
        sub(Ellipse(0.5, -0.01, neck, 0.06 + 0.03 * d)),
    ]


def trousers(a: float, b: float, c: float, d: float) -> list[Part]:
    gap = 0.05 + 0.09 * a  # half gap between the hems
    crotch = 0.28 + 0.12 * b
    flare = 0.06 * c
    wb = 0.06 + 0.03 * d  # waistband height
    leg = [(0.07, crotch - 0.01), (0.5, crotch - 0.01), (0.5 - gap, 1.45), (0.06 - flare, 1.45)]
    return [
        add(Rect(0.1, 0.0, 0.9, wb)),
        add(poly([(0.1, wb * 0.5), (0.9, wb * 0.5), (0.93, crotch), (0.07, crotch)])),
        add(poly(leg)),
        add(poly(mirror(leg, 0.5))),
    ]


def hat(a: float, b: float, c: float, d: float) -> list[Part]:
    # A fedora: tapered crown with a pinched top, on a wide elliptical brim.
    brim = 0.5 + 0.25 * a  # brim half-width
    bh = 0.07 + 0.05 * b  # brim half-height
    ch = 0.45 + 0.3 * c  # crown height
    cw = 0.28 + 0.05 * d  # crown half-width at the band
    return [
        add(poly([(-cw * 0.85, 0.0), (cw * 0.85, 0.0), (cw, ch), (-cw, ch)])),
        sub(Ellipse(0.0, -0.045, cw * 0.5, 0.08)),
        add(Ellipse(0.0, ch, brim, bh)),
    ]


def mitten(a: float, b: float, c: float, d: float) -> list[Part]:
    # Palm with a rounded top narrowing to the wrist, a thumb sticking out, a cuff.
    tilt = -30.0 - 20.0 * a  # thumb angle
    tl = 0.16 + 0.05 * b  # thumb half-length
    cuff = 0.16 + 0.06 * c
    pw = 0.5 + 0.08 * d  # palm width
    x0, x1 = 0.22, 0.22 + pw
    yw = 1.0 - cuff  # wrist
    return [
        add(Ellipse((x0 + x1) / 2.0, pw * 0.5, pw * 0.5, pw * 0.5)),
        add(poly([(x0, pw * 0.5), (x1, pw * 0.5), (x1 - 0.02, yw + 0.02),
                  (x0 + 0.05, yw + 0.02)])),
        add(Ellipse(x0 + 0.02, 0.55, 0.095, tl, angle=tilt)),
        add(poly([(x0, 0.5), (x0 - 0.02, 0.62), (x0 + 0.05, 0.78), (x0 + 0.1, 0.6)])),
        add(Rect(x0 + 0.01, yw, x1 + 0.01, 1.0, r=0.02)),
    ]

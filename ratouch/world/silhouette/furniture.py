"""Furniture and other rigid household objects: lamp, chair, table, guitar.

Each builder takes the four variant numbers (a, b, c, d) in [0, 1] and returns the parts in
drawing order: additive parts are OR-ed in, subtractive ones cut what was drawn before them.
"""

from __future__ import annotations

from ratouch.world.silhouette.parts import Part, add, poly, profile, sub
from ratouch.world.silhouette.primitives import Ellipse, Rect


def lamp(a: float, b: float, c: float, d: float) -> list[Part]:
    sh = 0.3 + 0.14 * a  # shade height
    top = 0.2 + 0.1 * d
    sw = 0.02 + 0.02 * b  # stem half-width
    bw = 0.16 + 0.1 * c  # base half-width
    return [
        add(profile([(0.0, top), (sh, 0.42)])),
        add(Rect(-0.42, sh - 0.03, 0.42, sh)),  # shade rim
        add(Rect(-sw, sh - 0.02, sw, 0.92)),
        add(Rect(-0.035, sh + 0.22, 0.035, sh + 0.27, r=0.01)),  # switch knuckle
        add(Rect(-bw, 0.9, bw, 1.0, r=0.035)),
    ]


def chair(a: float, b: float, c: float, d: float) -> list[Part]:
    # Side view: slanted back post running into the rear leg, seat, front leg, stretcher.
    sy = 0.48 + 0.1 * a  # seat height (from the top of the back)
    st = 0.08 + 0.03 * b  # seat thickness
    lt = 0.075 + 0.03 * c  # leg thickness
    tilt = 0.03 + 0.06 * d
    bw = lt + 0.03
    depth = 0.85
    return [
        add(poly([(0.0, 0.0), (bw, 0.0), (tilt + bw, sy), (tilt, sy)])),
        add(Rect(0.0, 0.0, bw, 0.12)),  # backrest top rail
        add(Rect(tilt, sy, tilt + lt, 1.0)),
        add(Rect(0.0, sy, depth, sy + st, r=0.01)),
        add(Rect(depth - lt, sy, depth, 1.0)),
        add(Rect(tilt, 0.81, depth, 0.85)),
    ]


def table(a: float, b: float, c: float, d: float) -> list[Part]:
    w, h = 1.4, 0.8
    tt = 0.06 + 0.04 * a  # top thickness
    ap = 0.06 + 0.05 * b  # apron depth
    inset = 0.05 + 0.12 * c
    lw = 0.08 + 0.04 * d
    return [
        add(Rect(0.0, 0.0, w, tt, r=0.01)),
        add(Rect(inset, tt, w - inset, tt + ap)),
        add(Rect(inset, tt, inset + lw, h)),
        add(Rect(w - inset - lw, tt, w - inset, h)),
    ]


def guitar(a: float, b: float, c: float, d: float) -> list[Part]:
    lb = 0.22 + 0.04 * b  # lower bout radius
    ub = lb * (0.72 + 0.1 * b)
    neck = 0.3 + 0.15 * a  # neck length above the body
    hs = 0.1 + 0.04 * d  # headstock length
    hole = 0.045 + 0.03 * c
    y_ub = hs + neck + ub * 0.85
    y_lb = y_ub + ub + lb * 0.55
    return [
        add(Rect(-0.055, 0.0, 0.055, hs, r=0.02)),
        add(Rect(-0.032, hs - 0.01, 0.032, y_ub)),
        add(Ellipse(0.0, y_ub, ub, ub)),
        add(Ellipse(0.0, y_lb, lb, lb)),
        sub(Ellipse(0.0, y_ub + ub * 0.75, hole, hole)),
    ]

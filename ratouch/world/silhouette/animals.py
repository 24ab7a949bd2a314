"""Animals and soft toys: blob (a four-legged animal), teddy.

Each builder takes the four variant numbers (a, b, c, d) in [0, 1] and returns the parts in
drawing order: additive parts are OR-ed in, subtractive ones cut what was drawn before them.
"""

from __future__ import annotations

import math

from ratouch.world.silhouette.parts import Part, add
from ratouch.world.silhouette.primitives import Ellipse, Rect


def blob(a: float, b: float, c: float, d: float) -> list[Part]:
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
        add(Ellipse(0.55, cy, 0.37, bh)),
        add(Ellipse(0.87, (cy + hy) / 2.0, 0.1, abs(cy - hy) / 2.0 + 0.07, angle=25.0)),  # neck
        add(Ellipse(0.95, hy, hr, hr * 0.92)),
        add(Ellipse(1.08, hy + 0.04, 0.075, 0.055)),  # snout
        add(Ellipse(0.89, hy - hr * 0.85, ear * 0.5, ear, angle=-20.0)),
        add(Ellipse(0.99, hy - hr * 0.85, ear * 0.5, ear, angle=15.0)),
        add(Ellipse((tx + ex) / 2, (ty + ey) / 2, tl / 2, 0.03, angle=el)),
    ]
    for x in (0.26 - spread, 0.37 - spread, 0.7 + spread, 0.8 + spread):
        parts.append(add(Rect(x, cy, x + 0.075, 1.0, r=0.02)))
    return parts


def teddy(a: float, b: float, c: float, d: float) -> list[Part]:
    er = 0.07 + 0.03 * c  # ear radius
    arm = 35.0 + 30.0 * b  # arm angle below the horizontal
    spread = 0.1 + 0.06 * d
    bw = 0.2 + 0.05 * a
    return [
        add(Ellipse(-0.16, 0.1, er, er)),
        add(Ellipse(0.16, 0.1, er, er)),
        add(Ellipse(0.0, 0.26, 0.2, 0.18)),
        add(Ellipse(0.0, 0.62, bw, 0.25)),
        add(Ellipse(bw + 0.04, 0.55, 0.15, 0.065, angle=arm)),
        add(Ellipse(-bw - 0.04, 0.55, 0.15, 0.065, angle=180.0 - arm)),
        add(Ellipse(spread + 0.04, 0.88, 0.1, 0.12)),
        add(Ellipse(-spread - 0.04, 0.88, 0.1, 0.12)),
    ]

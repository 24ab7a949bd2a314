"""Marker dots: does the frame show the background's markers where the background has them?

Many gels carry a grid of dark marker dots, each unit its own. A frame read against another
unit's no-contact frame then differs from it at every dot, and the structured check reads
those dots as contact (docs/geometry.md, "Another unit's background told by its marker
dots"). A press moves the dots only inside the contact (shear, a pixel or two); elsewhere
they stay where the unit's background has them.

`background_markers` finds the background's dots (dark peaks of a difference of Gaussians on
the grey frame, its shorter side at :data:`MARKER_SIDE` px) and the share of them that the frame
shows within :data:`MATCH_RADIUS` px. A background with fewer than :data:`MIN_DOTS` dots is not
read (no markers: Taxim's real gels, the DIGIT). A frame with markers read against a background
without any is not caught: its dots cannot be told from a texture's. The three numbers come from
renders only (a development look, docs/geometry.md).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter, maximum_filter

from ratouch.images import check_background_size, resize_array

#: The shorter side the dots are looked for at (the world's frames' own 96 px).
MARKER_SIDE = 96
#: A background with fewer dots than this carries no marker grid worth reading.
MIN_DOTS = 12
#: How far (working px) a background's dot may lie from the frame's nearest one and be found.
MATCH_RADIUS = 2.0
#: Below this share of the background's dots found in the frame, the background is not this
#: frame's unit's as it is now (another unit's, or the gel moved).
MIN_FOUND = 0.5
#: A dot is a peak of the darkness map this many robust deviations above its median.
PEAK_DEVIATIONS = 6.0


def _grey(frame: np.ndarray) -> np.ndarray:
    """The frame's grey level, float, its shorter side at :data:`MARKER_SIDE`."""
    h, w = frame.shape[:2]
    scale = MARKER_SIDE / min(h, w)
    grey = np.asarray(frame, np.float32).mean(2)
    if abs(scale - 1) > 1e-6:
        grey = resize_array(grey, (max(8, round(w * scale)), max(8, round(h * scale))))
    return np.asarray(grey, np.float64)


def marker_dots(frame: np.ndarray) -> np.ndarray:
    """(N, 2) positions (x, y, working px) of the frame's dark dots: the peaks (in 5 x 5) of a
    difference of Gaussians (σ 3 less σ 0.8) that stand :data:`PEAK_DEVIATIONS` robust
    deviations above its median and are darker than 4 % of the frame's mean level."""
    grey = _grey(frame)
    dark = gaussian_filter(grey, 3.0) - gaussian_filter(grey, 0.8)
    med = float(np.median(dark))
    mad = 1.4826 * float(np.median(np.abs(dark - med))) + 1e-6
    peak = ((dark == maximum_filter(dark, 5)) & (dark > med + PEAK_DEVIATIONS * mad)
            & (dark > 0.04 * grey.mean()))
    ys, xs = np.nonzero(peak)
    return np.stack([xs, ys], 1).astype(np.float64)


def background_markers(frame: np.ndarray, background: np.ndarray) -> dict | None:
    """The background's marker dots read in the frame: {"dots": how many the background
    shows, "found": how many of them the frame shows within :data:`MATCH_RADIUS`, "share",
    "moved": whether fewer than :data:`MIN_FOUND` of them are found}; None when the background
    shows fewer than :data:`MIN_DOTS` (nothing to read).

    Raises:
        DataError: the sizes differ.
    """
    check_background_size(background.shape[1::-1], frame.shape[1::-1], "the background")
    ref = marker_dots(background)
    if len(ref) < MIN_DOTS:
        return None
    seen = marker_dots(frame)
    found = 0
    if len(seen):
        d2 = ((ref[:, None, :] - seen[None, :, :]) ** 2).sum(-1).min(1)
        found = int((d2 <= MATCH_RADIUS ** 2).sum())
    share = found / len(ref)
    return {"dots": int(len(ref)), "found": found, "share": round(share, 3),
            "moved": bool(share < MIN_FOUND)}

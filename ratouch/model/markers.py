"""Marker dots: does the frame show the background's markers where the background has them?

Many gels carry a grid of dark marker dots, each unit its own. A frame read against another
unit's no-contact frame then differs from it at every dot, and the structured check reads
those dots as contact (docs/geometry.md, "Another unit's background told by its marker
dots"). A press moves the dots only inside the contact (shear, a pixel or two); elsewhere
they stay where the unit's background has them.

`background_markers` finds the background's dots (dark peaks of a difference of Gaussians on
the grey frame, its shorter side at :data:`MARKER_SIDE` px) and the share of them that the frame
shows within :data:`MATCH_RADIUS` px. A background with fewer than :data:`MIN_DOTS` dots has no
grid (Taxim's real gels, the DIGIT); against it, a frame that shows a marker grid of its own
(`marker_lattice`: many dots, evenly spaced at a marker pitch, covering the gel) cannot be of
the same unit, since markers are printed on the gel. The numbers come from renders only
(development looks, docs/geometry.md: "Another unit's background told by its marker dots" and
"A frame's marker grid that its background lacks").
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter, maximum_filter
from scipy.spatial import cKDTree

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
#: Where the background's dots found in the frame are, as a whole (their median displacement),
#: at least this far (working px) from where the background has them, the background is not this
#: frame's unit's either: another unit's grid a pixel or two away, or a gel that has slid. A press
#: moves the dots only inside its contact (docs/geometry.md, "Another unit's grid a pixel away").
MAX_SHIFT = 0.5
#: A dot is a peak of the darkness map this many robust deviations above its median.
PEAK_DEVIATIONS = 6.0
#: A frame's dots are a marker grid (`marker_lattice`) with at least this many dots, ...
LATTICE_DOTS = 40
#: ... a median nearest-neighbour distance (the pitch, working px) of at least this, ...
LATTICE_PITCH = 8.0
#: ... a spread of those distances (coefficient of variation) of at most this, ...
LATTICE_CV = 0.10
#: ... and spanning at least this many of its pitches along each axis (the smaller of the x
#: and y extents over the pitch): a grid printed across the gel, whatever the frame's size or
#: orientation, where a texture's dots confined to a contact span few (docs/geometry.md, "A
#: landscape frame's marker grid").
LATTICE_SPAN = 5.0


def _grey(frame: np.ndarray) -> np.ndarray:
    """The frame's grey level, float, its shorter side at :data:`MARKER_SIDE`."""
    h, w = frame.shape[:2]
    scale = MARKER_SIDE / min(h, w)
    grey = np.asarray(frame, np.float32).mean(2)
    if abs(scale - 1) > 1e-6:
        grey = resize_array(grey, (max(8, round(w * scale)), max(8, round(h * scale))))
    return np.asarray(grey, np.float64)


def marker_lattice(frame: np.ndarray, dots: np.ndarray | None = None) -> dict | None:
    """The frame's own marker grid: {"dots", "pitch" (working px), "cv", "cover" (its smaller
    extent in pitches)} where its dark dots (`marker_dots`, or `dots` where the caller has
    them) are at least :data:`LATTICE_DOTS`, at a pitch of at least :data:`LATTICE_PITCH`,
    evenly spaced (CV of the nearest-neighbour distances at most :data:`LATTICE_CV`) and span
    at least :data:`LATTICE_SPAN` pitches along x and along y; else None (a texture's dots, or
    none)."""
    d = marker_dots(frame) if dots is None else dots
    if len(d) < LATTICE_DOTS:
        return None
    nn = cKDTree(d).query(d, 2)[0][:, 1]
    pitch, cv = float(np.median(nn)), float(nn.std() / max(nn.mean(), 1e-9))
    cover = min(float(np.ptp(d[:, 0])), float(np.ptp(d[:, 1]))) / max(pitch, 1e-9)
    if pitch < LATTICE_PITCH or cv > LATTICE_CV or cover < LATTICE_SPAN:
        return None
    return {"dots": int(len(d)), "pitch": round(pitch, 2), "cv": round(cv, 3),
            "cover": round(cover, 3)}


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
    "shift": the length of the found dots' median displacement (working px; None where none
    is found), "moved": whether fewer than :data:`MIN_FOUND` of them are found, or they sit
    :data:`MAX_SHIFT` or more away as a whole}. Where the background shows fewer than
    :data:`MIN_DOTS` (no grid): where the frame shows a grid of its own (`marker_lattice`),
    {"dots", "found": 0, "share": None, "shift": None, "moved": True, "lattice": the frame's
    grid} (the background is another unit's), else None (nothing to read).

    Raises:
        DataError: the sizes differ.
    """
    check_background_size(background.shape[1::-1], frame.shape[1::-1], "the background")
    ref = marker_dots(background)
    if len(ref) < MIN_DOTS:
        grid = marker_lattice(frame)
        if grid is None:
            return None
        return {"dots": int(len(ref)), "found": 0, "share": None, "shift": None,
                "moved": True, "lattice": grid}
    seen = marker_dots(frame)
    found, shift = 0, None
    if len(seen):
        d2 = ((ref[:, None, :] - seen[None, :, :]) ** 2).sum(-1)
        near = d2.argmin(1)
        ok = d2[np.arange(len(ref)), near] <= MATCH_RADIUS ** 2
        found = int(ok.sum())
        if found:  # the found dots' median displacement: a press moves only its contact's
            shift = round(float(np.hypot(*np.median(seen[near[ok]] - ref[ok], 0))), 2)
    share = found / len(ref)
    return {"dots": int(len(ref)), "found": found, "share": round(share, 3), "shift": shift,
            "moved": bool(share < MIN_FOUND or (shift is not None and shift >= MAX_SHIFT))}

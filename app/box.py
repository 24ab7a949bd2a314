"""The visual image as the app holds it, and the contact box marked on it.

The app shows a preview of the visual image (longest side `PREVIEW_SIDE` px) and keeps the
original for the query; clicks arrive in preview pixels and are mapped back to image pixels.
A box is (x0, y0, x1, y1) in pixels of the (EXIF-rotated) image, x1/y1 exclusive, as
`ratouch.images.crop_box` takes it. Pure PIL/numpy: no gradio here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np
from PIL import Image, ImageDraw

from ratouch.errors import DataError
from ratouch.images import clip_box, oriented_size, resize_array, to_rgb_array, tvl_contact_box

PREVIEW_SIDE = 512
MARKED = (230, 30, 30)     # a box the user marked or typed
DEFAULT = (250, 200, 0)    # the centred TVL crop used when no box is marked
CORNER = (30, 144, 255)    # the first click, waiting for the second


@dataclass(frozen=True)
class Visual:
    """A visual image loaded into one user's session (kept in a `gr.State`).

    Attributes:
        source: what a query decodes (`QueryRequest.decode`): the uploaded file's path, or
            an example's array.
        size: (width, height) of the image, EXIF orientation applied.
        base: the preview, (h, w, 3) uint8, without any drawing on it.
        scale: preview pixels per image pixel.
        title: what the image is, for the status line.
        label: the ground-truth tactile label, for examples from the test split.
        corner: the first corner clicked (image pixels) while waiting for the second.
        example: where a world example came from ({"index", "condition", "box"}), so that a
            link can reproduce its query; None for an upload.
    """

    source: str | np.ndarray
    size: tuple[int, int]
    base: np.ndarray
    scale: float
    title: str
    label: str | None = None
    corner: tuple[float, float] | None = None
    example: Mapping[str, Any] | None = None


def load_visual(source: str | np.ndarray, title: str, label: str | None = None,
                example: Mapping[str, Any] | None = None) -> Visual:
    """Read (and check) a visual image and make its preview.

    Raises:
        DataError / DataNotFoundError: the image cannot be used (the library's message).
    """
    w, h = oriented_size(source, "visual image")  # a file's from its header
    # decoded no larger than the preview: an upload's memory is bounded by it, not the file
    image = to_rgb_array(source, name="visual image", max_side=PREVIEW_SIDE)
    scale = PREVIEW_SIDE / max(w, h)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    # small (world) images are upscaled with NEAREST so their pixels stay visible for clicking
    resample = Image.Resampling.NEAREST if scale >= 2 else Image.Resampling.LANCZOS
    base = resize_array(image, size, resample)
    return Visual(source, (w, h), base, size[0] / w, title, label, example=example)


def default_box(visual: Visual) -> tuple[int, int, int, int]:
    """TVL's centred contact crop, which the pipeline uses when no box is given."""
    return tvl_contact_box(*visual.size)


def click(visual: Visual, x: float, y: float
          ) -> tuple[Visual, tuple[int, int, int, int] | None]:
    """One click at preview pixel (x, y): the first click sets a corner, the second closes the
    box spanned by both (whole pixels, both clicked pixels inside) and starts over.

    Returns:
        The updated visual and the new box, or None after a first click.
    """
    px, py = (x + 0.5) / visual.scale, (y + 0.5) / visual.scale  # centre of the clicked pixel
    w, h = visual.size
    px, py = min(max(px, 0.0), w - 1e-6), min(max(py, 0.0), h - 1e-6)
    if visual.corner is None:
        return replace(visual, corner=(px, py)), None
    ax, ay = visual.corner
    box = (math.floor(min(ax, px)), math.floor(min(ay, py)),
           math.floor(max(ax, px)) + 1, math.floor(max(ay, py)) + 1)
    return replace(visual, corner=None), box


def fields_to_box(x0, y0, x1, y1) -> tuple[float, float, float, float] | None:
    """The box typed in the four fields: None when all are empty (the default box is used).

    Raises:
        DataError: some but not all fields are filled in.
    """
    values = (x0, y0, x1, y1)
    if all(v is None or v == "" for v in values):
        return None
    if any(v is None or v == "" for v in values):
        raise DataError(f"contact box: fill in all four of x0, y0, x1, y1 or none of them "
                        f"(none = TVL's centred crop); got {list(values)}")
    try:
        return tuple(float(v) for v in values)  # type: ignore[return-value]
    except (TypeError, ValueError) as e:
        raise DataError(f"contact box: x0, y0, x1, y1 must be numbers, got {list(values)}") from e


def box_problem(box: Sequence[float], size: tuple[int, int]) -> str | None:
    """A sentence on what is wrong with a box for an image of `size`, or None if it is fine.

    The pipeline refuses empty, inverted and outside boxes itself; this only lets the app say
    so before a query is run, and notes a box that will be clipped."""
    x0, y0, x1, y1 = box
    w, h = size
    if x1 <= x0 or y1 <= y0:
        return f"box {list(box)} is empty or inverted (need x0 < x1 and y0 < y1)"
    if x1 <= 0 or y1 <= 0 or x0 >= w or y0 >= h:
        return f"box {list(box)} lies entirely outside the {w}x{h} (WxH) image"
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
        return (f"box {list(box)} reaches outside the {w}x{h} (WxH) image; it will be clipped "
                f"to {list(clip_box(box, w, h))}")
    return None


def used_box(box: Sequence[float], size: tuple[int, int]) -> tuple[int, int, int, int]:
    """The box a query crops for `box` on an image of `size`: whole pixels, clipped (the
    library's `clip_box`, which `QueryRequest.decode` applies)."""
    return clip_box(box, *size)


def draw(visual: Visual, box: Sequence[float] | None) -> np.ndarray:
    """The preview with the box drawn (the default box, dashed-looking and labelled, when
    `box` is None) and the pending first corner marked."""
    im = Image.fromarray(visual.base)
    d = ImageDraw.Draw(im)
    s, lw = visual.scale, max(2, round(PREVIEW_SIDE / 170))
    if box is None:
        x0, y0, x1, y1 = (v * s for v in default_box(visual))
        _dashed_rect(d, (x0, y0, x1 - 1, y1 - 1), DEFAULT, lw)
        d.text((x0 + 4, y0 + 3), "default box", fill=DEFAULT)
    elif box[2] > box[0] and box[3] > box[1]:  # an inverted box has nothing to draw
        try:  # the box the query will use: whole pixels, clipped to the image
            x0, y0, x1, y1 = (v * s for v in used_box(box, visual.size))
            d.rectangle((x0, y0, x1 - 1, y1 - 1), outline=MARKED, width=lw)
        except DataError:  # entirely outside: nothing to draw (the note says why)
            pass
    if visual.corner is not None:
        cx, cy, r = visual.corner[0] * s, visual.corner[1] * s, 3 * lw
        d.line((cx - r, cy, cx + r, cy), fill=CORNER, width=lw)
        d.line((cx, cy - r, cx, cy + r), fill=CORNER, width=lw)
    return np.asarray(im)


def _dashed_rect(d: ImageDraw.ImageDraw, rect: tuple[float, ...], colour, width: int,
                 dash: int = 10) -> None:
    x0, y0, x1, y1 = rect
    for a, b, horizontal, at in ((x0, x1, True, y0), (x0, x1, True, y1),
                                 (y0, y1, False, x0), (y0, y1, False, x1)):
        t = a
        while t < b:
            e = min(t + dash, b)
            d.line((t, at, e, at) if horizontal else (at, t, at, e), fill=colour, width=width)
            t += 2 * dash

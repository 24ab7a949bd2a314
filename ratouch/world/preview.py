"""Contact sheets of the world that a person can look at: visual with contact box, tactile,
label and material, one tile per sample."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from PIL import Image, ImageDraw

from ratouch.errors import ConfigError
from ratouch.world.sampler import Sample

_TILE_W, _TILE_H, _TEXT_H = 2, 1, 40  # layout units: visual and tactile side by side


def draw_box(image: np.ndarray, box: Sequence[int], colour=(255, 40, 40), width: int = 2
             ) -> Image.Image:
    """A PIL copy of `image` with `box` (x0, y0, x1, y1) outlined."""
    im = Image.fromarray(image).convert("RGB")
    ImageDraw.Draw(im).rectangle([box[0], box[1], box[2] - 1, box[3] - 1], outline=colour,
                                 width=width)
    return im


def contact_sheet(samples: Sequence[Sample], columns: int = 4, scale: int = 2) -> Image.Image:
    """Lay samples out in a grid: visual (box drawn), tactile, and two lines of text."""
    if not samples:
        raise ConfigError("contact_sheet needs at least one sample")
    s = samples[0].visual.shape[0] * scale
    th, tw = (d * scale for d in samples[0].tactile.shape[:2])
    cell_w, cell_h = s + tw + 12, max(s, th) + _TEXT_H
    rows = (len(samples) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * cell_w, rows * cell_h), (250, 250, 250))
    draw = ImageDraw.Draw(sheet)
    for i, smp in enumerate(samples):
        x, y = (i % columns) * cell_w, (i // columns) * cell_h
        vis = draw_box(smp.visual, smp.box).resize((s, s), Image.Resampling.NEAREST)
        sheet.paste(vis, (x + 2, y + 2))
        tac = Image.fromarray(smp.tactile).resize((tw, th), Image.Resampling.BILINEAR)
        sheet.paste(tac, (x + s + 6, y + 2))
        what = smp.class_name or "close-up"
        draw.text((x + 4, y + max(s, th) + 4), f"{what} / {smp.material}", fill=(20, 20, 20))
        draw.text((x + 4, y + max(s, th) + 18), smp.caption, fill=(30, 30, 160))
    return sheet

"""Fast pure-numpy silhouette rasteriser for the world's object families.

Every family (ball, bottle, chair, teddy, ...) is a small union/difference of primitives
(ellipses and rings, rounded rectangles, y- or x-monotone polygons) described in the family's
own *design* coordinates (x right, y down, roughly in its natural proportions). The design
extent of the additive primitives is mapped onto the requested pixel bbox, so the drawn mask
touches all four bbox sides: a caller controls an object's size exactly.

Only the pixels whose centres (x + 0.5, y + 0.5) fall in the bbox's sub-grid are evaluated,
each primitive only inside its own window, with 1-D coordinate vectors broadcast to 2-D, so a
call costs a few hundred microseconds. Parts that would be thinner than a pixel are widened to
about one pixel, so small objects (a dozen pixels) keep their limbs, legs and handles and still
span their bbox.

Modules: `primitives` (the pixel grid and the shapes), `parts` (the family builders' building
blocks), the families by kind (`solids`, `vessels`, `clothing`, `furniture`, `animals`),
`families` (every family by name, in a fixed order) and `raster` (`silhouette_mask` and the
measures built on it).

Example:
    >>> mask = silhouette_mask("mug", (128, 128), (20.0, 30.0, 100.0, 110.0))
    >>> mask_bbox(mask)
    (20, 30, 100, 110)
"""

from ratouch.world.silhouette.builders import FAMILIES
from ratouch.world.silhouette.raster import (
    fill_fraction,
    mask_bbox,
    natural_aspect,
    silhouette_mask,
)

__all__ = ["FAMILIES", "fill_fraction", "mask_bbox", "natural_aspect", "silhouette_mask"]

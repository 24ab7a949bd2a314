"""Resizing image arrays: the library's one resize.

Every resize of an image held as a numpy array goes through `resize_array`, so the filter
(PIL's antialiased bilinear unless a caller says otherwise) is the same wherever an image is
scaled: for the encoders' inputs, the contact detector, the world's probes and the app's
preview. (Decoding an upload and shrinking it on the way in is `encoders.preprocess`'s
`to_rgb_array(..., max_side=...)`, which works on the PIL image before it becomes an array.)
"""

from __future__ import annotations

import numpy as np
from PIL import Image


def resize_array(arr: np.ndarray, size: int | tuple[int, int],
                 resample: Image.Resampling = Image.Resampling.BILINEAR,
                 reducing_gap: float | None = None) -> np.ndarray:
    """`arr` resized to `size` (``(width, height)``, or a square side).

    Args:
        arr: a ``uint8`` image, ``(H, W)`` or ``(H, W, C)``, or a ``float32`` ``(H, W)`` plane.
        size: the output ``(width, height)``, or one side for a square.
        resample: PIL's filter (antialiased bilinear by default, as TVL's ``Resize``).
        reducing_gap: PIL's two-step reduction for large shrinks (None: one step).

    Returns:
        An array of `arr`'s dtype; `arr` itself when it already has that size.
    """
    width, height = (size, size) if isinstance(size, int) else size
    if arr.shape[1] == width and arr.shape[0] == height:
        return arr
    img = Image.fromarray(np.ascontiguousarray(arr))
    out = np.asarray(img.resize((width, height), resample, reducing_gap=reducing_gap))
    return out.astype(arr.dtype, copy=False)

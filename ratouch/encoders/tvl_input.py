# Input tensors of the TVL encoders.
#
# The normalisation constants (CLIP RGB mean/std, TAC_MEAN/TAC_STD, TAC_MEAN_BG/TAC_STD_BG),
# the tactile "pad to square, then rotate by 90 degrees" step, the background subtraction
# and the contact-region crop geometry follow Max-Fu/tvl (tvl_enc/tacvis.py), the public
# code of "A Touch, Vision, and Language Dataset for Multimodal Alignment" (Fu et al., 2024),
# released under the Apache License 2.0 (the repository README says so). The code below is
# an independent implementation; only the layout and the numeric constants come from there.
"""Input tensors of the CLIP / TVL encoders, built from decoded image arrays.

* :func:`clip_rgb_tensor` builds a CLIP input batch (shorter side resized, centre crop,
  CLIP mean/std).
* :func:`tvl_tactile_tensor` builds a tactile-encoder input batch the way TVL does
  (pad to square, rotate 90 degrees counter-clockwise, resize, normalise, optionally after
  subtracting a no-contact background frame).

Decoding the images themselves (any file or array to ``(H, W, 3)`` ``uint8``) is
``ratouch.images.to_rgb_array``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from ratouch.errors import ConfigError, DataError
from ratouch.images import (
    MIN_SIDE,
    ImageLike,
    as_image_list,
    check_background_size,
    resize_array,
    to_rgb_array,
)

#: OpenCLIP / OpenAI CLIP normalisation (also what TVL uses for its RGB frames).
CLIP_MEAN: tuple[float, float, float] = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD: tuple[float, float, float] = (0.26862954, 0.26130258, 0.27577711)

#: TVL tactile statistics for raw (not background-subtracted) frames.
TAC_MEAN: tuple[float, float, float] = (
    0.29174602047139075, 0.2971325588927249, 0.2910404549605639,
)
TAC_STD: tuple[float, float, float] = (
    0.18764469044810236, 0.19467651810273057, 0.21871583397361818,
)

#: TVL tactile statistics for background-subtracted frames (frame - background, in [−1, 1]).
TAC_MEAN_BG: tuple[float, float, float] = (
    -0.00809318389762342, -0.01887447008747725, -0.018430588238856332,
)
TAC_STD_BG: tuple[float, float, float] = (
    0.04535400223885517, 0.044029170444552575, 0.05332520729596308,
)

#: Largest accepted output size for the tensor builders.
MAX_TENSOR_SIZE = 4096


def _check_tensor_size(size: Any) -> int:
    """Validate the output side length of a tensor builder.

    Args:
        size: The requested side length.

    Returns:
        The size as an ``int``.

    Raises:
        ConfigError: If it is not an integer in ``[MIN_SIDE, MAX_TENSOR_SIZE]``.
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)):
        raise ConfigError(f"size must be an integer, got {size!r}")
    if not MIN_SIDE <= int(size) <= MAX_TENSOR_SIZE:
        raise ConfigError(f"size must be between {MIN_SIDE} and {MAX_TENSOR_SIZE}, got {size}")
    return int(size)



def _shorter_side_size(width: int, height: int, size: int) -> tuple[int, int]:
    """Output (width, height) when the shorter side is resized to ``size`` (torchvision rule)."""
    if width <= height:
        return size, int(size * height / width)
    return int(size * width / height), size


def _normalise(chw: torch.Tensor, mean: Sequence[float], std: Sequence[float]) -> torch.Tensor:
    """Channel-wise ``(x - mean) / std`` of a ``(3, H, W)`` float tensor."""
    m = torch.tensor(mean, dtype=torch.float32).view(3, 1, 1)
    s = torch.tensor(std, dtype=torch.float32).view(3, 1, 1)
    return (chw - m) / s


def _to_chw_float(arr: np.ndarray) -> torch.Tensor:
    """``(H, W, 3)`` ``uint8`` -> ``(3, H, W)`` float32 in ``[0, 1]``."""
    arr = np.ascontiguousarray(arr)
    if not arr.flags.writeable:  # torch warns on read-only buffers (e.g. np.asarray(PIL image))
        arr = arr.copy()
    return torch.from_numpy(arr).permute(2, 0, 1).float().div_(255.0)


def clip_rgb_tensor(images: Sequence[ImageLike] | np.ndarray, size: int = 224, *,
                    mean: Sequence[float] = CLIP_MEAN, std: Sequence[float] = CLIP_STD,
                    index_offset: int = 0) -> torch.Tensor:
    """Build a CLIP input batch from RGB images.

    Each image is normalised with :func:`to_rgb_array`, its shorter side resized to
    ``size`` (antialiased bilinear, as TVL's ``RGB_PREPROCESS``), centre-cropped to
    ``size x size`` and normalised with the CLIP mean/std. Crop the contact region first
    (:func:`tvl_contact_box` + :func:`crop_box`) to match TVL's camera-frame input.

    Args:
        images: A list of images (or an ``(N, H, W, C)`` array).
        size: Output side length (the CLIP model's image size).
        mean: Per-channel mean (default: CLIP's).
        std: Per-channel standard deviation (default: CLIP's).
        index_offset: Added to the image index in error messages (for callers that batch).

    Returns:
        A float32 tensor of shape ``(N, 3, size, size)`` (``N`` may be 0).

    Raises:
        ConfigError: If ``size`` is invalid.
        DataError: If an image is invalid (the message names its index).
    """
    size = _check_tensor_size(size)
    items = as_image_list(images, "images")
    out = torch.empty((len(items), 3, size, size), dtype=torch.float32)
    for i, image in enumerate(items):
        arr = to_rgb_array(image, name=f"image {i + index_offset}")
        height, width = arr.shape[:2]
        new_w, new_h = _shorter_side_size(width, height, size)
        arr = resize_array(arr, (new_w, new_h))
        top = int(round((new_h - size) / 2.0))
        left = int(round((new_w - size) / 2.0))
        arr = arr[top:top + size, left:left + size]
        out[i] = _normalise(_to_chw_float(arr), mean, std)
    return out


def _pad_square_rotate(arr: np.ndarray) -> np.ndarray:
    """Zero-pad an ``(H, W, C)`` array to a centred square, then rotate it 90° counter-clockwise.

    TVL pads ``(max - side) // 2`` on both sides, which leaves odd differences one pixel
    short of square; here the extra pixel goes to the right/bottom so the result is always
    square (identical to TVL whenever the difference is even).
    """
    height, width = arr.shape[:2]
    side = max(height, width)
    top = (side - height) // 2
    left = (side - width) // 2
    if side != height or side != width:
        padded = np.zeros((side, side) + arr.shape[2:], dtype=arr.dtype)
        padded[top:top + height, left:left + width] = arr
        arr = padded
    return np.ascontiguousarray(np.rot90(arr, k=1, axes=(0, 1)))


def _background_list(background: Any, n: int) -> list[Any] | None:
    """Expand the ``background`` argument into one entry per frame (or ``None``)."""
    if background is None:
        return None
    if isinstance(background, (Image.Image, str, os.PathLike)) or (
        isinstance(background, np.ndarray) and background.ndim in (2, 3)
    ):
        return [background] * n
    items = as_image_list(background, "background")
    if len(items) != n:
        raise DataError(f"got {len(items)} background images for {n} tactile frames; pass one "
                        "background for all frames or exactly one per frame")
    return items


def tvl_tactile_tensor(frames: Sequence[ImageLike] | np.ndarray, size: int = 224,
                       background: Any = None, *, index_offset: int = 0) -> torch.Tensor:
    """Build a tactile-encoder input batch the way TVL preprocesses GelSight/DIGIT frames.

    Each frame is normalised with :func:`to_rgb_array`, zero-padded to a square, rotated 90°
    counter-clockwise (TVL's ``tac_padding``), resized to ``size x size`` (antialiased
    bilinear) and normalised with ``TAC_MEAN``/``TAC_STD``.

    With a ``background`` (a no-contact frame of the same sensor), TVL's background
    subtraction is applied instead: frame and background (both in ``[0, 1]``) are padded and
    rotated, subtracted at full resolution, the difference resized and normalised with
    ``TAC_MEAN_BG``/``TAC_STD_BG``. Only use it with an encoder trained that way.

    Args:
        frames: A list of tactile frames (or an ``(N, H, W, C)`` array).
        size: Output side length (the tactile ViT's image size).
        background: ``None``; one image used for every frame; or a list with one entry
            per frame (an image, or ``None`` for no subtraction on that frame). Each
            background must have the size of its frame.
        index_offset: Added to the frame index in error messages (for callers that batch).

    Returns:
        A float32 tensor of shape ``(N, 3, size, size)`` (``N`` may be 0).

    Raises:
        ConfigError: If ``size`` is invalid.
        DataError: If a frame or background is invalid, or their sizes differ.
    """
    size = _check_tensor_size(size)
    items = as_image_list(frames, "frames")
    backgrounds = _background_list(background, len(items))
    out = torch.empty((len(items), 3, size, size), dtype=torch.float32)
    cache: dict[int, np.ndarray] = {}
    for i, frame in enumerate(items):
        j = i + index_offset
        rgb = to_rgb_array(frame, name=f"tactile frame {j}")
        if backgrounds is None or backgrounds[i] is None:
            arr = resize_array(_pad_square_rotate(rgb), size)
            out[i] = _normalise(_to_chw_float(arr), TAC_MEAN, TAC_STD)
            continue
        key = id(backgrounds[i])
        if key not in cache:
            bg = to_rgb_array(backgrounds[i], name=f"background {j}")
            cache[key] = bg
        bg = cache[key]
        check_background_size(bg.shape[1::-1], rgb.shape[1::-1], f"background {j}",
                              f"tactile frame {j}")
        diff = (_to_chw_float(_pad_square_rotate(rgb))
                - _to_chw_float(_pad_square_rotate(bg)))
        if diff.shape[-1] != size:
            diff = F.interpolate(diff[None], size=(size, size), mode="bilinear",
                                 align_corners=False, antialias=True)[0]
        out[i] = _normalise(diff, TAC_MEAN_BG, TAC_STD_BG)
    return out


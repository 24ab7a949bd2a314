# Image preprocessing for the TVL encoders.
#
# The normalisation constants (CLIP RGB mean/std, TAC_MEAN/TAC_STD, TAC_MEAN_BG/TAC_STD_BG),
# the tactile "pad to square, then rotate by 90 degrees" step, the background subtraction
# and the contact-region crop geometry follow Max-Fu/tvl (tvl_enc/tacvis.py), the public
# code of "A Touch, Vision, and Language Dataset for Multimodal Alignment" (Fu et al., 2024),
# released under the Apache License 2.0 (the repository README says so). The code below is
# an independent implementation; only the layout and the numeric constants come from there.
"""Pure functions that turn images into the input tensors of the TVL encoders.

Everything here is deterministic and free of model state:

* :func:`to_rgb_array` normalises any PIL image, numpy array or image file into an
  ``(H, W, 3)`` ``uint8`` array (EXIF orientation applied, alpha composited on white,
  16-bit and float data rescaled) and rejects images that are too small or too large.
* :func:`crop_box` cuts a validated ``(x0, y0, x1, y1)`` box out of an image;
  :func:`tvl_contact_box` computes the box TVL crops around the sensor contact.
* :func:`clip_rgb_tensor` builds a CLIP input batch (shorter side resized, centre crop,
  CLIP mean/std).
* :func:`tvl_tactile_tensor` builds a tactile-encoder input batch the way TVL does
  (pad to square, rotate 90 degrees counter-clockwise, resize, normalise, optionally after
  subtracting a no-contact background frame).
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from typing import Any, Union

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image, ImageOps, UnidentifiedImageError

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.images import resize_array

log = logging.getLogger(__name__)

#: Anything :func:`to_rgb_array` accepts.
ImageLike = Union[Image.Image, np.ndarray, str, "os.PathLike[str]"]

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

#: Smallest accepted side length, in pixels.
MIN_SIDE = 8
#: Largest accepted image area, in pixels (50 megapixels).
MAX_PIXELS = 50_000_000
#: Largest accepted output size for the tensor builders.
MAX_TENSOR_SIZE = 4096
#: Longer side an upload is reduced to before any per-pixel work when it serves a query: a
#: DIGIT / GelSight-Mini frame's native 320 x 240 passes untouched, and it is above every
#: encoder's input side (default backend 64 px, TVL 224 px), so a 36-megapixel upload costs
#: what a 0.08-megapixel one does after decoding.
QUERY_MAX_SIDE = 320

# Half-width of the contact crop relative to the longer image side, as in TVL
# (``im_scale_range[1]``); the crop side is sqrt(2) * scale * max(H, W).
TVL_CONTACT_SCALE = 0.18


# --------------------------------------------------------------------------- validation


def _check_size(width: int, height: int, what: str = "image") -> None:
    """Reject images too small to be meaningful or too large to process safely.

    Args:
        width: Image width in pixels.
        height: Image height in pixels.
        what: How to name the image in the error message.

    Raises:
        DataError: If a side is below :data:`MIN_SIDE` or the area exceeds :data:`MAX_PIXELS`.
    """
    if width < MIN_SIDE or height < MIN_SIDE:
        raise DataError(
            f"{what} is {width}x{height} pixels (WxH); each side must be at least {MIN_SIDE} px"
        )
    if width * height > MAX_PIXELS:
        raise DataError(
            f"{what} is {width}x{height} pixels (WxH) = {width * height / 1e6:.1f} megapixels; "
            f"the limit is {MAX_PIXELS / 1e6:.0f} megapixels"
        )


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


def as_image_list(images: Any, what: str = "images") -> list[Any]:
    """Turn a batch argument into a list, refusing a lone image passed by mistake.

    Args:
        images: A sequence of images, or a 4-D ``(N, H, W, C)`` array.
        what: The argument name for error messages.

    Returns:
        The images as a list.

    Raises:
        DataError: If ``images`` is a single image rather than a batch.
    """
    if isinstance(images, np.ndarray):
        if images.ndim == 4:
            return list(images)
        raise DataError(
            f"{what} must be a list of images (or an (N, H, W, C) array); got a single array of "
            f"shape {images.shape} - wrap it in a list"
        )
    if isinstance(images, (Image.Image, str, os.PathLike, bytes)):
        raise DataError(f"{what} must be a list of images; got a single {type(images).__name__} - "
                        "wrap it in a list")
    if not isinstance(images, Sequence):
        try:
            return list(images)
        except TypeError as e:
            raise DataError(f"{what} must be a list of images, got {type(images).__name__}") from e
    return list(images)


# --------------------------------------------------------------------------- to_rgb_array


def _integer_to_uint8(arr: np.ndarray, what: str) -> np.ndarray:
    """Rescale integer pixel data to ``uint8`` by its bit depth.

    ``uint8`` is kept, ``uint16`` is divided by 257 (65535 -> 255). Wider or signed integer
    types (e.g. PIL mode ``I``) are treated as 8-bit when every value lies in ``[0, 255]``
    and as 16-bit when every value lies in ``[0, 65535]``.
    """
    if arr.dtype == np.uint8:
        return arr
    if arr.dtype == np.uint16:
        return ((arr.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    lo, hi = (int(arr.min()), int(arr.max())) if arr.size else (0, 0)
    if lo < 0 or hi > 65535:
        raise DataError(
            f"{what} has integer pixel values in [{lo}, {hi}]; expected 8-bit [0, 255] or "
            "16-bit [0, 65535] data"
        )
    if hi <= 255:
        return arr.astype(np.uint8)
    return ((arr.astype(np.int64) * 255 + 32767) // 65535).astype(np.uint8)


def _float_to_uint8(arr: np.ndarray, what: str) -> np.ndarray:
    """Rescale float pixel data (``[0, 1]`` or ``[0, 255]``) to ``uint8``."""
    if arr.size and not np.all(np.isfinite(arr)):
        raise DataError(f"{what} contains NaN or infinite pixel values")
    lo, hi = (float(arr.min()), float(arr.max())) if arr.size else (0.0, 0.0)
    eps = 1e-6
    if lo < -eps or hi > 255.0 + 1e-3:
        raise DataError(
            f"{what} has float pixel values in [{lo:g}, {hi:g}]; expected [0, 1] or [0, 255]"
        )
    scale = 255.0 if hi <= 1.0 + eps else 1.0
    return np.clip(np.rint(arr.astype(np.float64) * scale), 0, 255).astype(np.uint8)


def _channels_to_rgb(arr: np.ndarray, what: str) -> np.ndarray:
    """Turn an ``(H, W)`` / ``(H, W, 1|2|3|4)`` ``uint8`` array into ``(H, W, 3)``.

    Grey is replicated, alpha (2nd or 4th channel) is composited onto a white background.
    """
    if arr.ndim == 2:
        return np.repeat(arr[:, :, None], 3, axis=2)
    channels = arr.shape[2]
    if channels == 3:
        return arr
    if channels == 1:
        return np.repeat(arr, 3, axis=2)
    if channels in (2, 4):
        colour = arr[:, :, :1] if channels == 2 else arr[:, :, :3]
        alpha = arr[:, :, -1:].astype(np.float32) / 255.0
        out = colour.astype(np.float32) * alpha + 255.0 * (1.0 - alpha)
        out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
        return np.repeat(out, 3, axis=2) if channels == 2 else out
    raise DataError(f"{what} has {channels} channels; expected 1 (grey), 2 (grey+alpha), "
                    "3 (RGB) or 4 (RGBA), channels last")


def _array_to_rgb(arr: np.ndarray, what: str) -> np.ndarray:
    """Normalise a numpy image of any dtype / channel count to ``(H, W, 3)`` ``uint8``."""
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] > 4):
        raise DataError(
            f"{what} has shape {arr.shape}; expected (H, W) or (H, W, C) with C in 1..4 "
            "(channels last)"
        )
    height, width = arr.shape[:2]
    _check_size(width, height, what)
    if not arr.dtype.isnative:  # e.g. big-endian 16-bit data from PIL mode I;16B
        arr = arr.astype(arr.dtype.newbyteorder("="))
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8) * 255
    elif np.issubdtype(arr.dtype, np.integer):
        arr = _integer_to_uint8(arr, what)
    elif np.issubdtype(arr.dtype, np.floating):
        arr = _float_to_uint8(arr, what)
    else:
        raise DataError(f"{what} has unsupported pixel dtype {arr.dtype}")
    return np.ascontiguousarray(_channels_to_rgb(arr, what))


def _reduce_pil(img: Image.Image, max_side: int) -> Image.Image:
    """Shrink a loaded PIL image so its longer side is at most ``max_side`` (integer-factor
    ``reduce`` first, then an antialiased bilinear resize), keeping the aspect ratio."""
    longer = max(img.width, img.height)
    if longer <= max_side:
        return img
    scale = max_side / longer
    size = (max(1, round(img.width * scale)), max(1, round(img.height * scale)))
    return img.resize(size, Image.Resampling.BILINEAR, reducing_gap=2.0)


#: PIL modes that PIL resizes directly (the others are reduced after conversion to RGB).
_REDUCIBLE_MODES = ("RGB", "RGBA", "L", "LA", "RGBa", "La", "I", "F")


def _pil_to_rgb(img: Image.Image, what: str, max_side: int | None = None) -> np.ndarray:
    """Normalise a PIL image of any mode to ``(H, W, 3)`` ``uint8`` (EXIF orientation applied),
    reduced to ``max_side`` (when given) before any per-pixel conversion."""
    _check_size(img.width, img.height, what)
    if max_side is not None and getattr(img, "format", None) == "JPEG":
        img.draft("RGB", (max_side, max_side))  # JPEG: decode at a reduced scale directly
    try:
        img.load()
    except (OSError, ValueError, SyntaxError) as e:  # truncated or corrupt file data
        raise DataError(f"cannot decode {what}: {e}") from e
    if max_side is not None and img.mode in _REDUCIBLE_MODES:
        # reduce first: the EXIF rotation keeps the longer side, and copies the image
        img = _reduce_pil(img, max_side)
    try:
        rotated = ImageOps.exif_transpose(img)
    except Exception as e:  # broken EXIF blocks must not make the image unusable
        log.warning("ignoring unreadable EXIF orientation of %s: %s", what, e)
        rotated = None
    if rotated is not None:
        img = rotated
    mode = img.mode
    if mode == "RGB":
        return np.array(img, dtype=np.uint8)
    if mode == "P":
        img = img.convert("RGBA" if "transparency" in img.info else "RGB")
        mode = img.mode
    elif mode == "PA":
        img = img.convert("RGBA")
        mode = "RGBA"
    if mode in ("RGBA", "LA"):
        return _channels_to_rgb(np.asarray(img, dtype=np.uint8), what)
    if mode in ("RGBa", "La"):  # premultiplied alpha: un-premultiply via PIL first
        img = img.convert("RGBA" if mode == "RGBa" else "LA")
        return _channels_to_rgb(np.asarray(img, dtype=np.uint8), what)
    if mode in ("1", "L", "I", "F") or mode.startswith("I;"):
        return _array_to_rgb(np.asarray(img), what)
    # CMYK, YCbCr, LAB, HSV, ...: PIL knows how to get to RGB.
    try:
        img = img.convert("RGB")
    except (ValueError, OSError) as e:
        raise DataError(f"{what} has PIL mode {mode!r}, which cannot be converted to RGB") from e
    return np.array(img, dtype=np.uint8)


def _open_image(path: str | os.PathLike[str], role: str = "image") -> Image.Image:
    """Open an image file lazily, with project errors (naming its role, e.g. "tactile
    image", and path) for missing or unreadable files."""
    path_str = os.fspath(path)
    if not os.path.exists(path_str):
        raise DataNotFoundError(f"{role} file not found: {path_str}")
    if os.path.isdir(path_str):
        raise DataError(f"{role}: expected an image file, got a directory: {path_str}")
    try:
        return Image.open(path_str)
    except Image.DecompressionBombError as e:
        raise DataError(f"{role} {path_str} is too large to decode safely: {e}") from e
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise DataError(f"cannot read {role} {path_str} as an image: {e}") from e


def fit_within(arr: np.ndarray, max_side: int | None) -> np.ndarray:
    """An ``(H, W, 3)`` ``uint8`` array reduced (antialiased, aspect kept) so that its longer
    side is at most ``max_side`` pixels (unchanged if it already is, or ``max_side`` is None)."""
    if max_side is None or max(arr.shape[:2]) <= max_side:
        return arr
    return np.asarray(_reduce_pil(Image.fromarray(arr), max_side), dtype=np.uint8)


def to_rgb_array(image: ImageLike, name: str | None = None,
                 max_side: int | None = None) -> np.ndarray:
    """Normalise an image of any kind into an ``(H, W, 3)`` ``uint8`` RGB array.

    Accepts PIL images of any mode (``1``, ``L``, ``LA``, ``P``, ``PA``, ``RGB``, ``RGBA``,
    ``CMYK``, ``YCbCr``, ``I;16*``, ``I``, ``F``, ...), numpy arrays (``(H, W)`` or
    ``(H, W, C)`` with C in 1..4, channels last, of dtype bool, any integer or float type)
    and paths to image files. PIL images get their EXIF orientation applied. Alpha is
    composited onto white. ``uint16`` data is scaled by 255/65535; other integer data is
    read as 8-bit when it fits in ``[0, 255]`` and as 16-bit when it fits in ``[0, 65535]``;
    float data must lie in ``[0, 1]`` or ``[0, 255]``.

    Args:
        image: The image.
        name: How to name the image in error messages (defaults to "image" or the path).
        max_side: When given, the image is reduced (aspect ratio kept, antialiased) so its
            longer side is at most this many pixels, inside PIL and before any per-pixel
            numpy work (a JPEG is even decoded at a reduced scale): the work per upload is
            then bounded by ``max_side`` rather than by the upload's size.

    Returns:
        A C-contiguous ``(H, W, 3)`` ``uint8`` array (a new array unless ``image`` already
        was one of that exact kind and needed no reduction).

    Raises:
        DataNotFoundError: If ``image`` is a path that does not exist.
        DataError: If the image cannot be interpreted, has a side below 8 px or more than
            50 megapixels.
    """
    if isinstance(image, (str, os.PathLike)):
        what = name or f"image {os.fspath(image)}"
        with _open_image(image, name or "image") as img:
            return fit_within(_pil_to_rgb(img, what, max_side), max_side)
    what = name or "image"
    if isinstance(image, Image.Image):
        return fit_within(_pil_to_rgb(image, what, max_side), max_side)
    if isinstance(image, np.ndarray):
        return fit_within(_array_to_rgb(image, what), max_side)
    if isinstance(image, torch.Tensor):
        raise DataError(f"{what} is a torch.Tensor; pass a numpy array (H, W, C) or a PIL image")
    raise DataError(f"{what} must be a PIL image, a numpy array or a file path, "
                    f"got {type(image).__name__}")


# --------------------------------------------------------------------------- boxes


def oriented_size(image: ImageLike, name: str = "image") -> tuple[int, int]:
    """``(width, height)`` of an image as :func:`to_rgb_array` returns it (EXIF orientation
    applied); a file's is read from its header, without decoding the pixels.

    Raises:
        DataNotFoundError / DataError: as :func:`to_rgb_array` for unusable images.
    """
    if isinstance(image, (str, os.PathLike)):
        with _open_image(image, name) as img:
            return _oriented(img, name)
    if isinstance(image, Image.Image):
        return _oriented(image, name)
    height, width = to_rgb_array(image, name).shape[:2]  # arrays are decoded already
    return width, height


def _oriented(img: Image.Image, what: str) -> tuple[int, int]:
    _check_size(img.width, img.height, what)
    try:
        orientation = img.getexif().get(0x0112, 1)
    except Exception:  # noqa: BLE001 - broken EXIF is ignored, as in _pil_to_rgb
        orientation = 1
    return (img.height, img.width) if orientation in (5, 6, 7, 8) else (img.width, img.height)


def clip_box(box: Sequence[float], width: int, height: int) -> tuple[int, int, int, int]:
    """The box that :func:`crop_box` crops: whole pixels (x0/y0 floored, x1/y1 ceiled),
    clipped to a ``width`` x ``height`` image.

    Raises:
        DataError: the box is malformed, empty, inverted or entirely outside the image.
    """
    try:
        values = [float(v) for v in box]
    except (TypeError, ValueError) as e:
        raise DataError(f"box must be four numbers (x0, y0, x1, y1), got {box!r}") from e
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise DataError(f"box must be four finite numbers (x0, y0, x1, y1), got {box!r}")
    x0, y0, x1, y1 = values
    if x1 <= x0 or y1 <= y0:
        raise DataError(
            f"box {tuple(box)} is empty or inverted (need x0 < x1 and y0 < y1); "
            f"image is {width}x{height} (WxH)"
        )
    ix0, iy0, ix1, iy1 = math.floor(x0), math.floor(y0), math.ceil(x1), math.ceil(y1)
    cx0, cy0 = max(ix0, 0), max(iy0, 0)
    cx1, cy1 = min(ix1, width), min(iy1, height)
    if cx1 <= cx0 or cy1 <= cy0:
        raise DataError(
            f"box {tuple(box)} lies entirely outside the {width}x{height} (WxH) image"
        )
    if (cx0, cy0, cx1, cy1) != (ix0, iy0, ix1, iy1):
        log.debug("box %s clipped to (%d, %d, %d, %d) for a %dx%d image",
                  tuple(box), cx0, cy0, cx1, cy1, width, height)
    return cx0, cy0, cx1, cy1


def crop_box(image: ImageLike, box: Sequence[float], max_side: int | None = None,
             name: str | None = None) -> np.ndarray:
    """Crop ``box = (x0, y0, x1, y1)`` (pixels, x1/y1 exclusive) out of an image.

    Fractional coordinates are widened to whole pixels (x0/y0 floored, x1/y1 ceiled).
    A box partially outside the image is clipped to it.

    Args:
        image: Any image :func:`to_rgb_array` accepts.
        box: ``(x0, y0, x1, y1)`` with ``x0 < x1`` and ``y0 < y1``, in pixels of the image.
        max_side: When given, the crop is returned with its longer side at most this many
            pixels, and a file or PIL image is reduced inside PIL before it becomes an array
            (the work is bounded by ``max_side``, not by the image's pixels).
        name: How to name the image in error messages.

    Returns:
        The ``(h, w, 3)`` ``uint8`` crop (a copy).

    Raises:
        DataError: If the box is malformed, empty, inverted or entirely outside the image
            (the message names the box and the image size).
    """
    if max_side is None or isinstance(image, np.ndarray):
        arr = to_rgb_array(image, name)
        cx0, cy0, cx1, cy1 = clip_box(box, arr.shape[1], arr.shape[0])
        return fit_within(arr[cy0:cy1, cx0:cx1].copy(), max_side)
    width, height = oriented_size(image, name or "image")
    cx0, cy0, cx1, cy1 = clip_box(box, width, height)
    factor = min(1.0, max_side / max(cx1 - cx0, cy1 - cy0))
    arr = to_rgb_array(image, name, max_side=max(MIN_SIDE, math.ceil(max(width, height) * factor)))
    sx, sy = arr.shape[1] / width, arr.shape[0] / height
    rx0, ry0 = math.floor(cx0 * sx), math.floor(cy0 * sy)
    rx1, ry1 = max(math.ceil(cx1 * sx), rx0 + 1), max(math.ceil(cy1 * sy), ry0 + 1)
    return fit_within(arr[ry0:ry1, rx0:rx1].copy(), max_side)


def tvl_contact_box(width: int, height: int, version: str = "v1",
                    scale: float = TVL_CONTACT_SCALE, top: int = 0) -> tuple[int, int, int, int]:
    """The square box TVL crops around the contact point of a camera frame.

    TVL's camera frames show the sensor touching a surface; the encoders were trained on a
    square crop of side ``ceil(sqrt(2) * scale * max(W, H))``: centred for the SSVTP
    frames (``version="v1"``), and horizontally centred but starting at row ``top`` for
    the HCT frames (``version="v2"``; TVL uses ``top=0``, or 200 for one HCT sub-folder).

    Args:
        width: Frame width in pixels.
        height: Frame height in pixels.
        version: ``"v1"`` (SSVTP, centre crop) or ``"v2"`` (HCT, top-centre crop).
        scale: Relative crop half-size (TVL: 0.18).
        top: First row of the v2 crop.

    Returns:
        ``(x0, y0, x1, y1)`` for :func:`crop_box`; it can reach outside a very elongated
        frame, in which case :func:`crop_box` clips it.

    Raises:
        ConfigError: If ``version`` or ``scale`` is invalid.
        DataError: If the frame size is invalid.
    """
    _check_size(int(width), int(height), "frame")
    if not (isinstance(scale, (int, float)) and 0 < scale <= 1):
        raise ConfigError(f"scale must be in (0, 1], got {scale!r}")
    side = int(math.ceil(math.sqrt(2.0) * scale * max(width, height)))
    if version == "v1":
        y0 = int(round((height - side) / 2.0))
        x0 = int(round((width - side) / 2.0))
    elif version == "v2":
        y0 = int(top)
        x0 = (width - side) // 2
    else:
        raise ConfigError(f"version must be 'v1' (SSVTP) or 'v2' (HCT), got {version!r}")
    return (x0, y0, x0 + side, y0 + side)


# --------------------------------------------------------------------------- tensors


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
        if bg.shape != rgb.shape:
            raise DataError(
                f"background {j} is {bg.shape[1]}x{bg.shape[0]} (WxH) but tactile frame {j} is "
                f"{rgb.shape[1]}x{rgb.shape[0]}; the background must come from the same sensor "
                "at the same size"
            )
        diff = (_to_chw_float(_pad_square_rotate(rgb))
                - _to_chw_float(_pad_square_rotate(bg)))
        if diff.shape[-1] != size:
            diff = F.interpolate(diff[None], size=(size, size), mode="bilinear",
                                 align_corners=False, antialias=True)[0]
        out[i] = _normalise(diff, TAC_MEAN_BG, TAC_STD_BG)
    return out


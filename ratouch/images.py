"""Images as arrays: decoding an upload (any file, PIL image or array) into the ``(H, W, 3)``
``uint8`` array everything else works on, reduced on the way in; cropping a contact box out of
it; and the library's one resize of image arrays.

* :func:`to_rgb_array` normalises any PIL image, numpy array or image file into an
  ``(H, W, 3)`` ``uint8`` array (EXIF orientation applied, alpha composited on white,
  16-bit and float data rescaled) and rejects images that are too small or too large. With
  ``max_side`` the work is bounded by ``max_side``, not by the file: a mode PIL resizes
  directly is reduced inside PIL first; any other mode (1-bit, palette, 16-bit, CMYK, ...) is
  converted and reduced one band of rows at a time, so no full-size RGB copy is ever made.
* :func:`crop_box` cuts a validated ``(x0, y0, x1, y1)`` box out of an image;
  :func:`tvl_contact_box` computes the box TVL crops around the sensor contact (its geometry
  follows Max-Fu/tvl, ``tvl_enc/tacvis.py``, Apache License 2.0).
* :func:`resize_array`: every resize of an image held as a numpy array goes through it, so the
  filter (PIL's antialiased bilinear unless a caller says otherwise) is the same wherever an
  image is scaled: the encoders' inputs, the contact detector, the world's probes, the app's
  preview.

The encoders' input tensors (CLIP and TVL normalisation) are built from these arrays in
``ratouch.encoders.tvl_input``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import math
import os
import stat
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from functools import lru_cache
from typing import Any, Union

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from ratouch.errors import ConfigError, DataError, DataNotFoundError

log = logging.getLogger(__name__)

#: Anything :func:`to_rgb_array` accepts.
ImageLike = Union[Image.Image, np.ndarray, str, "os.PathLike[str]"]

#: Smallest accepted side length, in pixels.
MIN_SIDE = 8
#: Largest accepted image area, in pixels (50 megapixels).
MAX_PIXELS = 50_000_000
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
    return np.ascontiguousarray(_channels_to_rgb(_pixels_to_uint8(arr, what), what))


def _pixels_to_uint8(arr: np.ndarray, what: str) -> np.ndarray:
    """Pixel data of any dtype rescaled to ``uint8`` (channels kept)."""
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
    return arr


def _reduce_pil(img: Image.Image, max_side: int) -> Image.Image:
    """Shrink a loaded PIL image so its longer side is at most ``max_side`` (integer-factor
    ``reduce`` first, then an antialiased bilinear resize), keeping the aspect ratio."""
    longer = max(img.width, img.height)
    if longer <= max_side:
        return img
    scale = max_side / longer
    size = (max(1, round(img.width * scale)), max(1, round(img.height * scale)))
    return img.resize(size, Image.Resampling.BILINEAR, reducing_gap=2.0)


#: PIL modes that PIL resizes directly, averaging what the pixels mean (8-bit colour spaces,
#: 32-bit integer and float planes). The others (1-bit, palette, 16-bit) are first converted
#: band by band into one of these (`_compact`), never whole into RGB.
_REDUCIBLE_MODES = ("RGB", "RGBA", "L", "LA", "RGBa", "La", "I", "F", "CMYK", "YCbCr", "LAB",
                    "HSV")
#: Pixels of a mode PIL cannot resize converted at once (bounds the conversion's memory).
BAND_PIXELS = 1 << 20


def _compact(img: Image.Image, max_side: int, what: str) -> Image.Image:
    """A loaded image of a mode PIL cannot resize (1-bit, palette, 16-bit) as an 8-bit image
    (grey, RGB or RGBA) it can, converted one band of rows at a time, each band reduced by
    the whole factor that keeps the longer side at least ``max_side``: no full-size copy of
    the image in any wider mode is made."""
    factor = max(1, max(img.width, img.height) // max_side)
    rows = max(1, BAND_PIXELS // (img.width * factor)) * factor
    parts = []
    for top in range(0, img.height, rows):
        band = img.crop((0, top, img.width, min(top + rows, img.height)))
        if band.mode == "1":
            band = band.convert("L")
        elif band.mode in ("P", "PA"):
            band = band.convert("RGBA" if band.mode == "PA" or "transparency" in band.info
                                else "RGB")
        elif band.mode.startswith("I;"):  # 16-bit planes: to 8 bits, as `_integer_to_uint8`
            band = Image.fromarray(_pixels_to_uint8(np.asarray(band), what))
        else:
            band = band.convert("RGBA" if "A" in band.mode else "RGB")
        parts.append(np.asarray(band.reduce(factor) if factor > 1 else band))
    return Image.fromarray(np.concatenate(parts))


#: An upload of more pixels than this is "large": decoding it waits for one of
#: `DECODE_SLOTS`, so that a burst of huge uploads (the app batches up to 16 queries) costs
#: `DECODE_SLOTS` decodes' memory at once, not 16; smaller ones (every camera frame and world
#: render) never wait.
LARGE_PIXELS = 4_000_000
#: Large uploads decoded at once in one process (each at most about 200 MB at the pixel limit).
DECODE_SLOTS = 4


class DecodeSlots:
    """At most `n` large uploads decoded at once in this process (re-entrant per thread), and
    the C heap given back to the system after each (glibc keeps freed image buffers of a
    few MB otherwise: a burst's memory would stay)."""

    def __init__(self, n: int) -> None:
        self._slots = threading.BoundedSemaphore(n)
        self._held = threading.local()

    @contextmanager
    def hold(self, img: Image.Image) -> Iterator[None]:
        if img.width * img.height <= LARGE_PIXELS or getattr(self._held, "on", False):
            yield
            return
        with self._slots:
            self._held.on = True
            try:
                yield
            finally:
                self._held.on = False
        _trim_heap()


LARGE_DECODES = DecodeSlots(DECODE_SLOTS)


@lru_cache(maxsize=1)
def _malloc_trim():
    """glibc's `malloc_trim`, or None where there is none (another C library, not Linux)."""
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or None).malloc_trim
    except (OSError, AttributeError):
        return None


def _trim_heap() -> None:
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


def _pil_to_rgb(img: Image.Image, what: str, max_side: int | None = None) -> np.ndarray:
    """Normalise a PIL image of any mode to ``(H, W, 3)`` ``uint8`` (EXIF orientation applied),
    reduced to ``max_side`` (when given) before any per-pixel conversion."""
    _check_size(img.width, img.height, what)
    with LARGE_DECODES.hold(img):
        return _decode_pil(img, what, max_side)


def _decode_pil(img: Image.Image, what: str, max_side: int | None) -> np.ndarray:
    if max_side is not None and getattr(img, "format", None) == "JPEG":
        img.draft("RGB", (max_side, max_side))  # JPEG: decode at a reduced scale directly
    try:
        img.load()
    except (OSError, ValueError, SyntaxError) as e:  # truncated or corrupt file data
        raise DataError(f"cannot decode {what}: {e}") from e
    if max_side is not None and max(img.width, img.height) > max_side:
        # reduce first: the EXIF rotation keeps the longer side, and copies the image
        exif = img.getexif()
        if img.mode not in _REDUCIBLE_MODES:
            img = _compact(img, max_side, what)
            img.getexif().update(exif)  # the orientation still applies
        img = _reduce_pil(img, max_side)
        img.getexif().update(exif)
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


def not_a_file(path: str | os.PathLike[str]) -> str | None:
    """What a path that exists is when it is not a regular file ("a directory", "a character
    device", ...), for messages; None for a regular file or a path that does not exist."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    for test, kind in ((stat.S_ISREG, None), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


def _open_image(path: str | os.PathLike[str], role: str = "image") -> Image.Image:
    """Open an image file lazily, with project errors (naming its role, e.g. "tactile
    image", and path) for missing or unreadable files."""
    path_str = os.fspath(path)
    if not os.path.exists(path_str):
        raise DataNotFoundError(f"{role} file not found: {path_str}")
    kind = not_a_file(path_str)
    if kind == "a directory":
        raise DataError(f"{role}: expected an image file, got a directory: {path_str}")
    if kind is not None:  # /dev/zero would be read for ever
        raise DataError(f"{role} {path_str} is {kind}, not an image file")
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
        img = _open_image(image, name or "image")
        with LARGE_DECODES.hold(img), img:  # closed (its pixels freed) before the slot is
            return fit_within(_pil_to_rgb(img, what, max_side), max_side)
    what = name or "image"
    if isinstance(image, Image.Image):
        return fit_within(_pil_to_rgb(image, what, max_side), max_side)
    if isinstance(image, np.ndarray):
        return fit_within(_array_to_rgb(image, what), max_side)
    if type(image).__module__.split(".")[0] == "torch":  # torch itself is not imported here
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
        img = _open_image(image, name)
        with LARGE_DECODES.hold(img), img:  # a PNG's EXIF may follow its pixels: it loads
            return _oriented(img, name)
    if isinstance(image, Image.Image):
        return _oriented(image, name)
    height, width = to_rgb_array(image, name).shape[:2]  # arrays are decoded already
    return width, height


def _oriented(img: Image.Image, what: str) -> tuple[int, int]:
    _check_size(img.width, img.height, what)
    swap = _orientation(img) in (5, 6, 7, 8)
    return (img.height, img.width) if swap else (img.width, img.height)


def _orientation(img: Image.Image) -> int:
    """The EXIF orientation tag (1: as stored; 1 too for broken EXIF, as in _pil_to_rgb)."""
    try:
        return int(img.getexif().get(0x0112, 1))
    except Exception:  # noqa: BLE001 - broken EXIF is ignored, as in _pil_to_rgb
        return 1


#: Largest coordinate magnitude a box may have (a signed 64-bit integer's range).
MAX_COORDINATE = 2**63 - 1


def clip_box(box: Sequence[float], width: int, height: int) -> tuple[int, int, int, int]:
    """A box as whole pixels clipped to a ``width`` x ``height`` image (see :func:`crop_box`):
    the box a query uses, and reports.

    Raises:
        DataError: not four numbers, a value infinite, NaN or beyond the 64-bit range (the
            message names it), or a box empty, inverted or outside the image.
    """
    try:
        values = [float(v) for v in box]
    except (TypeError, ValueError, OverflowError) as e:
        raise DataError(f"box must be four numbers (x0, y0, x1, y1), got {box!r}") from e
    if len(values) != 4:
        raise DataError(f"box must be four finite numbers (x0, y0, x1, y1), got {box!r}")
    for name, v in zip(("x0", "y0", "x1", "y1"), values):
        if not math.isfinite(v):
            raise DataError(f"box must be four finite numbers (x0, y0, x1, y1): {name}={v} is "
                            f"not finite (box {list(box)})")
        if abs(v) > MAX_COORDINATE:
            raise DataError(f"box {name}={v:g} is beyond the 64-bit range (box {list(box)})")
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
    if isinstance(image, (str, os.PathLike)):
        img = _open_image(image, name or "image")
        with LARGE_DECODES.hold(img), img:  # closed (its pixels freed) before the slot is
            return _crop_pil(img, box, max_side, name or f"image {os.fspath(image)}")
    if isinstance(image, Image.Image):
        return _crop_pil(image, box, max_side, name or "image")
    return crop_box(to_rgb_array(image, name), box, max_side, name)  # not an image: its error


def _crop_pil(img: Image.Image, box: Sequence[float], max_side: int, what: str) -> np.ndarray:
    """`crop_box` of a PIL image, reduced to `max_side`: a file that is not a JPEG and needs
    no EXIF rotation is cut in its own mode before any conversion; a JPEG is decoded at a
    reduced scale and cut after (its draft mode makes that the cheaper order)."""
    width, height = _oriented(img, what)
    cx0, cy0, cx1, cy1 = clip_box(box, width, height)
    if getattr(img, "format", None) != "JPEG" and _orientation(img) == 1:
        with LARGE_DECODES.hold(img):
            try:
                region = img.crop((cx0, cy0, cx1, cy1))
            except (OSError, ValueError, SyntaxError) as e:  # truncated or corrupt file data
                raise DataError(f"cannot decode {what}: {e}") from e
            return to_rgb_array(region, what, max_side=max_side)
    factor = min(1.0, max_side / max(cx1 - cx0, cy1 - cy0))
    arr = to_rgb_array(img, what, max_side=max(MIN_SIDE, math.ceil(max(width, height) * factor)))
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


# --------------------------------------------------------------------------- resize


def check_background_size(background_wh: tuple[int, int], frame_wh: tuple[int, int],
                          background: str = "the background image",
                          frame: str = "the tactile image") -> None:
    """The one check that a tactile sensor's no-contact frame has the size (W, H) of the frame
    it belongs to (compared before any reduction, or as arrays).

    Args:
        background_wh, frame_wh: (width, height) of each.
        background, frame: how the message names them ("the background image",
            "background 3", a file's role and path).

    Raises:
        DataError: naming both sizes, when they differ.
    """
    if tuple(background_wh) != tuple(frame_wh):
        raise DataError(f"{background} is {background_wh[0]}x{background_wh[1]} (WxH) but "
                        f"{frame} is {frame_wh[0]}x{frame_wh[1]}; the background must be the "
                        "same sensor's no-contact frame at the same size")


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


# --------------------------------------------------------------------------- blur

#: How far a Gaussian blur reaches, in standard deviations (scipy.ndimage's default).
BLUR_TRUNCATE = 4.0
#: From this sigma on, `gaussian_blur` multiplies by the blur's matrix; below it scipy's
#: running sum over the (short) kernel is the faster (measured on 96-320 px frames).
BLUR_MATRIX_FROM = 2.0


@lru_cache(maxsize=64)
def _blur_matrix(n: int, sigma: float) -> np.ndarray:
    """(n, n) float64: the Gaussian blur of a length-`n` signal as a matrix, boundaries
    mirrored ("reflect"), exactly `scipy.ndimage.gaussian_filter1d`'s operator (made by
    applying it to the identity)."""
    from scipy.ndimage import gaussian_filter1d

    m = gaussian_filter1d(np.eye(n), sigma, axis=0, mode="reflect", truncate=BLUR_TRUNCATE)
    m.setflags(write=False)
    return m


def gaussian_blur(a: np.ndarray, sigma: float) -> np.ndarray:
    """A float image blurred by a Gaussian of `sigma` pixels over its two spatial axes (each
    channel of an (H, W, C) array alone): `scipy.ndimage.gaussian_filter(a, (sigma, sigma[,
    0]))`, boundaries mirrored, truncated at :data:`BLUR_TRUNCATE` sigmas, in the input's
    dtype. From :data:`BLUR_MATRIX_FROM` on, each axis is one matrix product with the blur's
    (cached) matrix, computed in float64: the same operator as scipy's, up to the order of
    the sums (1e-15 relative; a float32 result may differ by its last bit), and many times
    faster for the wide blurs the tactile inputs (sigma 8-20), the contact features and the
    height map read; below it, scipy's own filter.

    Raises:
        ValueError: `a` is not a 2-D or 3-D float array, or sigma is not positive.
    """
    if a.ndim not in (2, 3) or not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"gaussian_blur takes a 2-D or 3-D float array, not {a.dtype} "
                         f"{a.shape}")
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0, got {sigma}")
    if sigma < BLUR_MATRIX_FROM:
        from scipy.ndimage import gaussian_filter

        return gaussian_filter(a, (sigma, sigma, 0)[:a.ndim], mode="reflect",
                               truncate=BLUR_TRUNCATE)
    h, w = a.shape[:2]
    x = np.asarray(a, np.float64)
    rows = (_blur_matrix(h, float(sigma)) @ x.reshape(h, -1)).reshape(x.shape)
    cols = _blur_matrix(w, float(sigma)) @ np.swapaxes(rows, 0, 1).reshape(w, -1)
    out = np.swapaxes(cols.reshape((w, h) + x.shape[2:]), 0, 1)
    return np.ascontiguousarray(out, a.dtype)

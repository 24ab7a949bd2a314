"""What travels through serving: a decoded `QueryRequest` in, a `QueryResult` out, and the one
interface every serving part offers, `Answerer`.

A request is decoded once, where it arrives (`QueryRequest.decode`: in the app's handler, in
`ratouch query`, in a caller's thread), and handed down as it is. The parts of serving
(`RATouchPipeline`, `Cascade`, `ModelChoice`, `QueryBatcher`, `BackgroundPipeline`)
are each an `Answerer`, and the wrapping ones wrap an `Answerer`: none decodes again.

A request names its model (`QueryRequest.model`) as `model_name` spells it: an encoder set
("default-s"), or one with the generators of a pretrained language model
("default-s+smollm2-135m").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import numpy as np
from PIL import Image

from ratouch.errors import ConfigError
from ratouch.images import (
    QUERY_MAX_SIDE,
    check_background_size,
    clip_box,
    crop_box,
    oriented_size,
    to_rgb_array,
    tvl_contact_box,
)
from ratouch.model.geometry import HeightMap
from ratouch.search.modes import RETRIEVAL_SYSTEMS

Box = tuple[int, int, int, int]

#: The most neighbours per query mode a query may ask for, wherever it arrives (the app's
#: slider, `ratouch query --k`, the HTTP API): a larger K buys no better description, only a
#: larger answer (K = 10,000 made an 11 MB one).
MAX_K = 20


#: The largest K a person is offered: the app's slider and `/query` API, `ratouch query --k`
#: (more neighbours per mode than a page shows side by side or a reader compares).
MAX_K = 20


def check_k(k: Any, largest: int | None = None) -> int:
    """K, the neighbours per mode, as given or typed: a whole number from 1 to `largest`
    (None: no bound). An int, or a float or text holding a whole number (7.0 from a slider,
    "7" typed), counts as that number. The one check of K: the app, the CLI, every answerer
    (against its corpus's size) and the evaluations that take a K call it.

    Raises:
        ConfigError: naming K and the value, for anything else (a bool, 2.5, "", "five", NaN,
            0, more than `largest`).
    """
    value = float("nan")
    if not isinstance(k, bool):
        try:
            value = float(k)
        except (TypeError, ValueError, OverflowError):
            pass
    if not (value.is_integer() and value >= 1 and (largest is None or value <= largest)):
        span = f"from 1 to {largest}" if largest is not None else "of at least 1"
        raise ConfigError(f"K must be a whole number {span}, got K={k!r} (K: the neighbours "
                          "per query mode)")
    return int(value)


@dataclass(frozen=True, eq=False)
class QueryRequest:
    """One query, decoded: what every `Answerer` takes.

    Attributes:
        crop: the contact crop of the visual image, (h, w, 3) uint8, reduced to
            `QUERY_MAX_SIDE`.
        frame: the tactile frame, (h, w, 3) uint8 (reduced), or None: image-only retrieval.
        background: the tactile sensor's no-contact frame (same size as the frame), or None.
        box: the contact box used, (x0, y0, x1, y1) in whole pixels of the visual image,
            clipped to it (`clip_box`: what was cropped, whatever was given).
        k: neighbours per query mode.
        label: the ground-truth tactile caption, when known (plotted in the PCA).
        model: the model that should answer (an encoder set or "cascade"), for a server that
            offers a choice (`ratouch.serve.models.ModelChoice`); None: its default.
        retrieval: the retrieval system RA-Touch answers with (a key of
            `ratouch.search.modes.RETRIEVAL_SYSTEMS`: "paper", "gated", "text", "fallback");
            None: the answerer's default.
        warnings: what decoding had to assume (no box, no tactile image, ...).
        decode_ms: what decoding took.
    """

    crop: np.ndarray
    frame: np.ndarray | None
    background: np.ndarray | None
    box: Box
    k: int = 5
    label: str | None = None
    model: str | None = None
    warnings: tuple[str, ...] = ()
    decode_ms: float = 0.0
    retrieval: str | None = None

    @classmethod
    def decode(cls, visual: Any, tactile: Any = None, box=None, k: int = 5,
               label: str | None = None, background: Any = None,
               model: str | None = None, retrieval: str | None = None) -> "QueryRequest":
        """Check and decode one query's inputs.

        The work is bounded whatever the upload's size: the visual crop and the tactile frame
        (and its background) are reduced to `QUERY_MAX_SIDE` pixels inside PIL before any
        per-pixel work.

        Args:
            visual: the visual image (array, PIL image or path).
            tactile: the tactile image, or None (image-only retrieval, said in `warnings`).
            box: contact box (x0, y0, x1, y1) in pixels of the visual image; None uses TVL's
                centred crop and says so in `warnings`.
            k: neighbours per mode (whether the corpus has that many is the answerer's check).
            label: the ground-truth tactile caption, when known.
            background: the tactile sensor's no-contact frame (same size as `tactile`), or
                None: used by the no-contact check (and by encoders trained on
                background-subtracted frames).
            model: the model that should answer, where there is a choice.
            retrieval: the retrieval system (a key of `RETRIEVAL_SYSTEMS`), or None: the
                default.

        Raises:
            ConfigError: k is not a whole number from 1 to `MAX_K`; an unknown retrieval
                system.
            DataError, DataNotFoundError, OSError: an image or the box cannot be used.
        """
        t0 = time.perf_counter()
        k = check_k(k, MAX_K)
        if retrieval is not None and retrieval not in RETRIEVAL_SYSTEMS:
            raise ConfigError(f"unknown retrieval system {retrieval!r}; one of "
                              f"{', '.join(RETRIEVAL_SYSTEMS)}")
        width, height = oriented_size(visual, "visual image")
        warnings: list[str] = []
        used = clip_box(tvl_contact_box(width, height) if box is None else box, width, height)
        if box is None:
            warnings.append(f"no contact box given: used TVL's centred crop {list(used)}")
        elif used != tuple(box):
            warnings.append(f"contact box {_plain(box)} used as {list(used)} (whole pixels"
                            + (", clipped to the image)" if _clipped(box, width, height)
                               else ")"))
        crop = crop_box(visual, used, max_side=QUERY_MAX_SIDE, name="visual image")
        frame, bg = _tactile_inputs(tactile, background, warnings)
        return cls(crop, frame, bg, used, k, label, model, tuple(warnings),
                   round((time.perf_counter() - t0) * 1000, 2), retrieval)


def _plain(box) -> list:
    """A box as typed: whole numbers without ".0"."""
    return [int(v) if float(v).is_integer() else float(v) for v in box]


def _clipped(box, width: int, height: int) -> bool:
    x0, y0, x1, y1 = (float(v) for v in box)
    return x0 < 0 or y0 < 0 or x1 > width or y1 > height


def _tactile_inputs(tactile: Any, background: Any, warnings: list[str]
                    ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The tactile frame and sensor background, decoded and reduced."""
    if tactile is None:
        warnings.append("no tactile image: image-only retrieval; the tactile and joint "
                        "queries and the RA-Touch description are not available")
        if background is not None:
            warnings.append("a background frame was given without a tactile image: ignored")
        return None, None
    size = _source_size(tactile)
    frame = to_rgb_array(tactile, name="tactile image", max_side=QUERY_MAX_SIDE)
    if background is None:
        return frame, None
    bg_size = _source_size(background)
    bg = to_rgb_array(background, name="background image", max_side=QUERY_MAX_SIDE)
    check_background_size(bg_size or bg.shape[1::-1], size or frame.shape[1::-1])
    return frame, bg


def _source_size(image: Any) -> tuple[int, int] | None:
    """(W, H) of an image before any reduction: PIL images and arrays directly, files from
    their header (no decoding); None if a file cannot be opened (decoding then says why)."""
    if isinstance(image, Image.Image):
        return image.size
    if isinstance(image, np.ndarray) and image.ndim >= 2:
        return int(image.shape[1]), int(image.shape[0])
    try:
        with Image.open(image) as img:
            return img.size
    except Exception:  # noqa: BLE001 - to_rgb_array reports unreadable files properly
        return None


@dataclass
class QueryResult:
    """One answered query. `to_dict()` is its JSON form (what `ratouch query` prints, the
    app's `/query` API returns and the page shows).

    Attributes:
        neighbours: {mode: [{"id", "score", "class_name", "caption", "description",
            "source"}]}, best first, per query mode (`ratouch.search.modes.QUERY_MODES`, in
            its order) that the request allows (those needing a frame only with one).
        description: {"ra_touch", "baseline"} ("" where not generated).
        attention: {"image"|"text": [RA-Touch's integrator weight per neighbour it read]}.
        pca: {"points": [{"role", "x", "y", "id"?}], "explained": [..]}.
        timings_ms: {stage: ms, ..., "total": ms, "batch_size", "decode": this request's
            decoding, done before it was answered}; the stages are the batch's, shared by its
            requests.
        warnings: what the answer had to assume or found suspicious.
        box: the contact box used.
        encoder: the model that answered: its encoder set ("default-s"), with the language model
            its generators were adapted from where there is one ("default-s+smollm2-135m").
        visual_route: {"route": "render"}, or the photo route's account (a crop that looks
            like a real photo: "classes", "coverage", "note").
        trust: {"visual": {"novelty", "threshold", "novel", "space", "uniform"}, "tactile":
            {"novelty", "threshold", "novel", "contact", "contact_threshold", "no_contact",
            "background", "contact_model" (without a background, which model read the frame
            alone: "colour-blind" for a sensor unlike every rendered unit where the calibration
            has that model, else "disc-press"; None with one)} or None}, or None (no
            calibration). A uniform visual crop (a blank
            or flat photo) is novel whatever its distance (`model.trust.UNIFORM_SPREAD`).
            With a background, "tactile" also holds "structure" (the structured-contact
            reading: "score", "threshold", "family", "contact", "floors": "family" or, for a
            sensor unlike every rendered unit, "unfamiliar sensor") and "geometry" (the height
            map's "depth", "spread", "relief", "units", "family"), each None where no
            geometry lookup reads the sensor.
        retrieval: which neighbours RA-Touch read and how far touch steered them:
            {"system" (a key of `RETRIEVAL_SYSTEMS`), "reads" (the query mode), "touch_weight",
            "kind", "features", "why"}; None without a tactile frame.
        cascade: where a cascade answered, {"answered_by", "stage", "escalated",
            "confidence": [per stage tried], "thresholds", "measure"}; else None.
        height_map: the press read against the sensor's background as a height map
            (`TrustCalibration.read_geometry`), for a picture of it (`HeightMap.image`);
            None without a background or a geometry lookup. Not in `to_dict()`: its numbers
            are trust's "geometry".
    """

    neighbours: dict[str, list[dict]]
    description: dict[str, str]
    attention: dict[str, list[float]]
    pca: dict
    timings_ms: dict[str, float]
    warnings: list[str]
    box: list[int]
    encoder: str
    visual_route: dict
    trust: dict | None
    cascade: dict | None = field(default=None)
    retrieval: dict | None = field(default=None)
    height_map: HeightMap | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict:
        """The JSON-ready dict, keys in this order ("cascade" only where a cascade answered)."""
        out = {"neighbours": self.neighbours, "description": self.description,
               "attention": self.attention, "pca": self.pca, "timings_ms": self.timings_ms,
               "warnings": self.warnings, "box": self.box, "encoder": self.encoder,
               "visual_route": self.visual_route, "trust": self.trust,
               "retrieval": self.retrieval}
        if self.cascade is not None:
            out["cascade"] = self.cascade
        return out


M_co = TypeVar("M_co", covariant=True)


class Answerer(Protocol):
    """Answers decoded requests, several at once."""

    def answer(self, requests: Sequence[QueryRequest]) -> list[QueryResult | Exception]:
        """Per request, in order: its result, or the exception that request raised (a k the
        corpus cannot give, an unknown model, ...); the other requests are answered all the
        same."""
        ...


class ModelAnswerer(Answerer, Protocol[M_co]):
    """An `Answerer` that also gives the loaded model answering requests that name `name`
    (a `RATouchPipeline`, a `Cascade`, a `ModelChoice`, ...)."""

    def model(self, name: str | None = None) -> M_co:
        ...


def slots_for(requests: Sequence[QueryRequest], largest_k: int
              ) -> tuple[list[QueryResult | Exception | None], list[int]]:
    """An answerer's start: one empty slot per request, the error already in the slot of a
    request whose K is not from 1 to `largest_k` (the corpus's size), and the positions of
    the requests left to answer."""
    out: list[QueryResult | Exception | None] = [None] * len(requests)
    todo: list[int] = []
    for pos, req in enumerate(requests):
        try:
            check_k(req.k, largest_k)
            todo.append(pos)
        except ConfigError as e:
            out[pos] = e
    return out, todo


def all_answered(out: Sequence[QueryResult | Exception | None]
                 ) -> list[QueryResult | Exception]:
    """An answerer's per-request slots (filled in any order) once every one holds its result
    or its exception, as `Answerer.answer` returns them.

    Raises:
        RuntimeError: a slot is still empty (a bug of the answerer).
    """
    done = [r for r in out if r is not None]
    if len(done) != len(out):
        raise RuntimeError(f"{len(out) - len(done)} of {len(out)} requests were not answered")
    return done


def answer_one(answerer: Answerer, request: QueryRequest) -> QueryResult:
    """`answerer.answer` of one request: its result, or its exception raised."""
    out = answerer.answer([request])[0]
    if isinstance(out, BaseException):
        raise out
    return out


#: Joins an encoder set's name and a pretrained language model's in a model name.
LM_SEPARATOR = "+"


def model_name(encoder: str, lm: str | None = None) -> str:
    """The name a model answers by: "default-s", or "default-s+smollm2-135m" for the
    generators adapted from a pretrained language model."""
    return encoder if lm is None else f"{encoder}{LM_SEPARATOR}{lm}"


def split_model_name(name: str) -> tuple[str, str | None]:
    """(encoder, lm) of a `model_name`."""
    encoder, _, lm = name.partition(LM_SEPARATOR)
    return encoder, (lm or None)

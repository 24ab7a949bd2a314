"""What retrieval did for one answered query: whether RA-Touch's words differ from the
baseline's, which joint neighbours the integrator attended to most, and which words of the
description those neighbours' captions carry.

`trace_retrieval(result)` reads a `QueryResult` (or its JSON, `QueryResult.to_dict()`, as the
app and the `/query` API hold it) and returns a `RetrievalTrace`; `marked_segments` cuts a
description into pieces, each with the neighbours that carry it, for a client to highlight;
`touch_reading(result)` is what touch alone reads in the answer (the top caption of the query
made for the press's regime). Nothing here runs a model: it only reads what the answer already
holds.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ratouch.errors import DataError
from ratouch.search.modes import RA_TOUCH_MODE
from ratouch.serve.request import QueryResult
from ratouch.vocabulary import parse_adjectives


@dataclass(frozen=True)
class AttendedNeighbour:
    """One joint neighbour RA-Touch read, with the integrator's attention on it.

    Attributes:
        id: corpus id.
        rank: 1-based rank in the joint query's top-K.
        class_name: its corpus class.
        caption: its tactile caption.
        weight: the attention on it, the mean of its image and text weights (each sums to 1
            over the K neighbours, so an even share is 1/K).
        image: the attention on its image.
        text: the attention on its text.
        words: the description's words that its caption carries, in the description's order.
    """

    id: int
    rank: int
    class_name: str
    caption: str
    weight: float
    image: float
    text: float
    words: tuple[str, ...]


@dataclass(frozen=True)
class RetrievalTrace:
    """What retrieval changed in one answer.

    Attributes:
        ra_words: RA-Touch's adjectives, in order.
        baseline_words: the baseline's adjectives, in order.
        same_words: RA-Touch gave the baseline's words (as sets: order and repeats aside).
        added: RA-Touch's words the baseline did not say.
        dropped: the baseline's words RA-Touch did not say.
        attended: the most attended joint neighbours, most attended first.
        even_share: 1/K, the weight of each neighbour under uniform attention.
        carried: each RA-Touch word that an attended neighbour's caption carries -> the ranks
            of those neighbours.
        in_neighbours: RA-Touch's words found in any joint neighbour's caption.
        system: the retrieval system that answered (a key of `RETRIEVAL_SYSTEMS`: "paper", "gated", "text" or "fallback").
        reads: the query mode whose neighbours RA-Touch read.
        touch_weight: how far touch steered that query (1: fully, the paper's joint query;
            None: not said).
        touch_why: why touch was trusted as it was.
        generator: which RA-Touch generator read them: "paper" (the paper's, trained on the
            joint query's neighbours) or "reader" (the gated system's, trained in reading
            episodes); "" when not said.
    """

    ra_words: tuple[str, ...]
    baseline_words: tuple[str, ...]
    same_words: bool
    added: tuple[str, ...]
    dropped: tuple[str, ...]
    attended: tuple[AttendedNeighbour, ...]
    even_share: float
    carried: dict[str, tuple[int, ...]] = field(default_factory=dict)
    in_neighbours: tuple[str, ...] = ()
    system: str = "paper"
    reads: str = RA_TOUCH_MODE
    touch_weight: float | None = None
    touch_why: tuple[str, ...] = ()
    generator: str = ""

    @property
    def nearly_even(self) -> bool:
        """No neighbour stands out: the most attended holds under 1.25 even shares."""
        return not self.attended or self.attended[0].weight < 1.25 * self.even_share


def read_mode(result: Mapping[str, Any]) -> str:
    """The query mode whose neighbours an answer's RA-Touch read (`"reads"` in its retrieval
    block, `QueryResult.to_dict()`): the joint query's for the paper's system, the gated or
    the image query's for `gated`; the joint query's where the block says nothing."""
    return (result.get("retrieval") or {}).get("reads") or RA_TOUCH_MODE


def trace_retrieval(result: QueryResult | Mapping[str, Any], top: int = 3
                    ) -> RetrievalTrace | None:
    """The trace of one answer, or None when RA-Touch gave no description (no tactile image,
    no contact) or read no neighbours.

    Args:
        result: an answered query, or its JSON (`QueryResult.to_dict()`).
        top: how many of the most attended joint neighbours to keep.

    Raises:
        DataError: `top` < 1, or the attention does not have one weight per joint neighbour.
    """
    if top < 1:
        raise DataError(f"top must be at least 1 (attended neighbours to show), got {top!r}")
    res = result.to_dict() if isinstance(result, QueryResult) else result
    description = res.get("description") or {}
    block = res.get("retrieval") or {}
    reads = read_mode(res)
    joint = (res.get("neighbours") or {}).get(reads) or []
    ra_text = description.get("ra_touch") or ""
    if not ra_text or not joint:
        return None
    ra, base = parse_adjectives(ra_text), parse_adjectives(description.get("baseline") or "")
    weights = _weights(res.get("attention") or {}, len(joint))
    ra_set = set(ra)
    neighbours = []
    for rank, (n, (w_img, w_txt)) in enumerate(zip(joint, weights), 1):
        caption_words = set(parse_adjectives(n.get("caption", "")))
        neighbours.append(AttendedNeighbour(
            int(n["id"]), rank, str(n.get("class_name", "")), str(n.get("caption", "")),
            (w_img + w_txt) / 2, w_img, w_txt, tuple(w for w in ra if w in caption_words)))
    # most attended first; ties (no integrator: all weights equal) keep the retrieval order
    attended = tuple(sorted(neighbours, key=lambda a: -a.weight)[:top])
    carried: dict[str, tuple[int, ...]] = {}
    for word in ra:
        ranks = tuple(a.rank for a in attended if word in a.words)
        if ranks:
            carried[word] = ranks
    anywhere = {w for n in neighbours for w in n.words}
    return RetrievalTrace(
        tuple(ra), tuple(base), ra_set == set(base), tuple(w for w in ra if w not in set(base)),
        tuple(w for w in base if w not in ra_set), attended, 1.0 / len(joint), carried,
        tuple(w for w in ra if w in anywhere), block.get("system", "paper"), reads,
        # the joint query (the paper's and the text system's) lets touch steer fully
        (1.0 if reads == RA_TOUCH_MODE else block.get("touch_weight"))
        if block else None, tuple(block.get("why") or ()), str(block.get("generator") or ""))


def _weights(attention: Mapping[str, Sequence[float]], k: int) -> list[tuple[float, float]]:
    """(image, text) attention per joint neighbour; a path the integrator lacks counts as
    the other one, and no attention at all (no integrator) as even shares."""
    image, text = attention.get("image"), attention.get("text")
    for name, w in (("image", image), ("text", text)):
        if w is not None and len(w) != k:
            raise DataError(f"the integrator's {name} attention has {len(w)} weights for {k} "
                            "joint neighbours")
    if image is None and text is None:
        return [(1.0 / k, 1.0 / k)] * k
    image = image if image is not None else text
    text = text if text is not None else image
    assert image is not None and text is not None
    return [(float(a), float(b)) for a, b in zip(image, text)]


def marked_segments(text: str, carried: Mapping[str, Sequence[int]]
                    ) -> list[tuple[str, tuple[int, ...]]]:
    """`text` cut into pieces that together spell it, each with the ranks of the neighbours
    that carry it (() for the pieces between the carried words): a client highlights the
    pieces with ranks. Each carried word is marked at its first whole-word occurrence."""
    spans: list[tuple[int, int, tuple[int, ...]]] = []
    for word, ranks in carried.items():
        m = re.search(rf"(?<![\w-]){re.escape(word)}(?![\w-])", text, flags=re.IGNORECASE)
        if m and not any(s < m.end() and m.start() < e for s, e, _ in spans):
            spans.append((m.start(), m.end(), tuple(ranks)))
    out: list[tuple[str, tuple[int, ...]]] = []
    pos = 0
    for start, end, ranks in sorted(spans):
        if start > pos:
            out.append((text[pos:start], ()))
        out.append((text[start:end], ranks))
        pos = end
    if pos < len(text):
        out.append((text[pos:], ()))
    return out


def touch_reading(result: Mapping[str, Any]) -> dict:
    """What touch alone reads in a query's result: the top caption of the query made for the
    press's regime. A press read as an everyday one (a flat face, a fabric, foam, tape, wire,
    an edge, a small cap) is read by the adapted tactile query (the press map, fitted on such
    presses); a firm press of the world's regime (a material or a ball pressed in), or a frame
    no router read, by the paper's tactile query. Against a background the regime is the
    shape's (the family's firmness router, `RoutedFirmness`, `tactile.firmness`); alone, the
    tactile embedding's (the press map's `RegimeRouter`, `tactile.press_regime`)
    (docs/geometry.md, "The touch-only reading routed by the press's regime").

    Returns:
        {"caption": the reading ("" without neighbours), "query": "adapted" or "tactile",
        "regime": "everyday", "world" or None (no router read the frame), "by": "shape",
        "embedding" or None}.
    """
    tac = (result.get("trust") or {}).get("tactile") or {}
    by = "shape" if tac.get("background") else "embedding"
    regime = ((tac.get("firmness") if by == "shape" else tac.get("press_regime")) or {}).get(
        "regime")
    neighbours = result.get("neighbours") or {}
    query = "adapted" if regime == "everyday" and neighbours.get("adapted") else "tactile"
    top = neighbours.get(query) or []
    return {"caption": top[0]["caption"] if top else "", "query": query, "regime": regime,
            "by": by if regime else None}

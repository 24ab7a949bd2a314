"""The query modes: one row per way a query becomes a vector, read by everything that shows,
searches or scores a mode.

A row carries what the rest of the code needs to know about a mode: its name (the key of a
result's "neighbours" and of every evaluation's per-mode figures), its title, letter and colour
(the app's galleries and PCA plot, the stress charts), the inputs it needs (the crop's image
embedding, the tactile frame's, the Tactile-Guided Retriever) and how its query vectors are
made from them, and the corpus key modalities it is searched against in Table 4's retrieval
settings. The pipeline (`ratouch.serve.pipeline.RATouchPipeline.encode`), `CorpusSearch`,
evaluation (retrieval quality, the failure table, the stress sweeps, report and charts),
serving and the app iterate over :data:`QUERY_MODES` in its order; none of them spells a
mode's name, except for the one role that is a mode's by definition: RA-Touch reads the
neighbours of :data:`RA_TOUCH_MODE`.

Adding a mode is adding a row to :data:`_BUILTIN` (or `QUERY_MODES.register(row)` at run time,
as a test or a notebook does); an unknown name is a `ConfigError`, never a silent default.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ratouch.errors import ConfigError


class JointQuery(Protocol):
    """(V, T) -> joint queries: the Tactile-Guided Retriever (`RetrievalSide.joint_query`);
    `gated=True`: the trust-gated query (`ratouch.model.gate`); `adapted=True`: the tactile
    query through the retrieval side's press map (`ratouch.model.press_map`)."""

    def __call__(self, V: np.ndarray, T: np.ndarray, *, gated: bool = False,
                 adapted: bool = False) -> np.ndarray: ...

#: The inputs a mode may need: the crops' image embeddings, the frames' tactile embeddings,
#: the Tactile-Guided Retriever.
INPUTS = ("image", "tactile", "retriever")
#: The corpus key modalities a mode can be searched against.
KEYS = ("image", "text")


@dataclass(frozen=True)
class QueryMode:
    """One query mode.

    Attributes:
        name: the key of a result's "neighbours" and of the per-mode figures.
        title: the app's gallery title.
        letter: one letter, in "shared by I·T·J".
        colour: a CSS hex colour (galleries, PCA plot, stress charts).
        needs: the inputs its vectors are made from, a subset of :data:`INPUTS`.
        make: ``make(V, T, joint_query) -> (N, D)`` query vectors from (N, D) image and tactile
            embeddings (None where the mode does not need them) and the retriever.
        keys: the corpus key modalities it is searched against in Table 4's settings.
    """

    name: str
    title: str
    letter: str
    colour: str
    needs: frozenset[str]
    make: Callable[[np.ndarray | None, np.ndarray | None, JointQuery | None], np.ndarray]
    keys: tuple[str, ...] = ("text",)

    def __post_init__(self):
        if not self.name.isidentifier():
            raise ConfigError(f"query mode name must be an identifier, got {self.name!r}")
        if len(self.letter) != 1:
            raise ConfigError(f"query mode {self.name!r}: letter must be one character, "
                              f"got {self.letter!r}")
        if not (self.colour.startswith("#") and len(self.colour) == 7):
            raise ConfigError(f"query mode {self.name!r}: colour must be #rrggbb, "
                              f"got {self.colour!r}")
        if not self.needs or not set(self.needs) <= set(INPUTS):
            raise ConfigError(f"query mode {self.name!r}: needs must be a non-empty subset of "
                              f"{INPUTS}, got {sorted(self.needs)}")
        if not self.keys or not set(self.keys) <= set(KEYS):
            raise ConfigError(f"query mode {self.name!r}: keys must be a non-empty subset of "
                              f"{KEYS}, got {self.keys}")

    @property
    def needs_touch(self) -> bool:
        """Whether the mode exists only for queries with a tactile frame."""
        return "tactile" in self.needs

    def available(self, have: set[str] | frozenset[str]) -> bool:
        """Whether `have` (names of :data:`INPUTS`) holds every input the mode needs."""
        return self.needs <= set(have)

    def vectors(self, V: np.ndarray | None, T: np.ndarray | None,
                joint_query: JointQuery | None) -> np.ndarray:
        """The mode's (N, D) C-contiguous float32 query vectors."""
        given = {"image": V is not None, "tactile": T is not None,
                 "retriever": joint_query is not None}
        missing = [i for i in sorted(self.needs) if not given[i]]
        if missing:
            raise ConfigError(f"query mode {self.name!r} needs {', '.join(missing)}")
        return np.ascontiguousarray(self.make(V, T, joint_query), np.float32)


class QueryModes(Mapping[str, QueryMode]):
    """The registry: name -> `QueryMode`, in registration order. Iterating gives the names,
    so ``for m in QUERY_MODES`` and ``m in QUERY_MODES`` read as they did for a tuple."""

    def __init__(self, rows: tuple[QueryMode, ...]):
        self._rows: dict[str, QueryMode] = {}
        self._lock = threading.Lock()
        for row in rows:
            self.register(row)

    def __getitem__(self, name: str) -> QueryMode:
        try:
            return self._rows[name]
        except (KeyError, TypeError):
            raise ConfigError(f"unknown query mode {name!r}; known: {', '.join(self._rows)}"
                              ) from None

    def __contains__(self, name: object) -> bool:
        return name in self._rows

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(self._rows))

    def __len__(self) -> int:
        return len(self._rows)

    def __repr__(self) -> str:
        return f"QueryModes({tuple(self._rows)})"

    def register(self, row: QueryMode) -> None:
        """Add a mode (after the others). Raises ConfigError if its name or letter is taken."""
        with self._lock:
            if row.name in self._rows:
                raise ConfigError(f"query mode {row.name!r} is already registered")
            taken = {m.letter: m.name for m in self._rows.values()}
            if row.letter in taken:
                raise ConfigError(f"query mode {row.name!r}: letter {row.letter!r} is "
                                  f"{taken[row.letter]!r}'s")
            self._rows[row.name] = row

    def unregister(self, name: str) -> None:
        """Remove a mode registered at run time (the built-in ones stay)."""
        if name in _BUILTIN_NAMES:
            raise ConfigError(f"query mode {name!r} is built in and cannot be removed")
        with self._lock:
            self[name]  # noqa: B018 - raises ConfigError for an unknown name
            del self._rows[name]

    def field(self, attr: str) -> Mapping[str, str]:
        """A live name -> `attr` view (e.g. the titles), for code that reads a dict."""
        if attr not in QueryMode.__dataclass_fields__:
            raise ConfigError(f"query modes have no field {attr!r}")
        return _Field(self, attr)

    def needing_touch(self) -> tuple[str, ...]:
        """The modes that exist only with a tactile frame, in order."""
        return tuple(m for m, row in self._rows.items() if row.needs_touch)


class _Field(Mapping[str, str]):
    def __init__(self, modes: QueryModes, attr: str):
        self._modes, self._attr = modes, attr

    def __getitem__(self, name: str) -> str:
        return getattr(self._modes[name], self._attr)

    def __iter__(self) -> Iterator[str]:
        return iter(self._modes)

    def __len__(self) -> int:
        return len(self._modes)


def _image(V, T, joint_query):
    return V


def _tactile(V, T, joint_query):
    return T


def _joint(V, T, joint_query):
    return joint_query(V, T)


def _gated(V, T, joint_query):
    return joint_query(V, T, gated=True)


def _adapted(V, T, joint_query):
    return joint_query(V, T, adapted=True)


_BUILTIN = (
    QueryMode("image", "Image query", "I", "#1f77b4", frozenset({"image"}), _image,
              keys=("image", "text")),
    QueryMode("tactile", "Tactile query", "T", "#ff7f0e", frozenset({"tactile"}), _tactile,
              keys=("image", "text")),
    QueryMode("joint", "Joint query (Tactile-Guided Retriever)", "J", "#2ca02c",
              frozenset({"image", "tactile", "retriever"}), _joint),
    QueryMode("gated", "Trust-gated query", "G", "#d62728",
              frozenset({"image", "tactile", "retriever"}), _gated),
    # the tactile query brought back to its material for the presses people make (the
    # retrieval side's press map; the paper's tactile query above stays the embedding)
    QueryMode("adapted", "Tactile query, adapted to everyday presses", "A", "#9467bd",
              frozenset({"tactile", "retriever"}), _adapted, keys=("image", "text")),
)
_BUILTIN_NAMES = frozenset(m.name for m in _BUILTIN)

#: Every query mode, in the order galleries, columns and series show them.
QUERY_MODES = QueryModes(_BUILTIN)
#: The mode whose neighbours RA-Touch reads (its prompt, "take retrieval apart", the cascade):
#: the Tactile-Guided Retriever's, by definition of the method, wherever new rows go.
RA_TOUCH_MODE = "joint"
#: The retrieval systems RA-Touch can answer with, by the mode whose neighbours it reads:
#: "paper", the paper's joint query; "gated", the joint query moved towards the image query as
#: far as touch cannot be trusted (`ratouch.model.gate`); "text", the paper's joint query with
#: its neighbours' captions written into the prompt (plain retrieval-augmented generation,
#: `ratouch.model.neighbour_text`) instead of the Texture-Aware Integrator; "fallback", the
#: paper's system wherever the tactile frame looks like a rendered sensor's, and vision's
#: answer where it lies beyond every one (`WITHHOLDING_SYSTEMS`).
RETRIEVAL_SYSTEMS = {"paper": RA_TOUCH_MODE, "gated": "gated", "text": RA_TOUCH_MODE,
                     "fallback": RA_TOUCH_MODE}
#: The systems that withhold the touch of a frame beyond every validation render of the sensor
#: families: its answer reads the image query's neighbours with a neutral touch
#: (`ratouch.serve.pipeline.RATouchPipeline.withholds`, docs/premise.md).
WITHHOLDING_SYSTEMS = frozenset({"gated", "fallback"})
#: The mode every query has, whose neighbours stand in for a missing frame's modes.
IMAGE_MODE = "image"
assert {RA_TOUCH_MODE, IMAGE_MODE, *RETRIEVAL_SYSTEMS.values()} <= _BUILTIN_NAMES and not QUERY_MODES[IMAGE_MODE].needs_touch
assert WITHHOLDING_SYSTEMS <= set(RETRIEVAL_SYSTEMS)

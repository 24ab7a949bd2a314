"""What every tab of the page shares: `Page`, the read-only state loaded once for all
sessions, and `Outputs`, an event's output components matched by name.

A handler returns {name: value} for the outputs it changes (`QueryView.named`, a NamedTuple's
`_asdict()`); `Outputs.values` turns that into gradio's {component: value}. The names are the
page's own, built from the registries (a query mode's gallery is "gallery_<mode>"), so adding
a mode adds its components and its values together, and a value can never land in another
component because of its place in a list.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gradio as gr
import numpy as np

from ratouch.serve.request import MAX_K


class Outputs:
    """Output components by name, in the order gradio is given them.

    Args:
        components: name -> component.
    """

    def __init__(self, components: Mapping[str, Any]):
        self._by_name = dict(components)

    def __add__(self, other: Outputs) -> Outputs:
        both = set(self._by_name) & set(other._by_name)
        assert not both, f"outputs named twice: {sorted(both)}"
        return Outputs({**self._by_name, **other._by_name})

    def __getitem__(self, name: str) -> Any:
        return self._by_name[name]

    def __iter__(self):
        return iter(self._by_name)

    @property
    def components(self) -> list:
        """The components, for an event's `outputs=`."""
        return list(self._by_name.values())

    def only(self, names: Iterable[str]) -> Outputs:
        """The outputs named `names` (each must exist)."""
        return Outputs({n: self[n] for n in names})

    def values(self, named: Mapping[str, Any]) -> Any:
        """{component: value} for a handler's {name: value} (`gr.skip()` for {}); a name that
        is not an output of this event is a bug, raised here rather than shown in the wrong
        place."""
        unknown = [n for n in named if n not in self._by_name]
        if unknown:
            raise KeyError(f"not outputs of this event: {unknown}; its outputs: "
                           f"{list(self._by_name)}")
        if not named:  # nothing changes (gradio reads an empty dict as too few values)
            return gr.skip()
        return {self._by_name[n]: v for n, v in named.items()}


@dataclass
class Page:
    """The page's shared, read-only state (one per server, never per user).

    Attributes:
        pipeline: the serving `Answerer` that also names its loaded model (`model(name)`),
            or an `ratouch.serve.loader.BackgroundPipeline` still loading one.
        world: the `World` whose test split gives the examples.
        judge: the offline judge scoring labelled examples' descriptions (None: no scores).
        options: `ratouch.eval.failures.load_or_compute`'s world / k / conditions / indices.
        docs: the folder of the report, its figures and the stored checks.
        models: the models a query may choose (None: the pipeline's one model).
        max_batch: how many concurrent queries the pipeline answers together.
        model_state: name -> `ModelChoice.state(name)` (never waits); None: all ready.
        thumbnail: corpus id -> its thumbnail (cached).
        commit: the code's git commit, stamped on every export.
        failure_table: the failure table once loaded (shared by every session).
    """

    pipeline: Any
    world: Any
    judge: Any
    options: dict
    docs: Path
    models: list[str] | None
    max_batch: int
    model_state: Callable[[str], tuple] | None
    thumbnail: Callable[[int], np.ndarray]
    commit: str = "unknown"
    failure_table: dict = field(default_factory=dict)

    @property
    def choice(self) -> bool:
        """Whether a query names its model (the page offers a choice)."""
        return bool(self.models)

    def encoder(self, model: str | None) -> str | None:
        """The model a query names: the menu's choice, where there is one."""
        return (model or None) if self.choice else None

    def pending(self) -> bool:
        """Whether the models are still loading (or failed to): an
        `ratouch.serve.loader.BackgroundPipeline` says so; anything else is loaded."""
        ready = getattr(self.pipeline, "ready", None)
        return callable(ready) and not ready()

    def load_seconds(self) -> float | None:
        """How long the default model took to load (a `BackgroundPipeline`'s), else None."""
        return getattr(self.pipeline, "seconds", None)

    def corpus_size(self) -> int:
        """Entries of the corpus the loaded models search (MAX_K while they load)."""
        return MAX_K if self.pending() else len(self.pipeline.model().corpus.entries)

    def largest_k(self) -> int:
        return min(MAX_K, self.corpus_size())

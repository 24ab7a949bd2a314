"""What the experiments vary and what they return: a generator `Variant` (its retrieval and
integration), the shared `ExperimentConfig`, and one experiment's `Report`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ratouch.errors import ConfigError
from ratouch.search.modes import RA_TOUCH_MODE
from ratouch.search.retrieval import retrieval_settings

if TYPE_CHECKING:
    import plotly.graph_objects as go

SUBSET_NAMES = {"SSVTP": "structured", "HCT": "wild"}
CAPTION_TYPES = ("class_name", "visual_description", "tactile_caption")
#: Table 4's (query mode, key modality) settings: the built-in modes' `retrieval_settings`.
QUERY_KEY = tuple(retrieval_settings().values())
INTEGRATIONS = ("image", "text", "both")


@dataclass(frozen=True)
class Variant:
    """One generator variant: what it retrieves and how it integrates it.

    ``retrieval=False`` is the no-retrieval baseline (LoRA only); ``integration="sum"`` is Table
    2's "retriever without integrator" row (neighbours summed, one Linear to D').
    """

    retrieval: bool = True
    mode: str = RA_TOUCH_MODE      # query: a name of QUERY_MODES (default: the joint query)
    key: str = "text"              # key: image / text embeddings of the corpus
    caption: str = "tactile_caption"  # what the corpus text embeddings encode (Table 3)
    integration: str = "both"      # image / text / both (Table 5) / sum (Table 2)
    k: int = 5
    corpus_size: int = 0           # 0 = the whole corpus; else a stratified subset
    withheld: int = 0              # materials left out of the generator's paired training data

    def label(self) -> str:
        held = f", {self.withheld} materials withheld" if self.withheld else ""
        if not self.retrieval:
            return "baseline (no retrieval)" + held
        return (f"{self.mode}->{self.key}, {self.caption}, {self.integration}, K={self.k}"
                + (f", corpus {self.corpus_size}" if self.corpus_size else "") + held)


BASELINE = Variant(retrieval=False)
RA_TOUCH = Variant()


@dataclass(frozen=True)
class ExperimentConfig:
    """Settings shared by every experiment.

    Attributes:
        encoder: the default encoder whose retriever and generators are used.
        steps: stage-2 steps of every variant (the shipped generators had 800).
        batch: stage-2 batch size.
        seed: training seed.
        workers: variants trained in parallel processes (one thread each).
        corpus_sizes: Figure 3's stratified subset sizes of the corpus.
        ks: Figure 6's K values.
        stage1_steps: stage-1 steps of a generator retrained without withheld materials (the
            shipped stage 1 had 1500).
        withheld: Table 6's number of materials left out of the paired training data.
    """

    encoder: str = "default-s"
    steps: int = 300
    batch: int = 64
    seed: int = 0
    workers: int = 2
    corpus_sizes: tuple[int, ...] = (1000, 2500, 5000, 10000)
    ks: tuple[int, ...] = (1, 3, 5, 7, 10)
    stage1_steps: int = 1500
    withheld: int = 12

    def __post_init__(self) -> None:
        for name in ("steps", "batch", "workers"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 1")
        if not self.ks or min(self.ks) < 1:
            raise ConfigError(f"ks={self.ks} must be positive")
        if not self.corpus_sizes or min(self.corpus_sizes) < 1:
            raise ConfigError(f"corpus_sizes={self.corpus_sizes} must be positive")


@dataclass
class Report:
    """One experiment's output."""

    name: str
    title: str
    markdown: str
    figure: go.Figure | None = None
    data: dict = field(default_factory=dict)
    seconds: float = 0.0

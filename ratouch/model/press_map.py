"""The press map: the tactile query brought back to its material for the presses people make.

The encoders learnt touch from the world's training frames, a patch of material pressed
firmly into the gel. A press of an everyday thing (a flat face, a fabric, foam, tape, wire, an
edge, a small cap: `ratouch.world.presses`) is a different regime: its embedding still holds
the material (a linear probe names it at 2-3 times chance), but it lands in a region of the
space where the corpus's captions of that material are not, so the tactile query's top-5
captions are of the right material far less often (P@5 0.10 against 0.43 for the world's own
presses; docs/geometry.md).

The map is a small residual network on the (unit) tactile embedding, x + W2 gelu(W1 x + b1) +
b2, renormalised; it starts as the identity and is fitted (`ratouch train press-map`,
`ratouch.train.press_map`) with a softmax over the corpus materials' mean caption embeddings,
on renders of everyday presses and of the world's training presses, with a term that keeps
the world's presses where the shipped encoder puts them. It is read in numpy at query time,
by the query mode of its own (`adapted`, `ratouch.search.modes`); the paper's tactile query
stays the encoder's embedding.

The map also carries a router (`RegimeRouter`) that tells, from the embedding of a frame read
alone, whether it is an everyday press or a firm one of the world's regime: the touch-only
reading of a frame without a background follows it (`ratouch.serve.trace.touch_reading`).
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.special import erf

from ratouch.errors import DataError, DataNotFoundError
from ratouch.files import write_atomic

FORMAT = "ratouch-press-map-1"


def _gelu(x: np.ndarray) -> np.ndarray:
    return 0.5 * x * (1.0 + erf(x / np.sqrt(2.0)))


@dataclass(frozen=True)
class RegimeRouter:
    """Which regime a frame read alone is a press of, from its tactile embedding: a logistic
    model on the standardised embedding whose probability is that the press is an everyday
    one (a flat face, fabric, foam, tape, wire, an edge, a small cap), against a firm press of
    the world's regime or a rigid ball. Without a background there is no height map, so no
    shape to route by (`ratouch.model.geometry.RoutedFirmness`); this reads the embedding.

    Attributes:
        mean, scale: (D,) the embeddings' standardisation.
        coef: (D,) the logistic model's weights; bias: its intercept.
    """

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    bias: float

    def everyday(self, T: np.ndarray) -> np.ndarray:
        """(N,) probability that each (N, D) tactile embedding is of an everyday press."""
        x = (np.asarray(T, np.float64) - self.mean) / self.scale
        return 1.0 / (1.0 + np.exp(-np.clip(x @ self.coef + self.bias, -30, 30)))

    def read(self, T: np.ndarray) -> list[dict]:
        """Per embedding {"everyday": probability, "regime": "everyday" or "world" (at 0.5)}."""
        return [{"everyday": round(float(p), 3), "regime": "everyday" if p >= 0.5 else "world"}
                for p in self.everyday(T)]


@dataclass(frozen=True)
class PressMap:
    """The fitted map.

    Attributes:
        w1, b1: (D, H), (H,) the hidden layer.
        w2, b2: (H, D), (D,) the residual's output layer.
        meta: provenance and measured figures (the encoder set, how it was fitted, its P@5
            before and after on fresh renders).
        router: which regime a frame read alone is a press of (`RegimeRouter`), or None (a
            map fitted before it existed).
    """

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    meta: dict = field(default_factory=dict)
    router: RegimeRouter | None = None

    @property
    def dim(self) -> int:
        return int(self.w1.shape[0])

    def apply(self, T: np.ndarray) -> np.ndarray:
        """(N, D) tactile embeddings -> (N, D) unit query vectors, float32."""
        x = np.asarray(T, np.float32)
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise DataError(f"the press map reads (N, {self.dim}) tactile embeddings, "
                            f"got {x.shape}")
        z = x + _gelu(x @ self.w1 + self.b1) @ self.w2 + self.b2
        return (z / np.maximum(np.linalg.norm(z, axis=1, keepdims=True), 1e-12)).astype(
            np.float32)

    def save(self, path: str | os.PathLike) -> Path:
        buf = io.BytesIO()
        arrays: dict[str, np.ndarray] = {
            "w1": self.w1, "b1": self.b1, "w2": self.w2, "b2": self.b2,
            "meta": np.array(json.dumps({"format": FORMAT, **self.meta}))}
        if self.router is not None:
            arrays.update(router_mean=self.router.mean, router_scale=self.router.scale,
                          router_coef=self.router.coef, router_bias=np.array(self.router.bias))
        np.savez(buf, **arrays)  # type: ignore[arg-type]  # numpy's stub types allow_pickle
        return write_atomic(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | os.PathLike) -> PressMap:
        """Raises:
            DataNotFoundError: no file.
            DataError: not a press map.
        """
        path = Path(path)
        if not path.is_file():
            raise DataNotFoundError(f"no press map at {path} (`ratouch train press-map`)")
        try:
            with np.load(path, allow_pickle=False) as d:
                meta = json.loads(str(d["meta"]))
                if meta.get("format") != FORMAT:
                    raise ValueError(f"format {meta.get('format')!r}, expected {FORMAT!r}")
                w1, b1, w2, b2 = (np.asarray(d[k], np.float32) for k in ("w1", "b1", "w2", "b2"))
                router = None if "router_coef" not in d.files else RegimeRouter(
                    np.asarray(d["router_mean"], np.float64),
                    np.asarray(d["router_scale"], np.float64),
                    np.asarray(d["router_coef"], np.float64), float(d["router_bias"]))
            if router is not None and not (router.mean.shape == router.scale.shape
                                           == router.coef.shape == (w1.shape[0],)):
                raise ValueError(f"its router reads {router.coef.shape}, not ({w1.shape[0]},)")
            if w1.shape[0] != w2.shape[1] or w1.shape[1] != w2.shape[0]:
                raise ValueError(f"layer shapes {w1.shape} and {w2.shape} do not chain")
        except (ValueError, KeyError, OSError, TypeError) as e:
            raise DataError(f"{path} is not a press map: {e}") from e
        meta.pop("format", None)
        return cls(w1, b1, w2, b2, meta, router)

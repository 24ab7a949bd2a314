"""The photo route: how a visual crop that is not a render is turned into an image query.

The encoders' vision head was trained on the procedural world's renders. A real photo stands
far from every render in the frozen prior's feature space (the visual novelty), and there a
head trained on renders alone does not carry over. What does carry over is what the prior
learnt from ImageNet's real photos: its classifier. The corpus's object classes carry
ImageNet names (`ratouch.encoders.prior.imagenet_to_world`), so the classifier's probability
over them says which corpus entries the photo is of.

The photo's image neighbours are the corpus entries ranked by the classifier's probability of
their class (`PhotoRoute.neighbours`): every entry of the most probable class comes before any
entry of the next one, so the neighbours are of the photo's most probable class whenever the
corpus has it. A neighbour's score is that probability. Within a class, entries are ordered by
the cosine of their image embedding with the photo's query vector (then by lower id): the
query vector, not the render-trained head's embedding of the crop, because that head is what
does not carry over to photos. The query vector (`PhotoQuery.query`) is the
probability-weighted mixture of the classes' prototypes (the mean image embedding of each
class's corpus entries); it stands for the photo where the pipeline needs a (D,) vector: the
Tactile-Guided Retriever's joint query, the trust signals and the PCA plot. It is no longer
what the image neighbours are searched with: a mixture of several classes' prototypes can lie
nearest to an unrelated class.

When the corpus's classes hold little of the classifier's probability (the photo shows
something the corpus does not have), the neighbours are still ranked, and the note says so.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from ratouch.encoders.prior import VisualPrior, world_class_probabilities
from ratouch.search.index import top_k
from ratouch.world.objects import OBJECT_CLASSES

#: Below this share of the classifier's probability on the corpus's classes, the note says
#: that the photo's object is probably not in the corpus.
LOW_COVERAGE = 0.2
#: Classes named in the note.
TOP_CLASSES = 3


@dataclass(frozen=True)
class PhotoQuery:
    """The photo route's image query for one crop and what it rests on.

    Attributes:
        query: (D,) unit vector: the mixture of class prototypes (for the joint query, the
            trust signals and the PCA plot; the neighbours come from `PhotoRoute.neighbours`).
        probabilities: (C,) the classifier's probability of each world class (summed over
            the ImageNet classes mapped to it), zero for classes the corpus does not have.
        classes: the top corpus classes with their probability, most probable first.
        coverage: the share of the classifier's probability on the corpus's classes.
        note: a plain sentence for the user.
    """

    query: np.ndarray
    probabilities: np.ndarray
    classes: list[tuple[str, float]]
    coverage: float
    note: str

    def route(self) -> dict:
        """The result's `visual_route` for a crop this route answered."""
        return {"route": "photo", "classes": self.classes, "coverage": self.coverage,
                "note": self.note}


class PhotoRoute:
    """Class prototypes of a corpus and the prior's classifier, to answer photos.

    Args:
        prior: the encoders' frozen visual prior.
        class_names: the corpus entries' class names, in corpus order.
        image_embeddings: (N, D) the corpus's image embeddings (unit rows).
    """

    def __init__(self, prior: VisualPrior, class_names: list[str], image_embeddings: np.ndarray):
        self.prior = prior
        self._names = class_names
        self._emb = image_embeddings
        self._ids: np.ndarray | None = None
        self._protos: np.ndarray | None = None
        self._present: np.ndarray | None = None
        self._lock = threading.Lock()

    def _prototypes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(C, D) mean image embedding per world class (zero where the corpus has none), which
        classes the corpus has, and (N,) each entry's world class row (-1: none); computed
        once, on first use."""
        with self._lock:
            if self._protos is None:
                row = {c.name: i for i, c in enumerate(OBJECT_CLASSES)}
                ids = np.array([row.get(n, -1) for n in self._names], np.int64)
                protos = np.zeros((len(OBJECT_CLASSES), self._emb.shape[1]), np.float64)
                counts = np.bincount(ids[ids >= 0], minlength=len(OBJECT_CLASSES))
                np.add.at(protos, ids[ids >= 0], np.asarray(self._emb, np.float64)[ids >= 0])
                present = counts > 0
                protos[present] /= np.linalg.norm(protos[present], axis=1, keepdims=True)
                self._ids, self._protos, self._present = ids, protos.astype(np.float32), present
        assert self._ids is not None and self._protos is not None and self._present is not None
        return self._protos, self._present, self._ids

    def warm(self) -> None:
        """Build once, before a user's first photo, what that photo would otherwise pay for
        inside its query: the class prototypes and the classifier's first pass at its input
        size (for Lite0 the 224 px extractor is traced then: 1.2 s against 0.1 s for the
        next photo, measured on one thread)."""
        self._prototypes()
        self.prior.classify([np.zeros((32, 32, 3), np.uint8)])

    def query(self, crop: np.ndarray) -> PhotoQuery:
        """The image query of one uint8 (H, W, 3) crop.

        The classifier reads the crop at the prior's own input size (224 px for Lite0), the
        size it learnt ImageNet at, not at the encoders' `prior_size`: that smaller size was
        chosen for renders (`ratouch bench towers`) and costs a classifier of real photos
        accuracy. Only crops that take this route pay for the second pass."""
        protos, present, _ = self._prototypes()
        probs = self.prior.classify([crop])
        world = world_class_probabilities(probs)[0] * present        # (C,)
        coverage = float(world.sum())
        weights = world / coverage if coverage > 0 else present / present.sum()
        q = weights @ protos
        q = (q / (np.linalg.norm(q) + 1e-12)).astype(np.float32)
        top = top_k(world[None], TOP_CLASSES)[1][0]
        classes = [(OBJECT_CLASSES[i].name, round(float(world[i]), 4)) for i in top
                   if world[i] > 0]
        named = ", ".join(f"{n} {p:.2f}" for n, p in classes) or "none"
        note = ("the visual crop looks like a real photo, not a render: its image neighbours "
                "are the corpus entries of the classes that the visual prior's ImageNet "
                f"classifier finds most probable ({named}), scored by that probability, not "
                "found by the render-trained head")
        if coverage < LOW_COVERAGE:
            note += (f"; the corpus's classes hold only {coverage:.0%} of the classifier's "
                     "probability, so the neighbours are of the most probable class the "
                     "corpus has, not necessarily the photo's own")
        return PhotoQuery(q, world.astype(np.float32), classes, round(coverage, 4), note)

    def neighbours(self, photo: PhotoQuery, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The photo's top-k corpus entries: ((k,) scores, (k,) int64 ids), best first.

        Entries are ranked by the classifier's probability of their class (the score), then
        by the cosine of their image embedding with `photo.query`, then by lower id."""
        _, _, ids = self._prototypes()
        score = np.where(ids >= 0, photo.probabilities[np.maximum(ids, 0)], 0.0)   # (N,)
        sim = np.asarray(self._emb, np.float32) @ photo.query                      # (N,)
        order = np.lexsort((np.arange(len(ids)), -sim, -score))[:max(int(k), 0)]
        return score[order].astype(np.float32), order.astype(np.int64)


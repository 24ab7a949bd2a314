"""Serving many users from one `RATouchPipeline`: batched queries.

On a CPU, one query's cost is mostly the two generators' greedy decoding, whose per-step
overhead hardly grows with the batch; concurrent queries answered one by one queue behind
each other. `query_many` answers several queries with batched encoders, one index search and
batched generation; `QueryBatcher` gathers concurrent `query` calls from server threads into
such batches, so that latency under load stays close to a single user's.

`query_many([request])[0]` equals `RATouchPipeline.query(**request)` (timings aside); the
test suite checks it, so that both follow the same protocol.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Mapping, Sequence

import numpy as np

from ratouch.errors import ConfigError, RATouchError

log = logging.getLogger(__name__)

MODES = ("image", "tactile", "joint")


def _prepare(pipeline, req: Mapping[str, Any]) -> dict:
    """Check and decode one request (what `query` does before any model runs)."""
    from ratouch.encoders.preprocess import crop_box, to_rgb_array, tvl_contact_box

    k = req.get("k", 5)
    n = len(pipeline.corpus.entries)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n:
        raise ConfigError(f"k must be an integer in 1..{n}, got {k!r}")
    image = to_rgb_array(req["visual"], name="visual image")
    warnings: list[str] = []
    box = req.get("box")
    if box is None:
        box = tvl_contact_box(image.shape[1], image.shape[0])
        warnings.append(f"no contact box given: used TVL's centred crop {list(box)}")
    crop = crop_box(image, box)
    tactile = req.get("tactile")
    frame = to_rgb_array(tactile, name="tactile image") if tactile is not None else None
    if frame is None:
        warnings.append("no tactile image: image-only retrieval; the tactile and joint "
                        "queries and the RA-Touch description are not available")
    return {"crop": crop, "frame": frame, "box": box, "k": int(k), "label": req.get("label"),
            "warnings": warnings}


def query_many(pipeline, requests: Sequence[Mapping[str, Any]]) -> list[dict | Exception]:
    """Several `RATouchPipeline.query` calls at once (`query` is this with one request).

    Args:
        pipeline: a loaded `RATouchPipeline`.
        requests: `query`'s arguments by name (visual required; tactile, box, k, label).

    Returns:
        Per request, in order: `query`'s result, or the exception `query` would have raised
        for an unusable image, box or k (the other requests are answered all the same).
        `timings_ms` are the batch's stages, shared by its requests, plus "batch_size".
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}

    def lap(stage: str, t0: float) -> float:
        now = time.perf_counter()
        timings[stage] = round((now - t0) * 1000, 2)
        return now

    t = time.perf_counter()
    out: list[Any] = [None] * len(requests)
    items: list[dict] = []
    for pos, req in enumerate(requests):
        try:
            items.append({"pos": pos, **_prepare(pipeline, req)})
        except (RATouchError, OSError) as e:
            out[pos] = e
    if not items:
        return out
    t = lap("preprocess", t)
    V = pipeline.encoders.encode_image([it["crop"] for it in items])
    t = lap("encode_image", t)
    queries: list[dict[str, np.ndarray]] = [{"image": V[j:j + 1]} for j in range(len(items))]
    touch = [j for j, it in enumerate(items) if it["frame"] is not None]
    if touch:
        T = pipeline.encoders.encode_tactile([items[j]["frame"] for j in touch])
        t = lap("encode_tactile", t)
        J = pipeline.joint_query(V[touch], T)
        for r, j in enumerate(touch):
            queries[j]["tactile"], queries[j]["joint"] = T[r:r + 1], J[r:r + 1]
        t = lap("retriever", t)
    # every mode of every request searches the text index: one search at the largest K
    rows = [(j, m) for j, q in enumerate(queries) for m in MODES if m in q]
    scores, ids = pipeline.corpus.search(
        "text", np.concatenate([queries[j][m] for j, m in rows]), max(it["k"] for it in items))
    results: list[dict] = [{} for _ in items]
    for r, (j, m) in enumerate(rows):
        k = items[j]["k"]
        results[j][m] = (scores[r:r + 1, :k], ids[r:r + 1, :k])
    t = lap("search", t)
    ra: dict[int, str] = {}
    base: dict[int, str] = {}
    if touch:
        by_k: dict[int, list[int]] = {}
        for j in touch:  # RA-Touch reads K neighbours: one generator batch per K
            by_k.setdefault(items[j]["k"], []).append(j)
        for group in by_k.values():
            Tg = np.concatenate([queries[j]["tactile"] for j in group])
            nb = np.concatenate([results[j]["joint"][1] for j in group])
            ra.update(zip(group, pipeline.describe(V[group], Tg, nb)))
        t = lap("generate_ra", t)
        base.update(zip(touch, pipeline.describe(V[touch], T, None)))
        t = lap("generate_baseline", t)
    points = [pipeline._pca_points(queries[j], results[j], None) for j in range(len(items))]
    labelled = [j for j, it in enumerate(items) if it["label"]]
    if labelled:  # the ground-truth captions' embeddings in one encoder call
        xy = pipeline.pca.project(pipeline.encoders.encode_text(
            [items[j]["label"] for j in labelled]))
        for j, (x, y) in zip(labelled, xy):
            points[j].append({"role": "ground_truth", "x": float(x), "y": float(y)})
    t = lap("pca", t)
    timings["total"] = round((time.perf_counter() - t_start) * 1000, 2)
    timings["batch_size"] = len(items)
    explained = list(pipeline.pca.explained)
    for j, it in enumerate(items):
        out[it["pos"]] = {
            "neighbours": {mode: [pipeline._neighbour(i, s) for s, i in zip(sc[0], ii[0])]
                           for mode, (sc, ii) in results[j].items()},
            "description": {"ra_touch": ra.get(j, ""), "baseline": base.get(j, "")},
            "pca": {"points": points[j], "explained": explained},
            "timings_ms": dict(timings), "warnings": it["warnings"],
            "box": [int(v) for v in it["box"]]}
    return out


class _Pending:
    __slots__ = ("request", "result", "done")

    def __init__(self, request: dict):
        self.request = request
        self.result: Any = None
        self.done = threading.Event()


class QueryBatcher:
    """`query` like the pipeline's, but concurrent calls are answered together.

    A worker thread takes what is waiting (up to `max_batch` requests, after waiting at most
    `max_wait_s` for more to arrive once the first has) and runs `query_many` on it; each
    caller gets its own result or exception. One batch runs at a time, so the model work of
    a server is bounded however many threads call `query`.

    Args:
        pipeline: the loaded pipeline (or anything whose attribute access yields one, like
            the app's `BackgroundPipeline`).
        max_batch: most requests in one batch.
        max_wait_s: how long a batch waits for company; 0 answers what is there at once
            (requests that arrive while a batch runs form the next one anyway).
    """

    def __init__(self, pipeline, max_batch: int = 16, max_wait_s: float = 0.0):
        if max_batch < 1:
            raise ConfigError(f"max_batch must be >= 1, got {max_batch}")
        self.pipeline = pipeline
        self.max_batch = max_batch
        self.max_wait_s = max_wait_s
        self.batches: list[int] = []  # sizes of the recent batches (the last 1000)
        self._queue: list[_Pending] = []
        self._cv = threading.Condition()
        self._worker: threading.Thread | None = None

    def query(self, visual: Any, tactile: Any = None, box=None, k: int = 5,
              label: str | None = None) -> dict:
        """`RATouchPipeline.query`, answered in a batch with concurrent calls."""
        item = _Pending({"visual": visual, "tactile": tactile, "box": box, "k": k,
                         "label": label})
        with self._cv:
            self._queue.append(item)
            if self._worker is None or not self._worker.is_alive():
                self._worker = threading.Thread(target=self._run, daemon=True,
                                                name="query-batcher")
                self._worker.start()
            self._cv.notify()
        item.done.wait()
        if isinstance(item.result, BaseException):
            raise item.result
        return item.result

    def _take(self) -> list[_Pending]:
        with self._cv:
            while not self._queue:
                self._cv.wait()
            if self.max_wait_s > 0 and len(self._queue) < self.max_batch:
                end = time.monotonic() + self.max_wait_s
                while len(self._queue) < self.max_batch and (left := end - time.monotonic()) > 0:
                    self._cv.wait(left)
            batch, self._queue = self._queue[:self.max_batch], self._queue[self.max_batch:]
            return batch

    def _run(self) -> None:
        while True:
            batch = self._take()
            try:
                results = query_many(self.pipeline, [p.request for p in batch])
            except BaseException as e:  # noqa: BLE001 - every caller of the batch gets it
                log.error("a query batch of %d failed", len(batch), exc_info=e)
                results = [e] * len(batch)
            self.batches = (self.batches + [len(batch)])[-1000:]
            for p, r in zip(batch, results):
                p.result = r
                p.done.set()

    def __getattr__(self, name: str) -> Any:
        """Everything but `query` is the pipeline's (corpus, encoders, ...)."""
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.pipeline, name)

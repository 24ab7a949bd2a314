"""Which vision tower (`ratouch bench towers`): speed against accuracy of the render-trained CNN
and every frozen ImageNet prior of the registry (`ratouch.encoders.prior_registry.PRIORS`) at
several input sizes.

Everything is measured on **validation renders only**: the world's train split from index
``VALIDATION_START + 200_000`` on (no training run reads these indices; same distribution as
the training renders), never the test split. Per tower and input size:

* **material probe accuracy**: a logistic regression on standardised features of N renders'
  contact crops, 2-fold (shuffled, seeded) over the renders, mean of the folds, with its
  binomial standard error over the N renders (``probe_se``: about 0.02-0.03 at N = 300, so
  at that N the rule's 0.02 tolerance is within the noise; N = 600 or more narrows it);
* **image->image material precision@5**: each crop's 5 nearest entries (cosine similarity of
  the raw features) in a class-stratified sample of the corpus (whole corpus images, as the
  served image query searches them); the share with the crop's material;
* **speed**: the p50 / p95 latency of one crop at a time (uint8 crop -> features, resizing
  included; warm; ``threads`` intra-op threads, 2 by default), the p50 again on one thread,
  and the throughput of a batch (``threads`` threads).

The towers' features are what the served vision path reads: the CNN's are its mean/std pooled
conv features (the input of its ``vision.head``), the priors' their pooled pre-classifier
features. Both are features, not trained embeddings, so the probe compares what each tower
sees, not how a head was trained on top of it.

The rule that picks the tower is stated in the result (:data:`RULE`): the fastest tower/size
(single-crop p50) whose probe accuracy is within :data:`TOLERANCE` of the best one's.

Latencies are wall-clock on a shared machine: the load average at the start and end of the
run is part of the result. Under load, two intra-op threads on two busy cores wait at each
op's barrier for a descheduled thread (`ratouch.threads`): the 2-thread p50 then grows several
times over, most at the larger sizes, while the 1-thread p50 stays near the compute time. The
choice follows the configured ``threads`` (the rule's latency); ``p50_ms_1_thread`` is there
to read the ranking against.
"""

from __future__ import annotations

import logging
import os
import platform
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import torch

from ratouch.checkpoint import load_into, read_checkpoint
from ratouch.corpus.imagenet_t import stratified_world_ids
from ratouch.encoders.default import vision_tensor
from ratouch.encoders.factory import create_model, shipped_weights
from ratouch.encoders.prior import load_prior
from ratouch.encoders.prior_registry import PRIORS, prior_spec
from ratouch.errors import ConfigError, DataError, RATouchError, ServiceError
from ratouch.eval.report import png_bytes, write_figure_html
from ratouch.eval.retrieval import material_precision
from ratouch.files import write_atomic, write_json_atomic
from ratouch.paths import DOCS
from ratouch.search.index import top_k
from ratouch.threads import intra_op_threads
from ratouch.train.trust import VALIDATION_START
from ratouch.world.sampler import World

log = logging.getLogger(__name__)

#: The render-trained CNN's name among the towers; the others are the registry's priors.
CNN = "cnn"
#: One colour per tower in the chart, in the towers' order.
_PALETTE = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf")


def tower_names() -> tuple[str, ...]:
    """The towers `bench_towers` knows: the CNN, then every registered prior."""
    return (CNN, *PRIORS)
#: How far below the best probe accuracy the chosen tower may be.
TOLERANCE = 0.02
RULE = (f"the fastest tower/size (single-crop p50 latency) whose probe accuracy is within "
        f"{TOLERANCE} of the best")
#: Offset of the renders from `ratouch.train.trust.VALIDATION_START` (unseen by training).
RENDER_OFFSET = 200_000
#: Where `write_towers` puts its files by default.
FIGURE_NAME = "towers"


def _validation_start() -> int:
    return VALIDATION_START + RENDER_OFFSET


# --------------------------------------------------------------------------------- data

def render_set(n: int, start: int | None = None, world=None) -> tuple[list[np.ndarray], list[str],
                                                                        list[str]]:
    """Contact crops, materials and class names of train-split renders start .. start+n-1."""
    world = world or World()
    start = _validation_start() if start is None else start
    crops, mats, classes = [], [], []
    for i in range(start, start + n):
        s = world.sample("train", i)
        crops.append(np.ascontiguousarray(s.crop))
        mats.append(s.material)
        classes.append(s.class_name)
    return crops, mats, classes


def gallery_set(size: int, seed: int, world=None) -> tuple[list[np.ndarray], list[str]]:
    """Images and materials of a class-stratified sample of the world's corpus."""
    world = world or World()
    ids = stratified_world_ids(size, seed)
    return ([world.corpus_image(c, i) for c, i in ids],
            [world.corpus_record(c, i).material for c, i in ids])


# --------------------------------------------------------------------------------- towers

class _Tower:
    """uint8 crops -> (N, dim) float32 features, one way."""

    name: str
    size: int
    label: str

    def features(self, images: Sequence[np.ndarray]) -> np.ndarray:
        raise NotImplementedError


class PriorTower(_Tower):
    def __init__(self, name: str, size: int):
        self.name, self.size = name, int(size)
        self.prior = load_prior(name)
        self.prior.extractor(self.size)  # trace now, not inside a timing
        self.label = f"{name}@{self.size}"

    def features(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self.prior.features(list(images), self.size)


class CNNTower(_Tower):
    """The render-trained vision CNN of an encoder set: conv stages, then mean/std pooling.

    With `partial` (the default), a checkpoint that `create_model` refuses (one saved before
    the encoder set gained its prior head) still gives its CNN: the checkpoint's ``vision.*``
    tensors are loaded strictly into the CNN alone, when its width and vision size are the
    config's; the point's label and ``weights`` say so.
    """

    def __init__(self, encoder: str, weights: str | None = "shipped", partial: bool = True):
        self.note: str | None = None  # why only the checkpoint's CNN was loaded
        try:
            model = create_model(encoder, pretrained=weights)
        except DataError as e:
            if not partial or weights is None or "does not fit the model" not in str(e):
                raise
            model = self._vision_only(encoder, weights, e)
        if getattr(model, "backend", None) != "default" or not hasattr(model, "vision"):
            raise ConfigError(f"encoder {encoder!r} has no render-trained CNN (backend "
                              f"{getattr(model, 'backend', '?')!r})")
        self.model = model.eval()
        self.encoder = encoder
        self.random = weights is None
        h, w = model.cfg.vision_size
        self.name, self.size, self.hw = CNN, int(h), (h, w)
        self.label = f"cnn@{h}" + (" (random weights)" if self.random else
                                   " (vision.* only)" if self.note else "")

    def _vision_only(self, encoder: str, weights: str, error: Exception):
        folder = shipped_weights(encoder) if weights == "shipped" else Path(weights)
        state, saved, _ = read_checkpoint(folder)
        model = create_model(encoder, pretrained=None)
        cfg = model.cfg
        if (saved.get("name") != encoder or saved.get("width") != cfg.width
                or tuple(saved.get("vision_size", ())) != tuple(cfg.vision_size)):
            raise error
        load_into(model.vision, {k[len("vision."):]: v for k, v in state.items()
                                 if k.startswith("vision.")}, f"{folder} (vision.*)")
        self.note = (f"create_model({encoder!r}) refused {folder} ({error}); its vision.* "
                     f"tensors (width {cfg.width}, vision size {list(cfg.vision_size)}) were "
                     f"loaded into the CNN alone")
        return model

    def features(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        with torch.inference_mode():
            for lo in range(0, len(images), 256):
                f = self.model.vision.features(vision_tensor(list(images[lo:lo + 256]), self.hw))
                out.append(torch.cat([f.mean((2, 3)), f.flatten(2).std(2)], 1).numpy())
        return np.concatenate(out).astype(np.float32)


# --------------------------------------------------------------------------------- measures

def probe_accuracy(feats: np.ndarray, labels: Sequence[str], folds: int = 2, seed: int = 0
                   ) -> tuple[float, list[float]]:
    """Mean (and per-fold) accuracy of a logistic regression on standardised features,
    `folds`-fold over the rows (shuffled with `seed`)."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import KFold
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    y = np.asarray(labels)
    accs = []
    for train, test in KFold(folds, shuffle=True, random_state=seed).split(feats):
        clf = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            clf.fit(feats[train], y[train])
        accs.append(float((clf.predict(feats[test]) == y[test]).mean()))
    return float(np.mean(accs)), [round(a, 4) for a in accs]


def precision_at_k(query: np.ndarray, query_labels: Sequence[str], gallery: np.ndarray,
                   gallery_labels: Sequence[str], k: int = 5) -> float:
    """Mean share of each query's k nearest gallery rows (cosine) that share its label."""
    q = query / (np.linalg.norm(query, axis=1, keepdims=True) + 1e-12)
    g = gallery / (np.linalg.norm(gallery, axis=1, keepdims=True) + 1e-12)
    return float(material_precision(top_k(q @ g.T, k)[1], query_labels,
                                    np.asarray(gallery_labels)).mean())


def single_latency(tower: _Tower, crops: Sequence[np.ndarray], reps: int = 30, warm: int = 5
                   ) -> tuple[float, float]:
    """p50 and p95 (ms) of one crop at a time, cycling through `crops`, after `warm` calls."""
    for j in range(warm):
        tower.features([crops[j % len(crops)]])
    times = []
    for j in range(reps):
        t0 = time.perf_counter()
        tower.features([crops[j % len(crops)]])
        times.append(time.perf_counter() - t0)
    ms = np.asarray(times) * 1000
    return round(float(np.percentile(ms, 50)), 3), round(float(np.percentile(ms, 95)), 3)


def batch_throughput(tower: _Tower, crops: Sequence[np.ndarray], batch: int = 64,
                     reps: int = 3) -> float:
    """Crops per second through `features` on one batch (the best of `reps` runs)."""
    chunk = [crops[j % len(crops)] for j in range(batch)]
    tower.features(chunk[:2])
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        tower.features(chunk)
        best = min(best, time.perf_counter() - t0)
    return round(batch / best, 1)


def choose(points: Sequence[dict], tolerance: float = TOLERANCE) -> dict | None:
    """The fastest point (single-crop p50) whose probe accuracy is within `tolerance` of the
    best; ties on latency go to the more accurate one."""
    if not points:
        return None
    best = max(p["probe_accuracy"] for p in points)
    ok = [p for p in points if p["probe_accuracy"] >= best - tolerance - 1e-12]
    return min(ok, key=lambda p: (p["p50_ms"], -p["probe_accuracy"]))


# --------------------------------------------------------------------------------- the bench

def _sizes_for(tower: str, sizes: Sequence[int] | None) -> tuple[int, ...]:
    if sizes is None:
        return prior_spec(tower).sizes
    return tuple(int(s) for s in sizes)


def bench_towers(n: int = 600, sizes: Sequence[int] | None = None,
                 towers: Sequence[str] | None = None, seed: int = 0, encoder: str = "default-s",
                 gallery: int = 840, cnn_weights: str | None = "shipped",
                 cnn_partial: bool = True, threads: int = 2,
                 latency_reps: int = 30, batch: int = 64,
                 progress: Callable[[str], None] | None = None) -> dict:
    """Measure every tower/size on validation renders; returns the result dict.

    Args:
        n: renders (train split from ``VALIDATION_START + 200_000``) for the probe and as
            retrieval queries.
        sizes: input sizes for the prior towers; None: each row's `PriorSpec.sizes` (the usual
            ones below its own input size, and its own).
        towers: any of `tower_names()` (None: all).
        seed: the probe folds' shuffle and the gallery sample.
        encoder: whose render-trained CNN is the ``cnn`` tower.
        gallery: corpus entries (class-stratified) searched by the precision@5.
        cnn_weights: ``create_model``'s `pretrained` for the CNN: "shipped", a checkpoint
            folder, or None (random weights: only for tests, and labelled so).
        cnn_partial: where ``create_model`` refuses the checkpoint only for keys the CNN does
            not hold (saved before the prior head), load its ``vision.*`` alone (labelled
            "vision.* only", with a ``weights_note``); False: skip the CNN instead.
        threads: intra-op threads for everything (the latency's too).
        latency_reps: timed single-crop calls per point (after 5 warm ones).
        batch: crops per batch of the throughput.
        progress: called with one line per measured point.

    Returns:
        {"points": [{"tower", "size", "label", "dim", "probe_accuracy", "probe_se" (its
        binomial standard error over the n renders), "probe_folds",
        "precision_at_5", "p50_ms", "p95_ms", "p50_ms_1_thread", "throughput_per_s",
        "features_s"}],
        "skipped": [{"tower", "reason"}], "rule", "tolerance", "best", "choice" (a point's
        label, tower and size, or None), "chance" (the majority material's share),
        "settings": {...}}.
    """
    say = progress or (lambda line: None)
    towers = tower_names() if towers is None else towers
    unknown = [t for t in towers if t not in tower_names()]
    if unknown:
        raise ConfigError(f"unknown tower(s) {unknown}; choose from {list(tower_names())}")
    if n < 4:
        raise ConfigError(f"n={n}: the 2-fold probe needs at least 4 renders")
    if sizes is not None and any(not 32 <= int(s) <= 1024 for s in sizes):
        raise ConfigError(f"sizes={list(sizes)}: each must lie in [32, 1024]")

    load_before = [round(x, 2) for x in os.getloadavg()]
    t_start = time.perf_counter()
    world = World().warm()
    start = _validation_start()
    crops, mats, _classes = render_set(n, start, world)
    g_images, g_mats = gallery_set(gallery, seed, world)
    say(f"rendered {n} validation crops and {gallery} gallery images")
    values, counts = np.unique(mats, return_counts=True)
    points: list[dict] = []
    skipped: list[dict[str, str]] = []
    with intra_op_threads(threads):
        for name in towers:
            for tower in _towers(name, sizes, encoder, cnn_weights, cnn_partial, skipped, say):
                t0 = time.perf_counter()
                feats = tower.features(crops)
                g_feats = tower.features(g_images)
                features_s = time.perf_counter() - t0
                acc, folds = probe_accuracy(feats, mats, 2, seed)
                p50, p95 = single_latency(tower, crops, latency_reps)
                with intra_op_threads(1):
                    p50_1, _ = single_latency(tower, crops, latency_reps)
                point = {
                    "tower": tower.name, "size": tower.size, "label": tower.label,
                    "dim": int(feats.shape[1]), "probe_accuracy": round(acc, 4),
                    "probe_se": round(float(np.sqrt(acc * (1 - acc) / n)), 4),
                    "probe_folds": folds,
                    "precision_at_5": round(precision_at_k(feats, mats, g_feats, g_mats, 5), 4),
                    "p50_ms": p50, "p95_ms": p95, "p50_ms_1_thread": p50_1,
                    "throughput_per_s": batch_throughput(tower, crops, batch),
                    "features_s": round(features_s, 2)}
                if isinstance(tower, CNNTower):
                    point["encoder"] = tower.encoder
                    point["random_weights"] = tower.random
                    if tower.note:
                        point["weights_note"] = tower.note
                points.append(point)
                say(f"{tower.label:>24}: probe {acc:.3f}  P@5 {point['precision_at_5']:.3f}  "
                    f"p50 {p50:.2f} ms  {point['throughput_per_s']:.0f}/s")
    chosen = choose(points)
    best = max(points, key=lambda p: p["probe_accuracy"]) if points else None
    return {
        "points": points, "skipped": skipped, "rule": RULE, "tolerance": TOLERANCE,
        "best": None if best is None else {k: best[k] for k in ("label", "tower", "size",
                                                                "probe_accuracy", "p50_ms")},
        "choice": None if chosen is None else {k: chosen[k] for k in (
            "label", "tower", "size", "probe_accuracy", "precision_at_5", "p50_ms")},
        "chance": round(float(counts.max() / counts.sum()), 4),
        "settings": {
            "n": n, "renders": f"train[{start}:{start + n}] (validation: unseen by training; "
                               "never the test split)",
            "materials": int(len(values)), "gallery": gallery,
            "gallery_source": f"stratified_world_ids({gallery}, seed={seed}): whole corpus "
                              "images", "seed": seed, "encoder": encoder,
            "cnn_weights": cnn_weights, "cnn_partial": cnn_partial,
            "probe": "LogisticRegression on StandardScaler features, 2-fold shuffled, mean "
                     "accuracy",
            "precision": "image->image material precision@5, cosine on raw features",
            "threads": threads, "latency_reps": latency_reps, "batch": batch,
            "latency": "one crop per call, uint8 crop -> features (resize included), warm",
            "cpu_count": os.cpu_count(), "machine": platform.processor() or platform.machine(),
            "torch": torch.__version__, "load_average_before": load_before,
            "load_average_after": [round(x, 2) for x in os.getloadavg()],
            "seconds": round(time.perf_counter() - t_start, 1)}}


def _towers(name: str, sizes, encoder: str, cnn_weights, cnn_partial: bool,
            skipped: list[dict[str, str]], say) -> Iterator[_Tower]:
    """The towers to measure for `name`, one at a time; failures to load become `skipped`."""
    if name == CNN:
        try:
            cnn = CNNTower(encoder, cnn_weights, cnn_partial)
        except (RATouchError, OSError, ImportError) as e:
            reason = (f"encoder {encoder!r} with weights {cnn_weights!r} did not load: "
                      f"{type(e).__name__}: {e}")
            skipped.append({"tower": CNN, "reason": reason})
            say(f"skipped cnn: {reason}")
            return
        if cnn.note:
            say(f"cnn: {cnn.note}")
        yield cnn
        return
    for size in _sizes_for(name, sizes):
        try:
            tower = PriorTower(name, size)
        except (RATouchError, OSError, ImportError) as e:
            reason = f"visual prior {name!r} did not load: {type(e).__name__}: {e}"
            skipped.append({"tower": name, "reason": reason})
            say(f"skipped {name}: {reason}")
            return
        yield tower


# --------------------------------------------------------------------------------- output

def format_towers(result: dict) -> str:
    """A plain-text table of the points, the rule and the choice."""
    t = result["settings"]["threads"]
    w = max([24, *(len(p["label"]) for p in result["points"])])
    lines = [f"{'tower':>{w}} {'dim':>5} {'probe':>6} {'±se':>6} {'P@5':>6} "
             f"{f'p50 ms {t}t':>10} {f'p95 ms {t}t':>10} {'p50 ms 1t':>10} {'crops/s':>8}"]
    for p in result["points"]:
        lines.append(f"{p['label']:>{w}} {p['dim']:>5} {p['probe_accuracy']:>6.3f} "
                     f"{p.get('probe_se', float('nan')):>6.3f} {p['precision_at_5']:>6.3f} "
                     f"{p['p50_ms']:>10.2f} {p['p95_ms']:>10.2f} "
                     f"{p['p50_ms_1_thread']:>10.2f} {p['throughput_per_s']:>8.0f}")
    for s in result["skipped"]:
        lines.append(f"skipped {s['tower']}: {s['reason']}")
    lines.append(f"chance (majority material): {result['chance']:.3f}")
    lines.append(f"rule: {result['rule']}")
    c = result["choice"]
    lines.append("chosen: " + ("none (nothing measured)" if c is None else
                               f"{c['label']} (probe {c['probe_accuracy']:.3f}, "
                               f"p50 {c['p50_ms']:.2f} ms)"))
    return "\n".join(lines)


def tower_figure(result: dict):
    """The chart: single-crop p50 (log x) against probe accuracy, one labelled point per
    tower/size, the tolerance band under the best, the chosen point starred."""
    import plotly.graph_objects as go

    fig = go.Figure()
    colours = dict(zip(tower_names(), _PALETTE * 2))
    pts = result["points"]
    for tower in tower_names():
        sel = [p for p in pts if p["tower"] == tower]
        if sel:
            fig.add_scatter(
                x=[p["p50_ms"] for p in sel], y=[p["probe_accuracy"] for p in sel],
                mode="markers+text", name=tower, text=[p["label"] for p in sel],
                textposition="top center", marker={"size": 10, "color": colours[tower]},
                hovertext=[f"{p['label']}: P@5 {p['precision_at_5']:.3f}, "
                           f"1-thread p50 {p['p50_ms_1_thread']:.1f} ms, "
                           f"{p['throughput_per_s']:.0f} crops/s" for p in sel])
    if result["best"] is not None:
        best = result["best"]["probe_accuracy"]
        fig.add_hrect(y0=best - result["tolerance"], y1=best, fillcolor="grey", opacity=0.15,
                      line_width=0, annotation_text=f"within {result['tolerance']} of the best",
                      annotation_position="bottom left")
    c = result["choice"]
    if c is not None:
        fig.add_scatter(x=[c["p50_ms"]], y=[c["probe_accuracy"]], mode="markers",
                        name=f"chosen: {c['label']}",
                        marker={"symbol": "star", "size": 20, "color": "gold",
                                "line": {"width": 1, "color": "black"}})
    s = result["settings"]
    fig.update_xaxes(type="log", title=f"single-crop p50 latency, ms (warm, {s['threads']} "
                                       f"intra-op threads, load {s['load_average_before'][0]})")
    fig.update_yaxes(title=f"material linear probe accuracy ({s['n']} validation renders, "
                           "2-fold)")
    fig.update_layout(title=f"Vision towers: speed against accuracy (chance "
                            f"{result['chance']:.2f}); rule: {result['rule']}",
                      title_font_size=13, width=1000, height=600, template="plotly_white")
    return fig


def tower_chart(result: dict) -> bytes:
    """The chart as PNG bytes (plotly + kaleido, through the local Chromium).

    Raises:
        ServiceError: If no static exporter works here (kaleido needs a Chrome/Chromium);
            :func:`write_towers` then writes the HTML figure instead.
    """
    data, why = png_bytes(tower_figure(result))
    if data is None:
        raise ServiceError(f"no PNG export of the towers chart: {' '.join(why.split())[:300]}")
    return data


def write_towers(result: dict, png: str | os.PathLike | None = None) -> dict[str, str]:
    """Write the result JSON and the chart beside it.

    Args:
        png: the chart's path (default ``docs/figures/towers.png``); the JSON goes beside it
            as ``<stem>.data.json``. Where no PNG exporter works, the plotly HTML figure is
            written as ``<stem>.html`` (its plotly.min.js beside it) and "note" says why.

    Returns:
        {"json": path, "png" or "html": path, "note"?: why there is no PNG}.
    """
    path = Path(png) if png is not None else DOCS / "figures" / f"{FIGURE_NAME}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    out = {"json": str(write_json_atomic(path.with_name(f"{path.stem}.data.json"), result))}
    try:
        out["png"] = str(write_atomic(path, tower_chart(result)))
    except ServiceError as e:
        html = path.with_suffix(".html")
        write_figure_html(tower_figure(result), html)
        out["html"] = str(html)
        out["note"] = f"{e}; wrote the plotly HTML figure instead"
        log.warning("%s", out["note"])
    return out

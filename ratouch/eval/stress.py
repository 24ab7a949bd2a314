"""Stability where the methods fail: the world's test split under each stress knob.

For every knob (`ratouch.world.config.StressConfig`) the test split is rendered at a series of
values, encoded, and answered by every query mode (image / tactile / joint retrieval against
the corpus's text index) and by both generators (the no-retrieval baseline and RA-Touch). Each
sweep point reports

* retrieval, per mode: material precision@K and label-adjective overlap@K (the metrics of
  `ratouch.eval.retrieval`), and the top-K overlap |ids ∩ ids_ref| / K with the unperturbed
  answer for the same sample;
* generators, per system: mean offline-judge score (1-10), the share of descriptions identical
  to the unperturbed one, and the mean adjective Jaccard with it.

Break points: per knob and series, the first value (in sweep order, mildest first) at which the
quality falls below `drop` x its unperturbed value ("holds" if none does). The natural split is
also broken down by object-scale bin, and the retriever's joint queries are checked for collapse
with and without the stability loss (an "align"-only retriever trained into the cache against
the shipped "full" one).

Pairing. The world draws a knob's value from the sample's random stream only when the knob is
unset (None = the natural distribution); a fixed value skips that draw, so every later draw
(layout, colours, tactile pose, label adjectives) shifts and the sample becomes a different
scene of the same object class and material. To compare like with like, a knob that replaces a
per-sample draw (object_scale, clutter, background_dominance, tactile_noise, tactile_blur) is
compared with a *paired reference*: the same samples rendered with that knob fixed to each
sample's own natural value, which skips the same draw, so the reference and the stressed sample
differ only in the knob (the reference's values follow the natural distribution exactly).
box_offset > 0 adds a draw (the shift's direction): its reference is the split with a 1e-6
shift, which takes that draw and rounds to the unshifted box. clutter remains partly unpaired:
each distractor takes draws of its own, so a count other than the natural one still shifts the
later draws (contact box, lighting, tactile press, label); `paired_labels` (share of samples
whose label adjectives equal the reference's) shows how far each point is paired.
tactile_rotation and missing take no draw (0 / "none" are the natural values): their reference
is the natural split itself.

Missing tactile (`missing="tactile"`: the sensor gives a no-contact frame): the system is told
the modality is missing and falls back to image-only retrieval, as `RATouchPipeline.query` does,
so the tactile and joint modes answer with the image query; the generators still need a
tactile embedding and read the no-contact frame, RA-Touch with the image-only neighbours. The
point also reports, under `retrieval_no_fallback`, what the tactile and joint queries retrieve
from the no-contact frame when nothing falls back. `missing="visual"` (not in the default
sweep) is answered as it comes: the blank image is the image query, nothing falls back.
"""

from __future__ import annotations

import copy
import html
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ratouch.errors import ConfigError
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.report import png_bytes, write_plotly_js
from ratouch.eval.retrieval import entry_materials, retrieval_metrics
from ratouch.eval.tvl import SYSTEMS, describe, retrieve
from ratouch.files import write_atomic
from ratouch.model.retriever import collapse_stats
from ratouch.search.retrieval import QUERY_MODES
from ratouch.train.recipes import align_only_tgr
from ratouch.vocabulary import parse_adjectives
from ratouch.world.config import StressConfig, WorldConfig
from ratouch.world.generator import TEST_SIZE, TEST_STRUCTURED, World
from ratouch.world.splits import TestSplit

# knobs whose fixed value replaces a per-sample random draw (see "Pairing" above)
PER_SAMPLE = ("object_scale", "clutter", "background_dominance", "tactile_noise", "tactile_blur")
# knobs that add a draw when set (box_offset > 0 draws the shift's direction): the paired
# reference sets them to a value that takes the draw but changes nothing (a 1e-6 box shift
# rounds to the unshifted box)
PAIR_FIXED = {"box_offset": 1e-6}
# the paper's failure case: a small object in a loud, cluttered scene
PAPER_FAILURE = {"object_scale": 0.12, "background_dominance": 1.0, "clutter": 4}
# mildest first; the unperturbed reference is added in front of each sweep
SWEEPS: dict[str, list[dict]] = {
    "object_scale": [{"object_scale": v} for v in (0.6, 0.35, 0.2, 0.12)],
    "clutter": [{"clutter": v} for v in (0, 2, 4, 8)],
    "background_dominance": [{"background_dominance": v} for v in (0.0, 0.5, 0.8, 1.0)],
    "tactile_noise": [{"tactile_noise": v} for v in (0.05, 0.1, 0.2)],
    "tactile_blur": [{"tactile_blur": v} for v in (2.0, 4.0, 6.0)],
    "tactile_rotation": [{"tactile_rotation": v} for v in (45.0, 90.0, 180.0)],
    "box_offset": [{"box_offset": v} for v in (0.25, 0.5, 1.0, 2.0)],
    "missing": [{"missing": "tactile"}],
    "paper_failure": [dict(PAPER_FAILURE)],
}
KNOBS = tuple(SWEEPS)
_NATURAL_LABEL = {"tactile_rotation": "0", "box_offset": "0", "missing": "none"}
SCALE_BINS = ((0.0, 0.2, "<0.2"), (0.2, 0.4, "0.2-0.4"), (0.4, 0.7, "0.4-0.7"),
              (0.7, 1.01, ">=0.7"))
DEFAULT_N = 200


# ------------------------------------------------------------------------- sweep definitions

def _knob_value(knob: str, text: str):
    if knob == "missing":
        return text
    try:
        return int(text) if knob == "clutter" else float(text)
    except ValueError as e:
        raise ConfigError(f"{knob} value {text!r} is not a number") from e


def build_sweeps(knobs: Sequence[str] | None = None,
                 values: dict[str, Sequence] | None = None) -> dict[str, list[dict]]:
    """The sweeps to run: the chosen knobs (default all), optionally with other values.

    Every value is checked against the world's ranges here, before any work.
    """
    names = list(knobs) if knobs else list(KNOBS)
    values = dict(values or {})
    unknown = [k for k in list(names) + list(values) if k not in SWEEPS]
    if unknown:
        raise ConfigError(f"unknown stress knob(s) {sorted(set(unknown))}; known: "
                          f"{', '.join(KNOBS)}")
    if len(set(names)) != len(names):
        raise ConfigError(f"knob listed twice in {names}")
    stray = [k for k in values if k not in names]
    if stray:
        raise ConfigError(f"values given for {stray}, which are not among the knobs {names}")
    if "paper_failure" in values:
        raise ConfigError("paper_failure is one fixed combined point; it takes no values")
    sweeps = {}
    for knob in names:
        if knob in values:
            vals = list(values[knob])
            if not vals:
                raise ConfigError(f"no values given for {knob}")
            sweeps[knob] = [{knob: _knob_value(knob, str(v))} for v in vals]
        else:
            sweeps[knob] = [dict(p) for p in SWEEPS[knob]]
    for knob, points in sweeps.items():
        for p in points:
            if p.get("missing") == "none":
                raise ConfigError("missing=none is the reference; sweep 'tactile' or 'visual'")
            WorldConfig().with_stress(**p)  # range checks (ConfigError)
    return sweeps


def parse_values(specs: Sequence[str] | None) -> dict[str, list[str]]:
    """`["tactile_noise=0.1,0.2", ...]` -> {"tactile_noise": ["0.1", "0.2"]}."""
    out: dict[str, list[str]] = {}
    for spec in specs or ():
        knob, sep, rest = spec.partition("=")
        if not sep or not rest.strip():
            raise ConfigError(f"--values {spec!r} must read KNOB=V1,V2,...")
        out[knob.strip()] = [v.strip() for v in rest.split(",") if v.strip()]
    return out


def stratified_indices(n: int | None, total: int | None = None,
                       structured: int | None = None) -> list[int]:
    """`n` test indices, evenly spaced within the structured and the wild subset, in
    proportion to their sizes (all of them when n is None or >= the split size)."""

    total = TEST_SIZE if total is None else total
    structured = TEST_STRUCTURED if structured is None else structured
    if n is None or n >= total:
        return list(range(total))
    if n < 2:
        raise ConfigError(f"--n {n}: at least 2 samples are needed")
    n_s = max(1, round(n * structured / total))
    n_w = n - n_s

    def spread(lo: int, hi: int, m: int) -> list[int]:
        return [lo + int(j * (hi - lo) / m) for j in range(m)]

    return spread(0, structured, n_s) + spread(structured, total, n_w)


# ------------------------------------------------------------------------- rendering

class _Renderer:
    """Test samples under any stress, sharing one World's texture caches (pyramids and
    sensor backgrounds depend only on pattern specs and the tactile size, never on stress)."""

    def __init__(self, world: WorldConfig):

        self.world = world
        self.base = World(world)

    def _world(self, knobs: dict):
        w = copy.copy(self.base)  # shallow: the caches are shared
        w.cfg = self.world.with_stress(**knobs)
        return w

    def natural_values(self, indices: Sequence[int]) -> dict[str, list]:
        """Each sample's natural value of the per-sample knobs (drawn, nothing rendered)."""
        size = self.world.image_size
        out: dict[str, list] = {k: [] for k in PER_SAMPLE}
        for i in indices:
            _, _, _, scene, touch, _, _ = self.base.plan("test", i)
            out["object_scale"].append(float(scene.object_scale / size))
            out["clutter"].append(len(scene.distractors))
            out["background_dominance"].append(float(scene.dominance))
            out["tactile_noise"].append(float(touch.noise))
            out["tactile_blur"].append(float(touch.blur))
        return out

    def split(self, encoders, indices: Sequence[int], knobs: dict | None = None,
              per_sample: Sequence[dict] | None = None) -> TestSplit:
        """Render and encode; `per_sample[j]` are extra knobs for sample j."""
        samples = []
        shared = self._world(knobs or {})
        for j, i in enumerate(indices):
            w = self._world({**(knobs or {}), **per_sample[j]}) if per_sample else shared
            samples.append(w.sample("test", i))
        crops = [s.crop for s in samples]
        return TestSplit(
            V=encoders.encode_image(crops), T=encoders.encode_tactile([s.tactile for s in samples]),
            labels=[s.caption for s in samples], subsets=[s.subset for s in samples],
            materials=[s.material for s in samples], indices=list(indices),
            object_scale=[float(s.object_scale) for s in samples], world=shared.cfg)


# ------------------------------------------------------------------------- answering and scoring

class _Context:
    """What scoring needs once: corpus materials and caption adjectives, the judge."""

    def __init__(self, pipeline, k: int, judge):
        entries = pipeline.corpus.entries
        self.entry_mats = entry_materials(pipeline.corpus)
        self.entry_words = [set(parse_adjectives(e.caption)) for e in entries]
        self.k = k
        self.judge = judge


def _answers(pipeline, split: TestSplit, k: int, fallback_image: bool) -> dict:
    """Neighbour ids per mode and both systems' descriptions."""
    ids = {m: retrieve(pipeline, split.V, split.T, k, m) for m in QUERY_MODES}
    raw = None
    if fallback_image:  # missing tactile: the tactile and joint modes fall back to the image
        raw = {m: ids[m] for m in ("tactile", "joint")}
        ids["tactile"] = ids["joint"] = ids["image"]
    rv, rl = pipeline.neighbour_embeddings(ids["joint"])
    desc = {"baseline": describe(pipeline.generator_base, split.V, split.T),
            "ra-touch": describe(pipeline.generator_ra, split.V, split.T, rv, rl)}
    return {"ids": ids, "raw_ids": raw, "desc": desc}


def _retrieval_metrics(ids: np.ndarray, split: TestSplit, ctx: _Context,
                       sel: np.ndarray | None = None) -> dict:

    labels = [set(parse_adjectives(lbl)) for lbl in split.labels]
    sel = np.ones(len(labels), bool) if sel is None else sel
    return retrieval_metrics(ids, split.materials, labels, ctx.entry_mats, ctx.entry_words, ctx.k, sel)


def _judge_scores(split: TestSplit, desc: dict, ctx: _Context) -> dict[str, np.ndarray]:
    return {s: np.asarray(ctx.judge.score_many(list(zip(split.labels, desc[s]))), float)
            for s in SYSTEMS}


def _jaccard(a: str, b: str) -> float:
    x, y = set(parse_adjectives(a)), set(parse_adjectives(b))
    return 1.0 if not x and not y else len(x & y) / len(x | y)


def _score_point(split: TestSplit, ans: dict, ref_split: TestSplit, ref: dict,
                 ctx: _Context) -> dict:
    k = ctx.k
    retrieval = {}
    for m in QUERY_MODES:
        ids, rid = ans["ids"][m], ref["ids"][m]
        overlap = np.mean([len(set(a) & set(b)) / k for a, b in zip(ids, rid)])
        retrieval[m] = {**_retrieval_metrics(ids, split, ctx),
                        "topk_overlap": round(float(overlap), 4)}
    scores = _judge_scores(split, ans["desc"], ctx)
    gens = {}
    for s in SYSTEMS:
        d, rd = ans["desc"][s], ref["desc"][s]
        gens[s] = {"judge": round(float(scores[s].mean()), 4),
                   "identical": round(float(np.mean([a == b for a, b in zip(d, rd)])), 4),
                   "adj_jaccard": round(float(np.mean([_jaccard(a, b) for a, b in zip(d, rd)])), 4)}
    out = {"retrieval": retrieval, "generators": gens,
           "paired_labels": round(float(np.mean([a == b for a, b in
                                                  zip(split.labels, ref_split.labels)])), 4)}
    if ans.get("raw_ids"):
        out["retrieval_no_fallback"] = {
            m: {**_retrieval_metrics(ids, split, ctx),
                "topk_overlap": round(float(np.mean([len(set(a) & set(b)) / k for a, b in
                                                     zip(ids, ref["ids"][m])])), 4)}
            for m, ids in ans["raw_ids"].items()}
    return out


def _scale_bins(split: TestSplit, ans: dict, ctx: _Context) -> list[dict]:
    """Quality per object-scale bin of the natural split (structured close-ups apart)."""
    scale = np.asarray(split.object_scale)
    wild = np.array([s == "wild" for s in split.subsets])
    groups = [("structured", ~wild)] + [(name, wild & (scale >= lo) & (scale < hi))
                                        for lo, hi, name in SCALE_BINS]
    scores = _judge_scores(split, ans["desc"], ctx)
    rows = []
    for name, sel in groups:
        row: dict[str, Any] = {"bin": name, "n": int(sel.sum())}
        if sel.any():
            row["retrieval"] = {m: _retrieval_metrics(ans["ids"][m], split, ctx, sel)
                                for m in QUERY_MODES}
            row["judge"] = {s: round(float(scores[s][sel].mean()), 4) for s in SYSTEMS}
        rows.append(row)
    return rows


# ------------------------------------------------------------------------- break points

def _series(point: dict, k: int) -> dict[str, float]:
    out = {f"P@{k} {m}": point["retrieval"][m]["material_precision"] for m in QUERY_MODES}
    out.update({f"judge {s}": point["generators"][s]["judge"] for s in SYSTEMS})
    out.update({f"overlap {m}": point["retrieval"][m]["topk_overlap"] for m in QUERY_MODES})
    return out


def break_points(points: list[dict], k: int, drop: float) -> dict[str, dict]:
    """Per series: the first sweep value whose quality is below `drop` x the reference's
    (points[0]); "holds" when none is."""
    ref = _series(points[0], k)
    out = {}
    for name, v0 in ref.items():
        threshold = drop * v0
        at = None
        for p in points[1:]:
            if _series(p, k)[name] < threshold:
                at = p
                break
        worst = min(points[1:], key=lambda p: _series(p, k)[name]) if len(points) > 1 else None
        out[name] = {"reference": v0, "threshold": round(threshold, 4),
                     "breaks_at": at["label"] if at else None,
                     "value_at_break": _series(at, k)[name] if at else None,
                     "worst": ({"label": worst["label"], "value": _series(worst, k)[name]}
                               if worst else None)}
    return out


# ------------------------------------------------------------------------- collapse

def collapse_report(pipeline, split: TestSplit, ctx: _Context, encoder: str,
                    epochs: int = 12, seed: int = 0, align_tgr=None,
                    progress: bool = False) -> dict:
    """Collapse statistics (`collapse_stats`) and material precision@K of the joint queries on
    the natural split: the shipped retriever ("full" = alignment + stability loss) against one
    trained with alignment only (cached; trained on first use, `epochs` epochs)."""
    import torch


    info: dict[str, Any] = {"epochs_align": epochs}
    if align_tgr is None:
        align_tgr, trained = align_only_tgr(encoder, epochs, seed, progress)
        info.update(trained)
    V, T = torch.from_numpy(split.V), torch.from_numpy(split.T)
    rows = {}
    for name, tgr in (("full (shipped)", pipeline.tgr), ("align only", align_tgr)):
        with torch.no_grad():
            q = tgr(V, T).query
        ids = pipeline.corpus.search("text", np.ascontiguousarray(q.numpy(), np.float32),
                                     ctx.k)[1]
        stats = collapse_stats(q)
        rows[name] = {**{k: round(v, 4) for k, v in stats.items()},
                      **_retrieval_metrics(ids, split, ctx)}
    for name, x in (("image query (V)", split.V), ("tactile query (T)", split.T)):
        rows[name] = {k: round(v, 4) for k, v in collapse_stats(torch.from_numpy(x)).items()}
    info["rows"] = rows
    return info


# ------------------------------------------------------------------------- the sweep

def _label(knob: str, setting: dict | None, natural_mean: float | None) -> str:
    if setting is None:
        if knob in _NATURAL_LABEL:
            return _NATURAL_LABEL[knob]
        return "natural" if natural_mean is None else f"natural ({natural_mean:.3g})"
    if knob == "paper_failure":
        return "failure"
    v = setting[knob]
    return v if isinstance(v, str) else f"{v:g}"


def _x(knob: str, setting: dict | None, natural_mean: float | None):
    if knob in ("missing", "paper_failure"):
        return _label(knob, setting, None).split(" ")[0]
    if setting is None:
        return 0.0 if natural_mean is None else round(natural_mean, 4)
    return float(setting[knob])


def run_stress(pipeline, sweeps: dict[str, list[dict]] | None = None, k: int = 5,
               n: int | None = DEFAULT_N, world: WorldConfig | None = None, judge=None,
               collapse: bool = True, collapse_epochs: int = 12, encoder: str = "default-s",
               drop: float = 0.8, align_tgr=None,
               progress: Callable[[str], None] | None = None) -> dict:
    """Run the stress sweeps; returns the JSON-able result (see the module docstring).

    Args:
        pipeline: a loaded `RATouchPipeline` (encoders, corpus, retriever, generators).
        sweeps: `build_sweeps(...)` (default: every knob's default sweep).
        k: neighbours per query (precision@K, overlap@K; RA-Touch reads them).
        n: test samples (stratified over structured / wild); None = all 402.
        world: base world config (seed); its stress must be the default.
        judge: scorer with `score_many` (default the offline judge).
        collapse: also run the collapse diagnostic (trains an align-only retriever once).
        drop: break-point threshold as a fraction of the unperturbed value.
        align_tgr: an align-only retriever to compare with (skips loading/training it).
        progress: called with one line per finished point.
    """

    t_start = time.perf_counter()
    sweeps = build_sweeps() if sweeps is None else sweeps
    if not 1 <= k <= len(pipeline.corpus):
        raise ConfigError(f"K={k} must lie in [1, {len(pipeline.corpus)}] (the corpus size)")
    if not 0 < drop < 1:
        raise ConfigError(f"drop={drop} must lie in (0, 1)")
    world = world or WorldConfig()
    if world.stress != StressConfig():
        raise ConfigError("the base world of a stress sweep must be unstressed")
    say = progress or (lambda line: None)
    run = _Sweep(pipeline, _Context(pipeline, k, judge or OfflineJudge()),
                 stratified_indices(n), world, say)
    nat_split, nat_ans = run.reference(())
    result: dict[str, Any] = {
        "encoder": encoder, "k": k, "n": len(run.indices), "world_seed": world.seed,
        "drop": drop, "indices": run.indices, "judge": type(run.ctx.judge).__name__,
        "natural_means": {kk: round(float(np.mean(v)), 4) for kk, v in run.natural.items()},
        "reference": {**_score_point(nat_split, nat_ans, nat_split, nat_ans, run.ctx),
                      "scale_bins": _scale_bins(nat_split, nat_ans, run.ctx)},
        "knobs": {knob: run.knob(knob, settings, drop) for knob, settings in sweeps.items()}}
    result["collapse"] = None
    if collapse:
        t0 = time.perf_counter()
        result["collapse"] = collapse_report(pipeline, nat_split, run.ctx, encoder,
                                             collapse_epochs, world.seed, align_tgr=align_tgr,
                                             progress=progress is not None)
        result["collapse"]["seconds"] = round(time.perf_counter() - t0, 1)
        say(f"collapse diagnostic: {result['collapse']['seconds']:.1f} s")
    result["seconds"] = round(time.perf_counter() - t_start, 1)
    return result


class _Sweep:
    """One stress run's shared state: the samples, their natural knob values, and the
    (paired) references computed once per set of paired knobs."""

    def __init__(self, pipeline, ctx: _Context, indices: list[int], world: WorldConfig,
                 say: Callable[[str], None]):
        self.pipeline, self.ctx, self.indices, self.say = pipeline, ctx, indices, say
        self.renderer = _Renderer(world)
        self.natural = self.renderer.natural_values(indices)
        self.refs: dict[tuple, tuple[TestSplit, dict]] = {}

    def reference(self, keys: tuple) -> tuple[TestSplit, dict]:
        """The split and answers with the knobs `keys` at each sample's natural value."""
        if keys not in self.refs:
            t0 = time.perf_counter()
            fixed = {kk: PAIR_FIXED[kk] for kk in keys if kk in PAIR_FIXED}
            drawn = [kk for kk in keys if kk in PER_SAMPLE]
            per = ([{kk: self.natural[kk][j] for kk in drawn} for j in range(len(self.indices))]
                   if drawn else None)
            sp = self.renderer.split(self.pipeline.encoders, self.indices, knobs=fixed,
                                     per_sample=per)
            self.refs[keys] = (sp, _answers(self.pipeline, sp, self.ctx.k, False))
            self.say(f"reference {'natural' if not keys else 'paired ' + '+'.join(keys)}: "
                     f"{time.perf_counter() - t0:.1f} s")
        return self.refs[keys]

    def knob(self, knob: str, settings: list[dict], drop: float) -> dict:
        """Every setting of one knob against its paired reference, with its break points."""
        keys = tuple(sorted({kk for s in settings for kk in s if kk in PER_SAMPLE}
                            | {kk for s in settings for kk in s if kk in PAIR_FIXED and s[kk]}))
        ref_split, ref_ans = self.reference(keys)
        mean = (float(np.mean(self.natural[knob])) if knob in PER_SAMPLE else None)
        points = [{"label": _label(knob, None, mean), "value": None, "x": _x(knob, None, mean),
                   "reference": True,
                   **_score_point(ref_split, ref_ans, ref_split, ref_ans, self.ctx)}]
        for setting in settings:
            t0 = time.perf_counter()
            fallback = setting.get("missing") == "tactile"
            sp = self.renderer.split(self.pipeline.encoders, self.indices, knobs=setting)
            ans = _answers(self.pipeline, sp, self.ctx.k, fallback)
            points.append({"label": _label(knob, setting, mean), "value": setting,
                           "x": _x(knob, setting, mean), "reference": False,
                           **_score_point(sp, ans, ref_split, ref_ans, self.ctx),
                           "seconds": round(time.perf_counter() - t0, 1)})
            self.say(f"{knob}={points[-1]['label']}: {points[-1]['seconds']:.1f} s")
        return {"paired_reference": list(keys), "points": points,
                "break_points": break_points(points, self.ctx.k, drop)}


# ------------------------------------------------------------------------- figures

_MODE_COLOURS = {"image": "#1f77b4", "tactile": "#ff7f0e", "joint": "#2ca02c"}
_SYSTEM_COLOURS = {"baseline": "#7f7f7f", "ra-touch": "#d62728"}


def _sorted_points(points: list[dict]) -> list[dict]:
    if all(isinstance(p["x"], (int, float)) for p in points):
        return sorted(points, key=lambda p: p["x"])
    return points


def figures(result: dict):
    """(quality figure, stability figure): one subplot per knob.

    Quality: material P@K per mode (left axis, 0-1) and mean judge score per generator
    (dashed, right axis, 1-10). Stability: top-K overlap with the unperturbed answer per mode
    and adjective Jaccard with the unperturbed description per generator (dashed). The
    unperturbed reference is drawn as a star."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    knobs = list(result["knobs"])
    k = result["k"]
    cols = min(3, max(1, len(knobs)))
    rows = max(1, math.ceil(len(knobs) / cols))

    def frame(secondary: bool):
        return make_subplots(rows=rows, cols=cols, subplot_titles=knobs,
                             specs=[[{"secondary_y": secondary}] * cols for _ in range(rows)],
                             horizontal_spacing=0.09 if secondary else 0.06,
                             vertical_spacing=0.12)

    quality, stability = frame(True), frame(False)
    for j, knob in enumerate(knobs):
        r, c = j // cols + 1, j % cols + 1
        pts = _sorted_points(result["knobs"][knob]["points"])
        xs = [p["x"] for p in pts]
        symbols = ["star" if p["reference"] else "circle" for p in pts]
        text = [p["label"] for p in pts]
        first = j == 0
        for m in QUERY_MODES:
            common = dict(x=xs, mode="lines+markers", legendgroup=m, showlegend=first, text=text,
                          marker=dict(symbol=symbols, size=9, color=_MODE_COLOURS[m]),
                          line=dict(color=_MODE_COLOURS[m]))
            quality.add_trace(go.Scatter(y=[p["retrieval"][m]["material_precision"] for p in pts],
                                         name=f"P@{k} {m}", **common), row=r, col=c,
                              secondary_y=False)
            stability.add_trace(go.Scatter(y=[p["retrieval"][m]["topk_overlap"] for p in pts],
                                           name=f"top-{k} overlap {m}", **common), row=r, col=c)
        for s in SYSTEMS:
            common = dict(x=xs, mode="lines+markers", legendgroup=s, showlegend=first, text=text,
                          marker=dict(symbol=symbols, size=8, color=_SYSTEM_COLOURS[s]),
                          line=dict(color=_SYSTEM_COLOURS[s], dash="dash"))
            quality.add_trace(go.Scatter(y=[p["generators"][s]["judge"] for p in pts],
                                         name=f"judge {s}", **common), row=r, col=c,
                              secondary_y=True)
            stability.add_trace(go.Scatter(y=[p["generators"][s]["adj_jaccard"] for p in pts],
                                           name=f"adjective Jaccard {s}", **common), row=r, col=c)
    quality.update_yaxes(range=[0, 1.02], secondary_y=False)
    quality.update_yaxes(range=[1, 10], secondary_y=True, showgrid=False, tickmode="linear",
                         tick0=1, dtick=1)
    stability.update_yaxes(range=[0, 1.02])
    n = result["n"]
    quality.update_layout(
        title=f"Quality under stress (n={n}, K={k}): material P@{k} per query mode (solid, left "
              f"axis), judge score per generator (dashed, right axis 1-10); star = unperturbed",
        height=330 * rows + 120, width=1300, template="plotly_white")
    stability.update_layout(
        title=f"Stability under stress (n={n}): top-{k} overlap with the unperturbed answer "
              f"(solid), adjective Jaccard with the unperturbed description (dashed)",
        height=330 * rows + 120, width=1300, template="plotly_white")
    return quality, stability


# ------------------------------------------------------------------------- reports

def _f(v, nd: int = 3) -> str:
    return "—" if v is None else f"{v:.{nd}f}"


def format_table(result: dict) -> str:
    """The compact console table and the break points."""
    k = result["k"]
    lines = [f"stress sweep: n={result['n']} test samples, K={k}, encoder {result['encoder']}, "
             f"{result['seconds']:.0f} s",
             f"{'knob':<21}{'value':<16}{'P@' + str(k) + ' img':>9}{'tac':>7}{'joint':>7}"
             f"{'ovl joint':>10}{'judge base':>11}{'RA':>7}"]
    for knob, kr in result["knobs"].items():
        for p in kr["points"]:
            r, g = p["retrieval"], p["generators"]
            lines.append(f"{knob:<21}{p['label']:<16}{r['image']['material_precision']:>9.3f}"
                         f"{r['tactile']['material_precision']:>7.3f}"
                         f"{r['joint']['material_precision']:>7.3f}"
                         f"{r['joint']['topk_overlap']:>10.3f}{g['baseline']['judge']:>11.2f}"
                         f"{g['ra-touch']['judge']:>7.2f}")
    lines.append("")
    lines.append(f"break points (first value below {result['drop']:.0%} of the unperturbed):")
    series = [f"P@{k} {m}" for m in QUERY_MODES] + [f"judge {s}" for s in SYSTEMS]
    lines.append(f"{'knob':<21}" + "".join(f"{s:>16}" for s in series))
    for knob, kr in result["knobs"].items():
        bp = kr["break_points"]
        lines.append(f"{knob:<21}" + "".join(f"{(bp[s]['breaks_at'] or 'holds'):>16}"
                                             for s in series))
    col = result.get("collapse")
    if col:
        lines.append("")
        lines.append("collapse of the joint queries (natural split):")
        for name, row in col["rows"].items():
            p = row.get("material_precision")
            lines.append(f"  {name:<18} effective rank {row['effective_rank']:7.2f}  mean cosine "
                         f"{row['mean_cosine']:.3f}"
                         + (f"  P@{k} {p:.3f}" if p is not None else ""))
    return "\n".join(lines)


_PAIRED = 0.9  # paired-labels share below which a point counts as not paired


def _reference_text(keys: Sequence[str]) -> str:
    if not keys:
        return "the natural split"
    parts = [f"{kk} = 1e-6 (same box, same draws)" if kk in PAIR_FIXED
             else f"{kk} at each sample's natural value" for kk in keys]
    return "paired (" + ", ".join(parts) + ")"


def _md_point_table(kr: dict, k: int) -> list[str]:
    head = (f"| value | P@{k} image | P@{k} tactile | P@{k} joint | overlap image "
            f"| overlap tactile | overlap joint | judge baseline | judge RA-Touch "
            f"| identical base / RA | adj-Jaccard base / RA | paired labels |")
    lines = [head, "|" + "---|" * 12]
    for p in kr["points"]:
        r, g = p["retrieval"], p["generators"]
        lines.append(
            f"| {p['label']}{' (ref)' if p['reference'] else ''}"
            f"{' †' if p['paired_labels'] < _PAIRED else ''} "
            + "".join(f"| {r[m]['material_precision']:.3f} " for m in QUERY_MODES)
            + "".join(f"| {r[m]['topk_overlap']:.3f} " for m in QUERY_MODES)
            + f"| {g['baseline']['judge']:.2f} | {g['ra-touch']['judge']:.2f} "
            f"| {g['baseline']['identical']:.2f} / {g['ra-touch']['identical']:.2f} "
            f"| {g['baseline']['adj_jaccard']:.2f} / {g['ra-touch']['adj_jaccard']:.2f} "
            f"| {p['paired_labels']:.2f} |")
        if "retrieval_no_fallback" in p:
            nf = p["retrieval_no_fallback"]
            lines.append(f"| ↳ {p['label']}, no fallback (no-contact frame as the query) | — "
                         + "".join(f"| {nf[m]['material_precision']:.3f} "
                                   for m in ("tactile", "joint"))
                         + "| — " + "".join(f"| {nf[m]['topk_overlap']:.3f} "
                                            for m in ("tactile", "joint"))
                         + "| | | | | |")
    return lines


def format_markdown(result: dict, png: str | None, png_note: str) -> str:
    """The stress report in markdown: how to read it, the natural split, break points, every
    knob's points, the collapse check and the figures."""
    k = result["k"]
    out = _md_header(result)
    out += _md_natural(result["reference"], k)
    out += _md_break_points(result, k)
    out += ["", "## Per knob", ""]
    for knob, kr in result["knobs"].items():
        out += [f"### {knob}", "", f"Reference: {_reference_text(kr['paired_reference'])}.",
                ""] + _md_point_table(kr, k) + [""]
    out += _md_collapse(result, k)
    out += _md_figures(png, png_note)
    out.append("")
    return "\n".join(out)


def _md_header(result: dict) -> list[str]:
    k = result["k"]
    return [
        "# Stress sweep: stability where the methods fail",
        "",
        f"Encoder `{result['encoder']}`, K={k}, {result['n']} test samples (stratified over the "
        f"structured and wild subsets; world seed {result['world_seed']}), judge "
        f"{result['judge']}; wall time {result['seconds']:.0f} s. Made by `ratouch eval stress`.",
        "",
        "* **P@K**: material precision@K of the corpus entries retrieved against the text index "
        "(image, tactile and joint = Tactile-Guided Retriever query).",
        "* **overlap**: |top-K ∩ top-K of the unperturbed reference| / K, mean over samples; "
        "**identical** / **adj-Jaccard**: share of descriptions equal to the reference's, mean "
        "adjective Jaccard with it. Judge: mean score 1-10.",
        "* **Reference** of each knob: knobs that replace a per-sample random draw "
        f"({', '.join(PER_SAMPLE)}) are compared with a paired reference (same samples, knob "
        "fixed to each sample's natural value, so the rest of the scene is drawn the same way); "
        "box_offset with a 1e-6 shift (takes the shift's random draw, rounds to the true box); "
        "the others with the natural split. *paired labels* = share of samples whose label "
        "adjectives equal the reference's (1.00 = fully paired scenes). clutter stays partly "
        f"unpaired: each distractor takes draws of its own, so at a count other than the "
        f"sample's natural one the contact box, lighting, tactile press and label are re-drawn "
        f"too; overlap and identity at such points (marked †, paired labels < {_PAIRED:.1f}) mix "
        f"the knob with that re-draw, while P@K and the judge (each sample against its own "
        f"truth) stay valid. object_scale and clutter do not apply to the structured "
        f"close-ups, which stay as they are.",
        "* **missing=tactile**: the tactile and joint modes fall back to the image query "
        "(as the app does); the generators read the no-contact frame, RA-Touch with the "
        "image-only neighbours. The ↳ row shows the no-contact frame used as the query.",
        f"* Paper failure case: {', '.join(f'{a}={b}' for a, b in PAPER_FAILURE.items())}.",
        "",
    ]


def _md_natural(ref: dict, k: int) -> list[str]:
    out = [
        "## Unperturbed (natural split)",
        "",
        f"| mode | P@{k} | adjective overlap@{k} |", "|---|---|---|"]
    for m in QUERY_MODES:
        r = ref["retrieval"][m]
        out.append(f"| {m} | {r['material_precision']:.3f} | {r['adjective_overlap']:.3f} |")
    out += ["", "| generator | judge |", "|---|---|"]
    for s in SYSTEMS:
        out.append(f"| {s} | {ref['generators'][s]['judge']:.2f} |")
    out += ["", "### Quality per object-scale bin (natural split; wild samples by scale)", "",
            f"| bin | n | P@{k} image | P@{k} tactile | P@{k} joint | judge baseline "
            f"| judge RA-Touch |",
            "|---|---|---|---|---|---|---|"]
    for row in ref["scale_bins"]:
        if row["n"] == 0:
            out.append(f"| {row['bin']} | 0 | — | — | — | — | — |")
            continue
        out.append(f"| {row['bin']} | {row['n']} "
                   + "".join(f"| {row['retrieval'][m]['material_precision']:.3f} "
                             for m in QUERY_MODES)
                   + "".join(f"| {row['judge'][s]:.2f} " for s in SYSTEMS) + "|")
    return out


def _md_break_points(result: dict, k: int) -> list[str]:
    drop = result["drop"]
    out: list[str] = []
    out += ["", "## Break points", "",
            f"First sweep value (mildest first) at which the quality falls below {drop:.0%} of "
            f"the knob's unperturbed value; *holds* = never within the sweep (worst value in "
            f"brackets). Overlap columns: first value whose top-{k} overlap with the "
            f"unperturbed answer is below {drop:.2f}; † = the point is not paired with its "
            f"reference (see above), so its overlap mixes the knob with re-drawn scenes.", ""]
    series = ([f"P@{k} {m}" for m in QUERY_MODES] + [f"judge {s}" for s in SYSTEMS]
              + [f"overlap {m}" for m in QUERY_MODES])
    out.append("| knob | " + " | ".join(series) + " |")
    out.append("|---|" + "---|" * len(series))
    for knob, kr in result["knobs"].items():
        cells = []
        unpaired = {p["label"] for p in kr["points"] if p["paired_labels"] < _PAIRED}
        for s in series:
            b = kr["break_points"][s]
            if b["breaks_at"] is not None:
                dag = " †" if s.startswith("overlap") and b["breaks_at"] in unpaired else ""
                cells.append(f"**{b['breaks_at']}**{dag} ({_f(b['value_at_break'], 2)} vs "
                             f"{_f(b['reference'], 2)})")
            else:
                w = b["worst"]
                cells.append(f"holds ({_f(w['value'], 2)})" if w else "holds")
        out.append(f"| {knob} | " + " | ".join(cells) + " |")
    return out


def _md_collapse(result: dict, k: int) -> list[str]:
    out: list[str] = []
    col = result.get("collapse")
    out += ["## Collapse of the retriever's queries", ""]
    if col:
        out += [f"Joint queries of the natural split ({result['n']} samples): the shipped "
                f"retriever (alignment + stability loss, `full`) against one trained with "
                f"alignment only (`align`, {col['epochs_align']} epochs"
                + (f", trained in {col['trained_s']:.0f} s" if "trained_s" in col else "")
                + (f", cached in `{col['align_folder']}`" if "align_folder" in col else "")
                + "). Raw image and tactile embeddings for scale.", "",
                f"| queries | effective rank | mean pairwise cosine | mean dim std | P@{k} |",
                "|---|---|---|---|---|"]
        for name, row in col["rows"].items():
            out.append(f"| {name} | {row['effective_rank']:.2f} | {row['mean_cosine']:.4f} | "
                       f"{row['mean_dim_std']:.4f} | {_f(row.get('material_precision'))} |")
    else:
        out.append("Not run (`--no-collapse`).")
    return out


def _md_figures(png: str | None, png_note: str) -> list[str]:
    out: list[str] = []
    out += ["", "## Figures", "",
            "`stress.html` (both figures, with plotly.min.js beside it, works offline); plotly JSON "
            "for the app: `stress_fig.json` (quality), `stress_overlap_fig.json` (stability).",
            ""]
    if png:
        out += [f"![quality under stress]({png})", "",
                f"![stability under stress]({png.replace('.png', '_overlap.png')})"]
    else:
        out.append(f"PNG: {png_note}")
    return out


def _html(figs) -> str:
    parts = [f.to_html(full_html=False, include_plotlyjs="directory" if i == 0 else False)
             for i, f in enumerate(figs)]
    return ("<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>"
            + html.escape("RA-Touch stress sweep") + "</title></head><body>\n"
            + "\n".join(parts) + "\n</body></html>\n")




def write_report(result: dict, out: str | os.PathLike, png: bool = True) -> dict[str, str]:
    """Write stress.json, stress.md, stress.html, stress_fig.json, stress_overlap_fig.json and,
    when kaleido can export (it needs a Chrome/Chromium), stress.png and stress_overlap.png.
    Returns {kind: path}."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    quality, stability = figures(result)
    paths = {"json": out / "stress.json", "md": out / "stress.md", "html": out / "stress.html",
             "fig": out / "stress_fig.json", "overlap_fig": out / "stress_overlap_fig.json"}
    png_name, note = None, "not requested."
    if png:
        (q_png, why), (s_png, why2) = png_bytes(quality), png_bytes(stability)
        if q_png is not None and s_png is not None:
            for name, data in (("stress.png", q_png), ("stress_overlap.png", s_png)):
                write_atomic(out / name, data)
            png_name = "stress.png"
            paths["png"] = out / "stress.png"
            paths["overlap_png"] = out / "stress_overlap.png"
        else:
            note = (f"not written: static export needs kaleido and a Chrome/Chromium, not usable "
                    f"here ({why or why2}); open stress.html instead.")
    write_atomic(paths["json"], json.dumps(result, indent=1) + "\n")
    write_atomic(paths["html"], _html([quality, stability]))
    write_plotly_js(out)
    write_atomic(paths["fig"], quality.to_json())
    write_atomic(paths["overlap_fig"], stability.to_json())
    write_atomic(paths["md"], format_markdown(result, png_name, note))
    return {kk: str(v) for kk, v in paths.items()}

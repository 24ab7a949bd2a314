"""Speed against accuracy (`ratouch bench tradeoff`): latency per query against quality, over
encoder size, index type, corpus size and K, measured in one run, with the upstream retrieval
recipe as a reference point.

Per point:

* latency: p50 (and p95) over warm single-pair queries of the RA-Touch answer path - encode
  the contact crop and the tactile frame, the Tactile-Guided Retriever, search, the RA-Touch
  generation - on one thread-pinned index (no PCA, no baseline generation);
* quality: the offline judge's mean on the world's 402 test pairs for the RA-Touch description
  given that point's neighbours (the shipped generator, trained with K=5 over the whole corpus),
  and the material precision@5 of the joint query's neighbours.

Encoders without a trained retriever and generators (only default-s ships them) get retrieval
points only: tactile->text precision@5 and the encode + search latency, marked as such.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from ratouch.bench.index import upstream_retrieve
from ratouch.encoders.factory import OTHER_SETS
from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split
from ratouch.eval.experiments import Lab
from ratouch.eval.judge import mean_ci, score_stats
from ratouch.eval.retrieval import entry_materials, material_precision
from ratouch.model.gate import READ_BELOW
from ratouch.paths import cascade_calibration
from ratouch.search.index import BENCH_KINDS, KINDS, IndexConfig, VectorIndex
from ratouch.serve.cascade import CascadeCalibration, joint_confidence
from ratouch.serve.models import available_models, load_model
from ratouch.serve.pipeline import RATouchPipeline, default_corpus, open_retriever
from ratouch.timing import Progress, say_to
from ratouch.vocabulary import adjective_f1
from ratouch.world.dataset import world_for
from ratouch.world.sensors import beyond_every_unit
from ratouch.world.splits import encode_test_split

log = logging.getLogger(__name__)
#: The retrieval systems with a point of their own beside the paper's (`_system_point`).
SYSTEM_POINTS = ("gated", "text", "fallback")

#: How the cascade's point names its encoder sets ("cascade: default-tiny > default-s").
CASCADE_LABEL = "cascade: "


def _p(times: list[float], q: float) -> float:
    return round(float(np.percentile(np.asarray(times) * 1000, q)), 3)


def _subset_index(lab, kind: str, size: int):
    """A class-stratified subset of `size` entries, indexed with `kind`."""
    ids = lab.subset_ids(size)
    emb = np.ascontiguousarray(lab.pipeline.corpus_embeddings("tactile_caption")[ids])
    return ids, VectorIndex.build(emb, IndexConfig(kind=kind))


def bench_tradeoff(lab=None, indexes: Sequence[str] = BENCH_KINDS,
                   sizes: Sequence[int] = (1000, 2500, 10000), ks: Sequence[int] = (1, 5, 10),
                   other_encoders: Sequence[str] = OTHER_SETS,
                   n_latency: int = 30, progress: Progress = None) -> dict:
    """Measure every point; returns {"points": [...], "upstream": {...}, "settings": {...}}.

    `progress` is called with one line per measured point (the CLI prints them)."""
    say = say_to(progress, log)
    lab = lab or Lab()
    p, test = lab.pipeline, lab.test
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    picks = rng.choice(len(test.labels), size=min(n_latency, len(test.labels)), replace=False)
    pairs = _raw_pairs(test, picks)
    joint = p.joint_query(test.V, test.T)
    entry_mats = entry_materials(p.corpus)
    points, scores = [], []
    for kind in indexes:
        for size in sizes:
            ids_map, index = _subset_index(lab, kind, size)
            for k in ks:
                t0 = time.perf_counter()
                ids = ids_map[index.search(joint, k)[1]]
                judged, per_sample = _judge_stats(lab, ids)
                prec = material_precision(ids_map[index.search(joint, 5)[1]], test.materials,
                                          entry_mats)
                per_sample["precision_at_5"] = prec
                pt = {"encoder": lab.cfg.encoder, "index": kind, "corpus": len(ids_map), "k": k,
                      **_latency(p, pairs, lambda q, m=ids_map, ix=index, k=k: m[ix.search(q, k)[1]]),
                      **judged, **_ci("precision_at_5", prec), "system": "RA-Touch"}
                points.append(pt)
                scores.append(per_sample)
                say(f"{kind:<6}{len(ids_map):>7}{k:>4}  p50 {pt['p50_ms']:7.2f} ms  "
                    f"judge {pt['judge']:.3f}  P@5 {pt['precision_at_5']:.3f}  "
                    f"({time.perf_counter() - t0:.0f} s)")
    reference = _mark_noise(points, scores, len(p.corpus))
    upstream = _upstream_point(lab, pairs, points)
    floor, _ = _judge_stats(lab, None)  # the baseline (no retrieval) as the floor
    ref = next((sc for q, sc in zip(points, scores) if q.get("judge_vs_reference")
                and q["index"] == "flat" and q["corpus"] == len(p.corpus) and q["k"] == 5), None)
    for system in SYSTEM_POINTS:
        point = _system_point(lab, pairs, points, scores, system)
        if point is not None:
            points.append(point)
            say(f"{system:<7} {point['corpus']:>7}{5:>4}  p50 {point['p50_ms']:7.2f} ms  "
                f"judge {point['judge']:.3f}  P@5 {point['precision_at_5']:.3f}")
    alone = {lab.cfg.encoder: _Alone(p, test, p.corpus.search("text", joint, 5), ref)}
    points += _encoder_points(other_encoders, lab, alone, pairs, say)
    cascade = _cascade_point(lab, alone, pairs, say)
    if cascade is not None:
        points.append(cascade)
    return {"points": points, "upstream": upstream, "baseline_judge": floor["judge"],
            "baseline": floor, "reference": reference,
            "settings": {"encoder": lab.cfg.encoder, "n_latency": n_latency, "threads": 1, "test_pairs": len(test.labels),
                         "note": "RA-Touch generator trained with K=5 on the whole corpus; "
                                 "other points change retrieval at inference only"}}


def _judge_stats(lab, ids: np.ndarray | None, pipeline=None, split=None, generator=None
                 ) -> tuple[dict, dict[str, np.ndarray]]:
    """The judge on the test split (or `split`), RA-Touch (or `generator`) reading the
    neighbours `ids` or the baseline when None, with the lab's pipeline (or `pipeline`):
    ({"judge", "judge_ci", "f1", "mean_length"}, per-sample {"judge", "f1"})."""
    split = lab.test if split is None else split
    ans = answer_split(pipeline or lab.pipeline, split, BASELINE if ids is None else RA_TOUCH,
                       ids=ids, judge=lab.judge, generator=generator)
    responses, per_sample = ans.responses, ans.scores
    st = score_stats(split.labels, responses, per_sample)
    f1 = np.array([adjective_f1(label, r) for label, r in zip(split.labels, responses)])
    return ({"judge": round(st["mean"], 4),
             "judge_ci": [round(st["ci_low"], 4), round(st["ci_high"], 4)],
             "f1": round(st["f1"], 4), "f1_ci": [round(x, 4) for x in mean_ci(f1)[1:]],
             "mean_length": round(st["mean_length"], 2)}, {"judge": per_sample, "f1": f1})


def _ci(key: str, values: np.ndarray) -> dict:
    """{key: mean, key_ci: [low, high]} with a seeded 95 % bootstrap CI over the queries."""
    mean, lo, hi = mean_ci(values)
    return {key: round(mean, 4), f"{key}_ci": [round(lo, 4), round(hi, 4)]}


def _mark_noise(points: list[dict], scores: Sequence[dict[str, np.ndarray] | np.ndarray],
                full: int) -> dict | None:
    """Each point's differences to the reference point (flat index over the whole corpus,
    K=5: what the app serves) in the judge score (and in F1 and material P@5 where per-sample
    values are given), paired per test sample with 95 % CIs: `<key>_vs_reference`, with
    `within_noise` when the CI holds 0. `scores` per point: {"judge", "f1"?,
    "precision_at_5"?: (n,)}, or the judge scores alone. Returns the reference's
    description (None when it was not measured)."""
    ref = next((j for j, q in enumerate(points) if q["index"] == "flat"
                and q["corpus"] == full and q["k"] == 5), None)
    if ref is None:
        return None
    per_point = [sc if isinstance(sc, dict) else {"judge": sc} for sc in scores]
    for q, sc in zip(points, per_point):
        q.update(_vs_reference(sc, per_point[ref]))
    return {"index": "flat", "corpus": full, "k": 5}


def _vs_reference(per_sample: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> dict:
    """{"<key>_vs_reference": {"diff", "ci", "within_noise"}} for the keys both have."""
    out = {}
    for key in ("judge", "f1", "precision_at_5"):
        if key in per_sample and key in ref:
            mean, lo, hi = mean_ci(per_sample[key] - ref[key])
            out[f"{key}_vs_reference"] = {"diff": round(mean, 4),
                                          "ci": [round(lo, 4), round(hi, 4)],
                                          "within_noise": bool(lo <= 0 <= hi)}
    return out


def _latency(p, pairs: tuple[list, list], search, gated: bool = False,
             generator=None, look: bool = False) -> dict[str, float]:
    """p50 / p95 of the RA-Touch answer path (encoders, retriever, `search`, generation) and of
    the search alone, in ms, over warm single-pair queries (the first one warms caches).
    `gated`: the trust-gated query instead of the joint one; `generator`: another RA-Touch
    generator than the pipeline's; `look`: the frame's look is read first, as the serving
    path reads it for a withholding system (`guess_family`)."""
    gen = generator or p.generator_ra
    times, search_times = [], []
    for j, (crop, frame) in enumerate(zip(*pairs)):
        t0 = time.perf_counter()
        if look:
            beyond_every_unit(frame)
        V = p.encoders.encode_image([crop])
        T = p.encoders.encode_tactile([frame])
        q = p.joint_query(V, T, gated=gated)
        s0 = time.perf_counter()
        ids = search(q)
        s1 = time.perf_counter()
        rv, rl = p.neighbour_embeddings(ids)
        gen.describe(*(torch.from_numpy(x) for x in (V, T, rv, rl)))
        if j:
            search_times.append(s1 - s0)
            times.append(time.perf_counter() - t0)
    return {"p50_ms": _p(times, 50), "p95_ms": _p(times, 95),
            "search_p50_ms": _p(search_times, 50)}


def _system_point(lab, pairs: tuple[list, list], points: list[dict], scores: list,
                  system: str) -> dict | None:
    """A retrieval system beside the paper's on the flat index over the whole corpus, K=5,
    judged and timed like the other points: `gated`, the trust-gated query's neighbours read
    as the served system reads them (`system_generator`: the reader where the gate gives
    touch less than `READ_BELOW` of the say, the paper's RA-Touch generator elsewhere or
    where no reader is loaded; None without a touch gate); `text`, the joint query's
    neighbours read as text by the text arm (`generator_text`; None without one);
    `fallback`, the paper's answer path with the frame's look read first, where no test
    frame lies beyond every rendered unit (then its answers are the paper's; None otherwise:
    the withheld rows' answers are not built here, `scripts/why_withhold.py` measures them)."""
    p = lab.pipeline
    if system == "fallback":
        return _fallback_point(lab, pairs, points)
    gated = system == "gated"
    gen = p.system_generator("gated") if gated else p.generator_text
    if (gated and p.gate is None) or gen is None:
        return None
    test = lab.test
    ids = p.corpus.search("text", p.joint_query(test.V, test.T, gated=gated), 5)[1]
    judged, per_sample = _judge_stats(lab, ids, generator=gen)
    prec = material_precision(ids, test.materials, entry_materials(p.corpus))
    per_sample["precision_at_5"] = prec
    ref = next((sc for q, sc in zip(points, scores) if q["index"] == "flat"
                and q["corpus"] == len(p.corpus) and q["k"] == 5), None)
    name = ("RA-Touch, gated" + (f" (reader below touch weight {READ_BELOW})"
                                  if p.generator_reader is not None else "")
            if gated else "RA-Touch, text (captions in the prompt)")
    return {"encoder": lab.cfg.encoder, "index": "flat", "corpus": len(p.corpus), "k": 5,
            **_latency(p, pairs, lambda q: p.corpus.search("text", q, 5)[1], gated=gated,
                       generator=gen),
            **judged, **_ci("precision_at_5", prec),
            **(_vs_reference(per_sample, ref) if isinstance(ref, dict) else {}),
            "system": name}


#: A point's quality figures: what a point reading the paper's flat K=5 neighbours with the
#: paper's generator shares with that point.
_QUALITY = ("judge", "judge_ci", "f1", "mean_length", "precision_at_5", "precision_at_5_ci")


def _paper_flat(points: list[dict], corpus: int) -> dict | None:
    """The paper's point on the flat index over the whole corpus (`corpus` entries), K=5: the
    served one; None when it was not measured."""
    return next((q for q in points if q["index"] == "flat" and q["corpus"] == corpus
                 and q["k"] == 5 and q["system"] == "RA-Touch"), None)


def _fallback_point(lab, pairs: tuple[list, list], points: list[dict]) -> dict | None:
    """`_system_point` of `fallback` (see there)."""
    p, test = lab.pipeline, lab.test
    world = world_for(test.world)
    beyond = [i for i in test.indices if beyond_every_unit(world.sample("test", i).tactile)]
    if beyond:
        log.info("no fallback point: %d test frames lie beyond every rendered unit", len(beyond))
        return None
    paper = _paper_flat(points, len(p.corpus))
    if paper is None:
        return None
    return {"encoder": lab.cfg.encoder, "index": "flat", "corpus": len(p.corpus), "k": 5,
            **_latency(p, pairs, lambda q: p.corpus.search("text", q, 5)[1], look=True),
            **{key: paper.get(key) for key in _QUALITY},
            "system": "RA-Touch, fallback (the paper's answers: no test frame withheld)"}


def _upstream_point(lab, pairs: tuple[list, list], points: list[dict]) -> dict:
    """The upstream recipe (torch re-normalisation + full matmul + topk) on the whole corpus;
    its quality is the flat K=5 point's (the same neighbours)."""
    p = lab.pipeline
    corpus_t = torch.from_numpy(np.array(p.corpus_embeddings("tactile_caption"), np.float32))
    lat = _latency(p, pairs, lambda q: upstream_retrieve(corpus_t, torch.from_numpy(q), 5)
                   .numpy().reshape(1, -1))
    flat = _paper_flat(points, len(p.corpus))  # only the paper's points are made yet
    return {"encoder": lab.cfg.encoder, "index": "upstream", "corpus": len(p.corpus), "k": 5,
            **lat, **{key: (flat or {}).get(key) for key in _QUALITY},
            "system": "RA-Touch, upstream retrieval"}


def _raw_pairs(test, picks) -> tuple[list, list]:
    """The raw contact crops and tactile frames of test pairs `picks` (for timing)."""
    world = world_for(test.world)
    samples = [world.sample("test", test.indices[int(i)]) for i in picks]
    return [s.crop for s in samples], [s.tactile for s in samples]


class _Alone:
    """One encoder set answering the test split alone (the reference's scale: flat index over
    the whole corpus, K=5): its pipeline, encoded split, joint search and per-sample scores."""

    def __init__(self, pipeline, split, search=None, per_sample=None):
        self.pipeline, self.split = pipeline, split
        self.scores, self.ids = search if search is not None else pipeline.corpus.search(
            "text", pipeline.joint_query(split.V, split.T), 5)
        self.per_sample = per_sample


def _encoder_points(encoders: Sequence[str], lab, alone: dict, pairs: tuple[list, list],
                    say: Callable[[str], None]) -> list:
    """A point per other encoder set: the whole RA-Touch answer where its retriever and
    generators are shipped (judge, F1 and P@5 with CIs and their differences to the
    reference), retrieval only (tactile->text P@5) otherwise."""
    out, test = [], lab.test
    full = set(available_models())
    ref = alone[lab.cfg.encoder].per_sample
    for name in encoders:
        t0 = time.perf_counter()
        if name not in full:
            out.append(_retrieval_point(name, test, pairs))
            say(f"{name}: p50 {out[-1]['p50_ms']:.2f} ms (encode + search), tactile->text "
                f"P@5 {out[-1]['precision_at_5']:.3f} ({time.perf_counter() - t0:.0f} s)")
            continue
        p = load_model(name)  # an encoder set, or one on a pretrained LM's generators
        assert isinstance(p, RATouchPipeline)  # the cascade is its own point
        a = alone[name] = _Alone(p, encode_test_split(p.encoders, test.world))
        judged, a.per_sample = _judge_stats(lab, a.ids, p, a.split)
        a.per_sample["precision_at_5"] = material_precision(
            a.ids, a.split.materials, entry_materials(p.corpus))
        pt = {"encoder": name, "index": "flat", "corpus": len(p.corpus), "k": 5,
              **_latency(p, pairs, lambda q, p=p: p.corpus.search("text", q, 5)[1]),
              **judged, **_ci("precision_at_5", a.per_sample["precision_at_5"]),
              "system": "RA-Touch", **(_vs_reference(a.per_sample, ref) if ref else {})}
        out.append(pt)
        say(f"{name}: p50 {pt['p50_ms']:.2f} ms  judge {pt['judge']:.3f}  F1 {pt['f1']:.3f}  "
            f"P@5 {pt['precision_at_5']:.3f} ({time.perf_counter() - t0:.0f} s)")
    return out


def _retrieval_point(name: str, test, pairs: tuple[list, list]) -> dict:
    """Retrieval only for an encoder without a trained retriever / generators: tactile->text
    P@5 and the encode + search latency."""
    retriever = open_retriever(default_corpus(name, progress=False), name)
    split = encode_test_split(retriever.encoders, test.world)
    ids = retriever.corpus.search("text", split.T, 5)[1]
    times = []
    for j, (crop, frame) in enumerate(zip(*pairs)):
        s = time.perf_counter()
        retriever.encoders.encode_image([crop])
        T = retriever.encoders.encode_tactile([frame])
        retriever.corpus.search("text", T, 5)
        if j:
            times.append(time.perf_counter() - s)
    return {"encoder": name, "index": "flat", "corpus": len(retriever.corpus), "k": 5,
            "p50_ms": _p(times, 50), "p95_ms": _p(times, 95), "search_p50_ms": None,
            "judge": None,
            **_ci("precision_at_5", material_precision(
                ids, split.materials, entry_materials(retriever.corpus))),
            "system": "retrieval only (tactile->text)"}


def _cascade_point(lab, alone: dict, pairs: tuple[list, list],
                   say: Callable[[str], None]) -> dict | None:
    """The shipped cascade on the test split, when its calibration is shipped and every stage
    was measured alone: each pair answered by the stage the cascade picks (the stages' own
    answers, judged per sample), its latency on the answer path, and its escalation share."""
    path = cascade_calibration()
    if not path.is_file():
        return None
    cal = CascadeCalibration.load(path)
    missing = [n for n in cal.encoders if n not in alone or alone[n].per_sample is None]
    if missing:
        say(f"cascade: not measured ({', '.join(missing)} not measured alone; add them to "
            "--encoders)")
        return None
    t0 = time.perf_counter()
    stages = [alone[n] for n in cal.encoders]
    classes = np.array([e.class_name for e in stages[0].pipeline.corpus.entries])
    n = len(lab.test.labels)
    answer = np.full(n, len(stages) - 1)
    for s in range(len(stages) - 2, -1, -1):  # the first confident stage answers
        conf = joint_confidence(stages[s].scores, stages[s].ids, classes, cal.measure)
        answer = np.where(conf >= cal.thresholds[s], s, answer)
    per_sample = {key: np.choose(answer, [a.per_sample[key] for a in stages])
                  for key in ("judge", "f1", "precision_at_5")}
    ref = alone[lab.cfg.encoder].per_sample
    pt = {"encoder": CASCADE_LABEL + " > ".join(cal.encoders), "index": "flat",
          "corpus": len(stages[0].pipeline.corpus), "k": 5,
          **_cascade_latency([a.pipeline for a in stages], cal, classes, pairs),
          "judge": round(float(per_sample["judge"].mean()), 4),
          "judge_ci": [round(x, 4) for x in mean_ci(per_sample["judge"])[1:]],
          "f1": round(float(per_sample["f1"].mean()), 4),
          "f1_ci": [round(x, 4) for x in mean_ci(per_sample["f1"])[1:]],
          "mean_length": None, **_ci("precision_at_5", per_sample["precision_at_5"]),
          "escalated": round(float(np.mean(answer > 0)), 4),
          "answered_by": {name: round(float(np.mean(answer == s)), 4)
                          for s, name in enumerate(cal.encoders)},
          "measure": cal.measure, "thresholds": [float(t) for t in cal.thresholds],
          "system": "RA-Touch, cascade", **(_vs_reference(per_sample, ref) if ref else {})}
    say(f"cascade: p50 {pt['p50_ms']:.2f} ms  judge {pt['judge']:.3f}  F1 {pt['f1']:.3f}  "
        f"P@5 {pt['precision_at_5']:.3f}  escalated {pt['escalated']:.1%} "
        f"({time.perf_counter() - t0:.0f} s)")
    return pt



def _cascade_latency(stages: Sequence, cal, classes: np.ndarray, pairs: tuple[list, list]
                     ) -> dict[str, float | None]:
    """p50 / p95 of the cascade's answer path per pair: each stage in turn encodes, runs its
    retriever and searches until one is confident; that stage generates."""
    times = []
    for j, (crop, frame) in enumerate(zip(*pairs)):
        t0 = time.perf_counter()
        for s, p in enumerate(stages):
            V = p.encoders.encode_image([crop])
            T = p.encoders.encode_tactile([frame])
            scores, ids = p.corpus.search("text", p.joint_query(V, T), cal.k)
            if s < len(stages) - 1 and joint_confidence(
                    scores, ids, classes, cal.measure)[0] < cal.thresholds[s]:
                continue
            rv, rl = p.neighbour_embeddings(ids[:, :5])
            p.generator_ra.describe(*(torch.from_numpy(x) for x in (V, T, rv, rl)))
            break
        if j:
            times.append(time.perf_counter() - t0)
    return {"p50_ms": _p(times, 50), "p95_ms": _p(times, 95), "search_p50_ms": None}


def pareto(points: Sequence[dict], key: str) -> list[dict]:
    """Points not beaten on both latency (lower) and `key` (higher), by latency."""
    pts = sorted((q for q in points if q.get(key) is not None), key=lambda q: q["p50_ms"])
    front, best = [], -np.inf
    for q in pts:
        if q[key] > best:
            front.append(q)
            best = q[key]
    return front


#: Marker symbols and colours of the named points (other encoder sets, the other retrieval
#: systems, the cascade), one each, in the order the points come: each has its own legend
#: entry, so no label sits on another where the points crowd.
_NAMED_SYMBOLS = ("triangle-up", "star", "diamond-open", "square-open", "triangle-down",
                  "hexagon", "cross-open", "pentagon")
_NAMED_COLOURS = ("#000000", "#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd",
                  "#8c564b", "#e377c2")


def tradeoff_figure(result: dict):
    """Latency (log x) against the judge score, adjective F1 and material P@5 of the
    neighbours, each with 95 % CIs: the served encoder's sweep, the other encoder sets, the
    other retrieval systems and the cascade (each named in the legend), on the whole range
    (top row) and zoomed to the served encoder's points, where they crowd (bottom row)."""
    from plotly.subplots import make_subplots

    panels = (("judge", "offline judge (RA-Touch, test split)"),
              ("f1", "adjective F1 of the answer"),
              ("precision_at_5", "material precision@5 of the neighbours"))
    fig = make_subplots(rows=2, cols=3, vertical_spacing=0.16,
                        subplot_titles=[t for _, t in panels]
                        + [f"{t}: zoomed" for _, t in panels])
    symbols = {"flat": "circle", "hnsw": "diamond", "ivfflat": "cross", "ivfpq": "square",
               "upstream": "x"}
    pts = result["points"]
    served = result.get("settings", {}).get("encoder", "default-s")
    sweep = [q for q in pts if q["system"] == "RA-Touch" and q["encoder"] == served]
    others = [q for q in pts if q not in sweep]
    style = {_short(q): (_NAMED_SYMBOLS[i % len(_NAMED_SYMBOLS)],
                         _NAMED_COLOURS[i % len(_NAMED_COLOURS)])
             for i, q in enumerate(others)}
    named: set[str] = set()  # the named points already in the legend
    for row in (1, 2):
        for col, (key, _) in enumerate(panels, 1):
            legend = row == 1 and col == 1
            for kind in KINDS:
                sel = [q for q in sweep if q["index"] == kind and q.get(key) is not None]
                if sel:
                    fig.add_scatter(
                        x=[q["p50_ms"] for q in sel], y=[q[key] for q in sel], mode="markers",
                        name=f"{served} {kind}", legendgroup=kind, showlegend=legend,
                        marker={"symbol": symbols[kind], "size": [6 + 2 * q["k"] for q in sel],
                                "color": [np.log10(q["corpus"]) for q in sel],
                                "colorscale": "Viridis", "cmin": 3, "cmax": 4,
                                "showscale": row == 1 and col == 3,
                                "colorbar": {"title": "log10 corpus", "len": 0.4, "y": 0.8}},
                        error_y=_error_bars(sel, key),
                        text=[f"{q['index']} corpus {q['corpus']} K={q['k']}"
                              + _noise_note(q, key) for q in sel],
                        row=row, col=col)
            front = pareto(sweep, key)
            if front:
                fig.add_scatter(x=[q["p50_ms"] for q in front], y=[q[key] for q in front],
                                mode="lines", name="frontier",
                                line={"color": "grey", "dash": "dot"}, showlegend=legend,
                                legendgroup="frontier", row=row, col=col)
            up = result["upstream"]
            if up.get(key) is not None:
                fig.add_scatter(x=[up["p50_ms"]], y=[up[key]], mode="markers",
                                marker={"symbol": "x", "size": 12, "color": "red"},
                                name="upstream retrieval", legendgroup="upstream",
                                showlegend=legend, row=row, col=col)
            for q in others:
                if q.get(key) is None:
                    continue
                label = _short(q)
                symbol, colour = style[label]
                fig.add_scatter(
                    x=[q["p50_ms"]], y=[q[key]], mode="markers", name=label,
                    legendgroup=label, showlegend=label not in named,
                    error_y=_error_bars([q], key), hovertext=[q["system"] + _noise_note(q, key)],
                    marker={"symbol": symbol, "size": 12, "color": colour,
                            "line": {"width": 1.5, "color": colour}},
                    row=row, col=col)
                named.add(label)
            if key == "judge":
                fig.add_hline(y=result["baseline_judge"], line_dash="dash", line_color="black",
                              annotation_text="baseline (no retrieval)",
                              annotation_position="bottom left", row=row, col=col)
    fig.update_xaxes(type="log", title="p50 latency per query, ms (warm, 1 thread)")
    lo, hi = _zoom(sweep + others, sweep)
    fig.update_xaxes(range=[np.log10(lo), np.log10(hi)], row=2)
    for col, (key, _) in enumerate(panels, 1):
        span = _zoom_y([q for q in sweep + others if lo <= q["p50_ms"] <= hi], key)
        if span is not None:
            fig.update_yaxes(range=span, row=2, col=col)
    fig.update_layout(title="Speed against accuracy (marker size = K, colour = corpus size; "
                            "bars: 95 % CIs)",
                      template="plotly_white", height=950, width=1500,
                      legend={"orientation": "h", "y": -0.1})
    return fig


def _zoom(near: Sequence[dict], sweep: Sequence[dict]) -> tuple[float, float]:
    """The zoomed row's latency range: the served sweep's, widened to the points within
    twice its slowest (the systems beside it), with a margin."""
    times = [q["p50_ms"] for q in sweep] or [q["p50_ms"] for q in near]
    lo, hi = min(times), max(times)
    hi = max([hi] + [q["p50_ms"] for q in near if q["p50_ms"] <= 2 * hi])
    lo = min([lo] + [q["p50_ms"] for q in near if q["p50_ms"] >= lo / 2])
    return lo / 1.08, hi * 1.08


def _zoom_y(points: Sequence[dict], key: str) -> list[float] | None:
    """A zoomed panel's value range: its points' values and CIs, with a margin."""
    vals = [v for q in points if q.get(key) is not None
            for v in [q[key], *(q.get(f"{key}_ci") or [])]]
    if not vals:
        return None
    lo, hi = min(vals), max(vals)
    pad = max(hi - lo, 1e-3) * 0.08
    return [lo - pad, hi + pad]


def _short(q: dict) -> str:
    """A point's label on the chart: the encoder set, or the cascade with its escalations."""
    if q["system"].endswith("cascade"):
        return f"cascade, {q['escalated']:.0%} escalated"
    for system in SYSTEM_POINTS:
        if q["system"].startswith(f"RA-Touch, {system}"):
            return f"{q['encoder']} {system}"
    return q["encoder"] + ("" if q["system"] == "RA-Touch" else " (retrieval only)")


def _error_bars(points: Sequence[dict], key: str) -> dict | None:
    """Plotly error bars from each point's 95 % CI of `key` (None where none was measured)."""
    if any(q.get(f"{key}_ci") is None for q in points):
        return None
    cis = [q[f"{key}_ci"] for q in points]
    return {"type": "data", "symmetric": False, "thickness": 1,
            "array": [ci[1] - q[key] for q, ci in zip(points, cis)],
            "arrayminus": [q[key] - ci[0] for q, ci in zip(points, cis)]}


def _noise_note(q: dict, key: str = "judge") -> str:
    d = q.get(f"{key}_vs_reference")
    if not d:
        return ""
    return (f"<br>{key} vs reference {d['diff']:+.3f} [{d['ci'][0]:+.3f}, {d['ci'][1]:+.3f}]"
            + (" (inside the noise)" if d["within_noise"] else ""))


def format_tradeoff(result: dict) -> str:
    """The points as a table: latency, the judge with its 95 % CI, F1, length, P@5 with its
    CI, and the judge, F1 and P@5 differences to the reference point (`~` where the
    difference's 95 % CI holds 0, inside the noise; `*` where it does not)."""
    points = result["points"] + [result["upstream"]]
    w = max([13] + [len(q["encoder"]) + 1 for q in points
                    if not q["system"].endswith("cascade")])  # the widest model name
    lines = [f"{'encoder':<{w}}{'index':<9}{'corpus':>7}{'K':>4}{'p50 ms':>9}{'p95 ms':>9}"
             f"{'search':>9}  {'judge [95% CI]':<24}{'F1':>6}{'len':>5}  {'P@5 [95% CI]':<22}"
             f"{'vs ref: judge':>14}{'F1':>9}{'P@5':>9}  system"]
    for q in points:
        judge = (f"{q['judge']:.3f} [{q['judge_ci'][0]:.3f}, {q['judge_ci'][1]:.3f}]"
                 if q.get("judge") is not None else "-")
        f1 = f"{q['f1']:.3f}" if q.get("f1") is not None else "-"
        length = f"{q['mean_length']:.1f}" if q.get("mean_length") is not None else "-"
        prec = (f"{q['precision_at_5']:.3f} [{q['precision_at_5_ci'][0]:.3f}, "
                f"{q['precision_at_5_ci'][1]:.3f}]" if q.get("precision_at_5") is not None
                else "-")
        srch = f"{q['search_p50_ms']:.3f}" if q.get("search_p50_ms") is not None else "-"
        vs = [_vs_cell(q.get(f"{key}_vs_reference"))
              for key in ("judge", "f1", "precision_at_5")]
        name = q["encoder"] if not q["system"].endswith("cascade") else "cascade"
        system = q["system"] + (f" ({q['escalated']:.1%} escalated, {q['measure']} >= "
                                f"{', '.join(f'{t:.3f}' for t in q['thresholds'])}: "
                                f"{q['encoder'][len(CASCADE_LABEL):]})"
                                if "escalated" in q else "")
        lines.append(f"{name:<{w}}{q['index']:<9}{q['corpus']:>7}{q['k']:>4}"
                     f"{q['p50_ms']:>9.2f}{q['p95_ms']:>9.2f}{srch:>9}  {judge:<24}{f1:>6}"
                     f"{length:>5}  {prec:<22}{vs[0]:>14}{vs[1]:>9}{vs[2]:>9}  {system}")
    b = result.get("baseline") or {"judge": result["baseline_judge"]}
    lines.append(f"baseline (no retrieval) judge: {b['judge']:.3f}"
                 + (f" [{b['judge_ci'][0]:.3f}, {b['judge_ci'][1]:.3f}], F1 {b['f1']:.3f}, "
                    f"{b['mean_length']:.1f} adj" if "judge_ci" in b else ""))
    if result.get("reference"):
        r = result["reference"]
        lines.append(f"vs ref: differences to the {r['index']} index over the whole corpus "
                     f"({r['corpus']}) at K={r['k']} with the served encoder, paired per test "
                     "sample; ~ = its 95 % CI holds 0 (inside the noise), * = it does not")
    return "\n".join(lines)


def _vs_cell(d: dict | None) -> str:
    return f"{d['diff']:+.3f}{'~' if d['within_noise'] else '*'}" if d else "-"

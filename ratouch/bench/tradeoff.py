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
from typing import Callable, Sequence

import numpy as np
import torch

from ratouch.bench.index import upstream_retrieve
from ratouch.eval.experiments import Lab
from ratouch.eval.judge import judge_results, mean_ci, score_stats
from ratouch.eval.retrieval import entry_materials, material_precision
from ratouch.eval.tvl import describe, records_for
from ratouch.search.index import IndexConfig, VectorIndex
from ratouch.serve.pipeline import default_corpus, open_retriever
from ratouch.world.dataset import world_for
from ratouch.world.splits import encode_test_split

log = logging.getLogger(__name__)


def _p(times: list[float], q: float) -> float:
    return round(float(np.percentile(np.asarray(times) * 1000, q)), 3)


def _subset_index(lab, kind: str, size: int):
    """A class-stratified subset of `size` entries, indexed with `kind`."""
    ids = lab.subset_ids(size)
    emb = np.ascontiguousarray(lab.pipeline.corpus_embeddings("tactile_caption")[ids])
    return ids, VectorIndex.build(emb, IndexConfig(kind=kind))


def bench_tradeoff(lab=None, indexes: Sequence[str] = ("flat", "hnsw", "ivfpq"),
                   sizes: Sequence[int] = (1000, 2500, 10000), ks: Sequence[int] = (1, 5, 10),
                   other_encoders: Sequence[str] = ("default-tiny", "default-b"),
                   n_latency: int = 30, progress: Callable[[str], None] | None = None) -> dict:
    """Measure every point; returns {"points": [...], "upstream": {...}, "settings": {...}}.

    `progress` is called with one line per measured point (the CLI prints them)."""
    say = progress or (lambda line: None)
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
                judged, per_sample = _judge_stats(lab, p.neighbour_embeddings(ids))
                prec = material_precision(ids_map[index.search(joint, 5)[1]], test.materials,
                                          entry_mats)
                pt = {"encoder": lab.cfg.encoder, "index": kind, "corpus": len(ids_map), "k": k,
                      **_latency(p, pairs, lambda q: ids_map[index.search(q, k)[1]]),
                      **judged, **_ci("precision_at_5", prec), "system": "RA-Touch"}
                points.append(pt)
                scores.append(per_sample)
                say(f"{kind:<6}{len(ids_map):>7}{k:>4}  p50 {pt['p50_ms']:7.2f} ms  "
                    f"judge {pt['judge']:.3f}  P@5 {pt['precision_at_5']:.3f}  "
                    f"({time.perf_counter() - t0:.0f} s)")
    reference = _mark_noise(points, scores, len(p.corpus))
    upstream = _upstream_point(lab, pairs, points)
    floor, _ = _judge_stats(lab, None)  # the baseline (no retrieval) as the floor
    points += _encoder_points(other_encoders, test, n_latency, say)
    return {"points": points, "upstream": upstream, "baseline_judge": floor["judge"],
            "baseline": floor, "reference": reference,
            "settings": {"n_latency": n_latency, "threads": 1, "test_pairs": len(test.labels),
                         "note": "RA-Touch generator trained with K=5 on the whole corpus; "
                                 "other points change retrieval at inference only"}}


def _judge_stats(lab, neighbours: tuple[np.ndarray, np.ndarray] | None
                 ) -> tuple[dict, np.ndarray]:
    """The judge on the test split, RA-Touch reading `neighbours` (Rv, Rl) or the baseline
    when None: ({"judge", "judge_ci", "f1", "mean_length"}, per-sample scores)."""
    test, p = lab.test, lab.pipeline
    if neighbours is None:
        responses, system = describe(p.generator_base, test.V, test.T), "baseline"
    else:
        responses, system = describe(p.generator_ra, test.V, test.T, *neighbours), "ra-touch"
    rows, _ = judge_results(records_for(test, responses, system), lab.judge)
    per_sample = np.array([r[lab.judge.key] for r in rows], float)
    st = score_stats(test.labels, responses, per_sample)
    return ({"judge": round(st["mean"], 4),
             "judge_ci": [round(st["ci_low"], 4), round(st["ci_high"], 4)],
             "f1": round(st["f1"], 4), "mean_length": round(st["mean_length"], 2)}, per_sample)


def _ci(key: str, values: np.ndarray) -> dict:
    """{key: mean, key_ci: [low, high]} with a seeded 95 % bootstrap CI over the queries."""
    mean, lo, hi = mean_ci(values)
    return {key: round(mean, 4), f"{key}_ci": [round(lo, 4), round(hi, 4)]}


def _mark_noise(points: list[dict], scores: list[np.ndarray], full: int) -> dict | None:
    """Each point's judge difference to the reference point (flat index over the whole corpus,
    K=5: what the app serves), paired per test sample with its 95 % CI; `within_noise` when
    the CI holds 0. Returns the reference's description (None when it was not measured)."""
    ref = next((j for j, q in enumerate(points) if q["index"] == "flat"
                and q["corpus"] == full and q["k"] == 5), None)
    if ref is None:
        return None
    for q, s in zip(points, scores):
        mean, lo, hi = mean_ci(s - scores[ref])
        q["judge_vs_reference"] = {"diff": round(mean, 4), "ci": [round(lo, 4), round(hi, 4)],
                                   "within_noise": bool(lo <= 0 <= hi)}
    return {"index": "flat", "corpus": full, "k": 5}


def _latency(p, pairs: tuple[list, list], search) -> dict[str, float]:
    """p50 / p95 of the RA-Touch answer path (encoders, retriever, `search`, generation) and of
    the search alone, in ms, over warm single-pair queries (the first one warms caches)."""
    times, search_times = [], []
    for j, (crop, frame) in enumerate(zip(*pairs)):
        t0 = time.perf_counter()
        V = p.encoders.encode_image([crop])
        T = p.encoders.encode_tactile([frame])
        q = p.joint_query(V, T)
        s0 = time.perf_counter()
        ids = search(q)
        s1 = time.perf_counter()
        rv, rl = p.neighbour_embeddings(ids)
        p.generator_ra.describe(*(torch.from_numpy(x) for x in (V, T, rv, rl)))
        if j:
            search_times.append(s1 - s0)
            times.append(time.perf_counter() - t0)
    return {"p50_ms": _p(times, 50), "p95_ms": _p(times, 95),
            "search_p50_ms": _p(search_times, 50)}


def _upstream_point(lab, pairs: tuple[list, list], points: list[dict]) -> dict:
    """The upstream recipe (torch re-normalisation + full matmul + topk) on the whole corpus;
    its quality is the flat K=5 point's (the same neighbours)."""
    p = lab.pipeline
    corpus_t = torch.from_numpy(np.array(p.corpus_embeddings("tactile_caption"), np.float32))
    lat = _latency(p, pairs, lambda q: upstream_retrieve(corpus_t, torch.from_numpy(q), 5)
                   .numpy().reshape(1, -1))
    flat = next((q for q in points if q["index"] == "flat" and q["corpus"] == len(p.corpus)
                 and q["k"] == 5), None)
    same = ("judge", "judge_ci", "f1", "mean_length", "precision_at_5", "precision_at_5_ci")
    return {"encoder": lab.cfg.encoder, "index": "upstream", "corpus": len(p.corpus), "k": 5,
            **lat, **{key: (flat or {}).get(key) for key in same},
            "system": "RA-Touch, upstream retrieval"}


def _raw_pairs(test, picks) -> tuple[list, list]:
    """The raw contact crops and tactile frames of test pairs `picks` (for timing)."""
    world = world_for(test.world)
    samples = [world.sample("test", test.indices[int(i)]) for i in picks]
    return [s.crop for s in samples], [s.tactile for s in samples]


def _encoder_points(encoders: Sequence[str], test, n_latency: int,
                    say: Callable[[str], None]) -> list:
    """Retrieval-only points for encoders without a trained retriever / generators."""
    out = []
    for name in encoders:
        t0 = time.perf_counter()
        retriever = open_retriever(default_corpus(name, progress=False), name)
        split = encode_test_split(retriever.encoders, test.world)
        ids = retriever.corpus.search("text", split.T, 5)[1]
        crops, frames = _raw_pairs(test, range(min(n_latency, len(test.labels))))
        times = []
        for j, frame in enumerate(frames):
            s = time.perf_counter()
            retriever.encoders.encode_image([crops[j]])
            T = retriever.encoders.encode_tactile([frame])
            retriever.corpus.search("text", T, 5)
            if j:
                times.append(time.perf_counter() - s)
        pt = {"encoder": name, "index": "flat", "corpus": len(retriever.corpus), "k": 5,
              "p50_ms": _p(times, 50), "p95_ms": _p(times, 95), "search_p50_ms": None,
              "judge": None,
              **_ci("precision_at_5", material_precision(
                  ids, split.materials, entry_materials(retriever.corpus))),
              "system": "retrieval only (tactile->text)"}
        out.append(pt)
        say(f"{name}: p50 {pt['p50_ms']:.2f} ms (encode + search), tactile->text P@5 "
            f"{pt['precision_at_5']:.3f} ({time.perf_counter() - t0:.0f} s)")
    return out


def pareto(points: Sequence[dict], key: str) -> list[dict]:
    """Points not beaten on both latency (lower) and `key` (higher), by latency."""
    pts = sorted((q for q in points if q.get(key) is not None), key=lambda q: q["p50_ms"])
    front, best = [], -np.inf
    for q in pts:
        if q[key] > best:
            front.append(q)
            best = q[key]
    return front


def tradeoff_figure(result: dict):
    """One chart: latency (log x) against the judge score, and against precision@5."""
    from plotly.subplots import make_subplots

    fig = make_subplots(rows=1, cols=2, subplot_titles=(
        "offline judge score (RA-Touch, test split)", "material precision@5 of the neighbours"))
    symbols = {"flat": "circle", "hnsw": "diamond", "ivfpq": "square", "upstream": "x"}
    pts = result["points"]
    for col, key in ((1, "judge"), (2, "precision_at_5")):
        for kind in ("flat", "hnsw", "ivfpq"):
            sel = [q for q in pts if q["index"] == kind and q["system"] == "RA-Touch"
                   and q[key] is not None]
            if sel:
                fig.add_scatter(
                    x=[q["p50_ms"] for q in sel], y=[q[key] for q in sel], mode="markers",
                    name=f"{kind}", legendgroup=kind, showlegend=col == 1,
                    marker={"symbol": symbols[kind], "size": [6 + 2 * q["k"] for q in sel],
                            "color": [np.log10(q["corpus"]) for q in sel],
                            "colorscale": "Viridis", "cmin": 3, "cmax": 4,
                            "showscale": col == 2,
                            "colorbar": {"title": "log10 corpus"}},
                    error_y=_error_bars(sel, key),
                    text=[f"{q['index']} corpus {q['corpus']} K={q['k']}" + _noise_note(q)
                          for q in sel],
                    row=1, col=col)
        front = pareto([q for q in pts if q["system"] == "RA-Touch"], key)
        fig.add_scatter(x=[q["p50_ms"] for q in front], y=[q[key] for q in front],
                        mode="lines", name="frontier", line={"color": "grey", "dash": "dot"},
                        showlegend=col == 1, legendgroup="frontier", row=1, col=col)
        up = result["upstream"]
        if up.get(key) is not None:
            fig.add_scatter(x=[up["p50_ms"]], y=[up[key]], mode="markers+text",
                            text=["upstream"], textposition="top center",
                            marker={"symbol": "x", "size": 12, "color": "red"},
                            name="upstream retrieval", showlegend=col == 1, row=1, col=col)
        if key == "precision_at_5":
            enc = [q for q in pts if q["system"].startswith("retrieval only")]
            if enc:
                fig.add_scatter(x=[q["p50_ms"] for q in enc], y=[q[key] for q in enc],
                                mode="markers+text", text=[q["encoder"] for q in enc],
                                textposition="bottom center", name="other encoders "
                                "(tactile->text, no generator)",
                                marker={"symbol": "triangle-up", "size": 10, "color": "black"},
                                row=1, col=col)
        else:
            fig.add_hline(y=result["baseline_judge"], line_dash="dash", line_color="black",
                          annotation_text="baseline (no retrieval)", row=1, col=col)
    fig.update_xaxes(type="log", title="p50 latency per query, ms (warm, 1 thread)")
    fig.update_layout(title="Speed against accuracy (marker size = K, colour = corpus size; "
                            "bars: 95 % CIs)",
                      template="plotly_white", height=500, width=1100,
                      legend={"orientation": "h", "y": -0.22})
    return fig


def _error_bars(points: Sequence[dict], key: str) -> dict | None:
    """Plotly error bars from each point's 95 % CI of `key` (None where none was measured)."""
    cis = [q.get(f"{key}_ci") for q in points]
    if any(ci is None for ci in cis):
        return None
    return {"type": "data", "symmetric": False, "thickness": 1,
            "array": [ci[1] - q[key] for q, ci in zip(points, cis)],
            "arrayminus": [q[key] - ci[0] for q, ci in zip(points, cis)]}


def _noise_note(q: dict) -> str:
    d = q.get("judge_vs_reference")
    if not d:
        return ""
    return (f"<br>judge vs reference {d['diff']:+.3f} [{d['ci'][0]:+.3f}, {d['ci'][1]:+.3f}]"
            + (" (inside the noise)" if d["within_noise"] else ""))


def format_tradeoff(result: dict) -> str:
    """The points as a table: latency, the judge with its 95 % CI, F1, length, P@5 with its
    CI, and the judge difference to the reference point (`~` where it is inside the noise)."""
    lines = [f"{'encoder':<13}{'index':<9}{'corpus':>7}{'K':>4}{'p50 ms':>9}{'p95 ms':>9}"
             f"{'search':>9}  {'judge [95% CI]':<24}{'F1':>6}{'len':>5}  {'P@5 [95% CI]':<22}"
             f"{'vs ref':>8}  system"]
    for q in result["points"] + [result["upstream"]]:
        judge = (f"{q['judge']:.3f} [{q['judge_ci'][0]:.3f}, {q['judge_ci'][1]:.3f}]"
                 if q.get("judge") is not None else "-")
        f1 = f"{q['f1']:.3f}" if q.get("f1") is not None else "-"
        length = f"{q['mean_length']:.1f}" if q.get("mean_length") is not None else "-"
        prec = (f"{q['precision_at_5']:.3f} [{q['precision_at_5_ci'][0]:.3f}, "
                f"{q['precision_at_5_ci'][1]:.3f}]" if q.get("precision_at_5") is not None
                else "-")
        srch = f"{q['search_p50_ms']:.3f}" if q.get("search_p50_ms") is not None else "-"
        d = q.get("judge_vs_reference")
        vs = f"{d['diff']:+.3f}{'~' if d['within_noise'] else '*'}" if d else "-"
        lines.append(f"{q['encoder']:<13}{q['index']:<9}{q['corpus']:>7}{q['k']:>4}"
                     f"{q['p50_ms']:>9.2f}{q['p95_ms']:>9.2f}{srch:>9}  {judge:<24}{f1:>6}"
                     f"{length:>5}  {prec:<22}{vs:>8}  {q['system']}")
    b = result.get("baseline") or {"judge": result["baseline_judge"]}
    lines.append(f"baseline (no retrieval) judge: {b['judge']:.3f}"
                 + (f" [{b['judge_ci'][0]:.3f}, {b['judge_ci'][1]:.3f}], F1 {b['f1']:.3f}, "
                    f"{b['mean_length']:.1f} adj" if "judge_ci" in b else ""))
    if result.get("reference"):
        r = result["reference"]
        lines.append(f"vs ref: judge difference to the {r['index']} index over the whole corpus "
                     f"({r['corpus']}) at K={r['k']}, paired per test sample; ~ = its 95 % CI "
                     f"holds 0 (inside the noise), * = it does not")
    return "\n".join(lines)

"""Speed against accuracy: which differences the chart marks as inside the noise."""

from __future__ import annotations

import numpy as np
import pytest

from ratouch.bench.tradeoff import _mark_noise, format_tradeoff, pareto, tradeoff_figure


def _point(index, corpus, k, judge, p50):
    return {"encoder": "default-s", "index": index, "corpus": corpus, "k": k, "p50_ms": p50,
            "p95_ms": p50 + 1, "search_p50_ms": 0.5, "judge": judge,
            "judge_ci": [judge - 0.1, judge + 0.1], "f1": 0.6, "mean_length": 3.4,
            "precision_at_5": 0.5, "precision_at_5_ci": [0.45, 0.55], "system": "RA-Touch"}


def test_differences_to_the_served_point_are_marked_inside_or_outside_the_noise():
    rng = np.random.default_rng(0)
    ref = rng.uniform(6, 9, 400)
    points = [_point("flat", 10000, 5, 8.0, 40.0), _point("hnsw", 10000, 5, 8.0, 30.0),
              _point("flat", 1000, 5, 8.3, 20.0)]
    scores = [ref, ref + rng.normal(0, 0.3, 400), ref + 0.3 + rng.normal(0, 0.3, 400)]
    assert _mark_noise(points, scores, 10000) == {"index": "flat", "corpus": 10000, "k": 5}
    marks = [q["judge_vs_reference"] for q in points]
    assert marks[0] == {"diff": 0.0, "ci": [0.0, 0.0], "within_noise": True}
    assert marks[1]["within_noise"] and marks[1]["ci"][0] < 0 < marks[1]["ci"][1]
    assert not marks[2]["within_noise"] and marks[2]["ci"][0] > 0.2
    assert _mark_noise([_point("hnsw", 1000, 1, 8.0, 1.0)], [ref], 10000) is None
    result = {"points": points, "upstream": {**points[0], "index": "upstream"},
              "baseline_judge": 7.9, "reference": {"index": "flat", "corpus": 10000, "k": 5}}
    table = format_tradeoff(result)
    assert "+0.000~" in table and "*" in table.splitlines()[3]
    assert [q["index"] for q in pareto(points, "judge")] == ["flat"]  # 20 ms, best judge
    fig = tradeoff_figure(result)
    # judge, F1 (no CI given here: no bars) and P@5 panels
    bars = [t.error_y for t in fig.data if t.name == "default-s flat"]
    np.testing.assert_allclose(bars[0].array, [0.1, 0.1])
    np.testing.assert_allclose(bars[2].arrayminus, [0.05, 0.05])


def test_cascade_and_other_encoders_are_marked_against_the_reference():
    rng = np.random.default_rng(1)
    ref = {"judge": rng.uniform(6, 9, 400), "f1": rng.uniform(0, 1, 400),
           "precision_at_5": rng.uniform(0, 1, 400)}
    points = [_point("flat", 10000, 5, 8.0, 40.0)]
    tiny = {**_point("flat", 10000, 5, 7.9, 30.0), "encoder": "default-tiny"}
    worse = {k: v - 0.2 for k, v in ref.items()}
    assert _mark_noise(points + [tiny], [ref, worse], 10000) is not None
    assert not tiny["f1_vs_reference"]["within_noise"]
    assert tiny["precision_at_5_vs_reference"]["diff"] == -0.2
    cascade = {**_point("flat", 10000, 5, 8.0, 45.0), "encoder": "cascade: default-tiny > default-s",
               "system": "RA-Touch, cascade", "escalated": 0.25, "measure": "agreement",
               "thresholds": [0.6], "judge_vs_reference": {"diff": 0.0, "ci": [-0.1, 0.1],
                                                           "within_noise": True}}
    result = {"points": points + [tiny, cascade], "upstream": {**points[0], "index": "upstream"},
              "baseline_judge": 7.9, "settings": {"encoder": "default-s"}}
    table = format_tradeoff(result)
    assert "25.0% escalated, agreement >= 0.600: default-tiny > default-s" in table
    assert "-0.200*" in table and "+0.000~" in table
    fig = tradeoff_figure(result)
    # each named point is a trace of its own, in every panel of both rows, named once in
    # the legend, with a symbol and colour of its own
    named = {}
    for t in fig.data:
        if t.name in ("default-tiny", "cascade, 25% escalated"):
            named.setdefault(t.name, []).append(t)
    assert {k: len(v) for k, v in named.items()} == {"default-tiny": 6,
                                                     "cascade, 25% escalated": 6}
    assert [sum(bool(t.showlegend) for t in v) for v in named.values()] == [1, 1]
    looks = {(v[0].marker.symbol, v[0].marker.color) for v in named.values()}
    assert len(looks) == 2 and not any(t.text for v in named.values() for t in v)
    # the zoomed row spans the served sweep and the systems beside it
    lo, hi = fig.layout.xaxis4.range
    assert 10 ** lo < 30.0 and 10 ** hi > 45.0


def test_the_gated_point_is_labelled_on_the_chart_and_in_the_table():
    points = [_point("flat", 10000, 5, 8.0, 40.0)]
    gated = {**_point("flat", 10000, 5, 8.1, 42.0), "system": "RA-Touch, gated (reader)"}
    text = {**_point("flat", 10000, 5, 8.2, 45.0),
            "system": "RA-Touch, text (captions in the prompt)"}
    result = {"points": points + [gated, text], "upstream": {**points[0], "index": "upstream"},
              "baseline_judge": 7.9, "settings": {"encoder": "default-s"}}
    table = format_tradeoff(result)
    assert "RA-Touch, gated (reader)" in table and "RA-Touch, text (captions" in table
    names = [t.name for t in tradeoff_figure(result).data if t.showlegend]
    assert "default-s gated" in names and "default-s text" in names


@pytest.mark.slow
@pytest.mark.parametrize("system", ["gated", "text"])
def test_system_points_on_the_real_pipeline(real_pipeline, system):
    """A system's point on 12 test pairs: the reader (or the paper's generator) on the gated
    query's neighbours, or the text arm on the joint query's, judged, timed and compared with
    the reference point."""
    from types import SimpleNamespace

    from ratouch.bench.tradeoff import _raw_pairs, _system_point
    from ratouch.eval.judge import OfflineJudge
    from ratouch.world.splits import encode_test_split

    if system == "gated" and real_pipeline.gate is None:
        pytest.skip("no shipped touch gate")
    if system == "text" and real_pipeline.generator_text is None:
        pytest.skip("no shipped text arm")
    test = encode_test_split(real_pipeline.encoders, indices=range(12))
    lab = SimpleNamespace(pipeline=real_pipeline, test=test, judge=OfflineJudge(),
                          cfg=SimpleNamespace(encoder="default-s"))
    ref = {"judge": np.full(12, 7.0), "f1": np.full(12, 0.5), "precision_at_5": np.full(12, 0.5)}
    points = [_point("flat", len(real_pipeline.corpus), 5, 7.0, 40.0)]
    q = _system_point(lab, _raw_pairs(test, np.arange(4)), points, [ref], system)
    assert q is not None and q["system"].startswith(f"RA-Touch, {system}")
    assert 1 <= q["judge"] <= 10 and 0 <= q["precision_at_5"] <= 1 and q["p50_ms"] > 0
    assert "judge_vs_reference" in q


@pytest.mark.slow
def test_the_fallback_point_is_the_papers_with_the_look_check_timed(real_pipeline, monkeypatch):
    """`fallback` on 12 test pairs (none beyond every rendered unit): its quality is the
    paper's flat K=5 point's, its time is measured with the look check; where a test frame
    lies beyond the limit there is no point (its withheld answers are not built there)."""
    from types import SimpleNamespace

    from ratouch.bench import tradeoff
    from ratouch.eval.judge import OfflineJudge
    from ratouch.world.splits import encode_test_split

    test = encode_test_split(real_pipeline.encoders, indices=range(12))
    lab = SimpleNamespace(pipeline=real_pipeline, test=test, judge=OfflineJudge(),
                          cfg=SimpleNamespace(encoder="default-s"))
    paper = _point("flat", len(real_pipeline.corpus), 5, 7.25, 40.0)
    pairs = tradeoff._raw_pairs(test, np.arange(3))
    q = tradeoff._system_point(lab, pairs, [paper], [{}], "fallback")
    assert q is not None and q["system"].startswith("RA-Touch, fallback")
    assert all(q[key] == paper[key] for key in ("judge", "judge_ci", "f1", "precision_at_5"))
    assert q["p50_ms"] > 0 and q["index"] == "flat" and q["k"] == 5
    assert tradeoff._short(q) == "default-s fallback"
    monkeypatch.setattr(tradeoff, "beyond_every_unit", lambda frame: True)
    assert tradeoff._system_point(lab, pairs, [paper], [{}], "fallback") is None

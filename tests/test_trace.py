"""What retrieval did for one answer (`ratouch.serve.trace`): the words RA-Touch added or
dropped against the baseline, the neighbours the integrator attended to most, and which words
of the description their captions carry."""

from __future__ import annotations

import pytest

from ratouch.errors import DataError
from ratouch.serve.trace import marked_segments, trace_retrieval


def _result(ra: str, base: str, captions: list[str], image: list[float] | None,
            text: list[float] | None) -> dict:
    joint = [{"id": 100 + i, "score": 0.9 - i / 10, "class_name": f"class{i}", "caption": c,
              "description": c, "source": "world"} for i, c in enumerate(captions)]
    attention = {k: v for k, v in (("image", image), ("text", text)) if v is not None}
    return {"neighbours": {"image": [], "tactile": [], "joint": joint},
            "description": {"ra_touch": ra, "baseline": base}, "attention": attention}


def test_most_attended_neighbours_and_the_words_they_carry():
    result = _result("Soft, slightly fuzzy and plush.", "soft, fuzzy, plush",
                     ["hard, smooth.", "fuzzy, soft, warm", "plush, soft", "rough"],
                     image=[0.1, 0.5, 0.3, 0.1], text=[0.1, 0.3, 0.5, 0.1])
    trace = trace_retrieval(result, top=2)
    assert trace is not None
    assert trace.same_words and trace.added == () == trace.dropped
    assert trace.ra_words == ("soft", "fuzzy", "plush")
    # neighbours 2 and 3 hold 0.4 each (image and text averaged), well above 1/4
    assert [a.rank for a in trace.attended] == [2, 3]
    assert [a.id for a in trace.attended] == [101, 102]
    assert trace.attended[0].weight == pytest.approx(0.4) and trace.even_share == 0.25
    assert trace.attended[0].words == ("soft", "fuzzy")
    assert trace.carried == {"soft": (2, 3), "fuzzy": (2,), "plush": (3,)}
    assert not trace.nearly_even  # 0.4 is 1.6 even shares


def test_words_that_differ_from_the_baseline():
    result = _result("hard, ridged", "hard, smooth, flat", ["ridged, grooved", "soft"],
                     image=[0.7, 0.3], text=[0.6, 0.4])
    trace = trace_retrieval(result)
    assert not trace.same_words
    assert trace.added == ("ridged",) and trace.dropped == ("smooth", "flat")
    assert trace.carried == {"ridged": (1,)} and trace.in_neighbours == ("ridged",)
    assert len(trace.attended) == 2  # top=3 but only two neighbours


def test_no_integrator_attention_means_even_shares_in_retrieval_order():
    trace = trace_retrieval(_result("soft", "soft", ["a", "b", "c"], None, None), top=2)
    assert [a.rank for a in trace.attended] == [1, 2]
    assert all(a.weight == pytest.approx(1 / 3) for a in trace.attended)
    assert trace.nearly_even


def test_no_description_or_no_neighbours_gives_no_trace():
    assert trace_retrieval(_result("", "", ["soft"], [1.0], [1.0])) is None
    assert trace_retrieval(_result("soft", "soft", [], None, None)) is None


def test_attention_of_the_wrong_length_is_an_error():
    with pytest.raises(DataError, match="2 weights for 3 joint neighbours"):
        trace_retrieval(_result("soft", "soft", ["a", "b", "c"], [0.5, 0.5], None))
    with pytest.raises(DataError, match="top must be at least 1"):
        trace_retrieval(_result("soft", "soft", ["a"], None, None), top=0)


def test_marked_segments_spell_the_text_and_mark_whole_words():
    text = "Soft, slightly soft-ish and fuzzy."
    pieces = marked_segments(text, {"soft": (2,), "fuzzy": (1, 3), "absent": (1,)})
    assert "".join(p for p, _ in pieces) == text
    assert [p for p, r in pieces if r] == ["Soft", "fuzzy"]
    assert dict(pieces)["fuzzy"] == (1, 3)
    assert marked_segments("hard", {}) == [("hard", ())]


def test_the_gated_system_says_who_read_and_how_far_touch_was_trusted():
    from app.view import retrieval_md, touch_md

    result = _result("soft, fuzzy", "hard", ["soft, fuzzy"], [1.0], [1.0])
    result["neighbours"]["gated"] = result["neighbours"].pop("joint")
    result["retrieval"] = {"system": "gated", "reads": "gated", "generator": "reader",
                           "touch_weight": 0.12, "why": ["touch looks unlike the renders",
                                                         "the reader answers"]}
    trace = trace_retrieval(result)
    assert trace is not None and trace.generator == "reader" and trace.touch_weight == 0.12
    text = touch_md(trace)
    assert "with the reader" in text and "12%" in text and "the reader answers" in text
    result["retrieval"]["generator"] = "paper"
    assert "with the paper's generator" in touch_md(trace_retrieval(result))
    result["neighbours"]["joint"] = result["neighbours"].pop("gated")
    result["retrieval"] = {"system": "text", "reads": "joint", "generator": "text",
                           "touch_weight": 0.4, "why": ["captions in the prompt"]}
    text_trace = trace_retrieval(result)
    assert text_trace is not None and text_trace.touch_weight == 1.0   # the joint query
    assert "as text, their captions in the prompt" in touch_md(text_trace)
    assert "no integrator weighs them" in retrieval_md(text_trace)
    assert "integrator's attention" not in retrieval_md(text_trace)
    assert "- joint #1 · class0" in retrieval_md(text_trace)  # no attention share to show
    del result["retrieval"]["generator"]       # an answer from before the reader says nothing
    assert trace_retrieval(result).generator == ""


def _answer(regime: str | None, background: bool = True, adapted: bool = True) -> dict:
    firmness = None if regime is None else {"soft": 0.8, "reads": "soft", "regime": regime}
    return {"trust": {"tactile": {"background": background, "firmness": firmness}},
            "neighbours": {"tactile": [{"caption": "hard, smooth"}],
                           "adapted": [{"caption": "soft, woven"}] if adapted else []}}


def test_touch_reading_follows_the_press_regime():
    """docs/geometry.md, "The touch-only reading routed by the press's regime": an everyday
    press read against its background is read by the adapted query, a firm one, a frame
    without a background (no router) or an answer without adapted neighbours by the paper's
    tactile query."""
    from ratouch.serve.trace import touch_reading

    assert touch_reading(_answer("everyday")) == {"caption": "soft, woven", "query": "adapted",
                                                  "regime": "everyday", "by": "shape"}
    assert touch_reading(_answer("world")) == {"caption": "hard, smooth", "query": "tactile",
                                               "regime": "world", "by": "shape"}
    # no background: the shape's firmness is not read; the embedding's router is
    assert touch_reading(_answer("everyday", background=False))["query"] == "tactile"
    alone = _answer(None, background=False)
    alone["trust"]["tactile"]["press_regime"] = {"everyday": 0.8, "regime": "everyday"}
    assert touch_reading(alone) == {"caption": "soft, woven", "query": "adapted",
                                    "regime": "everyday", "by": "embedding"}
    alone["trust"]["tactile"]["press_regime"] = {"everyday": 0.2, "regime": "world"}
    assert touch_reading(alone)["query"] == "tactile"
    # with a background the embedding's router is not read
    both = _answer("world")
    both["trust"]["tactile"]["press_regime"] = {"everyday": 0.8, "regime": "everyday"}
    assert touch_reading(both)["query"] == "tactile"
    assert touch_reading(_answer(None)) == {"caption": "hard, smooth", "query": "tactile",
                                            "regime": None, "by": None}
    assert touch_reading(_answer("everyday", adapted=False))["caption"] == "hard, smooth"
    assert touch_reading({"neighbours": {}}) == {"caption": "", "query": "tactile",
                                                 "regime": None, "by": None}

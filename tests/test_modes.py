"""The query-mode registry: a mode registered in one place (here, inside the test) is answered
by the pipeline, printed in the JSON, shown in the app's galleries and plot, and reported in
the stress report's columns; a bad or unknown mode is an error that names it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ratouch.errors import ConfigError
from ratouch.search.modes import QUERY_MODES, RA_TOUCH_MODE, QueryMode


def _mean(V, T, joint_query):
    q = V + T  # (N, D): halfway between the two embeddings, on the unit sphere
    return q / np.linalg.norm(q, axis=1, keepdims=True)


MEAN = QueryMode("mean", "Mean of image and tactile", "M", "#9467bd",
                 frozenset({"image", "tactile"}), _mean)


@pytest.fixture
def mean_mode():
    QUERY_MODES.register(MEAN)
    try:
        yield MEAN
    finally:
        QUERY_MODES.unregister(MEAN.name)


def test_built_in_modes_and_their_rows():
    assert list(QUERY_MODES) == ["image", "tactile", "joint", "gated", "adapted"]
    assert RA_TOUCH_MODE == "joint"
    assert QUERY_MODES.needing_touch() == ("tactile", "joint", "gated", "adapted")
    assert "".join(QUERY_MODES[m].letter for m in QUERY_MODES) == "ITJGA"
    with pytest.raises(ConfigError, match="'both'"):
        QUERY_MODES["both"]
    with pytest.raises(ConfigError, match="already registered"):
        QUERY_MODES.register(QUERY_MODES["image"])
    with pytest.raises(ConfigError, match="letter 'I'"):
        QUERY_MODES.register(QueryMode("other", "x", "I", "#000000", frozenset({"image"}),
                                       _mean))
    with pytest.raises(ConfigError, match="built in"):
        QUERY_MODES.unregister("joint")
    with pytest.raises(ConfigError, match="needs"):
        QueryMode("bad", "x", "B", "#000000", frozenset({"sound"}), _mean)
    with pytest.raises(ConfigError, match="colour"):
        QueryMode("bad", "x", "B", "red", frozenset({"image"}), _mean)
    with pytest.raises(ConfigError, match="needs tactile"):
        QUERY_MODES["tactile"].vectors(np.zeros((1, 4), np.float32), None, None)


def test_a_registered_mode_reaches_the_pipeline_json_and_app(mean_mode, debug_pipeline, world):
    from app import view
    from app.plot import pca_figure
    from ratouch.search.retrieval import retrieval_settings

    s = world.sample("test", 3)
    r = debug_pipeline.query(s.visual, s.tactile, box=s.box, k=4)
    assert list(r["neighbours"]) == ["image", "tactile", "joint", "gated", "adapted", "mean"]
    enc = debug_pipeline.encoders
    crop = s.visual[s.box[1]:s.box[3], s.box[0]:s.box[2]]
    q = _mean(enc.encode_image([crop]), enc.encode_tactile([s.tactile]), None)
    ids = debug_pipeline.corpus.search("text", q.astype(np.float32), 4)[1][0]
    assert [n["id"] for n in r["neighbours"]["mean"]] == ids.tolist()
    assert "mean" in json.loads(json.dumps(r))["neighbours"]
    assert {"query_mean", "neighbour_mean"} <= {p["role"] for p in r["pca"]["points"]}
    # without a frame the mode, which needs one, is left out like the tactile and joint ones
    alone = debug_pipeline.query(s.visual, None, box=s.box, k=4)
    assert list(alone["neighbours"]) == ["image"]
    # the app: one gallery per mode, its header, letter and colour from the row
    assert list(view.MODES) == ["image", "tactile", "joint", "gated", "adapted", "mean"]
    strips = [view.neighbour_strip(r, m, lambda i: np.zeros((2, 2, 3), np.uint8))
              for m in view.MODES]
    assert len(strips) == len(view.MODES) and "<figure" in strips[-1]
    assert "Mean of image and tactile" in view.mode_header("mean")
    assert view.MODE_COLOUR["mean"] == "#9467bd" and view.MODE_LETTER["mean"] == "M"
    assert "mean query" in {t.name for t in pca_figure(r).data}
    assert "mean_text" in retrieval_settings()


def test_a_registered_mode_is_a_stress_report_column(mean_mode, debug_pipeline):
    from ratouch.eval.stress import build_sweeps, format_table, run_stress
    from ratouch.eval.stress.report import format_markdown

    result = run_stress(debug_pipeline, build_sweeps(["missing"]), k=3, n=4, collapse=False,
                        encoder="debug")
    assert set(result["reference"]["retrieval"]) == {"image", "tactile", "joint", "gated", "adapted",
                                                   "mean"}
    missing = result["knobs"]["missing"]
    assert "P@3 mean" in missing["break_points"] and "overlap mean" in missing["break_points"]
    # a missing frame: the mode needs one, so it falls back to the image query's neighbours
    point = missing["points"][1]
    assert point["retrieval"]["mean"]["material_precision"] == \
        point["retrieval"]["image"]["material_precision"]
    assert set(point["retrieval_no_fallback"]) == {"tactile", "joint", "gated", "adapted", "mean"}
    md = format_markdown(result, None, "not requested")
    assert "| P@3 mean " in md and "| overlap mean " in md and "| mean | " in md
    header = next(line for line in md.splitlines() if line.startswith("| value "))
    rule = md.splitlines()[md.splitlines().index(header) + 1]
    assert header.count("|") - 1 == rule.count("---")  # the columns and the rule agree
    assert "mean" in format_table(result).splitlines()[1]

"""`ratouch eval stress`: the sweep's structure and invariants on a few samples, the report
files, and clear errors that write nothing. Runs on the debug encoders, a 240-entry corpus,
random retrievers and fake generators (no training, no LLM), so it stays fast."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ratouch.errors import ConfigError
from ratouch.search.modes import QUERY_MODES


class FakeGenerator:
    """Describes from the inputs: a few TVL adjectives picked by the embedding's signs (and,
    for RA-Touch, the neighbours'), so a changed input can change the description."""

    def __init__(self, ra: bool):
        from ratouch.vocabulary import TVL_ADJECTIVES

        self.words = list(TVL_ADJECTIVES)[:16]
        self.ra = ra

    def describe(self, V, T, Rv=None, Rl=None):
        x = (V + T).numpy()
        if self.ra:
            x = x + Rl.numpy().mean(axis=1)
        return [", ".join(self.words[j] for j in np.argsort(-row[:16])[:3]) for row in x]


@pytest.fixture(scope="module")
def fake_pipeline(debug_encoders, small_corpus):
    import torch

    from ratouch.model.retriever import RetrieverConfig, TactileGuidedRetriever
    from ratouch.search.index import IndexConfig
    from ratouch.search.retrieval import CorpusIndex, CorpusSearch
    from ratouch.serve.pipeline import RATouchPipeline

    torch.manual_seed(0)
    tgr = TactileGuidedRetriever(RetrieverConfig(dim=debug_encoders.dim, cross_residual=True))
    index = CorpusIndex(small_corpus, debug_encoders.name, debug_encoders.dim,
                        IndexConfig(kind="flat"))
    return RATouchPipeline(CorpusSearch(debug_encoders, index), tgr.eval(), FakeGenerator(True),
                           FakeGenerator(False))


@pytest.fixture(scope="module")
def result(fake_pipeline):
    import torch

    from ratouch.eval.stress import build_sweeps, run_stress
    from ratouch.model.retriever import RetrieverConfig, TactileGuidedRetriever

    torch.manual_seed(1)
    align = TactileGuidedRetriever(RetrieverConfig(dim=384, cross_residual=True)).eval()
    sweeps = build_sweeps(["tactile_noise", "missing", "object_scale", "box_offset"],
                          {"tactile_noise": ["0.05", "0.2"], "object_scale": ["0.15"],
                           "box_offset": ["0.5"]})
    lines: list[str] = []
    r = run_stress(fake_pipeline, sweeps, k=5, n=8, align_tgr=align, encoder="debug",
                   progress=lines.append)
    r["_progress"] = lines
    return r


def test_structure_and_ranges(result):
    assert result["n"] == 8 and result["k"] == 5
    assert list(result["knobs"]) == ["tactile_noise", "missing", "object_scale", "box_offset"]
    labels = [p["label"] for p in result["knobs"]["tactile_noise"]["points"]]
    assert labels[1:] == ["0.05", "0.2"] and labels[0].startswith("natural (")
    # the label shows the natural mean at 3 significant digits, `natural_means` it rounded to 4 decimals
    assert float(labels[0][9:-1]) == pytest.approx(result["natural_means"]["tactile_noise"], abs=1e-4)
    assert [p["label"] for p in result["knobs"]["missing"]["points"]] == ["none", "tactile"]
    for knob in result["knobs"].values():
        assert knob["points"][0]["reference"] and not knob["points"][1]["reference"]
        for p in knob["points"]:
            for m in ("image", "tactile", "joint"):
                r = p["retrieval"][m]
                for key in ("material_precision", "adjective_overlap", "topk_overlap"):
                    assert 0.0 <= r[key] <= 1.0
            for s in ("baseline", "ra-touch"):
                g = p["generators"][s]
                assert 1.0 <= g["judge"] <= 10.0
                assert 0.0 <= g["identical"] <= 1.0 and 0.0 <= g["adj_jaccard"] <= 1.0
        assert set(knob["break_points"]) == {f"P@5 {m}" for m in QUERY_MODES} \
            | {"judge baseline", "judge ra-touch"} \
            | {f"overlap {m}" for m in QUERY_MODES}
    assert len(result["_progress"]) >= 5
    json.dumps(result)  # JSON-able


def test_reference_point_is_its_own_answer(result):
    for knob in result["knobs"].values():
        ref = knob["points"][0]
        assert all(ref["retrieval"][m]["topk_overlap"] == 1.0
                   for m in ("image", "tactile", "joint"))
        assert all(ref["generators"][s]["identical"] == 1.0 for s in ("baseline", "ra-touch"))
        assert ref["paired_labels"] == 1.0
        assert all(b["breaks_at"] is None or b["value_at_break"] < b["threshold"]
                   for b in knob["break_points"].values())


def test_pairing_and_fallback(result):
    # a fixed tactile noise is compared with the same scenes (knob at its natural value):
    # the labels, drawn after the knob, stay paired, and the image query does not move
    noise = result["knobs"]["tactile_noise"]
    assert noise["paired_reference"] == ["tactile_noise"]
    for p in noise["points"][1:]:
        assert p["paired_labels"] == 1.0
        assert p["retrieval"]["image"]["topk_overlap"] == 1.0
    # object_scale and box_offset change only the image: the tactile answer stays put
    for knob in ("object_scale", "box_offset"):
        p = result["knobs"][knob]["points"][1]
        assert p["paired_labels"] == 1.0 and p["retrieval"]["tactile"]["topk_overlap"] == 1.0
    assert result["knobs"]["box_offset"]["paired_reference"] == ["box_offset"]
    # missing tactile: tactile and joint fall back to the image query
    miss = result["knobs"]["missing"]
    assert miss["paired_reference"] == []
    p = miss["points"][1]
    assert p["retrieval"]["tactile"] == {**p["retrieval"]["image"],
                                         "topk_overlap": p["retrieval"]["tactile"]["topk_overlap"]}
    assert set(p["retrieval_no_fallback"]) == set(QUERY_MODES.needing_touch())


def test_scale_bins_and_collapse(result):
    bins = result["reference"]["scale_bins"]
    assert [b["bin"] for b in bins] == ["structured", "<0.2", "0.2-0.4", "0.4-0.7", ">=0.7"]
    assert sum(b["n"] for b in bins) == 8
    rows = result["collapse"]["rows"]
    assert {"full (shipped)", "align only"} <= set(rows)
    for name in ("full (shipped)", "align only"):
        assert 1.0 <= rows[name]["effective_rank"] <= 8.0
        assert -1.0 <= rows[name]["mean_cosine"] <= 1.0
        assert 0.0 <= rows[name]["material_precision"] <= 1.0


def test_report_files(result, tmp_path):
    import plotly.io as pio

    from ratouch.eval.stress import format_table, write_report

    paths = write_report(result, tmp_path / "rep", png=False)  # kaleido + Chromium: slow
    for kind in ("json", "md", "html", "fig", "overlap_fig"):
        assert (tmp_path / "rep").joinpath(paths[kind].split("/")[-1]).is_file()
    assert json.loads((tmp_path / "rep" / "stress.json").read_text())["n"] == 8
    fig = pio.from_json((tmp_path / "rep" / "stress_fig.json").read_text())
    assert len(fig.data) == 4 * (len(QUERY_MODES) + 2)  # 4 knobs x (modes + 2 generators)
    page = (tmp_path / "rep" / "stress.html").read_text()
    assert page.count('src="plotly.min.js"') == 1 and page.count("Plotly.newPlot") == 2
    assert "plotly.js v" in (tmp_path / "rep" / "plotly.min.js").read_text()[:400]  # js once
    md = (tmp_path / "rep" / "stress.md").read_text()
    assert "## Break points" in md and "tactile_noise" in md and "Collapse" in md
    assert "png" not in paths and "PNG: not requested" in md
    assert not list((tmp_path / "rep").glob(".*partial*"))
    table = format_table(result)
    assert "break points" in table and "align only" in table


def test_sweep_definitions_and_indices():
    from ratouch.eval.stress import KNOBS, build_sweeps, stratified_indices

    sweeps = build_sweeps()
    assert list(sweeps) == list(KNOBS)
    assert sweeps["paper_failure"] == [{"object_scale": 0.12, "background_dominance": 1.0,
                                        "clutter": 4}]
    assert build_sweeps(["clutter"], {"clutter": ["1", "3"]}) == {"clutter": [{"clutter": 1},
                                                                              {"clutter": 3}]}
    idx = stratified_indices(8)
    assert len(idx) == 8 == len(set(idx)) and idx == sorted(idx)
    assert sum(i < 46 for i in idx) == 1
    assert stratified_indices(None) == list(range(402)) == stratified_indices(500)
    for bad in (dict(knobs=["nope"]), dict(values={"object_scale": ["0.05"]}),
                dict(values={"clutter": ["many"]}), dict(values={"paper_failure": ["1"]}),
                dict(knobs=["clutter", "clutter"]), dict(values={"missing": ["none"]}),
                dict(knobs=["clutter"], values={"tactile_noise": ["0.1"]})):
        with pytest.raises(ConfigError):
            build_sweeps(**bad)


@pytest.mark.parametrize("argv, match", [
    (["--knobs", "object_scale,nope"], "unknown stress knob"),
    (["--values", "object_scale=0.01"], "object_scale"),
    (["--values", "tactile_noise"], "KNOB=V1"),
    (["--drop", "1.5"], "--drop"),
    (["--n", "1"], "at least 2"),
])
def test_cli_bad_arguments_write_nothing(tmp_path, capsys, argv, match):
    from ratouch.cli import main

    out = tmp_path / "rep"
    assert main(["eval", "stress", "--out", str(out), "--no-collapse", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err
    assert not out.exists()


def test_answer_split_is_what_every_evaluation_answers_with(fake_pipeline):
    """`answer_split`: a system's descriptions of a split (RA-Touch reading the neighbours of
    a query mode, of given ids or of given embeddings, with the pipeline's generator or
    another), judged as the TVL protocol judges them."""
    from ratouch.eval.answer import answer_split, describe, records_for
    from ratouch.eval.judge import OfflineJudge, judge_results
    from ratouch.search.retrieval import QUERY_MODES, mode_query
    from ratouch.world.splits import encode_test_split

    p, judge = fake_pipeline, OfflineJudge()
    split = encode_test_split(p.encoders, indices=range(0, 402, 50))
    base = answer_split(p, split, "baseline", judge=judge)
    assert base.ids is None and base.responses == describe(p.generator_base, split.V, split.T)
    rows, _ = judge_results(records_for(split, base.responses, "baseline"), judge)
    assert base.scores.tolist() == [r[judge.key] for r in rows]
    for mode in QUERY_MODES:
        q = mode_query(mode, split.V, split.T, p.joint_query)
        assert q.dtype == np.float32 and q.flags.c_contiguous
        ra = answer_split(p, split, "ra-touch", k=3, mode=mode, judge=judge)
        assert (ra.ids == p.corpus.search("text", q, 3)[1]).all()
        assert [r["neighbours"] for r in ra.records] == ra.ids.tolist()
        given = answer_split(p, split, "ra-touch", neighbours=p.neighbour_embeddings(ra.ids))
        assert given.responses == ra.responses and not given.scores.size and not given.records
    other = answer_split(None, split, "baseline", generator=p.generator_ra.__class__(False),
                         name="variant")
    assert other.name == "variant" and len(other.responses) == len(split.labels)
    with pytest.raises(ConfigError):
        answer_split(p, split, "ra_touch")
    with pytest.raises(ConfigError):
        mode_query("both", split.V, split.T, p.joint_query)


def test_stress_renders_encode_as_the_test_split_does(fake_pipeline):
    """The stress sweeps read each tactile frame against its sensor's background, as the test
    split (and the failure table built on it) does: with no stress they encode the same pairs
    into the same embeddings, and under a knob the frames change while the background of each
    frame is its own sensor's."""
    from ratouch.eval.stress.runner import _Renderer
    from ratouch.world.config import WorldConfig
    from ratouch.world.splits import encode_test_split

    enc, idx = fake_pipeline.encoders, [0, 60, 200, 350]
    stressed = _Renderer(WorldConfig()).split(enc, idx)
    plain = encode_test_split(enc, indices=idx)
    assert np.allclose(stressed.V, plain.V) and np.allclose(stressed.T, plain.T)
    assert stressed.families == plain.families and len(set(plain.families)) >= 2
    alone = enc.encode_tactile([_Renderer(WorldConfig()).base.sample("test", i).tactile
                                for i in idx])
    assert not np.allclose(alone, plain.T)  # the background is read, not ignored

"""The Gradio app: its handlers over a fake pipeline (same `query()` output as the real one,
the real input checks), the `/query` API through `gradio_client` against a real server on
127.0.0.1, and (slow, when the trained assets exist) the real pipeline on a small corpus."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import re
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from conftest import HAVE_ASSETS, FakePipeline, free_port
from ratouch.errors import DataError, RATouchError
from ratouch.images import tvl_contact_box
from ratouch.search.modes import QUERY_MODES

# the user's cache as it was before conftest isolated the tests from it (read at collection):
# the real-app load test serves the real default corpus from there
USER_CACHE = Path(os.environ.get("RATOUCH_CACHE", Path.home() / ".cache" / "ratouch"))


# ------------------------------------------------------------------------- the fake pipeline

@pytest.fixture
def fake():
    return FakePipeline()


@pytest.fixture(scope="module")
def pair_files(tmp_path_factory):
    """A world test pair written as PNGs (what a user would upload)."""
    from ratouch.world.sampler import World

    s = World().sample("test", 60)
    d = tmp_path_factory.mktemp("pair")
    Image.fromarray(s.visual).save(d / "visual.png")
    Image.fromarray(s.tactile).save(d / "tactile.png")
    return d / "visual.png", d / "tactile.png", s


def _plain(md: str) -> str:
    """A description block without its HTML marks (highlighted words, neighbour ranks)."""
    return re.sub(r"<sup>.*?</sup>|<[^>]+>", "", md)


def _thumb(i: int) -> np.ndarray:
    return np.zeros((8, 8, 3), np.uint8)


# ------------------------------------------------------------------------- the contact box

def test_two_clicks_on_the_preview_make_a_box_in_image_pixels(pair_files):
    from app import handlers

    visual, _, _ = handlers.upload_visual(str(pair_files[0]))[:3]
    assert visual.size == (128, 128) and visual.scale == 4.0  # 128 px shown at 512
    visual, preview, *fields, note = handlers.click_box(visual, 41, 402, (None,) * 4)
    assert fields == [None] * 4 and "opposite corner" in note
    assert preview.shape == (512, 512, 3)
    visual, preview, *fields, note = handlers.click_box(visual, 300, 81, fields)
    assert fields == [10, 20, 76, 101]  # both clicked pixels inside, corners in any order
    assert "Contact box [10, 20, 76, 101]" in note and visual.corner is None
    # the box is drawn in red on the preview, not on the original the query gets
    assert tuple(preview[81 + 40, 40]) == (230, 30, 30)
    assert visual.source == str(pair_files[0])


def test_typed_box_is_drawn_and_used_by_the_query(fake, pair_files):
    from app import handlers

    visual = handlers.upload_visual(str(pair_files[0]))[0]
    visual, preview, note = handlers.typed_box(visual, 5, 6, 50, 60)
    assert tuple(preview[6 * 4 + 1, 20 * 4]) == (230, 30, 30) and "[5, 6, 50, 60]" in note
    v = handlers.run_query(fake, _thumb, visual, str(pair_files[1]), 5, 6, 50, 60, 3)
    assert fake.calls[-1]["box"] == [5, 6, 50, 60] and fake.calls[-1]["k"] == 3
    assert "contact box [5, 6, 50, 60]" in v.status


def test_default_box_when_none_is_marked(fake, pair_files):
    from app import handlers

    visual, preview, *fields, note = handlers.upload_visual(str(pair_files[0]))
    assert fields == [None] * 4 and "TVL's centred crop [48, 48, 81, 81]" in note
    v = handlers.run_query(fake, _thumb, visual, str(pair_files[1]), *fields, 5)
    assert fake.calls[-1]["box"] == list(tvl_contact_box(128, 128))
    assert "centred crop" in v.status  # the pipeline's warning is shown
    visual, preview, *fields, note = handlers.reset_box(handlers.typed_box(visual, 1, 2, 30, 40)[0])
    assert fields == [None] * 4 and "centred crop" in note


def test_an_image_given_as_an_array_is_previewed_not_a_stack_trace():
    """An API caller may send the visual as an array where the page sends a file: it is
    read as one, named as an array (there is no file name to show)."""
    from app import handlers

    visual, preview, *fields, note = handlers.upload_visual(np.full((40, 60, 3), 128, np.uint8))
    assert visual is not None and visual.title == "uploaded image (an array)"
    assert fields == [None] * 4 and "✖" not in note and "centred crop" in note


def test_example_pair_brings_its_box_label_and_tactile(fake, world):
    from app import handlers

    visual, preview, tactile, background, *fields, note = handlers.load_example(world, 7)
    s = world.sample("test", 7)
    assert fields == list(s.box) and visual.label == s.caption and s.caption in note
    assert np.array_equal(tactile, s.tactile)
    # the sensor's no-contact frame fills the optional field, as TVL rows carry one
    assert np.array_equal(background, world.background_image(s.sensor))
    from ratouch.eval.failures import judge_scores
    from ratouch.eval.judge import OfflineJudge

    judge = OfflineJudge()
    v = handlers.run_query(fake, _thumb, visual, tactile, *fields, 5, judge=judge)
    assert fake.calls[-1]["label"] == s.caption
    assert f"Ground-truth label:** {s.caption}" in v.description
    # both descriptions carry the offline judge's score against the label
    scores = judge_scores(s.caption, {"ra_touch": "soft and grainy", "baseline": "smooth"},
                          judge)
    assert f"soft and grainy · judge **{scores['ra_touch']:.1f}**/10" in _plain(v.description)
    assert "soft</mark>" in v.description  # a word its neighbours carry, marked
    assert f"smooth · judge **{scores['baseline']:.1f}**/10" in _plain(v.description)
    assert any(t.name == "ground truth" for t in v.plot.data)
    assert "test example #7" in v.status
    assert "out of range" in handlers.load_example(world, 10_000)[-1]
    assert "no test example" in handlers.load_example(world, None)[-1]


# ------------------------------------------------------------------------- the query view

def test_query_view_marks_neighbours_that_modes_share(fake, pair_files):
    from app import handlers

    visual = handlers.upload_visual(str(pair_files[0]))[0]
    v = handlers.run_query(fake, _thumb, visual, str(pair_files[1]), None, None, None, None, 5)
    strips = v.galleries
    assert all(s.count("<figure") == 5 for s in strips.values())
    assert "Image query" in strips["image"] and "Joint query" in strips["joint"]
    assert "<span class='ra-badge'>1 · 0.90</span>" in strips["image"]  # id 0: image only
    assert "also found by the joint query" in strips["image"]  # id 1: image and joint
    assert ">I·T·J</span>" in strips["image"]  # id 2: all three
    assert v.tables["joint"].count("◆◆ I·T·J") == 3
    assert {t.name for t in v.plot.data} >= {"image query", "joint neighbours"}
    assert "RA-Touch (with retrieval):** <mark class='ra-carried'" in v.description
    assert "What retrieval did:" in v.description and "Read most" in v.description
    assert strips["joint"].count("ra-attended") == 3  # the three it read most, outlined
    assert "total 3 ms" in v.timings and v.raw["box"] == [48, 48, 81, 81]


def test_no_tactile_image_gives_an_honest_image_only_view(fake, pair_files):
    from app import handlers

    visual = handlers.upload_visual(str(pair_files[0]))[0]
    v = handlers.run_query(fake, _thumb, visual, None, None, None, None, None, 5)
    assert v.galleries["image"].count("<figure") == 5 and "<figure" not in v.galleries["joint"]
    assert "not available" in v.galleries["tactile"]
    assert v.status.startswith("**Image-only query** (no tactile image)")
    assert "image-only retrieval" in v.status and "not available" in v.tables["tactile"]
    assert "needs a tactile image" in v.description
    assert "judge" not in v.description  # no label, no scores


def _bytes_file(tmp_path: Path, name: str, data: bytes) -> str:
    p = tmp_path / name
    p.write_bytes(data)
    return str(p)


def _png(arr: np.ndarray, mode: str | None = None, **save) -> bytes:
    buf = io.BytesIO()
    (Image.fromarray(arr, mode) if mode else Image.fromarray(arr)).save(buf, "PNG", **save)
    return buf.getvalue()


def test_bad_uploads_give_messages_not_exceptions(fake, pair_files, tmp_path):
    from app import handlers

    good = handlers.upload_visual(str(pair_files[0]))[0]
    text = _bytes_file(tmp_path, "notes.png", b"this is not an image")
    png = _png(np.full((64, 64, 3), 120, np.uint8))
    truncated = _bytes_file(tmp_path, "cut.png", png[: len(png) // 2])
    tiny = _bytes_file(tmp_path, "tiny.png", _png(np.zeros((4, 4, 3), np.uint8)))
    for path in (text, truncated, tiny):
        state, preview, *fields, note = handlers.upload_visual(path)
        assert state is None and preview is None and note.startswith("✖"), (path, note)
    assert "4x4" in handlers.upload_visual(tiny)[-1]
    # a bad tactile file, a missing upload, bad boxes: the query view says why
    cases = [(good, text, (None,) * 4, "tactile image notes.png as an image"),
             (good, str(pair_files[1]), (50, 50, 10, 10), "empty or inverted"),
             (good, str(pair_files[1]), (10, 10, 10, 40), "empty or inverted"),
             (good, str(pair_files[1]), (500, 500, 600, 600), "outside"),
             (good, str(pair_files[1]), (1, 2, None, None), "all four"),
             (None, str(pair_files[1]), (None,) * 4, "upload a visual image")]
    for visual, tactile, box, expected in cases:
        v = handlers.run_query(fake, _thumb, visual, tactile, *box, 5)
        assert v.status.startswith("**✖") and expected in v.status, (box, v.status)
        assert v.galleries["image"] == "" and v.raw is None
    assert "outside" in handlers.typed_box(good, 500, 500, 600, 600)[-1]


def test_awkward_but_valid_images_are_accepted(fake, tmp_path):
    """Grayscale, RGBA, 16-bit, EXIF-rotated and 20-megapixel uploads all load."""
    from app import handlers

    grey = _bytes_file(tmp_path, "grey.png", _png(np.tile(np.arange(64, dtype=np.uint8), (48, 1))))
    rgba = np.zeros((48, 64, 4), np.uint8)
    rgba[..., 3] = 128
    rgba_f = _bytes_file(tmp_path, "rgba.png", _png(rgba))
    deep = _bytes_file(tmp_path, "deep.png",
                       _png(np.full((48, 64), 60000, np.uint16), mode="I;16"))
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90 degrees clockwise when shown
    buf = io.BytesIO()
    Image.new("RGB", (64, 48), (200, 10, 10)).save(buf, "JPEG", exif=exif)
    rotated = _bytes_file(tmp_path, "rotated.jpg", buf.getvalue())
    big = tmp_path / "big.jpg"
    Image.new("RGB", (5472, 3648), (90, 120, 60)).save(big, quality=70)  # 20 megapixels
    for path, size in ((grey, (64, 48)), (rgba_f, (64, 48)), (deep, (64, 48)),
                       (rotated, (48, 64)), (str(big), (5472, 3648))):
        visual, preview, *_, note = handlers.upload_visual(path)
        assert visual is not None and visual.size == size, (path, note)
        assert max(preview.shape[:2]) == 512 and preview.shape[2] == 3
        v = handlers.run_query(fake, _thumb, visual, path, None, None, None, None, 2)
        assert not v.status.startswith("**✖"), v.status
    # the query is decoded from the original, not from the preview
    assert fake.calls[-1]["box"] == list(tvl_contact_box(5472, 3648))


def test_unexpected_errors_are_logged_not_shown(pair_files, caplog):
    from app import handlers

    class Broken(FakePipeline):
        def answer(self, requests):
            raise KeyError("bug")

    visual = handlers.upload_visual(str(pair_files[0]))[0]
    v = handlers.run_query(Broken(), _thumb, visual, None, None, None, None, None, 5)
    assert "internal error (KeyError)" in v.status and "Traceback" not in v.status
    assert "unexpected error" in caplog.text


def test_importing_the_app_loads_no_model_and_main_has_the_options():
    import subprocess
    import sys

    code = "import app, sys; print('gradio' in sys.modules, 'torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parents[1], check=True).stdout
    assert out.split() == ["False", "False"]
    from app import main

    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    for bad in (["--batch-workers", "0"], ["--model-processes", "-1"]):
        with pytest.raises(SystemExit) as e:  # refused before any model loads or port opens
            main([*bad, "--port", "1"])
        assert e.value.code == 2


# ------------------------------------------------------------------------- failure cases tab

def _case(cond: str, i: int, subset: str, ra: float, base: float, pi: float, pt: float,
          pj: float) -> dict:
    best = max(pi, pt)
    return {"condition": cond, "index": i, "subset": subset, "material": "wool",
            "object_scale": 0.5, "label": "soft, fuzzy", "baseline": "soft",
            "ra_touch": "hard", "baseline_score": base, "ra_score": ra,
            "ra_delta": ra - base, "precision_image": pi, "precision_tactile": pt,
            "precision_joint": pj, "best_unimodal": best, "joint_gap": best - pj,
            "joint_loses": pj < best,
            # modes after the first three (the gated query, a test's): the joint's precision
            **{f"precision_{m}": pj for m in list(QUERY_MODES)[3:]}}


TABLE = {"meta": {"k": 5, "n_rows": 4, "conditions": {"natural": {}, "noisy touch": {}},
                  "computed_at": "2025-01-01 00:00:00", "seconds": 61.0},
         "rows": [_case("natural", 3, "structured", 2.0, 6.0, 0.8, 0.2, 0.4),
                  _case("natural", 80, "wild", 7.0, 7.0, 0.2, 0.2, 0.6),
                  _case("noisy touch", 80, "wild", 1.5, 2.0, 0.4, 0.0, 0.0),
                  _case("noisy touch", 90, "wild", 9.0, 8.0, 0.0, 0.0, 0.2)]}


def test_failure_table_filters_and_views():
    from app import handlers
    from ratouch.eval.failures import VIEWS

    v = handlers.failure_view(TABLE, "all", "all", VIEWS["ra_lowest"])
    assert list(v.cases["#"]) == [80, 3, 80, 90]
    assert list(v.cases["condition"])[:2] == ["noisy touch", "natural"]
    assert list(v.cases.columns[:2]) == ["condition", "#"]  # what a row click reads
    assert "Showing 4 of 4 cases" in v.status and "click a row" in v.status
    assert list(v.summary["subset"]) == ["all", "structured", "wild", "all"]
    assert list(v.summary["joint loses"]) == ["50%", "100%", "0%", "50%"]
    v = handlers.failure_view(TABLE, "wild", "all", VIEWS["joint_loses"])
    assert list(v.cases["#"]) == [80] and list(v.cases["condition"]) == ["noisy touch"]
    v = handlers.failure_view(TABLE, "all", "natural", VIEWS["joint_loses"], limit=1)
    assert list(v.cases["#"]) == [3] and "Showing 1 of 1" in v.status
    assert set(v.summary["condition"]) == {"natural"}
    assert handlers.failure_view(TABLE, "indoor", "all", VIEWS["ra_lowest"]).status \
        .startswith("✖")
    none = handlers.failure_view(None, "all", "all", VIEWS["ra_lowest"])
    assert "not been computed" in none.status and none.cases is None


def test_failure_tab_names_each_query_mode_once():
    """The tab's text lists every registered mode by its title, once, in a list that a
    title with a comma of its own ("tactile query, adapted to everyday presses") does not
    split."""
    import re

    from app import failure_tab, view

    about = failure_tab.about_md(["natural"])
    listed = re.search(r"each query mode \((.*?)\) retrieves", about.replace("\n", " "))
    assert listed is not None, about
    names = listed.group(1).split("; ")
    assert names == [view.MODE_TITLE[m].split(" (")[0].lower() for m in view.MODES]
    assert len(set(names)) == len(view.MODES)
    assert "tactile query, adapted to everyday presses" in names


def test_failure_tab_reads_the_cache_and_computes_only_on_request(fake, monkeypatch):
    from app import handlers
    from ratouch.eval import failures

    opts = {"k": 5, "conditions": ("natural",), "indices": [0, 1]}
    shared: dict = {}
    v = handlers.failures_tab(fake, opts, shared, False, "all", "all",
                              failures.VIEWS["ra_lowest"])
    assert "not been computed" in v.status and shared["table"] is None
    assert fake.calls == []
    # the fake corpus knows no materials: computing says why instead of raising
    v = handlers.failures_tab(fake, opts, shared, True, "all", "all",
                              failures.VIEWS["ra_lowest"])
    assert "cannot compute the failure table" in v.status and "material" in v.status
    v = handlers.failures_tab(fake, opts, shared, True, "all", "all",  # not again at once
                              failures.VIEWS["ra_lowest"])
    assert "computation failed" in v.status and "try again in 10 min" in v.status
    shared["failed_at"] -= handlers.FAILED_COMPUTE_PAUSE_S  # ten minutes later
    calls = []
    monkeypatch.setattr(failures, "load_or_compute",
                        lambda pipe, **kw: calls.append(kw) or TABLE)
    v = handlers.failures_tab(fake, opts, shared, True, "all", "all",
                              failures.VIEWS["ra_lowest"])
    assert calls[0]["cached_only"] is False and calls[0]["indices"] == [0, 1]
    assert shared["table"] is TABLE and len(v.cases) == 4
    handlers.failures_tab(fake, opts, shared, False, "all", "all", failures.VIEWS["ra_lowest"])
    assert len(calls) == 1  # loaded once per app


def test_opening_a_case_brings_its_stressed_inputs_and_label(fake):
    import gradio as gr

    from app import handlers
    from ratouch.eval.failures import case_sample, case_world
    from ratouch.eval.judge import OfflineJudge
    from ratouch.world.config import WorldConfig

    visual, preview, tactile, background, *box, note = handlers.open_case(WorldConfig(),
                                                             ["noisy touch", 80, "wild"])
    s = case_sample("noisy touch", 80)
    assert np.array_equal(tactile, s.tactile) and box == list(s.box)
    assert np.array_equal(background, case_world("noisy touch").background_image(s.sensor))
    assert visual.label == s.caption and "noisy touch" in visual.title
    assert "condition **noisy touch**" in note
    v = handlers.run_query(fake, _thumb, visual, tactile, *box, 5, judge=OfflineJudge())
    assert fake.calls[-1]["label"] == s.caption and "judge **" in v.description
    v = handlers.run_query(fake, _thumb, visual, tactile, *box, 5)  # no judge: no scores
    assert "judge **" not in v.description
    for bad in (["fog", 1], ["natural", 402], ["natural"], None):
        with pytest.raises(gr.Error):
            handlers.open_case(WorldConfig(), bad)


class _Answering(FakePipeline):
    """The fake pipeline, answering with given descriptions (a failure case's)."""

    def __init__(self, description: dict):
        super().__init__()
        self.description = description

    def _answer(self, req):
        result = super()._answer(req)
        result.description = dict(self.description)
        return result

    def regenerate(self, *args, **kwargs) -> dict:
        out = super().regenerate(*args, **kwargs)
        out["description"] = {"ra_touch": self.description["ra_touch"]}
        return out


def test_a_case_shows_the_judge_score_of_its_table_row():
    """The failure table judges each system's answers together (with the system's word rates);
    a case opened from the table shows its row's scores, not those of a lone answer, in the
    description and in "take retrieval apart"."""
    from app import handlers, view
    from ratouch.eval import failures
    from ratouch.eval.judge import OfflineJudge
    from ratouch.world.config import WorldConfig
    from test_failures import CONDS, INDICES
    from test_failures import FakePipeline as FailurePipeline

    judge = OfflineJudge()
    rows = failures.failure_cases(FailurePipeline(), k=3, conditions=CONDS, indices=INDICES)
    frame = view.cases_frame(rows)
    for i in (0, 1, 3, 10):  # both conditions; structured and wild
        r, clicked = rows[i], frame.iloc[i].tolist()  # what a click on the row sends
        # judged alone, the answer would score otherwise: the check can fail
        assert (round(judge.score(r["label"], r["ra_touch"]), 3) != r["ra_score"]
                or round(judge.score(r["label"], r["baseline"]), 3) != r["baseline_score"])
        visual, _, tactile, bg, *box, _ = handlers.open_case(WorldConfig(), clicked)
        pipe = _Answering({"ra_touch": r["ra_touch"], "baseline": r["baseline"]})
        v = handlers.run_query(pipe, _thumb, visual, tactile, *box, 5, judge=judge)
        assert f"{r['ra_touch']} · judge **{r['ra_score']:.1f}**/10" in _plain(v.description)
        assert f"{r['baseline']} · judge **{r['baseline_score']:.1f}**/10" in _plain(v.description)
        assert failures.judge_scores(r["label"], v.raw["description"], judge,
                                     handlers.judged_descriptions(visual)) == \
            {"ra_touch": r["ra_score"], "baseline": r["baseline_score"]}
        ids = [n["id"] for n in v.raw["neighbours"]["joint"]]
        again = handlers.regenerate(pipe, visual, tactile, *box, ids, v.raw, judge)
        assert again.count(f"{r['ra_touch']} · judge **{r['ra_score']:.1f}**/10") == 2
    # a description the row did not judge (another box, another model) is judged alone
    visual = handlers.open_case(WorldConfig(), frame.iloc[1].tolist())[0]
    other = failures.judge_scores(rows[1]["label"], {"ra_touch": "soft, rubbery"}, judge,
                                  handlers.judged_descriptions(visual))
    assert other == {"ra_touch": round(judge.score(rows[1]["label"], "soft, rubbery"), 3)}


# ------------------------------------------------------------------------- benchmarks tab

def _figure_json(title: str) -> str:
    import plotly.graph_objects as go

    return go.Figure(go.Scatter(x=[1, 2], y=[3, 4]), layout_title_text=title).to_json()


def _bench(docs, slots):
    from app.benchmark_tab import benchmarks

    out = benchmarks(docs, slots)
    return out["report"], out["note"], *(out[f"figure_{i}"] for i in range(slots))


def test_a_chart_is_dated_by_what_its_maker_recorded_else_its_last_commit(tmp_path,
                                                                          monkeypatch):
    """The speed chart's label says when and at which commit `ratouch bench tradeoff` measured
    it (it had said the commit that last changed the file, which can come days later); a
    chart with nothing recorded is dated by its last commit."""
    import json

    from app import benchmark_tab
    from ratouch.eval import report

    figs = tmp_path / "figures"
    figs.mkdir()
    (figs / "tradeoff.json").write_text(_figure_json("speed vs accuracy"))
    (figs / "table1.json").write_text(_figure_json("main"))
    (figs / "tradeoff.data.json").write_text(json.dumps(
        {"made": {"utc": "2026-11-29 10:00 UTC", "commit": "85f3b2e"}}))
    monkeypatch.setattr(report, "last_commit", lambda *paths: ("2026-12-01", "abc1234"))
    monkeypatch.setattr(benchmark_tab, "weights_commit", lambda: ("2026-12-03", "98363b2"))
    out = benchmark_tab.benchmarks(tmp_path, 2)
    labels = {u["label"].split(" — ")[0]: u["label"] for u in (out["figure_0"], out["figure_1"])}
    assert "made 2026-11-29 10:00 UTC (commit 85f3b2e), on weights older than the shipped " \
        "ones of 2026-12-03" in labels["tradeoff"]
    assert "made 2026-12-01 (commit abc1234), on weights older" in labels["table1"]


def test_a_figure_is_older_than_the_weights_by_ancestry_not_by_its_day(tmp_path, monkeypatch):
    """Two commits of one day: a figure measured at the first is on weights older than the
    second's, which the days alone cannot tell (a recorded time sorted after the weights'
    day and read as made on them); a commit this clone does not know falls back on the days;
    a stored check that records its own "measured" and "commit" is dated by them."""
    import json
    import subprocess

    from app import benchmark_tab
    from ratouch.eval import report

    repo = tmp_path / "repo"
    repo.mkdir()
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]

    def commit(msg: str) -> str:
        (repo / "f").write_text(msg)
        subprocess.run(["git", "add", "f"], cwd=repo, check=True)
        subprocess.run([*git, "commit", "-qm", msg], cwd=repo, check=True)
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo, check=True,
                              capture_output=True, text=True).stdout.strip()

    subprocess.run(["git", "init", "-q"], cwd=repo, check=True)
    first, second = commit("figure measured"), commit("weights shipped")
    monkeypatch.setattr(report, "REPO", repo)
    assert report.made_before(first, second) is True
    assert report.made_before(second, first) is False
    assert report.made_before(second + "+changes", second) is False
    assert report.made_before(second, second) is False
    assert report.made_before("0000000", second) is None
    assert report.made_before(None, second) is None

    docs = tmp_path / "docs"
    figs = docs / "figures"
    figs.mkdir(parents=True)
    (figs / "tradeoff.json").write_text(_figure_json("speed vs accuracy"))
    (figs / "tradeoff.data.json").write_text(json.dumps(
        {"made": {"utc": "2026-12-03 10:00 UTC", "commit": first}}))
    monkeypatch.setattr(benchmark_tab, "weights_commit", lambda: ("2026-12-03", second))
    label = benchmark_tab.benchmarks(docs, 1)["figure_0"]["label"]
    assert f"made 2026-12-03 10:00 UTC (commit {first}), on weights older than the shipped " \
        f"ones of 2026-12-03 ({second})" in label
    (figs / "tradeoff.data.json").write_text(json.dumps(
        {"made": {"utc": "2026-12-03 11:00 UTC", "commit": second}}))
    label = benchmark_tab.benchmarks(docs, 1)["figure_0"]["label"]
    assert f"(commit {second}), on the shipped weights of 2026-12-03" in label
    # a commit this clone lacks: the days decide
    (figs / "tradeoff.data.json").write_text(json.dumps(
        {"made": {"utc": "2026-12-02 11:00 UTC", "commit": "0000000"}}))
    assert "on weights older" in benchmark_tab.benchmarks(docs, 1)["figure_0"]["label"]
    # a check that records itself (`ratouch eval frames --json`)
    check = docs / "frames-real-2026-12-03.json"
    check.write_text(json.dumps({"measured": "2026-12-03", "commit": first, "frames": []}))
    assert report.recorded_made(check) == ("2026-12-03", first)
    assert report.figure_made(check) == ("2026-12-03", first, True)
    assert f"made 2026-12-03 (commit {first}), on weights older" in \
        benchmark_tab.provenance(check, ("2026-12-03", second))
    check.write_text(json.dumps({"measured": "2026-12-03", "frames": []}))  # before "commit"
    assert report.recorded_made(check) == ("2026-12-03", None)
    assert benchmark_tab.provenance(check, ("2026-12-03", second)).startswith(
        "made 2026-12-03, on the shipped weights")


def test_benchmarks_tab_without_and_with_a_report(tmp_path):
    from app import view

    report, note, *slots = _bench(tmp_path, 3)
    assert "Not generated yet" in report and "ratouch eval all" in report
    assert "ratouch bench tradeoff" in report and "ratouch bench tradeoff" in note
    assert all(u["visible"] is False for u in slots)
    figs = tmp_path / "figures"
    figs.mkdir()
    (figs / "b_recall.json").write_text(_figure_json("recall"))
    (figs / "tradeoff.json").write_text(_figure_json("speed vs accuracy"))
    (figs / "broken.json").write_text("{not json")
    (figs / "tradeoff.data.json").write_text('{"rows": []}')  # raw numbers, not a figure
    (figs / "tradeoff.html").write_text("<html></html>")
    (figs / "local.png").write_bytes(_png(np.zeros((4, 4, 3), np.uint8)))
    (tmp_path / "results.md").write_text(
        "# Results\n\n![Speed vs accuracy](figures/tradeoff.png) "
        "([interactive](figures/tradeoff.html))\n\n![local](figures/local.png)\n\n"
        "![gone](figures/gone.png) [missing](figures/gone.html) [web](https://x.org/a)\n"
        "| a | b |\n|---|---|\n")
    assert [p.name for p in view.list_figures(tmp_path)] == [
        "tradeoff.json", "b_recall.json", "broken.json"]
    report, note, *slots = _bench(tmp_path, 3)
    assert "interactive chart **tradeoff** above" in report
    # local files by their path inside the docs folder, never the server's own path
    assert "(ratouch-docs/figures/local.png)" in report and str(tmp_path) not in report
    assert "gone.png) not found" in report and "| a | b |" in report
    assert "[interactive](ratouch-docs/figures/tradeoff.html)" in report
    assert " missing " in report and "[web](https://x.org/a)" in report
    assert [u["visible"] for u in slots] == [True, True, False]
    assert slots[0]["value"].layout.title.text == "speed vs accuracy"
    assert slots[0]["label"].startswith("tradeoff — made ") and "broken.json (" in note
    assert slots[0]["value"].layout.width is None  # it takes the container's width
    # each figure says which weights and date it comes from
    old = view.figure_provenance(("2026-11-23", "a7d8ae0"), ("2026-11-26", "b4e551b"))
    assert old == ("made 2026-11-23 (commit a7d8ae0), on weights older than the shipped "
                   "ones of 2026-11-26 (b4e551b): not regenerated since")
    assert "on the shipped weights" in view.figure_provenance(("2026-11-27", None),
                                                              ("2026-11-26", "b4e551b"))
    report, note, *slots = _bench(tmp_path, 1)  # more figures than slots
    assert "only 1 figures are shown" in note


def test_the_report_figures_are_served_and_nothing_else(tmp_path):
    import urllib.error
    import urllib.request

    from app.app import build_demo, launch

    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "fig.html").write_text("<html>the figure</html>")
    demo = build_demo(FakePipeline(), docs=tmp_path)
    port = free_port()
    launch(demo, "127.0.0.1", port, block=False)
    base = f"http://127.0.0.1:{port}/"
    try:
        with urllib.request.urlopen(base + "ratouch-docs/figures/fig.html") as r:
            assert r.read() == b"<html>the figure</html>"
        for outside in ("ratouch-docs/../" + Path(__file__).name, "ratouch-docs/%2e%2e/x",
                        "ratouch-docs//etc/passwd",
                        f"gradio_api/file={tmp_path / 'figures' / 'fig.html'}",
                        f"gradio_api/file={Path(__file__).resolve()}"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(base + outside)
            assert e.value.code in (403, 404), outside
    finally:
        demo.close()


# ------------------------------------------------------------------------- start-up and serving

def test_the_app_serves_while_the_pipeline_loads(fake, pair_files):
    import threading

    from app import handlers
    from app.app import _header
    from ratouch.serve.loader import BackgroundPipeline, PipelineNotReady

    go = threading.Event()
    pending = BackgroundPipeline(lambda: go.wait(30) and fake, "fake-enc")
    assert not pending.ready() and "loading the models" in _header(pending)
    with pytest.raises(PipelineNotReady, match="still loading"):
        pending.get(timeout=0.01)
    visual = handlers.upload_visual(str(pair_files[0]))[0]
    threading.Timer(0.2, go.set).start()
    v = handlers.run_query(pending, _thumb, visual, str(pair_files[1]), None, None, None,
                           None, 5)  # waits for the models, then answers
    assert not v.status.startswith("**✖") and pending.ready()
    assert "corpus of 60" in _header(pending)

    def broken():
        raise DataError("assets/generator is missing")

    failed = BackgroundPipeline(broken, "fake-enc")
    failed._done.wait(5)
    assert "✖ failed: assets/generator is missing" in _header(failed)
    v = handlers.run_query(failed, _thumb, visual, None, None, None, None, None, 5)
    assert "failed to load: assets/generator is missing" in v.status


def test_the_batcher_answers_concurrent_queries_together(monkeypatch):
    import threading

    from ratouch.serve import batcher as serving
    from ratouch.serve.request import QueryRequest, answer_one

    batches = []

    def fake_answer(requests):
        batches.append(len(requests))
        time.sleep(0.05)
        return [DataError(f"bad {r.k}") if r.k == 13 else {"k": r.k} for r in requests]

    b = serving.QueryBatcher(SimpleNamespace(answer=fake_answer,
                                             model=lambda name=None: "the model"),
                             max_batch=4)
    assert b.model() == "the model"  # the loaded model behind it, asked explicitly
    out, errors = {}, {}

    def ask(k):
        try:
            out[k] = answer_one(b, QueryRequest(np.zeros((4, 4, 3), np.uint8), None, None,
                                                (0, 0, 4, 4), k))
        except DataError as e:
            errors[k] = str(e)

    threads = [threading.Thread(target=ask, args=(k,)) for k in range(1, 11)] + \
        [threading.Thread(target=ask, args=(13,))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert out == {k: {"k": k} for k in range(1, 11)} and errors == {13: "bad 13"}
    assert sum(batches) == 11 and max(batches) <= 4 and len(batches) < 11


# ------------------------------------------------------------------------- a real server

@pytest.fixture(scope="module")
def served():
    """The app over the fake pipeline, served on 127.0.0.1 (a free port)."""
    from app.app import build_demo, launch

    pipe = FakePipeline()
    demo = build_demo(pipe)
    port = free_port()
    launch(demo, "127.0.0.1", port, block=False)
    yield f"http://127.0.0.1:{port}/", pipe, demo
    demo.close()


def test_query_api_through_gradio_client(served, pair_files):
    from gradio_client import Client, handle_file

    url, pipe, _ = served
    client = Client(url, verbose=False)
    out = client.predict(handle_file(str(pair_files[0])), handle_file(str(pair_files[1])),
                         10, 20, 70, 90, 4, api_name="/query")
    assert set(out) == {"neighbours", "description", "attention", "pca", "timings_ms",
                        "warnings", "box", "encoder", "visual_route", "trust", "retrieval"}
    assert out["box"] == [10, 20, 70, 90] and len(out["neighbours"]["joint"]) == 4
    assert out["description"]["ra_touch"] == "soft and grainy"
    json.dumps(out)
    # the default box and image-only retrieval are labelled in the JSON
    out = client.predict(handle_file(str(pair_files[0])), None, None, None, None, None, 5,
                         api_name="/query")
    assert list(out["neighbours"]) == ["image"] and len(out["warnings"]) == 2
    # the API documents only /query: the UI's own events are not callable by clients
    assert list(client.view_api(print_info=False, return_format="dict")["named_endpoints"]) \
        == ["/query"]


def test_gradio_monitoring_is_off_and_costs_nothing_per_query(served, pair_files):
    """Gradio's own traffic monitoring is not served, and its queue neither rebuilds its
    summary table after each event nor keeps records for it (its cost per query grew with
    the queries served)."""
    import urllib.error
    import urllib.request

    from gradio_client import Client, handle_file

    url, _, demo = served
    client = Client(url, verbose=False)
    for _ in range(3):
        client.predict(handle_file(str(pair_files[0])), None, None, None, None, None, 3,
                       api_name="/query")
    queue = demo._queue
    assert queue.events_recorded >= 3
    assert queue.cached_event_analytics_summary == {"functions": {}}  # never rebuilt
    assert len(queue.event_analytics) <= 1
    for route in ("monitoring", "monitoring/summary"):
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(url + route)
        assert e.value.code in (403, 404), route


def test_the_model_is_a_choice_in_the_page_and_the_api(pair_files):
    from gradio_client import Client, handle_file

    from app.app import build_demo, launch
    from ratouch.serve.models import ModelChoice

    pipes = {"small": FakePipeline(), "large": FakePipeline()}
    choice = ModelChoice("small", ["small", "large"], load=pipes.__getitem__)
    demo = build_demo(choice, models=["small", "large"])
    dropdown = [c for c in demo.config["components"] if c.get("props", {}).get("elem_id") == "model"]
    assert dropdown[0]["props"]["interactive"] and dropdown[0]["props"]["value"] == "small"
    port = free_port()
    launch(demo, "127.0.0.1", port, block=False)
    try:
        client = Client(f"http://127.0.0.1:{port}/", verbose=False)
        files = handle_file(str(pair_files[0])), handle_file(str(pair_files[1]))
        client.predict(*files, None, None, None, None, 5, api_name="/query")  # the default
        client.predict(*files, None, None, None, None, 5, "large", api_name="/query")
        assert len(pipes["small"].calls) == 1 and len(pipes["large"].calls) == 1
        with pytest.raises(Exception, match="large|small|model"):  # not a choice: refused
            client.predict(*files, None, None, None, None, 5, "huge", api_name="/query")
        assert len(pipes["small"].calls) + len(pipes["large"].calls) == 2
    finally:
        demo.close()


def test_the_retrieval_system_is_a_choice_in_the_api(served, pair_files):
    """The `/query` API's last input names the retrieval system (every one of the registry's;
    left out: the page's default, the shipped one); one the registry lacks is refused before
    any answer."""
    from gradio_client import Client, handle_file

    from ratouch.search.modes import RETRIEVAL_SYSTEMS
    from ratouch.serve.pipeline import DEFAULT_RETRIEVAL

    url, pipe, _ = served
    client = Client(url, verbose=False)
    files = handle_file(str(pair_files[0])), handle_file(str(pair_files[1]))
    before = len(pipe.calls)
    for system in RETRIEVAL_SYSTEMS:
        client.predict(*files, None, None, None, None, 5, None, None, system, api_name="/query")
    client.predict(*files, None, None, None, None, 5, api_name="/query")
    assert [c["retrieval"] for c in pipe.calls[before:]] == [*RETRIEVAL_SYSTEMS, DEFAULT_RETRIEVAL]
    with pytest.raises(Exception, match="best|retrieval"):
        client.predict(*files, None, None, None, None, 5, None, None, "best", api_name="/query")
    assert len(pipe.calls) == before + len(RETRIEVAL_SYSTEMS) + 1


def test_query_api_bad_input_is_a_clear_error_and_the_server_keeps_serving(served, pair_files,
                                                                            tmp_path):
    from gradio_client import Client, handle_file

    url, pipe, _ = served
    client = Client(url, verbose=False)
    junk = _bytes_file(tmp_path, "junk.png", b"not an image at all")
    with pytest.raises(Exception, match=r"visual image junk.png as an image") as e:
        client.predict(handle_file(junk), None, None, None, None, None, 5, api_name="/query")
    assert "Traceback" not in str(e.value) and "/tmp/gradio" not in str(e.value)
    with pytest.raises(Exception, match="empty or inverted"):
        client.predict(handle_file(str(pair_files[0])), None, 9, 9, 3, 3, 5, api_name="/query")
    out = client.predict(handle_file(str(pair_files[0])), None, None, None, None, None, 2,
                         api_name="/query")
    assert len(out["neighbours"]["image"]) == 2


# ------------------------------------------------------------------------- the real pipeline

@pytest.mark.slow
def test_real_pipeline_example_query(real_pipeline, world):
    from app import handlers

    thumb = lambda i: real_pipeline.corpus.thumbnail(i, 64)  # noqa: E731
    visual, _, tactile, bg, *box, _ = handlers.load_example(world, 60)
    v = handlers.run_query(real_pipeline, thumb, visual, tactile, *box, 5)
    assert not v.status.startswith("**✖"), v.status
    # one gallery item per distinct caption, the raw top-5 in the JSON and the tables
    for mode, g in zip(("image", "tactile", "joint"),
                       (v.galleries["image"], v.galleries["tactile"], v.galleries["joint"])):
        ns = v.raw["neighbours"][mode]
        # one tile per distinct caption (duplicates folded with a count)
        assert len(ns) == 5 and g.count("<figure") == len({n["caption"] for n in ns}), mode
    assert v.raw["description"]["ra_touch"] and v.raw["description"]["baseline"]
    assert any(t.name == "ground truth" for t in v.plot.data)
    visual = handlers.load_example(world, 60)[0]
    v = handlers.run_query(real_pipeline, thumb, visual, None, None, None, None, None, 3)
    assert len(v.raw["neighbours"]["image"]) == 3 and 1 <= v.galleries["image"].count("<figure") <= 3
    assert "image-only" in v.status


@pytest.mark.slow
def test_real_failure_cases_show_their_table_scores(real_pipeline):
    """The real pipeline: a failure case opened from the table (with its sensor's background,
    which the table encoded it against) is answered with the table's descriptions, and the
    case view shows the table's judge scores for them."""
    from app import handlers, view
    from ratouch.eval import failures
    from ratouch.eval.judge import OfflineJudge
    from ratouch.world.config import WorldConfig

    table = failures.load_or_compute(real_pipeline, conditions=("natural", "noisy touch"),
                                     indices=[0, 60, 200])  # test_failures' table: cached
    rows, frame, judge = table["rows"], view.cases_frame(table["rows"]), OfflineJudge()
    thumb = lambda i: real_pipeline.corpus.thumbnail(i, 64)  # noqa: E731
    for i in (1, 4, 5):
        r = rows[i]
        visual, _, tactile, bg, *box, _ = handlers.open_case(WorldConfig(), frame.iloc[i].tolist())
        v = handlers.run_query(real_pipeline, thumb, visual, tactile, *box, 5, judge=judge,
                               background=bg)
        assert v.raw["description"]["ra_touch"] == r["ra_touch"]
        assert f"{r['ra_touch']} · judge **{r['ra_score']:.1f}**/10" in _plain(v.description)
        if v.raw["description"]["baseline"] == r["baseline"]:
            assert f"{r['baseline']} · judge **{r['baseline_score']:.1f}**/10" in _plain(v.description)


@pytest.mark.slow
def test_the_press_against_its_background_is_a_height_map(real_pipeline, world, tmp_path):
    """Issue 36 through the Run handler and the real pipeline: a world example with its
    sensor's background, and a real Taxim GelSight press with its own, show the press as a
    height map (its picture, depth, spread and relief in the sensor's units, the structured
    contact reading), the same numbers as the answer's JSON and its export; without a
    background, the hint; a real DIGIT frame of an unfamiliar unit is said to be one, with
    and without its background."""
    import base64

    from app import handlers, view
    from app.explore_tab import answer_named
    from app.page import Page
    from ratouch.eval.frames import digit_frames
    from ratouch.eval.photos import reference_dir
    from ratouch.world.taxim_optics import real_presses

    thumb = lambda i: real_pipeline.corpus.thumbnail(i, 64)  # noqa: E731
    visual, _, tactile, bg, *box, _ = handlers.load_example(world, 60)
    v = handlers.run_query(real_pipeline, thumb, visual, tactile, *box, 5, background=bg)
    tac = v.raw["trust"]["tactile"]
    geo, structure = tac["geometry"], tac["structure"]
    assert geo["family"] == "digit" and geo["units"] == "render units" and geo["depth"] > 0
    assert structure["contact"] and structure["score"] > structure["threshold"]
    assert f"depth <b>{geo['depth']:.1f} r.u.</b> (render units)" in v.geometry
    assert f"spread <b>{geo['spread']:.0%}</b>" in v.geometry
    assert f"structured change <b>{structure['score']:.2f}</b>" in v.geometry
    # the picture is the press's height map: a bright patch on a dark, flat gel
    png = v.geometry.split("data:image/png;base64,")[1].split("'")[0]
    picture = np.asarray(Image.open(io.BytesIO(base64.b64decode(png))).convert("L"))
    assert picture.shape == (160, 120)  # the DIGIT's working size, portrait
    assert picture.max() > 200 and np.median(picture) < 60
    # the export carries the numbers
    page = Page(real_pipeline, world, None, {"world": world.cfg}, tmp_path, None, 1, None,
                thumb)
    kept = answer_named(page, v, visual, tactile, bg, 5, None, tuple(box), [])
    exported = json.loads(Path(kept["export_json"].value["path"]).read_text())
    assert exported["result"]["trust"]["tactile"]["geometry"] == geo
    assert exported["result"]["trust"]["tactile"]["structure"] == structure
    assert "height_map" not in exported["result"]  # the picture is the page's, not the JSON's

    # the same frame without its background: the hint, and no geometry in the answer
    v = handlers.run_query(real_pipeline, thumb, visual, tactile, *box, 5)
    assert v.geometry == view.GEOMETRY_HINT and "geometry" not in v.raw["trust"]["tactile"]

    # a real GelSight press against its background: millimetres
    presses = real_presses("gelsight")
    v = handlers.run_query(real_pipeline, thumb, visual, presses["frames"][3], *box, 5,
                           background=presses["background"])
    geo = v.raw["trust"]["tactile"]["geometry"]
    assert geo["family"] == "gelsight" and geo["units"] == "mm"
    assert 1.0 < geo["depth"] < 2.5  # docs/geometry.md: 1.39-1.83 mm on these presses
    assert f"depth <b>{geo['depth']:.2f} mm</b>" in v.geometry and "✓ contact" in v.geometry
    # a rigid ball: its shape reads hard, in the strip and the answer's JSON
    firm = v.raw["trust"]["tactile"]["firmness"]
    assert firm["reads"] == "hard" and firm["soft"] < 0.5
    assert "shape <b>hard</b>" in v.geometry

    # a real DIGIT of another unit than the rendered ones: unfamiliar, said either way
    frames = {f.name: f for f in digit_frames(reference_dir())}
    if not frames:
        pytest.skip("the real DIGIT frames are not in ../shared/data/reference_tactile")
    for name in ("digit pressed", "digit pressed against the tacto background"):
        f = frames[name]
        v = handlers.run_query(real_pipeline, thumb, visual, f.frame, *box, 5,
                               background=f.background)
        assert v.raw["trust"]["tactile"]["unfamiliar_sensor"], name
        assert "⚠ unfamiliar sensor, sensor read as digit" in v.description, name
        assert "looks like none of the sensors" in v.description, name
        if f.background is not None:
            assert "⚠ unfamiliar sensor</b>, read as digit (a guess)" in v.geometry


# ------------------------------------------------------------------------- load

@pytest.mark.slow
def test_load_sixteen_clients_ten_queries_each(pair_files):
    """16 concurrent gradio_client clients x 10 queries against the fake pipeline (20 ms per
    query): every request is answered; prints p50/p95 latency and the server's RSS."""
    import threading

    import psutil
    from gradio_client import Client, handle_file

    from app.app import build_demo, launch

    demo = build_demo(FakePipeline(delay_s=0.02))
    port = free_port()
    launch(demo, "127.0.0.1", port, block=False)
    rss0 = psutil.Process().memory_info().rss
    latencies: list[float] = []
    errors: list[BaseException] = []

    def client_run():
        try:
            c = Client(f"http://127.0.0.1:{port}/", verbose=False)
            for _ in range(10):
                t = time.perf_counter()
                c.predict(handle_file(str(pair_files[0])), handle_file(str(pair_files[1])),
                          None, None, None, None, 5, api_name="/query")
                latencies.append(time.perf_counter() - t)
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    try:
        threads = [threading.Thread(target=client_run) for _ in range(16)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=300)
    finally:
        demo.close()
    rss1 = psutil.Process().memory_info().rss
    assert not errors, errors[:3]
    assert len(latencies) == 160
    p50, p95 = np.percentile(latencies, [50, 95])
    print(f"\nload: 160 queries, p50 {p50 * 1000:.0f} ms, p95 {p95 * 1000:.0f} ms; "
          f"RSS {rss0 / 2**20:.0f} -> {rss1 / 2**20:.0f} MiB")


def _tie_free(neighbours: dict) -> dict:
    """Neighbours by mode as (score, caption) multisets per score: entries with the same
    caption tie exactly, and a batched search may order tied entries differently."""
    return {m: sorted((n["score"], n["caption"]) for n in ns) for m, ns in neighbours.items()}


@pytest.mark.slow
def test_real_pipeline_batched_queries_match_single_ones(real_pipeline, world):
    from ratouch.errors import ConfigError
    from ratouch.serve.request import QueryRequest

    samples = [world.sample("test", i) for i in (60, 140, 290)]
    reqs = [{"visual": s.visual, "tactile": s.tactile, "box": s.box, "k": k, "label": s.caption}
            for s, k in zip(samples, (5, 5, 3))]
    reqs += [{"visual": samples[0].visual, "k": 4}]  # image-only
    decoded = [QueryRequest.decode(**req) for req in reqs]
    # a request whose K exceeds the corpus (decode caps K at MAX_K; a small corpus can be
    # smaller) fails alone, in its slot
    too_many = dataclasses.replace(decoded[3], k=len(real_pipeline.corpus.entries) + 1)
    many = real_pipeline.answer([*decoded, too_many])
    assert isinstance(many[4], ConfigError) and "K must be" in str(many[4])  # K > the corpus
    with pytest.raises(ConfigError, match="K must be a whole number from 1 to 20"):
        QueryRequest.decode(samples[0].visual, k=21)
    with pytest.raises(DataError, match="box"):  # decoding says what is wrong with a request
        QueryRequest.decode(samples[0].visual, box=(9, 9, 2, 2))
    with pytest.raises(ConfigError, match="K must be"):
        QueryRequest.decode(samples[0].visual, k=0)
    for req, got in zip(reqs[:4], many[:4]):
        got = got.to_dict()
        want = real_pipeline.query(**req)
        assert _tie_free(got["neighbours"]) == _tie_free(want["neighbours"])
        assert got["box"] == want["box"]
        assert got["description"] == want["description"]
        assert got["warnings"] == want["warnings"]
        assert [p["role"] for p in got["pca"]["points"]] == \
            [p["role"] for p in want["pca"]["points"]]
        xy = lambda r: sorted((p["role"], p["x"], p["y"]) for p in r["pca"]["points"])  # noqa: E731
        assert np.allclose([p[1:] for p in xy(got)], [p[1:] for p in xy(want)], atol=1e-4)
        assert got["timings_ms"]["batch_size"] == 4


@pytest.mark.slow
def test_real_pipeline_smoke_two_clients(real_pipeline, pair_files):
    """The real pipeline behind the batching server: 2 concurrent clients x 2 queries."""
    import threading

    from gradio_client import Client, handle_file

    from app.app import build_demo, launch
    from ratouch.serve.batcher import QueryBatcher

    batcher = QueryBatcher(real_pipeline)
    demo = build_demo(batcher)
    port = free_port()
    launch(demo, "127.0.0.1", port, block=False)
    answers, errors = [], []

    def client_run():
        try:
            c = Client(f"http://127.0.0.1:{port}/", verbose=False)
            for _ in range(2):
                answers.append(c.predict(handle_file(str(pair_files[0])),
                                         handle_file(str(pair_files[1])), None, None, None,
                                         None, 5, api_name="/query"))
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    try:
        threads = [threading.Thread(target=client_run) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=120)
    finally:
        demo.close()
    assert not errors, errors
    assert len(answers) == 4 and all(a["description"]["ra_touch"] for a in answers)
    assert sum(batcher.batches) == 4


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("RATOUCH_LOAD_TEST") != "1",
                    reason="the real-pipeline load test runs with RATOUCH_LOAD_TEST=1 "
                           "(or: python scripts/load_test.py)")
def test_load_real_app_sixteen_clients():
    """`python -m app` with the real default pipeline: time to ready, single-user p50, then
    16 clients x 10 queries (scripts/load_test.py). Targets: HTTP-ready <= 15 s, p50 under
    load <= 2x single-user p50, no failures."""
    import importlib.util

    if not HAVE_ASSETS:
        pytest.skip("the trained retriever/generator weights are not in assets/ yet")
    if not (USER_CACHE / "imagenet-t-10k-seed0" / "manifest.json").is_file():
        pytest.skip(f"the default corpus is not built in {USER_CACHE} (start the app once)")
    path = Path(__file__).resolve().parents[1] / "scripts" / "load_test.py"
    spec = importlib.util.spec_from_file_location("load_test", path)
    load_test = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(load_test)
    report = load_test.run(deadline_s=120, env={**os.environ, "RATOUCH_CACHE": str(USER_CACHE)})
    print("\n" + load_test.format_report(report))
    assert report["failures"] == 0 and report["not_run"] == 0, report["failure_examples"]
    assert all(report["targets"].values()), report["targets"]


# ------------------------------------------------------------------------- issue 13: real uploads

def test_unreadable_tactile_upload_is_named_and_clears_old_results(fake, pair_files, tmp_path):
    from app import handlers

    good = handlers.upload_visual(str(pair_files[0]))[0]
    old = handlers.run_query(fake, _thumb, good, str(pair_files[1]), None, None, None, None, 5)
    assert old.galleries["joint"]  # a previous answer is on the page
    text = _bytes_file(tmp_path, "notes.png", b"this is not an image")
    # the browser sends the upload undecoded (preprocess=False): {"path": ...}
    out = handlers.upload_tactile({"path": text, "orig_name": "notes.png"})
    assert out["tactile"] is None  # the unusable file is removed from the input
    assert "tactile image notes.png" in out["status"] and out["status"].startswith("**✖")
    assert out["gallery_joint"] == "" and out["description"] == "" and out["raw"] is None
    # every output is named: one gallery and one table per registered query mode
    assert set(out) == {"tactile", *handlers.output_names()}
    # a bad visual upload also clears the results, and says which file and role
    out = handlers.visual_uploaded({"path": text})
    assert out["state"] is None and "visual image notes.png" in out["status"]
    assert out["gallery_image"] == ""
    # a good tactile upload leaves everything as it is
    assert handlers.upload_tactile({"path": str(pair_files[1])}) == {}


@pytest.mark.parametrize("k", [2.5, 0, 21, "", None, "five", float("nan")])
def test_bad_k_is_named(fake, pair_files, k):
    from app import handlers
    from ratouch.serve.request import MAX_K, check_k

    good = handlers.upload_visual(str(pair_files[0]))[0]
    v = handlers.run_query(fake, _thumb, good, str(pair_files[1]), None, None, None, None, k)
    assert "K must be a whole number from 1 to 20" in v.status and v.raw is None
    assert check_k(7.0, MAX_K) == 7 and check_k("3", MAX_K) == 3  # a slider's, typed


def test_a_background_of_another_size_is_named_alike_on_upload_and_on_run(pair_files, tmp_path):
    from app import handlers
    from ratouch.serve.request import QueryRequest

    bg = tmp_path / "bg.png"
    Image.new("RGB", (50, 60)).save(bg)
    said = "is 50x60 (WxH) but the tactile image is 96x128; the background must be the same"
    upload = handlers.upload_background(str(bg), str(pair_files[1]))
    assert upload["background"] is None and said in upload["status"]  # removed, and why
    with pytest.raises(DataError, match=re.escape(said)):
        QueryRequest.decode(str(pair_files[0]), str(pair_files[1]), background=str(bg))


def test_a_background_of_another_size_on_run_is_a_message_not_a_trace(fake, pair_files,
                                                                      tmp_path):
    """Issue 36: Run with a background of another size than the tactile frame says so (both
    sizes), shows no answer and no height map, and raises nothing."""
    from app import handlers, view

    bg = tmp_path / "small_bg.png"
    Image.new("RGB", (50, 60)).save(bg)
    visual = handlers.upload_visual(str(pair_files[0])).state
    v = handlers.run_query(fake, _thumb, visual, str(pair_files[1]), None, None, None, None,
                           5, background=str(bg))
    assert v.raw is None and v.status.startswith("**✖ Cannot run this query:**")
    assert "the background image is 50x60 (WxH) but the tactile image is 96x128" in v.status
    assert "the background must be the same" in v.status
    assert "Traceback" not in v.status and str(tmp_path) not in v.status
    assert v.geometry == view.GEOMETRY_HINT and v.named()["geometry"] == view.GEOMETRY_HINT


def _geometry_result(units: str = "mm", unfamiliar: bool = False, **tactile) -> dict:
    geo = {"family": "gelsight" if units == "mm" else "digit", "units": units,
           "depth": 1.5312, "spread": 0.0412, "relief": 0.0331}
    return {"trust": {"visual": {"novelty": 1.0, "threshold": 1.5, "novel": False},
                      "tactile": {"novelty": 1.0, "threshold": 1.5, "novel": False,
                                  "contact": 7.2, "contact_threshold": 4.99,
                                  "no_contact": False, "background": True,
                                  "sensor": {"family": geo["family"], "distance": 0.9,
                                             "source": "guessed from the frame's colours"},
                                  "unfamiliar_sensor": unfamiliar,
                                  "structure": {"contact": True, "score": 10.523,
                                                "threshold": 1.163, "family": geo["family"]},
                                  "geometry": geo, **tactile}}}


def test_the_height_map_is_formatted_with_its_scale_and_numbers():
    """Issue 36: the strip under the tactile inputs: the picture, its scale in the sensor's
    units (mm for a calibrated lookup, render units for the DIGIT's), depth, spread, relief
    and the structured-contact reading; a hint without a background; why there is no height
    map where nothing reads the sensor; the unfamiliar sensor said."""
    from app import view

    picture = np.zeros((120, 160, 3), np.uint8)
    html = view.geometry_html(_geometry_result(), picture, True)
    assert html.count("<img src='data:image/png;base64,") == 1
    for said in ("dark flat → white 1.53 mm", "depth <b>1.53 mm</b>", "spread <b>4%</b>",
                 "relief <b>0.033 mm</b>", "structured change <b>10.52</b> × floor",
                 "(contact &gt; 1.16) ✓ contact", "gelsight"):
        assert said in html, said
    assert "unfamiliar" not in html and "shape <b>" not in html  # no firmness given
    soft = view.geometry_html(_geometry_result(firmness={"soft": 0.862, "reads": "soft"}),
                              picture, True)
    assert "shape <b>soft</b> 86%" in soft
    hard = view.geometry_html(_geometry_result(firmness={"soft": 0.1, "reads": "hard"}),
                              picture, True)
    assert "shape <b>hard</b> 90%" in hard
    sure = view.geometry_html(_geometry_result(firmness={"soft": 0.998, "reads": "soft"}),
                              picture, True)
    assert "shape <b>soft</b> &gt;99%" in sure
    assert "by a model fitted on renders of everyday presses" in sure  # one regime
    assert "(a guess)" not in sure and "(a guess)" not in hard
    # contact uncertain: the shape may be a wrong background's, so its firmness is a guess
    unsure = view.geometry_html(_geometry_result(firmness={"soft": 0.94, "reads": "soft"},
                                                 state="uncertain"), picture, True)
    assert "shape <b>soft</b> 94% <i class='ra-warn'>(a guess)</i>" in unsure
    assert "contact is uncertain: the shape may be a wrong background" in unsure
    for regime, said in (("world", "read here as a firm press"),
                         ("everyday", "read here as an everyday press")):
        routed = view.geometry_html(_geometry_result(firmness={
            "soft": 0.778, "reads": "soft", "regime": regime}), picture, True)
        assert "shape <b>soft</b> 78%" in routed and said in routed, regime
        assert "two models fitted on renders" in routed
    # against another unit's background (its marker dots not the frame's) the change over
    # the floors is not called contact
    other = _geometry_result(markers={"dots": 72, "found": 2, "share": 0.028, "moved": True})
    other_html = view.geometry_html(other, picture, True)
    assert "marker dots are not this frame" in other_html and "✓ contact" not in other_html
    # a change a smooth lighting field alone explains (another DIGIT unit's background)
    lit = _geometry_result()
    lit["trust"]["tactile"]["structure"]["lighting_field"] = {"score": 0.84, "explains": True}
    lit_html = view.geometry_html(lit, picture, True)
    assert "smooth lighting field alone explains it (0.84" in lit_html
    assert "✓ contact" not in lit_html
    lit["trust"]["tactile"]["structure"]["lighting_field"] = {"score": 3.1, "explains": False}
    assert "✓ contact" in view.geometry_html(lit, picture, True)
    # a Mini change barely above a blank's (inside the band): uncertain, not "✓ contact"
    near = _geometry_result()
    near["trust"]["tactile"]["structure"]["band"] = {"top": 2.045, "inside": True}
    near_html = view.geometry_html(near, picture, True)
    assert "barely above a blank&#39;s (within 2.045): contact uncertain" in near_html
    assert "✓ contact" not in near_html
    near["trust"]["tactile"]["structure"]["band"] = {"top": 2.045, "inside": False}
    assert "✓ contact" in view.geometry_html(near, picture, True)
    # a texture on a domed gel integrates to a few micrometres: said, not rounded to 0.00 mm
    faint = _geometry_result()
    faint["trust"]["tactile"]["geometry"].update(depth=0.0041, relief=0.00026)
    faint_html = view.geometry_html(faint, picture, True)
    for said in ("dark flat → white 4.1 µm", "depth <b>4.1 µm</b>", "relief <b>0.26 µm</b>"):
        assert said in faint_html, said
    assert "0.00 mm" not in faint_html
    ru = view.geometry_html(_geometry_result("render units", unfamiliar=True), picture, True)
    assert "depth <b>1.5 r.u.</b> (render units)" in ru and "no real calibration" in ru
    assert "⚠ unfamiliar sensor</b>, read as digit (a guess)" in ru
    assert "× floor" in ru and "unfamiliar-sensor floor" not in ru  # the family's floors
    own = _geometry_result("render units", unfamiliar=True)
    own["trust"]["tactile"]["structure"]["floors"] = "unfamiliar sensor"
    own_html = view.geometry_html(own, picture, True)
    assert "structured change <b>10.52</b> × unfamiliar-sensor floor" in own_html
    assert "floor set for sensors unlike every rendered unit" in own_html
    # without a background (or without a tactile frame, or before a query): the hint
    for result, bg in ((_geometry_result(), False), (None, True), ({"trust": None}, False)):
        assert view.geometry_html(result, None, bg) == view.GEOMETRY_HINT
    assert "give the sensor's background" in view.GEOMETRY_HINT
    # a background, but nothing reads it: said, never a picture
    unread = view.geometry_html(_geometry_result(geometry=None, structure=None), None, True)
    assert "none, no geometry lookup reads the sensor family “gelsight”" in unread
    assert "<img" not in unread
    assert "no geometry calibration is loaded" in view.geometry_html(
        {"trust": {"tactile": {"background": True, "novelty": 1.0}}}, None, True)
    assert "no trust calibration" in view.geometry_html({"trust": None}, None, True)
    # the trust line names an unfamiliar sensor, with or without a background
    for background in (True, False):
        result = {**_geometry_result(unfamiliar=True), "warnings": []}
        result["trust"]["tactile"]["background"] = background
        assert "⚠ unfamiliar sensor, sensor read as gelsight" in view.trust_lines(result)[0]
    assert "unfamiliar sensor" not in view.trust_lines({**_geometry_result(),
                                                        "warnings": []})[0]


def test_duplicate_captions_are_grouped_in_galleries_but_not_in_tables():
    from app import view

    ns = [{"id": i, "score": 0.5 - i / 100, "class_name": "sand castle",
           "caption": "grainy, hard" if i < 4 else "soft", "source": "w"} for i in range(5)]
    result = {"neighbours": {"joint": ns}}
    strip = view.neighbour_strip(result, "joint", _thumb)
    assert strip.count("<figure") == 2 and strip.count("×4") == 1  # folded: 4 + 1
    assert strip.index("grainy, hard") < strip.index(">soft<")
    assert view.neighbour_table(result, "joint").count("<tr") == 6  # raw top-5 + header


def test_trust_is_shown_above_the_descriptions():
    from app import view

    result = {"description": {"ra_touch": "", "baseline": ""},
              "warnings": ["no contact detected: the tactile image looks like ..."],
              "trust": {"visual": {"novelty": 1.2, "threshold": 1.5, "novel": False},
                        "tactile": {"novelty": 2.1, "threshold": 1.4, "novel": True,
                                    "contact": 0.9, "contact_threshold": 2.3,
                                    "no_contact": True, "background": False}}}
    md = view.description_md(result, None)
    assert md.index("**Trust:**") < md.index("RA-Touch (with retrieval)")
    assert "✖ no contact" in md and "⚠ unfamiliar" in md and "✓ familiar" in md
    assert "**no contact detected**: nothing is pressed" in md
    assert "<span class='ra-warn'>⚠ no contact detected" in md
    # each warning once: the status shows the others, folded into one line
    status = view.status_md("x", [*result["warnings"], "no contact box given: used TVL's"],
                            None, result)
    assert "no contact detected" not in status and "⚠ 1 note: no contact box given" in status
    # a frame alone read by the colour-blind model (a sensor unlike every rendered unit)
    blind = {**result["trust"]["tactile"], "contact_model": "colour-blind"}
    line = view.trust_lines({**result, "trust": {**result["trust"], "tactile": blind}})[0]
    assert "(flag < 2.30, read blind to colour) ✖ no contact" in line
    assert "blind to colour" not in view.trust_lines(result)[0]
    # uncertain against the background: the frame's second opinion, read alone, is shown
    doubted = {**result["trust"]["tactile"], "state": "uncertain", "background": True,
               "alone": {"state": "no contact", "contact": -2.8}}
    line = view.trust_lines({**result, "trust": {**result["trust"], "tactile": doubted}})[0]
    assert "? contact uncertain; read alone: no contact" in line
    assert "read alone" not in view.trust_lines(result)[0]


def test_the_touch_only_reading_is_marked_on_its_query():
    """The strip of the query whose top caption is what touch alone reads says so: the
    adapted query's for a press whose shape reads as everyday, the paper's tactile query's
    otherwise; no mark for a frame with no contact."""
    from app import view

    tactile = {"no_contact": False, "background": True, "state": "contact",
               "firmness": {"soft": 0.9, "reads": "soft", "regime": "everyday"}}

    def row(caption):
        return [{"id": 1, "score": 0.5, "class_name": "c", "caption": caption}]

    result = {"trust": {"tactile": tactile},
              "neighbours": {"tactile": row("hard, rigid"), "adapted": row("soft, <woven>")}}

    def strip(res, mode):
        return view.neighbour_strip(res, mode, lambda i: np.zeros((4, 4, 3), np.uint8))

    mark = "★ touch alone reads its top caption"
    assert mark in strip(result, "adapted") and mark not in strip(result, "tactile")
    assert "“soft, &lt;woven&gt;”; its shape reads as an everyday press" in strip(result,
                                                                                 "adapted")
    firm = {**tactile, "firmness": {"soft": 0.1, "reads": "hard", "regime": "world"}}
    res = {**result, "trust": {"tactile": firm}}
    assert mark in strip(res, "tactile") and mark not in strip(res, "adapted")
    assert "its shape reads as a firm press" in strip(res, "tactile")
    alone = {**result, "trust": {"tactile": {**tactile, "background": False}}}
    assert "no router read the press" in strip(alone, "tactile")
    alone["trust"]["tactile"]["press_regime"] = {"everyday": 0.9, "regime": "everyday"}
    assert "its tactile embedding (no background) reads as an everyday" in strip(alone,
                                                                                "adapted")
    blank = {**tactile, "no_contact": True, "state": "no contact", "firmness": None}
    res = {**result, "trust": {"tactile": blank}}
    assert mark not in strip(res, "tactile") + strip(res, "adapted")


def test_a_blank_frames_touch_modes_show_no_material():
    """Issue 36: with no contact detected, the modes that read touch do not show the nearest
    captions to an empty gel as a material's (strip and table say why; the JSON keeps them),
    the image query's neighbours stay, and no badge says they were also found by a touch
    mode; a frame called its background within the sensor's noise says so, not a false
    inequality of contact scores."""
    from app import view
    from ratouch.search.modes import QUERY_MODES

    ns = [{"id": i, "score": 0.5, "class_name": "c", "caption": "soft, plush", "source": "w"}
          for i in range(3)]
    tactile = {"novelty": 1.0, "threshold": 1.5, "novel": False, "contact": 7.66,
               "contact_threshold": 0.07, "no_contact": True, "background": True,
               "within_noise": {"change": 0.004, "floor": 0.011}}
    result = {"neighbours": {m: ns for m in QUERY_MODES},
              "trust": {"visual": None, "tactile": tactile}}
    for mode in QUERY_MODES:
        strip, table = view.neighbour_strip(result, mode, _thumb), view.neighbour_table(result, mode)
        if QUERY_MODES[mode].needs_touch:
            assert "<figure" not in strip and view.NO_CONTACT_NEIGHBOURS in strip
            assert "<tr" not in table and view.NO_CONTACT_NEIGHBOURS in table
        else:
            assert strip.count("<figure") == 1 and "ra-shared-badge" not in strip
            assert table.count("<tr") == 4 and "◆" not in table
    line = view.trust_lines(result)[0]
    assert "change vs background 0.004 (within noise < 0.011) ✖ no contact" in line
    assert "contact 7.66" not in line
    # with contact, every mode shows its neighbours and their shared badges
    pressed = {**result, "trust": {"tactile": {**tactile, "no_contact": False}}}
    assert all("<figure" in view.neighbour_strip(pressed, m, _thumb) for m in QUERY_MODES)
    assert "ra-shared-badge" in view.neighbour_strip(pressed, "image", _thumb)


def test_header_says_what_the_corpus_is(fake):
    from types import SimpleNamespace

    from app import view

    assert "procedural-world renders" in view.corpus_provenance(fake.corpus)
    mine = SimpleNamespace(entries=[1, 2], manifest={"source": "/data/my_list.txt"},
                           folder="/data/corpus")
    assert "your own corpus (images from /data/my_list.txt" in view.corpus_provenance(mine)


def test_query_api_k_error_names_k(served, pair_files):
    from gradio_client import Client, handle_file

    url, _, _ = served
    client = Client(url, verbose=False)
    with pytest.raises(Exception, match="K must be a whole number from 1 to 20, got K=2.5"):
        client.predict(handle_file(str(pair_files[0])), None, None, None, None, None, 2.5,
                       api_name="/query")


def test_an_answer_that_read_another_query_is_shown_and_taken_apart_on_that_query(fake, world):
    """A gated answer that read the image query's neighbours (touch withheld): the most
    attended are outlined in the image row, not the joint one; "take retrieval apart" offers
    the image neighbours and regenerates with the gated system, as it answered."""
    import dataclasses

    from app import handlers

    class Gated(type(fake)):
        def _answer(self, req):
            r = super()._answer(req)
            k = len(r.neighbours["image"])
            return dataclasses.replace(
                r, attention={"image": [0.6] + [0.1] * (k - 1), "text": [0.6] + [0.1] * (k - 1)},
                retrieval={"system": "gated", "reads": "image", "kind": "withheld",
                           "touch_weight": 0.0, "why": ["touch is withheld"],
                           "generator": "reader"})

    pipe = Gated()
    visual, _, tactile, bg, *fields, _ = handlers.load_example(world, 7)
    v = handlers.run_query(pipe, _thumb, visual, tactile, *fields, 5)
    assert v.raw["retrieval"]["reads"] == "image"
    assert v.galleries["image"].count("ra-attended") >= 1
    assert "ra-attended" not in v.galleries["joint"]
    image_ids = [n["id"] for n in v.raw["neighbours"]["image"]]
    assert [i for _, i in handlers.neighbour_picker(v.raw).choices] == image_ids
    out = handlers.regenerate(pipe, visual, tactile, *fields, image_ids[:2], v.raw)
    assert pipe.calls[-1]["regenerate"] == image_ids[:2]
    assert pipe.calls[-1]["retrieval"] == "gated"
    assert "2 of the 5 neighbours" in out


def test_taking_retrieval_apart_regenerates_with_the_ticked_neighbours(fake, world):
    from app import handlers
    from ratouch.eval.judge import OfflineJudge

    visual, _, tactile, bg, *fields, _ = handlers.load_example(world, 7)
    v = handlers.run_query(fake, _thumb, visual, tactile, *fields, 5)
    picker = handlers.neighbour_picker(v.raw)
    ids = [n["id"] for n in v.raw["neighbours"]["joint"]]
    assert [i for _, i in picker.choices] == ids and picker.value == ids
    assert all(label.startswith(f"#{i} ") for label, i in picker.choices)
    out = handlers.regenerate(fake, visual, tactile, *fields, ids[1:3], v.raw, OfflineJudge())
    assert fake.calls[-1]["regenerate"] == ids[1:3]
    assert "read 2 neighbours" in out and "2 of the 5 neighbours" in out
    assert f"dropped #{ids[0]}" in out and "soft and grainy" in out  # the original beside it
    assert "judge **" in out  # a labelled example: both are scored
    none = handlers.regenerate(fake, visual, tactile, *fields, [], v.raw)
    assert "no neighbours" in none and "read 0 neighbours" in none
    # nothing to take apart yet, or no tactile image: a message, not an exception
    assert "run a query" in handlers.regenerate(fake, visual, tactile, *fields, ids, None)
    assert "tactile image" in handlers.regenerate(fake, visual, None, *fields, ids, v.raw)
    assert handlers.neighbour_picker(None).choices == []



# ------------------------------------------------------------------------- issue 39: the page follows the registries

@pytest.fixture
def mean_mode():
    """A fourth query mode (the mean of the image and tactile embeddings), registered in this
    test only: nothing of the app names it."""
    from ratouch.search.modes import QUERY_MODES, QueryMode

    def mean(V, T, joint_query):
        q = V + T
        return q / np.linalg.norm(q, axis=1, keepdims=True)

    row = QueryMode("mean", "Mean of image and tactile", "M", "#9467bd",
                    frozenset({"image", "tactile"}), mean)
    QUERY_MODES.register(row)
    try:
        yield row
    finally:
        QUERY_MODES.unregister(row.name)


def test_a_registered_mode_runs_through_the_run_handler(mean_mode, debug_pipeline, world):
    """Issue 39: a fourth mode crashed Run (`QueryView.__new__() takes 12 positional
    arguments but 14 were given`). Through the real pipeline's query path: its gallery and
    table are named outputs, filled; the failure table has its column."""
    from app import handlers, view

    visual, _, tactile, bg, *box, _ = handlers.load_example(world, 7)
    thumb = lambda i: np.zeros((8, 8, 3), np.uint8)  # noqa: E731
    v = handlers.run_query(debug_pipeline, thumb, visual, tactile, *box, 4, background=bg)
    assert not v.status.startswith("**✖"), v.status
    named = v.named()
    assert {"gallery_mean", "table_mean"} <= set(named) == set(handlers.output_names())
    assert "Mean of image and tactile" in named["gallery_mean"]
    assert named["gallery_mean"].count("<figure") >= 1
    assert named["table_mean"].count("<tr") == 5  # header + K=4
    assert view.strip_order()[0] == "joint" and view.strip_order()[-1] == "mean"
    assert ("P@K mean", "precision_mean") in view.case_columns()
    assert len(view.case_widths()) == len(view.case_columns())
    # a table computed before the mode was registered has no such column: shown empty
    frame = view.cases_frame([{k: "x" for _, k in view.case_columns()[:-1]}])
    assert list(frame.columns)[-1] == "P@K mean" and frame.iloc[0, -1] is None
    # without a frame the mode is not available, and says so
    image_only = handlers.run_query(debug_pipeline, thumb, visual, None, *box, 4)
    assert "not available" in image_only.galleries["mean"]


def test_the_page_builds_its_outputs_from_the_registry(mean_mode):
    """The Explore tab has one gallery and one table per registered mode, matched by name:
    a value for an output the event does not have is an error, not a value in the wrong
    place."""
    from app import explore_tab
    from app.app import build_demo
    from app.page import Outputs

    demo = build_demo(FakePipeline())
    ids = {c.get("props", {}).get("elem_id") for c in demo.config["components"]}
    assert {"gallery-mean", "table-mean", "gallery-joint", "stale", "export-json",
            "compare-a"} <= ids
    import gradio as gr

    with gr.Blocks():
        a, b = gr.Markdown(), gr.Markdown()
    out = Outputs({"a": a, "b": b})
    assert out.values({"b": "x"}) == {b: "x"}
    with pytest.raises(KeyError, match="not outputs of this event: \\['c'\\]"):
        out.values({"c": 1})
    assert explore_tab.EXAMPLES  # the examples the page shows


def test_export_link_history_and_comparison(fake, world, pair_files, tmp_path):
    """Keep, share, compare: a run's record carries the inputs' sha256, the model, K, the
    box and the commit; its JSON and neighbours CSV say so; an example's run has a link
    that loads the same query; two runs side by side show what differs."""
    import csv
    import hashlib

    from app import handlers, record
    from app.explore_tab import answer_named
    from app.page import Page

    page = Page(fake, world, None, {"world": world.cfg}, tmp_path, ["small", "large"], 2,
                None, _thumb, commit="abc1234")
    visual, _, tactile, bg, *box, _ = handlers.load_example(world, 12)
    v = handlers.run_query(fake, _thumb, visual, tactile, *box, 4, background=bg)
    first = answer_named(page, v, visual, tactile, bg, 4, "small", tuple(box), [])
    assert first["shown"] == 1 and first["stale"] == "" and len(first["history"]) == 1
    rec = first["history"][0]
    exported = json.loads(Path(first["export_json"].value["path"]).read_text())
    assert exported["commit"] == "abc1234" and exported["model"] == "small"
    assert exported["settings"] == {"k": 4, "box": [float(b) for b in box]}
    sha = hashlib.sha256()
    sha.update(f"{visual.source.shape}:{visual.source.dtype}:".encode())
    sha.update(visual.source.tobytes())
    assert exported["inputs"]["visual"]["sha256"] == sha.hexdigest()
    assert exported["result"]["neighbours"]["joint"] == v.raw["neighbours"]["joint"]
    rows = list(csv.DictReader(Path(first["export_csv"].value["path"]).open()))
    assert len(rows) == len(QUERY_MODES) * 4 and rows[0]["commit"] == "abc1234"
    assert rows[0]["visual_sha256"] == sha.hexdigest() and rows[0]["model"] == "fake"
    # the link reproduces the query: the same example, model and K (and a changed box)
    assert rec.link() == "?example=12&model=small&k=4"
    assert "[Link to this query](?example=12&model=small&k=4)" in first["link"]
    link = handlers.open_link(world, world.cfg, {"example": "12", "model": "small", "k": "4"},
                              page.models)
    assert link.k == 4 and link.model == "small" and link.example.state.label == visual.label
    assert [int(x) for x in link.example[4:8]] == box
    moved = handlers.open_link(world, world.cfg, {"example": "12", "box": "1,2,30,40"}, None)
    assert moved.example.x0 == "1" and "Contact box [1, 2, 30, 40]" in moved.example.box_note
    case = handlers.open_link(world, world.cfg, {"example": "3", "condition": "noisy touch"},
                              None)
    assert "under “noisy touch”" in case.example.state.title
    assert handlers.open_link(world, world.cfg, {}, None) is None
    for bad, says in (({"example": "x"}, "test index"), ({"example": "1", "model": "huge"},
                                                           "not offered"),
                      ({"example": "1", "k": "99"}, "K must be"),
                      ({"example": "1", "condition": "underwater"}, "underwater")):
        # a bad K is the one check of K's ConfigError (issue 39), the others DataError
        with pytest.raises(RATouchError, match=says):
            handlers.open_link(world, world.cfg, bad, page.models)
    # an uploaded pair: no link, the file's own bytes hashed
    up = handlers.upload_visual(str(pair_files[0])).state
    v2 = handlers.run_query(fake, _thumb, up, str(pair_files[1]), None, None, None, None, 5)
    second = answer_named(page, v2, up, str(pair_files[1]), None, 5, "large",
                          (None,) * 4, first["history"])
    rec2 = second["history"][-1]
    assert rec2.number == 2 and rec2.link() is None and "No link" in second["link"]
    assert rec2.inputs["tactile"]["sha256"] == hashlib.sha256(
        pair_files[1].read_bytes()).hexdigest()
    assert rec2.inputs["tactile"]["name"] == "tactile.png"  # its name, not its server path
    assert str(pair_files[1].parent) not in json.dumps(rec2.to_dict())
    # side by side: the second against the first, what differs marked
    html = second["comparison"]
    assert "run 1" in html and "run 2" in html and "ra-differs" in html
    assert "Joint query" in html and "what retrieval did" in html
    assert second["compare_a"].value == 1 and second["compare_b"].value == 2
    assert record.remember([rec] * record.HISTORY_SIZE, rec2)[-1] is rec2
    assert len(record.remember([rec] * record.HISTORY_SIZE, rec2)) == record.HISTORY_SIZE
    # an error keeps nothing and hides the exports
    err = answer_named(page, handlers.error_view("x"), up, None, None, 5, "small",
                       (None,) * 4, second["history"])
    assert err["shown"] is None and "history" not in err


def test_stale_answers_are_marked_and_every_model_is_explained():
    from app import handlers, view

    assert view.stale_html(False) == ""
    assert "inputs changed — press Run" in view.stale_html(True)
    line = handlers.describe_model("cascade")[1]
    assert line.startswith("cascade: each query is answered by `default-tiny` when it is sure")
    assert "else passed on to `default-s`" in line
    md = handlers.models_md(["default-tiny", "default-s", "default-b", "cascade"])
    assert md.count("<div>") == 4 and "ViT-Small row" in md
    assert dict((v, k) for k, v in handlers.model_choices(["default-s", "cascade"])) == {
        "default-s": "default-s — the paper's ViT-Small row",
        "cascade": "cascade — default-tiny when sure, else default-s"}
    # the generators adapted from a pretrained language model say so
    lm = handlers.describe_model("default-s+smollm2-135m")
    assert lm[0] == "the paper's ViT-Small row, smollm2-135m generators"
    assert lm[1].startswith("default-s+smollm2-135m: the paper's ViT-Small row — 384-d")
    assert "pretrained language model `smollm2-135m`" in lm[1]


def test_the_benchmarks_story_dates_the_premise_and_the_real_frames():
    from app.benchmark_tab import story_md
    from ratouch.paths import DOCS

    md = story_md(DOCS, ("2026-11-27", "5a9ccf2"))
    assert "**refuted**" in md and "+0.051 [-0.004, +0.110]" in md  # the verdict's figures
    assert "before the visual prior — made 2026-11-23" in md
    assert "3 draws, before the seeded retrain" in md and "-0.019 [-0.090, +0.064]" in md
    # the newest run leads, with the gated system's verdict on the same runs
    assert "refuted** — the copy ceiling is +0.810 above the baseline on scarce materials, " \
        "yet RA-Touch gains only -0.034 [-0.089, +0.030]" in md
    assert "The `gated` system on the same runs: **refuted** — on scarce materials gated " \
        "gains -0.259 [-0.360, -0.151]" in md
    assert "the shipped weights, 3 draws (seeded trainings" in md
    assert "Taxim's GelSight / Mini | 72 / 72" in md and "reference DIGIT" in md
    # the stored check read Taxim's presses without their background too (--alone)
    assert "presses without their background: contact |" in md and "| 69 / 72 |" in md
    assert "ratouch-docs/premise.md" in md and str(DOCS) not in md
    # the text arm, on each generator it ran on, against the paper's integrator
    assert "**The neighbours as text**" in md
    # the run on the seeded weights (2026-12-03): the arm's figures repeat 2026-11-28's
    assert "| small decoder (shipped) — made 2026-12-03" in md
    assert "| | scarce | 6.622 | 6.577 | 6.162 | -0.415 [-0.585, -0.257] |" in md
    assert "| | world test split | 7.577 | 7.568 | 7.677 | +0.109 [+0.009, +0.207] |" in md
    assert "SmolLM2-135M — made 2026-11-28" in md
    assert "| | world test split | 5.913 | 6.587 | 7.25" in md
    # the default system's measures, read from its file
    assert "**The `fallback` system** (the default)" in md
    assert "| 804 / 804 (0 withheld) |" in md and "+0.397 [+0.185, +0.605]" in md
    assert "-0.177 [-0.348, -0.013]" in md and "| 5.842 / 4.959 / 4.970 |" in md
    assert "| 1 / 2000 |" in md and "seen 0 / 500 · scarce 0 / 500" in md


def test_the_benchmarks_story_shows_no_text_arm_table_without_its_runs(tmp_path):
    from app.benchmark_tab import story_md

    assert "neighbours as text" not in story_md(tmp_path, None)
    assert "`fallback` system** (the default): " in story_md(tmp_path, None)
    assert "*no result yet* (`python scripts/why_withhold.py --system fallback" in \
        story_md(tmp_path, None)

"""The encoder cascade (`ratouch.serve.cascade`), its calibration rule
(`ratouch.ship.cascade`) and the per-query model choice (`ratouch.serve.models`); the
serving ones over the debug pipeline (the real query path, untrained weights)."""

from __future__ import annotations

import dataclasses
import json
import os
import sys

import numpy as np
import pytest

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.serve.cascade import Cascade, CascadeCalibration, joint_confidence
from ratouch.serve.models import ModelChoice
from ratouch.serve.request import QueryRequest, answer_one
from ratouch.ship.cascade import choose_thresholds

pytestmark = pytest.mark.usefixtures("one_thread")


def test_confidence_measures():
    scores = np.array([[0.9, 0.5, 0.4], [0.6, 0.59, 0.58]])
    ids = np.array([[0, 1, 2], [3, 4, 5]])
    classes = np.array(["a", "a", "b", "c", "c", "c"])
    assert joint_confidence(scores, ids, classes, "top1").tolist() == [0.9, 0.6]
    np.testing.assert_allclose(joint_confidence(scores, ids, classes, "margin"),
                               [0.9 - 0.6, 0.6 - 0.59])
    np.testing.assert_allclose(joint_confidence(scores, ids, classes, "agreement"), [2 / 3, 1])
    with pytest.raises(ConfigError, match="unknown confidence measure"):
        joint_confidence(scores, ids, classes, "vibes")


def test_threshold_rule_keeps_the_large_stage_accuracy():
    rng = np.random.default_rng(0)
    n = 400
    conf = rng.random(n)
    large = {"precision": np.full(n, 0.6), "f1": np.full(n, 0.5)}
    # the small stage is better than the large one when confident, worse otherwise
    small = {"precision": np.where(conf > 0.5, 0.9, 0.1), "f1": np.where(conf > 0.5, 0.8, 0.1)}
    (t,), summary = choose_thresholds([conf], [small, large])
    here = conf >= t
    for m in ("precision", "f1"):
        assert np.where(here, small[m], large[m]).mean() >= large[m].mean()
    # the lowest such threshold: one step lower breaks the rule
    lower = np.sort(conf)[np.searchsorted(np.sort(conf), t) - 1]
    assert np.where(conf >= lower, small["f1"], large["f1"]).mean() < large["f1"].mean() or \
        np.where(conf >= lower, small["precision"], large["precision"]).mean() < 0.6
    assert summary["answered_by"][0] == pytest.approx(here.mean(), abs=1e-4)
    assert 1 < summary["stages_run"] < 2
    # a small stage worse everywhere never answers
    (t,), summary = choose_thresholds([conf], [{m: v * 0 for m, v in small.items()}, large])
    assert t == np.inf and summary["answered_by"] == [0.0, 1.0]


def test_calibration_file_round_trip(tmp_path):
    cal = CascadeCalibration(("default-tiny", "default-s"), "agreement", 5, (0.6,),
                             {"n_validation": 10})
    back = CascadeCalibration.load(cal.save(tmp_path / "c.json"))
    assert back == cal
    never = CascadeCalibration(("a", "b"), "top1", 5, (np.inf,))
    assert CascadeCalibration.load(never.save(tmp_path / "n.json")).thresholds == (np.inf,)
    with pytest.raises(DataNotFoundError, match="ratouch train cascade"):
        CascadeCalibration.load(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(DataError, match="not a cascade calibration"):
        CascadeCalibration.load(tmp_path / "bad.json")
    with pytest.raises(ConfigError, match="thresholds"):
        CascadeCalibration(("a", "b", "c"), "top1", 5, (0.5,))


def _cascade(pipeline, threshold: float) -> Cascade:
    name = pipeline.encoders.name
    return Cascade([pipeline, pipeline],
                   CascadeCalibration((name, name), "agreement", 5, (threshold,)))


def _ask(answerer, s, **kw) -> dict:
    """A world sample's query (with its tactile image and box), answered, as JSON."""
    return answer_one(answerer, QueryRequest.decode(s.visual, s.tactile, box=s.box,
                                                    **kw)).to_dict()


def test_cascade_answers_with_the_first_confident_stage(debug_pipeline, world):
    pipeline = debug_pipeline
    s = world.sample("test", 150)
    alone = pipeline.query(s.visual, s.tactile, box=s.box)
    first = _ask(_cascade(pipeline, -np.inf), s)
    last = _ask(_cascade(pipeline, np.inf), s)
    assert "cascade" not in alone and alone["encoder"] == "debug"
    assert first["cascade"]["stage"] == 0 and not first["cascade"]["escalated"]
    assert last["cascade"]["stage"] == 1 and last["cascade"]["escalated"]
    # the confidence is measured at the first stage only; the last stage always answers
    assert len(first["cascade"]["confidence"]) == len(last["cascade"]["confidence"]) == 1
    assert "earlier_stages" in last["timings_ms"] and "earlier_stages" not in first["timings_ms"]
    for r in (first, last):  # the same model at both stages: the same answer
        assert r["description"] == alone["description"]
        assert [n["id"] for n in r["neighbours"]["joint"]] == \
            [n["id"] for n in alone["neighbours"]["joint"]]
    # the threshold really decides: at the measured confidence the first stage answers
    c = first["cascade"]["confidence"][0]
    assert _ask(_cascade(pipeline, c), s)["cascade"]["stage"] == 0
    assert _ask(_cascade(pipeline, c + 1e-6), s)["cascade"]["stage"] == 1


def test_cascade_batches_mixed_requests(debug_pipeline, world):
    casc = _cascade(debug_pipeline, np.inf)
    a, b = world.sample("test", 160), world.sample("test", 170)
    first = QueryRequest.decode(a.visual, a.tactile, box=a.box)
    out = casc.answer([first,
                       QueryRequest.decode(b.visual, box=b.box),  # no tactile: no joint query
                       dataclasses.replace(QueryRequest.decode(a.visual),  # past MAX_K:
                                           k=10_000)])  # more than the corpus has
    out[:2] = [r.to_dict() for r in out[:2]]
    assert out[0]["cascade"]["escalated"]
    assert out[1]["cascade"] == {**out[1]["cascade"], "stage": 0, "confidence": []}
    assert isinstance(out[2], ConfigError) and "K must be" in str(out[2])
    again = casc.regenerate(first, [n["id"] for n in out[0]["neighbours"]["joint"]])
    assert again["description"]["ra_touch"] == out[0]["description"]["ra_touch"]
    assert casc.model() is casc and casc.corpus is debug_pipeline.corpus
    with pytest.raises(ConfigError, match="not a stage"):
        casc.regenerate(first, [1], encoder="default-xl")


def test_model_choice_routes_each_request(debug_pipeline, world):
    pipeline = debug_pipeline
    loads = []

    def load(name):
        loads.append(name)
        return pipeline

    choice = ModelChoice("default-s", ["default-s", "other"], load=load)
    assert loads == ["default-s"]  # the others load on first use
    s = world.sample("test", 180)
    out = choice.answer([QueryRequest.decode(s.visual, s.tactile, box=s.box),
                         QueryRequest.decode(s.visual, s.tactile, box=s.box, model="other"),
                         QueryRequest.decode(s.visual, model="nope")])
    assert loads == ["default-s", "other"]
    assert out[0].description == out[1].description
    assert isinstance(out[2], ConfigError) and "unknown model 'nope'" in str(out[2])
    with pytest.raises(ConfigError, match="unknown model"):
        answer_one(choice, QueryRequest.decode(s.visual, model="nope"))
    assert choice.model().corpus is pipeline.corpus  # the default model, asked explicitly
    assert choice.model("other") is pipeline


def test_the_page_says_which_model_answered_and_why():
    from app.view import model_note

    assert model_note({"encoder": "default-s"}) == " · model `default-s`"
    assert model_note({}) == ""
    note = model_note({"encoder": "default-s", "cascade": {
        "answered_by": "default-s", "stage": 1, "escalated": True, "confidence": [0.0008],
        "thresholds": [0.0456], "measure": "margin"}})
    assert note == " · answered by `default-s` (cascade, escalated: margin 0.001 < 0.046)"
    never = model_note({"cascade": {"answered_by": "b", "stage": 1, "escalated": True,
                                    "confidence": [0.5], "thresholds": [None],
                                    "measure": "top1"}})
    assert "top1 0.500 < ∞" in never


def test_model_choice_builds_the_cascade_from_its_own_models(debug_pipeline, tmp_path,
                                                            monkeypatch):
    import ratouch.paths
    import ratouch.serve.models as models

    pipeline = debug_pipeline
    name = pipeline.encoders.name
    path = CascadeCalibration((name, name), "margin", 5, (0.05,)).save(tmp_path / "c.json")
    monkeypatch.setattr(ratouch.paths, "cascade_calibration", lambda *a: path)
    loads = []
    monkeypatch.setattr(models, "load_model", lambda n, **kw: loads.append(n) or pipeline)
    choice = ModelChoice("cascade", [name, "cascade"])  # the cascade is the default model
    assert loads == [name]  # its stages are the choice's own model, loaded once
    assert choice.model("cascade").stages == [pipeline, pipeline]
    assert choice.model(name) is pipeline and loads == [name]


def test_models_are_prepared_in_the_background_while_the_default_answers():
    """`prepare` loads the other models in a thread; while one loads, its state says so and
    the default model is served at once (no lock held across a load)."""
    import threading
    import time

    from ratouch.serve.models import ModelChoice

    release = threading.Event()

    def load(name):
        if name == "slow":
            release.wait(10)
        return f"model {name}"

    choice = ModelChoice("fast", ["fast", "slow"], load=load)
    assert choice.state("slow") == ("not prepared", None)
    thread = choice.prepare(["slow"])
    for _ in range(100):
        if choice.state("slow")[0] == "preparing":
            break
        time.sleep(0.01)
    state, seconds = choice.state("slow")
    assert state == "preparing" and seconds >= 0
    t0 = time.perf_counter()
    assert choice.model("fast") == "model fast" and time.perf_counter() - t0 < 0.5
    release.set()
    thread.join(5)
    assert choice.state("slow") == ("ready", None) and choice.model("slow") == "model slow"


def test_a_query_waiting_for_a_model_being_prepared_does_not_hold_the_preparation_back():
    """A batch of queries waiting for a model that `prepare` is loading is not foreground
    work the loading must yield to (`waiting_for_background`): the load runs at full pace,
    and the prepare thread runs at the lowest priority, its torch work on one intra-op
    thread."""
    import threading
    import time

    import torch

    from ratouch.threads import BACKGROUND_NICE, foreground, yield_to_foreground

    seen = {}

    def load(name):
        if name == "slow":
            seen["threads"] = torch.get_num_threads()
            seen["nice"] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
            t0 = time.perf_counter()
            for _ in range(5):                         # five "corpus batches"
                yield_to_foreground(2.0)
            seen["waited"] = time.perf_counter() - t0
        return f"model {name}"

    choice = ModelChoice("fast", ["fast", "slow"], load=load)
    with foreground():  # a query batch asking for the model being prepared
        thread = choice.prepare(["slow"])
        time.sleep(0.05)
        assert choice.model("slow") == "model slow"
    thread.join(5)
    assert seen["threads"] == 1
    if sys.platform.startswith("linux"):  # the lowest priority, for this thread only
        assert seen["nice"] == BACKGROUND_NICE
        assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) < BACKGROUND_NICE
    assert seen["waited"] < 5.0  # not 5 x 2 s: the query was waiting for it, not running


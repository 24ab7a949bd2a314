"""scripts/load_test.py: its `/query` client against the app over fake pipelines (it sends every
input the endpoint takes, a changed endpoint stops it with a clear message, an error answer is
counted by what it says), and (slow) the script itself against the real app, bounded: 2 clients
x 2 queries."""

from __future__ import annotations

import importlib.util
import json
import time
from pathlib import Path

import pytest

from conftest import HAVE_ASSETS, FakePipeline, free_port

REPO = Path(__file__).resolve().parents[1]
BOUND_S = 480  # the bounded real run: launch, models, 2 + 2 x 2 queries, report
_DEMOS: dict = {}  # the apps the fixtures launched, by fixture


@pytest.fixture(scope="module")
def load_test():
    """scripts/load_test.py as a module."""
    spec = importlib.util.spec_from_file_location("load_test", REPO / "scripts" / "load_test.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def choice_app():
    """The app over two fake models ("small", the default, and "large"), on 127.0.0.1."""
    from app.app import build_demo, launch
    from ratouch.serve.models import ModelChoice

    pipes = {"small": FakePipeline(), "large": FakePipeline()}
    demo = build_demo(ModelChoice("small", ["small", "large"], load=pipes.__getitem__),
                      models=["small", "large"])
    port = free_port()
    launch(demo, "127.0.0.1", port, block=False)
    _DEMOS["choice"] = demo  # the sessions test reads the app's sessions
    yield port, pipes
    demo.close()


@pytest.fixture(scope="module")
def pairs(load_test, tmp_path_factory):
    return load_test.write_pairs(tmp_path_factory.mktemp("load-pairs"))


def test_the_client_sends_every_input_the_endpoint_takes(load_test, choice_app, pairs):
    port, pipes = choice_app
    params = load_test.endpoint_inputs(port)
    load_test.check_inputs(params)  # the endpoint takes what the script sends
    names = [p["parameter_name"] for p in params]
    assert names == [n for n, _ in load_test.INPUTS]
    assert load_test.choose_model(params) == "small"  # the app's default
    visual, tactile, box, background = pairs[0]
    for model in ("small", "large"):
        client = load_test.ApiClient(port, inputs=names,
                                     model=load_test.choose_model(params, model))
        out = client.query(visual, tactile, box, 4, background=background)
        assert set(load_test.RESULT_KEYS) <= set(out) and len(out["neighbours"]["joint"]) == 4
        assert pipes[model].calls[-1]["box"] == box and pipes[model].calls[-1]["k"] == 4
        assert pipes[model].calls[-1]["background"]  # the sensor's frame reached the model
        assert out["description"]["ra_touch"] == "soft and grainy"
    client.query(visual, tactile, box, 4)  # the background is optional
    assert not pipes["large"].calls[-1]["background"]
    assert pipes["large"].calls[-1]["retrieval"] is None  # the system: the app's default
    assert len(pipes["small"].calls) == 1 and len(pipes["large"].calls) == 2


def test_a_changed_endpoint_stops_the_test_with_a_clear_message(load_test, choice_app):
    port, _ = choice_app
    params = load_test.endpoint_inputs(port)
    # the endpoint before it took the model (the bug): 7 inputs where the script sends 10
    with pytest.raises(load_test.LoadTestError, match=r"takes 7 inputs .* sends 10 .*model"):
        load_test.check_inputs(params[:-3])
    added = params + [{"parameter_name": "label", "component": "Textbox",
                       "label": "ground-truth caption"}]
    with pytest.raises(load_test.LoadTestError,
                       match=r"takes 11 inputs .*label \(Textbox\).* update INPUTS"):
        load_test.check_inputs(added)
    with pytest.raises(load_test.LoadTestError, match=r"'huge' is not offered .*small"):
        load_test.choose_model(params, "huge")
    client = load_test.ApiClient(port, inputs=("visual", "tactile", "box", "k", "model"))
    with pytest.raises(load_test.LoadTestError, match=r"inputs \['box'\]"):
        client.values({}, {}, (1, 2, 3, 4), 5)


def test_an_error_answer_is_counted_by_what_it_says(load_test, choice_app, pairs):
    port, _ = choice_app
    # Gradio's error event: {"error": message}, message null when the app hides it
    assert load_test.error_message('{"error": null}') == load_test.NO_MESSAGE
    assert load_test.error_message("null") == load_test.NO_MESSAGE
    assert load_test.error_message('{"error": "K must be"}') == "K must be"
    names = [p["parameter_name"] for p in load_test.endpoint_inputs(port)]
    client = load_test.ApiClient(port, inputs=names, model="small")
    visual, tactile, box, background = pairs[0]
    with pytest.raises(RuntimeError, match=r"/query failed: .*empty or inverted"):
        client.query(visual, tactile, (9, 9, 3, 3), 5)
    assert load_test.check_answer({"neighbours": {"joint": [{}] * 3},
                                   "description": {"ra_touch": "soft"}, "timings_ms": {},
                                   "warnings": [], "box": None}, 3)
    with pytest.raises(RuntimeError, match=r"lacks \['timings_ms', 'warnings', 'box'\]"):
        load_test.check_answer({"neighbours": {}, "description": {}}, 3)
    # the connection is still usable after an error answer
    assert client.query(visual, tactile, box, 2)["box"] == list(box)


@pytest.fixture(scope="session")
def app_corpus(shipped_corpus):
    """The real pipeline's corpus for `python -m app --corpus`: the session's 600-entry world
    corpus, embedded with default-s (`conftest.shipped_corpus`, the one `real_pipeline`
    reads)."""
    if not HAVE_ASSETS:
        pytest.skip("the trained retriever/generator weights are not in assets/")
    return shipped_corpus


@pytest.mark.slow
def test_the_load_test_runs_against_the_real_app(load_test, app_corpus, tmp_path, capsys):
    """`python -m app` with the shipped default-s models on a 600-entry corpus, then the
    script's main: 2 single-user queries, 2 clients x 2 queries, all answered, in bounded
    time (the script's --timeout; the full 16 x 10 run is the lead's)."""
    out = tmp_path / "report.json"
    t0 = time.monotonic()
    rc = load_test.main(["--clients", "2", "--queries", "2", "--single", "2",
                         "--deadline", "120", "--timeout", str(BOUND_S),
                         "--corpus", str(app_corpus), "--batch-workers", "2",
                         "--warm-load", "1", "--json", str(out)])
    seconds = time.monotonic() - t0
    printed = capsys.readouterr()
    assert rc == 0, printed.err + printed.out
    report = json.loads(out.read_text())
    assert report["failures"] == 0 and report["failure_kinds"] == {}, report["failure_kinds"]
    assert report["not_run"] == 0 and report["answered"] == 4
    assert report["single"]["n"] == 2 and report["under_load"]["n"] == 4
    assert report["endpoint_inputs"] == [n for n, _ in load_test.INPUTS]
    assert report["model"] == "default-s"
    assert report["warm_load"]["queries"] == 2 and report["warm_load"]["clients_failed"] == 0
    assert {"ready_http_s", "ready_query_s", "single", "under_load", "throughput_qps",
            "cpu_s_per_query", "rss_before_mib", "rss_after_mib", "targets",
            "server_log_tail", "total_s"} <= set(report)
    assert report["targets"]["no failures"]
    assert seconds < BOUND_S + 30
    print(f"\nbounded load test: {seconds:.0f} s in all\n" + load_test.format_report(report))


def test_a_client_keeps_one_session_and_can_open_one_per_query(load_test, choice_app, pairs):
    """A client keeps one Gradio session for its queries (as a browser tab or gradio_client
    does); with `session=False` the app opens a new one for every query."""
    port, _ = choice_app
    sessions = _DEMOS["choice"].server_app.state_holder.session_data
    names = [n for n, _ in load_test.INPUTS]
    visual, tactile, box, _ = pairs[0]
    one = load_test.ApiClient(port, inputs=names, model="small")
    before = set(sessions)
    for _ in range(2):
        one.query(visual, tactile, box, 4)
    assert set(sessions) - before == {one.session_hash}
    fresh = load_test.ApiClient(port, inputs=names, model="small", session=False)
    assert fresh.session_hash is None
    before = set(sessions)
    for _ in range(2):
        fresh.query(visual, tactile, box, 4)
    assert len(set(sessions) - before) == 2

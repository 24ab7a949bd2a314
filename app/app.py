"""RA-Touch Explorer: the Gradio app over `ratouch.serve.pipeline.RATouchPipeline`.

Upload a visual and a tactile image (or pick a pair from the world's test split), mark the
contact box, and compare the neighbours that image, tactile and joint queries retrieve, where
they fall in the PCA frame, and the descriptions generated with and without retrieval.
`build_demo(pipeline)` builds the UI around a serving `Answerer` (`ratouch.serve.request`);
`main()` loads one and serves it.
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys
import time
from pathlib import Path
from types import SimpleNamespace

if __package__ in (None, ""):  # run as a script (`python app/app.py`, as `ratouch app` does):
    sys.path[0] = str(Path(__file__).resolve().parents[1])  # let `app` name the package

import gradio as gr  # noqa: E402

from app import handlers, view  # noqa: E402
from ratouch.errors import RATouchError  # noqa: E402
from ratouch.eval import failures  # noqa: E402
from ratouch.eval.judge import OfflineJudge  # noqa: E402
from ratouch.paths import DOCS  # noqa: E402
from ratouch.serve.batcher import QueryBatcher  # noqa: E402
from ratouch.serve.loader import BackgroundPipeline  # noqa: E402
from ratouch.world.sampler import TEST_SIZE, World  # noqa: E402

log = logging.getLogger(__name__)

# A few structured close-ups (indices < 46), then wild scenes, spread over the test split.
EXAMPLES = [0, 12, 40, 60, 140, 190, 290, 390]
THUMBNAIL_SIDE = 128
VISUAL_HEIGHT = 270  # the preview's display height: the inputs fit beside the answer
TACTILE_HEIGHT = 130
EXAMPLES_HEIGHT = 96
MAX_K = handlers.MAX_K
SESSION_TTL_S = 2 * 3600

CSS = """
.ra-muted { color: var(--body-text-color-subdued); font-size: 0.85em; }
.ra-timings * { color: var(--body-text-color-subdued) !important; font-size: 12px !important; }
.ra-table { font-size: 0.82em; width: 100%; }
.ra-table td, .ra-table th { padding: 2px 4px; vertical-align: top; }
.ra-shared { white-space: nowrap; color: #b8860b; }
.ra-gallery .caption-label { white-space: normal; font-size: 0.72em; line-height: 1.2;
                             max-width: calc(100% - 8px); }
#inputs, #answer { gap: 6px; }
#inputs .form { gap: 4px; }
#inputs input[type=text] { padding: 2px 6px; }
#status { font-size: 0.85em; }
.ra-notes summary { white-space: nowrap; overflow: hidden; text-overflow: ellipsis;
                    cursor: pointer; color: #92400e; }
.ra-notes div { margin: 2px 0 2px 12px; }
.ra-warn { color: #92400e; font-size: 0.92em; }
#status p, #status ul { margin: 0; }
#header h2 { margin: 0 0 2px 0; }
#header p { margin: 0; }
.ra-about summary { cursor: pointer; color: var(--body-text-color-subdued); font-size: 0.85em; }
.ra-about { font-size: 0.85em; }
#description p, #description blockquote { margin: 0 0 4px 0; }
#description ul { margin: 0 0 4px 0; }
#description li { margin: 0; font-size: 0.92em; }
mark.ra-carried { background: #fde68a; color: inherit; padding: 0 2px; border-radius: 3px; }
.ra-mode { display: flex; align-items: flex-start; gap: 8px; margin: 2px 0; }
.ra-mode-title { flex: 0 0 96px; font-weight: 600; font-size: 0.9em; line-height: 1.25; }
.ra-strip { display: flex; gap: 6px; overflow-x: auto; min-width: 0; flex: 1 1 auto;
            padding-bottom: 2px; }
.ra-tile { flex: 0 0 76px; width: 76px; margin: 0; position: relative; }
.ra-tile img { width: 76px; height: 76px; object-fit: cover; display: block;
               border-radius: 4px; border: 2px solid transparent; box-sizing: border-box; }
.ra-tile.ra-attended img { border-color: #2ca02c; border-width: 3px; }
.ra-tile figcaption { font-size: 10.5px; line-height: 1.2; height: 2.4em; overflow: hidden;
                      display: -webkit-box; -webkit-line-clamp: 2;
                      -webkit-box-orient: vertical; word-break: break-word; }
.ra-badge, .ra-count, .ra-shared-badge { position: absolute; font-size: 10px; color: #fff;
                                         padding: 0 3px; border-radius: 3px; line-height: 1.4; }
.ra-badge { top: 3px; left: 3px; background: rgba(0, 0, 0, 0.65); }
.ra-count { top: 3px; right: 3px; background: #b45309; font-weight: 700; }
.ra-shared-badge { top: 58px; left: 3px; background: rgba(184, 134, 11, 0.9); }
.js-plotly-plot, .plot-container { max-width: 100%; }
"""

MAX_FIGURES = 12  # plot slots of the Benchmarks tab
FAILURE_ROWS = 50  # worst cases shown at once

FAILURES_ABOUT = """### Failure cases
Every pair of the world's test split (46 structured close-ups + 356 wild scenes) under a few
stress conditions, described by the no-retrieval baseline and by RA-Touch, each description
scored by the offline judge (1–10) against the ground-truth label, and the material
precision@K of the neighbours that the image, tactile and joint queries retrieve. The table
is computed once per pipeline (about half a minute on a 2-core CPU, with a progress bar) and
cached; it is never computed at start-up. Conditions:
"""


def build_demo(pipeline, world=None, failure_options: dict | None = None,
               docs: str | Path | None = None, models: list[str] | None = None,
               max_batch: int | None = None, model_state=None) -> gr.Blocks:
    """The app around a serving answerer (read-only, shared by all sessions).

    Args:
        pipeline: an `Answerer` that also names its loaded model (`model(name)`: its
            `corpus`, `name`, `regenerate`): a `RATouchPipeline`, a `QueryBatcher` or a
            `ModelChoice`, or a `ratouch.serve.loader.BackgroundPipeline` still loading one
            (whose `ready()` and `status()` the header shows).
        world: the `World` whose test split gives the examples (default: the default world).
        failure_options: `ratouch.eval.failures.load_or_compute`'s k / conditions / indices
            (default: K=5, every condition, the whole test split, on `world`'s config).
        docs: the folder holding `results.md` and `figures/*.json` (default: the repo's docs/).
        models: the models a query may choose (encoder sets, "cascade"), the first being the
            default, for a pipeline that offers the choice (`ratouch.serve.models.ModelChoice`);
            None: the pipeline's one model, no choice.
        max_batch: how many concurrent queries the pipeline answers together (None: a
            `QueryBatcher`'s own `max_batch`, else 2).
        model_state: name -> `ModelChoice.state(name)` (never waits), for saying that a
            model chosen is still being prepared; None: every model is ready.
    """
    world = world or World()
    try:  # scores the descriptions of labelled examples; shared, read-only
        judge = OfflineJudge()
    except RATouchError as e:  # e.g. no judge calibration: the view simply has no scores
        log.warning("no judge scores: %s", e)
        judge = None
    options = {"world": world.cfg, "k": 5, "conditions": failures.DEFAULT_CONDITIONS,
               **(failure_options or {})}
    docs = Path(docs) if docs is not None else DOCS

    @functools.lru_cache(maxsize=512)  # corpus thumbnails are re-rendered; keep recent ones
    def thumbnail(i: int):
        return pipeline.model().corpus.thumbnail(i, THUMBNAIL_SIDE)

    if max_batch is None:
        max_batch = pipeline.max_batch if isinstance(pipeline, QueryBatcher) else 2
    with gr.Blocks(title="RA-Touch Explorer", delete_cache=(1800, SESSION_TTL_S)) as demo:
        ui = _layout(pipeline, world, options["conditions"], models)
        _wire(demo, ui, pipeline, world, thumbnail, options, docs, judge, bool(models),
              max_batch, model_state)
    demo.ratouch_docs = docs  # `launch` serves its images (and nothing else from disk)
    return demo


def _pending(pipeline) -> bool:
    """Whether the models are still loading (or failed to): a
    `ratouch.serve.loader.BackgroundPipeline` says so; anything else is loaded."""
    ready = getattr(pipeline, "ready", None)
    return callable(ready) and not ready()


def _load_seconds(pipeline) -> float | None:
    """How long the default model took to load (a `BackgroundPipeline`'s), else None."""
    return getattr(pipeline, "seconds", None)


def _corpus_size(pipeline) -> int:
    """Entries of the corpus the loaded models search (MAX_K while they load)."""
    return MAX_K if _pending(pipeline) else len(pipeline.model().corpus.entries)


STEPS = ("Describe how a surface feels, with retrieval (RA-Touch) and without (baseline): "
         "**photo → contact box → tactile frame → background (optional) → Run**, or click "
         "an example on the right.")


def _header(pipeline) -> str:
    """The title, the steps in one line, the models' state, and what the model and corpus
    are in a collapsed note (plain-text marks: Debian's Chromium lacks the emoji glyphs)."""
    title = f"## RA-Touch Explorer\n{STEPS}"
    if _pending(pipeline):
        status = pipeline.status()
        if status == "loading":
            return (f"{title} · Models `{pipeline.name}`: loading the models "
                    f"({time.perf_counter() - pipeline.started:.0f} s so far): browse "
                    "examples meanwhile; a query waits until they are ready")
        return f"{title} · Models `{pipeline.name}`: ✖ {status}"
    model = pipeline.model()
    prior = getattr(getattr(model, "encoders", None), "prior_note", None)
    about = (f"encoder `{model.name}` · {view.corpus_provenance(model.corpus)}"
             + (f" · {prior}" if prior else ""))
    return (f"{title}\n<details class='ra-about'><summary>About the model and corpus"
            f"</summary>{about}</details>")


def _layout(pipeline, world, conditions, models: list[str] | None) -> SimpleNamespace:
    """Place the components; returns them by name."""
    ui = SimpleNamespace(state=gr.State(None, time_to_live=SESSION_TTL_S))
    n_corpus = _corpus_size(pipeline)
    # refreshed on every page load, and by the timer while the models load
    ui.header = gr.Markdown(_header(pipeline), elem_id="header")
    ui.timer = gr.Timer(2.0, active=_pending(pipeline))
    with gr.Tabs(elem_id="tabs") as ui.tabs:
        with gr.Tab("Explore", id="explore", elem_id="tab-explore"):
            _explore_tab(ui, world, n_corpus, TEST_SIZE, models)
        with gr.Tab("Failure cases", id="failures", elem_id="tab-failures") as ui.failures_tab:
            gr.Markdown(FAILURES_ABOUT + view.conditions_md(
                {c: failures.CONDITIONS[c] for c in conditions}))
            with gr.Row(equal_height=True):
                ui.subset = gr.Radio(["all", *failures.SUBSETS], value="all", label="subset",
                                     elem_id="fail-subset")
                ui.condition = gr.Dropdown(["all", *conditions], value="all",
                                           label="condition", elem_id="fail-condition")
                ui.fail_view = gr.Radio(list(failures.VIEWS.values()),
                                        value=failures.VIEWS["ra_lowest"], label="view",
                                        elem_id="fail-view")
                ui.compute = gr.Button("Compute the failure table", elem_id="fail-compute",
                                       min_width=120, scale=0, size="sm")
            ui.fail_status = gr.Markdown(elem_id="fail-status")
            ui.fail_summary = gr.Dataframe(label="per condition and subset (means)",
                                           interactive=False, elem_id="fail-summary",
                                           max_height=260, visible=False)
            ui.cases = gr.Dataframe(label="worst cases — click a row to open it in Explore",
                                    interactive=False, wrap=True, elem_id="fail-cases",
                                    max_height=600, column_widths=view.CASE_WIDTHS,
                                    visible=False)
        with gr.Tab("Benchmarks", id="benchmarks", elem_id="tab-benchmarks") as ui.bench_tab:
            with gr.Row():
                ui.fig_note = gr.Markdown(elem_id="bench-note")
                ui.reload = gr.Button("Reload", size="sm", min_width=80, scale=0)
            # one figure per row: the charts' legends and axis labels need the full width
            ui.figures = [gr.Plot(visible=False, elem_id=f"bench-fig-{i}")
                          for i in range(MAX_FIGURES)]
            ui.report = gr.Markdown(elem_id="bench-report")
    with gr.Row(visible=False):  # the /query API's own inputs and output
        ui.api_visual = gr.File(label="visual image", file_types=["image"])
        ui.api_tactile = gr.File(label="tactile image", file_types=["image"])
        ui.api_background = gr.File(label="sensor background", file_types=["image"])
        ui.api_out = gr.JSON()
        ui.api_button = gr.Button()
    return ui


def _explore_tab(ui: SimpleNamespace, world, n_corpus: int, test_size: int,
                 models: list[str] | None) -> None:
    # one screen: the inputs on the left, the answer on the right (examples to start with,
    # then the trust line, both descriptions, what retrieval did and each mode's first
    # neighbours); the PCA, the tables and the details below
    with gr.Row(equal_height=False):
        with gr.Column(scale=5, min_width=420, elem_id="inputs"):
            ui.visual = gr.Image(
                label="1 · Photo — 2 · click two opposite corners of the contact box",
                type="filepath", image_mode=None, sources=["upload", "clipboard"],
                format="png", height=VISUAL_HEIGHT, elem_id="visual")
            with gr.Row():
                # text fields: empty until a box is marked (a Number would show 0 0 0 0,
                # which reads as a real zero-size box)
                ui.fields = [gr.Textbox(value="", label=n, placeholder="—", max_lines=1,
                                        elem_id=f"box-{n}", min_width=60)
                             for n in ("x0", "y0", "x1", "y1")]
                ui.reset = gr.Button("Default box", size="sm", min_width=60)
            ui.box_note = gr.Markdown(elem_id="box-note")
            with gr.Row():
                ui.tactile = gr.Image(label="3 · Tactile frame (DIGIT / GelSight)",
                                      type="filepath", image_mode=None, format="png",
                                      sources=["upload", "clipboard"], height=TACTILE_HEIGHT,
                                      elem_id="tactile")
                ui.background = gr.Image(label="4 · Sensor background (optional)",
                                         type="filepath", image_mode=None, format="png",
                                         sources=["upload"], height=TACTILE_HEIGHT,
                                         elem_id="background")
            with gr.Row():
                ui.k = gr.Slider(1, min(MAX_K, n_corpus), value=min(5, n_corpus), step=1,
                                 label=f"K (neighbours per query, 1–{min(MAX_K, n_corpus)})",
                                 elem_id="k", scale=3)
                # the encoder size; "cascade": the smallest confident encoder answers
                ui.model = gr.Dropdown(models or [""], value=(models or [""])[0],
                                       label="model (encoder size)", elem_id="model",
                                       interactive=bool(models and len(models) > 1),
                                       visible=bool(models), scale=2)
            ui.model_note = gr.Markdown(elem_id="model-note", elem_classes="ra-muted")
            ui.run = gr.Button("5 · Run query", variant="primary", elem_id="run")
        with gr.Column(scale=7, min_width=560, elem_id="answer"):
            # open on the first screen (one click loads a pair and runs it); closed after a
            # result, which takes its place
            with gr.Accordion("Start here: click an example from the world's test split to "
                              "load and run it", open=True, elem_id="examples-box"
                              ) as ui.examples_box:
                ui.examples = gr.Gallery(
                    handlers.example_gallery(world, EXAMPLES), columns=len(EXAMPLES),
                    height=EXAMPLES_HEIGHT, allow_preview=False, show_label=False,
                    elem_id="examples", elem_classes="ra-gallery", object_fit="cover")
                with gr.Row():
                    ui.index = gr.Number(label=f"or any test index (0–{test_size - 1})",
                                         value=0, precision=0, minimum=0,
                                         maximum=test_size - 1, min_width=120)
                    ui.load = gr.Button("Load example", size="sm", min_width=80)
            # what was queried (box used, model) and the warnings the trust block does not
            # show, then the answer
            ui.status = gr.Markdown(elem_id="status")
            ui.description = gr.Markdown(elem_id="description")
            # each mode's neighbours: a row of fixed-size tiles (duplicates folded, ×n)
            ui.galleries = [gr.HTML(elem_id=f"gallery-{mode}") for mode in view.MODES]
    ui.tables = []
    with gr.Row(equal_height=False):
        for mode in view.MODES:
            with gr.Column(min_width=260):
                gr.Markdown(view.mode_header(mode))
                ui.tables.append(gr.HTML(elem_id=f"table-{mode}"))
    ui.plot = gr.Plot(label="PCA", elem_id="pca")
    with gr.Accordion("Take retrieval apart: untick neighbours RA-Touch reads and regenerate "
                      "its description", open=False, elem_id="apart"):
        ui.keep = gr.CheckboxGroup(label="the joint query's neighbours (similarity; the "
                                   "integrator's attention on each one's image and text)",
                                   elem_id="keep")
        ui.regen = gr.Button("Regenerate RA-Touch", size="sm", elem_id="regen")
        ui.regen_out = gr.Markdown(elem_id="regen-out")
    ui.timings = gr.Markdown(elem_id="timings", elem_classes="ra-timings")
    with gr.Accordion("Raw result (the JSON that the /query API and `ratouch query` return)",
                      open=False):
        ui.raw = gr.JSON(show_label=False)


def _wire(demo: gr.Blocks, ui: SimpleNamespace, pipeline, world, thumbnail, options: dict,
          docs: Path, judge, choice: bool, max_batch: int, model_state=None) -> None:
    """Connect events to the handlers. Only `/query` is an API; the UI's events are private.

    Long on purpose: the page's whole event table in one place, so which event calls which
    handler with which inputs reads as one list.
    """
    box_out = [ui.state, ui.visual, *ui.fields, ui.box_note]
    example_out = [ui.state, ui.visual, ui.tactile, ui.background, *ui.fields, ui.box_note]
    query_in = [ui.state, ui.tactile, *ui.fields, ui.k, ui.background, ui.model]
    query_out = [ui.status, *ui.galleries, *ui.tables, ui.plot, ui.description, ui.timings,
                 ui.raw]
    # uploads reach the handlers undecoded (preprocess=False): the library decodes them with
    # its bounds and its messages, which name the file and its role
    raw = dict(preprocess=False)
    fail_in = [ui.subset, ui.condition, ui.fail_view]
    fail_out = [ui.fail_status, ui.fail_summary, ui.cases]
    bench_out = [ui.report, ui.fig_note, *ui.figures]
    private = dict(api_visibility="private")
    light = dict(concurrency_limit=None, show_progress="hidden", **private)  # milliseconds
    shared = {}  # the failure table once loaded: read-only, the same for every session
    # queries share one pool; a batching pipeline answers its concurrent calls together
    queries = dict(concurrency_id="query", concurrency_limit=max_batch)

    def select_example(evt: gr.SelectData):
        return handlers.load_example(world, EXAMPLES[evt.index])

    def click(state, a, b, c, d, evt: gr.SelectData):
        x, y = evt.index
        return handlers.click_box(state, x, y, (a, b, c, d))

    def model_note(model):
        if not (choice and model_state and model):
            return ""
        return view.model_state_md(model, *model_state(model), _load_seconds(pipeline))

    def show_query(state, tac, a, b, c, d, k, bg, model, progress=gr.Progress()):
        largest = min(MAX_K, _corpus_size(pipeline))
        return tuple(handlers.run_query(pipeline, thumbnail, state, tac, a, b, c, d, k,
                                        progress, background=bg, largest_k=largest,
                                        judge=judge, encoder=model if choice else None,
                                        wait_note=model_note(model)))

    def regenerate(state, tac, a, b, c, d, kept, result, model, bg):
        return handlers.regenerate(pipeline, state, tac, a, b, c, d, kept, result, judge,
                                   encoder=model if choice else None, background=bg)

    def api_query(visual, tactile, a, b, c, d, k, model=None, background=None):
        return handlers.api_query(pipeline, visual, tactile, a, b, c, d, k, background=background,
                                  encoder=(model or None) if choice else None)

    def failures_tab(subset, condition, view_label, compute, progress=None):
        shown = handlers.failures_tab(pipeline, options, shared, compute, subset, condition,
                                      view_label, FAILURE_ROWS, progress)
        # a table not computed yet is hidden, not an empty grid headed "1 2 3"
        return (shown.status, *(gr.update(value=t, visible=t is not None)
                                for t in (shown.summary, shown.cases)))

    def show_failures(subset, condition, view_label):
        return failures_tab(subset, condition, view_label, False)

    def compute_failures(subset, condition, view_label, progress=gr.Progress()):
        return failures_tab(subset, condition, view_label, True, progress)

    def open_case(evt: gr.SelectData):
        return (*handlers.open_case(options["world"], evt.row_value),
                gr.Tabs(selected="explore"))

    def poll_header():
        return _header(pipeline), gr.Timer(active=_pending(pipeline))

    gr.on([demo.load, ui.timer.tick], poll_header, None, [ui.header, ui.timer], **light)
    ui.model.change(model_note, ui.model, ui.model_note, **light)
    ui.visual.upload(handlers.visual_uploaded, ui.visual, box_out + query_out, **raw, **private)
    ui.tactile.upload(handlers.upload_tactile, ui.tactile, [ui.tactile, *query_out], **raw,
                      **private)
    ui.background.upload(handlers.upload_background, [ui.background, ui.tactile],
                         [ui.background, *query_out], **raw, **private)
    ui.visual.clear(lambda: handlers.reset_box(None), None, box_out, **light)
    # a result takes the examples' place: close them (one click opens them again)
    close_examples = dict(fn=lambda: gr.Accordion(open=False), inputs=None,
                          outputs=ui.examples_box, **light)
    # one click starts: the example is loaded and run
    ui.examples.select(select_example, None, example_out, **private).success(
        show_query, query_in, query_out, **queries, **raw, **private).then(**close_examples)
    ui.load.click(lambda i: handlers.load_example(world, i), ui.index, example_out, **private)
    ui.visual.select(click, [ui.state, *ui.fields], box_out, **light)
    gr.on([f.submit for f in ui.fields] + [f.blur for f in ui.fields], handlers.typed_box,
          [ui.state, *ui.fields], [ui.state, ui.visual, ui.box_note], **light)
    ui.reset.click(handlers.reset_box, ui.state, box_out, **light)
    ui.run.click(show_query, query_in, query_out, **queries, **raw, **private).then(
        **close_examples)
    # a new result (or none) resets the neighbour picker and the regenerated answer
    ui.raw.change(lambda r: (handlers.neighbour_picker(r), ""), ui.raw,
                  [ui.keep, ui.regen_out], **light)
    ui.regen.click(regenerate, [ui.state, ui.tactile, *ui.fields, ui.keep, ui.raw, ui.model,
                                ui.background],
                   ui.regen_out, **queries, **raw, **private)
    # failure cases: read from the cache when the tab opens, computed only on request
    gr.on([ui.failures_tab.select, ui.subset.change, ui.condition.change, ui.fail_view.change],
          show_failures, fail_in, fail_out, **private)
    ui.compute.click(compute_failures, fail_in, fail_out, concurrency_limit=1, **private)
    ui.cases.select(open_case, None, [*example_out, ui.tabs], **private).success(
        show_query, query_in, query_out, **queries, **raw, **private)
    gr.on([ui.bench_tab.select, ui.reload.click],
          lambda: handlers.benchmarks(docs, MAX_FIGURES), None, bench_out, **private)
    ui.api_button.click(api_query, [ui.api_visual, ui.api_tactile, *ui.fields, ui.k, ui.model,
                                    ui.api_background],
                        ui.api_out,
                        api_name="query", **queries)


def main(argv: list[str] | None = None) -> None:
    t_main = time.perf_counter()
    p = argparse.ArgumentParser(prog="python -m app", description=__doc__.splitlines()[0])
    p.add_argument("--host", default="127.0.0.1", help="address to serve on")
    p.add_argument("--port", type=int, default=7860)
    p.add_argument("--encoder", default="default-s",
                   help="the default model: an encoder set (default: default-s) or 'cascade'; "
                        "the page offers every shipped one")
    p.add_argument("--corpus", default=None,
                   help="built corpus folder (default: the world's 10k corpus, built on first use)")
    p.add_argument("--max-batch", type=int, default=16,
                   help="most concurrent queries answered in one batch (default 16)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    # heavy (torch, faiss, transformers): imported here, after the arguments are parsed, and
    # the models loaded in the background, so that the server answers at once
    from ratouch.serve.models import ModelChoice, available_models

    # serve at once; the models load meanwhile and a query waits for them. Concurrent
    # queries are answered in batches (one model pass for all of them), each by the model
    # it names.
    log.info("loading the RA-Touch pipeline (encoder %s) in the background ...", args.encoder)
    models = list(dict.fromkeys([args.encoder, *available_models()]))
    loaded: dict = {}

    def load():
        # the default model first; then the others are prepared in the background, so that
        # choosing one does not make its first query wait (a query for one still being
        # prepared waits for it and says so)
        loaded["choice"] = ModelChoice(args.encoder, models, corpus=args.corpus)
        loaded["choice"].prepare([m for m in models if m != args.encoder])
        return QueryBatcher(loaded["choice"], max_batch=args.max_batch)

    def model_state(name: str):
        return loaded["choice"].state(name) if "choice" in loaded else ("not prepared", None)

    loading = BackgroundPipeline(load, args.encoder, start=False)
    demo = build_demo(loading, models=models, max_batch=args.max_batch,
                      model_state=model_state)
    launch(demo, args.host, args.port, block=False)
    loading.start()  # after the server is up: both compete for the same cores and the GIL
    log.info("serving on http://%s:%d/ (%.1f s after main()); the models are loading",
             args.host, args.port, time.perf_counter() - t_main)
    try:
        loading.get(timeout=24 * 3600)
    except RATouchError as e:
        demo.close()
        raise SystemExit(f"python -m app: cannot load the pipeline: {e}") from e
    log.info("ready: the models loaded in %.1f s", loading.seconds)
    demo.block_thread()


def launch(demo: gr.Blocks, host: str, port: int, block: bool = True):
    """Serve `demo` with the app's limits: a bounded queue, bounded uploads and sessions.
    Besides uploads, only the docs folder (the benchmark report's figures) is served."""
    docs = getattr(demo, "ratouch_docs", DOCS)
    return demo.queue(default_concurrency_limit=2, max_size=64).launch(
        server_name=host, server_port=port, max_file_size="50mb", state_session_capacity=256,
        prevent_thread_lock=not block, show_error=False, ssr_mode=False, quiet=not block,
        css=CSS, footer_links=["api"], allowed_paths=[str(docs)])


if __name__ == "__main__":
    main()

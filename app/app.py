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
from fastapi.responses import FileResponse, Response  # noqa: E402

from app import benchmark_tab, explore_tab, failure_tab, handlers, view  # noqa: E402
from app.explore_tab import SESSION_TTL_S  # noqa: E402
from app.page import Page  # noqa: E402
from ratouch.errors import RATouchError  # noqa: E402
from ratouch.eval import failures  # noqa: E402
from ratouch.eval.judge import OfflineJudge  # noqa: E402
from ratouch.eval.report import git_commit  # noqa: E402
from ratouch.paths import DOCS  # noqa: E402
from ratouch.serve.batcher import QueryBatcher  # noqa: E402
from ratouch.serve.loader import BackgroundPipeline  # noqa: E402
from ratouch.world.sampler import TEST_SIZE, World  # noqa: E402

log = logging.getLogger(__name__)

THUMBNAIL_SIDE = 128

CSS = (Path(__file__).with_name("page.css")).read_text(encoding="utf-8")


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
        docs: the folder holding `results.md`, `figures/*.json` and the stored checks
            (default: the repo's docs/).
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

    @functools.lru_cache(maxsize=512)  # corpus thumbnails are re-rendered; keep recent ones
    def thumbnail(i: int):
        return pipeline.model().corpus.thumbnail(i, THUMBNAIL_SIDE)

    if max_batch is None:
        max_batch = pipeline.max_batch if isinstance(pipeline, QueryBatcher) else 2
    page = Page(pipeline, world, judge,
                {"world": world.cfg, "k": 5, "conditions": failures.DEFAULT_CONDITIONS,
                 **(failure_options or {})},
                Path(docs) if docs is not None else DOCS, models, max_batch, model_state,
                thumbnail, commit=git_commit())
    with gr.Blocks(title="RA-Touch Explorer", delete_cache=(1800, SESSION_TTL_S)) as demo:
        # refreshed on every page load, and by the timer while the models load
        header = gr.Markdown(_header(pipeline), elem_id="header")
        timer = gr.Timer(2.0, active=page.pending())
        with gr.Tabs(elem_id="tabs") as tabs:
            with gr.Tab("Explore", id="explore", elem_id="tab-explore"):
                explore = explore_tab.layout(page, TEST_SIZE)
            with gr.Tab("Failure cases", id="failures", elem_id="tab-failures") as fail_tab:
                fail = failure_tab.layout(page)
            with gr.Tab("Benchmarks", id="benchmarks", elem_id="tab-benchmarks") as bench_tab:
                bench = benchmark_tab.layout()
        api = _api_layout()
        gr.on([demo.load, timer.tick],
              lambda: (_header(pipeline), gr.Timer(active=page.pending())), None,
              [header, timer], concurrency_limit=None, show_progress="hidden",
              api_visibility="private")
        opened = explore_tab.wire(demo, page, explore)
        failure_tab.wire(page, fail, fail_tab, opened, tabs)
        benchmark_tab.wire(page, bench, bench_tab)
        _api_wire(page, api, explore)
    demo.ratouch_docs = page.docs  # `launch` serves its files (and nothing else from disk)
    return demo


def _pending(pipeline) -> bool:
    """Whether the models are still loading (or failed to): a
    `ratouch.serve.loader.BackgroundPipeline` says so; anything else is loaded."""
    ready = getattr(pipeline, "ready", None)
    return callable(ready) and not ready()


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


def _api_layout() -> SimpleNamespace:
    """The /query API's own inputs and output (hidden)."""
    with gr.Row(visible=False):
        return SimpleNamespace(
            visual=gr.File(label="visual image", file_types=["image"]),
            tactile=gr.File(label="tactile image", file_types=["image"]),
            background=gr.File(label="sensor background", file_types=["image"]),
            out=gr.JSON(), button=gr.Button())


def _api_wire(page: Page, api: SimpleNamespace, explore: SimpleNamespace) -> None:
    """Only `/query` is an API; the UI's events are private."""
    def api_query(visual, tactile, a, b, c, d, k, model=None, background=None, retrieval=None):
        return handlers.api_query(page.pipeline, visual, tactile, a, b, c, d, k,
                                  background=background, encoder=page.encoder(model),
                                  retrieval=retrieval)

    api.button.click(api_query, [api.visual, api.tactile, *explore.fields.values(), explore.k,
                                 explore.model, api.background, explore.retrieval],
                     api.out, api_name="query", concurrency_id="query",
                     concurrency_limit=page.max_batch)


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
    p.add_argument("--batch-workers", type=int, default=1,
                   help="batches answered at the same time, each on one thread (default 1; "
                        "on 2 cores, 2 gave about 10%% more queries/s but a longer p95 and "
                        "more CPU per query: docs/performance.md)")
    p.add_argument("--model-processes", type=int, default=2,
                   help="when concurrent queries first arrive, start this many child "
                        "processes, each with its own copy of the models (about 1.3 GB "
                        "each), and answer that many batches at once in them (default 2; "
                        "one user never starts them); 0: every query in the server's "
                        "process (docs/performance.md)")
    args = p.parse_args(argv)
    if args.batch_workers < 1:
        p.error(f"--batch-workers must be at least 1, got {args.batch_workers}")
    if args.model_processes < 0:
        p.error(f"--model-processes must be 0 or more, got {args.model_processes}")
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    # heavy (torch, faiss, transformers): imported here, after the arguments are parsed, and
    # the models loaded in the background, so that the server answers at once
    from ratouch.serve.models import ModelChoice, available_models
    from ratouch.serve.request import split_model_name

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
        loaded["choice"].warm()  # what the first query builds once, built before it comes
        # a pretrained language model's generators (hundreds of MB) load when first chosen
        loaded["choice"].prepare([m for m in models if m != args.encoder
                                  and split_model_name(m)[1] is None])
        if not args.model_processes:
            return QueryBatcher(loaded["choice"], max_batch=args.max_batch,
                                workers=args.batch_workers)
        from ratouch.serve.pool import ProcessPool

        pool = ProcessPool(loaded["choice"], args.model_processes, corpus=args.corpus,
                           on_demand=True)
        return QueryBatcher(pool, max_batch=args.max_batch,
                            workers=max(args.batch_workers, args.model_processes))

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


def _no_monitoring(demo: gr.Blocks) -> None:
    """Gradio's traffic monitoring off (the app serves its own timings): by default its queue
    rebuilds a pandas table of the last 10,000 events after every event, for a dashboard
    this app never serves (`launch(enable_monitoring=False)` closes the dashboard but not the
    rebuild); its CPU per query grew with the events served, 5.9 ms at 500 to 17 ms at
    10,000 (docs/performance.md, "Gradio's monitoring")."""
    queue = demo._queue
    if hasattr(queue, "ANAYLTICS_CACHE_FREQUENCY"):  # (Gradio's spelling)
        queue.ANAYLTICS_CACHE_FREQUENCY = sys.maxsize  # the summary is never rebuilt
    if hasattr(queue, "ANALYTICS_MAX_EVENTS"):
        queue.ANALYTICS_MAX_EVENTS = 1  # nor 10,000 records kept for it


def launch(demo: gr.Blocks, host: str, port: int, block: bool = True):
    """Serve `demo` with the app's limits: a bounded queue, bounded uploads and sessions.
    Besides uploads, only the docs folder (the benchmark report's figures and the stored
    checks) is served, under its own route (`view.DOCS_ROUTE`), by paths inside it: no URL
    carries the server's own path."""
    docs = Path(getattr(demo, "ratouch_docs", DOCS)).resolve()
    demo.queue(default_concurrency_limit=2, max_size=64)
    _no_monitoring(demo)
    out = demo.launch(
        server_name=host, server_port=port, max_file_size="50mb", state_session_capacity=256,
        prevent_thread_lock=True, show_error=False, ssr_mode=False, quiet=not block,
        css=CSS, footer_links=["api"], enable_monitoring=False)

    def docs_file(name: str):
        path = (docs / name).resolve()
        if not (path.is_file() and path.is_relative_to(docs)):
            return Response(status_code=404)
        return FileResponse(path)

    demo.server_app.add_api_route(f"/{view.DOCS_ROUTE}/{{name:path}}", docs_file,
                                  methods=["GET", "HEAD"])
    if block:
        demo.block_thread()
    return out


if __name__ == "__main__":
    main()

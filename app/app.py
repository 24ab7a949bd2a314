"""RA-Touch Explorer: the Gradio app over `ratouch.pipeline.RATouchPipeline`.

Upload a visual and a tactile image (or pick a pair from the world's test split), mark the
contact box, and compare the neighbours that image, tactile and joint queries retrieve, where
they fall in the PCA frame, and the descriptions generated with and without retrieval.
`build_demo(pipeline)` builds the UI around a loaded pipeline; `main()` loads one and serves it.
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys
from pathlib import Path
from types import SimpleNamespace

if __package__ in (None, ""):  # run as a script (`python app/app.py`, as `ratouch app` does):
    sys.path[0] = str(Path(__file__).resolve().parents[1])  # let `app` name the package

import gradio as gr  # noqa: E402

from app import handlers, view  # noqa: E402
from app.box import PREVIEW_SIDE  # noqa: E402

log = logging.getLogger(__name__)

# A few structured close-ups (indices < 46), then wild scenes, spread over the test split.
EXAMPLES = [0, 12, 40, 60, 140, 190, 290, 390]
THUMBNAIL_SIDE = 128
MAX_K = 20
SESSION_TTL_S = 2 * 3600

CSS = """
.ra-muted { color: var(--body-text-color-subdued); font-size: 0.85em; }
.ra-timings * { color: var(--body-text-color-subdued) !important; font-size: 12px !important; }
.ra-table { font-size: 0.82em; width: 100%; }
.ra-table td, .ra-table th { padding: 2px 4px; vertical-align: top; }
.ra-shared { white-space: nowrap; color: #b8860b; }
.ra-gallery .caption-label { white-space: normal; font-size: 0.72em; line-height: 1.2;
                             max-width: calc(100% - 8px); }
"""

ABOUT_LATER = """### Failure cases and benchmarks
The failure-case inspector (the worst test cases, the judge's score, what each query mode got
wrong) and the benchmark tables come with the evaluation, in a later issue. Until then this
tab has nothing to show: no numbers are made up here. Headless, `ratouch eval` and
`ratouch bench` are the way in."""


def build_demo(pipeline, world=None) -> gr.Blocks:
    """The app around a loaded pipeline (read-only, shared by all sessions).

    Args:
        pipeline: a `RATouchPipeline` (or an object with the same `query()`, `corpus` and
            `encoders`).
        world: the `World` whose test split gives the examples (default: the default world).
    """
    from ratouch.world.generator import World

    world = world or World()

    @functools.lru_cache(maxsize=512)  # corpus thumbnails are re-rendered; keep recent ones
    def thumbnail(i: int):
        return pipeline.corpus.thumbnail(i, THUMBNAIL_SIDE)

    with gr.Blocks(title="RA-Touch Explorer", delete_cache=(1800, SESSION_TTL_S)) as demo:
        ui = _layout(pipeline, world)
        _wire(ui, pipeline, world, thumbnail)
    return demo


def _layout(pipeline, world) -> SimpleNamespace:
    """Place the components; returns them by name."""
    from ratouch.world.generator import TEST_SIZE

    ui = SimpleNamespace(state=gr.State(None, time_to_live=SESSION_TTL_S))
    n_corpus = len(pipeline.corpus.entries)
    gr.Markdown(f"# RA-Touch Explorer\nRetrieval-augmented touch understanding · encoder "
                f"`{pipeline.encoders.name}` · corpus of {n_corpus:,} ImageNet-T entries")
    with gr.Tab("Explore"):
        with gr.Row():
            with gr.Column(scale=3):
                ui.visual = gr.Image(
                    label="Visual image — click two opposite corners of the contact box",
                    type="filepath", image_mode=None, sources=["upload", "clipboard"],
                    format="png", height=PREVIEW_SIDE, elem_id="visual")
                with gr.Row():
                    ui.fields = [gr.Number(label=n, precision=0, elem_id=f"box-{n}",
                                           min_width=60) for n in ("x0", "y0", "x1", "y1")]
                    ui.reset = gr.Button("Default box", size="sm", min_width=60)
                ui.box_note = gr.Markdown(elem_id="box-note")
            with gr.Column(scale=2):
                ui.tactile = gr.Image(label="Tactile image (DIGIT / GelSight frame)",
                                      type="filepath", image_mode=None, format="png",
                                      sources=["upload", "clipboard"], height=300,
                                      elem_id="tactile")
                ui.k = gr.Slider(1, min(MAX_K, n_corpus), value=min(5, n_corpus), step=1,
                                 label="K (neighbours per query)", elem_id="k")
                ui.run = gr.Button("Run query", variant="primary", elem_id="run")
                ui.status = gr.Markdown(elem_id="status")
        with gr.Accordion("Examples from the world's test split (ground-truth label shown)"):
            ui.examples = gr.Gallery(
                handlers.example_gallery(world, EXAMPLES), columns=len(EXAMPLES), height=200,
                allow_preview=False, show_label=False, elem_id="examples",
                elem_classes="ra-gallery")
            with gr.Row():
                ui.index = gr.Number(label=f"or any test index (0–{TEST_SIZE - 1})", value=0,
                                     precision=0, minimum=0, maximum=TEST_SIZE - 1)
                ui.load = gr.Button("Load example", size="sm")
        ui.galleries, ui.tables = [], []
        with gr.Row(equal_height=False):
            for mode in view.MODES:
                with gr.Column(min_width=260):
                    gr.Markdown(view.mode_header(mode))
                    ui.galleries.append(gr.Gallery(
                        show_label=False, columns=3, height=300, object_fit="contain",
                        elem_id=f"gallery-{mode}"))
                    ui.tables.append(gr.HTML(elem_id=f"table-{mode}"))
        with gr.Row():
            ui.plot = gr.Plot(label="PCA", elem_id="pca", scale=3)
            ui.description = gr.Markdown(elem_id="description")
        ui.timings = gr.Markdown(elem_id="timings", elem_classes="ra-timings")
        with gr.Accordion("Raw result (the JSON that the /query API and `ratouch query` return)",
                          open=False):
            ui.raw = gr.JSON(show_label=False)
    with gr.Tab("Failure cases & benchmarks"):
        gr.Markdown(ABOUT_LATER)
    with gr.Row(visible=False):  # the /query API's own inputs and output
        ui.api_visual = gr.File(label="visual image", file_types=["image"])
        ui.api_tactile = gr.File(label="tactile image", file_types=["image"])
        ui.api_out = gr.JSON()
        ui.api_button = gr.Button()
    return ui


def _wire(ui: SimpleNamespace, pipeline, world, thumbnail) -> None:
    """Connect events to the handlers. Only `/query` is an API; the UI's events are private."""
    box_out = [ui.state, ui.visual, *ui.fields, ui.box_note]
    example_out = [ui.state, ui.visual, ui.tactile, *ui.fields, ui.box_note]
    private = dict(api_visibility="private")
    light = dict(concurrency_limit=None, show_progress="hidden", **private)  # milliseconds

    def select_example(evt: gr.SelectData):
        return handlers.load_example(world, EXAMPLES[evt.index])

    def click(state, a, b, c, d, evt: gr.SelectData):
        x, y = evt.index
        return handlers.click_box(state, x, y, (a, b, c, d))

    def show_query(state, tac, a, b, c, d, k, progress=gr.Progress()):
        return tuple(handlers.run_query(pipeline, thumbnail, state, tac, a, b, c, d, k,
                                        progress))

    ui.visual.upload(handlers.upload_visual, ui.visual, box_out, **private)
    ui.visual.clear(lambda: handlers.reset_box(None), None, box_out, **light)
    ui.examples.select(select_example, None, example_out, **private)
    ui.load.click(lambda i: handlers.load_example(world, i), ui.index, example_out, **private)
    ui.visual.select(click, [ui.state, *ui.fields], box_out, **light)
    gr.on([f.submit for f in ui.fields] + [f.blur for f in ui.fields], handlers.typed_box,
          [ui.state, *ui.fields], [ui.state, ui.visual, ui.box_note], **light)
    ui.reset.click(handlers.reset_box, ui.state, box_out, **light)
    ui.run.click(show_query, [ui.state, ui.tactile, *ui.fields, ui.k],
                 [ui.status, *ui.galleries, *ui.tables, ui.plot, ui.description, ui.timings,
                  ui.raw], **private)
    ui.api_button.click(functools.partial(handlers.api_query, pipeline),
                        [ui.api_visual, ui.api_tactile, *ui.fields, ui.k], ui.api_out,
                        api_name="query")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m app", description=__doc__.splitlines()[0])
    p.add_argument("--host", default="127.0.0.1", help="address to serve on")
    p.add_argument("--port", type=int, default=7860)
    p.add_argument("--encoder", default="default-s", help="encoder set (default: default-s)")
    p.add_argument("--corpus", default=None,
                   help="built corpus folder (default: the world's 10k corpus, built on first use)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    from ratouch.errors import RATouchError
    from ratouch.pipeline import RATouchPipeline

    log.info("loading the RA-Touch pipeline (encoder %s) ...", args.encoder)
    try:
        pipeline = RATouchPipeline.load(args.encoder, corpus=args.corpus, progress=True)
    except RATouchError as e:
        raise SystemExit(f"python -m app: cannot load the pipeline: {e}") from e
    launch(build_demo(pipeline), args.host, args.port)


def launch(demo: gr.Blocks, host: str, port: int, block: bool = True):
    """Serve `demo` with the app's limits: a bounded queue, bounded uploads and sessions."""
    return demo.queue(default_concurrency_limit=2, max_size=64).launch(
        server_name=host, server_port=port, max_file_size="50mb", state_session_capacity=256,
        prevent_thread_lock=not block, show_error=False, ssr_mode=False, quiet=not block,
        css=CSS, footer_links=["api"])


if __name__ == "__main__":
    main()

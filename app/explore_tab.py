"""The Explore tab: the inputs on the left, the answer on the right, and what a researcher keeps
of it (export, a link, the session's history side by side).

`layout(page)` places the components and returns them by name; `wire(demo, page, ui)`
connects their events. Every output is matched by name (`app.page.Outputs`): the answer's
components are built from `QUERY_MODES`, one gallery and one table per mode, and a handler's
`QueryView.named()` fills them.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import gradio as gr

from app import handlers, record, view
from app.page import Outputs, Page
from ratouch.search.modes import RETRIEVAL_SYSTEMS
from ratouch.serve.pipeline import DEFAULT_RETRIEVAL

# A few structured close-ups (indices < 46), then wild scenes, spread over the test split.
EXAMPLES = [0, 12, 40, 60, 140, 190, 290, 390]
VISUAL_HEIGHT = 196  # the preview's display height: the inputs fit beside the answer
TACTILE_HEIGHT = 96  # with the height-map strip under them, Run stays on a 1280x800 screen
SESSION_TTL_S = 2 * 3600
EXPORTS = Path(tempfile.gettempdir()) / "ratouch-exports"  # gradio copies them to its cache


def layout(page: Page, test_size: int) -> SimpleNamespace:
    """Place the Explore tab's components (inside a `gr.Tab`); returns them by name."""
    ui = SimpleNamespace(state=gr.State(None, time_to_live=SESSION_TTL_S),
                         history=gr.State([], time_to_live=SESSION_TTL_S),
                         shown=gr.State(None, time_to_live=SESSION_TTL_S),
                         linked=gr.State(False))
    n_corpus = page.corpus_size()
    # one screen: the inputs on the left, the answer on the right (examples to start with,
    # then the trust line, both descriptions, what retrieval did and each mode's first
    # neighbours); the tables, the PCA and what to keep below
    with gr.Row(equal_height=False):
        with gr.Column(scale=5, min_width=420, elem_id="inputs"):
            _inputs(ui, page, n_corpus)
        with gr.Column(scale=7, min_width=560, elem_id="answer"):
            _answer(ui, page, test_size)
    ui.tables = {}
    with gr.Row(equal_height=False, elem_classes="ra-answer"):
        for mode in view.strip_order():
            with gr.Column(min_width=260):
                gr.Markdown(view.mode_header(mode))
                ui.tables[mode] = gr.HTML(elem_id=f"table-{mode}")
    ui.plot = gr.Plot(label="PCA", elem_id="pca", elem_classes="ra-answer")
    with gr.Accordion("Take retrieval apart: untick neighbours RA-Touch reads and regenerate "
                      "its description", open=False, elem_id="apart"):
        ui.keep = gr.CheckboxGroup(label="the joint query's neighbours (similarity; the "
                                   "integrator's attention on each one's image and text)",
                                   elem_id="keep")
        ui.regen = gr.Button("Regenerate RA-Touch", size="sm", elem_id="regen")
        ui.regen_out = gr.Markdown(elem_id="regen-out")
    with gr.Accordion("History: this session's runs, any two side by side", open=False,
                      elem_id="history"):
        with gr.Row():
            ui.compare_a = gr.Dropdown([], label="run", elem_id="compare-a", scale=1)
            ui.compare_b = gr.Dropdown([], label="beside", elem_id="compare-b", scale=1)
        ui.comparison = gr.HTML(record.compare_html(None, None), elem_id="comparison")
    ui.timings = gr.Markdown(elem_id="timings", elem_classes="ra-timings")
    with gr.Accordion("Raw result (the JSON that the /query API and `ratouch query` return)",
                      open=False):
        ui.raw = gr.JSON(show_label=False, elem_id="raw")
    return ui


def _inputs(ui: SimpleNamespace, page: Page, n_corpus: int) -> None:
    ui.visual = gr.Image(
        label="1 · Photo — 2 · click two opposite corners of the contact box",
        type="filepath", image_mode=None, sources=["upload", "clipboard"],
        format="png", height=VISUAL_HEIGHT, elem_id="visual")
    with gr.Row():
        # text fields: empty until a box is marked (a Number would show 0 0 0 0, which
        # reads as a real zero-size box)
        ui.fields = {n: gr.Textbox(value="", label=n, placeholder="—", max_lines=1,
                                   elem_id=f"box-{n}", min_width=60)
                     for n in ("x0", "y0", "x1", "y1")}
        with gr.Column(min_width=100, scale=1):
            ui.reset = gr.Button("Default box", size="sm", min_width=60)
            # the retrieval system RA-Touch answers with (`RETRIEVAL_SYSTEMS`); which
            # gallery it read is said under "What retrieval did" (a system may read another
            # mode's neighbours than its own, where touch is withheld)
            ui.retrieval = gr.Dropdown(
                [(name, name) for name in RETRIEVAL_SYSTEMS],
                value=DEFAULT_RETRIEVAL, show_label=False, container=False,
                elem_id="retrieval", min_width=100)
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
    # the press read against the background as a height map (after a query), else the hint
    # that a background gives one: one low strip, so that Run stays on the first screen
    ui.geometry = gr.HTML(view.GEOMETRY_HINT, elem_id="geometry", elem_classes="ra-answer")
    models = page.models or []
    with gr.Row(equal_height=True):
        largest = min(page.largest_k(), n_corpus)
        ui.k = gr.Slider(1, largest, value=min(5, n_corpus), step=1,
                         label=f"K neighbours (1–{largest})", elem_id="k", scale=3,
                         buttons=[])
        # the encoder size; "cascade": the smallest confident encoder answers
        ui.model = gr.Dropdown(handlers.model_choices(models) or [""],
                               value=(models or [""])[0], label="model",
                               elem_id="model", interactive=len(models) > 1,
                               visible=bool(models), scale=4)
        if not models:  # Run beside K; with a model menu, on its own row below
            ui.run = _run_button()
    if models:
        ui.run = _run_button()
    ui.model_about = gr.HTML(handlers.models_md(models) if models else "",
                             elem_id="model-about", visible=bool(models))
    ui.model_note = gr.Markdown(elem_id="model-note", elem_classes="ra-muted")


def _run_button() -> gr.Button:
    return gr.Button("5 · Run query", variant="primary", elem_id="run", scale=2,
                     min_width=120)


def _answer(ui: SimpleNamespace, page: Page, test_size: int) -> None:
    # open on the first screen (one click loads a pair and runs it); closed after a result,
    # which takes its place
    with gr.Accordion("Start here: click an example from the world's test split to load "
                      "and run it", open=True, elem_id="examples-box") as ui.examples_box:
        ui.examples = gr.HTML(view.example_strip(
            [(i, *handlers.example_item(page.world, i)) for i in EXAMPLES]),
            js_on_load=view.EXAMPLE_CLICK_JS, elem_id="examples")
        with gr.Row():
            ui.index = gr.Number(label=f"or any test index (0–{test_size - 1})", value=0,
                                 precision=0, minimum=0, maximum=test_size - 1,
                                 min_width=120)
            ui.load = gr.Button("Load example", size="sm", min_width=80)
    # shown over an answer whose inputs changed since; faded with it (CSS)
    ui.stale = gr.HTML("", elem_id="stale")
    # what was queried (box used, model) and the warnings the trust block does not show,
    # then the answer
    ui.status = gr.Markdown(elem_id="status", elem_classes="ra-answer")
    ui.description = gr.Markdown(elem_id="description", elem_classes="ra-answer")
    # each mode's neighbours: a row of fixed-size tiles (duplicates folded, ×n), the mode
    # RA-Touch reads first
    ui.galleries = {mode: gr.HTML(elem_id=f"gallery-{mode}", elem_classes="ra-answer")
                    for mode in view.strip_order()}
    with gr.Row(elem_id="keep-row", equal_height=True):
        ui.export_json = gr.DownloadButton("Export JSON", size="sm", elem_id="export-json",
                                           visible=False, min_width=80, scale=0)
        ui.export_csv = gr.DownloadButton("Neighbours CSV", size="sm", elem_id="export-csv",
                                          visible=False, min_width=80, scale=0)
        ui.link = gr.Markdown(elem_id="link")


def outputs(ui: SimpleNamespace) -> SimpleNamespace:
    """The tab's outputs by name: the inputs an example fills, and the answer's."""
    box = Outputs({"state": ui.state, "visual": ui.visual, **ui.fields,
                   "box_note": ui.box_note})
    example = box + Outputs({"tactile": ui.tactile, "background": ui.background})
    answer = Outputs({"status": ui.status,
                      **{f"gallery_{m}": c for m, c in ui.galleries.items()},
                      **{f"table_{m}": c for m, c in ui.tables.items()},
                      "plot": ui.plot, "description": ui.description,
                      "timings": ui.timings, "raw": ui.raw, "geometry": ui.geometry})
    kept = Outputs({"stale": ui.stale, "shown": ui.shown, "history": ui.history,
                    "export_json": ui.export_json, "export_csv": ui.export_csv,
                    "link": ui.link, "compare_a": ui.compare_a, "compare_b": ui.compare_b,
                    "comparison": ui.comparison})
    return SimpleNamespace(box=box, example=example, answer=answer, kept=kept,
                           typed=box.only(["state", "visual", "box_note"]))


def answer_named(page: Page, v: handlers.QueryView, visual, tactile, background, k, model,
                 fields: tuple, history: list) -> dict[str, Any]:
    """The answer's outputs and what is kept of it: a record in the session's history, its
    exports and link, and the comparison of it with the run before."""
    out = {**v.named(), "stale": ""}
    if v.raw is None:  # an error: nothing to keep
        return {**out, "shown": None, "export_json": gr.DownloadButton(visible=False),
                "export_csv": gr.DownloadButton(visible=False), "link": ""}
    number = history[-1].number + 1 if history else 1
    rec = record.make_record(
        number, visual.title,
        {"visual": visual.source, "tactile": handlers.upload_path(tactile),
         "background": handlers.upload_path(background)},
        {"k": int(k), "box": _box(fields)}, v.raw, page.commit, visual.example,
        page.encoder(model) or "")
    history = record.remember(history, rec)
    js, cs = record.write_exports(rec, Path(tempfile.mkdtemp(dir=_exports())))
    link = rec.link()
    choices = [(r.label, r.number) for r in reversed(history)]
    before = history[-2] if len(history) > 1 else None
    return {**out, "shown": number, "history": history,
            "export_json": gr.DownloadButton(value=str(js), visible=True),
            "export_csv": gr.DownloadButton(value=str(cs), visible=True),
            "link": (f"[Link to this query]({link}) <span class='ra-muted'>(reproduces it on "
                     "the world's example)</span>" if link else
                     "<span class='ra-muted'>No link for an uploaded image: export the JSON "
                     "(it carries the inputs' checksums)</span>"),
            "compare_a": gr.Dropdown(choices=choices, value=before.number if before else None),
            "compare_b": gr.Dropdown(choices=choices, value=number),
            "comparison": record.compare_html(before, rec)}


def _exports() -> Path:
    EXPORTS.mkdir(parents=True, exist_ok=True)
    return EXPORTS


def _box(fields: tuple) -> list[float] | None:
    try:
        box = handlers.boxes.fields_to_box(*fields)
    except handlers.DataError:
        return None
    return None if box is None else [float(v) for v in box]


def wire(demo: gr.Blocks, page: Page, ui: SimpleNamespace) -> SimpleNamespace:
    """Connect the Explore tab's events (and the page link read on load).

    Returns:
        what another tab needs to open something in Explore and run it: `example`, the
        outputs an example fills (by name), and `run`, the query event's keyword arguments
    """
    out = outputs(ui)
    fields = list(ui.fields.values())
    query_in = [ui.state, ui.tactile, *fields, ui.k, ui.background, ui.model, ui.retrieval,
                ui.history]
    query_out = (out.answer + out.kept).components
    # uploads reach the handlers undecoded (preprocess=False): the library decodes them with
    # its bounds and its messages, which name the file and its role
    raw: dict[str, Any] = dict(preprocess=False)
    private: dict[str, Any] = dict(api_visibility="private")
    light = dict(concurrency_limit=None, show_progress="hidden", **private)  # milliseconds
    # queries share one pool; a batching pipeline answers its concurrent calls together
    queries = dict(concurrency_id="query", concurrency_limit=page.max_batch)
    answered = out.answer + out.kept

    def model_note(model):
        if not (page.choice and page.model_state and model):
            return ""
        return view.model_state_md(model, *page.model_state(model), page.load_seconds())

    def show_query(state, tac, a, b, c, d, k, bg, model, retrieval, history,
                   progress=gr.Progress()):
        v = handlers.run_query(page.pipeline, page.thumbnail, state, tac, a, b, c, d, k,
                               progress, background=bg, largest_k=page.largest_k(),
                               judge=page.judge, encoder=page.encoder(model),
                               wait_note=model_note(model), retrieval=retrieval or None)
        return answered.values(answer_named(page, v, state, tac, bg, k, model,
                                            (a, b, c, d), history))

    def linked_query(linked, *args):
        if not linked:
            return gr.skip()
        return {**show_query(*args), ui.examples_box: gr.Accordion(open=False)}

    def select_example(evt: gr.EventData):
        return out.example.values(handlers.load_example(page.world, evt.index)._asdict())

    def click(state, a, b, c, d, evt: gr.SelectData):
        x, y = evt.index
        return out.box.values(handlers.click_box(state, x, y, (a, b, c, d))._asdict())

    def regenerate(state, tac, a, b, c, d, kept, result, model, bg):
        return handlers.regenerate(page.pipeline, state, tac, a, b, c, d, kept, result,
                                   page.judge, encoder=page.encoder(model), background=bg)

    upload_out = out.answer + out.box + Outputs({"tactile": ui.tactile,
                                                 "background": ui.background,
                                                 "shown": ui.shown})

    def uploaded(named: dict) -> dict:
        # an unusable file clears the answer: nothing is shown, so nothing is stale
        return upload_out.values({**named, **({"shown": None} if "raw" in named else {})})

    def from_link(request: gr.Request):
        """A page link (`?example=N&model=…&k=…`): its example, K and model, then its run."""
        try:
            link = handlers.open_link(page.world, page.options["world"],
                                      dict(request.query_params) if request else {},
                                      page.models, page.largest_k())
        except handlers.USER_ERRORS as e:
            gr.Warning(handlers.user_message(e))
            return linked_out.values({"linked": False})
        if link is None:
            return linked_out.values({"linked": False})
        named = {**link.example._asdict(), "k": link.k, "linked": True}
        if link.model:
            named["model"] = link.model
        return linked_out.values(named)

    linked_out = out.example + Outputs({"k": ui.k, "model": ui.model, "linked": ui.linked})
    mark_stale = dict(fn=lambda shown: view.stale_html(shown is not None), inputs=ui.shown,
                      outputs=ui.stale, **light)
    close_examples = dict(fn=lambda: gr.Accordion(open=False), inputs=None,
                          outputs=ui.examples_box, **light)

    demo.load(from_link, None, linked_out.components, show_progress="hidden",
              **private).then(linked_query, [ui.linked, *query_in],
                              [*query_out, ui.examples_box],
                              show_progress="hidden", **queries, **raw, **private)
    ui.model.change(model_note, ui.model, ui.model_note, **light)
    ui.visual.upload(lambda v: uploaded(handlers.visual_uploaded(v)), ui.visual,
                     upload_out.components, **raw, **private).then(**mark_stale)
    ui.tactile.upload(lambda v: uploaded(handlers.upload_tactile(v)), ui.tactile,
                      upload_out.components, **raw, **private).then(**mark_stale)
    ui.background.upload(lambda v, t: uploaded(handlers.upload_background(v, t)),
                         [ui.background, ui.tactile], upload_out.components, **raw,
                         **private).then(**mark_stale)
    ui.visual.clear(lambda: out.box.values(handlers.reset_box(None)._asdict()), None,
                    out.box.components, **light)
    # K, the model and the box change what a query would answer: the answer shown is stale
    gr.on([ui.k.input, ui.model.input, ui.retrieval.input, ui.reset.click, ui.visual.select,
           *(f.submit for f in fields)], **mark_stale)
    # one click starts: the example is loaded and run; the result closes the examples
    ui.examples.click(select_example, None, out.example.components, **private).success(
        show_query, query_in, query_out, **queries, **raw, **private).then(**close_examples)
    ui.load.click(lambda i: out.example.values(handlers.load_example(page.world, i)._asdict()),
                  ui.index, out.example.components, **private).then(**mark_stale)
    ui.visual.select(click, [ui.state, *fields], out.box.components, **light)
    gr.on([f.submit for f in fields] + [f.blur for f in fields],
          lambda *a: out.typed.values(handlers.typed_box(*a)._asdict()),
          [ui.state, *fields], out.typed.components, **light)
    ui.reset.click(lambda s: out.box.values(handlers.reset_box(s)._asdict()), ui.state,
                   out.box.components, **light)
    ui.run.click(show_query, query_in, query_out, **queries, **raw, **private).then(
        **close_examples)
    # a new result (or none) resets the neighbour picker and the regenerated answer
    ui.raw.change(lambda r: (handlers.neighbour_picker(r), ""), ui.raw,
                  [ui.keep, ui.regen_out], **light)
    # and the model's note: a query prepared its model
    ui.raw.change(model_note, ui.model, ui.model_note, **light)
    ui.regen.click(regenerate, [ui.state, ui.tactile, *fields, ui.keep, ui.raw, ui.model,
                                ui.background],
                   ui.regen_out, **queries, **raw, **private)
    gr.on([ui.compare_a.input, ui.compare_b.input],
          lambda h, a, b: record.compare_html(_run(h, a), _run(h, b)),
          [ui.history, ui.compare_a, ui.compare_b], ui.comparison, **light)
    return SimpleNamespace(example=out.example,
                           run=dict(fn=show_query, inputs=query_in, outputs=query_out,
                                    **queries, **raw, **private))


def _run(history: list, number: Any):
    return next((r for r in history or [] if r.number == number), None)

"""The Failure cases tab: every test pair under a few stress conditions, the worst cases first;
a row opens in Explore and runs there.

`layout(page)` places the components, `wire(page, ui, explore, tabs)` connects them; the
table's columns come from the query modes' registry (`view.case_columns`).
"""

from __future__ import annotations

from types import SimpleNamespace

import gradio as gr

from app import handlers, view
from app.page import Outputs, Page
from ratouch.eval import failures

FAILURE_ROWS = 50  # worst cases shown at once

ABOUT = """### Failure cases
Every pair of the world's test split (46 structured close-ups + 356 wild scenes) under a few
stress conditions, described by the no-retrieval baseline and by RA-Touch, each description
scored by the offline judge (1–10) against the ground-truth label, and the material
precision@K of the neighbours that each query mode ({modes}) retrieves. The table is computed
once per pipeline and cached; it is never computed at start-up. Computing it took
{wait} on a 2-core CPU when measured (4 conditions × 402 pairs; a progress bar shows how far
it is). Conditions:
"""


def about_md(conditions) -> str:
    # "; " between the modes: a mode's own title may hold a comma ("tactile query, adapted
    # to everyday presses"), which ", " would read as two modes
    return ABOUT.format(modes="; ".join(view.MODE_TITLE[m].split(" (")[0].lower()
                                        for m in view.MODES), wait=view.FAILURE_WAIT) + \
        view.conditions_md({c: failures.CONDITIONS[c] for c in conditions})


def layout(page: Page) -> SimpleNamespace:
    """Place the tab's components (inside a `gr.Tab`); returns them by name."""
    ui = SimpleNamespace()
    gr.Markdown(about_md(page.options["conditions"]), elem_id="fail-about")
    with gr.Row(equal_height=True):
        ui.subset = gr.Radio(["all", *failures.SUBSETS], value="all", label="subset",
                             elem_id="fail-subset")
        ui.condition = gr.Dropdown(["all", *page.options["conditions"]], value="all",
                                   label="condition", elem_id="fail-condition")
        ui.view = gr.Radio(list(failures.VIEWS.values()), value=failures.VIEWS["ra_lowest"],
                           label="view", elem_id="fail-view")
        ui.compute = gr.Button("Compute the failure table", elem_id="fail-compute",
                               min_width=120, scale=0, size="sm")
    ui.status = gr.Markdown(elem_id="fail-status")
    ui.summary = gr.Dataframe(label="per condition and subset (means)", interactive=False,
                              wrap=True, elem_id="fail-summary", max_height=260,
                              visible=False)
    ui.cases = gr.Dataframe(label="worst cases — click a row to open it in Explore",
                            interactive=False, wrap=True, elem_id="fail-cases",
                            max_height=600, column_widths=view.case_widths(), visible=False)
    return ui


def wire(page: Page, ui: SimpleNamespace, tab: gr.Tab, explore: SimpleNamespace,
         tabs: gr.Tabs) -> None:
    """Connect the tab's events; a clicked row opens in Explore (`explore`: what
    `explore_tab.wire` returned) and runs."""
    fail_in = [ui.subset, ui.condition, ui.view]
    shown = Outputs({"status": ui.status, "summary": ui.summary, "cases": ui.cases})
    private = dict(api_visibility="private")

    def show(subset, condition, view_label, compute, progress=None):
        v = handlers.failures_tab(page.pipeline, page.options, page.failure_table, compute,
                                  subset, condition, view_label, FAILURE_ROWS, progress)
        # a table not computed yet is hidden, not an empty grid headed "1 2 3"
        return shown.values({"status": v.status,
                             **{name: gr.update(value=t, visible=t is not None)
                                for name, t in (("summary", v.summary), ("cases", v.cases))}})

    def read(subset, condition, view_label):
        return show(subset, condition, view_label, False)

    def compute(subset, condition, view_label, progress=gr.Progress()):
        return show(subset, condition, view_label, True, progress)

    opened = explore.example + Outputs({"tabs": tabs})

    def open_case(evt: gr.SelectData):
        return opened.values({**handlers.open_case(page.options["world"],
                                                   evt.row_value)._asdict(),
                              "tabs": gr.Tabs(selected="explore")})

    # read from the cache when the tab opens, computed only on request
    gr.on([tab.select, ui.subset.change, ui.condition.change, ui.view.change], read,
          fail_in, shown.components, **private)
    ui.compute.click(compute, fail_in, shown.components, concurrency_limit=1, **private)
    ui.cases.select(open_case, None, opened.components, **private).success(**explore.run)

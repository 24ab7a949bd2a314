"""The app's event handlers: convert what the browser sends, call the library, format.

Each takes the serving `Answerer` (`ratouch.serve.request`: the loaded pipeline, or what
wraps it; read-only, shared) and the user's `Visual` state explicitly. A query's inputs are
decoded here, once, into a `QueryRequest`, which is handed down as it is.
Anything a user can cause (a bad file, a bad box, no image) becomes a message; only a bug
reaches the server log, and even then the browser gets a message, not a stack trace.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Iterable, NamedTuple

import gradio as gr
import numpy as np
from PIL import Image

from app import box as boxes
from app import view
from app.plot import pca_figure
from ratouch.encoders.factory import model_config
from ratouch.errors import DataError, RATouchError
from ratouch.eval import failures
from ratouch.images import QUERY_MAX_SIDE, check_background_size, to_rgb_array
from ratouch.paths import cascade_calibration
from ratouch.serve.cascade import CASCADE, CascadeCalibration
from ratouch.serve.request import MAX_K, QueryRequest, answer_one, check_k, split_model_name
from ratouch.serve.trace import read_mode, trace_retrieval

log = logging.getLogger(__name__)

# What a user can cause: the library's errors, and PIL's for files it cannot even open.
USER_ERRORS = (RATouchError, OSError, Image.DecompressionBombError)

Fields = tuple[Any, Any, Any, Any]
NO_BOX: Fields = (None, None, None, None)


def upload_path(value: Any) -> str | np.ndarray | None:
    """What an image component sends without gradio's own decoding (`preprocess=False`):
    the uploaded file's {"path": ...} becomes its server path; None and arrays stay."""
    if isinstance(value, dict):
        return value.get("path")
    return value


def user_message(e: BaseException, files: dict[str, Any] | None = None) -> str:
    """The message a user sees for an exception raised while handling their input.

    Args:
        e: the exception.
        files: {"visual image": path, ...}: uploaded files named in the message are shown by
            their own name and role, not by their path in the server's upload cache.
    """
    if isinstance(e, RATouchError):
        msg = str(e)
    elif isinstance(e, Image.DecompressionBombError):
        msg = f"the image is too large to decode safely: {e}"
    elif isinstance(e, OSError):
        msg = f"the file could not be read as an image ({type(e).__name__}: {e})"
    else:
        log.error("unexpected error in an app handler", exc_info=e)
        return f"internal error ({type(e).__name__}); it has been logged on the server"
    for role, path in (files or {}).items():
        if isinstance(path, str) and path:  # the role once (the library's or ours), the name
            name = Path(path).name
            if f"{role} {path}" in msg:
                msg = msg.replace(f"{role} {path}", f"{role} {name}")
            else:
                msg = msg.replace(path, f"{name} ({role})", 1)
            msg = msg.replace(path, name)
    return msg


def _fail(e: BaseException, files: dict[str, Any] | None = None) -> str:
    msg = user_message(e, files)
    gr.Warning(msg)
    return msg


def _box_note(visual: boxes.Visual | None, box) -> str:
    if visual is None:
        return ""
    if visual.corner is not None:
        x, y = (round(v) for v in visual.corner)
        return f"First corner at ({x}, {y}): click the opposite corner."
    if box is None:
        return (f"No box marked: TVL's centred crop {list(boxes.default_box(visual))} (dashed); "
                "click two corners to mark one.")
    problem = boxes.box_problem(box, visual.size)
    if problem:
        return f"⚠️ {problem}"
    used = list(boxes.used_box(box, visual.size))
    whole = [int(v) if float(v).is_integer() else v for v in box]
    return f"Contact box {used}." + ("" if used == whole else
                                     f" (typed {whole}; the query uses whole pixels)")


# ---------------------------------------------------------------------- loading the images

class BoxView(NamedTuple):
    """The visual image and its contact box as the page shows them (fields named as the
    page's outputs)."""

    state: boxes.Visual | None  # the session's visual image
    visual: Any  # the preview, box drawn
    x0: Any
    y0: Any
    x1: Any
    y1: Any
    box_note: str


class ExampleView(NamedTuple):
    """A world example (or failure case) loaded into Explore's inputs."""

    state: boxes.Visual | None
    visual: Any
    tactile: Any
    background: Any
    x0: Any
    y0: Any
    x1: Any
    y1: Any
    box_note: str


class TypedBox(NamedTuple):
    """The preview redrawn for a typed box."""

    state: boxes.Visual | None
    visual: Any
    box_note: str


def upload_visual(value: Any) -> BoxView:
    """A visual image was uploaded (the component's value, raw or a path): check it, preview
    it, clear the box."""
    path = upload_path(value)
    if path is None:
        return BoxView(None, None, *NO_BOX, "")
    try:
        name = Path(path).name if isinstance(path, str) else "(an array)"
        visual = boxes.load_visual(path, f"uploaded image {name}")
    except USER_ERRORS as e:
        return BoxView(None, None, *NO_BOX, f"✖ {_fail(e, {'visual image': path})}")
    return BoxView(visual, boxes.draw(visual, None), *NO_BOX, _box_note(visual, None))


def visual_uploaded(value: Any) -> dict[str, Any]:
    """`upload_visual`, then the results: kept, or cleared (with the message) when the file
    cannot be used, so that an old answer is never mistaken for the new one.

    Returns:
        the page's outputs by name: `BoxView`'s, and `QueryView`'s when cleared
    """
    out = upload_visual(value)
    if out.state is None and out.box_note.startswith("✖"):
        return {**out._asdict(), **error_view(out.box_note[2:]).named()}
    return out._asdict()


def upload_tactile(value: Any) -> dict[str, Any]:
    """A tactile image was uploaded (the component's raw value): decode it now (bounded, as
    the query will), so that an unreadable file is named, with its role, at once; it is then
    removed and the previous results are cleared.

    Returns:
        the page's outputs by name: {} when the file is usable, else the tactile input
        emptied and `QueryView`'s outputs holding the message
    """
    return _check_upload(value, "tactile image", "tactile")


def upload_background(value: Any, tactile: Any = None) -> dict[str, Any]:
    """A sensor background was uploaded: checked at once like a tactile frame (readable; the
    tactile frame's size when one is loaded), else removed, with the reason.

    Returns:
        as `upload_tactile`, for the background input
    """
    return _check_upload(value, "background image", "background",
                         against=upload_path(tactile))


def _check_upload(value: Any, role: str, output: str, against: Any = None) -> dict[str, Any]:
    """Decode an uploaded frame now (bounded, as the query will), and compare its size with
    `against` (the tactile frame a background belongs to): an unusable file is named, with
    its role, at once; it is then removed (`output`: its input's name) and the previous
    results are cleared."""
    path = upload_path(value)
    if path is None or not isinstance(path, str):
        return {}
    try:
        to_rgb_array(path, name=role, max_side=QUERY_MAX_SIDE)
        if isinstance(against, str) and against:
            with Image.open(path) as a, Image.open(against) as b:
                check_background_size(a.size, b.size, f"the {role} {path}")
    except USER_ERRORS as e:
        return {output: None, **error_view(_fail(e, {role: path})).named()}
    return {}


def example_item(world, index: int) -> tuple[np.ndarray, str]:
    """A test-split example's visual image and ground-truth label."""
    s = world.sample("test", index)
    return s.visual, s.caption


def _box4(box) -> tuple[int, int, int, int]:
    """A sample's contact box as four ints (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = (int(v) for v in box)
    return x0, y0, x1, y1


def load_example(world, index: Any) -> ExampleView:
    """Load test-split pair `index` (visual, tactile, its sensor's background, its contact
    box and label). The background fills the optional field, as TVL rows carry one: the
    query reads the frame against it, as the evaluations do."""
    try:
        i = int(index)
        s = world.sample("test", i)
        what = s.class_name or "close-up"
        box = _box4(s.box)
        visual = boxes.load_visual(s.visual, f"test example #{i} ({s.subset}: {what}, "
                                   f"{s.material.replace('_', ' ')})", label=s.caption,
                                   example={"index": i, "condition": None, "box": box})
    except (TypeError, ValueError, IndexError, *USER_ERRORS) as e:
        msg = _fail(e if isinstance(e, USER_ERRORS) else
                    DataError(f"no test example {index!r}: {e}"))
        return ExampleView(None, None, None, None, *NO_BOX, f"✖ {msg}")
    return ExampleView(visual, boxes.draw(visual, box), s.tactile,
                       world.background_image(s.sensor), *box,
                       f"Ground-truth label: **{s.caption}** · {_box_note(visual, box)}")


# ---------------------------------------------------------------------- the contact box

def click_box(visual: boxes.Visual | None, x: float, y: float, fields: Fields) -> BoxView:
    """A click on the preview at (x, y) preview pixels."""
    if visual is None:
        return BoxView(None, None, *fields, "Upload a visual image or pick an example first.")
    visual, box = boxes.click(visual, x, y)
    if box is None:  # first corner: keep the fields, show the corner over the old box
        return BoxView(visual, boxes.draw(visual, _typed(fields)), *fields,
                       _box_note(visual, None))
    return BoxView(visual, boxes.draw(visual, box), *box, _box_note(visual, box))


def typed_box(visual: boxes.Visual | None, *fields) -> TypedBox:
    """The box fields were edited: redraw."""
    if visual is None:
        return TypedBox(None, None, "")
    try:
        box = boxes.fields_to_box(*fields)
    except DataError as e:  # often just half typed: say what is missing, draw the default
        return TypedBox(visual, boxes.draw(visual, None), str(e))
    visual = boxes.replace(visual, corner=None)
    return TypedBox(visual, boxes.draw(visual, box), _box_note(visual, box))


def reset_box(visual: boxes.Visual | None) -> BoxView:
    """Back to the default box."""
    if visual is None:
        return BoxView(None, None, *NO_BOX, "")
    visual = boxes.replace(visual, corner=None)
    return BoxView(visual, boxes.draw(visual, None), *NO_BOX, _box_note(visual, None))


def _typed(fields: Fields):
    try:
        return boxes.fields_to_box(*fields)
    except DataError:
        return None


# ---------------------------------------------------------------------- the query

@dataclass(frozen=True)
class QueryView:
    """Everything the Explore tab shows for one query.

    Attributes:
        status: what was queried, with which box and model, and the notes.
        galleries: per query mode (`QUERY_MODES`), its row of neighbour tiles (HTML).
        tables: per query mode, its neighbour table (HTML).
        plot: the PCA figure.
        description: the trust line, both descriptions and what retrieval did.
        timings: the per-stage timings line.
        raw: the answer's JSON (None: no answer).
        geometry: the press read as a height map against the sensor's background, or
            the hint that a background gives one (`view.geometry_html`).
    """

    status: str
    galleries: Mapping[str, str]
    tables: Mapping[str, str]
    plot: Any
    description: str
    timings: str
    raw: dict | None
    geometry: str = view.GEOMETRY_HINT

    def named(self) -> dict[str, Any]:
        """The view by output name: "status", "gallery_<mode>" and "table_<mode>" per mode,
        "plot", "description", "timings", "raw", "geometry"."""
        return {"status": self.status,
                **{f"gallery_{m}": html for m, html in self.galleries.items()},
                **{f"table_{m}": html for m, html in self.tables.items()},
                "plot": self.plot, "description": self.description, "timings": self.timings,
                "raw": self.raw, "geometry": self.geometry}


def output_names(modes: Iterable[str] = view.MODES) -> list[str]:
    """`QueryView.named`'s names for the query modes `modes`."""
    return ["status", *(f"gallery_{m}" for m in modes), *(f"table_{m}" for m in modes),
            "plot", "description", "timings", "raw", "geometry"]


def error_view(message: str) -> QueryView:
    return QueryView(view.error_md(message), {m: "" for m in view.MODES},
                     {m: "" for m in view.MODES}, None, "", "", None)


def run_query(pipe, thumbnail: Callable[[int], np.ndarray], visual: boxes.Visual | None,
              tactile: Any, x0, y0, x1, y1, k, progress=None, background: Any = None,
              largest_k: int = MAX_K, judge=None, encoder: str | None = None,
              wait_note: str = "", retrieval: str | None = None) -> QueryView:
    """Decode the session's image, the tactile image (and the sensor's background frame, if
    given) and the box into a request, have `pipe` answer it, and format the answer.
    `tactile` and `background` may be the components' raw values; `judge` scores the
    descriptions of labelled examples; `encoder` names the model where `pipe` offers a
    choice (`ModelChoice`); `wait_note` says, while the query waits, that its model is still
    being prepared; `retrieval` names the retrieval system RA-Touch answers with (a key of
    `RETRIEVAL_SYSTEMS`; None: the answerer's default)."""
    tactile, background = upload_path(tactile), upload_path(background)
    t_run = time.perf_counter()
    try:
        if visual is None:
            raise DataError("upload a visual image or pick an example first")
        box = boxes.fields_to_box(x0, y0, x1, y1)
        k = check_k(k, largest_k)
        if progress is not None:
            progress(0.05, desc=wait_note or "encoding, retrieving, generating…")
        request = QueryRequest.decode(visual.source, tactile, box=box, k=k, label=visual.label,
                                      background=background, model=encoder or None,
                                      retrieval=retrieval)
        answered = answer_one(pipe, request)
        result = answered.to_dict()
        height = answered.height_map  # the press as geometry (with a background)
        t0 = time.perf_counter()
        waited_ms = (t0 - t_run) * 1000  # from Run: decoding, any wait for a model, answer
        if progress is not None:
            progress(0.9, desc="thumbnails…")
        trace = trace_retrieval(result)
        attended = [a.rank for a in trace.attended] if trace else []
        galleries = {m: view.neighbour_strip(result, m, thumbnail, attended) for m in view.MODES}
    except Exception as e:  # noqa: BLE001 - user_message logs anything not caused by the user
        files = {"visual image": getattr(visual, "source", None), "tactile image": tactile,
                 "background image": background}
        return error_view(_fail(e, files))
    tables = {m: view.neighbour_table(result, m) for m in view.MODES}
    # a ground-truth label (test-split examples): score both descriptions against it; a failure
    # case's descriptions that its table row judged keep the row's scores
    scores = (failures.judge_scores(visual.label, result["description"], judge,
                                    judged_descriptions(visual)) if judge else {})
    geometry = view.geometry_html(result, None if height is None else height.image(),
                                  request.background is not None)
    render_ms = (time.perf_counter() - t0) * 1000
    return QueryView(view.status_md(visual.title, result["warnings"], result.get("box"), result),
                     galleries, tables, pca_figure(result, visual.label),
                     view.description_md(result, visual.label, scores, trace),
                     view.timings_md(result["timings_ms"], render_ms, waited_ms), result,
                     geometry)


def neighbour_picker(result: dict | None):
    """The "take retrieval apart" checkboxes for a new result: every joint neighbour, ticked."""
    choices = view.neighbour_choices(result)
    return gr.CheckboxGroup(choices=choices, value=[i for _, i in choices])


def regenerate(pipe, visual: boxes.Visual | None, tactile: Any, x0, y0, x1, y1,
               kept: list[int] | None, result: dict | None, judge=None,
               encoder: str | None = None, background: Any = None) -> str:
    """RA-Touch's description again, reading only the ticked neighbours (the `regenerate` of
    the model that `encoder` names, `pipe.model(encoder)`), beside the description it
    answered with; the tactile frame is read against `background` as the query read it."""
    tactile, background = upload_path(tactile), upload_path(background)
    try:
        if visual is None or not result or not result.get("neighbours", {}).get(
                read_mode(result)):
            raise DataError("run a query with a tactile image first")
        kept = [int(i) for i in (kept or [])]
        box = boxes.fields_to_box(x0, y0, x1, y1)
        # the system the answer came from reads the kept neighbours again (its generator)
        request = QueryRequest.decode(visual.source, tactile, box=box, background=background,
                                      model=encoder or None,
                                      retrieval=(result.get("retrieval") or {}).get("system"))
        again = pipe.model(encoder or None).regenerate(request, kept)
    except Exception as e:  # noqa: BLE001 - user_message logs anything not caused by the user
        return view.error_md(_fail(e, {"visual image": getattr(visual, "source", None),
                                       "tactile image": tactile,
                                       "background image": background}))
    scores = {}
    if judge is not None and visual.label:
        ra = judged_descriptions(visual).get("ra_touch")
        scores = failures.judge_scores(visual.label, {
            "new": again["description"]["ra_touch"],
            "old": result["description"]["ra_touch"]}, judge,
            {"new": ra, "old": ra} if ra else None)
    return view.regenerated_md(result, again, kept, scores.get("new"), scores.get("old"))


def api_query(pipe, visual: str | None, tactile: str | None, x0, y0, x1, y1, k,
              encoder: str | None = None, background: str | None = None,
              retrieval: str | None = None) -> dict:
    """The `/query` API: image files, box, K, the model, the tactile sensor's background
    (optional: the frame is read against it) and the retrieval system (optional: a key of
    `RETRIEVAL_SYSTEMS`; the answerer's default) in, the answer's JSON out
    (`QueryResult.to_dict`).

    Raises:
        gr.Error: with the reason, for anything the caller can fix.
    """
    try:
        if visual is None:
            raise DataError("a visual image is required")
        box = boxes.fields_to_box(x0, y0, x1, y1)
        request = QueryRequest.decode(visual, tactile, box=box,
                                      k=check_k(5 if k is None else k, MAX_K), background=background,
                                      model=encoder or None, retrieval=retrieval or None)
        return answer_one(pipe, request).to_dict()
    except Exception as e:  # noqa: BLE001 - user_message logs anything not caused by the user
        files = {"visual image": visual, "tactile image": tactile,
                 "background image": background}
        raise gr.Error(user_message(e, files), print_exception=False) from e


# ---------------------------------------------------------------------- the models

def describe_model(name: str) -> tuple[str, str]:
    """(a few words for the menu, one line for the page) on a model of the menu: from its
    encoder config, or for the cascade from its shipped calibration."""
    if name == CASCADE:
        try:
            cal = CascadeCalibration.load(cascade_calibration())
        except RATouchError as e:
            return "not calibrated", f"cascade: {e}"
        first, *rest = cal.encoders
        meta = cal.meta or {}
        share = (meta.get("measures", {}).get(cal.measure, {}).get("answered_by") or [None])[0]
        last = (meta.get("stages") or {}).get(cal.encoders[-1], {})
        line = (f"cascade: each query is answered by `{first}` when it is sure (confidence "
                f"“{cal.measure}” of its top-{cal.k} joint neighbours ≥ "
                f"{cal.thresholds[0]:.3f}), else passed on to `{'` then `'.join(rest)}`"
                + (f"; on {meta['n_validation']:,} validation renders as accurate as "
                   f"`{cal.encoders[-1]}` alone (P@{cal.k} {last['precision']:.3f})"
                   if meta.get("n_validation") and last.get("precision") else "")
                + (f", {share:.0%} of them answered by `{first}`" if share is not None else ""))
        return f"{first} when sure, else {' then '.join(rest)}", line
    encoder, lm = split_model_name(name)
    try:
        cfg = model_config(encoder)
    except RATouchError:
        return "", f"{name}: not a shipped encoder set (no config describes it)"
    w, h = cfg.get("tactile_size", ("?", "?"))
    role = cfg.get("role", "encoder set")
    generators = ("" if lm is None else
                  f"; generators adapted from the pretrained language model `{lm}` (visual "
                  "prompt and LoRA; loaded when first chosen)")
    return (role if lm is None else f"{role}, {lm} generators"), (
        f"{name}: {role} — {cfg['dim']}-d embeddings, tower width "
        f"{cfg.get('width', '?')}, tactile frames at {w}×{h} px, visual prior "
        f"{cfg.get('prior', 'none')}{generators}")


def model_choices(models: Sequence[str]) -> list[tuple[str, str]]:
    """The menu's (label, name) pairs: each name with a few words on what it is."""
    out = []
    for name in models:
        short = describe_model(name)[0]
        out.append((f"{name} — {short}" if short else name, name))
    return out


def models_md(models: Sequence[str]) -> str:
    """Every model of the menu in one line each (what "cascade" does included)."""
    lines = "".join(f"<div>{_md_code(describe_model(m)[1])}</div>" for m in models)
    return (f"<details class='ra-about' id='models-about'><summary>What each model is "
            f"({len(models)})</summary>{lines}</details>")


def _md_code(text: str) -> str:
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", view.escape(text))


# ---------------------------------------------------------------------- failure cases

class FailureView(NamedTuple):
    """What the Failure cases tab shows, in output order."""

    status: str
    summary: Any  # DataFrame or None
    cases: Any  # DataFrame or None


def failure_table(pipe, options: dict, compute: bool, progress=None) -> dict | None:
    """The failure-case table for the app's settings: cached, else computed (`compute`) or
    None, with the pipeline of `pipe`'s default model (a cascade's: its first stage).
    `options` are `ratouch.eval.failures.load_or_compute`'s world/k/conditions/indices."""
    report = None if progress is None else (lambda f, what: progress(f, desc=what))
    model = pipe.model()
    pipeline = model.stages[0] if hasattr(model, "stages") else model
    return failures.load_or_compute(pipeline, progress=report, cached_only=not compute,
                                    **options)


#: After a failed computation of the failure table (about 30 s of CPU), how long Compute
#: refuses to start it again: at most one computation runs at a time (the event's
#: concurrency limit), a finished table is kept (`shared`), and a failing one cannot be
#: repeated back to back by whoever posts the event.
FAILED_COMPUTE_PAUSE_S = 600.0


def failures_tab(pipe, options: dict, shared: dict, compute: bool, subset: str,
                 condition: str, view_label: str, limit: int = 50, progress=None
                 ) -> FailureView:
    """The Failure cases tab: the table from `shared` (the app's, loaded once), else from
    the cache, else computed when `compute`; then filtered and sorted."""
    wait = FAILED_COMPUTE_PAUSE_S - (time.monotonic() - shared.get("failed_at", -1e9))
    if compute and shared.get("table") is None and wait > 0:  # anyone may press Compute (or
        # post its event): a computation that failed is not run again at once
        return FailureView(f"✖ the failure table's computation failed "
                           f"({shared.get('failure')}); try again in {wait / 60:.0f} min",
                           None, None)
    try:
        if shared.get("table") is None:
            shared["table"] = failure_table(pipe, options, compute, progress)
    except Exception as e:  # noqa: BLE001 - user_message logs anything not caused by the user
        if compute:
            shared["failed_at"], shared["failure"] = time.monotonic(), _fail(e)
        return FailureView(f"✖ cannot {'compute' if compute else 'load'} the failure "
                           f"table: {_fail(e)}", None, None)
    return failure_view(shared["table"], subset, condition, view_label, limit)


def failure_view(table: dict | None, subset: str, condition: str, view_label: str,
                 limit: int = 50) -> FailureView:
    """The filtered, sorted worst cases of a table (None: not computed yet)."""
    if table is None:
        return FailureView("The failure-case table has not been computed for this pipeline "
                           f"yet: press **Compute** ({view.FAILURE_WAIT} on a 2-core CPU when "
                           "measured; cached afterwards).",
                           None, None)
    view_key = next((k for k, v in failures.VIEWS.items() if v == view_label), view_label)
    try:
        matching = failures.select_cases(table["rows"], subset, condition, view_key, limit=None)
    except RATouchError as e:
        return FailureView(f"✖ {e}", None, None)
    summary = failures.summarise([r for r in table["rows"]
                                  if condition in ("all", r["condition"])])
    shown = matching[:limit]
    return FailureView(view.failures_status_md(table["meta"], len(shown), len(matching),
                                               failures.VIEWS[view_key]),
                       view.summary_frame(summary), view.cases_frame(shown))


@dataclass(frozen=True)
class CaseVisual(boxes.Visual):
    """A failure case's visual image (`open_case`), with the descriptions its table row judged:
    {system: (description, score)} (`failures.row_scores`). The case view shows a description
    the table judged with the table's score (`failures.judge_scores`)."""

    judged: Mapping[str, tuple[str | None, float]] = field(default_factory=dict)


def judged_descriptions(visual: boxes.Visual | None) -> dict[str, tuple[str | None, float]]:
    """The judged descriptions a session's visual image carries ({} unless a failure case)."""
    return dict(visual.judged) if isinstance(visual, CaseVisual) else {}


def _row_judged(row: Any, label: str | None) -> dict[str, tuple[str | None, float]]:
    """A clicked failure-table row's judged descriptions; {} for a row without them (a row
    holds the table's columns, `view.case_columns()`, in order) or judged against another
    label than the case's."""
    keys = [key for _, key in view.case_columns()]
    if not isinstance(row, (list, tuple)) or len(row) != len(keys):
        return {}
    values = dict(zip(keys, row))
    if values.get("label") != label:
        return {}
    try:
        return failures.row_scores(values)
    except (TypeError, ValueError):
        return {}


def open_case(world_cfg, row: Any) -> ExampleView:
    """Open a failure-table row (its condition and test index come first) in Explore. The
    session's image carries the row's judged descriptions (`CaseVisual`), so that the case
    view shows the table's scores.

    Raises:
        gr.Error: the row does not name a case (so that a chained query does not run).
    """
    try:
        condition, index = row[0], int(row[1])
        loaded = load_case(world_cfg, condition, index)
    except (TypeError, ValueError, IndexError, *USER_ERRORS) as e:
        raise gr.Error(user_message(e if isinstance(e, USER_ERRORS) else
                                    DataError(f"not a failure case: {row!r}")),
                       print_exception=False) from e
    state = loaded.state
    assert state is not None  # load_case always loads the case's image
    visual = CaseVisual(**{f.name: getattr(state, f.name) for f in fields(state)},
                        judged=_row_judged(row, state.label))
    return loaded._replace(state=visual)


def load_case(world_cfg, condition: str, index: int) -> ExampleView:
    """Test pair `index` under the stress condition `condition` (its stressed inputs, its
    sensor's background, box and label).

    Raises:
        ConfigError: an unknown condition; IndexError / DataError: no such pair.
    """
    s = failures.case_sample(condition, index, world_cfg)
    background = failures.case_world(condition, world_cfg).background_image(s.sensor)
    box = _box4(s.box)
    visual = boxes.load_visual(
        s.visual, f"failure case #{index} under “{condition}” ({s.subset}: "
        f"{s.class_name or 'close-up'}, {s.material.replace('_', ' ')})", label=s.caption,
        example={"index": index, "condition": condition, "box": box})
    return ExampleView(visual, boxes.draw(visual, box), s.tactile, background, *box,
                       f"Ground-truth label: **{s.caption}** · condition **{condition}** · "
                       f"{_box_note(visual, box)}")


class LinkView(NamedTuple):
    """What a link (`?example=N&model=…&k=…`) puts into Explore: the example and the
    settings, by output name."""

    example: ExampleView
    k: int
    model: str | None


def open_link(world, world_cfg, params: Mapping[str, str], models: Sequence[str] | None,
              largest_k: int = MAX_K) -> LinkView | None:
    """The query a page link names (`record.RunRecord.link`): `example` (a test index),
    optionally `condition` (a stress condition of the failure table), `model` (one of
    `models`), `k` and `box` (x0,y0,x1,y1). None when the link names no example.

    Raises:
        DataError: a parameter that does not name what the page offers (with its value).
    """
    if not params.get("example"):
        return None
    try:
        index = int(params["example"])
    except ValueError as e:
        raise DataError(f"link: example must be a test index, got {params['example']!r}") from e
    condition = params.get("condition") or None
    if condition:
        try:
            loaded = load_case(world_cfg, condition, index)
        except (IndexError, *USER_ERRORS) as e:
            raise DataError(f"link: no example {index} under condition {condition!r}: {e}"
                            ) from e
    else:
        loaded = load_example(world, index)
        if loaded.state is None:
            raise DataError(f"link: {loaded.box_note[2:]}")
    model = params.get("model") or None
    if model is not None and model not in (models or []):
        raise DataError(f"link: model {model!r} is not offered here; offered: "
                        f"{', '.join(models or []) or 'none to choose'}")
    k = check_k(params.get("k") or 5, largest_k)
    if params.get("box"):
        parts = params["box"].split(",")
        if len(parts) != 4:
            raise DataError(f"link: box must be x0,y0,x1,y1, got {params['box']!r}")
        box = boxes.fields_to_box(*parts)
        visual = loaded.state
        assert visual is not None  # an example without its image was refused above
        loaded = loaded._replace(visual=boxes.draw(visual, box), x0=parts[0], y0=parts[1],
                                 x1=parts[2], y1=parts[3], box_note=_box_note(visual, box))
    return LinkView(loaded, k, model)

"""Turning library results into what the app shows: gallery items with shared-neighbour marks,
neighbour tables, the descriptions (with judge scores), warnings and timings of one
`RATouchPipeline.query`; the failure-case table; the benchmark report and its figures.
Formatting only: every number comes from the library or from files it wrote."""

from __future__ import annotations

import base64
import io
import re
from html import escape
from pathlib import Path
from typing import Callable, Mapping, Sequence
from urllib.parse import quote

import numpy as np
from PIL import Image

from ratouch.search.modes import QUERY_MODES, RA_TOUCH_MODE
from ratouch.serve.request import split_model_name
from ratouch.serve.trace import RetrievalTrace, marked_segments, read_mode, touch_reading

MODES = QUERY_MODES
MODE_TITLE = QUERY_MODES.field("title")  # live views of the registry's rows
MODE_COLOUR = QUERY_MODES.field("colour")
MODE_LETTER = QUERY_MODES.field("letter")
STALE = "inputs changed — press Run"


def strip_order() -> list[str]:
    """The order the answer shows the modes' neighbour rows: the mode RA-Touch reads first
    (its neighbours are the ones the answer is made from), then the others in the
    registry's order."""
    return [RA_TOUCH_MODE, *(m for m in MODES if m != RA_TOUCH_MODE)]


def stale_html(shown: bool) -> str:
    """The banner over an answer whose inputs have changed since it was answered ("" when
    there is no answer on the page, or it is current)."""
    if not shown:
        return ""
    return (f"<div class='ra-stale' role='status'>⚠ {STALE}: the answer below is for the "
            "previous inputs</div>")


def example_strip(items: Sequence[tuple[int, np.ndarray, str]]) -> str:
    """The world's examples as a row of tiles (index, visual thumbnail, ground-truth label),
    each label shown whole under its tile; a click loads the example and runs it."""
    tiles = "".join(
        f"<figure class='ra-example' data-example='{i}' role='button' tabindex='0' "
        f"title='test example #{i}: {escape(label, quote=True)}'>"
        f"<img src='{data_uri(image)}' alt='test example {i}'>"
        f"<span class='ra-badge'>#{i}</span><figcaption>{escape(label)}</figcaption></figure>"
        for i, image, label in items)
    return f"<div class='ra-examples'>{tiles}</div>"


#: A click on an example tile triggers the component's "click" event with its test index.
EXAMPLE_CLICK_JS = (
    "element.addEventListener('click', (e) => {"
    " const f = e.target.closest('[data-example]');"
    " if (f) trigger('click', {index: Number(f.dataset.example)}); });"
    "element.addEventListener('keydown', (e) => {"
    " const f = e.target.closest('[data-example]');"
    " if (f && (e.key === 'Enter' || e.key === ' ')) {"
    " e.preventDefault(); trigger('click', {index: Number(f.dataset.example)}); } });")


def shared_modes(neighbours: dict[str, list[dict]]) -> dict[int, list[str]]:
    """For each retrieved id, the modes (in MODES order) whose top-K hold it."""
    held: dict[int, list[str]] = {}
    for mode in MODES:
        for n in neighbours.get(mode, []):
            if mode not in held.setdefault(n["id"], []):
                held[n["id"]].append(mode)
    return held


def share_mark(modes: list[str]) -> str:
    """'' for a neighbour one mode found; '◆ I·J' / '◆◆ I·T·J' for one found by two / three."""
    if len(modes) < 2:
        return ""
    return "◆" * (len(modes) - 1) + " " + "·".join(MODE_LETTER[m] for m in modes)


def group_by_caption(neighbours: Sequence[dict]) -> list[tuple[int, dict, int]]:
    """(rank of the best, best neighbour, count) per distinct tactile caption, best first:
    the top-K often repeats one caption, which a gallery then shows once (×count)."""
    groups: dict[str, list] = {}
    for rank, n in enumerate(neighbours, 1):
        groups.setdefault(n["caption"], [rank, n, 0])[2] += 1
    return [tuple(g) for g in groups.values()]


def data_uri(image: np.ndarray | str, png: bool = False) -> str:
    """A thumbnail as an inline JPEG, or PNG (`png`: sharp colours of a false-colour map; a
    string passes through: already a URI)."""
    if isinstance(image, str):
        return image
    buf = io.BytesIO()
    picture = Image.fromarray(np.asarray(image, dtype=np.uint8)).convert("RGB")
    if png:
        picture.save(buf, "PNG")
    else:
        picture.save(buf, "JPEG", quality=85)
    kind = "png" if png else "jpeg"
    return f"data:image/{kind};base64," + base64.b64encode(buf.getvalue()).decode("ascii")


#: What a mode that reads touch shows for a frame with no contact, instead of its neighbours.
NO_CONTACT_NEIGHBOURS = ("not shown: no contact detected, so this query's nearest captions "
                         "match an empty gel, not a material (they stay in the JSON)")


def touch_unread(result: dict, mode: str) -> bool:
    """Whether `mode` reads touch and the result's frame showed no contact: its neighbours
    are then the nearest captions to an empty gel, which the page does not show as a
    material's."""
    tactile = (result.get("trust") or {}).get("tactile") or {}
    return (bool(tactile.get("no_contact")) and mode in QUERY_MODES
            and QUERY_MODES[mode].needs_touch)


def shown_neighbours(result: dict) -> dict[str, list[dict]]:
    """The result's neighbours the page shows as a material's: every mode's but those
    `touch_unread` (so that no badge says an image neighbour was also found by them)."""
    return {m: rows for m, rows in result.get("neighbours", {}).items()
            if not touch_unread(result, m)}


def neighbour_strip(result: dict, mode: str, thumbnail: Callable[[int], np.ndarray | str],
                    attended: Sequence[int] = ()) -> str:
    """One mode's neighbours as a row of fixed-size tiles (HTML), one per distinct tactile
    caption, best first: a rank/similarity badge and a ×n badge for folded duplicates on the
    image, the caption under it (two lines; all of it, the class and which modes share it on
    hover). `attended`: ranks, among the neighbours of the mode the answer read (`read_mode`:
    the joint query's for the paper's system, the gated or the image query's for `gated`), of
    those the integrator attended to most; outlined in that mode's row only."""
    title = (f"<div class='ra-mode-title'><span style='color:{MODE_COLOUR[mode]}'>●</span> "
             f"{escape(MODE_TITLE[mode])}{touch_reading_mark(result, mode)}</div>")
    rows = result.get("neighbours", {}).get(mode)
    if rows and touch_unread(result, mode):
        return (f"<div class='ra-mode' id='strip-{mode}'>{title}<div class='ra-strip ra-muted'>"
                f"{NO_CONTACT_NEIGHBOURS}</div></div>")
    if not rows:
        return (f"<div class='ra-mode' id='strip-{mode}'>{title}<div class='ra-strip ra-muted'>"
                "not available for this query (needs a tactile image)</div></div>")
    shared = shared_modes(shown_neighbours(result))
    # a folded tile is outlined when any neighbour it holds was among the most attended
    reads = read_mode(result)
    read = {rows[r - 1]["caption"] for r in attended if 0 < r <= len(rows)}
    tiles = []
    for rank, n, count in group_by_caption(rows):
        modes = shared[n["id"]]
        held = f" · also found by the {', '.join(m for m in modes if m != mode)} query" \
            if len(modes) > 1 else ""
        hover = (f"#{rank} of {len(rows)} · similarity {n['score']:.3f}"
                 + (f" · {count} of the top {len(rows)} share this caption" if count > 1 else "")
                 + f" · {n['class_name']} (corpus id {n['id']}){held}\n{n['caption']}")
        cls = "ra-tile ra-attended" if mode == reads and n["caption"] in read else "ra-tile"
        badges = f"<span class='ra-badge'>{rank} · {n['score']:.2f}</span>"
        if count > 1:
            badges += f"<span class='ra-count'>×{count}</span>"
        if len(modes) > 1:
            badges += (f"<span class='ra-shared-badge'>"
                       f"{'·'.join(MODE_LETTER[m] for m in modes)}</span>")
        tiles.append(f"<figure class='{cls}' title='{escape(hover, quote=True)}'>"
                     f"<img src='{data_uri(thumbnail(n['id']))}' alt='{escape(n['caption'])}'>"
                     f"{badges}<figcaption>{escape(n['caption'])}</figcaption></figure>")
    return (f"<div class='ra-mode' id='strip-{mode}'>{title}<div class='ra-strip'>"
            f"{''.join(tiles)}</div></div>")


def touch_reading_mark(result: dict, mode: str) -> str:
    """Under the title of the query whose top caption is what touch alone reads
    (`touch_reading`: the adapted query's for a press whose shape reads as an everyday one,
    the paper's tactile query's otherwise), a mark that says so, the why in its tooltip; ""
    for the other modes and for a frame with no contact."""
    read = touch_reading(result)
    if read["query"] != mode or not read["caption"] or touch_unread(result, mode):
        return ""
    what = "its shape" if read["by"] == "shape" else "its tactile embedding (no background)"
    why = {"everyday": f"{what} reads as an everyday press (a flat face, fabric, foam, tape, "
                       "wire, an edge, a small cap), so the query fitted on such presses "
                       "reads it",
           "world": f"{what} reads as a firm press, so the paper's tactile query reads "
                    "it"}.get(read["regime"] or "", "no router read the press: the paper's "
                                                    "tactile query reads it")
    tip = escape(f"what touch alone reads: this query's top caption, "
                 f"“{read['caption']}”; {why}", quote=True)
    return (f"<div class='ra-touch-reading' id='touch-reading' title='{tip}'>★ touch alone "
            f"reads its top caption</div>")


def corpus_provenance(corpus) -> str:
    """What the corpus is, for the header: the world's own ImageNet-T-recipe corpus, or the
    user's (with its image source)."""
    manifest = getattr(corpus, "manifest", None) or {}
    n = len(corpus.entries)
    if manifest.get("source", "world") == "world":
        return (f"corpus of {n:,} procedural-world renders with tactile captions made by "
                "the ImageNet-T recipe (not ImageNet photos)")
    return (f"corpus of {n:,} entries of your own corpus (images from "
            f"{escape(str(manifest['source']))}, folder {escape(str(corpus.folder))})")


def neighbour_table(result: dict, mode: str) -> str:
    """An HTML table of one mode's neighbours: rank, class, tactile caption, similarity,
    and the other modes that retrieved the same entry."""
    rows = result["neighbours"].get(mode)
    if rows and touch_unread(result, mode):
        return f"<p class='ra-muted'>{NO_CONTACT_NEIGHBOURS}</p>"
    if not rows:
        return "<p class='ra-muted'>not available for this query</p>"
    shared = shared_modes(shown_neighbours(result))
    out = ["<table class='ra-table'><tr><th>#</th><th>class</th><th>tactile caption</th>"
           "<th>sim.</th><th>shared</th></tr>"]
    for rank, n in enumerate(rows, 1):
        mark = share_mark(shared[n["id"]])
        out.append(f"<tr title='corpus id {n['id']} · {escape(n['source'])}'><td>{rank}</td>"
                   f"<td>{escape(n['class_name'])}</td><td>{escape(n['caption'])}</td>"
                   f"<td>{n['score']:.3f}</td><td class='ra-shared'>{mark}</td></tr>")
    out.append("</table>")
    return "".join(out)


def mode_header(mode: str) -> str:
    dot = f"<span style='color:{MODE_COLOUR[mode]}'>●</span>"
    return f"#### {dot} {MODE_TITLE[mode]}"


def description_md(result: dict, label: str | None,
                   scores: Mapping[str, float | None] | None = None,
                   trace: RetrievalTrace | None = None) -> str:
    """The trust line, the generated descriptions (with and without retrieval; RA-Touch's
    words that its most attended neighbours carry marked), the ground truth, each
    description's judge score when the label is known, and what retrieval did (`trace`)."""
    d = result["description"]
    scores = scores or {}

    tactile = (result.get("trust") or {}).get("tactile") or {}
    empty = ("**no contact detected**: nothing is pressed into the gel, so there is no "
             "material to describe" if tactile.get("no_contact") else
             "_not available: needs a tactile image_")

    def line(title: str, key: str, text: str | None = None) -> str:
        text = text or escape(d.get(key) or "") or empty
        score = scores.get(key)
        return f"**{title}:** {text}" + (f" · judge **{score:.1f}**/10" if score else "")

    parts = [*trust_lines(result),
             line("RA-Touch (with retrieval)", "ra_touch", marked_description(d, trace)),
             line("Baseline (no retrieval)", "baseline")]
    if label:
        judged = any(v is not None for v in scores.values())
        parts.append(f"**Ground-truth label:** {escape(label)}" + (
            " <span class='ra-muted'>(judge: the offline judge's 1–10 score of a description "
            "against this label, as in `ratouch eval tvl`)</span>" if judged else ""))
    if trace is not None:
        parts.append(retrieval_md(trace))
    return "\n\n".join(parts)


def marked_description(description: Mapping[str, str], trace: RetrievalTrace | None) -> str:
    """RA-Touch's description as HTML, each word its most attended neighbours' captions carry
    highlighted, with those neighbours' joint ranks ("" when there is no description)."""
    text = description.get("ra_touch") or ""
    if not text or trace is None:
        return escape(text)
    out = []
    for piece, ranks in marked_segments(text, trace.carried):
        if not ranks:
            out.append(escape(piece))
            continue
        who = ", ".join(f"#{r}" for r in ranks)
        out.append(f"<mark class='ra-carried' title='carried by joint neighbour(s) {who}'>"
                   f"{escape(piece)}</mark><sup>{who}</sup>")
    return "".join(out)


def retrieval_md(trace: RetrievalTrace) -> str:
    """What retrieval did: the words RA-Touch changed against the baseline (or that it did
    not), then the joint neighbours the integrator read most, with their captions."""
    if trace.same_words:
        verdict = ("RA-Touch gave **the same words as the baseline**: retrieval did not change "
                   "this answer")
    else:
        changes = ([f"added *{', '.join(trace.added)}*"] if trace.added else []) + (
            [f"dropped *{', '.join(trace.dropped)}*"] if trace.dropped else [])
        verdict = ("RA-Touch **differs from the baseline**: " + "; ".join(changes)
                   if changes else "RA-Touch said the baseline's words in another order")
    spread = ("nearly even: no neighbour stands out" if trace.nearly_even else
              f"an even share is {trace.even_share:.0%}")
    read = ("Read (their captions written into the prompt, in rank order: no integrator "
            "weighs them):" if trace.generator == "text" else
            f"Read most (the integrator's attention; {spread}):")
    lines = [f"**What retrieval did:** {verdict}. {touch_md(trace)} {read}"]
    for a in trace.attended:
        carries = (f" — carries *{', '.join(a.words)}*" if a.words else
                   " — carries none of RA-Touch's words")
        share = "" if trace.generator == "text" else f" **{a.weight:.0%}**"  # no weights
        lines.append(f"- {trace.reads} #{a.rank}{share} · "
                     f"{escape(a.class_name)}: {escape(a.caption)}{carries}")
    return "\n".join(lines)


def touch_md(trace: RetrievalTrace) -> str:
    """Which neighbours the answer read and how far touch was trusted to steer them."""
    title = QUERY_MODES[trace.reads].title if trace.reads in QUERY_MODES else trace.reads
    text = f"Retrieval **{escape(trace.system)}**: read the *{escape(title)}*'s neighbours"
    if trace.generator:
        text += {"reader": " with the reader (trained to read them)",
                 "text": " as text, their captions in the prompt"}.get(
                     trace.generator, " with the paper's generator")
    if trace.touch_weight is None:
        return text + "."
    text += f"; touch steered it **{trace.touch_weight:.0%}**"
    why = [w for w in trace.touch_why if not w.startswith("(")]
    return text + (f" ({escape('; '.join(why))})." if why else ".")


# ---------------------------------------------------------------------- the press as geometry

GEOMETRY_HINT = ("<div class='ra-geometry-note' id='geometry-hint'><b>Height map:</b> "
                 "give the sensor's background (4: its frame with nothing pressed) to see the "
                 "press as a height map, with its depth, spread and relief.</div>")
#: How the height map's units are written, and what they are.
UNITS = {"mm": ("mm", "millimetres: the family's lookup is fitted on a real sensor's "
                      "calibrated ball presses"),
         "render units": ("r.u.", "render units: no real calibration exists for this "
                                  "family; its lookup is fitted on the world's renders, so "
                                  "the depth is a guess in the renderer's own units")}


def geometry_html(result: dict | None, picture: np.ndarray | None, background: bool) -> str:
    """The press read as geometry, under the tactile inputs: its height map (`picture`,
    `HeightMap.image`: dark is flat, white the deepest point) with its scale, depth, spread
    and relief, and the structured-contact reading against the background. Without a
    background the hint that one gives the height map; with one that nothing reads, why
    there is none."""
    tactile = ((result or {}).get("trust") or {}).get("tactile") or {}
    if not background or result is None or not tactile.get("background", background):
        return GEOMETRY_HINT
    title = "<b>Height map</b> of the press against the background"
    if not tactile:
        return (f"<div class='ra-geometry-note'>{title}: none, the model has no trust "
                "calibration, so the press is not read against its background.</div>")
    geo, structure = tactile.get("geometry"), tactile.get("structure")
    # the background's marker dots not where the frame's are, or the frame's own grid not in
    # a background without one: another unit's background
    marks = tactile.get("markers") or {}
    moved = "lattice" if marks.get("lattice") else bool(marks.get("moved"))
    sensor = (tactile.get("sensor") or {}).get("family", "?")
    if geo is None or picture is None:
        why = ("no geometry calibration is loaded" if "geometry" not in tactile else
               f"no geometry lookup reads the sensor family “{escape(sensor)}”")
        return (f"<div class='ra-geometry-note'>{title}: none, {why}."
                f"{structure_line(structure, moved)}</div>")
    unit, meaning = UNITS.get(geo["units"], (geo["units"], geo["units"]))
    digits = 2 if unit == "mm" else 1
    depth = _length(geo["depth"], unit, digits)
    family = escape(geo["family"])
    read = (f"<b class='ra-warn'>⚠ unfamiliar sensor</b>, read as {family} (a guess)"
            if tactile.get("unfamiliar_sensor") else family)
    named = "" if unit == geo["units"] else f" ({escape(geo['units'])})"
    return (f"<div class='ra-geometry' id='geometry-map'>"
            f"<img src='{data_uri(picture, png=True)}' alt='height map of the press (dark: "
            f"flat; white: pushed in {depth})' title='dark: flat · white: pushed in {depth}'>"
            f"<div class='ra-geometry-numbers'>"
            f"<div><b>Height map</b> vs background · {read} · <span "
            f"title='{escape(meaning, quote=True)}'>dark flat → white {depth}</span></div>"
            f"<div>depth <b>{depth}</b>{named} · <span title='share of the gel pushed in by "
            f"more than a third of the depth: a compliant object wraps the gel wide, a rigid "
            f"one small and deep'>spread <b>{geo['spread']:.0%}</b></span> · <span "
            f"title='RMS of the height map&#39;s fine detail: texture'>relief "
            f"<b>{_length(geo['relief'], unit, digits + 1)}</b></span>"
            f"{firmness_line(tactile.get('firmness'), tactile.get('state') == 'uncertain')}"
            f"</div>"
            f"{structure_line(structure, moved)}</div></div>")


def _length(value: float, unit: str, digits: int) -> str:
    """A height in the map's unit at `digits` decimals; a millimetre figure that would
    round to nothing (a texture on a domed gel) in micrometres, two significant digits."""
    if unit == "mm" and abs(value) < 10.0 ** -digits:
        return f"{value * 1000:.2g} µm"
    return f"{value:.{digits}f} {unit}"


def firmness_line(firmness: dict | None, uncertain: bool = False) -> str:
    """The firmness read from the press's shape (the trust block's `firmness`), on the
    numbers' line (the strip keeps its height, so Run stays on the first screen): soft or
    hard, and how sure; nothing for a blank or a family without a model. Where contact is
    `uncertain`, the shape may be the wrong background's or a lighting change's, not a
    press's: marked a guess."""
    if not firmness:
        return ""
    p = float(firmness["soft"])
    sure = p if firmness["reads"] == "soft" else 1 - p
    said = "&gt;99%" if sure > 0.99 else f"{sure:.0%}"
    everyday = ("renders of everyday presses (soft: fabrics, foams; hard: flat faces, tape, "
                "wire, edges, small caps)")
    # a routed model names the regime it read the press in (`RoutedFirmness`)
    regime = firmness.get("regime")
    by = (f"by two models fitted on renders, of {everyday} and of firm presses like the "
          f"world&#39;s own, mixed by how much the press looks like each (read here as "
          f"{'a firm press' if regime == 'world' else 'an everyday press'})"
          if regime else f"by a model fitted on {everyday}")
    guess, guess_why = ((" <i class='ra-warn'>(a guess)</i>",
                         "; contact is uncertain: the shape may be a wrong background&#39;s or a "
                         "lighting change&#39;s, not a press&#39;s, so this is a guess")
                        if uncertain else ("", ""))
    return (f" · <span id='geometry-firmness' title='firmness read from the height map&#39;s "
            f"profile and the change&#39;s texture {by}, {said} sure; a reading beside the "
            f"description, not its input{guess_why}'>shape <b>{escape(firmness['reads'])}</b> "
            f"{said}{guess}</span>")


def structure_line(structure: dict | None, moved: bool | str = False) -> str:
    """The structured-contact reading against the background: its score against the
    threshold of the floors that read it (the family's, or those set for a sensor unlike
    every rendered unit), and what it decides (`moved`: the background's marker dots are not
    where the frame's are, or "lattice": the frame shows a marker grid the background lacks,
    so a change over the floors is not read as contact; nor is one that the block's
    `lighting_field` says a smooth lighting field alone explains)."""
    if not structure:
        return ""
    score = structure.get("score")
    shown = "n/a" if score is None else f"{score:.2f}"
    field = structure.get("lighting_field") or {}
    band = structure.get("band") or {}
    mark = ("? the frame&#39;s marker grid is not in the background: contact uncertain"
            if moved == "lattice" else
            "? the background&#39;s marker dots are not this frame&#39;s: contact uncertain"
            if moved else
            f"? a smooth lighting field alone explains it ({field.get('score')} with the field "
            "removed): contact uncertain" if structure.get("contact") and field.get("explains")
            else f"? barely above a blank&#39;s (within {band.get('top')}): contact uncertain"
            if structure.get("contact") and band.get("inside")
            else "✓ contact" if structure.get("contact") else
            "below: the trust line's contact check decides")
    unlike = structure.get("floors") == "unfamiliar sensor"
    whose = ("the blank floor set for sensors unlike every rendered unit" if unlike else
             "the family&#39;s blank floor, raised by the pair&#39;s own noise where it is "
             "noisier than the blank pairs that floor was set on")
    return (f"<div title='structured change against the background (edges and texture, the "
            f"drift removed), in multiples of {whose}; above the "
            f"threshold is contact'>structured change <b>{shown}</b> × "
            f"{'unfamiliar-sensor floor' if unlike else 'floor'} "
            f"(contact &gt; {structure['threshold']:.2f}) {mark}</div>")


TRUST_WORDS = ("no contact detected", "contact uncertain", "unlike the", "looks like none")


def is_trust_warning(warning: str) -> bool:
    """Whether a warning belongs to the trust block (shown there, not in the status)."""
    return any(t in warning for t in TRUST_WORDS) or warning.startswith("no trust calibration")


def trust_lines(result: dict) -> list[str]:
    """The trust block of a result, shown above the descriptions: one line of scores, then
    its warnings (an uncalibrated pipeline says that nothing is checked)."""
    trust = result.get("trust")
    warned = [w for w in result.get("warnings", []) if is_trust_warning(w)]
    if not trust:
        return [f"<span class='ra-warn'>⚠ {escape(w)}</span>" for w in warned]
    cells = []
    for mode in ("visual", "tactile"):
        t = trust.get(mode)
        if not t:
            continue
        mark = "⚠ unfamiliar" if t["novel"] else "✓ familiar"
        cells.append(f"{mode} novelty {t['novelty']:.2f} (flag > {t['threshold']:.2f}) {mark}")
        if "contact" in t:
            state = t.get("state") or ("no contact" if t["no_contact"] else "contact")
            mark = {"no contact": "✖ no contact", "uncertain": "? contact uncertain"}.get(
                state, "✓ contact")
            against = ", vs background" if t.get("background") else (
                ", read blind to colour" if t.get("contact_model") == "colour-blind" else "")
            score = "n/a" if t["contact"] is None else f"{t['contact']:.2f}"
            noise = t.get("within_noise")
            alone = t.get("alone")  # the second opinion of a frame uncertain vs background
            second = "" if not alone else f"; read alone: {escape(alone['state'])}"
            cells.append(f"change vs background {noise['change']:.3f} (within noise < "
                         f"{noise['floor']:.3f}) {mark}" if noise else
                         f"contact {score} (flag < {t['contact_threshold']:.2f}"
                         f"{against}) {mark}{second}")
            sensor = t.get("sensor")
            if sensor:  # an unfamiliar one is said whether or not a background is given
                cells.append(("⚠ unfamiliar sensor, " if t.get("unfamiliar_sensor") else "")
                             + f"sensor read as {escape(sensor['family'])} "
                             f"({escape(sensor['source'])})")
    line = "**Trust:** " + " · ".join(cells)
    # its warnings on the same line, marked but not shouting: the answer stays in view
    return [line + "".join(f"<br><span class='ra-warn'>⚠ {escape(w)}</span>" for w in warned)]


def status_md(title: str, warnings: list[str], box: list[int] | None = None,
              result: dict | None = None) -> str:
    """The status line after a query: what was queried, with which box (the one used) and
    which model (and for the cascade, why that one), then the warnings that the trust block
    does not show already (each warning is shown once)."""
    found = (result or {}).get("neighbours", {})
    image_only = not any(found.get(m) for m in QUERY_MODES.needing_touch())
    what = "**Image-only query** (no tactile image)" if result and image_only else "**Queried:**"
    lines = [f"{what} {title}" + (f" · contact box {box}" if box else "")
             + model_note(result or {})]
    notes = [w for w in warnings if not is_trust_warning(w)]
    if notes:  # folded: one line (the first words of each), the whole text on a click
        head = "; ".join(notes)
        lines.append(f"<details class='ra-notes'><summary>⚠ {len(notes)} "
                     f"note{'s' if len(notes) > 1 else ''}: {escape(head)}</summary>"
                     + "".join(f"<div>⚠ {escape(w)}</div>" for w in notes) + "</details>")
    return "\n\n".join(lines)


def model_note(result: dict) -> str:
    """The status line's model: "· model `default-s`", or for the cascade "· answered by
    `default-tiny` (cascade: margin 0.080 ≥ 0.046)"; "" when the result names none."""
    c = result.get("cascade")
    if not c:
        return f" · model `{result['encoder']}`" if result.get("encoder") else ""
    conf, th = c["confidence"], c["thresholds"]
    steps = [f"{conf[s]:.3f} {'≥' if th[s] is not None and conf[s] >= th[s] else '<'} "
             f"{'∞' if th[s] is None else format(th[s], '.3f')}"
             for s in range(min(len(conf), len(th)))]
    why = f"{c['measure']} " + ", then ".join(steps) if steps else "no joint query"
    return (f" · answered by `{c['answered_by']}` (cascade"
            + (", escalated" if c["escalated"] else "") + f": {why})")


def model_state_md(name: str, state: str, seconds: float | None,
                   default_load_s: float | None) -> str:
    """What a chosen model is doing: "" when ready, else that it is being prepared (or will
    be, by its first query) and how long the default model took, as an estimate."""
    if state == "ready":
        return ""
    took = (f"; the default model took {default_load_s:.0f} s to prepare"
            if default_load_s else "")
    if state == "preparing":
        return (f"Model `{name}` is being prepared in the background ({seconds or 0:.0f} s so "
                f"far{took}): a query waits for it.")
    # a pretrained language model's generators search their encoder set's corpus, embedded
    embeds = "" if split_model_name(name)[1] else " and, the first time, embeds the corpus with it"
    return (f"Model `{name}` is not prepared yet: its first query prepares it (loads it"
            f"{embeds}{took}) and waits.")


def error_md(message: str) -> str:
    return f"**✖ Cannot run this query:** {message}"


def timings_md(timings: dict[str, float], render_ms: float | None = None,
               from_run_ms: float | None = None) -> str:
    """One discreet line: per-stage milliseconds, the total, the app's own rendering and the
    time from Run to the answer (which includes any wait for a model being prepared)."""
    stages = [f"{k.replace('_', ' ')} {v:.0f} ms" for k, v in timings.items()
              if k not in ("total", "batch_size")]
    line = " · ".join(stages) + f" · **total {timings.get('total', 0):.0f} ms**"
    if timings.get("batch_size", 1) > 1:
        line += f" (answered in a batch of {timings['batch_size']} concurrent queries)"
    if render_ms is not None:
        line += f" (+ app rendering {render_ms:.0f} ms)"
    if from_run_ms is not None:
        line += f" · **from Run to answer {from_run_ms / 1000:.1f} s**"
        waited = from_run_ms - timings.get("total", 0) - timings.get("decode", 0)
        if waited > 1000:  # the model was being prepared (loaded, its corpus embedded)
            line += f", of which {waited / 1000:.1f} s waiting for the model to be prepared"
    return f"Timings: {line}"


# ---------------------------------------------------------------------- failure cases

#: What computing the app's default failure table took, measured (4 conditions × the 402
#: test pairs, the default-s pipeline on the 10k corpus, a 2-core CPU).
FAILURE_WAIT = "48–57 s"

# (column header, row key) of the failure-case table; the first two identify the case
_CASE_HEAD = (("condition", "condition"), ("#", "index"), ("subset", "subset"),
              ("material", "material"), ("ground-truth label", "label"),
              ("RA-Touch", "ra_touch"), ("RA score", "ra_score"), ("baseline", "baseline"),
              ("base score", "baseline_score"), ("Δ RA−base", "ra_delta"))
# widths in px: each column's longest word fits (the table scrolls sideways where the page
# is narrower than their sum)
_CASE_WIDTHS = (150, 52, 104, 136, 180, 180, 76, 180, 76, 84)
_PRECISION_WIDTH = 84


def precision_columns() -> tuple[tuple[str, str], ...]:
    """(header, row key) of each query mode's material precision@K, from the registry."""
    return tuple((f"P@K {m}", f"precision_{m}") for m in MODES)


def case_columns() -> tuple[tuple[str, str], ...]:
    """(column header, row key) of the failure-case table; the first two identify the case,
    then one precision column per query mode (`QUERY_MODES`)."""
    return _CASE_HEAD + precision_columns()


def case_widths() -> list[str | int]:
    """The case table's column widths, one per `case_columns()`."""
    widths: list[str | int] = [f"{w}px" for w in (*_CASE_WIDTHS,
                                                  *[_PRECISION_WIDTH] * len(MODES))]
    return widths


def summary_columns() -> tuple[tuple[str, str], ...]:
    return ((("condition", "condition"), ("subset", "subset"), ("n", "n"),
             ("base score [95% CI]", "baseline_score"), ("RA score [95% CI]", "ra_score"),
             ("Δ RA−base [95% CI]", "ra_delta"), ("F1 base / RA", "f1"),
             ("adjectives base / RA", "length"))
            + precision_columns() + (("joint loses", "joint_loses"),))


def _frame(rows: Sequence[dict], columns):
    import pandas as pd

    # a mode registered after a table was computed has no column in it: shown empty
    return pd.DataFrame([[_cell(key, r.get(key)) for _, key in columns] for r in rows],
                        columns=[name for name, _ in columns])


def _cell(key: str, value):
    # names with underscores ("brushed_aluminum") break where a cell wraps: shown as words
    return value.replace("_", " ") if key == "material" and isinstance(value, str) else value


def cases_frame(rows: Sequence[dict]):
    """The failure-case rows as the table shows them (a pandas DataFrame)."""
    return _frame(rows, case_columns())


def summary_frame(summary: Sequence[dict]):
    """`ratouch.eval.failures.summarise` as a table; 'joint loses' as a percentage."""
    def ci(value: float, bounds) -> str:
        return f"{value:.2f} [{bounds[0]:.2f}, {bounds[1]:.2f}]" if bounds else f"{value:.2f}"

    rows = [{**s, "joint_loses": f"{s['joint_loses']:.0%}",
             "baseline_score": ci(s["baseline_score"], s.get("baseline_ci")),
             "ra_score": ci(s["ra_score"], s.get("ra_ci")),
             "ra_delta": ci(s["ra_delta"], s.get("ra_delta_ci")),
             "f1": f"{s.get('baseline_f1', 0):.2f} / {s.get('ra_f1', 0):.2f}",
             "length": f"{s.get('baseline_mean_length', 0):.1f} / "
                       f"{s.get('ra_mean_length', 0):.1f}"} for s in summary]
    return _frame(rows, summary_columns())


def failures_status_md(meta: dict, shown: int, matching: int, view: str) -> str:
    k = meta.get("k", "?")
    n_cond = len(meta.get("conditions", {}))
    return (f"{meta.get('n_rows', '?')} cases ({n_cond} conditions × the test split) · "
            f"computed {meta.get('computed_at', '?')} in {meta.get('seconds', '?')} s · "
            f"P@K = material precision@{k} of each query mode's neighbours · judge = offline "
            f"judge, 1–10. Showing {shown} of {matching} cases ({view}); **click a row to open "
            f"it in Explore**.")


def conditions_md(conditions: Mapping[str, Mapping]) -> str:
    """One line per stress condition: its name and knobs."""
    def knobs(d):
        return ", ".join(f"{k}={v}" for k, v in d.items()) or "no stress (the natural split)"

    return "\n".join(f"- **{name}**: {knobs(d)}" for name, d in conditions.items())


# ---------------------------------------------------------------------- benchmarks

REPORT_NAME = "results.md"
FIGURES_DIR = "figures"
FIRST_FIGURES = ("tradeoff",)  # shown first when present
NOT_GENERATED = ("**Not generated yet.** The paper-experiment report (`docs/{report}`) and its "
                 "figures (`docs/figures/*.json`) are written by the evaluation commands: run "
                 "`ratouch eval all` for the report, `ratouch bench tradeoff` for the "
                 "speed-vs-accuracy chart, then press *Reload*. Nothing is made up here.")
_IMAGE_LINK = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
_LINK = re.compile(r"(?<!!)\[([^\]]*)\]\(([^)\s]+)\)")


def list_figures(docs: Path) -> list[Path]:
    """The plotly figure files (`fig.to_json()` output) in `docs/figures/`, the
    speed-vs-accuracy chart first, then by name."""
    folder = Path(docs) / FIGURES_DIR
    if not folder.is_dir():
        return []
    # `<name>.data.json` beside a figure holds its raw numbers, not a figure
    files = sorted(p for p in folder.glob("*.json")
                   if p.is_file() and not p.name.endswith(".data.json"))
    rank = {name: i for i, name in enumerate(FIRST_FIGURES)}
    return sorted(files, key=lambda p: (rank.get(p.stem, len(rank)), p.name))


def figure_provenance(made: tuple[str, str | None], weights: tuple[str, str] | None,
                      older: bool | None = None) -> str:
    """Which weights and date a figure comes from: the time (and commit) it was made, against
    the shipped weights' (a figure made before them was not regenerated since). `older`:
    whether its commit lacks the weights' (`ratouch.eval.report.made_before`), where known;
    else the days are compared."""
    date, commit = made
    when = f"made {date}" + (f" (commit {commit})" if commit else "")
    if weights is None:
        return when
    if older is None:
        older = date[:10] < weights[0]
    if older:
        return (f"{when}, on weights older than the shipped ones of {weights[0]} "
                f"({weights[1]}): not regenerated since")
    return f"{when}, on the shipped weights of {weights[0]} ({weights[1]})"


def figure_title(path: Path) -> str:
    return Path(path).stem.replace("_", " ").replace("-", " ")


DOCS_ROUTE = "ratouch-docs"  # the app's route for the docs folder (`app.app.launch`)


def docs_url(docs: Path, target: str) -> str | None:
    """The page's URL of a file of the docs folder named relative to it: the docs route
    and the file's path inside the folder (never the server's own path); None when the
    file is not there or lies outside the folder."""
    local = (Path(docs) / target).resolve()
    root = Path(docs).resolve()
    if not (local.is_file() and local.is_relative_to(root)):
        return None
    return f"{DOCS_ROUTE}/{quote(local.relative_to(root).as_posix())}"


def report_md(docs: Path, figures: Sequence[Path] = ()) -> str:
    """`docs/results.md` ready for gr.Markdown: an image whose figure is shown interactively
    becomes a pointer to it; other local images and links to local files (the figures'
    HTML pages) go through the app's file route. The not-generated message when there is
    no report."""
    docs = Path(docs)
    path = docs / REPORT_NAME
    if not path.is_file():
        return NOT_GENERATED.format(report=REPORT_NAME)
    text = path.read_text(encoding="utf-8", errors="replace")
    interactive = {p.stem for p in figures}

    def image(m: re.Match) -> str:
        alt, target = m.group(1), m.group(2)
        if re.match(r"^[a-z]+://", target):
            return m.group(0)
        stem = Path(target).stem
        if stem in interactive:
            return (f"*[figure “{alt or stem}”: the interactive chart "
                    f"**{figure_title(Path(stem))}** above]*")
        url = docs_url(docs, target)
        if url:
            return f"![{alt}]({url})"
        return f"*[figure “{alt or stem}” ({target}) not found]*"

    def link(m: re.Match) -> str:
        text, target = m.group(1), m.group(2)
        if re.match(r"^([a-z]+:|#|/)", target):
            return m.group(0)
        url = docs_url(docs, target)
        if url:
            return f"[{text}]({url})"
        return text

    return _LINK.sub(link, _IMAGE_LINK.sub(image, text))


# ------------------------------------------------------------------------- taking retrieval apart

def neighbour_choices(result: dict | None) -> list[tuple[str, int]]:
    """(label, id) of each neighbour RA-Touch read (`read_mode`), with the integrator's
    attention on its image and its text: the choices of the "take retrieval apart"
    checkboxes."""
    if not result:
        return []
    att = result.get("attention") or {}
    out = []
    for j, n in enumerate(result.get("neighbours", {}).get(read_mode(result), [])):
        a_img, a_txt = ((att.get("image") or [None] * (j + 1))[j],
                        (att.get("text") or [None] * (j + 1))[j])
        share = (f" · attention image {a_img:.2f} / text {a_txt:.2f}"
                 if a_img is not None and a_txt is not None else "")
        out.append((f"#{n['id']} {n['class_name']}: {n['caption']} ({n['score']:.3f}){share}",
                    int(n["id"])))
    return out


def regenerated_md(original: dict, regenerated: dict, kept: Sequence[int],
                   score: float | None, original_score: float | None) -> str:
    """RA-Touch's description read with the kept neighbours, beside the original."""
    ids = [n["id"] for n in original["neighbours"][read_mode(original)]]
    dropped = [i for i in ids if i not in set(kept)]
    added = [i for i in kept if i not in set(ids)]
    what = (f"{len(kept)} of the {len(ids)} neighbours"
            + (f" (dropped {', '.join(f'#{i}' for i in dropped)})" if dropped else "")
            + (f" (added {', '.join(f'#{i}' for i in added)})" if added else ""))
    if not kept:
        what = "no neighbours (the integrator adds nothing: the prompt is p)"

    def judged(text: str, s: float | None) -> str:
        return f"{text or '_(empty)_'}" + (f" · judge **{s:.1f}**/10" if s else "")

    ms = regenerated.get("timings_ms", {}).get("total")
    return "\n\n".join([
        f"**RA-Touch read with {what}:** "
        + judged(regenerated["description"]["ra_touch"], score),
        f"**RA-Touch as answered (all {len(ids)}):** "
        + judged(original["description"]["ra_touch"], original_score),
        "<span class='ra-muted'>the same model and prompt; only the neighbours it reads "
        "changed — the interactive form of the neighbour-shuffle control"
        + (f" · {ms:.0f} ms" if ms is not None else "") + "</span>"])

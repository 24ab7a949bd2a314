"""Turning one `RATouchPipeline.query` result into what the app shows: gallery items with
shared-neighbour marks, neighbour tables, the descriptions, warnings and timings.
Formatting only: every number comes from the result."""

from __future__ import annotations

from html import escape
from typing import Callable

import numpy as np

MODES = ("image", "tactile", "joint")
MODE_TITLE = {"image": "Image query", "tactile": "Tactile query",
              "joint": "Joint query (Tactile-Guided Retriever)"}
MODE_COLOUR = {"image": "#1f77b4", "tactile": "#ff7f0e", "joint": "#2ca02c"}
MODE_LETTER = {"image": "I", "tactile": "T", "joint": "J"}


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


def gallery_items(result: dict, mode: str, thumbnail: Callable[[int], np.ndarray]
                  ) -> list[tuple[np.ndarray, str]]:
    """(thumbnail, caption) per neighbour of one mode, best first. The caption leads with
    what fits under a thumbnail (rank, similarity, ◆ per other mode sharing it, class);
    the gallery's preview shows the rest (tactile caption, which modes share it)."""
    shared = shared_modes(result["neighbours"])
    items = []
    for rank, n in enumerate(result["neighbours"].get(mode, []), 1):
        modes = shared[n["id"]]
        stars = " " + "◆" * (len(modes) - 1) if len(modes) > 1 else ""
        tail = f" · shared by {'·'.join(MODE_LETTER[m] for m in modes)}" if stars else ""
        items.append((thumbnail(n["id"]), f"{rank}. {n['score']:.3f}{stars} · "
                                          f"{n['class_name']} · {n['caption']}{tail}"))
    return items


def neighbour_table(result: dict, mode: str) -> str:
    """An HTML table of one mode's neighbours: rank, class, tactile caption, similarity,
    and the other modes that retrieved the same entry."""
    rows = result["neighbours"].get(mode)
    if not rows:
        return "<p class='ra-muted'>not available for this query</p>"
    shared = shared_modes(result["neighbours"])
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


def description_md(result: dict, label: str | None) -> str:
    """The generated descriptions (with and without retrieval) and the ground truth."""
    d = result["description"]
    ra = d.get("ra_touch") or "_not available: needs a tactile image_"
    base = d.get("baseline") or "_not available: needs a tactile image_"
    parts = ["### Tactile description",
             f"**RA-Touch (with retrieval):** {ra}",
             f"**Baseline (no retrieval):** {base}"]
    if label:
        parts.append(f"**Ground-truth label:** {label}")
    return "\n\n".join(parts)


def status_md(title: str, warnings: list[str], box: list[int] | None = None) -> str:
    """The status line after a query: what was queried, with which box, and any warnings."""
    lines = [f"**Queried:** {title}" + (f" · contact box {box}" if box else "")]
    lines += [f"- ⚠️ {w}" for w in warnings]
    return "\n".join(lines)


def error_md(message: str) -> str:
    return f"**⛔ Cannot run this query:** {message}"


def timings_md(timings: dict[str, float], render_ms: float | None = None) -> str:
    """One discreet line: per-stage milliseconds, the total, and the app's own rendering."""
    stages = [f"{k.replace('_', ' ')} {v:.0f} ms" for k, v in timings.items() if k != "total"]
    line = " · ".join(stages) + f" · **total {timings.get('total', 0):.0f} ms**"
    if render_ms is not None:
        line += f" (+ app rendering {render_ms:.0f} ms)"
    return f"Timings: {line}"

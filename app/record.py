"""A session's runs, kept: what each answered query was asked (the inputs' checksums, model, K,
box, the commit), its export as JSON and as a CSV of neighbours, the link that reproduces a
query on the world's examples, and two runs side by side.

Pure data and formatting: no gradio here. The Explore tab keeps a session's records in a
`gr.State` (`HISTORY_SIZE` at most) and shows them.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from html import escape
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import numpy as np

from ratouch.search.modes import QUERY_MODES
from ratouch.serve.trace import trace_retrieval

FORMAT = "ratouch-app-run-1"
HISTORY_SIZE = 20  # runs a session keeps (the oldest goes first)
CSV_COLUMNS = ("run", "model", "commit", "k", "visual_sha256", "tactile_sha256",
               "background_sha256", "mode", "rank", "corpus_id", "similarity", "class",
               "caption", "source")


def checksum(source: Any) -> str | None:
    """sha256 of an input: an uploaded file's bytes, or an example's pixel array (its bytes,
    C order, after its shape and dtype); None for no input."""
    if source is None:
        return None
    h = hashlib.sha256()
    if isinstance(source, np.ndarray):
        a = np.ascontiguousarray(source)
        h.update(f"{a.shape}:{a.dtype}:".encode())
        h.update(a.tobytes())
        return h.hexdigest()
    with open(source, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _input(source: Any) -> dict | None:
    if source is None:
        return None
    kind = "array" if isinstance(source, np.ndarray) else "file"
    name = None if kind == "array" else Path(source).name  # its name, never its server path
    return {"sha256": checksum(source), "kind": kind, "name": name}


@dataclass(frozen=True)
class RunRecord:
    """One answered query of a session.

    Attributes:
        number: the run's number in the session (1, 2, ...).
        made_at: when it was answered (UTC, ISO 8601).
        title: what was queried (the status line's words).
        settings: k and box (as typed; None: TVL's centred crop).
        inputs: per role ("visual", "tactile", "background") its sha256, kind and file name.
        commit: the code's git commit (`ratouch.eval.report.git_commit`).
        example: the world's test index and stress condition it came from, if any (what a
            link can reproduce).
        result: the answer's JSON (`QueryResult.to_dict()`; the model that answered is its
            "encoder").
        model: the model asked for ("" where the page offers no choice).
    """

    number: int
    made_at: str
    title: str
    settings: Mapping[str, Any]
    inputs: Mapping[str, dict | None]
    commit: str
    result: Mapping[str, Any]
    example: Mapping[str, Any] | None = None
    model: str = ""

    @property
    def label(self) -> str:
        """The run as a menu shows it."""
        return (f"run {self.number} · {self.made_at[11:19]} · {self.title[:60]} · "
                f"{self.result.get('encoder') or self.model} · K={self.settings.get('k')}")

    def link(self) -> str | None:
        """The query string that reproduces this run on the page (`?example=N&model=…&k=…`),
        or None for an uploaded input (export its JSON instead)."""
        if not self.example:
            return None
        params: dict[str, Any] = {"example": self.example["index"]}
        if self.example.get("condition"):
            params["condition"] = self.example["condition"]
        if self.model:
            params["model"] = self.model
        params["k"] = self.settings.get("k")
        box = self.settings.get("box")
        if box is not None and list(box) != list(self.example.get("box") or []):
            params["box"] = ",".join(str(int(v)) for v in box)
        return "?" + urlencode(params)

    def to_dict(self) -> dict:
        """The export: the run's inputs (checksums), settings, model, commit and answer."""
        return {"format": FORMAT, "run": self.number, "made_at": self.made_at,
                "title": self.title, "model": self.model or self.result.get("encoder"),
                "answered_by": self.result.get("encoder"), "commit": self.commit,
                "settings": dict(self.settings), "inputs": dict(self.inputs),
                "example": dict(self.example) if self.example else None, "link": self.link(),
                "result": dict(self.result)}

    def neighbours_csv(self) -> str:
        """Every mode's neighbours, one row each, with the run's model, commit and inputs."""
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(CSV_COLUMNS)
        sha = {r: (self.inputs.get(r) or {}).get("sha256") or ""
               for r in ("visual", "tactile", "background")}
        head = [self.number, self.result.get("encoder") or self.model, self.commit,
                self.settings.get("k"), sha["visual"], sha["tactile"], sha["background"]]
        for mode, rows in self.result.get("neighbours", {}).items():
            for rank, n in enumerate(rows, 1):
                w.writerow([*head, mode, rank, n["id"], n["score"], n.get("class_name", ""),
                            n.get("caption", ""), n.get("source", "")])
        return out.getvalue()


def make_record(number: int, title: str, sources: Mapping[str, Any], settings: Mapping,
                result: Mapping, commit: str, example: Mapping | None = None,
                model: str = "") -> RunRecord:
    """A run's record: the inputs' checksums are taken now (`sources`: role -> a file path,
    an array or None)."""
    return RunRecord(number, time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), title,
                     dict(settings), {role: _input(s) for role, s in sources.items()},
                     commit, dict(result), dict(example) if example else None, model)


def remember(history: Sequence[RunRecord] | None, record: RunRecord) -> list[RunRecord]:
    """The session's history with `record` added (the oldest dropped past HISTORY_SIZE)."""
    return [*(history or []), record][-HISTORY_SIZE:]


def write_exports(record: RunRecord, folder: Path) -> tuple[Path, Path]:
    """The run's JSON and neighbours CSV written into `folder` (a fresh temporary one)."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"ratouch-run{record.number}-{record.made_at[:19].replace(':', '')}"
    js, cs = folder / f"{stem}.json", folder / f"{stem}-neighbours.csv"
    js.write_text(json.dumps(record.to_dict(), indent=1, default=_plain) + "\n",
                  encoding="utf-8")
    cs.write_text(record.neighbours_csv(), encoding="utf-8")
    return js, cs


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


# ---------------------------------------------------------------------- side by side

def _trust(result: Mapping) -> str:
    trust = result.get("trust") or {}
    cells = []
    for mode in ("visual", "tactile"):
        t = trust.get(mode)
        if t:
            cells.append(f"{mode} novelty {t['novelty']:.2f} "
                         f"{'unfamiliar' if t['novel'] else 'familiar'}")
            if "contact" in t:
                cells.append(f"contact {t.get('state') or ('no contact' if t['no_contact'] else 'contact')}")
            geo = t.get("geometry")
            if geo:  # the press as a height map (read against a background)
                cells.append(f"depth {geo['depth']:.3g} {geo['units']}, spread "
                             f"{geo['spread']:.0%}, relief {geo['relief']:.3g}")
    return "; ".join(cells) or "not checked"


def _retrieval(result: Mapping) -> str:
    trace = trace_retrieval(result)
    if trace is None:
        return "no RA-Touch description"
    if trace.same_words:
        return "the baseline's words (retrieval changed nothing)"
    parts = ([f"added {', '.join(trace.added)}"] if trace.added else []) + (
        [f"dropped {', '.join(trace.dropped)}"] if trace.dropped else [])
    return "; ".join(parts) or "the baseline's words in another order"


def _neighbours(result: Mapping, mode: str) -> str:
    rows = result.get("neighbours", {}).get(mode)
    if not rows:
        return "<span class='ra-muted'>not available</span>"
    return "<br>".join(f"{r}. {escape(n['caption'])} <span class='ra-muted'>"
                       f"({escape(n.get('class_name', ''))}, {n['score']:.2f})</span>"
                       for r, n in enumerate(rows, 1))


def compare_html(a: RunRecord | None, b: RunRecord | None) -> str:
    """Two runs side by side: what was asked, the descriptions, trust, what retrieval did
    and each query mode's neighbours (rows that differ marked)."""
    if a is None or b is None:
        return ("<p class='ra-muted'>Run two queries (or more), then pick any two here to "
                "see them side by side.</p>")

    def settings(r: RunRecord) -> str:
        s = r.settings
        return (f"model {escape(str(r.result.get('encoder') or r.model))} · K={s.get('k')} · "
                f"box {list(s['box']) if s.get('box') is not None else 'TVL centred crop'}")

    def inputs(r: RunRecord) -> str:
        return " · ".join(f"{role} {(v or {}).get('sha256', '')[:10] or '—'}"
                          for role, v in r.inputs.items())

    rows: list[tuple[str, Callable[[RunRecord], str]]] = [
        ("run", lambda r: escape(r.label)), ("settings", settings),
        ("inputs (sha256)", inputs),
        ("RA-Touch", lambda r: escape(r.result["description"].get("ra_touch") or "—")),
        ("baseline", lambda r: escape(r.result["description"].get("baseline") or "—")),
        ("trust", lambda r: escape(_trust(r.result))),
        ("what retrieval did", lambda r: escape(_retrieval(r.result)))]
    def neighbours(mode: str) -> Callable[[RunRecord], str]:
        return lambda r: _neighbours(r.result, mode)

    rows += [(f"{QUERY_MODES[m].title} neighbours", neighbours(m)) for m in QUERY_MODES]
    out = ["<table class='ra-table ra-compare'><tr><th></th>"
           f"<th>run {a.number}</th><th>run {b.number}</th></tr>"]
    for name, cell in rows:
        x, y = cell(a), cell(b)
        differs = " class='ra-differs'" if x != y and name != "run" else ""
        out.append(f"<tr{differs}><th>{escape(name)}</th><td>{x}</td><td>{y}</td></tr>")
    out.append("</table>")
    return "".join(out)

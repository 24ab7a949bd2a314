"""Writing reports: static PNGs of plotly figures, the plotly script beside HTML figures, and
the commit a report was made at. Shared by the experiment, stress and trade-off reports."""

from __future__ import annotations

import json
import logging
import subprocess
import time
from pathlib import Path

from ratouch.files import write_atomic
from ratouch.paths import ASSETS, REPO

log = logging.getLogger(__name__)


def png_bytes(fig) -> tuple[bytes | None, str]:
    """A figure as PNG through kaleido and the local Chromium: (bytes, "") or, where that does
    not work offline, (None, why)."""
    try:
        return fig.to_image(format="png", scale=1), ""
    except Exception as e:  # noqa: BLE001 - any exporter failure means "no PNG", said by callers
        return None, f"{type(e).__name__}: {e}"


def save_png(fig, path: Path) -> Path | None:
    """Write the figure's PNG to `path`; None (and a logged reason) where no exporter works."""
    data, why = png_bytes(fig)
    if data is None:
        log.warning("no PNG for %s (%s)", path.name, why)
        return None
    return write_atomic(path, data)


def write_figure_html(fig, path: Path) -> Path:
    """The figure as an HTML page (written atomically) referencing plotly.min.js beside it."""
    write_atomic(path, fig.to_html(include_plotlyjs="directory", full_html=True))
    write_plotly_js(path.parent)
    return path


def utc_stamp() -> str:
    """Now, as a report says when it was made ("2026-12-03 08:04 UTC")."""
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, cwd=REPO, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10,
                               cwd=REPO).stdout.strip()
        return out.stdout.strip() + ("+changes" if dirty else "") or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def last_commit(*paths: Path) -> tuple[str, str] | None:
    """(date YYYY-MM-DD, short commit) of the last commit that touched any of `paths`; None
    when none is tracked (or git is not there). A figure says with it when it was made."""
    try:
        out = subprocess.run(["git", "log", "-1", "--format=%cs %h", "--", *map(str, paths)],
                             capture_output=True, text=True, cwd=REPO, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    parts = out.split()
    return (parts[0], parts[1]) if len(parts) == 2 else None


def measured_stamp() -> dict[str, str]:
    """What a stored check records of when and on what code it was measured: {"measured": today
    (UTC, YYYY-MM-DD), "commit": `git_commit()`}, as `recorded_made` reads it back. Taken
    before the check writes anything, so that its own output does not mark the commit
    "+changes"."""
    return {"measured": time.strftime("%Y-%m-%d", time.gmtime()), "commit": git_commit()}


def recorded_made(path: Path) -> tuple[str, str | None] | None:
    """(UTC time, commit) that a figure's maker recorded: in the data beside it
    (`<stem>.data.json`'s "made", as `ratouch bench tradeoff` writes), or, for a stored check
    that is itself JSON, its own "measured" (and "commit", where it has one; as `ratouch eval
    frames --json` writes); else None."""
    path = Path(path)
    data = path.with_name(f"{path.name.split('.')[0]}.data.json")
    if data.is_file():  # a figure and its data
        try:
            made = json.loads(data.read_text("utf-8"))["made"]
            return str(made["utc"]), str(made["commit"])
        except (OSError, ValueError, KeyError, TypeError):
            return None
    if path.suffix != ".json":
        return None
    try:
        own = json.loads(path.read_text("utf-8"))
        commit = own.get("commit")
        return str(own["measured"]), None if commit is None else str(commit)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def figure_made(path: Path) -> tuple[str, str | None, bool] | None:
    """When a figure of the docs folder was made: (when, commit, measured), where `measured`
    says the time and commit are what its maker recorded (the commit None where it recorded
    only the time), else (False) the last commit that changed it; None when neither is known.
    Never the file's modification time, which is when it was checked out."""
    made = recorded_made(path)
    if made is not None:
        return made[0], made[1], True
    committed = last_commit(Path(path).resolve())
    return (committed[0], committed[1], False) if committed else None


def made_before(commit: str | None, weights: str | None) -> bool | None:
    """Whether the code at `commit` (a figure's) lacks the commit `weights` (the shipped
    weights'), by ancestry: True where `weights` is not among `commit`'s ancestors (nor
    `commit` itself), False where it is; None where either is unknown or git cannot say (a
    commit not in this clone). Exact where dates are not: two commits of one day, or a time
    against a day. A commit recorded with "+changes" is read as the commit it was made on."""
    if not commit or not weights:
        return None
    commit = commit.split("+")[0]
    try:
        r = subprocess.run(["git", "merge-base", "--is-ancestor", weights, commit],
                           capture_output=True, text=True, cwd=REPO, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return {0: False, 1: True}.get(r.returncode)


def weights_commit() -> tuple[str, str] | None:
    """(date, commit) of the shipped weights: the last commit that changed assets/'s
    encoders, retrievers or generators."""
    return last_commit(*(ASSETS / d for d in ("encoders", "retriever", "generator")))


def write_plotly_js(folder: Path) -> None:
    """plotly.min.js beside the HTML figures that reference it (one copy per folder)."""
    from plotly.offline import get_plotlyjs

    js = folder / "plotly.min.js"
    if not js.is_file():
        write_atomic(js, get_plotlyjs())

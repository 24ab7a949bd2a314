"""Running experiments by name and writing what they report: each one's markdown, figure and
data files, and the whole `docs/results.md` with its provenance.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable, Sequence

from ratouch.errors import ConfigError
from ratouch.eval.catalog import EXPERIMENT_HELP
from ratouch.eval.experiments.figures import fig3_corpus_size, fig5_loss_pca, fig6_top_k
from ratouch.eval.experiments.lab import Lab
from ratouch.eval.experiments.tables import (
    table1_main,
    table2_ablation,
    table3_caption_type,
    table4_query_key,
    table5_integration,
    table6_withheld,
)
from ratouch.eval.experiments.variants import ExperimentConfig, Report
from ratouch.eval.report import (
    figure_made,
    git_commit,
    save_png,
    utc_stamp,
    write_figure_html,
)
from ratouch.files import write_atomic, write_json_atomic

log = logging.getLogger(__name__)

EXPERIMENTS: dict[str, Callable[[Lab], Report]] = {
    "table1": table1_main, "table2": table2_ablation, "table3": table3_caption_type,
    "table4": table4_query_key, "table5": table5_integration, "fig3": fig3_corpus_size,
    "fig6": fig6_top_k, "fig5": fig5_loss_pca, "table6": table6_withheld,
}
assert list(EXPERIMENTS) == list(EXPERIMENT_HELP), "ratouch.eval.catalog lists the experiments"


def write_report(rep: Report, folder: str | os.PathLike, png: bool = True) -> dict[str, Path]:
    """``<name>.md``, ``<name>.html`` (self-contained), ``<name>.json`` (plotly figure JSON, for
    the app) and ``<name>.png`` when a static exporter works offline."""

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = {"md": folder / f"{rep.name}.md"}
    write_atomic(out["md"], f"## {rep.title}\n\n{rep.markdown}\n")
    write_json_atomic(folder / f"{rep.name}.data.json", rep.data)
    if rep.figure is not None:
        out["html"] = folder / f"{rep.name}.html"
        write_figure_html(rep.figure, out["html"])
        out["json"] = write_atomic(folder / f"{rep.name}.json", rep.figure.to_json())
        path = save_png(rep.figure, folder / f"{rep.name}.png") if png else None
        if path is not None:
            out["png"] = path
    return out


def run_experiments(names: Sequence[str], cfg: ExperimentConfig, out: str | os.PathLike,
                    lab: Lab | None = None, png: bool = True) -> list[Report]:
    unknown = [n for n in names if n not in EXPERIMENTS]
    if unknown:
        raise ConfigError(f"unknown experiment(s) {unknown}; choose from {list(EXPERIMENTS)}")
    lab = lab or Lab(cfg)
    reports = []
    for n in names:
        t0 = time.perf_counter()
        rep = EXPERIMENTS[n](lab)
        rep.seconds = time.perf_counter() - t0
        write_report(rep, Path(out) / "figures", png)
        reports.append(rep)
        log.info("%s done in %.0f s", n, rep.seconds)
    return reports


def tradeoff_made(out: Path) -> str:
    """When and at which commit the speed-against-accuracy figures in `out`/figures were
    measured (`figure_made`), as the page says it."""
    made = figure_made(out / "figures" / "tradeoff.md")
    if made is None:
        return "date not recorded"
    when, commit, measured = made
    return f"{when}, commit `{commit}`" if measured else f"committed {when} in `{commit}`"


def companion_sections(out: str | os.PathLike) -> str:
    """The speed-against-accuracy and stress reports that live beside the results, when their
    commands (`ratouch bench tradeoff`, `ratouch eval stress --out <out>/stress`) made them."""
    out, parts = Path(out), []
    trade = out / "figures" / "tradeoff.md"
    if trade.is_file():
        parts += [trade.read_text(encoding="utf-8").strip(), "",
                  f"Made by `ratouch bench tradeoff` ({tradeoff_made(out)}).", ""]
        if (out / "figures" / "tradeoff.png").is_file():
            parts += ["![Speed against accuracy](figures/tradeoff.png) "
                      "([interactive](figures/tradeoff.html))", ""]
    stress = out / "stress" / "stress.md"
    if stress.is_file():
        text = stress.read_text(encoding="utf-8")
        start = text.find("## Break points")
        end = text.find("\n## ", start + 1)
        parts += ["## Stability where methods fail (`ratouch eval stress`)", "",
                  "The whole sweep, per knob, with the collapse check: "
                  "[stress/stress.md](stress/stress.md).", ""]
        if start >= 0:
            parts += ["#" + text[start:end if end > 0 else None].strip(), ""]
        for png in ("stress.png", "stress_overlap.png"):
            if (out / "stress" / png).is_file():
                parts += [f"![{png}](stress/{png})", ""]
    return "\n".join(parts)


def results_markdown(reports: Sequence[Report], cfg: ExperimentConfig, seconds: float,
                     header: str = "", out: str | os.PathLike | None = None,
                     counts: dict | None = None, commit: str | None = None) -> str:
    """The whole report: provenance, then every experiment with its figure. `commit`: the
    code's commit as the run began (`git_commit()`, read now when not given): read at the end,
    the run's own figures, written into the tracked docs/, would mark it "+changes"."""
    lines = ["# RA-Touch on the world: the paper's experiments",
             "",
             "Generated by `ratouch eval all` - do not edit by hand.",
             "",
             f"* commit `{commit or git_commit()}`, "
             f"{utc_stamp()}, "
             f"wall time {seconds / 60:.1f} min on this machine"
             + (f" ({counts['trained']} generator variants trained in this run, "
                f"{counts['from_cache']} read from the cache of earlier runs: the wall time "
                "covers only what was trained here)" if counts else ""),
             f"* settings: `{json.dumps(asdict(cfg))}`",
             "* test split: the world's 402 pairs (46 structured = SSVTP-like, 356 wild = "
             "HCT-like); scores: the offline judge (1-10, see README 'Judges'); gains are paired "
             "differences to the no-retrieval baseline with two-sided paired t-tests",
             ""]
    if header:
        lines += [header, ""]
    for rep in reports:
        lines += [f"## {rep.title}", "", rep.markdown, ""]
        if rep.figure is not None:
            png = f"figures/{rep.name}.png"
            lines += [f"![{rep.title}]({png}) ([interactive](figures/{rep.name}.html))", ""]
    if out is not None:
        lines.append(companion_sections(out))
    return "\n".join(lines) + "\n"

"""The Benchmarks tab: the story first (the paper's premise, tested, and its verdict; the
real-frame checks), then the report's figures and text, each dated against the shipped
weights.

Everything shown is read from files the evaluation commands wrote into the docs folder
(`docs/premise-result*.json`, `docs/frames-real-*.json`, `docs/results.md`,
`docs/figures/*.json`); nothing is computed here.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from types import SimpleNamespace

import gradio as gr
import plotly.io as pio

from app import view
from app.page import Outputs, Page
from ratouch.eval import report
from ratouch.eval.frames import summarise
from ratouch.eval.report import weights_commit
from ratouch.serve.pipeline import DEFAULT_RETRIEVAL

MAX_FIGURES = 12  # plot slots of the tab
#: The premise's results, newest last: (file, what it was run on).
PREMISES = (("premise-result.json", "before the visual prior"),
            ("premise-result-prior.json", "with the visual prior (the shipped weights' recipe)"),
            ("premise-result-3runs.json", "3 draws, before the seeded retrain"),
            ("premise-result-seeded-3runs.json", "the shipped weights, 3 draws (seeded "
             "trainings; the gated system beside it in docs/premise.md)"))
#: The text arm's premise runs: (file, the generator it ran on).
TEXT_ARMS = (("premise-result-text-seeded.json", "small decoder (shipped)"),
             ("premise-result-text-smollm2.json", "SmolLM2-135M"))
FRAMES_GLOB = "frames-real-*.json"
#: The fallback system's measures (`scripts/why_withhold.py --system fallback`).
FALLBACK = "premise-result-fallback.json"


def layout() -> SimpleNamespace:
    """Place the tab's components (inside a `gr.Tab`); returns them by name."""
    ui = SimpleNamespace()
    ui.story = gr.Markdown(elem_id="bench-story")
    with gr.Row():
        ui.note = gr.Markdown(elem_id="bench-note")
        ui.reload = gr.Button("Reload", size="sm", min_width=80, scale=0)
    # one figure per row: the charts' legends and axis labels need the full width
    ui.figures = [gr.Plot(visible=False, elem_id=f"bench-fig-{i}") for i in range(MAX_FIGURES)]
    ui.report = gr.Markdown(elem_id="bench-report")
    return ui


def wire(page: Page, ui: SimpleNamespace, tab: gr.Tab) -> None:
    shown = Outputs({"story": ui.story, "report": ui.report, "note": ui.note,
                     **{f"figure_{i}": f for i, f in enumerate(ui.figures)}})
    gr.on([tab.select, ui.reload.click],
          lambda: shown.values(benchmarks(page.docs, MAX_FIGURES)), None, shown.components,
          api_visibility="private")


def figure_made(path: Path) -> tuple[str, str | None]:
    """(when, commit) of a file of the docs folder: what its maker recorded, else its last
    commit (`ratouch.eval.report.figure_made`), else (an untracked copy, written here) the day
    it was written and no commit."""
    made = report.figure_made(path)
    if made is not None:
        return made[0], made[1]
    return time.strftime("%Y-%m-%d", time.gmtime(path.stat().st_mtime)), None


def provenance(path: Path, weights: tuple[str, str] | None) -> str:
    """When a file of the docs folder was made, against the shipped weights (`weights`:
    their date and commit): older by commit ancestry where both commits are known
    (`ratouch.eval.report.made_before`), else by date."""
    made = figure_made(path)
    older = None if weights is None else report.made_before(made[1], weights[1])
    return view.figure_provenance(made, weights, older)


def benchmarks(docs: Path, slots: int) -> dict:
    """The tab by output name: "story", "report", "note", and "figure_<i>" for `slots`
    plot slots (the figures found in docs/figures/, the rest hidden)."""
    files = view.list_figures(docs)
    weights = weights_commit()
    updates: list = []
    problems: list[str] = []
    for path in files:
        if len(updates) == slots:
            problems.append(f"{path.name} (only {slots} figures are shown)")
            continue
        try:
            fig = pio.from_json(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, TypeError) as e:
            problems.append(f"{path.name} ({type(e).__name__}: {str(e)[:120]})")
            continue
        # the width its maker chose (1,500 px for the trade-off) would be clipped by the
        # page: every figure takes its container's width
        fig.update_layout(width=None, autosize=True)
        label = f"{view.figure_title(path)} — {provenance(path, weights)}"
        updates.append(gr.update(value=fig, label=label, visible=True))
    updates += [gr.update(value=None, visible=False)] * (slots - len(updates))
    note = (f"{len(files)} figure file(s) in `docs/figures/`" if files else
            "No figure files (`docs/figures/*.json`) yet: `ratouch bench tradeoff` writes the "
            "speed-vs-accuracy chart.")
    if files and not (Path(docs) / view.FIGURES_DIR / "tradeoff.json").is_file():
        note += " · no speed-vs-accuracy chart yet (`ratouch bench tradeoff`)"
    report = Path(docs) / view.REPORT_NAME
    if report.is_file():
        note += (f" · the report (`{view.REPORT_NAME}`) was "
                 + provenance(report, weights))
    if problems:
        note += " · not shown: " + "; ".join(problems)
    return {"story": story_md(docs, weights), "report": view.report_md(docs, files),
            "note": note, **{f"figure_{i}": u for i, u in enumerate(updates)}}


def story_md(docs: Path, weights: tuple[str, str] | None) -> str:
    """The premise's verdict with its figures, then the real-frame checks, each dated
    against the shipped weights; what is missing is said, not made up."""
    docs = Path(docs)
    parts = ["### What the benchmarks say"]
    if weights:
        parts.append(f"<span class='ra-muted'>The shipped weights: {weights[0]} (commit "
                     f"{weights[1]}). Each result below says when it was made.</span>")
    parts.append(_premise_md(docs, weights))
    parts.append(_fallback_md(docs, weights))
    arms = _text_arm_md(docs, weights)
    if arms:
        parts.append(arms)
    parts.append(_frames_md(docs, weights))
    return "\n\n".join(parts)


def _read(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _stored(docs: Path, names: tuple[tuple[str, str], ...]) -> list[tuple[Path, str, dict]]:
    """(path, what it was run on, its JSON) of each stored result of `names` ((file, what))
    that the docs folder holds and that reads, in their order."""
    read = [(docs / name, what, _read(docs / name)) for name, what in names]
    return [(path, what, d) for path, what, d in read if d is not None]


def _premise_md(docs: Path, weights) -> str:
    found = _stored(docs, PREMISES)
    page = view.docs_url(docs, "premise.md")
    head = ("**The paper's premise** (retrieving from a visual corpus with tactile captions "
            "improves descriptions where paired touch data is scarce), tested by "
            "pre-registered criteria" + (f" ([how]({page}))" if page else ""))
    if not found:
        return head + ": *no result yet* (`ratouch eval premise --json > docs/premise-result.json`)."
    rows = ["| run | verdict | group | baseline | RA-Touch | gain [95% CI] | shuffle drop, p "
            "| copy ceiling | material oracle |", "|---|---|---|---|---|---|---|---|---|"]
    for path, what, d in found:
        when = provenance(path, weights)
        for group in ("scarce", "seen"):
            g = d.get("groups", {}).get(group)
            if not g:
                continue
            lo, hi = g.get("ci95", (float("nan"), float("nan")))
            run, verdict = ((f"{what} — {when}", f"**{d.get('verdict', '?')}**")
                            if group == "scarce" else ("", ""))
            nan = float("nan")
            rows.append(
                f"| {run} | {verdict} | {group} | {g['baseline']:.3f} | {g['ra_touch']:.3f} "
                f"| {g['gain']:+.3f} [{lo:+.3f}, {hi:+.3f}] "
                f"| {g.get('shuffle_drop', nan):+.3f}, p = {g.get('shuffle_p', nan):.3f} "
                f"| {g.get('copy_ceiling', nan):.3f} | {g.get('material_oracle', nan):.3f} |")
    latest = found[-1][2]
    gated = (f" The `gated` system on the same runs: **{latest['gated_verdict']}** — "
             f"{latest.get('gated_verdict_reason', '')}." if latest.get("gated_verdict")
             else "")
    return (f"{head}: **{latest.get('verdict', '?')}** — {latest.get('verdict_reason', '')}."
            + gated + "\n\n" + "\n".join(rows))


def _fallback_md(docs: Path, weights) -> str:
    """The `fallback` system's measures against its criteria (whether it is the default the
    page answers with is read from the pipeline); what is missing is said."""
    page = view.docs_url(docs, "premise.md")
    head = ("**The `fallback` system**" + (" (the default)" if DEFAULT_RETRIEVAL == "fallback"
                                            else f" (the default is `{DEFAULT_RETRIEVAL}`)")
            + ": the paper's system for every frame that looks like a rendered sensor, the "
            "image query's neighbours (read with a neutral touch) for a frame beyond every one"
            + (f" ([criteria]({page}))" if page else ""))
    d = _read(docs / FALLBACK)
    if d is None:
        return (head + ": *no result yet* (`python scripts/why_withhold.py --system fallback "
                f"> docs/{FALLBACK}`).")
    when = provenance(docs / FALLBACK, weights)
    nan = float("nan")

    def diff(block: dict, key: str) -> str:
        m = block.get(key) or {}
        lo, hi = m.get("ci95", (nan, nan))
        return f"{m.get('diff', nan):+.3f} [{lo:+.3f}, {hi:+.3f}]"

    serving, fresh = d.get("serving") or {}, d.get("fresh_renders") or {}
    bad, groups = d.get("recoloured_other") or {}, d.get("premise_groups") or {}
    rows = ["| measure | result |", "|---|---|"]
    if serving:
        same = serving["queries"] - len(serving.get("differ", []))
        rows.append(f"| world test queries answered as `paper` does (with and without the "
                    f"background) | {same} / {serving['queries']} ({serving['withheld']} "
                    "withheld) |")
    rows.append(f"| touch that tells nothing: gain over the baseline | "
                f"{diff(d.get('neutral_touch') or {}, 'rule_vs_baseline')} |")
    rows.append(f"| an unfamiliar-looking sensor whose touch is readable (recoloured "
                f"frames): against `paper` | {diff(d.get('recoloured') or {}, 'rule_vs_paper')} |")
    if bad:
        rows.append(f"| recoloured frames of another pair: fallback / paper / baseline | "
                    f"{bad['fallback']:.3f} / {bad['paper']:.3f} / {bad['baseline']:.3f} |")
    if fresh:
        rows.append(f"| fresh renders beyond the limit | {fresh['beyond']} / "
                    f"{fresh['renders']} |")
    if groups:
        rows.append("| premise frames beyond the limit | " + " · ".join(
            f"{g} {len(v['beyond'])} / {v['frames']}" for g, v in groups.items()) + " |")
    return f"{head} — {when}\n\n" + "\n".join(rows)


def _text_arm_md(docs: Path, weights) -> str:
    """The text arm against the paper's integrator on the same neighbours, per generator it
    ran on; empty where no run is stored."""
    found = _stored(docs, TEXT_ARMS)
    if not found:
        return ""
    nan = float("nan")
    rows = ["| generator | group | baseline | paper (integrator) | text arm | text − paper "
            "[95% CI] | text shuffle drop, p |", "|---|---|---|---|---|---|---|"]
    for path, what, d in found:
        when = provenance(path, weights)
        first = True
        for group in ("seen", "scarce"):
            g = d.get("groups", {}).get(group) or {}
            t = g.get("neighbour_text")
            if not t:
                continue
            lo, hi = t.get("vs_paper_ci95", (nan, nan))
            rows.append(f"| {f'{what} — {when} ' if first else ''}| {group} "
                        f"| {g['baseline']:.3f} | {g['ra_touch']:.3f} | {t['score']:.3f} "
                        f"| {t['vs_paper']:+.3f} [{lo:+.3f}, {hi:+.3f}] "
                        f"| {t['shuffle_drop']:+.3f}, p = {t['shuffle_p']:.1g} |")
            first = False
        test = d.get("arms_test") or {}
        score, diff = test.get("score", {}), test.get("text_vs_paper")
        if diff and "text" in score:
            lo, hi = diff.get("ci95", (nan, nan))
            rows.append(f"| | world test split | {score['baseline']:.3f} | {score['paper']:.3f} "
                        f"| {score['text']:.3f} | {diff['diff']:+.3f} [{lo:+.3f}, {hi:+.3f}] "
                        "| — |")
    page = view.docs_url(docs, "premise.md")
    return ("**The neighbours as text** (an arm that writes the retrieved captions into the "
            "generator's prompt, against the paper's integrator on the same neighbours; one "
            "run each" + (f"; [criteria and verdicts]({page})" if page else "") + ")\n\n"
            + "\n".join(rows))


def _frames_md(docs: Path, weights) -> str:
    files = sorted(docs.glob(FRAMES_GLOB))
    head = ("**Real frames** (Taxim's real presses of a rigid ball on GelSight and GelSight "
            "Mini, the reference DIGIT frames, and their blank backgrounds), read for what "
            "they are")
    if not files:
        return head + ": *no stored check* (`ratouch eval frames --real --json > docs/frames-real-DATE.json`)."
    path = files[-1]
    d = _read(path) or {}
    rows = d.get("frames", [])
    when = provenance(path, weights)
    taxim = summarise([r for r in rows if r.get("sensor") in ("gelsight", "mini")])
    digit = summarise([r for r in rows if r.get("sensor") == "digit"])
    alone = "presses_alone" in taxim  # a check run with --alone
    table = ["| frames | presses detected | contact region on the touch | read hard / soft "
             "| blanks read as no contact |" + (" presses without their background: "
                                                  "contact |" if alone else ""),
             "|---|---|---|---|---|" + ("---|" if alone else "")]
    for name, s in (("Taxim's GelSight / Mini", taxim), ("reference DIGIT", digit)):
        table.append(f"| {name} | {s['presses_detected']} / {s['presses']} "
                     f"| {s['presses_region_on_touch']} / {s['presses']} "
                     f"| {s['presses_read_hard']} / {s['presses_read_soft']} "
                     f"| {s['blanks_no_contact']} / {s['blanks']} |"
                     + (f" {s['presses_alone_detected']} / {s['presses_alone']} |"
                        if "presses_alone" in s else " – |" if alone else ""))
    source = view.docs_url(docs, path.name)
    return (f"{head} — `{d.get('command', 'ratouch eval frames --real')}` with "
            f"`{d.get('encoder', '?')}`, {when}"
            + (f"; corpus: {d['corpus']}" if d.get("corpus") else "")
            + (f" ([the rows]({source}))" if source else "") + ".\n\n" + "\n".join(table))

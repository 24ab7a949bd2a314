"""The stress report: the console table, the markdown report and the files written beside it
(JSON, HTML, plotly JSON and, where a static exporter works, PNG).
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path
from typing import Sequence

from ratouch.eval.answer import BASELINE, RA_TOUCH, SYSTEMS
from ratouch.eval.report import png_bytes, write_plotly_js
from ratouch.eval.stress.charts import figures
from ratouch.eval.stress.sweeps import PAIR_FIXED, PAPER_FAILURE, PER_SAMPLE
from ratouch.files import write_atomic
from ratouch.search.modes import QUERY_MODES, RA_TOUCH_MODE


def _f(v, nd: int = 3) -> str:
    return "—" if v is None else f"{v:.{nd}f}"


def format_table(result: dict) -> str:
    """The compact console table and the break points."""
    k = result["k"]
    heads = [f"P@{k} {m}" if i == 0 else m for i, m in enumerate(QUERY_MODES)]
    widths = [max(7, len(h) + 2) for h in heads]
    ovl = len(RA_TOUCH_MODE) + 6
    lines = [f"stress sweep: n={result['n']} test samples, K={k}, encoder {result['encoder']}, "
             f"{result['seconds']:.0f} s",
             f"{'knob':<21}{'value':<16}"
             + "".join(f"{h:>{w}}" for h, w in zip(heads, widths))
             + f"{'ovl ' + RA_TOUCH_MODE:>{ovl}}{'judge base':>11}{'RA':>7}"]
    for knob, kr in result["knobs"].items():
        for p in kr["points"]:
            r, g = p["retrieval"], p["generators"]
            lines.append(f"{knob:<21}{p['label']:<16}"
                         + "".join(f"{r[m]['material_precision']:>{w}.3f}"
                                   for m, w in zip(QUERY_MODES, widths))
                         + f"{r[RA_TOUCH_MODE]['topk_overlap']:>{ovl}.3f}"
                         f"{g[BASELINE]['judge']:>11.2f}{g[RA_TOUCH]['judge']:>7.2f}")
    lines.append("")
    lines.append(f"break points (first value below {result['drop']:.0%} of the unperturbed):")
    series = [f"P@{k} {m}" for m in QUERY_MODES] + [f"judge {s}" for s in SYSTEMS]
    lines.append(f"{'knob':<21}" + "".join(f"{s:>16}" for s in series))
    for knob, kr in result["knobs"].items():
        bp = kr["break_points"]
        lines.append(f"{knob:<21}" + "".join(f"{(bp[s]['breaks_at'] or 'holds'):>16}"
                                             for s in series))
    col = result.get("collapse")
    if col:
        lines.append("")
        lines.append("collapse of the joint queries (natural split):")
        for name, row in col["rows"].items():
            p = row.get("material_precision")
            lines.append(f"  {name:<18} effective rank {row['effective_rank']:7.2f}  mean cosine "
                         f"{row['mean_cosine']:.3f}"
                         + (f"  P@{k} {p:.3f}" if p is not None else ""))
    return "\n".join(lines)


_PAIRED = 0.9  # paired-labels share below which a point counts as not paired


def _reference_text(keys: Sequence[str]) -> str:
    if not keys:
        return "the natural split"
    parts = [f"{kk} = 1e-6 (same box, same draws)" if kk in PAIR_FIXED
             else f"{kk} at each sample's natural value" for kk in keys]
    return "paired (" + ", ".join(parts) + ")"


def _md_point_table(kr: dict, k: int) -> list[str]:
    head = ("| value " + "".join(f"| P@{k} {m} " for m in QUERY_MODES)
            + "".join(f"| overlap {m} " for m in QUERY_MODES)
            + "| judge baseline | judge RA-Touch "
            "| identical base / RA | adj-Jaccard base / RA | paired labels |")
    lines = [head, "|" + "---|" * (6 + 2 * len(QUERY_MODES))]
    for p in kr["points"]:
        r, g = p["retrieval"], p["generators"]
        lines.append(
            f"| {p['label']}{' (ref)' if p['reference'] else ''}"
            f"{' †' if p['paired_labels'] < _PAIRED else ''} "
            + "".join(f"| {r[m]['material_precision']:.3f} " for m in QUERY_MODES)
            + "".join(f"| {r[m]['topk_overlap']:.3f} " for m in QUERY_MODES)
            + f"| {g[BASELINE]['judge']:.2f} | {g[RA_TOUCH]['judge']:.2f} "
            f"| {g[BASELINE]['identical']:.2f} / {g[RA_TOUCH]['identical']:.2f} "
            f"| {g[BASELINE]['adj_jaccard']:.2f} / {g[RA_TOUCH]['adj_jaccard']:.2f} "
            f"| {p['paired_labels']:.2f} |")
        if "retrieval_no_fallback" in p:
            nf = p["retrieval_no_fallback"]
            cells = [(f"{nf[m]['material_precision']:.3f}" if m in nf else "—")
                     for m in QUERY_MODES]
            cells += [(f"{nf[m]['topk_overlap']:.3f}" if m in nf else "—") for m in QUERY_MODES]
            lines.append(f"| ↳ {p['label']}, no fallback (no-contact frame as the query) "
                         + "".join(f"| {c} " for c in cells) + "| | | | | |")
    return lines


def format_markdown(result: dict, png: str | None, png_note: str) -> str:
    """The stress report in markdown: how to read it, the natural split, break points, every
    knob's points, the collapse check and the figures."""
    k = result["k"]
    out = _md_header(result)
    out += _md_natural(result["reference"], k)
    out += _md_break_points(result, k)
    out += ["", "## Per knob", ""]
    for knob, kr in result["knobs"].items():
        out += [f"### {knob}", "", f"Reference: {_reference_text(kr['paired_reference'])}.",
                ""] + _md_point_table(kr, k) + [""]
    out += _md_collapse(result, k)
    out += _md_figures(png, png_note)
    out.append("")
    return "\n".join(out)


def _md_header(result: dict) -> list[str]:
    k = result["k"]
    return [
        "# Stress sweep: stability where the methods fail",
        "",
        f"Encoder `{result['encoder']}`, K={k}, {result['n']} test samples (stratified over the "
        f"structured and wild subsets; world seed {result['world_seed']}), judge "
        f"{result['judge']}; wall time {result['seconds']:.0f} s. Made by `ratouch eval stress`.",
        "",
        "* **P@K**: material precision@K of the corpus entries retrieved against the text index "
        "(image, tactile and joint = Tactile-Guided Retriever query).",
        "* **overlap**: |top-K ∩ top-K of the unperturbed reference| / K, mean over samples; "
        "**identical** / **adj-Jaccard**: share of descriptions equal to the reference's, mean "
        "adjective Jaccard with it. Judge: mean score 1-10.",
        "* **Reference** of each knob: knobs that replace a per-sample random draw "
        f"({', '.join(PER_SAMPLE)}) are compared with a paired reference (same samples, knob "
        "fixed to each sample's natural value, so the rest of the scene is drawn the same way); "
        "box_offset with a 1e-6 shift (takes the shift's random draw, rounds to the true box); "
        "the others with the natural split. *paired labels* = share of samples whose label "
        "adjectives equal the reference's (1.00 = fully paired scenes). clutter stays partly "
        f"unpaired: each distractor takes draws of its own, so at a count other than the "
        f"sample's natural one the contact box, lighting, tactile press and label are re-drawn "
        f"too; overlap and identity at such points (marked †, paired labels < {_PAIRED:.1f}) mix "
        f"the knob with that re-draw, while P@K and the judge (each sample against its own "
        f"truth) stay valid. object_scale and clutter do not apply to the structured "
        f"close-ups, which stay as they are.",
        "* **missing=tactile**: the tactile and joint modes fall back to the image query "
        "(as the app does); the generators read the no-contact frame, RA-Touch with the "
        "image-only neighbours. The ↳ row shows the no-contact frame used as the query.",
        f"* Paper failure case: {', '.join(f'{a}={b}' for a, b in PAPER_FAILURE.items())}.",
        "",
    ]


def _md_natural(ref: dict, k: int) -> list[str]:
    out = [
        "## Unperturbed (natural split)",
        "",
        f"| mode | P@{k} | adjective overlap@{k} |", "|---|---|---|"]
    for m in QUERY_MODES:
        r = ref["retrieval"][m]
        out.append(f"| {m} | {r['material_precision']:.3f} | {r['adjective_overlap']:.3f} |")
    out += ["", "| generator | judge |", "|---|---|"]
    for s in SYSTEMS:
        out.append(f"| {s} | {ref['generators'][s]['judge']:.2f} |")
    out += ["", "### Quality per object-scale bin (natural split; wild samples by scale)", "",
            "| bin | n " + "".join(f"| P@{k} {m} " for m in QUERY_MODES)
            + "| judge baseline | judge RA-Touch |",
            "|---|---|" + "---|" * (len(QUERY_MODES) + 2)]
    for row in ref["scale_bins"]:
        if row["n"] == 0:
            out.append(f"| {row['bin']} | 0 |" + " — |" * (len(QUERY_MODES) + 2))
            continue
        out.append(f"| {row['bin']} | {row['n']} "
                   + "".join(f"| {row['retrieval'][m]['material_precision']:.3f} "
                             for m in QUERY_MODES)
                   + "".join(f"| {row['judge'][s]:.2f} " for s in SYSTEMS) + "|")
    return out


def _md_break_points(result: dict, k: int) -> list[str]:
    drop = result["drop"]
    out: list[str] = []
    out += ["", "## Break points", "",
            f"First sweep value (mildest first) at which the quality falls below {drop:.0%} of "
            f"the knob's unperturbed value; *holds* = never within the sweep (worst value in "
            f"brackets). Overlap columns: first value whose top-{k} overlap with the "
            f"unperturbed answer is below {drop:.2f}; † = the point is not paired with its "
            f"reference (see above), so its overlap mixes the knob with re-drawn scenes.", ""]
    series = ([f"P@{k} {m}" for m in QUERY_MODES] + [f"judge {s}" for s in SYSTEMS]
              + [f"overlap {m}" for m in QUERY_MODES])
    out.append("| knob | " + " | ".join(series) + " |")
    out.append("|---|" + "---|" * len(series))
    for knob, kr in result["knobs"].items():
        cells = []
        unpaired = {p["label"] for p in kr["points"] if p["paired_labels"] < _PAIRED}
        for s in series:
            b = kr["break_points"][s]
            if b["breaks_at"] is not None:
                dag = " †" if s.startswith("overlap") and b["breaks_at"] in unpaired else ""
                cells.append(f"**{b['breaks_at']}**{dag} ({_f(b['value_at_break'], 2)} vs "
                             f"{_f(b['reference'], 2)})")
            else:
                w = b["worst"]
                cells.append(f"holds ({_f(w['value'], 2)})" if w else "holds")
        out.append(f"| {knob} | " + " | ".join(cells) + " |")
    return out


def _md_collapse(result: dict, k: int) -> list[str]:
    out: list[str] = []
    col = result.get("collapse")
    out += ["## Collapse of the retriever's queries", ""]
    if col:
        out += [f"Joint queries of the natural split ({result['n']} samples): the shipped "
                f"retriever (alignment + stability loss, `full`) against one trained with "
                f"alignment only (`align`, {col['epochs_align']} epochs"
                + (f", trained in {col['trained_s']:.0f} s" if "trained_s" in col else "")
                + (f", cached in `{col['align_folder']}`" if "align_folder" in col else "")
                + "). Raw image and tactile embeddings for scale.", "",
                f"| queries | effective rank | mean pairwise cosine | mean dim std | P@{k} |",
                "|---|---|---|---|---|"]
        for name, row in col["rows"].items():
            out.append(f"| {name} | {row['effective_rank']:.2f} | {row['mean_cosine']:.4f} | "
                       f"{row['mean_dim_std']:.4f} | {_f(row.get('material_precision'))} |")
    else:
        out.append("Not run (`--no-collapse`).")
    return out


def _md_figures(png: str | None, png_note: str) -> list[str]:
    out: list[str] = []
    out += ["", "## Figures", "",
            "`stress.html` (both figures, with plotly.min.js beside it, works offline); plotly JSON "
            "for the app: `stress_fig.json` (quality), `stress_overlap_fig.json` (stability).",
            ""]
    if png:
        out += [f"![quality under stress]({png})", "",
                f"![stability under stress]({png.replace('.png', '_overlap.png')})"]
    else:
        out.append(f"PNG: {png_note}")
    return out


def _html(figs) -> str:
    parts = [f.to_html(full_html=False, include_plotlyjs="directory" if i == 0 else False)
             for i, f in enumerate(figs)]
    return ("<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>"
            + html.escape("RA-Touch stress sweep") + "</title></head><body>\n"
            + "\n".join(parts) + "\n</body></html>\n")


def write_report(result: dict, out: str | os.PathLike, png: bool = True) -> dict[str, str]:
    """Write stress.json, stress.md, stress.html, stress_fig.json, stress_overlap_fig.json and,
    when kaleido can export (it needs a Chrome/Chromium), stress.png and stress_overlap.png.
    Returns {kind: path}."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    quality, stability = figures(result)
    paths = {"json": out / "stress.json", "md": out / "stress.md", "html": out / "stress.html",
             "fig": out / "stress_fig.json", "overlap_fig": out / "stress_overlap_fig.json"}
    png_name, note = None, "not requested."
    if png:
        (q_png, why), (s_png, why2) = png_bytes(quality), png_bytes(stability)
        if q_png is not None and s_png is not None:
            for name, data in (("stress.png", q_png), ("stress_overlap.png", s_png)):
                write_atomic(out / name, data)
            png_name = "stress.png"
            paths["png"] = out / "stress.png"
            paths["overlap_png"] = out / "stress_overlap.png"
        else:
            note = (f"not written: static export needs kaleido and a Chrome/Chromium, not usable "
                    f"here ({why or why2}); open stress.html instead.")
    write_atomic(paths["json"], json.dumps(result, indent=1) + "\n")
    write_atomic(paths["html"], _html([quality, stability]))
    write_plotly_js(out)
    write_atomic(paths["fig"], quality.to_json())
    write_atomic(paths["overlap_fig"], stability.to_json())
    write_atomic(paths["md"], format_markdown(result, png_name, note))
    return {kk: str(v) for kk, v in paths.items()}

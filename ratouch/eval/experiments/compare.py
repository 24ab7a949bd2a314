"""Variants against the no-retrieval baseline: the judge-score table rows (with 95 % CIs, gains
and paired t-tests), the paired-difference charts, and the two report shapes most experiments
share (a table of settings, a curve over one setting).
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from ratouch.eval.experiments.lab import Lab
from ratouch.eval.experiments.variants import BASELINE, Report, Variant


def judge_row(lab: Lab, name: str, r: dict, base: dict | None) -> list[str]:
    """A table row: SSVTP / HCT / TVL means with their 95 % bootstrap CI, the gain over the
    baseline and its p-value; then adjective F1 and mean answer length (overall)."""
    from scipy.stats import ttest_rel

    cells = [name]
    subs = np.array(lab.test.subsets)
    for key, sel in (("SSVTP", subs == "structured"), ("HCT", subs == "wild"),
                     ("overall", np.ones(len(subs), bool))):
        s = r["stats"][key]
        cell = f"{r['means'][key]:.3f} [{s['ci_low']:.2f}, {s['ci_high']:.2f}]"
        if base is not None and base is not r:
            a, b = np.array(base["scores"])[sel], np.array(r["scores"])[sel]
            d = float((b - a).mean())
            p = float(ttest_rel(b, a).pvalue) if np.any(b - a) else 1.0
            cell += f" ({d:+.3f}, p={p:.2g})"
        cells.append(cell)
    s = r["stats"]["overall"]
    return cells + [f"{s['f1']:.3f}", f"{s['mean_length']:.1f}"]


def md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


JUDGE_COLS = ["SSVTP (structured) [95% CI]", "HCT (wild) [95% CI]", "TVL (overall) [95% CI]",
              "adjective F1", "adjectives / answer"]


def paired_difference(a: np.ndarray, b: np.ndarray, level: float = 0.95
                      ) -> tuple[float, float, float]:
    """Mean of the paired differences b - a and its `level` t-interval (lo, hi)."""
    from scipy.stats import t as student_t

    d = np.asarray(b, np.float64) - np.asarray(a, np.float64)
    mean = float(d.mean())
    if len(d) < 2 or not np.any(d - mean):
        return mean, mean, mean
    half = float(student_t.ppf(0.5 + level / 2, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)))
    return mean, mean - half, mean + half


def diff_chart(title: str, names: Sequence[str], results: Sequence[dict], base: dict,
               subsets: Sequence[str]):
    """Each setting's judge-score difference from the baseline with its paired 95 % CI, per
    subset: the differences are a few hundredths, invisible on bars drawn from zero."""
    import plotly.graph_objects as go

    subs = np.array(subsets)
    fig = go.Figure()
    for _key, label, sel in (("SSVTP", "SSVTP (structured)", subs == "structured"),
                            ("HCT", "HCT (wild)", subs == "wild"),
                            ("overall", "TVL (overall)", np.ones(len(subs), bool))):
        stats = [paired_difference(np.array(base["scores"])[sel], np.array(r["scores"])[sel])
                 for r in results]
        fig.add_scatter(name=label, x=list(names), y=[m for m, _, _ in stats], mode="markers",
                        marker={"size": 9}, error_y={"type": "data", "symmetric": False,
                                                     "array": [hi - m for m, _, hi in stats],
                                                     "arrayminus": [m - lo for m, lo, _ in stats]})
    fig.add_hline(y=0, line_dash="dot", annotation_text="baseline (no retrieval)")
    fig.update_layout(title=title, template="plotly_white", height=440, autosize=True,
                      yaxis_title="judge score − baseline (paired 95 % CI)",
                      scattermode="group", legend={"orientation": "h", "y": -0.35},
                      margin={"b": 160})
    return fig


def simple_report(lab: Lab, name: str, title: str, rows: Sequence[tuple[str, Variant]],
                  note: str = "") -> Report:
    """A table of settings against the baseline (judge scores with CIs, gains, p-values) and
    the chart of their paired differences."""
    t0 = time.perf_counter()
    res = lab.evaluate([BASELINE] + [v for _, v in rows])
    base = res[BASELINE]
    named = [("baseline (no retrieval)", BASELINE)] + list(rows)
    table = md_table(["setting"] + JUDGE_COLS, [judge_row(lab, n, res[v], base) for n, v in named])
    md = table + ("\n\n" + note if note else "")
    fig = diff_chart(title, [n for n, _ in rows], [res[v] for _, v in rows], base,
                     lab.test.subsets)
    data = {n: res[v]["means"] for n, v in named}
    return Report(name, title, md, fig, data, time.perf_counter() - t0)


def curve_report(lab: Lab, name: str, title: str, xs: Sequence[int], variants: Sequence[Variant],
                 xlabel: str, log_x: bool = False) -> Report:
    """Judge scores over the values `xs` of one setting, against the baseline: a table and
    one curve per subset."""
    import plotly.graph_objects as go

    t0 = time.perf_counter()
    res = lab.evaluate([BASELINE] + list(variants))
    base = res[BASELINE]
    rows = [judge_row(lab, str(x), res[v], base) for x, v in zip(xs, variants)]
    md = md_table([xlabel] + JUDGE_COLS, [judge_row(lab, "baseline", base, None)] + rows)
    fig = go.Figure()
    for key, label in (("SSVTP", "SSVTP (structured)"), ("HCT", "HCT (wild)"),
                       ("overall", "TVL (overall)")):
        color = {"SSVTP": "#1f77b4", "HCT": "#ff7f0e", "overall": "#2ca02c"}[key]
        fig.add_scatter(x=list(xs), y=[res[v]["means"][key] for v in variants],
                        mode="lines+markers", name=f"RA-Touch, {label}", line={"color": color})
        fig.add_scatter(x=[min(xs), max(xs)], y=[base["means"][key]] * 2, mode="lines",
                        name=f"baseline, {label}", line={"color": color, "dash": "dot"})
    fig.update_layout(title=title, xaxis_title=xlabel, yaxis_title="offline judge score (1-10)",
                      template="plotly_white", height=420, width=760)
    if log_x:
        fig.update_xaxes(type="log")
    data = {str(x): res[v]["means"] for x, v in zip(xs, variants)}
    data["baseline"] = base["means"]
    return Report(name, title, md, fig, data, time.perf_counter() - t0)

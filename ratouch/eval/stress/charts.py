"""The stress figures: quality and stability along each knob's sweep, one subplot per knob.
"""

from __future__ import annotations

import math

from ratouch.eval.answer import SYSTEMS
from ratouch.search.modes import QUERY_MODES

_SYSTEM_COLOURS = dict(zip(SYSTEMS, ("#7f7f7f", "#d62728")))


def _sorted_points(points: list[dict]) -> list[dict]:
    if all(isinstance(p["x"], (int, float)) for p in points):
        return sorted(points, key=lambda p: p["x"])
    return points


def figures(result: dict):
    """(quality figure, stability figure): one subplot per knob.

    Quality: material P@K per mode (left axis, 0-1) and mean judge score per generator
    (dashed, right axis, 1-10). Stability: top-K overlap with the unperturbed answer per mode
    and adjective Jaccard with the unperturbed description per generator (dashed). The
    unperturbed reference is drawn as a star."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    knobs = list(result["knobs"])
    k = result["k"]
    cols = min(3, max(1, len(knobs)))
    rows = max(1, math.ceil(len(knobs) / cols))

    def frame(secondary: bool):
        return make_subplots(rows=rows, cols=cols, subplot_titles=knobs,
                             specs=[[{"secondary_y": secondary}] * cols for _ in range(rows)],
                             horizontal_spacing=0.09 if secondary else 0.06,
                             vertical_spacing=0.12)

    quality, stability = frame(True), frame(False)
    for j, knob in enumerate(knobs):
        r, c = j // cols + 1, j % cols + 1
        pts = _sorted_points(result["knobs"][knob]["points"])
        xs = [p["x"] for p in pts]
        symbols = ["star" if p["reference"] else "circle" for p in pts]
        text = [p["label"] for p in pts]
        first = j == 0
        for m in QUERY_MODES:
            common = dict(x=xs, mode="lines+markers", legendgroup=m, showlegend=first, text=text,
                          marker=dict(symbol=symbols, size=9, color=QUERY_MODES[m].colour),
                          line=dict(color=QUERY_MODES[m].colour))
            quality.add_trace(go.Scatter(y=[p["retrieval"][m]["material_precision"] for p in pts],
                                         name=f"P@{k} {m}", **common), row=r, col=c,
                              secondary_y=False)
            stability.add_trace(go.Scatter(y=[p["retrieval"][m]["topk_overlap"] for p in pts],
                                           name=f"top-{k} overlap {m}", **common), row=r, col=c)
        for s in SYSTEMS:
            common = dict(x=xs, mode="lines+markers", legendgroup=s, showlegend=first, text=text,
                          marker=dict(symbol=symbols, size=8, color=_SYSTEM_COLOURS[s]),
                          line=dict(color=_SYSTEM_COLOURS[s], dash="dash"))
            quality.add_trace(go.Scatter(y=[p["generators"][s]["judge"] for p in pts],
                                         name=f"judge {s}", **common), row=r, col=c,
                              secondary_y=True)
            stability.add_trace(go.Scatter(y=[p["generators"][s]["adj_jaccard"] for p in pts],
                                           name=f"adjective Jaccard {s}", **common), row=r, col=c)
    quality.update_yaxes(range=[0, 1.02], secondary_y=False)
    quality.update_yaxes(range=[1, 10], secondary_y=True, showgrid=False, tickmode="linear",
                         tick0=1, dtick=1)
    stability.update_yaxes(range=[0, 1.02])
    n = result["n"]
    quality.update_layout(
        title=f"Quality under stress (n={n}, K={k}): material P@{k} per query mode (solid, left "
              f"axis),<br>judge score per generator (dashed, right axis 1-10); star = unperturbed",
        height=330 * rows + 120, width=1300, template="plotly_white", margin={"t": 120})
    stability.update_layout(
        title=f"Stability under stress (n={n}): top-{k} overlap with the unperturbed answer "
              f"(solid),<br>adjective Jaccard with the unperturbed description (dashed)",
        height=330 * rows + 120, width=1300, template="plotly_white", margin={"t": 120})
    return quality, stability

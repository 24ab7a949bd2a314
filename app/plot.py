"""The PCA plot of one query: each query mode's embedding, their neighbours' caption
embeddings coloured by mode, and the ground-truth caption, in the pipeline's fixed frame."""

from __future__ import annotations

import plotly.graph_objects as go

from app.view import MODE_COLOUR, MODE_TITLE, MODES


def _neighbour_size(mode: str) -> int:
    """Neighbours of several modes sit on the same point: sizes decreasing in the modes' order
    (17, 12, 7, ...) keep every ring visible."""
    return max(17 - 5 * list(MODES).index(mode), 4)


def pca_figure(result: dict, label: str | None = None) -> go.Figure:
    """A plotly figure of `result["pca"]` (hover shows class and caption of neighbours)."""
    info = {(mode, n["id"]): n for mode, ns in result["neighbours"].items() for n in ns}
    points = result["pca"]["points"]
    fig = go.Figure()
    for mode in MODES:
        nb = [p for p in points if p["role"] == f"neighbour_{mode}"]
        if nb:
            fig.add_trace(go.Scatter(
                x=[p["x"] for p in nb], y=[p["y"] for p in nb], mode="markers",
                name=f"{mode} neighbours",
                marker=dict(size=_neighbour_size(mode), color=MODE_COLOUR[mode], opacity=0.75,
                            line=dict(width=1, color="white")),
                text=[_hover(info.get((mode, p.get("id")))) for p in nb], hoverinfo="text"))
    for mode in MODES:
        q = [p for p in points if p["role"] == f"query_{mode}"]
        if q:
            fig.add_trace(go.Scatter(
                x=[q[0]["x"]], y=[q[0]["y"]], mode="markers", name=f"{mode} query",
                marker=dict(symbol="star", size=20, color=MODE_COLOUR[mode],
                            line=dict(width=1.5, color="black")),
                hovertext=MODE_TITLE[mode], hoverinfo="text"))
    gt = [p for p in points if p["role"] == "ground_truth"]
    if gt:
        fig.add_trace(go.Scatter(
            x=[gt[0]["x"]], y=[gt[0]["y"]], mode="markers+text", name="ground truth",
            marker=dict(symbol="x", size=14, color="black"), text=[label or "ground truth"],
            textposition="top center", hovertext=f"ground truth: {label}", hoverinfo="text"))
    a, b = (list(result["pca"].get("explained", [])) + [0.0, 0.0])[:2]
    fig.update_layout(
        title=dict(text="PCA of the embeddings (fixed frame over the corpus)", font_size=14),
        xaxis_title=f"PC1 ({a:.0%} of variance)", yaxis_title=f"PC2 ({b:.0%})",
        template="plotly_white", height=420, margin=dict(l=50, r=10, t=40, b=40),
        legend=dict(orientation="h", y=-0.2))
    return fig


def _hover(n: dict | None) -> str:
    if n is None:
        return ""
    return f"{n['class_name']} (id {n['id']})<br>{n['caption']}<br>sim. {n['score']:.3f}"

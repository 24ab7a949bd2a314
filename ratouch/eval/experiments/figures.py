"""The paper's Figures 3 (corpus size), 5 (PCA of the joint queries per retriever loss) and 6
(number of retrieved neighbours K) on the world.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import torch

from ratouch.eval.experiments.compare import curve_report, md_table
from ratouch.eval.experiments.lab import Lab
from ratouch.eval.experiments.variants import RA_TOUCH, Report
from ratouch.eval.retrieval import entry_materials, material_precision
from ratouch.model.retriever import collapse_stats
from ratouch.search.index import exact_topk
from ratouch.search.pca import PCA2D
from ratouch.train.recipes import align_only_tgr


def fig3_corpus_size(lab: Lab) -> Report:
    """Figure 3: corpus scale (stratified subsets of the corpus)."""
    sizes = [s for s in lab.cfg.corpus_sizes if s <= len(lab.pipeline.corpus)]
    rep = curve_report(lab, "fig3", "Figure 3 - corpus size", sizes,
                       [replace(RA_TOUCH, corpus_size=s if s < len(lab.pipeline.corpus) else 0)
                        for s in sizes], "corpus entries", log_x=True)
    rep.markdown += (f"\n\nSubsets are class-stratified and nested inside the "
                     f"{len(lab.pipeline.corpus)}-entry default corpus; each point trains its "
                     "own integrator.")
    return rep


def fig6_top_k(lab: Lab) -> Report:
    """Figure 6: number of retrieved neighbours K."""
    return curve_report(lab, "fig6", "Figure 6 - number of retrieved samples K", list(lab.cfg.ks),
                        [replace(RA_TOUCH, k=k) for k in lab.cfg.ks], "K")


def fig5_loss_pca(lab: Lab) -> Report:
    """Figure 5: PCA of the joint queries, alignment loss only vs alignment + stability."""
    from plotly.subplots import make_subplots


    t0 = time.perf_counter()
    tgrs = {"alignment only": align_only_tgr(lab.cfg.encoder, seed=lab.cfg.seed)[0],
            "alignment + stability (shipped)": lab.pipeline.tgr}
    fig = make_subplots(rows=1, cols=2, subplot_titles=list(tgrs))
    mats = np.array(lab.test.materials)
    uniq = sorted(set(mats))
    from plotly.colors import sample_colorscale

    colours = sample_colorscale("Turbo", [j / max(1, len(uniq) - 1) for j in range(len(uniq))])
    rows, data = [], {}
    for col, (name, tgr) in enumerate(tgrs.items(), start=1):
        qn = lab.pipeline.joint_query(lab.test.V, lab.test.T, tgr)
        stats = collapse_stats(torch.from_numpy(qn))
        ids = exact_topk(qn, lab.pipeline.corpus_embeddings("tactile_caption"), 5)
        prec = float(material_precision(ids, lab.test.materials, entry_materials(lab.pipeline.corpus)).mean())
        xy = PCA2D.fit(qn).project(qn)
        for j, m in enumerate(uniq):
            sel = mats == m
            fig.add_scatter(x=xy[sel, 0], y=xy[sel, 1], mode="markers", name=m,
                            legendgroup=m, showlegend=col == 1,
                            marker={"size": 5, "color": colours[j]}, row=1, col=col)
        rows.append([name, f"{stats['mean_cosine']:.3f}", f"{stats['effective_rank']:.1f}",
                     f"{prec:.3f}"])
        data[name] = {**{k: round(float(v), 4) for k, v in stats.items()},
                      "material_precision@5": round(prec, 4)}
    fig.update_layout(title="Figure 5 - PCA of the joint queries on the test split (colour = "
                            "material)", template="plotly_white", height=480, width=980)
    md = md_table(["retriever loss", "mean pairwise cosine", "effective rank",
                   "joint->text material P@5"], rows)
    return Report("fig5", "Figure 5 - loss strategies: PCA of the queries", md, fig, data,
                  time.perf_counter() - t0)

"""The collapse check: do the retriever's joint queries collapse onto a few directions without
the stability loss?
"""

from __future__ import annotations

from typing import Any

import torch

from ratouch.eval.stress.scoring import Context, split_retrieval_metrics
from ratouch.model.retriever import collapse_stats
from ratouch.train.recipes import align_only_tgr
from ratouch.world.splits import TestSplit


def collapse_report(pipeline, split: TestSplit, ctx: Context, encoder: str,
                    epochs: int = 12, seed: int = 0, align_tgr=None,
                    progress: bool = False) -> dict:
    """Collapse statistics (`collapse_stats`) and material precision@K of the joint queries on
    the natural split: the shipped retriever ("full" = alignment + stability loss) against one
    trained with alignment only (cached; trained on first use, `epochs` epochs)."""
    info: dict[str, Any] = {"epochs_align": epochs}
    if align_tgr is None:
        align_tgr, trained = align_only_tgr(encoder, epochs, seed, progress)
        info.update(trained)
    rows = {}
    for name, tgr in (("full (shipped)", pipeline.tgr), ("align only", align_tgr)):
        q = pipeline.joint_query(split.V, split.T, tgr)
        ids = pipeline.corpus.search("text", q, ctx.k)[1]
        stats = collapse_stats(torch.from_numpy(q))
        rows[name] = {**{k: round(v, 4) for k, v in stats.items()},
                      **split_retrieval_metrics(ids, split, ctx)}
    for name, x in (("image query (V)", split.V), ("tactile query (T)", split.T)):
        rows[name] = {k: round(v, 4) for k, v in collapse_stats(torch.from_numpy(x)).items()}
    info["rows"] = rows
    return info

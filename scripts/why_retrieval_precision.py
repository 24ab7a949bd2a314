"""How often each retrieval mode finds the query's true material, on the premise's seen and
scarce groups (shipped default-s weights, draw 0): material precision@5 against the default
corpus for image->image, image->text, tactile->image, tactile->text and joint->text, and how
many corpus entries each group's materials have (the chance level is that share of the corpus).

A diagnostic for docs/premise.md ("Why"): RA-Touch can only read a scarce material's captions
if retrieval finds them.

    python scripts/why_retrieval_precision.py [N]      # N pairs per group (default 300)
"""

from __future__ import annotations

import json
import sys

import numpy as np

from ratouch.eval.premise import GROUPS, group_split
from ratouch.eval.retrieval import entry_materials
from ratouch.search.retrieval import QUERY_MODES, mode_query
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.world.scarcity import ScarceRegime


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    n = int(argv[0]) if argv else 300
    p = RATouchPipeline.load("default-s", generators=False)
    mats = entry_materials(p.corpus)
    out = {}
    for g in GROUPS:
        split = group_split(p.encoders, g, n, ScarceRegime())
        queries = {m: mode_query(m, split.V, split.T, p.joint_query) for m in QUERY_MODES}
        truth = np.array(split.materials)
        out[g] = {mode: round(float((mats[ids] == truth[:, None]).mean()), 4)
                  for mode, (_, ids) in p.retriever.retrieve(queries, k=5).items()}
        share = np.mean([(mats == m).mean() for m in truth])
        out[g]["chance"] = round(float(share), 4)
        print(g, json.dumps(out[g]), flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

"""Where the gated system's reader should answer: the touch weight below which it does,
chosen on validation renders by the rule of docs/premise.md ("The reader only where touch is
clearly wrong").

On N validation renders (world seed 0, train[START:START + N]; none is in the test split or a
premise group), with their own touch ("clean") and with another pair's ("mismatched"): the
paper's system, and the gated system answering with the reader where the gate gives touch less
than t and with the paper's generator elsewhere (both on the gated query's neighbours, as
`TrustRouted` answers), for t on the grid 0.05, 0.10 ... 0.50. The rule: the largest t at
which `gated` loses at most `--allow` (0.05) to `paper` on the clean pairs.

    python scripts/why_read_below.py [--start S] [--n N] [--k K] [--encoder E] [--allow A]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np

from ratouch.eval.answer import RA_TOUCH, answer_split, retrieve
from ratouch.eval.judge import OfflineJudge
from ratouch.model.gate import READ_BELOW
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.world.splits import encode_test_split

GRID = tuple(round(0.05 * i, 2) for i in range(1, 11))


def choose(grid: tuple[float, ...], loss: dict[float, float], allow: float) -> float | None:
    """The largest t of `grid` whose loss to paper is at most `allow` (None: none is)."""
    ok = [t for t in grid if loss[t] <= allow]
    return max(ok) if ok else None


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_read_below")
    ap.add_argument("--start", type=int, default=1_100_000, help="first validation render")
    ap.add_argument("--n", type=int, default=402)
    ap.add_argument("--k", type=int, default=5)
    ap.add_argument("--encoder", default="default-s")
    ap.add_argument("--allow", type=float, default=0.05,
                    help="the most gated may lose to paper on the clean pairs")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)

    p = RATouchPipeline.load(args.encoder)
    if p.gate is None or p.generator_reader is None:
        raise SystemExit(f"{args.encoder} has no touch gate or no reader: nothing to route")
    clean = encode_test_split(p.encoders, indices=range(args.start, args.start + args.n),
                              split="train")
    judge = OfflineJudge()
    out: dict = {"config": {**vars(args), "read_below_now": READ_BELOW}, "touch": {}}
    losses: dict[float, float] = {}
    for name, split in (("clean", clean),
                        ("mismatched", dataclasses.replace(clean, T=np.roll(clean.T, 1, 0)))):
        def score(ids, generator, label, split=split):
            return answer_split(p, split, RA_TOUCH, ids=ids, generator=generator, judge=judge,
                                name=label).scores

        w = p.gate.weights(split.V, split.T, p.joint_query(split.V, split.T))
        gated_ids = retrieve(p, split.V, split.T, args.k, "gated")
        paper = score(retrieve(p, split.V, split.T, args.k, "joint"), p.generator_ra, "paper")
        on_gated = score(gated_ids, p.generator_ra, "paper on the gated neighbours")
        reader = score(gated_ids, p.generator_reader, "reader")
        rows = {}
        for t in GRID:
            routed = np.where(w < t, reader, on_gated)
            rows[str(t)] = {"reader_answers": int((w < t).sum()),
                            "gated": round(float(routed.mean()), 4),
                            "vs_paper": round(float(routed.mean() - paper.mean()), 4)}
            if name == "clean":
                losses[t] = float(paper.mean() - routed.mean())
        out["touch"][name] = {"paper": round(float(paper.mean()), 4),
                              "paper_on_gated_neighbours": round(float(on_gated.mean()), 4),
                              "weight_quartiles": [round(float(x), 3)
                                                   for x in np.quantile(w, [0.25, 0.5, 0.75])],
                              "by_threshold": rows}
    out["chosen"] = choose(GRID, losses, args.allow)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

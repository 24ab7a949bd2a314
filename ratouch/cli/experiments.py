"""`ratouch eval table1 ... fig6`, `ratouch eval all`: the paper's experiments, their markdown
and figures (`all` regenerates docs/results.md).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ratouch.eval.experiments import (
    EXPERIMENTS,
    ExperimentConfig,
    Lab,
    results_markdown,
    run_experiments,
)
from ratouch.eval.report import git_commit
from ratouch.files import write_atomic


def run(args: argparse.Namespace) -> int:
    cfg = ExperimentConfig(encoder=args.encoder, steps=args.steps, seed=args.seed,
                           workers=args.workers)
    names = list(EXPERIMENTS) if args.eval_cmd == "all" else [args.eval_cmd]
    commit = git_commit()  # the code the run uses, before its figures change the tree
    t0 = time.perf_counter()
    lab = Lab(cfg)
    reports = run_experiments(names, cfg, args.out, lab)
    out = Path(args.out)
    doc = out / ("results.md" if args.eval_cmd == "all" else f"{args.eval_cmd}.md")
    write_atomic(doc, results_markdown(reports, cfg, time.perf_counter() - t0,
                                       out=out if args.eval_cmd == "all" else None,
                                       counts=lab.counts, commit=commit))
    for rep in reports:
        print(f"## {rep.title}  ({rep.seconds:.0f} s)\n\n{rep.markdown}\n")
    print(f"wrote {doc} and its figures in {out / 'figures'}")
    return 0

"""`ratouch bench`: index retrieval, speed against accuracy, the vision towers, the whole
query, corpus build throughput, a huge upload, world generation.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ratouch.bench.corpus import bench_corpus, format_corpus_bench
from ratouch.bench.index import (
    bench_corpus_index,
    bench_retrieval,
    bench_scale,
    format_bench,
    format_real,
)
from ratouch.bench.memory import bench_memory, format_memory
from ratouch.bench.query import bench_query, bench_world
from ratouch.bench.towers import bench_towers, format_towers, tower_names, write_towers
from ratouch.bench.tradeoff import bench_tradeoff, format_tradeoff, tradeoff_figure
from ratouch.bench.upload import bench_upload
from ratouch.cli.common import usage
from ratouch.corpus.imagenet_t import parse_size
from ratouch.eval.experiments import Report, write_report
from ratouch.eval.report import git_commit, utc_stamp
from ratouch.search.kinds import BENCH_KINDS
from ratouch.threads import blas_threads, intra_op_threads


def _csv(text: str, conv=str) -> list:
    try:
        return [conv(x) for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise usage(f"{text!r}: {e}") from e


def _bench_tradeoff(args: argparse.Namespace) -> int:
    bad = set(_csv(args.indexes)) - set(BENCH_KINDS)
    if bad:
        raise usage(f"--indexes: unknown index type(s) {sorted(bad)}; use "
                    f"{', '.join(BENCH_KINDS)}")
    commit = git_commit()  # the code measured, before the figures change the tree
    r = bench_tradeoff(indexes=_csv(args.indexes), sizes=_csv(args.sizes, int),
                       ks=_csv(args.ks, int), other_encoders=_csv(args.encoders),
                       n_latency=args.n, progress=None if args.json else print)
    # when and on what it was measured travels with the figures (a page that quotes them
    # says so; a file's modification time is only when it was checked out)
    r["made"] = {"utc": utc_stamp(), "commit": commit}
    table = format_tradeoff(r)
    write_report(Report("tradeoff", "Speed against accuracy", f"```\n{table}\n```\n\n"
                        f"Settings: `{json.dumps(r['settings'])}`", tradeoff_figure(r), r),
                 Path(args.out) / "figures")
    print(json.dumps(r, indent=1) if args.json else table)
    return 0


def _bench_towers(args: argparse.Namespace) -> int:
    towers = _csv(args.towers) if args.towers else list(tower_names())
    bad = set(towers) - set(tower_names())
    if bad or not towers:
        raise usage(f"--towers: unknown tower(s) {sorted(bad)}; use {', '.join(tower_names())}")
    sizes = _csv(args.sizes, int) if args.sizes else None
    r = bench_towers(n=args.n, sizes=sizes, towers=towers, encoder=args.encoder,
                     gallery=args.gallery, threads=args.threads, latency_reps=args.reps,
                     progress=None if args.json else print)
    files = write_towers(r, args.out)
    if args.json:
        print(json.dumps({**r, "files": files}, indent=1))
        return 0
    print(format_towers(r))
    print(f"wrote {', '.join(v for k, v in files.items() if k != 'note')}")
    if "note" in files:
        print(f"note: {files['note']}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.bench_cmd == "tradeoff":
        return _bench_tradeoff(args)
    if args.bench_cmd == "towers":
        return _bench_towers(args)
    if args.bench_cmd == "corpus":
        r = bench_corpus(args.engine, args.n, args.workers, args.encoder)
        print(json.dumps(r) if args.json else format_corpus_bench(r))
        return 0
    if args.bench_cmd == "query":
        blas_threads(1)  # as `ratouch query` and the app serve (ratouch.threads)
        with intra_op_threads(1):
            r = bench_query(args.encoder, args.corpus, n=args.n)
        print(json.dumps(r, indent=None if args.json else 1))
        return 0
    if args.bench_cmd == "memory":
        try:
            r = bench_memory(args.side, args.burst, tuple(_csv(args.modes)), args.box_side)
        except ValueError as e:
            raise usage(f"--modes: {e}") from e
        print(json.dumps(r, indent=1) if args.json else format_memory(r))
        return 0
    if args.bench_cmd == "upload":
        print(json.dumps(bench_upload(args.encoder, args.corpus, args.side, args.repeats),
                         indent=1))
        return 0
    if args.bench_cmd == "retrieval" and args.corpus:
        keys = ("image", "text") if args.key == "both" else (args.key,)
        kinds = tuple(k for k in args.kinds.split(",") if k)
        r = {key: bench_corpus_index(args.corpus, args.encoder, key, kinds, args.queries,
                                     progress=not args.json) for key in keys}
        print(json.dumps(r) if args.json else "\n\n".join(format_real(v) for v in r.values()))
        return 0
    if args.bench_cmd == "retrieval":
        r = bench_retrieval(n=args.n, dim=args.dim, n_queries=args.queries)
        if args.scale:
            r["scale"] = bench_scale(n=args.scale, dim=args.dim)
        print(json.dumps(r) if args.json else format_bench(r))
        return 0

    r = bench_world(parse_size(args.corpus_size), workers=args.workers)
    if args.json:
        print(json.dumps(r))
    else:
        print(f"world generation on {r['cpu_count']} cores, {r['workers']} workers:")
        print(f"  ImageNet-T {r['corpus_size']} metadata (plan + recaption): "
              f"{r['corpus_metadata_s']:.2f} s")
        print(f"  ImageNet-T {r['corpus_size']} images rendered: {r['corpus_render_s']:.2f} s "
              f"({r['corpus_images_per_s']:.0f} images/s)")
        print(f"  test split, 402 pairs written in TVL layout: {r['test_split_s']:.2f} s "
              f"({r['test_pairs_per_s']:.0f} pairs/s)")
        print(f"  total: {r['total_s']:.2f} s (target < {r['target_s']:.0f} s: "
              f"{'met' if r['meets_target'] else 'NOT met'})")
    return 0

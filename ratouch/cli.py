"""The `ratouch` command line: a thin client of the library.

Every subcommand is `main(argv)`-callable. User errors print one line and exit with code 2,
and leave nothing half-written behind.

Imports of the library's model-side modules sit inside the subcommand that needs them, on
purpose: they load torch, faiss and transformers (about 2-3 s), which `ratouch --help`, a
usage error or `ratouch judge` should not pay. The library itself imports at module top.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path
from typing import Sequence

from ratouch.errors import RATouchError
from ratouch.eval.catalog import EXPERIMENT_HELP
from ratouch.files import write_json_atomic
from ratouch.paths import APP_FILE, retriever_weights


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit code 2), as the CLI promises."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from e
    if v < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return v


def _pos_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from e
    if v <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return v


def _add_world(sub) -> None:
    world = sub.add_parser("world", help="the procedural visuo-tactile world")
    wsub = world.add_subparsers(dest="world_cmd", required=True)

    b = wsub.add_parser("build", help="write a split in the TVL data set layout")
    b.add_argument("--out", required=True, help="data set root folder")
    b.add_argument("--split", choices=("train", "test"), default="train")
    b.add_argument("--n", type=_pos_int, default=None,
                   help="number of pairs (train default 20000; test is always 402)")
    b.add_argument("--seed", type=_nonneg_int, default=0)
    b.add_argument("--workers", type=_pos_int, default=2)
    b.add_argument("--regime", choices=("scarce", "full"), default="scarce",
                   help="train split: the scarce-touch regime's pairs (14 materials keep 8 "
                        "pairs each; see docs/premise.md) or every pair")
    b.add_argument("--draw", type=_nonneg_int, default=0,
                   help="which few pairs of the scarce materials are kept")
    _add_stress(b)

    p = wsub.add_parser("preview", help="a contact sheet PNG a person can look at")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("--split", choices=("train", "test"), default="test")
    p.add_argument("--n", type=_pos_int, default=24)
    p.add_argument("--start", type=_nonneg_int, default=0, help="first sample index")
    p.add_argument("--stride", type=_pos_int, default=17, help="index step between samples")
    p.add_argument("--seed", type=_nonneg_int, default=0)
    p.add_argument("--columns", type=_pos_int, default=4)
    _add_stress(p)

    pr = wsub.add_parser("probe", help="material probe: visual vs tactile vs both")
    pr.add_argument("--n-train", type=_pos_int, default=2400)
    pr.add_argument("--n-test", type=_pos_int, default=800)
    pr.add_argument("--seed", type=_nonneg_int, default=0)
    pr.add_argument("--workers", type=_pos_int, default=2)
    pr.add_argument("--json", action="store_true", help="print JSON")


def _add_stress(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("stress knobs")
    g.add_argument("--object-scale", type=float, help="object side / frame side, 0.1..1")
    g.add_argument("--clutter", type=int, help="number of distractors")
    g.add_argument("--background-dominance", type=float, help="0..1")
    g.add_argument("--tactile-noise", type=float, help="sensor noise std, 0..0.3")
    g.add_argument("--tactile-blur", type=float, help="gel blur sigma, pixels")
    g.add_argument("--tactile-rotation", type=float, help="texture rotation, degrees")
    g.add_argument("--box-offset", type=float, default=0.0, help="box shift / box side")
    g.add_argument("--missing", choices=("none", "visual", "tactile"), default="none")
    g.add_argument("--no-contact", type=float, default=0.0, help="no-contact frame rate")


def _world_cfg(args: argparse.Namespace):

    from ratouch.world.config import StressConfig, WorldConfig

    stress = StressConfig(
        object_scale=args.object_scale, clutter=args.clutter,
        background_dominance=args.background_dominance, tactile_noise=args.tactile_noise,
        tactile_blur=args.tactile_blur, tactile_rotation=args.tactile_rotation,
        box_offset=args.box_offset, missing=args.missing, no_contact=args.no_contact)
    return WorldConfig(seed=args.seed, stress=stress)


def _add_corpus(sub) -> None:
    corpus = sub.add_parser("corpus", help="ImageNet-T, the tactile-recaptioned corpus")
    csub = corpus.add_subparsers(dest="corpus_cmd", required=True)
    b = csub.add_parser("build", help="recaption and sample a corpus")
    b.add_argument("--size", default="10k", help="10k, 50k, 100k, 150k or a count")
    b.add_argument("--out", required=True, help="corpus folder (must not hold a corpus)")
    b.add_argument("--seed", type=_nonneg_int, default=0)
    b.add_argument("--captioner", choices=("offline", "llm"), default="offline")
    b.add_argument("--endpoint", help="OpenAI-compatible base URL for --captioner llm "
                                      "(key from $RATOUCH_LLM_API_KEY)")
    b.add_argument("--model", default="gpt-4o-mini")
    b.add_argument("--from-list", help="CSV or Parquet of (image path, class, caption) for a "
                                       "real corpus")
    b.add_argument("--encoder", default="default-s", help="encoder to embed with")
    b.add_argument("--index", choices=("flat", "hnsw", "ivfpq", "ivfflat"), default="flat",
                   help="with --engine ray, ivfflat/ivfpq are built from the shards on disk")
    b.add_argument("--no-embed", action="store_true", help="only recaption and sample")
    b.add_argument("--workers", type=_pos_int, default=2,
                   help="render processes (local) or embedding actors (ray)")
    b.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="local: one process; ray: a Ray Data pipeline, resumable shards")
    b.add_argument("--address", default=None, help="Ray cluster address (default: "
                                                   "$RAY_ADDRESS, else a local Ray)")
    b.add_argument("--num-cpus", type=_pos_int, default=None, help="CPUs of a local Ray")
    b.add_argument("--batch-size", type=_pos_int, default=250, help="entries per Ray batch")
    b.add_argument("--shard-size", type=_pos_int, default=1000, help="entries per shard")
    b.add_argument("--llm-concurrency", type=_pos_int, default=8,
                   help="LLM requests in flight at once (ray)")
    b.add_argument("--llm-rate", type=float, default=50.0,
                   help="LLM requests per second, 0 for no limit (ray)")


def _add_train(sub) -> None:
    train = sub.add_parser("train", help="train the default models")
    tsub = train.add_subparsers(dest="train_cmd", required=True)
    e = tsub.add_parser("encoders", help="train the default vision/tactile/text encoders")
    e.add_argument("--model", action="append", choices=("default-tiny", "default-s", "default-b",
                                                         "debug"),
                   help="encoder(s) to train (repeatable; default: tiny, s and b)")
    e.add_argument("--out", default=None, help="folder for the weights (default: assets/encoders)")
    e.add_argument("--seed", type=_nonneg_int, default=0)
    e.add_argument("--steps", type=_pos_int, default=None, help="override the step count")
    e.add_argument("--n-pairs", type=_pos_int, default=12_000)
    e.add_argument("--n-corpus", type=_pos_int, default=8_000)
    e.add_argument("--threads", type=_pos_int, default=2, help="torch threads for training")
    r = tsub.add_parser("retriever", help="train the Tactile-Guided Retriever (then frozen)")
    r.add_argument("--encoder", default="default-s")
    r.add_argument("--seed", type=_nonneg_int, default=0)
    r.add_argument("--strategy", choices=("align", "align_mse", "align_div_nce", "full"),
                   default="full", help="loss strategy (the paper's Fig. 5 compares them)")
    r.add_argument("--paper-exact", action="store_true",
                   help="no residual around the cross-attention (eq. 2 as printed)")
    r.add_argument("--epochs", type=_pos_int, default=None)
    g = tsub.add_parser("generator", help="train the baseline and RA-Touch generators")
    g.add_argument("--encoder", default="default-s")
    g.add_argument("--seed", type=_nonneg_int, default=0)
    g.add_argument("--draw", type=_nonneg_int, default=0,
                   help="which few pairs of the scarce materials the paired split keeps")
    g.add_argument("--out", default=None,
                   help="folder for baseline/ and ra/ (default: the shipped assets)")
    g.add_argument("--stage0-steps", type=_pos_int, default=None,
                   help="language-prior steps (used only when assets/generator/ENC/prior "
                        "is missing)")
    g.add_argument("--stage1-steps", type=_pos_int, default=None)
    g.add_argument("--stage2-steps", type=_pos_int, default=None)
    tr = tsub.add_parser("trust", help="calibrate the trust signals (novelty, no contact) on "
                                       "the world's validation renders")
    tr.add_argument("--encoder", default="default-s")
    tr.add_argument("--seed", type=_nonneg_int, default=0)
    tr.add_argument("--false-alarm", type=float, default=0.02,
                    help="share of in-distribution validation inputs each signal may flag")
    tr.add_argument("--out", default=None,
                    help="calibration JSON (default: assets/trust/ENCODER.json)")
    cc = tsub.add_parser("cascade", help="calibrate the encoder cascade (smallest confident "
                                         "encoder answers) on the world's validation renders")
    cc.add_argument("--encoders", default="default-tiny,default-s",
                    help="encoder sets, smallest first (each needs its retriever and generators)")
    cc.add_argument("--seed", type=_nonneg_int, default=0)
    cc.add_argument("--n", type=_pos_int, default=1000, help="validation pairs")
    cc.add_argument("--out", default=None,
                    help="calibration JSON (default: assets/cascade/ENC1+ENC2.json)")
    a = tsub.add_parser("all", help="encoders, corpus embeddings, retriever, language prior, "
                                    "generators and trust calibration, in order")
    a.add_argument("--seed", type=_nonneg_int, default=0)


def _add_eval(sub) -> None:
    ev = sub.add_parser("eval", help="evaluations that print measured figures")
    esub = ev.add_subparsers(dest="eval_cmd", required=True)
    r = esub.add_parser("retrieval", help="material precision@K and adjective overlap@K")
    r.add_argument("--corpus", default=None, help="corpus folder (default: the cached 10k)")
    r.add_argument("--encoder", default="default-s")
    r.add_argument("--index", choices=("flat", "hnsw", "ivfpq"), default="flat")
    r.add_argument("--seed", type=_nonneg_int, default=0, help="world seed of the test split")
    r.add_argument("--json", action="store_true")
    t = esub.add_parser("tvl", help="TVL benchmark protocol on the world's test split: "
                                    "generate, judge, write a TVL-format results file")
    t.add_argument("--system", choices=("baseline", "ra-touch"), required=True)
    t.add_argument("--out", required=True, help="results JSON to write (TVL format + scores)")
    t.add_argument("--encoder", default="default-s")
    t.add_argument("--k", type=_pos_int, default=5, help="neighbours RA-Touch reads")
    t.add_argument("--seed", type=_nonneg_int, default=0, help="world seed of the test split")
    _add_stress(t)
    _add_judge_options(t)
    t.add_argument("--json", action="store_true")
    st = esub.add_parser("stress", help="quality and stability of retrieval and generation "
                                        "under each stress knob, break points, collapse check")
    st.add_argument("--encoder", default="default-s")
    st.add_argument("--k", type=_pos_int, default=5, help="neighbours per query (P@K, overlap@K)")
    st.add_argument("--n", type=_pos_int, default=None,
                    help="test samples, stratified over structured/wild (default 200; 402 = all)")
    st.add_argument("--knobs", default=None,
                    help="comma-separated knobs (default all: object_scale, clutter, "
                         "background_dominance, tactile_noise, tactile_blur, tactile_rotation, "
                         "box_offset, missing, paper_failure)")
    st.add_argument("--values", action="append", metavar="KNOB=V1,V2",
                    help="other sweep values for a knob (repeatable)")
    st.add_argument("--drop", type=float, default=0.8,
                    help="break point: quality below this fraction of the unperturbed value")
    st.add_argument("--no-collapse", action="store_true",
                    help="skip the collapse diagnostic (it trains an align-only retriever once)")
    st.add_argument("--collapse-epochs", type=_pos_int, default=12,
                    help="epochs of the align-only retriever (the shipped one had 12)")
    st.add_argument("--seed", type=_nonneg_int, default=0, help="world seed of the test split")
    st.add_argument("--out", default="reports/stress", help="report folder")
    st.add_argument("--json", action="store_true", help="print the result as JSON")

    for name, about in [*EXPERIMENT_HELP.items(),
                        ("all", "every paper experiment; regenerates docs/results.md")]:
        e = esub.add_parser(name, help=about)
        e.add_argument("--out", default="docs" if name == "all" else "reports",
                       help="folder for the markdown and figures (figures/ inside it)")
        e.add_argument("--steps", type=_pos_int, default=300,
                       help="stage-2 training steps of every generator variant")
        e.add_argument("--workers", type=_pos_int, default=2,
                       help="variants trained in parallel (one thread each)")
        e.add_argument("--encoder", default="default-s")
        e.add_argument("--seed", type=_nonneg_int, default=0)
    tt = esub.add_parser("ttest", help="paired t-test between two scored results files (B - A)")
    tt.add_argument("a", help="results file A (e.g. the baseline)")
    tt.add_argument("b", help="results file B (e.g. RA-Touch)")
    tt.add_argument("--json", action="store_true")
    c = esub.add_parser("controls", help="does RA-Touch read its neighbours? shuffled "
                                         "neighbours, zeroed integrator, copy and oracle ceilings")
    c.add_argument("--encoder", default="default-s")
    c.add_argument("--k", type=_pos_int, default=5, help="neighbours RA-Touch reads")
    c.add_argument("--shuffles", type=_pos_int, default=3, help="neighbour shuffles (seeds)")
    c.add_argument("--seed", type=_nonneg_int, default=0, help="seed of the shuffles and CIs")
    c.add_argument("--json", action="store_true")
    pr = esub.add_parser("premise", help="the paper's premise: baseline against RA-Touch on "
                                         "seen and scarce materials, over runs, with controls "
                                         "and the pre-registered verdict (docs/premise.md)")
    pr.add_argument("--encoder", default="default-s")
    pr.add_argument("--runs", type=_pos_int, default=3,
                    help="runs (run r: training seed r, draw r; run 0 is the shipped weights, "
                         "the others train into the cache on first use, ~8 min each)")
    pr.add_argument("--n", type=_pos_int, default=500, help="held-out pairs per group")
    pr.add_argument("--k", type=_pos_int, default=5, help="neighbours RA-Touch reads")
    pr.add_argument("--why", action="store_true",
                    help="instead: evidence for why the shipped generator does (not) read its "
                         "neighbours, on its training pairs (F1 of copying them, the "
                         "integrator's gradient with own vs shuffled neighbours, losses)")
    pr.add_argument("--json", action="store_true")


def _add_judge_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--judge", choices=("offline", "llm"), default="offline")
    p.add_argument("--endpoint", help="OpenAI-compatible base URL for --judge llm "
                                      "(default $RATOUCH_JUDGE_ENDPOINT)")
    p.add_argument("--model", help="model for --judge llm (default $RATOUCH_JUDGE_MODEL or gpt-4)")
    p.add_argument("--api-key-env", default="RATOUCH_JUDGE_API_KEY",
                   help="environment variable holding the API key")


def _make_judge(args: argparse.Namespace):

    from ratouch.eval import judge as J

    if args.judge == "llm":
        return J.LLMJudge(J.LLMJudgeConfig.from_env(args.endpoint, args.model, args.api_key_env))
    return J.OfflineJudge()


def _add_judge(sub) -> None:
    j = sub.add_parser("judge", help="score TVL-format results with the offline or LLM judge")
    j.add_argument("file", nargs="*", help="TVL-format JSON list (label, generated response, ...); "
                                           "one system per file; several with --compare")
    j.add_argument("--out", help="scored JSON to write (the input plus offline_score/llm_score)")
    j.add_argument("--explain", action="store_true",
                   help="print, per answer, the words matched, clashed or ignored and their weights")
    j.add_argument("--compare", action="store_true",
                   help="agreement of the offline judge with the LLM judge (--endpoint) on FILE(s)")
    _add_judge_options(j)
    j.add_argument("--validate", action="store_true",
                   help="the offline judge's agreement with GPT-4 on held-out samples, on a "
                        "held-out system (leave one out) and under style shifts")
    j.add_argument("--length-effect", action="store_true",
                   help="a material oracle's score on the world's test split with 2/3/4/5 "
                        "adjectives (the judge's length effect)")
    j.add_argument("--fit", action="store_true",
                   help="refit the offline judge's calibration on the FIT part and write it")
    j.add_argument("--json", action="store_true", help="print JSON")


def _box(text: str) -> tuple[int, int, int, int]:
    parts = text.split(",")
    try:
        box = tuple(int(round(float(v))) for v in parts)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not x0,y0,x1,y1") from e
    if len(box) != 4:
        raise argparse.ArgumentTypeError(f"{text!r} must have 4 numbers: x0,y0,x1,y1")
    return box


def _id_list(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of "
                                         f"corpus ids") from e


def _add_query(sub) -> None:
    q = sub.add_parser("query", help="one RA-Touch query: neighbours, description, PCA, timings")
    q.add_argument("--vision", required=True, help="visual image file")
    q.add_argument("--tactile", default=None, help="tactile image file (optional)")
    q.add_argument("--background", default=None,
                   help="the tactile sensor's no-contact frame (optional; same size as the "
                        "tactile image), for the no-contact check")
    q.add_argument("--box", type=_box, default=None, help="contact box x0,y0,x1,y1 in pixels")
    q.add_argument("--k", type=_pos_int, default=5)
    q.add_argument("--label", default=None, help="ground-truth caption, if known (for the PCA)")
    q.add_argument("--encoder", default="default-s",
                   help="encoder set (default-tiny, default-s, default-b where trained), or "
                        "'cascade': the smallest confident one answers")
    q.add_argument("--corpus", default=None, help="corpus folder (default: the cached 10k)")
    q.add_argument("--index", choices=("flat", "hnsw", "ivfpq", "ivfflat"), default="flat",
                   help="the corpus's index kind to search (a large corpus built with "
                        "--index ivfflat|ivfpq loads that index memory-mapped)")
    q.add_argument("--json", action="store_true", help="print JSON (the default output)")
    q.add_argument("--drop", type=_id_list, default=None, metavar="IDS",
                   help="comma-separated corpus ids: regenerate the RA-Touch description "
                        "without these joint neighbours (printed under 'regenerated')")
    q.add_argument("--neighbours-from", default=None, metavar="FILE",
                   help="regenerate the RA-Touch description with other neighbours: a JSON "
                        "file holding another query's output (its joint neighbours are used) "
                        "or a list of corpus ids")


def _add_bench(sub) -> None:
    bench = sub.add_parser("bench", help="benchmarks that print measured figures")
    bsub = bench.add_subparsers(dest="bench_cmd", required=True)
    r = bsub.add_parser("retrieval", help="index latency / recall against the upstream method")
    r.add_argument("--n", type=_pos_int, default=150_000)
    r.add_argument("--dim", type=_pos_int, default=768)
    r.add_argument("--queries", type=_pos_int, default=200)
    r.add_argument("--scale", type=_nonneg_int, default=0,
                   help="also build/load/query an index of this many vectors (e.g. 1000000)")
    r.add_argument("--corpus", default=None,
                   help="instead of synthetic vectors: a built corpus's real embeddings, with "
                        "--queries of its entries held out as queries")
    r.add_argument("--encoder", default="default-s", help="with --corpus: whose embeddings")
    r.add_argument("--key", choices=("image", "text", "both"), default="both",
                   help="with --corpus: which key's embeddings are indexed")
    r.add_argument("--kinds", default="hnsw,ivfflat,ivfpq", help="with --corpus: index kinds")
    r.add_argument("--json", action="store_true")
    to = bsub.add_parser("tradeoff", help="latency against quality over index, corpus size, "
                                          "K and encoder; one chart with the frontier")
    to.add_argument("--out", default="docs", help="writes figures/tradeoff.* inside it")
    to.add_argument("--n", type=_pos_int, default=30, help="timed queries per point")
    to.add_argument("--sizes", default="1000,2500,10000", help="corpus subset sizes")
    to.add_argument("--ks", default="1,5,10", help="values of K")
    to.add_argument("--indexes", default="flat,hnsw,ivfpq")
    to.add_argument("--encoders", default="default-tiny,default-b",
                    help="other encoders, retrieval-only points ('' for none)")
    to.add_argument("--json", action="store_true")
    qb = bsub.add_parser("query", help="latency of the whole RA-Touch query, cold and warm")
    qb.add_argument("--encoder", default="default-s")
    qb.add_argument("--corpus", default=None)
    qb.add_argument("--n", type=_pos_int, default=60)
    qb.add_argument("--json", action="store_true")
    cb = bsub.add_parser("corpus", help="corpus build throughput per stage and peak memory, "
                                        "single process or on Ray")
    cb.add_argument("--engine", choices=("local", "ray"), default="ray")
    cb.add_argument("--n", type=_pos_int, default=2000)
    cb.add_argument("--workers", type=_pos_int, default=2,
                    help="render processes (local) or embedding actors (ray)")
    cb.add_argument("--encoder", default="default-s")
    cb.add_argument("--json", action="store_true")
    up = bsub.add_parser("upload", help="a huge tactile upload: its latency, where the time "
                                        "goes, and the delay of a normal query beside it")
    up.add_argument("--encoder", default="default-s")
    up.add_argument("--corpus", default=None)
    up.add_argument("--side", type=_pos_int, default=6000, help="side of the square PNG")
    up.add_argument("--repeats", type=_pos_int, default=3)
    w = bsub.add_parser("world", help="corpus + test split generation throughput")
    w.add_argument("--corpus-size", default="10k")
    w.add_argument("--workers", type=_pos_int, default=2)
    w.add_argument("--json", action="store_true")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ratouch", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="cmd", required=True)
    _add_world(sub)
    _add_corpus(sub)
    _add_train(sub)
    _add_query(sub)
    _add_eval(sub)
    _add_bench(sub)
    _add_judge(sub)
    app = sub.add_parser("app", help="launch the Gradio app")
    app.add_argument("--host", default="127.0.0.1")
    app.add_argument("--port", type=_pos_int, default=7860)
    return parser


def _run_world(args: argparse.Namespace) -> int:
    from ratouch.world.config import WorldConfig
    from ratouch.world.dataset import check_writable, write_split
    from ratouch.world.generator import TEST_SIZE, World
    from ratouch.world.preview import contact_sheet
    from ratouch.world.probe import ProbeConfig, format_probe, run_probe

    cfg = _world_cfg(args) if args.world_cmd != "probe" else None
    if args.world_cmd == "build":

        from ratouch.world.scarcity import ScarceRegime

        regime = ScarceRegime(regime=args.regime, seed=args.seed, draw=args.draw)
        counts = write_split(cfg, args.out, args.split, args.n, workers=args.workers,
                             regime=regime)
        print(json.dumps({"out": str(args.out), "split": args.split, **counts}))
    elif args.world_cmd == "preview":

        out = Path(args.out)
        if out.suffix.lower() != ".png":
            raise _usage(f"--out {out} must be a .png file")
        check_writable(out.parent)
        world = World(cfg)
        limit = TEST_SIZE if args.split == "test" else None
        idx = [args.start + k * args.stride for k in range(args.n)]
        if limit is not None:
            idx = [i % limit for i in idx]
        sheet = contact_sheet([world.sample(args.split, i) for i in idx], columns=args.columns)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(".partial.png")
        sheet.save(tmp)
        os.replace(tmp, out)
        print(f"wrote {out} ({len(idx)} samples, {sheet.size[0]}x{sheet.size[1]})")
    else:

        result = run_probe(WorldConfig(seed=args.seed),
                           ProbeConfig(n_train=args.n_train, n_test=args.n_test,
                                       workers=args.workers), progress=not args.json)
        print(json.dumps(result, indent=2) if args.json else format_probe(result))
    return 0


def _run_corpus(args: argparse.Namespace) -> int:

    from ratouch.corpus.imagenet_t import build_corpus
    from ratouch.corpus.recaption import RecaptionConfig
    from ratouch.serve.pipeline import embed_and_index

    rc = RecaptionConfig(backend=args.captioner, endpoint=args.endpoint, model=args.model)
    if args.engine == "ray":
        return _run_corpus_ray(args, rc)
    manifest = build_corpus(args.out, args.size, seed=args.seed, recaption=rc,
                            image_list=args.from_list)
    if not args.no_embed:

        manifest = {**manifest, **embed_and_index(args.out, args.encoder, args.index,
                                                  workers=args.workers)}
    print(json.dumps(manifest))
    return 0


def _run_corpus_ray(args: argparse.Namespace, rc) -> int:
    from ratouch.build.ray_corpus import RayOptions, build_corpus_ray

    if args.no_embed:
        raise _usage("--no-embed is not supported with --engine ray (it embeds as it goes)")
    opts = RayOptions(address=args.address, num_cpus=args.num_cpus, workers=args.workers,
                      batch_size=args.batch_size, shard_size=args.shard_size,
                      llm_concurrency=args.llm_concurrency, llm_rate=args.llm_rate)
    manifest = build_corpus_ray(args.out, args.size, seed=args.seed, recaption=rc,
                                image_list=args.from_list, encoder=args.encoder,
                                index=args.index, options=opts)
    print(json.dumps(manifest))
    return 0


def _run_train(args: argparse.Namespace) -> int:

    from ratouch.train import recipes

    if args.train_cmd == "retriever":
        report = recipes.retriever_recipe(args.encoder, args.seed, args.strategy,
                                          cross_residual=not args.paper_exact, epochs=args.epochs)
        print(json.dumps(report))
        return 0
    if args.train_cmd == "generator":
        overrides = {k: v for k, v in (("stage0_steps", args.stage0_steps),
                                       ("stage1_steps", args.stage1_steps),
                                       ("stage2_steps", args.stage2_steps)) if v}
        print(json.dumps(recipes.generator_recipe(args.encoder, args.seed, draw=args.draw,
                                                  out=args.out, **overrides)))
        return 0
    if args.train_cmd == "trust":
        return _train_trust(args)
    if args.train_cmd == "cascade":
        return _train_cascade(args)
    if args.train_cmd == "all":
        args.model, args.out, args.steps, args.threads = None, None, None, 2
        args.n_pairs, args.n_corpus = 12_000, 8_000
        return _train_all(args)
    return _train_encoders(args)


def _train_all(args: argparse.Namespace) -> int:
    """Every shipped weight, in dependency order, with the time each part took."""
    import shutil
    import time

    from ratouch.paths import generator_weights
    from ratouch.serve.pipeline import default_corpus
    from ratouch.train import recipes

    t0, times = time.perf_counter(), {}

    def lap(name: str) -> None:
        nonlocal t0
        times[name] = round(time.perf_counter() - t0, 1)
        t0 = time.perf_counter()

    _train_encoders(args)
    lap("encoders")
    for name in ("default-tiny", "default-s", "default-b"):
        default_corpus(name)  # re-embeds: the recorded encoder weights changed
    lap("corpus_embeddings")
    print(json.dumps(recipes.retriever_recipe(seed=args.seed)))
    lap("retriever")
    prior = generator_weights("default-s", "prior")
    if prior.is_dir():
        shutil.rmtree(prior)  # trained on the old encoders' text embeddings
    print(json.dumps(recipes.generator_recipe(seed=args.seed)))
    lap("generators")
    args.encoder, args.false_alarm, args.out = "default-s", 0.02, None
    _train_trust(args)
    lap("trust")
    print(json.dumps({"seconds": times, "total_s": round(sum(times.values()), 1)}))
    return 0


def _train_cascade(args: argparse.Namespace) -> int:
    from ratouch.paths import cascade_calibration
    from ratouch.serve.pipeline import RATouchPipeline
    from ratouch.threads import intra_op_threads
    from ratouch.train.cascade import CascadeConfig, calibrate_cascade

    names = [n.strip() for n in args.encoders.split(",") if n.strip()]
    if len(names) < 2:
        raise _usage(f"--encoders: a cascade needs two or more encoder sets, got {names}")
    with intra_op_threads(2):
        cal = calibrate_cascade([RATouchPipeline.load(n) for n in names],
                                CascadeConfig(seed=args.seed, n_validation=args.n))
    out = cal.save(args.out or cascade_calibration("+".join(names)))
    print(json.dumps({"written": str(out), "measure": cal.measure,
                      "thresholds": list(cal.thresholds), **cal.meta}, indent=1))
    return 0


def _train_trust(args: argparse.Namespace) -> int:

    from ratouch.encoders.factory import create_model
    from ratouch.paths import trust_calibration
    from ratouch.train.trust import TrustConfig, calibrate

    cal = calibrate(create_model(args.encoder),
                    TrustConfig(seed=args.seed, false_alarm=args.false_alarm))
    out = cal.save(args.out or trust_calibration(args.encoder))
    print(json.dumps({"written": str(out), "contact_threshold": cal.contact_threshold,
                      "contact_threshold_bg": cal.contact_threshold_bg,
                      "visual_threshold": cal.visual.threshold,
                      "tactile_threshold": cal.tactile.threshold, **cal.meta}, indent=1))
    return 0


def _train_encoders(args: argparse.Namespace) -> int:

    from ratouch.encoders.factory import shipped_weights
    from ratouch.train.encoders import STEPS, TrainConfig, train_encoders

    models = args.model or ["default-tiny", "default-s", "default-b"]
    shared: dict = {}  # rendered data, shared by models with the same input sizes
    for name in models:
        out = Path(args.out) / name if args.out else shipped_weights(name)
        tc = TrainConfig(model=name, seed=args.seed, steps=args.steps or STEPS.get(name, 300),
                         n_pairs=args.n_pairs, n_corpus=args.n_corpus, threads=args.threads)
        _, report = train_encoders(tc, out=str(out), cache=shared)
        print(json.dumps({"out": str(out), **report}))
    return 0


def _run_query(args: argparse.Namespace) -> int:
    from ratouch.threads import intra_op_threads

    for role, path in (("visual image", args.vision), ("tactile image", args.tactile),
                       ("background image", args.background)):
        if path is not None and not Path(path).is_file():
            raise _usage(f"{role} file {path} does not exist")
    swap = _neighbours_file(args.neighbours_from) if args.neighbours_from else None
    with intra_op_threads(1):  # the serving setting (see ratouch.threads)
        return _query(args, swap)


def _query(args: argparse.Namespace, swap: list[int] | None) -> int:
    from ratouch.serve.models import load_model

    pipe = load_model(args.encoder, corpus=args.corpus, index=args.index)
    result = pipe.query(args.vision, args.tactile, box=args.box, k=args.k, label=args.label,
                        background=args.background)
    if args.drop is not None or swap is not None:
        ids = swap if swap is not None else [n["id"] for n in result["neighbours"]["joint"]]
        drop = set(args.drop or ())
        if drop - set(ids):
            raise _usage(f"--drop: {sorted(drop - set(ids))} are not among the neighbours {ids}")
        ids = [i for i in ids if i not in drop]
        result["regenerated"] = pipe.regenerate(args.vision, args.tactile, ids, box=args.box)
    print(json.dumps(result, indent=1))
    return 0


def _neighbours_file(path: str) -> list[int]:
    """Corpus ids from --neighbours-from: a query's JSON output (its joint neighbours, or a
    regenerated set's) or a JSON list of ids."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise _usage(f"--neighbours-from {path}: not a readable JSON file ({e})") from e
    if isinstance(data, dict):
        data = data.get("regenerated", data)
        nb = data.get("neighbours") if isinstance(data, dict) else None
        if isinstance(nb, dict):  # a query's output: {"image"|"tactile"|"joint": [...]}
            nb = nb.get("joint")
        data = [n.get("id") if isinstance(n, dict) else n for n in nb] \
            if isinstance(nb, list) else None
    if not isinstance(data, list) or not all(isinstance(i, int) and not isinstance(i, bool)
                                             for i in data):
        raise _usage(f"--neighbours-from {path}: expected a query's JSON output or a list of "
                     f"corpus ids")
    return data


def _run_eval(args: argparse.Namespace) -> int:
    from ratouch.eval.retrieval import evaluate_retrieval, format_retrieval_eval
    from ratouch.serve.pipeline import RATouchPipeline, default_corpus, open_retriever
    from ratouch.world.config import WorldConfig

    if args.eval_cmd == "tvl":
        return _eval_tvl(args)
    if args.eval_cmd in _experiment_names():
        return _eval_experiments(args)
    if args.eval_cmd == "ttest":
        return _eval_ttest(args)
    if args.eval_cmd == "stress":
        return _eval_stress(args)
    if args.eval_cmd == "controls":
        return _eval_controls(args)
    if args.eval_cmd == "premise":
        return _eval_premise(args)

    corpus = args.corpus or default_corpus(args.encoder)
    if (retriever_weights(args.encoder) / "manifest.json").is_file():
        p = RATouchPipeline.load(args.encoder, corpus, args.index, generators=False)
        retriever, joint_fn = p.retriever, p.joint_query
    else:
        retriever, joint_fn = open_retriever(corpus, args.encoder, args.index), None
    r = evaluate_retrieval(retriever, WorldConfig(seed=args.seed), joint_fn=joint_fn)
    print(json.dumps(r, indent=1) if args.json else format_retrieval_eval(r))
    return 0


def _eval_premise(args: argparse.Namespace) -> int:
    from ratouch.eval.premise import format_premise, run_premise, why_ignored

    if args.why:
        print(json.dumps(why_ignored(args.encoder), indent=1))
        return 0
    say = (lambda m: print(m, file=sys.stderr)) if args.json else print
    r = run_premise(args.encoder, runs=args.runs, n=args.n, k=args.k, report=say)
    print(json.dumps(r, indent=1) if args.json else format_premise(r))
    return 0


def _eval_controls(args: argparse.Namespace) -> int:
    from ratouch.eval.controls import format_controls, run_controls
    from ratouch.serve.pipeline import RATouchPipeline

    r = run_controls(RATouchPipeline.load(args.encoder), k=args.k, shuffles=args.shuffles,
                     seed=args.seed)
    print(json.dumps(r, indent=1) if args.json else format_controls(r))
    return 0


def _eval_tvl(args: argparse.Namespace) -> int:

    from ratouch.eval.judge import format_summary
    from ratouch.eval.tvl import run_tvl
    from ratouch.serve.pipeline import RATouchPipeline

    judge = _make_judge(args)  # configuration errors before any work
    pipeline = RATouchPipeline.load(args.encoder)
    records, summary = run_tvl(pipeline, args.system, args.k, judge, _world_cfg(args))
    write_json_atomic(args.out, records)
    if args.json:
        print(json.dumps({**summary, "out": str(args.out)}, indent=1))
        return 0
    print(f"{args.system} on the world's test split (seed {args.seed}, K={args.k}):")
    print(format_summary(summary))
    print(f"wrote {args.out}")
    return 0


def _eval_stress(args: argparse.Namespace) -> int:

    from ratouch.eval import stress as S
    from ratouch.serve.pipeline import RATouchPipeline
    from ratouch.world.config import WorldConfig
    from ratouch.world.dataset import check_writable

    knobs = [k.strip() for k in args.knobs.split(",") if k.strip()] if args.knobs else None
    sweeps = S.build_sweeps(knobs, S.parse_values(args.values))  # checked before any work
    if not 0 < args.drop < 1:
        raise _usage(f"--drop {args.drop} must lie in (0, 1)")
    S.stratified_indices(args.n or S.DEFAULT_N)
    check_writable(Path(args.out))
    pipeline = RATouchPipeline.load(args.encoder)
    result = S.run_stress(pipeline, sweeps, k=args.k, n=args.n or S.DEFAULT_N,
                          world=WorldConfig(seed=args.seed), collapse=not args.no_collapse,
                          collapse_epochs=args.collapse_epochs, encoder=args.encoder,
                          drop=args.drop, progress=lambda line: print(line, file=sys.stderr,
                                                                      flush=True))
    paths = S.write_report(result, args.out)
    if args.json:
        print(json.dumps({**result, "files": paths}, indent=1))
        return 0
    print(S.format_table(result))
    print(f"wrote {', '.join(paths.values())}")
    return 0


def _experiment_names() -> set[str]:
    return set(EXPERIMENT_HELP) | {"all"}


def _eval_experiments(args: argparse.Namespace) -> int:
    import time

    from ratouch.eval.experiments import (
        EXPERIMENTS,
        ExperimentConfig,
        Lab,
        results_markdown,
        run_experiments,
    )


    cfg = ExperimentConfig(encoder=args.encoder, steps=args.steps, seed=args.seed,
                           workers=args.workers)
    names = list(EXPERIMENTS) if args.eval_cmd == "all" else [args.eval_cmd]
    t0 = time.perf_counter()
    lab = Lab(cfg)
    reports = run_experiments(names, cfg, args.out, lab)
    out = Path(args.out)
    doc = out / ("results.md" if args.eval_cmd == "all" else f"{args.eval_cmd}.md")
    doc.write_text(results_markdown(reports, cfg, time.perf_counter() - t0,
                                    out=out if args.eval_cmd == "all" else None,
                                    counts=lab.counts),
                   encoding="utf-8")
    for rep in reports:
        print(f"## {rep.title}  ({rep.seconds:.0f} s)\n\n{rep.markdown}\n")
    print(f"wrote {doc} and its figures in {out / 'figures'}")
    return 0


def _csv(text: str, conv=str) -> list:
    try:
        return [conv(x) for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise _usage(f"{text!r}: {e}") from e


def _bench_tradeoff(args: argparse.Namespace) -> int:

    from ratouch.bench.tradeoff import bench_tradeoff, format_tradeoff, tradeoff_figure
    from ratouch.eval.experiments import Report, write_report

    bad = set(_csv(args.indexes)) - {"flat", "hnsw", "ivfpq"}
    if bad:
        raise _usage(f"--indexes: unknown index type(s) {sorted(bad)}; use flat, hnsw, ivfpq")
    r = bench_tradeoff(indexes=_csv(args.indexes), sizes=_csv(args.sizes, int),
                       ks=_csv(args.ks, int), other_encoders=_csv(args.encoders),
                       n_latency=args.n, progress=None if args.json else print)
    table = format_tradeoff(r)
    write_report(Report("tradeoff", "Speed against accuracy", f"```\n{table}\n```\n\n"
                        f"Settings: `{json.dumps(r['settings'])}`", tradeoff_figure(r), r),
                 Path(args.out) / "figures")
    print(json.dumps(r, indent=1) if args.json else table)
    return 0


def _eval_ttest(args: argparse.Namespace) -> int:

    from ratouch.eval.judge import read_records
    from ratouch.eval.tvl import format_ttest, paired_ttest

    r = paired_ttest(read_records(args.a), read_records(args.b))
    print(json.dumps(r, indent=1) if args.json else format_ttest(r, args.a, args.b))
    return 0


def _run_bench(args: argparse.Namespace) -> int:

    from ratouch.bench.index import (bench_corpus_index, bench_retrieval, bench_scale,
                                     format_bench, format_real)
    from ratouch.bench.query import bench_query, bench_world
    from ratouch.corpus.imagenet_t import parse_size

    if args.bench_cmd == "tradeoff":
        return _bench_tradeoff(args)
    if args.bench_cmd == "corpus":
        from ratouch.bench.corpus import bench_corpus, format_corpus_bench

        r = bench_corpus(args.engine, args.n, args.workers, args.encoder)
        print(json.dumps(r) if args.json else format_corpus_bench(r))
        return 0
    if args.bench_cmd == "query":

        from ratouch.threads import intra_op_threads

        with intra_op_threads(1):  # as `ratouch query` and the app serve (ratouch.threads)
            r = bench_query(args.encoder, args.corpus, n=args.n)
        print(json.dumps(r, indent=None if args.json else 1))
        return 0
    if args.bench_cmd == "upload":
        from ratouch.bench.upload import bench_upload

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


def _check_judge_args(args: argparse.Namespace) -> None:
    files = args.file
    if not (files or args.validate or args.fit or args.length_effect):
        raise _usage("judge needs FILE --out SCORED.json, FILE --explain, FILE --compare, "
                     "--validate or --fit")
    if (args.explain or args.compare) and not files:
        raise _usage("--explain and --compare need an input FILE")
    if len(files) > 1 and not args.compare:
        raise _usage(f"{len(files)} files given; only --compare takes several")
    if files and not (args.out or args.explain or args.compare):
        raise _usage("judge FILE needs --out SCORED.json (or --explain / --compare)")
    if args.out and (not files or args.compare):
        raise _usage("--out needs exactly one input FILE (and no --compare)")


def _run_judge(args: argparse.Namespace) -> int:

    from ratouch.eval import judge as J

    _check_judge_args(args)
    report: dict = {}
    llm = (J.LLMJudge(J.LLMJudgeConfig.from_env(args.endpoint, args.model, args.api_key_env))
           if args.compare else None)  # configuration errors before any work
    judge = _make_judge(args) if args.out else None
    records = {f: J.read_records(f) for f in args.file}  # checked before anything is written
    if args.fit:
        report["fit"] = str(J.write_offline_config(J.fit_offline_judge()))
    scored = None
    if args.out:
        scored, report["results"] = J.judge_results(records[args.file[0]], judge)
    if args.explain:
        report["explain"] = {f: J.explain_results(r) for f, r in records.items()}
    if llm is not None:
        report["compare"] = J.compare_judges(records, llm)
    if args.validate:
        report["validation"] = J.validate_judge()
    if args.length_effect:
        from ratouch.eval.tvl import oracle_length_effect  # imports torch and the world

        report["length_effect"] = oracle_length_effect()
    if scored is not None:
        write_json_atomic(args.out, scored)
        report["out"] = str(args.out)
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        _print_judge_report(J, args, report)
    return 0


def _print_judge_report(J, args: argparse.Namespace, report: dict) -> None:
    if "fit" in report:
        print(f"wrote the offline judge calibration to {report['fit']}")
    if "results" in report:
        r = report["results"]
        print(f"{r['judge']} judge on {args.file[0]}: {r['n']} responses, {r['n_failed']} failed "
              f"(scored 1)")
        print(J.format_summary(r))
        print(f"wrote {args.out}")
    for name, explained in report.get("explain", {}).items():
        print(f"offline judge on {name}, answer by answer:")
        print(J.format_explain(explained))
    if "compare" in report:
        print("offline judge vs LLM judge:")
        print(J.format_compare(report["compare"]))
    if "validation" in report:
        print(J.format_validation(report["validation"]))
    if "length_effect" in report:
        le = report["length_effect"]
        print("material oracle on the world's test split (the n heaviest profile words):")
        for n, s in le["stats"].items():
            print(f"  {n} adjectives: {J.format_stats(s)}")
        print(f"  spread {le['spread']:.3f}")


def _run_app(args: argparse.Namespace) -> int:
    app_file = APP_FILE
    if not app_file.is_file():
        raise _usage(f"the app is not found at {app_file} (run from a checkout of the repo)")
    os.execv(sys.executable, [sys.executable, str(app_file), "--host", args.host,
                              "--port", str(args.port)])
    return 0  # not reached


class _UsageError(RATouchError):
    pass


def _usage(msg: str) -> _UsageError:
    return _UsageError(msg)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point. Returns the exit code (0 ok, 2 user error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    runners = {"world": _run_world, "corpus": _run_corpus, "train": _run_train,
               "query": _run_query, "eval": _run_eval, "bench": _run_bench, "app": _run_app,
               "judge": _run_judge}
    try:
        return runners[args.cmd](args)
    except (RATouchError, OSError) as e:
        print(f"ratouch: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ratouch: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

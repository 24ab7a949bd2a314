"""`ratouch eval`: retrieval quality, the TVL protocol, the paired t-test, the stress sweep, the
neighbour controls, the premise and the visible real photos. (The paper's experiments:
`ratouch.cli.experiments`.)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ratouch.cli.common import usage, world_cfg
from ratouch.cli.judge import make_judge
from ratouch.encoders.factory import create_model
from ratouch.errors import DataNotFoundError
from ratouch.eval import stress as S
from ratouch.eval.controls import format_controls, run_controls
from ratouch.eval.frames import (
    digit_frames,
    format_frames,
    frames_in,
    height_sheet,
    read_frames,
    summarise,
    taxim_frames,
)
from ratouch.eval.judge import OfflineJudge, format_stats, format_summary, read_records
from ratouch.eval.photos import (
    evaluate_photos,
    evaluate_real_pairs,
    evaluate_reference_tactile,
    format_photos,
    format_real_pairs,
    format_reference_tactile,
    reference_dir,
)
from ratouch.eval.premise import format_premise, run_premise, why_ignored
from ratouch.eval.presses import (
    cross_unit_contact,
    format_cross_unit_contact,
    format_press_contact,
    format_press_probe,
    format_press_readings,
    format_world_contact,
    press_contact,
    press_probe,
    press_readings,
    world_contact,
)
from ratouch.eval.recaption import format_recaption_agreement, recaption_agreement
from ratouch.eval.report import measured_stamp
from ratouch.eval.retrieval import evaluate_retrieval, format_retrieval_eval
from ratouch.eval.sensor_families import evaluate_families, format_families
from ratouch.eval.sensors import compare_sensors, format_sensors
from ratouch.eval.tvl import format_ttest, paired_ttest, run_tvl
from ratouch.files import write_json_atomic
from ratouch.paths import retriever_weights
from ratouch.search.retrieval_side import default_corpus, open_retriever
from ratouch.serve.models import language_models
from ratouch.serve.pipeline import RATouchPipeline, load_trust
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import check_writable
from ratouch.world.splits import VALIDATION_SIZE, VALIDATION_START, encode_validation_split
from ratouch.world.taxim_optics import CALIBRATIONS


def run(args: argparse.Namespace) -> int:
    if args.eval_cmd == "tvl":
        return _eval_tvl(args)
    if args.eval_cmd == "recaption":
        names = [x.strip() for x in args.recaptioners.split(",") if x.strip()]
        r = recaption_agreement(names, n=args.n, seed=args.seed)
        print(json.dumps(r, indent=1) if args.json else format_recaption_agreement(r))
        return 0
    if args.eval_cmd == "ttest":
        return _eval_ttest(args)
    if args.eval_cmd == "stress":
        return _eval_stress(args)
    if args.eval_cmd == "controls":
        return _eval_controls(args)
    if args.eval_cmd == "premise":
        return _eval_premise(args)
    if args.eval_cmd == "photos":
        return _eval_photos(args)
    if args.eval_cmd == "frames":
        return _eval_frames(args)
    if args.eval_cmd == "presses":
        return _eval_presses(args)
    if args.eval_cmd == "sensors":
        r = compare_sensors(n=args.n)
        print(json.dumps(r, indent=1) if args.json else format_sensors(r))
        return 0
    if args.eval_cmd == "families":
        r = evaluate_families(RATouchPipeline.load(args.encoder, generators=False), n=args.n,
                              seed=args.seed)
        print(json.dumps(r, indent=1) if args.json else format_families(r))
        return 0

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
    if args.why:
        print(json.dumps(why_ignored(args.encoder), indent=1))
        return 0
    say = (lambda m: print(m, file=sys.stderr)) if args.json else print
    _check_lm(args)  # run_premise refuses --runs above 1 on an LM before loading anything
    r = run_premise(args.encoder, runs=args.runs, n=args.n, k=args.k, progress=say,
                    arm=not args.no_arm, arms=args.arms, lm=args.lm)
    print(json.dumps(r, indent=1) if args.json else format_premise(r))
    return 0


def _eval_presses(args: argparse.Namespace) -> int:
    trust = load_trust(args.encoder)
    if trust is None:
        raise DataNotFoundError(f"no trust calibration for {args.encoder}")
    hw = (96, 128) if args.landscape else (128, 96)
    rep = press_contact(trust, n=args.n, blanks=args.blanks, seed=args.seed, hw=hw)
    readings = None
    if args.readings:
        readings = press_readings(RATouchPipeline.load(args.encoder), OfflineJudge(),
                                  n=args.readings, seed=args.seed + 1)
    probe = None
    if args.probe:
        probe = press_probe(create_model(args.encoder), trust, n=args.probe, seed=args.seed + 3)
    world = world_contact(trust, n=args.world) if args.world else None
    cross = (cross_unit_contact(trust, n=args.cross_unit, seed=args.seed, hw=hw)
             if args.cross_unit else None)
    if args.json:
        extra = {**({"readings": readings} if readings else {}),
                 **({"probe": probe} if probe else {}),
                 **({"world": world} if world else {}),
                 **({"cross_unit": cross} if cross else {})}
        print(json.dumps({**rep, **extra}, indent=1))
        return 0
    print(format_press_contact(rep))
    if world:
        print()
        print(format_world_contact(world))
    if cross:
        print()
        print(format_cross_unit_contact(cross))
    if readings:
        print()
        print(format_press_readings(readings))
    if probe:
        print()
        print(format_press_probe(probe))
    return 0


def _eval_frames(args: argparse.Namespace) -> int:
    if (args.folder is None) == (not args.real):
        raise usage("ratouch eval frames: give a folder of frames, or --real (not both)")
    if args.alone and not args.real:
        raise usage("ratouch eval frames: --alone reads Taxim's presses: give --real")
    if args.real:
        frames = [f for name in CALIBRATIONS for f in taxim_frames(name, args.alone)]
        frames += digit_frames(reference_dir())
    else:
        frames = frames_in(args.folder, args.background)
    t0 = time.perf_counter()
    stamp = measured_stamp()  # the code read with, before anything is written
    pipeline = RATouchPipeline.load(args.encoder, args.corpus)
    rows = read_frames(pipeline, frames, k=args.k)
    if args.json:  # with its provenance: the app's Benchmarks tab dates a stored check by it
        command = " ".join(["ratouch eval frames", "--real" if args.real else str(args.folder)]
                           + (["--alone"] if args.alone else [])
                           + [f"--{n} {getattr(args, n)}" for n in ("background", "corpus")
                              if getattr(args, n)]
                           + [f"--encoder {args.encoder}", f"--k {args.k}", "--json"])
        print(json.dumps({**stamp, "command": command, "encoder": args.encoder,
                          "corpus": str(args.corpus) if args.corpus else None,
                          "seconds": round(time.perf_counter() - t0, 1),
                          "frames": rows, "summary": summarise(rows)}, indent=1))
    else:
        print(format_frames(rows))
    if args.sheet:
        print(f"height maps: {height_sheet(pipeline.trust, frames, args.sheet)}",
              file=sys.stderr)
    return 0


def _eval_photos(args: argparse.Namespace) -> int:
    pipeline = RATouchPipeline.load(args.encoder)
    if args.pairs:
        rows = evaluate_real_pairs(pipeline, k=args.k)
        print(json.dumps(rows, indent=1) if args.json else format_real_pairs(rows))
        return 0
    photos = evaluate_photos(pipeline, k=args.k)
    tactile = evaluate_reference_tactile(pipeline, k=args.k)
    if args.json:
        print(json.dumps({"photos": photos, "reference_tactile": tactile}, indent=1))
        return 0
    print(f"The visible real photos through {args.encoder} (for looking: no thresholds are "
          f"set on them)\n")
    print(format_photos(photos))
    print()
    print(format_reference_tactile(tactile))
    return 0


def _check_lm(args: argparse.Namespace) -> None:
    """`--lm`, when given, names a language model the encoder set has generators on."""
    lms = language_models(args.encoder)
    if args.lm is not None and args.lm not in lms:
        raise usage(f"--lm {args.lm!r}: no generators of {args.encoder} on it (trained: "
                    f"{', '.join(lms) or 'none'}; `ratouch train generator --lm`)")


def _pipeline_on_lm(args: argparse.Namespace) -> RATouchPipeline:
    """The encoder set's pipeline, on the generators of `--lm` when given (checked first)."""
    _check_lm(args)
    return RATouchPipeline.load(args.encoder, lm=args.lm)


def _eval_controls(args: argparse.Namespace) -> int:
    r = run_controls(_pipeline_on_lm(args), k=args.k, shuffles=args.shuffles,
                     seed=args.seed)
    print(json.dumps(r, indent=1) if args.json else format_controls(r))
    return 0


def _eval_tvl(args: argparse.Namespace) -> int:
    judge = make_judge(args)  # configuration errors before any work
    pipeline = _pipeline_on_lm(args)
    world = world_cfg(args)
    split = encode_validation_split(pipeline.encoders, world) if args.validation else None
    records, summary = run_tvl(pipeline, args.system, args.k, judge, world, split=split,
                               retrieval=args.retrieval)
    summary["split"] = "validation" if args.validation else "test"
    write_json_atomic(args.out, records)
    if args.json:
        print(json.dumps({**summary, "out": str(args.out)}, indent=1))
        return 0
    end = VALIDATION_START + VALIDATION_SIZE
    where = (f"{VALIDATION_SIZE} validation pairs (train[{VALIDATION_START}:{end}])"
             if args.validation else "the world's test split")
    print(f"{args.system} of {pipeline.name} on {where} (seed {args.seed}, "
          f"K={args.k}, retrieval {args.retrieval}):")
    print(format_summary(summary))
    if summary["families"]:
        print("per sensor family:")
    for family, stats in summary["families"].items():
        print(f"  {family:<9}{stats['n']:>5}  {format_stats(stats)}")
    print(f"wrote {args.out}")
    return 0


def _eval_stress(args: argparse.Namespace) -> int:
    knobs = [k.strip() for k in args.knobs.split(",") if k.strip()] if args.knobs else None
    sweeps = S.build_sweeps(knobs, S.parse_values(args.values))  # checked before any work
    if not 0 < args.drop < 1:
        raise usage(f"--drop {args.drop} must lie in (0, 1)")
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


def _eval_ttest(args: argparse.Namespace) -> int:
    r = paired_ttest(read_records(args.a), read_records(args.b))
    print(json.dumps(r, indent=1) if args.json else format_ttest(r, args.a, args.b))
    return 0

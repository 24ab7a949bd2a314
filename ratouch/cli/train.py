"""`ratouch train`: the default encoders, the retriever, the generators, the trust signals and
the cascade, or all of them in order.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ratouch.cli.common import usage
from ratouch.encoders.factory import DEFAULT_SETS, create_model, shipped_weights
from ratouch.model.geometry import GeometryCalibration
from ratouch.model.pretrained_lm import PRETRAINED_LMS
from ratouch.model.trust import TrustCalibration
from ratouch.paths import (
    cascade_calibration,
    generator_weights,
    geometry_calibration,
    trust_calibration,
)
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.ship import retrain
from ratouch.ship.cascade import CascadeConfig, calibrate_cascade
from ratouch.threads import intra_op_threads
from ratouch.train import recipes
from ratouch.train.encoders import STEPS, TrainConfig, train_encoders
from ratouch.train.gate import format_gate_report, gate_recipe
from ratouch.train.geometry import calibrate as calibrate_geometry
from ratouch.train.geometry import with_family_floors, with_firmness, with_unfamiliar_floors
from ratouch.train.press_map import PressMapConfig, press_map_recipe
from ratouch.train.trust import TrustConfig, calibrate, with_alone_band, with_unfamiliar_contact


def run(args: argparse.Namespace) -> int:
    if args.train_cmd == "retriever":
        report = recipes.retriever_recipe(args.encoder, args.seed, args.strategy,
                                          cross_residual=not args.paper_exact, epochs=args.epochs)
        print(json.dumps(report))
        return 0
    if args.train_cmd == "generator":
        overrides = {k: v for k, v in (("stage0_steps", args.stage0_steps),
                                       ("stage1_steps", args.stage1_steps),
                                       ("stage2_steps", args.stage2_steps)) if v}
        if args.lm is not None:
            if args.lm not in PRETRAINED_LMS and not (Path(args.lm) / "config.json").is_file():
                raise usage(f"--lm {args.lm!r}: one of {', '.join(PRETRAINED_LMS)} or a local "
                            "HF-format LLaMA folder (with its config.json)")
            if args.draw or "stage0_steps" in overrides:
                raise usage("--lm adapts a pretrained model on draw 0 with no language prior "
                            "(stage 0): --draw and --stage0-steps do not apply")
            out = None if args.out is None else Path(args.out)
            print(json.dumps(recipes.pretrained_generator_recipe(
                args.encoder, args.lm, args.seed, out=out, **overrides)))
            return 0
        print(json.dumps(recipes.generator_recipe(args.encoder, args.seed, draw=args.draw,
                                                  out=args.out, **overrides)))
        return 0
    if args.train_cmd == "trust":
        return _train_trust(args)
    if args.train_cmd == "cascade":
        return _train_cascade(args)
    if args.train_cmd == "geometry":
        return _train_geometry(args)
    if args.train_cmd == "press-map":
        cfg = PressMapConfig(fit_per_kind=args.fit, world=args.world, balls=args.balls,
                             eval_per_kind=args.eval, world_eval=args.world_eval,
                             balls_eval=args.balls_eval, steps=args.steps, seed=args.seed,
                             router_balls=args.router_balls)
        with intra_op_threads(2):
            rep = press_map_recipe(args.encoder, cfg, args.out, args.router_only)
        print(json.dumps(rep, indent=1))
        return 0
    if args.train_cmd == "gate":
        if args.n < 20:
            raise usage(f"--n {args.n}: the gate needs at least 20 probe pairs")
        with intra_op_threads(2):
            rep = gate_recipe(args.encoder, args.seed, args.n, args.out)
        print(format_gate_report(rep))
        print(json.dumps({k: v for k, v in rep.items() if k != "by_variant"}))
        return 0
    if args.train_cmd in ("reader", "text"):  # stage 2 again from the shipped stage 1
        extra: dict[str, Any] = ({"arm": args.arm or recipes.READER_ARM}
                                 if args.train_cmd == "reader" else {})
        recipe = (recipes.reader_recipe if args.train_cmd == "reader"
                  else recipes.text_arm_recipe)
        with intra_op_threads(2):
            _, rep = recipe(
                args.encoder, generator_weights(args.encoder, "ra"), seed=args.seed,
                out=args.out or generator_weights(args.encoder, args.train_cmd), **extra,
                **({"stage2_steps": args.steps} if args.steps else {}))
        print(json.dumps({k: v for k, v in rep.items() if k != "history"}))
        return 0
    if args.train_cmd == "all":
        args.model, args.out, args.steps, args.threads = None, None, None, 2
        args.n_pairs, args.n_corpus = 12_000, 8_000
        return _train_all(args)
    return _train_encoders(args)


def _train_all(args: argparse.Namespace) -> int:
    """Every shipped weight, in dependency order (`retrain.train_all`), with the time each
    part took."""
    with intra_op_threads(2):
        out = retrain.train_all(seed=args.seed, report=lambda r: print(json.dumps(r, default=str)))
    print(json.dumps(out))
    return 0


def _train_cascade(args: argparse.Namespace) -> int:
    names = [n.strip() for n in args.encoders.split(",") if n.strip()]
    if len(names) < 2:
        raise usage(f"--encoders: a cascade needs two or more encoder sets, got {names}")
    with intra_op_threads(2):
        cal = calibrate_cascade([RATouchPipeline.load(n) for n in names],
                                CascadeConfig(seed=args.seed, n_validation=args.n))
    out = cal.save(args.out or cascade_calibration("+".join(names)))
    print(json.dumps({"written": str(out), "measure": cal.measure,
                      "thresholds": list(cal.thresholds), **cal.meta}, indent=1))
    return 0


def _train_geometry(args: argparse.Namespace) -> int:
    if sum(map(bool, (args.firmness_only, args.unfamiliar_floors, args.floors_only))) > 1:
        raise usage("--firmness-only, --unfamiliar-floors and --floors-only each refit one "
                    "part of the stored calibration: give one of them")
    if args.floors_only:
        path = args.out or geometry_calibration()
        cal = with_family_floors(GeometryCalibration.load(path), args.seed, args.pairs)
        out = cal.save(path)
        print(json.dumps({"written": str(out), "floors": {
            k: {"threshold": lk.structure_threshold, "noise_ref": lk.noise_ref,
                **({"field_threshold": lk.field_threshold,
                    "field_noise_ref": lk.field_noise_ref} if lk.field_floors else {})}
            for k, lk in cal.lookups.items()}}, indent=1))
        return 0
    if args.unfamiliar_floors:
        path = args.out or geometry_calibration()
        cal = with_unfamiliar_floors(GeometryCalibration.load(path), args.seed, args.pairs)
        out = cal.save(path)
        print(json.dumps({"written": str(out), "unfamiliar_floors": {
            k: {"threshold": lk.unfamiliar_threshold,
                "floors_on": lk.meta.get("unfamiliar_floors_on")}
            for k, lk in cal.lookups.items()}}, indent=1))
        return 0
    if args.firmness_only:
        path = args.out or geometry_calibration()
        cal, fits = with_firmness(GeometryCalibration.load(path), args.seed,
                                  args.firmness_per_kind, args.firmness_world)
        out = cal.save(path)
        print(json.dumps({"written": str(out), "firmness": fits}, indent=1))
        return 0
    cal, held_out = calibrate_geometry(args.seed, samples=args.samples, pairs=args.pairs,
                                       per_kind=args.firmness_per_kind,
                                       world=args.firmness_world)
    out = cal.save(args.out or geometry_calibration())
    print(json.dumps({"written": str(out), "held_out": {
        k: {m: v for m, v in r.items() if m != "presses"} for k, r in held_out.items()},
        "thresholds": {k: lk.structure_threshold for k, lk in cal.lookups.items()}}, indent=1))
    return 0


def _train_trust(args: argparse.Namespace) -> int:
    if args.alone_band and args.unfamiliar:
        raise usage("--alone-band and --unfamiliar each refit one part of the stored "
                    "calibration: give one of them")
    if args.unfamiliar:
        path = trust_calibration(args.encoder)
        cal = with_unfamiliar_contact(TrustCalibration.load(path), seed=args.seed,
                                      false_alarm=args.false_alarm)
        out = cal.save(args.out or path)
        print(json.dumps({"written": str(out),
                          "unfamiliar_contact": cal.meta["unfamiliar_contact"]}, indent=1))
        return 0
    if args.alone_band:
        path = trust_calibration(args.encoder)
        cal = with_alone_band(TrustCalibration.load(path), seed=args.seed)
        out = cal.save(args.out or path)
        print(json.dumps({"written": str(out), "uncertain_alone": cal.uncertain_alone,
                          "press_alone": sorted(cal.press_alone or {}),
                          "contact_threshold": cal.contact_threshold,
                          "alone_band": cal.meta["alone_band"]}, indent=1))
        return 0
    cal = calibrate(create_model(args.encoder),
                    TrustConfig(seed=args.seed, false_alarm=args.false_alarm))
    out = cal.save(args.out or trust_calibration(args.encoder))
    print(json.dumps({"written": str(out), "contact_threshold": cal.contact_threshold,
                      "contact_threshold_bg": cal.contact_threshold_bg,
                      "visual_threshold": cal.visual.threshold,
                      "tactile_threshold": cal.tactile.threshold, **cal.meta}, indent=1))
    return 0


def _train_encoders(args: argparse.Namespace) -> int:
    models = args.model or list(DEFAULT_SETS)
    shared: dict = {}  # rendered data, shared by models with the same input sizes
    for name in models:
        out = Path(args.out) / name if args.out else shipped_weights(name)
        tc = TrainConfig(model=name, seed=args.seed, steps=args.steps or STEPS.get(name, 300),
                         n_pairs=args.n_pairs, n_corpus=args.n_corpus, threads=args.threads,
                         device=args.device)
        _, report = train_encoders(tc, out=str(out), cache=shared)
        print(json.dumps({"out": str(out), **report}))
    return 0

"""Does the firmness read from shape hold on the world's own frames? The check of
docs/geometry.md, "Firmness from shape on the world's own frames" (criteria fixed before the
first run).

A geometry calibration's firmness models (the shipped one, and `--after F`, a calibration with
the same lookups whose firmness models were refitted: `ratouch train geometry --firmness-only
--out F`) read, on the same renders:

1. the world's validation renders with contact (`train[1000000:]`, 200 a family; another
   start with --world-start) against their unit's background;
2. fresh everyday presses (`ratouch.world.presses`, every kind, 30 a kind a family, a stream
   no fit draws from; another with --everyday-seed);
3. Taxim's real ball presses against their backgrounds (how many read soft);
4. the world's test split (402 pairs; measured only, never a criterion).

Each: balanced accuracy (the mean of the soft and the hard recall; soft: compliance >= 0.5).

    python scripts/why_world_firmness.py [--after F] [--per-kind 30] [--world 200] [--test 402]
                                         [--world-start I] [--everyday-seed S] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ratouch.eval.presses import balanced_accuracy
from ratouch.model.geometry import GeometryCalibration, press_shape
from ratouch.paths import geometry_calibration
from ratouch.train.geometry import shape_renders, world_shape_renders
from ratouch.train.trust import VALIDATION_START
from ratouch.world.sampler import TEST_SIZE
from ratouch.world.sensors import SENSOR_FAMILIES
from ratouch.world.taxim_optics import real_presses

#: The fresh everyday presses' stream (no fit draws from it).
EVERYDAY_SEED = (29, 4242)


def renders(cal: GeometryCalibration, per_kind: int, world: int, test: int = TEST_SIZE,
            world_start: int = VALIDATION_START, everyday_seed: int = EVERYDAY_SEED[0]
            ) -> dict:
    """Per family, the shape features and truths each calibration reads (the lookups are
    the calibrations' shared ones)."""
    lookups = cal.lookups
    val = world_shape_renders(lookups, world, world_start)
    test = world_shape_renders(lookups, test, 0, "test", stop=test)
    rng = np.random.default_rng([everyday_seed, EVERYDAY_SEED[1]])
    out: dict = {}
    for name, lookup in lookups.items():
        X, y, _ = shape_renders(lookup, rng, per_kind)
        row = SENSOR_FAMILIES[name]
        real = None
        if row.renderer == "taxim":
            r = real_presses(str(row.calibration))
            real = np.asarray([press_shape(lookup, f, r["background"]) for f in r["frames"]])
        out[name] = {"world_validation": val[name], "everyday": (X, y),
                     "world_test": test[name], "real_balls": real}
    return out


def read(cal: GeometryCalibration, data: dict) -> dict:
    """Balanced accuracies and Taxim's balls read soft, per family."""
    out: dict = {}
    for name, d in data.items():
        model = cal.firmness.get(name)
        if model is None:
            continue
        rec: dict = {}
        for stream in ("world_validation", "everyday", "world_test"):
            X, y = d[stream]
            soft = [model.soft(x) >= 0.5 for x in X]
            rec[stream] = balanced_accuracy(soft, list(y))
        if d["real_balls"] is not None:
            rec["real_balls_read_soft"] = int(sum(model.soft(x) >= 0.5 for x in d["real_balls"]))
            rec["real_balls"] = int(len(d["real_balls"]))
        out[name] = rec
    return out


def verdict(before: dict, after: dict) -> list[str]:
    """The criteria fixed before the first run that `after` misses (empty: none)."""
    missed = []
    for name, a in after.items():
        if a["world_validation"]["balanced"] < 0.70:
            missed.append(f"{name}: world validation balanced accuracy "
                          f"{a['world_validation']['balanced']} < 0.70")
        e = a["everyday"]
        if e["balanced"] < 0.75 or min(e["soft_recall"], e["hard_recall"]) < 0.60:
            missed.append(f"{name}: everyday presses {e}")
        if e["balanced"] < before[name]["everyday"]["balanced"] - 0.03:
            missed.append(f"{name}: everyday presses {e['balanced']} more than 0.03 below "
                          f"the shipped model's {before[name]['everyday']['balanced']}")
        if a.get("real_balls_read_soft", 0) > 4:
            missed.append(f"{name}: {a['real_balls_read_soft']} of Taxim's real balls read soft")
    return missed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--after", default=None, help="a refitted geometry calibration")
    ap.add_argument("--per-kind", type=int, default=30)
    ap.add_argument("--world", type=int, default=200, help="validation renders a family")
    ap.add_argument("--test", type=int, default=TEST_SIZE, help="the test split's first pairs")
    ap.add_argument("--world-start", type=int, default=VALIDATION_START,
                    help="where the world's validation renders start in the train split")
    ap.add_argument("--everyday-seed", type=int, default=EVERYDAY_SEED[0],
                    help="the fresh everyday presses' stream")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    shipped = GeometryCalibration.load(geometry_calibration())
    data = renders(shipped, args.per_kind, args.world, args.test, args.world_start,
                   args.everyday_seed)
    rep: dict = {"before": read(shipped, data)}
    if args.after:
        rep["after"] = read(GeometryCalibration.load(args.after), data)
        rep["criteria_missed"] = verdict(rep["before"], rep["after"])
    text = json.dumps(rep, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

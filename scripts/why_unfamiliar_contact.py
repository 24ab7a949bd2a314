"""A sensor unlike every rendered unit, read alone: does contact read blind to colour recognise
its blanks without refusing its presses?

The measures of docs/geometry.md, "A sensor unlike every rendered unit, read alone: contact
blind to colour", the trust calibration before (its colour-blind model removed: every frame
alone read by the disc-press model) and after (with it):

1. fresh renders under an unfamiliar view (`unfamiliar_view`), the views beyond every
   rendered unit (`WITHHOLD_LIMIT`) only: blanks (the world's and drifted ones) read
   "no contact", the world's presses refused, everyday presses answered minus drifted blanks
   called contact, per family;
2. frames within the limit, read alone, whose state changed: the world's test presses and
   blanks, Taxim's real presses and backgrounds, the tacto DIGIT background;
3. real frames beyond it: the real DIGIT press alone, and unfamiliar views of Taxim's real
   presses and backgrounds.

    python scripts/why_unfamiliar_contact.py [--after CAL] [--n N] [--views V] [--seed S]
        [--start I] [--view-seed S] [--per-kind K] [--blanks B] [--test T] [--out F]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from ratouch.eval.frames import digit_frames, taxim_frames
from ratouch.files import json_text, write_json_atomic
from ratouch.model.trust import TrustCalibration
from ratouch.paths import trust_calibration
from ratouch.train.trust import render_samples
from ratouch.world.config import WorldConfig
from ratouch.world.presses import render_blank_pair, render_presses
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.sensors import (
    WITHHOLD_LIMIT,
    beyond_every_unit,
    family_names,
    guess_family,
    unfamiliar_look,
    unfamiliar_views,
)

#: First training-split index of the fresh renders: no fit or threshold reads them.
FRESH_START = 1_400_000
#: The real reference frames (the DIGIT's), where a checkout has them.
REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "reference_tactile"


def _states(cal: TrustCalibration, frames: list[np.ndarray]) -> list[str]:
    return [cal.contact_state(f)[0] for f in frames]


def _beyond(frames: list[np.ndarray], families: list[str], rng: np.random.Generator
            ) -> tuple[list[np.ndarray], list[str]]:
    """Each frame under one unfamiliar view; the views beyond the limit and their families."""
    views, kept = unfamiliar_views(frames, rng)
    return views, [families[i] for i in kept]


def _share(states: list[str], families: list[str], fam: str, what: tuple[str, ...]) -> float:
    sel = [s for s, f in zip(states, families) if f == fam]
    return round(float(np.mean([s in what for s in sel])), 4) if sel else float("nan")


def fresh_measures(before: TrustCalibration, after: TrustCalibration, n: int, seed: int = 13,
                   start: int = FRESH_START, per_kind: int = 8, blanks_per_family: int = 100
                   ) -> dict:
    """Measure 1 on fresh renders (see the module docstring): the world's train[start:
    start + n], `per_kind` everyday presses of every kind and `blanks_per_family` drifted
    blanks per family, of `seed`."""
    world = World(WorldConfig(seed=0)).warm()
    nc_world = World(WorldConfig(seed=0).with_stress(no_contact=1.0)).warm()
    idx = range(start, start + n)
    presses, blanks = render_samples(world, "train", idx), render_samples(nc_world, "train", idx)
    rng = np.random.default_rng([seed, 1])
    everyday, drifted = [], []
    for fam in family_names():
        everyday += [(p.frame, fam) for p in render_presses(fam, rng, per_kind)]
        drifted += [(render_blank_pair(fam, rng)[0], fam) for _ in range(blanks_per_family)]
    views = np.random.default_rng([seed, 2])
    sets = {"world presses": _beyond(presses["frames"], presses["families"], views),
            "world blanks": _beyond(blanks["frames"], blanks["families"], views),
            "everyday presses": _beyond([f for f, _ in everyday], [x for _, x in everyday],
                                        views),
            "drifted blanks": _beyond([f for f, _ in drifted], [x for _, x in drifted], views)}
    out: dict = {"counts": {k: len(v[0]) for k, v in sets.items()}}
    for name, cal in (("before", before), ("after", after)):
        st = {k: _states(cal, v[0]) for k, v in sets.items()}
        fams = {k: v[1] for k, v in sets.items()}
        rows = {}
        for fam in family_names():
            blank_states = st["world blanks"] + st["drifted blanks"]
            blank_fams = fams["world blanks"] + fams["drifted blanks"]
            answered = _share(st["everyday presses"], fams["everyday presses"], fam,
                              ("contact", "uncertain"))
            false_alarm = _share(st["drifted blanks"], fams["drifted blanks"], fam,
                                 ("contact",))
            rows[fam] = {
                "blanks_no_contact": _share(blank_states, blank_fams, fam, ("no contact",)),
                "world_presses_refused": _share(st["world presses"], fams["world presses"],
                                                fam, ("no contact",)),
                "everyday_answered": answered, "drifted_blanks_contact": false_alarm,
                "everyday_answered_minus_blanks_contact": round(answered - false_alarm, 4)}
        out[name] = rows
    return out


def within_limit_changes(before: TrustCalibration, after: TrustCalibration,
                         real: list, n_test: int = TEST_SIZE) -> dict:
    """Measure 2: frames within the limit read alone whose state changed (the world's first
    `n_test` test pairs with and without contact, and the real frames)."""
    world = World(WorldConfig(seed=0)).warm()
    nc_world = World(WorldConfig(seed=0).with_stress(no_contact=1.0)).warm()
    groups = {"world test presses": render_samples(world, "test", range(n_test))["frames"],
              "world test blanks": render_samples(nc_world, "test", range(n_test))["frames"],
              "real frames within the limit": [
                  f.frame for f in real if f.background is None
                  and not beyond_every_unit(f.frame)]}
    out = {}
    for name, frames in groups.items():
        a, b = _states(before, frames), _states(after, frames)
        out[name] = {"frames": len(frames), "changed": int(sum(x != y for x, y in zip(a, b)))}
    return out


def real_beyond(before: TrustCalibration, after: TrustCalibration, real: list, views: int,
                seed: int = 17) -> dict:
    """Measure 3: real frames beyond the limit, and unfamiliar views of Taxim's."""
    rng = np.random.default_rng([seed, 1])
    out: dict = {"frames": {}}
    for f in real:
        look = guess_family(f.frame)
        if f.background is None and unfamiliar_look(look, WITHHOLD_LIMIT):
            out["frames"][f.name] = {"distance": round(look[1], 3),
                                     "before": before.contact_state(f.frame, look=look)[0],
                                     "after": after.contact_state(f.frame, look=look)[0]}
    taxim = [f for f in real if f.background is None and "digit" not in f.name]
    kept: dict[str, list[np.ndarray]] = {"presses": [], "blanks": []}
    for f in taxim:
        kept["blanks" if "background" in f.name else "presses"] += unfamiliar_views(
            [f.frame] * views, rng)[0]
    for name, cal in (("before", before), ("after", after)):
        p, b = _states(cal, kept["presses"]), _states(cal, kept["blanks"])
        out[name] = {"taxim_press_views_refused": f"{p.count('no contact')} of {len(p)}",
                     "taxim_blank_views_no_contact": f"{b.count('no contact')} of {len(b)}"}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_unfamiliar_contact")
    ap.add_argument("--after", default=None,
                    help="the calibration with the colour-blind model (default: the shipped "
                         "default-s one)")
    ap.add_argument("--n", type=int, default=300, help="fresh world renders each way")
    ap.add_argument("--views", type=int, default=5, help="views of each Taxim frame")
    ap.add_argument("--per-kind", type=int, default=8, help="fresh everyday presses a kind")
    ap.add_argument("--blanks", type=int, default=100, help="fresh drifted blanks a family")
    ap.add_argument("--test", type=int, default=TEST_SIZE,
                    help="world test pairs read within the limit (default all 402)")
    ap.add_argument("--seed", type=int, default=13,
                    help="stream of the everyday presses, drifted blanks and their views")
    ap.add_argument("--start", type=int, default=FRESH_START,
                    help="first training-split index of the fresh world renders")
    ap.add_argument("--view-seed", type=int, default=17,
                    help="stream of the views of Taxim's real frames")
    ap.add_argument("--out", default=None, help="also write the figures here (JSON)")
    args = ap.parse_args(argv)
    after = TrustCalibration.load(args.after or trust_calibration("default-s"))
    if after.contact_unfamiliar is None:
        sys.exit("why_unfamiliar_contact: the calibration has no colour-blind contact model "
                 "(`ratouch train trust --unfamiliar`)")
    before = dataclasses.replace(after, contact_unfamiliar=None)
    real = [f for cal in ("gelsight", "gelsight_mini") for f in taxim_frames(cal, alone=True)]
    real = [f for f in real if f.background is None] + [
        f for f in digit_frames(REFERENCE) if f.background is None]
    result = {"limit": WITHHOLD_LIMIT,
              "threshold": after.contact_unfamiliar[1],
              "streams": {"seed": args.seed, "start": args.start,
                          "view_seed": args.view_seed},
              "fresh": fresh_measures(before, after, args.n, args.seed, args.start,
                                      args.per_kind, args.blanks),
              "within_limit": within_limit_changes(before, after, real, args.test),
              "real_beyond": real_beyond(before, after, real, args.views, args.view_seed)}
    print(json_text(result), end="")
    if args.out:
        write_json_atomic(args.out, result)


if __name__ == "__main__":
    main()

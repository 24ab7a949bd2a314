"""A sensor unlike every rendered unit, read against its background: do floors of its own
recognise its blank pairs without refusing its presses?

The measures of docs/geometry.md, "A sensor unlike every rendered unit, read against its
background: floors of its own", the geometry calibration before (its lookups' floors for such
a sensor removed: every frame held to the floors of the family it looks like) and after (with
them), through the shipped default-s trust calibration:

1. fresh blank pairs and presses (every kind of everyday press and rigid balls), each frame
   and its background recoloured alike (`unfamiliar_pair_view`), the views beyond every rendered
   unit (`WITHHOLD_LIMIT`) only: blank pairs called "contact", and "contact" or "uncertain";
   presses answered ("contact" or "uncertain"), per family;
2. frames within the limit read against their backgrounds whose state changed: the world's
   test presses and blanks, Taxim's real presses, the same fresh pairs unrecoloured;
3. real frames: recoloured views of Taxim's presses with their background recoloured alike
   (beyond the limit), and the real DIGIT press against the tacto background.

    python scripts/why_unfamiliar_floors.py [--after CAL] [--blanks B] [--per-kind K]
        [--views V] [--test T] [--seed S] [--out F]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from ratouch.eval.frames import digit_frames, taxim_frames
from ratouch.files import json_text, write_json_atomic
from ratouch.model.geometry import GeometryCalibration
from ratouch.model.trust import TrustCalibration
from ratouch.paths import geometry_calibration, trust_calibration
from ratouch.train.trust import render_samples
from ratouch.world.config import WorldConfig
from ratouch.world.presses import render_ball, render_blank_pair, render_presses
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.sensors import (
    WITHHOLD_LIMIT,
    beyond_every_unit,
    family_names,
    unfamiliar_pair_view,
)

#: The real reference frames (the DIGIT's), where a checkout has them.
REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "reference_tactile"
ANSWERED = ("contact", "uncertain")

Pair = tuple[np.ndarray, np.ndarray]


def _states(cal: TrustCalibration, pairs: list[Pair]) -> list[str]:
    return [cal.contact_state(f, b)[0] for f, b in pairs]


def _share(states: list[str], what: tuple[str, ...]) -> float | None:
    return round(float(np.mean([s in what for s in states])), 4) if states else None


def fresh_pairs(blanks: int, per_kind: int, seed: int) -> dict[str, dict[str, list[Pair]]]:
    """Per family, fresh drifted blank pairs and presses (every everyday kind and balls,
    `per_kind` each) of streams no fit reads ([seed, k] for the k-th family)."""
    out = {}
    for k, fam in enumerate(family_names()):
        rng = np.random.default_rng([seed, k])
        presses = [(p.frame, p.background) for p in render_presses(fam, rng, per_kind)]
        presses += [(p.frame, p.background) for p in
                    (render_ball(fam, rng) for _ in range(per_kind))]
        out[fam] = {"blanks": [render_blank_pair(fam, rng) for _ in range(blanks)],
                    "presses": presses}
    return out


def fresh_measures(before: TrustCalibration, after: TrustCalibration,
                   fresh: dict[str, dict[str, list[Pair]]], seed: int) -> dict:
    """Measure 1: per family, the recoloured pairs beyond the limit read before and after."""
    out: dict = {}
    for k, (fam, sets) in enumerate(fresh.items()):
        rng = np.random.default_rng([seed, 100 + k])
        views = {}
        for what, pairs in sets.items():
            viewed = [unfamiliar_pair_view(f, b, rng) for f, b in pairs]
            views[what] = [p for p in viewed if beyond_every_unit(p[0])]
        row: dict = {"blank pairs": len(views["blanks"]), "presses": len(views["presses"])}
        for name, cal in (("before", before), ("after", after)):
            b, p = _states(cal, views["blanks"]), _states(cal, views["presses"])
            row[name] = {"blanks_contact": _share(b, ("contact",)),
                         "blanks_contact_or_uncertain": _share(b, ANSWERED),
                         "presses_answered": _share(p, ANSWERED),
                         "presses_contact": _share(p, ("contact",))}
        out[fam] = row
    return out


def within_limit_changes(before: TrustCalibration, after: TrustCalibration,
                         fresh: dict[str, dict[str, list[Pair]]], real: list,
                         n_test: int = TEST_SIZE) -> dict:
    """Measure 2: frames within the limit read against their backgrounds whose state
    changed."""
    world = World(WorldConfig(seed=0)).warm()
    nc_world = World(WorldConfig(seed=0).with_stress(no_contact=1.0)).warm()
    groups: dict[str, list[Pair]] = {}
    for name, w in (("world test presses", world), ("world test blanks", nc_world)):
        data = render_samples(w, "test", range(n_test))
        groups[name] = list(zip(data["frames"], data["backgrounds"]))
    groups["fresh pairs, not recoloured"] = [
        p for sets in fresh.values() for pairs in sets.values() for p in pairs]
    groups["Taxim's real presses"] = [(f.frame, f.background) for f in real
                                      if f.background is not None and "press" in f.name]
    out = {}
    for name, pairs in groups.items():
        pairs = [p for p in pairs if not beyond_every_unit(p[0])]
        a, b = _states(before, pairs), _states(after, pairs)
        out[name] = {"pairs": len(pairs), "changed": int(sum(x != y for x, y in zip(a, b)))}
    return out


def real_measures(before: TrustCalibration, after: TrustCalibration, real: list,
                  digit: list, views: int, seed: int) -> dict:
    """Measure 3: recoloured views of Taxim's real presses (with their background recoloured
    alike) beyond the limit, and the real DIGIT press against the tacto background."""
    rng = np.random.default_rng([seed, 7])
    viewed = [unfamiliar_pair_view(f.frame, f.background, rng) for f in real
              if f.background is not None and "press" in f.name for _ in range(views)]
    viewed = [p for p in viewed if beyond_every_unit(p[0])]
    out: dict = {"taxim press views beyond the limit": len(viewed)}
    for name, cal in (("before", before), ("after", after)):
        st = _states(cal, viewed)
        out[name] = {"taxim_press_views_refused": st.count("no contact"),
                     "taxim_press_views_uncertain": st.count("uncertain"),
                     **{f.name: cal.contact_state(f.frame, f.background)[0]
                        for f in digit if f.background is not None
                        and "pressed" in f.name}}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_unfamiliar_floors")
    ap.add_argument("--after", default=None,
                    help="the geometry calibration with the floors for a sensor unlike every "
                         "rendered unit (default: the shipped one)")
    ap.add_argument("--blanks", type=int, default=200, help="fresh blank pairs a family")
    ap.add_argument("--per-kind", type=int, default=10,
                    help="fresh presses of every kind (and balls) a family")
    ap.add_argument("--views", type=int, default=5, help="views of each Taxim press")
    ap.add_argument("--test", type=int, default=TEST_SIZE,
                    help="world test pairs read within the limit (default all 402)")
    ap.add_argument("--seed", type=int, default=31, help="stream of the fresh pairs")
    ap.add_argument("--out", default=None, help="also write the figures here (JSON)")
    args = ap.parse_args(argv)
    geo = GeometryCalibration.load(args.after or geometry_calibration())
    if not any(lk.unfamiliar_floors for lk in geo.lookups.values()):
        sys.exit("why_unfamiliar_floors: the geometry calibration has no floors for a sensor "
                 "unlike every rendered unit (`ratouch train geometry --unfamiliar-floors`)")
    trust = TrustCalibration.load(trust_calibration("default-s"))
    after = dataclasses.replace(trust, geometry=geo)
    before = dataclasses.replace(trust, geometry=dataclasses.replace(geo, lookups={
        k: dataclasses.replace(lk, unfamiliar_floors=()) for k, lk in geo.lookups.items()}))
    real = [f for cal in ("gelsight", "gelsight_mini") for f in taxim_frames(cal)]
    digit = digit_frames(REFERENCE)
    fresh = fresh_pairs(args.blanks, args.per_kind, args.seed)
    result = {"limit": WITHHOLD_LIMIT,
              "thresholds": {k: lk.unfamiliar_threshold for k, lk in geo.lookups.items()},
              "streams": {"seed": args.seed},
              "fresh": fresh_measures(before, after, fresh, args.seed + 1),
              "within_limit": within_limit_changes(before, after, fresh, real,
                                                   args.test),
              "real": real_measures(before, after, real, digit, args.views, args.seed + 2)}
    print(json_text(result), end="")
    if args.out:
        write_json_atomic(args.out, result)


if __name__ == "__main__":
    main()

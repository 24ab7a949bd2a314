"""A sensor unlike every rendered unit, read alone: what the disc-press contact model's
"contact" is worth there, and what the rule that makes it "uncertain" changes.

The measures of docs/geometry.md, "…read alone: its contact a guess", through the shipped
default-s trust calibration (without the colour-blind model, as shipped). "Before" is the
disc-press model's own decision (contact at its threshold); "after" is `contact_state`, which
calls such a frame "uncertain" where the model says contact. Below the threshold nothing
differs, so "no contact" is the same before and after by construction (counted anyway).

1. fresh renders recoloured (`unfamiliar_view`), the views beyond every rendered unit
   (`WITHHOLD_LIMIT`) only, read alone: per family, the world's test presses and blanks, and
   everyday presses and drifted blanks: the share called "contact", "uncertain" and "no
   contact", and the contact logit's quantiles for blanks and presses;
2. frames within the limit read alone whose state changed: the world's test presses and
   blanks, Taxim's real presses and backgrounds;
3. real frames: recoloured views of Taxim's presses (beyond the limit) and the real DIGIT
   press alone.

    python scripts/why_unfamiliar_alone.py [--test T] [--per-kind K] [--blanks B]
        [--views V] [--seed S] [--out F]
"""

from __future__ import annotations

import argparse
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
    unfamiliar_views,
)

#: The real reference frames (the DIGIT's), where a checkout has them.
REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "reference_tactile"
STATES = ("contact", "uncertain", "no contact")


def states(cal: TrustCalibration, frames: list[np.ndarray]) -> tuple[list[str], list[str],
                                                                     list[float]]:
    """Each frame read alone: the disc-press model's own decision ("before"), the state
    `contact_state` gives ("after"), and the contact logit."""
    before, after, scores = [], [], []
    for f in frames:
        state, score = cal.contact_state(f)
        after.append(state)
        scores.append(score)
        before.append("contact" if np.isfinite(score) and score >= cal.contact_threshold
                      else state)
    return before, after, scores


def _shares(s: list[str]) -> dict:
    return {k: round(s.count(k) / len(s), 4) if s else None for k in STATES}


def _q(x: list[float]) -> list[float] | None:
    return np.round(np.quantile(x, [0.5, 0.9, 0.995]), 2).tolist() if x else None


def fresh_measures(cal: TrustCalibration, n_test: int, per_kind: int, blanks: int, seed: int
                   ) -> dict:
    """Measure 1 (see the module docstring)."""
    world = World(WorldConfig(seed=0)).warm()
    nc_world = World(WorldConfig(seed=0).with_stress(no_contact=1.0)).warm()
    presses = render_samples(world, "test", range(n_test))
    empty = render_samples(nc_world, "test", range(n_test))
    out: dict = {}
    for k, fam in enumerate(family_names()):
        rng = np.random.default_rng([seed, k])
        groups = {
            "world presses": [f for f, x in zip(presses["frames"], presses["families"])
                              if x == fam],
            "world blanks": [f for f, x in zip(empty["frames"], empty["families"]) if x == fam],
            "everyday presses": [p.frame for p in render_presses(fam, rng, per_kind)],
            "drifted blanks": [render_blank_pair(fam, rng)[0] for _ in range(blanks)]}
        row: dict = {}
        for name, frames in groups.items():
            views = unfamiliar_views(frames, rng)[0]
            before, after, scores = states(cal, views)
            row[name] = {"views": len(views), "before": _shares(before),
                         "after": _shares(after), "logit_q50_q90_q995": _q(scores)}
        out[fam] = row
    return out


def within_limit_changes(cal: TrustCalibration, n_test: int, real: list) -> dict:
    """Measure 2: frames within the limit read alone whose state differs from the model's."""
    world = World(WorldConfig(seed=0)).warm()
    nc_world = World(WorldConfig(seed=0).with_stress(no_contact=1.0)).warm()
    groups = {"world test presses": render_samples(world, "test", range(n_test))["frames"],
              "world test blanks": render_samples(nc_world, "test", range(n_test))["frames"],
              "Taxim's real frames": [f.frame for f in real]}
    out = {}
    for name, frames in groups.items():
        frames = [f for f in frames if not beyond_every_unit(f)]
        before, after, _ = states(cal, frames)
        out[name] = {"frames": len(frames),
                     "changed": int(sum(a != b for a, b in zip(before, after)))}
    return out


def real_measures(cal: TrustCalibration, real: list, digit: list, views: int, seed: int
                  ) -> dict:
    """Measure 3: recoloured views of Taxim's real presses, and the real DIGIT press alone."""
    rng = np.random.default_rng([seed, 3])
    pressed = [f.frame for f in real if "press" in f.name]
    viewed = unfamiliar_views([f for f in pressed for _ in range(views)], rng)[0]
    before, after, _ = states(cal, viewed)
    out: dict = {"taxim press views beyond the limit": len(viewed),
                 "before": _shares(before), "after": _shares(after)}
    for f in digit:
        if f.background is None and "pressed" in f.name:
            b, a, s = states(cal, [f.frame])
            out[f.name] = {"before": b[0], "after": a[0], "logit": round(s[0], 3)}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_unfamiliar_alone")
    ap.add_argument("--test", type=int, default=TEST_SIZE,
                    help="world test pairs (default all 402), each with and without contact")
    ap.add_argument("--per-kind", type=int, default=10, help="fresh everyday presses a kind")
    ap.add_argument("--blanks", type=int, default=100, help="fresh drifted blanks a family")
    ap.add_argument("--views", type=int, default=5, help="views of each Taxim press")
    ap.add_argument("--seed", type=int, default=51, help="stream of the fresh renders and views")
    ap.add_argument("--out", default=None, help="also write the figures here (JSON)")
    args = ap.parse_args(argv)
    cal = TrustCalibration.load(trust_calibration("default-s"))
    # Taxim's frames read alone: its presses and its backgrounds
    real = [f for c in ("gelsight", "gelsight_mini") for f in taxim_frames(c, alone=True)
            if f.background is None]
    result = {"limit": WITHHOLD_LIMIT, "threshold": cal.contact_threshold,
              "colour_blind_model": cal.contact_unfamiliar is not None,
              "streams": {"seed": args.seed},
              "fresh": fresh_measures(cal, args.test, args.per_kind, args.blanks, args.seed),
              "within_limit": within_limit_changes(cal, args.test, real),
              "real": real_measures(cal, real, digit_frames(REFERENCE), args.views,
                                    args.seed + 1)}
    print(json_text(result), end="")
    if args.out:
        write_json_atomic(args.out, result)


if __name__ == "__main__":
    main()

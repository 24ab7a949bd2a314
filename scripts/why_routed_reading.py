"""The touch-only reading routed by the press's regime: the measures of docs/geometry.md, "The
touch-only reading routed by the press's regime" (with the background: the shape's router) and
"The touch-only reading of a frame alone, routed too" (without it: the press map's router on
the tactile embedding).

Every frame is read beside a mid-grey visual (`eval.frames.read_frame`, the shipped default-s
pipeline and corpus) and judged by the offline judge against the pressed material's five most
weighted adjectives (`eval.presses.material_label`). Two readings of the same rows: the
routed one (`reading`: `ratouch.serve.trace.touch_reading`) and the paper's tactile query's
(`reading_tactile`); the adapted query's (`reading_adapted`) beside them. Each group is read
with its background (`with_background`) and without it (`alone`):

1. everyday presses (`render_presses`, `--per-kind` a kind a family, the stream of
   `press_readings` at `--seed`);
2. the world's own presses (renders with contact, train[`--world-start`:+`--world`]);
3. Taxim's 72 real ball presses (their backgrounds, or none), and the reference DIGIT press
   (where a checkout has it);
4. rows whose reading is not the one their router names (none by construction).

    python scripts/why_routed_reading.py [--per-kind K] [--seed S] [--world-start I]
        [--world N] [--taxim N] [--out F]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ratouch.eval.frames import Frame, digit_frames, firmness, read_frame, taxim_frames
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.presses import reading_scores, reading_stats
from ratouch.files import json_text, write_json_atomic
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.trust import render_samples
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.presses import SOFT_AT, render_presses
from ratouch.world.sampler import World
from ratouch.world.sensors import family_names

#: The real reference frames (the DIGIT's), where a checkout has them.
REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "reference_tactile"
#: The readings compared: the routed one, the paper's tactile query's, the adapted one's.
KEYS = {"routed": "reading", "tactile": "reading_tactile", "adapted": "reading_adapted"}


@dataclass(frozen=True)
class Pressed:
    """What was pressed, for `reading_stats`: the material and whether it is soft."""

    material: str
    soft: bool


def compare(rows: list[dict], items: list, judge, seed: int) -> dict:
    """Per reading, `reading_stats`; the routed reading's judge minus the paper's tactile
    reading's, paired, with a 95 % bootstrap interval over the rows; the share routed to the
    adapted query."""
    out = {name: reading_stats(rows, items, key, judge) for name, key in KEYS.items()}
    d = (np.array(reading_scores(rows, items, "reading", judge))
         - np.array(reading_scores(rows, items, "reading_tactile", judge)))
    rng = np.random.default_rng([seed, 7])
    boot = [d[rng.integers(0, len(d), len(d))].mean() for _ in range(2000)]
    out["routed_minus_tactile"] = {"mean": round(float(d.mean()), 4), "ci95": np.round(
        np.quantile(boot, [0.025, 0.975]), 4).tolist()}
    out["routed_to_adapted"] = round(float(np.mean(
        [r["reading_query"] == "adapted" for r in rows])), 4)
    out["rows"] = len(rows)
    return out


#: The two ways every group is read.
WAYS = ("with_background", "alone")


def off_router(rows: list[dict]) -> int:
    """Rows whose reading is not the query their router names (measure 4; none by
    construction): the adapted query's exactly where the shape (with a background) or the
    embedding (alone) reads an everyday press, and adapted neighbours exist."""
    def named(r: dict) -> str:
        block = r.get("shape") if r["background"] else r.get("press_regime")
        return "adapted" if (block or {}).get("regime") == "everyday" else "tactile"
    return sum(r["reading_query"] != named(r) for r in rows if r["reading_adapted"])


def by_family(rows: list[dict], items: list, fams: np.ndarray, judge, seed: int) -> dict:
    """`compare` per family present and over all."""
    out = {fam: compare([r for r, f in zip(rows, fams) if f == fam],
                        [p for p, f in zip(items, fams) if f == fam], judge, seed)
           for fam in family_names() if (fams == fam).any()}
    out["all"] = compare(rows, items, judge, seed)
    return out


def read_both_ways(pipe, frames: list[Frame]) -> dict[str, list[dict]]:
    """Each frame read with its background and alone."""
    return {"with_background": [read_frame(pipe, f) for f in frames],
            "alone": [read_frame(pipe, Frame(f.name, f.frame, None, f.centre, f.radius))
                      for f in frames]}


def everyday(pipe, judge, per_kind: int, seed: int) -> tuple[dict, int]:
    """Measure 1 (and 4's count): per way, family and over all."""
    rng = np.random.default_rng([seed, 912])  # the stream of `press_readings`
    presses = [p for fam in family_names() for p in render_presses(fam, rng, per_kind)]
    rows = read_both_ways(pipe, [Frame(f"{p.kind} {p.material}", p.frame, p.background)
                                 for p in presses])
    fams = np.array([p.family for p in presses])
    return ({way: by_family(rows[way], presses, fams, judge, seed) for way in WAYS},
            sum(off_router(r) for r in rows.values()))


def world(pipe, judge, start: int, n: int, seed: int) -> tuple[dict, int]:
    """Measure 2 (and 4's count): the world's renders with contact, per way and family."""
    data = render_samples(World(WorldConfig(seed=0)).warm(), "train", range(start, start + n))
    rows = read_both_ways(pipe, [Frame(f"train {start + i}", f, b) for i, (f, b) in
                                 enumerate(zip(data["frames"], data["backgrounds"]))])
    items = [Pressed(m, material(m).feel.compliance >= SOFT_AT) for m in data["materials"]]
    fams = np.asarray(data["families"])
    return ({way: by_family(rows[way], items, fams, judge, seed) for way in WAYS},
            sum(off_router(r) for r in rows.values()))


def real(pipe, per_calibration: int | None = None) -> tuple[dict, int]:
    """Measure 3 (and 4's count): Taxim's real ball presses with their backgrounds and alone
    (the first `per_calibration` of each calibration; None: all), and the DIGIT press."""
    frames = [f for c in ("gelsight", "gelsight_mini")
              for f in [f for f in taxim_frames(c) if "press" in f.name][:per_calibration]]
    both = read_both_ways(pipe, frames)
    out: dict = {"presses": len(frames)}
    for way, rows in both.items():
        rec: dict = {"answered": sum(r["state"] != "no contact" for r in rows),
                     "routed_to_adapted": sum(r["reading_query"] == "adapted" for r in rows)}
        for name, key in KEYS.items():
            firm = [firmness(r[key]) for r in rows if r["state"] != "no contact"]
            rec[name] = {w: firm.count(w) for w in ("hard", "soft", "both", "neither")}
        out[way] = rec
    for f in digit_frames(REFERENCE):
        if "pressed" in f.name:
            r = read_frame(pipe, f)
            out[f.name] = {**{name: r[key] for name, key in KEYS.items()},
                           "query": r["reading_query"]}
    return out, sum(off_router(r) for r in both.values())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="why_routed_reading")
    ap.add_argument("--per-kind", type=int, default=4, help="everyday presses a kind a family")
    ap.add_argument("--seed", type=int, default=12, help="stream of the everyday presses")
    ap.add_argument("--world-start", type=int, default=1_900_000,
                    help="first world training render read")
    ap.add_argument("--world", type=int, default=300, help="world renders read")
    ap.add_argument("--taxim", type=int, default=None,
                    help="Taxim's presses read per calibration (default all: 48 and 24)")
    ap.add_argument("--out", default=None, help="also write the figures here (JSON)")
    args = ap.parse_args(argv)
    pipe = RATouchPipeline.load("default-s")
    judge = OfflineJudge()
    presses, off1 = everyday(pipe, judge, args.per_kind, args.seed)
    worlds, off2 = world(pipe, judge, args.world_start, args.world, args.seed)
    reals, off3 = real(pipe, args.taxim)
    result = {"streams": {"seed": args.seed, "per_kind": args.per_kind,
                          "world": f"train[{args.world_start}:{args.world_start + args.world}]"},
              "press_map_router": getattr(pipe.press_map, "router", None) is not None,
              "everyday": presses, "world": worlds, "real": reals,
              "off_router": off1 + off2 + off3}
    print(json_text(result), end="")
    if args.out:
        write_json_atomic(args.out, result)


if __name__ == "__main__":
    main()

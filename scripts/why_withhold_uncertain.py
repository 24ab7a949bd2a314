"""Withholding touch where contact is uncertain: does vision answer better where the trust line
cannot tell whether the gel was touched?

The measures of docs/premise.md, "Touch withheld where contact is uncertain", on the world
test split (its first N pairs), offline judge, the shipped weights. Each pair's frame is read
five ways, its contact state decided by the shipped trust calibration as serving decides it
(`TrustCalibration.contact_state`) and its tactile embedding encoded as serving encodes it:

* A. the press, alone; B. the press against its own unit's background (the natural split);
* C. the press against another unit's background of the same family;
* D. the same sample rendered without contact (its crop and material are the pair's; it is
  judged on the pair's label), against another unit's background; E. that blank, alone.

On each row the withholding rule's answer (the image query's neighbours, the reader with the
neutral touch: `scripts/why_withhold.py`'s) replaces the system's where the frame is beyond
`WITHHOLD_LIMIT` (today's rule, in both arms) and, with a new rule (`RULES`), where it fires:

* "uncertain": the state is "uncertain" (docs/premise.md, "Touch withheld where contact is
  uncertain");
* "second-opinion": a background is given, the state against it is "uncertain" and the frame
  read alone is not "contact" (the next section there).

Rows read "no contact" are answered by neither arm and only counted. The criteria and verdict
are `--rule`'s; both rules are reported under "rules". `--split probe --start S` reads fresh
probe-split rows S ... S + N - 1 instead of the test split.

    python scripts/why_withhold_uncertain.py [--n N] [--k K] [--encoder E] [--seed S]
        [--split test|probe] [--start S] [--rule uncertain|second-opinion] [--serving N]
        [--json F]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections import Counter

import numpy as np

from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split, retrieve
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.judge.stats import mean_ci
from ratouch.eval.report import measured_stamp
from ratouch.files import write_atomic
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.world.config import WorldConfig
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.sensors import WITHHOLD_LIMIT, beyond_every_unit, family_sensors, sensor_family
from ratouch.world.splits import encode_test_split

#: The five readings of each pair: (name, blank?, background: None / "own" / "other").
CONDITIONS = (("A_press_alone", False, None), ("B_press_own_background", False, "own"),
              ("C_press_other_unit", False, "other"), ("D_blank_other_unit", True, "other"),
              ("E_blank_alone", True, None))
#: The rules compared (see the module).
RULES = ("uncertain", "second-opinion")


def other_unit(sensor: int) -> int:
    """The next unit of `sensor`'s family (its background is another unit's)."""
    units = list(family_sensors(sensor_family(sensor)))
    return units[(units.index(int(sensor)) + 1) % len(units)]


def _diff(a: np.ndarray, b: np.ndarray, seed: int) -> dict:
    if len(a) == 0:
        return {"diff": None, "ci95": None, "rows": 0}
    m, lo, hi = mean_ci(a - b, seed=seed)
    return {"diff": round(m, 4), "ci95": [round(lo, 4), round(hi, 4)], "rows": int(len(a))}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="why_withhold_uncertain")
    ap.add_argument("--n", type=int, default=TEST_SIZE, help="test pairs (default all 402)")
    ap.add_argument("--k", type=int, default=5)
    ap.add_argument("--encoder", default="default-s")
    ap.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    ap.add_argument("--split", choices=("test", "probe"), default="test")
    ap.add_argument("--start", type=int, default=0, help="(probe) the first row's index")
    ap.add_argument("--rule", choices=RULES, default="uncertain",
                    help="the rule the criteria and the verdict are of")
    ap.add_argument("--serving", type=int, default=0,
                    help="also check the serving path on the first N test pairs (`serving`)")
    ap.add_argument("--json", default=None, help="also write the report to this file")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)

    # when and on what code it was measured, as the other checks of docs/ record it
    made = measured_stamp()
    p = RATouchPipeline.load(args.encoder)
    assert p.trust is not None, "the rule reads the trust calibration's contact state"
    n = min(args.n, TEST_SIZE) if args.split == "test" else args.n
    start = 0 if args.split == "test" else args.start
    test = encode_test_split(p.encoders, indices=range(start, start + n), split=args.split)
    presses = World(WorldConfig())
    blanks = World(WorldConfig().with_stress(no_contact=1.0))
    judge = OfflineJudge()
    neutral = np.repeat(p.neutral_touch(), n, 0)
    reader = p.generator_reader or p.generator_ra
    # the rule's answer: the image query's neighbours (they do not depend on touch), the
    # reader with the neutral touch; the same on every reading of a pair
    withheld = answer_split(p, dataclasses.replace(test, T=neutral), RA_TOUCH, judge=judge,
                            ids=retrieve(p, test.V, test.T, args.k, "image"), generator=reader,
                            name="withheld").scores

    out: dict = {**made, "config": {**vars(args), "n": n, "withhold_limit": WITHHOLD_LIMIT,
                            "reader": p.generator_reader is not None}, "conditions": {}}
    rows: dict[str, dict[str, list]] = {}
    for c, (name, blank, bg) in enumerate(CONDITIONS):
        world = blanks if blank else presses
        samples = [world.sample(args.split, i) for i in test.indices]
        if blank:  # the same pair (crop, material; judged on its label), no contact
            assert [s.material for s in samples] == list(test.materials)
        backs = [None if bg is None else world.background_image(
            s.sensor if bg == "own" else other_unit(s.sensor)) for s in samples]
        frames = [s.tactile for s in samples]
        T = (test.T if name.startswith("B_") else
             p.encoders.encode_tactile(frames, None if bg is None else backs))
        split = dataclasses.replace(test, T=T)
        states = np.array([p.trust.contact_state(f, b)[0] for f, b in zip(frames, backs)])
        look = np.array([beyond_every_unit(f) for f in frames])
        paper = answer_split(p, split, RA_TOUCH, k=args.k, judge=judge, name="paper").scores
        gated = answer_split(p, split, RA_TOUCH, judge=judge, name="gated",
                             ids=retrieve(p, split.V, split.T, args.k, "gated"),
                             generator=p.system_generator("gated")).scores
        base = answer_split(p, split, BASELINE, judge=judge, name="baseline").scores
        unsure = states == "uncertain"
        answered = states != "no contact"
        # the second opinion: the frame read alone, where a background was given
        alone = (states if bg is None else
                 np.array([p.trust.contact_state(f, None)[0] if u else "-"
                           for f, u in zip(frames, unsure)]))
        fires = {"uncertain": unsure,
                 "second-opinion": unsure & (bg is not None) & (alone != "contact")}
        arms = {"fallback": np.where(look, withheld, paper),
                "gated": np.where(look, withheld, gated)}
        for r, f in fires.items():
            arms[f"fallback_{r}"] = np.where(look | f, withheld, paper)
            arms[f"gated_{r}"] = np.where(look | f, withheld, gated)
        arms["fallback_rule"] = arms[f"fallback_{args.rule}"]
        arms["gated_rule"] = arms[f"gated_{args.rule}"]
        by_family: dict[str, Counter] = {}
        for s, st in zip(samples, states):
            by_family.setdefault(sensor_family(s.sensor), Counter())[str(st)] += 1
        shown = {**arms, "paper": paper, "baseline": base}
        rep = {"states": dict(Counter(states.tolist())),
               "states_by_family": {f: dict(v) for f, v in by_family.items()},
               "beyond_limit": int(look.sum()),
               "uncertain_read_alone": dict(Counter(alone[unsure].tolist())),
               "fires": {r: int(f.sum()) for r, f in fires.items()},
               "all_answered_rows": {a: round(float(v[answered].mean()), 4) if answered.any()
                                     else None for a, v in shown.items()},
               "uncertain_rows": {a: round(float(v[unsure].mean()), 4) if unsure.any()
                                  else None for a, v in shown.items()},
               "rule_vs_fallback_uncertain": _diff(arms["fallback_rule"][unsure],
                                                   arms["fallback"][unsure], args.seed + c),
               "rule_vs_gated_uncertain": _diff(arms["gated_rule"][unsure],
                                                arms["gated"][unsure], args.seed + 10 + c)}
        if name.startswith(("A_", "B_")):  # criterion 3: every row of the split
            rep["all_rows_rule_vs_fallback"] = _diff(arms["fallback_rule"], arms["fallback"],
                                                     args.seed + 20 + c)
            rep["changed_rows"] = int((arms["fallback_rule"] != arms["fallback"]).sum())
            for r in RULES:
                rep[f"all_rows_{r}_vs_fallback"] = _diff(arms[f"fallback_{r}"],
                                                         arms["fallback"], args.seed + 20 + c)
                rep[f"changed_rows_{r}"] = int((arms[f"fallback_{r}"] != arms["fallback"]).sum())
        out["conditions"][name] = rep
        rows[name] = {"unsure": unsure, **arms}

    def pooled(names: tuple[str, ...], a: str, b: str, seed: int) -> dict:
        m = [rows[x]["unsure"] for x in names]
        return _diff(np.concatenate([rows[x][a][u] for x, u in zip(names, m)]),
                     np.concatenate([rows[x][b][u] for x, u in zip(names, m)]), seed)

    blanks_ = ("D_blank_other_unit", "E_blank_alone")
    presses_ = ("A_press_alone", "C_press_other_unit")
    every = presses_ + blanks_

    def judged(rule: str) -> dict:
        """The criteria, their verdict and `gated`'s figures of one rule."""
        a = f"fallback_{rule}"
        cond_a, cond_b = out["conditions"]["A_press_alone"], out["conditions"][
            "B_press_own_background"]
        cr = {"1_blanks_uncertain": pooled(blanks_, a, "fallback", args.seed + 31),
              "2_presses_uncertain": pooled(presses_, a, "fallback", args.seed + 32),
              "3_natural_split_changed_rows": cond_b[f"changed_rows_{rule}"],
              "3_alone_all_rows": cond_a[f"all_rows_{rule}_vs_fallback"],
              "4_every_uncertain_row": pooled(every, a, "fallback", args.seed + 34)}
        c1, c2, c4 = (cr["1_blanks_uncertain"], cr["2_presses_uncertain"],
                      cr["4_every_uncertain_row"])
        verdict = {
            "1": bool(c1["rows"] >= 20 and c1["diff"] >= 0.30 and c1["ci95"][0] > 0),
            "2": bool(c2["rows"] == 0 or c2["diff"] >= -0.15),
            "3": bool(cr["3_natural_split_changed_rows"] == 0
                      and cr["3_alone_all_rows"]["diff"] >= -0.01),
            "4": bool(c4["rows"] > 0 and c4["diff"] > 0 and c4["ci95"][0] > 0)}
        g = f"gated_{rule}"
        gated = {"blanks_uncertain": pooled(blanks_, g, "gated", args.seed + 41),
                 "presses_uncertain": pooled(presses_, g, "gated", args.seed + 42),
                 "every_uncertain_row": pooled(every, g, "gated", args.seed + 44)}
        return {"criteria": cr, "verdict": verdict, "gated": gated}

    out["rules"] = {r: judged(r) for r in RULES}
    out.update(out["rules"][args.rule])
    if args.serving:
        out["serving"] = serving(p, args.serving, args.k)
    text = json.dumps(out, indent=1)
    if args.json:
        write_atomic(args.json, text + "\n")
    print(text)
    return out


def serving(p: RATouchPipeline, n: int, k: int) -> dict:
    """The shipped rule ("second-opinion") through the serving path (`answer_one`,
    `fallback`) on the world's first `n` test pairs: each press and blank against another
    unit's background (C, D), whether the serving path withheld touch where the rule fires
    and nowhere else; and each press alone and against its own background (A, B), the pairs
    whose answers differ from `paper`'s."""
    from ratouch.serve.request import QueryRequest, answer_one

    def ask(s, bg, system):
        return answer_one(p, QueryRequest.decode(s.visual, s.tactile, box=s.box, k=k,
                                                 background=bg, retrieval=system))

    assert p.trust is not None
    presses, blanks = World(WorldConfig()), World(WorldConfig().with_stress(no_contact=1.0))
    out = {"answered": 0, "fires": 0, "withheld": 0, "disagree": [], "queries_a_b": 0,
           "differ_from_paper_a_b": []}
    for i in range(min(n, TEST_SIZE)):
        for w, kind in ((presses, "C"), (blanks, "D")):
            s = w.sample("test", i)
            bg = w.background_image(other_unit(s.sensor))
            state = p.trust.contact_state(s.tactile, bg)[0]
            if state == "no contact":
                continue
            alone = p.trust.second_opinion(s.tactile, bg, state)
            fires = alone is not None and alone["state"] != "contact"
            held = (ask(s, bg, "fallback").retrieval or {}).get("kind") == "withheld"
            out["answered"] += 1
            out["fires"] += int(fires)
            out["withheld"] += int(held)
            if fires != held:
                out["disagree"].append([kind, i])
        s = presses.sample("test", i)
        for bg in (None, presses.background_image(s.sensor)):
            a, b = ask(s, bg, "paper"), ask(s, bg, "fallback")
            out["queries_a_b"] += 1
            if a.description != b.description or a.neighbours != b.neighbours:
                out["differ_from_paper_a_b"].append([i, bg is not None])
    return out


if __name__ == "__main__":
    main()

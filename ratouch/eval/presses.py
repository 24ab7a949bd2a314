"""`ratouch eval presses`: contact on renders of the presses people make
(`ratouch.world.presses`), per sensor family and press kind, with and without the sensor's
background (captured at another moment, drifted as Taxim's real pairs drift), and false
alarms on drifted blank pairs; the shipped trust calibration's decision, and the
structured-change check alone. With `--world`, the world's own test presses and blanks read
the same way (`world_contact`). With `--readings`, what the whole pipeline reads from those
presses by touch alone (`press_readings`): hard against soft, the judge against the pressed
material's own words, and how many distinct readings. Renders only: the figures the
thresholds were not set on (fresh seeds)."""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from ratouch.errors import ConfigError
from ratouch.eval.frames import Frame, firmness, read_frame
from ratouch.model.trust import TrustCalibration
from ratouch.world.material import material
from ratouch.world.presses import PRESS_KINDS, render_blank_pair, render_press, render_presses
from ratouch.world.sensors import family_names

#: Adjectives of a pressed material's reference label: its profile's strongest words.
LABEL_WORDS = 5


def press_contact(trust: TrustCalibration, n: int = 10, blanks: int = 40, seed: int = 1,
                  hw: tuple[int, int] = (128, 96)) -> dict:
    """Per family: per kind the share of presses read as contact (with background, without,
    and by the structured check alone), the depth and spread of their height maps, and the
    share of blank pairs read as contact (false alarms), and the balanced accuracy of the
    firmness read from shape (`shape_firmness`, every press read against its background;
    `shape_soft` per kind). A miss is any reading but
    "contact"; a refusal is "no contact" (the answer withheld), where "uncertain" still
    answers with a caveat: both are counted, for presses and for blanks. `hw`: the
    renders' (height, width), portrait by default."""
    rng = np.random.default_rng([seed, 911])
    out: dict = {}
    for fam in family_names():
        rows: dict = defaultdict(lambda: defaultdict(list))
        shape: tuple[list, list] = ([], [])  # firmness read from shape, and the truth
        for kind in PRESS_KINDS:
            for _ in range(n):
                p = render_press(fam, rng, kind, hw)
                read = trust.read_geometry(p.frame, p.background)
                sc = None if read is None else read["structure"]
                hm = None if read is None else read["height"]
                st_bg, _ = trust.contact_state(p.frame, p.background, sc)
                st, _ = trust.contact_state(p.frame, None)
                r = rows[kind]
                r["with_background"].append(st_bg == "contact")
                r["without_background"].append(st == "contact")
                r["refused_with_background"].append(st_bg == "no contact")
                r["refused_without_background"].append(st == "no contact")
                r["structured"].append(bool(sc and sc["contact"]))
                firm = None if read is None else read["firmness"]
                if firm is not None:
                    r["shape_soft"].append(firm["reads"] == "soft")
                    shape[0].append(firm["reads"] == "soft")
                    shape[1].append(p.soft)
                if hm is not None:
                    r["depth"].append(hm.depth)
                    r["spread"].append(hm.spread)
        fa_bg, fa, empty_bg, empty = [], [], [], []
        for _ in range(blanks):
            frame, bg = render_blank_pair(fam, rng, hw)
            st_bg, st = trust.contact_state(frame, bg)[0], trust.contact_state(frame, None)[0]
            fa_bg.append(st_bg == "contact")
            fa.append(st == "contact")
            empty_bg.append(st_bg == "no contact")
            empty.append(st == "no contact")
        out[fam] = {
            "kinds": {k: {m: round(float(np.mean(v)), 4) for m, v in r.items()}
                      for k, r in rows.items()},
            "miss_with_background": round(1 - float(np.mean(
                [x for r in rows.values() for x in r["with_background"]])), 4),
            "miss_without_background": round(1 - float(np.mean(
                [x for r in rows.values() for x in r["without_background"]])), 4),
            "refused_with_background": round(float(np.mean(
                [x for r in rows.values() for x in r["refused_with_background"]])), 4),
            "refused_without_background": round(float(np.mean(
                [x for r in rows.values() for x in r["refused_without_background"]])), 4),
            "false_alarm_with_background": round(float(np.mean(fa_bg)), 4),
            "false_alarm_without_background": round(float(np.mean(fa)), 4),
            "blank_recognised_with_background": round(float(np.mean(empty_bg)), 4),
            "blank_recognised_without_background": round(float(np.mean(empty)), 4),
            "shape_firmness": balanced_accuracy(*shape) if shape[0] else None,
            "n_presses": n * len(PRESS_KINDS), "n_blanks": blanks}
    return out


#: The contact states `TrustCalibration.contact_state` answers with, in report order.
STATES = ("contact", "uncertain", "no contact")


def world_contact(trust: TrustCalibration, n: int = 402, seed: int = 0) -> dict:
    """The world's own regime beside the everyday presses: its first `n` test presses and the
    same samples rendered without contact, each read alone and against its unit's background;
    per family (and "all"), how many land in each state (`STATES`) for
    {"presses", "blanks"} x {"alone", "with_background"}. What a change made for the presses
    people make costs the frames the models were trained on."""
    from ratouch.train.trust import render_samples
    from ratouch.world.config import WorldConfig
    from ratouch.world.sampler import World

    base = WorldConfig(seed=seed)
    out: dict = {}
    for kind, cfg in (("presses", base), ("blanks", base.with_stress(no_contact=1.0))):
        data = render_samples(World(cfg).warm(), "test", range(n))
        for frame, bg, fam in zip(data["frames"], data["backgrounds"], data["families"]):
            for way, b in (("alone", None), ("with_background", bg)):
                state = trust.contact_state(frame, b)[0]
                for key in (fam, "all"):
                    counts = out.setdefault(key, {}).setdefault(kind, {}).setdefault(
                        way, dict.fromkeys(STATES, 0))
                    counts[state] += 1
    return out


def cross_unit_contact(trust: TrustCalibration, n: int = 100, seed: int = 0,
                       hw: tuple[int, int] = (128, 96)) -> dict:
    """Blank frames read against the background of another unit of the same family
    (`render_cross_unit_pair`, `n` a family, a stream of its own, rendered at `hw`): per
    family, how many land in each contact state (`STATES`) and how many the structured check
    alone calls contact. Not a press, so every "contact" is one the wrong background made."""
    from ratouch.world.presses import render_cross_unit_pair
    from ratouch.world.sensors import family_names

    rng = np.random.default_rng([seed, 5501])
    out: dict = {}
    for fam in family_names():
        counts = dict.fromkeys(STATES, 0)
        structured = field = band = 0
        for _ in range(n):
            frame, bg = render_cross_unit_pair(fam, rng, hw)
            read = trust.read_geometry(frame, bg, height=False)
            block = None if read is None else read["structure"]
            structured += bool(block and block["contact"])
            field += bool(block and (block.get("lighting_field") or {}).get("explains"))
            band += bool(block and (block.get("band") or {}).get("inside"))
            counts[trust.contact_state(frame, bg, structured=block)[0]] += 1
        out[fam] = {**counts, "structured_contact": structured,
                    "lighting_field_explains": field, "band_inside": band, "pairs": n}
    return out


def format_cross_unit_contact(rep: dict) -> str:
    lines = ["| family | blank against another unit's background | " + " | ".join(STATES)
             + " | structured check: contact | of which a lighting field explains "
             "| of which barely above (the band) |",
             "|---|---|" + "---|" * (len(STATES) + 3)]
    for fam, r in rep.items():
        lines.append(f"| {fam} | {r['pairs']} pairs | " + " | ".join(str(r[s]) for s in STATES)
                     + f" | {r['structured_contact']} | {r.get('lighting_field_explains', 0)} "
                     f"| {r.get('band_inside', 0)} |")
    return "\n".join(lines)


def format_world_contact(rep: dict) -> str:
    lines = ["| family | what | read | " + " | ".join(STATES) + " |",
             "|---|---|---|" + "---|" * len(STATES)]
    for fam, kinds in rep.items():
        for kind, ways in kinds.items():
            for way, counts in ways.items():
                lines.append(f"| {fam} | world test {kind} | {way.replace('_', ' ')} | "
                             + " | ".join(str(counts[s]) for s in STATES) + " |")
    return "\n".join(lines)


def balanced_accuracy(soft: list[bool], truth: list[bool]) -> dict:
    """{"balanced", "soft_recall", "hard_recall", "n"} of soft-or-hard readings against the
    truth (balanced: the mean of the two recalls)."""
    s, t = np.asarray(soft, bool), np.asarray(truth, bool)
    rs = float((s & t).sum() / max(t.sum(), 1))
    rh = float((~s & ~t).sum() / max((~t).sum(), 1))
    return {"balanced": round((rs + rh) / 2, 3), "soft_recall": round(rs, 3),
            "hard_recall": round(rh, 3), "n": int(len(t))}


def press_probe(encoders, trust: TrustCalibration, n: int = 20, seed: int = 4,
                folds: int = 5) -> dict:
    """What the tactile encoder and the press's shape hold about the pressed thing, on
    renders of everyday presses: per family, `n` presses of every kind, and linear probes
    (standardised logistic regression, `folds`-fold cross-validation over shuffled presses)
    of the material (accuracy; chance: the most common material's share) and of soft against
    hard (balanced accuracy) from the tactile embedding with the background, without it, the
    shape features (`model.geometry.shape_features`, against the background) and the
    embedding with the background and the shape together.

    Raises:
        ConfigError: no geometry calibration loaded."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import KFold, cross_val_predict
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from ratouch.model.geometry import press_shape

    if trust.geometry is None:
        raise ConfigError("no geometry calibration loaded: `ratouch train geometry`")
    rng = np.random.default_rng([seed, 977])
    out: dict = {}
    for fam in family_names():
        lookup = trust.geometry.lookup(fam)
        if lookup is None:
            continue
        presses = render_presses(fam, rng, n)
        frames = [p.frame for p in presses]
        bgs = [p.background for p in presses]
        shapes = [press_shape(lookup, p.frame, p.background) for p in presses]
        with_bg = encoders.encode_tactile(frames, bgs, sensors=[fam] * len(frames))
        alone = encoders.encode_tactile(frames, None, sensors=[fam] * len(frames))
        inputs = {"embedding_with_background": with_bg, "embedding_alone": alone,
                  "shape": np.asarray(shapes),
                  "embedding_and_shape": np.concatenate([with_bg, np.asarray(shapes)], 1)}
        names = np.array([p.material for p in presses])
        soft = np.array([p.soft for p in presses])
        split = KFold(folds, shuffle=True, random_state=seed)
        row: dict = {"presses": len(presses), "materials": int(len(set(names))),
                     "material_chance": round(float(max(np.mean(names == m)
                                                        for m in set(names))), 3)}
        for key, X in inputs.items():
            probe = make_pipeline(StandardScaler(), LogisticRegression(max_iter=3000))
            said = cross_val_predict(probe, X, names, cv=split)
            firm = make_pipeline(StandardScaler(), LogisticRegression(
                max_iter=3000, class_weight="balanced"))
            soft_said = cross_val_predict(firm, X, soft, cv=split)
            row[key] = {"material": round(float(np.mean(said == names)), 3),
                        "firmness": balanced_accuracy(list(soft_said), list(soft))["balanced"]}
        out[fam] = row
    return out


def format_press_probe(rep: dict) -> str:
    lines = ["| family | input | material accuracy (chance) | soft vs hard, balanced |",
             "|---|---|---|---|"]
    for fam, r in rep.items():
        for key in ("embedding_with_background", "embedding_alone", "shape",
                    "embedding_and_shape"):
            lines.append(f"| {fam} | {key.replace('_', ' ')} | {r[key]['material']:.3f} "
                         f"({r['material_chance']:.3f}) | {r[key]['firmness']:.3f} |")
    return "\n".join(lines)


def format_press_contact(rep: dict) -> str:
    lines = ["| family | kind | contact with bg | structured only | contact without bg | depth | "
             "spread |", "|---|---|---|---|---|---|---|"]
    for fam, f in rep.items():
        for kind, r in f["kinds"].items():
            lines.append(f"| {fam} | {kind} | {r['with_background']:.2f} | {r['structured']:.2f}"
                         f" | {r['without_background']:.2f} | {r.get('depth', float('nan')):.3g}"
                         f" | {r.get('spread', float('nan')):.2f} |")
    lines += ["", "| family | miss (bg) | miss (no bg) | refused (bg) | refused (no bg) | "
              "false alarm (bg) | false alarm (no bg) | blank recognised (bg) | "
              "blank recognised (no bg) |", "|---|---|---|---|---|---|---|---|---|"]
    for fam, f in rep.items():
        lines.append(f"| {fam} | {f['miss_with_background']:.3f} | "
                     f"{f['miss_without_background']:.3f} | "
                     f"{f['refused_with_background']:.3f} | "
                     f"{f['refused_without_background']:.3f} | "
                     f"{f['false_alarm_with_background']:.3f} | "
                     f"{f['false_alarm_without_background']:.3f} | "
                     f"{f['blank_recognised_with_background']:.3f} | "
                     f"{f['blank_recognised_without_background']:.3f} |")
    shaped = {fam: f["shape_firmness"] for fam, f in rep.items() if f.get("shape_firmness")}
    if shaped:
        lines += ["", "| family | firmness from shape: balanced accuracy | soft recall | "
                  "hard recall | presses |", "|---|---|---|---|---|"]
        lines += [f"| {fam} | {r['balanced']:.3f} | {r['soft_recall']:.3f} | "
                  f"{r['hard_recall']:.3f} | {r['n']} |" for fam, r in shaped.items()]
    return "\n".join(lines)


def material_label(name: str) -> str:
    """A material's reference label for the judge: its `LABEL_WORDS` most weighted tactile
    adjectives (`Material.profile`), comma-joined."""
    words = sorted(material(name).profile, key=lambda wv: -wv[1])[:LABEL_WORDS]
    return ", ".join(w for w, _ in words)


def press_readings(pipeline, judge, n: int = 4, seed: int = 2, k: int = 5) -> dict:
    """What the pipeline reads by touch alone (beside a mid-grey visual, `eval.frames
    .read_frame`) from `n` renders per family and press kind, each with its drifted
    background and without it.

    Per family and way of reading (``with_background``, ``without_background``): how many
    presses; how many were refused ("no contact"); of the hard presses (compliance below
    `presses.SOFT_AT`) how many read soft, of the soft ones how many read hard (a reading's
    firmness from the judge's soft and hard words, `frames.firmness`; a refused press has
    none); the share whose firmness is right (a refused press is not); the offline judge of the reading against the pressed material's own
    words (`material_label`), a refused press scoring as an empty answer; and how many
    distinct readings. The reading is the touch-only reading (`frames.touch_reading`: the
    adapted query's for a press the firmness router reads as an everyday one, else the
    paper's tactile query's; "routed_to_adapted": the share read by the adapted one); the
    same figures for the paper's tactile query's reading under "tactile", and for the adapted
    tactile query's (the press map's, `ratouch.model.press_map`) under "adapted"."""
    rng = np.random.default_rng([seed, 912])
    out: dict = {}
    for fam in family_names():
        presses = render_presses(fam, rng, n)
        out[fam] = {}
        for way in ("with_background", "without_background"):
            rows = [read_frame(pipeline, Frame(f"{p.kind} {p.material}", p.frame,
                                               p.background if way == "with_background"
                                               else None), k)
                    for p in presses]
            out[fam][way] = {**reading_stats(rows, presses, "reading", judge),
                             # the share of presses the routed reading read by the adapted query
                             "routed_to_adapted": round(float(np.mean(
                                 [r["reading_query"] == "adapted" for r in rows])), 4),
                             "tactile": reading_stats(rows, presses, "reading_tactile",
                                                       judge),
                             "adapted": reading_stats(rows, presses, "reading_adapted",
                                                       judge)}
    return out


def reading_scores(rows: list[dict], presses: list, key: str, judge) -> list[float]:
    """The offline judge of one reading of each row (`key`, as `reading_stats`) against the
    pressed material's words (`material_label`); a refused press ("no contact") scores as an
    empty answer."""
    return judge.score_many([(material_label(p.material),
                              r[key] if r["state"] != "no contact" else None)
                             for r, p in zip(rows, presses)])


def reading_stats(rows: list[dict], presses: list, key: str, judge) -> dict:
    """The figures of `press_readings` for one reading of the rows (`key`: "reading", the
    touch-only reading; "reading_tactile", the paper's tactile query's top caption;
    "reading_adapted", the adapted tactile query's)."""
    # a refused press has no reading: neither firmness, and not right
    firm = [firmness(r[key]) if r["state"] != "no contact" else "refused" for r in rows]
    hard = [f for f, p in zip(firm, presses) if not p.soft]
    soft = [f for f, p in zip(firm, presses) if p.soft]
    right = sum(f == ("soft" if p.soft else "hard") for f, p in zip(firm, presses))
    scores = reading_scores(rows, presses, key, judge)
    return {"presses": len(rows), "hard": len(hard), "soft": len(soft),
            "refused": sum(r["state"] == "no contact" for r in rows),
            "hard_read_soft": hard.count("soft"), "soft_read_hard": soft.count("hard"),
            "firmness_right": round(right / len(rows), 4),
            "judge": round(float(np.mean(scores)), 3),
            "distinct_readings": len({r[key] for r in rows if r["state"] != "no contact"})}


def format_press_readings(rep: dict) -> str:
    lines = ["| family | background | reading | refused | hard read soft | soft read hard | "
             "firmness right | judge | distinct readings |",
             "|---|---|---|---|---|---|---|---|---|"]
    for fam, ways in rep.items():
        for way, both in ways.items():
            for name, r in (("routed", both), ("tactile", both.get("tactile")),
                            ("adapted", both.get("adapted"))):
                if r is None:
                    continue
                lines.append(
                    f"| {fam} | {'with' if way == 'with_background' else 'without'} | {name} | "
                    f"{r['refused']}/{r['presses']} | {r['hard_read_soft']}/{r['hard']} | "
                    f"{r['soft_read_hard']}/{r['soft']} | {r['firmness_right']:.2f} | "
                    f"{r['judge']:.2f} | {r['distinct_readings']} |")
    return "\n".join(lines)

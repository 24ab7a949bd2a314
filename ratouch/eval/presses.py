"""`ratouch eval presses`: contact on renders of the presses people make
(`ratouch.world.presses`), per sensor family and press kind, with and without the sensor's
background (captured at another moment, drifted as Taxim's real pairs drift), and false
alarms on drifted blank pairs; the shipped trust calibration's decision, and the
structured-change check alone. Renders only: the figures the thresholds were not set on
(fresh seeds)."""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from ratouch.model.trust import TrustCalibration
from ratouch.world.presses import PRESS_KINDS, render_blank_pair, render_press
from ratouch.world.sensors import family_names


def press_contact(trust: TrustCalibration, n: int = 10, blanks: int = 40, seed: int = 1
                  ) -> dict:
    """Per family: per kind the share of presses read as contact (with background, without,
    and by the structured check alone), the depth and spread of their height maps, and the
    share of blank pairs read as contact (false alarms). A miss is any reading but
    "contact"; a refusal is "no contact" (the answer withheld), where "uncertain" still
    answers with a caveat: both are counted, for presses and for blanks."""
    rng = np.random.default_rng([seed, 911])
    out: dict = {}
    for fam in family_names():
        rows: dict = defaultdict(lambda: defaultdict(list))
        for kind in PRESS_KINDS:
            for _ in range(n):
                p = render_press(fam, rng, kind)
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
                if hm is not None:
                    r["depth"].append(hm.depth)
                    r["spread"].append(hm.spread)
        fa_bg, fa, empty_bg, empty = [], [], [], []
        for _ in range(blanks):
            frame, bg = render_blank_pair(fam, rng)
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
            "n_presses": n * len(PRESS_KINDS), "n_blanks": blanks}
    return out


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
    return "\n".join(lines)

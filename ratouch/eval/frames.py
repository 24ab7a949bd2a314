"""Real tactile frames read for what they are: `ratouch eval frames DIR [--background F]`.

For a folder of a user's own sensor frames, and for the real frames the project can see
(Taxim's 72 presses of a rigid ball on a real GelSight and GelSight Mini with their no-contact
frames, `world.taxim_optics.real_presses`, and the two real DIGIT frames of
``../shared/data/reference_tactile``), each frame is queried with a plain mid-grey visual
image, so that touch alone must carry the answer. Per frame: the sensor family it was read
as, the contact reading (contact / no contact / uncertain) and its score, where the frame
differs from its background (the contact region, when a background is known), the touch-only
reading (`touch_reading`: the top caption of the query made for the press's regime),
RA-Touch's description and the tactile query's top neighbours.

Nothing is tuned on these frames: every threshold comes from renders (`ratouch train trust`).
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from scipy.ndimage import gaussian_filter, label

from ratouch.errors import ConfigError, DataNotFoundError
from ratouch.eval.judge.lexicon import MEMBERS
from ratouch.files import write_atomic
from ratouch.images import to_rgb_array
from ratouch.serve.trace import touch_reading
from ratouch.vocabulary import parse_adjectives
from ratouch.world.sensors import family

#: Image files `frames_in` reads from a folder.
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
#: The plain visual image beside every frame: mid-grey, so that touch alone answers.
GREY = 128
#: Words that make a reading "soft" or "hard" (the offline judge's groups, full members).
SOFT_WORDS = frozenset(w for w, groups in MEMBERS.items() if groups.get("soft", 0) >= 0.7)
HARD_WORDS = frozenset(w for w, groups in MEMBERS.items() if groups.get("hard", 0) >= 1.0)


@dataclass(frozen=True)
class Frame:
    """One frame to read: its name, pixels (uint8 RGB), background (or None) and, where
    known, the touch's centre (x, y) and radius in the frame's pixels."""

    name: str
    frame: np.ndarray
    background: np.ndarray | None = None
    centre: tuple[float, float] | None = None
    radius: float | None = None


def firmness(caption: str) -> str:
    """"soft", "hard", "both" or "neither": which of the judge's soft and hard words a
    reading uses."""
    words = set(parse_adjectives(caption))
    soft, hard = bool(words & SOFT_WORDS), bool(words & HARD_WORDS)
    return {(True, False): "soft", (False, True): "hard", (True, True): "both"}.get(
        (soft, hard), "neither")


def contact_region(frame: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Where a frame differs from its background: the largest connected region whose lightly
    blurred |difference| is above half of its 99.5th percentile (a boolean mask, the frame's
    size; empty when the frame equals its background)."""
    d = np.abs(frame.astype(np.float32) - background.astype(np.float32)).mean(2)
    d = gaussian_filter(d, 2.0)
    top = float(np.percentile(d, 99.5))
    if top <= 1.0:  # within a level of the background everywhere
        return np.zeros(d.shape, bool)
    labels, n = label(d > top / 2)
    if n == 0:
        return np.zeros(d.shape, bool)
    sizes = np.bincount(labels.ravel())[1:]
    return labels == 1 + int(np.argmax(sizes))


def overlaps(region: np.ndarray, centre: tuple[float, float], radius: float) -> bool:
    """Whether a region reaches the known touch disk (centre (x, y), radius, pixels)."""
    ys, xs = np.nonzero(region)
    if not len(xs):
        return False
    return bool(np.min((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2) <= radius ** 2)


def read_frame(pipeline, item: Frame, k: int = 5) -> dict:
    """What the pipeline makes of one frame (queried beside a mid-grey visual image)."""
    grey = np.full((224, 224, 3), GREY, np.uint8)
    result = pipeline.query(grey, item.frame, box=(0, 0, 224, 224), k=k,
                            background=item.background)
    tac = (result.get("trust") or {}).get("tactile") or {}
    tactile = (result.get("neighbours") or {}).get("tactile", [])
    adapted = (result.get("neighbours") or {}).get("adapted", [])
    read = touch_reading(result)
    row = {"frame": item.name, "sensor": (tac.get("sensor") or {}).get("family"),
           "background": item.background is not None,
           "state": tac.get("state"), "contact": tac.get("contact"),
           # called its background within the sensor's noise (the contact model not asked)
           "within_noise": tac.get("within_noise"),
           # the touch-only reading (`touch_reading`) and the query it came from
           "reading": read["caption"], "reading_query": read["query"],
           "firmness": firmness(read["caption"]),
           # the paper's tactile query's top caption, and the adapted one's (the press map's)
           "reading_tactile": tactile[0]["caption"] if tactile else "",
           "reading_adapted": adapted[0]["caption"] if adapted else "",
           "ra_touch": (result.get("description") or {}).get("ra_touch", ""),
           "neighbours": [n.get("caption") for n in tactile[:k]],
           "geometry": tac.get("geometry"), "structure": tac.get("structure"),
           "shape": tac.get("firmness"),
           # alone: which regime the press map's router reads the press in (the reading's)
           "press_regime": tac.get("press_regime"),
           "unfamiliar_sensor": bool(tac.get("unfamiliar_sensor")),
           "warnings": list(result.get("warnings", [])),
           "known_touch": item.centre is not None}
    if item.background is not None and item.centre is not None and item.radius is not None:
        row["region_overlaps_touch"] = overlaps(
            contact_region(item.frame, item.background), item.centre, item.radius)
    return row


def frames_in(folder: str | Path, background: str | Path | None = None) -> list[Frame]:
    """The image files of a folder (sorted by name; the background file itself left out), each
    with the background read from `background` when given.

    Raises:
        DataNotFoundError: the folder does not exist or holds no image file.
        DataError: an image cannot be read, or the background's size differs from a frame's.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataNotFoundError(f"{folder} is not a folder of tactile frames")
    bg_path = Path(background).resolve() if background is not None else None
    bg = to_rgb_array(bg_path, "background") if bg_path is not None else None
    files = [p for p in sorted(folder.iterdir())
             if p.suffix.lower() in FRAME_SUFFIXES and p.resolve() != bg_path]
    if not files:
        raise DataNotFoundError(
            f"{folder} holds no image file ({', '.join(FRAME_SUFFIXES)})")
    return [Frame(p.name, to_rgb_array(p, "tactile image"), bg) for p in files]


def taxim_frames(calibration: str, alone: bool = False) -> list[Frame]:
    """Taxim's real presses of one calibration with their background, and the background
    read alone and against itself (`world.taxim_optics.real_presses`); `alone`: each press
    also without its background (named "... alone")."""
    from ratouch.world.taxim_optics import real_presses

    d = real_presses(calibration)
    bg = d["background"]
    out = [Frame(f"{calibration} press {i}", f, bg, (float(c[0]), float(c[1])), float(r))
           for i, (f, c, r) in enumerate(zip(d["frames"], d["centres"], d["radii"]))]
    if alone:
        out += [Frame(f"{calibration} press {i} alone", f, None, (float(c[0]), float(c[1])),
                      float(r))
                for i, (f, c, r) in enumerate(zip(d["frames"], d["centres"], d["radii"]))]
    out += [Frame(f"{calibration} background alone", bg),
            Frame(f"{calibration} background against itself", bg, bg)]
    return out


def digit_frames(folder: Path) -> list[Frame]:
    """The two real DIGIT frames: the pressed frame (alone and against the tacto background)
    and the tacto background (alone and against itself); [] where the folder lacks them."""
    ref = family("digit").reference
    assert ref is not None  # the DIGIT's row names its real frames
    pressed, blank = folder / ref.pressed, folder / ref.background
    if not (pressed.is_file() and blank.is_file()):
        return []
    p, b = to_rgb_array(pressed, "tactile image"), to_rgb_array(blank, "background")
    return [Frame("digit pressed", p), Frame("digit pressed against the tacto background", p, b),
            Frame("digit background alone", b), Frame("digit background against itself", b, b)]


def read_frames(pipeline, frames: Iterable[Frame], k: int = 5) -> list[dict]:
    """`read_frame` of every frame."""
    return [read_frame(pipeline, f, k) for f in frames]


def summarise(rows: list[dict]) -> dict:
    """Counts over read frames: presses (frames with a known touch) detected, their contact
    regions reaching the touch, read as soft or hard; blank frames (names with "background")
    recognised as no contact or left uncertain; the distinct readings."""
    presses = [r for r in rows if "region_overlaps_touch" in r or "pressed" in r["frame"]]
    # presses with a known touch read without any background (`taxim_frames(alone=True)`)
    alone = [r for r in rows if r.get("known_touch") and not r["background"]]
    blanks = [r for r in rows if "background" in r["frame"] and "pressed" not in r["frame"]]
    readings = [r["reading"] for r in rows if r["state"] == "contact"]
    return {
        "presses": len(presses),
        "presses_detected": sum(r["state"] == "contact" for r in presses),
        "presses_region_on_touch": sum(bool(r.get("region_overlaps_touch")) for r in presses),
        "presses_read_soft": sum(r["firmness"] == "soft" for r in presses),
        "presses_read_hard": sum(r["firmness"] == "hard" for r in presses),
        # firmness read from the press's shape against its background (none alone)
        "presses_shape_soft": sum((r.get("shape") or {}).get("reads") == "soft"
                                  for r in presses),
        "presses_shape_hard": sum((r.get("shape") or {}).get("reads") == "hard"
                                  for r in presses),
        "blanks": len(blanks),
        "blanks_no_contact": sum(r["state"] == "no contact" for r in blanks),
        "blanks_uncertain": sum(r["state"] == "uncertain" for r in blanks),
        "distinct_readings": len(set(readings)),
        **({"presses_alone": len(alone),
            "presses_alone_detected": sum(r["state"] == "contact" for r in alone),
            "presses_alone_refused": sum(r["state"] == "no contact" for r in alone),
            "presses_alone_read_hard": sum(r["firmness"] == "hard" for r in alone
                                           if r["state"] != "no contact")}
           if alone else {}),
    }


def format_frames(rows: list[dict]) -> str:
    """A plain table of read frames and their summary."""
    if not rows:
        raise ConfigError("no frames to show")
    lines = [f"{'frame':<44} {'sensor':<9} {'state':<11} {'contact':>8} {'depth':>14} "
             f"{'spread':>6} {'shape':>10}  reading -> RA-Touch"]
    for r in rows:
        score = ("noise" if r.get("within_noise") else
                 "-" if r["contact"] is None else f"{r['contact']:.2f}")
        geo = r.get("geometry") or {}
        depth = (f"{geo['depth']:.3g} {'mm' if geo['units'] == 'mm' else 'r.u.'}"
                 if geo else "-")
        spread = f"{geo['spread']:.2f}" if geo else "-"
        shape = r.get("shape")
        shape = f"{shape['reads']} {shape['soft']:.2f}" if shape else "-"
        lines.append(f"{r['frame'][:44]:<44} {str(r['sensor']):<9} {str(r['state']):<11} "
                     f"{score:>8} {depth:>14} {spread:>6} {shape:>10}  {r['reading'] or '-'} -> "
                     f"{r['ra_touch'] or '-'}")
    s = summarise(rows)
    lines.append("")
    lines.append(
        f"presses: {s['presses_detected']}/{s['presses']} detected, "
        f"{s['presses_read_soft']} read as soft, {s['presses_read_hard']} as hard"
        + (f" (from shape: {s['presses_shape_soft']} soft, {s['presses_shape_hard']} hard)"
           if s["presses_shape_soft"] + s["presses_shape_hard"] else "")
        + (f", {s['presses_region_on_touch']} with the contact region on the known touch"
           if any("region_overlaps_touch" in r for r in rows) else "")
        + f"; blank frames: {s['blanks_no_contact']}/{s['blanks']} no contact, "
        f"{s['blanks_uncertain']} uncertain; {s['distinct_readings']} distinct readings"
        + (f"; presses without their background: {s['presses_alone_detected']}/"
           f"{s['presses_alone']} contact, {s['presses_alone_refused']} no contact, "
           f"{s['presses_alone_read_hard']} read hard" if "presses_alone" in s else ""))
    return "\n".join(lines)


def height_sheet(trust, frames: Iterable[Frame], path: str | Path, columns: int = 4,
                 tile: int = 160) -> Path:
    """A contact sheet (PNG): each frame beside its height map (read against its background by
    the guessed family's lookup; frames without a background get none), captioned with the
    frame's name, depth, spread and the firmness read from its shape. Written atomically.

    Raises:
        ConfigError: no frame, or no geometry calibration loaded.
    """
    items = list(frames)
    if not items:
        raise ConfigError("no frames to draw")
    if trust is None or trust.geometry is None:
        raise ConfigError("no geometry calibration loaded: `ratouch train geometry`")
    th = tile * 3 // 4
    cell_w, cell_h = 2 * tile + 8, th + 30
    rows = (len(items) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * cell_w, rows * cell_h), (250, 250, 250))
    draw = ImageDraw.Draw(sheet)
    for n, item in enumerate(items):
        x, y = (n % columns) * cell_w, (n // columns) * cell_h
        f = item.frame if item.frame.shape[0] <= item.frame.shape[1] else item.frame.transpose(
            1, 0, 2)
        sheet.paste(Image.fromarray(f).resize((tile, th)), (x, y))
        caption = item.name[:30]
        if item.background is not None:
            read = trust.read_geometry(item.frame, item.background)
            hm = None if read is None else read["height"]
            if hm is not None:
                img = hm.image()
                if img.shape[0] > img.shape[1]:
                    img = img.transpose(1, 0, 2)
                sheet.paste(Image.fromarray(img).resize((tile, th)), (x + tile + 4, y))
                unit = "mm" if hm.units == "mm" else "r.u."
                caption += f" | {hm.depth:.2g} {unit}, spread {hm.spread:.2f}"
                if read["firmness"] is not None:
                    caption += f", {read['firmness']['reads']}"
        else:
            draw.text((x + tile + 12, y + th // 2), "no background:\nno height map",
                      fill=(90, 90, 90))
        draw.text((x + 2, y + th + 4), caption, fill=(20, 20, 20))
    buf = io.BytesIO()
    sheet.save(buf, format="PNG")
    return write_atomic(path, buf.getvalue())


__all__ = ["height_sheet", "Frame", "firmness", "contact_region", "overlaps", "read_frame", "read_frames",
           "frames_in", "taxim_frames", "digit_frames", "summarise", "format_frames"]

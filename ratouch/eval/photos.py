"""The visible real photos: a small set of real images to look at and smoke-test with.

Seven photos bundled with scikit-image whose terms are public domain or CC0 (each one's terms
are in :data:`PHOTO_LICENCES`, as scikit-image's ``skimage.data`` docstrings state them), and
the two real DIGIT frames in ``../shared/data/reference_tactile/`` beside the checkout (read
in place, never copied into the repo; left out where that folder is absent).

What this module reports is for looking only: no threshold is set on these photos, nothing is
tuned on them, and they are too few to measure anything. :func:`evaluate_photos` shows what
the served pipeline makes of each photo as the visual image (the visual novelty and whether it
was flagged, the route that answered it, what the frozen prior's ImageNet classifier sees in
the crop, the image query's neighbours); :func:`evaluate_reference_tactile` shows what it makes
of the pressed DIGIT frame with and without a no-contact frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from ratouch.encoders.prior import imagenet_names, load_prior
from ratouch.encoders.prior_registry import DEFAULT_PRIOR
from ratouch.errors import ConfigError, DataNotFoundError
from ratouch.images import QUERY_MAX_SIDE, crop_box, tvl_contact_box
from ratouch.paths import REPO
from ratouch.search.index import top_k
from ratouch.serve.request import QueryRequest, answer_one

#: Each bundled scikit-image photo's terms, as `skimage.data`'s docstrings state them. Only
#: public-domain and CC0 photos are in the set.
PHOTO_LICENCES: dict[str, str] = {
    "chelsea": "CC0 (photographer Stefan van der Walt; 'No copyright restrictions')",
    "coffee": "CC0 (photographer Rachel Michetti; 'No copyright restrictions')",
    "brick": "CC0 (CC0Textures 'Bricks25'; warped, rotated, cropped and made grey by "
             "scikit-image)",
    "grass": "CC0 (DeviantArt linolafett 'Grass 01'; cropped and made grey by scikit-image)",
    "gravel": "CC0 (CC0Textures 'Gravel04'; rescaled, cropped and made grey by scikit-image)",
    "rocket": "public domain (SpaceX photo of Falcon 9 at Launch Complex 40, released into "
              "the public domain by SpaceX)",
    "astronaut": "public domain (NASA Great Images, Eileen Collins; 'No known copyright "
                 "restrictions, released into the public domain')",
}
#: The real DIGIT frames: name -> (file in the reference folder, terms, what it shows).
REFERENCE_TACTILE: dict[str, tuple[str, str, str]] = {
    "digit_pressed": (
        "digit_aurova_digit_raw.png",
        "MIT (AUROVA-LAB/aurova_grasping); its data set asks for non-profit research use and "
        "citation of Castaño-Amorós and Gil",
        "a DIGIT frame with an object pressed into the gel"),
    "digit_background": (
        "digit_tacto_bg_digit_240_320.png",
        "MIT (facebookresearch/tacto, examples/conf/bg_digit_240_320.jpg)",
        "a DIGIT's no-contact frame (the sensor's own background)"),
}
#: What the background frame is, said beside every result that uses it.
BACKGROUND_NOTE = ("the background is a no-contact frame of a DIGIT from facebookresearch/tacto, "
                   "not necessarily the same unit as the pressed frame (AUROVA-LAB): it "
                   "removes the DIGIT's common LED layout, not that unit's own gel, markers "
                   "and vignetting")
#: The photo used as the visual image beside the tactile frames by default.
DEFAULT_VISUAL = "chelsea"


def reference_dir() -> Path:
    """The real DIGIT frames' folder: ``../shared/data/reference_tactile`` beside the checkout."""
    return REPO.parent / "shared" / "data" / "reference_tactile"


def photo_names() -> list[str]:
    """Every name `load_photo` knows (the DIGIT frames whether or not their folder exists)."""
    return [*PHOTO_LICENCES, *REFERENCE_TACTILE]


def _rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.stack([image] * 3, axis=-1)
    return np.ascontiguousarray(image[..., :3].astype(np.uint8))


def load_photo(name: str) -> np.ndarray:
    """One photo of the set as an (H, W, 3) uint8 RGB array (grey photos repeated over RGB).

    Raises:
        ConfigError: If `name` is not in the set (the message lists the names).
        DataNotFoundError: If it is a DIGIT frame and the reference folder lacks it.
    """
    if name in PHOTO_LICENCES:
        import skimage.data

        return _rgb(getattr(skimage.data, name)())
    if name in REFERENCE_TACTILE:
        path = reference_dir() / REFERENCE_TACTILE[name][0]
        if not path.is_file():
            raise DataNotFoundError(f"real DIGIT frame {name!r}: {path} is missing (the "
                                    f"shared reference data sits beside the checkout)")
        with Image.open(path) as im:
            return _rgb(np.asarray(im.convert("RGB")))
    raise ConfigError(f"unknown photo {name!r}; known photos: {photo_names()}")


def photo_set(tactile: bool = True) -> list[dict]:
    """The visible photos: [{"name", "image", "licence", "kind" ("photo" or "tactile"),
    "about"}], the scikit-image photos first, then the DIGIT frames that are present
    (`tactile=False` leaves them out)."""
    rows = [{"name": n, "image": load_photo(n), "licence": lic, "kind": "photo",
             "about": f"skimage.data.{n}()"} for n, lic in PHOTO_LICENCES.items()]
    if tactile:
        for n, (file, lic, about) in REFERENCE_TACTILE.items():
            if (reference_dir() / file).is_file():
                rows.append({"name": n, "image": load_photo(n), "licence": lic,
                             "kind": "tactile", "about": about})
    return rows


# --------------------------------------------------------------------------------- looking

def _encoders(pipeline):
    return getattr(pipeline, "encoders", None)


def _prior_and_size(pipeline, prior=None, size: int | None = None):
    """The visual prior to classify crops with and the side it reads them at: the pipeline's
    encoders' own prior, else `DEFAULT_PRIOR`; at the prior's own input size (what the photo route
    reads), unless `size` is given."""
    if prior is None:
        prior = getattr(_encoders(pipeline), "visual_prior", None)
    if prior is None:
        prior = load_prior(DEFAULT_PRIOR)
    return prior, int(size or prior.spec.input_size)


def _crop(image: np.ndarray, box) -> tuple[np.ndarray, list[int]]:
    if box is None:
        box = tvl_contact_box(image.shape[1], image.shape[0])
    return crop_box(image, box, max_side=QUERY_MAX_SIDE), [int(v) for v in box]


def _top_imagenet(prior, crop: np.ndarray, size: int, top: int = 3) -> list[list]:
    probs = prior.classify([crop], size)[0]
    names = imagenet_names()
    return [[names[j], round(float(probs[j]), 4)] for j in top_k(probs[None], top)[1][0]]


def _neighbours(result: dict, mode: str, k: int) -> list[dict]:
    return [{"class_name": n.get("class_name"), "caption": n.get("caption")}
            for n in (result.get("neighbours") or {}).get(mode, [])[:k]]


def _visual_trust(result: dict) -> dict:
    vis = (result.get("trust") or {}).get("visual") or {}
    return {"novelty": vis.get("novelty"), "threshold": vis.get("threshold"),
            "novel": vis.get("novel"), "space": vis.get("space")}


def evaluate_photos(pipeline, k: int = 5, names: list[str] | None = None, prior=None,
                    prior_size: int | None = None) -> list[dict]:
    """What the pipeline makes of each photo as the visual image (centred box, no tactile).

    Args:
        pipeline: a `RATouchPipeline` (or anything with its `query`).
        k: neighbours per photo.
        names: photos to query (default: the scikit-image photos of :func:`photo_set`).
        prior: the visual prior whose ImageNet classifier reads each crop (default: the
            pipeline's encoders' prior, else `DEFAULT_PRIOR`).
        prior_size: the side it reads crops at (default: the prior's own input size, the
            size the photo route reads).

    Returns:
        Per photo: {"name", "licence", "size" [W, H], "box", "novelty", "threshold", "novel"
        (flagged), "visual_route" ("photo" or "render"), "route_classes" (the photo route's
        corpus classes, else []), "coverage", "imagenet_top3" [[name, probability]], "prior",
        "prior_size", "neighbours" [{"class_name", "caption"}] (the image query's top k),
        "warnings"}. No thresholds are set on these photos: this is for looking only.
    """
    names = list(PHOTO_LICENCES) if names is None else list(names)
    prior, size = _prior_and_size(pipeline, prior, prior_size)
    rows = []
    for name in names:
        image = load_photo(name)
        result = pipeline.query(image, None, k=k)
        crop, box = _crop(image, result.get("box"))
        route = result.get("visual_route") or {}
        rows.append({
            "name": name, "licence": PHOTO_LICENCES.get(name) or REFERENCE_TACTILE[name][1],
            "size": [int(image.shape[1]), int(image.shape[0])], "box": box,
            **_visual_trust(result),
            "visual_route": route.get("route", "render"),
            "route_classes": [list(c) for c in route.get("classes", [])],
            "coverage": route.get("coverage"),
            "imagenet_top3": _top_imagenet(prior, crop, size),
            "prior": prior.name, "prior_size": size,
            "neighbours": _neighbours(result, "image", k),
            "warnings": list(result.get("warnings", []))})
    return rows


def evaluate_reference_tactile(pipeline, visual: str = DEFAULT_VISUAL, k: int = 5
                               ) -> list[dict]:
    """What the pipeline makes of the pressed DIGIT frame, without and with the DIGIT
    background frame, and of the background frame itself (which shows no contact).

    The visual image is a photo of the set (`visual`, centred box); only the tactile side is
    of interest here. Returns [] where the reference folder lacks the frames.

    Returns:
        Per case: {"case", "tactile", "background" (the background frame's name or None),
        "contact", "contact_threshold", "no_contact", "tactile_novelty",
        "tactile_threshold", "tactile_novel", "ra_touch", "neighbours" (the tactile query's
        top k), "visual", "note", "warnings"}.
    """
    folder = reference_dir()
    if not all((folder / f).is_file() for f, _, _ in REFERENCE_TACTILE.values()):
        return []
    image = load_photo(visual)
    pressed, bg = load_photo("digit_pressed"), load_photo("digit_background")
    cases = [("pressed, no background", "digit_pressed", pressed, None, None),
             ("pressed, with background", "digit_pressed", pressed, "digit_background", bg),
             ("background alone (no contact)", "digit_background", bg, None, None)]
    rows = []
    for case, tname, frame, bname, background in cases:
        result = pipeline.query(image, frame, k=k, background=background)
        tac = (result.get("trust") or {}).get("tactile") or {}
        note = (f"{BACKGROUND_NOTE}" if bname else
                "no background: the frame's own smooth illumination field is taken away")
        rows.append({
            "case": case, "tactile": tname, "background": bname, "visual": visual,
            "contact": tac.get("contact"), "contact_threshold": tac.get("contact_threshold"),
            "no_contact": tac.get("no_contact"), "tactile_novelty": tac.get("novelty"),
            "tactile_threshold": tac.get("threshold"), "tactile_novel": tac.get("novel"),
            "ra_touch": (result.get("description") or {}).get("ra_touch", ""),
            "neighbours": _neighbours(result, "tactile", k), "note": note,
            "warnings": list(result.get("warnings", []))})
    return rows


# --------------------------------------------------------------------------------- tables

def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _num(x: Any, fmt: str = ".3f") -> str:
    return "-" if x is None else format(x, fmt)


def _flag(x: Any) -> str:
    return "-" if x is None else ("yes" if x else "no")


def format_photos(rows: list[dict]) -> str:
    """The photos' rows as a markdown table (for looking; no thresholds are set on them)."""
    out = ["| photo | novelty / threshold | flagged | route | ImageNet top-3 (prior) | "
           "image neighbours: class (caption) | licence |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        top = ", ".join(f"{n} {p:.2f}" for n, p in r["imagenet_top3"])
        neigh = "; ".join(f"{n['class_name']} ({n['caption']})" for n in r["neighbours"])
        out.append("| " + " | ".join(_cell(c) for c in (
            r["name"], f"{_num(r['novelty'])} / {_num(r['threshold'])}", _flag(r["novel"]),
            r["visual_route"], f"{top} ({r['prior']}@{r['prior_size']})", neigh or "-",
            r["licence"])) + " |")
    return "\n".join(out)


def format_reference_tactile(rows: list[dict]) -> str:
    """The DIGIT frames' rows as a markdown table, with the background's caveat below."""
    if not rows:
        return f"(no real DIGIT frames: {reference_dir()} lacks them)"
    out = ["| case | contact / threshold | no contact | tactile novelty / threshold | "
           "RA-Touch description |", "|---|---|---|---|---|"]
    for r in rows:
        out.append("| " + " | ".join(_cell(c) for c in (
            r["case"], f"{_num(r['contact'], '.4f')} / {_num(r['contact_threshold'], '.4f')}",
            _flag(r["no_contact"]),
            f"{_num(r['tactile_novelty'])} / {_num(r['tactile_threshold'])}",
            r["ra_touch"] or "-")) + " |")
    out.append("")
    out.append(f"Visual image: {rows[0]['visual']}. Note: {BACKGROUND_NOTE}.")
    return "\n".join(out)


# ------------------------------------------------------------------ real photo + real touch

#: The visible real pairs: a scikit-image photo with a real press (Taxim's GelSight and
#: GelSight Mini ball presses, against their backgrounds; the reference DIGIT frame where
#: present). None of them has a tactile label: the table is for reading, side by side.
REAL_PAIRS = (("brick", "gelsight", 0), ("gravel", "gelsight_mini", 0), ("grass", "gelsight", 6),
              ("coffee", "gelsight_mini", 6), ("chelsea", "gelsight", 12), ("grass", "digit", 0))


def evaluate_real_pairs(pipeline, k: int = 5) -> list[dict]:
    """Per visible real pair (`REAL_PAIRS`): RA-Touch as each retrieval system answers
    (`RETRIEVAL_SYSTEMS`: the paper's, the gated one, the text one, the fallback), the
    baseline, a copy of each query mode's top-1 caption, and how far the gate let touch steer
    (the photo's centred box; the press against its background).

    Returns:
        [{"photo", "touch", *RETRIEVAL_SYSTEMS, "baseline", "copy": {mode: caption},
        "touch_weight", "why", "tactile_novel", "unfamiliar_sensor"}]; pairs whose frames
        are missing are left out.
    """
    from ratouch.eval.frames import digit_frames, taxim_frames
    from ratouch.search.modes import QUERY_MODES, RETRIEVAL_SYSTEMS

    rows = []
    for photo, sensor, index in REAL_PAIRS:
        frames = (digit_frames(reference_dir()) if sensor == "digit"
                  else taxim_frames(sensor))
        frames = [f for f in frames if f.background is not None and f.background is not f.frame
                  and "against itself" not in f.name]
        if len(frames) <= index:
            continue
        f = frames[index]
        image = load_photo(photo)
        out = {}
        for system in RETRIEVAL_SYSTEMS:
            out[system] = answer_one(pipeline, QueryRequest.decode(
                image, f.frame, k=k, background=f.background, retrieval=system)).to_dict()
        res = out["gated"]
        tac = (res.get("trust") or {}).get("tactile") or {}
        rows.append({
            "photo": photo, "touch": f.name,
            **{system: o["description"]["ra_touch"] for system, o in out.items()},
            "baseline": res["description"]["baseline"],
            "copy": {m: (res["neighbours"].get(m) or [{}])[0].get("caption")
                     for m in QUERY_MODES if m in res["neighbours"]},
            "touch_weight": (res.get("retrieval") or {}).get("touch_weight"),
            "why": (res.get("retrieval") or {}).get("why", []),
            "tactile_novel": tac.get("novel"), "unfamiliar_sensor": tac.get("unfamiliar_sensor")})
    return rows


def format_real_pairs(rows: list[dict]) -> str:
    """The real pairs as a Markdown table."""
    from ratouch.search.modes import RETRIEVAL_SYSTEMS

    modes = list(rows[0]["copy"]) if rows else []
    systems = [s for s in RETRIEVAL_SYSTEMS if not rows or s in rows[0]]
    head = ["photo", "touch", "touch weight", *(f"RA-Touch ({s})" for s in systems),
            "baseline", *(f"copy {m} top-1" for m in modes)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        w = r["touch_weight"]
        cells = [r["photo"], r["touch"], "–" if w is None else f"{w:.2f}",
                 *(r[s] or "–" for s in systems), r["baseline"] or "–",
                 *(r["copy"].get(m) or "–" for m in modes)]
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return "\n".join(lines)

"""The visible real photos: the set, its licences, and the tables made from a pipeline's answers
(a stub pipeline here; the real pipeline's run is done by hand after retraining)."""

from __future__ import annotations

import numpy as np
import pytest

from ratouch.errors import ConfigError, DataNotFoundError
from ratouch.eval.photos import (
    PHOTO_LICENCES,
    REFERENCE_TACTILE,
    evaluate_photos,
    evaluate_reference_tactile,
    format_photos,
    format_reference_tactile,
    load_photo,
    photo_set,
    reference_dir,
)

pytest.importorskip("skimage.data")
NAMES = ["chelsea", "coffee", "brick", "grass", "gravel", "rocket", "astronaut"]


class StubPipeline:
    """Answers `query` in `RATouchPipeline.query`'s documented shape, and records the calls."""

    def __init__(self):
        self.calls = []

    def query(self, visual, tactile=None, box=None, k=5, label=None, background=None):
        self.calls.append({"visual": visual, "tactile": tactile, "box": box, "k": k,
                           "background": background})
        h, w = np.asarray(visual).shape[:2]
        side = min(h, w) // 2
        box = [(w - side) // 2, (h - side) // 2, (w + side) // 2, (h + side) // 2]
        photo = w == 451   # chelsea goes the photo route, the rest the render route
        neigh = [{"id": i, "score": 0.5, "class_name": f"class {i}",
                  "caption": "soft | fuzzy", "description": "d", "source": "s"}
                 for i in range(k)]
        tactile_block = None if tactile is None else {
            "novelty": 0.3, "threshold": 0.5, "novel": False,
            "contact": 0.0 if background is not None and tactile is background else 0.05,
            "contact_threshold": 0.01, "no_contact": False, "background": background is not None}
        return {
            "neighbours": {"image": neigh, **({"tactile": neigh, "joint": neigh}
                                              if tactile is not None else {})},
            "description": {"ra_touch": "smooth, hard" if tactile is not None else "",
                            "baseline": ""},
            "warnings": ["no contact box given: used TVL's centred crop"], "box": box,
            "visual_route": ({"route": "photo", "classes": [["tabby", 0.6]], "coverage": 0.7,
                              "note": "n"} if photo else {"route": "render"}),
            "trust": {"visual": {"novelty": 2.0 if photo else 0.1, "threshold": 1.0,
                                 "novel": photo, "space": "prior"},
                      "tactile": tactile_block}}


class StubPrior:
    name = "stub"

    class spec:
        input_size = 224

    def classify(self, images, size=None):
        p = np.full((len(images), 1000), 0.5 / 997, np.float32)
        p[:, 281], p[:, 282], p[:, 285] = 0.3, 0.15, 0.05   # tabby, tiger cat, Egyptian cat
        return p


def test_photo_set_holds_the_listed_photos_with_licences():
    rows = photo_set(tactile=False)
    assert [r["name"] for r in rows] == NAMES == list(PHOTO_LICENCES)
    for r in rows:
        assert r["kind"] == "photo"
        assert r["licence"].startswith(("CC0", "public domain"))
        img = r["image"]
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert set(PHOTO_LICENCES) == set(NAMES)


def test_reference_frames_are_read_in_place():
    rows = [r for r in photo_set() if r["kind"] == "tactile"]
    present = [n for n, (f, _, _) in REFERENCE_TACTILE.items() if (reference_dir() / f).is_file()]
    assert [r["name"] for r in rows] == present
    for r in rows:
        assert r["image"].shape == (320, 240, 3) and "MIT" in r["licence"]


def test_unknown_photo_names_the_known_ones():
    with pytest.raises(ConfigError, match="known photos") as e:
        load_photo("lena")
    for n in NAMES:
        assert n in str(e.value)


def test_missing_reference_frame(monkeypatch, tmp_path):
    monkeypatch.setattr("ratouch.eval.photos.reference_dir", lambda: tmp_path)
    with pytest.raises(DataNotFoundError):
        load_photo("digit_pressed")
    assert [r["kind"] for r in photo_set()] == ["photo"] * len(NAMES)
    assert evaluate_reference_tactile(StubPipeline()) == []
    assert "lacks them" in format_reference_tactile([])


def test_evaluate_photos_with_a_stub_pipeline():
    stub = StubPipeline()
    rows = evaluate_photos(stub, k=5, prior=StubPrior())
    assert [r["name"] for r in rows] == NAMES
    assert all(c["tactile"] is None and c["box"] is None and c["k"] == 5 for c in stub.calls)
    cat = rows[0]
    assert cat["visual_route"] == "photo" and cat["novel"] is True
    assert cat["novelty"] == 2.0 and cat["threshold"] == 1.0
    assert cat["imagenet_top3"] == [["tabby", 0.3], ["tiger cat", 0.15], ["Egyptian cat", 0.05]]
    assert cat["prior_size"] == 224 and len(cat["neighbours"]) == 5
    assert rows[1]["visual_route"] == "render" and rows[1]["novel"] is False
    table = format_photos(rows)
    lines = table.splitlines()
    assert len(lines) == 2 + len(NAMES)
    assert all(line.startswith("|") and line.endswith("|") for line in lines)
    assert lines[0].count(" | ") == lines[2].count(" | ")   # pipes in captions are escaped
    assert "tabby 0.30" in lines[2] and "class 0 (soft \\| fuzzy)" in lines[2]


def test_evaluate_reference_tactile_with_a_stub_pipeline():
    if not all((reference_dir() / f).is_file() for f, _, _ in REFERENCE_TACTILE.values()):
        pytest.skip(f"no real DIGIT frames in {reference_dir()}")
    stub = StubPipeline()
    rows = evaluate_reference_tactile(stub)
    assert [r["case"] for r in rows] == ["pressed, no background", "pressed, with background",
                                         "background alone (no contact)"]
    assert [c["background"] is not None for c in stub.calls] == [False, True, False]
    assert rows[1]["background"] == "digit_background" and "same unit" in rows[1]["note"]
    assert rows[0]["contact"] == 0.05 and rows[0]["no_contact"] is False
    assert rows[0]["ra_touch"] == "smooth, hard"
    table = format_reference_tactile(rows)
    assert table.count("\n| ") == 3 and "not necessarily the same unit" in table


def test_cli_eval_photos_help(capsys):
    from ratouch.cli import main

    with pytest.raises(SystemExit) as e:
        main(["eval", "photos", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "--encoder" in out and "--json" in out and "neighbours per photo" in out

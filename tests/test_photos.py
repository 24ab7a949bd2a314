"""The visible real photos: the set, its licences, the tables made from a pipeline's answers
(a stub pipeline), and how the photo route ranks a photo's image neighbours (a stub classifier
over a made-up corpus, then the shipped pipeline on the cat photo)."""

from __future__ import annotations

import numpy as np
import pytest

from ratouch.encoders.prior import imagenet_to_world
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
from ratouch.serve.photo import PhotoRoute
from ratouch.world.objects import OBJECT_CLASSES

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


# ------------------------------------------------------------------ the photo route's ranking

class ClassPrior:
    """A visual prior whose ImageNet classifier puts the given probabilities on the given
    world classes (through one ImageNet class mapped to each); the rest of the probability
    sits on ImageNet classes that map to no world class."""

    name = "stub"

    class spec:
        input_size = 224

    def __init__(self, world: dict[str, float]):
        mapping = imagenet_to_world()
        first: dict[str, int] = {}
        for j in sorted(mapping):
            first.setdefault(OBJECT_CLASSES[mapping[j]].name, j)
        unmapped = [j for j in range(1000) if j not in mapping]
        self.p = np.zeros(1000, np.float32)
        for name, prob in world.items():
            self.p[first[name]] = prob
        self.p[unmapped] = (1 - sum(world.values())) / len(unmapped)

    def classify(self, images, size=None):
        return np.tile(self.p, (len(images), 1))


def _unit(v):
    v = np.asarray(v, np.float32)
    return v / np.linalg.norm(v)


def _mapped_classes() -> list[str]:
    """The world classes some ImageNet class maps to, other than tabby and teapot."""
    mapped = {OBJECT_CLASSES[k].name for k in imagenet_to_world().values()}
    assert {"tabby", "teapot"} <= mapped
    return sorted(mapped - {"tabby", "teapot"})


def _mixture_trap():
    """Tabby entries along e0, teapot entries along e1, and a third class whose entries lie
    between them: the classifier says tabby 0.40, teapot 0.35, third class 0."""
    third = _mapped_classes()[0]
    names = ["teapot", third, "tabby", "teapot", third, "tabby", "tabby", "teapot", third]
    emb = np.stack([_unit([0, 1, 0.1]), _unit([1, 1, 0]), _unit([1, -0.1, 0]),
                    _unit([0, 1, 0]), _unit([1, 1, 0.05]), _unit([1, 0, 0]),
                    _unit([1, 0.1, 0]), _unit([0.1, 1, 0]), _unit([1, 1, -0.05])])
    return third, names, emb, ClassPrior({"tabby": 0.40, "teapot": 0.35})


def test_photo_neighbours_are_the_most_probable_class_first_not_the_mixtures_nearest():
    third, names, emb, prior = _mixture_trap()
    route = PhotoRoute(prior, names, emb)
    photo = route.query(np.zeros((32, 32, 3), np.uint8))
    assert [n for n, _ in photo.classes] == ["tabby", "teapot"]
    # the prototype mixture lies nearest to the third class, which the classifier rules out
    assert names[int(np.argmax(emb @ photo.query))] == third
    scores, ids = route.neighbours(photo, 9)
    assert [names[i] for i in ids] == ["tabby"] * 3 + ["teapot"] * 3 + [third] * 3
    assert np.allclose(scores, [0.40] * 3 + [0.35] * 3 + [0] * 3)
    # within a class: nearest to the photo's query vector first (e0 leaning towards e1)
    assert list(ids[:3]) == [6, 5, 2] and list(ids[3:6]) == [7, 3, 0]
    assert ids.dtype == np.int64 and scores.dtype == np.float32
    # k caps the list; a corpus-wide k lists every entry once
    assert list(route.neighbours(photo, 2)[1]) == [6, 5]
    assert sorted(route.neighbours(photo, 50)[1]) == list(range(9))
    assert "scored by that probability" in photo.note


def test_photo_neighbours_when_the_corpus_lacks_the_photos_class():
    """The classifier's top class is not in the corpus: the neighbours are of the most probable
    class the corpus has, and the note says the corpus's classes hold little probability."""
    third, names, emb, _ = _mixture_trap()
    absent = _mapped_classes()[1]
    prior = ClassPrior({absent: 0.80, "teapot": 0.04, "tabby": 0.01})
    route = PhotoRoute(prior, names, emb)
    photo = route.query(np.zeros((32, 32, 3), np.uint8))
    assert [n for n, _ in photo.classes] == ["teapot", "tabby"]
    assert [names[i] for i in route.neighbours(photo, 4)[1]] == ["teapot"] * 3 + ["tabby"]
    assert photo.coverage == pytest.approx(0.05, abs=1e-4)
    assert "hold only 5%" in photo.note


def test_a_real_photos_image_neighbours_are_its_top_class_first(pipeline):
    """The shipped pipeline on the cat photo: the image neighbours are the corpus entries of
    the class the classifier finds most probable, scored by that probability, then the next
    class's; the result has the shape of any query's."""
    row = evaluate_photos(pipeline, k=5, names=["chelsea"])[0]
    assert row["visual_route"] == "photo"
    result = pipeline.query(load_photo("chelsea"), None, k=5)
    classes = result["visual_route"]["classes"]
    image = result["neighbours"]["image"]
    count = {}
    for e in pipeline.corpus.entries:
        count[e.class_name] = count.get(e.class_name, 0) + 1
    top, p_top = classes[0]
    first = min(5, count[top])
    assert [n["class_name"] for n in image[:first]] == [top] * first
    assert [n["score"] for n in image[:first]] == [round(p_top, 4)] * first
    assert all(a["score"] >= b["score"] for a, b in zip(image, image[1:]))
    probability = dict(classes)
    assert all(n["score"] == round(probability[n["class_name"]], 4) for n in image
               if n["class_name"] in probability)
    assert [n["class_name"] for n in row["neighbours"]] == [n["class_name"] for n in image]
    assert all(set(n) == {"id", "score", "class_name", "caption", "description", "source"}
               for n in image)
    assert list(result["neighbours"]) == ["image"]


@pytest.mark.slow
def test_the_visible_real_pairs_through_every_retrieval_system(real_pipeline):
    """`ratouch eval photos --pairs`: per visible real pair, RA-Touch as every retrieval system
    answers (`RETRIEVAL_SYSTEMS`), the baseline, a copy of each mode's top-1 caption and the
    gate's weight; the table has a column per system."""
    from ratouch.eval.photos import REAL_PAIRS, evaluate_real_pairs, format_real_pairs
    from ratouch.search.modes import RETRIEVAL_SYSTEMS

    rows = evaluate_real_pairs(real_pipeline, k=5)
    assert 0 < len(rows) <= len(REAL_PAIRS)
    for r in rows:
        assert all(r[s] for s in RETRIEVAL_SYSTEMS) and r["baseline"]
        assert {"image", "joint"} <= set(r["copy"]) and 0 <= r["touch_weight"] <= 1
    table = format_real_pairs(rows)
    assert all(f"RA-Touch ({s})" in table for s in RETRIEVAL_SYSTEMS)
    assert table.count("\n") == len(rows) + 1

"""Real priors, as a user meets them: touch read the same from a crisp and a faint sensor,
with or without the sensor's background; a real photo answered through the visual prior's
classifier, with a note saying so; renders still answered by the encoders' own head."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ratouch.encoders.default import (
    CONTRAST_FLOOR,
    TACTILE_CHANNELS,
    DefaultConfig,
    PriorHead,
    tactile_input,
)
from ratouch.encoders.factory import create_model
from ratouch.encoders.prior import load_prior
from ratouch.errors import ConfigError
from ratouch.serve.photo import PhotoRoute
from ratouch.world.objects import OBJECT_CLASSES
from ratouch.world.sensors import family

skimage_data = pytest.importorskip("skimage.data")


def test_tactile_input_normalises_contrast_and_keeps_it_as_a_channel(world):
    s = world.sample("test", 3)
    bg = world.background_image(s.sensor)
    x = tactile_input(s.tactile, (48, 64), bg)
    assert x.shape == (TACTILE_CHANNELS, 48, 64) and x.dtype == np.float32
    # a faint copy of the same press (a fifth of the contrast) differs only in its level
    faint = (bg.astype(np.float32) + (s.tactile.astype(np.float32) - bg) / 5).round()
    y = tactile_input(np.clip(faint, 0, 255).astype(np.uint8), (48, 64), bg)
    assert np.corrcoef(x[:3].ravel(), y[:3].ravel())[0, 1] > 0.95
    assert y[3, 0, 0] < x[3, 0, 0] - 1.0  # log contrast: about log(5) lower
    # the background itself: nothing changed, the contrast sits at its floor, read against
    # the family's typical press
    z = tactile_input(bg, (48, 64), bg, s.family)
    ref = family(s.family).press_contrast
    assert np.allclose(z[:3], 0) and np.isclose(z[3, 0, 0], max(np.log(CONTRAST_FLOOR / 4 / ref), -3))
    # a landscape frame is read turned to portrait: the same input as its transpose
    wide = np.ascontiguousarray(s.tactile.transpose(1, 0, 2))
    wide_bg = np.ascontiguousarray(bg.transpose(1, 0, 2))
    assert np.allclose(tactile_input(wide, (48, 64), wide_bg, s.family),
                       tactile_input(s.tactile, (48, 64), bg, s.family), atol=1e-5)


def test_unknown_prior_is_a_config_error():
    with pytest.raises(ConfigError, match="known priors"):
        DefaultConfig(name="x", prior="resnet")


@pytest.mark.parametrize("p", [-0.1, 1.0])
def test_prior_dropout_outside_0_1_is_a_config_error(p):
    with pytest.raises(ConfigError, match="prior_dropout"):
        DefaultConfig(name="x", prior="lite0", prior_dropout=p)


def test_prior_dropout_acts_in_training_only():
    torch.manual_seed(0)
    head = PriorHead(32, 16, 8, dropout=0.5)
    x = torch.randn(4, 32)
    head.eval()
    assert torch.equal(head(x), head(x))  # no dropout when embedding queries
    head.train()
    assert not torch.allclose(head(x), head(x))
    # the shipped sets train their head with it, and the state dict carries no extra tensor
    cfg = create_model("default-s", pretrained=None).cfg
    assert cfg.prior_dropout > 0
    assert PriorHead(32, 16, 8, 0.5).state_dict().keys() == PriorHead(32, 16, 8).state_dict().keys()


def test_tactile_backgrounds_must_match_the_frames(world):
    enc = create_model("debug", pretrained=None)
    s = world.sample("test", 0)
    with pytest.raises(ConfigError, match="1 backgrounds and 2 sensor families for 2 tactile"):
        enc.encode_tactile([s.tactile, s.tactile], [world.background_image(s.sensor)])


def _centre_crop(image: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    side = min(h, w)
    y, x = (h - side) // 2, (w - side) // 2
    return image[y:y + side, x:x + side]


def test_photo_route_reads_the_classifier_over_the_corpus_classes():
    """A corpus of two classes whose prototypes are orthogonal: the cat photo's query lies on
    the tabby prototype, with the classes named in the note."""
    prior = load_prior("lite0")
    names = ["tabby"] * 3 + ["teapot"] * 3
    emb = np.zeros((6, 4), np.float32)
    emb[:3, 0], emb[3:, 1] = 1, 1
    route = PhotoRoute(prior, names, emb)
    photo = route.query(_centre_crop(skimage_data.chelsea()))
    assert photo.classes[0][0] == "tabby"
    assert photo.query[0] > 0.99 and np.isclose(np.linalg.norm(photo.query), 1)
    assert "real photo" in photo.note and "tabby" in photo.note
    assert 0 < photo.coverage <= 1


def test_photo_route_classifies_at_the_priors_own_input_size():
    """The encoders read crops at their `prior_size` (96, chosen on renders); the photo route's
    classifier reads the crop at the size the prior learnt ImageNet at (224 for Lite0)."""
    prior = load_prior("lite0")
    sizes = []

    class Recording:
        name, spec = prior.name, prior.spec

        def classify(self, images, size=None):
            sizes.append(size or prior.spec.input_size)
            return prior.classify(images, size)

    assert DefaultConfig(name="x").prior_size < prior.spec.input_size == 224
    route = PhotoRoute(Recording(), ["tabby", "teapot"], np.eye(2, dtype=np.float32))
    route.query(_centre_crop(skimage_data.chelsea()))
    assert sizes == [224]


def test_a_warmed_photo_route_answers_its_first_photo_without_tracing(monkeypatch):
    """`PhotoRoute.warm` does the tracing a fresh prior's first photo would do inside its
    query (the classifier's extractor at 224 px): once warmed, the first photo traces nothing
    and is answered as an unwarmed route answers it."""
    from ratouch.encoders.prior import VisualPrior

    names = ["tabby"] * 3 + ["teapot"] * 3
    emb = np.zeros((6, 4), np.float32)
    emb[:3, 0], emb[3:, 1] = 1, 1
    traced = []
    trace = torch.jit.trace
    monkeypatch.setattr(torch.jit, "trace", lambda *a, **k: (traced.append(1), trace(*a, **k))[1])
    crop = _centre_crop(skimage_data.chelsea())
    cold = PhotoRoute(VisualPrior("lite0"), names, emb)  # a fresh prior: nothing traced yet
    expected = cold.query(crop)
    assert traced == [1]  # the control: an unwarmed route traces during its first photo
    route = PhotoRoute(VisualPrior("lite0"), names, emb)
    route.warm()
    assert traced == [1, 1]
    photo = route.query(crop)
    assert traced == [1, 1]  # nothing left for the photo to build
    assert photo.classes == expected.classes and np.array_equal(photo.query, expected.query)


def test_real_photo_goes_the_photo_route_and_a_render_does_not(pipeline, world):
    cat = skimage_data.chelsea()
    r = pipeline.query(cat, None)
    assert r["visual_route"]["route"] == "photo"
    assert r["trust"]["visual"]["space"] == "prior" and r["trust"]["visual"]["novel"]
    assert any("looks like a real photo" in w for w in r["warnings"])
    names = {c.name for c in OBJECT_CLASSES}
    assert {n["class_name"] for n in r["neighbours"]["image"]} <= names
    json.dumps(r)
    s = world.sample("test", 5)
    r = pipeline.query(s.visual, s.tactile, box=s.box, background=world.background_image(s.sensor))
    assert r["visual_route"] == {"route": "render"}
    assert not any("looks like a real photo" in w for w in r["warnings"])


def test_background_changes_the_tactile_query_but_not_the_render_route(pipeline, world):
    s = world.sample("test", 7)
    a = pipeline.query(s.visual, s.tactile, box=s.box)
    b = pipeline.query(s.visual, s.tactile, box=s.box, background=world.background_image(s.sensor))
    assert a["trust"]["tactile"]["background"] is False and b["trust"]["tactile"]["background"]
    assert a["neighbours"]["image"] == b["neighbours"]["image"]

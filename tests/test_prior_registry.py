"""Swapping the visual prior: a small timm model (not an EfficientNet), with weights this test
writes itself under names of its own, registered as one row, builds, loads those weights
through the row's key mapping, and an encoder set runs on it with its feature size."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ratouch.checkpoint import sha256_file
from ratouch.encoders import prior as P
from ratouch.encoders.prior_registry import PRIORS, PriorSpec, prior_spec, register_prior
from ratouch.errors import ConfigError, DataError

pytestmark = pytest.mark.usefixtures("one_thread")

NAME = "test-convnext"
ARCH = "test_convnext"  # one of timm's own tiny test models


def _strip_backbone(theirs, ours):
    """This test's file holds the model under "backbone.<timm name>"."""
    out = {k.removeprefix("backbone."): v for k, v in theirs.items()}
    if set(out) != set(ours):
        raise DataError(f"keys {sorted(set(out) ^ set(ours))[:3]} do not match")
    return out


@pytest.fixture
def convnext_prior(tmp_path):
    import timm

    torch.manual_seed(0)
    model = timm.create_model(ARCH, pretrained=False)
    state = {f"backbone.{k}": v for k, v in model.state_dict().items()}
    path = tmp_path / "convnext.pth"
    torch.save(state, path)
    register_prior(NAME, PriorSpec(ARCH, str(path), sha256_file(path), 64, "Test ConvNeXt",
                                   mean=(0.5, 0.5, 0.5), std=(0.25, 0.25, 0.25),
                                   key_map=_strip_backbone))
    try:
        yield state, model.num_features
    finally:
        PRIORS.pop(NAME)
        P._loaded.pop(NAME, None)


def test_a_registered_timm_model_is_an_encoder_sets_prior(convnext_prior):
    from ratouch.bench.towers import tower_names
    from ratouch.encoders.default import DefaultConfig, DefaultEncoders

    state, width = convnext_prior
    assert width != 1280  # the feature size is the model's, not EfficientNet's
    built = P.build_model(NAME)
    for k, v in built.state_dict().items():
        torch.testing.assert_close(v, state[f"backbone.{k}"])
    assert P.feature_dim(NAME) == width and P.load_prior(NAME).dim == width
    assert NAME in tower_names() and prior_spec(NAME).sizes == (64,)

    enc = DefaultEncoders(DefaultConfig(name="convnext-set", width=8, vision_size=(48, 48),
                                        prior=NAME, prior_size=48)).eval()
    assert "Test ConvNeXt" in enc.prior_note
    crops = [np.full((40, 30, 3), v, np.uint8) for v in (20, 200)]
    V, feats = enc.encode_image_features(crops)
    assert V.shape == (2, enc.dim) and feats.shape == (2, width)
    np.testing.assert_allclose(np.linalg.norm(V, axis=1), 1.0, rtol=1e-5)
    assert not np.allclose(feats[0], feats[1])  # the prior reads the pixels


def test_a_mobilenet_rows_width_is_the_features_taken(tmp_path):
    """MobileNetV3 pools, then widens with a head convolution: its pre-logit features are
    `head_hidden_size` wide (1024), not `num_features` (288). The row's width is measured on the
    built model, so an encoder set runs on it and the classifier reads its features."""
    import timm

    from ratouch.encoders.default import DefaultConfig, DefaultEncoders

    torch.manual_seed(0)
    model = timm.create_model("mobilenetv3_small_050", pretrained=False)
    path = tmp_path / "mobilenet.pth"
    torch.save(model.state_dict(), path)   # the registry's layout: timm's own names
    name = "test-mobilenet"
    register_prior(name, PriorSpec("mobilenetv3_small_050", str(path), sha256_file(path), 64,
                                   "Test MobileNetV3-Small"))
    try:
        assert model.num_features != model.head_hidden_size   # the trap this row sets
        assert P.feature_dim(name) == model.head_hidden_size == P.load_prior(name).dim
        enc = DefaultEncoders(DefaultConfig(name="mobilenet-set", width=8, vision_size=(48, 48),
                                            prior=name, prior_size=48)).eval()
        crops = [np.full((40, 30, 3), v, np.uint8) for v in (20, 200)]
        V, feats = enc.encode_image_features(crops)
        assert V.shape == (2, enc.dim) and feats.shape == (2, model.head_hidden_size)
        probs = P.load_prior(name).classify(crops)
        assert probs.shape == (2, 1000)
        np.testing.assert_allclose(probs.sum(1), 1.0, rtol=1e-5)
    finally:
        PRIORS.pop(name)
        P._loaded.pop(name, None)
        P.feature_dim.cache_clear()


def test_a_row_that_does_not_fit_is_refused(convnext_prior, tmp_path):
    state, _ = convnext_prior
    short = tmp_path / "short.pth"
    torch.save(dict(list(state.items())[:-1]), short)
    spec = PRIORS[NAME]
    PRIORS[NAME] = PriorSpec(spec.arch, str(short), sha256_file(short), 64, spec.title,
                             key_map=_strip_backbone)
    with pytest.raises(DataError, match=f"short.pth for {ARCH}: keys"):
        P.build_model(NAME)
    with pytest.raises(ConfigError, match="already registered"):
        register_prior(NAME, spec)
    with pytest.raises(ConfigError, match="input_size"):
        PriorSpec(ARCH, "x.pth", "0" * 64, 8, "tiny")
    with pytest.raises(ConfigError, match="prior='nope'"):
        from ratouch.encoders.default import DefaultConfig

        DefaultConfig(name="x", prior="nope")

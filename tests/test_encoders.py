"""Encoders: the factory, the default backend, checkpoints that describe themselves."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ratouch.checkpoint import read_checkpoint, save_checkpoint
from ratouch.encoders.factory import create_model, list_models, shipped_weights
from ratouch.errors import ConfigError, DataError, DataNotFoundError


def _unit(x: np.ndarray) -> bool:
    return np.allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-4)


def test_registry_has_three_default_sizes_tvl_and_debug():
    names = list_models()
    for n in ("default-tiny", "default-s", "default-b", "debug", "tvl-vitb", "tvl-vits",
              "tvl-vittiny"):
        assert n in names
    with pytest.raises(ConfigError, match="unknown encoder"):
        create_model("resnet-9000")


def test_debug_encoders_embed_every_modality(debug_encoders, world):
    s = [world.sample("test", i) for i in (50, 60, 70)]
    img = debug_encoders.encode_image([x.visual[x.box[1]:x.box[3], x.box[0]:x.box[2]] for x in s])
    tac = debug_encoders.encode_tactile([x.tactile for x in s],
                                        [world.background_image(x.sensor) for x in s])
    tac_nobg = debug_encoders.encode_tactile([x.tactile for x in s])
    txt = debug_encoders.encode_text([x.caption for x in s])
    for e in (img, tac, tac_nobg, txt):
        assert e.shape == (3, 384) and e.dtype == np.float32 and _unit(e)
    assert debug_encoders.encode_image([]).shape == (0, 384)


def test_untrained_projection_keeps_minilm_geometry(debug_encoders):
    e = debug_encoders.encode_text(["soft, fuzzy, deformable", "hard, rigid, smooth",
                                    "squishy, plush"])
    # the measured MiniLM weakness the trained projection must fix
    assert e[0] @ e[1] == pytest.approx(0.574, abs=0.01)
    assert e[0] @ e[2] == pytest.approx(0.515, abs=0.01)


def test_checkpoint_round_trip_and_integrity(tmp_path, debug_encoders):
    folder = tmp_path / "ck"
    cfg = {"name": "debug"}
    from ratouch.encoders.factory import model_config

    save_checkpoint(folder, debug_encoders.state_dict(), model_config("debug"))
    loaded = create_model("debug", pretrained=folder)
    texts = ["soft, plush", "hard, metallic"]
    assert np.allclose(loaded.encode_text(texts), debug_encoders.encode_text(texts), atol=1e-6)
    state, config, manifest = read_checkpoint(folder)
    assert config["name"] == "debug" and set(manifest["files"]) == {"model.safetensors",
                                                                    "config.json"}
    # another model's checkpoint is refused
    with pytest.raises(ConfigError, match="debug"):
        create_model("default-tiny", pretrained=folder)
    # a corrupt byte is refused and the file is left as it was
    w = folder / "model.safetensors"
    data = bytearray(w.read_bytes())
    data[-10] ^= 0xFF
    w.write_bytes(bytes(data))
    with pytest.raises(DataError, match="corrupt"):
        create_model("debug", pretrained=folder)
    assert w.read_bytes() == bytes(data)
    with pytest.raises(DataNotFoundError):
        create_model("debug", pretrained=tmp_path / "nowhere")
    del cfg


def test_checkpoint_that_does_not_fit_is_reported(tmp_path, debug_encoders):
    from ratouch.encoders.factory import model_config

    state = dict(debug_encoders.state_dict())
    state["vision.head.weight"] = torch.zeros(5, 5)
    save_checkpoint(tmp_path / "bad", state, model_config("debug"))
    with pytest.raises(DataError, match="vision.head.weight"):
        create_model("debug", pretrained=tmp_path / "bad")


@pytest.mark.parametrize("name", ["default-tiny", "default-s", "default-b"])
def test_shipped_weights_load_and_are_small(name):
    folder = shipped_weights(name)
    if not (folder / "manifest.json").is_file():
        pytest.fail(f"shipped weights missing for {name}: run `ratouch train encoders`")
    model = create_model(name)
    size = (folder / "model.safetensors").stat().st_size
    assert size < 8 * 2**20
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["meta"]["train"]["model"] == name
    e = model.encode_text(["soft, fuzzy, deformable", "hard, rigid, smooth", "squishy, plush"])
    assert e[0] @ e[2] > e[0] @ e[1]  # the trained space separates tactile antonyms


def test_training_reduces_the_loss(tmp_path):
    from ratouch.train.encoders import TrainConfig, train_encoders

    model, report = train_encoders(TrainConfig(model="debug", n_pairs=120, n_corpus=120,
                                               steps=25, batch=32, workers=1),
                                   out=str(tmp_path / "dbg"), progress=False)
    assert (tmp_path / "dbg" / "model.safetensors").is_file()
    meta = json.loads((tmp_path / "dbg" / "manifest.json").read_text())["meta"]
    first, last = meta["history"][0], meta["history"][-1]
    assert last["tactile_text"] < first["tactile_text"]
    # what the floating-point sums depend on, so that a run can be repeated as it was
    assert (meta["train"]["threads"], meta["train"]["device"]) == (2, "cpu")


_TRAIN_AND_HASH = """
import hashlib
from ratouch.train.encoders import TrainConfig, train_encoders
model, _ = train_encoders(TrainConfig(model="default-tiny", n_pairs=64, n_corpus=64, steps=6,
                                      batch=16, workers=1), progress=False)
h = hashlib.sha256()
for k, v in sorted(model.state_dict().items()):
    h.update(k.encode())
    h.update(v.detach().contiguous().numpy().tobytes())
print(h.hexdigest())
"""


@pytest.mark.slow
def test_training_gives_the_same_weights_from_an_empty_cache_and_from_the_cache(tmp_path):
    """Each in a fresh process, as `ratouch train encoders` runs: rendering the data loads the
    visual prior, reading it cached does not, and neither may change what is trained (the
    prior's first load once drew from torch's global generator, which dropout reads)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "RATOUCH_CACHE": str(tmp_path / "cache")}

    def run() -> str:
        out = subprocess.run([sys.executable, "-c", _TRAIN_AND_HASH], env=env, text=True,
                             capture_output=True, timeout=600)
        assert out.returncode == 0, out.stderr[-3000:]
        return out.stdout.strip().splitlines()[-1]

    cold = run()
    assert list((tmp_path / "cache").glob("train-data-*.npz"))  # rendered, then cached
    assert run() == cold


def test_weights_fingerprints_identify_the_loaded_weights(debug_checkpoints, monkeypatch):
    """What corpus embeddings record to tell which weights made them."""
    from ratouch.encoders import factory

    assert create_model("debug", pretrained=None).weights_fingerprint is None  # random init
    a, b = (create_model("debug", pretrained=f).weights_fingerprint for f in debug_checkpoints)
    assert a == json.loads((debug_checkpoints[0] / "manifest.json").read_text()
                           )["files"]["model.safetensors"]
    assert a != b
    monkeypatch.setattr(factory, "shipped_weights", lambda name: debug_checkpoints[1])
    assert factory.shipped_fingerprint("debug") == create_model("debug").weights_fingerprint == b
    with pytest.raises(ConfigError, match="no shipped weights"):
        factory.shipped_fingerprint("tvl-vittiny")


def test_tvl_weights_fingerprint_follows_the_files_not_their_folder(tmp_path, monkeypatch):
    """The TVL set's fingerprint comes from its checkpoint files (their loading is
    test_tvl_encoders.py's business: a registered TVL config is a real ViT-L-14, so the loader
    is stubbed here)."""
    import shutil

    from ratouch.encoders import tvl

    class Loaded:
        weights_fingerprint = None

    # the factory imports the TVL backend when it creates a TVL model
    monkeypatch.setattr(tvl, "load_tvl", lambda clip, tactile, cfg, device: Loaded())
    one = tmp_path / "one"
    one.mkdir()
    (one / "open_clip_model.safetensors").write_bytes(b"clip weights")
    (one / "tvl_enc_vittiny.pth").write_bytes(b"tactile weights")
    shutil.copytree(one, tmp_path / "moved")
    first = create_model("tvl-vittiny", pretrained=one).weights_fingerprint
    assert len(first) == 64
    assert create_model("tvl-vittiny", pretrained={
        "clip": tmp_path / "moved" / "open_clip_model.safetensors",
        "tactile": tmp_path / "moved" / "tvl_enc_vittiny.pth"}).weights_fingerprint == first
    (one / "tvl_enc_vittiny.pth").write_bytes(b"tactile weights, retrained")
    assert create_model("tvl-vittiny", pretrained=one).weights_fingerprint != first


@pytest.mark.slow
def test_queries_are_encoded_as_training_pairs_were():
    """The shipped default-s sees at query time what it saw in training: training renders
    prepared by the training data's path (crops resized for the CNN and for the prior, prior
    features cached as float16, tactile inputs against the background cached as float16) and
    the same renders through `encode_image` / `encode_tactile` give the same embeddings."""
    import torch

    from ratouch.encoders.prior import load_prior
    from ratouch.train.encoders import _pair_chunk
    from ratouch.world.config import WorldConfig
    from ratouch.world.dataset import world_for

    enc = create_model("default-s").eval()
    cfg, idx = enc.cfg, list(range(0, 200, 25))
    crops, pcrops, _, tacs_bg, _, _ = _pair_chunk(
        (WorldConfig(), idx, cfg.vision_size, cfg.tactile_size, cfg.prior_size))
    feats = load_prior(cfg.prior).features(pcrops, cfg.prior_size).astype(np.float16)
    with torch.no_grad():
        pixels = torch.from_numpy(np.stack(crops)).float().div(255).sub(0.5).div(0.25)
        v_train = enc.embed_vision(pixels.permute(0, 3, 1, 2),
                                   torch.from_numpy(feats.astype(np.float32))).numpy()
        t_train = enc.embed_tactile(torch.from_numpy(np.stack(tacs_bg).astype(np.float32))).numpy()
    world = world_for(WorldConfig())
    samples = [world.sample("train", i) for i in idx]
    v_query = enc.encode_image([s.crop for s in samples])
    t_query = enc.encode_tactile([s.tactile for s in samples],
                                 [world.background_image(s.sensor) for s in samples])

    def cos(a, b):
        return (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)

    assert cos(v_train, v_query).min() > 0.999 and cos(t_train, t_query).min() > 0.999
    t_alone = enc.encode_tactile([s.tactile for s in samples])  # without the background
    assert cos(t_train, t_alone).min() < 0.999  # the check can fail: the background matters

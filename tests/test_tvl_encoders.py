"""Tests of the TVL encoder loader (ratouch.encoders.tvl) and its preprocessing.

Checkpoints are built here with random weights in the exact layouts the loader reads:

* OpenCLIP: a plain state dict (``torch.save`` or safetensors), as in
  ``open_clip_pytorch_model.bin`` / ``open_clip_model.safetensors``;
* TVL (Max-Fu/tvl, ``util/misc.py::save_model``): ``{"model": ..., "optimizer": ...,
  "epoch": ..., "scaler": ..., "args": argparse.Namespace}`` where ``TVL.state_dict()`` has
  dropped every key containing "clip", so "model" holds only ``tactile_encoder.*`` and
  ``logit_scale``.

To stay fast, the CLIP architecture is a tiny OpenCLIP config of the ViT-L-14 family
registered with ``open_clip.add_model_config``; the tactile encoder is the real
``vit_tiny_patch16_224``. One ``slow`` test builds the real ViT-L-14.
"""

from __future__ import annotations

import argparse
import io
import json
import pickle
from pathlib import Path

import numpy as np
import open_clip
import pytest
import timm
import torch
import torchvision.transforms as T
import torchvision.transforms.functional as TF
from PIL import Image
from safetensors.torch import save_file

from ratouch.encoders import tvl_input as pp
from ratouch.encoders.tvl import TVLConfig, TVLEncoders, load_tvl, resolve_tactile_arch
from ratouch.encoders.tvl_input import (
    CLIP_MEAN,
    CLIP_STD,
    TAC_MEAN,
    TAC_MEAN_BG,
    TAC_STD,
    TAC_STD_BG,
    clip_rgb_tensor,
    tvl_tactile_tensor,
)
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.images import crop_box, to_rgb_array, tvl_contact_box

MINI_ARCH = "ratouch-test-ViT-mini"
MINI_DIM = 64
MINI_CLIP_CFG = {
    "embed_dim": MINI_DIM,
    "vision_cfg": {"image_size": 112, "layers": 2, "width": 64, "patch_size": 14,
                   "head_width": 32},
    "text_cfg": {"context_length": 77, "vocab_size": 49408, "width": 64, "heads": 2,
                 "layers": 2},
}


# --------------------------------------------------------------------------- helpers


def _write_marker(path: str) -> None:
    Path(path).write_text("code was executed")


class Exploit:
    """Unpickling this runs ``_write_marker`` - unless the loader refuses it."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (_write_marker, (self.marker,))


class Custom:
    """A harmless custom class: weights_only loading must still refuse it."""

    def __init__(self) -> None:
        self.value = 3


def _tvl_checkpoint(tactile_state: dict, **extra) -> dict:
    """A checkpoint in TVL's save_model layout (no CLIP keys: TVL.state_dict drops them)."""
    model = {f"tactile_encoder.{k}": v for k, v in tactile_state.items()}
    model["logit_scale"] = torch.tensor(float(np.log(1 / 0.07)))
    ckpt = {
        "model": model,
        "optimizer": {"state": {}, "param_groups": [{"lr": 3e-4, "weight_decay": 0.05,
                                                     "betas": (0.9, 0.95), "params": [0, 1]}]},
        "epoch": 3,
        "scaler": {"scale": 65536.0, "growth_factor": 2.0, "backoff_factor": 0.5,
                   "growth_interval": 2000, "_growth_tracker": 0},
        "args": argparse.Namespace(tactile_model="vit_tiny_patch16_224", common_latent_dim=None,
                                   batch_size=256, blr=3e-4, datasets=["ssvtp", "hct"],
                                   subtract_background=None, output_dir="./output_dir"),
    }
    ckpt.update(extra)
    return ckpt


def _tiny_tactile(num_classes: int = MINI_DIM, seed: int = 0) -> torch.nn.Module:
    """TVL's tactile ViT-Tiny with random weights (timm's own trunc-normal init is slow)."""
    model = timm.create_model("vit_tiny_patch16_224", pretrained=False, num_classes=num_classes,
                              global_pool="avg", weight_init="skip")
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, tensor in model.state_dict().items():
            noise = torch.randn(tensor.shape, generator=gen)
            is_norm_scale = "norm" in name and name.endswith("weight")
            tensor.copy_(1 + 0.1 * noise if is_norm_scale else 0.02 * noise)
    return model


def _rand_images(n: int, seed: int = 0, shapes=((120, 160), (96, 96), (200, 150))) -> list:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (*shapes[i % len(shapes)], 3), dtype=np.uint8)
            for i in range(n)]


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Random-weight checkpoints in the real layouts, written once per module."""
    root = tmp_path_factory.mktemp("tvl_ckpt")
    cfg_path = root / f"{MINI_ARCH}.json"
    cfg_path.write_text(json.dumps(MINI_CLIP_CFG))
    open_clip.add_model_config(cfg_path)

    torch.manual_seed(0)
    clip = open_clip.create_model(MINI_ARCH, pretrained=None)
    clip_state = {k: v.clone() for k, v in clip.state_dict().items()}
    torch.save(clip_state, root / "open_clip_pytorch_model.bin")
    save_file({k: v.contiguous() for k, v in clip_state.items()},
              str(root / "open_clip_model.safetensors"))

    tactile_state = {k: v.clone() for k, v in _tiny_tactile().state_dict().items()}
    torch.save(_tvl_checkpoint(tactile_state), root / "tvl_enc_vittiny.pth")
    return {"root": root, "clip": root / "open_clip_pytorch_model.bin",
            "clip_st": root / "open_clip_model.safetensors",
            "tactile": root / "tvl_enc_vittiny.pth",
            "clip_state": clip_state, "tactile_state": tactile_state}


@pytest.fixture(scope="module")
def cfg(files) -> TVLConfig:
    return TVLConfig(clip_arch=MINI_ARCH, tactile_arch="tiny", dim=MINI_DIM)


@pytest.fixture(scope="module")
def enc(files, cfg) -> TVLEncoders:
    return load_tvl(files["clip"], files["tactile"], cfg)


# --------------------------------------------------------------------------- config


def test_config_aliases_and_name():
    assert TVLConfig(tactile_arch="tiny").tactile_arch == "vit_tiny_patch16_224"
    assert TVLConfig(tactile_arch="s").tactile_arch == "vit_small_patch16_224"
    assert TVLConfig(tactile_arch="b").tactile_arch == "vit_base_patch16_224"
    assert TVLConfig(tactile_arch="vitb").name == "tvl-vitb"
    assert TVLConfig().name == "tvl-vittiny"
    assert TVLConfig(clip_arch="ViT-L-14", tactile_arch="vit_small_patch16_224").name == "tvl-vits"
    assert resolve_tactile_arch("ViTTiny") == "vit_tiny_patch16_224"


@pytest.mark.parametrize("kwargs, match", [
    ({"tactile_arch": "huge"}, "unknown tactile_arch 'huge'"),
    ({"tactile_arch": "resnet18"}, "resnet18"),
    ({"dim": 0}, "dim must be a positive integer, got 0"),
    ({"dim": 768.0}, "dim must be a positive integer"),
    ({"clip_arch": ""}, "clip_arch"),
    ({"clip_arch": "hf-hub:laion/x"}, "hf-hub:laion/x"),
    ({"batch_size": 0}, "batch_size"),
    ({"subtract_background": "yes"}, "subtract_background"),
])
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        TVLConfig(**kwargs)


# --------------------------------------------------------------------------- encoding


def test_encoders_shapes_norms_and_attributes(enc):
    assert isinstance(enc, torch.nn.Module)
    assert enc.dim == MINI_DIM and enc.name == f"tvl-vittiny-{MINI_ARCH}"
    assert enc.image_size == 112 and enc.tactile_size == 224
    assert not enc.training
    assert all(not p.requires_grad for p in enc.parameters())
    for out, n in ((enc.encode_image(_rand_images(3)), 3),
                   (enc.encode_tactile(_rand_images(2, seed=1)), 2),
                   (enc.encode_text(["soft and fuzzy", "hard", "rough, grainy"]), 3)):
        assert isinstance(out, np.ndarray) and out.dtype == np.float32
        assert out.shape == (n, MINI_DIM)
        np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)


def test_encoders_are_deterministic_and_batch_independent(enc):
    images = _rand_images(3, seed=2)
    a = enc.encode_image(images)
    np.testing.assert_array_equal(a, enc.encode_image(images))
    np.testing.assert_allclose(a, enc.encode_image(images, batch_size=1), atol=1e-5)
    frames = _rand_images(2, seed=3)
    t = enc.encode_tactile(frames)
    np.testing.assert_allclose(enc.encode_tactile(frames, batch_size=1), t, atol=1e-5)
    enc.train()  # encode_* must switch back to eval mode themselves
    np.testing.assert_array_equal(enc.encode_tactile(frames), t)
    assert not enc.training


def test_text_embeddings_differ_between_texts(enc):
    e = enc.encode_text(["soft, fuzzy", "hard, rigid, metallic", "soft, fuzzy"])
    assert not np.allclose(e[0], e[1], atol=1e-3)
    np.testing.assert_allclose(e[0], e[2], atol=1e-6)
    np.testing.assert_allclose(e, enc.encode_text(["soft, fuzzy", "hard, rigid, metallic",
                                                   "soft, fuzzy"], batch_size=1), atol=1e-5)


def test_empty_batches(enc):
    assert enc.encode_image([]).shape == (0, MINI_DIM)
    assert enc.encode_tactile([]).shape == (0, MINI_DIM)
    assert enc.encode_text([]).shape == (0, MINI_DIM)


def test_loaded_weights_are_the_checkpoint_weights(enc, files):
    for key, value in files["tactile_state"].items():
        assert torch.equal(enc.tactile.state_dict()[key], value), key
    for key, value in files["clip_state"].items():
        assert torch.equal(enc.clip.state_dict()[key], value), key


def test_save_load_round_trip_gives_same_embeddings(enc, files, cfg, tmp_path):
    images, frames = _rand_images(2, seed=4), _rand_images(2, seed=5)
    texts = ["smooth", "bumpy and ridged"]
    ref = (enc.encode_image(images), enc.encode_tactile(frames), enc.encode_text(texts))
    # Re-save the loaded weights in both layouts and load them again.
    save_file({k: v.contiguous() for k, v in enc.clip.state_dict().items()},
              str(tmp_path / "clip.safetensors"))
    torch.save(_tvl_checkpoint(enc.tactile.state_dict()), tmp_path / "tvl_enc_vittiny.pth")
    again = load_tvl(tmp_path / "clip.safetensors", tmp_path / "tvl_enc_vittiny.pth", cfg)
    np.testing.assert_allclose(again.encode_image(images), ref[0], atol=1e-6)
    np.testing.assert_allclose(again.encode_tactile(frames), ref[1], atol=1e-6)
    np.testing.assert_allclose(again.encode_text(texts), ref[2], atol=1e-6)
    # The .safetensors copy of the original file gives the same model as the .bin one.
    st = load_tvl(files["clip_st"], files["tactile"], cfg)
    np.testing.assert_allclose(st.encode_text(texts), ref[2], atol=1e-6)


def test_openclip_training_checkpoint_layout_is_accepted(enc, files, cfg, tmp_path):
    wrapped = {"epoch": 32, "name": "run",
               "state_dict": {f"module.{k}": v for k, v in files["clip_state"].items()}}
    torch.save(wrapped, tmp_path / "epoch_32.pt")
    other = load_tvl(tmp_path / "epoch_32.pt", files["tactile"], cfg)
    np.testing.assert_allclose(other.encode_text(["soft"]), enc.encode_text(["soft"]), atol=1e-6)


def test_bad_encode_inputs(enc):
    with pytest.raises(DataError, match="single string 'soft'"):
        enc.encode_text("soft")
    with pytest.raises(DataError, match="text 1 is int 3"):
        enc.encode_text(["soft", 3])
    with pytest.raises(DataError, match="single array of shape"):
        enc.encode_image(np.zeros((32, 32, 3), np.uint8))
    with pytest.raises(DataError, match="image 2 is 5x5"):
        enc.encode_image(_rand_images(2) + [np.zeros((5, 5, 3), np.uint8)], batch_size=2)
    with pytest.raises(ConfigError, match="batch_size"):
        enc.encode_text(["soft"], batch_size=0)


def test_backgrounds_ignored_unless_configured(enc, files, cfg):
    frames = _rand_images(2, seed=6, shapes=((60, 80),))
    bgs = _rand_images(2, seed=7, shapes=((60, 80),))
    plain = enc.encode_tactile(frames)
    np.testing.assert_array_equal(enc.encode_tactile(frames, backgrounds=bgs), plain)
    bg_cfg = TVLConfig(clip_arch=MINI_ARCH, tactile_arch="tiny", dim=MINI_DIM,
                       subtract_background=True)
    bg_enc = load_tvl(files["clip"], files["tactile"], bg_cfg)
    with pytest.raises(DataError, match="pass backgrounds="):
        bg_enc.encode_tactile(frames)
    with pytest.raises(DataError, match=r"background missing for tactile frames \[1\]"):
        bg_enc.encode_tactile(frames, backgrounds=[bgs[0], None])
    out = bg_enc.encode_tactile(frames, backgrounds=bgs)
    assert out.shape == (2, MINI_DIM)
    assert not np.allclose(out, plain, atol=1e-3)
    np.testing.assert_allclose(bg_enc.encode_tactile(frames[:1], backgrounds=bgs[0])[0], out[0],
                               atol=1e-6)


# --------------------------------------------------------------------------- loader errors


def test_missing_files(files, cfg, tmp_path):
    with pytest.raises(DataNotFoundError, match="nope_clip.bin"):
        load_tvl(tmp_path / "nope_clip.bin", files["tactile"], cfg)
    with pytest.raises(DataNotFoundError, match="tvl_enc_nope.pth"):
        load_tvl(files["clip"], tmp_path / "tvl_enc_nope.pth", cfg)
    with pytest.raises(DataError, match="directory"):
        load_tvl(files["clip"], tmp_path, cfg)


@pytest.mark.parametrize("content", [b"", b"hello, not a checkpoint\n", b"PK\x03\x04garbage"])
def test_not_a_checkpoint(files, cfg, tmp_path, content):
    bad = tmp_path / "bad.pth"
    bad.write_bytes(content)
    with pytest.raises(DataError, match=r"bad\.pth is not a PyTorch checkpoint"):
        load_tvl(files["clip"], bad, cfg)
    with pytest.raises(DataError, match=r"bad\.pth is not a PyTorch checkpoint"):
        load_tvl(bad, files["tactile"], cfg)


def test_truncated_and_bad_safetensors(files, cfg, tmp_path):
    data = files["tactile"].read_bytes()
    (tmp_path / "cut.pth").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="cut.pth is not a PyTorch checkpoint"):
        load_tvl(files["clip"], tmp_path / "cut.pth", cfg)
    (tmp_path / "bad.safetensors").write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json")
    with pytest.raises(DataError, match="bad.safetensors is not a valid safetensors file"):
        load_tvl(tmp_path / "bad.safetensors", files["tactile"], cfg)


def test_pickled_code_is_refused_not_executed(files, cfg, tmp_path):
    marker = tmp_path / "marker.txt"
    # Sanity check: the payload is live - a plain unpickler runs it.
    live = tmp_path / "live.txt"
    pickle.loads(pickle.dumps(Exploit(live)))
    assert live.exists()

    ckpt = _tvl_checkpoint(files["tactile_state"], args=Exploit(marker))
    torch.save(ckpt, tmp_path / "tvl_enc_evil.pth")
    with pytest.raises(DataError, match=r"refusing to load .*tvl_enc_evil\.pth.*_write_marker"):
        load_tvl(files["clip"], tmp_path / "tvl_enc_evil.pth", cfg)
    torch.save({**files["clip_state"], "evil": Exploit(marker)}, tmp_path / "clip_evil.bin")
    with pytest.raises(DataError, match=r"refusing to load .*clip_evil\.bin"):
        load_tvl(tmp_path / "clip_evil.bin", files["tactile"], cfg)
    assert not marker.exists()


def test_custom_objects_and_pickled_modules_are_refused(files, cfg, tmp_path):
    torch.save(_tvl_checkpoint(files["tactile_state"], extra=Custom()), tmp_path / "custom.pth")
    with pytest.raises(DataError, match=r"refusing to load .*custom\.pth.*Custom"):
        load_tvl(files["clip"], tmp_path / "custom.pth", cfg)
    torch.save(_tiny_tactile(), tmp_path / "module.pth")  # a whole pickled nn.Module
    with pytest.raises(DataError, match=r"refusing to load .*module\.pth.*VisionTransformer"):
        load_tvl(files["clip"], tmp_path / "module.pth", cfg)


def test_tvl_layout_errors(files, cfg, tmp_path):
    path = tmp_path / "t.pth"
    torch.save({"state_dict": {"a": torch.zeros(1)}, "epoch": 1}, path)
    with pytest.raises(DataError, match=r"no 'model' entry.*found keys \['state_dict', 'epoch'\]"):
        load_tvl(files["clip"], path, cfg)
    torch.save({"model": {"visual.proj": torch.zeros(2), "logit_scale": torch.zeros(())}}, path)
    with pytest.raises(DataError, match=r"no 'tactile_encoder\.\*' keys.*'visual\.proj'"):
        load_tvl(files["clip"], path, cfg)
    # The two files swapped.
    with pytest.raises(DataError, match=r"no 'model' entry.*'positional_embedding'"):
        load_tvl(files["clip"], files["clip"], cfg)
    with pytest.raises(DataError, match=r"not an OpenCLIP state dict.*swapped"):
        load_tvl(files["tactile"], files["tactile"], cfg)
    ckpt = _tvl_checkpoint(files["tactile_state"])
    ckpt["model"]["modality_heads.tactile.weight"] = torch.zeros(4, 192)
    torch.save(ckpt, path)
    with pytest.raises(DataError, match="modality_heads"):
        load_tvl(files["clip"], path, cfg)
    torch.save({"model": [1, 2]}, path)
    with pytest.raises(DataError, match="'model' is a list"):
        load_tvl(files["clip"], path, cfg)


@pytest.mark.parametrize("arch, alias", [("s", "tiny"), ("b", "tiny")])
def test_tactile_arch_mismatch_names_key_shapes_and_suggests_arch(files, tmp_path, arch, alias):
    cfg = TVLConfig(clip_arch=MINI_ARCH, tactile_arch=arch, dim=MINI_DIM)
    width = {"s": 384, "b": 768}[arch]
    with pytest.raises(DataError) as info:
        load_tvl(files["clip"], files["tactile"], cfg)
    msg = str(info.value)
    assert "'tactile_encoder.cls_token'" in msg
    assert "(1, 1, 192) in the checkpoint" in msg and f"(1, 1, {width}) in the model" in msg
    assert "vit_tiny_patch16_224" in msg and f"tactile_arch={alias!r}" in msg


def test_tactile_head_dim_mismatch(files, cfg, tmp_path):
    state = _tiny_tactile(num_classes=32).state_dict()
    torch.save(_tvl_checkpoint(state), tmp_path / "head32.pth")
    with pytest.raises(DataError, match=r"head outputs 32 dimensions.*\(32, 192\).*embeds into 64"):
        load_tvl(files["clip"], tmp_path / "head32.pth", cfg)


def test_missing_and_unexpected_keys(files, cfg, tmp_path):
    state = dict(files["tactile_state"])
    del state["fc_norm.bias"]
    state["extra.weight"] = torch.zeros(3)
    torch.save(_tvl_checkpoint(state), tmp_path / "keys.pth")
    with pytest.raises(DataError, match=r"missing keys \['tactile_encoder\.fc_norm\.bias'\]; "
                                        r"unexpected keys \['tactile_encoder\.extra\.weight'\]"):
        load_tvl(files["clip"], tmp_path / "keys.pth", cfg)
    clip_state = dict(files["clip_state"])
    del clip_state["text_projection"]
    torch.save(clip_state, tmp_path / "clip_missing.bin")
    with pytest.raises(DataError, match=r"clip_missing\.bin does not fit the model.*'text_projection'"):
        load_tvl(tmp_path / "clip_missing.bin", files["tactile"], cfg)
    clip_state = dict(files["clip_state"])
    clip_state["token_embedding.weight"] = torch.zeros(100, 64)
    torch.save(clip_state, tmp_path / "clip_shape.bin")
    with pytest.raises(DataError, match=r"'token_embedding\.weight' has shape \(100, 64\) in the "
                                        r"checkpoint but \(49408, 64\)"):
        load_tvl(tmp_path / "clip_shape.bin", files["tactile"], cfg)
    torch.save({"a": torch.zeros(1), "b": 3}, tmp_path / "clip_nontensor.bin")
    with pytest.raises(DataError, match="entry 'b' is a int, not a tensor"):
        load_tvl(tmp_path / "clip_nontensor.bin", files["tactile"], cfg)


def test_config_errors_at_load(files, cfg):
    with pytest.raises(ConfigError, match=f"dim=32 but OpenCLIP {MINI_ARCH} embeds into 64"):
        load_tvl(files["clip"], files["tactile"],
                 TVLConfig(clip_arch=MINI_ARCH, tactile_arch="tiny", dim=32))
    with pytest.raises(ConfigError, match=r"unknown OpenCLIP architecture 'ViT-L-41'.*ViT-L-14"):
        load_tvl(files["clip"], files["tactile"], TVLConfig(clip_arch="ViT-L-41"))
    with pytest.raises(ConfigError, match="invalid device 'gpu0'"):
        load_tvl(files["clip"], files["tactile"], cfg, device="gpu0")
    with pytest.raises(ConfigError, match="cfg must be a TVLConfig"):
        load_tvl(files["clip"], files["tactile"], {"clip_arch": MINI_ARCH})


# --------------------------------------------------------------------------- to_rgb_array


def _pil(mode: str, size=(12, 10), color=None) -> Image.Image:
    return Image.new(mode, size, color) if color is not None else Image.new(mode, size)


@pytest.mark.parametrize("image, expected", [
    (_pil("RGB", color=(10, 20, 30)), (10, 20, 30)),
    (_pil("L", color=77), (77, 77, 77)),
    (_pil("1", color=1), (255, 255, 255)),
    (_pil("LA", color=(100, 255)), (100, 100, 100)),
    (_pil("LA", color=(100, 0)), (255, 255, 255)),  # transparent: white background
    (_pil("RGBA", color=(10, 20, 30, 255)), (10, 20, 30)),
    (_pil("RGBA", color=(0, 0, 0, 0)), (255, 255, 255)),
    (_pil("RGBA", color=(0, 0, 0, 128)), (127, 127, 127)),
    (_pil("CMYK", color=(0, 0, 0, 0)), (255, 255, 255)),
    (_pil("YCbCr", color=(128, 128, 128)), (128, 128, 128)),
    (_pil("I;16", color=65535), (255, 255, 255)),
    (_pil("I;16", color=257 * 40), (40, 40, 40)),
    (_pil("I", color=200), (200, 200, 200)),  # fits 8 bits: read as 8-bit
    (_pil("I", color=65535), (255, 255, 255)),  # 16-bit data in a 32-bit mode
    (_pil("F", color=0.5), (128, 128, 128)),
    (_pil("F", color=200.0), (200, 200, 200)),
])
def test_to_rgb_array_pil_modes(image, expected):
    out = to_rgb_array(image)
    assert out.dtype == np.uint8 and out.shape == (10, 12, 3)
    assert out.flags.c_contiguous
    assert tuple(int(v) for v in out[0, 0]) == expected


def test_to_rgb_array_palette_with_and_without_transparency():
    p = Image.new("P", (10, 10))
    p.putpalette([0, 0, 0, 200, 10, 20] + [0] * 762)
    p.putpixel((0, 0), 1)
    out = to_rgb_array(p)
    assert tuple(out[0, 0]) == (200, 10, 20) and tuple(out[5, 5]) == (0, 0, 0)
    p.info["transparency"] = 0  # index 0 is transparent -> white
    out = to_rgb_array(p)
    assert tuple(out[0, 0]) == (200, 10, 20) and tuple(out[5, 5]) == (255, 255, 255)


@pytest.mark.parametrize("array, expected", [
    (np.full((9, 9), 50, np.uint8), (50, 50, 50)),
    (np.full((9, 9, 1), 50, np.uint8), (50, 50, 50)),
    (np.dstack([np.full((9, 9), 50, np.uint8), np.full((9, 9), 255, np.uint8)]), (50, 50, 50)),
    (np.full((9, 9, 4), 255, np.uint8) * np.array([1, 0, 0, 1], np.uint8), (255, 0, 0)),
    (np.full((9, 9, 3), 65535, np.uint16), (255, 255, 255)),
    (np.full((9, 9, 3), 257 * 3, np.uint16).astype(">u2"), (3, 3, 3)),
    (np.full((9, 9, 3), 0.25, np.float32), (64, 64, 64)),
    (np.full((9, 9, 3), 100.0, np.float64), (100, 100, 100)),
    (np.ones((9, 9), bool), (255, 255, 255)),
    (np.full((9, 9, 3), 1000, np.int32), (4, 4, 4)),
])
def test_to_rgb_array_numpy(array, expected):
    out = to_rgb_array(array)
    assert out.dtype == np.uint8 and out.shape == (9, 9, 3)
    assert tuple(int(v) for v in out[4, 4]) == expected


@pytest.mark.parametrize("array, match", [
    (np.zeros((3, 32, 32), np.uint8), r"shape \(3, 32, 32\).*channels last"),
    (np.zeros((9, 9, 5), np.uint8), r"shape \(9, 9, 5\)"),
    (np.zeros((2, 9, 9, 3), np.uint8), r"shape \(2, 9, 9, 3\)"),
    (np.full((9, 9, 3), -0.5, np.float32), r"float pixel values in \[-0.5, -0.5\]"),
    (np.full((9, 9, 3), np.nan, np.float32), "NaN"),
    (np.full((9, 9, 3), 70000, np.int32), r"integer pixel values in \[70000, 70000\]"),
    (np.full((9, 9, 3), 1 + 2j), "dtype complex"),
])
def test_to_rgb_array_rejects_bad_arrays(array, match):
    with pytest.raises(DataError, match=match):
        to_rgb_array(array)


def test_to_rgb_array_rejects_other_types():
    with pytest.raises(DataError, match="torch.Tensor"):
        to_rgb_array(torch.zeros(3, 9, 9))
    with pytest.raises(DataError, match="got list"):
        to_rgb_array([[1, 2], [3, 4]])


def test_to_rgb_array_size_limits():
    assert to_rgb_array(np.zeros((8, 8, 3), np.uint8)).shape == (8, 8, 3)
    with pytest.raises(DataError, match=r"100x7 pixels \(WxH\).*at least 8"):
        to_rgb_array(np.zeros((7, 100, 3), np.uint8))
    with pytest.raises(DataError, match=r"7x7 pixels"):
        to_rgb_array(Image.new("RGB", (7, 7)))
    huge = np.zeros((7200, 7000), np.uint8)  # 50.4 MP, lazily allocated
    with pytest.raises(DataError, match=r"7000x7200 pixels \(WxH\) = 50.4 megapixels"):
        to_rgb_array(huge)
    with pytest.raises(DataError, match=r"8000x6400 pixels \(WxH\) = 51.2 megapixels"):
        to_rgb_array(Image.new("1", (8000, 6400)))


def _exif_image(orientation: int) -> tuple[np.ndarray, bytes]:
    base = np.zeros((20, 40, 3), np.uint8)
    base[:10, :20] = (255, 0, 0)  # top-left quadrant red
    base[:10, 20:] = (0, 255, 0)  # top-right green
    img = Image.fromarray(base)
    exif = img.getexif()
    exif[0x0112] = orientation
    buf = io.BytesIO()
    img.save(buf, format="PNG", exif=exif)
    return base, buf.getvalue()


@pytest.mark.parametrize("orientation, expected", [
    (1, lambda a: a),
    (3, lambda a: np.rot90(a, 2)),
    (6, lambda a: np.rot90(a, -1)),  # stored rotated; display = 90 degrees clockwise
    (8, lambda a: np.rot90(a, 1)),
    (2, lambda a: a[:, ::-1]),
])
def test_to_rgb_array_applies_exif_orientation(tmp_path, orientation, expected):
    base, data = _exif_image(orientation)
    path = tmp_path / "exif.png"
    path.write_bytes(data)
    want = expected(base)
    np.testing.assert_array_equal(to_rgb_array(path), want)
    with Image.open(io.BytesIO(data)) as img:
        np.testing.assert_array_equal(to_rgb_array(img), want)


def test_to_rgb_array_files(tmp_path):
    p16 = tmp_path / "deep.png"
    Image.fromarray(np.full((10, 10), 257 * 90, np.uint16)).save(p16)
    assert tuple(to_rgb_array(p16)[0, 0]) == (90, 90, 90)
    assert tuple(to_rgb_array(str(p16))[0, 0]) == (90, 90, 90)
    with pytest.raises(DataNotFoundError, match="missing.png"):
        to_rgb_array(tmp_path / "missing.png")
    (tmp_path / "notimage.png").write_text("not an image")
    with pytest.raises(DataError, match="notimage.png"):
        to_rgb_array(tmp_path / "notimage.png")
    buf = io.BytesIO()
    Image.fromarray(np.zeros((64, 64, 3), np.uint8)).save(buf, format="PNG")
    (tmp_path / "cut.png").write_bytes(buf.getvalue()[:60])
    with pytest.raises(DataError, match="cut.png"):
        to_rgb_array(tmp_path / "cut.png")


# --------------------------------------------------------------------------- boxes


def test_crop_box_valid_and_clipped():
    img = np.arange(20 * 30 * 3, dtype=np.uint32).reshape(20, 30, 3) % 251
    img = img.astype(np.uint8)
    np.testing.assert_array_equal(crop_box(img, (5, 2, 15, 12)), img[2:12, 5:15])
    np.testing.assert_array_equal(crop_box(img, (5.5, 2.2, 14.1, 11.9)), img[2:12, 5:15])
    np.testing.assert_array_equal(crop_box(img, (-10, -5, 10, 8)), img[0:8, 0:10])
    np.testing.assert_array_equal(crop_box(img, (25, 15, 100, 100)), img[15:20, 25:30])
    np.testing.assert_array_equal(crop_box(Image.fromarray(img), (0, 0, 30, 20)), img)
    out = crop_box(img, (0, 0, 10, 10))
    out[:] = 0  # a copy, not a view
    assert img[0, 0, 0] != 0 or img[0, 0, 1] != 0 or img[0, 0, 2] != 0


@pytest.mark.parametrize("box, match", [
    ((5, 5, 5, 10), r"box \(5, 5, 5, 10\) is empty or inverted.*image is 30x20"),
    ((10, 5, 4, 10), r"box \(10, 5, 4, 10\) is empty or inverted"),
    ((0, 12, 10, 3), r"empty or inverted"),
    ((30, 0, 40, 10), r"box \(30, 0, 40, 10\) lies entirely outside the 30x20 \(WxH\) image"),
    ((-20, -20, -1, -1), r"entirely outside"),
    ((0, 0, 10), r"four finite numbers"),
    ((0, 0, float("nan"), 10), r"four finite numbers"),
    (("a", 0, 1, 1), r"four numbers"),
])
def test_crop_box_rejects_bad_boxes(box, match):
    with pytest.raises(DataError, match=match):
        crop_box(np.zeros((20, 30, 3), np.uint8), box)


def test_tvl_contact_box_matches_tvl_crop():
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    box = tvl_contact_box(640, 480)
    side = int(np.ceil(np.sqrt(2) * 0.18 * 640))
    assert box[2] - box[0] == side == box[3] - box[1]
    want = np.asarray(TF.center_crop(Image.fromarray(frame), side))  # TVL's v1 crop
    np.testing.assert_array_equal(crop_box(frame, box), want)
    x0, y0, x1, y1 = tvl_contact_box(640, 480, version="v2")
    assert (y0, x0) == (0, (640 - side) // 2) and x1 - x0 == side
    assert tvl_contact_box(640, 480, version="v2", top=200)[1] == 200
    with pytest.raises(ConfigError, match="version"):
        tvl_contact_box(640, 480, version="v3")


# --------------------------------------------------------------------------- tensors


def test_clip_rgb_tensor_matches_torchvision_reference():
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, (150, 300, 3), dtype=np.uint8),
              rng.integers(0, 256, (240, 100, 3), dtype=np.uint8),
              rng.integers(0, 256, (224, 224, 3), dtype=np.uint8)]
    out = clip_rgb_tensor(images, size=224)
    assert out.shape == (3, 3, 224, 224) and out.dtype == torch.float32
    ref = T.Compose([T.Resize(224), T.CenterCrop(224), T.ToTensor(),
                     T.Normalize(CLIP_MEAN, CLIP_STD)])
    for i, img in enumerate(images):
        torch.testing.assert_close(out[i], ref(Image.fromarray(img)), atol=1e-6, rtol=0)
    # A constant image maps to (v/255 - mean)/std, and the batch accepts mixed kinds.
    const = clip_rgb_tensor([Image.new("L", (50, 40), 128), np.full((30, 30, 3), 128, np.uint8)],
                            size=32)
    want = (128 / 255 - torch.tensor(CLIP_MEAN)) / torch.tensor(CLIP_STD)
    torch.testing.assert_close(const[:, :, 5, 5], want.expand(2, 3), atol=1e-6, rtol=0)
    assert clip_rgb_tensor([], size=32).shape == (0, 3, 32, 32)
    stacked = np.stack(images[:1] * 2)
    assert clip_rgb_tensor(stacked, size=16).shape == (2, 3, 16, 16)


def _tvl_reference(frame: np.ndarray, background: np.ndarray | None = None) -> torch.Tensor:
    """TVL's own tactile pipeline (tac_padding + Resize + Normalize), built from torchvision."""
    h, w = frame.shape[:2]
    hpad, wpad = (max(h, w) - h) // 2, (max(h, w) - w) // 2
    if background is None:
        tac = TF.rotate(TF.pad(Image.fromarray(frame), [wpad, hpad]), 90)
        return T.Compose([T.Resize(224), T.ToTensor(), T.Normalize(TAC_MEAN, TAC_STD)])(tac)
    tac = TF.rotate(TF.pad(TF.to_tensor(frame), [wpad, hpad]), 90)
    bg = TF.rotate(TF.pad(TF.to_tensor(background), [wpad, hpad]), 90)
    return T.Compose([T.Resize(224), T.Normalize(TAC_MEAN_BG, TAC_STD_BG)])(tac - bg)


def test_tvl_tactile_tensor_matches_tvl_pipeline():
    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 256, (320, 240, 3), dtype=np.uint8),
              rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)]
    out = tvl_tactile_tensor(frames)
    assert out.shape == (2, 3, 224, 224) and out.dtype == torch.float32
    for i, frame in enumerate(frames):
        torch.testing.assert_close(out[i], _tvl_reference(frame), atol=1e-6, rtol=0)
    bgs = [rng.integers(0, 256, f.shape, dtype=np.uint8) for f in frames]
    out_bg = tvl_tactile_tensor(frames, background=bgs)
    for i, frame in enumerate(frames):
        torch.testing.assert_close(out_bg[i], _tvl_reference(frame, bgs[i]), atol=1e-4, rtol=0)


def test_tvl_tactile_tensor_orientation_and_padding():
    frame = np.zeros((16, 32, 3), np.uint8)  # wide frame: padded top/bottom
    frame[:, :4] = 255  # left edge white
    out = tvl_tactile_tensor([frame], size=32)[0]
    black = (0 - torch.tensor(TAC_MEAN)) / torch.tensor(TAC_STD)
    # Rotated 90 degrees counter-clockwise: the left edge becomes the bottom edge,
    # and the padding (black) ends up on the left and right.
    assert torch.all(out[:, -1, 10:22] > 2)
    assert torch.allclose(out[:, 10, 0], black, atol=1e-5)
    assert torch.allclose(out[:, 10, -1], black, atol=1e-5)
    # Odd size difference: still a square result.
    assert tvl_tactile_tensor([np.zeros((17, 32, 3), np.uint8)], size=20).shape == (1, 3, 20, 20)


def test_tvl_tactile_tensor_backgrounds():
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (40, 30, 3), dtype=np.uint8) for _ in range(2)]
    same = tvl_tactile_tensor(frames, size=32, background=frames)  # frame - itself = 0
    want = (0 - torch.tensor(TAC_MEAN_BG)) / torch.tensor(TAC_STD_BG)
    torch.testing.assert_close(same[:, :, 3, 3], want.expand(2, 3), atol=1e-5, rtol=0)
    one = tvl_tactile_tensor(frames, size=32, background=frames[0])
    torch.testing.assert_close(one[0], same[0])
    mixed = tvl_tactile_tensor(frames, size=32, background=[frames[0], None])
    torch.testing.assert_close(mixed[1], tvl_tactile_tensor(frames[1:], size=32)[0])
    narrow = np.zeros((40, 20, 3), np.uint8)
    msg = r"background 1 is 20x40 \(WxH\) but tactile frame 1 is 30x40"
    with pytest.raises(DataError, match=msg):
        tvl_tactile_tensor(frames, size=32, background=[frames[0], narrow])
    with pytest.raises(DataError, match="got 1 background images for 2 tactile frames"):
        tvl_tactile_tensor(frames, size=32, background=[frames[0]])


def test_tensor_builders_reject_bad_arguments():
    img = np.zeros((20, 20, 3), np.uint8)
    for fn in (clip_rgb_tensor, tvl_tactile_tensor):
        with pytest.raises(ConfigError, match="size must be between"):
            fn([img], size=4)
        with pytest.raises(ConfigError, match="size must be an integer"):
            fn([img], size=22.5)
        with pytest.raises(DataError, match="wrap it in a list"):
            fn(img)
        with pytest.raises(DataError, match="wrap it in a list"):
            fn(Image.new("RGB", (20, 20)))
    with pytest.raises(DataError, match="image 1 is 3x3"):
        clip_rgb_tensor([img, np.zeros((3, 3, 3), np.uint8)])
    with pytest.raises(DataError, match="tactile frame 4 is 3x3"):
        tvl_tactile_tensor([img, np.zeros((3, 3, 3), np.uint8)], index_offset=3)


def test_module_constants_match_tvl():
    assert pp.TAC_MEAN == (0.29174602047139075, 0.2971325588927249, 0.2910404549605639)
    assert pp.TAC_STD == (0.18764469044810236, 0.19467651810273057, 0.21871583397361818)
    assert pp.TAC_MEAN_BG[0] == -0.00809318389762342 and pp.TAC_STD_BG[2] == 0.05332520729596308
    assert pp.CLIP_MEAN == (0.48145466, 0.4578275, 0.40821073)


# --------------------------------------------------------------------------- real ViT-L-14


@pytest.mark.slow
def test_real_vit_l_14_architecture_round_trip(tmp_path):
    """The real ViT-L-14 + ViT-Tiny layout, random weights (about 45 s and 4 GB on CPU)."""
    torch.manual_seed(0)
    clip = open_clip.create_model("ViT-L-14", pretrained=None)
    save_file({k: v.contiguous() for k, v in clip.state_dict().items()},
              str(tmp_path / "open_clip_model.safetensors"))
    ref_proj = clip.text_projection.detach().clone()
    del clip
    torch.save(_tvl_checkpoint(_tiny_tactile(num_classes=768).state_dict()),
               tmp_path / "tvl_enc_vittiny.pth")
    enc = load_tvl(tmp_path / "open_clip_model.safetensors", tmp_path / "tvl_enc_vittiny.pth",
                   TVLConfig())
    assert enc.name == "tvl-vittiny" and enc.dim == 768 and enc.image_size == 224
    assert torch.equal(enc.clip.text_projection, ref_proj)
    image = enc.encode_image([np.zeros((300, 400, 3), np.uint8)])
    tactile = enc.encode_tactile([np.zeros((320, 240, 3), np.uint8)])
    text = enc.encode_text(["soft and fuzzy"])
    for out in (image, tactile, text):
        assert out.shape == (1, 768)
        np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)


# --------------------------------------------------------------------------- devices


def test_create_model_takes_a_device_for_tvl_and_keeps_the_default_backend_on_the_cpu(
        files, monkeypatch):
    """`create_model(..., device=)`: the TVL backend's models go where asked (the loader checks
    the name); the default backend refuses anything but the CPU, with a message."""
    from ratouch.encoders import factory

    monkeypatch.setattr(factory, "MODEL_CONFIGS", {**factory.MODEL_CONFIGS, "tvl-mini": {
        "name": "tvl-mini", "backend": "tvl", "dim": MINI_DIM, "clip_arch": MINI_ARCH,
        "tactile_arch": "vit_tiny_patch16_224"}})
    enc = factory.create_model("tvl-mini", pretrained=files["root"], device="cpu")
    assert enc.device == torch.device("cpu")
    with pytest.raises(ConfigError, match="invalid device 'gpu0'"):
        factory.create_model("tvl-mini", pretrained=files["root"], device="gpu0")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="CUDA is not available"):
            factory.create_model("tvl-mini", pretrained=files["root"], device="cuda")
    with pytest.raises(ConfigError, match="runs on the CPU in fp32 only"):
        factory.create_model("default-tiny", pretrained=None, device="cuda")
    with pytest.raises(ConfigError, match="runs on the CPU in fp32 only"):
        factory.create_model("default-tiny", pretrained=None, precision="bf16")
    assert factory.create_model("tvl-mini", pretrained=files["root"],
                                precision="bf16").cfg.precision == "bf16"


def _device_check():
    import importlib.util
    import sys

    path = Path(__file__).resolve().parents[1] / "scripts" / "device_check.py"
    spec = importlib.util.spec_from_file_location("device_check", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["device_check"] = module
    spec.loader.exec_module(module)
    return module


def test_device_check_script_compares_both_paths_and_fails_on_a_miss(files, monkeypatch,
                                                                     tmp_path, capsys):
    """scripts/device_check.py, the CPU against itself (no GPU here): the TVL encoders (the
    mini architecture, random weights written by the script in the real layouts) and the
    default encoders' training step agree exactly; a bar they cannot meet exits 1, and a
    device that cannot be used exits 2 with a message."""
    from ratouch.encoders import factory

    monkeypatch.setattr(factory, "MODEL_CONFIGS", {**factory.MODEL_CONFIGS, "tvl-mini": {
        "name": "tvl-mini", "backend": "tvl", "dim": MINI_DIM, "clip_arch": MINI_ARCH,
        "tactile_arch": "vit_tiny_patch16_224"}})
    script = _device_check()
    out = tmp_path / "check.json"
    argv = ["--device", "cpu", "--encoder", "tvl-mini", "--model", "default-tiny", "--n", "3",
            "--steps", "2", "--batch", "8"]
    assert script.main(argv + ["--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["passed"] and rep["tvl"]["encoder"] == "tvl-mini"
    for kind in ("image", "tactile", "text"):
        assert rep["tvl"][f"{kind}_min_cos"] == pytest.approx(1.0, abs=1e-6)
        assert rep["tvl"]["cpu"][f"{kind}_seconds"] > 0
    tr = rep["training"]
    assert tr["batch"] == 8 and len(tr["cpu_losses"]) == len(tr["device_losses"]) == 2
    assert tr["cpu_losses"] == tr["device_losses"] and tr["loss_max_rel_diff"] == 0.0
    assert tr["cpu_losses"][1] != tr["cpu_losses"][0]  # the optimiser stepped
    assert script.main(argv + ["--min-cos", "1.01"]) == 1
    capsys.readouterr()
    assert script.main(["--device", "nowhere"]) == 2
    assert "cannot use device 'nowhere'" in capsys.readouterr().err


def test_bf16_precision_is_checked_and_close_to_fp32(files, cfg):
    """`TVLConfig.precision`: "fp32" or "bf16" (the towers under bfloat16 autocast, the rows
    still float32 and unit length, near fp32's); anything else is refused."""
    with pytest.raises(ConfigError, match="precision must be one of fp32, bf16"):
        TVLConfig(clip_arch=MINI_ARCH, tactile_arch="tiny", dim=MINI_DIM, precision="fp16")
    half = load_tvl(files["clip"], files["tactile"],
                    TVLConfig(clip_arch=MINI_ARCH, tactile_arch="tiny", dim=MINI_DIM,
                              precision="bf16"))
    full = load_tvl(files["clip"], files["tactile"], cfg)
    images = _rand_images(3, seed=5)
    a, b = full.encode_image(images), half.encode_image(images)
    assert b.dtype == np.float32 and not np.array_equal(a, b)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-5)
    assert np.min(np.sum(a * b, axis=1)) > 0.98

"""The decoder: tokenizer, loss, greedy generation with a KV cache, LoRA, the HF path.

Everything runs on a tiny LLaMA (hidden 32, 2 layers, ~60 words); the HF path uses a tiny random
`LlamaForCausalLM` saved to disk with a `tokenizers`-built tokenizer, loaded offline like a real
LLaMA-2 folder.
"""

from __future__ import annotations

import json

import pytest
import torch

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.model.decoder import (
    PROMPT,
    Decoder,
    DecoderConfig,
    TactileTokenizer,
    build_small_decoder,
    clean_description,
    load_hf_decoder,
)
from ratouch.vocabulary import TVL_ADJECTIVES

WORDS = TVL_ADJECTIVES[:48]
CAPTIONS = ["hard, smooth, flat", "soft, plush", "rough, grainy, coarse, bumpy", "glossy"]


def tiny_cfg(**kw) -> DecoderConfig:
    base = dict(hidden=32, layers=2, heads=2, intermediate=64, max_new_tokens=8, lora_r=4,
                lora_alpha=8)
    base.update(kw)
    return DecoderConfig(**base)


def tiny_decoder(seed: int = 0, **kw) -> Decoder:
    return build_small_decoder(tiny_cfg(**kw), WORDS, seed=seed)


def overfit(dec: Decoder, prefix: torch.Tensor, captions: list[str], steps: int) -> list[float]:
    opt = torch.optim.Adam([p for p in dec.parameters() if p.requires_grad], lr=1e-2)
    losses = []
    dec.train()
    for _ in range(steps):
        loss = dec.forward_loss(prefix, captions)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    return losses


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Tiny models: intra-op threads only add overhead, and on a shared 2-core machine they
    wait on each other (80 training steps took 50 s with 2 threads, 1 s with one)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def trained():
    """A tiny decoder overfitted on four captions, each bound to its own random prefix."""
    dec = tiny_decoder()
    prefix = torch.randn(4, 1, 32, generator=torch.Generator().manual_seed(1))  # (4, 1, D')
    losses = overfit(dec, prefix, CAPTIONS, 80)
    return dec.eval(), prefix, losses


# --- tokenizer ---------------------------------------------------------------------------

def test_tokenizer_round_trip_and_unknown_words(tmp_path):
    tok = TactileTokenizer.build(WORDS)
    assert 55 <= len(tok) <= 70
    assert tok.unk_id not in tok.encode(PROMPT)
    ids = tok.encode("Hard,  Smooth , flat")
    assert tok.decode(ids) == "hard, smooth, flat"
    unk = tok.encode("hard zorblax")
    assert unk[1] == tok.unk_id and tok.decode(unk) == "hard <unk>"
    assert tok.decode([tok.bos_id] + ids + [tok.eos_id, tok.pad_id]) == "hard, smooth, flat"
    tok.save(tmp_path / "tok.json")
    again = TactileTokenizer.load(tmp_path / "tok.json")
    assert again.words == tok.words and again.encode("soft, plush") == tok.encode("soft, plush")


def test_tokenizer_load_errors(tmp_path):
    with pytest.raises(DataNotFoundError):
        TactileTokenizer.load(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(DataError):
        TactileTokenizer.load(tmp_path / "bad.json")
    (tmp_path / "nospecial.json").write_text(json.dumps({"words": ["hard", "soft"]}))
    with pytest.raises(DataError, match="special"):
        TactileTokenizer.load(tmp_path / "nospecial.json")


def test_clean_description():
    assert clean_description("hard, smooth, smooth, flat") == "hard, smooth, flat"
    assert clean_description("a, b, c, d, e, f, g") == "a, b, c, d, e"
    assert clean_description(" Soft , , plush. <unk>,") == "soft, plush"
    assert clean_description("") == ""


def test_config_validation():
    with pytest.raises(ConfigError, match="kind"):
        DecoderConfig(kind="gpt")
    with pytest.raises(ConfigError, match="path"):
        DecoderConfig(kind="hf")
    with pytest.raises(ConfigError, match="heads"):
        DecoderConfig(hidden=30, heads=4)
    with pytest.raises(ConfigError, match="lora_dropout"):
        DecoderConfig(lora_dropout=1.0)
    with pytest.raises(ConfigError, match="lora_targets"):
        DecoderConfig(lora_targets="q_proj")
    assert DecoderConfig(lora_targets=["q_proj"]).lora_targets == ("q_proj",)


# --- loss and generation -----------------------------------------------------------------

def test_overfit_then_reproduce(trained):
    dec, prefix, losses = trained
    assert all(torch.isfinite(torch.tensor(losses)))
    assert losses[-1] < 0.1 * losses[0]
    # Rows of different lengths each stop at their own <eos>.
    assert dec.generate(prefix) == CAPTIONS


def test_generation_is_deterministic_and_keeps_mode(trained):
    dec, prefix, _ = trained
    dec.train()
    first = dec.generate(prefix)
    assert dec.training  # restored after generating in eval mode
    dec.eval()
    assert dec.generate(prefix) == first


def test_max_new_tokens(trained):
    dec, prefix, _ = trained
    assert dec.generate(prefix, max_new_tokens=2) == ["hard,", "soft,", "rough,", "glossy"]
    assert dec.generate(prefix, max_new_tokens=0) == [""] * 4
    with pytest.raises(ConfigError):
        dec.generate(prefix, max_new_tokens=-1)
    rnd = tiny_decoder(seed=3).eval()
    for text in rnd.generate(torch.randn(3, 2, 32), max_new_tokens=5):
        assert len(rnd.tokenizer.encode(text)) <= 5


def test_kv_cache_matches_recomputation(trained):
    dec, prefix, _ = trained
    assert dec.generate(prefix, use_cache=False) == dec.generate(prefix)
    rnd = tiny_decoder(seed=5).eval()
    p = torch.randn(3, 2, 32, generator=torch.Generator().manual_seed(2))
    assert rnd.generate(p, 8, use_cache=False) == rnd.generate(p, 8)


def test_prefix_shape_is_checked():
    dec = tiny_decoder()
    with pytest.raises(ConfigError, match="prefix"):
        dec.generate(torch.randn(2, 1, 16))
    with pytest.raises(ConfigError, match="targets"):
        dec.forward_loss(torch.randn(2, 1, 32), ["hard"])


# --- LoRA --------------------------------------------------------------------------------

def test_lora_trains_only_the_adapter():
    dec = tiny_decoder()
    prefix = torch.randn(2, 1, 32)
    before_out = dec.forward_loss(prefix, CAPTIONS[:2]).item()
    base_before = {k: v.clone() for k, v in dec.base_state_dict().items()}
    dec.add_lora()
    trainable = [n for n, p in dec.named_parameters() if p.requires_grad]
    assert trainable and all("lora_" in n for n in trainable)
    # q_proj and v_proj in both layers, A and B each.
    assert len(trainable) == 2 * 2 * 2
    # LoRA B starts at zero: the adapter does not change the model until trained.
    assert dec.forward_loss(prefix, CAPTIONS[:2]).item() == pytest.approx(before_out, abs=1e-5)
    lora_before = {n: p.detach().clone() for n, p in dec.named_parameters() if p.requires_grad}
    overfit(dec, prefix, CAPTIONS[:2], 1)
    base_after = dec.base_state_dict()
    assert base_after.keys() == base_before.keys()
    assert all(torch.equal(base_before[k], base_after[k]) for k in base_before)
    assert any(not torch.equal(lora_before[n], p) for n, p in dec.named_parameters()
               if p.requires_grad)
    with pytest.raises(ConfigError, match="already"):
        dec.add_lora()


def test_adapter_round_trip(tmp_path):
    prefix = torch.randn(4, 1, 32, generator=torch.Generator().manual_seed(7))
    dec = tiny_decoder()
    dec.add_lora()
    overfit(dec, prefix, CAPTIONS, 5)
    dec.eval()
    dec.save_adapter(tmp_path / "adapter")
    assert (tmp_path / "adapter" / "adapter_model.safetensors").is_file()
    ref_loss = dec.forward_loss(prefix, CAPTIONS)
    ref_text = dec.generate(prefix)

    fresh = tiny_decoder().eval()  # same seed: the same base weights
    plain_loss = fresh.forward_loss(prefix, CAPTIONS)
    fresh.load_adapter(tmp_path / "adapter")
    assert not any(p.requires_grad for p in fresh.parameters())
    assert torch.equal(fresh.forward_loss(prefix, CAPTIONS), ref_loss)
    assert not torch.equal(plain_loss, ref_loss)  # the adapter really changed the model
    assert fresh.generate(prefix) == ref_text

    again = tiny_decoder().eval()
    again.add_lora()
    again.load_adapter(tmp_path / "adapter", trainable=True)  # onto an existing adapter
    assert torch.equal(again.forward_loss(prefix, CAPTIONS), ref_loss)
    assert all("lora_" in n for n, p in again.named_parameters() if p.requires_grad)

    with pytest.raises(DataNotFoundError):
        tiny_decoder().load_adapter(tmp_path / "nowhere")
    wider = build_small_decoder(tiny_cfg(hidden=64, heads=4), WORDS)
    with pytest.raises(DataError):
        wider.load_adapter(tmp_path / "adapter")


# --- the HF (LLaMA-2) path -----------------------------------------------------------------

def test_hf_decoder_with_lora_on_all_layers(tiny_llama):
    dec = load_hf_decoder(DecoderConfig(kind="hf", path=str(tiny_llama), max_new_tokens=6))
    assert dec.hidden == 64
    dec.add_lora()
    lora_layers = {n.split(".layers.")[1].split(".")[0] for n, _ in dec.named_parameters()
                   if "lora_" in n}
    assert lora_layers == {"0", "1"}
    prefix = torch.randn(2, 1, 64)
    loss = dec.forward_loss(prefix, ["hard, smooth", "soft"])
    assert torch.isfinite(loss)
    loss.backward()
    grads = [n for n, p in dec.named_parameters() if p.grad is not None]
    assert grads and all("lora_" in n for n in grads)
    out = dec.generate(prefix)
    assert len(out) == 2 and all(isinstance(t, str) for t in out)
    assert dec.generate(prefix, use_cache=False) == out
    assert all(len(dec.tokenizer.encode(t)) <= 6 for t in out)


def test_hf_decoder_errors(tmp_path):
    with pytest.raises(DataNotFoundError):
        load_hf_decoder(DecoderConfig(kind="hf", path=str(tmp_path / "missing")))
    with pytest.raises(DataError, match="config.json"):
        load_hf_decoder(DecoderConfig(kind="hf", path=str(tmp_path)))
    (tmp_path / "config.json").write_text(json.dumps({"model_type": "gpt2"}))
    with pytest.raises(DataError, match="not a LLaMA"):
        load_hf_decoder(DecoderConfig(kind="hf", path=str(tmp_path)))

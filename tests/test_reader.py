"""The `gated` system's generator, the reader (`ratouch.train.recipes.reader_recipe`): its
reading episodes, its training end to end on a few world pairs, and how a request that names
the gated system is answered by it."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from conftest import HAVE_ASSETS
from ratouch.cli import main
from ratouch.errors import ConfigError
from ratouch.model.gate import READ_BELOW
from ratouch.serve.pipeline import TrustRouted
from ratouch.train import recipes
from ratouch.train.recipes import (
    READER_NOISE_RMS,
    degraded_touch,
    noisy_inputs,
    reader_episodes,
)


class _Encoders:
    """embed_tactile: a fixed random projection of the flattened input, normalised."""

    name = "fake"

    def __init__(self, size: int, dim: int = 6):
        self.proj = torch.randn(size, dim, generator=torch.Generator().manual_seed(1))

    def embed_tactile(self, x: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.normalize(x.flatten(1).float() @ self.proj, dim=-1)


def _data(n: int = 40):
    rng = np.random.default_rng(0)
    plain = rng.normal(size=(n, 4, 5, 3)).astype(np.float16)
    return {"tactile": plain, "tactile_bg": (plain * 0.5).astype(np.float16)}


def test_noisy_inputs_drown_the_signal_and_keep_the_contrast():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(8, 4, 12, 10, generator=g) * torch.linspace(0.2, 3, 8)[:, None, None, None]
    y = noisy_inputs(x, torch.Generator().manual_seed(1))
    rms = y[:, :3].pow(2).mean((1, 2, 3)).sqrt()
    assert torch.allclose(rms, torch.ones(8), atol=1e-4)       # unit RMS, as tactile_input
    assert torch.equal(y[:, 3:], x[:, 3:])                      # the contrast channel kept
    cos = torch.nn.functional.cosine_similarity(y[:, :3].flatten(1), x[:, :3].flatten(1))
    expected = 1 / np.sqrt(1 + READER_NOISE_RMS ** 2)           # 0.32 for 3x noise
    assert abs(cos.mean().item() - expected) < 0.05 and ((cos > 0.1) & (cos < 0.55)).all()


def test_degraded_touch_mismatches_half_and_noises_the_other_half():
    data = _data()
    enc = _Encoders(4 * 5 * 3)
    gen = torch.Generator().manual_seed(0)
    from ratouch.train.encoders import tactile_batch
    T = enc.embed_tactile(tactile_batch(data, torch.arange(40), gen)).numpy()
    out = degraded_touch(enc, data, T, seed=3)
    assert out.shape == T.shape and np.isfinite(out).all()
    own = np.isclose(out, T, atol=1e-6).all(1)
    assert not own.any()                                        # nobody keeps its own touch
    other = np.array([any(np.isclose(out[i], T[j], atol=1e-6).all() for j in range(40) if j != i)
                      for i in range(40)])
    assert 10 <= other.sum() <= 30 and (~other).sum() >= 10     # about half each
    assert np.array_equal(out, degraded_touch(enc, data, T, seed=3))  # seeded
    assert not np.array_equal(out, degraded_touch(enc, data, T, seed=4))


def test_episodes_need_the_gate():
    side = SimpleNamespace(gate=None)
    with pytest.raises(ConfigError, match="train gate"):
        reader_episodes(side, _Encoders(60), _data(), np.zeros((40, 6)), np.zeros((40, 6)), 5)


def test_trust_routed_answers_each_row_with_the_reader_only_where_touch_is_untrusted():
    w = np.array([0.1, 0.9, READ_BELOW - 0.01, READ_BELOW])
    side = SimpleNamespace(gate=SimpleNamespace(weights=lambda V, T, J: w),
                           joint_query=lambda V, T: V)

    def gen(tag):
        return SimpleNamespace(describe=lambda V, T, *nb: [f"{tag}{int(v[0])}:{len(nb)}"
                                                           for v in V])

    V = torch.arange(4, dtype=torch.float32)[:, None].repeat(1, 3)
    nb = torch.zeros(4, 5, 3)
    routed = TrustRouted(side, gen("paper"), gen("reader"))
    assert routed.describe(V, V, nb, nb) == ["reader0:2", "paper1:2", "reader2:2", "paper3:2"]
    assert routed.describe(V, V) == ["reader0:0", "paper1:0", "reader2:0", "paper3:0"]


def test_train_reader_cli_wires_the_recipe(monkeypatch, capsys, tmp_path):
    seen = {}

    def fake(encoder, stage1_from, seed=0, out=None, **kw):
        seen.update(encoder=encoder, stage1_from=str(stage1_from), seed=seed, out=str(out), **kw)
        return None, {"system": "gated", "history": [1, 2], "seconds": 0.1}

    monkeypatch.setattr(recipes, "reader_recipe", fake)
    assert main(["train", "reader", "--seed", "2", "--steps", "7",
                 "--out", str(tmp_path / "r")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out == {"system": "gated", "seconds": 0.1}             # the history is left out
    assert seen["seed"] == 2 and seen["stage2_steps"] == 7 and seen["out"] == str(tmp_path / "r")
    assert seen["stage1_from"].endswith("generator/default-s/ra")
    assert seen["arm"] == recipes.READER_ARM                      # the shipped reader's form
    assert main(["train", "reader", "--arm", "text", "--out", str(tmp_path / "r")]) == 0
    assert seen["arm"] == "text"


def test_reader_arm_must_be_known():
    with pytest.raises(ConfigError, match="known arms are integrator, text"):
        recipes.reader_recipe("default-s", "nowhere", arm="pointer")


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSETS, reason="the trained weights are not in assets/")
@pytest.mark.parametrize("arm", recipes.READER_ARMS)
def test_reader_trains_on_a_few_pairs_and_answers_the_gated_system(real_pipeline, world,
                                                                   tmp_path, arm):
    """The reader, in either form (a Texture-Aware Integrator, or the neighbours' captions in
    the prompt), end to end on 24 world training pairs (3 steps): it saves, loads for
    serving, and a request naming "gated" is answered by it (the result says so), while
    "paper" keeps the paper's generator."""
    from ratouch.model.generator import load_generator, save_generator
    from ratouch.model.integrator import TextureAwareIntegrator
    from ratouch.model.neighbour_text import NeighbourText
    from ratouch.paths import generator_weights
    from ratouch.serve.pipeline import RATouchPipeline, load_for_serving
    from ratouch.serve.request import QueryRequest
    from ratouch.train.encoders import _pair_chunk, tactile_batch
    from ratouch.train.generator import GeneratorTrainConfig
    from ratouch.world.config import WorldConfig

    p = real_pipeline
    if p.gate is None:
        pytest.skip("no shipped touch gate")
    cfg = p.encoders.cfg
    _, _, tacs, tacs_bg, labels, _ = _pair_chunk(
        (WorldConfig(seed=0), list(range(24)), cfg.vision_size, cfg.tactile_size, 0))
    data = {"tactile": np.stack(tacs), "tactile_bg": np.stack(tacs_bg)}
    V = p.encoders.encode_image([world.sample("train", i).crop for i in range(24)])
    with torch.no_grad():
        T = p.encoders.embed_tactile(tactile_batch(data, torch.arange(24),
                                                   torch.Generator().manual_seed(0))).numpy()
    stage1 = load_generator(generator_weights("default-s", "ra"), stage1=True)
    tc = GeneratorTrainConfig(stage2_steps=3, batch=8)
    torch.manual_seed(1)  # two processes' different initial seeds: the same reader
    gen, info = recipes.train_reader(p, p.encoders, stage1, data, V, T, labels, tc, arm)
    torch.manual_seed(2)
    again, _ = recipes.train_reader(p, p.encoders, stage1, data, V, T, labels, tc, arm)
    trained, retrained = gen.state_dict(), again.state_dict()
    assert trained.keys() == retrained.keys()
    assert all(torch.equal(trained[k], retrained[k]) for k in trained)
    assert info["episodes"]["n_pairs"] == 24 and 0 < info["episodes"]["degraded"] < 24
    assert info["arm"] == arm and len(info["history"]) == 1
    form = NeighbourText if arm == "text" else TextureAwareIntegrator
    assert isinstance(gen.integrator, form)
    save_generator(tmp_path / "reader", gen, {"encoder": "default-s", **info}, half=True)
    reader = load_for_serving(tmp_path / "reader")
    assert isinstance(reader.integrator, form)
    pipe = RATouchPipeline(p.retriever, p.tgr, p.generator_ra, p.generator_base, pca=p.pca,
                           trust=p.trust, gate=p.gate, generator_reader=reader)
    s = world.sample("test", 12)
    res = {system: pipe.answer([QueryRequest.decode(s.visual, s.tactile, s.box, 5,
                                                    retrieval=system)])[0].to_dict()
           for system in ("paper", "gated")}
    g = res["gated"]["retrieval"]
    assert g["generator"] == ("reader" if g["touch_weight"] < READ_BELOW else "paper")
    assert res["paper"]["retrieval"]["generator"] == "paper"
    # touch that is pure noise: the gate trusts it little, and the reader answers
    noise = np.random.default_rng(0).integers(0, 256, s.tactile.shape, dtype=np.uint8)
    noisy = pipe.answer([QueryRequest.decode(s.visual, noise, s.box, 5,
                                             retrieval="gated")])[0].to_dict()["retrieval"]
    assert noisy["touch_weight"] < READ_BELOW and noisy["generator"] == "reader"
    assert any("reader" in w for w in noisy["why"])
    for r in res.values():
        assert r["description"]["ra_touch"] and r["description"]["baseline"]
    # both systems in one batch: each answered as it would be alone
    both = pipe.answer([QueryRequest.decode(s.visual, s.tactile, s.box, 5, retrieval=system)
                        for system in ("paper", "gated")])
    assert [b.to_dict()["description"] for b in both] == [res["paper"]["description"],
                                                          res["gated"]["description"]]
    again = pipe.regenerate(QueryRequest.decode(s.visual, s.tactile, s.box, 5, retrieval="gated"),
                            [n["id"] for n in res["gated"]["neighbours"]["gated"]])
    assert again["description"]["ra_touch"] == res["gated"]["description"]["ra_touch"]

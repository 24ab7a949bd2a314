"""The `text` retrieval system: the paper's joint query, its neighbours' captions written into
the prompt by the text arm (`ratouch.model.neighbour_text`), shipped beside `paper` and
`gated` (`RETRIEVAL_SYSTEMS`), trained by `ratouch train text` and `ratouch train all`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import HAVE_ASSETS
from ratouch.cli import main
from ratouch.model.neighbour_text import NeighbourText, NeighbourTextConfig
from ratouch.serve.pipeline import text_arm_fits
from ratouch.serve.request import QueryRequest
from ratouch.train import recipes


def _arm(keys: np.ndarray) -> NeighbourText:
    arm = NeighbourText(NeighbourTextConfig(dim=keys.shape[1], out_dim=4, entries=len(keys),
                                            vocab=2))
    arm.keys.copy_(torch.from_numpy(keys))
    return arm


def test_a_text_arm_fits_only_the_corpus_it_was_built_on():
    keys = np.random.default_rng(0).normal(size=(300, 8)).astype(np.float32)
    arm = _arm(keys)
    assert text_arm_fits(arm, keys)
    assert text_arm_fits(arm, keys.astype(np.float16).astype(np.float32))  # half precision
    assert not text_arm_fits(arm, keys[:299])                   # another size
    other = keys.copy()
    other[-1] += 0.5                                            # another last caption
    assert not text_arm_fits(arm, other)


def test_train_text_cli_wires_the_recipe(monkeypatch, capsys, tmp_path):
    seen = {}

    def fake(encoder, stage1_from, seed=0, out=None, **kw):
        seen.update(encoder=encoder, stage1_from=str(stage1_from), seed=seed, out=str(out), **kw)
        return None, {"arm": "neighbour_text", "history": [1], "seconds": 0.2}

    monkeypatch.setattr(recipes, "text_arm_recipe", fake)
    assert main(["train", "text", "--seed", "3", "--steps", "5",
                 "--out", str(tmp_path / "t")]) == 0
    assert json.loads(capsys.readouterr().out) == {"arm": "neighbour_text", "seconds": 0.2}
    assert seen["seed"] == 3 and seen["stage2_steps"] == 5 and seen["out"] == str(tmp_path / "t")
    assert seen["stage1_from"].endswith("generator/default-s/ra")
    assert main(["train", "text"]) == 0
    assert seen["out"].endswith("generator/default-s/text")


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSETS, reason="the trained weights are not in assets/")
def test_the_text_system_answers_with_the_text_arm(real_pipeline, world):
    """A request naming "text" reads the joint query's neighbours (as "paper" does) and is
    answered by the shipped text arm, rebuilt on the corpus served (the tests' 600 entries,
    not the 10k it was trained on): it writes this corpus's captions. The result says so;
    `system_generator` (what `eval tvl --retrieval text` judges) is the same generator."""
    p = real_pipeline
    if p.generator_text is None:
        pytest.skip(f"no shipped text arm: {p.text_missing}")
    arm = p.generator_text.integrator
    assert isinstance(arm, NeighbourText) and arm.cfg.words == 10
    assert text_arm_fits(arm, p.corpus_embeddings("tactile_caption"))
    assert p.system_generator("text") is p.generator_text
    s = world.sample("test", 7)
    res = {system: p.answer([QueryRequest.decode(s.visual, s.tactile, s.box, 5,
                                                 retrieval=system)])[0].to_dict()
           for system in ("paper", "text")}
    t = res["text"]["retrieval"]
    assert t["system"] == "text" and t["reads"] == "joint" and t["generator"] == "text"
    assert any("captions are written into the prompt" in w for w in t["why"])
    assert res["text"]["description"]["ra_touch"]
    joint = res["text"]["neighbours"]["joint"]
    assert [n["id"] for n in joint] == [n["id"] for n in res["paper"]["neighbours"]["joint"]]
    # the words the arm writes are those of the neighbours this corpus returned
    Rl = torch.from_numpy(np.asarray(p.corpus_embeddings("tactile_caption"))[
        [n["id"] for n in joint]][None].astype(np.float32))
    captions = [e.caption for e in p.corpus.entries]
    assert [captions[i] for i in arm.entries(Rl)[0].tolist()] == [n["caption"] for n in joint]
    # with no text arm loaded, "text" is answered by the paper's generator, which it says
    from ratouch.serve.pipeline import RATouchPipeline

    q = RATouchPipeline(p.retriever, p.tgr, p.generator_ra, p.generator_base, pca=p.pca,
                        trust=p.trust, gate=p.gate, generator_reader=p.generator_reader)
    r = q.answer([QueryRequest.decode(s.visual, s.tactile, s.box, 5,
                                      retrieval="text")])[0].to_dict()["retrieval"]
    assert r["generator"] == "paper"
    assert any("no text-arm generator is loaded: the paper's generator answers" in w
               for w in r["why"])


def test_without_a_text_arm_the_text_system_says_the_paper_answers(monkeypatch):
    from ratouch.serve import pipeline as pl

    monkeypatch.setattr(pl, "generator_weights", lambda enc, kind, lm=None: Path("/nowhere"))
    assert pl.load_text_arm("default-s") is None


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSETS, reason="the trained weights are not in assets/")
def test_a_pipeline_rebuilds_the_text_arm_in_a_generator_of_its_own(real_pipeline):
    """One loaded text generator handed to a pipeline on a corpus it was not built on is
    left as it was: the pipeline rebuilds the arm in a generator of its own (sharing the
    frozen prompt and decoder), so another pipeline can still serve the given one."""
    from ratouch.serve.pipeline import RATouchPipeline, load_text_arm

    given = load_text_arm("default-s")
    if given is None:
        pytest.skip("no shipped text arm")
    arm = given.integrator
    p = real_pipeline
    other = RATouchPipeline(p.retriever, p.tgr, p.generator_ra, p.generator_base,
                            trust=p.trust, generator_text=given)
    assert given.integrator is arm                          # the one given is untouched
    assert other.generator_text is not given
    assert other.generator_text.decoder is given.decoder   # the frozen parts are shared
    assert text_arm_fits(other.generator_text.integrator,
                         p.corpus_embeddings("tactile_caption"))
    assert not any(t.requires_grad for t in other.generator_text.parameters())

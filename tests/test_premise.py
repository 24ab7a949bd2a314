"""The scarce-touch regime and the premise's statistics and verdict."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from ratouch.errors import ConfigError
from ratouch.eval.premise import _aggregate, decide, format_premise, pooled_ci, run_premise
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for
from ratouch.world.material import MATERIALS
from ratouch.world.scarcity import ScarceRegime, premise_indices


def _materials(split: str, indices) -> list[str]:
    world = world_for(WorldConfig(seed=0))
    return [world.plan(split, i)[2].name for i in indices]


def test_scarce_regime_keeps_few_pairs_of_its_scarce_materials():
    r = ScarceRegime(tail_pairs=3)
    scarce = r.scarce_materials()
    assert len(scarce) == 14 and len(set(scarce)) == 14
    assert set(scarce) <= {m.name for m in MATERIALS}
    assert scarce == ScarceRegime(tail_pairs=3, draw=5).scarce_materials()  # the world fixes it
    assert scarce != ScarceRegime(seed=1).scarce_materials()
    idx = r.train_indices(1500)
    assert len(idx) == 1500 == len(set(idx)) and idx == sorted(idx)
    counts = Counter(_materials("train", idx))
    assert all(counts[m] == 3 for m in scarce)  # the world has dozens of each in this stretch
    head = [c for m, c in counts.items() if m not in scarce]
    assert max(head) > 20 * 3  # a dense head
    other = ScarceRegime(tail_pairs=3, draw=1).train_indices(1500)
    kept = lambda ix: {i for i, m in zip(ix, _materials("train", ix)) if m in scarce}  # noqa: E731
    assert kept(idx) != kept(other)  # a draw picks which few pairs survive
    assert ScarceRegime(regime="full").train_indices(7) == list(range(7))
    for n in (1, 2, 5):
        assert len(set(ScarceRegime().train_indices(n))) == n
    assert ScarceRegime(regime="full").scarce_materials() == ()


@pytest.mark.parametrize("bad", [{"regime": "sparse"}, {"draw": -1}, {"n_scarce": 0},
                                 {"n_scarce": 47}, {"tail_pairs": -2}])
def test_scarce_regime_rejects_bad_settings(bad):
    with pytest.raises(ConfigError):
        ScarceRegime(**bad)


def test_premise_groups_hold_only_their_materials():
    r = ScarceRegime()
    scarce = set(r.scarce_materials())
    s, seen = premise_indices("scarce", 30, r), premise_indices("seen", 30, r)
    assert not set(s) & set(seen)
    assert all(m in scarce for m in _materials("probe", s))
    assert not any(m in scarce for m in _materials("probe", seen))
    assert len(set(_materials("probe", s))) > 5  # balanced over the scarce materials
    with pytest.raises(ConfigError):
        premise_indices("rare", 3, r)


def test_pooled_ci_widens_with_disagreeing_runs():
    rng = np.random.default_rng(0)
    same = [rng.normal(0.2, 1.0, 400) for _ in range(3)]
    lo, hi = pooled_ci(same)
    assert lo < np.mean([d.mean() for d in same]) < hi
    apart = [d + shift for d, shift in zip(same, (-1.0, 0.0, 1.0))]
    lo2, hi2 = pooled_ci(apart)
    assert hi2 - lo2 > 2 * (hi - lo)


def _fake_run(rng, base, gain, drop, copy, n=300):
    b = rng.normal(base, 1.0, n)
    ra = b + rng.normal(gain, 0.5, n)
    sh = ra - rng.normal(drop, 0.5, n)
    systems = {name: {"mean": float(m), "f1": 0.5, "mean_length": 3.0} for name, m in
               (("baseline", b.mean()), ("ra_touch", ra.mean()), ("neighbours_shuffled", sh.mean()),
                ("integrator_zeroed", b.mean()), ("copy_captions", copy - 0.2),
                ("copy_perfect_retrieval", copy), ("material_oracle", base + 1))}
    return {"n": n, "systems": systems, "scores": {"baseline": b, "ra_touch": ra,
                                                   "shuffled_0": sh},
            "paired_vs_baseline": {"ra_touch": {"diff": float((ra - b).mean()), "ci_low": 0,
                                                "ci_high": 0}},
            "shuffle": {"changed_share": 0.3, "diff": float((ra - sh).mean()), "ci_low": 0,
                        "ci_high": 0},
            "reading": {}}


@pytest.mark.parametrize("scarce, verdict", [
    ((5.0, 0.4, 0.3, 6.0), "supported"),
    ((5.0, 0.0, 0.0, 6.0), "refuted"),
    ((5.0, 0.0, 0.0, 5.2), "inconclusive"),   # the corpus has nothing to give
    ((5.0, 0.4, 0.0, 6.0), "inconclusive"),   # a gain the shuffle does not explain
])
def test_verdict_follows_the_preregistered_criteria(scarce, verdict):
    rng = np.random.default_rng(1)
    groups = {"seen": _aggregate([_fake_run(rng, 7.0, 0.0, 0.0, 6.5) for _ in range(3)], 0),
              "scarce": _aggregate([_fake_run(rng, *scarce) for _ in range(3)], 0)}
    v, why = decide(groups)
    assert v == verdict, why
    r = {"config": {"runs": 3, "seeds": [0, 1, 2], "n": 300, "k": 5, "judge": "offline",
                    "regime": "scarce14x8-d0"}, "scarce_materials": ["felt"], "groups": groups,
         "verdict": v, "verdict_reason": why, "seconds": 1.0}
    assert f"verdict: {verdict}" in format_premise(r)
    json.dumps(r)  # the CLI's --json


@pytest.mark.slow
def test_premise_runs_end_to_end_on_the_shipped_weights(real_pipeline):
    lines = []
    r = run_premise(runs=1, n=12, pipeline=real_pipeline, progress=lines.append, arm=False)
    assert r["verdict"] in ("supported", "refuted", "inconclusive")
    for g in ("seen", "scarce"):
        s = r["groups"][g]
        assert s["n"] == 12 and len(s["runs"]) == 1
        for key in ("baseline", "ra_touch", "gain", "ci95", "shuffle_drop", "copy_ceiling"):
            assert key in s
        assert s["gain"] == pytest.approx(s["ra_touch"] - s["baseline"], abs=1e-3)
    assert len(lines) == 4 and "run 0 scarce" in lines[-2] and "touch withheld" in lines[-1]
    tw = r["touch_withheld"]
    assert tw["n"] == 12 and set(tw["score"]) == {"baseline", "paper", "copy_image_top1",
                                                    "gated", "gated_shuffled", "reader",
                                                    "reader_shuffled"}
    for key in ("paper_gain", "gated_gain", "gated_shuffle_drop"):
        assert tw[key]["diff"] == pytest.approx(
            tw["score"][key.split("_")[0]] - tw["score"][
                {"paper_gain": "baseline", "gated_gain": "baseline",
                 "gated_shuffle_drop": "gated_shuffled"}[key]], abs=2e-3)
    for g in ("seen", "scarce"):   # the routed system and the reader alone, each with a shuffle
        for arm in ("gated", "reader"):
            assert {"score", "gain", "shuffle_drop", "shuffle_p"} <= set(r["groups"][g][arm])
    assert "touch withheld" in format_premise(r)
    json.dumps(r)


@pytest.mark.slow
def test_why_ignored_reports_training_signal(real_pipeline):
    from ratouch.eval.premise import why_ignored

    # the first 1,000 of the 12,000 training pairs: a twelfth of the rendering, with scarce
    # pairs among them, and no more than the regime keeps
    w = why_ignored(n=40, pipeline=real_pipeline, n_pairs=1000)
    regime = ScarceRegime()
    assert w["n_pairs"] == 1000
    assert 0 < w["scarce_share"] <= regime.n_scarce * regime.tail_pairs / 1000
    for g in ("head", "scarce"):
        assert set(w["f1"][g]) == {"baseline", "ra_touch", "copy_captions"}
        assert set(w["training_loss"][g]) == {"own", "shuffled", "none"}
    for stage in ("start", "end"):
        assert -1 <= w["integrator_gradient"][stage]["cosine_own_vs_shuffled"] <= 1


@pytest.mark.slow
def test_premise_judges_the_text_arm_on_the_groups_and_the_test_split(real_pipeline,
                                                                      monkeypatch):
    """The arm path of `run_premise`, with an untrained text arm standing in for the trained
    one (training it takes minutes): per group its score, gain, difference to the paper's
    RA-Touch and shuffle drop; on the world test split every system's score and each arm's
    differences to the baseline and to `paper`."""
    from ratouch.eval import premise
    from ratouch.model.generator import load_generator
    from ratouch.model.neighbour_text import NeighbourText
    from ratouch.paths import generator_weights

    def untrained(encoder, run, progress=False, lm=None):
        gen = load_generator(generator_weights(encoder, "ra"), stage1=True)
        gen.integrator = NeighbourText.build(
            [e.caption for e in real_pipeline.corpus.entries],
            real_pipeline.corpus_embeddings("tactile_caption"), gen.decoder)
        return gen

    monkeypatch.setitem(premise.ARMS, "text", untrained)
    lines = []
    r = run_premise(runs=1, n=12, pipeline=real_pipeline, progress=lines.append,
                    gated=False, arms=("text",))
    assert r["config"]["arms"] == ["text"]
    for g in ("seen", "scarce"):
        t = r["groups"][g]["neighbour_text"]
        assert {"score", "gain", "ci95", "vs_paper", "vs_paper_ci95", "shuffle_drop",
                "shuffle_p"} <= set(t)
        assert t["vs_paper"] == pytest.approx(t["score"] - r["groups"][g]["ra_touch"],
                                              abs=2e-3)
    at = r["arms_test"]
    assert at["n"] == 12 and set(at["score"]) == {"baseline", "paper", "text"}
    assert at["text_vs_paper"]["diff"] == pytest.approx(
        at["score"]["text"] - at["score"]["paper"], abs=2e-3)
    assert any("world test split" in line for line in lines)
    out = format_premise(r)
    assert "text arm" in out and "text vs paper" in out
    json.dumps(r)
    with pytest.raises(ConfigError):
        run_premise(runs=1, n=12, pipeline=real_pipeline, arms=("nope",))

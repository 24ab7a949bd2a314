"""Controls for RA-Touch: neighbour shuffles, the zeroed integrator, copy and oracle answers."""

from __future__ import annotations

import numpy as np
import pytest

from ratouch.errors import ConfigError
from ratouch.eval.controls import derangement, format_controls, run_controls, vote
from ratouch.eval.tvl import oracle_answer
from ratouch.vocabulary import parse_adjectives
from ratouch.world.material import material
from ratouch.world.splits import encode_test_split


@pytest.mark.parametrize("n", [2, 3, 10, 401])
def test_derangement_gives_every_query_another_ones_neighbours(n):
    for seed in range(5):
        d = derangement(n, seed)
        assert sorted(d.tolist()) == list(range(n))
        assert not np.any(d == np.arange(n))
    assert not np.array_equal(derangement(50, 0), derangement(50, 1))
    with pytest.raises(ConfigError):
        derangement(1, 0)


def test_vote_and_oracle_answers():
    caps = ["soft, fuzzy, warm", "soft, plush", "fuzzy, soft, thick"]
    assert vote(caps, 2) == "soft, fuzzy"
    assert vote(caps, 0) == "soft"  # at least one adjective
    top = sorted(material("glass").profile, key=lambda wv: -wv[1])
    assert parse_adjectives(oracle_answer("glass", 3)) == [w for w, _ in top[:3]]


@pytest.mark.slow
def test_shipped_ra_touch_changes_its_answer_when_its_neighbours_change(real_pipeline):
    """A generator that ignored its neighbours would answer the same whatever it reads."""
    split = encode_test_split(real_pipeline.encoders, indices=range(0, 402, 6))
    r = run_controls(real_pipeline, k=5, shuffles=1, split=split)
    assert r["n"] == len(split.labels)
    assert r["shuffle"]["changed_share"] > 0.02
    assert set(r["systems"]) >= {"baseline", "ra_touch", "neighbours_shuffled",
                                 "integrator_zeroed", "copy_captions", "material_oracle"}
    # the oracle knows the material: it beats a vote over random-ish captions
    assert r["systems"]["material_oracle"]["f1"] > r["systems"]["copy_captions"]["f1"]
    d = r["reading"]
    assert 1 <= d["distinct_captions"] <= 5 and -1 <= d["key_cosine"] <= 1
    for a in d["attention"].values():  # head-averaged weights: at least uniform at the top
        assert a["max"] >= a["uniform"] - 1e-6 and 0 < a["entropy_over_log_k"] <= 1 + 1e-6
    text = format_controls(r)
    assert "neighbours shuffled" in text and "distinct captions" in text

"""Retriever losses (eqs. 6-9): term values on hand-made tensors, weights, strategies, gradients."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from ratouch.errors import ConfigError, DataError
from ratouch.model.loss import (
    STRATEGIES,
    RetrieverLossConfig,
    diversity_term,
    infonce_term,
    mse_term,
    retriever_loss,
)
from ratouch.model.retriever import RetrieverConfig, TactileGuidedRetriever


def _unit(*shape: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return F.normalize(torch.randn(*shape, generator=g), dim=-1)


def test_alignment_is_zero_when_query_equals_text_and_tactile():
    L = _unit(4, 8, seed=0)
    _, logs = retriever_loss(L, L, L, L, RetrieverLossConfig(strategy="align"))
    assert logs["align_text"] == pytest.approx(0.0, abs=1e-6)
    assert logs["align"] == pytest.approx(0.0, abs=1e-6)
    assert logs["mse"] == pytest.approx(0.0, abs=1e-12)


def test_alignment_values_on_orthogonal_and_opposite_vectors():
    e = torch.eye(4)
    Q, L, T = e[:2], e[2:], -e[:2]  # Q ⟂ L, Q = -T
    _, logs = retriever_loss(Q, L, T, Q, RetrieverLossConfig(lambda1=0.2))
    assert logs["align_text"] == pytest.approx(1.0)
    assert logs["align_tactile"] == pytest.approx(2.0)
    assert logs["align"] == pytest.approx(1.0 + 0.2 * 2.0)


def test_mse_is_the_elementwise_mean():
    Q, L = torch.eye(4)[:2], torch.eye(4)[2:]
    # each row differs in two of four entries by 1 -> mean over 8 elements = 4 / 8
    assert mse_term(Q, L).item() == pytest.approx(0.5)


def test_diversity_is_mean_off_diagonal_cosine():
    same = _unit(1, 8, seed=0).repeat(5, 1)
    assert diversity_term(same).item() == pytest.approx(1.0, abs=1e-6)
    assert diversity_term(torch.eye(5)).item() == pytest.approx(0.0)
    e = torch.eye(3)[:1]
    assert diversity_term(torch.cat([e, -e])).item() == pytest.approx(-1.0)
    assert diversity_term(e).item() == 0.0  # a batch of one has no pairs


def test_infonce_values():
    Q = torch.eye(3)
    # perfect match: logits 1/τ on the diagonal, 0 elsewhere
    tau = 0.5
    expected = -math.log(math.exp(2.0) / (math.exp(2.0) + 2.0))
    assert infonce_term(Q, Q, tau).item() == pytest.approx(expected, rel=1e-6)
    # T all identical: every candidate scores the same -> log B
    assert infonce_term(Q, torch.ones(3, 3), tau).item() == pytest.approx(math.log(3), rel=1e-6)


def test_total_follows_the_weights():
    Q, L, T, V = (_unit(6, 8, seed=s) for s in range(4))
    base = RetrieverLossConfig()
    total, logs = retriever_loss(Q, L, T, V, base)
    expected = (logs["align_text"] + 0.2 * logs["align_tactile"]
                + 10.0 * logs["mse"] + 0.1 * (logs["div"] + logs["nce"]))
    assert total.item() == pytest.approx(expected, rel=1e-5)
    assert logs["total"] == pytest.approx(expected, rel=1e-5)

    doubled, _ = retriever_loss(Q, L, T, V, RetrieverLossConfig(lambda2=20.0))
    assert doubled.item() - total.item() == pytest.approx(10.0 * logs["mse"], rel=1e-4)
    no_tac, _ = retriever_loss(Q, L, T, V, RetrieverLossConfig(lambda1=0.0))
    assert total.item() - no_tac.item() == pytest.approx(0.2 * logs["align_tactile"], rel=1e-4)


def test_strategies_pick_their_terms():
    Q, L, T, V = (_unit(6, 8, seed=s) for s in range(4))
    logs = {s: retriever_loss(Q, L, T, V, RetrieverLossConfig(strategy=s))[1]
            for s in STRATEGIES}
    raw = logs["full"]
    assert logs["align"]["total"] == pytest.approx(raw["align"])
    assert logs["align_mse"]["total"] == pytest.approx(raw["align"] + 10.0 * raw["mse"])
    assert logs["align_div_nce"]["total"] == pytest.approx(
        raw["align"] + 0.1 * (raw["div"] + raw["nce"]))
    assert raw["total"] == pytest.approx(raw["align"] + raw["stability"])


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_every_strategy_backpropagates_into_the_retriever(strategy):
    torch.manual_seed(0)
    m = TactileGuidedRetriever(RetrieverConfig(dim=16, heads=4, cross_residual=True))
    V, T, L = (_unit(5, 16, seed=s) for s in range(3))
    loss, logs = retriever_loss(m(V, T), L, T, V, RetrieverLossConfig(strategy=strategy))
    loss.backward()
    assert torch.isfinite(loss) and all(math.isfinite(v) for v in logs.values())
    grads = [p.grad for p in m.parameters() if p.grad is not None]
    assert grads and sum(g.abs().sum().item() for g in grads) > 0


@pytest.mark.parametrize("kwargs", [dict(lambda1=-0.1), dict(lambda2="10"), dict(lambda3=-1),
                                    dict(temperature=0.0), dict(strategy="stability")])
def test_config_validation(kwargs):
    with pytest.raises(ConfigError):
        RetrieverLossConfig(**kwargs)


def test_mismatched_shapes_raise():
    Q = _unit(4, 8, seed=0)
    with pytest.raises(DataError):
        retriever_loss(Q, _unit(3, 8, seed=1), Q, Q)

"""Tactile-Guided Retriever (eqs. 1-3): shapes, use of V and T, training, collapse stats."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from ratouch.errors import ConfigError, DataError
from ratouch.model.loss import RetrieverLossConfig, retriever_loss
from ratouch.model.retriever import (
    RetrieverConfig,
    RetrieverOutput,
    TactileGuidedRetriever,
    collapse_stats,
)

D = 32


def _unit(*shape: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return F.normalize(torch.randn(*shape, generator=g), dim=-1)


def _model(cross_residual: bool = False, seed: int = 0) -> TactileGuidedRetriever:
    torch.manual_seed(seed)
    return TactileGuidedRetriever(RetrieverConfig(dim=D, heads=8,
                                                  cross_residual=cross_residual)).eval()


def test_shapes_for_vectors_and_token_sequences():
    m = _model()
    out = m(_unit(5, D, seed=1), _unit(5, D, seed=2))
    assert isinstance(out, RetrieverOutput)
    assert out.query.shape == out.q.shape == out.v_prime.shape == out.t_prime.shape == (5, D)

    out = m(_unit(5, 7, D, seed=1), _unit(5, 3, D, seed=2))
    assert out.query.shape == out.q.shape == (5, D)
    assert out.v_prime.shape == (5, 7, D) and out.t_prime.shape == (5, 3, D)


def test_query_is_unit_norm():
    for m in (_model(False), _model(True)):
        q = m(_unit(6, D, seed=1), _unit(6, D, seed=2)).query
        torch.testing.assert_close(q.norm(dim=-1), torch.ones(6))


def test_changing_v_changes_the_query():
    for m in (_model(False), _model(True)):
        T = _unit(4, D, seed=2)
        q1 = m(_unit(4, D, seed=1), T).query
        q2 = m(_unit(4, D, seed=3), T).query
        assert (q1 - q2).abs().max() > 1e-3


def test_paper_exact_eq2_ignores_t_for_single_token_v():
    # Softmax over one key is 1 whatever the query: with eq. 2 as printed and one-token V,
    # the query is blind to T. This pins the documented degeneracy.
    m = _model(cross_residual=False)
    V = _unit(4, D, seed=1)
    q1, q2 = m(V, _unit(4, D, seed=2)).query, m(V, _unit(4, D, seed=3)).query
    torch.testing.assert_close(q1, q2)


def test_t_changes_the_query_with_residual_or_token_sequences():
    V, T1, T2 = _unit(4, D, seed=1), _unit(4, D, seed=2), _unit(4, D, seed=3)
    m = _model(cross_residual=True)
    assert (m(V, T1).query - m(V, T2).query).abs().max() > 1e-3
    # With several visual tokens T steers the attention weights even without the residual.
    m = _model(cross_residual=False)
    Vs = _unit(4, 6, D, seed=4)
    assert (m(Vs, T1).query - m(Vs, T2).query).abs().max() > 1e-3


def test_deterministic_in_eval_mode():
    torch.manual_seed(0)
    m = TactileGuidedRetriever(RetrieverConfig(dim=D, heads=8, dropout=0.5)).eval()
    V, T = _unit(4, 5, D, seed=1), _unit(4, D, seed=2)
    torch.testing.assert_close(m(V, T).query, m(V, T).query, rtol=0, atol=0)


@pytest.mark.parametrize("kwargs", [dict(dim=30, heads=8), dict(dim=0), dict(heads=0),
                                    dict(dropout=1.0), dict(dropout=-0.1),
                                    dict(cross_residual="yes")])
def test_config_validation(kwargs):
    with pytest.raises(ConfigError):
        RetrieverConfig(**kwargs)


def test_bad_input_shapes_raise():
    m = _model()
    with pytest.raises(DataError):
        m(_unit(4, D + 1, seed=1), _unit(4, D, seed=2))
    with pytest.raises(DataError):
        m(_unit(4, D, seed=1), _unit(3, D, seed=2))


def test_collapse_stats_identical_vs_random():
    same = collapse_stats(_unit(1, D, seed=1).repeat(50, 1) * 3.0)
    assert same["mean_cosine"] == pytest.approx(1.0, abs=1e-6)
    assert same["effective_rank"] == pytest.approx(1.0, abs=1e-3)
    assert same["mean_dim_std"] == pytest.approx(0.0, abs=1e-6)

    rand = collapse_stats(_unit(200, D, seed=2))
    assert abs(rand["mean_cosine"]) < 0.05
    assert rand["effective_rank"] > 0.8 * D
    assert rand["mean_dim_std"] == pytest.approx(D ** -0.5, rel=0.15)

    with pytest.raises(DataError):
        collapse_stats(_unit(1, D, seed=3))


def _joint_target_batches(seed: int):
    """Batches where L = normalize(V + T): V alone or T alone gives cos(., L) ~0.71."""
    g = torch.Generator().manual_seed(seed)

    def batch(n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        V = F.normalize(torch.randn(n, D, generator=g), dim=-1)
        T = F.normalize(torch.randn(n, D, generator=g), dim=-1)
        return V, T, F.normalize(V + T, dim=-1)

    return batch


def _train(m: TactileGuidedRetriever, batch, cfg: RetrieverLossConfig,
           steps: int = 60) -> None:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny matrices: extra threads only contend on a shared machine
    try:
        opt = torch.optim.Adam(m.parameters(), lr=1e-2)
        m.train()
        for _ in range(steps):
            V, T, L = batch(64)
            loss, _ = retriever_loss(m(V, T), L, T, V, cfg)
            opt.zero_grad()
            loss.backward()
            opt.step()
        m.eval()
    finally:
        torch.set_num_threads(threads)


def test_training_learns_a_joint_target_neither_modality_gives():
    batch = _joint_target_batches(0)
    m = _model(cross_residual=True)
    cfg = RetrieverLossConfig()
    Vt, Tt, Lt = batch(512)
    with torch.no_grad():
        before = retriever_loss(m(Vt, Tt), Lt, Tt, Vt, cfg)[1]
    _train(m, batch, cfg)
    with torch.no_grad():
        after = retriever_loss(m(Vt, Tt), Lt, Tt, Vt, cfg)[1]

    assert after["align"] < 0.5 * before["align"]
    v_alone = F.cosine_similarity(Vt, Lt).mean().item()
    t_alone = F.cosine_similarity(Tt, Lt).mean().item()
    assert after["cos_q_l"] > max(v_alone, t_alone) + 0.1


def test_paper_exact_retriever_cannot_beat_the_image_alone_on_single_vectors():
    # The T-blind query of eq. 2 as printed is a function of V only, so on a target that needs
    # T it cannot do better than V itself (the best V-only guess of normalize(V + T) is V).
    batch = _joint_target_batches(0)
    m = _model(cross_residual=False)
    Vt, Tt, Lt = batch(512)
    _train(m, batch, RetrieverLossConfig())
    with torch.no_grad():
        after = retriever_loss(m(Vt, Tt), Lt, Tt, Vt)[1]
    assert after["cos_q_l"] < F.cosine_similarity(Vt, Lt).mean().item() + 0.02

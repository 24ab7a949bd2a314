"""Texture-Aware Integrator (eqs. 4-5): shapes, zero init, ablation switches, masking."""

from __future__ import annotations

import pytest
import torch

from ratouch.errors import ConfigError, DataError
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator

B, K, D, DP = 3, 5, 16, 24


def _inputs(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(B, D, generator=g), torch.randn(B, K, D, generator=g),
            torch.randn(B, K, D, generator=g))


def _model(**kwargs) -> TextureAwareIntegrator:
    """A model perturbed away from its zero init, so every path shows in the output."""
    torch.manual_seed(0)
    m = TextureAwareIntegrator(IntegratorConfig(dim=D, out_dim=DP, heads=4, ffn_mult=2,
                                                **kwargs))
    with torch.no_grad():
        for p in m.parameters():
            p.add_(0.1 * torch.randn_like(p))
    return m.eval()


def test_output_shape():
    T, Rv, Rl = _inputs()
    assert _model()(T, Rv, Rl).shape == (B, DP)


def test_delta_is_zero_at_init_but_trainable():
    torch.manual_seed(0)
    m = TextureAwareIntegrator(IntegratorConfig(dim=D, out_dim=DP, heads=4))
    T, Rv, Rl = _inputs()
    delta = m(T, Rv, Rl)
    assert torch.equal(delta, torch.zeros(B, DP))
    (delta * torch.randn(B, DP)).sum().backward()
    assert m.fuse.weight.grad.abs().sum() > 0  # the FFN's identity path carries a gradient


@pytest.mark.parametrize("use_image,use_text", [(True, False), (False, True)])
def test_a_disabled_path_is_really_gone(use_image, use_text):
    m = _model(use_image=use_image, use_text=use_text)
    T, Rv, Rl = _inputs(0)
    _, Rv2, Rl2 = _inputs(1)
    base = m(T, Rv, Rl)
    if use_text:  # image path off: changing Rv changes nothing, Rl still matters
        torch.testing.assert_close(m(T, Rv2, Rl), base)
        torch.testing.assert_close(m(T, None, Rl), base)
        assert (m(T, Rv, Rl2) - base).abs().max() > 1e-4
    else:
        torch.testing.assert_close(m(T, Rv, Rl2), base)
        torch.testing.assert_close(m(T, Rv, None), base)
        assert (m(T, Rv2, Rl) - base).abs().max() > 1e-4
    names = {n.split(".")[0] for n, _ in m.named_parameters()}
    assert ("image_ca" in names) == use_image and ("text_ca" in names) == use_text


def test_both_paths_and_t_matter():
    m = _model()
    T, Rv, Rl = _inputs(0)
    T2, Rv2, Rl2 = _inputs(1)
    base = m(T, Rv, Rl)
    for changed in (m(T2, Rv, Rl), m(T, Rv2, Rl), m(T, Rv, Rl2)):
        assert (changed - base).abs().max() > 1e-4


def test_masked_neighbours_are_ignored():
    m = _model()
    T, Rv, Rl = _inputs(0)
    mask = torch.ones(B, K, dtype=torch.bool)
    mask[:, 3:] = False
    base = m(T, Rv, Rl, mask)
    Rv2, Rl2 = Rv.clone(), Rl.clone()
    Rv2[:, 3:] = 100.0
    Rl2[:, 3:] = -100.0
    torch.testing.assert_close(m(T, Rv2, Rl2, mask), base)
    # the same as giving only the real neighbours
    torch.testing.assert_close(m(T, Rv[:, :3], Rl[:, :3]), base)


def test_a_sample_without_neighbours_gets_zero_delta():
    m = _model()
    T, Rv, Rl = _inputs(0)
    mask = torch.ones(B, K, dtype=torch.bool)
    mask[1] = False
    out = m(T, Rv, Rl, mask)
    assert torch.isfinite(out).all()
    assert torch.equal(out[1], torch.zeros(DP))
    torch.testing.assert_close(out[[0, 2]], m(T, Rv, Rl)[[0, 2]])


@pytest.mark.parametrize("kwargs", [dict(use_image=False, use_text=False), dict(dim=18),
                                    dict(out_dim=0), dict(ffn_mult=0), dict(heads=-1),
                                    dict(dropout=1.5), dict(use_text=1)])
def test_config_validation(kwargs):
    base = dict(dim=D, out_dim=DP, heads=4)
    with pytest.raises(ConfigError):
        IntegratorConfig(**{**base, **kwargs})


def test_bad_inputs_raise():
    m = _model()
    T, Rv, Rl = _inputs()
    with pytest.raises(DataError):
        m(T, None, Rl)
    with pytest.raises(DataError):
        m(T, Rv[:, :, :-1], Rl)
    with pytest.raises(DataError):
        m(T, Rv, Rl, torch.ones(B, K))  # not bool

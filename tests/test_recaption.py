"""Tests for ratouch.corpus.recaption: caption validation, offline and LLM recaptioners."""

from __future__ import annotations

import pytest

from conftest import FakeLLM, serve_fake_llm
from ratouch.corpus.recaption import (
    PAPER_PROMPT,
    CaptionRejected,
    LLMRecaptioner,
    OfflineRecaptioner,
    RecaptionConfig,
    build_prompt,
    create_recaptioner,
    validate_caption,
)
from ratouch.errors import ConfigError, DataError
from ratouch.vocabulary import TACTILE_WORDS

KEY_ENV = "RATOUCH_TEST_LLM_KEY"
PLUSH = ["soft", "plush", "fibrous", "pliable", "cushioned"]


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "text, expected",
    [
        ("soft, plush, fibrous, pliable, cushioned", PLUSH),
        ("Soft, plush, fibrous, pliable, cushioned.", PLUSH),
        ("'soft,plush , fibrous,pliable,  CUSHIONED'", PLUSH),
        ('  "hard, smooth, rigid, metallic, solid"\n', ["hard", "smooth", "rigid", "metallic", "solid"]),
        ("cloth-like, fine-grained, woven, soft, sewn",
         ["cloth-like", "fine-grained", "woven", "soft", "sewn"]),
    ],
)
def test_validate_accepts_good_captions(text, expected):
    assert validate_caption(text) == expected


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("soft, plush, fibrous, pliable", "exactly 5"),
        ("soft, plush, fibrous, pliable, cushioned, woven", "exactly 5"),
        ("soft, plush, soft, pliable, cushioned", "'soft' appears twice"),
        ("soft, very plush, fibrous, pliable, cushioned", "not a single word"),
        ("soft, plush, fibr0us, pliable, cushioned", "not a single word"),
        ("soft, , fibrous, pliable, cushioned", "empty"),
        ("", "exactly 5"),
    ],
)
def test_validate_rejects_malformed(text, fragment):
    with pytest.raises(CaptionRejected) as info:
        validate_caption(text)
    assert fragment in info.value.reason
    assert isinstance(info.value, DataError)


@pytest.mark.parametrize(
    "word, category",
    [("red", "colour"), ("shiny", "visual"), ("round", "shape"), ("warm", "temperature"),
     ("heavy", "weight"), ("crunchy", "sound")],
)
def test_validate_rejects_banned_words_naming_category(word, category):
    with pytest.raises(CaptionRejected) as info:
        validate_caption(f"soft, {word}, fibrous, pliable, cushioned")
    assert info.value.reason == f"'{word}' is a {category} word"
    assert f"'{word}' is a {category} word" in str(info.value)


def test_build_prompt_fills_paper_prompt():
    prompt = build_prompt("teddy bear", "a brown fur toy")
    expected = PAPER_PROMPT.replace("{class_name}", "teddy bear").replace("{caption}", "a brown fur toy")
    assert prompt == expected
    assert "Class: teddy bear\nDescription: a brown fur toy\n" in prompt
    assert prompt.endswith("Your ENTIRE response must be ONLY 5 adjectives separated by commas.")


# --------------------------------------------------------------------------- offline


OFFLINE_CASES = [
    ("teddy bear", "a brown fur toy"),
    ("frying pan", "a black metal pan"),
    ("golden retriever", "a dog lying on the grass"),
    ("running shoe", "a pair of leather shoes on a wooden floor"),
    ("zzyzx", "qwerty"),
    ("", ""),
]


@pytest.mark.parametrize("class_name, description", OFFLINE_CASES)
def test_offline_returns_five_valid_deterministic_words(class_name, description):
    first = OfflineRecaptioner().recaption(class_name, description)
    assert len(first) == 5
    assert validate_caption(", ".join(first)) == first
    assert set(first) <= TACTILE_WORDS
    assert OfflineRecaptioner().recaption(class_name, description) == first


def test_offline_reflects_its_input():
    rec = OfflineRecaptioner()
    teddy = rec.recaption("teddy bear", "a brown fur toy")
    pan = rec.recaption("frying pan", "a black metal pan")
    assert {"soft", "furry", "plush"} <= set(teddy)
    assert {"hard", "metallic"} <= set(pan)
    assert not {"hard", "metallic"} & set(teddy)
    assert not {"soft", "furry"} & set(pan)


def test_offline_backoff_when_nothing_matches():
    out = OfflineRecaptioner().recaption("zzyzx", "qwerty")
    assert out == ["textured", "solid", "firm", "smooth", "uneven"]


def test_offline_user_lexicon_changes_output():
    base = OfflineRecaptioner().recaption("gizmo", "a faux leather gizmo")
    custom = OfflineRecaptioner({"faux leather": {"tacky": 5.0, "waxy": 4.0}, "Gizmo": {"springy": 3.0}})
    out = custom.recaption("gizmo", "a faux leather gizmo")
    assert out != base
    assert out[:3] == ["springy", "tacky", "waxy"]  # springy: 1.5 * 3 (class) + 3 (description)
    assert "leathery" not in out  # the phrase replaced its single words


def test_offline_recaption_many_keeps_order():
    rec = OfflineRecaptioner()
    items = [("frying pan", "metal"), ("teddy bear", "fur"), ("zzyzx", "")]
    assert rec.recaption_many(items) == [rec.recaption(c, d) for c, d in items]


@pytest.mark.parametrize(
    "lexicon, fragment",
    [
        ({"gizmo": {"red": 1.0}}, "colour"),
        ({"gizmo": {"wobbly": 1.0}}, "not a tactile word"),
        ({"gizmo": {"soft": -1.0}}, "must be > 0"),
        ({"gizmo": {}}, "must map"),
        ({"one two three": {"soft": 1.0}}, "two-word"),
    ],
)
def test_offline_rejects_bad_lexicon(lexicon, fragment):
    with pytest.raises(ConfigError, match=fragment):
        OfflineRecaptioner(lexicon)


# --------------------------------------------------------------------------- config


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        ({"backend": "gpt"}, "backend"),
        ({"backend": "llm"}, "endpoint"),
        ({"backend": "llm", "endpoint": "ftp://host/v1"}, "endpoint"),
        ({"endpoint": "not a url"}, "endpoint"),
        ({"timeout_s": 0}, "timeout_s"),
        ({"timeout_s": -1.0}, "timeout_s"),
        ({"max_attempts": 0}, "max_attempts"),
        ({"temperature": 2.5}, "temperature"),
        ({"temperature": -0.1}, "temperature"),
        ({"model": ""}, "model"),
    ],
)
def test_config_rejects_bad_values(kwargs, fragment):
    with pytest.raises(ConfigError, match=fragment):
        RecaptionConfig(**kwargs)


def test_create_recaptioner_picks_backend():
    lexicon = {"gizmo": {"springy": 3.0}}
    offline = create_recaptioner(RecaptionConfig(), lexicon)
    assert isinstance(offline, OfflineRecaptioner)
    assert offline.recaption("gizmo", "")[0] == "springy"
    llm = create_recaptioner(RecaptionConfig(backend="llm", endpoint="http://127.0.0.1:9/v1"), lexicon)
    assert isinstance(llm, LLMRecaptioner)
    assert llm.fallback.recaption("gizmo", "")[0] == "springy"


# --------------------------------------------------------------------------- LLM against a local server


@pytest.fixture
def fake_llm(monkeypatch):
    monkeypatch.delenv(KEY_ENV, raising=False)
    with serve_fake_llm(monkeypatch, "soft, plush, fibrous, pliable, cushioned") as state:
        yield state


def _llm(state: FakeLLM, **overrides) -> LLMRecaptioner:
    kwargs = {"backend": "llm", "endpoint": state.endpoint, "model": "test-model",
              "api_key_env": KEY_ENV, "timeout_s": 5.0, "max_attempts": 2}
    kwargs.update(overrides)
    return LLMRecaptioner(RecaptionConfig(**kwargs), OfflineRecaptioner())


def test_llm_valid_answer_with_key(fake_llm, monkeypatch):
    monkeypatch.setenv(KEY_ENV, "sk-test-123")
    fake_llm.reply = "Soft, plush, fibrous, pliable, cushioned."
    rec = _llm(fake_llm, temperature=0.3)
    assert rec.recaption("teddy bear", "a brown fur toy") == PLUSH
    assert rec.stats() == {"n_requests": 1, "n_rejected": 0, "n_errors": 0, "n_fallbacks": 0}
    (seen,) = fake_llm.requests
    assert seen["path"] == "/v1/chat/completions"
    assert seen["headers"]["Authorization"] == "Bearer sk-test-123"
    assert seen["headers"]["Content-Type"] == "application/json"
    assert seen["body"] == {
        "model": "test-model",
        "messages": [{"role": "user", "content": build_prompt("teddy bear", "a brown fur toy")}],
        "temperature": 0.3,
    }
    assert "Class: teddy bear\nDescription: a brown fur toy" in seen["body"]["messages"][0]["content"]


def test_llm_no_authorization_without_key(fake_llm):
    rec = _llm(fake_llm)
    assert rec.recaption("frying pan", "a black metal pan") == PLUSH
    assert "Authorization" not in fake_llm.requests[0]["headers"]


def test_llm_key_is_not_logged(fake_llm, monkeypatch, caplog):
    monkeypatch.setenv(KEY_ENV, "sk-secret-xyz")
    fake_llm.mode = "http500"
    with caplog.at_level("DEBUG"):
        _llm(fake_llm).recaption("frying pan", "metal")
    assert caplog.records and "sk-secret-xyz" not in caplog.text


@pytest.mark.parametrize("reply", ["red, shiny, soft, smooth, hard", "soft, smooth, hard"])
@pytest.mark.parametrize("attempts", [1, 3])
def test_llm_invalid_answer_falls_back(fake_llm, reply, attempts):
    fake_llm.reply = reply
    rec = _llm(fake_llm, max_attempts=attempts)
    out = rec.recaption("frying pan", "a black metal pan")
    assert out == OfflineRecaptioner().recaption("frying pan", "a black metal pan")
    assert len(fake_llm.requests) == attempts
    expected = {"n_requests": attempts, "n_rejected": attempts, "n_errors": 0, "n_fallbacks": 1}
    assert rec.stats() == expected


@pytest.mark.parametrize("mode", ["http500", "badjson"])
def test_llm_transport_errors_fall_back(fake_llm, mode):
    fake_llm.mode = mode
    rec = _llm(fake_llm)
    assert rec.recaption("teddy bear", "fur") == OfflineRecaptioner().recaption("teddy bear", "fur")
    assert rec.stats() == {"n_requests": 2, "n_rejected": 0, "n_errors": 2, "n_fallbacks": 1}


def test_llm_missing_choices_is_an_error(fake_llm):
    fake_llm.mode = "ok"
    fake_llm.reply = None  # content null -> malformed reply
    rec = _llm(fake_llm, max_attempts=1)
    rec.recaption("teddy bear", "fur")
    assert rec.n_errors == 1 and rec.n_fallbacks == 1


def test_llm_timeout_falls_back_without_hanging(fake_llm):
    fake_llm.mode = "sleep"
    fake_llm.sleep_s = 1.5
    rec = _llm(fake_llm, timeout_s=0.2, max_attempts=2)
    out = rec.recaption("frying pan", "metal")
    # both attempts timed out (a client that waited would have got the server's late answer)
    assert out == OfflineRecaptioner().recaption("frying pan", "metal")
    assert rec.n_errors == 2 and rec.n_fallbacks == 1


def test_llm_connection_refused_falls_back():
    rec = LLMRecaptioner(
        RecaptionConfig(backend="llm", endpoint="http://127.0.0.1:9/v1", timeout_s=1.0, max_attempts=1),
        OfflineRecaptioner(),
    )
    assert rec.recaption("frying pan", "metal") == OfflineRecaptioner().recaption("frying pan", "metal")
    assert rec.n_errors == 1 and rec.n_fallbacks == 1


def test_llm_recaption_many_keeps_order(fake_llm):
    fake_llm.mode = "echo"
    rec = _llm(fake_llm)
    items = [("pan", "x"), ("bear", "y"), ("rock", "z")] * 4
    out = rec.recaption_many(items, max_workers=4)
    expected = {"pan": ["hard", "metallic", "smooth", "rigid", "solid"],
                "bear": ["soft", "furry", "plush", "fluffy", "cushioned"],
                "rock": ["rough", "hard", "craggy", "uneven", "gritty"]}
    assert out == [expected[c] for c, _ in items]
    assert rec.stats()["n_requests"] == len(items)
    assert rec.recaption_many([]) == []
    with pytest.raises(ConfigError, match="max_workers"):
        rec.recaption_many(items, max_workers=0)

"""The LLM judge: the TVL-style prompt to any OpenAI-compatible chat-completions endpoint.

Bounded retries per answer; the offline judge answers when every attempt fails or the reply
has no 1-10 score first.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from ratouch.errors import ConfigError
from ratouch.eval.judge.features import is_failed
from ratouch.eval.judge.offline import OfflineJudge
from ratouch.eval.judge.records import MIN_SCORE, parse_gpt_score
from ratouch.llm_http import (
    REQUEST_ERRORS,
    chat_completion,
    chat_url,
    check_client_settings,
    is_http_url,
)
from ratouch.vocabulary import TVL_QUESTION

logger = logging.getLogger(__name__)

JUDGE_SYSTEM = "You are a careful and impartial assistant who grades answers against a reference."
JUDGE_PROMPT = """[Question]: {question}

[Assistant's answer]: {response}

[Correct answer]: {label}

Please rate how well the AI assistant's answer to the question above matches the correct answer.
The user asked the question while looking at an image; the correct answer lists the tactile
properties of the surface (how it feels to the touch). Compare only the meaning of the two
answers and ignore grammar and formatting. Give the assistant one overall score from 1 to 10,
where a higher score means the answer is closer to the correct answer.
Write the score alone on the first line. From the next line on, explain your rating briefly and
without bias."""


def build_judge_prompt(label: str, response: str, question: str = TVL_QUESTION) -> str:
    """Fill `JUDGE_PROMPT` with the question, the generated response and the correct label."""
    return JUDGE_PROMPT.format(question=question.strip(), response=response.strip(),
                               label=label.strip())


@dataclass(frozen=True)
class LLMJudgeConfig:
    """Where and how the LLM judge asks.

    Attributes:
        endpoint: Base URL such as ``http://127.0.0.1:8000/v1`` (requests go to
            ``{endpoint}/chat/completions``); default ``$RATOUCH_JUDGE_ENDPOINT``.
        model: Model name; default ``$RATOUCH_JUDGE_MODEL`` or ``gpt-4``.
        api_key_env: Environment variable holding the API key (never passed or logged).
        timeout_s: Per-request timeout in seconds.
        max_attempts: Requests per answer before falling back to the offline judge.
        temperature: Sampling temperature in [0, 2].
    """

    endpoint: str
    model: str = "gpt-4"
    api_key_env: str = "RATOUCH_JUDGE_API_KEY"
    timeout_s: float = 30.0
    max_attempts: int = 3
    temperature: float = 0.0

    def __post_init__(self) -> None:
        if not is_http_url(self.endpoint):
            raise ConfigError(f"LLM judge endpoint must be an http(s) URL, got {self.endpoint!r} "
                              "(set --endpoint or $RATOUCH_JUDGE_ENDPOINT)")
        check_client_settings("LLMJudgeConfig", self)

    @classmethod
    def from_env(cls, endpoint: str | None = None, model: str | None = None,
                 api_key_env: str | None = None, **kwargs) -> "LLMJudgeConfig":
        """Arguments first, then ``$RATOUCH_JUDGE_ENDPOINT`` / ``$RATOUCH_JUDGE_MODEL``."""
        return cls(endpoint=endpoint or os.environ.get("RATOUCH_JUDGE_ENDPOINT", ""),
                   model=model or os.environ.get("RATOUCH_JUDGE_MODEL", "") or "gpt-4",
                   api_key_env=api_key_env or "RATOUCH_JUDGE_API_KEY", **kwargs)


class LLMJudge:
    """Judge that asks an OpenAI-compatible chat-completions endpoint the TVL-style prompt.

    Each answer gets up to ``config.max_attempts`` requests; transport errors, malformed replies
    and replies without a 1-10 score first are retried, then the offline judge answers.
    Thread-safe; counters: ``n_requests``, ``n_errors``, ``n_unparseable``, ``n_fallbacks``.

    Args:
        config: Endpoint, model, key variable, timeout, attempts and temperature.
        fallback: Judge used when every attempt fails (default: `OfflineJudge()`).
    """

    name = "llm"
    key = "llm_score"

    def __init__(self, config: LLMJudgeConfig, fallback: OfflineJudge | None = None) -> None:
        self.config = config
        self.fallback = fallback if fallback is not None else OfflineJudge()
        self.url = chat_url(config.endpoint)
        self.n_requests = self.n_errors = self.n_unparseable = self.n_fallbacks = 0
        self._lock = threading.Lock()

    def _count(self, name: str) -> None:
        with self._lock:
            setattr(self, name, getattr(self, name) + 1)

    def score(self, label: str, response: str | None, question: str = TVL_QUESTION) -> float:
        """Score in [1, 10] from the LLM, or the offline judge's after failed attempts; a
        missing or empty response scores 1 without a request."""
        if response is None or is_failed(response):
            return MIN_SCORE
        prompt = build_judge_prompt(label, response, question)
        for attempt in range(1, self.config.max_attempts + 1):
            self._count("n_requests")
            try:
                reply = chat_completion(self.url, self.config.model, prompt,
                                        api_key_env=self.config.api_key_env,
                                        timeout_s=self.config.timeout_s,
                                        temperature=self.config.temperature, system=JUDGE_SYSTEM)
            except REQUEST_ERRORS as exc:
                self._count("n_errors")
                logger.warning("judge attempt %d failed: %s: %s", attempt, type(exc).__name__, exc)
                continue
            value = parse_gpt_score(reply)
            if value is not None:
                return value
            self._count("n_unparseable")
            logger.warning("judge attempt %d: no 1-10 score first in %r", attempt, reply[:80])
        self._count("n_fallbacks")
        return self.fallback.score(label, response)

    def score_many(self, pairs: Iterable[tuple[str, str | None]], max_workers: int = 4) -> list[float]:
        """Scores of (label, response) pairs with a small thread pool, in input order."""
        pairs = list(pairs)
        if not pairs:
            return []
        with ThreadPoolExecutor(max_workers=max(1, min(max_workers, len(pairs)))) as pool:
            return list(pool.map(lambda p: self.score(p[0], p[1]), pairs))

    def stats(self) -> dict:
        with self._lock:
            return {"n_requests": self.n_requests, "n_errors": self.n_errors,
                    "n_unparseable": self.n_unparseable, "n_fallbacks": self.n_fallbacks}

"""One chat-completions request to an OpenAI-compatible endpoint, standard library only.

Shared by the LLM recaptioner (`ratouch.corpus.recaption`) and the LLM judge (`ratouch.eval.judge`).
The API key is read from an environment variable at request time; it is never passed as an
argument, stored or logged.
"""

from __future__ import annotations

import http.client
import json
import math
import os
import urllib.error
import urllib.parse
import urllib.request

from ratouch.errors import ConfigError

# Failures of one request: OSError covers URLError/HTTPError, timeouts and refused connections;
# ValueError covers malformed JSON; Key/Index/TypeError a reply without choices[0].message.content.
REQUEST_ERRORS = (OSError, http.client.HTTPException, ValueError, KeyError, IndexError, TypeError)


def is_http_url(text: object) -> bool:
    """True for an http(s) URL with a host."""
    if not isinstance(text, str):
        return False
    parsed = urllib.parse.urlparse(text)
    return parsed.scheme in ("http", "https") and bool(parsed.netloc)


def check_client_settings(owner: str, settings) -> None:
    """Raise ConfigError unless the request settings of an LLM client config are usable:
    non-empty `model` and `api_key_env`, `timeout_s` > 0, integer `max_attempts` >= 1 and
    `temperature` in [0, 2]. Messages name the field as ``{owner}.{field}``."""
    for name in ("model", "api_key_env"):
        value = getattr(settings, name)
        if not isinstance(value, str) or not value.strip():
            raise ConfigError(f"{owner}.{name} must be a non-empty string, got {value!r}")
    timeout, attempts, temp = settings.timeout_s, settings.max_attempts, settings.temperature
    if not _is_number(timeout) or not timeout > 0:
        raise ConfigError(f"{owner}.timeout_s must be > 0, got {timeout!r}")
    if not isinstance(attempts, int) or isinstance(attempts, bool) or attempts < 1:
        raise ConfigError(f"{owner}.max_attempts must be an integer >= 1, got {attempts!r}")
    if not _is_number(temp) or not 0.0 <= temp <= 2.0:
        raise ConfigError(f"{owner}.temperature must be in [0, 2], got {temp!r}")


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def chat_url(endpoint: str) -> str:
    """``{endpoint}/chat/completions`` for a base URL such as ``http://127.0.0.1:8000/v1``."""
    return endpoint.rstrip("/") + "/chat/completions"


def chat_completion(
    url: str,
    model: str,
    prompt: str,
    *,
    api_key_env: str,
    timeout_s: float,
    temperature: float,
    system: str | None = None,
) -> str:
    """POST one chat-completions request and return the reply text.

    Args:
        url: Full chat-completions URL (see `chat_url`).
        model: Model name sent with the request.
        prompt: The user message.
        api_key_env: Environment variable holding the API key; sent as ``Bearer`` if set.
        timeout_s: Socket timeout in seconds.
        temperature: Sampling temperature.
        system: Optional system message placed before the user message.

    Raises:
        One of `REQUEST_ERRORS` on transport errors, HTTP errors or malformed replies.
    """
    messages = [{"role": "system", "content": system}] if system else []
    messages.append({"role": "user", "content": prompt})
    body = {"model": model, "messages": messages, "temperature": temperature}
    headers = {"Content-Type": "application/json"}
    key = os.environ.get(api_key_env, "")
    if key:
        headers["Authorization"] = f"Bearer {key}"
    request = urllib.request.Request(
        url, data=json.dumps(body).encode("utf-8"), headers=headers, method="POST"
    )
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as response:
            payload = json.loads(response.read().decode("utf-8"))
    except urllib.error.HTTPError as exc:
        exc.close()  # release the socket before the caller retries
        raise
    content = payload["choices"][0]["message"]["content"]
    if not isinstance(content, str):
        raise TypeError(f"message content is {type(content).__name__}, not a string")
    return content

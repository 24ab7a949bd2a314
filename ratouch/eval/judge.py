"""The evaluation judges of the TVL benchmark protocol: an offline judge and an LLM judge.

TVL scores a generated tactile description by asking GPT-4 to rate it against the ground-truth
adjectives on a 1-10 scale (`JUDGE_PROMPT` is written in the spirit of TVL's prompt).

`OfflineJudge` needs no network. It splits label and answer into adjectives, compares them with
hand-made synonym groups and antonym pairs (soft ~ plush ~ cushioned; soft vs hard; ...) and
weighs every answer word by its informativeness: words that fit nearly every label (label base
rates from the fit data) or that the judged system says for nearly every sample (its own word
rates, measured at judge time on the answers being judged) earn little; antonym clashes cost.
Five weighted features map to 1-10 with ``1 + 9 * sigmoid(b + w . z)``, fitted by least squares
on the FIT half of the published TVL judge data (`fit_offline_judge`, stored in
``ratouch/configs/judge/offline.json``). `validate_judge` measures it on held-out samples, on a
held-out system (leave one out) and under style shifts; docs/judge.md has the figures.
`mean_ci` / `score_stats` give the 95 % bootstrap CI, adjective F1 and mean length that every
system comparison prints.

`LLMJudge` asks any OpenAI-compatible chat-completions endpoint, retries a bounded number of
times, and falls back to the offline judge when the endpoint fails or answers without a score.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import threading
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import write_json_atomic
from ratouch.llm_http import (
    REQUEST_ERRORS,
    chat_completion,
    chat_url,
    check_client_settings,
    is_http_url,
)
from ratouch.paths import CONFIGS, TVL_JUDGE_ENV, tvl_judge_dir
from ratouch.vocabulary import (
    EXTRA_TACTILE,
    TVL_ADJECTIVES,
    TVL_QUESTION,
    adjective_f1,
    parse_adjectives,
)

logger = logging.getLogger(__name__)

MIN_SCORE, MAX_SCORE = 1.0, 10.0
LABEL_KEY, RESPONSE_KEY, EVAL_KEY = "label", "generated response", "evaluation"
MODELS = ("tvl_llama_vits", "tvl_llama_vits_bgs", "tvl_llama_vittiny")
SUBSETS = ("SSVTP", "HCT")
GPT4_INTERRUN_SPEARMAN = 0.89  # reference agreement of two GPT-4 judging runs (quoted, not measured)
# Issue 12's targets on systems the judge was not fitted on.
TARGETS = {"max_abs_mean_error": 0.15, "pooled_spearman": 0.85, "ranking": "preserved",
           "length_effect_difference": 0.1}  # |judge - GPT-4| per extra adjective (this project's bound)
DATA_DIR_ENV = TVL_JUDGE_ENV
CONFIG_PATH = CONFIGS / "judge" / "offline.json"

# --------------------------------------------------------------------------- parsing

_SCORE_RE = re.compile(r"^\s*(?:\*\*)?\s*(?:score\s*[:=]?\s*)?(\d{1,2}(?:\.\d+)?)(?!\d)", re.I)


def parse_gpt_score(evaluation: str | None) -> float | None:
    """The judge's score: the number (1-10) that starts its answer, else None.

    TVL's GPT-4 evaluations put the score first ("7.5\\nThe assistant's response ..."); scores
    may be fractional (7.5, 7.785), so the value is a float, as in TVL's own analysis script.
    A leading "Score:" or markdown bold and a trailing "/10" are tolerated.
    """
    if not isinstance(evaluation, str):
        return None
    m = _SCORE_RE.match(evaluation)
    if m is None:
        return None
    value = float(m.group(1))
    return value if MIN_SCORE <= value <= MAX_SCORE else None


# --------------------------------------------------------------------------- lexicon

# Synonym groups, "word" or "word:weight" (weight of a looser member, default 1). Two different
# words are similar when they share a group: similarity SYNONYM * w_a * w_b (exact match: 1).
_GROUPS_SPEC = {
    "soft": "soft plush cushioned cushiony squishy spongy fluffy padded yielding compressible "
            "velvety fuzzy:0.7 pliable:0.6 deformable:0.6",
    "hard": "hard rigid firm stiff solid sturdy dense durable:0.6 metallic:0.5 wooden:0.5",
    "flexible": "flexible pliable deformable elastic rubbery rubber stretchy supple flimsy:0.7 "
                "resilient:0.7 springy yielding:0.7",
    "smooth": "smooth sleek slick polished glossy:0.8 slippery:0.8 even:0.8 level:0.7 uniform:0.6 "
              "varnished:0.8 silky glassy flat:0.5",
    "glossy": "glossy polished sleek:0.8 shiny reflective:0.7 varnished slick:0.7",
    "rough": "rough coarse abrasive gritty grainy:0.8 granular:0.8 scratchy rugged textured:0.6 "
             "uneven:0.5",
    "uneven": "uneven bumpy lumpy irregular knobby dented indented dimpled raised:0.8 extruded:0.7 "
              "textured:0.6 rugged:0.7 wrinkly:0.6 wrinkled:0.6 creased:0.6 contoured:0.5 "
              "rough:0.5",
    "ridged": "lined ridged grooved ribbed corrugated striped:0.7 grid-like:0.8 patterned:0.5 "
              "textured:0.5",
    "patterned": "patterned dotted splotchy speckled printed text striped embroidered:0.6 "
                 "grid-like:0.6",
    "fabric": "woven fabric cloth-like fabric-like fibrous mesh:0.8 knitted sewn embroidered:0.8 "
              "fuzzy:0.6 plush:0.5",
    "metal": "metallic wired wire",
    "plastic": "plastic plastic-like synthetic artificial rubbery:0.6 rubber:0.6",
    "matte": "matte dry:0.7",
    "flat": "flat level even:0.8 smooth:0.4",
    "curved": "curved round circular contoured",
    "sharp": "pointed sharp",
    "perforated": "perforated mesh grid-like:0.6",
    "thick": "thick",
    "thin": "thin flimsy:0.8 paper-like:0.6",
    "wrinkled": "wrinkly wrinkled creased folded",
    "grippy": "grippy rubbery:0.6 tacky",
    "slippery": "slippery slick sleek:0.6",
}
# Opposite groups: a predicted word that matches nothing in the label but belongs to the
# opposite of a label word's group is an antonym clash (strength w_a * w_b).
ANTONYM_GROUPS = (
    ("soft", "hard"), ("smooth", "rough"), ("smooth", "uneven"), ("flexible", "hard"),
    ("glossy", "matte"), ("flat", "uneven"), ("flat", "curved"), ("thick", "thin"),
    ("slippery", "grippy"), ("smooth", "ridged"),
)
# Words TVL-LLaMA answers use that are not touch properties (temperature, looks, durability).
NON_TACTILE = frozenset({
    "cool", "warm", "cold", "hot", "reflective", "shiny", "blurred", "blurry", "indistinct",
    "printed", "speckled", "durable", "text", "colorful", "bright", "dark",
})
SYNONYM = 0.7
_MATCHED = 0.5  # a predicted word with similarity >= this to a label word is not a clash


def _parse_groups(spec: Mapping[str, str]) -> dict[str, dict[str, float]]:
    members: dict[str, dict[str, float]] = {}
    for group, words in spec.items():
        for item in words.split():
            word, _, weight = item.partition(":")
            members.setdefault(word, {})[group] = float(weight) if weight else 1.0
    return members


_MEMBERS = _parse_groups(_GROUPS_SPEC)
_OPPOSITE = frozenset(ANTONYM_GROUPS) | frozenset((b, a) for a, b in ANTONYM_GROUPS)
assert {g for pair in ANTONYM_GROUPS for g in pair} <= set(_GROUPS_SPEC)


def similarity(a: str, b: str) -> float:
    """1 for the same word, SYNONYM * w_a * w_b for words sharing a synonym group, else 0."""
    if a == b:
        return 1.0
    ga, gb = _MEMBERS.get(a, {}), _MEMBERS.get(b, {})
    return max((SYNONYM * ga[g] * gb[g] for g in ga.keys() & gb.keys()), default=0.0)


def antonymy(a: str, b: str) -> float:
    """w_a * w_b when a and b belong to opposite groups (soft / hard, ...), else 0."""
    ga, gb = _MEMBERS.get(a, {}), _MEMBERS.get(b, {})
    return max((wa * wb for x, wa in ga.items() for y, wb in gb.items() if (x, y) in _OPPOSITE),
               default=0.0)


FEATURES = ("precision", "exact_precision", "recall", "antonym_clash", "non_tactile_share")
PSEUDO_ANSWERS = 10.0  # a system's word rates are count / (n + 10): one answer ignores nothing
IGNORE_BELOW = 0.1     # informativeness under this counts as 0 (the word is ignored)


@dataclass(frozen=True)
class WordRates:
    """How often one system says each word: the share of its answers that contain it.

    Computed at judge time from the answers being judged (`answer_rates`); shrunk towards 0 by
    `PSEUDO_ANSWERS`, so a file of a few answers ignores little and a word said in every one of
    400 answers is worth almost nothing.
    """

    counts: Mapping[str, int]
    n: int

    def rate(self, word: str) -> float:
        return self.counts.get(word, 0) / (self.n + PSEUDO_ANSWERS)


NO_RATES = WordRates({}, 0)


def answer_rates(responses: Iterable[str | None]) -> WordRates:
    """The word rates of one system's answers (failed answers count as answers saying nothing)."""
    counts: dict[str, int] = {}
    n = 0
    for r in responses:
        n += 1
        for w in parse_adjectives(r):
            counts[w] = counts.get(w, 0) + 1
    return WordRates(counts, n)


def label_fit_rates(labels: Iterable[str], extra_words: Iterable[str] = ()) -> dict[str, float]:
    """Label-side base rate of every word: its mean best similarity to a label, over labels.

    A word that fits nearly every label ("textured", "uneven") has a rate near 1 and earns little
    when it matches. Computed for the words of the labels, of `extra_words` and of the lexicon.
    """
    labs = [parse_adjectives(x) for x in labels]
    labs = [x for x in labs if x]
    if not labs:
        raise DataError("label base rates need at least one non-empty label")
    vocab = ({w for x in labs for w in x} | set(extra_words) | set(_MEMBERS)
             | set(TVL_ADJECTIVES) | set(EXTRA_TACTILE))
    return {w: round(sum(max(similarity(w, lw) for lw in x) for x in labs) / len(labs), 4)
            for w in sorted(vocab)}


def informativeness(word: str, label_rates: Mapping[str, float], rates: WordRates) -> float:
    """(1 - b^2) * (1 - f^2), b the word's label base rate and f the system's rate of it; 0
    below `IGNORE_BELOW`. (Squares: chosen over the linear and square-root forms by
    leave-one-system-out agreement, see docs/judge.md.)"""
    u = (1.0 - label_rates.get(word, 0.0) ** 2) * (1.0 - rates.rate(word) ** 2)
    return u if u >= IGNORE_BELOW else 0.0


def word_table(label: Sequence[str], predicted: Sequence[str], label_rates: Mapping[str, float],
               rates: WordRates = NO_RATES) -> list[dict]:
    """Per predicted word: best label match, similarity, clash strength, rates and weight."""
    rows = []
    for p in predicted:
        sims = [similarity(p, lw) for lw in label]
        best = max(sims)
        clash = max(antonymy(p, lw) for lw in label) if best < _MATCHED else 0.0
        u = informativeness(p, label_rates, rates)
        if p in NON_TACTILE:
            status = "non-tactile"
        elif best >= _MATCHED:
            status = "matched" if u > 0 else "ignored"
        elif clash > 0:
            status = "clash"
        else:
            status = "unmatched" if u > 0 else "ignored"
        rows.append({"word": p, "status": status, "label_word": label[sims.index(best)] if best
                     else None, "similarity": round(best, 3), "clash": round(clash, 3),
                     "label_rate": label_rates.get(p, 0.0), "system_rate": round(rates.rate(p), 3),
                     "weight": round(u, 3)})
    return rows


def judge_features(label: Sequence[str], predicted: Sequence[str],
                   label_rates: Mapping[str, float], rates: WordRates = NO_RATES) -> list[float]:
    """The `FEATURES` of a predicted adjective list against the label's (both non-empty).

    Credit is weighted by informativeness: precision and recall count a predicted word by its
    weight, so an ignored word (weight 0) neither helps nor hurts; antonym clashes always cost.
    """
    table = word_table(label, predicted, label_rates, rates)
    u = np.array([t["weight"] for t in table])
    best = np.array([t["similarity"] for t in table])
    exact = np.array([float(p in set(label)) for p in predicted])
    mass = float(u.sum())
    precision = float(u @ best) / mass if mass > 0 else 0.0
    exact_precision = float(u @ exact) / mass if mass > 0 else 0.0
    recall = sum(max(similarity(lw, p) * w for p, w in zip(predicted, u)) for lw in label) / len(label)
    clash = float(sum(t["clash"] for t in table))
    non_tactile = sum(p in NON_TACTILE for p in predicted) / len(predicted)
    return [precision, exact_precision, float(recall), clash, non_tactile]


def _is_failed(response: object) -> bool:
    return not parse_adjectives(response if isinstance(response, str) else None)


# --------------------------------------------------------------------------- offline judge


class OfflineJudge:
    """Informativeness-weighted synonym/antonym matching plus a fitted 1-10 calibration.

    A matched adjective earns credit in proportion to how informative it is: words that fit
    nearly every label (label base rates from the fit data) and words the judged system says in
    nearly every answer (its own rates, `answer_rates`, measured by `score_many` on the answers
    being judged) earn little; contradicted words (antonyms of a label word) cost.

    Args:
        params: Calibration (keys ``features``, ``mean``, ``scale``, ``intercept``, ``weights``,
            ``label_rates``), e.g. from `fit_offline_judge`; default: the shipped
            ``configs/judge/offline.json``.

    Raises:
        ConfigError: If the calibration is missing or malformed.
    """

    name = "offline"
    key = "offline_score"

    def __init__(self, params: Mapping | None = None) -> None:
        if params is None:
            params = load_offline_config()
        self.params = _check_params(params)
        self._mean = np.asarray(self.params["mean"], dtype=np.float64)
        self._scale = np.asarray(self.params["scale"], dtype=np.float64)
        self._w = np.asarray(self.params["weights"], dtype=np.float64)
        self._b = float(self.params["intercept"])
        self.label_rates: dict[str, float] = dict(self.params["label_rates"])

    def _calibrate(self, feats: Sequence[float]) -> float:
        z = (np.asarray(feats) - self._mean) / self._scale
        return MIN_SCORE + (MAX_SCORE - MIN_SCORE) / (1.0 + math.exp(-(self._b + float(z @ self._w))))

    def explain(self, label: str, response: str | None, rates: WordRates = NO_RATES) -> dict:
        """Parsed adjectives, per-word table (matched / clash / ignored ..., weights), features
        and score of one answer, `rates` being the judged system's word rates."""
        lab, pred = parse_adjectives(label), parse_adjectives(response)
        if not lab:
            raise DataError(f"label {label!r} has no adjectives")
        if not pred:
            return {"label": lab, "predicted": [], "words": [], "features": None,
                    "score": MIN_SCORE}
        feats = judge_features(lab, pred, self.label_rates, rates)
        return {"label": lab, "predicted": pred,
                "words": word_table(lab, pred, self.label_rates, rates),
                "features": dict(zip(FEATURES, feats)), "score": self._calibrate(feats)}

    def score(self, label: str, response: str | None, rates: WordRates = NO_RATES) -> float:
        """Score in [1, 10] of a generated response against the ground-truth label; a missing
        or empty response scores 1. Without `rates` only the label base rates weigh words."""
        lab, pred = parse_adjectives(label), parse_adjectives(response)
        if not lab:
            raise DataError(f"label {label!r} has no adjectives")
        if not pred:
            return MIN_SCORE
        return self._calibrate(judge_features(lab, pred, self.label_rates, rates))

    def score_many(self, pairs: Iterable[tuple[str, str | None]]) -> list[float]:
        """Scores of (label, response) pairs of ONE system, in order; the system's word rates
        are measured on these responses."""
        pairs = list(pairs)
        rates = answer_rates(r for _, r in pairs)
        return [self.score(label, response, rates) for label, response in pairs]

    def stats(self) -> dict:
        return {}


def _check_params(params: Mapping) -> dict:
    if not isinstance(params, Mapping):
        raise ConfigError(f"offline judge calibration must be a mapping, got {type(params).__name__}")
    missing = [k for k in ("features", "mean", "scale", "intercept", "weights", "label_rates")
               if k not in params]
    if missing:
        raise ConfigError(f"offline judge calibration lacks {missing}; "
                          "refit with `ratouch judge --fit`")
    if list(params["features"]) != list(FEATURES):
        raise ConfigError(f"offline judge calibration is for features {params['features']}, "
                          f"this code computes {list(FEATURES)}; refit with `ratouch judge --fit`")
    for k in ("mean", "scale", "weights"):
        v = params[k]
        if (not isinstance(v, Sequence) or len(v) != len(FEATURES)
                or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in v)):
            raise ConfigError(f"offline judge calibration {k!r} must be {len(FEATURES)} finite numbers")
    if not all(s > 0 for s in params["scale"]):
        raise ConfigError("offline judge calibration 'scale' must be > 0")
    if not isinstance(params["intercept"], (int, float)) or not math.isfinite(params["intercept"]):
        raise ConfigError("offline judge calibration 'intercept' must be a finite number")
    rates = params["label_rates"]
    if not isinstance(rates, Mapping) or not all(
            isinstance(v, (int, float)) and 0 <= v <= 1 for v in rates.values()):
        raise ConfigError("offline judge calibration 'label_rates' must map words to [0, 1]")
    return dict(params)


def load_offline_config(path: str | os.PathLike | None = None) -> dict:
    """Read the offline judge's calibration (default: the shipped one)."""
    path = Path(path) if path is not None else CONFIG_PATH
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as e:
        raise ConfigError(f"offline judge calibration {path} is missing; "
                          "write it with `ratouch judge --fit`") from e
    except ValueError as e:
        raise ConfigError(f"offline judge calibration {path} is not valid JSON: {e}") from e


# --------------------------------------------------------------------------- LLM judge

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
        if _is_failed(response):
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


# --------------------------------------------------------------------------- TVL result files


def subset_of(image_fp: object) -> str | None:
    """"SSVTP" or "HCT" from a TVL image path (relative or absolute), else None."""
    if not isinstance(image_fp, str):
        return None
    fp = image_fp.lower()
    if "ssvtp" in fp:
        return "SSVTP"
    if "hct" in fp:
        return "HCT"
    return None


def check_records(records: object, source: str = "input") -> list[dict]:
    """Raise DataError unless `records` is a non-empty list of objects, each with a non-empty
    string ``label`` and a ``generated response`` (a string or null)."""
    if not isinstance(records, list):
        raise DataError(f"{source}: expected a JSON list of objects, got {type(records).__name__}")
    if not records:
        raise DataError(f"{source}: the list is empty")
    for i, rec in enumerate(records):
        if not isinstance(rec, dict):
            raise DataError(f"{source}: record {i} is a {type(rec).__name__}, not an object")
        for key in (LABEL_KEY, RESPONSE_KEY):
            if key not in rec:
                raise DataError(f"{source}: record {i} has no {key!r} key")
        if not isinstance(rec[LABEL_KEY], str) or not parse_adjectives(rec[LABEL_KEY]):
            raise DataError(f"{source}: record {i} has an empty or non-string label "
                            f"{rec[LABEL_KEY]!r}")
        if rec[RESPONSE_KEY] is not None and not isinstance(rec[RESPONSE_KEY], str):
            raise DataError(f"{source}: record {i} 'generated response' must be a string or null, "
                            f"got {type(rec[RESPONSE_KEY]).__name__}")
    return records


def read_records(path: str | os.PathLike) -> list[dict]:
    """Load and check a TVL-format result file (see `check_records`)."""
    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(f"{path} does not exist or is not a file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as e:
        raise DataError(f"{path} is not valid JSON: {e}") from e
    return check_records(data, str(path))


BOOTSTRAP_SAMPLES = 2000


def mean_ci(values: Sequence[float], level: float = 0.95, n_boot: int = BOOTSTRAP_SAMPLES,
            seed: int = 0) -> tuple[float, float, float]:
    """(mean, low, high): the mean and its percentile bootstrap CI (seeded, so reproducible).

    Raises:
        DataError: If `values` is empty.
    """
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        raise DataError("a confidence interval needs at least one value")
    if not 0 < level < 1:
        raise ConfigError(f"level {level} must lie in (0, 1)")
    means = x[np.random.default_rng(seed).integers(0, x.size, (n_boot, x.size))].mean(1)
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(x.mean()), float(lo), float(hi)


def score_stats(labels: Sequence[str], responses: Sequence[str | None], scores: Sequence[float],
                seed: int = 0) -> dict:
    """What every system comparison prints: the judge mean with its 95 % bootstrap CI, label
    adjective F1 and the mean number of adjectives per answer (failed answers count 0).

    Returns:
        ``{"n", "mean", "ci_low", "ci_high", "f1", "mean_length"}``.
    """
    if not len(labels) == len(responses) == len(scores):
        raise DataError(f"{len(labels)} labels, {len(responses)} responses, {len(scores)} scores")
    mean, lo, hi = mean_ci(scores, seed=seed)
    return {"n": len(scores), "mean": mean, "ci_low": lo, "ci_high": hi,
            "f1": float(np.mean([adjective_f1(lab, r) for lab, r in zip(labels, responses)])),
            "mean_length": float(np.mean([len(parse_adjectives(r)) for r in responses]))}


def format_stats(s: Mapping) -> str:
    """``7.945 [7.901, 7.988]  F1 0.606  3.4 adj`` from `score_stats`."""
    return (f"{s['mean']:.3f} [{s['ci_low']:.3f}, {s['ci_high']:.3f}]  F1 {s['f1']:.3f}  "
            f"{s['mean_length']:.1f} adj")


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def judge_results(records: list[dict], judge: OfflineJudge | LLMJudge) -> tuple[list[dict], dict]:
    """Score every record of a TVL-format list (as one system: the offline judge measures the
    system's word rates on these answers).

    Returns:
        (copies of the records with ``judge.key`` -- ``offline_score`` or ``llm_score`` -- added,
        summary). A null or empty response scores 1 and counts as failed. The summary holds,
        per subset (SSVTP, HCT, overall), n, n_failed, the judge's mean with its 95 % bootstrap
        CI, adjective F1 and mean length (`score_stats`) and, where the ``evaluation`` field
        parses, the GPT-4 mean and how many parsed.
    """
    check_records(records)
    failed = [_is_failed(r[RESPONSE_KEY]) for r in records]
    todo = [i for i, f in enumerate(failed) if not f]
    got = judge.score_many([(records[i][LABEL_KEY], records[i][RESPONSE_KEY]) for i in todo])
    scores = [MIN_SCORE] * len(records)
    for i, s in zip(todo, got):
        scores[i] = float(s)
    out = [{**rec, judge.key: s} for rec, s in zip(records, scores)]
    groups: dict[str, list[int]] = {name: [] for name in SUBSETS}
    for i, rec in enumerate(records):
        sub = subset_of(rec.get("image_fp"))
        if sub is not None:
            groups[sub].append(i)
    groups["overall"] = list(range(len(records)))
    subsets = {}
    for name, idx in groups.items():
        gpt = [g for g in (parse_gpt_score(records[i].get(EVAL_KEY)) for i in idx) if g is not None]
        stats = (score_stats([records[i][LABEL_KEY] for i in idx],
                             [records[i][RESPONSE_KEY] for i in idx], [scores[i] for i in idx])
                 if idx else {"mean": None})
        subsets[name] = {**stats, "n": len(idx), "n_failed": sum(failed[i] for i in idx),
                         "gpt4_mean": _mean(gpt), "n_gpt4": len(gpt)}
    summary = {"judge": judge.name, "score_key": judge.key, "n": len(records),
               "n_failed": sum(failed), "subsets": subsets, **judge.stats()}
    return out, summary


def format_summary(summary: dict) -> str:
    """Per-subset means (95 % bootstrap CI, adjective F1, mean length) as a small table."""
    judge = summary["judge"]
    lines = [f"{'subset':<9}{'n':>5}{'failed':>8}  {judge + ' [95% CI]':<26}{'F1':>6}{'adj':>6}"
             f"{'GPT-4':>8}"]
    for name, s in summary["subsets"].items():
        if s["mean"] is None:
            lines.append(f"{name:<9}{s['n']:>5}{s['n_failed']:>8}  -")
            continue
        gpt = f"{s['gpt4_mean']:.3f}" if s["gpt4_mean"] is not None else "-"
        ci = f"{s['mean']:.3f} [{s['ci_low']:.3f}, {s['ci_high']:.3f}]"
        lines.append(f"{name:<9}{s['n']:>5}{s['n_failed']:>8}  {ci:<26}{s['f1']:>6.3f}"
                     f"{s['mean_length']:>6.1f}{gpt:>8}")
    if judge == "llm":
        lines.append(f"LLM requests {summary['n_requests']}, errors {summary['n_errors']}, "
                     f"unparseable {summary['n_unparseable']}, "
                     f"fallbacks to the offline judge {summary['n_fallbacks']}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- protocol: fit / validate


def judge_data_dir() -> Path:
    """``$RATOUCH_TVL_JUDGE_DIR``, else ``../shared/data/tvl_judge`` beside the repository."""
    return tvl_judge_dir()


def load_tvl_results(data_dir: str | os.PathLike | None = None) -> dict[str, list[dict]]:
    """The three published TVL-LLaMA result files, checked to hold the same samples in order."""
    folder = Path(data_dir) if data_dir is not None else judge_data_dir()
    out = {}
    for model in MODELS:
        path = folder / f"{model}.json"
        if not path.is_file():
            raise DataNotFoundError(f"TVL judge data {path} not found (set ${DATA_DIR_ENV})")
        out[model] = read_records(path)
    ref = out[MODELS[0]]
    for model in MODELS[1:]:
        recs = out[model]
        if len(recs) != len(ref) or any(
                a[LABEL_KEY] != b[LABEL_KEY] or Path(str(a.get("image_fp"))).name
                != Path(str(b.get("image_fp"))).name for a, b in zip(ref, recs)):
            raise DataError(f"{model}.json does not list the same samples as {MODELS[0]}.json")
    return out


def heldout_split(records: list[dict], seed: int = 0, fit_fraction: float = 0.5
                  ) -> tuple[list[int], list[int]]:
    """(fit, held-out) sample indices, stratified by subset and seeded. The same indices are
    used for every model, so the answers of the models to one sample share a side."""
    rng = np.random.default_rng(seed)
    by_subset: dict[str | None, list[int]] = {}
    for i, rec in enumerate(records):
        by_subset.setdefault(subset_of(rec.get("image_fp")), []).append(i)
    fit: list[int] = []
    for key in (*SUBSETS, None):  # a fixed order: SSVTP, HCT, then samples of neither
        if key not in by_subset:
            continue
        idx = np.asarray(by_subset[key])[rng.permutation(len(by_subset[key]))]
        fit += idx[: int(len(idx) * fit_fraction)].tolist()
    fit_set = set(fit)
    return sorted(fit_set), [i for i in range(len(records)) if i not in fit_set]


def _rows(data: Mapping[str, list[dict]], idx: Sequence[int], models: Sequence[str] = MODELS):
    """(label, response, GPT-4 score, model, subset) of the answers of `models` to samples
    `idx`, skipping answers whose GPT-4 evaluation does not parse."""
    rows = []
    for model in models:
        for i in idx:
            rec = data[model][i]
            gpt = parse_gpt_score(rec.get(EVAL_KEY))
            if gpt is not None:
                rows.append((rec[LABEL_KEY], rec[RESPONSE_KEY], gpt, model,
                             subset_of(rec.get("image_fp"))))
    return rows


def fit_calibration(data: Mapping[str, list[dict]], models: Sequence[str], idx: Sequence[int],
                    meta: Mapping | None = None) -> dict:
    """Fit label base rates and the 1-10 calibration on the answers of `models` to samples `idx`.

    Label base rates come from the labels of `idx`; each model's word rates from its own answers
    to `idx` (as `score_many` measures them at judge time); then least squares of
    ``1 + 9 * sigmoid(b + w . z)`` against GPT-4, z the standardised `FEATURES`.
    """
    from scipy.optimize import least_squares

    labels = [data[models[0]][i][LABEL_KEY] for i in idx]
    answer_words = {w for m in models for i in idx for w in parse_adjectives(data[m][i][RESPONSE_KEY])}
    label_rates = label_fit_rates(labels, answer_words)
    X, y = [], []
    for model in models:
        rates = answer_rates(data[model][i][RESPONSE_KEY] for i in idx)
        for label, response, gpt, _, _ in _rows(data, idx, [model]):
            pred = parse_adjectives(response)
            if pred:
                X.append(judge_features(parse_adjectives(label), pred, label_rates, rates))
                y.append(gpt)
    X, y = np.asarray(X, dtype=np.float64), np.asarray(y, dtype=np.float64)
    mean, scale = X.mean(0), X.std(0)
    scale[scale == 0] = 1.0
    Z = (X - mean) / scale

    def residual(p):
        return MIN_SCORE + (MAX_SCORE - MIN_SCORE) / (1.0 + np.exp(-(p[0] + Z @ p[1:]))) - y

    p = least_squares(residual, np.zeros(Z.shape[1] + 1), method="trf").x
    return {"features": list(FEATURES), "mean": mean.tolist(), "scale": scale.tolist(),
            "intercept": float(p[0]), "weights": p[1:].tolist(), "label_rates": label_rates,
            "fit": {"models": list(models), **(meta or {}), "n_fit_samples": len(idx),
                    "n_fit_answers": int(len(y))}}


def fit_offline_judge(data_dir: str | os.PathLike | None = None, seed: int = 0,
                      fit_fraction: float = 0.5) -> dict:
    """Fit the offline judge on the FIT part (`heldout_split`) of all three TVL files."""
    data = load_tvl_results(data_dir)
    fit_idx, _ = heldout_split(data[MODELS[0]], seed, fit_fraction)
    return fit_calibration(data, MODELS, fit_idx, {"split_seed": seed, "fit_fraction": fit_fraction})


def write_offline_config(params: Mapping, path: str | os.PathLike | None = None) -> Path:
    """Write a calibration (atomically) to `path` (default: the shipped config)."""
    return write_json_atomic(path if path is not None else CONFIG_PATH, _check_params(params))


def _ranking(means: Mapping[str, float]) -> list[str]:
    return sorted(means, key=lambda m: (-means[m], m))


def _spearman(a: Sequence[float], b: Sequence[float]) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(a, b)[0])


def leave_one_system_out(data: Mapping[str, list[dict]], fit_idx: Sequence[int],
                         held_idx: Sequence[int]) -> dict:
    """Fit on two systems' answers to the FIT samples, judge the third on the held-out samples.

    Returns per held-out system its GPT-4 and judge means and the error, the ranking of the three
    held-out means against GPT-4's, and the pooled Spearman rho of the held-out answers.
    """
    per_system, judge_all, gpt_all = {}, [], []
    for held in MODELS:
        judge = OfflineJudge(fit_calibration(data, [m for m in MODELS if m != held], fit_idx))
        rows = _rows(data, held_idx, [held])
        scores = judge.score_many([(r[0], r[1]) for r in rows])
        gpt = [r[2] for r in rows]
        per_system[held] = {"n_answers": len(rows), "gpt4": float(np.mean(gpt)),
                            "offline": float(np.mean(scores)),
                            "error": float(np.mean(scores) - np.mean(gpt)),
                            "spearman": _spearman(scores, gpt)}
        judge_all += scores
        gpt_all += gpt
    rank_gpt = _ranking({m: s["gpt4"] for m, s in per_system.items()})
    rank_off = _ranking({m: s["offline"] for m, s in per_system.items()})
    return {"per_system": per_system, "pooled_spearman": _spearman(judge_all, gpt_all),
            "max_abs_error": max(abs(s["error"]) for s in per_system.values()),
            "ranking_gpt4": rank_gpt, "ranking_offline": rank_off,
            "ranking_identical": rank_gpt == rank_off}


# --------------------------------------------------------------------------- style shifts


def generic_words(label_rates: Mapping[str, float], n: int = 3) -> list[str]:
    """The `n` tactile words that fit the most labels (the padding of the style-shift test)."""
    tactile = set(TVL_ADJECTIVES) | set(EXTRA_TACTILE)
    return sorted((w for w in label_rates if w in tactile), key=lambda w: (-label_rates[w], w))[:n]


def antonym_answer(label: str) -> str | None:
    """An answer that contradicts the label: the head word of each group opposite to a label
    word's groups ("soft, fuzzy" -> "hard"); None when no label word has an antonym."""
    out: list[str] = []
    for w in parse_adjectives(label):
        for g in _MEMBERS.get(w, {}):
            out += [b for a, b in sorted(_OPPOSITE) if a == g and b not in out]
    return ", ".join(out) if out else None


def style_shift(kind: str, labels: Sequence[str], responses: Sequence[str | None], seed: int = 0,
                pad: Sequence[str] = ()) -> list[str | None]:
    """One system's answers rewritten in another style: "pad" (append the `pad` words),
    "truncate" (first word only), "shuffle" (answers permuted across samples, seeded) or
    "antonyms" (contradict the label; None where it has no antonym)."""
    if kind == "pad":
        return [", ".join(parse_adjectives(r) + [w for w in pad if w not in parse_adjectives(r)])
                for r in responses]
    if kind == "truncate":
        return [(parse_adjectives(r) or [None])[0] for r in responses]
    if kind == "shuffle":
        perm = np.random.default_rng(seed).permutation(len(responses))
        return [responses[i] for i in perm]
    if kind == "antonyms":
        return [antonym_answer(lab) for lab in labels]
    raise ConfigError(f"unknown style shift {kind!r}")


SHIFTS = {  # kind: what GPT-4 would be expected to do
    "pad": "must not rise (generic words carry no information)",
    "truncate": "must fall (fewer correct adjectives)",
    "shuffle": "must fall to near the chance level",
    "antonyms": "must fall below the chance level",
}
CHANCE_TOLERANCE = 0.5


def _cell(label: str, response: str | None, label_rates: Mapping[str, float]) -> tuple[int, int]:
    table = word_table(parse_adjectives(label), parse_adjectives(response), label_rates)
    return (min(sum(t["similarity"] >= _MATCHED for t in table), 3),
            min(sum(t["clash"] > 0 for t in table), 2))


def chance_level(data: Mapping[str, list[dict]], idx: Sequence[int], judge: OfflineJudge,
                 seed: int = 0) -> dict:
    """What GPT-4 would give answers shuffled across samples, estimated from its real scores.

    Each real answer falls in a cell (matched words 0/1/2/3+, contradicted words 0/1/2+); the
    chance level is the mean, over shuffled pairs, of GPT-4's mean score of the real answers in
    the shuffled pair's cell. ``floor``: GPT-4's mean over real answers matching nothing.
    """
    rows = [r for r in _rows(data, idx) if parse_adjectives(r[1])]
    cells: dict[tuple[int, int], list[float]] = {}
    for r in rows:
        cells.setdefault(_cell(r[0], r[1], judge.label_rates), []).append(r[2])
    means = {c: float(np.mean(v)) for c, v in cells.items()}
    est = []
    for model in MODELS:
        labels = [data[model][i][LABEL_KEY] for i in idx]
        shuffled = style_shift("shuffle", labels, [data[model][i][RESPONSE_KEY] for i in idx], seed)
        for lab, resp in zip(labels, shuffled):
            c = _cell(lab, resp, judge.label_rates) if parse_adjectives(resp) else None
            if c in means:
                est.append(means[c])
    return {"chance": float(np.mean(est)), "floor": means.get((0, 0), float("nan"))}


def style_shifts(data: Mapping[str, list[dict]], idx: Sequence[int], judge: OfflineJudge,
                 seed: int = 0) -> dict:
    """The judge's mean over the three systems' answers to `idx`, as written and under each
    style shift, with the expected direction checked (each system is judged as its own file)."""
    pad = generic_words(judge.label_rates)
    levels = chance_level(data, idx, judge, seed)
    chance = levels["chance"]
    base, shifted = [], {k: [] for k in SHIFTS}
    for model in MODELS:
        labels = [data[model][i][LABEL_KEY] for i in idx]
        responses = [data[model][i][RESPONSE_KEY] for i in idx]
        base += judge.score_many(zip(labels, responses))
        for kind in SHIFTS:
            new = style_shift(kind, labels, responses, seed, pad)
            keep = [i for i, r in enumerate(new) if r is not None]
            shifted[kind] += judge.score_many([(labels[i], new[i]) for i in keep])
    original = float(np.mean(base))
    out = {"original": original, "chance_level_gpt4": chance, "no_match_gpt4": levels["floor"],
           "pad_words": pad, "shifts": {}}
    for kind, scores in shifted.items():
        m = float(np.mean(scores))
        ok = {"pad": m <= original + 0.05, "truncate": m < original,
              "shuffle": m < original and abs(m - chance) <= CHANCE_TOLERANCE,
              "antonyms": m < min(original, chance)}[kind]
        out["shifts"][kind] = {"n_answers": len(scores), "mean": m, "change": m - original,
                               "expected": SHIFTS[kind], "as_expected": bool(ok)}
    return out


def length_effect(data: Mapping[str, list[dict]], idx: Sequence[int], judge: OfflineJudge) -> dict:
    """What one more adjective does to the score at fixed content, for GPT-4 and for the judge.

    Least squares of the score on (matched words, contradicted words, predicted words, label
    words) over the three systems' answers to `idx`; the ``per_adjective`` coefficients are the
    change per extra adjective that neither matches nor contradicts the label.
    """
    X, gpt, off = [], [], []
    for model in MODELS:
        rows = [r for r in _rows(data, idx, [model]) if parse_adjectives(r[1])]
        off += judge.score_many([(r[0], r[1]) for r in rows])
        for r in rows:
            lab, pred = parse_adjectives(r[0]), parse_adjectives(r[1])
            table = word_table(lab, pred, judge.label_rates)
            X.append([1.0, sum(t["similarity"] >= _MATCHED for t in table),
                      sum(t["clash"] > 0 for t in table), len(pred), len(lab)])
            gpt.append(r[2])
    X = np.asarray(X)
    coef = {name: np.linalg.lstsq(X, np.asarray(y), rcond=None)[0]
            for name, y in (("gpt4", gpt), ("offline", off))}
    out = {name: {"per_matched": float(c[1]), "per_contradicted": float(c[2]),
                  "per_adjective": float(c[3])} for name, c in coef.items()}
    out["difference_per_adjective"] = out["offline"]["per_adjective"] - out["gpt4"]["per_adjective"]
    return out


def validate_judge(data_dir: str | os.PathLike | None = None, judge: OfflineJudge | None = None,
                   seed: int | None = None, fit_fraction: float | None = None) -> dict:
    """Agreement of the offline judge with GPT-4 on answers and styles it was not fitted on.

    The split defaults to the one the judge's calibration was fitted with, so only samples it
    never saw are used. Returns, on the held-out samples: pooled and per-subset Spearman rho of
    the judge (and of plain adjective F1), per-model means and rankings; ``loso``: leave one
    system out (`leave_one_system_out`); ``style_shifts`` (`style_shifts`).
    """
    judge = judge if judge is not None else OfflineJudge()
    fit_meta = judge.params.get("fit", {})
    seed = fit_meta.get("split_seed", 0) if seed is None else seed
    fit_fraction = fit_meta.get("fit_fraction", 0.5) if fit_fraction is None else fit_fraction
    data = load_tvl_results(data_dir)
    fit_idx, held_idx = heldout_split(data[MODELS[0]], seed, fit_fraction)
    rows = _rows(data, held_idx)
    gpt = np.array([r[2] for r in rows])
    models = np.array([r[3] for r in rows])
    off = np.zeros(len(rows))
    for m in MODELS:  # each system judged as its own file (its own word rates)
        sel = np.flatnonzero(models == m)
        off[sel] = judge.score_many([(rows[i][0], rows[i][1]) for i in sel])
    f1 = np.array([adjective_f1(r[0], r[1]) for r in rows])
    subsets = np.array([str(r[4]) for r in rows])
    per_model = {m: {"gpt4": float(gpt[models == m].mean()), "offline": float(off[models == m].mean()),
                     "f1": float(f1[models == m].mean())} for m in MODELS}
    rankings = {k: _ranking({m: per_model[m][k] for m in MODELS}) for k in ("gpt4", "offline", "f1")}
    by_subset = {name: {"n_answers": int((subsets == name).sum()),
                        "spearman_offline": _spearman(off[subsets == name], gpt[subsets == name]),
                        "spearman_f1": _spearman(f1[subsets == name], gpt[subsets == name])}
                 for name in SUBSETS if (subsets == name).sum() > 1}
    return {
        "split_seed": seed, "fit_fraction": fit_fraction, "n_samples": len(data[MODELS[0]]),
        "n_fit_samples": len(fit_idx), "n_heldout_samples": len(held_idx),
        "n_heldout_answers": len(rows),
        "spearman_offline": _spearman(off, gpt), "spearman_f1": _spearman(f1, gpt),
        "gpt4_interrun_reference": GPT4_INTERRUN_SPEARMAN,
        "by_subset": by_subset, "per_model": per_model,
        "ranking_gpt4": rankings["gpt4"], "ranking_offline": rankings["offline"],
        "ranking_f1": rankings["f1"],
        "ranking_identical": rankings["offline"] == rankings["gpt4"],
        "loso": leave_one_system_out(data, fit_idx, held_idx),
        "style_shifts": style_shifts(data, held_idx, judge, seed),
        "length_effect": length_effect(data, held_idx, judge),
        "targets": TARGETS,
    }


def format_validation(r: dict) -> str:
    """The validation figures for people."""
    lines = [
        f"offline judge vs GPT-4 on the held-out part of the TVL judge data: "
        f"{r['n_heldout_samples']} of {r['n_samples']} samples x {len(r['per_model'])} models = "
        f"{r['n_heldout_answers']} answers (fitted on the other {r['n_fit_samples']} samples, "
        f"split seed {r['split_seed']})",
        f"Spearman rho with GPT-4: offline judge {r['spearman_offline']:.3f}, "
        f"adjective-set F1 {r['spearman_f1']:.3f} "
        f"(GPT-4 inter-run reference {r['gpt4_interrun_reference']:.2f})",
    ]
    for name, s in r["by_subset"].items():
        lines.append(f"  {name:<6} ({s['n_answers']} answers): offline {s['spearman_offline']:.3f}, "
                     f"F1 {s['spearman_f1']:.3f}")
    lines.append(f"{'model':<22}{'GPT-4':>8}{'offline':>9}{'F1':>8}")
    for m, s in r["per_model"].items():
        lines.append(f"{m:<22}{s['gpt4']:>8.3f}{s['offline']:>9.3f}{s['f1']:>8.3f}")
    lines.append("ranking GPT-4:   " + " > ".join(r["ranking_gpt4"]))
    lines.append("ranking offline: " + " > ".join(r["ranking_offline"])
                 + ("  (identical)" if r["ranking_identical"] else "  (DIFFERENT)"))
    lines.append("ranking F1:      " + " > ".join(r["ranking_f1"]))
    le = r["length_effect"]
    lines += ["", "length effect at fixed content (score change per extra adjective that neither "
                  "matches nor contradicts, least squares on the held-out answers): "
                  f"GPT-4 {le['gpt4']['per_adjective']:+.3f}, offline "
                  f"{le['offline']['per_adjective']:+.3f} (difference "
                  f"{le['difference_per_adjective']:+.3f}, bound "
                  f"{TARGETS['length_effect_difference']})"]
    return "\n".join(lines + _format_loso(r["loso"], r["targets"])
                     + _format_shifts(r["style_shifts"]))


def _format_loso(lo: dict, targets: Mapping) -> list[str]:
    met = (lo["max_abs_error"] <= targets["max_abs_mean_error"] and lo["ranking_identical"]
           and lo["pooled_spearman"] >= targets["pooled_spearman"])
    lines = ["", "leave one system out (fit on the other two systems' FIT answers, judge the "
                 "held-out system's held-out answers):",
             f"{'held-out system':<22}{'GPT-4':>8}{'offline':>9}{'error':>8}{'rho':>7}"]
    for m, s in lo["per_system"].items():
        lines.append(f"{m:<22}{s['gpt4']:>8.3f}{s['offline']:>9.3f}{s['error']:>+8.3f}"
                     f"{s['spearman']:>7.3f}")
    lines.append(f"pooled Spearman {lo['pooled_spearman']:.3f} (target >= "
                 f"{targets['pooled_spearman']}), max |mean error| {lo['max_abs_error']:.3f} "
                 f"(target <= {targets['max_abs_mean_error']}), ranking "
                 f"{'preserved' if lo['ranking_identical'] else 'CHANGED'}: "
                 f"{'targets met' if met else 'TARGET MISSED'}")
    return lines


def _format_shifts(sh: dict) -> list[str]:
    lines = ["", f"style shifts of the held-out answers (judge mean as written "
                 f"{sh['original']:.3f}; GPT-4 chance level {sh['chance_level_gpt4']:.3f}; "
                 f"padding words: {', '.join(sh['pad_words'])}):",
             f"{'shift':<10}{'mean':>8}{'change':>8}  expected"]
    for kind, s in sh["shifts"].items():
        lines.append(f"{kind:<10}{s['mean']:>8.3f}{s['change']:>+8.3f}  {s['expected']}: "
                     f"{'yes' if s['as_expected'] else 'NO'}")
    return lines


# --------------------------------------------------------------------------- explain / compare


def explain_results(records: list[dict], judge: OfflineJudge | None = None) -> list[dict]:
    """Per record (one system's answers): label, answer, per-word table and score."""
    judge = judge if judge is not None else OfflineJudge()
    check_records(records)
    rates = answer_rates(r[RESPONSE_KEY] for r in records)
    return [judge.explain(r[LABEL_KEY], r[RESPONSE_KEY], rates) for r in records]


def format_explain(explained: Sequence[dict]) -> str:
    """One block per answer: score, label, then each word with its status and weight."""
    lines = []
    for i, e in enumerate(explained):
        lines.append(f"[{i}] score {e['score']:.2f}  label: {', '.join(e['label'])}")
        if not e["words"]:
            lines.append("    (no adjectives: failed answer, scored 1)")
        for t in e["words"]:
            match = (f" ~ {t['label_word']} (sim {t['similarity']:.2f})"
                     if t["status"] in ("matched", "ignored") and t["label_word"] else "")
            clash = f" clash {t['clash']:.2f}" if t["clash"] else ""
            lines.append(f"    {t['word']:<14}{t['status']:<12}weight {t['weight']:.2f} "
                         f"(label rate {t['label_rate']:.2f}, system rate {t['system_rate']:.2f})"
                         f"{match}{clash}")
    return "\n".join(lines)


def compare_judges(files: Mapping[str, list[dict]], llm: LLMJudge,
                   offline: OfflineJudge | None = None) -> dict:
    """Agreement of the offline judge with an LLM judge on the user's own result files.

    Returns per file n, both means and their difference (offline - LLM), the Spearman rho of
    the per-answer scores (None where either judge gives one constant score), the pooled rho,
    and the LLM judge's request counters.
    """
    offline = offline if offline is not None else OfflineJudge()
    per_file, all_off, all_llm = {}, [], []
    for name, records in files.items():
        off = [r[offline.key] for r in judge_results(records, offline)[0]]
        lm = [r[llm.key] for r in judge_results(records, llm)[0]]
        per_file[name] = {"n": len(records), "offline_mean": float(np.mean(off)),
                          "llm_mean": float(np.mean(lm)),
                          "mean_diff": float(np.mean(off) - np.mean(lm)),
                          "spearman": _safe_spearman(off, lm)}
        all_off += off
        all_llm += lm
    return {"files": per_file, "pooled_spearman": _safe_spearman(all_off, all_llm),
            "llm": llm.stats()}


def _safe_spearman(a: Sequence[float], b: Sequence[float]) -> float | None:
    if len(a) < 2 or len(set(a)) < 2 or len(set(b)) < 2:
        return None
    return _spearman(a, b)


def format_compare(r: dict) -> str:
    """The offline-vs-LLM agreement table."""
    def rho(x):
        return "-" if x is None else f"{x:.3f}"

    lines = [f"{'file':<40}{'n':>5}{'offline':>9}{'LLM':>8}{'diff':>8}{'rho':>7}"]
    for name, s in r["files"].items():
        lines.append(f"{name[-40:]:<40}{s['n']:>5}{s['offline_mean']:>9.3f}{s['llm_mean']:>8.3f}"
                     f"{s['mean_diff']:>+8.3f}{rho(s['spearman']):>7}")
    lines.append(f"pooled Spearman rho {rho(r['pooled_spearman'])}; LLM requests "
                 f"{r['llm']['n_requests']}, errors {r['llm']['n_errors']}, fallbacks to the "
                 f"offline judge {r['llm']['n_fallbacks']}")
    return "\n".join(lines)

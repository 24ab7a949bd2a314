"""Recaptioning: turn (class name, visual description) into exactly 5 tactile adjectives.

ImageNet-T is built by asking a language model the paper's prompt (`PAPER_PROMPT`) for every
corpus entry. `LLMRecaptioner` does that against any OpenAI-compatible chat-completions endpoint
using only the standard library; `OfflineRecaptioner` is a deterministic lexicon-based stand-in
that needs no network and also serves as the LLM's fallback; `SmolLM2Recaptioner`
(`corpus/smollm.py`) answers the same prompt offline with a real pretrained language model,
constrained to the TVL vocabulary. Every caption a recaptioner returns passes `validate_caption`.
"""

from __future__ import annotations

import logging
import math
import re
import threading
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Protocol

from ratouch.errors import ConfigError, DataError
from ratouch.llm_http import (
    REQUEST_ERRORS,
    chat_completion,
    chat_url,
    check_client_settings,
    is_http_url,
)
from ratouch.vocabulary import (
    EXTRA_TACTILE,
    TACTILE_WORDS,
    TVL_ADJECTIVES,
    banned_category,
)

if TYPE_CHECKING:
    from ratouch.corpus.smollm import SmolLM2Recaptioner

logger = logging.getLogger(__name__)

PAPER_PROMPT = """## Task
Create a tactile caption for an object in the given image based on its class name and an image description.
Class: {class_name}
Description: {caption}

## Instructions
1. Provide exactly 5 adjectives that refer solely to how the object feels to the touch--focusing on texture, flexibility, density, and material properties.
2. Try to include more varied and nuanced tactile descriptors.
3. Do not include adjectives related to visual appearance, shape, color, temperature, sound, weight, or any non-tactile properties.
4. Respond using the exact format: "adj1, adj2, adj3, adj4, adj5".

Remember: Your ENTIRE response must be ONLY 5 adjectives separated by commas."""

N_ADJECTIVES = 5
#: The recaptioners `create_recaptioner` builds, by the name `RecaptionConfig.backend` gives.
BACKENDS = ("offline", "llm", "smollm2")
# Generic fill-ins used when the lexicon scores fewer than 5 adjectives.
BACKOFF_ADJECTIVES: tuple[str, ...] = (
    "textured", "solid", "firm", "smooth", "uneven", "hard", "rigid", "flat",
)
# Class-name words say what the object is; description words may also describe its surroundings.
CLASS_NAME_WEIGHT = 1.5
DESCRIPTION_WEIGHT = 1.0

_WORD_RE = re.compile(r"^[a-z]+(?:-[a-z]+)*$")
_TOKEN_RE = re.compile(r"[a-z]+(?:-[a-z]+)*")
_QUOTES = "\"'`\u201c\u201d\u2018\u2019"
# Rank of every tactile word: TVL frequency order first, then the extra words.
_RANK: Mapping[str, int] = MappingProxyType(
    {w: i for i, w in enumerate(dict.fromkeys(TVL_ADJECTIVES + EXTRA_TACTILE))}
)

# Built-in lexicon: "key | key = adj adj ..."; the n-th adjective of a line weighs 1.0 - 0.1 n.
_BUILTIN_SPEC = """
wood | wooden | timber | plank | log | oak | pine = hard grainy solid rigid textured dry
metal | steel | iron | aluminum | aluminium | tin | chrome = metallic hard smooth rigid solid polished
stainless = metallic smooth polished hard sleek
glass | crystal | mirror | window = glassy smooth slick hard brittle rigid
ceramic | porcelain | clay | pottery = hard smooth glossy rigid brittle solid
plastic = plastic smooth rigid hard sleek flexible
leather = leathery supple smooth pliable grainy firm
suede = velvety soft supple nubby fuzzy
fur | furry | pelt = furry soft fluffy plush fuzzy hairy
wool | woolen | woollen | yarn = fibrous soft scratchy fuzzy woven thick
knit | knitted | crochet = knitted stretchy soft ribbed fibrous
cotton = cottony soft fabric fibrous woven pliable
denim | jeans = woven coarse fabric stiff thick sewn
silk | silky = silky smooth slippery soft satiny supple
satin = satiny silky smooth slippery soft
velvet = velvety plush soft fuzzy smooth
rubber = rubbery elastic grippy flexible smooth deformable
foam = spongy squishy soft compressible porous yielding
sponge = spongy porous squishy soft compressible
paper | tissue | napkin = papery smooth flimsy dry flat crinkled
cardboard | carton = corrugated stiff papery rigid dry flat
stone | rock | pebble | boulder = hard rough solid uneven craggy gritty
marble = smooth polished hard solid glossy
granite = hard grainy polished solid rough
concrete | cement | pavement | road = hard rough gritty solid abrasive porous
brick | tile = rough hard porous gritty solid grainy
sand | beach | dune = sandy grainy gritty loose powdery
fabric | cloth | textile = fabric woven soft pliable cloth-like sewn
towel = soft fibrous plush cottony thick nubby
carpet | rug | mat = fibrous plush soft textured woven dense
wicker | rattan | basket | hamper = woven ridged rigid rough textured dry
straw | hay = fibrous dry scratchy coarse brittle
bark | trunk = rough craggy uneven ridged coarse hard
feather | feathers | feathery | plumage = downy soft fluffy silky flexible
fleece = fluffy soft fuzzy plush cottony
felt = fuzzy soft dense matte fibrous
linen = woven fabric smooth dry cloth-like wrinkly
burlap | sack = coarse scratchy woven rough fibrous
mesh | net | netting = mesh perforated flexible woven lined
lace = perforated embroidered soft woven flimsy
nylon | polyester = smooth slick fabric stretchy flexible
canvas | tent = woven coarse fabric stiff sturdy
wax | candle = waxy smooth solid firm slick
bone | horn | tusk | antler = hard smooth solid rigid dense
shell | seashell = hard ridged smooth brittle rigid
plaster | chalk = powdery dry matte brittle gritty
ice = slippery smooth hard slick glassy
snow = powdery soft loose compressible
dirt | soil | earth = loose gritty grainy powdery lumpy
mud = squishy tacky deformable yielding
gravel = pebbled gritty loose uneven hard
grass | lawn = soft flexible fibrous springy uneven
leaf | leaves | foliage = flexible smooth papery dry supple
moss = soft spongy fuzzy springy
flower | petal | rose = soft silky velvety supple flimsy
cactus | thorn = pointed sharp rough bristly firm
apple | tomato | pepper = smooth firm waxy solid
lemon | lime | citrus = pebbled waxy firm bumpy
pineapple = rough bumpy pointed hard ridged
bread | loaf | bagel | bun = spongy soft porous squishy dry
cake | muffin = soft spongy squishy yielding
cheese = firm smooth waxy dense
balloon = elastic stretchy smooth rubbery slick
sofa | couch | armchair = cushioned soft plush padded fabric
pillow | cushion = soft cushioned plush squishy fluffy
blanket | quilt | duvet = soft quilted fabric plush sewn
mattress = cushioned springy soft padded firm
bottle | jar = smooth hard rigid glossy plastic
cup | mug | teapot | jug = smooth hard glossy rigid solid
bowl | plate | dish | vase = smooth hard glossy rigid curved
pan | pot | wok | skillet | kettle | frying pan = metallic hard smooth rigid solid
knife | knives | blade | sword | axe | scissors = sharp metallic hard smooth rigid
boot | shoe | sneaker | sandal | loafer = leathery firm sewn textured flexible
bag | backpack | purse | wallet | handbag = leathery fabric sewn flexible supple
sweater | cardigan | pullover = knitted soft fibrous stretchy fuzzy
mitten | glove | sock | scarf | beanie = knitted soft stretchy fibrous fuzzy
hat | cap | bonnet = fabric soft flexible sewn fibrous
shirt | jacket | coat | dress | skirt | apron = fabric soft woven sewn pliable
ball = smooth firm rubbery elastic curved
tennis ball = fuzzy springy rubbery soft
golf ball = dotted indented hard smooth
basketball = pebbled rubbery grippy firm
baseball = leathery sewn hard firm
soccer ball | football = textured sewn firm rubbery smooth
tire | tyre | wheel = rubbery grooved ridged firm rough
brush | broom | toothbrush = bristly stiff scratchy fibrous
rope | string | cord | twine = fibrous coarse woven rough flexible
chain = metallic hard bumpy rigid solid
coin = metallic hard smooth flat ridged
table | desk | bench | shelf | cabinet = hard flat smooth solid rigid
chair | stool = hard smooth rigid solid firm
door | wall | floor = hard flat smooth solid rigid
fence = rough hard rigid uneven
keyboard = plastic hard raised smooth ridged
phone | laptop | screen | monitor | television = sleek smooth glassy hard rigid
book | notebook | envelope = papery smooth flat dry firm
helmet = hard smooth rigid glossy plastic
car | truck | bus | vehicle = metallic smooth hard glossy rigid
bicycle | bike = metallic hard rigid smooth grippy
guitar | violin | piano | cello = smooth polished hard glossy solid
drum = firm smooth elastic hard
umbrella = fabric slick smooth flexible
clock | watch = smooth hard glossy metallic
bucket | bin = plastic hard rigid smooth
toy = plastic smooth hard
teddy bear | plush toy | stuffed toy | fur toy | stuffed animal = soft plush furry fluffy cushioned
cat | kitten = furry soft fluffy silky fuzzy
dog | puppy | hound | terrier | retriever = furry soft hairy fuzzy plush
rabbit | bunny | hamster | guinea pig = furry soft fluffy downy plush
sheep | lamb | alpaca | llama = fluffy fuzzy fibrous soft thick
bear | wolf | fox | lion | tiger = furry thick hairy coarse dense
monkey | ape | gorilla = furry hairy coarse soft
bird | parrot | owl | chicken | hen | duck | goose | swan = downy soft fluffy smooth silky
fish | eel | dolphin = slippery slick smooth
frog | toad = slippery bumpy smooth slick
snake | lizard = pebbled smooth dry ridged supple
crocodile | alligator = rough bumpy hard ridged leathery
turtle | tortoise = hard ridged rough solid grooved
horse | cow | deer = hairy smooth firm leathery
elephant | rhinoceros | hippopotamus = leathery rough wrinkly thick wrinkled
hedgehog | porcupine = bristly pointed sharp coarse
beetle | insect | ant = hard smooth glossy rigid
spider | tarantula = hairy bristly fuzzy
crab | lobster | shrimp = hard ridged bumpy rigid rough
jellyfish = slippery squishy soft deformable slick
starfish = bumpy rough firm textured
sea urchin = pointed sharp bristly hard
coral = rough porous hard craggy
"""


def _parse_spec(spec: str) -> dict[str, dict[str, float]]:
    lexicon: dict[str, dict[str, float]] = {}
    for line in spec.strip().splitlines():
        keys, _, words = line.partition("=")
        weights = {w: round(1.0 - 0.1 * i, 2) for i, w in enumerate(words.split())}
        for key in keys.split("|"):
            lexicon[key.strip()] = weights
    return lexicon


def _check_lexicon(lexicon: Mapping[str, Mapping[str, float]], source: str) -> None:
    """Raise ConfigError unless every key is a word/phrase and every target a tactile word."""
    for key, weights in lexicon.items():
        if not isinstance(key, str) or not 1 <= len(key.split()) <= 2:
            raise ConfigError(f"{source}: key {key!r} must be a word or a two-word phrase")
        if not isinstance(weights, Mapping) or not weights:
            raise ConfigError(f"{source}: entry {key!r} must map adjectives to weights")
        for word, weight in weights.items():
            category = banned_category(word) if isinstance(word, str) else None
            if category is not None:
                raise ConfigError(f"{source}: entry {key!r} targets {word!r}, a {category} word")
            if word not in TACTILE_WORDS:
                raise ConfigError(f"{source}: entry {key!r} targets {word!r}, not a tactile word")
            if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not (
                math.isfinite(weight) and weight > 0
            ):
                raise ConfigError(f"{source}: weight of {word!r} in {key!r} must be > 0, got {weight!r}")


_BUILTIN_LEXICON: Mapping[str, Mapping[str, float]] = MappingProxyType(
    {k: MappingProxyType(v) for k, v in _parse_spec(_BUILTIN_SPEC).items()}
)
_check_lexicon(_BUILTIN_LEXICON, "built-in lexicon")


@dataclass(frozen=True)
class RecaptionConfig:
    """How ImageNet-T captions are produced.

    Attributes:
        backend: "offline" (lexicon, no network), "llm" (OpenAI-compatible endpoint) or
            "smollm2" (SmolLM2-135M-Instruct on this machine, `corpus/smollm.py`).
        endpoint: Base URL such as ``http://127.0.0.1:8000/v1``; requests go to
            ``{endpoint}/chat/completions``. Required for the llm backend.
        model: Model name sent with each request.
        api_key_env: Environment variable holding the API key (never passed or logged).
        timeout_s: Per-request timeout in seconds.
        max_attempts: Requests per caption before falling back to the offline recaptioner.
        temperature: Sampling temperature in [0, 2].
    """

    backend: str = "offline"
    endpoint: str | None = None
    model: str = "gpt-4o-mini"
    api_key_env: str = "RATOUCH_LLM_API_KEY"
    timeout_s: float = 30.0
    max_attempts: int = 2
    temperature: float = 0.0

    def __post_init__(self) -> None:
        """Validate every field; raise ConfigError naming the field and the bad value."""
        if self.backend not in BACKENDS:
            raise ConfigError(f"RecaptionConfig.backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.endpoint is not None:
            if not is_http_url(self.endpoint):
                raise ConfigError(
                    f"RecaptionConfig.endpoint must be an http(s) URL, got {self.endpoint!r}"
                )
        elif self.backend == "llm":
            raise ConfigError("RecaptionConfig.endpoint is required for backend 'llm', got None")
        check_client_settings("RecaptionConfig", self)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def build_prompt(class_name: str, caption: str) -> str:
    """Fill the paper's recaptioning prompt with a class name and a visual description."""
    return PAPER_PROMPT.format(class_name=class_name.strip(), caption=caption.strip())


class CaptionRejected(DataError):
    """A tactile caption broke the recaptioning rules.

    Attributes:
        reason: Why the caption was rejected.
        text: The caption as received.
    """

    def __init__(self, reason: str, text: str = "") -> None:
        super().__init__(f"caption rejected: {reason} (caption: {text!r})")
        self.reason = reason
        self.text = text


def validate_caption(text: str) -> list[str]:
    """Check a caption of exactly 5 comma-separated tactile adjectives.

    Args:
        text: Caption such as ``"Soft, plush, fibrous, pliable, cushioned."``.

    Returns:
        The 5 adjectives, lower-cased.

    Raises:
        CaptionRejected: Wrong count, a multi-word or non-alphabetic item, a duplicate,
            or a banned (colour, visual, shape, temperature, weight, sound) word.
    """
    if not isinstance(text, str):
        raise CaptionRejected(f"expected a string, got {type(text).__name__}", repr(text))
    cleaned = text.strip().strip(_QUOTES).strip()
    cleaned = cleaned.rstrip(".").strip().strip(_QUOTES).strip()
    items = [item.strip().strip(_QUOTES).strip().lower() for item in cleaned.split(",")]
    if len(items) != N_ADJECTIVES:
        raise CaptionRejected(
            f"expected exactly {N_ADJECTIVES} comma-separated adjectives, got {len(items)}", text
        )
    seen: set[str] = set()
    for item in items:
        if not item:
            raise CaptionRejected("empty item", text)
        if not _WORD_RE.match(item):
            raise CaptionRejected(f"{item!r} is not a single word", text)
        if item in seen:
            raise CaptionRejected(f"{item!r} appears twice", text)
        category = banned_category(item)
        if category is not None:
            raise CaptionRejected(f"{item!r} is a {category} word", text)
        seen.add(item)
    return items


class OfflineRecaptioner:
    """Deterministic lexicon-based recaptioner (no network, no model).

    Args:
        lexicon: Extra entries mapping a word or two-word phrase to weights over tactile
            adjectives; merged over (and overriding) the built-in lexicon.

    Raises:
        ConfigError: If an entry targets a non-tactile or banned word or has a bad weight.
    """

    def __init__(self, lexicon: Mapping[str, Mapping[str, float]] | None = None) -> None:
        user = {k.strip().lower() if isinstance(k, str) else k: v for k, v in (lexicon or {}).items()}
        _check_lexicon(user, "lexicon")
        merged = dict(_BUILTIN_LEXICON)
        merged.update({k: MappingProxyType(dict(v)) for k, v in user.items()})
        self._lexicon: Mapping[str, Mapping[str, float]] = MappingProxyType(merged)

    def _lookup(self, key: str) -> Mapping[str, float] | None:
        """Weights of a word/phrase, trying simple singular forms of its last word."""
        head, _, last = key.rpartition(" ")
        candidates = [last]
        if last.endswith("ies"):
            candidates.append(last[:-3] + "y")
        if last.endswith("es"):
            candidates.append(last[:-2])
        if last.endswith("s"):
            candidates.append(last[:-1])
        for cand in candidates:
            weights = self._lexicon.get(f"{head} {cand}" if head else cand)
            if weights is not None:
                return weights
        if not head and key in TACTILE_WORDS:
            return {key: 1.0}  # a tactile adjective in the text counts for itself
        return None

    def _score_text(self, text: str, scale: float, scores: dict[str, float]) -> None:
        tokens = _TOKEN_RE.findall(text.lower())
        i = 0
        while i < len(tokens):
            weights = self._lookup(f"{tokens[i]} {tokens[i + 1]}") if i + 1 < len(tokens) else None
            step = 2 if weights is not None else 1  # a phrase match replaces its single words
            if weights is None:
                weights = self._lookup(tokens[i])
            for word, weight in (weights or {}).items():
                scores[word] = scores.get(word, 0.0) + scale * weight
            i += step

    def recaption(self, class_name: str, description: str) -> list[str]:
        """Return the 5 best-scoring tactile adjectives for an object.

        Args:
            class_name: Object class, e.g. ``"teddy bear"``.
            description: Visual description, e.g. ``"a brown fur toy"``.

        Returns:
            Exactly 5 distinct adjectives; ties follow TVL frequency order, then the extras,
            and missing slots are filled from `BACKOFF_ADJECTIVES`.
        """
        if not isinstance(class_name, str) or not isinstance(description, str):
            raise DataError(
                f"class name and description must be strings, got {class_name!r}, {description!r}"
            )
        scores: dict[str, float] = {}
        self._score_text(class_name, CLASS_NAME_WEIGHT, scores)
        self._score_text(description, DESCRIPTION_WEIGHT, scores)
        positive = [w for w, s in scores.items() if s > 0]
        ranked = sorted(positive, key=lambda w: (-round(scores[w], 9), _RANK[w]))
        chosen = ranked[:N_ADJECTIVES]
        for word in BACKOFF_ADJECTIVES:
            if len(chosen) == N_ADJECTIVES:
                break
            if word not in chosen:
                chosen.append(word)
        return chosen

    def recaption_many(self, items: Sequence[tuple[str, str]]) -> list[list[str]]:
        """Recaption (class name, description) pairs in order."""
        return [self.recaption(class_name, description) for class_name, description in items]


class Recaptioner(Protocol):
    """What gives an object's tactile adjectives from its class name and description."""

    def recaption(self, class_name: str, description: str) -> list[str]: ...


class LLMRecaptioner:
    """Recaptioner that asks an OpenAI-compatible chat-completions endpoint the paper's prompt.

    Each caption gets up to ``config.max_attempts`` requests; transport errors, malformed
    replies and captions failing `validate_caption` are retried, then the offline fallback
    answers. Thread-safe; counters: ``n_requests``, ``n_rejected``, ``n_errors``, ``n_fallbacks``.

    Args:
        config: Recaptioning settings (endpoint, model, timeout, attempts, temperature).
        fallback: Recaptioner used when every attempt fails.
    """

    def __init__(self, config: RecaptionConfig, fallback: Recaptioner) -> None:
        if config.endpoint is None:
            raise ConfigError("RecaptionConfig.endpoint is required for LLMRecaptioner, got None")
        self.config = config
        self.fallback = fallback
        self.url = chat_url(config.endpoint)
        self.n_requests = 0
        self.n_rejected = 0
        self.n_errors = 0
        self.n_fallbacks = 0
        self._lock = threading.Lock()

    def _count(self, name: str) -> None:
        with self._lock:
            setattr(self, name, getattr(self, name) + 1)

    def _request(self, prompt: str) -> str:
        """POST one chat-completions request and return the reply text."""
        self._count("n_requests")
        return chat_completion(
            self.url, self.config.model, prompt, api_key_env=self.config.api_key_env,
            timeout_s=self.config.timeout_s, temperature=self.config.temperature,
        )

    def recaption(self, class_name: str, description: str) -> list[str]:
        """Return 5 validated tactile adjectives from the LLM, or the fallback's.

        Args:
            class_name: Object class name.
            description: Visual description of the image.

        Returns:
            Exactly 5 adjectives that pass `validate_caption`.
        """
        prompt = build_prompt(class_name, description)
        for attempt in range(1, self.config.max_attempts + 1):
            try:
                return validate_caption(self._request(prompt))
            except CaptionRejected as exc:
                self._count("n_rejected")
                logger.warning("attempt %d for %r: %s", attempt, class_name, exc.reason)
            except REQUEST_ERRORS as exc:
                self._count("n_errors")
                logger.warning(
                    "attempt %d for %r failed: %s: %s", attempt, class_name, type(exc).__name__, exc
                )
        self._count("n_fallbacks")
        logger.warning("falling back to the offline recaptioner for %r", class_name)
        return self.fallback.recaption(class_name, description)

    def recaption_many(self, items: Sequence[tuple[str, str]], max_workers: int = 4) -> list[list[str]]:
        """Recaption pairs concurrently with a small thread pool, keeping input order."""
        if not _is_int(max_workers) or max_workers < 1:
            raise ConfigError(f"max_workers must be an integer >= 1, got {max_workers!r}")
        if not items:
            return []
        with ThreadPoolExecutor(max_workers=min(max_workers, len(items))) as pool:
            return list(pool.map(lambda item: self.recaption(item[0], item[1]), items))

    def stats(self) -> dict[str, int]:
        """Return the request, rejection, error and fallback counters."""
        with self._lock:
            return {
                "n_requests": self.n_requests,
                "n_rejected": self.n_rejected,
                "n_errors": self.n_errors,
                "n_fallbacks": self.n_fallbacks,
            }


def create_recaptioner(
    config: RecaptionConfig, lexicon: Mapping[str, Mapping[str, float]] | None = None,
    progress: bool = False,
) -> OfflineRecaptioner | LLMRecaptioner | SmolLM2Recaptioner:
    """Build the recaptioner `config.backend` names; the LLM one falls back to an offline one.
    The SmolLM2 one loads its model here (from the cache after the first time)."""
    offline = OfflineRecaptioner(lexicon)
    if config.backend == "llm":
        return LLMRecaptioner(config, offline)
    if config.backend == "smollm2":
        # imported here: it imports this module, and torch and transformers with it
        from ratouch.corpus.smollm import SmolLM2Recaptioner

        return SmolLM2Recaptioner(progress=progress)
    return offline

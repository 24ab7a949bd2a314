"""The tactile vocabulary and the word lists that keep captions tactile.

`TVL_ADJECTIVES` is the label vocabulary of the real TVL benchmark (the adjectives annotators
used for its 402 test samples, most frequent first); the world's tactile profiles and the offline
recaptioner speak it. The banned lists implement rule 3 of the paper's recaptioning prompt
(no visual appearance, shape, colour, temperature, sound or weight words). Words that TVL
annotators themselves use for touch (glossy, matte, metallic, patterned, flat, curved) stay
allowed, so ImageNet-T captions and TVL labels share one vocabulary.
"""

from __future__ import annotations

import re

# Frequency order of the TVL test labels (derived once from the published result files).
#: The TVL benchmark's question, asked of every test pair (the paper's prompt to the LLM).
TVL_QUESTION = "This image gives tactile feelings of?"

TVL_ADJECTIVES: tuple[str, ...] = (
    "uneven", "hard", "textured", "smooth", "glossy", "firm", "rigid", "lined", "soft",
    "pliable", "ridged", "coarse", "metallic", "fibrous", "bumpy", "woven", "flat",
    "patterned", "matte", "grainy", "fabric", "deformable", "extruded", "plush", "sleek",
    "dented", "solid", "sewn", "plastic", "polished", "curved", "rough", "stiff", "splotchy",
    "pointed", "indented", "flexible", "slippery", "grooved", "abrasive", "cushioned", "mesh",
    "thick", "elastic", "slick", "dotted", "sharp", "flimsy", "wrinkly", "perforated",
    "gritty", "cloth-like", "embroidered", "wrinkled", "rubbery", "grippy", "dry", "raised",
)

# Extra tactile adjectives the world and the recaptioner may use beyond the TVL labels
# ("more varied and nuanced tactile descriptors", rule 2 of the prompt).
EXTRA_TACTILE: tuple[str, ...] = (
    "fuzzy", "furry", "velvety", "silky", "spongy", "squishy", "springy", "porous", "knitted",
    "ribbed", "crinkled", "pebbled", "leathery", "supple", "waxy", "powdery", "sandy", "loose",
    "compressible", "dense", "brittle", "bristly", "scratchy", "nubby", "cottony", "stretchy",
    "tacky", "hairy", "waffled", "corrugated", "quilted", "padded", "fluffy", "downy", "lumpy",
    "rugged", "craggy", "glassy", "satiny", "papery", "fine-grained", "sturdy", "yielding",
)

TACTILE_WORDS: frozenset[str] = frozenset(TVL_ADJECTIVES) | frozenset(EXTRA_TACTILE)

COLOUR_WORDS: frozenset[str] = frozenset({
    "red", "green", "blue", "yellow", "orange", "purple", "violet", "pink", "brown", "black",
    "white", "grey", "gray", "beige", "tan", "golden", "gold", "silver", "silvery", "cyan",
    "magenta", "turquoise", "teal", "navy", "maroon", "crimson", "ivory", "cream", "khaki",
    "olive", "lavender", "colorful", "colourful", "multicolored", "multicoloured", "pastel",
    "bronze", "copper", "amber", "scarlet", "azure", "emerald",
})
VISUAL_WORDS: frozenset[str] = frozenset({
    "shiny", "bright", "dark", "dim", "transparent", "translucent", "opaque", "reflective",
    "sparkly", "sparkling", "glittery", "glowing", "luminous", "vivid", "pale", "faded",
    "beautiful", "pretty", "ugly", "elegant", "clear", "cloudy", "glowy", "iridescent",
    "vibrant", "dull", "spotted", "striped", "checkered", "plaid", "floral",
})
SHAPE_WORDS: frozenset[str] = frozenset({
    "round", "circular", "square", "rectangular", "triangular", "spherical", "cylindrical",
    "oval", "tall", "wide", "long", "short", "large", "small", "big", "tiny", "huge",
    "narrow", "conical", "cubic", "oblong", "angular",
})
TEMPERATURE_WORDS: frozenset[str] = frozenset({
    "warm", "cold", "cool", "hot", "chilly", "icy", "frozen", "lukewarm", "tepid", "freezing",
})
WEIGHT_WORDS: frozenset[str] = frozenset({
    "heavy", "light", "lightweight", "weighty", "hefty", "featherlight", "massive", "weightless",
})
SOUND_WORDS: frozenset[str] = frozenset({
    "loud", "quiet", "noisy", "squeaky", "crunchy", "rustling", "silent", "creaky", "crinkly",
    "clinking", "jingly", "rattly", "muffled", "squeaking", "buzzing",
})

BANNED_WORDS: dict[str, frozenset[str]] = {
    "colour": COLOUR_WORDS,
    "visual": VISUAL_WORDS,
    "shape": SHAPE_WORDS,
    "temperature": TEMPERATURE_WORDS,
    "weight": WEIGHT_WORDS,
    "sound": SOUND_WORDS,
}


_MODIFIERS = frozenset({
    "slightly", "very", "somewhat", "quite", "a", "bit", "little", "mostly", "rather", "fairly",
    "and", "or", "the", "but", "with", "also", "extremely", "highly", "relatively",
})
_STRIP = " \t.!?\"'`()[]*:"


def banned_category(word: str) -> str | None:
    """Return the banned category ("colour", "visual", ...) of a word, or None if allowed."""
    w = word.strip().lower()
    for category, words in BANNED_WORDS.items():
        if w in words:
            return category
    return None


def _split(text: str) -> list[str]:
    cleaned = text.replace("\n", ",").replace(".", "").replace(";", ",").lower()
    return [w.strip() for w in cleaned.split(",") if w.strip()]


def parse_adjectives(text: str | None) -> list[str]:
    """Distinct lower-case adjectives of a caption, in order.

    The one parser of adjective lists, for TVL-style captions ("hard, smooth, flat.") and for
    free answers alike: splits on commas, new lines, ";", "/", "and", "or" and "&", lower-cases,
    strips quotes and punctuation and drops modifiers ("slightly squishy" -> "squishy").
    """
    if not isinstance(text, str):
        return []
    text = re.sub(r"\s+(?:and|or|&)\s+", ", ", text.replace("/", ","), flags=re.I)
    out: list[str] = []
    for chunk in _split(text):
        words = [w.strip(_STRIP) for w in chunk.split()]
        words = [w for w in words if w and w not in _MODIFIERS]
        word = " ".join(words)
        if word and word not in out:
            out.append(word)
    return out


def adjective_f1(label: str, response: str | None) -> float:
    """Plain adjective-set F1 (exact words), the baseline the offline judge is compared with."""
    lab, pred = set(parse_adjectives(label)), set(parse_adjectives(response))
    if not lab or not pred:
        return 0.0
    return 2 * len(lab & pred) / (len(lab) + len(pred))

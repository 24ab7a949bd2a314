"""The offline judge's lexicon: synonym groups, antonym pairs and non-tactile words.

Two different words are similar when they share a synonym group; a predicted word that matches
nothing in the label but belongs to the opposite group of a label word's is an antonym clash.
"""

from __future__ import annotations

from collections.abc import Mapping

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
MATCHED = 0.5  # a predicted word with similarity >= this to a label word is not a clash


def _parse_groups(spec: Mapping[str, str]) -> dict[str, dict[str, float]]:
    members: dict[str, dict[str, float]] = {}
    for group, words in spec.items():
        for item in words.split():
            word, _, weight = item.partition(":")
            members.setdefault(word, {})[group] = float(weight) if weight else 1.0
    return members


MEMBERS = _parse_groups(_GROUPS_SPEC)
OPPOSITE = frozenset(ANTONYM_GROUPS) | frozenset((b, a) for a, b in ANTONYM_GROUPS)
assert {g for pair in ANTONYM_GROUPS for g in pair} <= set(_GROUPS_SPEC)


def similarity(a: str, b: str) -> float:
    """1 for the same word, SYNONYM * w_a * w_b for words sharing a synonym group, else 0."""
    if a == b:
        return 1.0
    ga, gb = MEMBERS.get(a, {}), MEMBERS.get(b, {})
    return max((SYNONYM * ga[g] * gb[g] for g in ga.keys() & gb.keys()), default=0.0)


def antonymy(a: str, b: str) -> float:
    """w_a * w_b when a and b belong to opposite groups (soft / hard, ...), else 0."""
    ga, gb = MEMBERS.get(a, {}), MEMBERS.get(b, {})
    return max((wa * wb for x, wa in ga.items() for y, wb in gb.items() if (x, y) in OPPOSITE),
               default=0.0)

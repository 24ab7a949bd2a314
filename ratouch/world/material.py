"""The world's materials: how each looks, how it feels, and which ones are designed to be confused.

Two kinds of designed ambiguity carry the paper's premise:

* look-alike groups (`look_group`): members share one visual generator, palette and gloss, so
  an image cannot tell them apart, while their touch height-maps and compliance differ;
* feel-alike groups (`feel_group`): members share one touch generator and compliance, so a
  tactile frame cannot tell them apart, while they look different.

Tactile profiles are weights over the TVL label vocabulary (`ratouch.vocabulary`).
"""

from __future__ import annotations

from dataclasses import dataclass

from ratouch.errors import ConfigError
from ratouch.vocabulary import TACTILE_WORDS
from ratouch.world.texture import PatternSpec

# Named colours (linear-ish RGB in [0, 1]); names are what appearance captions say.
COLOURS: dict[str, tuple[float, float, float]] = {
    "white": (0.90, 0.90, 0.88), "black": (0.10, 0.10, 0.11), "grey": (0.50, 0.50, 0.52),
    "red": (0.75, 0.15, 0.14), "blue": (0.18, 0.32, 0.72), "green": (0.20, 0.55, 0.28),
    "yellow": (0.92, 0.80, 0.20), "orange": (0.90, 0.48, 0.12), "pink": (0.92, 0.60, 0.68),
    "teal": (0.15, 0.55, 0.55), "navy": (0.12, 0.16, 0.40), "cream": (0.92, 0.86, 0.72),
    "beige": (0.80, 0.72, 0.58), "tan": (0.74, 0.58, 0.40), "brown": (0.48, 0.30, 0.16),
    "dark brown": (0.28, 0.17, 0.09), "honey": (0.78, 0.55, 0.25), "olive": (0.45, 0.45, 0.22),
    "purple": (0.45, 0.25, 0.58), "silver": (0.72, 0.73, 0.75), "sand": (0.86, 0.76, 0.55),
    "maroon": (0.45, 0.10, 0.14), "charcoal": (0.25, 0.25, 0.27), "pale blue": (0.62, 0.76, 0.88),
    "rust": (0.60, 0.28, 0.15), "mint": (0.62, 0.86, 0.72), "lilac": (0.74, 0.64, 0.84),
}


@dataclass(frozen=True)
class Look:
    """How a material appears: shared verbatim by the members of a look-alike group."""

    word: str  # what an appearance-only caption calls it ("glossy", "wooden", "suede")
    pattern: PatternSpec
    palette: tuple[str, ...]
    contrast: float = 0.5  # texture modulation depth
    gloss: float = 0.0  # specular strength, 0..1
    two_tone: bool = False  # texture mixes a dark and a light shade of the colour


@dataclass(frozen=True)
class Feel:
    """How a material feels: shared verbatim by the members of a feel-alike group."""

    pattern: PatternSpec
    relief: float  # micro-geometry amplitude pressed into the gel, 0..1
    compliance: float  # 0 rigid .. 1 very soft: contact area and how much texture survives


@dataclass(frozen=True)
class Material:
    name: str
    look: Look
    feel: Feel
    profile: tuple[tuple[str, float], ...]  # tactile adjective weights
    look_group: str | None = None
    feel_group: str | None = None

    def __post_init__(self) -> None:
        for word, w in self.profile:
            if word not in TACTILE_WORDS:
                raise ConfigError(f"Material {self.name!r}: profile word {word!r} is not tactile")
            if w <= 0:
                raise ConfigError(f"Material {self.name!r}: weight of {word!r} must be > 0")
        for c in self.look.palette:
            if c not in COLOURS:
                raise ConfigError(f"Material {self.name!r}: unknown colour {c!r}")

    @property
    def compliance(self) -> float:
        return self.feel.compliance

    @property
    def gloss(self) -> float:
        return self.look.gloss


def _profile(text: str) -> tuple[tuple[str, float], ...]:
    out = []
    for item in text.split():
        word, weight = item.rsplit(":", 1)
        out.append((word, float(weight)))
    return tuple(out)


P = PatternSpec

# --- shared looks (look-alike groups) -----------------------------------------------------
LOOK_GLOSSY = Look("glossy", P("flat", rough=0.25), ("white", "black", "red", "blue", "grey",
                   "green", "pale blue"), contrast=0.15, gloss=0.9)
LOOK_WOOD = Look("wooden", P("grain", period=9, angle=0), ("tan", "brown", "dark brown",
                 "honey"), contrast=0.7, gloss=0.15, two_tone=True)
LOOK_SUEDE = Look("suede", P("fibre", period=3, rough=0.3, params=(("stretch", 3.0),)),
                  ("tan", "brown", "grey", "navy", "olive"), contrast=0.3)
LOOK_LEATHER = Look("leather", P("cells", period=7, rough=0.15), ("black", "brown",
                    "dark brown", "maroon", "tan"), contrast=0.35, gloss=0.35)
LOOK_STONE = Look("speckled stone", P("grit", period=4, rough=0.4), ("grey", "charcoal",
                  "beige", "pink"), contrast=0.8, gloss=0.25, two_tone=True)
LOOK_SAND = Look("sandy", P("grit", period=2.5, rough=0.5), ("sand", "beige", "tan"),
                 contrast=0.45)
LOOK_WEAVE = Look("woven", P("weave", period=5, rough=0.25), ("beige", "cream", "grey",
                  "olive", "white"), contrast=0.55)

# --- shared feels (feel-alike groups) -----------------------------------------------------
FEEL_HARD_SMOOTH = Feel(P("flat", rough=0.1), relief=0.03, compliance=0.0)
FEEL_FLEECE = Feel(P("fibre", period=3, rough=0.5, params=(("stretch", 1.0),)), relief=0.35,
                   compliance=0.75)
FEEL_KNIT = Feel(P("knit", period=7, rough=0.3), relief=0.6, compliance=0.6)
FEEL_RUBBER = Feel(P("noise", period=14, rough=0.2, params=(("beta", 2.5),)), relief=0.12,
                   compliance=0.55)
FEEL_RIDGED = Feel(P("ribs", period=6, rough=0.2, params=(("sharp", 0.8),)), relief=0.4,
                   compliance=0.15)
FEEL_COARSE = Feel(P("fibre", period=3, rough=0.9, params=(("stretch", 3.0),)), relief=0.85,
                   compliance=0.2)
FEEL_FOAM = Feel(P("pores", period=5, rough=0.3, params=(("hole", 0.4),)), relief=0.5,
                 compliance=0.85)

M = Material
MATERIALS: tuple[Material, ...] = (
    # glossy look-alikes: plastic, ceramic, glass, metal
    M("glossy_plastic", LOOK_GLOSSY, Feel(P("noise", period=20, rough=0.2), 0.15, 0.3),
      _profile("smooth:3 plastic:2 glossy:2 firm:1.5 sleek:1 slick:1 flexible:0.5"), "glossy"),
    M("glazed_ceramic", LOOK_GLOSSY, Feel(P("cells", period=4, rough=0.4), 0.25, 0.0),
      _profile("hard:3 smooth:2 glossy:2 solid:1.5 rigid:1.5 uneven:0.5 polished:1"), "glossy"),
    M("glass", LOOK_GLOSSY, FEEL_HARD_SMOOTH,
      _profile("smooth:3 hard:3 glossy:2 slippery:1.5 rigid:1.5 sleek:1 glassy:1"), "glossy",
      "hard_smooth"),
    M("polished_metal", LOOK_GLOSSY, Feel(P("brushed", rough=0.1, params=(("stretch", 40.0),)),
      0.12, 0.0), _profile("metallic:3 hard:3 smooth:2 polished:2 rigid:1 sleek:1 lined:0.5"),
      "glossy"),
    # wood look-alikes
    M("oak", LOOK_WOOD, Feel(P("grain", period=9, rough=0.3), 0.6, 0.02),
      _profile("hard:3 grainy:2 lined:2 textured:1.5 solid:1.5 rigid:1 ridged:1 dry:0.5"),
      "wood"),
    M("wood_vinyl", LOOK_WOOD, Feel(P("noise", period=16, rough=0.1, params=(("beta", 3.0),)),
      0.05, 0.25), _profile("smooth:3 flat:2 plastic:2 sleek:1 firm:1.5 slick:1"), "wood"),
    # suede look-alikes
    M("suede", LOOK_SUEDE, Feel(P("fibre", period=1.5, rough=0.2, params=(("stretch", 10.0),)),
      0.3, 0.45), _profile("soft:3 velvety:2 fibrous:1.5 pliable:2 matte:1 textured:1"), "suede"),
    M("faux_suede", LOOK_SUEDE, Feel(P("weave", period=3, rough=0.1), 0.15, 0.3),
      _profile("smooth:2.5 soft:1.5 woven:1.5 fabric:2 flexible:1.5"), "suede"),
    # leather look-alikes
    M("leather", LOOK_LEATHER, Feel(P("cells", period=7, rough=0.2), 0.45, 0.4),
      _profile("smooth:2 pliable:2.5 leathery:2 supple:1.5 textured:1 soft:1 grainy:1"),
      "leather"),
    M("faux_leather", LOOK_LEATHER, Feel(P("studs", period=6, rough=0.1,
      params=(("stagger", 1.0), ("radius", 0.42))), 0.3, 0.15),
      _profile("smooth:2 plastic:2 stiff:2 slick:1.5 patterned:1 firm:1 dotted:0.5"), "leather"),
    # stone look-alikes
    M("granite", LOOK_STONE, Feel(P("grit", period=4, rough=0.6), 0.7, 0.0),
      _profile("hard:3 rough:2 uneven:2 grainy:2 solid:1.5 coarse:1 rigid:1"), "stone"),
    M("stone_laminate", LOOK_STONE, FEEL_HARD_SMOOTH,
      _profile("smooth:3 hard:3 flat:2 sleek:1 rigid:1.5 polished:1 slippery:1"), "stone",
      "hard_smooth"),
    # sand look-alikes
    M("sand", LOOK_SAND, Feel(P("grit", period=3, rough=0.3), 0.5, 0.85),
      _profile("grainy:3 gritty:2 deformable:2.5 loose:2 soft:1 sandy:1.5 uneven:1"), "sand"),
    M("sandpaper", LOOK_SAND, Feel(P("grit", period=2, rough=0.7), 0.8, 0.02),
      _profile("abrasive:3 rough:3 gritty:2 coarse:2 hard:1 grainy:1 scratchy:1"), "sand"),
    # weave look-alikes
    M("linen", LOOK_WEAVE, Feel(P("weave", period=5, rough=0.3), 0.4, 0.45),
      _profile("woven:3 fabric:2.5 soft:2 pliable:2 textured:1 cloth-like:1 flexible:1"),
      "weave"),
    M("woven_placemat", LOOK_WEAVE, Feel(P("weave", period=5, rough=0.1, params=(("group", 2.0),)),
      0.75, 0.05), _profile("ridged:2.5 woven:2 stiff:2 rigid:1.5 hard:1.5 grooved:1 plastic:1"),
      "weave"),
    # feel-alike: hard & smooth (glass and stone laminate above), polished marble
    M("polished_marble", Look("marble", P("veins", period=10), ("white", "grey", "cream"),
      contrast=0.5, gloss=0.6), FEEL_HARD_SMOOTH,
      _profile("smooth:3 hard:3 polished:2 solid:1.5 sleek:1 rigid:1"), None, "hard_smooth"),
    # feel-alike: fleece-soft
    M("fleece", Look("fleece", P("loops", period=3, rough=0.3), ("red", "blue", "grey", "green",
      "pink"), contrast=0.3), FEEL_FLEECE,
      _profile("soft:3 plush:2 fuzzy:2 fibrous:1 cushioned:1 pliable:1.5 fluffy:1"), None,
      "fleece"),
    M("felt", Look("felt", P("noise", period=6, rough=0.2, params=(("beta", 2.5),)), ("red",
      "green", "grey", "yellow", "purple"), contrast=0.15), FEEL_FLEECE,
      _profile("soft:3 fuzzy:2 fibrous:1.5 plush:1 dense:1 pliable:1.5 matte:1"), None, "fleece"),
    M("velvet", Look("velvet", P("fibre", period=4, rough=0.2, params=(("stretch", 2.0),)),
      ("maroon", "navy", "green", "purple"), contrast=0.35, gloss=0.3), FEEL_FLEECE,
      _profile("soft:3 plush:2 velvety:2 smooth:1 fabric:1 pliable:1.5 fuzzy:1"), None, "fleece"),
    # feel-alike: knit loops
    M("wool_knit", Look("knitted", P("knit", period=7, rough=0.25), ("red", "cream", "grey",
      "navy", "green", "charcoal"), contrast=0.6), FEEL_KNIT,
      _profile("soft:3 knitted:2 woven:1.5 stretchy:1.5 textured:1.5 fibrous:1 bumpy:1"), None,
      "knit"),
    M("terry_cloth", Look("towel", P("loops", period=2.5, rough=0.4), ("white", "pale blue",
      "pink", "yellow", "mint"), contrast=0.35), FEEL_KNIT,
      _profile("soft:3 textured:2 fabric:2 bumpy:1 plush:1.5 fibrous:1"), None, "knit"),
    # feel-alike: rubbery
    M("rubber", Look("rubber", P("noise", period=3, rough=0.3, params=(("beta", 1.0),)),
      ("black", "charcoal", "grey"), contrast=0.12, gloss=0.1), FEEL_RUBBER,
      _profile("rubbery:3 grippy:2 elastic:2 pliable:1.5 smooth:1 firm:1 deformable:1"), None,
      "rubbery"),
    M("silicone", Look("silicone", P("flat", rough=0.3), ("pink", "teal", "mint", "lilac",
      "white"), contrast=0.1, gloss=0.5), FEEL_RUBBER,
      _profile("rubbery:3 soft:2 elastic:2 flexible:1.5 smooth:1.5 grippy:1 squishy:1"), None,
      "rubbery"),
    # feel-alike: ridged
    M("corrugated_cardboard", Look("cardboard", P("noise", period=5, rough=0.3,
      params=(("beta", 1.5),)), ("tan", "brown", "beige"), contrast=0.2), FEEL_RIDGED,
      _profile("ridged:3 stiff:2 lined:2 corrugated:1.5 dry:1 firm:1 papery:1"), None, "ridged"),
    M("ribbed_plastic", Look("ribbed plastic", P("ribs", period=3, rough=0.1), ("blue", "red",
      "green", "white", "yellow"), contrast=0.25, gloss=0.3), FEEL_RIDGED,
      _profile("ridged:3 hard:2 lined:2 plastic:1.5 grooved:1.5 firm:1 rigid:1"), None, "ridged"),
    # feel-alike: coarse fibre
    M("burlap", Look("burlap", P("weave", period=4, rough=0.6), ("tan", "beige", "brown"),
      contrast=0.6), FEEL_COARSE,
      _profile("coarse:3 rough:2 woven:2 fibrous:2 scratchy:1.5 stiff:1 uneven:1"), None,
      "coarse"),
    M("coir", Look("bristly", P("fibre", period=4, rough=0.5, params=(("stretch", 8.0),)),
      ("brown", "tan", "dark brown"), contrast=0.7), FEEL_COARSE,
      _profile("coarse:3 bristly:2 rough:2 fibrous:2 stiff:1.5 scratchy:1"), None, "coarse"),
    # feel-alike: spongy foam
    M("sponge", Look("porous", P("pores", period=5, rough=0.2, params=(("hole", 0.4),)),
      ("yellow", "green", "orange", "pink"), contrast=0.55), FEEL_FOAM,
      _profile("spongy:3 soft:2 porous:2 squishy:2 deformable:1.5 compressible:1 cushioned:1"),
      None, "foam"),
    M("memory_foam", Look("foam", P("noise", period=8, rough=0.1, params=(("beta", 2.8),)),
      ("white", "grey", "cream", "pale blue"), contrast=0.08), FEEL_FOAM,
      _profile("soft:3 cushioned:2 deformable:2 spongy:1.5 squishy:1.5 plush:1 porous:1"), None,
      "foam"),
    # distinct materials
    M("denim", Look("denim", P("weave", period=3, rough=0.3, params=(("shift", 1.0),)),
      ("blue", "navy", "pale blue", "charcoal"), contrast=0.5),
      Feel(P("weave", period=3, rough=0.3, params=(("shift", 1.0),)), 0.35, 0.35),
      _profile("woven:2.5 fabric:2 textured:2 stiff:1 coarse:1 sewn:1 lined:1")),
    M("brushed_aluminum", Look("brushed metal", P("brushed", rough=0.3,
      params=(("stretch", 25.0),)), ("silver", "grey"), contrast=0.35, gloss=0.5),
      Feel(P("brushed", rough=0.3, params=(("stretch", 25.0),)), 0.45, 0.0),
      _profile("metallic:3 hard:2.5 lined:2 smooth:1 rigid:1.5 grooved:1 solid:1")),
    M("concrete", Look("concrete", P("pores", period=6, rough=0.7, params=(("hole", 0.2),)),
      ("grey", "beige", "charcoal"), contrast=0.4),
      Feel(P("pores", period=6, rough=0.7, params=(("hole", 0.2),)), 0.6, 0.0),
      _profile("hard:3 rough:2.5 uneven:2 gritty:1.5 solid:1.5 dented:1 coarse:1")),
    M("brick", Look("brick", P("noise", period=5, rough=0.5, params=(("beta", 1.3),)),
      ("red", "rust", "brown"), contrast=0.4),
      Feel(P("noise", period=6, rough=0.6, params=(("beta", 1.5),)), 0.7, 0.0),
      _profile("hard:3 rough:2.5 coarse:2 solid:2 uneven:1.5 abrasive:1 dry:1")),
    M("tree_bark", Look("bark", P("bark", period=6, angle=90), ("brown", "dark brown", "grey"),
      contrast=0.8, two_tone=True), Feel(P("bark", period=6, angle=90), 0.9, 0.05),
      _profile("rough:3 uneven:2.5 ridged:2 coarse:2 hard:1.5 craggy:1 grooved:1")),
    M("paper", Look("paper", P("noise", period=3, rough=0.2, params=(("beta", 1.0),)),
      ("white", "cream", "beige"), contrast=0.06),
      Feel(P("noise", period=4, rough=0.2, params=(("beta", 1.0),)), 0.08, 0.2),
      _profile("smooth:2 flat:2 papery:2 flimsy:1.5 dry:1.5 flexible:1")),
    M("wicker", Look("wicker", P("weave", period=8, rough=0.3, params=(("group", 2.0),)),
      ("tan", "honey", "brown"), contrast=0.7),
      Feel(P("weave", period=8, rough=0.3, params=(("group", 2.0),)), 0.9, 0.1),
      _profile("woven:3 ridged:2 stiff:2 rough:1.5 bumpy:1.5 lined:1 uneven:1")),
    M("fur", Look("furry", P("fibre", period=6, rough=0.3, params=(("stretch", 4.0),)),
      ("brown", "grey", "white", "orange", "black", "cream"), contrast=0.6, two_tone=True),
      Feel(P("fibre", period=5, rough=0.4, params=(("stretch", 2.0),)), 0.45, 0.9),
      _profile("soft:3 furry:2.5 fluffy:2 plush:2 hairy:1 fibrous:1 silky:1")),
    M("mesh_fabric", Look("mesh", P("mesh", period=5, params=(("hole", 0.5),)), ("black",
      "white", "blue", "red", "grey"), contrast=0.7),
      Feel(P("mesh", period=5, params=(("hole", 0.5),)), 0.5, 0.4),
      _profile("mesh:3 perforated:2 flexible:2 textured:1.5 fabric:1.5 stretchy:1 soft:1")),
    M("bubble_wrap", Look("bubbly plastic", P("studs", period=11, params=(("stagger", 1.0),
      ("radius", 0.38))), ("white", "pale blue", "mint"), contrast=0.3, gloss=0.6),
      Feel(P("studs", period=11, params=(("stagger", 1.0), ("radius", 0.38))), 0.7, 0.6),
      _profile("bumpy:3 squishy:2 plastic:2 smooth:1 deformable:1.5 raised:1 dotted:1")),
    M("plastic_studs", Look("studded plastic", P("studs", period=13, params=(("radius", 0.3),)),
      ("red", "yellow", "blue", "green", "white"), contrast=0.45, gloss=0.7),
      Feel(P("studs", period=13, params=(("radius", 0.3),)), 0.85, 0.0),
      _profile("bumpy:3 hard:2.5 plastic:2 raised:1.5 rigid:1.5 smooth:1 dotted:1")),
    M("silk", Look("silky", P("fibre", period=2, rough=0.1, params=(("stretch", 30.0),)),
      ("red", "purple", "cream", "navy", "pink", "teal"), contrast=0.15, gloss=0.6),
      Feel(P("fibre", period=1.5, rough=0.05, params=(("stretch", 30.0),)), 0.05, 0.65),
      _profile("silky:3 smooth:3 slippery:2 soft:2 satiny:1 flexible:1 sleek:1")),
    M("corduroy", Look("corduroy", P("ribs", period=4, rough=0.3, params=(("sharp", 0.4),)),
      ("brown", "olive", "tan", "maroon", "navy"), contrast=0.5),
      Feel(P("ribs", period=4, rough=0.3, params=(("sharp", 0.4),)), 0.6, 0.5),
      _profile("ridged:3 soft:2 lined:2 fabric:1.5 textured:1.5 velvety:1 grooved:1")),
    M("cast_iron", Look("cast iron", P("grit", period=2, rough=0.8), ("black", "charcoal"),
      contrast=0.25, gloss=0.2), Feel(P("noise", period=3, rough=0.8, params=(("beta", 1.2),)),
      0.5, 0.0), _profile("hard:3 metallic:2 rough:2 solid:2 rigid:1.5 gritty:1 dense:1")),
    M("carpet", Look("carpet", P("loops", period=2, rough=0.6), ("beige", "grey", "maroon",
      "navy", "olive"), contrast=0.45), Feel(P("loops", period=3, rough=0.5), 0.6, 0.75),
      _profile("soft:2.5 fibrous:2 plush:2 textured:2 cushioned:1.5 coarse:1 dense:1")),
    M("cotton_jersey", Look("cotton", P("knit", period=2, rough=0.2), ("white", "grey", "black",
      "red", "blue", "yellow"), contrast=0.2), Feel(P("knit", period=2.5, rough=0.2), 0.25, 0.55),
      _profile("soft:3 stretchy:2 fabric:2 smooth:1.5 flexible:1.5 cottony:1 cloth-like:1")),
    M("matte_plastic", Look("plastic", P("noise", period=10, rough=0.1, params=(("beta", 3.0),)),
      ("black", "white", "grey", "blue", "red", "yellow"), contrast=0.08, gloss=0.15),
      Feel(P("noise", period=10, rough=0.2, params=(("beta", 2.0),)), 0.1, 0.1),
      _profile("hard:2.5 plastic:2.5 smooth:2 matte:1.5 rigid:1.5 firm:1 solid:1")),
)

MATERIAL_INDEX: dict[str, int] = {m.name: i for i, m in enumerate(MATERIALS)}


def material(name: str) -> Material:
    """Look a material up by name, with the valid names in the error."""
    try:
        return MATERIALS[MATERIAL_INDEX[name]]
    except KeyError as e:
        raise ConfigError(f"unknown material {name!r}; known: {sorted(MATERIAL_INDEX)}") from e


def groups(kind: str) -> dict[str, list[str]]:
    """Members of each look-alike (kind="look") or feel-alike (kind="feel") group."""
    if kind not in ("look", "feel"):
        raise ConfigError(f"kind={kind!r} must be 'look' or 'feel'")
    out: dict[str, list[str]] = {}
    for m in MATERIALS:
        g = m.look_group if kind == "look" else m.feel_group
        if g is not None:
            out.setdefault(g, []).append(m.name)
    return out

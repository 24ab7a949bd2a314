"""Captions of the world: TVL-style tactile labels for pairs, appearance-only descriptions
(like a BLIP-2 caption: what can be seen, never how it feels) for corpus entries."""

from __future__ import annotations

import numpy as np

from ratouch.world.material import Material, material

# Label lengths as in the TVL test labels (2-5 adjectives; 3 and 4 dominate).
LABEL_LENGTHS = (2, 3, 4, 5)
LABEL_LENGTH_P = (0.14, 0.44, 0.38, 0.04)

_TEMPLATES = (
    "a {colour} {look} {cls} on a {bg} surface",
    "a photo of a {colour} {look} {cls} sitting on a {bg} surface",
    "a {colour} {cls} made of {look} material on a {bg} background",
    "a close up of a {colour} {look} {cls}",
)
_CLOSEUP = (
    "a close-up of a {colour} {look} surface",
    "a {colour} {look} texture filling the frame",
)


def tactile_label(rng: np.random.Generator, mat: Material) -> list[str]:
    """Draw a 2-5 adjective label from the material's tactile profile."""
    n = int(rng.choice(LABEL_LENGTHS, p=LABEL_LENGTH_P))
    words = [w for w, _ in mat.profile]
    weights = np.array([w for _, w in mat.profile]) ** 1.5
    idx = rng.choice(len(words), size=min(n, len(words)), replace=False, p=weights / weights.sum())
    return [words[i] for i in idx]


def visual_description(rng: np.random.Generator, class_name: str, mat_name: str, colour: str,
                       bg_name: str | None) -> str:
    """Appearance-only caption: colour, how the material looks, the class, the background."""
    look = material(mat_name).look.word
    if not class_name:
        template = _CLOSEUP[rng.integers(len(_CLOSEUP))]
        return _articles(template.format(colour=colour, look=look))
    template = _TEMPLATES[rng.integers(len(_TEMPLATES))]
    bg = material(bg_name).look.word if bg_name else "plain"
    return _articles(template.format(colour=colour, look=look, cls=class_name, bg=bg))


def _articles(text: str) -> str:
    """Use "an" before a vowel sound ("an olive ...")."""
    words = text.split(" ")
    for i in range(len(words) - 1):
        if words[i] == "a" and words[i + 1][:1].lower() in "aeiou":
            words[i] = "an"
    return " ".join(words)

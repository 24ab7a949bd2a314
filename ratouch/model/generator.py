"""The two describing systems: TVL-LLaMA's baseline and RA-Touch, as one class.

TVL-LLaMA (paper §3, first paragraph): the visual and tactile features are summed and passed
through a linear layer to give the visual prompt embedding p, which a LLaMA decoder reads before
the text prompt. RA-Touch (§3.3, eq. 5) adds the Texture-Aware Integrator's output:
p' = p + FFN(Linear(a^V + a^L)). `RATouchGenerator` with ``integrator=None`` is the baseline,
so ablations compare like with like: same prompt layer, same decoder, same decoding.

Training stages (§3.4, §4.2), as `trainable_parameters(gen, stage)`:

* ``baseline`` (TVL-LLaMA): the prompt projection is trained. The paper decodes through a
  frozen pretrained LLaMA-2; the embedded small decoder has no pretraining, so here it is
  trained from scratch together with the projection. A decoder that carries LoRA trains only
  its LoRA weights; an ``hf`` decoder without LoRA stays frozen.
* ``ra`` (RA-Touch): "we freeze [the retriever's] parameters and train the Texture-Aware
  Integrator, while updating LLaMA-2 in a parameter-efficient manner" - the integrator and the
  decoder's LoRA weights are trained; the decoder's base weights are frozen. The paper takes p
  "from TVL-LLaMA's projection layer", i.e. the trained baseline's, so the prompt projection is
  frozen by default; §4.2 calls that layer "learnable", so ``train_prompt=True`` unfreezes it.
  The retriever and the encoders are not part of this module: they are frozen upstream and
  only their outputs (V, T, Rv, Rl) arrive here.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import torch
from torch import Tensor, nn

from ratouch.checkpoint import load_into, read_checkpoint, require_files, save_checkpoint
from ratouch.errors import ConfigError, DataError
from ratouch.model.decoder import (
    Decoder,
    DecoderConfig,
    TactileTokenizer,
    build_decoder,
    clean_description,
    generate_together,
)
from ratouch.model.fastpath import StackCache

logger = logging.getLogger(__name__)

STAGES = ("baseline", "ra")
ADAPTER_DIR = "adapter"
ADAPTER_CONFIG = "adapter_config.json"             # what peft's save_pretrained writes
ADAPTER_WEIGHTS = "adapter_model.safetensors"
TOKENIZER_FILE = "tokenizer.json"
FORMAT = "ratouch-generator/1"


@dataclass
class PromptConfig:
    """TVL-LLaMA's visual prompt projection.

    Attributes:
        dim: D, the width of the frozen encoders' features V and T.
        out_dim: D', the decoder's hidden size.
        n_prefix: prefix vectors the projection produces per sample.
    """

    dim: int = 384
    out_dim: int = 256
    n_prefix: int = 1

    def __post_init__(self) -> None:
        for name in ("dim", "out_dim", "n_prefix"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"PromptConfig.{name} must be a positive integer, "
                                  f"got {value!r}")


class BaselinePrompt(nn.Module):
    """p = Linear(V + T), reshaped into `n_prefix` vectors of width D'."""

    def __init__(self, cfg: PromptConfig):
        super().__init__()
        self.cfg = cfg
        self.proj = nn.Linear(cfg.dim, cfg.out_dim * cfg.n_prefix)

    def forward(self, V: Tensor, T: Tensor) -> Tensor:
        """Args:
            V: (B, D) visual features.
            T: (B, D) tactile features.

        Returns:
            (B, n_prefix, D') prompt embeddings.
        """
        if V.dim() != 2 or V.shape != T.shape or V.shape[1] != self.cfg.dim:
            raise ConfigError(f"V and T must both have shape (B, {self.cfg.dim}), got "
                              f"{tuple(V.shape)} and {tuple(T.shape)}")
        p = self.proj(V + T)                                          # (B, n_prefix * D')
        return p.view(V.shape[0], self.cfg.n_prefix, self.cfg.out_dim)  # (B, n_prefix, D')


class RATouchGenerator(nn.Module):
    """Prompt projection, optional Texture-Aware Integrator and decoder.

    Args:
        prompt: the visual prompt projection (p).
        decoder: the language model; its hidden size must equal the prompt's D'.
        integrator: any module with ``forward(T (B, D), Rv (B, K, D), Rl (B, K, D)) ->
            (B, D')``; None gives the no-retrieval baseline.
    """

    def __init__(self, prompt: BaselinePrompt, decoder: Decoder,
                 integrator: nn.Module | None = None):
        super().__init__()
        if prompt.cfg.out_dim != decoder.hidden:
            raise ConfigError(f"PromptConfig.out_dim ({prompt.cfg.out_dim}) must equal the "
                              f"decoder's hidden size ({decoder.hidden})")
        self.prompt = prompt
        self.decoder = decoder
        self.integrator = integrator

    def prefix(self, V: Tensor, T: Tensor, Rv: Tensor | None = None,
               Rl: Tensor | None = None) -> Tensor:
        """The decoder's prefix: p, or p' = p + delta when an integrator and neighbours are given
        (or [p, neighbour tokens] for an integrator with ``as_tokens``, the second arm).

        Without an integrator the neighbours are ignored (the baseline), so both systems can be
        fed the same batch.

        Args:
            V: (B, D) visual features.
            T: (B, D) tactile features.
            Rv: (B, K, D) retrieved image features, or None.
            Rl: (B, K, D) retrieved text features, or None.

        Returns:
            (B, n_prefix, D') prefix embeddings.
        """
        p = self.prompt(V, T)                                         # (B, n_prefix, D')
        if (Rv is None) != (Rl is None):
            raise ConfigError("Rv and Rl must be given together (or both left out)")
        if self.integrator is None or Rv is None or Rl is None:  # both None, or both given
            return p
        if Rv.dim() != 3 or Rv.shape != Rl.shape or Rv.shape[0] != V.shape[0]:
            raise ConfigError(f"Rv and Rl must both have shape (B={V.shape[0]}, K, D), got "
                              f"{tuple(Rv.shape)} and {tuple(Rl.shape)}")
        delta = self.integrator(T, Rv, Rl)                            # (B, D') or (B, K, D')
        if getattr(self.integrator, "as_tokens", False):  # the neighbour-token arm
            if delta.dim() != 3 or delta.shape[0] != p.shape[0] or delta.shape[2] != p.shape[2]:
                raise ConfigError(f"neighbour tokens must have shape (B, K, D') = "
                                  f"({p.shape[0]}, K, {p.shape[2]}), got {tuple(delta.shape)}")
            return torch.cat([p, delta.to(p.dtype)], dim=1)           # (B, n_prefix + K, D')
        if tuple(delta.shape) != (p.shape[0], p.shape[2]):
            raise ConfigError(f"the integrator must return (B, D') = "
                              f"{(p.shape[0], p.shape[2])}, got {tuple(delta.shape)}")
        return p + delta.unsqueeze(1)                                 # (B, n_prefix, D')

    def loss(self, V: Tensor, T: Tensor, targets: Sequence[str], Rv: Tensor | None = None,
             Rl: Tensor | None = None) -> Tensor:
        """Cross-entropy of the target captions given the (augmented) prompt; a scalar."""
        return self.decoder.forward_loss(self.prefix(V, T, Rv, Rl), targets)

    def describe(self, V: Tensor, T: Tensor, Rv: Tensor | None = None,
                 Rl: Tensor | None = None, max_new_tokens: int | None = None,
                 clean: bool = True) -> list[str]:
        """Greedy tactile descriptions, one per sample.

        Args:
            V, T, Rv, Rl: as in `prefix`.
            max_new_tokens: generation limit; None takes the decoder's default.
            clean: reduce each to at most five unique adjectives (`clean_description`).

        Runs in eval mode and restores the previous mode.
        """
        was_training = self.training
        self.eval()  # no dropout in the prompt, integrator or LoRA while describing
        try:
            with torch.inference_mode():
                p = self.prefix(V, T, Rv, Rl)                         # (B, n_prefix, D')
            texts = self.decoder.generate(p, max_new_tokens)
        finally:
            self.train(was_training)
        return [clean_description(t) for t in texts] if clean else texts


def describe_together(generators: Sequence[RATouchGenerator], prefixes: Sequence[Tensor],
                      max_new_tokens: int | None = None, clean: bool = True,
                      cache: StackCache | None = None) -> list[list[str]]:
    """Descriptions from several generators' prefixes at once (RA-Touch's and the
    baseline's), their decoders decoding together where they can (`generate_together`).

    Args:
        generators: G generators.
        prefixes: per generator, its (B, n_prefix, D') `prefix` output.
        max_new_tokens, clean: as in `describe`.
        cache: keeps the decoders' stacked weights between calls (see `generate_together`).

    Returns:
        Per generator, its B descriptions.
    """
    if len(generators) != len(prefixes):
        raise ConfigError(f"{len(generators)} generators for {len(prefixes)} prefix batches")
    texts = generate_together([g.decoder for g in generators], prefixes, max_new_tokens,
                              cache=cache)
    return [[clean_description(t) for t in ts] if clean else ts for ts in texts]


def trainable_parameters(gen: RATouchGenerator, stage: str,
                         train_prompt: bool = False) -> list[nn.Parameter]:
    """Set `requires_grad` for a training stage and return the trainable parameters.

    Args:
        gen: the generator (its flags are changed in place).
        stage: "baseline" (TVL-LLaMA) or "ra" (RA-Touch); see the module docstring.
        train_prompt: stage "ra" only: also train the prompt projection.

    Returns:
        The parameters to hand to the optimiser, in `gen.named_parameters()` order.
    """
    if stage not in STAGES:
        raise ConfigError(f"stage must be one of {STAGES}, got {stage!r}")
    dec = gen.decoder
    for p in gen.parameters():
        p.requires_grad_(False)
    if stage == "baseline":
        if train_prompt:
            raise ConfigError("train_prompt applies to stage 'ra' only; stage 'baseline' "
                              "always trains the prompt")
        gen.prompt.requires_grad_(True)
        if dec.has_lora:
            _unfreeze_lora(dec)
        elif dec.cfg.kind == "small":
            dec.requires_grad_(True)
    else:
        if gen.integrator is None:
            raise ConfigError("stage 'ra' trains the integrator, but the generator has none")
        if not dec.has_lora:
            raise ConfigError("stage 'ra' trains LoRA on the decoder: call "
                              "decoder.add_lora() first")
        gen.integrator.requires_grad_(True)
        _unfreeze_lora(dec)
        gen.prompt.requires_grad_(train_prompt)
    params = [p for p in gen.parameters() if p.requires_grad]
    logger.info("stage %s: %d trainable tensors, %d parameters", stage, len(params),
                sum(p.numel() for p in params))
    return params


def _unfreeze_lora(dec: Decoder) -> None:
    for name, p in dec.named_parameters():
        if "lora_" in name:
            p.requires_grad_(True)


def save_generator(folder: str | os.PathLike, gen: RATouchGenerator,
                   meta: dict | None = None, half: bool = False) -> Path:
    """Write a generator checkpoint.

    Layout: ``model.safetensors`` + ``config.json`` + ``manifest.json`` (via
    `ratouch.checkpoint.save_checkpoint`) holding the prompt, the integrator and, for a small
    decoder, its base weights; ``tokenizer.json`` for a small decoder; ``adapter/`` with the
    LoRA adapter (peft `save_pretrained`). An ``hf`` decoder's base model is referenced by its
    path in the config, never copied.

    Args:
        folder: destination (created).
        gen: the generator.
        meta: anything worth keeping (training figures, seed, ...), stored in the manifest.
        half: store floating weights as float16 (the shipped assets do; loading casts back).
    """
    folder = Path(folder)
    dec = gen.decoder
    state = {f"prompt.{k}": v for k, v in gen.prompt.state_dict().items()}
    if gen.integrator is not None:
        state.update({f"integrator.{k}": v for k, v in gen.integrator.state_dict().items()})
    if dec.cfg.kind == "small":
        state.update({f"decoder.{k}": v for k, v in dec.base_state_dict().items()})
    icfg = getattr(gen.integrator, "cfg", None)
    config = {
        "format": FORMAT,
        "prompt": asdict(gen.prompt.cfg),
        "decoder": dec.cfg.saved(),
        "integrator": None if gen.integrator is None else
        (asdict(icfg) if dataclasses.is_dataclass(icfg) and not isinstance(icfg, type) else {}),
        "lora": dec.has_lora,
    }

    def extra(staging: Path) -> None:  # checked on load like the weights (the manifest's)
        if dec.has_lora:
            dec.save_adapter(staging / ADAPTER_DIR)
        if isinstance(dec.tokenizer, TactileTokenizer):
            dec.tokenizer.save(staging / TOKENIZER_FILE)

    # published as a whole: a run killed while saving leaves the previous checkpoint
    return save_checkpoint(folder, state, config, meta, half=half, extra=extra)


def load_generator(folder: str | os.PathLike,
                   integrator_factory: Callable[[dict], nn.Module] | None = None,
                   stage1: bool = False) -> RATouchGenerator:
    """Read a checkpoint written by `save_generator`.

    Args:
        folder: the checkpoint folder.
        integrator_factory: builds an untrained integrator from its saved config dict (empty
            when the integrator had no dataclass ``cfg``); required when the checkpoint holds
            an integrator.
        stage1: return only what stage 1 trained (the prompt projection and the decoder's base
            weights; no LoRA adapter, no integrator): the common starting point of stage-2
            variants (ablations).

    Returns:
        The generator in eval mode with all parameters frozen (call `trainable_parameters` to
        continue training).
    """
    folder = Path(folder)
    state, config, manifest = read_checkpoint(folder)
    if config.get("format") != FORMAT:
        raise DataError(f"{folder} is not a generator checkpoint (format "
                        f"{config.get('format')!r}, expected {FORMAT!r})")
    try:
        pcfg = PromptConfig(**config["prompt"])
        dcfg = DecoderConfig(**config["decoder"])
    except (KeyError, TypeError) as e:
        raise DataError(f"generator config in {folder} is unreadable: {e}") from e
    parts = _split_state(state)
    small = dcfg.kind == "small"
    lora = bool(config.get("lora")) and not stage1
    # every file read below must be one the manifest recorded (and so was checked)
    require_files(folder, manifest, [TOKENIZER_FILE] * small + [
        f"{ADAPTER_DIR}/{ADAPTER_CONFIG}", f"{ADAPTER_DIR}/{ADAPTER_WEIGHTS}"] * lora)
    tokenizer = TactileTokenizer.load(folder / TOKENIZER_FILE) if small else None
    decoder = build_decoder(dcfg, tokenizer)
    if small:
        load_into(decoder.model, parts.get("decoder", {}), f"{folder} (decoder)")
    if lora:
        decoder.load_adapter(folder / ADAPTER_DIR)
    prompt = BaselinePrompt(pcfg)
    load_into(prompt, parts.get("prompt", {}), f"{folder} (prompt)")
    integrator = None
    if config.get("integrator") is not None and not stage1:
        if integrator_factory is None:
            raise ConfigError(f"{folder} holds an integrator: pass integrator_factory")
        integrator = integrator_factory(config["integrator"])
        load_into(integrator, parts.get("integrator", {}), f"{folder} (integrator)")
    elif integrator_factory is not None and not stage1:
        raise ConfigError(f"{folder} holds no integrator, yet integrator_factory was given")
    gen = RATouchGenerator(prompt, decoder, integrator).eval()
    gen.requires_grad_(False)
    return gen


def _split_state(state: dict[str, Tensor]) -> dict[str, dict[str, Tensor]]:
    parts: dict[str, dict[str, Tensor]] = {}
    for key, value in state.items():
        part, _, rest = key.partition(".")
        if part not in ("prompt", "integrator", "decoder") or not rest:
            raise DataError(f"unexpected tensor {key!r} in a generator checkpoint")
        parts.setdefault(part, {})[rest] = value
    return parts

"""Greedy decoding of small LLaMA decoders on merged weights, without transformers' overhead.

The embedded decoder (4 layers, width 256, a 114-word vocabulary) costs about 6 MFLOP per
token, well under a millisecond, yet a `LlamaForCausalLM.forward` step spends several
milliseconds in Python (cache objects, masks, hooks, output dataclasses). This module is a
hand-written forward of the same LLaMA architecture for greedy decoding only:

* one prefill over ``<bos>, prefix, prompt``, then single-token steps;
* keys and values written into a cache preallocated for the whole generation;
* q/k/v and gate/up projections fused into one matmul each, the residual adds fused into the
  output matmuls (`torch.baddbmm`);
* one intra-op thread is the setting to serve with (`ratouch.threads`): a step is ~100 tiny
  ops, and a second OpenMP thread on shared cores stalls them;
* G decoders of one shape (RA-Touch's and the baseline's) decode together: their weights are
  stacked, so every matmul is one batched matmul over the G models and one step of Python
  serves both.

It reads the weights of a plain `LlamaForCausalLM` (LoRA merged) by their HF names and never
imports transformers; the reference is `Decoder._greedy`, and a slow test checks that both give
the same descriptions on the whole test split.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

if TYPE_CHECKING:  # for the annotations only: this module never imports transformers
    from transformers import LlamaForCausalLM


def supports(model: nn.Module) -> bool:
    """Whether `model` is a LLaMA this fast path computes exactly as transformers does:
    SiLU MLP, no biases, default RoPE, as many key/value heads as query heads."""
    cfg = getattr(model, "config", None)
    if cfg is None or getattr(cfg, "model_type", None) != "llama":
        return False
    rope = getattr(cfg, "rope_parameters", None) or {}
    return (getattr(cfg, "hidden_act", None) == "silu"
            and not getattr(cfg, "attention_bias", False) and not getattr(cfg, "mlp_bias", False)
            and cfg.num_key_value_heads == cfg.num_attention_heads
            and rope.get("rope_type", "default") == "default"
            and all(p.dtype == torch.float32 for p in model.parameters())
            and not any("lora_" in n for n, _ in model.named_parameters()))


def weights_version(models: Sequence[nn.Module]) -> tuple:
    """Identity and in-place-update counters of the models' weights: a `GreedyStack` built
    from them is stale once this changes (an optimiser step or `load_state_dict` bumps
    a tensor's `_version`)."""
    return tuple((id(m), tuple(_version(p) for p in m.parameters())) for m in models)


def _version(p: Tensor) -> int:
    try:
        return p._version
    except RuntimeError:  # an inference tensor keeps no counter (and is never trained)
        return -1


class GreedyStack:
    """G LLaMA decoders of one shape, their weights stacked for decoding together.

    Args:
        models: plain `LlamaForCausalLM`s (no LoRA layers: merge first) of the same shape.

    Raises:
        ValueError: a model is not supported (see `supports`) or the shapes differ.
    """

    def __init__(self, models: Sequence[LlamaForCausalLM]):
        if not models or not all(supports(m) for m in models):
            raise ValueError("GreedyStack needs plain LLaMA models without LoRA layers")
        cfg = models[0].config
        keys = ("hidden_size", "num_hidden_layers", "num_attention_heads", "intermediate_size",
                "vocab_size", "rms_norm_eps")
        if any(getattr(m.config, k) != getattr(cfg, k) for m in models for k in keys):
            raise ValueError("GreedyStack needs models of one shape")
        self.version = weights_version(models)
        self.G, self.D, self.L = len(models), cfg.hidden_size, cfg.num_hidden_layers
        self.H = cfg.num_attention_heads
        self.hd, self.I = self.D // self.H, cfg.intermediate_size
        self.eps = cfg.rms_norm_eps
        with torch.no_grad():
            self._stack_weights(models)
            rot = models[0].model.rotary_emb
            self.inv_freq = rot.inv_freq.detach().float().clone()      # (hd/2,)
            self.rope_scale = float(rot.attention_scaling)
        self.max_positions = int(cfg.max_position_embeddings)
        # built once: `greedy` only reads the stack, so threads may share it
        self._cos, self._sin = self._rope_table(self.max_positions)

    def _stack_weights(self, models: Sequence[LlamaForCausalLM]) -> None:
        params = [dict(m.named_parameters()) for m in models]

        def w(names: Sequence[str]) -> Tensor:
            """The projections `names` side by side, (in, out) as x @ w = F.linear(x, weight):
            one (in, out) tensor when every model has the same weights (the two shipped
            generators share all but their LoRA-merged q and v), else stacked (G, in, out)."""
            per = [torch.cat([p[n].detach().t() for n in names], dim=1) for p in params]
            if all(torch.equal(per[0], x) for x in per[1:]):
                return per[0].contiguous()
            return torch.stack(per).contiguous()

        def norm(name: str) -> Tensor:  # (G, 1, D)
            return torch.stack([p[name].detach() for p in params]).unsqueeze(1).clone()

        self.layers = []
        for i in range(self.L):
            p = f"model.layers.{i}."
            self.layers.append({
                "ln1": norm(p + "input_layernorm.weight"),
                "ln2": norm(p + "post_attention_layernorm.weight"),
                "qkv": w([p + f"self_attn.{x}_proj.weight" for x in "qkv"]),   # (G?, D, 3D)
                "o": w([p + "self_attn.o_proj.weight"]),                       # (G?, D, D)
                "gate_up": w([p + "mlp.gate_proj.weight", p + "mlp.up_proj.weight"]),
                "down": w([p + "mlp.down_proj.weight"]),                       # (G?, I, D)
            })
        self.norm = norm("model.norm.weight")
        self.lm_head = torch.stack([m.get_output_embeddings().weight.detach().t()
                                    for m in models]).contiguous()                  # (G,D,V)
        self.embed = torch.stack([p["model.embed_tokens.weight"].detach()
                                  for p in params]).clone()                         # (G,V,D)

    def step_bytes(self) -> int:
        """Weight bytes one decoding step reads (each shared weight once; the embedding
        table is only indexed, so it is left out)."""
        tensors = [t for layer in self.layers for t in layer.values()] + [self.norm,
                                                                            self.lm_head]
        return sum(t.numel() * t.element_size() for t in tensors)

    def step_flops(self, rows: int) -> int:
        """Multiply-add FLOPs of one position of `rows` sequences per model, over the G
        models (matmuls only; attention over a few dozen positions is negligible)."""
        per_model = sum(t[0].numel() if t.dim() == 3 else t.numel()
                        for layer in self.layers for k, t in layer.items()
                        if k not in ("ln1", "ln2")) + self.lm_head[0].numel()
        return 2 * per_model * rows * self.G

    @staticmethod
    def _mm(x: Tensor, w: Tensor, add: Tensor | None = None) -> Tensor:
        """(add +) x @ w for x (G, N, in) and a shared (in, out) or stacked (G, in, out) w."""
        if w.dim() == 3:
            return torch.bmm(x, w) if add is None else torch.baddbmm(add, x, w)
        G, N, _ = x.shape
        flat = x.reshape(G * N, -1)
        out = flat @ w if add is None else torch.addmm(add.reshape(G * N, -1), flat, w)
        return out.view(G, N, -1)

    def _rope_table(self, n: int) -> tuple[Tensor, Tensor]:
        """cos and sign-folded sin for positions 0..n-1, each (n, hd), computed as
        transformers' LlamaRotaryEmbedding does (float32)."""
        pos = torch.arange(n, dtype=torch.float32)
        freqs = (self.inv_freq[:, None] @ pos[None, :]).t()                 # (n, hd/2)
        emb = torch.cat([freqs, freqs], dim=-1)                             # (n, hd)
        cos, sin = emb.cos() * self.rope_scale, emb.sin() * self.rope_scale
        h = self.hd // 2
        # rotate_half(q) * sin == roll(q, h) * [-sin_lo, sin_hi]: the sign moves onto sin
        return cos, torch.cat([-sin[:, :h], sin[:, h:]], dim=-1)

    def _rms(self, x: Tensor, w: Tensor) -> Tensor:
        var = x.pow(2).mean(-1, keepdim=True)
        return w * (x * torch.rsqrt(var + self.eps))

    def _forward(self, x: Tensor, cache: list[Tensor], pos: int, cos: Tensor,
                 sin: Tensor) -> Tensor:
        """Run S new positions of G x B sequences; x (G, B*S, D) -> (G, B*S, D)."""
        G, N, D = x.shape
        B = cache[0].shape[2]
        S = N // B
        for layer, kv in zip(self.layers, cache):
            h = self._rms(x, layer["ln1"])
            qkv = self._mm(h, layer["qkv"])                                # (G, B*S, 3D)
            qkv = qkv.view(G * B, S, 3, self.H, self.hd).permute(2, 0, 3, 1, 4)  # (3,GB,H,S,hd)
            qk = qkv[:2] * cos + qkv[:2].roll(self.hd // 2, -1) * sin       # (2,GB,H,S,hd)
            kv[0, :, :, :, pos:pos + S] = qk[1].view(G, B, self.H, S, self.hd)
            kv[1, :, :, :, pos:pos + S] = qkv[2].view(G, B, self.H, S, self.hd)
            keys = kv[0, :, :, :, :pos + S].reshape(G * B, self.H, pos + S, self.hd)
            vals = kv[1, :, :, :, :pos + S].reshape(G * B, self.H, pos + S, self.hd)
            a = F.scaled_dot_product_attention(qk[0], keys, vals, is_causal=S > 1)
            a = a.transpose(1, 2).reshape(G, N, D)                           # (G, B*S, D)
            x = self._mm(a, layer["o"], x)
            g, u = self._mm(self._rms(x, layer["ln2"]), layer["gate_up"]).split(self.I, -1)
            x = self._mm(F.silu(g) * u, layer["down"], x)              # (G, B*S, D)
        return x

    def _next(self, x: Tensor, B: int) -> Tensor:
        """Greedy next token of each sequence from its last position; (G, B)."""
        last = x.view(self.G, B, -1, self.D)[:, :, -1]                      # (G, B, D)
        return torch.bmm(self._rms(last, self.norm), self.lm_head).argmax(-1)  # (G, B)

    @torch.inference_mode()
    def greedy(self, context: Tensor, n: int, eos_id: int) -> Tensor:
        """Greedy continuation of G x B embedded contexts.

        Args:
            context: (G, B, C, D) embedded ``<bos>, prefix, prompt`` of each model's rows.
            n: new tokens at most (a row stops at its <eos>; later tokens of it are <eos>).
            eos_id: the end-of-sequence token.

        Returns:
            (G, B, steps) token ids, steps <= n (fewer when every row has ended).

        Runs on the calling thread's intra-op threads: serve with one (`ratouch.threads`).
        """
        G, B, C, D = context.shape
        assert G == self.G and D == self.D, (tuple(context.shape), self.G, self.D)
        if n == 0:
            return torch.empty(G, B, 0, dtype=torch.long)
        if C + n > self.max_positions:
            raise ValueError(f"context {C} + {n} new tokens exceed the model's "
                             f"{self.max_positions} positions")
        cos, sin = self._cos, self._sin
        cache = [torch.empty(2, G, B, self.H, C + n, self.hd) for _ in self.layers]
        x = self._forward(context.reshape(G, B * C, D).float(), cache, 0, cos[:C], sin[:C])
        tokens = torch.full((G, B, n), eos_id, dtype=torch.long)
        done = torch.zeros(G, B, dtype=torch.bool)
        rows = torch.arange(G)[:, None]                                     # (G, 1)
        for step in range(n):
            nxt = self._next(x, B).masked_fill(done, eos_id)                # (G, B)
            tokens[:, :, step] = nxt
            done |= nxt == eos_id
            if bool(done.all()) or step == n - 1:
                return tokens[:, :, :step + 1]
            p = C + step
            x = self._forward(self.embed[rows, nxt], cache, p, cos[p:p + 1], sin[p:p + 1])
        return tokens


class StackCache:
    """The `GreedyStack` of some models, rebuilt only when the models or their weights change
    (so a decoder still being trained never decodes with stale weights)."""

    def __init__(self) -> None:
        self._stack: GreedyStack | None = None

    def get(self, models: Sequence[LlamaForCausalLM]) -> GreedyStack:
        """The stack of `models`, built on first use and whenever their weights change."""
        stack = self._stack
        if stack is None or stack.version != weights_version(models):
            stack = self._stack = GreedyStack(models)
        return stack

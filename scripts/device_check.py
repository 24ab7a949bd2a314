"""The accelerator paths, checked against the CPU where a GPU is lent.

The test suite cannot run them: CI and the development machines have no GPU. Two paths take a
device, and this script runs each on the CPU and on `--device` and compares:

1. **The TVL encoders** (`create_model(encoder, pretrained=folder, device=...)`; `--encoder`,
   default `tvl-vitb`: OpenCLIP ViT-L-14 for images and text, TVL's ViT-Base for touch).
   Checkpoints of random values in the real layouts (an OpenCLIP `.safetensors` state dict and
   TVL's `tvl_enc_vit*.pth`, `model` -> `tactile_encoder.*`) are written to a temporary folder
   and loaded twice, once per device. Both embed the same `--n` images, tactile frames and
   texts: the lowest cosine between a row's two embeddings, and the median seconds of 3 calls
   (after a first, untimed one) on each device.
2. **The default encoders' training step** (`ratouch.train.encoders.step_losses`, AdamW, the
   shipped recipe's batch and learning rate, `TrainConfig.device`) on random inputs of the
   training data's shapes: from one initialisation, `--steps` steps on each device. Agreement
   is read in eval mode (dropout draws differ between a CPU's and a GPU's generators), the
   time per step in training mode.

    python scripts/device_check.py --device cuda [--encoder tvl-vitb] [--n 32] [--steps 20]
        [--precision fp32|bf16] [--model default-s] [--batch B] [--json out.json]

Exit status 0; 1 when a cosine is below --min-cos or a step's loss differs from the CPU's by
more than --loss-tol (relative); 2 when the device cannot be used.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np
import torch

from ratouch.encoders.factory import create_model, model_config
from ratouch.errors import ConfigError
from ratouch.train.encoders import TrainConfig, step_losses


def random_tvl_weights(encoder: str, folder: Path, seed: int = 0) -> None:
    """Checkpoints of `encoder`'s architectures, random values, in the layouts `create_model`
    reads: `open_clip_model.safetensors` and `tvl_enc_vit*.pth`."""
    import open_clip
    import timm
    from safetensors.torch import save_file

    cfg = model_config(encoder)
    gen = torch.Generator().manual_seed(seed)

    def fill(model: torch.nn.Module) -> dict:
        state = model.state_dict()
        with torch.no_grad():  # small values: the towers' activations stay finite
            for name, t in state.items():
                if t.is_floating_point():
                    noise = torch.randn(t.shape, generator=gen)
                    scale = name.endswith("weight") and "norm" in name
                    t.copy_(1 + 0.1 * noise if scale else 0.02 * noise)
        return state

    clip = open_clip.create_model(cfg["clip_arch"], pretrained=None)
    save_file({k: v.contiguous() for k, v in fill(clip).items()},
              str(folder / "open_clip_model.safetensors"))
    del clip
    tactile = timm.create_model(cfg["tactile_arch"], pretrained=False, num_classes=cfg["dim"],
                                global_pool="avg")
    state = {f"tactile_encoder.{k}": v for k, v in fill(tactile).items()}
    torch.save({"model": state}, folder / "tvl_enc_vit.pth")


def _timed(fn, repeats: int = 3) -> tuple[np.ndarray, float]:
    """fn's result and the median seconds of `repeats` calls after an untimed first one."""
    out = fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times))


def check_tvl(encoder: str, device: str, n: int, seed: int = 0,
              precision: str = "fp32") -> dict:
    """Part 1: the TVL encoders on the CPU (fp32) and on `device` (in `precision`), the
    same inputs."""
    rng = np.random.default_rng(seed)
    images = [rng.integers(0, 256, (300, 400, 3), np.uint8) for _ in range(n)]
    frames = [rng.integers(0, 256, (320, 240, 3), np.uint8) for _ in range(n)]
    words = ["soft", "hard", "rough", "smooth", "fuzzy", "metallic", "grainy", "cold"]
    texts = [f"{words[i % 8]}, {words[(3 * i + 1) % 8]}" for i in range(n)]
    report: dict = {"encoder": encoder, "n": n, "precision": precision}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        random_tvl_weights(encoder, Path(tmp), seed)
        report["write_seconds"] = round(time.perf_counter() - t0, 1)
        out: dict = {}
        for side, dev in (("cpu", "cpu"), ("device", device)):
            t0 = time.perf_counter()
            enc = create_model(encoder, pretrained=tmp, device=dev,
                               precision="fp32" if side == "cpu" else precision)
            load = time.perf_counter() - t0
            got = {"load_seconds": round(load, 2), "on": str(enc.device)}
            calls = {"image": partial(enc.encode_image, images),
                     "tactile": partial(enc.encode_tactile, frames),
                     "text": partial(enc.encode_text, texts)}
            for kind, fn in calls.items():
                emb, sec = _timed(fn)
                out.setdefault(kind, []).append(emb)
                got[f"{kind}_seconds"] = round(sec, 4)
            report[side] = got
            del enc, calls
    for kind, (a, b) in out.items():
        report[f"{kind}_min_cos"] = round(float(np.min(np.sum(a * b, axis=1))), 6)
        report[f"{kind}_speedup"] = round(report["cpu"][f"{kind}_seconds"]
                                          / max(report["device"][f"{kind}_seconds"], 1e-9), 1)
    return report


def _random_training_data(model, n: int, seed: int) -> tuple[dict, torch.Tensor, torch.Tensor,
                                                               torch.Tensor]:
    """Random inputs of the cached training data's shapes and dtypes for `model`, and a text
    table: (data, MiniLM features (T, 384), label ids, caption ids)."""
    from ratouch.encoders.default import TACTILE_CHANNELS
    from ratouch.encoders.prior import feature_dim

    rng = np.random.default_rng(seed)
    vh, vw = model.cfg.vision_size
    th, tw = model.cfg.tactile_size
    data = {"crops": rng.integers(0, 256, (n, vh, vw, 3), np.uint8),
            "corpus_images": rng.integers(0, 256, (n, vh, vw, 3), np.uint8),
            "tactile": rng.normal(size=(n, TACTILE_CHANNELS, th, tw)).astype(np.float16),
            "tactile_bg": rng.normal(size=(n, TACTILE_CHANNELS, th, tw)).astype(np.float16)}
    if model.cfg.prior:
        f = feature_dim(model.cfg.prior)
        data["prior_crops"] = rng.normal(size=(n, f)).astype(np.float16)
        data["prior_corpus"] = rng.normal(size=(n, f)).astype(np.float16)
    texts = 40
    minilm = torch.from_numpy(rng.normal(size=(texts, 384)).astype(np.float32))
    minilm = torch.nn.functional.normalize(minilm, dim=-1)
    lab = torch.from_numpy(rng.integers(0, texts, n))
    cap = torch.from_numpy(rng.integers(0, texts, n))
    return data, minilm, lab, cap


def _run_steps(model, data, minilm, lab, cap, tc: TrainConfig, steps: int,
               train: bool) -> tuple[list[float], float]:
    """`steps` AdamW steps on `tc.device`: each step's summed loss, median seconds a step."""
    dev = torch.device(tc.device)
    model = model.to(dev).train(train)
    table = minilm.to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    gen = torch.Generator().manual_seed(tc.seed)
    losses, times = [], []
    for _ in range(steps):
        t0 = time.perf_counter()
        loss = sum(step_losses(model, data, table, lab, cap, tc.batch, gen).values())
        opt.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[union-attr]
        opt.step()
        losses.append(float(loss.detach()))  # reads the value back: the step has finished
        times.append(time.perf_counter() - t0)
    return losses, float(np.median(times[1:] if steps > 1 else times))


def check_training(model_name: str, device: str, steps: int, batch: int | None = None,
                   seed: int = 0) -> dict:
    """Part 2: the default encoders' training step on the CPU and on `device` (`batch`: the
    shipped recipe's where None)."""
    torch.manual_seed(seed)
    base = create_model(model_name, pretrained=None)
    tc = TrainConfig(model=model_name, seed=seed, **({} if batch is None else {"batch": batch}))
    data, minilm, lab, cap = _random_training_data(base, 4 * tc.batch, seed)
    report: dict = {"model": model_name, "batch": tc.batch, "steps": steps}
    runs = {}
    for side, dev in (("cpu", "cpu"), ("device", device)):
        tcd = dataclasses.replace(tc, device=dev)
        runs[side], _ = _run_steps(copy.deepcopy(base), data, minilm, lab, cap, tcd, steps, False)
        _, sec = _run_steps(copy.deepcopy(base), data, minilm, lab, cap, tcd, steps, True)
        report[f"{side}_step_seconds"] = round(sec, 4)
    a, b = np.array(runs["cpu"]), np.array(runs["device"])
    report["cpu_losses"] = [round(x, 5) for x in a.tolist()]
    report["device_losses"] = [round(x, 5) for x in b.tolist()]
    report["loss_max_rel_diff"] = float(np.max(np.abs(a - b) / np.abs(a)))
    report["speedup"] = round(report["cpu_step_seconds"]
                              / max(report["device_step_seconds"], 1e-9), 1)
    return report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="device_check")
    ap.add_argument("--device", default="cuda", help="the device to check against the CPU")
    ap.add_argument("--encoder", default="tvl-vitb", help="a TVL encoder set (part 1)")
    ap.add_argument("--model", default="default-s", help="a default encoder set (part 2)")
    ap.add_argument("--n", type=int, default=32, help="inputs of each kind (part 1)")
    ap.add_argument("--steps", type=int, default=20, help="training steps a device (part 2)")
    ap.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                    help="the TVL towers' forward on --device (part 1; the CPU's is fp32)")
    ap.add_argument("--batch", type=int, default=None,
                    help="training batch (part 2; default: the shipped recipe's)")
    ap.add_argument("--min-cos", type=float, default=0.999)
    ap.add_argument("--loss-tol", type=float, default=1e-3)
    ap.add_argument("--json", default=None, help="also write the report here")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.n < 1 or args.steps < 1:
        ap.error("--n and --steps must be at least 1")
    try:
        torch.empty(1, device=args.device)
    except (RuntimeError, AssertionError) as e:
        print(f"device_check: cannot use device {args.device!r}: {e}", file=sys.stderr)
        return 2
    report: dict = {"device": args.device, "torch": torch.__version__,
                    "device_name": (torch.cuda.get_device_name(0)
                                    if torch.device(args.device).type == "cuda" else "cpu"),
                    "cpu_threads": torch.get_num_threads()}
    try:
        report["tvl"] = check_tvl(args.encoder, args.device, args.n, precision=args.precision)
        print(json.dumps({"tvl": report["tvl"]}), flush=True)
        report["training"] = check_training(args.model, args.device, args.steps, args.batch)
    except ConfigError as e:
        print(f"device_check: {e}", file=sys.stderr)
        return 2
    tvl, tr = report["tvl"], report["training"]
    worst_cos = min(tvl[f"{k}_min_cos"] for k in ("image", "tactile", "text"))
    report["passed"] = bool(worst_cos >= args.min_cos and tr["loss_max_rel_diff"] <= args.loss_tol)
    text = json.dumps(report, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())

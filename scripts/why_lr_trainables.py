"""Does the paper's integrator start reading its neighbours with another learning rate, or with
other stage-2 trainables?

The last two items of issue 11's "find out why" list, for docs/premise.md. RA-Touch's stage 2 is
retrained from the shipped stage-1 model on the shipped retrieval (each pair's own joint-query
neighbours, as in training the shipped generator), with the shipped budget (600 steps, batch 64),
changing one thing at a time:

    lr_0.3x       learning rate 3e-4 (shipped 1e-3), integrator + LoRA
    lr_3x         learning rate 3e-3, integrator + LoRA
    integrator    the integrator alone trains (LoRA frozen at zero): the decoder cannot adapt
                  around the integrator, so every stage-2 gain has to come through it
    with_prompt   integrator + LoRA + the prompt projection (the paper freezes the projection)

Each variant (and the shipped RA-Touch, for reference) is judged on the premise's seen and scarce
groups with its own neighbours and with another query's (one derangement), against the shipped
baseline. Criterion, fixed before the first run: a variant *reads its neighbours* when the
shuffle drop on scarce materials is > 0 with a paired t-test p < 0.01. If none does, learning
rate and trainables are not why the shipped integrator ignores them.

    python scripts/why_lr_trainables.py [--n 500] [--steps 600] [--variants a,b,...] [--pairs N]

(`--pairs N`: train on the first N paired training renders instead of all of them: a smoke run.)
"""

from __future__ import annotations

import argparse
import copy
import json
import time

import torch
from scipy import stats

from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split
from ratouch.eval.controls import derangement
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.premise import GROUPS, group_split
from ratouch.model.generator import load_generator, trainable_parameters
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.paths import generator_weights
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.train.generator import GeneratorTrainConfig, _steps
from ratouch.train.recipes import training_pairs
from ratouch.world.scarcity import ScarceRegime

VARIANTS = {  # name: (learning rate, which parameters train)
    "lr_0.3x": (3e-4, "integrator+lora"),
    "lr_3x": (3e-3, "integrator+lora"),
    "integrator": (1e-3, "integrator"),
    "with_prompt": (1e-3, "integrator+lora+prompt"),
}


def train_variant(stage1, dim: int, lr: float, which: str, V, T, labels, rv, rl,
                  tc: GeneratorTrainConfig):
    """RA-Touch's stage 2 (as `train_stage2`) with the variant's learning rate and trainables."""
    torch.manual_seed(tc.seed)
    gen = copy.deepcopy(stage1)
    gen.integrator = TextureAwareIntegrator(IntegratorConfig(dim=dim, out_dim=stage1.decoder.hidden))
    gen.decoder.add_lora(gen.decoder.cfg, seed=tc.seed)
    params = trainable_parameters(gen, "ra", train_prompt=which.endswith("+prompt"))
    if which == "integrator":
        for name, p in gen.decoder.named_parameters():
            if "lora_" in name:
                p.requires_grad_(False)
        params = [p for p in gen.parameters() if p.requires_grad]
    _steps(gen, params, V, T, labels, rv, rl, tc.stage2_steps, tc.batch, lr, tc.seed + 1, which)
    gen.decoder.merge_lora()
    return gen


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--pairs", type=int, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(2)
    t0 = time.perf_counter()
    pipe = RATouchPipeline.load("default-s")
    data = training_pairs(pipe.encoders, n_pairs=args.pairs)
    rv, rl = pipe.neighbour_embeddings(pipe.joint_neighbours(data["V"], data["T"], 5))
    stage1 = load_generator(generator_weights("default-s", "ra"), stage1=True)
    tc = GeneratorTrainConfig(seed=0, stage2_steps=args.steps)
    models = {"shipped": pipe.generator_ra}
    for name in args.variants.split(","):
        lr, which = VARIANTS[name]
        models[name] = train_variant(stage1, pipe.encoders.dim, lr, which,
                                     torch.from_numpy(data["V"]), torch.from_numpy(data["T"]),
                                     data["labels"], torch.from_numpy(rv), torch.from_numpy(rl), tc)
        print(f"trained {name} ({time.perf_counter() - t0:.0f} s)", flush=True)
    judge, out = OfflineJudge(), {"config": {"n": args.n, "stage2_steps": args.steps,
                                             "variants": {k: VARIANTS[k] for k in models
                                                          if k in VARIANTS}}}

    def scores(gen, split, nb, name):
        return answer_split(pipe, split, RA_TOUCH, ids=nb, generator=gen, name=name,
                            judge=judge).scores

    for g in GROUPS:
        split = group_split(pipe.encoders, g, args.n, ScarceRegime())
        nb = pipe.joint_neighbours(split.V, split.T, 5)
        shuffled = nb[derangement(len(nb), 0)]
        base = answer_split(pipe, split, BASELINE, judge=judge).scores
        out[g] = {"baseline": round(float(base.mean()), 4)}
        for name, gen in models.items():
            own, shuf = scores(gen, split, nb, name), scores(gen, split, shuffled, name + "_shuf")
            d, drop = own - base, own - shuf
            out[g][name] = {"score": round(float(own.mean()), 4),
                            "gain": round(float(d.mean()), 4),
                            "gain_p": float(stats.ttest_1samp(d, 0).pvalue),
                            "shuffle_drop": round(float(drop.mean()), 4),
                            "shuffle_p": float(stats.ttest_1samp(drop, 0).pvalue),
                            "reads": bool(drop.mean() > 0
                                          and stats.ttest_1samp(drop, 0).pvalue < 0.01)}
        print(g, json.dumps(out[g]), flush=True)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
